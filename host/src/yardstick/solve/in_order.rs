//! `in-order`: the paper's result. Frames are scanned in sequence order and a
//! frame is taken iff no frame already taken overlaps it.
//!
//! The paper's code calls networkx `dominating_set(G)` on nodes `0..n`: it
//! takes the first node (0), then repeatedly pops an arbitrary not yet
//! dominated node from a Python `set`, takes it and marks its neighbours
//! dominated. CPython pops small integers in increasing order only while the
//! set's hash table is larger than the indices left in it, so networkx visits
//! frames in sequence order in the common case (and on the reference test
//! database: 0.05 -> {0, 1, 3}) but not always: when frame 0 dominates more
//! than a quarter of the frames, or late in a scan after the set shrinks its
//! table, a later frame can be popped first. A random check of networkx 3.6
//! against this function found no difference at 1000 frames and occasional
//! ones (a few frames) at 20–300 frames. This function is the well-defined
//! sequence-order version the definition describes.

use crate::yardstick::graph::OverlapGraph;

/// Frames taken by a scan in sequence order (ascending).
pub fn in_order(g: &OverlapGraph) -> Vec<usize> {
    in_order_by(g.n, |v| {
        let adj = g.neighbours(v);
        adj[adj.partition_point(|&u| u as usize <= v)..]
            .iter()
            .map(|&u| u as usize)
    })
}

/// [`in_order`] on frames `0..n` given only each frame's later neighbours
/// (`later(v)`, all above `v`): when the scan reaches a frame, its earlier
/// neighbours are decided already, so marking them would change nothing.
/// `select` runs it on the co-observation rows, which hold exactly those,
/// without building the graph.
///
/// # Panics
/// When `later` yields a frame `>= n`.
pub fn in_order_by<I: Iterator<Item = usize>>(n: usize, later: impl Fn(usize) -> I) -> Vec<usize> {
    let mut dominated = vec![false; n];
    let mut taken = Vec::new();
    for v in 0..n {
        if !dominated[v] {
            taken.push(v);
            for u in later(v) {
                dominated[u] = true;
            }
        }
    }
    taken
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use crate::yardstick::graph::CoObservation;

    #[test]
    fn on_co_observation_rows_it_takes_what_it_takes_on_the_graph() {
        let mut rng = SplitMix64::new(3);
        for _ in 0..200 {
            let n = rng.below(40) as usize;
            // Frames along a line of voxels, of random lengths and steps:
            // neighbours share voxels, some pairs overlap above mu.
            let mut start = 0u64;
            let sets: Vec<Vec<u64>> = (0..n)
                .map(|_| {
                    start += rng.below(6);
                    (start..start + rng.below(12)).collect()
                })
                .collect();
            let co = CoObservation::new(&sets, None);
            for mu in [0.0, 0.3, 0.6] {
                let by_rows = in_order_by(n, |v| co.later_overlaps(v, mu));
                assert_eq!(by_rows, in_order(&co.graph(mu)), "{sets:?} at {mu}");
            }
        }
    }

    #[test]
    fn path_takes_every_other_pair() {
        let g = OverlapGraph::from_edges(5, &[(0, 1), (1, 2), (2, 3), (3, 4)]);
        assert_eq!(in_order(&g), vec![0, 2, 4]);
        let g = OverlapGraph::from_edges(0, &[]);
        assert!(in_order(&g).is_empty());
    }
}
