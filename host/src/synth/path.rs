//! The camera's walk through the office: along the corridor eastwards into
//! every north room, back westwards into every south room, then eastwards again
//! into the middle north room — so the corridor is seen both ways and some
//! places are revisited with the same heading (loops for place recognition).
//!
//! In each room the camera walks in through the door to the room's centre,
//! looks around one and a half turns (pitched a little down, ending towards the
//! door) and walks back out. The route is a dense polyline of (x, y, yaw,
//! pitch) samples, one per centimetre of walking or per 1/60 rad of turning
//! (1/45 rad when looking around), smoothed by a moving average (corners become
//! curves, turns on the spot ease in and out) and sampled evenly into the
//! requested number of frames. A gentle bob, sway and roll on top make the
//! orientation general (never exactly level), at eye height (world z = 0,
//! 1.37 m above the floor) give or take 2 cm.

use super::scene::{Room, Scene, CORRIDOR_HALF_WIDTH, WALL};
use super::SynthConfig;
use crate::rng::SplitMix64;
use crate::sequence::FrameInfo;
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use std::f64::consts::{PI, TAU};

/// Frame rate of the synthetic camera; timestamps start at 1.0 s.
pub const FRAME_RATE: f64 = 30.0;
/// Walking cost between dense samples (metres, or metres-equivalent of turning).
const STEP: f64 = 0.01;
/// Metres-equivalent cost of turning one radian.
const TURN_COST: f64 = 0.6;
/// Half-width of the smoothing window, in dense samples (applied twice).
const SMOOTH: usize = 20;
/// Metres-equivalent cost of turning one radian while looking around a room.
const LOOK_TURN_COST: f64 = 0.45;
/// Pitch while looking around a room, radians (down).
const LOOK_PITCH: f64 = -0.15;

/// One dense sample of the route.
#[derive(Debug, Clone, Copy)]
struct Sample {
    x: f64,
    y: f64,
    yaw: f64,
    pitch: f64,
}

/// Builds the dense route step by step.
struct Walker {
    samples: Vec<Sample>,
    x: f64,
    y: f64,
    yaw: f64,
}

impl Walker {
    fn push(&mut self, pitch: f64) {
        self.samples.push(Sample {
            x: self.x,
            y: self.y,
            yaw: self.yaw,
            pitch,
        });
    }

    /// Turns by `delta` radians on the spot, at `cost` metres per radian.
    fn turn_by(&mut self, delta: f64, cost: f64, pitch: f64) {
        let n = (delta.abs() * cost / STEP).ceil() as usize;
        let yaw0 = self.yaw;
        for k in 1..=n {
            self.yaw = yaw0 + delta * k as f64 / n as f64;
            self.push(pitch);
        }
    }

    /// Turns the short way round to face `heading`.
    fn face(&mut self, heading: f64) {
        let delta = (heading - self.yaw + PI).rem_euclid(TAU) - PI;
        self.turn_by(delta, TURN_COST, 0.0);
    }

    /// Faces `to` and walks there in a straight line.
    fn walk_to(&mut self, to: [f64; 2]) {
        let (dx, dy) = (to[0] - self.x, to[1] - self.y);
        let len = dx.hypot(dy);
        if len < 1e-9 {
            return;
        }
        self.face(dy.atan2(dx));
        let (x0, y0) = (self.x, self.y);
        let n = (len / STEP).ceil() as usize;
        for k in 1..=n {
            let f = k as f64 / n as f64;
            self.x = x0 + dx * f;
            self.y = y0 + dy * f;
            self.push(0.0);
        }
    }

    /// From the corridor centre line: into `room`, a full look around, and out
    /// again, ending where it started facing `heading`.
    fn visit(&mut self, room: &Room, heading: f64, clockwise: bool) {
        let s = room.side();
        let inside = CORRIDOR_HALF_WIDTH + WALL + 0.8;
        self.walk_to([room.door_x, 0.0]);
        self.walk_to([room.door_x, s * inside]);
        self.walk_to(room.center);
        // One and a half turns, ending towards the way out.
        let out = (s * inside - room.center[1]).atan2(room.door_x - room.center[0]);
        let ccw = (out - self.yaw).rem_euclid(TAU);
        let turn = if clockwise {
            ccw - 2.0 * TAU
        } else {
            ccw + TAU
        };
        self.turn_by(turn, LOOK_TURN_COST, LOOK_PITCH);
        self.walk_to([room.door_x, s * inside]);
        self.walk_to([room.door_x, 0.0]);
        self.face(heading);
    }
}

/// Moving average of half-width `k` (indices clamped at the ends).
fn smooth(values: &mut [f64], k: usize) {
    let n = values.len();
    if n == 0 {
        return;
    }
    let src = values.to_vec();
    let at = |i: isize| src[i.clamp(0, n as isize - 1) as usize];
    let k = k as isize;
    let mut sum: f64 = (-k..=k).map(at).sum();
    let width = (2 * k + 1) as f64;
    for (i, out) in values.iter_mut().enumerate() {
        let i = i as isize;
        *out = sum / width;
        sum += at(i + k + 1) - at(i - k);
    }
}

/// The dense, unsmoothed route through `scene`.
fn route(scene: &Scene, rng: &mut SplitMix64) -> Vec<Sample> {
    let [west, east] = scene.x_range();
    // The walk starts at the origin, as far from the west wall as it turns
    // from the east wall.
    let east_end = east + west;
    let mut w = Walker {
        samples: Vec::new(),
        x: 0.0,
        y: 0.0,
        yaw: 0.0,
    };
    w.push(0.0);
    let mut north: Vec<&Room> = scene.rooms().iter().filter(|r| r.north).collect();
    let mut south: Vec<&Room> = scene.rooms().iter().filter(|r| !r.north).collect();
    north.sort_by(|a, b| a.door_x.total_cmp(&b.door_x));
    south.sort_by(|a, b| b.door_x.total_cmp(&a.door_x));
    for r in &north {
        w.visit(r, 0.0, rng.chance(0.5));
    }
    w.walk_to([east_end, 0.0]);
    w.turn_by(PI, TURN_COST, 0.0);
    for r in &south {
        w.visit(r, PI, rng.chance(0.5));
    }
    w.walk_to([0.0, 0.0]);
    w.turn_by(-PI, TURN_COST, 0.0);
    if let Some(r) = north.get(north.len() / 2) {
        w.visit(r, 0.0, rng.chance(0.5));
        w.walk_to([(r.door_x + 3.0).min(east_end), 0.0]);
    } else {
        w.walk_to([east_end, 0.0]);
    }
    w.samples
}

/// `x` rounded to a nanometre: clears the running sums' last-bit noise, so
/// files show `1.92`, not `1.919999999999991`.
fn nm(x: f64) -> f64 {
    (x * 1e9).round() / 1e9
}

/// `q` divided by its norm, repeated until that changes nothing: readers that
/// normalise the quaternions they parse then get back the very same bits.
fn canonical(q: [f64; 4]) -> [f64; 4] {
    let mut q = q;
    for _ in 0..8 {
        let n = q.iter().map(|c| c * c).sum::<f64>().sqrt();
        let next = q.map(|c| c / n);
        if next == q {
            break;
        }
        q = next;
    }
    q
}

/// Camera-to-world rotation (OpenCV camera axes, world z up) of a camera
/// heading `yaw` (from +x towards +y), pitched up by `pitch`, rolled by `roll`.
fn orientation(yaw: f64, pitch: f64, roll: f64) -> UnitQuaternion<f64> {
    let (sy, cy) = yaw.sin_cos();
    let (sp, cp) = pitch.sin_cos();
    let (sr, cr) = roll.sin_cos();
    let forward = Vector3::new(cy * cp, sy * cp, sp);
    let right0 = Vector3::new(sy, -cy, 0.0);
    let down0 = Vector3::new(cy * sp, sy * sp, -cp);
    let right = right0 * cr + down0 * sr;
    let down = down0 * cr - right0 * sr;
    let m = Matrix3::from_columns(&[right, down, forward]);
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m))
}

/// The camera path through `scene`: `cfg.frames` frames at [`FRAME_RATE`]
/// from t = 1 s (rounded to microseconds, as the TUM files write them), each
/// with its camera-to-world pose (translation in metres, rotation
/// `[qx, qy, qz, qw]` of unit norm) and the depth file name the TUM writer
/// uses (`depth/<timestamp>.png`).
pub fn camera_path(scene: &Scene, cfg: &SynthConfig) -> Vec<FrameInfo> {
    if cfg.frames == 0 {
        return Vec::new();
    }
    let mut rng = SplitMix64::stream(cfg.seed, u64::MAX);
    let dense = route(scene, &mut rng);
    let mut channels: [Vec<f64>; 4] = [
        dense.iter().map(|s| s.x).collect(),
        dense.iter().map(|s| s.y).collect(),
        dense.iter().map(|s| s.yaw).collect(),
        dense.iter().map(|s| s.pitch).collect(),
    ];
    for c in channels.iter_mut() {
        smooth(c, SMOOTH);
        smooth(c, SMOOTH);
    }
    let phase: [f64; 4] = std::array::from_fn(|_| rng.range(0.0, TAU));
    let last = dense.len() - 1;
    let mut prev = UnitQuaternion::identity();
    (0..cfg.frames)
        .map(|i| {
            let f = if cfg.frames == 1 {
                0.0
            } else {
                i as f64 * last as f64 / (cfg.frames - 1) as f64
            };
            let k = (f.floor() as usize).min(last.saturating_sub(1));
            let a = f - k as f64;
            let lerp = |c: &[f64]| c[k] + (c[(k + 1).min(last)] - c[k]) * a;
            let [x, y, yaw, pitch] = [0, 1, 2, 3].map(|j| lerp(&channels[j]));
            // Walking cost so far, metres: drives the bob, sway and roll.
            let s = f * STEP;
            let wave = |period: f64, j: usize| (TAU * s / period + phase[j]).sin();
            let z = 0.02 * wave(1.3, 0);
            let yaw = yaw + 0.035 * wave(3.7, 1);
            let pitch = pitch - 0.03 + 0.05 * wave(6.1, 2);
            let roll = 0.025 * wave(4.3, 3);
            let mut q = orientation(yaw, pitch, roll);
            if q.coords.dot(&prev.coords) < 0.0 {
                q = UnitQuaternion::new_unchecked(-q.into_inner());
            }
            prev = q;
            let timestamp = ((1.0 + i as f64 / FRAME_RATE) * 1e6).round() / 1e6;
            FrameInfo {
                index: i,
                timestamp,
                translation: [x, y, z].map(nm),
                rotation: canonical([q.i, q.j, q.k, q.w]),
                depth_name: format!("depth/{timestamp:.6}.png"),
                color_path: None,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_camera_looks_along_heading() {
        let q = orientation(0.0, 0.0, 0.0);
        let f = q * Vector3::z();
        let down = q * Vector3::y();
        assert!((f - Vector3::x()).norm() < 1e-12);
        assert!((down + Vector3::z()).norm() < 1e-12);
        let q = orientation(PI / 2.0, 0.3, 0.0);
        let f = q * Vector3::z();
        assert!(f.x.abs() < 1e-12 && f.y > 0.0 && (f.z - 0.3f64.sin()).abs() < 1e-12);
        // Roll keeps the optical axis.
        let q = orientation(1.0, -0.2, 0.4);
        let f0 = orientation(1.0, -0.2, 0.0) * Vector3::z();
        assert!((q * Vector3::z() - f0).norm() < 1e-12);
    }

    #[test]
    fn path_is_smooth_clear_and_unit() {
        let bench = SynthConfig {
            frames: 2000,
            ..SynthConfig::bench()
        };
        for (cfg, max_step) in [(SynthConfig::demo(), 0.35), (bench, 0.15)] {
            let scene = Scene::office(&cfg);
            let path = camera_path(&scene, &cfg);
            assert_eq!(path.len(), cfg.frames);
            for pair in path.windows(2) {
                let (a, b) = (&pair[0], &pair[1]);
                let step: f64 = (0..3)
                    .map(|i| (a.translation[i] - b.translation[i]).powi(2))
                    .sum();
                assert!(
                    step.sqrt() < max_step,
                    "frame {} jumps {}",
                    b.index,
                    step.sqrt()
                );
                let dot: f64 = (0..4).map(|i| a.rotation[i] * b.rotation[i]).sum();
                let angle = 2.0 * dot.abs().min(1.0).acos();
                assert!(
                    angle < max_step * 1.5,
                    "frame {} turns {angle} rad",
                    b.index
                );
            }
            for f in &path {
                let n: f64 = f.rotation.iter().map(|c| c * c).sum();
                assert!((n.sqrt() - 1.0).abs() < 1e-12);
                // Nothing within 25 cm in the eight horizontal directions.
                for k in 0..8 {
                    let a = k as f64 * TAU / 8.0;
                    let t = scene
                        .ray_distance(f.translation, [a.cos(), a.sin(), 0.0])
                        .unwrap();
                    assert!(t > 0.25, "frame {} is {t} m from a surface", f.index);
                }
            }
        }
    }
}
