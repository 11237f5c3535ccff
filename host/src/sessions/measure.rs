//! The metrics of an extended run over every session's frames. The new
//! session's frames are measured exactly, against the whole database
//! (earlier database frames included), on the combined stride-1 sets; an
//! earlier session's frames carry what their own run measured (a frame can
//! only be covered better by a larger database, so for them the figures
//! are a floor), and its voxels count in `spatial_coverage` through the
//! extension file's `all_voxels`.

use crate::sessions::extension::{Extension, Fate, Measured};
use crate::yardstick::graph::CoObservation;
use crate::yardstick::metrics::{self, Metrics, PerFrame};

/// The metrics of database `db` (combined positions: `0..m` the earlier
/// database frames, `m..` the new session's frames) over every session,
/// and what was measured of each new frame, in order.
pub fn over_sessions(
    ext: &Extension,
    eval_sets: &[Vec<u64>],
    eval_co: &CoObservation,
    db: &[usize],
    mu: f32,
) -> (Metrics, Vec<Measured>) {
    let m = ext.database.len();
    let now = metrics::per_frame(eval_sets, eval_co, db, mu);
    let new: Vec<Measured> = (m..eval_sets.len())
        .map(|p| Measured {
            coverage: now.coverage[p] as f32,
            covered: now.covered[p],
        })
        .collect();
    // Earlier frames first, as their global indices go. One that its run
    // did not measure (a device's) counts as covered unless it was
    // decided uncovered, and has no coverage figure.
    let mut frames = PerFrame {
        covered: Vec::with_capacity(ext.frames.len() + new.len()),
        coverage: Vec::with_capacity(ext.frames.len() + new.len()),
    };
    for f in &ext.frames {
        match f.measured {
            Some(x) => {
                frames.covered.push(x.covered);
                frames.coverage.push(f64::from(x.coverage));
            }
            None => frames.covered.push(!matches!(f.fate, Fate::Uncovered(_))),
        }
    }
    for p in m..eval_sets.len() {
        frames.covered.push(now.covered[p]);
        frames.coverage.push(now.coverage[p]);
    }
    let kept = metrics::union(
        &db.iter()
            .map(|&b| eval_sets[b].as_slice())
            .collect::<Vec<_>>(),
    )
    .len();
    let all = match &ext.all_voxels {
        Some(earlier) => {
            let mut parts: Vec<&[u64]> = vec![earlier.as_slice()];
            parts.extend(eval_sets.iter().map(Vec::as_slice));
            metrics::union(&parts).len()
        }
        None => eval_co.distinct_keys(),
    };
    let mut out = metrics::summarize(&frames, db.len(), kept, all);
    // The size and reduction count every session's frames, measured or not.
    let n = ext.frames.len() + new.len();
    out.reduction = if db.is_empty() {
        0.0
    } else {
        n as f64 / db.len() as f64
    };
    (out, new)
}
