//! The key pool: exact voxel keys of the frames the selector keeps, packed
//! into one fixed array of `u32` words.
//!
//! A frame's keys all lie within a few dozen voxels of its camera, so each key
//! is stored relative to the frame's bounding-box corner in 32 bits (x 11, y 11,
//! z 10 bits), half the size of a packed absolute key. The relative word
//! preserves the `(x, y, z)` order, so stored runs stay sorted and two runs
//! (or a run and a fresh frame) intersect by a plain merge. Freed runs are
//! compacted away at once, so the pool never fragments: the price is a
//! `copy_within` per freed frame, which is cheap next to voxelizing it.

use crate::voxel::VoxelKey;

const DX_BITS: u32 = 11;
const DY_BITS: u32 = 11;
const DZ_BITS: u32 = 10;

/// Axis-aligned bounding box of a voxel set, inclusive, in voxel coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Aabb {
    /// Smallest x, y, z.
    pub min: [i32; 3],
    /// Largest x, y, z.
    pub max: [i32; 3],
}

impl Aabb {
    /// Box of ascending packed keys; `None` for an empty set.
    #[inline(never)]
    pub fn of_sorted(keys: &[u64]) -> Option<Aabb> {
        let first = VoxelKey::from_bits(*keys.first()?)?.coords();
        let mut b = Aabb {
            min: [first.0, first.1, first.2],
            max: [first.0, first.1, first.2],
        };
        for &k in keys {
            if let Some(key) = VoxelKey::from_bits(k) {
                let (x, y, z) = key.coords();
                let axes = b.min.iter_mut().zip(b.max.iter_mut());
                for ((lo, hi), c) in axes.zip([x, y, z]) {
                    *lo = (*lo).min(c);
                    *hi = (*hi).max(c);
                }
            }
        }
        Some(b)
    }

    /// Whether the boxes share at least one voxel: sets whose boxes do not
    /// cannot intersect, which skips most comparisons in a large building.
    pub fn touches(&self, other: &Aabb) -> bool {
        let mine = self.min.into_iter().zip(self.max);
        let theirs = other.min.into_iter().zip(other.max);
        mine.zip(theirs)
            .all(|((lo, hi), (other_lo, other_hi))| lo <= other_hi && other_lo <= hi)
    }

    /// Whether every key of the box fits the relative 32-bit encoding.
    pub fn fits_relative(&self) -> bool {
        let span = |lo: i32, hi: i32| (hi as i64 - lo as i64) as u64;
        let ([x0, y0, z0], [x1, y1, z1]) = (self.min, self.max);
        span(x0, x1) < (1 << DX_BITS)
            && span(y0, y1) < (1 << DY_BITS)
            && span(z0, z1) < (1 << DZ_BITS)
    }
}

/// Where one frame's keys live in the pool.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KeyRun {
    /// First word.
    pub offset: u32,
    /// Number of keys.
    pub len: u32,
    /// Corner the words are relative to.
    pub base: [i32; 3],
}

/// Fixed array of relative key words, used from the front.
#[derive(Debug, Clone)]
pub struct KeyPool<const N: usize> {
    words: [u32; N],
    used: usize,
}

impl<const N: usize> Default for KeyPool<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> KeyPool<N> {
    /// An empty pool.
    pub const fn new() -> Self {
        KeyPool {
            words: [0; N],
            used: 0,
        }
    }

    /// Words in use.
    pub fn used(&self) -> usize {
        self.used
    }

    /// Capacity in words (keys).
    pub const fn capacity(&self) -> usize {
        N
    }

    /// Empties the pool.
    pub fn clear(&mut self) {
        self.used = 0;
    }

    /// Stores ascending keys whose box is `aabb`; `None` (and nothing stored)
    /// when they do not fit the free space or the relative encoding.
    #[inline(never)]
    pub fn store(&mut self, keys: &[u64], aabb: &Aabb) -> Option<KeyRun> {
        if !aabb.fits_relative() || keys.len() > N - self.used {
            return None;
        }
        let base = aabb.min;
        let start = self.used;
        // In range by the check above; `?` keeps that a checked fact.
        let run = self.words.get_mut(start..start + keys.len())?;
        for (slot, &k) in run.iter_mut().zip(keys) {
            let (x, y, z) = VoxelKey::from_bits(k)?.coords();
            let (dx, dy, dz) = (
                (x - base[0]) as u32,
                (y - base[1]) as u32,
                (z - base[2]) as u32,
            );
            *slot = (dx << (DY_BITS + DZ_BITS)) | (dy << DZ_BITS) | dz;
        }
        self.used += keys.len();
        Some(KeyRun {
            offset: start as u32,
            len: keys.len() as u32,
            base,
        })
    }

    /// Removes a run and closes the gap; every run stored after it moves down
    /// by `run.len` words, which the caller applies with [`KeyRun::after_free`].
    pub fn free(&mut self, run: &KeyRun) {
        let (start, len) = (run.offset as usize, run.len as usize);
        let end = (start + len).min(self.used);
        if start >= end {
            return;
        }
        self.words.copy_within(end..self.used, start);
        self.used -= end - start;
    }

    /// The keys of a run as packed absolute keys, ascending.
    pub fn keys<'a>(&'a self, run: &KeyRun) -> impl Iterator<Item = u64> + 'a {
        let base = run.base;
        self.words(run).iter().map(move |&w| key_of(base, w))
    }

    /// The stored words of a run: ascending, relative to `run.base`.
    pub fn words(&self, run: &KeyRun) -> &[u32] {
        let start = (run.offset as usize).min(self.used);
        let end = (start + run.len as usize).min(self.used);
        self.words.get(start..end).unwrap_or(&[])
    }

    /// Size of the intersection of a stored run with ascending keys.
    pub fn intersect(&self, run: &KeyRun, keys: &[u64]) -> u32 {
        merge_count(self.keys(run), keys.iter().copied())
    }

    /// Size of the intersection of two stored runs.
    pub fn intersect_runs(&self, a: &KeyRun, b: &KeyRun) -> u32 {
        merge_count(self.keys(a), self.keys(b))
    }
}

impl KeyRun {
    /// Adjusts this run after `freed` was removed from the pool.
    pub fn after_free(&mut self, freed: &KeyRun) {
        if self.offset > freed.offset {
            self.offset -= freed.len;
        }
    }
}

/// The packed absolute key of relative word `w` of a run based at `base`.
#[inline]
pub fn key_of(base: [i32; 3], w: u32) -> u64 {
    let dx = (w >> (DY_BITS + DZ_BITS)) as i32;
    let dy = ((w >> DZ_BITS) & ((1 << DY_BITS) - 1)) as i32;
    let dz = (w & ((1 << DZ_BITS) - 1)) as i32;
    VoxelKey::new(
        base[0].saturating_add(dx),
        base[1].saturating_add(dy),
        base[2].saturating_add(dz),
    )
    .to_bits()
}

/// Number of common items of two ascending, duplicate-free sequences.
pub fn merge_count(a: impl Iterator<Item = u64>, b: impl Iterator<Item = u64>) -> u32 {
    let (mut a, mut b) = (a.peekable(), b.peekable());
    let mut n = 0;
    while let (Some(&x), Some(&y)) = (a.peek(), b.peek()) {
        if x < y {
            a.next();
        } else if y < x {
            b.next();
        } else {
            n += 1;
            a.next();
            b.next();
        }
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    fn keys(coords: &[(i32, i32, i32)]) -> [u64; 4] {
        let mut out = [0u64; 4];
        for (o, &(x, y, z)) in out.iter_mut().zip(coords) {
            *o = VoxelKey::new(x, y, z).to_bits();
        }
        out.sort_unstable();
        out
    }

    #[test]
    fn store_round_trip_intersect_and_compact() {
        let mut pool = KeyPool::<10>::new();
        let a = keys(&[(-5, 3, 2), (-5, 4, 0), (0, 0, 0), (7, -2, 9)]);
        let b = keys(&[(0, 0, 0), (7, -2, 9), (8, 8, 8), (100, 0, 0)]);
        let ra = pool.store(&a, &Aabb::of_sorted(&a).unwrap()).unwrap();
        let rb = pool.store(&b, &Aabb::of_sorted(&b).unwrap()).unwrap();
        assert!(pool.keys(&ra).eq(a.iter().copied()));
        assert!(pool.keys(&rb).eq(b.iter().copied()));
        assert_eq!(pool.intersect_runs(&ra, &rb), 2);
        assert_eq!(pool.intersect(&rb, &a), 2);
        // Full: a third run of 4 does not fit in the 2 words left.
        assert!(pool.store(&a, &Aabb::of_sorted(&a).unwrap()).is_none());
        pool.free(&ra);
        let mut rb2 = rb;
        rb2.after_free(&ra);
        assert_eq!(pool.used(), 4);
        assert!(pool.keys(&rb2).eq(b.iter().copied()));
    }

    #[test]
    fn refuses_boxes_too_large_to_encode() {
        let mut pool = KeyPool::<10>::new();
        let far = keys(&[(0, 0, 0), (0, 0, 1), (0, 0, 2), (0, 0, 5000)]);
        assert!(pool.store(&far, &Aabb::of_sorted(&far).unwrap()).is_none());
        assert_eq!(pool.used(), 0);
    }

    #[test]
    fn boxes_touch() {
        let a = Aabb {
            min: [0, 0, 0],
            max: [2, 2, 2],
        };
        let b = Aabb {
            min: [2, 2, 2],
            max: [3, 3, 3],
        };
        let c = Aabb {
            min: [3, 0, 0],
            max: [4, 2, 2],
        };
        assert!(a.touches(&b) && b.touches(&a) && !a.touches(&c));
    }
}
