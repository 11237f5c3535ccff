//! The frame's voxel keys sorted by a least-significant-digit radix sort:
//! one pass per axis (z, then y, then x), each axis's coordinate relative
//! to the frame's smallest being the digit.
//!
//! A frame's voxels lie within a few dozen voxels of its camera, so each
//! axis spans well under 256 voxels, and three counting passes over the keys
//! replace a comparison sort of `u64`s, which a 32-bit core without 64-bit
//! compares (the Cortex-M0+) pays for dearly. The histograms are counted
//! once the keys are gathered from the hash set, by the coordinates' low
//! byte, which is the digit rotated by the smallest coordinate's low byte;
//! each pass turns its histogram into bucket starts in place, over the
//! digits the keys use.

/// Bits per axis in a packed key (x, y, z from the top).
const AXIS_BITS: u32 = 21;
const AXIS_MASK: u64 = (1 << AXIS_BITS) - 1;
/// Buckets per pass: an axis whose span is wider takes the comparison sort.
const BUCKETS: usize = 256;

/// What a count of the gathered keys learns of them for the sort.
pub(super) struct Census {
    /// Smallest and largest coordinate per axis (x, y, z), biased.
    low: [u32; 3],
    high: [u32; 3],
    /// Keys per low byte of each axis's coordinate.
    counts: [[u16; BUCKETS]; 3],
}

impl Census {
    pub(super) fn new() -> Census {
        Census {
            low: [u32::MAX; 3],
            high: [0; 3],
            counts: [[0; BUCKETS]; 3],
        }
    }

    /// Counts the keys (at most `u16::MAX`: a frame set holds fewer), one
    /// axis at a time: an axis's bounds stay in registers, where the three
    /// axes' six did not fit the M0+'s eight.
    pub(super) fn take(&mut self, keys: &[u64]) {
        self.axis::<0>(keys);
        self.axis::<1>(keys);
        self.axis::<2>(keys);
    }

    #[inline(always)]
    fn axis<const A: usize>(&mut self, keys: &[u64]) {
        let (Some(low), Some(high), Some(counts)) = (
            self.low.get_mut(A),
            self.high.get_mut(A),
            self.counts.get_mut(A),
        ) else {
            return;
        };
        let (mut lo, mut hi) = (*low, *high);
        for &key in keys {
            let c = coord::<A>(key);
            lo = lo.min(c);
            hi = hi.max(c);
            if let Some(count) = counts.get_mut(usize::from(c as u8)) {
                *count = count.wrapping_add(1);
            }
        }
        (*low, *high) = (lo, hi);
    }
}

/// Coordinate `A` (0 x, 1 y, 2 z) of a packed key, biased: a constant
/// shift, which a 32-bit core does inline (a variable one is a library call).
#[inline(always)]
fn coord<const A: usize>(key: u64) -> u32 {
    let shift = match A {
        0 => 2 * AXIS_BITS,
        1 => AXIS_BITS,
        _ => 0,
    };
    ((key >> shift) & AXIS_MASK) as u32
}

/// Sorts the `n` keys at the front of `slots` ascending, with
/// `slots[n..2n]` as scratch, when every axis spans fewer than
/// [`BUCKETS`] coordinates and the scratch fits; returns where the sorted
/// keys are (`None`: not sorted, the keys untouched at the front). The
/// census's counts become the passes' bucket starts.
pub(super) fn sort(
    slots: &mut [u64],
    n: usize,
    census: &mut Census,
) -> Option<core::ops::Range<usize>> {
    let narrow = census
        .low
        .iter()
        .zip(&census.high)
        .all(|(&low, &high)| high.wrapping_sub(low) < BUCKETS as u32);
    let end = n.checked_mul(2).filter(|&end| end <= slots.len())?;
    if !narrow {
        return None;
    }
    let (front, back) = slots.split_at_mut(n);
    let back = back.get_mut(..n)?;
    // z into the scratch, y back to the front, x into the scratch: each pass
    // stable, so the keys end ordered by (x, y, z), the packed order.
    pass::<2>(front, back, census);
    pass::<1>(back, front, census);
    pass::<0>(front, back, census);
    Some(n..end)
}

/// One stable counting pass by axis `A`'s coordinate less the smallest.
#[inline(never)]
fn pass<const A: usize>(from: &[u64], to: &mut [u64], census: &mut Census) {
    let (Some(&low), Some(&high), Some(counts)) = (
        census.low.get(A),
        census.high.get(A),
        census.counts.get_mut(A),
    ) else {
        return;
    };
    // Each bucket's count becomes where its next key goes, in digit order
    // (digit `d` is counted under low byte `d + low`; the span is under
    // 256, so no two digits share a low byte), over the digits the keys
    // use only: a frame's few dozen, not all 256.
    let mut at = 0u16;
    for d in 0..=high.wrapping_sub(low) {
        let byte = d.wrapping_add(low) as u8;
        if let Some(count) = counts.get_mut(usize::from(byte)) {
            let keys = *count;
            *count = at;
            at = at.wrapping_add(keys);
        }
    }
    // Bucketed by the low byte itself: no subtraction per key.
    for &key in from {
        let byte = coord::<A>(key) as u8;
        if let Some(slot) = counts.get_mut(usize::from(byte)) {
            if let Some(out) = to.get_mut(usize::from(*slot)) {
                *out = key;
            }
            *slot = slot.wrapping_add(1);
        }
    }
}
