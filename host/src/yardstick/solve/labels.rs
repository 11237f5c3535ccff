//! Class labels of frames for a database, and the domination check.
//!
//! The label of a frame is the frame itself when it is in the database,
//! otherwise the database frame with the highest IoU to it (ties: lowest
//! index) — DESIGN section 2. A frame sharing no voxel with any database frame
//! (possible only when the database does not dominate, e.g. for baselines)
//! gets the lowest-index database frame: every IoU is 0 and the tie rule
//! applies. Callers that care can detect it with `co.iou(f, label) == 0`.

use crate::yardstick::graph::{CoObservation, OverlapGraph};

/// Label of every frame: itself if in `db`, else its best-IoU frame of `db`.
///
/// # Panics
/// When `db` is empty while there are frames, or holds an index `>= co.len()`.
pub fn labels(co: &CoObservation, db: &[usize]) -> Vec<usize> {
    let n = co.len();
    let mut in_db = vec![false; n];
    for &b in db {
        in_db[b] = true;
    }
    let Some(&first) = db.iter().min() else {
        assert!(n == 0, "labels of {n} frames need a non-empty database");
        return Vec::new();
    };
    // (best IoU, label); the start value is the tie rule for "no overlap".
    let mut best: Vec<(f32, usize)> = (0..n)
        .map(|f| {
            if in_db[f] {
                (f32::INFINITY, f)
            } else {
                (0.0, first)
            }
        })
        .collect();
    let mut offer = |f: usize, b: usize, iou: f32| {
        let cur = &mut best[f];
        if iou > cur.0 || (iou == cur.0 && b < cur.1) {
            *cur = (iou, b);
        }
    };
    for (i, j, c) in co.pairs() {
        match (in_db[i], in_db[j]) {
            (false, true) => offer(i, j, co.pair_iou(i, j, c)),
            (true, false) => offer(j, i, co.pair_iou(i, j, c)),
            _ => {}
        }
    }
    best.into_iter().map(|(_, b)| b).collect()
}

/// Whether every vertex of `g` is in `db` or adjacent to a vertex of `db`.
///
/// # Panics
/// When `db` holds an index `>= g.n`.
pub fn is_dominating(g: &OverlapGraph, db: &[usize]) -> bool {
    let mut dominated = vec![false; g.n];
    for &b in db {
        dominated[b] = true;
        for &u in g.neighbours(b) {
            dominated[u as usize] = true;
        }
    }
    dominated.iter().all(|&d| d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn best_iou_and_ties() {
        // 0 and 4 are the database; 1 overlaps 0 more, 2 overlaps both
        // equally, 3 overlaps neither.
        let sets = vec![
            vec![1, 2, 3, 4],
            vec![1, 2, 3, 9],
            vec![4, 5],
            vec![20],
            vec![5, 6, 7, 8],
        ];
        let co = CoObservation::new(&sets, None);
        // IoU(2,0) = 1/5, IoU(2,4) = 1/5: tie -> 0.
        assert_eq!(labels(&co, &[4, 0]), vec![0, 0, 0, 0, 4]);
        assert_eq!(labels(&co, &[4]), vec![4, 4, 4, 4, 4]);
        let g = co.graph(0.1);
        assert!(!is_dominating(&g, &[0, 4]));
        assert!(is_dominating(&g, &[0, 3, 4]));
    }
}
