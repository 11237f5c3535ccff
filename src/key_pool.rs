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
    /// Box of ascending packed keys; `None` for an empty set (or one whose
    /// first word is no key).
    ///
    /// Runs once a frame over all its keys, on the packed words (x in bits
    /// 42..63, y in 21..42, z in 0..21). x is the most significant field, so
    /// in ascending keys the smallest x is the first key's and the largest
    /// the last valid key's (words no key packs to sort above every key).
    /// y and z are compared as 32-bit words holding the field in their top
    /// 21 bits (`k >> 10` and `k << 11`): the bits below the field cannot
    /// change which field value is smallest or largest, and the loop needs
    /// no mask, bias or 64-bit shift, so it fits the Cortex-M0+'s registers.
    #[inline(never)]
    pub fn of_sorted(keys: &[u64]) -> Option<Aabb> {
        let &first = keys.first()?;
        VoxelKey::from_bits(first)?;
        let last = keys
            .iter()
            .rev()
            .copied()
            .find(|&k| VoxelKey::from_bits(k).is_some())
            .unwrap_or(first);
        let top_y = |k: u64| (k >> 10) as u32;
        let top_z = |k: u64| (k as u32) << 11;
        let (mut y0, mut y1) = (top_y(first), top_y(first));
        let (mut z0, mut z1) = (top_z(first), top_z(first));
        for &k in keys {
            if VoxelKey::from_bits(k).is_some() {
                let (y, z) = (top_y(k), top_z(k));
                y0 = y0.min(y);
                y1 = y1.max(y);
                z0 = z0.min(z);
                z1 = z1.max(z);
            }
        }
        // The x of `x_of` with the y and z fields of the kept words.
        let corner = |x_of: u64, y: u32, z: u32| {
            let bits = (x_of >> 42 << 42) | (u64::from(y >> 11) << 21) | u64::from(z >> 11);
            VoxelKey::from_bits(bits).map(VoxelKey::coords)
        };
        let (lo, hi) = (corner(first, y0, z0)?, corner(last, y1, z1)?);
        Some(Aabb {
            min: [lo.0, lo.1, lo.2],
            max: [hi.0, hi.1, hi.2],
        })
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

/// A frame's keys encoded in the pool's free space by [`KeyPool::stage`],
/// not yet stored: valid until the pool next changes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Staged {
    /// Where [`KeyPool::commit`] will store them.
    run: KeyRun,
    /// Their box (its corner is `run.base`).
    aabb: Aabb,
}

/// A fresh frame's keys as the merges read them: ascending packed keys,
/// and the same keys staged in the pool when it had room for them.
#[derive(Debug, Clone, Copy)]
pub struct Fresh<'a> {
    /// Ascending packed keys.
    pub keys: &'a [u64],
    /// The same keys as words, from [`KeyPool::stage`].
    pub staged: Option<&'a Staged>,
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
        let staged = self.stage(keys, aabb)?;
        self.commit(&staged)
    }

    /// Encodes ascending keys whose box is `aabb` into the free space without
    /// storing them, so that a fresh frame's overlaps merge 32-bit words, and
    /// [`Self::commit`] then stores what is already encoded; `None` (nothing
    /// written) exactly when [`Self::store`] would refuse them.
    #[inline(never)]
    pub fn stage(&mut self, keys: &[u64], aabb: &Aabb) -> Option<Staged> {
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
        Some(Staged {
            run: KeyRun {
                offset: start as u32,
                len: keys.len() as u32,
                base,
            },
            aabb: *aabb,
        })
    }

    /// The words of a staged frame while they are still the free space's
    /// first words (nothing stored or freed since); `None` otherwise.
    pub fn staged_words(&self, staged: &Staged) -> Option<&[u32]> {
        let start = staged.run.offset as usize;
        if start != self.used {
            return None;
        }
        self.words
            .get(start..start.checked_add(staged.run.len as usize)?)
    }

    /// Stores a staged frame: its words become a run, with no encoding
    /// again; `None` (nothing stored) when the pool changed since.
    pub fn commit(&mut self, staged: &Staged) -> Option<KeyRun> {
        self.staged_words(staged)?;
        self.used += staged.run.len as usize;
        Some(staged.run)
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

    /// Size of the intersection of a stored run, whose frame's box is
    /// `run_box`, with a fresh frame: the same number as [`Self::intersect`]
    /// with its keys, by a 32-bit merge of the words when the fresh keys are
    /// staged and both boxes allow it (see [`common_words`]).
    pub fn intersect_fresh(&self, run: &KeyRun, run_box: Option<&Aabb>, fresh: Fresh<'_>) -> u32 {
        let staged = fresh
            .staged
            .and_then(|s| Some((self.staged_words(s)?, &s.aabb)));
        if let (Some((words, fresh_box)), Some(run_box)) = (staged, run_box) {
            let run_words = self.words(run);
            // The run's words are relative to its box's corner (how `store`
            // wrote them); a run that says otherwise takes the long way.
            if run_box.min == run.base && run_words.len() == run.len as usize {
                if let Some(n) = common_words(run_words, run_box, words, fresh_box) {
                    return n;
                }
            }
        }
        self.intersect(run, fresh.keys)
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

/// The relative word of offset `d` from a corner, each axis within its field.
fn pack(d: [i32; 3]) -> u32 {
    ((d[0] as u32) << (DY_BITS + DZ_BITS)) | ((d[1] as u32) << DZ_BITS) | d[2] as u32
}

/// The words of ascending `words` whose x offset lies in `lo..=hi`: one run,
/// as x is the word's top field.
fn x_range(words: &[u32], lo: i32, hi: i32) -> &[u32] {
    let dx = |w: &u32| (w >> (DY_BITS + DZ_BITS)) as i32;
    let start = words.partition_point(|w| dx(w) < lo);
    let end = words.partition_point(|w| dx(w) <= hi);
    words.get(start..end).unwrap_or(&[])
}

/// Voxels two frames share, from their relative words: ascending `a`
/// relative to the corner of its box `a_box`, which holds every key of `a`,
/// and `b` likewise. Both are re-expressed relative to the corner of the
/// box around both boxes by adding one constant each: when that box fits
/// the relative encoding every key of either frame has its word there, and
/// that re-expression preserves order and equality, so a merge of 32-bit
/// words counts exactly the common keys. Only the keys in the x range both
/// boxes share can match, a run of each (found by binary search). `None`
/// when the box around both does not fit (the caller merges packed keys).
pub fn common_words(a: &[u32], a_box: &Aabb, b: &[u32], b_box: &Aabb) -> Option<u32> {
    let ([ax0, ay0, az0], [ax1, ay1, az1]) = (a_box.min, a_box.max);
    let ([bx0, by0, bz0], [bx1, by1, bz1]) = (b_box.min, b_box.max);
    let apart = |a0: i32, a1: i32, b0: i32, b1: i32| a0.max(b0) > a1.min(b1);
    if apart(ax0, ax1, bx0, bx1) || apart(ay0, ay1, by0, by1) || apart(az0, az1, bz0, bz1) {
        return Some(0);
    }
    let around = Aabb {
        min: [ax0.min(bx0), ay0.min(by0), az0.min(bz0)],
        max: [ax1.max(bx1), ay1.max(by1), az1.max(bz1)],
    };
    if !around.fits_relative() {
        return None;
    }
    // Every difference below lies within `around`, so it fits its field
    // (and cannot overflow).
    let [cx, cy, cz] = around.min;
    let shift = |[x, y, z]: [i32; 3]| pack([x - cx, y - cy, z - cz]);
    let (x0, x1) = (ax0.max(bx0), ax1.min(bx1));
    let a = x_range(a, x0 - ax0, x1 - ax0);
    let b = x_range(b, x0 - bx0, x1 - bx0);
    Some(merge_shifted(a, shift(a_box.min), b, shift(b_box.min)))
}

/// Common items of ascending `a` and `b` after adding `da` to each item of
/// `a` and `db` to each of `b`, where every shifted item fits a `u32` (see
/// [`common_words`]). One side's shift is folded into the other's: with
/// `da >= db`, `a + da` and `b + db` compare as `a + (da - db)` and `b`,
/// and `a + (da - db)` lies between `a` and `a + da`, so it cannot wrap.
fn merge_shifted(a: &[u32], da: u32, b: &[u32], db: u32) -> u32 {
    if da >= db {
        merge_offset(a, da - db, b)
    } else {
        merge_offset(b, db - da, a)
    }
}

/// Common items of ascending `a`, each plus `d` (no sum wraps), and
/// ascending `b`. Shaped for the Cortex-M0+: one pass over `a`, `b`
/// advanced inside it, so the loop's state fits its low registers.
#[inline(never)]
fn merge_offset(a: &[u32], d: u32, b: &[u32]) -> u32 {
    let mut b = b.iter();
    let Some(&first) = b.next() else {
        return 0;
    };
    let (mut y, mut n) = (first, 0u32);
    for &v in a {
        let x = v.wrapping_add(d);
        while y < x {
            match b.next() {
                Some(&w) => y = w,
                None => return n,
            }
        }
        if y == x {
            n += 1;
            match b.next() {
                Some(&w) => y = w,
                None => return n,
            }
        }
    }
    n
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
    extern crate std;
    use proptest::prelude::*;
    use std::collections::BTreeSet;
    use std::vec;
    use std::vec::Vec;

    /// Ascending packed keys of `corner + d` for each offset `d`.
    fn set_at(corner: [i32; 3], offsets: &[(i32, i32, i32)]) -> Vec<u64> {
        let mut keys: Vec<u64> = offsets
            .iter()
            .map(|&(x, y, z)| {
                let at = |c: i32, d: i32| c.saturating_add(d);
                VoxelKey::new(at(corner[0], x), at(corner[1], y), at(corner[2], z)).to_bits()
            })
            .collect();
        keys.sort_unstable();
        keys.dedup();
        keys
    }

    /// What the merges must count: the keys both sets hold.
    fn reference(a: &[u64], b: &[u64]) -> u32 {
        let a: BTreeSet<u64> = a.iter().copied().collect();
        b.iter().filter(|k| a.contains(k)).count() as u32
    }

    /// Stores `a` and stages `b` in a fresh pool, and returns what the word
    /// merge of `b` with the stored `a` counts and whether it took the word
    /// path (`None`: one of them does not fit the pool's encoding).
    fn fresh_count(a: &[u64], b: &[u64]) -> Option<(u32, bool)> {
        let mut pool = KeyPool::<8192>::new();
        let (a_box, b_box) = (Aabb::of_sorted(a)?, Aabb::of_sorted(b)?);
        let run = pool.store(a, &a_box)?;
        let staged = pool.stage(b, &b_box)?;
        let fresh = Fresh {
            keys: b,
            staged: Some(&staged),
        };
        let words = pool.staged_words(&staged)?;
        let by_words = common_words(pool.words(&run), &a_box, words, &b_box).is_some();
        let n = pool.intersect_fresh(&run, Some(&a_box), fresh);
        // The other way round: the stored run as the fresh frame.
        let back = common_words(words, &b_box, pool.words(&run), &a_box);
        assert_eq!(back.is_some(), by_words);
        if let Some(back) = back {
            assert_eq!(back, n, "the count does not depend on which side is fresh");
        }
        // And what the long way counts.
        assert_eq!(pool.intersect(&run, b), n);
        Some((n, by_words))
    }

    /// The corners the key range and the word fields make hard: zero, the
    /// ends of the key range, and a plain one.
    const CORNERS: [[i32; 3]; 5] = [
        [0, 0, 0],
        [VoxelKey::MIN, VoxelKey::MIN, VoxelKey::MIN],
        [
            VoxelKey::MAX - 2047,
            VoxelKey::MAX - 2047,
            VoxelKey::MAX - 1023,
        ],
        [-7, 1_000, -300_000],
        [VoxelKey::MIN + 5, VoxelKey::MAX - 3000, 12],
    ];

    #[test]
    fn word_merges_count_what_packed_keys_share_at_the_field_edges() {
        // Each set spans its box's full 11/11/10-bit fields or just one
        // voxel; they touch, nest, sit apart, or share a corner.
        let full = [
            (0, 0, 0),
            (2047, 0, 0),
            (0, 2047, 0),
            (0, 0, 1023),
            (2047, 2047, 1023),
        ];
        // The cube of edge `e + 1` voxels with its low corner at `o`.
        let cube = |o: (i32, i32, i32), e: i32| -> Vec<(i32, i32, i32)> {
            (0..=e)
                .flat_map(|x| {
                    (0..=e).flat_map(move |y| (0..=e).map(move |z| (x + o.0, y + o.1, z + o.2)))
                })
                .collect()
        };
        let (at0, at1) = ((0, 0, 0), (1, 1, 1));
        // Two sets of voxel offsets, the keys they share, and whether the
        // box around both fits the word fields.
        type Case = (Vec<(i32, i32, i32)>, Vec<(i32, i32, i32)>, u32, bool);
        for corner in CORNERS {
            let cases: [Case; 9] = [
                // The same set.
                (cube(at0, 3), cube(at0, 3), 64, true),
                // Nested: a small cube inside a big box.
                (full.to_vec(), cube(at1, 2), 0, true),
                (
                    full.iter().copied().chain(cube(at1, 2)).collect(),
                    cube(at1, 2),
                    27,
                    true,
                ),
                // Touching at one face (x = 3), sharing its 16 voxels.
                (cube(at0, 3), cube((3, 0, 0), 3), 16, true),
                // Touching at one corner voxel.
                (cube(at0, 3), cube((3, 3, 3), 3), 1, true),
                // Apart on z only: the boxes do not touch.
                (cube(at0, 1), vec![(0, 0, 2), (1, 1, 5)], 0, true),
                // The box around both is one voxel too long on z, x, y.
                (
                    vec![(0, 0, 0), (0, 0, 1)],
                    vec![(0, 0, 1), (0, 0, 1024)],
                    1,
                    false,
                ),
                (
                    vec![(0, 0, 0), (1, 0, 0)],
                    vec![(1, 0, 0), (2048, 0, 0)],
                    1,
                    false,
                ),
                (
                    vec![(5, 0, 0), (5, 1, 0)],
                    vec![(5, 1, 0), (5, 2048, 0)],
                    1,
                    false,
                ),
            ];
            for (i, (a, b, common, by_words)) in cases.into_iter().enumerate() {
                let (a, b) = (set_at(corner, &a), set_at(corner, &b));
                if a.len() < 2 || b.len() < 2 {
                    continue; // clamped together at the end of the key range
                }
                let got = fresh_count(&a, &b);
                let want = reference(&a, &b);
                assert_eq!(got.map(|g| g.0), Some(want), "case {i} at {corner:?}");
                // Clamping at the range's end can only merge voxels.
                if corner == CORNERS[0] {
                    assert_eq!(got, Some((common, by_words)), "case {i}");
                }
            }
        }
    }

    #[test]
    fn empty_runs_share_nothing() {
        let b = Aabb {
            min: [0; 3],
            max: [3; 3],
        };
        assert_eq!(common_words(&[], &b, &[5, 6], &b), Some(0));
        assert_eq!(common_words(&[5, 6], &b, &[], &b), Some(0));
        assert_eq!(merge_offset(&[], 3, &[1]), 0);
        assert_eq!(merge_offset(&[1], 3, &[]), 0);
    }

    #[test]
    fn staging_is_storing_in_two_steps() {
        let a = set_at([3, -4, 5], &[(0, 0, 0), (1, 2, 3), (9, 0, 1)]);
        let a_box = Aabb::of_sorted(&a).unwrap();
        let (mut one, mut two) = (KeyPool::<5>::new(), KeyPool::<5>::new());
        let stored = one.store(&a, &a_box).unwrap();
        let staged = two.stage(&a, &a_box).unwrap();
        assert_eq!(two.used(), 0, "staged words are not stored");
        assert_eq!(two.staged_words(&staged), Some(one.words(&stored)));
        assert_eq!(two.commit(&staged), Some(stored));
        assert_eq!(two.words(&stored), one.words(&stored));
        // Once the pool has changed, the staged words are gone.
        assert_eq!(two.staged_words(&staged), None);
        assert_eq!(two.commit(&staged), None);
        // Refused as `store` refuses: two words left for three keys.
        assert!(two.stage(&a, &a_box).is_none() && two.store(&a, &a_box).is_none());
    }

    /// Offsets from a shared corner, mostly near it (so that two sets
    /// overlap), some out to the fields' edges and past them.
    fn offsets() -> impl Strategy<Value = Vec<(i32, i32, i32)>> {
        let axis = |edge: i32| {
            prop_oneof![
                6 => 0..6i32,
                2 => 0..40i32,
                1 => (edge - 3)..(edge + 3),
                1 => 0..(edge + 2),
            ]
        };
        proptest::collection::vec((axis(2047), axis(2047), axis(1023)), 0..120)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        #[test]
        fn word_merges_count_what_packed_keys_share(
            corner in prop_oneof![
                Just(CORNERS[1]),
                Just(CORNERS[2]),
                (-3000..3000i32, -3000..3000i32, -3000..3000i32).prop_map(|(x, y, z)| [x, y, z]),
            ],
            shared in offsets(),
            only_a in offsets(),
            only_b in offsets(),
            shift in (-8..8i32, -8..8i32, -8..8i32),
        ) {
            let moved: Vec<_> = only_b
                .iter()
                .map(|&(x, y, z)| (x + shift.0, y + shift.1, z + shift.2))
                .collect();
            let a: Vec<_> = shared.iter().chain(&only_a).copied().collect();
            let b: Vec<_> = shared.iter().chain(&moved).copied().collect();
            let (a, b) = (set_at(corner, &a), set_at(corner, &b));
            if let Some((n, _)) = fresh_count(&a, &b) {
                prop_assert_eq!(n, reference(&a, &b));
            }
        }
    }

    proptest! {
        /// The box from the ends' x and a loop over y and z is the box
        /// every valid key's three axes give, with words no key packs to
        /// (which sort last) left out.
        #[test]
        fn box_of_sorted_keys_is_every_axis_bound(
            corner in (-3000..3000i32, -3000..3000i32, -3000..3000i32).prop_map(|(x, y, z)| [x, y, z]),
            offsets in offsets(),
            junk in proptest::collection::vec(1u64 << 63.., 0..3),
        ) {
            let mut keys = set_at(corner, &offsets);
            keys.sort_unstable();
            keys.dedup();
            keys.extend(junk);
            keys.sort_unstable();
            let valid: Vec<_> = keys.iter().filter_map(|&k| VoxelKey::from_bits(k)).collect();
            let expected = valid.first().map(|k0| {
                let c = k0.coords();
                let mut b = Aabb { min: [c.0, c.1, c.2], max: [c.0, c.1, c.2] };
                for k in &valid {
                    let (x, y, z) = k.coords();
                    for (i, v) in [x, y, z].into_iter().enumerate() {
                        b.min[i] = b.min[i].min(v);
                        b.max[i] = b.max[i].max(v);
                    }
                }
                b
            });
            prop_assert_eq!(Aabb::of_sorted(&keys), expected);
        }
    }

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
