//! [`super::frame_keys_chunked`] compiled for AVX2 with the core's
//! portable kernel, and for AVX-512 with a kernel of its own: LLVM's
//! vectorization of the portable kernel spends about twice the
//! instructions of this hand-written one (masks kept in vectors instead of
//! mask registers, counts converted lane by lane).

use super::{frame_keys_chunked, DepthImage, FrameProjector};
use placedb::camera::wide::{portable_chunk, ChunkCounts, ChunkRays, CHUNK};
use std::arch::x86_64::*;

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

#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,popcnt,bmi1")]
pub(super) fn frame_keys_avx512(
    proj: &FrameProjector,
    img: &DepthImage,
    keys: &mut Vec<u64>,
    row_keys: &mut Vec<u64>,
) -> (u32, u32) {
    let mut kernel =
        |raws: &_, rays, previous, chunk: &mut _| avx512_chunk(raws, rays, previous, chunk);
    frame_keys_chunked(proj, img, keys, row_keys, &mut kernel)
}

/// [`portable_chunk`] eight samples per step: the same arithmetic on
/// 64-bit lanes, with validity, range and novelty as mask registers.
#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,popcnt,bmi1")]
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
