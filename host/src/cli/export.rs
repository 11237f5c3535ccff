//! `placedb export`: a device's database and labels pulled into a
//! directory (resumable, checked by count and CRC), and the dataset of the
//! exported labels when asked.

use super::{print_dataset, Ros2Args};
use crate::device::client::connect;
use crate::device::error::DeviceError;
use crate::device::export::{export_to, Export};
use crate::error::CommandError as Error;
use crate::output::dataset;
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
    /// With --dataset: the sequence that was streamed (directory or ROS 2 bag).
    #[arg(long, requires = "dataset")]
    sequence: Option<PathBuf>,
    /// With --dataset: the sequence's layout (detected when omitted).
    #[arg(long, value_enum)]
    format: Option<Format>,
    #[command(flatten)]
    ros2: Ros2Args,
    /// No progress bar.
    #[arg(long, short)]
    quiet: bool,
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
    let export = export_cmd(&a.port, &a.out, a.from, a.quiet)?;
    if let (Some(dir), Some(seq)) = (&a.dataset, &seq) {
        let (timestamps, labels) = export.labels();
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
        let d = dataset::write(dir, seq, &labels)?;
        print_dataset(dir, &d);
    }
    Ok(())
}

/// `placedb export`: pulls every record from the device on `port` and
/// writes `database.csv`, `labels.csv` and `metrics.json` to `out`.
/// `from = Some(k)` resumes an interrupted export of the same device state
/// from record `k` (the checked records before it are kept in `out`).
pub fn export_cmd(
    port: &str,
    out: &Path,
    from: Option<u32>,
    quiet: bool,
) -> Result<Export, DeviceError> {
    let mut client = connect(port)?;
    export_to(&mut client, out, from, quiet)
}
