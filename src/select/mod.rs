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
//!
//! The database itself lives in a [`FrameStore`] (the flash log on a
//! device): RAM keeps `R` *resident* frames whole (the latest taken, with
//! their sketches and, while the pool allows, exact keys) and a compact
//! [`database::DbIndex`] entry for each of up to `DB` database frames. A new
//! frame is compared with the resident frames and with the stored frames
//! whose box touches its own, loaded from the store one at a time. When the
//! resident set is full, its oldest frame that the store holds leaves RAM;
//! with [`NoStore`] none can, so the database is at most `R` frames.

use crate::camera::Pose;
use crate::frame::{FrameError, FrameIngest, FrameMeta, ScanConfig};
use crate::key_pool::{Aabb, Fresh, KeyPool, KeyRun};
use crate::sketch::Sketch;
use crate::voxel::iou;

mod against_db;
pub mod database;
mod restore;
pub use database::{FrameStore, NoStore};
pub use restore::{DbSnapshot, RestoreError};

use crate::persist::keys::{KEY_CHUNK_BYTES, MAX_KEY_CHUNKS};
use against_db::{against_database, DbView, Measured};
use database::{entry_of, DbIndex, KEY_BUDGET, NOWHERE};

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
    /// The key budget was spent: later frames keep no exact keys and are
    /// compared by sketch.
    pub const KEY_BUDGET_SPENT: u32 = 1 << 4;
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
    /// Database frames held whole in RAM.
    pub resident: Usage,
    /// Key pool words.
    pub pool: Usage,
    /// Window frames.
    pub window: Usage,
    /// Distinct voxels in one frame.
    pub frame_voxels: Usage,
    /// Frames whose exact keys the key pool could not hold on arrival (see
    /// [`Selector::end_frame_with`]'s window rule), or, without a store,
    /// database frames that gave theirs up to a newer frame: compared by
    /// sketch.
    pub sketched_frames: u32,
    /// Frames that arrived after the key budget was spent: their keys would
    /// not be kept in flash, so they keep none and are compared by sketch.
    pub unkeyed_frames: u32,
    /// Frames measured by sketch against at least one database or window
    /// frame: their coverage decision may rest on an estimate.
    pub sketch_compared_frames: u32,
    /// Frames whose voxel set was truncated.
    pub truncated_frames: u32,
    /// Frames decided [`Decision::Uncovered`].
    pub uncovered_frames: u32,
    /// Points dropped for an out-of-range voxel key.
    pub out_of_range_points: u32,
    /// Stored database frames that could not be read back (compared as
    /// overlapping nothing).
    pub unreadable_frames: u32,
    /// Bytes of exact keys given to the store (at most the key budget:
    /// [`Selector::key_budget`]).
    pub stored_key_bytes: u32,
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
        resident: Usage::ZERO,
        pool: Usage::ZERO,
        window: Usage::ZERO,
        frame_voxels: Usage::ZERO,
        sketched_frames: 0,
        unkeyed_frames: 0,
        sketch_compared_frames: 0,
        truncated_frames: 0,
        uncovered_frames: 0,
        out_of_range_points: 0,
        unreadable_frames: 0,
        stored_key_bytes: 0,
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
    /// Key pool words the window rule counts for it: its voxels when it
    /// got its exact keys on arrival, else 0.
    held: u32,
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
            held: 0,
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
/// `POOL` key words, `DB` database frames (index entries), `W` window frames
/// (at most 64), sketches of `K` hashes, `R` database frames resident in RAM.
#[derive(Debug)]
pub struct Selector<
    const FV: usize,
    const POOL: usize,
    const DB: usize,
    const W: usize,
    const K: usize,
    const R: usize = 64,
> {
    /// `None` until configured; an all-zero `None` keeps a fresh selector in `.bss`.
    config: Option<(ScanConfig, SelectorConfig)>,
    ingest: FrameIngest<FV>,
    pool: KeyPool<POOL>,
    /// Every database frame, by frame index.
    db: DbIndex<DB>,
    /// Database frames held whole, in the order they were taken.
    resident: heapless::Vec<Stored<K>, R>,
    ring: [RingEntry<W, K>; W],
    head: usize,
    len: usize,
    /// Key pool words of decided frames (their `Slot::held`), by frame
    /// index modulo `W`: the window rule counts the frames of the window's
    /// span that a restore brought back decided (see [`Self::window_voxels`]).
    recent: [u32; W],
    /// The first frame the window rule counts: the window emptied before it
    /// (a finish).
    recent_from: u32,
    /// The key budget when not [`KEY_BUDGET`] (see [`Self::set_key_budget`]);
    /// `None` keeps a fresh selector all zero bytes.
    key_budget: Option<core::num::NonZeroU32>,
    /// The key bytes (in [`database::KEY_UNIT`]s) of the database frames
    /// before a frame index: `(index, units)`, a running sum for the key
    /// budget rule (see [`Self::settled_key_bytes`]).
    settled: (u32, u32),
    status: Status,
}

/// Whether a frame taken gives the store its exact keys. This is the one
/// rule for when keys are stored, and the selector alone applies it: a
/// frame taken while deciding for a new frame (`end_frame_with`) offers the
/// keys it kept on arrival (the window rule decided that, the key budget
/// ([`Selector::key_budget`]) and the chunk limit included), and so does a
/// frame taken by `finish_with` (a later session is compared with it);
/// `finish_without_keys` offers none. A store keeps every key it is
/// offered: the host replay's store always can, and a device refuses the
/// frame (`StorageFull`) before its log could not
/// ([`Selector::key_chunks_next_frame`]), so a replay and a device decide
/// alike up to the last frame the device's log accepts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum KeyOffer {
    /// The keys the frame kept on arrival.
    Held,
    /// No keys.
    None,
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

/// Measures the overlap of a new frame (its exact keys in hand) with every
/// database frame near it and every open window frame, records the window
/// relations in both directions, and returns the new frame's window slot and
/// the number of stored frames that could not be read, and whether any
/// overlap was measured by sketch. The keys come staged
/// in the pool's free space too when it had room (the merges then compare
/// 32-bit words). Kept out of line so instruction counts split voxelize /
/// overlap / select.
#[inline(never)]
fn overlaps<const POOL: usize, const DB: usize, const W: usize, const K: usize>(
    cfg: &SelectorConfig,
    pool: &KeyPool<POOL>,
    db: DbView<'_, DB, K>,
    ring: &mut [RingEntry<W, K>; W],
    window: WindowView,
    new: Stored<K>,
    fresh: Fresh<'_>,
) -> (Slot<W, K>, u32, bool) {
    let (mu, margin) = (cfg.mu, cfg.sketch_margin);
    let touching = |a: &Option<Aabb>, b: &Option<Aabb>| match (a, b) {
        (Some(a), Some(b)) => a.touches(b),
        _ => false,
    };
    let mut sketched = false;
    let mut overlap = |other: &Stored<K>| -> (f32, bool) {
        if !touching(&new.aabb, &other.aabb) {
            return (0.0, false);
        }
        match &other.keys {
            Some(run) => {
                let common = pool.intersect_fresh(run, other.aabb.as_ref(), fresh);
                let x = iou(new.len, other.len, common);
                (x, x > mu)
            }
            None => {
                // As against a database frame: the estimate counts only
                // where the new frame's voxels in the other's box allow an
                // IoU above mu (sketch noise above a proven bound never
                // makes an overlap).
                sketched = true;
                let x = new.sketch.jaccard(&other.sketch);
                let allowed = || {
                    other.aabb.as_ref().is_some_and(|a| {
                        let inside = database::CoarseBox::of(a).count_in(fresh.keys);
                        iou(new.len, other.len, inside) > mu
                    })
                };
                (x, x > mu + margin && allowed())
            }
        }
    };
    let Measured {
        cover,
        nearest,
        unreadable,
        sketched: db_sketched,
    } = against_database(cfg, pool, db, &new, fresh, window.len);
    let s = window.slot;
    let mut slot = Slot {
        frame: new.clone(),
        taken: false,
        cover,
        nearest,
        adjacent: 0,
        iou: [0.0; W],
        held: 0,
    };
    for k in 0..window.len {
        let t = (window.head + k) % W;
        if let Some(other) = ring.get_mut(t).and_then(RingEntry::get_mut) {
            if other.taken {
                continue;
            }
            let (x, overlaps) = overlap(&other.frame);
            if let Some(v) = slot.iou.get_mut(t) {
                *v = x;
            }
            if let Some(v) = other.iou.get_mut(s) {
                *v = x;
            }
            if overlaps {
                slot.adjacent |= 1 << t;
                other.adjacent |= 1 << s;
            } else {
                other.adjacent &= !(1 << s);
            }
        }
    }
    (slot, unreadable, sketched || db_sketched)
}

impl<
        const FV: usize,
        const POOL: usize,
        const DB: usize,
        const W: usize,
        const K: usize,
        const R: usize,
    > Default for Selector<FV, POOL, DB, W, K, R>
{
    fn default() -> Self {
        Self::new()
    }
}

impl<
        const FV: usize,
        const POOL: usize,
        const DB: usize,
        const W: usize,
        const K: usize,
        const R: usize,
    > Selector<FV, POOL, DB, W, K, R>
{
    const WINDOW_FITS_MASK: () = assert!(W >= 1 && W <= 64, "window capacity must be 1..=64");
    const RESIDENT_HOLDS_A_FRAME: () = assert!(R >= 1, "at least one resident frame");

    /// An unconfigured selector.
    pub const fn new() -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::WINDOW_FITS_MASK;
        #[allow(clippy::let_unit_value)]
        let () = Self::RESIDENT_HOLDS_A_FRAME;
        Selector {
            config: None,
            ingest: FrameIngest::new(),
            pool: KeyPool::new(),
            db: DbIndex::new(),
            resident: heapless::Vec::new(),
            ring: [const { RingEntry::EMPTY }; W],
            head: 0,
            len: 0,
            recent: [0; W],
            recent_from: 0,
            key_budget: None,
            settled: (0, 0),
            status: Status::ZERO,
        }
    }

    /// Forgets everything: configuration, frames, database, counters.
    pub fn reset(&mut self) {
        self.config = None;
        self.ingest.abort();
        self.pool.clear();
        self.db.clear();
        self.resident.clear();
        self.ring.iter_mut().for_each(|s| *s = RingEntry::EMPTY);
        self.head = 0;
        self.len = 0;
        self.recent = [0; W];
        self.recent_from = 0;
        self.settled = (0, 0);
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
        st.resident.limit = R as u32;
        st.pool.limit = POOL as u32;
        st.window.limit = W as u32;
        st.frame_voxels.limit = FrameIngest::<FV>::VOXEL_LIMIT as u32;
        st
    }

    /// Most key chunks the store may be given while the next frame ends
    /// (see `KeyOffer`): each frame it decides may take one frame, and a
    /// frame taken gives the keys it kept on arrival, at most
    /// [`crate::persist::keys::MAX_KEY_CHUNKS`] chunks; the next frame may
    /// keep its keys too. A device reserves log room for them before it
    /// accepts the frame.
    pub fn key_chunks_next_frame(&self) -> usize {
        let window = self
            .config
            .as_ref()
            .map_or(1, |(_, c)| usize::from(c.window));
        // The frames that leave the window when the next frame ends.
        let takes = (self.len + 1).saturating_sub(window.saturating_sub(1));
        self.key_chunks_for(takes, 1)
    }

    /// The most key chunk records `takes` frames taken may write: only
    /// frames holding exact keys give any (the window's, and `arriving`
    /// more), each at most [`MAX_KEY_CHUNKS`].
    fn key_chunks_for(&self, takes: usize, arriving: usize) -> usize {
        let holding = (0..self.len)
            .filter_map(|k| self.ring.get((self.head + k) % W).and_then(RingEntry::get))
            .filter(|s| !s.taken && s.frame.keys.is_some())
            .count();
        takes
            .min(holding.saturating_add(arriving))
            .saturating_mul(MAX_KEY_CHUNKS)
    }

    /// The key pool words decided frame `index` got on arrival (its voxels
    /// when it kept its exact keys, else 0), while it is among the last `W`
    /// decided (every frame one step decides is): what a device stores with
    /// its decision, for the window rule of a restored scan.
    pub fn decided_held(&self, index: u32) -> Option<u32> {
        let decided = self.status.frames_decided;
        let recent = decided.saturating_sub(W as u32)..decided;
        if !recent.contains(&index) {
            return None;
        }
        self.recent.get(index as usize % W).copied()
    }

    /// Sets the bytes of exact keys a scan may give to the store (default
    /// [`KEY_BUDGET`]; a device sets [`database::key_budget_for_log`] of its
    /// log). A property of the store, kept by [`Self::reset`]; set it before
    /// a scan, and the same for a restore as for the scan it restores.
    pub fn set_key_budget(&mut self, bytes: u32) {
        self.key_budget = core::num::NonZeroU32::new(bytes.max(1));
    }

    /// The key budget in force (see [`Self::set_key_budget`]).
    pub fn key_budget(&self) -> u32 {
        self.key_budget
            .map_or(KEY_BUDGET, core::num::NonZeroU32::get)
    }

    /// Number of database entries.
    pub fn database_len(&self) -> usize {
        self.db.len()
    }

    /// The index entry of database frame `i` in frame order (its frame
    /// index and where the store keeps it).
    pub fn database_entry(&self, i: usize) -> Option<database::DbEntry> {
        self.db.entries().get(i).copied()
    }

    /// Database entry `i` in frame order, from RAM when it is resident, else
    /// from `store`; `None` past the end or when the store cannot read it.
    pub fn database_record(&self, i: usize, store: &mut dyn FrameStore<K>) -> Option<DbRecord> {
        let e = self.db.entries().get(i)?;
        let record = |meta: FrameMeta, voxels| DbRecord {
            index: meta.index,
            timestamp: meta.timestamp,
            pose: meta.pose,
            voxels,
        };
        match self.resident.iter().find(|r| r.meta.index == e.index) {
            Some(r) => Some(record(r.meta, r.len)),
            None => store
                .load(e.at)
                .filter(|f| f.meta.index == e.index)
                .map(|f| record(f.meta, f.voxels)),
        }
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

    /// [`Self::end_frame_with`] for a selector whose database stays in RAM
    /// ([`NoStore`]: at most `R` database frames).
    pub fn end_frame(&mut self, emit: impl FnMut(FrameDecision)) -> Result<(), SelectError> {
        self.end_frame_with(&mut NoStore, emit)
    }

    /// Ends the frame in progress and runs the selection step; `emit` receives
    /// the final decisions of frames leaving the window, in frame order, then
    /// `Pending` for this frame if it stays in the window. Frames taken go to
    /// `store`; stored frames near this one are read back from it.
    #[inline(never)]
    pub fn end_frame_with(
        &mut self,
        store: &mut dyn FrameStore<K>,
        mut emit: impl FnMut(FrameDecision),
    ) -> Result<(), SelectError> {
        // Checked before the frame is closed, so a refusal changes nothing.
        if self.ingest.current().is_none() {
            return Err(SelectError::Frame(FrameError::NoFrame));
        }
        let cfg = match &self.config {
            Some((_, cfg)) => *cfg,
            None => return Err(SelectError::NotConfigured),
        };
        // The window's span before this frame (see the window rule below).
        let (span, budget_spent) = match self.ingest.current().map(|m| m.index) {
            Some(index) => {
                let from = self.span_start(index, usize::from(cfg.window));
                let spent = self.settled_key_bytes(from) >= self.key_budget();
                (self.window_voxels(index, usize::from(cfg.window)), spent)
            }
            None => (0, false),
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
        let db = DbView {
            resident: &self.resident,
            resident_capacity: R,
            index: &self.db,
            store,
        };
        // The window rule: the frame keeps its exact keys in the pool when
        // they fit beside the keys the frames before it in the window's span
        // (the last `window` frames of the session) got on arrival, and the
        // key budget was not spent by the database frames before that span.
        // Both depend on the frames alone, never on what RAM held (resident
        // keys give way), so a device restored from flash keeps the keys of
        // the same frames as one that never lost power; and a frame that
        // keeps its keys gives them to the store when it is taken, so it is
        // compared exactly in the window and in the database alike.
        let admitted = !budget_spent && span.saturating_add(u64::from(n)) <= POOL as u64;
        // Encoded once for the store, and merged as words meanwhile.
        let staged = aabb.as_ref().and_then(|a| self.pool.stage(keys, a));
        let fresh = Fresh {
            keys,
            staged: staged.as_ref(),
        };
        let (mut slot, unreadable, sketch_compared) =
            overlaps(&cfg, &self.pool, db, &mut self.ring, window, new, fresh);
        if let (Some(a), true) = (&aabb, admitted) {
            // What `store` would give: staging refuses exactly what it refuses.
            slot.frame.keys = staged.and_then(|s| self.pool.commit(&s));
            // The resident database frames give up their keys until the frame
            // fits, oldest first. By the window rule it then does: the pool
            // holds, besides resident keys, only window frames' keys. A frame
            // the store keeps with its keys is still compared exactly from
            // there; one only in RAM (no store) is compared by sketch since.
            let worth_it = a.fits_relative() && keys.len() <= POOL;
            let mut next = 0;
            while slot.frame.keys.is_none() && worth_it {
                let Some(i) = (next..self.resident.len())
                    .find(|&i| self.resident.get(i).is_some_and(|r| r.keys.is_some()))
                else {
                    break;
                };
                next = i + 1;
                let Some(r) = self.resident.get_mut(i) else {
                    break;
                };
                let index = r.meta.index;
                if let Some(run) = r.keys.take() {
                    drop_keys(&mut self.pool, &mut self.resident, &mut self.ring, &run);
                    let ram_only = self.db.find(index).and_then(|j| self.db.entries().get(j));
                    if ram_only.is_some_and(|e| e.at == NOWHERE) {
                        let st = &mut self.status;
                        st.sketched_frames = st.sketched_frames.saturating_add(1);
                        st.flags |= flags::POOL_FULL;
                    }
                }
                slot.frame.keys = self.pool.store(keys, a);
            }
        }
        // Keys a store could not keep whole (more chunks than a frame may
        // write: a fact of the keys) are not kept here either.
        if let Some(run) = slot.frame.keys {
            let worst = n as usize * 5 > MAX_KEY_CHUNKS * (KEY_CHUNK_BYTES - 5);
            let words = self.pool.words(&run);
            if worst && crate::persist::keys::encoded_size(words).0 > MAX_KEY_CHUNKS {
                slot.frame.keys = None;
                self.release(&run);
            }
        }
        slot.held = if slot.frame.keys.is_some() { n } else { 0 };
        // Bookkeeping of this frame's degradations.
        let st = &mut self.status;
        if n > 0 && budget_spent {
            st.unkeyed_frames = st.unkeyed_frames.saturating_add(1);
            st.flags |= flags::KEY_BUDGET_SPENT;
        } else if n > 0 && slot.frame.keys.is_none() {
            st.sketched_frames = st.sketched_frames.saturating_add(1);
            st.flags |= flags::POOL_FULL;
        }
        if sketch_compared {
            st.sketch_compared_frames = st.sketch_compared_frames.saturating_add(1);
        }
        if stats.dropped > 0 {
            st.truncated_frames = st.truncated_frames.saturating_add(1);
            st.flags |= flags::FRAME_VOXELS_FULL;
        }
        if stats.out_of_range > 0 {
            st.out_of_range_points = st.out_of_range_points.saturating_add(stats.out_of_range);
            st.flags |= flags::OUT_OF_RANGE;
        }
        st.unreadable_frames = st.unreadable_frames.saturating_add(unreadable);
        st.frame_voxels.set(n as usize);
        st.valid_pixels = st
            .valid_pixels
            .saturating_add(u64::from(stats.valid_pixels));
        st.frames_seen = st.frames_seen.saturating_add(1);
        if let Some(entry) = self.ring.get_mut(s) {
            *entry = RingEntry { live: true, slot };
        }
        self.len += 1;
        // A frame restored into the database before its own decision was
        // stored (see `restore_database`) is streamed again: it takes its
        // place back, whole in RAM again, and counts as taken.
        if self.db.find(meta.index).is_some() {
            self.rejoin(s);
        }
        self.note_usage();
        while self.len >= cfg.window as usize {
            self.decide_oldest(store, KeyOffer::Held, &mut emit);
        }
        if self.len > 0 && self.ring.get(s).is_some_and(|e| e.live) {
            emit(FrameDecision {
                index: meta.index,
                decision: Decision::Pending,
            });
        }
        Ok(())
    }

    /// Ends a frame voxelized by another [`FrameIngest`] instead of through
    /// [`Self::begin_frame`] and [`Self::push_rows`], with the same result:
    /// a host replaying a recording voxelizes many frames in parallel and
    /// decides them here in order. `ingest` must hold a complete frame with
    /// the next frame index, begun with this selector's scan configuration;
    /// it is exchanged with the selector's own idle ingest, so it comes back
    /// empty, ready for another frame. Refused with nothing changed (and
    /// `ingest` untouched) otherwise, and while a frame is in progress here.
    pub fn end_frame_from(
        &mut self,
        ingest: &mut FrameIngest<FV>,
        store: &mut dyn FrameStore<K>,
        emit: impl FnMut(FrameDecision),
    ) -> Result<(), SelectError> {
        let (scan, _) = self.config.as_ref().ok_or(SelectError::NotConfigured)?;
        if self.ingest.current().is_some() {
            return Err(SelectError::FrameInProgress);
        }
        let meta = ingest
            .current()
            .ok_or(SelectError::Frame(FrameError::NoFrame))?;
        if meta.index != self.status.frames_seen {
            return Err(SelectError::Frame(FrameError::WrongIndex {
                expected: self.status.frames_seen,
            }));
        }
        if !ingest.begun_with(scan) {
            return Err(SelectError::BadConfig);
        }
        core::mem::swap(&mut self.ingest, ingest);
        let ended = self.end_frame_with(store, emit);
        if ended.is_err() {
            // Refused (rows missing): the frame is still open; hand it back.
            core::mem::swap(&mut self.ingest, ingest);
        }
        ended
    }

    /// [`Self::finish_with`] for a selector whose database stays in RAM.
    pub fn finish(&mut self, emit: impl FnMut(FrameDecision)) -> Result<(), SelectError> {
        self.finish_with(&mut NoStore, emit)
    }

    /// Decides every frame still in the window (end of scan). The selector
    /// stays usable: later frames start with an empty window. A frame taken
    /// now offers its exact keys as a frame taken mid-scan does (within the
    /// key budget): a later session is compared with it, and compared by
    /// sketch it could count a frame it covers as uncovered and store the
    /// same place again.
    pub fn finish_with(
        &mut self,
        store: &mut dyn FrameStore<K>,
        emit: impl FnMut(FrameDecision),
    ) -> Result<(), SelectError> {
        self.finish_offering(store, KeyOffer::Held, emit)
    }

    /// [`Self::finish_with`] for a store with no room left for keys (a
    /// device whose log is nearly full): the frames taken now keep none, and
    /// a later session compares them by sketch.
    pub fn finish_without_keys(
        &mut self,
        store: &mut dyn FrameStore<K>,
        emit: impl FnMut(FrameDecision),
    ) -> Result<(), SelectError> {
        self.finish_offering(store, KeyOffer::None, emit)
    }

    /// The most key chunk records [`Self::finish_with`] may write: those of
    /// every frame in the window that holds exact keys. A device checks its
    /// log has room for them, else it finishes [`Self::finish_without_keys`].
    pub fn key_chunks_finish(&self) -> usize {
        self.key_chunks_for(self.len, 0)
    }

    #[inline(never)]
    fn finish_offering(
        &mut self,
        store: &mut dyn FrameStore<K>,
        offer: KeyOffer,
        mut emit: impl FnMut(FrameDecision),
    ) -> Result<(), SelectError> {
        if self.ingest.current().is_some() {
            return Err(SelectError::FrameInProgress);
        }
        while self.len > 0 {
            self.decide_oldest(store, offer, &mut emit);
        }
        self.recent_from = self.status.frames_decided;
        Ok(())
    }

    /// The first frame of frame `index`'s window span: `index + 1 -
    /// window`, or the first frame after the last finish.
    fn span_start(&self, index: u32, window: usize) -> u32 {
        index
            .saturating_add(1)
            .saturating_sub(window as u32)
            .max(self.recent_from)
    }

    /// The key bytes (whole [`database::KEY_UNIT`]s) the store kept of the
    /// database frames before frame `from`: frames decided for good when
    /// a frame whose window span starts at `from` arrives, the same in a
    /// scan restored from flash as in one that never lost power (a frame
    /// taken later, or restored ahead of its decision, is not counted).
    fn settled_key_bytes(&mut self, from: u32) -> u32 {
        let (upto, units) = self.settled;
        let entries = self.db.entries();
        let (start, units) = if from < upto { (0, 0) } else { (upto, units) };
        let lo = entries.partition_point(|e| e.index < start);
        let hi = entries.partition_point(|e| e.index < from);
        let more: u32 = entries
            .get(lo..hi.max(lo))
            .unwrap_or(&[])
            .iter()
            .map(|e| u32::from(e.key_units))
            .sum();
        let units = units.saturating_add(more);
        self.settled = (from, units);
        units.saturating_mul(database::KEY_UNIT)
    }

    /// Key pool words the window rule counts before frame `index`: those
    /// the frames from `index + 1 - window` (or from the last finish) to
    /// `index - 1` got on arrival, in the window or, after a restore,
    /// decided already (their counts come back with their decisions).
    fn window_voxels(&self, index: u32, window: usize) -> u64 {
        let in_ring: u64 = (0..self.len)
            .filter_map(|k| self.ring.get((self.head + k) % W).and_then(RingEntry::get))
            .map(|s| u64::from(s.held))
            .sum();
        let lo = self.span_start(index, window);
        let decided = self.status.frames_decided.min(index);
        // At most `window - 1` frames (lo > index - window), all among the
        // last `W` decided.
        let restored: u64 = (lo..decided)
            .filter_map(|f| self.recent.get(f as usize % W))
            .map(|&v| u64::from(v))
            .sum();
        in_ring.saturating_add(restored)
    }

    fn note_usage(&mut self) {
        self.status.database.set(self.db.len());
        self.status.resident.set(self.resident.len());
        self.status.pool.set(self.pool.used());
        self.status.window.set(self.len);
    }

    /// Live, not-taken ring slots as a bit mask, and those among them not yet covered.
    fn masks(&self) -> (u64, u64) {
        let (mut open, mut uncovered) = (0u64, 0u64);
        for k in 0..self.len {
            let t = (self.head + k) % W;
            if let Some(slot) = self.ring.get(t).and_then(RingEntry::get) {
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

    /// Whether a frame can join the database now: the index has room, and
    /// so does the resident set, or one of its frames can leave RAM.
    fn can_take(&self) -> bool {
        !self.db.is_full() && (!self.resident.is_full() || self.evictable().is_some())
    }

    /// The oldest resident frame that the store holds.
    fn evictable(&self) -> Option<usize> {
        let stored = |index: u32| {
            self.db
                .find(index)
                .and_then(|i| self.db.entries().get(i))
                .is_some_and(|e| e.at != NOWHERE)
        };
        self.resident.iter().position(|r| stored(r.meta.index))
    }

    /// Makes room in the resident set: its oldest stored frame leaves RAM
    /// (and gives its exact keys back to the pool).
    fn evict(&mut self) -> bool {
        if !self.resident.is_full() {
            return true;
        }
        let Some(i) = self.evictable() else {
            return false;
        };
        let gone = self.resident.remove(i);
        if let Some(e) = self.db.get_mut(gone.meta.index) {
            e.resident = false;
        }
        if let Some(run) = gone.keys {
            self.drop_keys(&run);
        }
        true
    }

    /// Final decision for the oldest window frame, taking a frame if needed.
    #[inline(never)]
    fn decide_oldest(
        &mut self,
        store: &mut dyn FrameStore<K>,
        keys: KeyOffer,
        emit: &mut impl FnMut(FrameDecision),
    ) {
        let o = self.head;
        let Some(oldest) = self.ring.get(o).and_then(RingEntry::get) else {
            // Unreachable by construction; keep the window consistent anyway.
            self.head = (self.head + 1) % W;
            self.len = self.len.saturating_sub(1);
            return;
        };
        let index = oldest.frame.meta.index;
        let oldest_held = oldest.held;
        let decision = if oldest.taken {
            Decision::Taken
        } else if let Some((_, k)) = oldest.cover {
            Decision::DominatedBy(k)
        } else {
            let nearest = oldest.nearest;
            let (open, uncovered) = self.masks();
            let candidates = (oldest.adjacent | (1 << o)) & open;
            let mut best: Option<(u32, u32, usize)> = None; // (score, frame index, slot)
            for t in 0..W {
                if candidates & (1 << t) == 0 {
                    continue;
                }
                if let Some(c) = self.ring.get(t).and_then(RingEntry::get) {
                    let score = ((c.adjacent | (1 << t)) & uncovered).count_ones();
                    let idx = c.frame.meta.index;
                    if best.is_none_or(|(bs, bi, _)| score > bs || (score == bs && idx > bi)) {
                        best = Some((score, idx, t));
                    }
                }
            }
            match best {
                Some((_, idx, t)) if self.can_take() && self.take(t, store, keys) => {
                    if t == o {
                        Decision::Taken
                    } else {
                        Decision::DominatedBy(idx)
                    }
                }
                _ => {
                    self.status.uncovered_frames = self.status.uncovered_frames.saturating_add(1);
                    self.status.flags |= flags::DATABASE_FULL;
                    Decision::Uncovered(nearest.map(|(_, k)| k))
                }
            }
        };
        emit(FrameDecision { index, decision });
        if let Some(v) = self.recent.get_mut(index as usize % W) {
            *v = oldest_held;
        }
        self.status.frames_decided = self.status.frames_decided.saturating_add(1);
        if let Some(gone) = self.ring.get_mut(o).and_then(RingEntry::take) {
            if let (false, Some(run)) = (gone.taken, gone.frame.keys) {
                self.release(&run);
            }
        }
        self.head = (self.head + 1) % W;
        self.len = self.len.saturating_sub(1);
        self.note_usage();
    }

    /// Moves window slot `t` into the database (the store and the resident
    /// set) and updates every window frame's cover and nearest database
    /// frame; `false` (nothing changed) when there is no room.
    fn take(&mut self, t: usize, store: &mut dyn FrameStore<K>, offer: KeyOffer) -> bool {
        let Some(frame) = self.ring.get(t).and_then(RingEntry::get).map(|s| &s.frame) else {
            return false;
        };
        if self.db.is_full() {
            return false;
        }
        let snapshot = DbSnapshot {
            meta: frame.meta,
            voxels: frame.len,
            aabb: frame.aabb,
            sketch: frame.sketch,
        };
        if !self.evict() {
            return false;
        }
        // Evicting may have moved the pool: read the frame's run afterwards.
        let Some(mut frame) = self
            .ring
            .get(t)
            .and_then(RingEntry::get)
            .map(|s| s.frame.clone())
        else {
            return false;
        };
        // Its exact keys go with it when it kept them on arrival (the one
        // rule: see `KeyOffer`).
        let words = frame.keys.as_ref().map(|run| self.pool.words(run));
        let (chunks, bytes) = words.map_or((0, 0), crate::persist::keys::encoded_size);
        let offer = words.filter(|_| offer == KeyOffer::Held && chunks <= MAX_KEY_CHUNKS);
        let (at, keyed) = store.save(&snapshot, offer).unwrap_or((NOWHERE, false));
        if keyed {
            let st = &mut self.status;
            st.stored_key_bytes = st.stored_key_bytes.saturating_add(bytes as u32);
        }
        if at != NOWHERE && !keyed {
            // Stored without its keys (a finish without room for them):
            // compared by sketch from now on, resident or not (a restore
            // brings it back without them), so its keys in the pool serve
            // nothing.
            if let Some(run) = frame.keys.take() {
                self.drop_keys(&run);
            }
        }
        let entry = database::DbEntry {
            resident: true,
            key_units: database::key_units(keyed, bytes as u32),
            ..entry_of(&snapshot, at)
        };
        if !self.db.add(entry) || self.resident.push(frame).is_err() {
            return false;
        }
        if let Some(slot) = self.ring.get_mut(t).and_then(RingEntry::get_mut) {
            slot.taken = true;
        }
        self.cover_from(t);
        true
    }

    /// The window frame in slot `s` is a database frame restored from the
    /// store before its own decision was: it counts as taken again and, room
    /// permitting, is resident again (with its exact keys).
    fn rejoin(&mut self, s: usize) {
        let Some(slot) = self.ring.get_mut(s).and_then(RingEntry::get_mut) else {
            return;
        };
        slot.taken = true;
        let mut frame = slot.frame.clone();
        let index = frame.meta.index;
        let keyed = self
            .db
            .find(index)
            .and_then(|i| self.db.entries().get(i))
            .is_some_and(|e| e.keyed() || e.at == NOWHERE);
        if !keyed {
            // The store holds it without keys: compared by sketch (as in
            // `take`), so the copy in RAM keeps none either.
            frame.keys = None;
        }
        let already = self.resident.iter().any(|r| r.meta.index == index);
        let resident = !already && self.evict() && self.resident.push(frame).is_ok();
        if let Some(e) = self.db.get_mut(index) {
            e.resident = resident || already;
        }
        if !resident || !keyed {
            // Not resident through this copy (no room, or resident already),
            // or resident without keys: its keys go back to the pool, the
            // store (or RAM) has the rest.
            let keys = self.ring.get_mut(s).and_then(RingEntry::get_mut);
            if let Some(run) = keys.and_then(|s| s.frame.keys.take()) {
                self.release(&run);
            }
        }
        self.cover_from(s);
    }

    /// Updates every window frame's cover and nearest database frame with
    /// the taken window frame in slot `t`.
    fn cover_from(&mut self, t: usize) {
        let Some(slot) = self.ring.get(t).and_then(RingEntry::get) else {
            return;
        };
        let idx = slot.frame.meta.index;
        for k in 0..self.len {
            let j = (self.head + k) % W;
            if j == t {
                continue;
            }
            if let Some(other) = self.ring.get_mut(j).and_then(RingEntry::get_mut) {
                if other.taken {
                    continue;
                }
                let x = other.iou.get(t).copied().unwrap_or(0.0);
                other.nearest = better(other.nearest, x, idx);
                if other.adjacent & (1 << t) != 0 {
                    other.cover = better(other.cover, x, idx);
                }
            }
        }
    }

    /// A database frame gives up its exact keys (see [`drop_keys`]).
    fn drop_keys(&mut self, run: &KeyRun) {
        drop_keys(&mut self.pool, &mut self.resident, &mut self.ring, run);
    }

    /// Frees a run of the key pool (see [`release`]).
    fn release(&mut self, run: &KeyRun) {
        release(&mut self.pool, &mut self.resident, &mut self.ring, run);
    }
}

/// A database frame gives up its exact keys: every copy of the run in the
/// window (a taken frame still there shares it) forgets it, and the pool
/// frees it. The caller has taken it out of the resident copy.
fn drop_keys<const POOL: usize, const R: usize, const W: usize, const K: usize>(
    pool: &mut KeyPool<POOL>,
    resident: &mut heapless::Vec<Stored<K>, R>,
    ring: &mut [RingEntry<W, K>; W],
    run: &KeyRun,
) {
    for e in ring.iter_mut().filter_map(RingEntry::get_mut) {
        if e.frame.keys == Some(*run) {
            e.frame.keys = None;
        }
    }
    release(pool, resident, ring, run);
}

/// Frees a run of the key pool and shifts every run stored after it.
fn release<const POOL: usize, const R: usize, const W: usize, const K: usize>(
    pool: &mut KeyPool<POOL>,
    resident: &mut heapless::Vec<Stored<K>, R>,
    ring: &mut [RingEntry<W, K>; W],
    run: &KeyRun,
) {
    pool.free(run);
    let runs = resident.iter_mut().map(|s| &mut s.keys).chain(
        ring.iter_mut()
            .filter_map(RingEntry::get_mut)
            .map(|s| &mut s.frame.keys),
    );
    for r in runs.flatten() {
        r.after_free(run);
    }
}
