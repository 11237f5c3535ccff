//! Eight rows at once with AVX2 (sixteen 16-bit lanes: eight rows times two
//! bytes), for CPUs that have it (chosen at run time by the caller).
//!
//! Row `k` runs [`LAG`] pixels behind row `k - 1`, so a lane's "up" is the
//! output of the lane pair before it [`LAG`] steps ago: the cross-lane
//! shuffle that moves it into place is off the step-to-step dependency
//! chain, which is left with the predictor itself. Pixels go in and out
//! [`BLOCK`] steps at a time: sixteen pixels of each row (each row's block
//! starting [`LAG`] pixels before the previous row's) are loaded and
//! transposed into one vector per step, and the outputs transposed back and
//! stored. The rows are copied out and back with zeros before them and room
//! after, so that the ramp-up and ramp-down, where some lanes are outside
//! their rows, are whole blocks too.

use std::arch::x86_64::*;

/// Vectors of eight rows a step.
const VECTORS: usize = 2;
/// Rows a group.
pub(super) const ROWS: usize = 8 * VECTORS;
/// Pixels row `k` runs behind row `k - 1` (what [`State`] keeps assumes 2).
const LAG: usize = 2;
/// Steps per load, transpose and store.
const BLOCK: usize = 16;
/// Narrower rows are not worth the ramp-up and ramp-down.
pub(super) const MIN_WIDTH: usize = 2 * BLOCK;

/// Pixels of zeros before each row in the scratch copy: as many as the
/// last row's first block reaches before its row.
const PAD_BEFORE: usize = LAG * (ROWS - 1);
/// Pixels after each row in the scratch copy: as many as row 0's last
/// block reaches past its row.
const PAD_AFTER: usize = LAG * (ROWS - 1) + BLOCK;

/// Unfilters [`ROWS`] consecutive scanlines (`group`, each `1 + row_bytes`
/// bytes, every filter type known) against `above`, the unfiltered row
/// before them (`None`: zeros). `scratch` holds the copy the wavefront
/// runs on (grown as needed; its contents do not matter).
#[target_feature(enable = "avx2")]
pub(super) fn unfilter_group(
    group: &mut [u8],
    above: Option<&[u8]>,
    row_bytes: usize,
    scratch: &mut Vec<u8>,
) {
    let line = row_bytes + 1;
    let width = row_bytes / 2;
    let filters = Filters::of(group, line);
    // The row above and the group's rows with zeros before and room
    // after, so that every block is whole: the ramp-up's lanes before
    // their rows read zeros (and give zeros, as the specification's
    // missing neighbours are), the ramp-down's lanes past their rows'
    // ends give bytes no row keeps.
    let stride = 2 * (PAD_BEFORE + width + PAD_AFTER);
    scratch.resize(scratch.len().max((ROWS + 1) * stride), 0);
    let start = 2 * PAD_BEFORE;
    let (top_row, rows) = scratch.split_at_mut(stride);
    match above {
        Some(a) => top_row[start..start + row_bytes].copy_from_slice(&a[..row_bytes]),
        None => top_row[start..start + row_bytes].fill(0),
    }
    for (copy, line) in rows.chunks_exact_mut(stride).zip(group.chunks_exact(line)) {
        copy[..start].fill(0);
        copy[start..start + row_bytes].copy_from_slice(&line[1..]);
    }
    let zero = [_mm256_setzero_si256(); VECTORS];
    let mut state = State {
        left: zero,
        older: zero,
        up: zero,
    };
    // One register a row: its block's filtered bytes in, unfiltered out.
    let mut blocks = [_mm256_setzero_si256(); ROWS];
    let steps = width + LAG * (ROWS - 1);
    for t0 in (0..steps).step_by(BLOCK) {
        // Row k's block starts at pixel t0 - LAG k.
        let at = |k: usize| k * stride + 2 * (PAD_BEFORE + t0 - LAG * k);
        for (k, block) in blocks.iter_mut().enumerate() {
            *block = load(&rows[at(k)..]);
        }
        state.block(&filters, &mut blocks, load(&top_row[start + 2 * t0..]));
        for (k, block) in blocks.iter().enumerate() {
            store(&mut rows[at(k)..], *block);
        }
    }
    for (copy, line) in rows.chunks_exact(stride).zip(group.chunks_exact_mut(line)) {
        line[1..].copy_from_slice(&copy[start..start + row_bytes]);
    }
}

/// The first 32 bytes of `bytes`, which must have that many.
#[target_feature(enable = "avx2")]
#[inline]
fn load(bytes: &[u8]) -> __m256i {
    let block = &bytes[..32];
    // SAFETY: `block` is 32 bytes, the load's width (unaligned is fine).
    unsafe { _mm256_loadu_si256(block.as_ptr().cast()) }
}

/// Stores `v` to the first 32 bytes of `bytes`, which must have that many.
#[target_feature(enable = "avx2")]
#[inline]
fn store(bytes: &mut [u8], v: __m256i) {
    let block = &mut bytes[..32];
    // SAFETY: `block` is 32 bytes, the store's width.
    unsafe { _mm256_storeu_si256(block.as_mut_ptr().cast(), v) }
}

/// Per lane, all ones where the lane's row uses the filter.
struct Filters {
    sub: [__m256i; VECTORS],
    up: [__m256i; VECTORS],
    average: [__m256i; VECTORS],
    paeth: [__m256i; VECTORS],
}

impl Filters {
    #[target_feature(enable = "avx2")]
    #[inline]
    fn of(group: &[u8], line: usize) -> Filters {
        let mut masks = [[0i32; ROWS]; 4];
        for (k, line) in group.chunks_exact(line).take(ROWS).enumerate() {
            if let f @ 1..=4 = line[0] {
                // Both 16-bit lanes of the row's 32-bit pair.
                masks[usize::from(f - 1)][k] = -1;
            }
        }
        let vectors = |m: [i32; ROWS]| {
            let mut v = [_mm256_setzero_si256(); VECTORS];
            for (v, m) in v.iter_mut().zip(m.chunks_exact(8)) {
                *v = _mm256_setr_epi32(m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7]);
            }
            v
        };
        Filters {
            sub: vectors(masks[0]),
            up: vectors(masks[1]),
            average: vectors(masks[2]),
            paeth: vectors(masks[3]),
        }
    }
}

/// Per vector of eight rows: the outputs of the last two steps (`left`,
/// the latest: every lane's left neighbour now; `older`, which moved one
/// row down is every lane's "up" now, as [`LAG`] is 2) and the last step's
/// "up" vector (every lane's up-left neighbour now).
#[derive(Clone, Copy)]
struct State {
    left: [__m256i; VECTORS],
    older: [__m256i; VECTORS],
    up: [__m256i; VECTORS],
}

impl State {
    /// [`BLOCK`] steps: `blocks[k]` holds the 32 filtered bytes of row
    /// `k` from its block's first pixel, and gets them unfiltered; `top`
    /// holds the 32 bytes above row 0's.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn block(&mut self, f: &Filters, blocks: &mut [__m256i; ROWS], top: __m256i) {
        // Per vector v of eight rows and step s of the block, the 128-bit
        // half `s / 8` of `steps[v][s % 8]` holds step s's pixels, one per
        // row, row `8v + k`'s at bytes `2k`, `2k + 1`.
        let mut steps = [[_mm256_setzero_si256(); 8]; VECTORS];
        for (steps, rows) in steps.iter_mut().zip(blocks.chunks_exact(8)) {
            steps.copy_from_slice(rows);
            transpose(steps);
        }
        let tops = [
            _mm256_cvtepu8_epi16(_mm256_castsi256_si128(top)),
            _mm256_cvtepu8_epi16(_mm256_extracti128_si256::<1>(top)),
        ];
        // A local copy, so that the loop keeps it in registers.
        let mut state = *self;
        // The outputs of the first eight steps, until those of the last
        // eight join them.
        let mut first_half = steps;
        let mut raw = [_mm256_setzero_si256(); VECTORS];
        for (half, &top) in tops.iter().enumerate() {
            for j in 0..8 {
                for v in 0..VECTORS {
                    raw[v] = _mm256_cvtepu8_epi16(match half {
                        0 => _mm256_castsi256_si128(steps[v][j]),
                        _ => _mm256_extracti128_si256::<1>(steps[v][j]),
                    });
                }
                // The pixel above row 0's, in its 32-bit lane pair.
                let top = _mm256_permutevar8x32_epi32(top, _mm256_set1_epi32(j as i32));
                let out = state.step(f, raw, top);
                for v in 0..VECTORS {
                    if half == 0 {
                        first_half[v][j] = out[v];
                    } else {
                        // Back to bytes, steps j and j + 8 in the halves.
                        let packed = _mm256_packus_epi16(first_half[v][j], out[v]);
                        steps[v][j] = _mm256_permute4x64_epi64::<0b11_01_10_00>(packed);
                    }
                }
            }
        }
        *self = state;
        for (steps, rows) in steps.iter_mut().zip(blocks.chunks_exact_mut(8)) {
            transpose(steps);
            rows.copy_from_slice(steps);
        }
    }

    /// One step: `raw[v]` holds the filtered bytes of the pixels of rows
    /// `8v..8v + 8` (row `8v + k`'s in 16-bit lanes `2k`, `2k + 1`), `top`
    /// the two bytes above row 0's pixel in lanes 0 and 1. Returns the
    /// unfiltered bytes in the same lanes.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn step(&mut self, f: &Filters, raw: [__m256i; VECTORS], top: __m256i) -> [__m256i; VECTORS] {
        // Row k's "up" is row k - 1's output LAG steps ago (`older`, one
        // 32-bit lane pair on, the last into the next vector); row 0's is
        // `top`.
        let one_on = _mm256_setr_epi32(7, 0, 1, 2, 3, 4, 5, 6);
        let mut rotated = self.older;
        for r in &mut rotated {
            *r = _mm256_permutevar8x32_epi32(*r, one_on);
        }
        let mut out = [_mm256_setzero_si256(); VECTORS];
        for v in 0..VECTORS {
            let a = self.left[v];
            let b = _mm256_blend_epi32::<1>(rotated[v], if v == 0 { top } else { rotated[v - 1] });
            let c = self.up[v];
            // The Paeth predictor as `super::paeth` computes it.
            let threshold = _mm256_sub_epi16(
                _mm256_sub_epi16(_mm256_add_epi16(c, _mm256_add_epi16(c, c)), b),
                a,
            );
            let (lo, hi) = (_mm256_min_epi16(a, b), _mm256_max_epi16(a, b));
            // t = hi <= threshold ? lo : c;  p = threshold <= lo ? hi : t
            let t = _mm256_blendv_epi8(lo, c, _mm256_cmpgt_epi16(hi, threshold));
            let paeth = _mm256_blendv_epi8(hi, t, _mm256_cmpgt_epi16(threshold, lo));
            let average = _mm256_srli_epi16::<1>(_mm256_add_epi16(a, b));
            let predicted = _mm256_blendv_epi8(_mm256_and_si256(f.up[v], b), a, f.sub[v]);
            let predicted = _mm256_blendv_epi8(predicted, average, f.average[v]);
            let predicted = _mm256_blendv_epi8(predicted, paeth, f.paeth[v]);
            // Byte-wise: the high bytes are zero in both.
            out[v] = _mm256_add_epi8(raw[v], predicted);
            (self.older[v], self.left[v], self.up[v]) = (a, out[v], b);
        }
        out
    }
}

/// Transposes, in each 128-bit half, the 8x8 matrix of 16-bit elements
/// whose row `k` is that half of `r[k]`.
#[target_feature(enable = "avx2")]
#[inline]
fn transpose(r: &mut [__m256i; 8]) {
    let a = [
        _mm256_unpacklo_epi16(r[0], r[1]),
        _mm256_unpackhi_epi16(r[0], r[1]),
        _mm256_unpacklo_epi16(r[2], r[3]),
        _mm256_unpackhi_epi16(r[2], r[3]),
        _mm256_unpacklo_epi16(r[4], r[5]),
        _mm256_unpackhi_epi16(r[4], r[5]),
        _mm256_unpacklo_epi16(r[6], r[7]),
        _mm256_unpackhi_epi16(r[6], r[7]),
    ];
    let b = [
        _mm256_unpacklo_epi32(a[0], a[2]),
        _mm256_unpackhi_epi32(a[0], a[2]),
        _mm256_unpacklo_epi32(a[1], a[3]),
        _mm256_unpackhi_epi32(a[1], a[3]),
        _mm256_unpacklo_epi32(a[4], a[6]),
        _mm256_unpackhi_epi32(a[4], a[6]),
        _mm256_unpacklo_epi32(a[5], a[7]),
        _mm256_unpackhi_epi32(a[5], a[7]),
    ];
    *r = [
        _mm256_unpacklo_epi64(b[0], b[4]),
        _mm256_unpackhi_epi64(b[0], b[4]),
        _mm256_unpacklo_epi64(b[1], b[5]),
        _mm256_unpackhi_epi64(b[1], b[5]),
        _mm256_unpacklo_epi64(b[2], b[6]),
        _mm256_unpackhi_epi64(b[2], b[6]),
        _mm256_unpacklo_epi64(b[3], b[7]),
        _mm256_unpackhi_epi64(b[3], b[7]),
    ];
}
