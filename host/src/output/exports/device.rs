//! The exports of `placedb export --sequence SEQ`: from a device's records,
//! through the same writers as `placedb select`'s, so that a board's scan
//! and the host's replay of it export alike.

use super::{write_all, ExportFlags, Selection, StreamedWith};
use crate::device::export::Export;
use crate::output::dataset::DatasetError;
use crate::output::replace::Outputs;
use crate::read::{self, ReadOptions};
use crate::sequence::Sequence;
use crate::VoxelConfig;

/// Writes the exports `flags` asks for from `export`, the device's records
/// of streamed sequence `seq`, into `outputs`; returns a line about each.
pub fn write_from_device(
    flags: &ExportFlags,
    streamed: &StreamedWith,
    seq: &Sequence,
    export: &Export,
    quiet: bool,
    outputs: &mut Outputs,
) -> Result<Vec<String>, DatasetError> {
    if !flags.any() {
        return Ok(Vec::new());
    }
    // database.csv's rows, as `select --solver online` writes them.
    let rows = crate::output::rows_from_records(&export.database());
    let (_, labels) = export.labels();
    // The overlaps of the streamed frames, on the grid the device used.
    let prep = match &flags.pairs {
        Some(_) => {
            let config = VoxelConfig {
                voxel: streamed.voxel,
                ..VoxelConfig::default()
            };
            let prep = crate::pipeline::prepare(seq, config, quiet).map_err(|e| match e {
                crate::voxelize::VoxelizeError::Read(r) => DatasetError::Read(r),
                other => DatasetError::Mismatch(other.to_string()),
            })?;
            Some(prep)
        }
        None => None,
    };
    let test = match &streamed.test {
        Some(path) => Some(read::open(path, &ReadOptions::default())?),
        None => None,
    };
    let sel = Selection {
        seq,
        rows: &rows,
        labels: &labels,
        overlaps: prep.as_ref().map(|p| &p.co),
        mu: streamed.mu,
        test: test.as_ref(),
    };
    write_all(flags, &sel, outputs)
}
