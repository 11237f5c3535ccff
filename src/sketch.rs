//! Bottom-k MinHash sketches of voxel sets, for overlap estimates when a
//! frame's exact keys do not fit the key pool.
//!
//! A sketch keeps the `K` smallest 32-bit hashes of a set. The `K` smallest
//! hashes of `A ∪ B` are all in `S(A) ∪ S(B)`, and such a hash is in both
//! sketches exactly when its voxel is in `A ∩ B`, so the share of shared
//! hashes among the `K` smallest of the union is an unbiased Jaccard (IoU)
//! estimate with standard error about `sqrt(J (1 - J) / K)`.

/// Hash of a packed voxel key: the finaliser of MurmurHash3 (a bijection on
/// `u64`, so distinct keys collide only in the 32 bits kept).
#[inline]
pub fn hash_key(bits: u64) -> u32 {
    let mut h = bits;
    h ^= h >> 33;
    h = h.wrapping_mul(0xff51_afd7_ed55_8ccd);
    h ^= h >> 33;
    h = h.wrapping_mul(0xc4ce_b9fe_1a85_ec53);
    h ^= h >> 33;
    (h >> 32) as u32
}

/// Restores the max-heap order of `heap` below `i` (children of `i` are
/// `2i + 1` and `2i + 2`), `heap[i]` being the one entry out of place.
fn sift_down(heap: &mut [u32], mut i: usize) {
    loop {
        let left = i.saturating_mul(2).saturating_add(1);
        let right = left.saturating_add(1);
        let mut largest = i;
        for child in [left, right] {
            if let (Some(c), Some(l)) = (heap.get(child), heap.get(largest)) {
                if c > l {
                    largest = child;
                }
            }
        }
        let (Some(&parent), Some(&child)) = (heap.get(i), heap.get(largest)) else {
            return;
        };
        if largest == i {
            return;
        }
        if let Some(p) = heap.get_mut(i) {
            *p = child;
        }
        if let Some(c) = heap.get_mut(largest) {
            *c = parent;
        }
        i = largest;
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
        let mut keys = keys.map(hash_key);
        for (slot, h) in s.hashes.iter_mut().zip(&mut keys) {
            *slot = h;
            // `len < K <= u16::MAX` (see `LEN_FITS`): no wrap.
            s.len += 1;
        }
        if usize::from(s.len) == K {
            for i in (0..K / 2).rev() {
                sift_down(&mut s.hashes, i);
            }
            for h in keys {
                if let Some(largest) = s.hashes.first_mut().filter(|l| h < **l) {
                    *largest = h;
                    sift_down(&mut s.hashes, 0);
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
