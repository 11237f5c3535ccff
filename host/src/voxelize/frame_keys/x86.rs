//! [`super::frame_keys_chunked`] compiled for AVX2 with the core's
//! portable kernel, and for AVX-512 with a kernel of its own: LLVM's
//! vectorization of the portable kernel spends about twice the
//! instructions of this hand-written one (masks kept in vectors instead of
//! mask registers, counts converted lane by lane). With AVX-512, bands of
//! four rows take the tile path of `tiles.rs` (single precision, a tile of
//! 4 x 8 samples at a time where its samples share a key) wherever it can
//! promise the exact keys; other rows (strides above 1, the last rows,
//! extreme scales) the exact kernel.

use super::{frame_keys_chunked, DepthImage, FrameProjector};
use placedb::camera::wide::{portable_chunk, ChunkCounts, ChunkRays, CHUNK};
use std::arch::x86_64::*;

mod tiles;

#[target_feature(enable = "avx2,bmi1")]
pub(super) fn frame_keys_avx2(
    proj: &FrameProjector,
    img: &DepthImage,
    keys: &mut Vec<u64>,
    row_keys: &mut Vec<u64>,
) -> (u32, u32) {
    // A closure, not the function itself: defined here, it is compiled
    // with this function's features, and the kernel inlined into it.
    let mut kernel =
        |raws: &_, rays, previous, chunk: &mut _| portable_chunk(raws, rays, previous, chunk);
    frame_keys_chunked(proj, img, keys, row_keys, &mut kernel)
}

#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx512cd,popcnt,bmi1")]
pub(super) fn frame_keys_avx512(
    proj: &FrameProjector,
    img: &DepthImage,
    keys: &mut Vec<u64>,
    row_keys: &mut Vec<u64>,
) -> (u32, u32) {
    let mut exact =
        |raws: &_, rays, previous, chunk: &mut _| avx512_chunk(raws, rays, previous, chunk);
    let mut bands = tiles::Bands::default();
    let samples = usize::from(proj.samples_per_row());
    row_keys.resize(samples, 0);
    let (mut valid, mut out_of_range) = (0u32, 0u32);
    // Rows below `done` were projected with their band.
    let mut done = 0u16;
    for v in (0..img.height).step_by(usize::from(proj.stride())) {
        if v < done {
            continue;
        }
        // Bands of four consecutive rows (stride 1) in single precision
        // where it can promise the exact keys.
        if proj.stride() == 1 && usize::from(v) % tiles::ROWS == 0 {
            if let Some(band_valid) = band(proj, img, v, samples, &mut bands, keys) {
                valid += band_valid;
                done = v + tiles::ROWS as u16;
                continue;
            }
        }
        let (row_valid, n) =
            proj.project_row_with(v, img.row(v), &mut out_of_range, row_keys, &mut exact);
        valid += row_valid;
        keys.extend_from_slice(&row_keys[..n]);
    }
    (valid, out_of_range)
}

/// Rows `v..v + 4` with [`tiles::Bands::band`], or `None` (nothing
/// appended) where it does not run: rows past the image or shorter than
/// `samples`, rays only the exact loop handles.
#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx512cd,popcnt,bmi1")]
fn band(
    proj: &FrameProjector,
    img: &DepthImage,
    v: u16,
    samples: usize,
    bands: &mut tiles::Bands,
    keys: &mut Vec<u64>,
) -> Option<u32> {
    if usize::from(v) + tiles::ROWS > usize::from(img.height) {
        return None;
    }
    let row = |r: usize| {
        let v = v + r as u16;
        Some((proj.row_chunk_rays(v)?, img.row(v).get(..samples)?))
    };
    let [a, b, c, d] = [row(0)?, row(1)?, row(2)?, row(3)?];
    let width = usize::from(img.width);
    let next = usize::from(v) + tiles::ROWS;
    let ahead = img.data.get(next * width..).unwrap_or(&[]);
    let ahead = &ahead[..ahead.len().min(tiles::ROWS * width)];
    bands.band(&[a.0, b.0, c.0, d.0], [a.1, b.1, c.1, d.1], ahead, keys)
}

/// [`portable_chunk`] eight samples per step: the same arithmetic on
/// 64-bit lanes, with validity, range and novelty as mask registers.
#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx512cd,popcnt,bmi1")]
#[inline]
fn avx512_chunk(
    raws: &[u16; CHUNK],
    rays: ChunkRays,
    previous: u64,
    keys: &mut [u64; CHUNK],
) -> ChunkCounts {
    let all = |x: i64| _mm512_set1_epi64(x);
    let lanes = _mm512_setr_epi64(0, 1, 2, 3, 4, 5, 6, 7);
    // Lane i's ray is the chunk's ray plus i steps; eight lanes a step.
    let ray = |a: usize| {
        _mm512_add_epi64(
            all(rays.ray[a]),
            _mm512_mullo_epi64(lanes, all(rays.step[a])),
        )
    };
    let (mut rx, mut ry, mut rz) = (ray(0), ray(1), ray(2));
    let step = |a: usize| all(rays.step[a].wrapping_mul(8));
    let (sx, sy, sz) = (step(0), step(1), step(2));
    let (tx, ty, tz) = (all(rays.t[0]), all(rays.t[1]), all(rays.t[2]));
    let (lo, span) = (all(rays.lo as i64), all(rays.span as i64));
    let (limit, no_key) = (all(1 << 61), all(-1));
    let mut before = all(previous as i64);
    let mut counts = ChunkCounts {
        new: 0,
        valid: 0,
        outside: 0,
    };
    for (g, (raw, out)) in raws
        .chunks_exact(8)
        .zip(keys.chunks_exact_mut(8))
        .enumerate()
    {
        // SAFETY: reads the 16 bytes of `raw`, eight u16.
        let raw = _mm512_cvtepu16_epi64(unsafe { _mm_loadu_si128(raw.as_ptr().cast()) });
        let ok = _mm512_cmple_epu64_mask(_mm512_sub_epi64(raw, lo), span);
        let p = |ray, t| _mm512_add_epi64(_mm512_mullo_epi64(raw, ray), t);
        let (px, py, pz) = (p(rx, tx), p(ry, ty), p(rz, tz));
        // 0xfe: a | b | c.
        let inside = _mm512_cmplt_epu64_mask(_mm512_ternarylogic_epi64::<0xfe>(px, py, pz), limit);
        let x = _mm512_slli_epi64::<42>(_mm512_srli_epi64::<40>(px));
        let y = _mm512_slli_epi64::<21>(_mm512_srli_epi64::<40>(py));
        let z = _mm512_srli_epi64::<40>(pz);
        let key = _mm512_mask_blend_epi64(
            ok & inside,
            no_key,
            _mm512_ternarylogic_epi64::<0xfe>(x, y, z),
        );
        // SAFETY: writes the 64 bytes of `out`, eight u64.
        unsafe { _mm512_storeu_si512(out.as_mut_ptr().cast(), key) };
        // Lane i's predecessor: lane i - 1, or the previous step's last.
        let shifted = _mm512_alignr_epi64::<7>(key, before);
        let new = _mm512_mask_cmpneq_epu64_mask(ok & inside, key, shifted);
        counts.new |= u64::from(new) << (8 * g);
        counts.valid += ok.count_ones();
        counts.outside += (ok & !inside).count_ones();
        before = key;
        (rx, ry, rz) = (
            _mm512_add_epi64(rx, sx),
            _mm512_add_epi64(ry, sy),
            _mm512_add_epi64(rz, sz),
        );
    }
    counts
}
