//! Database quality metrics (DESIGN section 3, fixed names and meaning).
//!
//! Conventions for corner cases, so every number is defined:
//! - a frame with an empty voxel set has frame coverage 1 when it is in the
//!   database and 0 otherwise (`s(q, b)` divides by `|d_q| = 0`);
//! - with no frames, the coverage statistics are 1, 1 and 0 (nothing is
//!   uncovered), `spatial_coverage` is 1 when no frame has a voxel, and
//!   `reduction` is 0 for an empty database.

use crate::voxelize::key_cells::BoxCells;
use crate::yardstick::graph::{CoObservation, KeyMap};
use rayon::prelude::*;

/// Coverage below this is "poorly covered" (the paper's recall criterion).
pub const COVERAGE_THRESHOLD: f64 = 0.3;

/// Quality of one database of one sequence.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Metrics {
    /// `|D|`.
    pub size: usize,
    /// `N / |D|`.
    pub reduction: f64,
    /// Frames neither in `D` nor with IoU > mu to a frame of `D`.
    pub uncovered: usize,
    /// `|∪_{i∈D} d_i| / |∪_all d_i|`.
    pub spatial_coverage: f64,
    /// Mean over frames of `max_{b∈D} s(frame, b)`.
    pub frames_coverage_mean: f64,
    /// Minimum over frames of the same.
    pub frames_coverage_min: f64,
    /// Share of frames whose coverage is below 0.3.
    pub frames_coverage_below_0_3: f64,
    /// `oracle_recall@0.3` on a test sequence, when one was given.
    pub oracle_recall_0_3: Option<f64>,
}

/// The metrics of database `db` (frame indices) of the frames `sets`, whose
/// co-observation counts are `co`, at IoU threshold `mu`;
/// `oracle_recall_0_3` is left `None` (see [`oracle_recall`]).
///
/// # Panics
/// When `co` was not built from `sets` (frame counts differ) or `db` holds an
/// index out of range.
pub fn evaluate(sets: &[Vec<u64>], co: &CoObservation, db: &[usize], mu: f32) -> Metrics {
    let frames = per_frame(sets, co, db, mu);
    let size = db_flags(sets.len(), db).iter().filter(|&&x| x).count();
    // The union of all sets is the co-observation count's own: its
    // inverted index numbers every distinct voxel.
    let all = co.distinct_keys();
    let kept = union(&db.iter().map(|&b| sets[b].as_slice()).collect::<Vec<_>>()).len();
    summarize(&frames, size, kept, all)
}

/// The metrics of frames covered as `frames` says by a database of `size`
/// frames whose sets hold `kept` of the `all` distinct voxels of every frame.
pub fn summarize(frames: &PerFrame, size: usize, kept: usize, all: usize) -> Metrics {
    let PerFrame { covered, coverage } = frames;
    let n = coverage.len();
    let uncovered = covered.iter().filter(|&&c| !c).count();
    Metrics {
        size,
        reduction: if size == 0 {
            0.0
        } else {
            n as f64 / size as f64
        },
        uncovered,
        spatial_coverage: if all == 0 {
            1.0
        } else {
            kept as f64 / all as f64
        },
        frames_coverage_mean: if n == 0 {
            1.0
        } else {
            coverage.iter().sum::<f64>() / n as f64
        },
        frames_coverage_min: coverage.iter().copied().fold(1.0, f64::min),
        frames_coverage_below_0_3: if n == 0 {
            0.0
        } else {
            coverage.iter().filter(|&&c| c < COVERAGE_THRESHOLD).count() as f64 / n as f64
        },
        oracle_recall_0_3: None,
    }
}

/// Each frame's coverage by a database (what [`evaluate`] sums up).
#[derive(Debug, Clone, PartialEq)]
pub struct PerFrame {
    /// In the database, or some database frame overlaps it (IoU > mu).
    pub covered: Vec<bool>,
    /// Frame coverage `max_{b∈D} s(frame, b)` (1 for a database frame).
    pub coverage: Vec<f64>,
}

fn db_flags(n: usize, db: &[usize]) -> Vec<bool> {
    let mut in_db = vec![false; n];
    for &b in db {
        in_db[b] = true;
    }
    in_db
}

/// The coverage of every frame of `sets` (co-observation counts `co`) by
/// database `db` at threshold `mu`.
///
/// # Panics
/// As [`evaluate`].
pub fn per_frame(sets: &[Vec<u64>], co: &CoObservation, db: &[usize], mu: f32) -> PerFrame {
    let n = sets.len();
    assert_eq!(co.len(), n, "co-observation of another sequence");
    let in_db = db_flags(n, db);
    // One pass over co-observing pairs: domination and best coverage.
    let mut covered = in_db.clone();
    let mut best_common = vec![0u32; n];
    for (i, j, c) in co.pairs() {
        for (f, b) in [(i, j), (j, i)] {
            if in_db[b] && !in_db[f] {
                covered[f] |= co.pair_iou(i, j, c) > mu;
                best_common[f] = best_common[f].max(c);
            }
        }
    }
    let coverage: Vec<f64> = (0..n)
        .map(|f| match (in_db[f], sets[f].len()) {
            (true, _) => 1.0,
            (false, 0) => 0.0,
            (false, len) => best_common[f] as f64 / len as f64,
        })
        .collect();
    PerFrame { covered, coverage }
}

/// Share of test frames `q` with `max_b |d_q ∩ d_b| / |d_q| > threshold` over
/// the database frames `db_sets` (all ascending, duplicate-free, on the same
/// grid). Test frames with an empty set count as missed; no test frames
/// gives 0.
pub fn oracle_recall(test_sets: &[Vec<u64>], db_sets: &[&[u64]], threshold: f64) -> f64 {
    if test_sets.is_empty() {
        return 0.0;
    }
    // Inverted index key -> database frames, then one count per test frame.
    let mut index: KeyMap<Vec<u32>> = KeyMap::default();
    for (b, set) in db_sets.iter().enumerate() {
        for &k in set.iter() {
            index.entry(k).or_default().push(b as u32);
        }
    }
    let hits = test_sets
        .par_iter()
        .map_init(
            || vec![0u32; db_sets.len()],
            |count, q| {
                if q.is_empty() {
                    return false;
                }
                for k in q {
                    if let Some(bs) = index.get(k) {
                        for &b in bs {
                            count[b as usize] += 1;
                        }
                    }
                }
                let best = count.iter().copied().max().unwrap_or(0);
                count.fill(0);
                best as f64 / q.len() as f64 > threshold
            },
        )
        .filter(|&hit| hit)
        .count();
    hits as f64 / test_sets.len() as f64
}

/// The distinct keys of some sets, ascending: through a bitmap of the keys'
/// bounding box where it has few cells (a scan's, mostly), with no copy of
/// every key, whose sort also took most of the time; else sorted.
pub fn union<S: AsRef<[u64]> + Sync>(sets: &[S]) -> Vec<u64> {
    let keys = || sets.iter().flat_map(|s| s.as_ref().iter().copied());
    let total = sets.iter().map(|s| s.as_ref().len()).sum();
    let Some(cells) = BoxCells::of(sets, total) else {
        let mut all: Vec<u64> = keys().collect();
        all.par_sort_unstable();
        all.dedup();
        return all;
    };
    let (mut marked, mut all) = (Vec::new(), Vec::new());
    cells.mark(keys(), &mut marked);
    cells.drain_marked(&mut marked, &mut all);
    all
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_example() {
        // d0 = {1,2,3,4}, d1 = {3,4,5,6}, d2 = {5,6,7,8,9,10}, d3 = {}.
        let sets = vec![
            vec![1, 2, 3, 4],
            vec![3, 4, 5, 6],
            vec![5, 6, 7, 8, 9, 10],
            vec![],
        ];
        let co = CoObservation::new(&sets, None);
        // IoU(0,1) = 2/6, IoU(1,2) = 2/8, IoU(0,2) = 0.
        let m = evaluate(&sets, &co, &[0], 0.3);
        assert_eq!(m.size, 1);
        assert_eq!(m.reduction, 4.0);
        assert_eq!(m.uncovered, 2); // frame 1 overlaps 0 (1/3 > 0.3); 2 and 3 do not
        assert_eq!(m.spatial_coverage, 4.0 / 10.0);
        // coverage: 1, 2/4, 0, 0
        assert_eq!(m.frames_coverage_mean, 1.5 / 4.0);
        assert_eq!(m.frames_coverage_min, 0.0);
        assert_eq!(m.frames_coverage_below_0_3, 0.5);
        let m = evaluate(&sets, &co, &[0, 2, 3], 0.3);
        assert_eq!(m.uncovered, 0);
        assert_eq!(m.spatial_coverage, 1.0);
        assert_eq!(m.frames_coverage_min, 0.5);
        assert_eq!(m.frames_coverage_below_0_3, 0.0);
    }

    #[test]
    fn union_is_the_distinct_keys_ascending_in_a_box_or_not() {
        let mut rng = crate::rng::SplitMix64::new(5);
        let key = |x: u64, y: u64, z: u64| x << 42 | y << 21 | z;
        for round in 0..200 {
            // Keys in a small box (a bitmap), or with one far away (a box
            // too large: sorted), or with a word that is no key.
            let base = [0; 3].map(|_: u64| rng.below(1 << 20));
            let mut sets: Vec<Vec<u64>> = (0..rng.below(6))
                .map(|_| {
                    let mut s: Vec<u64> = (0..rng.below(30))
                        .map(|_| {
                            let [x, y, z] = base.map(|b| b + rng.below(5));
                            key(x, y, z)
                        })
                        .collect();
                    s.sort_unstable();
                    s.dedup();
                    s
                })
                .collect();
            match round % 3 {
                1 => sets.push(vec![key(base[0] + 100_000, base[1], base[2])]),
                2 => sets.push(vec![u64::MAX]),
                _ => {}
            }
            let want: std::collections::BTreeSet<u64> = sets.iter().flatten().copied().collect();
            assert_eq!(union(&sets), want.into_iter().collect::<Vec<_>>());
        }
    }

    #[test]
    fn recall() {
        let db: Vec<&[u64]> = vec![&[1, 2, 3, 4], &[10, 11]];
        let test = vec![
            vec![1, 2, 50],
            vec![3, 60, 61, 62],
            vec![10, 11, 12],
            vec![],
        ];
        // coverages: 2/3, 1/4, 2/3, none
        assert_eq!(oracle_recall(&test, &db, 0.3), 0.5);
        assert_eq!(oracle_recall(&test, &db, 0.2), 0.75);
        assert_eq!(oracle_recall(&[], &db, 0.3), 0.0);
    }
}
