//! Bottom-k MinHash sketches of voxel sets, for overlap estimates when a
//! frame's exact keys do not fit the key pool.
//!
//! A sketch keeps the `K` smallest 32-bit hashes of a set. The `K` smallest
//! hashes of `A ∪ B` are all in `S(A) ∪ S(B)`, and such a hash is in both
//! sketches exactly when its voxel is in `A ∩ B`, so the share of shared
//! hashes among the `K` smallest of the union is an unbiased Jaccard (IoU)
//! estimate with standard error about `sqrt(J (1 - J) / K)`.

/// Hash of a packed voxel key: the finaliser of MurmurHash3 (a bijection on
/// `u64`, so distinct keys collide only in the 32 bits kept), of which only
/// the high 32 bits are kept.
///
/// Computed on 32-bit words, bit for bit what the definition on `u64` gives
/// (`hash_key_definition` in the tests, which check it): a frame hashes every one of its
/// keys, and a 32-bit core has no 64-bit multiply (the Cortex-M0+ not even a
/// widening one, and `__aeabi_lmul` is a call doing four partial products and
/// more). Writing `k = kh:kl` (high and low words):
/// - `f = k ^ (k >> 33)` is `kh : kl ^ (kh >> 1)`, the shift's high word being 0;
/// - `f * C1 mod 2^64` is `lo(fl*c1l) : hi(fl*c1l) + fh*c1l + fl*c1h`
///   (mod `2^32`): one widening and two plain multiplies;
/// - `g = h ^ (h >> 33)` as for `f`;
/// - the kept word, `(g * C2 ^ (g * C2 >> 33)) >> 32`, is the high word of
///   `g * C2` alone (the last shift moves nothing into it): again one
///   widening and two plain multiplies, of which only the high word counts.
#[inline]
pub fn hash_key(bits: u64) -> u32 {
    hash_on_words(bits, widening_mul)
}

/// The hash as MurmurHash3 defines its finaliser, on `u64`: the reference
/// [`hash_key`] is checked against.
#[cfg(test)]
fn hash_key_definition(bits: u64) -> u32 {
    let mut h = bits;
    h ^= h >> 33;
    h = h.wrapping_mul(0xff51_afd7_ed55_8ccd);
    h ^= h >> 33;
    h = h.wrapping_mul(0xc4ce_b9fe_1a85_ec53);
    h ^= h >> 33;
    (h >> 32) as u32
}

/// MurmurHash3's finaliser constants, as (high, low) words.
const C1: (u32, u32) = (0xff51_afd7, 0xed55_8ccd);
const C2: (u32, u32) = (0xc4ce_b9fe, 0x1a85_ec53);

/// [`hash_key`] with `mul` for the 32x32 -> 64-bit multiply, as (low, high)
/// words (see [`hash_key`] for the derivation).
#[inline(always)]
fn hash_on_words(bits: u64, mul: impl Fn(u32, u32) -> (u32, u32) + Copy) -> u32 {
    let (gh, gl) = first_stage(bits, mul);
    second_stage(gh, gl, mul)
}

/// `g = f * C1 ^ (f * C1 >> 33)`, `f = k ^ (k >> 33)`, as (high, low) words.
#[inline(always)]
fn first_stage(bits: u64, mul: impl Fn(u32, u32) -> (u32, u32)) -> (u32, u32) {
    let (kh, kl) = ((bits >> 32) as u32, bits as u32);
    let (fh, fl) = (kh, kl ^ (kh >> 1));
    let (hl, p) = mul(fl, C1.1);
    let hh = p
        .wrapping_add(fh.wrapping_mul(C1.1))
        .wrapping_add(fl.wrapping_mul(C1.0));
    (hh, hl ^ (hh >> 1))
}

/// The hash from `g`: the high word of `g * C2`.
#[inline(always)]
fn second_stage(gh: u32, gl: u32, mul: impl Fn(u32, u32) -> (u32, u32)) -> u32 {
    let (_, p) = mul(gl, C2.1);
    p.wrapping_add(gh.wrapping_mul(C2.1))
        .wrapping_add(gl.wrapping_mul(C2.0))
}

/// How far the hash may lie above [`hash_floor`].
const FLOOR_SLACK: u32 = 1 << 17;

/// A floor of the hash from `g` for three plain multiplies instead of the
/// widening one: the hash is `(floor + e) mod 2^32` with `0 <= e <=
/// FLOOR_SLACK`. With `gl = a1:a0` and `c = b1:b0` (16-bit halves of `C2`'s
/// low word), the high word of `gl * c` is `a1*b1` plus the high word of
/// `(a0*b1 + a1*b0) << 16 + a0*b0`, which is below `2^49 + 2^32`: at most
/// `2^17`. The floor keeps `a1*b1` alone.
#[inline(always)]
fn hash_floor(gh: u32, gl: u32) -> u32 {
    (gl >> 16)
        .wrapping_mul(C2.1 >> 16)
        .wrapping_add(gh.wrapping_mul(C2.1))
        .wrapping_add(gl.wrapping_mul(C2.0))
}

/// The hash of `bits`, unless it is sure to be at least `bound` (`None`):
/// a hash whose floor is at least `bound`, with no wrap past `u32::MAX`
/// within its slack, is too, so most keys of a large set are refused
/// before the widening multiply of the second stage.
#[inline(always)]
fn hash_unless_at_least(bits: u64, bound: u32) -> Option<u32> {
    let (gh, gl) = first_stage(bits, widening_mul);
    let floor = hash_floor(gh, gl);
    if floor >= bound && floor <= u32::MAX - FLOOR_SLACK {
        return None;
    }
    Some(second_stage(gh, gl, widening_mul))
}

/// The 32x32 -> 64-bit product as (low, high) words: by 16-bit halves on
/// the Cortex-M0/M0+ (ARMv6-M), which has no widening multiply. Stable Rust
/// names no target feature for that, but ARMv6-M is also the one ARM
/// profile without 32-bit atomics, which it does name.
#[cfg(all(target_arch = "arm", not(target_has_atomic = "32")))]
#[inline(always)]
fn widening_mul(a: u32, b: u32) -> (u32, u32) {
    mul_by_halves(a, b)
}

/// The 32x32 -> 64-bit product as (low, high) words: one instruction
/// (`umull`) on a Cortex-M3/M4, a 64-bit multiply on a 64-bit host.
#[cfg(not(all(target_arch = "arm", not(target_has_atomic = "32"))))]
#[inline(always)]
fn widening_mul(a: u32, b: u32) -> (u32, u32) {
    let p = u64::from(a) * u64::from(b);
    (p as u32, (p >> 32) as u32)
}

/// The 32x32 -> 64-bit product as (low, high) words from four 16x16 -> 32
/// products (single-cycle `muls` on the Cortex-M0+, which keeps only the low
/// word of a product): `a*b = a1*b1 << 32 + (a0*b1 + a1*b0) << 16 + a0*b0`.
#[inline(always)]
#[cfg_attr(
    not(any(test, all(target_arch = "arm", not(target_has_atomic = "32")))),
    allow(dead_code)
)]
fn mul_by_halves(a: u32, b: u32) -> (u32, u32) {
    let (a0, a1) = (a & 0xffff, a >> 16);
    let (b0, b1) = (b & 0xffff, b >> 16);
    // Each 16x16 product is below 2^32; their sums carry explicitly.
    let (mid, mid_carry) = a0.wrapping_mul(b1).overflowing_add(a1.wrapping_mul(b0));
    let (lo, lo_carry) = a0.wrapping_mul(b0).overflowing_add(mid << 16);
    // The high word of a 32x32 product is at most 2^32 - 2: no wrap.
    let hi = a1
        .wrapping_mul(b1)
        .wrapping_add(mid >> 16)
        .wrapping_add(u32::from(mid_carry) << 16)
        .wrapping_add(u32::from(lo_carry));
    (lo, hi)
}

/// Puts `h` into the max-heap `heap` at `i`, in place of the entry there,
/// and restores the heap order below `i` (the children of `i` are `2i + 1`
/// and `2i + 2`): larger children move up into the hole until `h` is at
/// least both of them. With `i` the root this replaces the largest entry.
fn sift_down(heap: &mut [u32], mut i: usize, h: u32) {
    loop {
        // `i < heap.len()`, far below `usize::MAX / 2`: no wrap.
        let left = i.wrapping_mul(2).wrapping_add(1);
        let Some(&l) = heap.get(left) else {
            break;
        };
        let right = left.wrapping_add(1);
        let (child, c) = match heap.get(right) {
            Some(&r) if r > l => (right, r),
            _ => (left, l),
        };
        if c <= h {
            break;
        }
        if let Some(hole) = heap.get_mut(i) {
            *hole = c;
        }
        i = child;
    }
    if let Some(hole) = heap.get_mut(i) {
        *hole = h;
    }
}

/// The `K` smallest hashes of a voxel set, ascending.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sketch<const K: usize> {
    hashes: [u32; K],
    len: u16,
}

impl<const K: usize> Default for Sketch<K> {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl<const K: usize> Sketch<K> {
    /// The count of kept hashes is a `u16`: every `len += 1` stops at `K`.
    const LEN_FITS: () = assert!(K <= u16::MAX as usize, "sketch size must fit u16");

    /// The sketch of the empty set.
    pub const EMPTY: Self = {
        let () = Self::LEN_FITS;
        Sketch {
            hashes: [0; K],
            len: 0,
        }
    };

    /// Sketch of a set given as distinct packed keys, in any order: the
    /// `K` smallest of their hashes (with repeats, as [`Self::offer`] keeps
    /// them), ascending.
    ///
    /// The first `K` hashes fill the array; from then on it is a max-heap,
    /// so a hash below the largest kept replaces it in `log K` steps (an
    /// insertion into the sorted array moves half of it, and a frame
    /// offers a few hundred such hashes); one sort at the end.
    #[inline(never)]
    pub fn from_keys(keys: impl Iterator<Item = u64>) -> Self {
        let mut s = Self::default();
        let mut keys = keys;
        for (slot, k) in s.hashes.iter_mut().zip(&mut keys) {
            *slot = hash_key(k);
            // `len < K <= u16::MAX` (see `LEN_FITS`): no wrap.
            s.len += 1;
        }
        if usize::from(s.len) == K {
            for i in (0..K / 2).rev() {
                if let Some(&h) = s.hashes.get(i) {
                    sift_down(&mut s.hashes, i, h);
                }
            }
            // The largest kept, held here: most hashes of a large set are
            // refused by it, most of them before they are fully computed.
            if let Some(&first) = s.hashes.first() {
                let mut largest = first;
                for k in keys {
                    match hash_unless_at_least(k, largest) {
                        Some(h) if h < largest => {
                            sift_down(&mut s.hashes, 0, h);
                            largest = s.hashes.first().copied().unwrap_or(h);
                        }
                        _ => {}
                    }
                }
            }
        }
        s.hashes
            .get_mut(..usize::from(s.len))
            .unwrap_or_default()
            .sort_unstable();
        s
    }

    /// A sketch from stored hashes, which must be strictly ascending and at
    /// most `K` (as [`Self::hashes`] gives them); `None` otherwise.
    pub fn from_hashes(hashes: impl Iterator<Item = u32>) -> Option<Self> {
        let mut s = Self::default();
        for h in hashes {
            let len = s.len as usize;
            let ascending = len == 0 || s.hashes.get(len - 1).is_some_and(|&p| p < h);
            *s.hashes.get_mut(len).filter(|_| ascending)? = h;
            // `len < K <= u16::MAX` (see `LEN_FITS`): no wrap.
            s.len += 1;
        }
        Some(s)
    }

    /// Keeps `h` if it is among the `K` smallest seen so far: the one-by-one
    /// definition [`Self::from_keys`]'s heap is tested against.
    #[cfg(test)]
    fn offer(&mut self, h: u32) {
        let len = self.len as usize;
        // Full: `h` must beat the largest kept (with `K == 0` nothing is kept).
        if len == K && self.hashes.last().is_none_or(|&largest| h >= largest) {
            return;
        }
        // Insertion into the sorted prefix; expected O(K log(n / K)) inserts in
        // all. The window is the kept hashes plus the slot the last one moves
        // to: the free slot after them, or (when full) the largest, dropped.
        let Some(window) = self.hashes.get_mut(..=len.min(K.saturating_sub(1))) else {
            return;
        };
        let Some((_, kept)) = window.split_last_mut() else {
            return;
        };
        // After every kept hash not above `h`, as the insertion always put it.
        let at = kept.partition_point(|&p| p <= h);
        let mut carry = h;
        for slot in window.iter_mut().skip(at) {
            carry = core::mem::replace(slot, carry);
        }
        if len < K {
            // `len < K <= u16::MAX` (see `LEN_FITS`): no wrap.
            self.len += 1;
        }
    }

    /// The kept hashes, ascending.
    pub fn hashes(&self) -> &[u32] {
        // `len <= K` always; the fallback is never taken.
        self.hashes.get(..self.len as usize).unwrap_or(&[])
    }

    /// Estimated Jaccard index (IoU) of the two sets; 0 when either is empty.
    pub fn jaccard(&self, other: &Self) -> f32 {
        let (a, b) = (self.hashes(), other.hashes());
        let (mut i, mut j, mut taken, mut shared) = (0, 0, 0u32, 0u32);
        while taken < K as u32 {
            let (Some(x), Some(y)) = (a.get(i), b.get(j)) else {
                break;
            };
            match x.cmp(y) {
                core::cmp::Ordering::Less => i += 1,
                core::cmp::Ordering::Greater => j += 1,
                core::cmp::Ordering::Equal => {
                    shared += 1;
                    i += 1;
                    j += 1;
                }
            }
            taken += 1;
        }
        // When one sketch runs out, the rest of the union's K smallest come
        // from the other alone: they count as taken, not shared.
        let rest = ((a.len() - i) + (b.len() - j)) as u32;
        taken = (taken + rest).min(K as u32);
        if taken == 0 {
            0.0
        } else {
            shared as f32 / taken as f32
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stream of random keys from the core's test generator.
    fn random(seed: u64) -> impl Iterator<Item = u64> + Clone {
        let mut rng = crate::test_rng::TestRng::new(seed);
        core::iter::repeat_with(move || rng.next_u64())
    }

    /// Keys at the edges: 0, all ones, each single bit and its complement,
    /// the voxel key range's corners and the words' boundaries.
    fn edge_keys() -> impl Iterator<Item = u64> {
        use crate::voxel::VoxelKey;
        let (lo, hi) = (VoxelKey::MIN, VoxelKey::MAX);
        let corners = [
            VoxelKey::new(lo, lo, lo),
            VoxelKey::new(hi, hi, hi),
            VoxelKey::new(lo, hi, lo),
            VoxelKey::new(hi, lo, hi),
            VoxelKey::new(0, 0, 0),
            VoxelKey::new(-1, -1, -1),
        ]
        .map(VoxelKey::to_bits);
        let words = [
            0,
            u64::MAX,
            u64::from(u32::MAX),
            1 << 32,
            u64::MAX << 32,
            (1 << 63) - 1,
            (1 << 63) - 2,
            (1 << 63) + 1,
            (1 << 33) - 1,
            0xffff,
            0x1_0000,
        ];
        (0..64)
            .flat_map(|i| [1u64 << i, !(1u64 << i)])
            .chain(corners)
            .chain(words)
            .flat_map(|k| [k, k.wrapping_sub(1), k.wrapping_add(1)])
    }

    #[test]
    fn the_product_by_halves_is_the_widening_product() {
        let edges = [
            0u32,
            1,
            0xffff,
            0x1_0000,
            0x1_ffff,
            0xffff_0000,
            u32::MAX - 1,
            u32::MAX,
        ];
        let pairs = edges
            .iter()
            .flat_map(|&a| edges.iter().map(move |&b| (a, b)))
            .chain(
                random(1)
                    .take(200_000)
                    .map(|r| (r as u32, (r >> 32) as u32)),
            );
        for (a, b) in pairs {
            let p = u64::from(a) * u64::from(b);
            assert_eq!(
                mul_by_halves(a, b),
                (p as u32, (p >> 32) as u32),
                "{a:#x} * {b:#x}"
            );
        }
    }

    /// The hash on words, with either multiply (the Cortex-M0+ takes the one by
    /// halves, every other target the widening one), is the definition's.
    #[test]
    fn the_hash_on_words_is_the_definition() {
        let native = |a: u32, b: u32| {
            let p = u64::from(a) * u64::from(b);
            (p as u32, (p >> 32) as u32)
        };
        // Random keys, and random keys within the packed key range (63 bits).
        let keys = edge_keys()
            .chain(random(2).take(200_000))
            .chain(random(3).take(200_000).map(|k| k >> 1));
        for k in keys {
            let want = hash_key_definition(k);
            assert_eq!(hash_on_words(k, mul_by_halves), want, "key {k:#x}");
            assert_eq!(hash_on_words(k, native), want, "key {k:#x}");
            assert_eq!(hash_key(k), want, "key {k:#x}");
        }
    }

    /// The floor is at most `FLOOR_SLACK` below the hash (mod 2^32), and a
    /// hash is refused against a bound only when it is at least the bound.
    #[test]
    fn the_early_refusal_refuses_only_hashes_at_least_the_bound() {
        let keys = edge_keys()
            .chain(random(4).take(200_000))
            .chain(random(5).take(200_000).map(|k| k >> 1));
        let (mut refused, mut near_wrap) = (0u32, 0u32);
        for (i, k) in keys.enumerate() {
            let h = hash_key_definition(k);
            let (gh, gl) = first_stage(k, mul_by_halves);
            let floor = hash_floor(gh, gl);
            assert!(h.wrapping_sub(floor) <= FLOOR_SLACK, "key {k:#x}");
            near_wrap += u32::from(floor > u32::MAX - FLOOR_SLACK);
            let r = (i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) as u32;
            for bound in [
                0,
                1,
                h.saturating_sub(1),
                h,
                h.saturating_add(1),
                r,
                u32::MAX,
            ] {
                match hash_unless_at_least(k, bound) {
                    Some(got) => assert_eq!(got, h, "key {k:#x}"),
                    None => {
                        assert!(h >= bound, "key {k:#x} refused below {bound:#x}");
                        refused += 1;
                    }
                }
            }
        }
        // The refusal does happen, and floors near the wrap are among the keys.
        assert!(refused > 100_000 && near_wrap > 0, "{refused} {near_wrap}");
    }

    /// Sketches of random sets (sizes around `K` and far above, random
    /// order) are the `K` smallest of the definition's hashes, ascending.
    #[test]
    fn sketches_of_random_sets_are_the_definitions() {
        let mut all = [0u32; 5000];
        for (t, n) in [0usize, 1, 63, 64, 65, 500, 5000].into_iter().enumerate() {
            for seed in 0..4u64 {
                // Packed keys are below 2^63; any u64 is hashed alike.
                let shift = if seed % 2 == 0 { 1 } else { 0 };
                let keys = random(seed * 16 + t as u64).take(n).map(|k| k >> shift);
                for (slot, k) in all.iter_mut().zip(keys.clone()) {
                    *slot = hash_key_definition(k);
                }
                let all = &mut all[..n];
                all.sort_unstable();
                let want = &all[..n.min(64)];
                assert_eq!(
                    Sketch::<64>::from_keys(keys).hashes(),
                    want,
                    "n {n} seed {seed}"
                );
            }
        }
    }

    #[test]
    fn identical_disjoint_and_partial() {
        let a = Sketch::<64>::from_keys(0..1000u64);
        let b = Sketch::<64>::from_keys(0..1000u64);
        let c = Sketch::<64>::from_keys(5000..6000u64);
        assert_eq!(a.jaccard(&b), 1.0);
        assert_eq!(a.jaccard(&c), 0.0);
        // |A ∩ B| = 500, |A ∪ B| = 1500: J = 1/3.
        let d = Sketch::<64>::from_keys(500..1500u64);
        let j = a.jaccard(&d);
        assert!((j - 1.0 / 3.0).abs() < 0.2, "{j}");
        assert!(a.hashes().windows(2).all(|w| w[0] < w[1]));
    }

    #[test]
    fn stored_hashes_round_trip_and_bad_ones_are_refused() {
        let a = Sketch::<8>::from_keys(0..100u64);
        assert_eq!(
            Sketch::<8>::from_hashes(a.hashes().iter().copied()),
            Some(a)
        );
        assert_eq!(Sketch::<8>::from_hashes([3, 2].into_iter()), None);
        assert_eq!(Sketch::<8>::from_hashes([3, 3].into_iter()), None);
        assert_eq!(Sketch::<2>::from_hashes([1, 2, 3].into_iter()), None);
        assert_eq!(
            Sketch::<2>::from_hashes(core::iter::empty()),
            Some(Sketch::EMPTY)
        );
    }

    #[test]
    fn keeps_exactly_the_k_smallest_hashes() {
        // Sets around the capacity, offered in a scrambled order (7919 is a
        // prime, so `i * 7919 % n` visits every key once).
        for n in [0u64, 1, 7, 8, 9, 100, 1000] {
            let keys = (0..n).map(|i| (i * 7919) % n + 40_000);
            let mut all = [0u32; 1000];
            for (slot, k) in all.iter_mut().zip(keys.clone()) {
                *slot = hash_key(k);
            }
            let all = &mut all[..n as usize];
            all.sort_unstable();
            let kept = Sketch::<8>::from_keys(keys.clone());
            assert_eq!(kept.hashes(), &all[..all.len().min(8)], "n = {n}");
            assert_eq!(Sketch::<0>::from_keys(keys).hashes(), &[] as &[u32]);
        }
    }

    /// The heap of `from_keys` keeps what offering the hashes one by one
    /// into the sorted array keeps, for set sizes around `K` and far above,
    /// keys offered in scrambled orders.
    #[test]
    fn from_keys_keeps_what_offering_keeps() {
        for n in [0u64, 1, 15, 16, 17, 100, 5000] {
            for spread in [1u64, 3, 1 << 40] {
                let keys = (0..n).map(|i| (i * 7919) % n.max(1) * spread);
                let mut offered = Sketch::<16>::default();
                for k in keys.clone() {
                    offered.offer(hash_key(k));
                }
                assert_eq!(Sketch::<16>::from_keys(keys.clone()), offered, "n {n}");
                let mut offered = Sketch::<64>::default();
                for k in keys.clone() {
                    offered.offer(hash_key(k));
                }
                assert_eq!(Sketch::<64>::from_keys(keys), offered, "n {n}");
            }
        }
    }

    #[test]
    fn small_sets_are_exact() {
        let a = Sketch::<64>::from_keys([1u64, 2, 3, 4].into_iter());
        let b = Sketch::<64>::from_keys([3u64, 4, 5, 6].into_iter());
        assert_eq!(a.jaccard(&b), 2.0 / 6.0);
        assert_eq!(Sketch::<64>::default().jaccard(&a), 0.0);
    }

    #[test]
    fn estimate_error_is_small_on_average() {
        // Many pairs with true J = 0.3: mean estimate close, spread about sqrt(J(1-J)/K).
        let mut sum = 0.0;
        let trials = 200;
        for t in 0..trials {
            let base = t * 100_000;
            // |A| = |B| = 1300, |A ∩ B| = 600: J = 600 / 2000 = 0.3.
            let a = Sketch::<128>::from_keys(base..base + 1300);
            let b = Sketch::<128>::from_keys(base + 700..base + 2000);
            sum += a.jaccard(&b);
        }
        let mean = sum / trials as f32;
        assert!((mean - 0.3).abs() < 0.02, "{mean}");
    }
}
