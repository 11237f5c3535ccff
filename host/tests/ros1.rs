//! ROS 1 bags in: the fixture script (host/tests/recordings/write_recordings.py)
//! writes `.bag` files of 7scenes-1000 frames with the `rosbags` library's
//! own ROS 1 writer — chunks uncompressed, bz2 and lz4, poses as PoseStamped
//! or a TF tree — from the poses placedb reads off the 7-Scenes files; the
//! reader must give back the same frames, depth and database as the 7-Scenes
//! layout, and refuse a bag cut inside a chunk in words naming the file.

mod bag_common;

use bag_common::{assert_same_selection, database, write_recordings};
use placedb_host::pipeline::Solver;
use placedb_host::read::{self, ReadOptions};
use placedb_host::sequence::PoseInterpolation;
use placedb_host::{Format, ReadError, Sequence};
use std::path::{Path, PathBuf};

/// Frames of 7scenes-1000 written to the bags (each is 600 KB of depth).
const FRAMES: usize = 14;

fn sevenscenes() -> Sequence {
    bag_common::sevenscenes(FRAMES)
}

/// A fresh folder for one test (tests of one binary run in parallel).
fn temp(name: &str) -> PathBuf {
    let p = std::env::temp_dir().join(format!("placedb-ros1-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&p);
    std::fs::create_dir_all(&p).unwrap();
    p
}

/// Reads a bag with the nearest pose rule (the bags hold a pose at every
/// frame's stamp, so it gives the 7-Scenes poses bit for bit).
fn open(path: &Path) -> Result<Sequence, ReadError> {
    read::open(
        path,
        &ReadOptions {
            pose_interpolation: PoseInterpolation::Nearest,
            ..ReadOptions::default()
        },
    )
}

fn same_database(ros: &Sequence, s7: &Sequence, what: &str) {
    for solver in [Solver::InOrder, Solver::Online] {
        assert_eq!(
            database(ros, solver),
            database(s7, solver),
            "{what} {solver:?}"
        );
    }
}

#[test]
fn plain_bz2_and_lz4_bags_give_the_7scenes_frames_depth_and_database() {
    let s7 = sevenscenes();
    let dir = temp("chunks");
    // lz4 as the rosbags library frames it (linked blocks, no checksum) and
    // as rosbag does (independent 1 MiB blocks, a content checksum).
    let variants = ["ros1", "ros1-bz2", "ros1-lz4", "ros1-roslz4"];
    let out = write_recordings(&dir, &s7, &variants);
    for name in variants {
        let bag = out.join(format!("{name}.bag"));
        assert_eq!(read::detect(&bag).unwrap(), Format::Ros1, "{name}");
        let ros = open(&bag).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(ros.format, Format::Ros1);
        assert_eq!(ros.frames.len(), s7.frames.len(), "{name}");
        assert_eq!(
            (ros.camera, ros.depth_scale, ros.size),
            (s7.camera, s7.depth_scale, s7.size),
            "{name}"
        );
        for (a, b) in ros.frames.iter().zip(&s7.frames) {
            assert_eq!(
                (a.timestamp, a.translation, a.rotation),
                (b.timestamp, b.translation, b.rotation),
                "{name}"
            );
        }
        for i in [0, FRAMES / 2, FRAMES - 1] {
            assert_eq!(ros.depth(i).unwrap(), s7.depth(i).unwrap(), "{name} {i}");
        }
        same_database(&ros, &s7, name);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_tf_tree_bag_gives_the_7scenes_poses_and_database() {
    let s7 = sevenscenes();
    let dir = temp("tf");
    // The tree as tf2 records it (/tf_static), and as tf1 did (TUM RGB-D's
    // bags): every link on /tf as tf/tfMessage, frames named `/map`, found
    // from `map` as tf2 finds them.
    let out = write_recordings(&dir, &s7, &["ros1-tf", "ros1-tf1"]);
    let from = |pose_frame: Option<&str>| ReadOptions {
        pose_interpolation: PoseInterpolation::Nearest,
        ros2: read::ros2::Ros2Options {
            pose_frame: pose_frame.map(str::to_string),
            ..Default::default()
        },
        ..ReadOptions::default()
    };
    for (variant, pose_frame) in [
        ("ros1-tf", None),
        ("ros1-tf1", None),
        ("ros1-tf1", Some("map")),
        ("ros1-tf1", Some("/map")),
    ] {
        let what = format!("{variant} from {pose_frame:?}");
        let bag = out.join(format!("{variant}.bag"));
        let ros = read::open(&bag, &from(pose_frame)).unwrap_or_else(|e| panic!("{what}: {e}"));
        assert_eq!(ros.frames.len(), s7.frames.len(), "{what}");
        for (a, b) in ros.frames.iter().zip(&s7.frames) {
            assert_eq!(a.timestamp, b.timestamp);
            let near = |x: &[f64], y: &[f64]| x.iter().zip(y).all(|(p, q)| (p - q).abs() <= 1e-9);
            assert!(
                near(&a.translation, &b.translation) && near(&a.rotation, &b.rotation),
                "{what} t={}: {:?} {:?} vs {:?} {:?}",
                a.timestamp,
                a.translation,
                a.rotation,
                b.translation,
                b.rotation
            );
        }
        // The same frames selected, the same labels; the poses in
        // database.csv are the composed ones (equal to float64 rounding).
        assert_same_selection(&ros, &s7, &what);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_bag_cut_inside_a_chunk_or_of_format_1_2_is_an_error_naming_the_file() {
    let s7 = sevenscenes();
    let dir = temp("truncated");
    let out = write_recordings(&dir, &s7, &["bad-truncated-bag"]);
    let bag = out.join("bad-truncated-bag.bag");
    let Err(e) = open(&bag) else {
        panic!("a truncated bag must be refused");
    };
    let text = e.to_string();
    assert!(
        text.contains("bad-truncated-bag.bag") && text.contains("cut short"),
        "{text}"
    );
    // A bag of the older format 1.2 is refused by name, not read as MCAP.
    let old = dir.join("old.bag");
    std::fs::write(&old, b"#ROSBAG V1.2\nE\0\0\0").unwrap();
    assert_eq!(read::detect(&old).unwrap(), Format::Ros1);
    let Err(e) = open(&old) else {
        panic!("a format 1.2 bag must be refused");
    };
    let text = e.to_string();
    assert!(
        text.contains("old.bag") && text.contains("not a ROS 1 bag of format 2.0"),
        "{text}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
