//! The command line's names for the library's choices (`--solver`,
//! `--format`, `--grid-origin`): clap's `ValueEnum` for each, here so that
//! the types below `cli` stay free of the command line. Each name is the
//! one the type serializes as (metrics.json, the extension file), and each
//! help line is what `--help` lists.

use crate::pipeline::Solver;
use crate::sequence::{Format, PoseInterpolation};
use crate::voxelize::GridOrigin;
use clap::builder::PossibleValue;
use clap::ValueEnum;

impl ValueEnum for Solver {
    fn value_variants<'a>() -> &'a [Self] {
        &Solver::ALL
    }

    fn to_possible_value(&self) -> Option<PossibleValue> {
        let help = match self {
            Solver::InOrder => "The paper's result: take a frame iff no taken frame overlaps it",
            Solver::Greedy => "Take the frame dominating most undominated frames, repeatedly",
            Solver::Exact => {
                "A minimum dominating set (integer program, HiGHS), within a time limit"
            }
            Solver::Online => "The device core's streaming selector, replayed",
            Solver::EveryNth => "Baseline: every N-th frame",
            Solver::Distance => "Baseline: a frame each D metres of path",
            Solver::Cube => "Baseline: the frame nearest the centre of each C-metre cube",
        };
        Some(PossibleValue::new(self.name()).help(help))
    }
}

impl ValueEnum for Format {
    /// Every layout `--format` offers (not `Synthetic`: `--demo` is no
    /// layout to read).
    fn value_variants<'a>() -> &'a [Self] {
        &[
            Format::Tum,
            Format::SevenScenes,
            Format::Vprdb,
            Format::Ros2,
            Format::Ros1,
            Format::ScanNet,
        ]
    }

    fn to_possible_value(&self) -> Option<PossibleValue> {
        let (name, help) = match self {
            Format::Tum => ("tum", "TUM RGB-D: depth.txt, rgb.txt, groundtruth.txt"),
            Format::SevenScenes => (
                "7scenes",
                "Microsoft 7-Scenes: frame-XXXXXX.depth.png and .pose.txt",
            ),
            Format::Vprdb => (
                "vprdb",
                "The reference code's layout: depth/, color/, poses file, intrinsics.txt",
            ),
            Format::Ros2 => (
                "ros2",
                "A ROS 2 recording (rosbag2, MCAP or sqlite3): a bag folder, a .mcap or .db3 file",
            ),
            Format::ScanNet => (
                "scannet",
                "ScanNet's export: depth/N.png, pose/N.txt, color/N.jpg, intrinsic/",
            ),
            Format::Ros1 => (
                "ros1",
                "A ROS 1 bag (format 2.0; chunks uncompressed, bz2 or lz4): a `.bag` file",
            ),
            Format::Synthetic | Format::Arrays => return None,
        };
        Some(PossibleValue::new(name).help(help))
    }
}

impl ValueEnum for PoseInterpolation {
    fn value_variants<'a>() -> &'a [Self] {
        &[PoseInterpolation::Linear, PoseInterpolation::Nearest]
    }

    fn to_possible_value(&self) -> Option<PossibleValue> {
        let (name, help) = match self {
            PoseInterpolation::Linear => (
                "linear",
                "Linear in position, spherical-linear in rotation; never extrapolated",
            ),
            PoseInterpolation::Nearest => ("nearest", "The pose sample nearest in time"),
        };
        Some(PossibleValue::new(name).help(help))
    }
}

impl ValueEnum for GridOrigin {
    fn value_variants<'a>() -> &'a [Self] {
        &[GridOrigin::World, GridOrigin::SceneMin]
    }

    fn to_possible_value(&self) -> Option<PossibleValue> {
        let (name, help) = match self {
            GridOrigin::World => (
                "world",
                "The world origin: what the device does, since it cannot know the scene in advance",
            ),
            GridOrigin::SceneMin => (
                "scene-min",
                "The minimum corner of all points: what the reference code does",
            ),
        };
        Some(PossibleValue::new(name).help(help))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The command line's names are the names the files carry.
    #[test]
    fn names_are_the_serialized_names() {
        fn serialized<T: serde::Serialize>(v: T) -> String {
            serde_json::to_value(v)
                .unwrap()
                .as_str()
                .unwrap()
                .to_string()
        }
        for s in Solver::value_variants() {
            assert_eq!(s.to_possible_value().unwrap().get_name(), serialized(*s));
        }
        for f in Format::value_variants() {
            assert_eq!(f.to_possible_value().unwrap().get_name(), serialized(*f));
        }
        for p in PoseInterpolation::value_variants() {
            assert_eq!(p.to_possible_value().unwrap().get_name(), serialized(*p));
        }
        for o in GridOrigin::value_variants() {
            assert_eq!(o.to_possible_value().unwrap().get_name(), serialized(*o));
        }
    }
}
