//! The reference code's baselines (DESIGN section 2), on poses only. None of
//! them guarantees coverage: that is the point of comparing.
//!
//! - `every-nth N`: frames `0, N, 2N, …`.
//! - `distance D`: frame 0, then every frame at which the path length since
//!   the last taken frame (summed over consecutive translations) exceeds `D`.
//! - `cube C`: the trajectory's bounding box is cut into cubes of `C` metres
//!   from its minimum corner; in every occupied cube the frame nearest the
//!   cube's centre is taken (ties: lowest index).

use crate::sequence::FrameInfo;
use std::collections::BTreeMap;

/// Frames `0, n, 2n, …` below `n_frames`.
///
/// # Panics
/// When `n` is 0.
pub fn every_nth(n_frames: usize, n: usize) -> Vec<usize> {
    assert!(n > 0, "every-nth needs N >= 1");
    (0..n_frames).step_by(n).collect()
}

/// Frame 0, then each frame where the path length since the last taken frame
/// exceeds `d_metres` (the counter restarts at 0 there).
pub fn distance(frames: &[FrameInfo], d_metres: f64) -> Vec<usize> {
    if frames.is_empty() {
        return Vec::new();
    }
    let mut taken = vec![0];
    let mut path = 0.0;
    for i in 1..frames.len() {
        path += dist(&frames[i - 1].translation, &frames[i].translation);
        if path > d_metres {
            taken.push(i);
            path = 0.0;
        }
    }
    taken
}

/// In every cube of `c_metres` (grid anchored at the trajectory's minimum
/// corner) holding a camera position, the frame nearest the cube's centre;
/// ascending.
///
/// # Panics
/// When `c_metres` is not positive and finite.
pub fn cube(frames: &[FrameInfo], c_metres: f64) -> Vec<usize> {
    assert!(
        c_metres > 0.0 && c_metres.is_finite(),
        "cube size must be positive"
    );
    let mut min = [f64::INFINITY; 3];
    for f in frames {
        for (m, t) in min.iter_mut().zip(f.translation) {
            *m = m.min(t);
        }
    }
    let mut best: BTreeMap<[i64; 3], (f64, usize)> = BTreeMap::new();
    for (i, f) in frames.iter().enumerate() {
        let p = f.translation;
        let cell = [0, 1, 2].map(|a| ((p[a] - min[a]) / c_metres).floor() as i64);
        let centre = [0, 1, 2].map(|a| min[a] + (cell[a] as f64 + 0.5) * c_metres);
        let d = dist(&p, &centre);
        best.entry(cell)
            .and_modify(|b| {
                if d < b.0 {
                    *b = (d, i);
                }
            })
            .or_insert((d, i));
    }
    let mut out: Vec<usize> = best.into_values().map(|(_, i)| i).collect();
    out.sort_unstable();
    out
}

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(xs: &[[f64; 3]]) -> Vec<FrameInfo> {
        xs.iter()
            .enumerate()
            .map(|(i, &t)| FrameInfo {
                index: i,
                timestamp: i as f64,
                translation: t,
                rotation: [0.0, 0.0, 0.0, 1.0],
                depth_name: format!("{i}"),
                color_path: None,
            })
            .collect()
    }

    #[test]
    fn every_nth_steps() {
        assert_eq!(every_nth(7, 3), vec![0, 3, 6]);
        assert_eq!(every_nth(0, 3), Vec::<usize>::new());
    }

    #[test]
    fn distance_accumulates_path() {
        let f = at(&[
            [0.0; 3],
            [0.4, 0.0, 0.0],
            [0.8, 0.0, 0.0],
            [0.8, 0.4, 0.0],
            [0.8, 0.8, 0.0],
        ]);
        // Path 0.4, 0.8 (> 0.5: take 2, reset), 0.4, 0.8 (take 4).
        assert_eq!(distance(&f, 0.5), vec![0, 2, 4]);
        assert!(distance(&[], 0.5).is_empty());
    }

    #[test]
    fn cube_takes_nearest_to_centre() {
        let f = at(&[
            [0.0; 3],
            [0.4, 0.4, 0.4],
            [0.6, 0.5, 0.5],
            [1.5, 0.5, 0.5],
            [1.9, 0.0, 0.0],
        ]);
        // Cubes of 1 m from (0,0,0): cube (0,0,0) has 0,1,2 -> 2 is nearest
        // (0.5,0.5,0.5); cube (1,0,0) has 3 and 4 -> 3.
        assert_eq!(cube(&f, 1.0), vec![2, 3]);
    }
}
