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
/// much, go with them (frames after that are kept without keys and compared
/// by sketch, resident or not: see [`super::Selector`]). 384 KiB leaves the
/// rest of a 1 MiB log for the sketches of ~1,000 database frames and the
/// labels of ~20,000 frames. The selector counts it, not the store, so that
/// a replay decides as a board does.
pub const KEY_BUDGET: u32 = 384 * 1024;

/// The key budget of a store of `log_bytes` (a device's flash log; see
/// [`crate::persist::Journal::usage`]): [`KEY_BUDGET`], or two fifths of
/// the log when that is less, so that a small log keeps room for the
/// labels and sketches. Both boards' logs (1 MiB, of which 1,020 KiB hold
/// records) give [`KEY_BUDGET`], as the host's replay counts.
pub const fn key_budget_for_log(log_bytes: u32) -> u32 {
    let share = log_bytes / 5 * 2;
    if share < KEY_BUDGET {
        share
    } else {
        KEY_BUDGET
    }
}

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

/// A frame's box in 12 bytes, exact over the whole voxel key range
/// (±2^20 voxels per axis: ±314 km at 0.3 m voxels, ±52 km at 0.05 m).
///
/// Per axis one word: the low corner in the key's 21 bits, and the extent
/// in the 11 bits above it. An extent of [`CoarseBox::OPEN`] or more is
/// stored as "to the end of the key range": such a box is looser than the
/// exact one, never tighter, so the index never skips a frame whose set may
/// share a voxel with a new frame; it may merely compare one more frame.
/// (An earlier entry clamped the corners to `i16`, ±9.8 km at 0.3 m, and
/// its key lookup then missed every frame beyond that on x.)
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CoarseBox {
    axes: [u32; 3],
}

impl CoarseBox {
    /// Bits of the low corner: a voxel key's bits per axis.
    const MIN_BITS: u32 = 21;
    /// The stored extent meaning "to [`VoxelKey::MAX`]" (the 11 high bits all set).
    pub const OPEN: u32 = (1 << (32 - Self::MIN_BITS)) - 1;

    /// The box of `aabb` (its corners in the key range, as every box of
    /// voxel keys is; a corner outside it is clamped into it).
    pub fn of(aabb: &Aabb) -> CoarseBox {
        let bias = 1i64 << (Self::MIN_BITS - 1);
        let mut axes = [0u32; 3];
        for (word, (&lo, &hi)) in axes.iter_mut().zip(aabb.min.iter().zip(&aabb.max)) {
            let lo = lo.clamp(VoxelKey::MIN, VoxelKey::MAX);
            let extent = (i64::from(hi) - i64::from(lo)).clamp(0, i64::from(Self::OPEN));
            *word = ((extent as u32) << Self::MIN_BITS) | (i64::from(lo) + bias) as u32;
        }
        CoarseBox { axes }
    }

    /// Low and high corner on each axis (the high one [`VoxelKey::MAX`]
    /// when the extent was too large to store).
    pub fn corners(&self) -> ([i32; 3], [i32; 3]) {
        let bias = 1i32 << (Self::MIN_BITS - 1);
        let (mut lo, mut hi) = ([0i32; 3], [0i32; 3]);
        for ((&word, l), h) in self.axes.iter().zip(&mut lo).zip(&mut hi) {
            let min = (word & ((1 << Self::MIN_BITS) - 1)) as i32 - bias;
            let extent = word >> Self::MIN_BITS;
            *l = min;
            *h = if extent >= Self::OPEN {
                VoxelKey::MAX
            } else {
                min.saturating_add(extent as i32).min(VoxelKey::MAX)
            };
        }
        (lo, hi)
    }

    /// How many of `keys` (ascending packed voxel keys) lie in the box: at
    /// least as many as a set with this box shares with them, so with the
    /// set sizes a bound on the IoU.
    pub fn count_in(&self, keys: &[u64]) -> u32 {
        let ([x0, y0, z0], [x1, y1, z1]) = self.corners();
        // Packed keys order by x first: the keys with x in range are one run.
        let lo = VoxelKey::new(x0, VoxelKey::MIN, VoxelKey::MIN).to_bits();
        let hi = VoxelKey::new(x1, VoxelKey::MAX, VoxelKey::MAX).to_bits();
        let start = keys.partition_point(|&k| k < lo);
        let end = keys.partition_point(|&k| k <= hi);
        let run = keys.get(start..end.max(start)).unwrap_or(&[]);
        let inside = |k: &&u64| {
            VoxelKey::from_bits(**k).is_some_and(|key| {
                let (_, y, z) = key.coords();
                (y0..=y1).contains(&y) && (z0..=z1).contains(&z)
            })
        };
        run.iter().filter(inside).count() as u32
    }

    /// Whether the box may share a voxel with `aabb`.
    pub fn touches(&self, aabb: &Aabb) -> bool {
        let (lo, hi) = self.corners();
        let other = CoarseBox::of(aabb).corners();
        (0..3).all(
            |a| match (lo.get(a), hi.get(a), other.0.get(a), other.1.get(a)) {
                (Some(lo), Some(hi), Some(other_lo), Some(other_hi)) => {
                    other_lo <= hi && lo <= other_hi
                }
                _ => false,
            },
        )
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
    /// The bytes of exact keys the store kept of it, in units of
    /// [`KEY_UNIT`] bytes, rounded up (0: none kept; it is compared by
    /// sketch). What the key budget counts of it.
    pub key_units: u8,
}

/// The unit of [`DbEntry::key_units`]: a frame's keys take at most
/// `MAX_KEY_CHUNKS` chunks of `KEY_CHUNK_BYTES` (5,888 bytes, 92 units).
pub const KEY_UNIT: u32 = 64;

impl DbEntry {
    /// The store kept its exact keys: it is compared exactly from there.
    pub fn keyed(&self) -> bool {
        self.key_units > 0
    }
}

/// [`DbEntry::key_units`] of keys that took `bytes` (at least 1 when the
/// keys were kept, whatever their size).
pub fn key_units(keyed: bool, bytes: u32) -> u8 {
    if !keyed {
        return 0;
    }
    u8::try_from(bytes.div_ceil(KEY_UNIT))
        .unwrap_or(u8::MAX)
        .max(1)
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
    let empty = CoarseBox { axes: [0; 3] };
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
        key_units: 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    extern crate std;
    use std::vec::Vec;

    /// Ascending packed keys of `coords`, and their box.
    fn set(coords: impl Iterator<Item = (i32, i32, i32)>) -> (Vec<u64>, Aabb) {
        let mut keys: Vec<u64> = coords
            .map(|(x, y, z)| VoxelKey::new(x, y, z).to_bits())
            .collect();
        keys.sort_unstable();
        keys.dedup();
        let aabb = Aabb::of_sorted(&keys).unwrap();
        (keys, aabb)
    }

    /// Corners where the old `i16` box broke (its edges and past them),
    /// and the edges of the key range, on every axis.
    const CORNERS: [i32; 9] = [
        0,
        32_700,
        32_767,
        32_768,
        -32_769,
        40_000,
        -40_000,
        VoxelKey::MAX - 20,
        VoxelKey::MIN,
    ];

    #[test]
    fn the_box_and_its_count_are_exact_over_the_whole_key_range() {
        for axis in 0..3 {
            for &c in &CORNERS {
                // A 10 x 4 x 3 block with its low corner at `c` on `axis`.
                let at = |i: i32, j: i32, k: i32| {
                    let mut p = [i, j + 5, k + 2];
                    p[axis] += c;
                    (p[0], p[1], p[2])
                };
                let (keys, aabb) = set((0..10)
                    .flat_map(|i| (0..4).flat_map(move |j| (0..3).map(move |k| at(i, j, k)))));
                let b = CoarseBox::of(&aabb);
                assert_eq!(b.corners(), (aabb.min, aabb.max), "axis {axis} at {c}");
                assert_eq!(b.count_in(&keys), 120, "axis {axis} at {c}");
                assert!(b.touches(&aabb), "axis {axis} at {c}");
                // One voxel past the box on the axis: not inside, not touching.
                let mut past = aabb;
                past.min[axis] = aabb.max[axis].saturating_add(1);
                past.max[axis] = past.min[axis];
                if aabb.max[axis] < VoxelKey::MAX {
                    assert!(!b.touches(&past), "axis {axis} at {c}");
                    let mut p = [aabb.min[0], aabb.min[1], aabb.min[2]];
                    p[axis] = past.min[axis];
                    let outside = [VoxelKey::new(p[0], p[1], p[2]).to_bits()];
                    assert_eq!(b.count_in(&outside), 0, "axis {axis} at {c}");
                }
            }
        }
    }

    #[test]
    fn a_box_too_long_to_store_reaches_the_end_of_the_key_range() {
        // Two voxels 5,000 apart on y: more than the 11-bit extent holds.
        let (keys, aabb) = set([(3, -2_000, 1), (3, 3_000, 1)].into_iter());
        let b = CoarseBox::of(&aabb);
        let (lo, hi) = b.corners();
        assert_eq!((lo, hi[1]), (aabb.min, VoxelKey::MAX));
        assert_eq!(hi[0], 3);
        assert_eq!(b.count_in(&keys), 2);
        let far = set([(3, VoxelKey::MAX, 1)].into_iter());
        assert!(b.touches(&far.1), "looser, never tighter");
        // The longest extent stored exactly.
        let (_, aabb) = set([(0, 0, 0), (CoarseBox::OPEN as i32 - 1, 0, 0)].into_iter());
        assert_eq!(CoarseBox::of(&aabb).corners(), (aabb.min, aabb.max));
    }

    #[test]
    fn an_entry_is_24_bytes() {
        assert_eq!(core::mem::size_of::<DbEntry>(), 24);
    }
}
