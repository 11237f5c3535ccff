//! The online dominating-set selector: frames arrive once, in order; the
//! selector keeps the database frames and a window of recent undecided frames,
//! and decides each frame when it leaves the window.
//!
//! Rule: a frame is covered as soon as some database frame overlaps it
//! (IoU > mu). When the oldest window frame must leave uncovered, the selector
//! takes the window frame that overlaps it and covers the most still-uncovered
//! window frames (ties: the latest frame, which reaches furthest into the
//! future). With a window of 1 this is exactly the paper's `in-order` rule; a
//! longer window lets a later, better-placed frame cover a run of frames.
//!
//! Overlaps are exact (merge of stored keys) while keys fit the key pool.
//! When the pool is full, the oldest database frames give up their exact keys
//! first (they are compared least, only on revisits), so the window stays
//! exact; a frame without keys is compared by its bottom-k sketch, and then
//! counts as overlapping only above `mu + sketch_margin`, so that sketch noise
//! rarely claims coverage the exact sets would deny. Every degradation is
//! counted in [`Status`].

use crate::camera::Pose;
use crate::frame::{FrameError, FrameIngest, FrameMeta, ScanConfig};
use crate::sketch::Sketch;
use crate::store::{Aabb, KeyPool, KeyRun};
use crate::voxel::iou;

mod restore;
pub use restore::{DbSnapshot, RestoreError};

/// Tuning of the selection rule.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SelectorConfig {
    /// Overlap threshold: frames overlap when IoU > mu.
    pub mu: f32,
    /// Frames held undecided (1 = the paper's in-order rule); at most the
    /// selector's window capacity.
    pub window: u16,
    /// Extra IoU a sketch estimate must show to count as an overlap.
    pub sketch_margin: f32,
}

impl Default for SelectorConfig {
    fn default() -> Self {
        SelectorConfig {
            mu: 0.3,
            window: u16::MAX,
            sketch_margin: 0.05,
        }
    }
}

/// The fate of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Decision {
    /// In the database; its own class.
    Taken,
    /// Overlaps database frame `k` (a frame index), which is its class.
    DominatedBy(u32),
    /// Still in the window; its final decision comes later.
    Pending,
    /// Degraded: no database frame overlaps it and the database is full; the
    /// nearest database frame (highest IoU), if any, is its class.
    Uncovered(Option<u32>),
}

/// A decision about one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct FrameDecision {
    /// Frame index.
    pub index: u32,
    /// What was decided.
    pub decision: Decision,
}

/// One database entry as exported.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DbRecord {
    /// Frame index.
    pub index: u32,
    /// Timestamp, seconds.
    pub timestamp: f64,
    /// Camera-to-world pose.
    pub pose: Pose,
    /// Voxels in the frame's set.
    pub voxels: u32,
}

/// Degradation flags in [`Status::flags`].
pub mod flags {
    /// Some frame had more voxels than the frame set holds; its set was truncated.
    pub const FRAME_VOXELS_FULL: u32 = 1 << 0;
    /// Some frame's keys did not fit the key pool; it is compared by sketch.
    pub const POOL_FULL: u32 = 1 << 1;
    /// Some frame could not be covered because the database is full.
    pub const DATABASE_FULL: u32 = 1 << 2;
    /// Some points were too far from the grid origin for a voxel key.
    pub const OUT_OF_RANGE: u32 = 1 << 3;
}

/// One capacity: what is used now, the most ever used, and the limit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub struct Usage {
    /// In use now.
    pub used: u32,
    /// High-water mark since the last reset.
    pub peak: u32,
    /// Capacity.
    pub limit: u32,
}

impl Usage {
    const ZERO: Usage = Usage {
        used: 0,
        peak: 0,
        limit: 0,
    };

    fn set(&mut self, used: usize) {
        self.used = used as u32;
        self.peak = self.peak.max(self.used);
    }
}

/// Counters and capacities, for the status message and the host report.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub struct Status {
    /// Frames ended so far.
    pub frames_seen: u32,
    /// Frames with a final decision.
    pub frames_decided: u32,
    /// Database entries.
    pub database: Usage,
    /// Key pool words.
    pub pool: Usage,
    /// Window frames.
    pub window: Usage,
    /// Distinct voxels in one frame.
    pub frame_voxels: Usage,
    /// Frames stored without exact keys, or that gave theirs up to a newer
    /// frame (compared by sketch).
    pub sketched_frames: u32,
    /// Frames whose voxel set was truncated.
    pub truncated_frames: u32,
    /// Frames decided [`Decision::Uncovered`].
    pub uncovered_frames: u32,
    /// Points dropped for an out-of-range voxel key.
    pub out_of_range_points: u32,
    /// Sampled pixels with a valid depth, over all frames.
    pub valid_pixels: u64,
    /// [`flags`] of every degradation seen.
    pub flags: u32,
}

impl Status {
    /// Nothing seen, nothing used (limits are filled in by [`Selector::status`]).
    pub const ZERO: Status = Status {
        frames_seen: 0,
        frames_decided: 0,
        database: Usage::ZERO,
        pool: Usage::ZERO,
        window: Usage::ZERO,
        frame_voxels: Usage::ZERO,
        sketched_frames: 0,
        truncated_frames: 0,
        uncovered_frames: 0,
        out_of_range_points: 0,
        valid_pixels: 0,
        flags: 0,
    };
}

/// A frame the selector keeps: its identity and what overlap tests need.
#[derive(Debug, Clone)]
struct Stored<const K: usize> {
    meta: FrameMeta,
    len: u32,
    aabb: Option<Aabb>,
    keys: Option<KeyRun>,
    sketch: Sketch<K>,
}

/// Best (IoU, frame index) so far; ties go to the lowest frame index.
type Best = Option<(f32, u32)>;

fn better(best: Best, iou: f32, index: u32) -> Best {
    match best {
        Some((b, i)) if b > iou || (b == iou && i < index) => best,
        _ => Some((iou, index)),
    }
}

/// A window frame and its relations to the other window frames.
#[derive(Debug, Clone)]
struct Slot<const W: usize, const K: usize> {
    frame: Stored<K>,
    taken: bool,
    /// Best overlapping database frame: set means covered.
    cover: Best,
    /// Best database frame, overlapping or not (for degraded labels).
    nearest: Best,
    /// Bit t: overlaps the frame in ring slot t.
    adjacent: u64,
    /// IoU with the frame in ring slot t (valid while both are live).
    iou: [f32; W],
}

/// A window ring entry. Not `Option<Slot>`: its `None` would be encoded in
/// a niche (a non-zero byte), and a selector whose fresh state is all zero
/// bytes lands in `.bss` instead of costing its size again in flash.
#[derive(Debug, Clone)]
struct RingEntry<const W: usize, const K: usize> {
    live: bool,
    slot: Slot<W, K>,
}

impl<const W: usize, const K: usize> RingEntry<W, K> {
    const EMPTY: Self = RingEntry {
        live: false,
        slot: Slot {
            frame: Stored {
                meta: FrameMeta {
                    index: 0,
                    timestamp: 0.0,
                    pose: Pose {
                        translation: [0.0; 3],
                        rotation: [0.0; 4],
                    },
                },
                len: 0,
                aabb: None,
                keys: None,
                sketch: Sketch::EMPTY,
            },
            taken: false,
            cover: None,
            nearest: None,
            adjacent: 0,
            iou: [0.0; W],
        },
    };

    fn get(&self) -> Option<&Slot<W, K>> {
        self.live.then_some(&self.slot)
    }

    fn get_mut(&mut self) -> Option<&mut Slot<W, K>> {
        self.live.then_some(&mut self.slot)
    }

    fn take(&mut self) -> Option<Slot<W, K>> {
        let entry = core::mem::replace(self, Self::EMPTY);
        entry.live.then_some(entry.slot)
    }
}

/// The online selector with its capacities: `FV` slots of the frame voxel set,
/// `POOL` key words, `DB` database frames, `W` window frames (at most 64),
/// sketches of `K` hashes.
#[derive(Debug)]
pub struct Selector<
    const FV: usize,
    const POOL: usize,
    const DB: usize,
    const W: usize,
    const K: usize,
> {
    /// `None` until configured; an all-zero `None` keeps a fresh selector in `.bss`.
    config: Option<(ScanConfig, SelectorConfig)>,
    ingest: FrameIngest<FV>,
    pool: KeyPool<POOL>,
    db: heapless::Vec<Stored<K>, DB>,
    ring: [RingEntry<W, K>; W],
    head: usize,
    len: usize,
    status: Status,
}

/// Why the selector refused a step; nothing stored changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum SelectError {
    /// No scan configuration yet.
    NotConfigured,
    /// Configuration refused while a frame is in progress.
    FrameInProgress,
    /// The scan or selector configuration is invalid.
    BadConfig,
    /// A frame step was refused.
    Frame(FrameError),
}

impl From<FrameError> for SelectError {
    fn from(e: FrameError) -> Self {
        SelectError::Frame(e)
    }
}

/// Where the window sits in the ring, and the slot the new frame will use.
#[derive(Debug, Clone, Copy)]
struct WindowView {
    head: usize,
    len: usize,
    slot: usize,
}

/// Measures the overlap of a new frame (exact `keys` in hand) with every
/// database frame and every open window frame, records the window relations
/// in both directions, and returns the new frame's window slot. Kept out of
/// line so instruction counts split voxelize / overlap / select.
#[inline(never)]
fn overlaps<const POOL: usize, const W: usize, const K: usize>(
    cfg: &SelectorConfig,
    pool: &KeyPool<POOL>,
    db: &[Stored<K>],
    ring: &mut [RingEntry<W, K>; W],
    window: WindowView,
    new: Stored<K>,
    keys: &[u64],
) -> Slot<W, K> {
    let (mu, margin) = (cfg.mu, cfg.sketch_margin);
    let overlap = |other: &Stored<K>| -> (f32, bool) {
        match (&new.aabb, &other.aabb) {
            (Some(a), Some(b)) if a.touches(b) => {}
            _ => return (0.0, false),
        }
        match &other.keys {
            Some(run) => {
                let x = iou(new.len, other.len, pool.intersect(run, keys));
                (x, x > mu)
            }
            None => {
                let x = new.sketch.jaccard(&other.sketch);
                (x, x > mu + margin)
            }
        }
    };
    let (mut cover, mut nearest): (Best, Best) = (None, None);
    for other in db {
        let (x, overlaps) = overlap(other);
        nearest = better(nearest, x, other.meta.index);
        if overlaps {
            cover = better(cover, x, other.meta.index);
        }
    }
    let s = window.slot;
    let mut slot = Slot {
        frame: new.clone(),
        taken: false,
        cover,
        nearest,
        adjacent: 0,
        iou: [0.0; W],
    };
    for k in 0..window.len {
        let t = (window.head + k) % W;
        if let Some(other) = ring[t].get_mut() {
            if other.taken {
                continue;
            }
            let (x, overlaps) = overlap(&other.frame);
            slot.iou[t] = x;
            other.iou[s] = x;
            if overlaps {
                slot.adjacent |= 1 << t;
                other.adjacent |= 1 << s;
            } else {
                other.adjacent &= !(1 << s);
            }
        }
    }
    slot
}

impl<const FV: usize, const POOL: usize, const DB: usize, const W: usize, const K: usize> Default
    for Selector<FV, POOL, DB, W, K>
{
    fn default() -> Self {
        Self::new()
    }
}

impl<const FV: usize, const POOL: usize, const DB: usize, const W: usize, const K: usize>
    Selector<FV, POOL, DB, W, K>
{
    const WINDOW_FITS_MASK: () = assert!(W >= 1 && W <= 64, "window capacity must be 1..=64");

    /// An unconfigured selector.
    pub const fn new() -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::WINDOW_FITS_MASK;
        Selector {
            config: None,
            ingest: FrameIngest::new(),
            pool: KeyPool::new(),
            db: heapless::Vec::new(),
            ring: [const { RingEntry::EMPTY }; W],
            head: 0,
            len: 0,
            status: Status::ZERO,
        }
    }

    /// Forgets everything: configuration, frames, database, counters.
    pub fn reset(&mut self) {
        self.config = None;
        self.ingest.abort();
        self.pool.clear();
        self.db.clear();
        self.ring.iter_mut().for_each(|s| *s = RingEntry::EMPTY);
        self.head = 0;
        self.len = 0;
        self.status = Status::default();
    }

    /// Sets the scan and selection parameters. Only between frames; a
    /// selector that already holds frames keeps them (the new parameters apply
    /// to the frames that follow), so reconfigure after [`Self::reset`] to
    /// start a new scan.
    pub fn configure(&mut self, scan: ScanConfig, cfg: SelectorConfig) -> Result<(), SelectError> {
        if self.ingest.current().is_some() {
            return Err(SelectError::FrameInProgress);
        }
        scan.validate().map_err(|_| SelectError::BadConfig)?;
        let margin_ok = (0.0..=1.0).contains(&cfg.sketch_margin);
        if !((0.0..1.0).contains(&cfg.mu) && margin_ok) || cfg.window == 0 {
            return Err(SelectError::BadConfig);
        }
        let cfg = SelectorConfig {
            window: cfg.window.min(W as u16),
            ..cfg
        };
        self.config = Some((scan, cfg));
        Ok(())
    }

    /// The scan configuration, once configured.
    pub fn scan_config(&self) -> Option<&ScanConfig> {
        self.config.as_ref().map(|(scan, _)| scan)
    }

    /// The selection parameters in force (window clamped to capacity).
    pub fn config(&self) -> Option<&SelectorConfig> {
        self.config.as_ref().map(|(_, cfg)| cfg)
    }

    /// Counters and capacities.
    pub fn status(&self) -> Status {
        // Limits are constants, filled in here so that the state itself
        // starts all zero (see `new`).
        let mut st = self.status;
        st.database.limit = DB as u32;
        st.pool.limit = POOL as u32;
        st.window.limit = W as u32;
        st.frame_voxels.limit = FrameIngest::<FV>::VOXEL_LIMIT as u32;
        st
    }

    /// Number of database entries.
    pub fn database_len(&self) -> usize {
        self.db.len()
    }

    /// Database entry `i` in the order frames were taken.
    pub fn database_record(&self, i: usize) -> Option<DbRecord> {
        self.db.get(i).map(|s| DbRecord {
            index: s.meta.index,
            timestamp: s.meta.timestamp,
            pose: s.meta.pose,
            voxels: s.len,
        })
    }

    /// The frame in progress, if any.
    pub fn current_frame(&self) -> Option<&FrameMeta> {
        self.ingest.current()
    }

    /// Sampled columns per row the next chunk must have.
    pub fn samples_per_row(&self) -> Option<u16> {
        self.ingest.samples_per_row()
    }

    /// Starts frame `meta`; its index must be the number of frames seen so far.
    pub fn begin_frame(&mut self, meta: FrameMeta) -> Result<(), SelectError> {
        let (scan, _) = self.config.as_ref().ok_or(SelectError::NotConfigured)?;
        self.ingest.begin(meta, self.status.frames_seen, scan)?;
        Ok(())
    }

    /// Feeds whole sampled rows of the frame in progress (see [`FrameIngest::push_rows`]).
    pub fn push_rows(&mut self, first_row: u16, data: &[u16]) -> Result<(), SelectError> {
        self.ingest.push_rows(first_row, data)?;
        Ok(())
    }

    /// Abandons the frame in progress, if any; nothing else changes.
    pub fn abort_frame(&mut self) {
        self.ingest.abort();
    }

    /// Ends the frame in progress and runs the selection step; `emit` receives
    /// the final decisions of frames leaving the window, in frame order, then
    /// `Pending` for this frame if it stays in the window.
    #[inline(never)]
    pub fn end_frame(&mut self, mut emit: impl FnMut(FrameDecision)) -> Result<(), SelectError> {
        // Checked before the frame is closed, so a refusal changes nothing.
        if self.ingest.current().is_none() {
            return Err(SelectError::Frame(FrameError::NoFrame));
        }
        let cfg = match &self.config {
            Some((_, cfg)) => *cfg,
            None => return Err(SelectError::NotConfigured),
        };
        let (meta, keys, stats) = self.ingest.end()?;
        let n = keys.len() as u32;
        let aabb = Aabb::of_sorted(keys);
        let sketch = Sketch::<K>::from_keys(keys.iter().copied());
        let s = (self.head + self.len) % W;
        let new = Stored {
            meta,
            len: n,
            aabb,
            keys: None,
            sketch,
        };
        let window = WindowView {
            head: self.head,
            len: self.len,
            slot: s,
        };
        let mut slot = overlaps(
            &cfg,
            &self.pool,
            &self.db,
            &mut self.ring,
            window,
            new,
            keys,
        );
        if let Some(a) = &aabb {
            slot.frame.keys = self.pool.store(keys, a);
            // Pool full: the oldest database frames give up their exact keys
            // (they are compared least, only on revisits) so that the frames
            // of the window, compared with every new frame, stay exact.
            let worth_it = a.fits_relative() && keys.len() <= POOL;
            let mut next = 0;
            while slot.frame.keys.is_none() && worth_it {
                let Some(i) = (next..self.db.len()).find(|&i| self.db[i].keys.is_some()) else {
                    break;
                };
                next = i + 1;
                if let Some(run) = self.db[i].keys.take() {
                    // A taken frame still in the window shares the run.
                    for e in self.ring.iter_mut().filter_map(RingEntry::get_mut) {
                        if e.frame.keys == Some(run) {
                            e.frame.keys = None;
                        }
                    }
                    release_run(&mut self.pool, &mut self.db, &mut self.ring, &run);
                    self.status.sketched_frames += 1;
                    self.status.flags |= flags::POOL_FULL;
                }
                slot.frame.keys = self.pool.store(keys, a);
            }
        }
        // Bookkeeping of this frame's degradations.
        let st = &mut self.status;
        if n > 0 && slot.frame.keys.is_none() {
            st.sketched_frames += 1;
            st.flags |= flags::POOL_FULL;
        }
        if stats.dropped > 0 {
            st.truncated_frames += 1;
            st.flags |= flags::FRAME_VOXELS_FULL;
        }
        if stats.out_of_range > 0 {
            st.out_of_range_points = st.out_of_range_points.saturating_add(stats.out_of_range);
            st.flags |= flags::OUT_OF_RANGE;
        }
        st.frame_voxels.set(n as usize);
        st.valid_pixels += u64::from(stats.valid_pixels);
        st.frames_seen += 1;
        self.ring[s] = RingEntry { live: true, slot };
        self.len += 1;
        // A frame restored into the database before its own decision was
        // stored (see `restore_database`) is streamed again: it takes its
        // place back, with exact keys now, and counts as taken.
        if let Some(i) = self.db.iter().rposition(|d| d.meta.index == meta.index) {
            if let Some(slot) = self.ring[s].get_mut() {
                slot.taken = true;
                self.db[i] = slot.frame.clone();
                self.status.sketched_frames = self.status.sketched_frames.saturating_sub(1);
                self.cover_from(s);
            }
        }
        self.note_usage();
        while self.len >= cfg.window as usize {
            self.decide_oldest(&mut emit);
        }
        if self.len > 0 && self.ring[s].live {
            emit(FrameDecision {
                index: meta.index,
                decision: Decision::Pending,
            });
        }
        Ok(())
    }

    /// Decides every frame still in the window (end of scan). The selector
    /// stays usable: later frames start with an empty window.
    #[inline(never)]
    pub fn finish(&mut self, mut emit: impl FnMut(FrameDecision)) -> Result<(), SelectError> {
        if self.ingest.current().is_some() {
            return Err(SelectError::FrameInProgress);
        }
        while self.len > 0 {
            self.decide_oldest(&mut emit);
        }
        Ok(())
    }

    fn note_usage(&mut self) {
        self.status.database.set(self.db.len());
        self.status.pool.set(self.pool.used());
        self.status.window.set(self.len);
    }

    /// Live, not-taken ring slots as a bit mask, and those among them not yet covered.
    fn masks(&self) -> (u64, u64) {
        let (mut open, mut uncovered) = (0u64, 0u64);
        for k in 0..self.len {
            let t = (self.head + k) % W;
            if let Some(slot) = self.ring[t].get() {
                if !slot.taken {
                    open |= 1 << t;
                    if slot.cover.is_none() {
                        uncovered |= 1 << t;
                    }
                }
            }
        }
        (open, uncovered)
    }

    /// Final decision for the oldest window frame, taking a frame if needed.
    #[inline(never)]
    fn decide_oldest(&mut self, emit: &mut impl FnMut(FrameDecision)) {
        let o = self.head;
        let Some(oldest) = self.ring[o].get() else {
            // Unreachable by construction; keep the window consistent anyway.
            self.head = (self.head + 1) % W;
            self.len = self.len.saturating_sub(1);
            return;
        };
        let index = oldest.frame.meta.index;
        let decision = if oldest.taken {
            Decision::Taken
        } else if let Some((_, k)) = oldest.cover {
            Decision::DominatedBy(k)
        } else {
            let (open, uncovered) = self.masks();
            let candidates = (oldest.adjacent | (1 << o)) & open;
            let mut best: Option<(u32, u32, usize)> = None; // (score, frame index, slot)
            for t in 0..W {
                if candidates & (1 << t) == 0 {
                    continue;
                }
                if let Some(c) = self.ring[t].get() {
                    let score = ((c.adjacent | (1 << t)) & uncovered).count_ones();
                    let idx = c.frame.meta.index;
                    if best.is_none_or(|(bs, bi, _)| score > bs || (score == bs && idx > bi)) {
                        best = Some((score, idx, t));
                    }
                }
            }
            match best {
                Some((_, idx, t)) if !self.db.is_full() => {
                    self.take(t);
                    if t == o {
                        Decision::Taken
                    } else {
                        Decision::DominatedBy(idx)
                    }
                }
                _ => {
                    self.status.uncovered_frames += 1;
                    self.status.flags |= flags::DATABASE_FULL;
                    Decision::Uncovered(oldest.nearest.map(|(_, k)| k))
                }
            }
        };
        emit(FrameDecision { index, decision });
        self.status.frames_decided += 1;
        if let Some(gone) = self.ring[o].take() {
            if let (false, Some(run)) = (gone.taken, gone.frame.keys) {
                self.release(&run);
            }
        }
        self.head = (self.head + 1) % W;
        self.len -= 1;
        self.note_usage();
    }

    /// Moves window slot `t` into the database and updates every window
    /// frame's cover and nearest database frame.
    fn take(&mut self, t: usize) {
        let Some(slot) = self.ring[t].get_mut() else {
            return;
        };
        if self.db.push(slot.frame.clone()).is_err() {
            return;
        }
        slot.taken = true;
        self.cover_from(t);
    }

    /// Updates every window frame's cover and nearest database frame with
    /// the taken window frame in slot `t`.
    fn cover_from(&mut self, t: usize) {
        let Some(slot) = self.ring[t].get() else {
            return;
        };
        let idx = slot.frame.meta.index;
        for k in 0..self.len {
            let j = (self.head + k) % W;
            if j == t {
                continue;
            }
            if let Some(other) = self.ring[j].get_mut() {
                if other.taken {
                    continue;
                }
                let x = other.iou[t];
                other.nearest = better(other.nearest, x, idx);
                if other.adjacent & (1 << t) != 0 {
                    other.cover = better(other.cover, x, idx);
                }
            }
        }
    }

    /// Frees a run of the key pool and shifts every run stored after it.
    fn release(&mut self, run: &KeyRun) {
        release_run(&mut self.pool, &mut self.db, &mut self.ring, run);
    }
}

/// Frees a run of the key pool and shifts every run stored after it.
fn release_run<const POOL: usize, const DB: usize, const W: usize, const K: usize>(
    pool: &mut KeyPool<POOL>,
    db: &mut heapless::Vec<Stored<K>, DB>,
    ring: &mut [RingEntry<W, K>; W],
    run: &KeyRun,
) {
    pool.free(run);
    let runs = db.iter_mut().map(|s| &mut s.keys).chain(
        ring.iter_mut()
            .filter_map(RingEntry::get_mut)
            .map(|s| &mut s.frame.keys),
    );
    for r in runs.flatten() {
        r.after_free(run);
    }
}
