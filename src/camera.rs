//! Pinhole camera model, poses and back-projection of depth rows into voxel keys.
//!
//! The hot loop is [`FrameProjector::project_row`]: it is the only place that turns
//! depth pixels into world points, so the host yardstick, the online selector and
//! the firmware all voxelize identically. 64-bit hosts may take the chunked
//! form of the same arithmetic in [`wide`], tested against it key for key. Arithmetic is `f32` because a
//! Cortex-M4F has only a single-precision FPU; `f32` is exact enough for 0.3 m
//! voxels within a few kilometres of the origin.

use crate::voxel::{VoxelGrid, VoxelKey, AXIS_BIAS};
use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

mod narrow;
#[cfg(target_pointer_width = "64")]
pub mod wide;

/// Whether rows take [`narrow::narrow_loop`]: on ARMv6-M (Cortex-M0/M0+),
/// which has no 32x32->64-bit multiply, so `fast_loop`'s multiply-accumulates
/// are library calls. ARMv6-M is also the ARM profile without LDREX/STREX,
/// which is how `cfg` tells it from ARMv7-M (no 32-bit atomics).
const NARROW: bool = cfg!(all(target_arch = "arm", not(target_has_atomic = "32")));

/// Why a camera or pose description was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum CameraError {
    /// A focal length is not within [`Intrinsics::FOCAL_RANGE`] or not finite,
    /// or the principal point is not finite or lies more than an image
    /// side outside the image.
    BadIntrinsics,
    /// Width or height is zero or larger than [`Intrinsics::MAX_SIDE`].
    BadImageSize,
    /// The depth scale (units per metre) is not within
    /// [`FrameProjector::DEPTH_SCALE_RANGE`].
    BadDepthScale,
    /// The depth range is empty, negative or NaN.
    BadDepthRange,
    /// The pixel stride is zero or larger than [`Intrinsics::MAX_SIDE`].
    BadStride,
    /// A pose component is NaN or infinite.
    NonFinitePose,
    /// The rotation part is not a rotation (not orthonormal, or a reflection).
    NotARotation,
    /// The voxel size is outside [`VoxelGrid::SIZE_RANGE`] (or NaN), or the
    /// grid origin is not finite.
    BadVoxelSize,
    /// Depth scale, voxel size, image size or camera position are so extreme
    /// that projected coordinates would not fit the fixed-point range.
    ScaleOutOfRange,
}

/// Pinhole intrinsics of a depth image of `width x height` pixels.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Intrinsics {
    /// Image width in pixels.
    pub width: u16,
    /// Image height in pixels.
    pub height: u16,
    /// Focal length along x, pixels.
    pub fx: f32,
    /// Focal length along y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
}

impl Intrinsics {
    /// Largest accepted image side; far above any depth sensor, small enough that
    /// pixel coordinates are exact in `f32`.
    pub const MAX_SIDE: u16 = 8192;
    /// Plausible focal lengths, pixels: below 1 the field of view is all but
    /// 180 degrees, above 1e6 it is under a thousandth of a degree on the
    /// widest image: such values are a unit or parsing mistake.
    pub const FOCAL_RANGE: core::ops::RangeInclusive<f32> = 1.0..=1.0e6;

    /// Checks that the model can back-project: finite positive focal lengths, a
    /// finite principal point and a non-empty image.
    pub fn validate(&self) -> Result<(), CameraError> {
        let finite = self.fx.is_finite()
            && self.fy.is_finite()
            && self.cx.is_finite()
            && self.cy.is_finite();
        if self.width == 0
            || self.height == 0
            || self.width > Self::MAX_SIDE
            || self.height > Self::MAX_SIDE
        {
            return Err(CameraError::BadImageSize);
        }
        let (w, h) = (f32::from(self.width), f32::from(self.height));
        let plausible = Self::FOCAL_RANGE.contains(&self.fx)
            && Self::FOCAL_RANGE.contains(&self.fy)
            && (-w..=2.0 * w).contains(&self.cx)
            && (-h..=2.0 * h).contains(&self.cy);
        if !finite || !plausible {
            return Err(CameraError::BadIntrinsics);
        }
        Ok(())
    }
}

/// Which depths count as measurements, in metres: `min < z <= max`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DepthRange {
    /// Exclusive lower bound, metres (default 0.1).
    pub min: f32,
    /// Inclusive upper bound, metres (default 10); may be `f32::INFINITY`.
    pub max: f32,
}

impl Default for DepthRange {
    fn default() -> Self {
        DepthRange {
            min: 0.1,
            max: 10.0,
        }
    }
}

impl DepthRange {
    /// Checks `0 <= min < max` (max may be infinite, neither may be NaN).
    pub fn validate(&self) -> Result<(), CameraError> {
        if self.min.is_nan() || self.max.is_nan() || self.min < 0.0 || self.min >= self.max {
            return Err(CameraError::BadDepthRange);
        }
        Ok(())
    }
}

/// Camera-to-world pose `p_w = R p_c + t`, checked to be a proper rotation.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Pose {
    /// Translation, metres.
    pub translation: [f32; 3],
    /// Orientation as a unit quaternion `[qx, qy, qz, qw]`.
    pub rotation: [f32; 4],
}

impl Pose {
    /// Tolerance on `|q| - 1` and on `R^T R - I`: poses from files carry 6-9
    /// significant digits, anything further off is a broken pose, not rounding.
    pub const ROTATION_TOLERANCE: f32 = 1e-3;

    /// The identity pose.
    pub const IDENTITY: Pose = Pose {
        translation: [0.0; 3],
        rotation: [0.0, 0.0, 0.0, 1.0],
    };

    /// A pose from a translation and a quaternion `[qx, qy, qz, qw]` whose norm
    /// must be 1 within [`Self::ROTATION_TOLERANCE`]; it is renormalised.
    pub fn from_quaternion(translation: [f32; 3], q: [f32; 4]) -> Result<Pose, CameraError> {
        if translation.iter().chain(q.iter()).any(|c| !c.is_finite()) {
            return Err(CameraError::NonFinitePose);
        }
        let norm = libm::sqrtf(q.iter().map(|c| c * c).sum::<f32>());
        if libm::fabsf(norm - 1.0) > Self::ROTATION_TOLERANCE {
            return Err(CameraError::NotARotation);
        }
        Ok(Pose {
            translation,
            rotation: [q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm],
        })
    }

    /// A pose from a row-major rotation matrix and a translation; the matrix must
    /// be orthonormal with determinant +1 within [`Self::ROTATION_TOLERANCE`].
    pub fn from_matrix(
        rotation: [[f32; 3]; 3],
        translation: [f32; 3],
    ) -> Result<Pose, CameraError> {
        if rotation
            .iter()
            .flatten()
            .chain(translation.iter())
            .any(|c| !c.is_finite())
        {
            return Err(CameraError::NonFinitePose);
        }
        let m = matrix(rotation);
        let off = (m.transpose() * m - Matrix3::identity()).amax();
        if off > Self::ROTATION_TOLERANCE || m.determinant() <= 0.0 {
            return Err(CameraError::NotARotation);
        }
        let q = UnitQuaternion::from_matrix(&m);
        Ok(Pose {
            translation,
            rotation: [q.i, q.j, q.k, q.w],
        })
    }

    /// Row-major rotation matrix of this pose.
    pub fn rotation_matrix(&self) -> [[f32; 3]; 3] {
        let [x, y, z, w] = self.rotation;
        let m = UnitQuaternion::new_unchecked(Quaternion::new(w, x, y, z)).to_rotation_matrix();
        let m = m.matrix();
        [
            [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
            [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
            [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
        ]
    }

    /// Re-checks a pose that came from outside (e.g. the wire) as
    /// [`Pose::from_quaternion`] would.
    pub fn validate(&self) -> Result<(), CameraError> {
        Pose::from_quaternion(self.translation, self.rotation).map(|_| ())
    }

    /// World coordinates of a camera-frame point.
    pub fn transform(&self, p: [f32; 3]) -> [f32; 3] {
        let r = self.rotation_matrix();
        let v = matrix(r) * Vector3::from(p);
        [
            v.x + self.translation[0],
            v.y + self.translation[1],
            v.z + self.translation[2],
        ]
    }
}

/// The matrix of row-major `rows`.
fn matrix(rows: [[f32; 3]; 3]) -> Matrix3<f32> {
    let [[a, b, c], [d, e, f], [g, h, i]] = rows;
    Matrix3::new(a, b, c, d, e, f, g, h, i)
}

/// Back-projects the pixel `(u, v)` with depth `z` metres into the camera frame.
pub fn back_project(k: &Intrinsics, u: f32, v: f32, z: f32) -> [f32; 3] {
    [(u - k.cx) * z / k.fx, (v - k.cy) * z / k.fy, z]
}

/// Everything needed to turn one frame's depth rows into voxel keys, folded into
/// per-frame constants so that the per-pixel work is integer only.
///
/// A pixel's grid coordinate is `raw * D(u, v) + t` (raw depth units times the
/// ray direction per unit, plus the camera centre, all in voxels), and `D` is
/// linear in `u` along a row. Both are held in fixed point with `shift`
/// fractional bits, so a pixel costs three integer multiply-adds, three shifts
/// (an arithmetic shift is a floor) and one range test: no float-to-int
/// conversions, and bit-identical results on every CPU. The fixed-point
/// rounding moves a point by less than `raw * u * 2^-shift` voxels, about
/// 10^-6 voxel for a 640-pixel row at 10 m (`shift` is 40 for the usual depth
/// scales and voxel sizes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameProjector {
    /// World-from-camera rotation times metres per unit over voxel size.
    rotation: [[f32; 3]; 3],
    /// Camera centre relative to the grid origin, voxels, fixed point.
    translation: [i64; 3],
    shift: u32,
    inv_fx: f32,
    inv_fy: f32,
    cx: f32,
    cy: f32,
    /// Valid raw depths are `raw_min..=raw_max` (empty when min > max).
    raw_min: u16,
    raw_max: u16,
    width: u16,
    height: u16,
    stride: u16,
    /// What every row's rays share, computed once per frame ([`RowSetUp`]).
    rows: RowSetUp,
}

/// The parts of [`FrameProjector::row_rays`] that do not depend on the row,
/// computed once per frame: on a core without an FPU (the M0+) each float
/// operation is a library call, and a frame has hundreds of rows.
#[derive(Debug, Clone, Copy, PartialEq)]
struct RowSetUp {
    /// `rotation[a][0] * x0` per axis, `x0` the ray's x at pixel column 0:
    /// the first term of each row's ray, as that sum rounds it.
    first_term: [f32; 3],
    /// The fixed-point step from one sample to the next, per axis.
    step: [i64; 3],
    /// Every row of the frame fits [`narrow::fits`]: checked at the first
    /// and last sampled rows, which bound every row in between (a row's
    /// ray is monotone in `v`; see [`FrameProjector::every_row_fits_narrow`]).
    /// 1 for yes, 0 for no: not a `bool`, whose niche would make the
    /// `Option<(FrameMeta, FrameProjector)>` in the device state a non-zero
    /// byte when `None`, and so move the whole device static from `.bss`
    /// into flash (`host/tests/board_qemu.rs`, `firmware_fits_its_budget`).
    narrow: u8,
}

/// Fixed-point fraction bits tried first; fewer only for extreme scales.
const MAX_SHIFT: u32 = 40;
/// Below this the rounding would reach a visible share of a voxel.
const MIN_SHIFT: u32 = 20;

impl FrameProjector {
    /// Plausible depth scales, units per metre: from metres (1) to
    /// micrometres (1e6); sensors use 1000 (mm) or 5000 (TUM).
    pub const DEPTH_SCALE_RANGE: core::ops::RangeInclusive<f32> = 1.0..=1.0e6;

    /// Prepares the projection of one frame; validates every input.
    pub fn new(
        intrinsics: &Intrinsics,
        depth_scale: f32,
        range: DepthRange,
        stride: u16,
        grid: &VoxelGrid,
        pose: &Pose,
    ) -> Result<FrameProjector, CameraError> {
        intrinsics.validate()?;
        range.validate()?;
        grid.validate()?;
        pose.validate()?;
        if !Self::DEPTH_SCALE_RANGE.contains(&depth_scale) {
            return Err(CameraError::BadDepthScale);
        }
        if stride == 0 || stride > Intrinsics::MAX_SIDE {
            return Err(CameraError::BadStride);
        }
        let metres_per_unit = 1.0 / depth_scale;
        let per_unit = metres_per_unit / grid.voxel_size;
        let r = pose.rotation_matrix();
        let rotation = r.map(|row| row.map(|x| x * per_unit));
        let mut centre = [0.0f32; 3];
        for ((c, t), o) in centre.iter_mut().zip(&pose.translation).zip(&grid.origin) {
            *c = (t - o) / grid.voxel_size;
        }
        let (inv_fx, inv_fy) = (1.0 / intrinsics.fx, 1.0 / intrinsics.fy);
        // Largest |ray per unit| over the image, to keep raw * ray + t in i64.
        let far = |c: f32, side: u16, inv: f32| {
            libm::fmaxf(libm::fabsf(c), libm::fabsf(side as f32 - c)) * inv
        };
        let (x_max, y_max) = (
            far(intrinsics.cx, intrinsics.width, inv_fx),
            far(intrinsics.cy, intrinsics.height, inv_fy),
        );
        // An infinite factor would make `0 * inf = NaN` below, which `fmaxf`
        // drops, and the bound would pass while the rays saturate i64.
        if !(x_max.is_finite() && y_max.is_finite() && per_unit.is_finite()) {
            return Err(CameraError::ScaleOutOfRange);
        }
        let mut ray_max = 0.0f32;
        let mut centre_max = 0.0f32;
        for (m, c) in rotation.iter().zip(&centre) {
            let ray = libm::fabsf(m[0]) * x_max + libm::fabsf(m[1]) * y_max + libm::fabsf(m[2]);
            ray_max = libm::fmaxf(ray_max, ray);
            centre_max = libm::fmaxf(centre_max, libm::fabsf(*c));
        }
        let bound = 65535.0 * ray_max + centre_max;
        let shift = (MIN_SHIFT..=MAX_SHIFT)
            .rev()
            .find(|&s| bound < libm::ldexpf(1.0, 61 - s as i32))
            .ok_or(CameraError::ScaleOutOfRange)?;
        let one = libm::ldexpf(1.0, shift as i32);
        let translation = centre.map(|c| (c * one) as i64);
        let (raw_min, raw_max) = valid_raw_range(metres_per_unit, range);
        let x0 = -intrinsics.cx * inv_fx;
        let stride_i64 = i64::from(stride);
        let mut projector = FrameProjector {
            rotation,
            translation,
            shift,
            inv_fx,
            inv_fy,
            cx: intrinsics.cx,
            cy: intrinsics.cy,
            raw_min,
            raw_max,
            width: intrinsics.width,
            height: intrinsics.height,
            stride,
            rows: RowSetUp {
                first_term: rotation.map(|r| r[0] * x0),
                step: rotation.map(|r| fixed(r[0] * inv_fx, shift).wrapping_mul(stride_i64)),
                narrow: 0,
            },
        };
        projector.rows.narrow = u8::from(projector.every_row_fits_narrow());
        Ok(projector)
    }

    /// Whether [`narrow::fits`] accepts every row: it does when it accepts
    /// the first and the last sampled row. A row's first ray is monotone in
    /// `v` on each axis (`y` grows with `v`; a product with a fixed factor,
    /// a sum with a fixed term, IEEE rounding and the truncation to fixed
    /// point are all monotone), and sample `i`'s ray is that plus `i`
    /// steps, so its magnitude at any row is at most its magnitude at one of
    /// the two ends; `fits` bounds exactly those magnitudes.
    fn every_row_fits_narrow(&self) -> bool {
        let samples = u32::from(self.samples_per_row());
        let last_row = self
            .sampled_rows()
            .saturating_sub(1)
            .saturating_mul(self.stride);
        let raw_max = u32::from(self.raw_max);
        [0, last_row].iter().all(|&v| {
            let (ray, step) = self.row_rays(v);
            narrow::fits(&ray, &step, samples, raw_max)
        })
    }

    /// Image width this projector expects, pixels.
    pub fn width(&self) -> u16 {
        self.width
    }

    /// Image height this projector expects, pixels.
    pub fn height(&self) -> u16 {
        self.height
    }

    /// Pixel stride in u and v.
    pub fn stride(&self) -> u16 {
        self.stride
    }

    /// Whether row `v` is sampled at this stride.
    pub fn samples_row(&self, v: u16) -> bool {
        v.is_multiple_of(self.stride)
    }

    /// Back-projects the sampled pixels of a full-resolution image row `v`
    /// (`row[u]` is the depth of pixel `(u, v)`) and calls `emit` with the
    /// voxel key of every valid pixel, in order of `u`; returns how many valid
    /// pixels it saw. Rows the stride does not sample, and rows below the
    /// image, emit nothing; pixels past the image width are ignored. Points
    /// whose key does not fit [`VoxelKey`]'s range count as valid but are not
    /// emitted; `out_of_range` is incremented for each.
    pub fn project_row(
        &self,
        v: u16,
        row: &[u16],
        out_of_range: &mut u32,
        emit: impl FnMut(VoxelKey),
    ) -> u32 {
        if !self.projects_row(v) {
            return 0;
        }
        let samples = row.iter().copied().step_by(usize::from(self.stride));
        let samples = samples.take(usize::from(self.samples_per_row()));
        self.project::<false, NARROW>(v, samples, None, out_of_range, emit)
    }

    /// Like [`Self::project_row`] for a row that is already subsampled, as the
    /// wire carries it: `samples[i]` is the depth of pixel `(i * stride, v)`,
    /// and `v` must be a sampled row (`v % stride == 0`), else nothing is
    /// emitted. Consecutive valid pixels in one voxel emit its key once (a
    /// frame's voxels are a set; neighbouring pixels mostly share a voxel, and
    /// skipping the repeat here costs less than in the set).
    pub fn project_samples(
        &self,
        v: u16,
        samples: &[u16],
        out_of_range: &mut u32,
        emit: impl FnMut(VoxelKey),
    ) -> u32 {
        self.project_samples_with::<NARROW>(v, samples, out_of_range, emit)
    }

    /// [`Self::project_samples`] with the choice of the 32-bit loop made
    /// by the caller (`NARROW_LOOP`; [`NARROW`] on the device), so that host
    /// tests run the Cortex-M0+'s path too.
    #[inline(always)]
    pub(crate) fn project_samples_with<const NARROW_LOOP: bool>(
        &self,
        v: u16,
        samples: &[u16],
        out_of_range: &mut u32,
        emit: impl FnMut(VoxelKey),
    ) -> u32 {
        if !self.projects_row(v) {
            return 0;
        }
        let row = samples
            .get(..usize::from(self.samples_per_row()))
            .unwrap_or(samples);
        self.project::<true, NARROW_LOOP>(v, row.iter().copied(), Some(row), out_of_range, emit)
    }

    /// Sampled columns per row: `ceil(width / stride)`.
    pub fn samples_per_row(&self) -> u16 {
        self.width.div_ceil(self.stride)
    }

    /// Sampled rows per image: `ceil(height / stride)`.
    pub fn sampled_rows(&self) -> u16 {
        self.height.div_ceil(self.stride)
    }

    /// Whether row `v` is sampled and inside the image (the fixed-point range
    /// of [`Self::new`] holds only there).
    fn projects_row(&self, v: u16) -> bool {
        v < self.height && self.samples_row(v)
    }

    /// The one back-projection loop: `samples` yields the raw depths of
    /// pixels `u = 0, stride, 2 stride, ...` of row `v`, at most one row's
    /// worth (so `invalid` cannot wrap). With `RUNS`, a key equal to the
    /// previous one emitted is not emitted again. With `NARROW_LOOP`, rows
    /// [`narrow::fits`] accepts take [`narrow::narrow_loop`] when the
    /// samples are a slice, given as `whole` (the wire's rows; the loop
    /// indexes them within a chunk).
    #[inline(always)]
    fn project<const RUNS: bool, const NARROW_LOOP: bool>(
        &self,
        v: u16,
        samples: impl ExactSizeIterator<Item = u16>,
        whole: Option<&[u16]>,
        out_of_range: &mut u32,
        mut emit: impl FnMut(VoxelKey),
    ) -> u32 {
        // At most `MAX_SIDE` samples (the callers cut a row to the image).
        let seen = u32::try_from(samples.len()).unwrap_or(u32::MAX);
        let (mut ray, step) = self.row_rays(v);
        // Valid raws are `lo..=hi`: one unsigned compare of `raw - lo`.
        let (lo, hi) = (u32::from(self.raw_min), u32::from(self.raw_max));
        let Some(span) = hi.checked_sub(lo) else {
            return 0;
        };
        let mut last = u64::MAX;
        let mut emit_new = |key: Option<VoxelKey>| match key {
            Some(key) if RUNS && key.to_bits() == last => {}
            Some(key) => {
                last = key.to_bits();
                emit(key);
            }
            None => *out_of_range = out_of_range.saturating_add(1),
        };
        // Counting the invalid pixels keeps a counter out of the valid
        // pixels' path.
        let mut invalid = 0u32;
        if self.shift == MAX_SHIFT {
            let t = self.biased_translation();
            let fits = || self.rows.narrow == 1 || narrow::fits(&ray, &step, seen, hi);
            let narrow = whole.filter(|_| NARROW_LOOP && fits());
            invalid = match narrow {
                Some(row) => narrow::narrow_loop(row, ray, step, t, (lo, span), &mut emit_new),
                None => fast_loop(samples, ray, step, t, (lo, span), &mut emit_new),
            };
        } else {
            let (shift, t) = (self.shift, self.translation);
            for raw in samples {
                let raw = u32::from(raw);
                if raw.wrapping_sub(lo) > span {
                    invalid += 1;
                } else {
                    let raw = i64::from(raw);
                    let axis = |a: usize| {
                        raw.wrapping_mul(pick(&ray, a)).wrapping_add(pick(&t, a)) >> shift
                    };
                    emit_new(VoxelKey::from_wide(axis(0), axis(1), axis(2)));
                }
                for (r, s) in ray.iter_mut().zip(&step) {
                    *r = r.wrapping_add(*s);
                }
            }
        }
        seen.saturating_sub(invalid)
    }

    /// The fixed-point ray per raw unit through pixel `(0, v)`, and its step
    /// from one sample to the next: the ray through `(u, v)` is
    /// `base + u * step`, stepped from sample to sample, which integers do
    /// exactly.
    ///
    /// By definition, with `x0 = -cx / fx` and `y = (v - cy) / fy` (as
    /// `f32` products with the reciprocals), the ray of axis `a` is
    /// `fixed(m[a][0] x0 + m[a][1] y + m[a][2])` and its step
    /// `fixed(m[a][0] / fx) * stride`, `fixed(x)` being `x 2^shift`
    /// truncated to an integer; the parts without `v` come from [`RowSetUp`].
    fn row_rays(&self, v: u16) -> ([i64; 3], [i64; 3]) {
        let y = (f32::from(v) - self.cy) * self.inv_fy;
        let mut ray = [0i64; 3];
        for ((r, m), first) in ray
            .iter_mut()
            .zip(&self.rotation)
            .zip(&self.rows.first_term)
        {
            *r = fixed(first + m[1] * y + m[2], self.shift);
        }
        (ray, self.rows.step)
    }

    /// The translation with the key bias added: `raw * ray + t + 2^60` has
    /// the biased key `floor(. / 2^40)`, in range exactly when it is in
    /// `0..2^61`, i.e. when its high word shifted by 8 is below `2^21` (shift
    /// [`MAX_SHIFT`] only; `|raw * ray + t| < 2^61` by the bound of `new`, so
    /// adding `2^60` does not wrap).
    fn biased_translation(&self) -> [i64; 3] {
        let bias = i64::from(AXIS_BIAS) << MAX_SHIFT;
        self.translation.map(|t| t.wrapping_add(bias))
    }
}

/// `x 2^shift` truncated toward zero, as `(x * 2^shift) as i64` gives it
/// (the product is exact in `f32`: a power of two), without the float
/// multiply and the saturating conversion's compares, which a core without
/// an FPU makes library calls: from the bits, for every `x` whose result
/// is below `2^62` in magnitude (the rays and steps `FrameProjector::new`
/// bounds), and by the float path otherwise (NaN, infinities, huge values).
#[inline]
fn fixed(x: f32, shift: u32) -> i64 {
    let bits = x.to_bits();
    let exponent = ((bits >> 23) & 0xff) as i32;
    // Normal numbers have the implicit leading one; subnormals the exponent of the smallest normal.
    let (mantissa, exponent) = match exponent {
        0 => (bits & 0x7f_ffff, 1),
        e => ((bits & 0x7f_ffff) | 0x80_0000, e),
    };
    // `x = mantissa 2^(exponent - 150)`; the result is that times `2^shift`.
    let k = exponent - 150 + shift as i32;
    let magnitude = match k {
        // `mantissa < 2^24`: at most `2^62` after the shift.
        0..=38 => i64::from(mantissa) << k,
        -31..=-1 => i64::from(mantissa >> -k),
        ..=-32 => 0,
        _ => return (x * libm::ldexpf(1.0, shift as i32)) as i64,
    };
    if bits >> 31 == 0 {
        magnitude
    } else {
        -magnitude
    }
}

/// The projection loop at the usual shift ([`MAX_SHIFT`]), `t` the biased
/// translation: the biased key is the high word of the 64-bit fixed-point
/// coordinate shifted by 8, so each axis is one 32x32 multiply-accumulate
/// into the translation and one multiply-add. Returns the invalid samples.
/// Out of line, so that the loop gets the registers to itself (three 64-bit
/// rays and their steps hardly fit a 32-bit core's).
#[inline(never)]
fn fast_loop(
    samples: impl Iterator<Item = u16>,
    mut ray: [i64; 3],
    step: [i64; 3],
    t: [i64; 3],
    (lo, span): (u32, u32),
    emit: &mut impl FnMut(Option<VoxelKey>),
) -> u32 {
    let mut invalid = 0u32;
    for raw in samples {
        let raw = u32::from(raw);
        if raw.wrapping_sub(lo) > span {
            invalid += 1;
        } else {
            let high = |a: usize| high_word(raw, pick(&ray, a), pick(&t, a)) >> 8;
            emit(VoxelKey::from_biased(high(0), high(1), high(2)));
        }
        for (r, s) in ray.iter_mut().zip(&step) {
            *r = r.wrapping_add(*s);
        }
    }
    invalid
}

/// Bits 32..64 of `raw * ray + t`, for `raw < 2^16` and a sum that does not
/// wrap (as [`FrameProjector::new`] bounds it): the product of `raw` and the
/// low word of `ray`, accumulated onto `t` (one `umlal` on a Cortex-M), then
/// `raw` times the high word of `ray` (one `mla`). Exactly the high word of
/// the `i64` sum.
#[cfg(not(target_pointer_width = "64"))]
#[inline(always)]
fn high_word(raw: u32, ray: i64, t: i64) -> u32 {
    let (ray_low, ray_high) = (ray as u32, (ray >> 32) as u32);
    let low_sum = (u64::from(raw) * u64::from(ray_low)).wrapping_add(t as u64);
    ((low_sum >> 32) as u32).wrapping_add(raw.wrapping_mul(ray_high))
}

/// [`high_word`] where 64-bit multiplies are native (the host): the same
/// bits of the same wrapping sum, in one multiply-add.
#[cfg(target_pointer_width = "64")]
#[inline(always)]
fn high_word(raw: u32, ray: i64, t: i64) -> u32 {
    (i64::from(raw).wrapping_mul(ray).wrapping_add(t) >> 32) as u32
}

/// `a[i]` for `i < 3`, as the per-pixel loops use it: no bounds check to
/// panic (the index is a constant after inlining).
#[inline(always)]
fn pick(a: &[i64; 3], i: usize) -> i64 {
    match i {
        0 => a[0],
        1 => a[1],
        _ => a[2],
    }
}

/// The raw depths whose metres `raw * metres_per_unit` (in `f32`, as the
/// definition computes them) satisfy `min < z <= max`, as an inclusive range.
/// The predicate is monotone in `raw`, so two binary searches find its ends.
fn valid_raw_range(metres_per_unit: f32, range: DepthRange) -> (u16, u16) {
    let z = |raw: u32| raw as f32 * metres_per_unit;
    // Smallest raw with z > min, and smallest raw with z > max.
    let first = |pred: &dyn Fn(u32) -> bool| {
        let (mut lo, mut hi) = (0u32, 65536u32);
        while lo < hi {
            let mid = (lo + hi) / 2;
            if pred(mid) {
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        lo
    };
    let lo = first(&|raw| z(raw) > range.min);
    let past = first(&|raw| z(raw) > range.max);
    match (
        u16::try_from(lo),
        past.checked_sub(1).and_then(|h| u16::try_from(h).ok()),
    ) {
        (Ok(lo), Some(hi)) if lo <= hi && lo > 0 => (lo, hi),
        _ => (1, 0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn k() -> Intrinsics {
        Intrinsics {
            width: 640,
            height: 480,
            fx: 585.0,
            fy: 585.0,
            cx: 320.0,
            cy: 240.0,
        }
    }

    #[test]
    fn rejects_bad_intrinsics_and_poses() {
        let mut bad = k();
        bad.fx = 0.0;
        assert_eq!(bad.validate(), Err(CameraError::BadIntrinsics));
        bad = k();
        bad.cy = f32::NAN;
        assert_eq!(bad.validate(), Err(CameraError::BadIntrinsics));
        for (fx, cx) in [(0.5, 320.0), (2e6, 320.0), (585.0, 2000.0), (585.0, -700.0)] {
            bad = k();
            (bad.fx, bad.cx) = (fx, cx);
            assert_eq!(bad.validate(), Err(CameraError::BadIntrinsics), "{fx} {cx}");
        }
        bad = k();
        bad.width = 0;
        assert_eq!(bad.validate(), Err(CameraError::BadImageSize));
        assert_eq!(
            Pose::from_quaternion([0.0, f32::NAN, 0.0], [0.0, 0.0, 0.0, 1.0]),
            Err(CameraError::NonFinitePose)
        );
        assert_eq!(
            Pose::from_quaternion([0.0; 3], [0.0, 0.0, 0.0, 2.0]),
            Err(CameraError::NotARotation)
        );
        let reflection = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]];
        assert_eq!(
            Pose::from_matrix(reflection, [0.0; 3]),
            Err(CameraError::NotARotation)
        );
        let shear = [[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        assert_eq!(
            Pose::from_matrix(shear, [0.0; 3]),
            Err(CameraError::NotARotation)
        );
    }

    #[test]
    fn extreme_intrinsics_are_refused_not_overflowed() {
        // Found by fuzzing: 0 * inf = NaN slipped through the ray bound and
        // raw * ray overflowed i64 (a panic in debug, wrong keys in release).
        let grid = VoxelGrid::new(0.3, [0.0; 3]).unwrap();
        let mut k = k();
        k.cx = -5.9e29;
        k.fx = 5e-13;
        let r = FrameProjector::new(&k, 1000.0, DepthRange::default(), 1, &grid, &Pose::IDENTITY);
        assert_eq!(r, Err(CameraError::BadIntrinsics));
        // Plausible intrinsics, a camera 1e12 m away: the fixed-point range
        // is what refuses it.
        let far = Pose::from_quaternion([1e12, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]).unwrap();
        let r = FrameProjector::new(&self::k(), 1000.0, DepthRange::default(), 1, &grid, &far);
        assert_eq!(r, Err(CameraError::ScaleOutOfRange));
    }

    #[test]
    fn matrix_and_quaternion_agree() {
        // 90 degrees about z.
        let m = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]];
        let p = Pose::from_matrix(m, [1.0, 2.0, 3.0]).unwrap();
        let h = core::f32::consts::FRAC_1_SQRT_2;
        let q = Pose::from_quaternion([1.0, 2.0, 3.0], [0.0, 0.0, h, h]).unwrap();
        let a = p.transform([1.0, 0.0, 0.0]);
        let b = q.transform([1.0, 0.0, 0.0]);
        for i in 0..3 {
            assert!((a[i] - b[i]).abs() < 1e-6);
        }
        assert!((a[0] - 1.0).abs() < 1e-6 && (a[1] - 3.0).abs() < 1e-6);
    }

    #[test]
    fn projector_matches_definition() {
        let grid = VoxelGrid::new(0.3, [0.0; 3]).unwrap();
        let pose = Pose::from_quaternion([0.5, -0.2, 1.0], [0.1, 0.2, 0.3, 0.927]).unwrap();
        let proj =
            FrameProjector::new(&k(), 1000.0, DepthRange::default(), 1, &grid, &pose).unwrap();
        let mut row = [0u16; 640];
        row[10] = 2500;
        row[300] = 50; // 5 cm: below min depth
        row[600] = 12000; // 12 m: beyond max depth
        row[639] = 7000;
        let mut keys = [VoxelKey::new(0, 0, 0); 4];
        let mut n = 0;
        let mut oor = 0;
        let valid = proj.project_row(17, &row, &mut oor, |key| {
            keys[n] = key;
            n += 1;
        });
        assert_eq!((valid, n, oor), (2, 2, 0));
        for (i, (u, d)) in [(10u16, 2.5f32), (639, 7.0)].iter().enumerate() {
            let pc = back_project(&k(), *u as f32, 17.0, *d);
            let pw = pose.transform(pc);
            let expect = VoxelKey::new(
                libm::floorf(pw[0] / 0.3) as i32,
                libm::floorf(pw[1] / 0.3) as i32,
                libm::floorf(pw[2] / 0.3) as i32,
            );
            assert_eq!(keys[i], expect);
        }
    }

    /// The keys by the definition of the fixed-point projection: the
    /// voxel of `(raw * ray + t) >> shift` per axis, every ray stepped.
    fn reference_keys(proj: &FrameProjector, v: u16, row: &[u16], out: &mut [Option<u64>]) {
        let (mut ray, step) = proj.row_rays(v);
        let t = proj.translation;
        for (u, slot) in row.iter().step_by(proj.stride as usize).zip(out.iter_mut()) {
            let raw = i64::from(*u);
            *slot = (raw >= i64::from(proj.raw_min) && raw <= i64::from(proj.raw_max))
                .then(|| {
                    let axis = |a: usize| (raw * ray[a] + t[a]) >> proj.shift;
                    VoxelKey::from_wide(axis(0), axis(1), axis(2)).map(|k| k.to_bits())
                })
                .flatten();
            for a in 0..3 {
                ray[a] += step[a];
            }
        }
    }

    #[test]
    fn fast_path_matches_the_fixed_point_definition() {
        // Random poses, grids and depths (a small LCG; no std in this crate),
        // including voxels small enough for keys to leave the range.
        let mut rng = crate::test_rng::TestRng::new(0x2545_f491_4f6c_dd1d);
        let (mut checked, mut outside) = (0, 0);
        for case in 0..200 {
            let (grid, pose) = {
                let mut unit = || rng.unit();
                let voxel = [0.001, 0.05, 0.3, 2.0][case % 4];
                let grid = VoxelGrid::new(voxel, [unit() * 50.0 - 25.0, 0.0, unit()]).unwrap();
                let q = [unit() - 0.5, unit() - 0.5, unit() - 0.5, unit() + 0.1];
                let n = libm::sqrtf(q.iter().map(|c| c * c).sum::<f32>());
                let t = [unit() * 2e3 - 1e3, unit() * 10.0, unit() * 4e3 - 2e3];
                (grid, Pose::from_quaternion(t, q.map(|c| c / n)).unwrap())
            };
            let stride = 1 + (case % 5) as u16;
            let proj =
                FrameProjector::new(&k(), 1000.0, DepthRange::default(), stride, &grid, &pose)
                    .unwrap();
            assert_eq!(proj.shift, MAX_SHIFT);
            let v = (rng.next31() % 480) as u16 / stride * stride;
            let row: [u16; 640] = core::array::from_fn(|_| (rng.next31() % 12_000) as u16);
            let mut want = [None; 640];
            reference_keys(&proj, v, &row, &mut want);
            let (mut got, mut n, mut oor) = ([0u64; 640], 0, 0);
            let valid = proj.project_row(v, &row, &mut oor, |key| {
                got[n] = key.to_bits();
                n += 1;
            });
            #[cfg(target_pointer_width = "64")]
            chunked_matches(&proj, v, &row, &want);
            let emitted: usize = want.iter().filter(|w| w.is_some()).count();
            assert_eq!(n, emitted, "case {case}");
            assert_eq!(valid as usize, n + oor as usize, "case {case}");
            let mut expected = want.iter().flatten();
            assert!(
                got[..n].iter().all(|g| Some(g) == expected.next()),
                "case {case}"
            );
            checked += n;
            outside += oor;
        }
        assert!(checked > 10_000 && outside > 1_000, "{checked} {outside}");
    }

    #[test]
    fn fixed_matches_the_float_conversion() {
        let float = |x: f32, s: u32| (x * libm::ldexpf(1.0, s as i32)) as i64;
        let edges = [
            0.0f32,
            -0.0,
            f32::MIN_POSITIVE,
            -f32::MIN_POSITIVE / 3.0,
            f32::from_bits(1),
            0.5,
            -1.0,
            1.0 - f32::EPSILON,
            libm::ldexpf(1.0, 62 - 40),
            -libm::ldexpf(1.0, 62 - 40),
            libm::ldexpf(1.0, 62 - 40) * (1.0 - f32::EPSILON),
            f32::MAX,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
        ];
        for shift in MIN_SHIFT..=MAX_SHIFT {
            for &x in &edges {
                assert_eq!(fixed(x, shift), float(x, shift), "{x} {shift}");
            }
        }
        // Every 4093rd bit pattern (both signs, every exponent), at three shifts.
        for shift in [MIN_SHIFT, 33, MAX_SHIFT] {
            for bits in (0..=u32::MAX).step_by(4093) {
                let x = f32::from_bits(bits);
                assert_eq!(fixed(x, shift), float(x, shift), "{bits:#x} {shift}");
            }
        }
    }

    /// The rays of row `v` by the definition, every float operation per row.
    fn defined_rays(proj: &FrameProjector, v: u16) -> ([i64; 3], [i64; 3]) {
        let m = &proj.rotation;
        let one = libm::ldexpf(1.0, proj.shift as i32);
        let fixed = |x: f32| (x * one) as i64;
        let y = (f32::from(v) - proj.cy) * proj.inv_fy;
        let x0 = -proj.cx * proj.inv_fx;
        let stride = i64::from(proj.stride);
        let ray = m.map(|r| fixed(r[0] * x0 + r[1] * y + r[2]));
        let step = m.map(|r| fixed(r[0] * proj.inv_fx).wrapping_mul(stride));
        (ray, step)
    }

    #[test]
    fn rows_set_up_once_per_frame_give_the_defined_rays() {
        let mut rng = crate::test_rng::TestRng::new(0x0123_4567_89ab_cdef);
        let (mut narrow, mut wide, mut rows) = (0, 0, 0);
        for case in 0..300 {
            let mut unit = || rng.unit();
            let mut k = k();
            (k.fx, k.fy) = (200.0 + unit() * 800.0, 200.0 + unit() * 800.0);
            (k.cx, k.cy) = (unit() * 640.0, unit() * 480.0);
            let voxel = [0.01, 0.05, 0.3, 2.0][case % 4];
            let grid = VoxelGrid::new(voxel, [unit() * 50.0 - 25.0, 0.0, unit()]).unwrap();
            let q = [unit() - 0.5, unit() - 0.5, unit() - 0.5, unit() + 0.1];
            let n = libm::sqrtf(q.iter().map(|c| c * c).sum::<f32>());
            let t = [unit() * 2e3 - 1e3, unit() * 10.0, unit() * 4e3 - 2e3];
            let pose = Pose::from_quaternion(t, q.map(|c| c / n)).unwrap();
            let stride = 1 + (case % 4) as u16;
            let range = DepthRange {
                min: 0.1,
                max: [10.0, 40.0, 65.0][case % 3],
            };
            let Ok(proj) = FrameProjector::new(&k, 1000.0, range, stride, &grid, &pose) else {
                continue;
            };
            let samples = u32::from(proj.samples_per_row());
            let mut every_row_fits = true;
            for v in (0..480).step_by(usize::from(stride)) {
                let rays = proj.row_rays(v);
                assert_eq!(rays, defined_rays(&proj, v), "case {case} row {v}");
                let fits = narrow::fits(&rays.0, &rays.1, samples, u32::from(proj.raw_max));
                every_row_fits &= fits;
                rows += 1;
            }
            // The frame's check is exact here: it says yes exactly when
            // every row fits (it is sound in general, and the ends decide).
            assert_eq!(proj.rows.narrow == 1, every_row_fits, "case {case}");
            if every_row_fits {
                narrow += 1;
            } else {
                wide += 1;
            }
        }
        assert!(
            narrow > 50 && wide > 20 && rows > 20_000,
            "{narrow} {wide} {rows}"
        );
    }

    /// Each run of one key once.
    fn runs(keys: impl Iterator<Item = u64>) -> impl Iterator<Item = u64> {
        let mut last = None;
        keys.filter(move |&k| last.replace(k) != Some(k))
    }

    /// The chunked loop of 64-bit hosts with its portable kernel gives
    /// `want`'s keys, some consecutive repeats dropped, and its counts.
    #[cfg(target_pointer_width = "64")]
    fn chunked_matches(proj: &FrameProjector, v: u16, row: &[u16], want: &[Option<u64>]) {
        let (mut got, mut oor) = ([0u64; 640], 0);
        let (valid, n) = proj.project_row_into(v, row, &mut oor, &mut got);
        assert!(runs(got[..n].iter().copied()).eq(runs(want.iter().flatten().copied())));
        let samples = want.len().min(row.len().div_ceil(proj.stride as usize));
        let invalid = row.iter().step_by(proj.stride as usize).take(samples);
        let invalid = invalid
            .filter(|&&r| r < proj.raw_min || r > proj.raw_max)
            .count();
        assert_eq!(valid as usize, samples - invalid);
        assert_eq!(valid as usize, want.iter().flatten().count() + oor as usize);
    }

    #[test]
    fn stride_skips_rows_and_columns() {
        let grid = VoxelGrid::new(0.3, [0.0; 3]).unwrap();
        let proj = FrameProjector::new(
            &k(),
            1000.0,
            DepthRange::default(),
            4,
            &grid,
            &Pose::IDENTITY,
        )
        .unwrap();
        let row = [1000u16; 640];
        let mut oor = 0;
        assert_eq!(proj.project_row(1, &row, &mut oor, |_| {}), 0);
        assert_eq!(proj.project_row(8, &row, &mut oor, |_| {}), 160);
        assert_eq!((proj.samples_per_row(), proj.sampled_rows()), (160, 120));
    }

    #[test]
    fn subsampled_rows_give_the_same_keys() {
        let grid = VoxelGrid::new(0.3, [0.0; 3]).unwrap();
        let pose = Pose::from_quaternion([0.5, -0.2, 1.0], [0.1, 0.2, 0.3, 0.927]).unwrap();
        let proj =
            FrameProjector::new(&k(), 1000.0, DepthRange::default(), 3, &grid, &pose).unwrap();
        let row: [u16; 640] = core::array::from_fn(|u| (500 + 7 * u) as u16);
        let samples: [u16; 214] = core::array::from_fn(|i| row[3 * i]);
        let (mut full, mut sub) = ([0u64; 214], [0u64; 214]);
        let (mut nf, mut ns, mut oor) = (0, 0, 0);
        let valid_full = proj.project_row(9, &row, &mut oor, |key| {
            // Every pixel's key; repeats of the previous one dropped here.
            if nf == 0 || full[nf - 1] != key.to_bits() {
                full[nf] = key.to_bits();
                nf += 1;
            }
        });
        let valid_sub = proj.project_samples(9, &samples, &mut oor, |key| {
            sub[ns] = key.to_bits();
            ns += 1;
        });
        assert_eq!((valid_full, valid_sub, oor), (214, 214, 0));
        // The samples emit each run of one voxel once.
        assert!(nf > 1 && nf < 214, "{nf} runs");
        assert_eq!(&full[..nf], &sub[..ns]);
    }

    /// The wire's rows through the Cortex-M0+'s path (`narrow_loop`) and
    /// through `fast_loop` on random poses, grids and rows: the same keys,
    /// counts and out-of-range counts, each run of one key emitted once,
    /// and those runs the runs of the definition's keys.
    #[test]
    fn narrow_samples_give_the_keys_of_the_fast_samples() {
        let mut rng = crate::test_rng::TestRng::new(0x5851_f42d_4c95_7f2d);
        let (mut narrow_rows, mut keys, mut repeats) = (0, 0, 0);
        for case in 0..300 {
            let mut unit = || rng.unit();
            let voxel = [0.05, 0.1, 0.3, 2.0][case % 4];
            let grid = VoxelGrid::new(voxel, [unit() * 50.0 - 25.0, 0.0, unit()]).unwrap();
            let q = [unit() - 0.5, unit() - 0.5, unit() - 0.5, unit() + 0.1];
            let n = libm::sqrtf(q.iter().map(|c| c * c).sum::<f32>());
            let t = [unit() * 2e3 - 1e3, unit() * 10.0, unit() * 4e3 - 2e3];
            let pose = Pose::from_quaternion(t, q.map(|c| c / n)).unwrap();
            let stride = 1 + (case % 4) as u16;
            let proj =
                FrameProjector::new(&k(), 1000.0, DepthRange::default(), stride, &grid, &pose)
                    .unwrap();
            narrow_rows += usize::from(proj.rows.narrow);
            let v = (rng.next31() % 480) as u16 / stride * stride;
            // Smooth stretches (runs of one voxel) between random depths.
            let mut depth = 2000u32;
            let row: [u16; 640] = core::array::from_fn(|_| {
                match rng.next31() % 8 {
                    0 => depth = rng.next31() % 12_000,
                    1 => depth = 0,
                    _ => depth = (depth + rng.next31() % 8).min(12_000),
                }
                depth as u16
            });
            let samples = proj.samples_per_row();
            let row: &[u16] = &row[..usize::from(samples)];
            let (mut fast, mut narrow) = ([0u64; 640], [0u64; 640]);
            let (mut nf, mut nn, mut oor_fast, mut oor_narrow) = (0, 0, 0, 0);
            let valid_fast = proj.project_samples_with::<false>(v, row, &mut oor_fast, |key| {
                fast[nf] = key.to_bits();
                nf += 1;
            });
            let valid_narrow = proj.project_samples_with::<true>(v, row, &mut oor_narrow, |key| {
                narrow[nn] = key.to_bits();
                nn += 1;
            });
            assert_eq!(
                (valid_fast, oor_fast),
                (valid_narrow, oor_narrow),
                "case {case}"
            );
            assert_eq!(fast[..nf], narrow[..nn], "case {case}");
            assert!(narrow[..nn].windows(2).all(|w| w[0] != w[1]), "case {case}");
            // The definition's keys, one a valid pixel, at full resolution.
            let full: [u16; 640] = core::array::from_fn(|u| {
                if u % usize::from(stride) == 0 {
                    row.get(u / usize::from(stride)).copied().unwrap_or(0)
                } else {
                    0
                }
            });
            let mut want = [None; 640];
            reference_keys(&proj, v, &full, &mut want);
            let defined = want.iter().flatten().count();
            assert!(runs(want.iter().flatten().copied()).eq(narrow[..nn].iter().copied()));
            keys += nn;
            repeats += defined - nn;
        }
        assert!(narrow_rows > 200, "{narrow_rows} rows took narrow_loop");
        assert!(keys > 10_000 && repeats > 10_000, "{keys} {repeats}");
    }
}
