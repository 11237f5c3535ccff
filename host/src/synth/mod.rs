//! The built-in synthetic scan: a deterministic ray-cast office floor (rooms
//! off a corridor, the same desks and doors in every room — the hard,
//! repetitive case of place recognition) and a camera walk through it.
//!
//! It is the default demo sequence (`placedb select --demo`, no download) and,
//! written in the TUM RGB-D layout (`placedb synth OUT`), test data for the
//! readers and the whole pipeline.
//!
//! * World frame: metres, z up, x east along the corridor (centre line y = 0),
//!   origin at the walk's start at eye height, floor at z = -1.37 (see
//!   [`scene`]).
//! * Poses: camera-to-world `p_w = R p_c + t`, OpenCV camera axes (x right,
//!   y down, z forward), rotation `[qx, qy, qz, qw]` (see [`path`]).
//! * Depth: z-depth, 5000 units per metre as TUM, 0 beyond 10 m of ray
//!   (see [`render()`]). Everything is a pure function of [`SynthConfig`]: the
//!   same configuration gives the same poses and the same depth bits.

mod grid;
pub mod path;
pub mod render;
pub mod scene;
pub mod scene_box;
pub mod shade;
pub mod tum_writer;

pub use path::{camera_path, FRAME_RATE};
pub use render::{render, MAX_RANGE};
pub use scene::{Material, Room, Scene, SceneBox, EYE_HEIGHT, FLOOR_Z};
pub use tum_writer::{is_synth_output, write_tum, SYNTH_OUTPUT};

use crate::error::ReadError;
use crate::sequence::{CameraModel, DepthImage, DepthSource, Format, Sequence};
use std::path::PathBuf;
use std::sync::Arc;

/// Depth units per metre of synthetic sequences (TUM's).
pub const DEPTH_SCALE: f64 = 5000.0;

/// What to synthesise.
///
/// The camera is a pinhole with square pixels, `fx = fy = 0.8 * width` (64°
/// horizontal field of view whatever the resolution) and the principal point
/// at the image centre `((width - 1) / 2, (height - 1) / 2)`. The route
/// through the office is fixed by the scene; `frames` only sets how densely it
/// is sampled (about 100 m of walking for 6 rooms: 0.17 m between frames at
/// 600 frames, 2 cm at 5000).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SynthConfig {
    /// Number of frames (30 Hz timestamps from 1.0 s).
    pub frames: usize,
    /// Image width, pixels.
    pub width: u16,
    /// Image height, pixels.
    pub height: u16,
    /// Seed of the furniture layout and the path's small variations.
    pub seed: u64,
    /// Number of rooms, alternately north and south of the corridor.
    pub rooms: usize,
}

impl Default for SynthConfig {
    /// The demo scan: 600 frames of 320x240 through 4 rooms, seed 1.
    fn default() -> Self {
        SynthConfig {
            frames: 600,
            width: 320,
            height: 240,
            seed: 1,
            rooms: 4,
        }
    }
}

impl SynthConfig {
    /// The sequence `placedb select --demo` uses (the default).
    pub fn demo() -> Self {
        Self::default()
    }

    /// The benchmark sequence: 5000 frames of 320x240 through 8 rooms.
    pub fn bench() -> Self {
        SynthConfig {
            frames: 5000,
            rooms: 8,
            ..Self::default()
        }
    }

    /// Refuses, in words, a configuration whose sequence could not be read
    /// back: no frame, no room, or an image side outside 2..=8192 (the
    /// core's largest side; one pixel wide, the focal length 0.8 * width is
    /// below the core's smallest).
    pub fn check(&self) -> Result<(), String> {
        let sides = 2..=placedb::Intrinsics::MAX_SIDE;
        if !sides.contains(&self.width) || !sides.contains(&self.height) {
            return Err(format!(
                "an image of {}x{} pixels: give --width and --height from {} to {}",
                self.width,
                self.height,
                sides.start(),
                sides.end()
            ));
        }
        if self.frames == 0 {
            return Err("--frames 0: give at least 1 frame".into());
        }
        if self.rooms == 0 {
            return Err("--rooms 0: give at least 1 room".into());
        }
        Ok(())
    }

    /// The pinhole model of this configuration.
    pub fn camera(&self) -> CameraModel {
        let f = 0.8 * self.width as f64;
        CameraModel {
            fx: f,
            fy: f,
            cx: (self.width as f64 - 1.0) / 2.0,
            cy: (self.height as f64 - 1.0) / 2.0,
        }
    }
}

/// Renders frames on demand; shared read-only between threads.
struct SynthSource {
    scene: Arc<Scene>,
    camera: CameraModel,
    size: (u16, u16),
    poses: Vec<([f64; 3], [f64; 4])>,
}

impl DepthSource for SynthSource {
    fn depth(&self, i: usize) -> Result<DepthImage, ReadError> {
        let Some(&(t, q)) = self.poses.get(i) else {
            return Err(ReadError::Layout {
                path: PathBuf::from("synthetic"),
                reason: format!("no frame {i}: the sequence has {} frames", self.poses.len()),
            });
        };
        Ok(render(
            &self.scene,
            &self.camera,
            self.size,
            t,
            q,
            DEPTH_SCALE,
        ))
    }
}

/// The synthetic sequence of `cfg`: name "synthetic", [`Format::Synthetic`],
/// depth scale 5000, depth rendered when asked for.
pub fn sequence(cfg: &SynthConfig) -> Sequence {
    let scene = Arc::new(Scene::office(cfg));
    let frames = camera_path(&scene, cfg);
    let camera = cfg.camera();
    let size = (cfg.width, cfg.height);
    let poses = frames.iter().map(|f| (f.translation, f.rotation)).collect();
    Sequence {
        name: "synthetic".to_string(),
        root: None,
        format: Format::Synthetic,
        camera,
        depth_scale: DEPTH_SCALE,
        size,
        frames,
        clock: crate::sequence::Clock::Seconds,
        frames_skipped: 0,
        pose_interpolation: None,
        source: Box::new(SynthSource {
            scene,
            camera,
            size,
            poses,
        }),
    }
}
