//! The `placedb` subcommands, one file each with its arguments and what it
//! prints; `main.rs` defines the command line from them and dispatches. This
//! file holds what several share: where the frames come from
//! ([`SeqArgs`], [`Ros2Args`]) and the solver parameters ([`ParamArgs`]).

pub mod bench;
pub mod budget;
pub mod compare;
pub mod device;
pub mod export;
pub mod select;
pub mod stream;
pub mod synth;

use crate::error::CommandError as Error;
use crate::output::dataset::DatasetSummary;
use crate::pipeline::SolverParams;
use crate::read::{self, ReadOptions};
use crate::synth::SynthConfig;
use crate::{CameraModel, Format, GridOrigin, Sequence, VoxelConfig};
use clap::Args;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Where the frames come from and how they become voxel sets.
#[derive(Args, Clone)]
pub struct SeqArgs {
    /// Sequence directory (TUM RGB-D, 7-Scenes, the reference code's layout) or ROS 2 bag (folder or .mcap).
    #[arg(required_unless_present = "demo")]
    seq: Option<PathBuf>,
    /// Use the built-in synthetic office scan (600 frames, 320x240) instead of a directory.
    #[arg(long, conflicts_with = "seq")]
    demo: bool,
    /// With --demo: walk the same office in this many frames.
    #[arg(long, default_value_t = 600, requires = "demo")]
    demo_frames: usize,
    /// Sequence layout; detected from the directory's files when omitted.
    #[arg(long, value_enum)]
    format: Option<Format>,
    /// Depth units per metre (TUM 5000, 7-Scenes and the reference layout 1000).
    #[arg(long)]
    depth_scale: Option<f64>,
    /// Pinhole intrinsics "fx,fy,cx,cy" in pixels, replacing the sequence's.
    #[arg(long, value_parser = parse_intrinsics)]
    intrinsics: Option<CameraModel>,
    /// Voxel edge in metres.
    #[arg(long, default_value_t = 0.3)]
    voxel: f32,
    /// Use every s-th pixel in u and v (1 = exact voxel sets).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=64))]
    stride: u16,
    /// Valid depths "min,max" in metres: min < z <= max ("0.1,inf" keeps far points).
    #[arg(long, default_value = "0.1,10", value_parser = parse_range)]
    depth_range: (f32, f32),
    /// Anchor of the voxel grid: the world origin (as the device) or the scene's minimum corner (as the reference code).
    #[arg(long, value_enum, default_value_t = GridOrigin::World)]
    grid_origin: GridOrigin,
    /// Use only the first N frames of the sequence.
    #[arg(long)]
    max_frames: Option<usize>,
    #[command(flatten)]
    ros2: Ros2Args,
}

/// Which topics of a ROS 2 bag to read (each defaults to the only candidate).
#[derive(Args, Clone, Default)]
pub struct Ros2Args {
    /// ROS 2 bag: the depth topic (sensor_msgs/msg/Image, 16UC1 or 32FC1).
    #[arg(long)]
    depth_topic: Option<String>,
    /// ROS 2 bag: the pose topic (PoseStamped, Odometry, or /tf with --pose-frame).
    #[arg(long)]
    pose_topic: Option<String>,
    /// ROS 2 bag: the CameraInfo topic.
    #[arg(long)]
    camera_info_topic: Option<String>,
    /// ROS 2 bag: the colour topic (rgb8, bgr8, rgba8, bgra8, mono8), for --dataset.
    #[arg(long)]
    color_topic: Option<String>,
    /// ROS 2 bag: take poses from /tf, as the transform to this child frame (the camera's optical frame).
    #[arg(long)]
    pose_frame: Option<String>,
    /// ROS 2 bag: largest time difference between a depth frame and its pose, seconds.
    #[arg(long, default_value_t = read::ros2::POSE_TOLERANCE)]
    pose_tolerance: f64,
}

impl Ros2Args {
    pub(crate) fn options(&self) -> read::ros2::Ros2Options {
        read::ros2::Ros2Options {
            depth_topic: self.depth_topic.clone(),
            pose_topic: self.pose_topic.clone(),
            camera_info_topic: self.camera_info_topic.clone(),
            color_topic: self.color_topic.clone(),
            pose_frame: self.pose_frame.clone(),
            pose_tolerance: Some(self.pose_tolerance),
        }
    }
}

/// Solver parameters shared by select and compare.
#[derive(Args, Clone)]
pub struct ParamArgs {
    /// every-nth: take every N-th frame.
    #[arg(long, default_value_t = 10)]
    every_nth: usize,
    /// distance: take a frame each D metres of camera path.
    #[arg(long, default_value_t = 0.5)]
    distance: f64,
    /// cube: take the frame nearest the centre of each C-metre cube of the trajectory's box.
    #[arg(long, default_value_t = 1.0)]
    cube: f64,
    /// exact: time limit in seconds; past it the best set and a proven lower bound are reported.
    #[arg(long, default_value_t = 60.0)]
    time_limit: f64,
    /// online: device capacity profile (ram256k, ram512k, ram1m; see `placedb budget`).
    #[arg(long, default_value = "ram512k")]
    profile: String,
    /// online: frames held undecided (1 reproduces in-order; capped by the profile's window).
    #[arg(long, default_value_t = 32)]
    window: u16,
    /// online: decode every frame again and push its rows, as a board
    /// receives them, instead of reusing the voxel sets (same decisions;
    /// `bench --core` counts the core's voxelizing this way).
    #[arg(long, hide = true)]
    push_rows: bool,
    /// Test sequence of the same place: adds oracle_recall@0.3.
    #[arg(long)]
    test: Option<PathBuf>,
    /// Print machine-readable JSON instead of text.
    #[arg(long)]
    json: bool,
    /// No progress bars.
    #[arg(long, short)]
    quiet: bool,
}

fn parse_intrinsics(s: &str) -> Result<CameraModel, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>().map_err(|e| format!("{x:?}: {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [fx, fy, cx, cy] => Ok(CameraModel { fx, fy, cx, cy }),
        _ => Err("expected four numbers fx,fy,cx,cy".into()),
    }
}

fn parse_range(s: &str) -> Result<(f32, f32), String> {
    let (a, b) = s.split_once(',').ok_or("expected min,max in metres")?;
    let min: f32 = a.trim().parse().map_err(|e| format!("{a:?}: {e}"))?;
    let max: f32 = b.trim().parse().map_err(|e| format!("{b:?}: {e}"))?;
    if !(min >= 0.0 && max > min) {
        return Err(format!("need 0 <= min < max, got {min},{max}"));
    }
    Ok((min, max))
}

pub(crate) fn open_sequence(a: &SeqArgs) -> Result<Sequence, Error> {
    let mut seq = open_full_sequence(a)?;
    if let Some(n) = a.max_frames {
        seq.frames.truncate(n);
    }
    Ok(seq)
}

pub(crate) fn open_full_sequence(a: &SeqArgs) -> Result<Sequence, Error> {
    if a.demo {
        let cfg = SynthConfig {
            frames: a.demo_frames,
            ..SynthConfig::demo()
        };
        return Ok(crate::synth::sequence(&cfg));
    }
    let path = a
        .seq
        .as_ref()
        .ok_or("a sequence directory or --demo is required")?;
    let opts = ReadOptions {
        format: a.format,
        depth_scale: a.depth_scale,
        intrinsics: a.intrinsics,
        ros2: a.ros2.options(),
    };
    Ok(read::open(path, &opts)?)
}

pub(crate) fn open_test(path: &Path, a: &SeqArgs) -> Result<Sequence, Error> {
    let opts = ReadOptions {
        format: None,
        depth_scale: a.depth_scale,
        intrinsics: a.intrinsics,
        ros2: a.ros2.options(),
    };
    Ok(read::open(path, &opts)?)
}

pub(crate) fn voxel_config(a: &SeqArgs) -> VoxelConfig {
    VoxelConfig {
        voxel: a.voxel,
        stride: a.stride,
        range: placedb::DepthRange {
            min: a.depth_range.0,
            max: a.depth_range.1,
        },
        origin: a.grid_origin,
    }
}

pub(crate) fn solver_params(p: &ParamArgs) -> Result<SolverParams, Error> {
    if !(p.time_limit.is_finite() && p.time_limit > 0.0) {
        return Err("--time-limit must be a positive number of seconds".into());
    }
    if placedb::profile::by_name(&p.profile).is_none() {
        return Err(format!("unknown --profile {:?}; see `placedb budget`", p.profile).into());
    }
    Ok(SolverParams {
        every_nth: p.every_nth,
        distance: p.distance,
        cube: p.cube,
        time_limit: Duration::from_secs_f64(p.time_limit),
        profile: p.profile.clone(),
        window: p.window.max(1),
        push_rows: p.push_rows,
        ..SolverParams::default()
    })
}

/// One line about a written dataset.
pub(crate) fn print_dataset(dir: &Path, d: &DatasetSummary) {
    println!(
        "  dataset: {} frames ({} in database/), {}, in {}",
        d.frames,
        d.database,
        if d.color {
            "with colour"
        } else {
            "no colour (the sequence has none for every frame)"
        },
        dir.display()
    );
}
