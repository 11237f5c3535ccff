//! The frame's voxel keys sorted by a least-significant-digit radix sort:
//! one pass per axis (z, then y, then x), each axis's coordinate relative
//! to the frame's smallest being the digit.
//!
//! A frame's voxels lie within a few dozen voxels of its camera, so each
//! axis spans well under 256 voxels, and three counting passes over the keys
//! replace a comparison sort of `u64`s, which a 32-bit core without 64-bit
//! compares (the Cortex-M0+) pays for dearly. The histograms are counted
//! while the keys are gathered from the hash set, by the coordinates' low
//! byte, which is the digit rotated by the smallest coordinate's low byte.

/// Bits per axis in a packed key (x, y, z from the top).
const AXIS_BITS: u32 = 21;
const AXIS_MASK: u64 = (1 << AXIS_BITS) - 1;
/// Buckets per pass: an axis whose span is wider takes the comparison sort.
const BUCKETS: usize = 256;

/// What the gathering pass learns of the keys for the sort.
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

    /// Counts one key (at most `u16::MAX` keys: a frame set holds fewer).
    #[inline(always)]
    pub(super) fn add(&mut self, key: u64) {
        self.axis::<0>(coord::<0>(key));
        self.axis::<1>(coord::<1>(key));
        self.axis::<2>(coord::<2>(key));
    }

    #[inline(always)]
    fn axis<const A: usize>(&mut self, c: u32) {
        if let (Some(low), Some(high), Some(counts)) = (
            self.low.get_mut(A),
            self.high.get_mut(A),
            self.counts.get_mut(A),
        ) {
            *low = (*low).min(c);
            *high = (*high).max(c);
            if let Some(count) = counts.get_mut(usize::from(c as u8)) {
                *count = count.wrapping_add(1);
            }
        }
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
/// keys are (`None`: not sorted, the keys untouched at the front).
pub(super) fn sort(
    slots: &mut [u64],
    n: usize,
    census: &Census,
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
fn pass<const A: usize>(from: &[u64], to: &mut [u64], census: &Census) {
    let (Some(&low), Some(counts)) = (census.low.get(A), census.counts.get(A)) else {
        return;
    };
    // `next[d]`: where the next key of digit `d` goes. Digit `d` counted
    // under low byte `d + low` (the span is under 256, so no two digits
    // share a low byte).
    let mut next = [0u16; BUCKETS];
    let mut at = 0u16;
    for (d, slot) in next.iter_mut().enumerate() {
        *slot = at;
        let byte = (d as u32).wrapping_add(low) as u8;
        at = at.wrapping_add(counts.get(usize::from(byte)).copied().unwrap_or(0));
    }
    for &key in from {
        let digit = coord::<A>(key).wrapping_sub(low) as u8;
        if let Some(slot) = next.get_mut(usize::from(digit)) {
            if let Some(out) = to.get_mut(usize::from(*slot)) {
                *out = key;
            }
            *slot = slot.wrapping_add(1);
        }
    }
}
