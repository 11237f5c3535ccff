//! Replays a recorded sequence through the device core (`placedb::Selector`)
//! exactly as a board would receive it: frame by frame, sampled rows in
//! chunks, one selector of a named capacity profile.

use crate::row_chunks::row_spans;
use crate::sequence::{DepthImage, Sequence};
use crate::voxelize::{VoxelSets, VoxelizeError};
use indicatif::ProgressBar;
use placedb::frame::{FrameError, FrameIngest};
use placedb::key_pool::{key_of, merge_count};
use placedb::profile::{Ram1M, Ram256K, Ram512K};
use placedb::select::{DbSnapshot, FrameStore};
use placedb::{
    DbRecord, Decision, FrameMeta, ScanConfig, SelectError, Selector, SelectorConfig, Status,
};
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
    #[error("frame {frame}: the core refused it: {reason}")]
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
    replay_with(seq, None, profile, scan, cfg, rows_per_chunk, progress)
}

/// [`replay`] of a sequence already voxelized with `scan` (its stride,
/// grid, range and camera: `sets` from [`crate::voxelize`] on the same
/// configuration): a frame whose voxel set fits the profile's frame set
/// is filled from `sets` instead of decoded and voxelized again, with the
/// same result; the others (a set the device would truncate) are decoded
/// and their rows pushed as in [`replay`].
pub fn replay_voxelized(
    seq: &Sequence,
    sets: &VoxelSets,
    profile: &str,
    scan: ScanConfig,
    cfg: SelectorConfig,
    rows_per_chunk: usize,
    progress: Option<&ProgressBar>,
) -> Result<OnlineRun, ReplayError> {
    replay_with(
        seq,
        Some(sets),
        profile,
        scan,
        cfg,
        rows_per_chunk,
        progress,
    )
}

fn replay_with(
    seq: &Sequence,
    sets: Option<&VoxelSets>,
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
                sets,
                scan,
                cfg,
                rows_per_chunk,
                progress,
            ),
            "ram512k" => run(
                &mut Box::new(Ram512K::new()),
                seq,
                sets,
                scan,
                cfg,
                rows_per_chunk,
                progress,
            ),
            "ram1m" => run(
                &mut Box::new(Ram1M::new()),
                seq,
                sets,
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

/// One frame voxelized off the selector, ready for `end_frame_from`.
struct Ingested<const FV: usize> {
    ingest: Box<FrameIngest<FV>>,
    read_time: Duration,
}

/// Voxelizes frame `i`: from its voxel set in `sets` when that fits, else
/// decoded and voxelized as a board would receive it, its sampled rows
/// pushed `rows_per_chunk` at a time.
fn ingest<const FV: usize>(
    seq: &Sequence,
    sets: Option<&VoxelSets>,
    i: usize,
    scan: &ScanConfig,
    rows_per_chunk: usize,
    img: &mut DepthImage,
) -> Result<Ingested<FV>, ReplayError> {
    // The camera refused for this frame (a pose too far for the
    // fixed-point keys) in the words the offline solvers use.
    let core_err = |reason: FrameError| match reason {
        FrameError::Camera(reason) => ReplayError::Read(VoxelizeError::Camera {
            frame: i,
            name: seq.frames[i].depth_name.clone(),
            reason,
        }),
        reason => ReplayError::Core {
            frame: i,
            reason: SelectError::Frame(reason),
        },
    };
    let pose = seq.frames[i]
        .pose()
        .map_err(|reason| VoxelizeError::Camera {
            frame: i,
            name: seq.frames[i].depth_name.clone(),
            reason,
        })?;
    let mut ingest = Box::new(FrameIngest::<FV>::new());
    let meta = FrameMeta {
        index: i as u32,
        timestamp: seq.frames[i].timestamp,
        pose,
    };
    ingest.begin(meta, i as u32, scan).map_err(core_err)?;
    let known = sets.and_then(|s| {
        let oor = s.frame_out_of_range.get(i).copied().unwrap_or(0);
        Some((s.sets.get(i)?, *s.valid_pixels.get(i)?, oor))
    });
    if let Some((keys, valid, oor)) = known {
        if ingest.fill_from_set(keys, valid, oor) {
            return Ok(Ingested {
                ingest,
                read_time: Duration::ZERO,
            });
        }
    }
    let t = Instant::now();
    seq.depth_into(i, img).map_err(VoxelizeError::from)?;
    let read_time = t.elapsed();
    let (width, rows) = sampled_rows(img, scan.stride);
    for (first, data) in row_spans(width, &rows, rows_per_chunk) {
        ingest.push_rows(first, data).map_err(core_err)?;
    }
    Ok(Ingested { ingest, read_time })
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
    sets: Option<&VoxelSets>,
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
    // Frames are decoded and voxelized in parallel, each into its own
    // ingest, and decided in order (the selection is sequential by nature):
    // batch k + 1 is voxelized while batch k is decided.
    let batch = 8 * rayon::current_num_threads().max(1);
    let voxelize_batch = |start: usize| -> Result<Vec<Ingested<FV>>, ReplayError> {
        crate::voxelize::in_order::try_map_init(
            start..(start + batch).min(n),
            DepthImage::default,
            |img, i| ingest(seq, sets, i, &scan, rows_per_chunk, img),
        )
    };
    let mut ready = voxelize_batch(0)?;
    let mut start = 0;
    while start < n {
        let next = start + batch;
        let mut decide = |frames: Vec<Ingested<FV>>| -> Result<Duration, ReplayError> {
            let t = Instant::now();
            for (k, mut frame) in frames.into_iter().enumerate() {
                read_time += frame.read_time;
                sel.end_frame_from(&mut frame.ingest, &mut store, &mut record)
                    .map_err(core_err(start + k))?;
                if let Some(p) = progress {
                    p.inc(1);
                }
            }
            Ok(t.elapsed())
        };
        let (voxelized, decided) = if next < n {
            rayon::join(|| voxelize_batch(next), || decide(ready))
        } else {
            (Ok(Vec::new()), decide(ready))
        };
        core_time += decided?;
        ready = voxelized?;
        start = next;
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
