//! The offline solvers with an earlier database fixed, on the combined
//! frames: positions `0..m` are the earlier sessions' database frames,
//! positions `m..` the new session's frames in order. The earlier frames
//! are taken already; a new frame they overlap is covered already; the
//! solver covers the rest with new frames only.

use crate::sessions::extension::Extension;
use crate::yardstick::graph::{CoObservation, OverlapGraph};
use crate::yardstick::solve::greedy::{greedy_cover, Incidence};

/// What to do with a database frame whose voxel set the file lacks (a
/// device keeps only the keys it compared exactly).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Missing {
    /// Refuse in words: an offline solver needs every set.
    Refuse,
    /// Count it as an empty set (the metrics then are a floor) and count it.
    Empty,
}

/// The combined voxel sets: the earlier database frames' (`eval`: their
/// stride-1 sets, for the metrics) then `session`'s, in order; and how
/// many earlier sets were missing (see [`Missing`]).
pub fn combined_sets(
    ext: &Extension,
    session: &[Vec<u64>],
    eval: bool,
    missing: Missing,
) -> Result<(Vec<Vec<u64>>, usize), String> {
    let mut sets = Vec::with_capacity(ext.database.len() + session.len());
    let mut absent = 0;
    for f in &ext.database {
        let set = if eval && ext.config.stride != 1 {
            f.eval_keys.as_ref()
        } else {
            f.keys.as_ref()
        };
        match (set, missing) {
            (Some(set), _) => sets.push(set.clone()),
            (None, Missing::Empty) => {
                absent += 1;
                sets.push(Vec::new());
            }
            (None, Missing::Refuse) => {
                return Err(format!(
                    "database frame {} has no voxel set in the extension file (its run kept only its sketch): extend it with --solver online",
                    f.index
                ))
            }
        }
    }
    sets.extend(session.iter().cloned());
    Ok((sets, absent))
}

/// The new frames (positions `m..`) that some of the first `m` overlap.
fn covered_by_earlier(co: &CoObservation, m: usize, mu: f32) -> Vec<bool> {
    let mut covered = vec![false; co.len()];
    for a in 0..m {
        for p in co.later_overlaps(a, mu) {
            covered[p] = true;
        }
    }
    covered
}

/// `in-order` after the first `m` positions: a new frame is taken iff no
/// frame taken so far (earlier database included) overlaps it. Returns
/// the positions taken, ascending (all `>= m`).
pub fn in_order(co: &CoObservation, m: usize, mu: f32) -> Vec<usize> {
    let mut dominated = covered_by_earlier(co, m, mu);
    let mut taken = Vec::new();
    for v in m..co.len() {
        if !dominated[v] {
            taken.push(v);
            for u in co.later_overlaps(v, mu) {
                dominated[u] = true;
            }
        }
    }
    taken
}

/// What is left to cover once the earlier database is in: rows are the
/// new frames it does not cover, columns every new frame.
struct Residual<'a> {
    g: &'a OverlapGraph,
    m: usize,
    /// Position of each row.
    rows: Vec<usize>,
    /// Row of each position, `usize::MAX` for positions already covered
    /// (and the earlier frames).
    row_of: Vec<usize>,
}

impl Incidence for Residual<'_> {
    fn n_cols(&self) -> usize {
        self.g.n - self.m
    }

    fn n_rows(&self) -> usize {
        self.rows.len()
    }

    fn rows_of(&self, c: usize) -> impl Iterator<Item = usize> + '_ {
        let p = c + self.m;
        std::iter::once(p)
            .chain(self.g.neighbours(p).iter().map(|&u| u as usize))
            .map(|q| self.row_of[q])
            .filter(|&r| r != usize::MAX)
    }

    fn cols_of(&self, r: usize) -> impl Iterator<Item = usize> + '_ {
        let p = self.rows[r];
        std::iter::once(p)
            .chain(self.g.neighbours(p).iter().map(|&u| u as usize))
            .filter(|&q| q >= self.m)
            .map(|q| q - self.m)
    }
}

/// `greedy` after the first `m` positions: the new frame covering most
/// new frames not yet covered, repeatedly, until every new frame is
/// covered. Returns the positions taken, ascending (all `>= m`).
pub fn greedy(co: &CoObservation, m: usize, mu: f32) -> Vec<usize> {
    let g = co.graph(mu);
    let covered = covered_by_earlier(co, m, mu);
    let rows: Vec<usize> = (m..co.len()).filter(|&p| !covered[p]).collect();
    let mut row_of = vec![usize::MAX; co.len()];
    for (r, &p) in rows.iter().enumerate() {
        row_of[p] = r;
    }
    let residual = Residual {
        g: &g,
        m,
        rows,
        row_of,
    };
    greedy_cover(&residual).into_iter().map(|c| c + m).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::yardstick::solve;

    /// Runs of overlapping sets along a line: set `i` is `[2i, 2i + 3]`.
    fn line(n: usize) -> Vec<Vec<u64>> {
        (0..n as u64)
            .map(|i| (2 * i..2 * i + 4).collect())
            .collect()
    }

    #[test]
    fn nothing_fixed_is_the_plain_solver() {
        let sets = line(9);
        let co = CoObservation::new(&sets, None);
        assert_eq!(in_order(&co, 0, 0.3), solve::in_order(&co.graph(0.3)));
        assert_eq!(greedy(&co, 0, 0.3), solve::greedy(&co.graph(0.3)));
    }

    #[test]
    fn frames_the_earlier_database_covers_are_not_taken_again() {
        // Position 0 is an earlier database frame equal to new frame 3's set.
        let mut sets = vec![line(9)[2].clone()];
        sets.extend(line(9));
        let co = CoObservation::new(&sets, None);
        let g = co.graph(0.3);
        for taken in [in_order(&co, 1, 0.3), greedy(&co, 1, 0.3)] {
            assert!(taken.iter().all(|&p| p >= 1));
            let mut db = vec![0];
            db.extend(&taken);
            assert!(solve::is_dominating(&g, &db), "{taken:?}");
            // New frame 2 (position 3) is the earlier frame's own set.
            assert!(!taken.contains(&3), "{taken:?}");
        }
    }
}
