//! `export --sequence SEQ`: the streamed sequence measured as the device
//! scanned it. The device keeps no voxel set of its frames, so the coverage
//! metrics of `metrics.json` and the overlaps `--pairs` lists come from
//! `SEQ` voxelized again on the scan's own grid: its voxel size, stride,
//! depth range, grid corner and camera, read from the device's flash log
//! (the flags, or their defaults, only for a device without one), so that
//! they are the figures `placedb select SEQ --solver online` with the same
//! settings writes. First `SEQ` is cut to the frames the device labelled,
//! found by timestamp ([`streamed_frames`]): a real-time replay skips the
//! frames that came while the device was busy, so they are not always the
//! first ones.

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

/// Where in `seq` each frame the device labelled is, by timestamp: the
/// device's frame `k` is the first frame after the one its frame `k - 1`
/// matched whose timestamp is bit for bit the device's (the device keeps
/// the timestamp it was sent as given; a layout that numbers its frames
/// instead, 7-Scenes, sends the number, as unique). The first frames of
/// `seq` when the device was sent every frame, fewer when a real-time
/// replay skipped some (`stream --realtime`). Why not, in words: the first
/// device frame that matches none.
fn received_frames(seq: &Sequence, timestamps: &[f64]) -> Result<Vec<usize>, String> {
    if timestamps.len() > seq.frames.len() {
        return Err(format!(
            "the device scanned {} frames, the sequence has {}",
            timestamps.len(),
            seq.frames.len()
        ));
    }
    let mut positions: Vec<usize> = Vec::with_capacity(timestamps.len());
    let mut next = 0;
    for (k, t) in timestamps.iter().enumerate() {
        let found = seq.frames[next..]
            .iter()
            .position(|f| f.timestamp.to_bits() == t.to_bits());
        let Some(p) = found.map(|p| next + p) else {
            let after = match positions.last() {
                Some(&q) => format!(
                    " after frame {} (the device's frame {}, timestamp {})",
                    seq.frames[q].index,
                    k - 1,
                    seq.frames[q].timestamp
                ),
                None => String::new(),
            };
            return Err(format!(
                "the device's frame {k} has timestamp {t}, which no frame of the sequence has{after}"
            ));
        };
        positions.push(p);
        next = p + 1;
    }
    Ok(positions)
}

/// `seq` as the device scanned it: only the frames it labelled, matched by
/// timestamp ([`received_frames`]: the first frames, or fewer when a
/// real-time replay skipped some; each keeps its number in `seq`, which
/// the outputs name it by), with the scan's camera. Refused, naming what
/// differs, when `export` is not a scan of `seq`.
pub fn streamed_frames(seq: Sequence, export: &Export) -> Result<Sequence, OutputError> {
    let firsts = export.sessions();
    if firsts.len() > 1 {
        // As `select --extend` refuses the exports: one sequence is one
        // session (the tables, the dataset and the exports would have to
        // name the frames of several).
        let at: Vec<String> = firsts.iter().map(u32::to_string).collect();
        return Err(OutputError::Mismatch(format!(
            "--sequence {}: the device's scan holds {} sessions (stream --extend; they begin at \
             frames {}): --sequence, and so --dataset, --colmap, --vpr-eval and --pairs, does \
             not combine with sessions yet, as select --extend does not; export without them",
            seq.name,
            firsts.len(),
            at.join(", ")
        )));
    }
    let (timestamps, _) = export.labels();
    let not_it = |what: String| {
        OutputError::Mismatch(format!(
            "--sequence {}: {what}: not the streamed sequence?",
            seq.name
        ))
    };
    let positions = received_frames(&seq, &timestamps).map_err(not_it)?;
    if let Some(c) = &export.config {
        let k = c.intrinsics;
        if (k.width, k.height) != seq.size {
            return Err(not_it(format!(
                "its depth images are {}x{}, the device's scan's {}x{}",
                seq.size.0, seq.size.1, k.width, k.height
            )));
        }
    }
    let mut seq = seq.keep_frames(&positions);
    if let Some(c) = &export.config {
        // The camera the device projected with (it may have been given
        // with --intrinsics or --depth-scale when streaming).
        let k = c.intrinsics;
        seq.camera = CameraModel {
            fx: f64::from(k.fx),
            fy: f64::from(k.fy),
            cx: f64::from(k.cx),
            cy: f64::from(k.cy),
        };
        seq.depth_scale = f64::from(c.depth_scale);
    }
    Ok(seq)
}

/// Measures the export's database and labels on `seq`, the frames the
/// device labelled ([`streamed_frames`]), voxelized on the scan's grid.
/// `None` when the device decided no frame yet (there is nothing to
/// measure).
pub fn measure(
    seq: &Sequence,
    export: &Export,
    streamed: &StreamedWith,
    quiet: bool,
) -> Result<Option<Measuring>, OutputError> {
    // A contradicting flag fails the run, so nothing of it is written.
    let streamed = streamed
        .resolve(export.config.as_ref())
        .map_err(OutputError::Mismatch)?;
    let (_, labels) = export.labels();
    if labels.is_empty() {
        return Ok(None);
    }
    let config = export.config;
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

#[cfg(test)]
mod tests {
    use super::received_frames;
    use crate::sequence::Sequence;
    use crate::synth::{self, SynthConfig};

    /// The demo cut to frames stamped `stamps`.
    fn stamped(stamps: &[f64]) -> Sequence {
        let mut seq = synth::sequence(&SynthConfig::demo());
        seq.frames.truncate(stamps.len());
        for (f, &t) in seq.frames.iter_mut().zip(stamps) {
            f.timestamp = t;
        }
        seq
    }

    #[test]
    fn the_device_frames_are_found_by_timestamp_in_order() {
        let seq = stamped(&[1.0, 1.1, 1.2, 1.3, 1.4, 1.5]);
        // Sent every frame (the first ones), and a real-time replay's.
        assert_eq!(received_frames(&seq, &[1.0, 1.1]), Ok(vec![0, 1]));
        assert_eq!(received_frames(&seq, &[1.0, 1.2, 1.5]), Ok(vec![0, 2, 5]));
        assert_eq!(received_frames(&seq, &[]), Ok(vec![]));
        // 7-Scenes sends frame numbers, with gaps where files are missing.
        let numbered = stamped(&[0.0, 1.0, 2.0, 7.0, 8.0]);
        assert_eq!(
            received_frames(&numbered, &[0.0, 7.0, 8.0]),
            Ok(vec![0, 3, 4])
        );
    }

    #[test]
    fn a_device_frame_the_sequence_lacks_is_named() {
        let seq = stamped(&[1.0, 1.1, 1.2, 1.3]);
        let err = received_frames(&seq, &[1.0, 1.15, 1.3]).unwrap_err();
        assert_eq!(
            err,
            "the device's frame 1 has timestamp 1.15, which no frame of the sequence has after \
             frame 0 (the device's frame 0, timestamp 1)"
        );
        // Out of order is not a real-time replay of this sequence.
        let err = received_frames(&seq, &[1.2, 1.1]).unwrap_err();
        assert!(
            err.starts_with("the device's frame 1 has timestamp 1.1,"),
            "{err}"
        );
        let err = received_frames(&seq, &[0.5]).unwrap_err();
        assert_eq!(
            err,
            "the device's frame 0 has timestamp 0.5, which no frame of the sequence has"
        );
        let err = received_frames(&seq, &[1.0; 5]).unwrap_err();
        assert_eq!(err, "the device scanned 5 frames, the sequence has 4");
    }
}
