//! A new frame measured against the database: the database frame that
//! covers it (IoU > mu), and the nearest one (highest IoU), the label of a
//! frame left uncovered by a full database. Both are the same whether a
//! database frame is resident in RAM or only in the store, so that neither
//! depends on what RAM holds: not on the profile's resident count, not on
//! whether the database was just restored from flash (which restores it
//! with nothing resident).
//!
//! Every database frame is measured the same way, from its index entry: its
//! box and voxel count bound its IoU with the new frame (the new frame's
//! voxels inside that box, over the union of the two counts). A frame whose
//! bound is at most mu cannot cover the new one. Reading a stored frame
//! back costs flash reads, so a first pass measures only the frames whose
//! bound is above mu (all that can cover). The nearest frame matters only
//! when the new frame will be decided [`super::Decision::Uncovered`], which
//! needs a database that can take no frame before that decision; then a
//! second pass measures the frames with a bound in (0, mu] too. That pass
//! costs, per such frame, one store read of every database frame whose box
//! holds some of its voxels and whose bound is at most mu (a database
//! record, plus its key chunks when the store kept its keys), and no
//! memory: the best frame so far is all it keeps. A frame with bound 0
//! shares no voxel with the new one (IoU 0), so it is never read.
//!
//! The measure: exact keys when the store keeps them (exact IoU, an overlap
//! above mu; read from RAM instead while the frame is resident with them),
//! else the bottom-k sketches (an overlap above mu + margin). Which of the
//! two is a fact of the frame, not of RAM: a frame the store keeps without
//! keys is compared by sketch even while RAM still holds its keys, because
//! a device restored from flash would hold none, and must decide as the
//! device that never lost power. Only a frame that was never stored (a
//! store that keeps nothing: no restore to agree with) is compared exactly
//! from RAM alone. Resident or not, a frame is measured only when its bound
//! allows it, so sketch noise above a proven bound never covers a frame.

use super::database::{DbEntry, DbIndex, FrameStore, NOWHERE};
use super::{better, Best, SelectorConfig, Stored};
use crate::key_pool::{Fresh, KeyPool};
use crate::voxel::iou;

/// The database as the overlap step reads it.
pub(super) struct DbView<'a, const DB: usize, const K: usize> {
    /// Database frames held whole in RAM.
    pub resident: &'a [Stored<K>],
    /// How many the resident set holds at most.
    pub resident_capacity: usize,
    /// Every database frame.
    pub index: &'a DbIndex<DB>,
    /// Where the database frames not resident are.
    pub store: &'a mut dyn FrameStore<K>,
}

/// What the database says about a new frame.
pub(super) struct Measured {
    /// The best database frame it overlaps (IoU > mu), if any.
    pub cover: Best,
    /// The database frame with the highest IoU; exact (over every database
    /// frame) whenever `cover` is `None` and the frame can end uncovered.
    pub nearest: Best,
    /// Stored frames that could not be read back.
    pub unreadable: u32,
    /// Some database frame was measured by sketch.
    pub sketched: bool,
}

/// Whether the frame being measured, `ahead` frames behind the oldest in
/// the window, can be decided uncovered: at its decision the database can
/// take no frame. Until then at most `ahead` frames are taken (one per
/// decision), so that needs an index with at most `ahead` free entries, or
/// a resident set that fills with frames the store does not hold (they
/// cannot leave RAM). Otherwise some frame can be taken at its decision.
fn may_end_uncovered<const DB: usize, const K: usize>(
    db: &DbView<'_, DB, K>,
    ahead: usize,
) -> bool {
    let free = DB.saturating_sub(db.index.len());
    let entries = db.index.entries().iter();
    let pinned = entries.filter(|e| e.resident && e.at == NOWHERE).count();
    free <= ahead || pinned.saturating_add(ahead) >= db.resident_capacity
}

/// Measures the new frame (`new`, its ascending packed keys in hand, and
/// the same staged in the pool when it had room) against every database
/// frame that can matter (see the module docs).
pub(super) fn against_database<const POOL: usize, const DB: usize, const K: usize>(
    cfg: &SelectorConfig,
    pool: &KeyPool<POOL>,
    mut db: DbView<'_, DB, K>,
    new: &Stored<K>,
    fresh: Fresh<'_>,
    ahead: usize,
) -> Measured {
    let mu = cfg.mu;
    // Only the database frames before the new one: a later frame is in the
    // database only when a restore brought it back ahead of its own
    // decision (see `Selector::restore_database`), and the uninterrupted
    // scan met it as a window frame when it arrived, after this one; so
    // does the resumed scan, when it is streamed again.
    let index = new.meta.index;
    let earlier = db.index.entries().partition_point(|e| e.index < index);
    let entries = db.index.entries().get(..earlier).unwrap_or(&[]);
    let mut m = Measured {
        cover: None,
        // The lowest frame index, in case nothing overlaps at all: `better`
        // keeps the highest IoU, ties to the lowest index.
        nearest: entries.first().map(|e| (0.0, e.index)),
        unreadable: 0,
        sketched: false,
    };
    let bound = |e: &DbEntry| match &new.aabb {
        Some(a) if e.len > 0 && e.bbox.touches(a) => {
            iou(new.len, u32::from(e.len), e.bbox.count_in(fresh.keys))
        }
        _ => 0.0,
    };
    // First pass: the frames that can cover; second: the rest that can be
    // nearest, when the frame may end uncovered.
    for pass in 0..2 {
        if pass == 1 && (m.cover.is_some() || !may_end_uncovered(&db, ahead)) {
            break;
        }
        for e in entries {
            let b = bound(e);
            let first = b > mu;
            let wanted = if pass == 0 { first } else { !first && b > 0.0 };
            if !wanted {
                continue;
            }
            match measure(cfg, pool, &mut db, e, new, fresh) {
                Some((x, overlaps, by_sketch)) => {
                    m.sketched |= by_sketch;
                    m.nearest = better(m.nearest, x, e.index);
                    if overlaps {
                        m.cover = better(m.cover, x, e.index);
                    }
                }
                None => m.unreadable = m.unreadable.saturating_add(1),
            }
        }
    }
    m
}

/// The IoU of the new frame with database frame `e`, whether it counts as
/// an overlap, and whether it was measured by sketch; `None` when the store
/// cannot read the frame back.
fn measure<const POOL: usize, const DB: usize, const K: usize>(
    cfg: &SelectorConfig,
    pool: &KeyPool<POOL>,
    db: &mut DbView<'_, DB, K>,
    e: &DbEntry,
    new: &Stored<K>,
    fresh: Fresh<'_>,
) -> Option<(f32, bool, bool)> {
    let exact = |x: f32| (x, x > cfg.mu, false);
    let sketched = |x: f32| (x, x > cfg.mu + cfg.sketch_margin, true);
    let resident = db.resident.iter().find(|r| r.meta.index == e.index);
    // Exact from RAM only where a restored device is exact too.
    let exact_in_ram = e.keyed() || e.at == NOWHERE;
    let in_ram = resident.filter(|_| exact_in_ram);
    if let Some((r, run)) = in_ram.and_then(|r| Some((r, r.keys.as_ref()?))) {
        let common = pool.intersect_fresh(run, r.aabb.as_ref(), fresh);
        return Some(exact(iou(new.len, r.len, common)));
    }
    if e.keyed() {
        if let Some((common, len)) = db.store.intersect(e.at, fresh.keys) {
            return Some(exact(iou(new.len, len, common)));
        }
    }
    if let Some(r) = resident {
        return Some(sketched(new.sketch.jaccard(&r.sketch)));
    }
    match db.store.load(e.at) {
        Some(f) if f.meta.index == e.index => Some(sketched(new.sketch.jaccard(&f.sketch))),
        _ => None,
    }
}
