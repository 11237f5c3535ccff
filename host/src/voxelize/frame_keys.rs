//! One frame's voxel keys with the widest vector unit the CPU has, chosen
//! at run time (the build targets baseline x86-64, whose SSE2 has two
//! 64-bit lanes and no 64-bit multiply). With AVX2 or AVX-512 the core's
//! chunked row loop ([`FrameProjector::project_row_with`]) runs, compiled
//! for that unit, with the core's portable kernel (AVX2) or a hand-written
//! one (AVX-512, `x86.rs`, which takes four rows at a time in single
//! precision where it can promise the exact keys); elsewhere (baseline
//! x86-64, other targets) the core's per-pixel loop, which the chunked one
//! does not beat there.

use crate::sequence::DepthImage;
#[cfg(target_arch = "x86_64")]
use placedb::camera::wide::{ChunkCounts, ChunkRays, CHUNK};
use placedb::FrameProjector;

use crate::vector_unit::VectorUnit;

#[cfg(target_arch = "x86_64")]
mod x86;

/// Appends to `keys` the keys of every sampled row of `img`, some repeats
/// dropped and in no particular order: the frame's key set, with `unit`,
/// which must be one of
/// [`VectorUnit::available`] (others run as [`VectorUnit::Baseline`]).
/// `row_keys` is scratch space. Returns the valid pixels and the points out
/// of the key range.
pub fn frame_keys(
    unit: VectorUnit,
    proj: &FrameProjector,
    img: &DepthImage,
    keys: &mut Vec<u64>,
    row_keys: &mut Vec<u64>,
) -> (u32, u32) {
    match unit {
        // SAFETY: the CPU has the features these functions are compiled
        // for (`runs_here`).
        #[cfg(target_arch = "x86_64")]
        VectorUnit::Avx512 if unit.runs_here() => unsafe {
            x86::frame_keys_avx512(proj, img, keys, row_keys)
        },
        // SAFETY: as above.
        #[cfg(target_arch = "x86_64")]
        VectorUnit::Avx2 if unit.runs_here() => unsafe {
            x86::frame_keys_avx2(proj, img, keys, row_keys)
        },
        _ => frame_keys_scalar(proj, img, keys, row_keys),
    }
}

/// [`frame_keys`] a pixel at a time, with the core's own loop: where
/// vectors are two 64-bit lanes or none (baseline x86-64, other
/// targets), the chunked loop gains nothing.
fn frame_keys_scalar(
    proj: &FrameProjector,
    img: &DepthImage,
    keys: &mut Vec<u64>,
    row_keys: &mut Vec<u64>,
) -> (u32, u32) {
    // One slot more than a row's keys: the write past the last new key.
    row_keys.resize(usize::from(proj.samples_per_row()) + 1, 0);
    let (mut valid, mut out_of_range) = (0u32, 0u32);
    let mut last = u64::MAX;
    for v in (0..img.height).step_by(usize::from(proj.stride())) {
        let mut n = 0;
        // Branch-free: every key is written, and the end moves only past a
        // new one (a branch on "new key" would mispredict at every voxel
        // edge).
        valid += proj.project_row(v, img.row(v), &mut out_of_range, |key| {
            let bits = key.to_bits();
            if let Some(slot) = row_keys.get_mut(n) {
                *slot = bits;
            }
            n += usize::from(bits != last);
            last = bits;
        });
        keys.extend_from_slice(&row_keys[..n.min(row_keys.len())]);
    }
    (valid, out_of_range)
}

/// [`frame_keys`] a chunk at a time with `kernel`, inlined into each
/// compilation.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn frame_keys_chunked(
    proj: &FrameProjector,
    img: &DepthImage,
    keys: &mut Vec<u64>,
    row_keys: &mut Vec<u64>,
    kernel: &mut impl FnMut(&[u16; CHUNK], ChunkRays, u64, &mut [u64; CHUNK]) -> ChunkCounts,
) -> (u32, u32) {
    row_keys.resize(usize::from(proj.samples_per_row()), 0);
    let (mut valid, mut out_of_range) = (0u32, 0u32);
    for v in (0..img.height).step_by(usize::from(proj.stride())) {
        let (row_valid, n) =
            proj.project_row_with(v, img.row(v), &mut out_of_range, row_keys, kernel);
        valid += row_valid;
        keys.extend_from_slice(&row_keys[..n]);
    }
    (valid, out_of_range)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use placedb::{DepthRange, Intrinsics, Pose, VoxelGrid};

    /// A random frame: intrinsics, pose, grid, stride and depths, with
    /// widths that are not multiples of a chunk, invalid depths (0, too
    /// near, too far, 65535), voxels small enough for keys to leave the
    /// range and, now and then, a camera far enough away for the
    /// projector to use fewer fixed-point bits.
    fn random_frame(rng: &mut SplitMix64) -> (FrameProjector, DepthImage) {
        let (width, height) = (1 + rng.below(300) as u16, 1 + rng.below(12) as u16);
        let (w, h) = (f32::from(width), f32::from(height));
        let f = rng.range(1.0, 2000.0) as f32;
        let k = Intrinsics {
            width,
            height,
            fx: f,
            fy: f * rng.range(0.8, 1.2) as f32,
            cx: rng.range(-0.5, 1.5) as f32 * w,
            cy: rng.range(-0.5, 1.5) as f32 * h,
        };
        let voxel = [0.001, 0.01, 0.3, 3.0][rng.below(4) as usize];
        let origin = [0.0; 3].map(|_: f32| rng.range(-50.0, 50.0) as f32);
        let grid = VoxelGrid::new(voxel, origin).unwrap();
        let q = [0.0; 4].map(|_: f32| rng.range(-1.0, 1.0) as f32);
        let n = q.iter().map(|c| c * c).sum::<f32>().sqrt().max(1e-3);
        let far = if rng.chance(0.1) { 1e6 } else { 1e3 };
        let t = [0.0; 3].map(|_: f32| rng.range(-far, far) as f32);
        let pose = Pose::from_quaternion(t, q.map(|c| c / n))
            .unwrap_or_else(|_| Pose::from_quaternion(t, [0.0, 0.0, 0.0, 1.0]).unwrap());
        let range = if rng.chance(0.2) {
            DepthRange {
                min: 0.0,
                max: f32::INFINITY,
            }
        } else {
            DepthRange::default()
        };
        let scale = [1000.0, 5000.0][rng.below(2) as usize];
        let stride = 1 + rng.below(5) as u16;
        let proj = match FrameProjector::new(&k, scale, range, stride, &grid, &pose) {
            Ok(p) => p,
            // Too extreme for the fixed-point range: an ordinary camera.
            Err(_) => {
                FrameProjector::new(&k, scale, range, stride, &grid, &Pose::IDENTITY).unwrap()
            }
        };
        // Noise, or (as real depth images) a smooth surface with holes,
        // whose neighbouring pixels mostly share a voxel.
        let smooth = rng.chance(0.5);
        let (base, du, dv) = (
            rng.range(200.0, 40_000.0),
            rng.range(-30.0, 30.0),
            rng.range(-30.0, 30.0),
        );
        let data = (0..usize::from(width) * usize::from(height))
            .map(|i| match rng.below(if smooth { 40 } else { 10 }) {
                0 => 0,
                1 => 65535,
                2 => rng.below(200) as u16,
                _ if smooth => {
                    let (u, v) = (
                        (i % usize::from(width)) as f64,
                        (i / usize::from(width)) as f64,
                    );
                    (base + du * u + dv * v + rng.range(-2.0, 2.0)).clamp(0.0, 65535.0) as u16
                }
                _ => rng.below(60_000) as u16,
            })
            .collect();
        let img = DepthImage {
            width,
            height,
            data,
        };
        (proj, img)
    }

    /// The core's own per-pixel loop, every key emitted.
    fn reference(proj: &FrameProjector, img: &DepthImage) -> (Vec<u64>, u32, u32) {
        let (mut keys, mut valid, mut out_of_range) = (Vec::new(), 0, 0);
        for v in 0..img.height {
            valid += proj.project_row(v, img.row(v), &mut out_of_range, |k| keys.push(k.to_bits()));
        }
        (keys, valid, out_of_range)
    }

    /// Recorded frames: every unit gives the frame's key set, and the
    /// AVX-512 path, which drops repeats through a table of the keys it
    /// kept, hands on fewer than two keys per distinct voxel (the others
    /// drop only neighbours' repeats, dozens per voxel).
    #[test]
    fn recorded_frames_give_their_key_sets_with_few_repeats() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data");
        let seq = crate::read::open(&dir.join("7scenes-1000"), &Default::default()).unwrap();
        let grid = VoxelGrid::new(0.3, [0.0; 3]).unwrap();
        for i in [0, 250, 500, 999] {
            let img = seq.depth(i).unwrap();
            let pose = seq.frames[i].pose().unwrap();
            let proj = FrameProjector::new(
                &seq.intrinsics(),
                seq.depth_scale as f32,
                DepthRange::default(),
                1,
                &grid,
                &pose,
            )
            .unwrap();
            let (mut want, valid, out_of_range) = reference(&proj, &img);
            want.sort_unstable();
            want.dedup();
            for unit in VectorUnit::available() {
                let (mut got, mut row_keys) = (Vec::new(), Vec::new());
                let counts = frame_keys(unit, &proj, &img, &mut got, &mut row_keys);
                let handed_on = got.len();
                got.sort_unstable();
                got.dedup();
                assert_eq!(counts, (valid, out_of_range), "frame {i} {unit:?}");
                assert!(got == want, "frame {i} {unit:?}");
                if unit == VectorUnit::Avx512 {
                    assert!(
                        handed_on < 2 * want.len(),
                        "frame {i}: {handed_on} keys for {} voxels",
                        want.len()
                    );
                }
            }
        }
    }

    #[test]
    fn every_vector_unit_gives_the_keys_of_the_per_pixel_loop() {
        let units = VectorUnit::available();
        let mut rng = SplitMix64::new(12);
        let (mut keys_seen, mut outside_seen, mut fewer_bits) = (0, 0, 0);
        for case in 0..3000 {
            let (proj, img) = random_frame(&mut rng);
            let (mut want, valid, out_of_range) = reference(&proj, &img);
            // The paths drop different repeats and order keys differently:
            // compare the sets.
            want.sort_unstable();
            want.dedup();
            for &unit in &units {
                let (mut got, mut row_keys) = (Vec::new(), Vec::new());
                let counts = frame_keys(unit, &proj, &img, &mut got, &mut row_keys);
                got.sort_unstable();
                got.dedup();
                assert_eq!(counts, (valid, out_of_range), "case {case} {unit:?}");
                assert!(got == want, "case {case} {unit:?}: {proj:?}");
            }
            keys_seen += want.len();
            outside_seen += out_of_range;
            // Cameras so far away that fewer fixed-point bits fit take
            // the general loop (the bits are private; Debug shows them).
            fewer_bits += usize::from(!format!("{proj:?}").contains("shift: 40"));
        }
        assert!(
            keys_seen > 100_000 && outside_seen > 1_000 && fewer_bits > 10,
            "{keys_seen} {outside_seen} {fewer_bits}"
        );
    }
}
