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
//! through the `mcap` crate's writer (chunks of its default size).

use std::collections::BTreeMap;
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
    match recompress(input, output, compression) {
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

fn recompress(
    input: &str,
    output: &str,
    compression: Option<mcap::Compression>,
) -> Result<usize, Box<dyn std::error::Error>> {
    let bytes = std::fs::read(input)?;
    let out = std::io::BufWriter::new(std::fs::File::create(output)?);
    let mut writer = mcap::WriteOptions::new()
        .compression(compression)
        .profile("ros2")
        .create(out)?;
    // Channels by their id in the input: the id each has in the output.
    let mut channels = BTreeMap::new();
    let mut n = 0;
    for message in mcap::MessageStream::new(&bytes)? {
        let message = message?;
        let channel = &message.channel;
        let id = match channels.get(&channel.id) {
            Some(&id) => id,
            None => {
                let schema = match &channel.schema {
                    Some(s) => writer.add_schema(&s.name, &s.encoding, &s.data)?,
                    None => 0,
                };
                let id = writer.add_channel(
                    schema,
                    &channel.topic,
                    &channel.message_encoding,
                    &channel.metadata,
                )?;
                channels.insert(channel.id, id);
                id
            }
        };
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: message.sequence,
            log_time: message.log_time,
            publish_time: message.publish_time,
        };
        writer.write_to_known_channel(&header, &message.data)?;
        n += 1;
    }
    writer.finish()?;
    Ok(n)
}
