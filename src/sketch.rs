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

/// The `K` smallest hashes of a voxel set, ascending.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sketch<const K: usize> {
    hashes: [u32; K],
    len: u16,
}

impl<const K: usize> Default for Sketch<K> {
    fn default() -> Self {
        Sketch {
            hashes: [0; K],
            len: 0,
        }
    }
}

impl<const K: usize> Sketch<K> {
    /// The sketch of the empty set.
    pub const EMPTY: Self = Sketch {
        hashes: [0; K],
        len: 0,
    };

    /// Sketch of a set given as distinct packed keys, in any order.
    #[inline(never)]
    pub fn from_keys(keys: impl Iterator<Item = u64>) -> Self {
        let mut s = Self::default();
        for k in keys {
            s.offer(hash_key(k));
        }
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
            s.len += 1;
        }
        Some(s)
    }

    /// Keeps `h` if it is among the `K` smallest seen so far.
    fn offer(&mut self, h: u32) {
        let len = self.len as usize;
        if len == K && (K == 0 || h >= self.hashes[K - 1]) {
            return;
        }
        // Insertion into the sorted prefix; expected O(K log(n / K)) inserts in all.
        let mut i = len.min(K.saturating_sub(1));
        if len < K {
            self.len += 1;
        }
        while i > 0 && self.hashes[i - 1] > h {
            self.hashes[i] = self.hashes[i - 1];
            i -= 1;
        }
        if i < K {
            self.hashes[i] = h;
        }
    }

    /// The kept hashes, ascending.
    pub fn hashes(&self) -> &[u32] {
        &self.hashes[..self.len as usize]
    }

    /// Estimated Jaccard index (IoU) of the two sets; 0 when either is empty.
    pub fn jaccard(&self, other: &Self) -> f32 {
        let (a, b) = (self.hashes(), other.hashes());
        let (mut i, mut j, mut taken, mut shared) = (0, 0, 0u32, 0u32);
        while taken < K as u32 && i < a.len() && j < b.len() {
            match a[i].cmp(&b[j]) {
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
