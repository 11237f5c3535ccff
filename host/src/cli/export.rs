//! `placedb export`: a device's database and labels pulled into a
//! directory (resumable, checked by count and CRC), and the dataset of the
//! exported labels when asked.

use super::{print_dataset, Ros2Args};
use crate::device::client::connect;
use crate::device::error::DeviceError;
use crate::device::export::{self, export_to, Export, ExportOptions};
use crate::error::CommandError as Error;
use crate::output::{self, dataset, exports, replace};
use crate::read::{self, ReadOptions};
use crate::Format;
use clap::Args;
use std::path::{Path, PathBuf};

/// `placedb export`.
#[derive(Args)]
pub struct ExportArgs {
    /// Device: a serial port (/dev/ttyACM0), tcp:HOST:PORT (the emulator) or local:PROFILE.
    #[arg(long)]
    port: String,
    /// Output directory for database.csv, labels.csv, metrics.json.
    #[arg(short, long)]
    out: PathBuf,
    /// Resume an interrupted export into the same directory from record K.
    #[arg(long)]
    from: Option<u32>,
    /// Also write a training-ready dataset (as `select --dataset`) from the
    /// exported labels and the frames of --sequence (the sequence streamed).
    #[arg(long, requires = "sequence")]
    dataset: Option<PathBuf>,
    /// With --dataset, --colmap, --vpr-eval or --pairs: the sequence that
    /// was streamed (directory or ROS 2 bag).
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
    exports: exports::ExportFlags,
    #[command(flatten)]
    streamed: exports::StreamedWith,
}

/// `placedb export`, and the dataset of the exported labels when asked.
pub fn run(a: ExportArgs) -> Result<(), Error> {
    // The sequence first: a wrong path fails before the device is touched.
    let seq = match &a.sequence {
        Some(path) => {
            let opts = ReadOptions {
                format: a.format,
                ros2: a.ros2.options(),
                ..ReadOptions::default()
            };
            Some(read::open(path, &opts)?)
        }
        None => None,
    };
    if seq.is_some() && a.dataset.is_none() && !a.exports.any() {
        return Err("--sequence is for --dataset, --colmap, --vpr-eval or --pairs".into());
    }
    if a.exports.any() && seq.is_none() {
        return Err(
            "--colmap, --vpr-eval and --pairs need --sequence SEQ (the streamed sequence)".into(),
        );
    }
    // A refused or unwritable output fails before the device is asked.
    output::check_outputs(&a.out, a.dataset.as_deref(), &a.exports)?;
    let mut client = connect(&a.port)?;
    let export = export::pull(
        &mut client,
        &a.out,
        a.from,
        a.quiet,
        &ExportOptions::default(),
    )?;
    if let Some(seq) = &seq {
        let (timestamps, _) = export.labels();
        // The device's timestamps are the sequence's: a different sequence shows.
        if let Some(i) = timestamps
            .iter()
            .zip(&seq.frames)
            .position(|(t, f)| *t != f.timestamp)
        {
            return Err(format!(
                "--sequence {}: frame {i} has timestamp {}, the device's has {}: not the streamed sequence?",
                seq.name, seq.frames[i].timestamp, timestamps[i]
            )
            .into());
        }
        if let Some(dir) = &a.dataset {
            if export.labels().1.is_empty() {
                // Nothing is written (the export and its dataset appear
                // together): an empty dataset would read as a made one.
                return Err(format!(
                    "--dataset {}: the device's export has no labelled frame (its scan decided \
                     none yet): no dataset written, nor {}. Finish the scan first (placedb stream \
                     {} --port {} --resume, with the options it was streamed with), or export \
                     without --dataset",
                    dir.display(),
                    a.out.display(),
                    a.sequence.as_deref().unwrap_or(Path::new("SEQ")).display(),
                    a.port
                )
                .into());
            }
        }
    }
    // The export, its dataset and exports appear together, or none does.
    let (dataset, exported) = replace::together(|outputs| {
        export::stage(outputs, &a.out, &export, &[])?;
        let Some(seq) = &seq else {
            return Ok((None, Vec::new()));
        };
        let dataset = match &a.dataset {
            Some(dir) => Some((dir, dataset::stage(outputs, dir, seq, &export.labels().1)?)),
            None => None,
        };
        let exported = exports::device::write_from_device(
            &a.exports,
            &a.streamed,
            seq,
            &export,
            a.quiet,
            outputs,
        )?;
        Ok((dataset, exported))
    })?;
    export::finished(&a.out, &export, a.quiet)?;
    if let Some((dir, d)) = &dataset {
        print_dataset(dir, d);
    }
    for line in exported {
        println!("{line}");
    }
    Ok(())
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
    export_to(&mut client, out, from, quiet)
}
