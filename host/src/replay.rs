//! Replays a recorded sequence through the device core (`placedb::Selector`)
//! exactly as a board would receive it: frame by frame, sampled rows in
//! chunks, one selector of a named capacity profile.

use crate::frame_rows::{row_spans, sampled_rows};
use crate::sequence::{DepthImage, Sequence};
use crate::voxelize::{VoxelSets, VoxelizeError};
use indicatif::ProgressBar;
use placedb::frame::{FrameError, FrameIngest};
use placedb::key_pool::{key_of, merge_count, Aabb};
use placedb::profile::{Ram1M, Ram256K, Ram512K};
use placedb::select::{DbSnapshot, FrameStore};
use placedb::{
    DbRecord, Decision, FrameMeta, ScanConfig, SelectError, Selector, SelectorConfig, Status,
};
use std::time::{Duration, Instant};

/// Result of a replay.
#[derive(Debug, Clone)]
pub struct OnlineRun {
    /// Final decision of every frame, by global frame index (an extended
    /// replay's earlier sessions first, as the extension file has them).
    pub decisions: Vec<Decision>,
    /// Class label (a global frame index) of every frame.
    pub labels: Vec<usize>,
    /// Database entries in frame order.
    pub database: Vec<DbRecord>,
    /// What the store keeps of each entry of `database`, in the same order.
    pub stored: Vec<StoredFrame>,
    /// The selector's final counters.
    pub status: Status,
    /// Summed over threads: decoding depth.
    pub read_time: Duration,
    /// Wall time inside the core (voxelize + overlap + select).
    pub core_time: Duration,
}

/// What the replay's store keeps of a database frame, for the extension file.
#[derive(Debug, Clone, PartialEq)]
pub struct StoredFrame {
    /// Box of its voxel set.
    pub aabb: Option<Aabb>,
    /// Its sketch's hashes, ascending.
    pub sketch: Vec<u32>,
    /// Its exact keys, when the store kept them.
    pub keys: Option<Vec<u64>>,
    /// Bytes of the key budget they took.
    pub key_bytes: u32,
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
    /// The earlier sessions' database cannot seed this selector.
    #[error("the database to extend: {0}")]
    Seed(String),
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
    let job = Job {
        seq,
        earlier: None::<&FirstSession>,
        sets: None,
        scan,
        cfg,
        rows_per_chunk,
        progress,
    };
    replay_with(job, profile)
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
    let job = Job {
        seq,
        earlier: None::<&FirstSession>,
        sets: Some(sets),
        scan,
        cfg,
        rows_per_chunk,
        progress,
    };
    replay_with(job, profile)
}

/// [`replay`] (or [`replay_voxelized`] with `sets`) of a later session
/// `seq` on top of `earlier` sessions: the selector is seeded with their
/// database and decisions ([`Seed::seed`], as a device restores its flash
/// log), then `seq`'s frames follow with global indices from the index the
/// seed returns. The run's decisions, labels and database cover every
/// session. The earlier sessions' model is the caller's
/// (`crate::sessions::seed` for an extension file).
#[allow(clippy::too_many_arguments)]
pub fn replay_after<S: Seed>(
    earlier: &S,
    seq: &Sequence,
    sets: Option<&VoxelSets>,
    profile: &str,
    scan: ScanConfig,
    cfg: SelectorConfig,
    rows_per_chunk: usize,
    progress: Option<&ProgressBar>,
) -> Result<OnlineRun, ReplayError> {
    let job = Job {
        seq,
        earlier: Some(earlier),
        sets,
        scan,
        cfg,
        rows_per_chunk,
        progress,
    };
    replay_with(job, profile)
}

/// Earlier sessions a replay goes on from, put into a fresh selector as a
/// device restores its flash log before it continues.
pub trait Seed: Sync {
    /// Configures `sel` with `scan` and `cfg`, puts the earlier database
    /// frames into it and `store`, and restores every earlier frame's
    /// decision in order; returns the global index of the next frame.
    fn seed<
        const FV: usize,
        const POOL: usize,
        const DB: usize,
        const W: usize,
        const K: usize,
        const R: usize,
    >(
        &self,
        sel: &mut Selector<FV, POOL, DB, W, K, R>,
        store: &mut MemStore<K>,
        scan: ScanConfig,
        cfg: SelectorConfig,
    ) -> Result<u32, ReplayError>;

    /// The final decision of every earlier frame, by global index.
    fn decisions(&self) -> Vec<Decision>;
}

/// No earlier session: a replay of a first session ([`replay`],
/// [`replay_voxelized`]). It has no value, so it is never seeded.
pub enum FirstSession {}

impl Seed for FirstSession {
    fn seed<
        const FV: usize,
        const POOL: usize,
        const DB: usize,
        const W: usize,
        const K: usize,
        const R: usize,
    >(
        &self,
        _: &mut Selector<FV, POOL, DB, W, K, R>,
        _: &mut MemStore<K>,
        _: ScanConfig,
        _: SelectorConfig,
    ) -> Result<u32, ReplayError> {
        match *self {}
    }

    fn decisions(&self) -> Vec<Decision> {
        match *self {}
    }
}

/// What one replay runs on.
struct Job<'a, S> {
    seq: &'a Sequence,
    /// The earlier sessions to continue, if any.
    earlier: Option<&'a S>,
    /// The sequence's voxel sets, to reuse.
    sets: Option<&'a VoxelSets>,
    scan: ScanConfig,
    cfg: SelectorConfig,
    rows_per_chunk: usize,
    progress: Option<&'a ProgressBar>,
}

fn replay_with<S: Seed>(job: Job<'_, S>, profile: &str) -> Result<OnlineRun, ReplayError> {
    // The selectors are hundreds of KiB: build them on a thread with a stack to match.
    std::thread::scope(|s| {
        let job = s.spawn_scoped_big(move || match profile {
            "ram256k" => run(&mut Box::new(Ram256K::new()), job),
            "ram512k" => run(&mut Box::new(Ram512K::new()), job),
            "ram1m" => run(&mut Box::new(Ram1M::new()), job),
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
    /// Each frame saved, its exact keys if kept, and the bytes of the key
    /// budget they took.
    frames: Vec<(DbSnapshot<K>, Option<Vec<u64>>, u32)>,
}

impl<const K: usize> MemStore<K> {
    /// Keeps `frame` (with its exact `keys`, which took `key_bytes` of the
    /// key budget) as a store of an earlier session holds it; returns where.
    pub fn put(&mut self, frame: DbSnapshot<K>, keys: Option<Vec<u64>>, key_bytes: u32) -> u32 {
        self.frames.push((frame, keys, key_bytes));
        (self.frames.len() - 1) as u32
    }

    /// What the store keeps of database frame `index` (its latest copy).
    pub fn kept(&self, index: u32) -> Option<StoredFrame> {
        let (f, keys, key_bytes) = self
            .frames
            .iter()
            .rev()
            .find(|(f, _, _)| f.meta.index == index)?;
        Some(StoredFrame {
            aabb: f.aabb,
            sketch: f.sketch.hashes().to_vec(),
            keys: keys.clone(),
            key_bytes: *key_bytes,
        })
    }
}

impl<const K: usize> FrameStore<K> for MemStore<K> {
    fn save(&mut self, frame: &DbSnapshot<K>, keys: Option<&[u32]>) -> Option<(u32, bool)> {
        let base = frame.aabb.map(|a| a.min);
        let bytes = keys.map_or(0, |w| placedb::persist::keys::encoded_size(w).1 as u32);
        let keys: Option<Vec<u64>> = keys
            .zip(base)
            .map(|(words, base)| words.iter().map(|&w| key_of(base, w)).collect());
        let kept = keys.is_some();
        let bytes = if kept { bytes } else { 0 };
        let at = u32::try_from(self.frames.len()).ok()?;
        self.frames.push((*frame, keys, bytes));
        Some((at, kept))
    }

    fn load(&mut self, at: u32) -> Option<DbSnapshot<K>> {
        self.frames.get(at as usize).map(|(f, _, _)| *f)
    }

    fn intersect(&mut self, at: u32, keys: &[u64]) -> Option<(u32, u32)> {
        let (frame, stored, _) = self.frames.get(at as usize)?;
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
    first: u32,
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
            name: seq.depth_where(i),
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
            name: seq.depth_where(i),
            reason,
        })?;
    let mut ingest = Box::new(FrameIngest::<FV>::new());
    let index = first + i as u32;
    let meta = FrameMeta {
        index,
        timestamp: seq.frames[i].timestamp,
        pose,
    };
    ingest.begin(meta, index, scan).map_err(core_err)?;
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
    job: Job<'_, impl Seed>,
) -> Result<OnlineRun, ReplayError> {
    let Job {
        seq,
        earlier,
        sets,
        scan,
        cfg,
        rows_per_chunk,
        progress,
    } = job;
    let n = seq.frames.len();
    let mut store = MemStore::<K>::default();
    let first = match earlier {
        Some(earlier) => earlier.seed(sel, &mut store, scan, cfg)?,
        None => {
            sel.configure(scan, cfg)
                .map_err(|reason| ReplayError::Core { frame: 0, reason })?;
            0
        }
    };
    let base = first as usize;
    let core_err = |frame: usize| move |reason| ReplayError::Core { frame, reason };
    let mut decisions = vec![Decision::Pending; base + n];
    if let Some(earlier) = earlier {
        for (d, e) in decisions.iter_mut().zip(earlier.decisions()) {
            *d = e;
        }
    }
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
            |img, i| ingest(seq, sets, first, i, &scan, rows_per_chunk, img),
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
                    .map_err(core_err(base + start + k))?;
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
        .map_err(core_err(base + n))?;
    core_time += t.elapsed();
    let labels = decisions
        .iter()
        .enumerate()
        .map(|(i, d)| match *d {
            Decision::DominatedBy(k) | Decision::Uncovered(Some(k)) => k as usize,
            _ => i,
        })
        .collect();
    let database: Vec<DbRecord> = (0..sel.database_len())
        .filter_map(|i| sel.database_record(i, &mut store))
        .collect();
    let stored = database
        .iter()
        .filter_map(|r| store.kept(r.index))
        .collect();
    Ok(OnlineRun {
        decisions,
        labels,
        database,
        stored,
        status: sel.status(),
        read_time,
        core_time,
    })
}
