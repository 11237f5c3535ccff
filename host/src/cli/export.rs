//! `placedb export`: a device's database and labels pulled into a
//! directory (resumable, checked by count and CRC), and the dataset of the
//! exported labels when asked.

use super::{print_dataset, Ros2Args};
use crate::board::client::connect;
use crate::board::error::DeviceError;
use crate::board::export::{self, export_to, Export, ExportOptions};
use crate::board::pacing::index_ranges;
use crate::degradation::plural;
use crate::error::CommandError as Error;
use crate::error::OutputError;
use crate::output::exports::{write_all, ExportTargets, Selection};
use crate::output::replace::Outputs;
use crate::output::{self, dataset, replace};
use crate::read::{self, ReadOptions};
use crate::sequence::Sequence;
use crate::sessions::extension;
use crate::Format;
use clap::Args;
use placedb::protocol::{CapacitySlot, Config};
use std::path::{Path, PathBuf};

mod measure;
pub use measure::{measure, streamed_frames, Measuring};

/// `placedb export`.
#[derive(Args)]
pub struct ExportArgs {
    /// Device: a serial port (/dev/ttyACM0), a board's USB serial number
    /// (placedb.example:E6614103E7452D2F) or the end of its hex ID (2D2F),
    /// tcp:HOST:PORT (the emulator) or local:PROFILE.
    #[arg(long)]
    port: String,
    /// Output directory for database.csv, labels.csv, metrics.json.
    #[arg(short, long)]
    out: PathBuf,
    /// Resume an interrupted export into the same directory from record K.
    #[arg(long, value_parser = super::params::whole::<u32>(0, u32::MAX.into()), allow_negative_numbers = true)]
    from: Option<u32>,
    /// Also write a training-ready dataset (as `select --dataset`) from the
    /// exported labels and the frames of --sequence (the sequence streamed).
    #[arg(long, requires = "sequence")]
    dataset: Option<PathBuf>,
    /// The sequence that was streamed (directory, ROS 2 or ROS 1 bag): the
    /// coverage metrics of metrics.json are measured on it, and --dataset,
    /// --colmap, --vpr-eval and --pairs need it. The device's frames are
    /// found in it by timestamp (stream --realtime skips some) and every
    /// output numbers them by the sequence.
    #[arg(long)]
    sequence: Option<PathBuf>,
    /// With --dataset: the sequence's layout (detected when omitted).
    #[arg(long, value_enum)]
    format: Option<Format>,
    #[command(flatten)]
    ros2: Ros2Args,
    /// No progress bar.
    #[arg(long, short)]
    quiet: bool,
    #[command(flatten)]
    exports: super::ExportFlags,
    #[command(flatten)]
    streamed: StreamedWith,
}

/// What `export --sequence` needs to know of the stream for the exports:
/// the device's scan's settings, read from its flash log; the flags only
/// for a device that keeps no log ([`StreamedWith::resolve`]).
#[derive(clap::Args, Debug, Clone)]
pub struct StreamedWith {
    /// With --pairs: the IoU threshold the sequence was streamed with
    /// (default: the device's scan's, else 0.3); another than the device's
    /// is refused.
    #[arg(long, value_parser = super::params::mu, allow_negative_numbers = true)]
    pub mu: Option<f32>,
    /// With --pairs: the voxel edge in metres the sequence was streamed
    /// with (default: the device's scan's, else 0.3); another than the
    /// device's is refused.
    #[arg(long, value_parser = super::params::voxel, allow_negative_numbers = true)]
    pub voxel: Option<f32>,
    /// With --vpr-eval: a test sequence of the same place, whose frames are
    /// the queries (otherwise the non-database frames are).
    #[arg(long)]
    pub test: Option<PathBuf>,
}

/// `--mu` and `--voxel` of a device without a flash log, unless given.
const DEFAULT_MU: f32 = 0.3;
const DEFAULT_VOXEL: f32 = 0.3;

impl StreamedWith {
    /// The settings the exports use: those of the device's scan (`device`,
    /// from its flash log), a flag that contradicts one refused naming both
    /// values; without a log, the flags or their defaults.
    pub fn resolve(&self, device: Option<&Config>) -> Result<StreamedWith, String> {
        let pick = |flag: &str, given: Option<f32>, theirs: Option<f32>, default: f32| match (
            given, theirs,
        ) {
            (Some(g), Some(t)) if g != t => Err(format!(
                "{flag} {g} does not match the device's scan, made with {} {t}: the exports \
                     use the scan's own settings (leave {flag} out)",
                &flag[2..]
            )),
            (_, Some(t)) => Ok(t),
            (Some(g), None) => Ok(g),
            (None, None) => Ok(default),
        };
        Ok(StreamedWith {
            mu: Some(pick("--mu", self.mu, device.map(|c| c.mu), DEFAULT_MU)?),
            voxel: Some(pick(
                "--voxel",
                self.voxel,
                device.map(|c| c.voxel_size),
                DEFAULT_VOXEL,
            )?),
            test: self.test.clone(),
        })
    }
}

/// `placedb export`, and the dataset of the exported labels when asked.
pub fn run(a: ExportArgs) -> Result<(), Error> {
    // The sequence first: a wrong path fails before the device is touched.
    let seq = match &a.sequence {
        Some(path) => {
            let opts = ReadOptions {
                format: a.format,
                ros2: a.ros2.options(),
                pose_interpolation: a.ros2.pose_interpolation,
                ..ReadOptions::default()
            };
            Some(read::open(path, &opts)?)
        }
        None => None,
    };
    let targets = a.exports.targets();
    if targets.any() && seq.is_none() {
        return Err(
            "--colmap, --vpr-eval and --pairs need --sequence SEQ (the streamed sequence)".into(),
        );
    }
    // A refused or unwritable output fails before the device is asked.
    output::check_outputs(&a.out, a.dataset.as_deref(), &targets)?;
    if let (Some(file), Some(seq)) = (&targets.pairs, &seq) {
        // So does a colour file the pairs cannot name.
        crate::output::exports::pairs::names(seq, file)?;
    }
    let mut client = connect(&a.port)?;
    let mut export = export::pull(
        &mut client,
        &a.out,
        a.from,
        a.quiet,
        &ExportOptions::default(),
    )
    .map_err(|e| match e {
        // An in-process device is new in every command: say where its scan is.
        DeviceError::Input(m) if m == export::NO_SCAN && a.port.starts_with("local:") => {
            DeviceError::Input(format!(
                "{m}; a local:PROFILE device is new in every command, so keep its scan with \
                 `placedb stream -o DIR`"
            ))
        }
        e => e,
    })?;
    // A refusal of what was pulled (the scan is not of this sequence, a
    // setting contradicts the scan's) is no interrupted export: there is
    // nothing for --from to go on with, so its records go too, as a refused
    // run leaves nothing (docs/FORMATS.md).
    let (seq, measuring) = match streamed(&a, seq, &mut export) {
        Ok(found) => found,
        Err(e) => {
            let _ = export::finished(&a.out);
            return Err(e);
        }
    };
    // The export, its dataset and exports appear together, or none does.
    let (dataset, exported) = replace::together(|outputs| {
        let on = match (&seq, &measuring) {
            (Some(seq), Some(m)) => Some(m.on(seq)),
            _ => None,
        };
        export::stage(outputs, &a.out, &export, on.as_ref(), &[])?;
        let Some(seq) = &seq else {
            return Ok((None, Vec::new()));
        };
        let dataset = match &a.dataset {
            Some(dir) => Some((dir, dataset::stage(outputs, dir, seq, &export.labels().1)?)),
            None => None,
        };
        let exported =
            match &measuring {
                Some(m) => write_from_device(&targets, m, seq, &export, outputs)?,
                None if targets.any() => return Err(OutputError::Mismatch(
                    "--colmap, --vpr-eval and --pairs: the device's scan decided no frame yet: \
                     nothing to export (finish it with placedb stream --resume first)"
                        .into(),
                )),
                None => Vec::new(),
            };
        Ok((dataset, exported))
    })?;
    export::finished(&a.out)?;
    print_exported(&a.out, &export, a.quiet);
    if let (Some(seq), false) = (&seq, a.quiet) {
        print_numbered(seq);
    }
    if let Some((dir, d)) = &dataset {
        print_dataset(dir, d);
    }
    for line in exported {
        println!("{line}");
    }
    Ok(())
}

/// The frames of `seq` the device's scan `export` received, measured for
/// the exports, after the checks that refuse them (an empty dataset, a
/// sequence that is not the scan's, settings that contradict its own);
/// `(None, None)` without --sequence.
fn streamed(
    a: &ExportArgs,
    seq: Option<Sequence>,
    export: &mut Export,
) -> Result<(Option<Sequence>, Option<Measuring>), Error> {
    match seq {
        Some(seq) => {
            if let Some(dir) = &a.dataset {
                if export.labels().1.is_empty() {
                    // Nothing is written (the export and its dataset appear
                    // together): an empty dataset would read as a made one.
                    return Err(format!(
                        "--dataset {}: the device's export has no labelled frame (its scan \
                         decided none yet): no dataset written, nor {}. Finish the scan first \
                         (placedb stream {} --port {} --resume, with the options it was \
                         streamed with), or export without --dataset",
                        dir.display(),
                        a.out.display(),
                        a.sequence.as_deref().unwrap_or(Path::new("SEQ")).display(),
                        a.port
                    )
                    .into());
                }
            }
            let seq = measure::streamed_frames(seq, export)?;
            // The tables name the device's frames as the exports do: by
            // their numbers in the sequence.
            export.sequence_frames = Some(seq.frames.iter().map(|f| f.index).collect());
            let measuring = measure::measure(&seq, export, &a.streamed, a.quiet)?;
            Ok((Some(seq), measuring))
        }
        None => Ok((None, None)),
    }
}

/// The line saying which frames of `seq` (cut to the device's by
/// [`streamed_frames`]) the device received, when it was not sent every
/// frame up to its last: the outputs number them by the sequence.
fn print_numbered(seq: &Sequence) {
    let numbers: Vec<usize> = seq.frames.iter().map(|f| f.index).collect();
    if numbers.iter().copied().eq(0..numbers.len()) {
        return;
    }
    let last = numbers.last().map_or(0, |n| n + 1);
    println!(
        "  numbered by {}'s frames: the device received {} of its first {last} ({}; the others, \
         skipped by stream --realtime, have no row in labels.csv)",
        seq.name,
        plural(numbers.len() as u64, "frame", "frames"),
        index_ranges(&numbers)
    );
}

/// `placedb export`: pulls every record from the device on `port` and
/// writes `database.csv`, `labels.csv` and `metrics.json` to `out`.
/// `from = Some(k)` resumes an interrupted export of the same device state
/// from record `k` (the checked records before it are kept beside `out`,
/// [`export::resume_file`]).
pub fn export_cmd(
    port: &str,
    out: &Path,
    from: Option<u32>,
    quiet: bool,
) -> Result<Export, DeviceError> {
    output::check_database_dir(out)?;
    let mut client = connect(port)?;
    let export = export_to(&mut client, out, from, quiet)?;
    print_exported(out, &export, quiet);
    Ok(export)
}

/// The line saying what an export pulled and wrote to `out` (`export -o`
/// and `stream -o`; not when `quiet`), and a warning when the scan is open
/// (its undecided frames have no label yet) or was restored from flash
/// (its RAM counters are unknown).
pub fn print_exported(out: &Path, export: &Export, quiet: bool) {
    let st = &export.status;
    if st.phase != placedb::protocol::Phase::Finished {
        crate::warning::warn(format!(
            "the board's scan is open (not finished): {} seen, {} decided, {} undecided and \
             not in {}; finish it with placedb stream SEQ --port PORT --resume, then export again",
            plural(st.frames_seen.into(), "frame", "frames"),
            st.frames_decided,
            st.frames_seen.saturating_sub(st.frames_decided),
            out.display()
        ));
    }
    if st.degradation & placedb::protocol::degradation::RESTORED != 0 {
        crate::warning::warn(
            "the board restarted and restored this scan from flash: what it counts in RAM \
             (frames compared by sketch, truncated or uncovered, dropped labels) covers only the \
             frames since, so metrics.json reports those counters as null (unknown)",
        );
    }
    if quiet {
        return;
    }
    let firsts = export.sessions();
    println!(
        "exported {} ({}, {}{}), checked by count and CRC{}; wrote {}/{{database.csv,labels.csv,metrics.json{}}}",
        plural(export.records.len() as u64, "record", "records"),
        plural(export.status.database_size.into(), "database frame", "database frames"),
        plural(export.status.capacity(CapacitySlot::Labels).used.into(), "label", "labels"),
        match firsts.len() {
            1 => String::new(),
            n => format!(", {n} sessions"),
        },
        if export.retried > 0 {
            format!(" ({} batches retried)", export.retried)
        } else {
            String::new()
        },
        out.display(),
        if export.extension.is_some() {
            format!(",{}", extension::FILE_NAME)
        } else {
            String::new()
        }
    );
}

/// The exports of `placedb export --sequence SEQ`: writes those `flags`
/// asks for from `export`, the device's records of streamed sequence `seq`,
/// as `measuring` measured them ([`measure::measure`]: the scan's settings,
/// the overlaps on its grid), into `outputs`, through the same writers as
/// `placedb select`'s, so that a board's scan and the host's replay of it
/// export alike; returns a line about each.
pub fn write_from_device(
    flags: &ExportTargets,
    measuring: &Measuring,
    seq: &Sequence,
    export: &Export,
    outputs: &mut Outputs,
) -> Result<Vec<String>, OutputError> {
    if !flags.any() {
        return Ok(Vec::new());
    }
    let streamed = &measuring.streamed;
    // database.csv's rows, as `select --solver online` writes them.
    let rows = crate::output::rows_from_records(&export.database());
    let (_, labels) = export.labels();
    let test = match &streamed.test {
        Some(path) => Some(read::open(path, &ReadOptions::default())?),
        None => None,
    };
    let sel = Selection {
        seq,
        rows: &rows,
        labels: &labels,
        overlaps: Some(&measuring.prep.co),
        mu: streamed.mu.unwrap_or(DEFAULT_MU),
        test: test.as_ref(),
    };
    write_all(flags, &sel, outputs)
}
