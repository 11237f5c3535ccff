//! `export --sequence SEQ`: the streamed sequence measured as the device
//! scanned it. The device keeps no voxel set of its frames, so the coverage
//! metrics of `metrics.json` and the overlaps `--pairs` lists come from
//! `SEQ` voxelized again on the scan's own grid: its voxel size, stride,
//! depth range, grid corner and camera, read from the device's flash log
//! (the flags, or their defaults, only for a device without one), so that
//! they are the figures `placedb select SEQ --solver online` with the same
//! settings writes.

use super::StreamedWith;
use crate::board::export::Export;
use crate::error::OutputError;
use crate::output::metrics_json::OnSequence;
use crate::pipeline::{self, Measured, Prepared};
use crate::sequence::{CameraModel, Sequence};
use crate::voxelize::{VoxelConfig, VoxelizeError};
use placedb::VoxelGrid;

/// The device's scan measured on its sequence.
pub struct Measuring {
    /// The settings the exports use ([`StreamedWith::resolve`]).
    pub streamed: StreamedWith,
    /// The sequence's voxel sets and overlaps on the scan's grid.
    pub prep: Prepared,
    /// The device's database and labels measured on them.
    pub measured: Measured,
}

impl Measuring {
    /// What `metrics.json` takes of it.
    pub fn on<'a>(&'a self, seq: &'a Sequence) -> OnSequence<'a> {
        OnSequence {
            seq,
            prep: &self.prep,
            measured: &self.measured,
        }
    }
}

/// Checks that `export` is a scan of `seq`'s first frames (as many, with
/// the same timestamps, from a camera of the same image size), cuts `seq`
/// to them and gives it the scan's camera, then measures the export's
/// database and labels on `seq` voxelized on the scan's grid. `None` when
/// the device decided no frame yet (there is nothing to measure).
pub fn measure(
    seq: &mut Sequence,
    export: &Export,
    streamed: &StreamedWith,
    quiet: bool,
) -> Result<Option<Measuring>, OutputError> {
    // A contradicting flag fails the run, so nothing of it is written.
    let streamed = streamed
        .resolve(export.config.as_ref())
        .map_err(OutputError::Mismatch)?;
    let (timestamps, labels) = export.labels();
    let not_it = |what: String| {
        OutputError::Mismatch(format!(
            "--sequence {}: {what}: not the streamed sequence?",
            seq.name
        ))
    };
    if labels.len() > seq.frames.len() {
        return Err(not_it(format!(
            "the device scanned {} frames, the sequence has {}",
            labels.len(),
            seq.frames.len()
        )));
    }
    // The device's timestamps are the sequence's: a different sequence shows.
    if let Some(i) = timestamps
        .iter()
        .zip(&seq.frames)
        .position(|(t, f)| *t != f.timestamp)
    {
        return Err(not_it(format!(
            "frame {i} has timestamp {}, the device's has {}",
            seq.frames[i].timestamp, timestamps[i]
        )));
    }
    let config = export.config;
    if let Some(c) = &config {
        let k = c.intrinsics;
        if (k.width, k.height) != seq.size {
            return Err(not_it(format!(
                "its depth images are {}x{}, the device's scan's {}x{}",
                seq.size.0, seq.size.1, k.width, k.height
            )));
        }
        // The camera the device projected with (it may have been given
        // with --intrinsics or --depth-scale when streaming).
        seq.camera = CameraModel {
            fx: f64::from(k.fx),
            fy: f64::from(k.fy),
            cx: f64::from(k.cx),
            cy: f64::from(k.cy),
        };
        seq.depth_scale = f64::from(c.depth_scale);
    }
    seq.frames.truncate(labels.len());
    if labels.is_empty() {
        return Ok(None);
    }
    let voxel = streamed.voxel.unwrap_or(super::DEFAULT_VOXEL);
    let failed = |e| match e {
        VoxelizeError::Read(r) => OutputError::Read(r),
        other => OutputError::Mismatch(other.to_string()),
    };
    let prep = match &config {
        Some(c) => {
            let vcfg = VoxelConfig {
                voxel,
                stride: c.stride,
                range: c.depth_range,
                ..VoxelConfig::default()
            };
            let grid = VoxelGrid {
                voxel_size: voxel,
                origin: c.grid_origin,
            };
            pipeline::prepare_on(seq, vcfg, grid, quiet)
        }
        None => pipeline::prepare(
            seq,
            VoxelConfig {
                voxel,
                ..VoxelConfig::default()
            },
            quiet,
        ),
    }
    .map_err(failed)?;
    let n = labels.len();
    let mut database: Vec<usize> = export.database().iter().map(|r| r.index as usize).collect();
    database.sort_unstable();
    database.dedup();
    if let Some(&f) = database.iter().chain(&labels).find(|&&f| f >= n) {
        return Err(OutputError::Mismatch(format!(
            "the device's export names frame {f} of a scan of {n} frames"
        )));
    }
    let mu = streamed.mu.unwrap_or(super::DEFAULT_MU);
    let measured = pipeline::measure(&prep, &database, &labels, mu);
    Ok(Some(Measuring {
        streamed,
        prep,
        measured,
    }))
}
