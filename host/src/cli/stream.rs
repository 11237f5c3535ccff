//! `placedb stream`: a recorded sequence streamed to a device (a board, an
//! emulator or `local:PROFILE`), with a live status line and a summary.

use super::{open_sequence, voxel_config, SeqArgs};
use crate::board::client::{self, Client};
use crate::board::error::DeviceError;
use crate::board::export;
use crate::board::link::{self, fault::FaultConfig, fault::FaultInjector};
use crate::board::scan::{status_line, stream, stream_config, Recovery, StreamReport};
use crate::degradation::{self, plural, DeviceCounters};
use crate::error::CommandError as Error;
use crate::pipeline::SolverParams;
use crate::sequence::Sequence;
use crate::voxelize::VoxelConfig;
use clap::Args;
use indicatif::ProgressBar;
use placedb::SelectorConfig;
use std::path::{Path, PathBuf};
use std::time::Duration;

pub mod realtime;

/// `placedb stream`: the sequence options of select, a port and the selector's.
#[derive(Args)]
pub struct StreamArgs {
    #[command(flatten)]
    seq: SeqArgs,
    /// Device: a serial port (/dev/ttyACM0), a board's USB serial number
    /// (placedb.example:E6614103E7452D2F) or the end of its hex ID (2D2F),
    /// tcp:HOST:PORT (the emulator) or local:PROFILE.
    #[arg(long)]
    port: String,
    /// IoU threshold, from 0 to below 1: frames overlap when IoU > mu.
    #[arg(long, default_value_t = 0.3, value_parser = super::params::mu, allow_negative_numbers = true)]
    mu: f32,
    /// Frames held undecided, from 1 to the profile's window (`placedb budget` lists it).
    #[arg(long, default_value_t = 32, value_parser = super::params::window(), allow_negative_numbers = true)]
    window: u16,
    /// Capacity profile the device's firmware was built with (checked).
    #[arg(long, default_value = "ram512k", value_parser = super::params::profile())]
    profile: String,
    /// Also export the result into this directory (as `placedb export -o`).
    #[arg(short, long)]
    out: Option<PathBuf>,
    /// No progress bar.
    #[arg(long, short)]
    quiet: bool,
    /// Fault injection: chance that a frame is dropped, each direction (0..1).
    #[arg(long, default_value_t = 0.0, value_parser = super::params::chance, allow_negative_numbers = true)]
    drop_chance: f64,
    /// Fault injection: chance that a frame has one bit flipped, each direction (0..1).
    #[arg(long, default_value_t = 0.0, value_parser = super::params::chance, allow_negative_numbers = true)]
    corrupt_chance: f64,
    /// Seed of the fault injector's PRNG (a run is reproducible).
    #[arg(long, default_value_t = 1, value_parser = super::params::whole::<u64>(0, u64::MAX), allow_negative_numbers = true)]
    fault_seed: u64,
    /// Retransmissions per message (stop-and-wait). Default: 0 (pipelined, the
    /// first error stops the stream) without fault injection, 20 with; 0 to 1000.
    #[arg(long, value_parser = super::params::whole::<usize>(0, 1000), allow_negative_numbers = true)]
    retries: Option<usize>,
    /// With retransmission: the longest wait, in milliseconds (1 to 3600000), for a reply before sending again; shorter waits follow the link's measured round trip, and only a wait this long counts against --retries.
    #[arg(long, default_value_t = 2000, value_parser = super::params::whole::<usize>(1, 3_600_000), allow_negative_numbers = true)]
    resend_ms: usize,
    /// Go on with the scan the device holds (e.g. restored from flash after a
    /// power cut) from its first undecided frame, instead of starting over.
    #[arg(long)]
    resume: bool,
    /// Continue the finished scan the device holds in flash with this
    /// sequence as a new session (same options as the first session's):
    /// its frames are numbered on from the earlier sessions', and the
    /// export holds every session.
    #[arg(long, conflicts_with = "resume")]
    extend: bool,
    /// Leave the scan open (no Finish): more frames can follow with --resume.
    #[arg(long)]
    no_finish: bool,
    /// Replace the scan the board holds (finished or not) with a new one.
    /// Without it a board holding a scan is refused, naming what it holds.
    #[arg(long, conflicts_with_all = ["resume", "extend"])]
    new_scan: bool,
    /// Replay at the sequence's recorded rate, as a live camera delivers it:
    /// a frame due while the device is still busy with earlier ones is
    /// skipped (named in the output and in skipped.csv with -o; it has no
    /// label) instead of waiting. -o numbers the frames by the sequence.
    /// The camera's rate is the layout's: a stamped sequence (TUM, ROS 2,
    /// the reference layout with timestamps) at its stamps; one that only
    /// numbers its frames (7-Scenes) at 30 frames/s by position, so gaps in
    /// the numbering never idle.
    #[arg(long, conflicts_with_all = ["resume", "extend", "no_finish", "drop_chance", "corrupt_chance", "retries"])]
    realtime: bool,
    /// With --realtime: replay at HZ frames per second (above 0 to 1000)
    /// by position in the sequence, whatever the layout's rate or stamps.
    #[arg(long, value_name = "HZ", requires = "realtime", value_parser = super::params::rate, allow_negative_numbers = true)]
    rate: Option<f64>,
}

/// Runs `placedb stream`.
pub fn run(a: StreamArgs) -> Result<(), Error> {
    super::params::check_window(&a.profile, a.window)?;
    // A refused or unwritable -o fails before the sequence is read.
    if let Some(dir) = &a.out {
        crate::output::check_database_dir(dir)?;
    }
    let seq = open_sequence(&a.seq)?;
    let v = voxel_config(&a.seq);
    let sel = placedb::SelectorConfig {
        mu: a.mu,
        window: a.window,
        sketch_margin: SolverParams::default().sketch_margin,
    };
    let out = a.out.as_deref();
    // The in-process device ends with this command: its result is only
    // kept in the directory of -o.
    if out.is_none() && a.port.starts_with("local:") {
        return Err(format!(
            "--port {}: the in-process device ends with this command, and its result with it: give -o DIR to export it",
            a.port
        )
        .into());
    }
    // A sequence that would measure nothing is refused before the device
    // is touched.
    degradation::check_depth(&seq, v.range, v.stride)?;
    if a.realtime {
        realtime::realtime_cmd(&a.port, &seq, &v, sel, &a.profile, a.rate, a.new_scan, out)?;
        return Ok(());
    }
    let recovery = Recovery {
        faults: FaultConfig::new(a.drop_chance, a.corrupt_chance, a.fault_seed),
        retries: a.retries,
        resend_after: Duration::from_millis(a.resend_ms as u64),
        resume: a.resume,
        extend: a.extend,
        finish: !a.no_finish,
        new_scan: a.new_scan,
    };
    stream_cmd(&a.port, &seq, &v, sel, &a.profile, out, a.quiet, &recovery)?;
    Ok(())
}

/// `e`, or, when the board went away mid-stream (reset, unplugged, its
/// emulator ended), what to do: the board keeps its scan in flash, so the
/// same command with `--resume` goes on from its first undecided frame.
fn lost_board(e: DeviceError, port: &str) -> DeviceError {
    use std::io::ErrorKind as K;
    match &e {
        DeviceError::Io(io)
            if matches!(
                io.kind(),
                K::ConnectionReset | K::ConnectionAborted | K::BrokenPipe | K::UnexpectedEof
            ) && !port.starts_with("local:") =>
        {
            DeviceError::Input(format!(
                "the board on {port} went away mid-stream ({}): restart it (its scan is kept \
                 in flash) and run the same command again with --resume to go on from its \
                 first undecided frame",
                crate::error::io_words(io)
            ))
        }
        _ => e,
    }
}

/// `placedb stream`: streams `seq` (configured by `vcfg` and `sel`, as
/// `placedb select` is) to the device on `port`, which must run `profile`;
/// prints a summary, and exports into `out` if given. `recovery` injects
/// faults into the link and sets the retransmission policy.
#[allow(clippy::too_many_arguments)]
pub fn stream_cmd(
    port: &str,
    seq: &Sequence,
    vcfg: &VoxelConfig,
    sel: SelectorConfig,
    profile: &str,
    out: Option<&Path>,
    quiet: bool,
    recovery: &Recovery,
) -> Result<StreamReport, DeviceError> {
    recovery.faults.validate().map_err(DeviceError::Input)?;
    if let Some(dir) = out {
        crate::output::check_database_dir(dir)?;
    }
    let (scan, sel, cfg) = stream_config(seq, vcfg, sel, profile)?;
    let link = link::open(port, Duration::from_secs(10))?;
    let mut client = Client::new(FaultInjector::new(link, recovery.faults));
    let pb = (!quiet).then(|| {
        let pb = ProgressBar::new(seq.frames.len() as u64);
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} frames {msg}",
        ) {
            pb.set_style(style);
        }
        pb
    });
    // Ctrl-C or SIGTERM ends the stream between frames, the board left
    // ready for `--resume` (a second one stops at once).
    crate::output::replace::defer_stop();
    let streamed = stream(
        &mut client,
        seq,
        &cfg,
        profile,
        &recovery.stream_options(),
        pb.as_ref(),
    );
    if let Some(pb) = &pb {
        pb.finish_and_clear();
    }
    if let Err(DeviceError::Stopped { signal, next }) = streamed {
        eprintln!(
            "placedb: stopped by {} before frame {next}: every frame sent is answered and none \
             is left open on the board at {port}; go on with the same command and --resume",
            if signal == libc::SIGINT {
                "Ctrl-C"
            } else {
                "SIGTERM"
            }
        );
        crate::output::replace::stop_now(signal);
    }
    let report = streamed.map_err(|e| lost_board(e, port))?;
    // What follows (the summary, the export of -o) stops at once, as any
    // run that writes outputs.
    crate::output::replace::end_defer();
    if let Some(signal) = crate::output::replace::stop_requested() {
        // Stopped after the last frame: the scan is streamed (finished
        // unless --no-finish); the export is not made.
        eprintln!(
            "placedb: stopped after the last frame: the board at {port} holds the scan; \
             export it with placedb export --port {port} -o DIR"
        );
        crate::output::replace::stop_now(signal);
    }
    let st = &report.status;
    if report.frames > 0 && st.valid_pixels == 0 {
        return Err(DeviceError::Input(format!(
            "the device found no valid depth pixel in any frame: {}",
            degradation::no_valid_pixel(seq, vcfg.range)
        )));
    }
    if st.sessions > 1 {
        println!(
            "{}: session {} of the device's scan, frames {}..{} (the earlier sessions hold frames 0..{})",
            seq.name,
            st.sessions - 1,
            report.first_index,
            report.first_index as usize + seq.frames.len(),
            report.first_index
        );
    }
    println!(
        "{}: {} -> {} on the device ({} profile, mu {}, window {}, stride {})",
        seq.name,
        plural(report.frames as u64, "frame", "frames"),
        plural(st.database_size.into(), "database frame", "database frames"),
        profile,
        sel.mu,
        sel.window,
        scan.stride
    );
    println!(
        "  link: {:.1} s, {:.2} frames/s, {} messages, {:.1} KB sent ({:.1} KB/s)",
        report.wall.as_secs_f64(),
        report.fps(),
        report.messages,
        report.bytes_sent as f64 / 1e3,
        report.bytes_sent as f64 / 1e3 / report.wall.as_secs_f64().max(1e-9)
    );
    if let Some(t) = report.ticks_per_frame() {
        println!(
            "  device: {:.3} M clock ticks per frame (max {:.3} M) at {} Hz: {:.2} ms of device time per frame{}",
            t / 1e6,
            f64::from(st.cost.max) / 1e6,
            st.cost.clock_hz,
            1e3 * t / f64::from(st.cost.clock_hz),
            clock_words(st.cost.clock_hz)
        );
    }
    if let Some(restart) = client::restart_words(st) {
        println!("  {restart}");
    }
    for warning in client::flash_warnings(st) {
        println!("  WARNING: {warning}");
    }
    if let Some(k) = report.log_full_at {
        println!(
            "  the device's flash log is full: frames {k}..{} of the sequence were not \
             scanned; the scan was finished with frames 0..{k} of it (Reset the device, or \
             give it more flash, for a longer scan)",
            seq.frames.len()
        );
    }
    if recovery.faults.is_active() {
        let f = client.link().stats();
        let lost = report.decisions.iter().filter(|d| d.is_none()).count();
        println!(
            "  faults (seed {}): host->device {} of {} frames dropped, {} corrupted; \
             device->host {} of {} dropped, {} corrupted; {} retransmissions; \
             {lost} decisions lost on the way (the export has them)",
            recovery.faults.seed,
            f.sent_dropped,
            f.sent,
            f.sent_corrupted,
            f.received_dropped,
            f.received,
            f.received_corrupted,
            report.retransmissions
        );
    }
    println!("  {}", status_line(st, Some(sel.window)));
    println!(
        "  input: {} skipped by the reader, {} outside the voxel key range (device count)",
        plural(seq.frames_skipped as u64, "frame", "frames"),
        plural(st.out_of_range_points.into(), "point", "points"),
    );
    let mut warnings = degradation::Losses {
        frames_skipped: seq.frames_skipped,
        out_of_range_points: st.out_of_range_points.into(),
        ..Default::default()
    }
    .warnings();
    warnings.extend(degradation::device_warnings(&DeviceCounters::of_device(st)));
    crate::warning::warn_all(&warnings);
    match out {
        Some(dir) => {
            let opts = recovery.export_options();
            let export = export::export_to_with(&mut client, dir, None, quiet, &opts, &[], None)?;
            super::export::print_exported(dir, &export, quiet);
        }
        None => println!("  pull the result with: placedb export --port {port} -o DIR"),
    }
    Ok(report)
}

/// What the ticks of a device reporting `clock_hz` are, in words for the
/// summary: the QEMU board counts instructions (1 GHz under `-icount
/// shift=0`), the Pico (board or emulator) its 1 MHz timer; any other clock
/// is named by its rate alone.
fn clock_words(clock_hz: u32) -> &'static str {
    match clock_hz {
        1_000_000_000 => " (the QEMU board's ticks: instructions under -icount shift=0)",
        1_000_000 => " (the Pico's ticks: its 1 MHz timer)",
        _ => "",
    }
}

#[cfg(test)]
mod clock_tests {
    use super::clock_words;

    #[test]
    fn the_words_name_the_board_that_clock_is() {
        assert!(clock_words(1_000_000_000).contains("QEMU"));
        assert!(clock_words(1_000_000).contains("Pico"));
        assert_eq!(clock_words(48_000_000), "");
    }
}
