//! `greedy`: repeatedly take the frame that dominates the most not yet
//! dominated frames (ties: lowest index) — the classic ln(n)-approximation.
//!
//! Gains only decrease, so a lazy max-heap suffices: a popped entry whose gain
//! is stale is pushed back with its current gain. `O((n + m) log n)` for `n`
//! frames and `m` edges. The same routine solves the set-cover form the exact
//! solver reduces to (`greedy_cover`).

use crate::yardstick::graph::OverlapGraph;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// A set-cover instance: columns (candidates) cover rows (demands).
pub(crate) trait Incidence {
    /// Number of columns.
    fn n_cols(&self) -> usize;
    /// Number of rows.
    fn n_rows(&self) -> usize;
    /// Rows covered by column `c`.
    fn rows_of(&self, c: usize) -> impl Iterator<Item = usize> + '_;
    /// Columns covering row `r`.
    fn cols_of(&self, r: usize) -> impl Iterator<Item = usize> + '_;
}

/// A graph's domination instance: column and row `v` are both `N[v]`.
impl Incidence for OverlapGraph {
    fn n_cols(&self) -> usize {
        self.n
    }

    fn n_rows(&self) -> usize {
        self.n
    }

    fn rows_of(&self, c: usize) -> impl Iterator<Item = usize> + '_ {
        std::iter::once(c).chain(self.neighbours(c).iter().map(|&u| u as usize))
    }

    fn cols_of(&self, r: usize) -> impl Iterator<Item = usize> + '_ {
        self.rows_of(r)
    }
}

/// Greedy dominating set of `g`, ascending.
pub fn greedy(g: &OverlapGraph) -> Vec<usize> {
    greedy_cover(g)
}

/// Greedy set cover: columns in ascending order covering every row.
///
/// # Panics
/// When some row has no column.
pub(crate) fn greedy_cover<I: Incidence>(inc: &I) -> Vec<usize> {
    let mut gain: Vec<u32> = (0..inc.n_cols())
        .map(|c| inc.rows_of(c).count() as u32)
        .collect();
    let mut heap: BinaryHeap<(u32, Reverse<u32>)> = gain
        .iter()
        .enumerate()
        .filter(|&(_, &g)| g > 0)
        .map(|(c, &g)| (g, Reverse(c as u32)))
        .collect();
    let mut covered = vec![false; inc.n_rows()];
    let mut left = inc.n_rows();
    let mut chosen = Vec::new();
    while left > 0 {
        let (g, Reverse(c)) = heap.pop().expect("a row no column covers");
        let c = c as usize;
        if g != gain[c] {
            if gain[c] > 0 {
                heap.push((gain[c], Reverse(c as u32)));
            }
            continue;
        }
        chosen.push(c);
        for r in inc.rows_of(c) {
            if !covered[r] {
                covered[r] = true;
                left -= 1;
                for c2 in inc.cols_of(r) {
                    gain[c2] -= 1;
                }
            }
        }
    }
    chosen.sort_unstable();
    chosen
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn star_with_tail() {
        // 0 is a hub of 1..=4, 4-5-6 a tail: greedy takes 0 then 5 or 6 (5 first: lower index, same gain).
        let g = OverlapGraph::from_edges(7, &[(0, 1), (0, 2), (0, 3), (0, 4), (4, 5), (5, 6)]);
        assert_eq!(greedy(&g), vec![0, 5]);
    }

    #[test]
    fn ties_take_lowest_index() {
        let g = OverlapGraph::from_edges(4, &[(0, 1), (2, 3)]);
        assert_eq!(greedy(&g), vec![0, 2]);
        assert!(greedy(&OverlapGraph::from_edges(0, &[])).is_empty());
        assert_eq!(greedy(&OverlapGraph::from_edges(2, &[])), vec![0, 1]);
    }
}
