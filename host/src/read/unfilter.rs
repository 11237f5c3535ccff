//! PNG scanline unfiltering for two bytes per pixel (16-bit greyscale), the
//! step of depth decoding that costs the most.
//!
//! Byte `i` of a row is predicted from byte `i - 2` (left, `a`), byte `i` of
//! the row above (up, `b`) and byte `i - 2` above (up-left, `c`). The Paeth
//! filter, which depth encoders choose for most rows, makes each pixel wait
//! for its left neighbour: a row is one long dependency chain, about ten
//! cycles a pixel however the predictor is written. The only parallelism is
//! across rows, so on x86-64 several rows are unfiltered at once as a
//! wavefront: each row runs behind the one above it, so that the pixel
//! above and the one above-left of every lane are earlier outputs of the
//! lane before it. All four filters are computed for every lane and each
//! lane keeps its row's. Which wavefront runs is chosen at run time
//! ([`VectorUnit`]): with AVX2 (or AVX-512, which runs the same code),
//! sixteen rows, two pixels apart, in two vectors of sixteen 16-bit lanes
//! (`avx2.rs`); otherwise four rows, one pixel apart, in SSE2's eight lanes
//! (part of every x86-64 CPU). Rows too narrow for a wavefront, the last
//! rows of an image that do not fill a group, and other targets take the
//! row-at-a-time path; every path is checked against the specification.

use crate::vector_unit::VectorUnit;

/// Undoes the filters of `scanlines` in place: rows of `1 + row_bytes` bytes,
/// each a filter type byte followed by the filtered row. `row_bytes` must be
/// even. `unit` picks the wavefront (one of [`VectorUnit::available`];
/// others run as [`VectorUnit::Baseline`]). Returns the first unknown filter
/// type met, leaving later rows as they were.
pub(crate) fn unfilter_scanlines(
    unit: VectorUnit,
    scanlines: &mut [u8],
    row_bytes: usize,
) -> Result<(), u8> {
    let line = row_bytes + 1;
    if let Some(bad) = scanlines.chunks_exact(line).map(|l| l[0]).find(|&f| f > 4) {
        // Unfilter the rows before the bad one, so the error is the only
        // difference from a decoder that stops there.
        let rows = scanlines
            .chunks_exact(line)
            .take_while(|l| l[0] <= 4)
            .count();
        unfilter_checked(unit, &mut scanlines[..rows * line], row_bytes);
        return Err(bad);
    }
    unfilter_checked(unit, scanlines, row_bytes);
    Ok(())
}

/// Unfilters rows whose filter types are all known.
fn unfilter_checked(unit: VectorUnit, scanlines: &mut [u8], row_bytes: usize) {
    let line = row_bytes + 1;
    let rows = scanlines.len() / line;
    let mut done = 0;
    // Groups of `n` rows from row `done` on with `unfilter_group` (which
    // gets the group and the row above it).
    #[cfg(target_arch = "x86_64")]
    let mut groups = |n: usize, unfilter_group: &mut UnfilterGroup| {
        while done + n <= rows {
            let (before, group) = scanlines.split_at_mut(done * line);
            let above = before.get(before.len().wrapping_sub(row_bytes)..);
            unfilter_group(&mut group[..n * line], above);
            done += n;
        }
    };
    #[cfg(target_arch = "x86_64")]
    {
        let wide =
            matches!(unit, VectorUnit::Avx2 | VectorUnit::Avx512) && VectorUnit::Avx2.runs_here();
        if wide && row_bytes >= 2 * avx2::MIN_WIDTH {
            // SAFETY: the CPU has AVX2 (`runs_here`).
            let mut scratch = Vec::new();
            groups(avx2::ROWS, &mut |group, above| unsafe {
                avx2::unfilter_group(group, above, row_bytes, &mut scratch)
            });
        }
        if row_bytes >= 2 * wavefront::MIN_WIDTH {
            // SAFETY: `unfilter_four` only needs SSE2, which every x86-64
            // CPU has (it is part of the architecture's baseline).
            groups(4, &mut |group, above| unsafe {
                wavefront::unfilter_four(group, above, row_bytes)
            });
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = unit;
    for r in done..rows {
        let (before, rest) = scanlines.split_at_mut(r * line);
        let above = before.get(before.len().wrapping_sub(row_bytes)..);
        let (filter, row) = rest[..line].split_at_mut(1);
        unfilter_row(filter[0], row, above);
    }
}

/// A wavefront's unfiltering of a group of rows (the group, the row above).
#[cfg(target_arch = "x86_64")]
type UnfilterGroup<'a> = dyn FnMut(&mut [u8], Option<&[u8]>) + 'a;

/// One row, against the unfiltered row above (`None` for the first row,
/// which the specification treats as zeros).
fn unfilter_row(filter: u8, row: &mut [u8], above: Option<&[u8]>) {
    let zeros;
    let above = match above {
        Some(a) => a,
        None => {
            zeros = vec![0u8; row.len()];
            &zeros
        }
    };
    match filter {
        1 => {
            let mut left = [0u8; 2];
            for px in row.chunks_exact_mut(2) {
                left = [px[0].wrapping_add(left[0]), px[1].wrapping_add(left[1])];
                (px[0], px[1]) = (left[0], left[1]);
            }
        }
        2 => {
            for (x, up) in row.iter_mut().zip(above) {
                *x = x.wrapping_add(*up);
            }
        }
        3 => {
            let avg = |l: u8, u: u8| ((u16::from(l) + u16::from(u)) / 2) as u8;
            let mut left = [0u8; 2];
            for (px, up) in row.chunks_exact_mut(2).zip(above.chunks_exact(2)) {
                left = [
                    px[0].wrapping_add(avg(left[0], up[0])),
                    px[1].wrapping_add(avg(left[1], up[1])),
                ];
                (px[0], px[1]) = (left[0], left[1]);
            }
        }
        4 => {
            let (mut left, mut up_left) = ([0i16; 2], [0i16; 2]);
            for (px, up) in row.chunks_exact_mut(2).zip(above.chunks_exact(2)) {
                let up = [i16::from(up[0]), i16::from(up[1])];
                let x = [
                    px[0].wrapping_add(paeth(left[0], up[0], up_left[0])),
                    px[1].wrapping_add(paeth(left[1], up[1], up_left[1])),
                ];
                (px[0], px[1]) = (x[0], x[1]);
                left = [i16::from(x[0]), i16::from(x[1])];
                up_left = up;
            }
        }
        _ => {} // 0: None
    }
}

/// The Paeth predictor of a (left), b (up), c (up-left) in a branch-free
/// form equivalent to the specification's (stb_image's): `p = a + b - c`,
/// and the nearest of a, b, c to `p`, ties in that order.
#[inline(always)]
fn paeth(a: i16, b: i16, c: i16) -> u8 {
    let threshold = 3 * c - (a + b);
    let (lo, hi) = (a.min(b), a.max(b));
    let t = if hi <= threshold { lo } else { c };
    (if threshold <= lo { hi } else { t }) as u8
}

#[cfg(target_arch = "x86_64")]
mod avx2;

#[cfg(target_arch = "x86_64")]
mod wavefront {
    //! Four rows at once in SSE2 (part of every x86-64 CPU): lane pair `k` holds the two bytes of a
    //! pixel of row `k`, which at step `t` is pixel `t - k`.
    use std::arch::x86_64::*;

    /// Narrower rows are not worth the ramp-up and ramp-down.
    pub(super) const MIN_WIDTH: usize = 8;

    /// Unfilters four consecutive scanlines (`group`, each `1 + row_bytes`
    /// bytes, every filter type known) against `above`, the unfiltered row
    /// before them (`None`: zeros).
    #[target_feature(enable = "sse2")]
    pub(super) fn unfilter_four(group: &mut [u8], above: Option<&[u8]>, row_bytes: usize) {
        let line = row_bytes + 1;
        let width = row_bytes / 2;
        // Per lane, all ones where the lane's row uses the filter.
        let mut masks = [[0i16; 8]; 4]; // Sub, Up, Average, Paeth
        for k in 0..4 {
            if let Some(f @ 1..=4) = group.get(k * line).copied() {
                masks[usize::from(f - 1)][2 * k] = -1;
                masks[usize::from(f - 1)][2 * k + 1] = -1;
            }
        }
        let v = |m: [i16; 8]| _mm_set_epi16(m[7], m[6], m[5], m[4], m[3], m[2], m[1], m[0]);
        let filters = Filters {
            sub: v(masks[0]),
            up: v(masks[1]),
            average: v(masks[2]),
            paeth: v(masks[3]),
        };
        // The row above as the top lane pair's "up" at pixel x.
        let up_of = |x: usize| -> i32 {
            match above.and_then(|a| a.get(2 * x..2 * x + 2)) {
                Some(p) => i32::from(p[0]) | i32::from(p[1]) << 16,
                None => 0,
            }
        };
        let (r0, rest) = group.split_at_mut(line);
        let (r1, rest) = rest.split_at_mut(line);
        let (r2, r3) = rest.split_at_mut(line);
        let mut rows = [&mut r0[1..], &mut r1[1..], &mut r2[1..], &mut r3[1..line]];
        let mut state = State {
            out: _mm_setzero_si128(),
            up: _mm_setzero_si128(),
        };
        // Ramp-up and ramp-down: some lanes are outside their row; they read
        // zeros (so their outputs stay zero, as the specification's missing
        // neighbours are) and write nothing.
        let edge = |t: usize, rows: &mut [&mut [u8]; 4], state: &mut State| {
            let pixel = |k: usize| t.checked_sub(k).filter(|&x| x < width);
            let mut raw = 0u64;
            for (k, row) in rows.iter().enumerate() {
                if let Some(x) = pixel(k) {
                    let p = u64::from(row[2 * x]) | u64::from(row[2 * x + 1]) << 8;
                    raw |= p << (16 * k);
                }
            }
            let out = state.step(&filters, raw, up_of(t));
            for (k, row) in rows.iter_mut().enumerate() {
                if let Some(x) = pixel(k) {
                    (row[2 * x], row[2 * x + 1]) = (out[2 * k], out[2 * k + 1]);
                }
            }
        };
        for t in 0..3 {
            edge(t, &mut rows, &mut state);
        }
        for t in 3..width {
            let [a, b, c, d] = &mut rows;
            let (x0, x1, x2, x3) = (2 * t, 2 * t - 2, 2 * t - 4, 2 * t - 6);
            let pair = |r: &[u8], x: usize| u64::from(u16::from_le_bytes([r[x], r[x + 1]]));
            let raw = pair(a, x0) | pair(b, x1) << 16 | pair(c, x2) << 32 | pair(d, x3) << 48;
            let out = state.step(&filters, raw, up_of(t));
            // Byte by byte: a two-byte `copy_from_slice` can become a
            // call to memmove.
            (a[x0], a[x0 + 1]) = (out[0], out[1]);
            (b[x1], b[x1 + 1]) = (out[2], out[3]);
            (c[x2], c[x2 + 1]) = (out[4], out[5]);
            (d[x3], d[x3 + 1]) = (out[6], out[7]);
        }
        for t in width..width + 3 {
            edge(t, &mut rows, &mut state);
        }
    }

    struct Filters {
        sub: __m128i,
        up: __m128i,
        average: __m128i,
        paeth: __m128i,
    }

    /// The previous step's output (every lane's left neighbour now) and
    /// "up" vector (every lane's up-left neighbour now).
    struct State {
        out: __m128i,
        up: __m128i,
    }

    impl State {
        /// One step: `raw` holds the filtered bytes of the four lanes' pixels
        /// (byte `2k`, `2k + 1` for row `k`), `top_up` the two bytes above
        /// row 0's pixel. Returns the unfiltered bytes in the same order.
        #[target_feature(enable = "sse2")]
        #[inline]
        fn step(&mut self, f: &Filters, raw: u64, top_up: i32) -> [u8; 8] {
            let zero = _mm_setzero_si128();
            let raw = _mm_unpacklo_epi8(_mm_cvtsi64_si128(raw as i64), zero);
            let a = self.out;
            // Lane pair k's "up" is lane pair k - 1's last output.
            let b = _mm_or_si128(_mm_slli_si128::<4>(a), _mm_cvtsi32_si128(top_up));
            let c = self.up;
            let ab = _mm_add_epi16(a, b);
            let threshold = _mm_sub_epi16(_mm_add_epi16(c, _mm_add_epi16(c, c)), ab);
            let (lo, hi) = (_mm_min_epi16(a, b), _mm_max_epi16(a, b));
            // t = hi <= threshold ? lo : c;  p = threshold <= lo ? hi : t
            let select = |m: __m128i, x: __m128i, y: __m128i| {
                _mm_or_si128(_mm_and_si128(m, x), _mm_andnot_si128(m, y))
            };
            let t = select(_mm_cmpgt_epi16(hi, threshold), c, lo);
            let paeth = select(_mm_cmpgt_epi16(threshold, lo), t, hi);
            let average = _mm_srli_epi16::<1>(ab);
            let predicted = _mm_or_si128(
                _mm_or_si128(_mm_and_si128(f.sub, a), _mm_and_si128(f.up, b)),
                _mm_or_si128(
                    _mm_and_si128(f.average, average),
                    _mm_and_si128(f.paeth, paeth),
                ),
            );
            let out = _mm_and_si128(_mm_add_epi16(raw, predicted), _mm_set1_epi16(0xff));
            self.out = out;
            self.up = b;
            (_mm_cvtsi128_si64(_mm_packus_epi16(out, zero)) as u64).to_le_bytes()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The PNG specification's Paeth predictor, as written there.
    fn paeth_reference(a: u8, b: u8, c: u8) -> u8 {
        let p = i16::from(a) + i16::from(b) - i16::from(c);
        let (pa, pb, pc) = (
            (p - i16::from(a)).abs(),
            (p - i16::from(b)).abs(),
            (p - i16::from(c)).abs(),
        );
        if pa <= pb && pa <= pc {
            a
        } else if pb <= pc {
            b
        } else {
            c
        }
    }

    #[test]
    fn paeth_matches_the_specification_everywhere() {
        for a in 0..=255u8 {
            for b in 0..=255u8 {
                for c in 0..=255u8 {
                    let fast = paeth(i16::from(a), i16::from(b), i16::from(c));
                    assert_eq!(fast, paeth_reference(a, b, c), "a={a} b={b} c={c}");
                }
            }
        }
    }

    /// The specification's unfiltering, byte by byte.
    fn reference(scanlines: &[u8], row_bytes: usize) -> Vec<u8> {
        let mut out: Vec<u8> = Vec::new();
        for (r, line) in scanlines.chunks_exact(row_bytes + 1).enumerate() {
            for i in 0..row_bytes {
                let a = if i >= 2 {
                    out[r * row_bytes + i - 2]
                } else {
                    0
                };
                let b = if r > 0 {
                    out[(r - 1) * row_bytes + i]
                } else {
                    0
                };
                let c = if r > 0 && i >= 2 {
                    out[(r - 1) * row_bytes + i - 2]
                } else {
                    0
                };
                let pred = match line[0] {
                    0 => 0,
                    1 => a,
                    2 => b,
                    3 => ((u16::from(a) + u16::from(b)) / 2) as u8,
                    _ => paeth_reference(a, b, c),
                };
                out.push(line[1 + i].wrapping_add(pred));
            }
        }
        out
    }

    #[test]
    fn every_filter_mix_matches_the_specification_on_every_vector_unit() {
        let mut rng = crate::rng::SplitMix64::new(0x2545_f491_4f6c_dd1d);
        let mut next = move || rng.next_u64();
        let units = VectorUnit::available();
        // Widths around each wavefront's minimum (and odd ones), heights
        // around each group size; the last rows of a height that is not a
        // multiple take the narrower paths.
        let widths = [1usize, 2, 7, 8, 9, 13, 15, 16, 17, 31, 33, 47, 64, 101];
        let heights = [1usize, 3, 4, 5, 7, 8, 9, 12, 15, 16, 17, 23, 31, 33, 40];
        for width in widths {
            for height in heights {
                for trial in 0..6 {
                    let row_bytes = 2 * width;
                    let mut lines = vec![0u8; (row_bytes + 1) * height];
                    for line in lines.chunks_exact_mut(row_bytes + 1) {
                        // Trial 0: all Paeth; the others: a random mix.
                        line[0] = if trial == 0 { 4 } else { (next() % 5) as u8 };
                        for b in &mut line[1..] {
                            *b = next() as u8;
                        }
                    }
                    let expected = reference(&lines, row_bytes);
                    for &unit in &units {
                        let mut lines = lines.clone();
                        unfilter_scanlines(unit, &mut lines, row_bytes).unwrap();
                        let got: Vec<u8> = lines
                            .chunks_exact(row_bytes + 1)
                            .flat_map(|l| l[1..].to_vec())
                            .collect();
                        assert_eq!(got, expected, "{unit:?} {width}x{height} trial {trial}");
                    }
                }
            }
        }
    }

    #[test]
    fn unknown_filter_is_reported_after_the_rows_before_it() {
        for unit in VectorUnit::available() {
            let mut lines = vec![1, 1, 2, 3, 4, 7, 0, 0, 0, 0, 1, 9, 9, 9, 9];
            assert_eq!(unfilter_scanlines(unit, &mut lines, 4), Err(7));
            assert_eq!(
                &lines[..5],
                &[1, 1, 2, 4, 6],
                "{unit:?}: the row before is unfiltered"
            );
            assert_eq!(
                &lines[10..],
                &[1, 9, 9, 9, 9],
                "{unit:?}: the row after is untouched"
            );
        }
    }
}
