//! Replays a recorded sequence through the device core (`placedb::Selector`)
//! exactly as a board would receive it: frame by frame, sampled rows in
//! chunks, one selector of a named capacity profile.

use crate::sequence::{DepthImage, Sequence};
use crate::voxelize::VoxelizeError;
use indicatif::ProgressBar;
use placedb::profile::{Ram1M, Ram256K, Ram512K};
use placedb::select::{DbSnapshot, FrameStore};
use placedb::store::{key_of, merge_count};
use placedb::{
    DbRecord, Decision, FrameMeta, ScanConfig, SelectError, Selector, SelectorConfig, Status,
};
use rayon::prelude::*;
use std::time::{Duration, Instant};

/// Result of a replay.
#[derive(Debug, Clone)]
pub struct OnlineRun {
    /// Final decision of every frame, by frame index.
    pub decisions: Vec<Decision>,
    /// Class label (a frame index) of every frame.
    pub labels: Vec<usize>,
    /// Database entries in frame order.
    pub database: Vec<DbRecord>,
    /// The selector's final counters.
    pub status: Status,
    /// Summed over threads: decoding depth.
    pub read_time: Duration,
    /// Wall time inside the core (voxelize + overlap + select).
    pub core_time: Duration,
}

/// Why a replay stopped.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// Reading depth failed.
    #[error(transparent)]
    Read(#[from] VoxelizeError),
    /// The core refused a step.
    #[error("frame {frame}: the core refused it: {reason:?}")]
    Core {
        /// Frame index.
        frame: usize,
        /// The core's error.
        reason: SelectError,
    },
    /// No such profile.
    #[error("unknown profile {0:?} (known: ram256k, ram512k, ram1m)")]
    UnknownProfile(String),
}

/// The rows a board receives for one frame: sampled rows of sampled columns.
pub fn sampled_rows(img: &DepthImage, stride: u16) -> (usize, Vec<u16>) {
    sampled_rows_of(&img.data, img.width, stride)
}

/// [`sampled_rows`] of a row-major buffer `width` values wide (a frame held
/// in memory, e.g. a camera driver's): its rows `0, stride, 2 stride, ...`,
/// each sampled the same way. A last partial row is ignored.
pub fn sampled_rows_of(data: &[u16], width: u16, stride: u16) -> (usize, Vec<u16>) {
    let s = stride.max(1) as usize;
    let w = width as usize;
    let height = data.len().checked_div(w).unwrap_or(0);
    let sampled = w.div_ceil(s);
    let mut out = Vec::with_capacity(sampled * height.div_ceil(s));
    for row in data.chunks_exact(w.max(1)).take(height).step_by(s) {
        out.extend(row.iter().step_by(s));
    }
    (sampled, out)
}

/// Runs `seq` through a selector of profile `profile` (see `placedb::profile`).
/// `rows_per_chunk` sampled rows are pushed at a time, as a transport would.
pub fn replay(
    seq: &Sequence,
    profile: &str,
    scan: ScanConfig,
    cfg: SelectorConfig,
    rows_per_chunk: usize,
    progress: Option<&ProgressBar>,
) -> Result<OnlineRun, ReplayError> {
    // The selectors are hundreds of KiB: build them on a thread with a stack to match.
    std::thread::scope(|s| {
        let job = s.spawn_scoped_big(move || match profile {
            "ram256k" => run(
                &mut Box::new(Ram256K::new()),
                seq,
                scan,
                cfg,
                rows_per_chunk,
                progress,
            ),
            "ram512k" => run(
                &mut Box::new(Ram512K::new()),
                seq,
                scan,
                cfg,
                rows_per_chunk,
                progress,
            ),
            "ram1m" => run(
                &mut Box::new(Ram1M::new()),
                seq,
                scan,
                cfg,
                rows_per_chunk,
                progress,
            ),
            other => Err(ReplayError::UnknownProfile(other.to_string())),
        });
        job.join().expect("replay thread panicked")
    })
}

/// Spawning with a stack large enough for a selector built by value.
trait SpawnBig<'scope> {
    fn spawn_scoped_big<T: Send + 'scope>(
        &'scope self,
        f: impl FnOnce() -> T + Send + 'scope,
    ) -> std::thread::ScopedJoinHandle<'scope, T>;
}

impl<'scope, 'env> SpawnBig<'scope> for std::thread::Scope<'scope, 'env> {
    fn spawn_scoped_big<T: Send + 'scope>(
        &'scope self,
        f: impl FnOnce() -> T + Send + 'scope,
    ) -> std::thread::ScopedJoinHandle<'scope, T> {
        std::thread::Builder::new()
            .stack_size(64 << 20)
            .spawn_scoped(self, f)
            .expect("cannot start the replay thread")
    }
}

/// The replay's [`FrameStore`]: database frames (and the exact keys the
/// selector hands over) in a `Vec`, as a board keeps them in its flash log,
/// so the replay decides exactly as a board with flash does.
#[derive(Debug, Default)]
pub struct MemStore<const K: usize> {
    frames: Vec<(DbSnapshot<K>, Option<Vec<u64>>)>,
}

impl<const K: usize> FrameStore<K> for MemStore<K> {
    fn save(&mut self, frame: &DbSnapshot<K>, keys: Option<&[u32]>) -> Option<(u32, bool)> {
        let base = frame.aabb.map(|a| a.min);
        let keys = keys
            .zip(base)
            .map(|(words, base)| words.iter().map(|&w| key_of(base, w)).collect());
        let kept = keys.is_some();
        self.frames.push((*frame, keys));
        Some((u32::try_from(self.frames.len() - 1).ok()?, kept))
    }

    fn load(&mut self, at: u32) -> Option<DbSnapshot<K>> {
        self.frames.get(at as usize).map(|(f, _)| *f)
    }

    fn intersect(&mut self, at: u32, keys: &[u64]) -> Option<(u32, u32)> {
        let (frame, stored) = self.frames.get(at as usize)?;
        let stored = stored.as_ref()?;
        let common = merge_count(stored.iter().copied(), keys.iter().copied());
        Some((common, frame.voxels))
    }
}

fn run<
    const FV: usize,
    const POOL: usize,
    const DB: usize,
    const W: usize,
    const K: usize,
    const R: usize,
>(
    sel: &mut Selector<FV, POOL, DB, W, K, R>,
    seq: &Sequence,
    scan: ScanConfig,
    cfg: SelectorConfig,
    rows_per_chunk: usize,
    progress: Option<&ProgressBar>,
) -> Result<OnlineRun, ReplayError> {
    let n = seq.frames.len();
    let core_err = |frame: usize| move |reason| ReplayError::Core { frame, reason };
    sel.configure(scan, cfg).map_err(core_err(0))?;
    let mut decisions = vec![Decision::Pending; n];
    let mut store = MemStore::<K>::default();
    let mut read_time = Duration::ZERO;
    let mut core_time = Duration::ZERO;
    let mut record = |d: placedb::FrameDecision| {
        if let Some(slot) = decisions.get_mut(d.index as usize) {
            if d.decision != Decision::Pending {
                *slot = d.decision;
            }
        }
    };
    // Decode a batch in parallel, then feed it in order: the core is sequential by nature.
    let batch = 2 * rayon::current_num_threads().max(1);
    for start in (0..n).step_by(batch) {
        let end = (start + batch).min(n);
        let images: Vec<_> = (start..end)
            .into_par_iter()
            .map(|i| {
                let t = Instant::now();
                let img = seq.depth(i).map_err(VoxelizeError::from)?;
                let pose = seq.frames[i]
                    .pose()
                    .map_err(|reason| VoxelizeError::Camera {
                        frame: i,
                        name: seq.frames[i].depth_name.clone(),
                        reason,
                    })?;
                let (width, rows) = sampled_rows(&img, scan.stride);
                Ok((pose, width, rows, t.elapsed()))
            })
            .collect::<Result<_, VoxelizeError>>()?;
        for (k, (pose, width, rows, took)) in images.into_iter().enumerate() {
            let i = start + k;
            read_time += took;
            let t = Instant::now();
            let meta = FrameMeta {
                index: i as u32,
                timestamp: seq.frames[i].timestamp,
                pose,
            };
            sel.begin_frame(meta).map_err(core_err(i))?;
            let chunk = width * rows_per_chunk.max(1);
            for (c, data) in rows.chunks(chunk.max(1)).enumerate() {
                let first = (c * rows_per_chunk.max(1)) as u16;
                sel.push_rows(first, data).map_err(core_err(i))?;
            }
            sel.end_frame_with(&mut store, &mut record)
                .map_err(core_err(i))?;
            core_time += t.elapsed();
            if let Some(p) = progress {
                p.inc(1);
            }
        }
    }
    let t = Instant::now();
    sel.finish_with(&mut store, &mut record)
        .map_err(core_err(n))?;
    core_time += t.elapsed();
    let labels = decisions
        .iter()
        .enumerate()
        .map(|(i, d)| match *d {
            Decision::DominatedBy(k) | Decision::Uncovered(Some(k)) => k as usize,
            _ => i,
        })
        .collect();
    let database = (0..sel.database_len())
        .filter_map(|i| sel.database_record(i, &mut store))
        .collect();
    Ok(OnlineRun {
        decisions,
        labels,
        database,
        status: sel.status(),
        read_time,
        core_time,
    })
}
