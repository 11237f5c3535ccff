//! A scan built to fill a device's flash log fast, for the tests of its
//! erases (host/tests/board_rp2040_flash.rs): every frame a new place, and each of its
//! samples a voxel of its own, so that every frame is taken and stored with
//! some 2.5 KiB of exact keys beside its database record, where a real scan
//! stores a database frame every few dozen frames: about 1.4 frames fill a
//! 4 KiB sector (80 frames erase 58 on the Pico, 2 of them at boot and at
//! the Hello).
//!
//! The camera looks along +z and moves [`STEP_M`] along +x a frame, more
//! than a frame sees, so no two frames share a voxel; its depth is a rough
//! surface, each pixel's depth drawn from a hash of the frame and the pixel
//! between 1 and 7 m (the 0.1 m voxels of [`VOXEL_M`] then hold about one
//! sample each). Depth is computed when asked for: nothing is read from disk.

use placedb_host::{
    CameraModel, DepthImage, DepthSource, Format, FrameInfo, ReadError, Sequence, VoxelConfig,
};

/// How far the camera moves between frames, metres: beyond the ~9 m a
/// frame sees across at its farthest depth.
pub const STEP_M: f64 = 20.0;
/// The voxel edge the scan is meant for, metres.
pub const VOXEL_M: f32 = 0.1;
/// The pixel stride it is meant for: 40x30 samples of the 320x240 image.
pub const STRIDE: u16 = 8;
const WIDTH: u16 = 320;
const HEIGHT: u16 = 240;
/// Depth units per metre.
const DEPTH_SCALE: f64 = 1000.0;

/// The voxel configuration of the scan: [`VOXEL_M`], [`STRIDE`], the
/// default depth range and grid.
pub fn voxel_config() -> VoxelConfig {
    VoxelConfig {
        voxel: VOXEL_M,
        stride: STRIDE,
        ..VoxelConfig::default()
    }
}

/// The scan of `frames` frames at 30 Hz.
pub fn new_place_every_frame(frames: usize) -> Sequence {
    let f = 0.8 * f64::from(WIDTH);
    Sequence {
        name: "new-place-every-frame".to_string(),
        root: None,
        format: Format::Synthetic,
        camera: CameraModel {
            fx: f,
            fy: f,
            cx: (f64::from(WIDTH) - 1.0) / 2.0,
            cy: (f64::from(HEIGHT) - 1.0) / 2.0,
        },
        depth_scale: DEPTH_SCALE,
        size: (WIDTH, HEIGHT),
        frames: (0..frames)
            .map(|i| FrameInfo {
                index: i,
                timestamp: 1.0 + i as f64 / 30.0,
                translation: [STEP_M * i as f64, 0.0, 0.0],
                rotation: [0.0, 0.0, 0.0, 1.0],
                depth_name: format!("rough surface {i}"),
                color_path: None,
            })
            .collect(),
        clock: placedb_host::Clock::Seconds,
        frames_skipped: 0,
        pose_interpolation: None,
        source: Box::new(RoughSurface { frames }),
    }
}

/// The depth of [`new_place_every_frame`].
struct RoughSurface {
    frames: usize,
}

impl DepthSource for RoughSurface {
    fn depth(&self, i: usize) -> Result<DepthImage, ReadError> {
        if i >= self.frames {
            return Err(ReadError::Layout {
                path: "new-place-every-frame".into(),
                reason: format!("no frame {i}: the scan has {} frames", self.frames),
            });
        }
        let data = (0..u64::from(HEIGHT))
            .flat_map(|v| (0..u64::from(WIDTH)).map(move |u| (u, v)))
            .map(|(u, v)| {
                let h = mix((i as u64) << 32 | v << 16 | u);
                // 1,000..7,000 mm.
                1000 + (h % 6000) as u16
            })
            .collect();
        Ok(DepthImage {
            width: WIDTH,
            height: HEIGHT,
            data,
        })
    }
}

/// SplitMix64's finaliser: a well-spread hash of `x`.
fn mix(mut x: u64) -> u64 {
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}
