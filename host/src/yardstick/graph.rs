//! Exact co-observation counts between frames and the overlap graph `G(mu)`.
//!
//! [`CoObservation::new`] counts `|d_i ∩ d_j|` for every pair of frames that
//! share at least one voxel, the way the paper's code does: an inverted index
//! voxel -> frames, then for each frame `i` a walk over its voxels' posting
//! lists counting the frames `j > i` met there, into a dense counter array of
//! length `n` per thread — never an all-pairs loop over frames. That walk costs
//! `Σ_voxels m² / 2` increments (`m` = frames seeing the voxel). Consecutive
//! frames of a sequence share most of their voxels, so threads take runs of
//! consecutive frames and, when cheaper, turn frame `i - 1`'s counts into
//! frame `i`'s by walking only the postings of the voxels that enter and
//! leave (the counters then hold every `j > run start` and are swept in order).
//!
//! IoU uses the core's [`placedb::voxel::iou`], so host and device compare
//! the very same `f32` against `mu`.

use crate::voxelize::key_cells::BoxCells;
use indicatif::ProgressBar;
use rayon::prelude::*;
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// Hasher for packed voxel keys: one 64x64->128 multiply folded to 64 bits,
/// so that every key bit reaches the low bits the hash table indexes with.
#[derive(Default, Clone, Copy)]
pub(crate) struct KeyHasher(u64);

const MIX: u64 = 0x9E37_79B9_7F4A_7C15;

impl Hasher for KeyHasher {
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ b as u64).wrapping_mul(MIX);
        }
    }

    fn write_u64(&mut self, k: u64) {
        self.0 ^= k;
    }

    fn finish(&self) -> u64 {
        let p = (self.0 as u128).wrapping_mul(MIX as u128);
        (p as u64) ^ ((p >> 64) as u64)
    }
}

/// A `HashMap` keyed by packed voxel keys.
pub(crate) type KeyMap<V> = HashMap<u64, V, BuildHasherDefault<KeyHasher>>;

/// Inverted index voxel -> frames over a list of voxel sets.
struct InvertedIndex {
    /// Frames holding voxel `v` (dense id) are `items[starts[v]..starts[v + 1]]`, ascending.
    starts: Vec<u32>,
    /// Frame indices, grouped by voxel.
    items: Vec<u32>,
    /// Voxel id of every key occurrence, frame-major: frame `i`'s are
    /// `ids[frame_starts[i]..frame_starts[i + 1]]`, in its key order.
    ids: Vec<u32>,
    /// Start of each frame's occurrences in `ids` (length `n + 1`).
    frame_starts: Vec<usize>,
    /// Number of distinct keys.
    distinct: usize,
}

impl InvertedIndex {
    /// Builds the index. Voxel ids are cells of the keys' bounding box when
    /// it has no more cells than key occurrences (plus 65536), else the ranks
    /// of the distinct keys found with a hash map. Either way ids ascend with
    /// keys, so within a frame they ascend.
    ///
    /// # Panics
    /// When the sets hold `u32::MAX` key occurrences or more in total.
    fn new(sets: &[Vec<u64>]) -> InvertedIndex {
        let total: usize = sets.iter().map(Vec::len).sum();
        InvertedIndex::build(sets, BoxCells::of(sets, total))
    }

    /// Builds the index with voxel ids from `cells`, or from a hash map.
    fn build(sets: &[Vec<u64>], cells: Option<BoxCells>) -> InvertedIndex {
        let total: usize = sets.iter().map(Vec::len).sum();
        assert!(
            total < u32::MAX as usize,
            "too many voxel occurrences: {total}"
        );
        let mut frame_starts = Vec::with_capacity(sets.len() + 1);
        frame_starts.push(0);
        for s in sets {
            frame_starts.push(frame_starts.last().copied().unwrap_or(0) + s.len());
        }
        let mut ids = vec![0u32; total];
        let n_ids = match cells {
            Some(cells) => {
                per_frame_mut(&mut ids, &frame_starts)
                    .into_par_iter()
                    .zip(sets)
                    .for_each(|(out, s)| {
                        for (o, &k) in out.iter_mut().zip(s) {
                            *o = cells.cell(k);
                        }
                    });
                cells.count
            }
            None => {
                let mut map: KeyMap<u32> = KeyMap::default();
                for (o, &k) in ids.iter_mut().zip(sets.iter().flatten()) {
                    let next = map.len() as u32;
                    *o = *map.entry(k).or_insert(next);
                }
                // Renumber by key order.
                let mut keys: Vec<(u64, u32)> = map.into_iter().collect();
                keys.par_sort_unstable();
                let mut rank = vec![0u32; keys.len()];
                for (r, &(_, first)) in keys.iter().enumerate() {
                    rank[first as usize] = r as u32;
                }
                ids.par_iter_mut().for_each(|id| *id = rank[*id as usize]);
                keys.len()
            }
        };

        // Counting sort of (id, frame) by id, in parallel over id ranges:
        // within a frame the ids of a range are a contiguous run.
        let n_ranges = (8 * rayon::current_num_threads()).min(n_ids.max(1));
        let bounds: Vec<u32> = (0..=n_ranges)
            .map(|r| (r * n_ids / n_ranges) as u32)
            .collect();
        let run = |i: usize, lo: u32, hi: u32| {
            let f = &ids[frame_starts[i]..frame_starts[i + 1]];
            &f[f.partition_point(|&v| v < lo)..f.partition_point(|&v| v < hi)]
        };
        let counts: Vec<Vec<u32>> = bounds
            .par_windows(2)
            .map(|w| {
                let mut c = vec![0u32; (w[1] - w[0]) as usize];
                for i in 0..sets.len() {
                    for &v in run(i, w[0], w[1]) {
                        c[(v - w[0]) as usize] += 1;
                    }
                }
                c
            })
            .collect();
        let mut starts = Vec::with_capacity(n_ids + 1);
        starts.push(0u32);
        let mut distinct = 0;
        for &c in counts.iter().flatten() {
            distinct += (c != 0) as usize;
            starts.push(starts.last().copied().unwrap_or(0) + c);
        }
        let mut items = vec![0u32; total];
        let mut parts: Vec<&mut [u32]> = Vec::with_capacity(n_ranges);
        let mut rest = &mut items[..];
        for w in bounds.windows(2) {
            let len = (starts[w[1] as usize] - starts[w[0] as usize]) as usize;
            let (part, tail) = rest.split_at_mut(len);
            parts.push(part);
            rest = tail;
        }
        parts
            .into_par_iter()
            .zip(bounds.par_windows(2))
            .for_each(|(part, w)| {
                let base = starts[w[0] as usize];
                let mut cursor: Vec<u32> = starts[w[0] as usize..w[1] as usize]
                    .iter()
                    .map(|&s| s - base)
                    .collect();
                for i in 0..sets.len() {
                    for &v in run(i, w[0], w[1]) {
                        let p = &mut cursor[(v - w[0]) as usize];
                        part[*p as usize] = i as u32;
                        *p += 1;
                    }
                }
            });
        InvertedIndex {
            starts,
            items,
            ids,
            frame_starts,
            distinct,
        }
    }

    /// Voxel ids of frame `i`'s keys, in key order.
    fn ids_of(&self, i: usize) -> &[u32] {
        &self.ids[self.frame_starts[i]..self.frame_starts[i + 1]]
    }

    /// Range of `items` holding voxel `v`'s frames.
    fn range(&self, v: u32) -> (usize, usize) {
        (
            self.starts[v as usize] as usize,
            self.starts[v as usize + 1] as usize,
        )
    }

    /// Frames after `after` holding voxel `v`, ascending.
    fn after(&self, v: u32, after: usize) -> &[u32] {
        let (a, b) = self.range(v);
        let p = &self.items[a..b];
        &p[p.partition_point(|&j| j as usize <= after)..]
    }
}

/// `buf` cut into one slice per frame.
fn per_frame_mut<'a>(mut buf: &'a mut [u32], frame_starts: &[usize]) -> Vec<&'a mut [u32]> {
    let mut out = Vec::with_capacity(frame_starts.len().saturating_sub(1));
    for w in frame_starts.windows(2) {
        let (head, tail) = buf.split_at_mut(w[1] - w[0]);
        out.push(head);
        buf = tail;
    }
    out
}

/// Per-thread state of the counting walk over a run of consecutive frames.
struct Counter {
    /// Counts indexed by frame.
    count: Vec<u32>,
    /// `Some(base)`: `count[j] = |d_prev ∩ d_j|` for every `j > base`, where
    /// `prev` is the frame just counted, and zero for `j <= base`.
    /// `None`: all zero.
    holding: Option<usize>,
    /// Frames whose count left zero (sparse rows).
    touched: Vec<u32>,
    /// Voxel ids entering / leaving between consecutive frames.
    added: Vec<u32>,
    removed: Vec<u32>,
    /// Rows counted by delta, dense and sparse walks.
    paths: [usize; 3],
}

impl Counter {
    fn new(n: usize) -> Counter {
        Counter {
            count: vec![0; n],
            holding: None,
            touched: Vec::new(),
            added: Vec::new(),
            removed: Vec::new(),
            paths: [0; 3],
        }
    }

    /// Rows of the consecutive frames `frames`, one after the other in one
    /// vector, and where each ends in it; leaves the counters zeroed.
    fn rows(
        &mut self,
        index: &InvertedIndex,
        frames: std::ops::Range<usize>,
        progress: Option<&ProgressBar>,
    ) -> (Vec<(u32, u32)>, Vec<usize>) {
        let mut pairs = Vec::new();
        let mut ends = Vec::with_capacity(frames.len());
        for i in frames {
            self.row(index, i, &mut pairs);
            ends.push(pairs.len());
            if let Some(p) = progress {
                p.inc(1);
            }
        }
        self.release();
        pairs.shrink_to_fit();
        (pairs, ends)
    }

    /// Zeroes the counters.
    fn release(&mut self) {
        if let Some(base) = self.holding.take() {
            self.count[base + 1..].fill(0);
        }
    }

    /// Row `i`: every `(j, |d_i ∩ d_j|)` with `j > i` and a non-zero count,
    /// ascending in `j`. Three ways, cheapest first by estimate:
    /// - delta: when holding frame `i - 1`'s counts, add the postings of
    ///   voxels entering and subtract those leaving, then sweep `j > i`;
    /// - dense: count frame `i`'s posting-list tails (`j > i`), then sweep;
    /// - sparse: the same, remembering touched counters and sorting them.
    fn row(&mut self, index: &InvertedIndex, i: usize, out: &mut Vec<(u32, u32)>) {
        let n = self.count.len();
        let ids = index.ids_of(i);
        if let Some(base) = self.holding {
            self.diff(index, i);
            let len = |v: &u32| {
                let (a, b) = index.range(*v);
                b - a
            };
            let delta: usize = self.added.iter().chain(&self.removed).map(len).sum();
            let fresh: usize = ids.iter().map(len).sum::<usize>() / 2;
            if delta + (n - i) / 4 < fresh {
                let count = &mut self.count[..];
                for &v in &self.added {
                    for &j in index.after(v, base) {
                        count[j as usize] += 1;
                    }
                }
                for &v in &self.removed {
                    for &j in index.after(v, base) {
                        count[j as usize] -= 1;
                    }
                }
                self.paths[0] += 1;
                return self.sweep(i, out);
            }
            self.release();
        }
        let work: usize = ids.iter().map(|&v| index.after(v, i).len()).sum();
        let count = &mut self.count[..];
        if 4 * work >= n - i - 1 {
            for &v in ids {
                for &j in index.after(v, i) {
                    count[j as usize] += 1;
                }
            }
            self.holding = Some(i);
            self.paths[1] += 1;
            return self.sweep(i, out);
        }
        let touched = &mut self.touched;
        for &v in ids {
            for &j in index.after(v, i) {
                let c = &mut count[j as usize];
                if *c == 0 {
                    touched.push(j);
                }
                *c += 1;
            }
        }
        touched.sort_unstable();
        self.paths[2] += 1;
        out.extend(
            touched
                .iter()
                .map(|&j| (j, std::mem::take(&mut count[j as usize]))),
        );
        touched.clear();
    }

    /// Non-zero counts of frames after `i`, without clearing them.
    fn sweep(&self, i: usize, out: &mut Vec<(u32, u32)>) {
        out.extend(
            self.count[i + 1..]
                .iter()
                .enumerate()
                .filter(|&(_, &c)| c != 0)
                .map(|(k, &c)| ((i + 1 + k) as u32, c)),
        );
    }

    /// Voxel ids in `d_i` but not `d_{i-1}` (`added`) and the reverse
    /// (`removed`): a merge of the two frames' ascending ids.
    fn diff(&mut self, index: &InvertedIndex, i: usize) {
        let (a, b) = (index.ids_of(i - 1), index.ids_of(i));
        self.added.clear();
        self.removed.clear();
        let (mut p, mut q) = (0, 0);
        while p < a.len() && q < b.len() {
            match a[p].cmp(&b[q]) {
                std::cmp::Ordering::Less => {
                    self.removed.push(a[p]);
                    p += 1;
                }
                std::cmp::Ordering::Greater => {
                    self.added.push(b[q]);
                    q += 1;
                }
                std::cmp::Ordering::Equal => {
                    p += 1;
                    q += 1;
                }
            }
        }
        self.removed.extend_from_slice(&a[p..]);
        self.added.extend_from_slice(&b[q..]);
    }
}

/// Intersection counts of every co-observing pair of frames.
///
/// Only pairs `i < j` with `|d_i ∩ d_j| > 0` are stored, in row `i`
/// (compressed rows, ascending `j`): memory grows with the number of
/// co-observing pairs, not with `n²`. The rows stay in the vectors the
/// counting threads filled, one per run of consecutive frames: joining
/// them would hold every pair twice at the peak.
#[derive(Debug, Clone)]
pub struct CoObservation {
    /// `|d_i|` per frame.
    sizes: Vec<u32>,
    /// Frames per run: row `i` is in `runs[i / run]`.
    run: usize,
    /// Per run, its rows one after the other: `(j, |d_i ∩ d_j|)`, `j > i`.
    runs: Vec<Vec<(u32, u32)>>,
    /// Per frame, where its row ends in its run's vector.
    ends: Vec<usize>,
    /// Co-observing pairs in all.
    pair_count: usize,
    /// `|∪ d_i|`.
    distinct_keys: usize,
}

impl CoObservation {
    /// Counts intersections of all co-observing pairs of `sets` (each
    /// ascending and duplicate-free). `progress`, when given, is incremented
    /// once per frame.
    ///
    /// # Panics
    /// When a set holds `u32::MAX` keys or more, or all sets together
    /// `u32::MAX` key occurrences or more.
    pub fn new(sets: &[Vec<u64>], progress: Option<&ProgressBar>) -> CoObservation {
        let n = sets.len();
        assert!(n < u32::MAX as usize, "too many frames: {n}");
        debug_assert!(sets.iter().all(|s| s.windows(2).all(|w| w[0] < w[1])));
        let index = InvertedIndex::new(sets);
        // Runs of consecutive frames, so that each run can mostly update
        // the previous frame's counts; several runs per thread for balance.
        let run = (n / (4 * rayon::current_num_threads())).clamp(16, 256);
        let (runs, ends): (Vec<_>, Vec<_>) = (0..n.div_ceil(run))
            .into_par_iter()
            .map_init(
                || Counter::new(n),
                |counter, r| counter.rows(&index, r * run..((r + 1) * run).min(n), progress),
            )
            .unzip();
        CoObservation {
            sizes: sets.iter().map(|s| s.len() as u32).collect(),
            run,
            pair_count: runs.iter().map(Vec::len).sum(),
            runs,
            ends: ends.into_iter().flatten().collect(),
            distinct_keys: index.distinct,
        }
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.sizes.len()
    }

    /// `true` when there are no frames.
    pub fn is_empty(&self) -> bool {
        self.sizes.is_empty()
    }

    /// `|d_i|`.
    pub fn size(&self, i: usize) -> u32 {
        self.sizes[i]
    }

    /// `|∪ d_i|` over all frames.
    pub fn distinct_keys(&self) -> usize {
        self.distinct_keys
    }

    /// Number of co-observing pairs (`i < j`, at least one common voxel).
    pub fn pair_count(&self) -> usize {
        self.pair_count
    }

    /// Row `i`: `(j, |d_i ∩ d_j|)` for every co-observing `j > i`, ascending.
    pub fn row(&self, i: usize) -> &[(u32, u32)] {
        let start = if i.is_multiple_of(self.run) {
            0
        } else {
            self.ends[i - 1]
        };
        &self.runs[i / self.run][start..self.ends[i]]
    }

    /// Every co-observing pair as `(i, j, |d_i ∩ d_j|)` with `i < j`, row by row.
    pub fn pairs(&self) -> impl Iterator<Item = (usize, usize, u32)> + '_ {
        (0..self.len()).flat_map(move |i| self.row(i).iter().map(move |&(j, c)| (i, j as usize, c)))
    }

    /// `|d_i ∩ d_j|` (symmetric; `|d_i|` when `i == j`).
    pub fn common(&self, i: usize, j: usize) -> u32 {
        if i == j {
            return self.sizes[i];
        }
        let (a, b) = if i < j { (i, j) } else { (j, i) };
        let row = self.row(a);
        match row.binary_search_by_key(&(b as u32), |&(j, _)| j) {
            Ok(k) => row[k].1,
            Err(_) => 0,
        }
    }

    /// IoU of frames `i` and `j` by the core's formula (symmetric; 0 for pairs
    /// sharing no voxel and for two empty sets; 1 for `i == j` unless empty).
    pub fn iou(&self, i: usize, j: usize) -> f32 {
        self.pair_iou(i, j, self.common(i, j))
    }

    /// IoU of `i` and `j` given their intersection count.
    pub fn pair_iou(&self, i: usize, j: usize, common: u32) -> f32 {
        placedb::voxel::iou(self.sizes[i], self.sizes[j], common)
    }

    /// The frames after `i` that overlap it at `mu`, ascending: its edges
    /// to later frames in `G(mu)`. An edge is `IoU > mu` (strict); for
    /// `mu < 0` pairs sharing no voxel still get no edge (IoU 0 is not an
    /// overlap); NaN gives no edges.
    pub fn later_overlaps(&self, i: usize, mu: f32) -> impl Iterator<Item = usize> + '_ {
        self.row(i)
            .iter()
            .filter(move |&&(j, c)| self.pair_iou(i, j as usize, c) > mu)
            .map(|&(j, _)| j as usize)
    }

    /// The overlap graph `G(mu)`: edge `i–j` iff `IoU > mu` (see
    /// [`Self::later_overlaps`]).
    pub fn graph(&self, mu: f32) -> OverlapGraph {
        let n = self.len();
        // The later overlaps in parallel, a run of rows at a time: per row
        // its count, and the rows' lists one after the other.
        let runs: Vec<(Vec<usize>, Vec<u32>)> = (0..n.div_ceil(self.run))
            .into_par_iter()
            .map(|r| {
                let (mut counts, mut items) = (Vec::new(), Vec::new());
                for i in r * self.run..((r + 1) * self.run).min(n) {
                    let before = items.len();
                    items.extend(self.later_overlaps(i, mu).map(|j| j as u32));
                    counts.push(items.len() - before);
                }
                (counts, items)
            })
            .collect();
        // Read where they are: a flat copy would add a third of the
        // graph's memory to its peak.
        let later = || {
            runs.iter().flat_map(|(counts, items)| {
                let mut start = 0;
                counts.iter().map(move |&c| {
                    start += c;
                    &items[start - c..start]
                })
            })
        };
        OverlapGraph {
            n,
            mu,
            adj: Adjacency::symmetric(n, later),
        }
    }
}

/// Lists of vertices in one allocation: vertex `v`'s are
/// `items[starts[v]..starts[v + 1]]`.
#[derive(Debug, Clone, PartialEq)]
struct Adjacency {
    starts: Vec<usize>,
    items: Vec<u32>,
}

impl Adjacency {
    fn of(&self, v: usize) -> &[u32] {
        &self.items[self.starts[v]..self.starts[v + 1]]
    }

    /// The undirected graph on `n` vertices whose edges are the lists
    /// `later()` yields, vertex after vertex, each holding later vertices
    /// only, ascending (read twice: to count, then to fill). Every vertex's
    /// list gets its earlier neighbours (ascending), then its own.
    ///
    /// # Panics
    /// When `later()` yields other than `n` lists, or a list holds a vertex
    /// not after its own or past the last.
    fn symmetric<'a, I: Iterator<Item = &'a [u32]>>(n: usize, later: impl Fn() -> I) -> Adjacency {
        let mut degree = vec![0usize; n];
        let mut lists = 0;
        for (v, list) in later().enumerate() {
            degree[v] += list.len();
            for &u in list {
                assert!((v + 1..n).contains(&(u as usize)), "edge {v}-{u}");
                degree[u as usize] += 1;
            }
            lists += 1;
        }
        assert_eq!(lists, n, "lists of {lists} vertices for {n}");
        let mut starts = Vec::with_capacity(n + 1);
        starts.push(0);
        for d in degree {
            starts.push(starts[starts.len() - 1] + d);
        }
        let mut items = vec![0u32; starts[n]];
        // Where each list's next vertex goes. In ascending order of `v`,
        // a list receives its earlier neighbours before its own later ones,
        // so it stays sorted.
        let mut next = starts[..n].to_vec();
        for (v, later) in later().enumerate() {
            for &u in later {
                items[next[u as usize]] = v as u32;
                next[u as usize] += 1;
            }
            items[next[v]..next[v] + later.len()].copy_from_slice(later);
        }
        Adjacency { starts, items }
    }
}

/// An undirected simple graph on frames `0..n`.
#[derive(Debug, Clone, PartialEq)]
pub struct OverlapGraph {
    /// Number of vertices (frames).
    pub n: usize,
    /// The IoU threshold it was built with; NaN for graphs built from edges.
    pub mu: f32,
    /// Sorted, duplicate-free neighbours of each vertex, without the vertex
    /// itself; symmetric. One allocation, not one per vertex: a building's
    /// graph has millions of edges.
    adj: Adjacency,
}

impl OverlapGraph {
    /// A graph from an edge list (any order, duplicates and self-loops
    /// ignored); `mu` is NaN.
    ///
    /// # Panics
    /// When an endpoint is `>= n`.
    pub fn from_edges(n: usize, edges: &[(usize, usize)]) -> OverlapGraph {
        let mut pairs: Vec<(u32, u32)> = edges
            .iter()
            .filter(|&&(a, b)| {
                assert!(a < n && b < n, "edge ({a}, {b}) outside 0..{n}");
                a != b
            })
            .map(|&(a, b)| (a.min(b) as u32, a.max(b) as u32))
            .collect();
        pairs.sort_unstable();
        pairs.dedup();
        let mut later = Adjacency {
            starts: vec![0; n + 1],
            items: pairs.iter().map(|&(_, b)| b).collect(),
        };
        for &(a, _) in &pairs {
            later.starts[a as usize + 1] += 1;
        }
        for v in 0..n {
            later.starts[v + 1] += later.starts[v];
        }
        OverlapGraph {
            n,
            mu: f32::NAN,
            adj: Adjacency::symmetric(n, || (0..n).map(|v| later.of(v))),
        }
    }

    /// Neighbours of `v` (not including `v`), ascending.
    pub fn neighbours(&self, v: usize) -> &[u32] {
        self.adj.of(v)
    }

    /// Whether `a` and `b` are adjacent.
    pub fn has_edge(&self, a: usize, b: usize) -> bool {
        self.neighbours(a).binary_search(&(b as u32)).is_ok()
    }

    /// Number of edges.
    pub fn edge_count(&self) -> usize {
        self.adj.items.len() / 2
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use placedb::voxel::intersection_size;

    #[test]
    fn small_counts_and_graph() {
        let sets = vec![
            vec![1, 2, 3, 4],
            vec![3, 4, 5],
            vec![10],
            vec![],
            vec![1, 2, 3, 4],
        ];
        let co = CoObservation::new(&sets, None);
        assert_eq!(co.row(0), &[(1, 2), (4, 4)]);
        assert_eq!(co.row(1), &[(4, 2)]);
        assert!(co.row(2).is_empty() && co.row(3).is_empty());
        assert_eq!(co.common(4, 1), 2);
        assert_eq!(co.iou(1, 0), 2.0 / 5.0);
        assert_eq!(co.iou(0, 4), 1.0);
        assert_eq!(co.iou(2, 3), 0.0);
        assert_eq!(co.iou(3, 3), 0.0);
        assert_eq!(co.distinct_keys(), 6);
        let lists = |g: &OverlapGraph| {
            (0..g.n)
                .map(|v| g.neighbours(v).to_vec())
                .collect::<Vec<_>>()
        };
        let g = co.graph(0.4);
        assert_eq!(lists(&g), vec![vec![4], vec![], vec![], vec![], vec![0]]);
        let g = co.graph(0.3);
        assert_eq!(
            lists(&g),
            vec![vec![1, 4], vec![0, 4], vec![], vec![], vec![0, 1]]
        );
        assert_eq!(
            g,
            OverlapGraph {
                mu: 0.3,
                ..OverlapGraph::from_edges(5, &[(4, 1), (0, 4), (1, 0), (0, 1)])
            }
        );
    }

    /// Rows of `sets` by one counter over `run`-frame runs, in both id
    /// modes, checked against merges; returns how often each path ran.
    fn check_rows(sets: &[Vec<u64>], run: usize) -> [usize; 3] {
        let total = sets.iter().map(Vec::len).sum();
        let mut paths = [0; 3];
        for cells in [BoxCells::of(sets, total), None] {
            let index = InvertedIndex::build(sets, cells);
            let mut counter = Counter::new(sets.len());
            let mut i = 0;
            for r in (0..sets.len()).step_by(run) {
                let (pairs, ends) = counter.rows(&index, r..(r + run).min(sets.len()), None);
                let starts = std::iter::once(0).chain(ends.iter().copied());
                for (start, &end) in starts.zip(&ends) {
                    let row = &pairs[start..end];
                    let want: Vec<(u32, u32)> = (i + 1..sets.len())
                        .map(|j| (j as u32, intersection_size(&sets[i], &sets[j])))
                        .filter(|&(_, c)| c > 0)
                        .collect();
                    assert_eq!(row, want, "frame {i}");
                    i += 1;
                }
                assert!(counter.count.iter().all(|&c| c == 0));
            }
            paths = counter.paths;
        }
        paths
    }

    #[test]
    fn every_counting_path_matches_merges() {
        use placedb::VoxelKey;
        let key = |x: i32, y: i32, z: i32| VoxelKey::new(x, y, z).to_bits();
        // A sliding window along x, 1 voxel per frame: consecutive frames
        // share most voxels (delta path).
        let slide: Vec<Vec<u64>> = (0..120)
            .map(|i| {
                (i..i + 30)
                    .flat_map(|x| (0..3).map(move |y| key(x, y, -2)))
                    .collect()
            })
            .collect();
        let p = check_rows(&slide, 40);
        assert!(p[0] > 50 && p[1] >= 3, "{p:?}");
        // Unrelated consecutive frames over a small world (dense path).
        let mut rng = crate::rng::SplitMix64::new(1);
        let mut next = move || rng.next_u64();
        let shuffled: Vec<Vec<u64>> = (0..80)
            .map(|_| {
                let mut s: Vec<u64> = (0..40)
                    .filter(|_| next() % 3 == 0)
                    .map(|x| key(x, 5, 5))
                    .collect();
                s.dedup();
                s
            })
            .collect();
        let p = check_rows(&shuffled, 16);
        assert!(p[1] > 40, "{p:?}");
        // Frame 0 sees many frames through few voxels, the others only
        // their neighbours (sparse path), plus empty frames.
        let mut sparse: Vec<Vec<u64>> = (0..300)
            .map(|i| vec![key(i, 0, 0), key(i / 7, 1, 0)])
            .collect();
        sparse[0] = (0..300).map(|i| key(i, 0, 0)).collect();
        sparse[5].clear();
        sparse[6].clear();
        sparse.iter_mut().for_each(|s| s.sort_unstable());
        let p = check_rows(&sparse, 300);
        assert!(p[2] > 100, "{p:?}");
    }

    #[test]
    fn hasher_spreads_low_bits() {
        let h = |k: u64| {
            let mut s = KeyHasher::default();
            s.write_u64(k);
            s.finish() & 0xff
        };
        // Keys differing only in the x field (high bits) must not collide in the low bits.
        let distinct: std::collections::HashSet<u64> = (0..64u64).map(|x| h(x << 42)).collect();
        assert!(distinct.len() > 40);
    }
}
