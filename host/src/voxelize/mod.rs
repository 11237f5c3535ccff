//! Voxelizes a whole sequence on the host, in parallel, with the core's own
//! projector: the offline yardstick sees exactly the voxel sets the device
//! would see at the same stride.

pub mod frame_keys;
pub mod in_order;
pub(crate) mod key_cells;

use crate::error::ReadError;
use crate::sequence::{DepthImage, Sequence};
use crate::vector_unit::VectorUnit;
use crate::voxelize::frame_keys::frame_keys;
use crate::voxelize::key_cells::{axes, BoxCells};
use indicatif::ProgressBar;
use placedb::{DepthRange, FrameProjector, VoxelGrid};
use std::time::{Duration, Instant};

/// Where voxel (0, 0, 0) starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum GridOrigin {
    /// The world origin: what the device does, since it cannot know the scene in advance.
    World,
    /// The minimum corner of all points: what the reference code does.
    SceneMin,
}

/// How frames become voxel sets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoxelConfig {
    /// Voxel edge, metres.
    pub voxel: f32,
    /// Pixel stride in u and v (1 = exact).
    pub stride: u16,
    /// Valid depths, metres.
    pub range: DepthRange,
    /// Grid anchoring.
    pub origin: GridOrigin,
}

impl Default for VoxelConfig {
    fn default() -> Self {
        VoxelConfig {
            voxel: 0.3,
            stride: 1,
            range: DepthRange::default(),
            origin: GridOrigin::World,
        }
    }
}

/// The voxel set of every frame of a sequence.
#[derive(Debug, Clone)]
pub struct VoxelSets {
    /// The grid the keys refer to.
    pub grid: VoxelGrid,
    /// Per frame: ascending, duplicate-free packed voxel keys.
    pub sets: Vec<Vec<u64>>,
    /// Per frame: pixels with a valid depth at this stride.
    pub valid_pixels: Vec<u32>,
    /// Points dropped because their key was out of the representable range.
    pub out_of_range: u64,
    /// Per frame: the same points.
    pub frame_out_of_range: Vec<u32>,
    /// Summed over threads: time spent decoding or rendering depth.
    pub read_time: Duration,
    /// Summed over threads: time spent back-projecting and deduplicating.
    pub voxelize_time: Duration,
}

/// Why voxelization failed.
#[derive(Debug, thiserror::Error)]
pub enum VoxelizeError {
    /// The depth could not be read.
    #[error(transparent)]
    Read(#[from] ReadError),
    /// A frame's pose or the configuration was refused by the core.
    #[error("frame {frame} ({name}): {reason}")]
    Camera {
        /// Frame index.
        frame: usize,
        /// Its depth file.
        name: String,
        /// The core's verdict.
        reason: placedb::CameraError,
    },
    /// No frame, no valid depth pixel, or every point out of key range.
    #[error(transparent)]
    NothingMeasured(#[from] crate::error::NothingMeasured),
}

/// Voxelizes every frame; frames are processed in parallel, results are in order.
pub fn voxelize(
    seq: &Sequence,
    cfg: &VoxelConfig,
    progress: Option<&ProgressBar>,
) -> Result<VoxelSets, VoxelizeError> {
    let origin = match cfg.origin {
        GridOrigin::World => [0.0; 3],
        GridOrigin::SceneMin => scene_min(seq, cfg, progress)?,
    };
    let grid = VoxelGrid::new(cfg.voxel, origin).map_err(|reason| VoxelizeError::Camera {
        frame: 0,
        name: "configuration".into(),
        reason,
    })?;
    voxelize_on(seq, cfg, grid, progress)
}

/// Voxelizes every frame on a given grid (`cfg.origin` and `cfg.voxel` are
/// ignored): a test sequence must share its database's grid.
pub fn voxelize_on(
    seq: &Sequence,
    cfg: &VoxelConfig,
    grid: VoxelGrid,
    progress: Option<&ProgressBar>,
) -> Result<VoxelSets, VoxelizeError> {
    let k = seq.intrinsics();
    let unit = VectorUnit::best();
    let per_frame = in_order::try_map_init(0..seq.frames.len(), Scratch::default, |scratch, i| {
        let set = frame_set(seq, &k, cfg, &grid, unit, i, scratch)?;
        if let Some(p) = progress {
            p.inc(1);
        }
        Ok::<_, VoxelizeError>(set)
    })?;
    let mut out = VoxelSets {
        grid,
        sets: Vec::with_capacity(per_frame.len()),
        valid_pixels: Vec::with_capacity(per_frame.len()),
        out_of_range: 0,
        frame_out_of_range: Vec::with_capacity(per_frame.len()),
        read_time: Duration::ZERO,
        voxelize_time: Duration::ZERO,
    };
    for FrameSet {
        keys,
        valid,
        out_of_range: oor,
        read,
        voxelize: vox,
    } in per_frame
    {
        out.sets.push(keys);
        out.valid_pixels.push(valid);
        out.out_of_range += oor as u64;
        out.frame_out_of_range.push(oor);
        out.read_time += read;
        out.voxelize_time += vox;
    }
    Ok(out)
}

/// One image, one row of keys and one bitmap per worker, reused frame after
/// frame.
type Scratch = (DepthImage, Vec<u64>, Vec<u64>);

/// One frame voxelized, with its counts and times.
struct FrameSet {
    keys: Vec<u64>,
    valid: u32,
    out_of_range: u32,
    read: Duration,
    voxelize: Duration,
}

/// Frame `i` of `seq` voxelized on `grid` (`k` its intrinsics).
fn frame_set(
    seq: &Sequence,
    k: &placedb::Intrinsics,
    cfg: &VoxelConfig,
    grid: &VoxelGrid,
    unit: VectorUnit,
    i: usize,
    (img, row_keys, bitmap): &mut Scratch,
) -> Result<FrameSet, VoxelizeError> {
    let camera_err = |reason| VoxelizeError::Camera {
        frame: i,
        name: seq.depth_where(i),
        reason,
    };
    let t0 = Instant::now();
    seq.depth_into(i, img)?;
    let t1 = Instant::now();
    let pose = seq.frames[i].pose().map_err(camera_err)?;
    let proj = FrameProjector::new(
        k,
        seq.depth_scale as f32,
        cfg.range,
        cfg.stride,
        grid,
        &pose,
    )
    .map_err(camera_err)?;
    // Neighbouring pixels mostly fall in the same voxel: dropping repeats
    // there keeps the sort below small.
    let mut keys = Vec::new();
    let (valid, out_of_range) = frame_keys(unit, &proj, img, &mut keys, row_keys);
    sort_unique(&mut keys, bitmap);
    keys.shrink_to_fit();
    Ok(FrameSet {
        keys,
        valid,
        out_of_range,
        read: t1 - t0,
        voxelize: Instant::now() - t1,
    })
}

/// The number of distinct voxels of each of `frames` (world-anchored
/// grid), voxelized as [`voxelize`] does: what a few frames cost, before
/// all of them are voxelized.
pub fn voxel_counts(
    seq: &Sequence,
    cfg: &VoxelConfig,
    frames: &[usize],
) -> Result<Vec<usize>, VoxelizeError> {
    let grid = VoxelGrid::new(cfg.voxel, [0.0; 3]).map_err(|reason| VoxelizeError::Camera {
        frame: 0,
        name: "configuration".into(),
        reason,
    })?;
    let k = seq.intrinsics();
    let unit = VectorUnit::best();
    let mut scratch = Scratch::default();
    frames
        .iter()
        .map(|&i| frame_set(seq, &k, cfg, &grid, unit, i, &mut scratch).map(|s| s.keys.len()))
        .collect()
}

/// Cells of the largest key box [`sort_unique`] marks in a bitmap (256 KiB
/// of bits, within a core's L2 cache); larger boxes are sorted.
const BITMAP_CELLS: u64 = 1 << 21;

/// Sorts packed voxel keys ascending and drops repeats. A frame's keys lie
/// in a small box of the grid (a few metres of 0.3 m voxels), so instead of
/// sorting, they mark their cells of the box in a bitmap ([`BoxCells`]).
/// `bitmap` is scratch, all zero between calls. Boxes over
/// [`BITMAP_CELLS`] are sorted.
fn sort_unique(keys: &mut Vec<u64>, bitmap: &mut Vec<u64>) {
    let (lo, hi) = key_box(keys);
    let Some(cells) = BoxCells::spanning(lo, hi, BITMAP_CELLS) else {
        keys.sort_unstable();
        keys.dedup();
        return;
    };
    cells.mark(keys.iter().copied(), bitmap);
    keys.clear();
    cells.drain_marked(bitmap, keys);
}

/// The smallest and the largest coordinate of `keys` on each axis (`lo`
/// all `u64::MAX` and `hi` zero for no keys). With AVX2, where the CPU has
/// it, the same loop is compiled for it: it becomes eight keys a step
/// instead of a chain of compares a key (a frame has thousands of keys).
fn key_box(keys: &[u64]) -> ([u64; 3], [u64; 3]) {
    #[cfg(target_arch = "x86_64")]
    if VectorUnit::Avx2.runs_here() {
        // SAFETY: the CPU has AVX2 (`runs_here`).
        return unsafe { key_box_avx2(keys) };
    }
    key_box_portable(keys)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn key_box_avx2(keys: &[u64]) -> ([u64; 3], [u64; 3]) {
    key_box_portable(keys)
}

/// [`key_box`] as LLVM vectorizes it: axes are 21 bits, so 32-bit lanes.
#[inline(always)]
fn key_box_portable(keys: &[u64]) -> ([u64; 3], [u64; 3]) {
    let (mut lo, mut hi) = ([u32::MAX; 3], [0u32; 3]);
    for &k in keys {
        let axes = axes(k).map(|a| a as u32);
        for a in 0..3 {
            lo[a] = lo[a].min(axes[a]);
            hi[a] = hi[a].max(axes[a]);
        }
    }
    let wide = |x: u32| {
        if x == u32::MAX {
            u64::MAX
        } else {
            u64::from(x)
        }
    };
    (lo.map(wide), hi.map(u64::from))
}

/// Decodes every frame's depth as [`voxelize_on`] does (same threads, same
/// buffer reuse) and does nothing else with them: the floor under
/// voxelizing, which `placedb bench` prints.
pub fn decode_all(seq: &Sequence) -> Result<(), VoxelizeError> {
    in_order::try_map_init(0..seq.frames.len(), DepthImage::default, |img, i| {
        seq.depth_into(i, img).map_err(VoxelizeError::from)
    })
    .map(drop)
}

/// Minimum corner of all valid points of the sequence (the reference code's
/// grid anchor); computed in `f64` from the definition, not the fast path.
fn scene_min(
    seq: &Sequence,
    cfg: &VoxelConfig,
    progress: Option<&ProgressBar>,
) -> Result<[f32; 3], VoxelizeError> {
    let c = seq.camera;
    let mins = in_order::try_map_init(
        0..seq.frames.len(),
        || (),
        |(), i| {
            let img = seq.depth(i)?;
            let f = &seq.frames[i];
            let pose = f.pose().map_err(|reason| VoxelizeError::Camera {
                frame: i,
                name: seq.depth_where(i),
                reason,
            })?;
            let r = pose.rotation_matrix();
            let mut m = [f64::INFINITY; 3];
            let step = cfg.stride as usize;
            for v in (0..img.height as usize).step_by(step) {
                for (u, &raw) in img.row(v as u16).iter().enumerate().step_by(step) {
                    let z = raw as f64 / seq.depth_scale;
                    if raw == 0 || !(z > cfg.range.min as f64 && z <= cfg.range.max as f64) {
                        continue;
                    }
                    let pc = [
                        (u as f64 - c.cx) * z / c.fx,
                        (v as f64 - c.cy) * z / c.fy,
                        z,
                    ];
                    for a in 0..3 {
                        let pw = r[a][0] as f64 * pc[0]
                            + r[a][1] as f64 * pc[1]
                            + r[a][2] as f64 * pc[2]
                            + f.translation[a];
                        m[a] = m[a].min(pw);
                    }
                }
            }
            if let Some(p) = progress {
                p.inc(1);
            }
            Ok::<_, VoxelizeError>(m)
        },
    )?;
    let mut m = [f64::INFINITY; 3];
    for fm in mins {
        for a in 0..3 {
            m[a] = m[a].min(fm[a]);
        }
    }
    if m.iter().any(|c| !c.is_finite()) {
        m = [0.0; 3]; // no valid point at all: any anchor gives empty sets
    }
    Ok(m.map(|c| c as f32))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    #[test]
    fn sort_unique_is_sort_and_dedup() {
        let mut rng = SplitMix64::new(7);
        let mut bitmap = Vec::new();
        let (mut by_bitmap, mut by_sort) = (0, 0);
        for case in 0..2000 {
            // Boxes from one cell to wider than the bitmap takes, at any
            // place of the 21-bit axes (edges included).
            let side = [1, 2, 40, 130, 1 << 21][rng.below(5) as usize];
            let corner = [0u64; 3].map(|_| match rng.below(3) {
                0 => 0,
                1 => (1 << 21) - side,
                _ => rng.below((1 << 21) - side + 1),
            });
            let n = rng.below(3000) as usize;
            let mut keys: Vec<u64> = (0..n)
                .map(|_| {
                    let [x, y, z] = corner.map(|c| c + rng.below(side));
                    x << 42 | y << 21 | z
                })
                .collect();
            let mut want = keys.clone();
            want.sort_unstable();
            want.dedup();
            sort_unique(&mut keys, &mut bitmap);
            assert_eq!(keys, want, "case {case}");
            assert!(
                bitmap.iter().all(|&w| w == 0),
                "case {case}: scratch left set"
            );
            if side.pow(3) <= BITMAP_CELLS && n > 0 {
                by_bitmap += 1;
            } else {
                by_sort += 1;
            }
        }
        assert!(by_bitmap > 500 && by_sort > 500, "{by_bitmap} {by_sort}");
    }
}
