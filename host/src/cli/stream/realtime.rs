//! `placedb stream --realtime`: a recorded sequence replayed to a device at
//! its recorded rate ([`crate::board::pacing::stream_realtime`]), frames
//! the device is still busy for skipped and named, and the summary printed.

use crate::board::client::Client;
use crate::board::error::DeviceError;
use crate::board::link::{self, Link};
use crate::board::pacing::{index_ranges, stream_realtime, Pace, RealtimeReport};
use crate::board::scan::{stream_config, StreamOptions};
use crate::board::session::Session;
use crate::sequence::Sequence;
use crate::voxelize::VoxelConfig;
use placedb::SelectorConfig;
use std::path::Path;
use std::time::Duration;

/// `placedb stream --realtime`: replays `seq` to the device on `port` at
/// the camera's rate, or at `rate` frames per second (`--rate`)
/// ([`realtime_on`], [`Pace::of`]); `new_scan`: replace the scan the device
/// holds ([`StreamOptions::new_scan`]). A refused `seq`, selector, profile,
/// rate or `out` fails before the port is opened.
#[allow(clippy::too_many_arguments)]
pub fn realtime_cmd(
    port: &str,
    seq: &Sequence,
    vcfg: &VoxelConfig,
    sel: SelectorConfig,
    profile: &str,
    rate: Option<f64>,
    new_scan: bool,
    out: Option<&Path>,
) -> Result<RealtimeReport, DeviceError> {
    stream_config(seq, vcfg, sel, profile)?;
    Pace::of(seq, rate)?;
    if let Some(dir) = out {
        crate::output::check_database_dir(dir)?;
    }
    let link = link::open(port, Duration::from_secs(10))?;
    realtime_on(link, port, seq, vcfg, sel, profile, rate, new_scan, out)
}

/// `count` things, `first` to `first + count - 1` in words: "frame 0",
/// "frames 0 to 5".
fn numbered(count: usize) -> String {
    match count {
        0 => "no frame".to_string(),
        1 => "the 1 sent frame 0".to_string(),
        n => format!("the {n} sent frames 0 to {}", n - 1),
    }
}

/// `placedb stream --realtime` on `link` (the device on `port`):
/// [`stream_realtime`] at [`Pace::of`]`(seq, rate)`, refused if it measured nothing
/// ([`RealtimeReport::check_measured`]); prints what was skipped and the
/// database the device got, and with `out` exports it there numbered by
/// the sequence's frames (the device numbers only those it received), with
/// `skipped.csv` (sequence frame and timestamp of every skipped frame,
/// which has no row in `labels.csv`).
#[allow(clippy::too_many_arguments)]
pub fn realtime_on<L: Link>(
    link: L,
    port: &str,
    seq: &Sequence,
    vcfg: &VoxelConfig,
    sel: SelectorConfig,
    profile: &str,
    rate: Option<f64>,
    new_scan: bool,
    out: Option<&Path>,
) -> Result<RealtimeReport, DeviceError> {
    let (scan, sel, cfg) = stream_config(seq, vcfg, sel, profile)?;
    let pace = Pace::of(seq, rate)?;
    let opts = StreamOptions {
        new_scan,
        ..StreamOptions::default()
    };
    let mut session = Session::new(Client::new(link), opts);
    let report = stream_realtime(&mut session, seq, &cfg, profile, &pace)?;
    report.check_measured(seq)?;
    let n = seq.frames.len();
    println!(
        "{}: {n} frames replayed at {:.1} frames/s ({}) in {:.1} s: {} sent, {} skipped \
         (the device was busy when they were due; they have no label)",
        seq.name,
        report.rate,
        report.rate_source,
        report.wall.as_secs_f64(),
        report.sent.len(),
        report.skipped.len(),
    );
    if !report.skipped.is_empty() {
        println!(
            "  skipped frames (positions in the sequence, from 0): {}",
            index_ranges(&report.skipped)
        );
    }
    println!(
        "  database: {} on the device ({profile} profile, mu {}, window {}, stride {}); \
         the device numbers {} (positions {} of the sequence)",
        crate::degradation::plural(u64::from(report.status.database_size), "frame", "frames"),
        sel.mu,
        sel.window,
        scan.stride,
        numbered(report.sent.len()),
        index_ranges(&report.sent),
    );
    match out {
        Some(dir) => {
            let mut csv = String::from("frame,timestamp\n");
            for &i in &report.skipped {
                csv.push_str(&format!("{i},{:.6}\n", seq.frames[i].timestamp));
            }
            // skipped.csv is part of the export's directory: both or
            // neither. The tables name the sent frames as skipped.csv names
            // the others, by their place in the sequence, so that `export
            // --sequence SEQ` and its exports name them alike.
            session.export_to_with(dir, &[("skipped.csv", csv)], Some(&report.sent))?;
            let path = dir.join("skipped.csv");
            println!(
                "  {} numbered by the sequence's frames; {} skipped frames listed in {}",
                dir.join("{database,labels}.csv").display(),
                report.skipped.len(),
                path.display()
            );
        }
        None => println!("  pull the result with: placedb export --port {port} -o DIR"),
    }
    Ok(report)
}
