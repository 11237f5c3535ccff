//! The bounding box of packed voxel keys as a dense grid of cells, and the
//! distinct keys of some keys through a bitmap of it: each key marks its
//! cell, and the marked cells read in order are the keys in order (cells
//! are x-major, like the packing). A scan's keys fill a small box, so this
//! replaces a sort: the voxelizer orders a frame's keys this way, the
//! metrics and the top view unite sets this way, and the co-observation
//! index numbers voxels by their cells.

use rayon::prelude::*;

/// Bits of one axis of a packed key.
const AXIS_BITS: u32 = 21;

/// The three 21-bit coordinates of a packed key, x first.
#[inline(always)]
pub(crate) fn axes(k: u64) -> [u64; 3] {
    const MASK: u64 = (1 << AXIS_BITS) - 1;
    [k >> (2 * AXIS_BITS), (k >> AXIS_BITS) & MASK, k & MASK]
}

/// A box of keys as a dense grid of cells.
pub(crate) struct BoxCells {
    min: [u64; 3],
    dims: [u64; 3],
    /// Cells in the box.
    pub(crate) count: usize,
}

impl BoxCells {
    /// The box from corner `lo` to corner `hi` (inclusive), when it has at
    /// most `limit` cells (and fewer than `u32::MAX`); `None` for `lo`
    /// past `hi` on an axis, as the box of no keys is.
    pub(crate) fn spanning(lo: [u64; 3], hi: [u64; 3], limit: u64) -> Option<BoxCells> {
        let mut dims = [0u64; 3];
        for a in 0..3 {
            dims[a] = hi[a].checked_sub(lo[a])? + 1;
        }
        let count = dims.iter().map(|&d| u128::from(d)).product::<u128>();
        (count <= u128::from(limit) && count < u128::from(u32::MAX)).then_some(BoxCells {
            min: lo,
            dims,
            count: count as usize,
        })
    }

    /// The box of `sets`, holding `total` keys, when it has at most
    /// `total + 65536` cells; `None` also where a word is no key (bit 63).
    pub(crate) fn of<S: AsRef<[u64]> + Sync>(sets: &[S], total: usize) -> Option<BoxCells> {
        // Per axis minimum and maximum, and the OR of all keys.
        let empty = ([u64::MAX; 3], [0u64; 3], 0u64);
        let (lo, hi, or) = sets
            .par_iter()
            .map(|s| {
                let (mut lo, mut hi, mut or) = empty;
                for &k in s.as_ref() {
                    let c = axes(k);
                    for a in 0..3 {
                        lo[a] = lo[a].min(c[a]);
                        hi[a] = hi[a].max(c[a]);
                    }
                    or |= k;
                }
                (lo, hi, or)
            })
            .reduce(
                || empty,
                |(l1, h1, o1), (l2, h2, o2)| {
                    (
                        [0, 1, 2].map(|a| l1[a].min(l2[a])),
                        [0, 1, 2].map(|a| h1[a].max(h2[a])),
                        o1 | o2,
                    )
                },
            );
        if total == 0 || or >> 63 != 0 {
            return None;
        }
        BoxCells::spanning(lo, hi, total as u64 + 65536)
    }

    /// Cell of key `k`, inside the box: lexicographic in (x, y, z) like the
    /// packed keys.
    #[inline]
    pub(crate) fn cell(&self, k: u64) -> u32 {
        let [x, y, z] = [0, 1, 2].map(|a| axes(k)[a] - self.min[a]);
        ((x * self.dims[1] + y) * self.dims[2] + z) as u32
    }

    /// The key of cell `cell`: [`Self::cell`] undone.
    #[inline]
    pub(crate) fn key(&self, cell: u32) -> u64 {
        let [_, dy, dz] = self.dims;
        let cell = u64::from(cell);
        let c = [cell / (dy * dz), cell / dz % dy, cell % dz];
        (c[0] + self.min[0]) << (2 * AXIS_BITS)
            | (c[1] + self.min[1]) << AXIS_BITS
            | (c[2] + self.min[2])
    }

    /// Marks the cell of each of `keys` (inside the box) in `bitmap`, a bit
    /// a cell, all zero before: it grows to the box's cells.
    pub(crate) fn mark(&self, keys: impl IntoIterator<Item = u64>, bitmap: &mut Vec<u64>) {
        bitmap.resize(self.count.div_ceil(64), 0);
        for k in keys {
            let cell = self.cell(k);
            bitmap[cell as usize / 64] |= 1 << (cell % 64);
        }
    }

    /// Appends the keys of the cells marked in `bitmap` to `out`, ascending,
    /// and clears them: `bitmap` is all zero again after.
    pub(crate) fn drain_marked(&self, bitmap: &mut [u64], out: &mut Vec<u64>) {
        for (w, word) in bitmap.iter_mut().enumerate() {
            let mut bits = std::mem::take(word);
            while bits != 0 {
                out.push(self.key(64 * w as u32 + bits.trailing_zeros()));
                bits &= bits - 1;
            }
        }
    }
}
