//! The `placedb` subcommands, one file each with its arguments and what it
//! prints; `main.rs` defines the command line from them and dispatches. This
//! file holds what several share: where the frames come from
//! ([`SeqArgs`], [`Ros2Args`]) and the solver parameters ([`ParamArgs`]).
//! Every numeric option is checked by one value parser of [`params`] while
//! the command line is parsed, before any work: a value out of range is
//! refused with the range, the same way in every command.

pub mod bench;
pub mod budget;
pub mod compare;
pub mod device;
pub mod export;
pub mod params;
pub mod select;
pub mod stream;
pub mod synth;
mod values;

use crate::error::CommandError as Error;
use crate::output::dataset::DatasetSummary;
use crate::output::exports::ExportTargets;
use crate::pipeline::SolverParams;
use crate::read::{self, ReadOptions};
use crate::sequence::PoseInterpolation;
use crate::synth::SynthConfig;
use crate::{CameraModel, Format, GridOrigin, Sequence, VoxelConfig};
use clap::Args;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The export options shared by `select` and `export`.
#[derive(Args, Debug, Clone, Default)]
pub struct ExportFlags {
    /// Also write the database frames as a COLMAP text model here:
    /// sparse/0/{cameras,images,points3D}.txt and images/ (docs/exports.md).
    #[arg(long)]
    pub colmap: Option<PathBuf>,
    /// Also write VPR-methods-evaluation's layout here: database/ and
    /// queries/ named @east@north@index@.jpg (docs/exports.md).
    #[arg(long)]
    pub vpr_eval: Option<PathBuf>,
    /// Also write hloc's retrieval pairs to this file: each non-database
    /// frame with the database frames it overlaps above mu, best first,
    /// named by their colour files relative to SEQ (docs/exports.md).
    #[arg(long)]
    pub pairs: Option<PathBuf>,
}

impl ExportFlags {
    /// Where the exports asked for go.
    pub fn targets(&self) -> ExportTargets {
        ExportTargets {
            colmap: self.colmap.clone(),
            vpr_eval: self.vpr_eval.clone(),
            pairs: self.pairs.clone(),
        }
    }
}

/// Where the frames come from and how they become voxel sets.
#[derive(Args, Clone)]
pub struct SeqArgs {
    /// Sequence directory (TUM RGB-D, 7-Scenes, the reference code's layout) or ROS 2 bag (folder, .mcap or .db3) or ROS 1 bag (.bag).
    #[arg(required_unless_present = "demo")]
    seq: Option<PathBuf>,
    /// Use the built-in synthetic office scan (600 frames, 320x240) instead of a directory.
    #[arg(long, conflicts_with = "seq")]
    demo: bool,
    /// With --demo: walk the same office in this many frames (1 to 1000000).
    #[arg(long, default_value_t = 600, requires = "demo", value_parser = params::whole::<usize>(1, params::MAX_SYNTH_FRAMES), allow_negative_numbers = true)]
    demo_frames: usize,
    /// Sequence layout; detected from the directory's files when omitted.
    #[arg(long, value_enum)]
    format: Option<Format>,
    /// Depth units per metre, from 1 to 1e6 (TUM 5000, 7-Scenes and the reference layout 1000).
    #[arg(long, value_parser = params::depth_scale, allow_negative_numbers = true)]
    depth_scale: Option<f64>,
    /// Pinhole intrinsics "fx,fy,cx,cy" in pixels, replacing the sequence's.
    #[arg(long, value_parser = params::intrinsics, allow_hyphen_values = true)]
    intrinsics: Option<CameraModel>,
    /// Voxel edge in metres, from 0.001 to 100 (below about 0.01 the voxel sets take
    /// megabytes a frame: a warning says how much).
    #[arg(long, default_value_t = 0.3, value_parser = params::voxel, allow_negative_numbers = true)]
    voxel: f32,
    /// Use every s-th pixel in u and v (1 = exact voxel sets).
    #[arg(long, default_value_t = 1, value_parser = params::whole::<u16>(1, 64), allow_negative_numbers = true)]
    stride: u16,
    /// Valid depths "min,max" in metres: min < z <= max ("0.1,inf" keeps far points).
    #[arg(long, default_value = "0.1,10", value_parser = params::depth_range, allow_hyphen_values = true)]
    depth_range: (f32, f32),
    /// Anchor of the voxel grid: the world origin (as the device) or the scene's minimum corner (as the reference code).
    #[arg(long, value_enum, default_value_t = GridOrigin::World)]
    grid_origin: GridOrigin,
    /// Use only the first N frames of the sequence (1 or more).
    #[arg(long, value_parser = params::whole::<usize>(1, u64::MAX), allow_negative_numbers = true)]
    max_frames: Option<usize>,
    #[command(flatten)]
    ros2: Ros2Args,
}

/// Which topics of a ROS 2 or ROS 1 bag to read (each defaults to the only candidate).
#[derive(Args, Clone, Default)]
pub struct Ros2Args {
    /// ROS 2 or ROS 1 bag: the depth topic (sensor_msgs/msg/Image 16UC1 or 32FC1, or its compressedDepth or 16-bit PNG CompressedImage).
    #[arg(long)]
    depth_topic: Option<String>,
    /// ROS 2 or ROS 1 bag: the pose topic (PoseStamped, Odometry, or a TF topic).
    #[arg(long)]
    pose_topic: Option<String>,
    /// ROS 2 or ROS 1 bag: the CameraInfo topic.
    #[arg(long)]
    camera_info_topic: Option<String>,
    /// ROS 2 or ROS 1 bag: the colour topic (rgb8, bgr8, rgba8, bgra8, mono8), for --dataset.
    #[arg(long)]
    color_topic: Option<String>,
    /// ROS 2 or ROS 1 bag: take poses from the TF tree (/tf, /tf_static), in this fixed frame (default: the tree's root, e.g. map).
    #[arg(long)]
    pose_frame: Option<String>,
    /// ROS 2 or ROS 1 bag with TF: the camera's frame, replacing the depth images' frame_id.
    #[arg(long)]
    camera_frame: Option<String>,
    /// ROS 2 or ROS 1 bag: largest time from a depth frame to the nearest pose sample, seconds.
    #[arg(long, default_value_t = read::ros2::POSE_TOLERANCE, value_parser = params::non_negative_seconds, allow_negative_numbers = true)]
    pose_tolerance: f64,
    /// TUM, ROS 2 and ROS 1 bags: a frame's pose between the pose samples around its time.
    #[arg(long, value_enum, default_value_t = PoseInterpolation::Linear)]
    pub(crate) pose_interpolation: PoseInterpolation,
}

impl Ros2Args {
    pub(crate) fn options(&self) -> read::ros2::Ros2Options {
        read::ros2::Ros2Options {
            depth_topic: self.depth_topic.clone(),
            pose_topic: self.pose_topic.clone(),
            camera_info_topic: self.camera_info_topic.clone(),
            color_topic: self.color_topic.clone(),
            pose_frame: self.pose_frame.clone(),
            camera_frame: self.camera_frame.clone(),
            pose_tolerance: Some(self.pose_tolerance),
        }
    }
}

/// Solver parameters shared by select and compare.
#[derive(Args, Clone)]
pub struct ParamArgs {
    /// every-nth: take every N-th frame (N >= 1).
    #[arg(long, default_value_t = 10, value_parser = params::whole::<usize>(1, u64::MAX), allow_negative_numbers = true)]
    every_nth: usize,
    /// distance: take a frame each D metres of camera path (D > 0).
    #[arg(long, default_value_t = 0.5, value_parser = params::positive, allow_negative_numbers = true)]
    distance: f64,
    /// cube: take the frame nearest the centre of each C-metre cube of the trajectory's box (C > 0).
    #[arg(long, default_value_t = 1.0, value_parser = params::positive, allow_negative_numbers = true)]
    cube: f64,
    /// exact: time limit in seconds (above 0 to 1000000); past it the best set and a proven lower bound are reported.
    #[arg(long, default_value_t = 60.0, value_parser = params::time_limit, allow_negative_numbers = true)]
    time_limit: f64,
    /// online: device capacity profile (see `placedb budget`).
    #[arg(long, default_value = "ram512k", value_parser = params::profile())]
    profile: String,
    /// online: frames held undecided, from 1 (reproduces in-order) to the profile's
    /// window (`placedb budget` lists it).
    #[arg(long, default_value_t = 32, value_parser = params::window(), allow_negative_numbers = true)]
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
    /// No progress bars; select prints no summary either (its warnings and
    /// errors still go to stderr, and --json its JSON).
    #[arg(long, short)]
    quiet: bool,
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
        pose_interpolation: a.ros2.pose_interpolation,
    };
    Ok(read::open(path, &opts)?)
}

/// Bytes the host holds per voxel of a frame while the overlaps are counted:
/// the frame's set (a `u64` key), the inverted index's entry for it (its
/// voxel id and frame, two `u32`), and at worst (every voxel distinct, as
/// with millimetre voxels) a slot of the index's key map (`u64` key, `u32`
/// id, padded, one control byte, 7/8 full) and the voxel's start (`u32`).
const BYTES_PER_VOXEL: f64 = 8.0 + 2.0 * 4.0 + (16.0 + 1.0) * 8.0 / 7.0 + 4.0;

/// Above this many bytes a frame, [`warn_voxel_memory`] warns (the default
/// 0.3 m voxels take tens of kilobytes a frame).
const LARGE_FRAME_BYTES: f64 = 1e6;

/// Warns, before the work starts, when the voxel sets of `seq` will take
/// megabytes a frame (a small `--voxel`): a few frames are voxelized and
/// the whole sequence's memory estimated from them. Frames that cannot be
/// voxelized are left for the run itself to report.
pub(crate) fn warn_voxel_memory(seq: &Sequence, a: &SeqArgs) {
    let n = seq.frames.len();
    if n == 0 {
        return;
    }
    let mut sample = vec![0, n / 2, n - 1];
    sample.dedup();
    let Ok(counts) = crate::voxelize::voxel_counts(seq, &voxel_config(a), &sample) else {
        return;
    };
    let voxels = counts.iter().sum::<usize>() as f64 / counts.len() as f64;
    let per_frame = voxels * BYTES_PER_VOXEL;
    if per_frame >= LARGE_FRAME_BYTES {
        crate::warning::warn(format!(
            "--voxel {}: about {:.1} MB a frame ({:.0} voxels a frame, {:.0} bytes each while \
             the overlaps are counted), about {} for the {n} frames; a larger --voxel \
             or --stride takes less",
            a.voxel,
            per_frame / 1e6,
            voxels,
            BYTES_PER_VOXEL,
            megabytes_or_gigabytes(per_frame * n as f64)
        ));
    }
}

/// `bytes` as "12.3 MB" or, from a gigabyte, "1.2 GB".
fn megabytes_or_gigabytes(bytes: f64) -> String {
    if bytes < 1e9 {
        format!("{:.0} MB", bytes / 1e6)
    } else {
        format!("{:.1} GB", bytes / 1e9)
    }
}

pub(crate) fn open_test(path: &Path, a: &SeqArgs) -> Result<Sequence, Error> {
    let opts = ReadOptions {
        format: None,
        depth_scale: a.depth_scale,
        intrinsics: a.intrinsics,
        ros2: a.ros2.options(),
        pose_interpolation: a.ros2.pose_interpolation,
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

/// The solver parameters of `p`, refused when `--window` is more than
/// `--profile` holds (the one check that needs two options; the others are
/// their parsers'). Commands call it first, before reading the sequence.
pub(crate) fn solver_params(p: &ParamArgs) -> Result<SolverParams, Error> {
    params::check_window(&p.profile, p.window)?;
    Ok(SolverParams {
        every_nth: p.every_nth,
        distance: p.distance,
        cube: p.cube,
        time_limit: Duration::from_secs_f64(p.time_limit),
        profile: p.profile.clone(),
        window: p.window,
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
