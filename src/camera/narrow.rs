//! The projection loop for cores without a 32x32->64-bit multiply (the
//! Cortex-M0+ of the RP2040): the same keys as `fast_loop`, from 32-bit
//! multiplies only, exact (no error bound, no fallback inside a row).
//!
//! A point is `P = raw * ray + t` in fixed point with 40 fraction bits
//! (`t` biased), and its biased key is `floor(P / 2^40)`. With
//! `ray = A 2^16 + B` (`0 <= B < 2^16`) and `t = T 2^40 + M 2^16 + L`
//! (`0 <= M < 2^24`, `0 <= L < 2^16`),
//!
//! `floor(P / 2^40) = T + floor(R / 2^24)`, where
//! `R = raw A + M + floor((raw B + L) / 2^16)`,
//!
//! exactly: `raw B + L < 2^32` always, and `R` fits an `i32` whenever
//! `raw_max * |A| + 2^24 + 2^16 < 2^31`, which [`fits`] checks once per row
//! (the ray is linear along a row, so its largest `|A|` is at an end). That
//! holds while the farthest valid depth is under ~120 voxels from the camera
//! (10 m at 0.3 m voxels is ~40); a row beyond it takes `fast_loop`.
//! Each axis then costs two single-cycle `muls` and a few adds and shifts,
//! where `fast_loop` calls the 64-bit multiply routine.

use crate::voxel::VoxelKey;

/// `|raw * A|` must stay below this for `R` to fit an `i32`:
/// `2^31 - 2^25`, leaving room for `M < 2^24` and the carry `< 2^16`.
const PRODUCT_LIMIT: u64 = (1 << 31) - (1 << 25);

/// Whether [`narrow_loop`] is exact for a row of `samples` samples whose
/// first ray is `ray`, stepped by `step`, with valid raws up to `raw_max`.
pub(super) fn fits(ray: &[i64; 3], step: &[i64; 3], samples: u32, raw_max: u32) -> bool {
    // `|ray| < 2^45` and `samples < 2^14` (the bound of `FrameProjector::new`
    // and `Intrinsics::MAX_SIDE`): nothing below wraps.
    let last = i64::from(samples.saturating_sub(1));
    ray.iter().zip(step).all(|(&first, &s)| {
        let end = first.wrapping_add(s.wrapping_mul(last));
        let largest = first.unsigned_abs().max(end.unsigned_abs());
        // `floor` rounds a negative ray's `A` one further from zero.
        let a = (largest >> 16) + 1;
        u64::from(raw_max).saturating_mul(a) < PRODUCT_LIMIT
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

    /// The biased key `floor((raw * ray + t) / 2^40)` of a ray given as
    /// `A 2^16 + B`, as a `u32` (negative keys wrap to values above `2^21`,
    /// which the range test refuses, as `fast_loop`'s high word does).
    #[inline(always)]
    fn key(self, raw: u32, ray: Ray) -> u32 {
        // `raw * b + low <= (2^16 - 1)^2 + 2^16 - 1 < 2^32`: never wraps.
        let carry = raw.wrapping_mul(ray.b_high >> 16).wrapping_add(self.low) >> 16;
        let r = (raw as i32)
            .wrapping_mul(ray.a)
            .wrapping_add(self.mid)
            .wrapping_add(carry as i32);
        self.high.wrapping_add((r >> 24) as u32)
    }
}

/// A fixed-point ray (or its step) as `a 2^16 + b`, `0 <= b < 2^16`, with
/// `b` kept in the high half of `b_high` (`b_high = b 2^16`): the halves
/// the key needs, stepped without 64-bit arithmetic, and `b`'s carry into
/// `a` is the carry flag of the add (an `adds` and an `adcs` a step, where
/// a `b` in the low half takes a shift, a mask and two adds).
#[derive(Clone, Copy)]
struct Ray {
    a: i32,
    b_high: u32,
}

impl Ray {
    /// `|ray| < 2^45` (the bound of `FrameProjector::new`): `a` fits.
    fn of(ray: i64) -> Ray {
        Ray {
            a: (ray >> 16) as i32,
            b_high: (ray as u32) << 16,
        }
    }

    /// The ray one sample on: the carry out of `b` moves into `a`.
    #[inline(always)]
    fn step(self, by: Ray) -> Ray {
        let (b_high, carry) = self.b_high.overflowing_add(by.b_high);
        Ray {
            a: self.a.wrapping_add(by.a).wrapping_add(i32::from(carry)),
            b_high,
        }
    }
}

/// `fast_loop` in 32-bit multiplies, for a row [`fits`] accepts: `t` is the
/// biased translation; returns the invalid samples.
#[inline(never)]
pub(super) fn narrow_loop(
    samples: impl Iterator<Item = u16>,
    ray: [i64; 3],
    step: [i64; 3],
    t: [i64; 3],
    (lo, span): (u32, u32),
    emit: &mut impl FnMut(Option<VoxelKey>),
) -> u32 {
    let [tx, ty, tz] = t.map(Split::of);
    let [mut x, mut y, mut z] = ray.map(Ray::of);
    let [sx, sy, sz] = step.map(Ray::of);
    let mut invalid = 0u32;
    for raw in samples {
        let raw = u32::from(raw);
        if raw.wrapping_sub(lo) > span {
            invalid += 1;
        } else {
            let (kx, ky, kz) = (tx.key(raw, x), ty.key(raw, y), tz.key(raw, z));
            emit(VoxelKey::from_biased(kx, ky, kz));
        }
        (x, y, z) = (x.step(sx), y.step(sy), z.step(sz));
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
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            seed = seed
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (seed >> 33) as u32
        };
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
            let mut unit = || next() as f32 / (1u64 << 31) as f32;
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
            let v = (next() % 480) as u16 / stride * stride;
            let row: [u16; 640] = core::array::from_fn(|_| (next() % 12_000) as u16);
            let samples = usize::from(proj.samples_per_row());
            let raws = || {
                row.iter()
                    .copied()
                    .step_by(usize::from(stride))
                    .take(samples)
            };
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
            let b = narrow_loop(raws(), ray, step, t, valid, &mut |key| {
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
}
