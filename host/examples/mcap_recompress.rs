//! Rewrites an MCAP file with its chunks compressed by zstd or lz4 (or
//! none), as a rosbag2 storage preset (`zstd_fast`, `zstd_small`) records
//! them: the recordings the bench reads beside the PNG files
//! (docs/PERFORMANCE.md) come from the tests' fixture writer, whose MCAP
//! chunks are uncompressed.
//!
//! ```sh
//! cargo run --release -p placedb-host --example mcap_recompress -- IN.mcap OUT.mcap zstd
//! ```
//!
//! Every message is copied with its channel, schema, sequence and times,
//! through the `mcap` crate's writer (chunks of its default size), by
//! `placedb_host::testing::mcap_recompress`, which the tests use too.

use std::process::ExitCode;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [input, output, compression] = &args[..] else {
        eprintln!("usage: mcap_recompress IN.mcap OUT.mcap zstd|lz4|none");
        return ExitCode::from(2);
    };
    let compression = match compression.as_str() {
        "zstd" => Some(mcap::Compression::Zstd),
        "lz4" => Some(mcap::Compression::Lz4),
        "none" => None,
        other => {
            eprintln!("compression `{other}`: zstd, lz4 or none");
            return ExitCode::from(2);
        }
    };
    match placedb_host::testing::mcap_recompress(input.as_ref(), output.as_ref(), compression) {
        Ok(n) => {
            println!("wrote {output}: {n} messages");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
