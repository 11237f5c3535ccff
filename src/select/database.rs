//! The database index: what RAM keeps of every database frame once the frame
//! itself lives in a [`FrameStore`] (the flash log on a device).
//!
//! A building-sized scan has hundreds of database frames, and a full frame
//! (pose, box, sketch, exact keys) is hundreds of bytes: too many for the
//! RAM of a small board. RAM keeps instead, per database frame, a 24-byte
//! [`DbEntry`]: its index, voxel count, a coarse box, where the store put it
//! and whether the store holds its exact keys. The box
//! is what makes this an index: a new frame is compared only with the
//! database frames whose box touches its own, and those few are loaded from
//! the store, so the cost of a frame grows with the database frames *near*
//! it, not with the database.
//!
//! Entries are kept sorted by frame index, so the export walks them in frame
//! order without sorting, and a frame is found by binary search.

use crate::key_pool::Aabb;
use crate::voxel::VoxelKey;

use super::DbSnapshot;

/// Where a [`FrameStore`] put nothing: the frame is only in RAM.
pub const NOWHERE: u32 = u32::MAX;

/// Bytes of encoded exact keys (see [`crate::persist::keys`]) a scan may
/// give to the store: the keys of the first database frames, until this
/// much, go with them (frames after that are compared by sketch once they
/// leave RAM). 384 KiB leaves the rest of a 1 MiB log for the sketches of
/// ~1,000 database frames and the labels of ~20,000 frames. The selector
/// counts it, not the store, so that a replay decides as a board does.
pub const KEY_BUDGET: u32 = 384 * 1024;

/// Where database frames live once they leave RAM. A device backs it with its
/// flash log; the host replay with a `Vec`; [`NoStore`] keeps nothing (a
/// board without flash: its database is what RAM holds).
pub trait FrameStore<const K: usize> {
    /// Stores a database frame, with its exact keys when `keys` are given
    /// (the key pool's relative words, ascending, relative to the corner of
    /// its box); returns where (any value but [`NOWHERE`]) and whether the
    /// keys were kept, or `None` when nothing could be stored.
    fn save(&mut self, frame: &DbSnapshot<K>, keys: Option<&[u32]>) -> Option<(u32, bool)>;
    /// The frame saved at `at`; `None` when it cannot be read back.
    fn load(&mut self, at: u32) -> Option<DbSnapshot<K>>;
    /// For the frame saved at `at` with its keys: the voxels it shares with
    /// ascending packed `keys`, and its own voxel count; `None` when its
    /// keys were not kept or cannot be read.
    fn intersect(&mut self, at: u32, keys: &[u64]) -> Option<(u32, u32)>;
}

/// A store that keeps nothing: every database frame must stay in RAM.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoStore;

impl<const K: usize> FrameStore<K> for NoStore {
    fn save(&mut self, _: &DbSnapshot<K>, _: Option<&[u32]>) -> Option<(u32, bool)> {
        None
    }

    fn load(&mut self, _: u32) -> Option<DbSnapshot<K>> {
        None
    }

    fn intersect(&mut self, _: u32, _: &[u64]) -> Option<(u32, u32)> {
        None
    }
}

/// A box in voxel coordinates clamped to `i16` (±9.8 km at 0.3 m voxels).
/// Clamping keeps every pair of boxes that touch touching (it is monotone),
/// so the index never misses a candidate; far-away boxes may merely touch
/// where the exact ones do not, which costs a comparison, not a decision.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CoarseBox {
    min: [i16; 3],
    max: [i16; 3],
}

impl CoarseBox {
    fn clamp(v: i32) -> i16 {
        v.clamp(i16::MIN.into(), i16::MAX.into()) as i16
    }

    /// The clamped box of `aabb`.
    pub fn of(aabb: &Aabb) -> CoarseBox {
        CoarseBox {
            min: aabb.min.map(Self::clamp),
            max: aabb.max.map(Self::clamp),
        }
    }

    /// How many of `keys` (ascending packed voxel keys) lie in the box: at
    /// least as many as a set with this box shares with them, so with the
    /// set sizes a bound on the IoU (clamping only loosens it).
    pub fn count_in(&self, keys: &[u64]) -> u32 {
        let [x0, y0, z0] = self.min.map(i32::from);
        let [x1, y1, z1] = self.max.map(i32::from);
        // Packed keys order by x first: the keys with x in range are one run.
        let lo = VoxelKey::new(x0, VoxelKey::MIN, VoxelKey::MIN).to_bits();
        let hi = VoxelKey::new(x1, VoxelKey::MAX, VoxelKey::MAX).to_bits();
        let start = keys.partition_point(|&k| k < lo);
        let end = keys.partition_point(|&k| k <= hi);
        let run = keys.get(start..end.max(start)).unwrap_or(&[]);
        let inside = |k: &&u64| {
            VoxelKey::from_bits(**k).is_some_and(|key| {
                let (_, y, z) = key.coords();
                let (y, z) = (i32::from(Self::clamp(y)), i32::from(Self::clamp(z)));
                (y0..=y1).contains(&y) && (z0..=z1).contains(&z)
            })
        };
        run.iter().filter(inside).count() as u32
    }

    /// Whether the box may share a voxel with `aabb`.
    pub fn touches(&self, aabb: &Aabb) -> bool {
        let other = CoarseBox::of(aabb);
        (0..3).all(|a| match (self.min.get(a), self.max.get(a)) {
            (Some(&lo), Some(&hi)) => {
                other.min.get(a).is_some_and(|&m| m <= hi)
                    && other.max.get(a).is_some_and(|&m| lo <= m)
            }
            _ => false,
        })
    }
}

/// One database frame as RAM keeps it (24 bytes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DbEntry {
    /// Frame index.
    pub index: u32,
    /// Where the store keeps it; [`NOWHERE`] while only RAM has it.
    pub at: u32,
    /// Its box (meaningless when `len` is 0).
    pub bbox: CoarseBox,
    /// Voxels in its set, saturated at `u16::MAX` (0: empty, overlaps
    /// nothing); with the box, a bound on its IoU with a new frame.
    pub len: u16,
    /// It is held whole in RAM (the selector's resident set).
    pub resident: bool,
    /// The store kept its exact keys: it is compared exactly from there.
    pub keyed: bool,
}

/// Database entries sorted by frame index, at most `N`.
#[derive(Debug)]
pub struct DbIndex<const N: usize> {
    entries: heapless::Vec<DbEntry, N>,
}

impl<const N: usize> Default for DbIndex<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> DbIndex<N> {
    /// An empty index.
    pub const fn new() -> Self {
        DbIndex {
            entries: heapless::Vec::new(),
        }
    }

    /// Entries, ascending by frame index.
    pub fn entries(&self) -> &[DbEntry] {
        &self.entries
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether there is none.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Whether no entry can be added.
    pub fn is_full(&self) -> bool {
        self.entries.is_full()
    }

    /// Forgets every entry.
    pub fn clear(&mut self) {
        self.entries.clear();
    }

    /// Position of frame `index`, if it is in the database.
    pub fn find(&self, index: u32) -> Option<usize> {
        self.entries.binary_search_by_key(&index, |e| e.index).ok()
    }

    /// The entry of frame `index`.
    pub fn get_mut(&mut self, index: u32) -> Option<&mut DbEntry> {
        let i = self.find(index)?;
        self.entries.get_mut(i)
    }

    /// Removes the entry of frame `index`; it, or `None` when there is none.
    pub fn remove(&mut self, index: u32) -> Option<DbEntry> {
        let i = self.find(index)?;
        Some(self.entries.remove(i))
    }

    /// Adds an entry (its frame not yet in the index); `false` when the index
    /// is full or holds the frame already.
    pub fn add(&mut self, entry: DbEntry) -> bool {
        match self.entries.binary_search_by_key(&entry.index, |e| e.index) {
            Ok(_) => false,
            Err(pos) => self.entries.insert(pos, entry).is_ok(),
        }
    }
}

/// The entry of `frame`, stored at `at`, not resident.
pub fn entry_of<const K: usize>(frame: &DbSnapshot<K>, at: u32) -> DbEntry {
    let empty = CoarseBox {
        min: [0; 3],
        max: [0; 3],
    };
    DbEntry {
        index: frame.meta.index,
        at,
        bbox: frame.aabb.as_ref().map_or(empty, CoarseBox::of),
        len: if frame.aabb.is_some() {
            u16::try_from(frame.voxels).unwrap_or(u16::MAX).max(1)
        } else {
            0
        },
        resident: false,
        keyed: false,
    }
}
