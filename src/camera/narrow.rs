//! The projection loop for cores without a 32x32->64-bit multiply (the
//! Cortex-M0+ of the RP2040): the same keys as `fast_loop`, from 32-bit
//! multiplies only, one a valid sample and axis but for the few samples
//! next to a voxel edge, which take the exact form.
//!
//! A point is `P = raw * ray + t` in fixed point with 40 fraction bits
//! (`t` biased), and its biased key is `floor(P / 2^40)`. With
//! `A = floor(ray / 2^16)`, `B = ray - A 2^16` and `t = T 2^40 + M 2^16 + L`
//! (`0 <= M < 2^24`, `0 <= L < 2^16`),
//!
//! `floor(P / 2^40) = T + floor(R / 2^24)`, where
//! `R = raw A + M + floor((raw B + L) / 2^16)`,
//!
//! exactly (`raw B + L < 2^32`; `R` fits an `i32` as [`fits`] checks once
//! per row: the ray is linear along a row, so its largest `|A|` is at an
//! end; that holds while the farthest valid depth is under ~120 voxels from
//! the camera, 10 m at 0.3 m voxels is ~40; a row beyond it takes
//! `fast_loop`). That is [`Split::key`], two multiplies an axis.
//!
//! The loop takes one: `R' = raw A' + M`, with `A'` from a 32-bit ray that
//! is not stepped exactly (see [`narrow_loop`]) and is `A` or `A - 1`. Then
//! `R - R' = raw (A - A') + floor((raw B + L) / 2^16)` is in
//! `0..=raw_max + 2^16 - 1`, so `floor(R / 2^24) = floor(R' / 2^24)`
//! whenever `R' mod 2^24 < 2^24 - (raw_max + 2^16 - 1)`: all but about
//! `(raw_max + 2^16) / 2^24` of the samples an axis (1/220 at 10 m in
//! millimetres). A sample with an axis in that guard band takes the exact
//! key instead ([`Exact::key`]), so every key is exact.

use crate::voxel::VoxelKey;

/// `|raw * A'|` must stay below this for `R'` and `R` to fit an `i32`:
/// `2^31 - 2^25`, leaving room for `M < 2^24` and `R - R' < 2^17`.
const PRODUCT_LIMIT: u64 = (1 << 31) - (1 << 25);

/// Samples a chunk: the loop's 32-bit ray restarts exact at each chunk's
/// first sample, so its error (under two units of `2^-32` a step, see
/// [`narrow_loop`]) stays under the `2^8` that would take `A'` further
/// than `A - 1`.
const CHUNK: usize = 128;

/// `|ray|` must stay below this for the loop's 32-bit ray `floor(ray / 2^8)`
/// to fit an `i32` with room for its error (`2^30 + 2^8 < 2^31`).
const RAY_LIMIT: u64 = 1 << 38;

/// Whether [`narrow_loop`] is exact for a row of `samples` samples whose
/// first ray is `ray`, stepped by `step`, with valid raws up to `raw_max`.
pub(super) fn fits(ray: &[i64; 3], step: &[i64; 3], samples: u32, raw_max: u32) -> bool {
    // `|ray| < 2^45` and `samples < 2^14` (the bound of `FrameProjector::new`
    // and `Intrinsics::MAX_SIDE`): nothing below wraps.
    let last = i64::from(samples.saturating_sub(1));
    ray.iter().zip(step).all(|(&first, &s)| {
        let end = first.wrapping_add(s.wrapping_mul(last));
        let largest = first.unsigned_abs().max(end.unsigned_abs());
        // `floor` rounds a negative ray's `A` one further from zero, and
        // the loop's `A'` may be one below `A`.
        let a = (largest >> 16) + 2;
        largest < RAY_LIMIT && u64::from(raw_max).saturating_mul(a) < PRODUCT_LIMIT
    })
}

/// The translation of one axis split as `T 2^40 + M 2^16 + L`.
#[derive(Clone, Copy)]
struct Split {
    high: u32,
    mid: i32,
    low: u32,
}

impl Split {
    fn of(t: i64) -> Split {
        Split {
            // `|t| < 2^62` (biased), so `t >> 40` fits 22 bits and a sign.
            high: (t >> 40) as u32,
            mid: ((t >> 16) & 0xff_ffff) as i32,
            low: (t & 0xffff) as u32,
        }
    }

    /// The exact biased key `floor((raw * ray + t) / 2^40)`, as a `u32`
    /// (negative keys wrap to values above `2^21`, which the range test
    /// refuses, as `fast_loop`'s high word does).
    #[inline(always)]
    fn key(self, raw: u32, ray: i64) -> u32 {
        // `|ray| < 2^38` ([`fits`]): `A` fits; `0 <= B < 2^16`.
        let (a, b) = ((ray >> 16) as i32, (ray & 0xffff) as u32);
        // `raw * B + L <= (2^16 - 1)^2 + 2^16 - 1 < 2^32`: never wraps.
        let carry = raw.wrapping_mul(b).wrapping_add(self.low) >> 16;
        let r = (raw as i32)
            .wrapping_mul(a)
            .wrapping_add(self.mid)
            .wrapping_add(carry as i32);
        self.high.wrapping_add((r >> 24) as u32)
    }

    /// The biased key from `R'` when it is outside the guard band.
    #[inline(always)]
    fn fast_key(self, r: i32) -> u32 {
        self.high.wrapping_add((r >> 24) as u32)
    }
}

/// What the exact key of any sample of the row needs; out of the loop's
/// registers, read by the few samples in the guard band.
struct Exact {
    ray: [i64; 3],
    step: [i64; 3],
    t: [Split; 3],
}

impl Exact {
    /// The exact biased key on `axis` of sample `index` (depth `raw`): its
    /// ray is `ray + index * step`, exactly (`fits` bounds it at both ends).
    /// Out of line and apart for each axis, so that the loop keeps a branch
    /// an axis to it rather than computing every axis's test.
    #[cold]
    #[inline(never)]
    fn key(&self, axis: usize, raw: u32, index: u32) -> u32 {
        let (ray, step, t) = match axis {
            0 => (self.ray[0], self.step[0], self.t[0]),
            1 => (self.ray[1], self.step[1], self.t[1]),
            _ => (self.ray[2], self.step[2], self.t[2]),
        };
        t.key(raw, ray.wrapping_add(step.wrapping_mul(i64::from(index))))
    }
}

/// The smallest `(R' mod 2^24) 2^8` (the `u32` `R' << 8`) in the guard band
/// for valid raws up to `raw_max`: with `D = raw_max + 2^16 - 1`, the bound
/// of `R - R'`, a sample is safe when `R' mod 2^24 <= 2^24 - 1 - D`, that is
/// (a multiple of `2^8`) when `R' << 8 < (2^24 - D) 2^8`.
fn guard(raw_max: u32) -> u32 {
    // `raw_max < 2^16`: `D < 2^17`, nothing wraps.
    ((1 << 24) - (raw_max + 0xffff)) << 8
}

/// `fast_loop` in 32-bit multiplies, for a row [`fits`] accepts: `t` is the
/// biased translation; returns the invalid samples.
///
/// The ray of sample `i` is `ray + i * step` (40 fraction bits). The loop
/// holds it as `F = floor(ray / 2^8)` in an `i32` (`|ray| < 2^38`), exact at
/// the first sample `c` of each chunk of [`CHUNK`], and for the `j`-th
/// sample of the chunk (`j < 2^7`) takes `F' = F_c + 2 j floor(step / 2^9)`
/// and `A' = floor(F' / 2^8)`. With `ray_c = 2^8 p + rho` and
/// `step = 2^9 q + sigma` (`0 <= rho < 2^8`, `0 <= sigma < 2^9`), the exact
/// `F = p + 2 j q + floor((rho + j sigma) / 2^8)` and `F' = p + 2 j q`, so
/// `0 <= F - F' <= floor((255 + 511 j) / 2^8) < 2^8`; then `A = floor(F / 2^8)`
/// (floors nest) and `A'` differ by 0 or 1, `A' <= A`, as the module's
/// bound needs. `|F| < 2^30`, so `F'` fits an `i32` and wrapping
/// arithmetic gives it exactly.
///
/// `2 j` is the sample's address less the chunk's (`u16`s): the loop takes
/// `F' = (F_c - 2 q start) + 2 q address` (wrapping, so only the difference
/// counts, on any pointer width), and so needs no counter besides the
/// slice's pointer, which is a register on the Cortex-M0+.
#[inline(never)]
pub(super) fn narrow_loop(
    samples: &[u16],
    ray: [i64; 3],
    step: [i64; 3],
    t: [i64; 3],
    (lo, span): (u32, u32),
    emit: &mut impl FnMut(Option<VoxelKey>),
) -> u32 {
    let exact = Exact {
        ray,
        step,
        t: t.map(Split::of),
    };
    let [tx, ty, tz] = exact.t;
    let guard = guard(lo.wrapping_add(span));
    // `q = floor(step / 2^9)`, wrapping: only `2 j q` modulo `2^32` counts.
    let [sx, sy, sz] = step.map(|s| (s >> 9) as i32);
    let address = |raw: &u16| (raw as *const u16 as usize) as u32 as i32;
    let mut first = ray;
    let (mut invalid, mut base) = (0u32, 0u32);
    for chunk in samples.chunks(CHUNK) {
        let start = chunk.first().map_or(0, address);
        let f = |ray: i64, s: i32| ((ray >> 8) as i32).wrapping_sub(start.wrapping_mul(s));
        let (fx, fy, fz) = (f(first[0], sx), f(first[1], sy), f(first[2], sz));
        for raw_at in chunk {
            let raw = u32::from(*raw_at);
            if raw.wrapping_sub(lo) > span {
                invalid += 1;
                continue;
            }
            let at = address(raw_at);
            // `R'` of one axis: `raw A' + M`.
            let r = |f: i32, s: i32, t: Split| {
                let a = f.wrapping_add(s.wrapping_mul(at)) >> 8;
                (raw as i32).wrapping_mul(a).wrapping_add(t.mid)
            };
            let (rx, ry, rz) = (r(fx, sx, tx), r(fy, sy, ty), r(fz, sz, tz));
            // The key of one axis, exact in the guard band.
            let key = |axis: usize, r: i32, t: Split| {
                if (r as u32) << 8 >= guard {
                    // The sample's index in the row.
                    let j = (at.wrapping_sub(start) as u32) >> 1;
                    exact.key(axis, raw, base.wrapping_add(j))
                } else {
                    t.fast_key(r)
                }
            };
            let (kx, ky, kz) = (key(0, rx, tx), key(1, ry, ty), key(2, rz, tz));
            emit(VoxelKey::from_biased(kx, ky, kz));
        }
        base = base.wrapping_add(CHUNK as u32);
        // The next chunk's first ray, exactly (wrapping only past the row).
        for (f, s) in first.iter_mut().zip(&step) {
            *f = f.wrapping_add(s.wrapping_mul(CHUNK as i64));
        }
    }
    invalid
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{fast_loop, DepthRange, FrameProjector, Intrinsics, Pose};
    use crate::voxel::VoxelGrid;

    /// Every key of both loops on random poses, grids and rows, including
    /// keys out of range and rows `fits` refuses (counted, not compared).
    #[test]
    fn narrow_loop_gives_the_keys_of_fast_loop() {
        let mut rng = crate::test_rng::TestRng::new(0x9e37_79b9_7f4a_7c15);
        let k = Intrinsics {
            width: 640,
            height: 480,
            fx: 585.0,
            fy: 585.0,
            cx: 320.0,
            cy: 240.0,
        };
        let (mut compared, mut refused, mut outside) = (0usize, 0usize, 0usize);
        for case in 0..400 {
            let mut unit = || rng.unit();
            let voxel = [0.02, 0.1, 0.3, 2.0][case % 4];
            let grid = VoxelGrid::new(voxel, [unit() * 50.0 - 25.0, 0.0, unit()]).unwrap();
            let q = [unit() - 0.5, unit() - 0.5, unit() - 0.5, unit() + 0.1];
            let n = libm::sqrtf(q.iter().map(|c| c * c).sum::<f32>());
            // Some cameras at the edge of the key range (2^20 voxels).
            let x = if case % 7 == 0 {
                (1_048_560.0 + unit() * 30.0) * voxel * if case % 2 == 0 { 1.0 } else { -1.0 }
            } else {
                unit() * 4e3 - 2e3
            };
            let t = [x, unit() * 10.0, unit() * 4e3 - 2e3];
            let pose = Pose::from_quaternion(t, q.map(|c| c / n)).unwrap();
            let stride = 1 + (case % 3) as u16;
            let range = DepthRange::default();
            let proj = FrameProjector::new(&k, 1000.0, range, stride, &grid, &pose).unwrap();
            let v = (rng.next31() % 480) as u16 / stride * stride;
            let row: [u16; 640] = core::array::from_fn(|_| (rng.next31() % 12_000) as u16);
            let samples = usize::from(proj.samples_per_row());
            let mut sampled = [0u16; 640];
            for (s, &r) in sampled
                .iter_mut()
                .zip(row.iter().step_by(usize::from(stride)))
            {
                *s = r;
            }
            let sampled = &sampled[..samples];
            let raws = || sampled.iter().copied();
            let (ray, step) = proj.row_rays(v);
            let t = proj.biased_translation();
            let valid = (
                u32::from(proj.raw_min),
                u32::from(proj.raw_max - proj.raw_min),
            );
            if !fits(&ray, &step, samples as u32, u32::from(proj.raw_max)) {
                refused += 1;
                continue;
            }
            let (mut want, mut got) = ([None; 640], [None; 640]);
            let (mut i, mut j) = (0, 0);
            let a = fast_loop(raws(), ray, step, t, valid, &mut |key| {
                want[i] = key;
                i += 1;
            });
            let b = narrow_loop(sampled, ray, step, t, valid, &mut |key| {
                got[j] = key;
                j += 1;
            });
            assert_eq!((a, i), (b, j), "case {case}");
            assert_eq!(want[..i], got[..j], "case {case}");
            compared += i;
            outside += want[..i].iter().filter(|k| k.is_none()).count();
        }
        assert!(compared > 50_000 && outside > 1_000, "{compared} {outside}");
        assert!(refused > 10 && refused < 200, "{refused} rows refused");
    }

    /// Rows built to put many samples within the guard band of a voxel
    /// edge, on both sides of it and on every axis: a ray of about
    /// `+-1/8` voxel a raw unit puts every eighth raw at the same offset
    /// from an edge, which the translation sets to within `2^32` of it.
    #[test]
    fn narrow_loop_is_exact_next_to_voxel_edges() {
        let mut rng = crate::test_rng::TestRng::new(0x2545_f491_4f6c_dd1d);
        let mut next = move || i64::from(rng.next31());
        // Valid raws 1..=1000: `1000 (2^21 + 2^7) < 2^31 - 2^25`, so it fits.
        let (lo, span) = (1u32, 999u32);
        let (mut compared, mut banded) = (0usize, 0usize);
        for case in 0..300 {
            let mut axis = || {
                let sign = if next() % 2 == 0 { 1 } else { -1 };
                let ray = sign * ((1i64 << 37) + next() % (1 << 20));
                let step = next() % (1 << 12) - (1 << 11);
                let edge = (next() % 2000 - 1000) << 40;
                let t = edge + (1i64 << 60) + (next() << 2) - (1 << 32);
                (ray, step, t)
            };
            let [(rx, sx, tx), (ry, sy, ty), (rz, sz, tz)] = [axis(), axis(), axis()];
            let (ray, step, t) = ([rx, ry, rz], [sx, sy, sz], [tx, ty, tz]);
            let samples = 300 + (case % 400);
            assert!(fits(&ray, &step, samples as u32, lo + span), "case {case}");
            let row: [u16; 700] = core::array::from_fn(|_| (next() % 1100) as u16);
            let raws = || row.iter().copied().take(samples);
            let (mut want, mut got) = ([None; 700], [None; 700]);
            let (mut i, mut j) = (0, 0);
            let a = fast_loop(raws(), ray, step, t, (lo, span), &mut |key| {
                want[i] = key;
                i += 1;
            });
            let b = narrow_loop(&row[..samples], ray, step, t, (lo, span), &mut |key| {
                got[j] = key;
                j += 1;
            });
            assert_eq!((a, i), (b, j), "case {case}");
            assert_eq!(want[..i], got[..j], "case {case}");
            compared += i;
            // Samples the guard band catches on some axis, by the
            // definition: within `(raw_max + 2^16) 2^16` below an edge.
            let band = i128::from(lo + span + (1 << 16)) << 16;
            for (n, raw) in raws().enumerate() {
                let raw = i128::from(raw);
                if raw < i128::from(lo) || raw > i128::from(lo + span) {
                    continue;
                }
                let near = (0..3).any(|a| {
                    let ray = i128::from(ray[a]) + n as i128 * i128::from(step[a]);
                    let gap = (1i128 << 40) - (raw * ray + i128::from(t[a])).rem_euclid(1 << 40);
                    gap <= band
                });
                banded += usize::from(near);
            }
        }
        assert!(compared > 100_000 && banded > 5_000, "{compared} {banded}");
    }
}
