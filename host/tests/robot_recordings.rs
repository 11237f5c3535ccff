//! Recordings made the way robots make them, by the ecosystem's own writers
//! (`host/tests/recordings/write_recordings.py`: the Python `rosbags` library
//! for bags, OpenCV for PNGs), from the first frames of the 7-Scenes sample:
//! each must read as the 7-Scenes layout of the same frames, and each broken
//! one must be refused in words with nothing written.

mod bag_common;
mod cli_common;

use bag_common::{assert_same_selection, database, write_recordings, SEVEN_SCENES};
use cli_common::{placedb, stderr, TempDir};
use placedb_host::pipeline::Solver;
use placedb_host::read::ros2::{color_codec, Ros2Options};
use placedb_host::read::timed_poses::{interpolate, TimedPose};
use placedb_host::read::{self, ReadOptions};
use placedb_host::sequence::PoseInterpolation;
use placedb_host::{Format, Sequence};
use std::path::Path;

/// Frames of the sample each recording holds.
const FRAMES: usize = 16;

fn sevenscenes() -> Sequence {
    bag_common::sevenscenes(FRAMES)
}

fn open(path: &Path, ros2: Ros2Options, rule: PoseInterpolation) -> Sequence {
    read::open(
        path,
        &ReadOptions {
            ros2,
            pose_interpolation: rule,
            ..ReadOptions::default()
        },
    )
    .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `depth` with 65535 ("no measurement" in 7-Scenes, dropped by the
/// compressedDepth encoder's 10 m limit) as 0.
fn blank_65535(depth: &[u16]) -> Vec<u16> {
    depth
        .iter()
        .map(|&v| if v == u16::MAX { 0 } else { v })
        .collect()
}

fn assert_same_frames(name: &str, got: &Sequence, want: &Sequence) {
    assert_eq!(got.frames.len(), want.frames.len(), "{name}");
    assert_eq!((got.camera, got.size), (want.camera, want.size), "{name}");
    for (a, b) in got.frames.iter().zip(&want.frames) {
        assert_eq!(
            (a.timestamp, a.translation, a.rotation),
            (b.timestamp, b.translation, b.rotation),
            "{name}"
        );
    }
}

/// Each ROS 2 bag `names` in `out` is detected as one and gives the
/// frames, depth (first, middle, last) and databases of `s7`.
fn assert_ros2_bags_read_as(out: &Path, names: &[&str], s7: &Sequence) {
    let want = [Solver::InOrder, Solver::Online].map(|s| database(s7, s));
    for name in names {
        let bag = out.join(name);
        assert_eq!(read::detect(&bag).unwrap(), Format::Ros2, "{name}");
        let seq = open(&bag, Ros2Options::default(), PoseInterpolation::Linear);
        assert_same_frames(name, &seq, s7);
        for i in [0, FRAMES / 2, FRAMES - 1] {
            assert_eq!(seq.depth(i).unwrap(), s7.depth(i).unwrap(), "{name} {i}");
        }
        let got = [Solver::InOrder, Solver::Online].map(|s| database(&seq, s));
        assert_eq!(got, want, "{name}");
    }
}

#[test]
fn ros2_bags_in_sqlite3_split_sqlite3_and_mcap_read_as_the_7scenes_frames() {
    let s7 = sevenscenes();
    let dir = TempDir::new("rec-sqlite3");
    let bags = ["ros2-sqlite3", "ros2-sqlite3-split", "ros2-mcap"];
    let out = write_recordings(dir.path(), &s7, &bags);
    assert_ros2_bags_read_as(&out, &bags, &s7);
    // One .db3 file given alone reads the same, as a .mcap does.
    let single = out.join("ros2-sqlite3").join("ros2-sqlite3.db3");
    assert_eq!(read::detect(&single).unwrap(), Format::Ros2);
    let seq = open(&single, Ros2Options::default(), PoseInterpolation::Linear);
    assert_same_frames("one .db3", &seq, &s7);
    // Colour rides along in the sqlite3 bag, frame by frame.
    let seq = open(
        &out.join("ros2-sqlite3"),
        Ros2Options::default(),
        PoseInterpolation::Linear,
    );
    assert!(seq.source.color(FRAMES - 1).unwrap().is_some());
    // The command on the sqlite3 bag writes what it writes on the 7-Scenes
    // frames, and says how the poses were taken.
    let bag = out.join("ros2-sqlite3").to_string_lossy().into_owned();
    let frames = FRAMES.to_string();
    let a = placedb(&["select", &bag, "-q", "-o", &dir.arg("bag")]);
    let b = placedb(&[
        "select",
        SEVEN_SCENES,
        "--max-frames",
        &frames,
        "-q",
        "-o",
        &dir.arg("7scenes"),
    ]);
    assert!(a.status.success() && b.status.success(), "{}", stderr(&a));
    for file in ["database.csv", "labels.csv"] {
        assert_eq!(
            std::fs::read(dir.path().join("bag").join(file)).unwrap(),
            std::fs::read(dir.path().join("7scenes").join(file)).unwrap(),
            "{file}"
        );
    }
    let metrics = std::fs::read_to_string(dir.path().join("bag/metrics.json")).unwrap();
    assert!(
        metrics.contains("\"pose_interpolation\": \"linear\""),
        "{metrics}"
    );
}

/// An MCAP bag whose chunks are compressed (zstd, as rosbag2's `zstd_fast`
/// and `zstd_small` storage presets record, or lz4) reads as the same bag
/// with plain chunks: the same frames and depth, and the command writes
/// the same database and labels.
#[test]
fn mcap_chunks_compressed_as_rosbag2_presets_write_them_read_as_plain_ones() {
    let s7 = sevenscenes();
    let dir = TempDir::new("rec-mcap-chunks");
    let out = write_recordings(dir.path(), &s7, &["ros2-mcap"]);
    let plain = out.join("ros2-mcap");
    let metadata = std::fs::read_to_string(plain.join("metadata.yaml")).unwrap();
    let select = |bag: &Path, to: &str| {
        let bag = bag.to_string_lossy().into_owned();
        let run = placedb(&["select", &bag, "-q", "-o", &dir.arg(to)]);
        assert!(run.status.success(), "{to}: {}", stderr(&run));
    };
    select(&plain, "plain");
    // `bench --walk-only`, the bench's one pass over a bag: its messages
    // and their bytes.
    let walk = |bag: &Path| -> serde_json::Value {
        let run = placedb(&["bench", "--walk-only", &bag.to_string_lossy()]);
        assert!(run.status.success(), "{}", stderr(&run));
        serde_json::from_slice(&run.stdout).unwrap()
    };
    let plain_walk = walk(&plain);
    for (name, compression) in [
        ("zstd", mcap::Compression::Zstd),
        ("lz4", mcap::Compression::Lz4),
    ] {
        let bag = dir.path().join(format!("ros2-mcap-{name}"));
        std::fs::create_dir_all(&bag).unwrap();
        let file = format!("ros2-mcap-{name}.mcap");
        let written = placedb_host::testing::mcap_recompress(
            &plain.join("ros2-mcap.mcap"),
            &bag.join(&file),
            Some(compression),
        )
        .unwrap();
        assert!(written > 2 * FRAMES, "{name}: {written} messages");
        std::fs::write(
            bag.join("metadata.yaml"),
            metadata.replace("ros2-mcap.mcap", &file),
        )
        .unwrap();
        // The walk meets every message the writer wrote, decompressed to
        // the plain bag's bytes.
        let walked = walk(&bag);
        assert_eq!(walked["messages"], written as u64, "{name}");
        assert_eq!(walked["messages"], plain_walk["messages"], "{name}");
        assert_eq!(walked["bytes"], plain_walk["bytes"], "{name}");
        let seq = open(&bag, Ros2Options::default(), PoseInterpolation::Linear);
        assert_same_frames(name, &seq, &s7);
        for i in 0..FRAMES {
            assert_eq!(seq.depth(i).unwrap(), s7.depth(i).unwrap(), "{name} {i}");
        }
        select(&bag, name);
        for csv in ["database.csv", "labels.csv"] {
            assert_eq!(
                std::fs::read(dir.path().join(name).join(csv)).unwrap(),
                std::fs::read(dir.path().join("plain").join(csv)).unwrap(),
                "{name}: {csv}"
            );
        }
    }
}

/// Bags rosbag2 compressed itself (`ros2 bag record --compression-format
/// zstd --compression-mode file|message`, Humble's only compression for
/// sqlite3) read as the plain bag: the same frames, depth and database.
/// A file given alone reads too. The command decompresses a
/// file-compressed bag into TMPDIR and leaves nothing there (and removes
/// what a reading killed before its end left); a cut file and a damaged
/// message are refused in words, nothing written.
#[test]
fn bags_rosbag2_compressed_file_by_file_or_message_by_message_read_as_plain_ones() {
    let s7 = sevenscenes();
    let dir = TempDir::new("rec-rosbag2-zstd");
    let variants = [
        "ros2-sqlite3-zstd-file",
        "ros2-sqlite3-zstd-message",
        "ros2-mcap-zstd-file",
        "ros2-mcap-zstd-message",
    ];
    let out = write_recordings(
        dir.path(),
        &s7,
        &[&["ros2-sqlite3"][..], &variants].concat(),
    );
    assert_ros2_bags_read_as(&out, &variants, &s7);
    // Through the command, with a TMPDIR of its own holding a folder a
    // killed reading left (a process id no system gives).
    let tmp = dir.path().join("tmp");
    let abandoned = tmp.join(format!(".placedb-bag-{}-x", u32::MAX));
    std::fs::create_dir_all(abandoned.join("bag_0.db3")).unwrap();
    let select = |bag: &str, to: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_placedb"))
            .args(["select", &out.join(bag).to_string_lossy(), "-q", "-o"])
            .arg(dir.path().join(to))
            .env("TMPDIR", &tmp)
            .output()
            .unwrap()
    };
    // Files given alone, without their metadata.yaml, tell by themselves
    // how rosbag2 compressed them.
    for (from, to) in [
        (
            "ros2-sqlite3-zstd-message/ros2-sqlite3-zstd-message.db3",
            "alone-message.db3",
        ),
        (
            "ros2-mcap-zstd-file/ros2-mcap-zstd-file.mcap.zstd",
            "alone-file.mcap.zstd",
        ),
    ] {
        std::fs::copy(out.join(from), out.join(to)).unwrap();
    }
    for bag in [
        "ros2-sqlite3",
        "ros2-sqlite3-zstd-file",
        "ros2-mcap-zstd-message",
        "alone-message.db3",
        "alone-file.mcap.zstd",
    ] {
        let run = select(bag, bag);
        assert!(run.status.success(), "{bag}: {}", stderr(&run));
        for csv in ["database.csv", "labels.csv"] {
            assert_eq!(
                std::fs::read(dir.path().join(bag).join(csv)).unwrap(),
                std::fs::read(dir.path().join("ros2-sqlite3").join(csv)).unwrap(),
                "{bag}: {csv}"
            );
        }
        // Read plain, the bag needs no folder; read file-compressed, its
        // folder and the abandoned one are gone.
        let left: Vec<_> = std::fs::read_dir(&tmp).unwrap().collect();
        assert_eq!(
            left.is_empty(),
            bag != "ros2-sqlite3",
            "{bag}: TMPDIR has {left:?}"
        );
    }
    // A file-compressed bag file cut short.
    let file = out.join("ros2-sqlite3-zstd-file/ros2-sqlite3-zstd-file.db3.zstd");
    let bytes = std::fs::read(&file).unwrap();
    std::fs::write(&file, &bytes[..bytes.len() / 2]).unwrap();
    // A message-compressed depth message with bytes flipped in its middle.
    let db = out.join("ros2-sqlite3-zstd-message/ros2-sqlite3-zstd-message.db3");
    let conn = rusqlite::Connection::open(&db).unwrap();
    let (id, mut data): (i64, Vec<u8>) = conn
        .query_row(
            "SELECT m.id, m.data FROM messages m JOIN topics t ON t.id = m.topic_id \
             WHERE t.name = '/camera/depth/image_rect_raw' ORDER BY m.timestamp LIMIT 1 OFFSET 2",
            [],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )
        .unwrap();
    let mid = data.len() / 2;
    for b in &mut data[mid..mid + 4] {
        *b ^= 0xff;
    }
    conn.execute(
        "UPDATE messages SET data = ?1 WHERE id = ?2",
        rusqlite::params![data, id],
    )
    .unwrap();
    drop(conn);
    for (bag, needles) in [
        (
            "ros2-sqlite3-zstd-file",
            &["ros2-sqlite3-zstd-file.db3.zstd", "does not decompress"][..],
        ),
        (
            "ros2-sqlite3-zstd-message",
            &[
                "ros2-sqlite3-zstd-message.db3",
                "/camera/depth/image_rect_raw at t=2.000000",
                "does not decompress",
            ][..],
        ),
    ] {
        let to = format!("broken-{bag}");
        let run = select(bag, &to);
        let e = stderr(&run);
        assert_eq!(run.status.code(), Some(1), "{bag}: {e}");
        for n in needles {
            assert!(e.contains(n), "{bag}: {n:?} not in {e}");
        }
        assert!(!dir.path().join(&to).exists(), "{bag}: wrote its output");
        let left: Vec<_> = std::fs::read_dir(&tmp).unwrap().collect();
        assert!(left.is_empty(), "{bag} left {left:?} in TMPDIR");
    }
}

/// A run stopped by SIGINT or SIGTERM while it reads a file-compressed
/// bag removes the folder it decompressed the bag into, as it removes its
/// partial outputs, and exits 130 or 143 with nothing written.
#[test]
fn a_run_stopped_while_it_reads_a_file_compressed_bag_leaves_nothing_in_tmpdir() {
    // Frames enough that the folder lives a good part of a second.
    let s7 = bag_common::sevenscenes(200);
    let dir = TempDir::new("rec-rosbag2-zstd-stopped");
    let out = write_recordings(dir.path(), &s7, &["ros2-sqlite3-zstd-file"]);
    let tmp = dir.path().join("tmp");
    std::fs::create_dir_all(&tmp).unwrap();
    for (signal, code) in [("INT", 130), ("TERM", 143)] {
        let target = dir.path().join(format!("out-{signal}"));
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_placedb"))
            .arg("select")
            .arg(out.join("ros2-sqlite3-zstd-file"))
            .args(["-q", "-o"])
            .arg(&target)
            .env("TMPDIR", &tmp)
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        let start = std::time::Instant::now();
        while std::fs::read_dir(&tmp).unwrap().next().is_none() {
            assert!(
                child.try_wait().unwrap().is_none(),
                "{signal}: the run ended before it decompressed the bag"
            );
            assert!(
                start.elapsed().as_secs() < 120,
                "{signal}: no folder in TMPDIR"
            );
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        let killed = std::process::Command::new("kill")
            .args([&format!("-{signal}"), &child.id().to_string()])
            .status()
            .unwrap();
        assert!(killed.success());
        let status = child.wait().unwrap();
        assert_eq!(status.code(), Some(code), "{signal}");
        let left: Vec<_> = std::fs::read_dir(&tmp).unwrap().collect();
        assert!(left.is_empty(), "{signal}: TMPDIR has {left:?}");
        assert!(!target.exists(), "{signal}: wrote {}", target.display());
    }
}

#[test]
fn compressed_depth_as_image_transport_writes_it() {
    let s7 = sevenscenes();
    let dir = TempDir::new("rec-compressed");
    let variants = [
        "ros2-compressed-png",
        "ros2-compressed-png-rolling",
        "ros2-compressed-rvl",
        "ros2-png",
        "ros2-compressed-32f",
    ];
    let out = write_recordings(dir.path(), &s7, &variants);
    let want = [Solver::InOrder, Solver::Online].map(|s| database(&s7, s));
    for name in variants {
        let seq = open(
            &out.join(name),
            Ros2Options::default(),
            PoseInterpolation::Linear,
        );
        assert_same_frames(name, &seq, &s7);
        for i in [0, FRAMES / 2, FRAMES - 1] {
            let (got, source) = (seq.depth(i).unwrap(), s7.depth(i).unwrap());
            if name == "ros2-compressed-32f" {
                // Inverse depth in 16 bits: a step is d^2 / 10100 m, 1.3 mm
                // at 3.6 m; "no depth" stays no depth.
                for (g, s) in got.data.iter().zip(&source.data) {
                    assert_eq!(*g == 0, *s == 0, "{name} {i}");
                    assert!(g.abs_diff(*s) <= 2, "{name} {i}: {g} for {s}");
                }
            } else {
                assert_eq!(blank_65535(&got.data), source.data, "{name} {i}");
            }
        }
        let got = [Solver::InOrder, Solver::Online].map(|s| database(&seq, s));
        assert_eq!(got, want, "{name}");
    }
    // Colour recorded compressed, as robots do (a JPEG CompressedImage):
    // found without --color-topic, each frame's the sample's JPEG decoded.
    let seq = open(
        &out.join("ros2-compressed-png-rolling"),
        Ros2Options::default(),
        PoseInterpolation::Linear,
    );
    for i in [0, FRAMES - 1] {
        let jpeg =
            std::fs::read(Path::new(SEVEN_SCENES).join(format!("frame-{i:06}.color.jpg"))).unwrap();
        let want = color_codec::decode(color_codec::ColorCodec::Jpeg, &jpeg).unwrap();
        assert_eq!(
            seq.source.color(i).unwrap(),
            Some(want),
            "colour of frame {i}"
        );
    }
}

#[test]
fn poses_from_the_tf_tree_and_between_half_rate_samples() {
    let s7 = sevenscenes();
    let dir = TempDir::new("rec-tf");
    let out = write_recordings(
        dir.path(),
        &s7,
        &["ros2-tf", "ros2-tf-half-rate", "ros2-pose-half-rate"],
    );
    let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-9);
    // map -> odom -> base_link (on /tf) -> camera_link -> the optical frame
    // (on /tf_static), composed from the root down to the images' frame.
    let tf = open(
        &out.join("ros2-tf"),
        Ros2Options::default(),
        PoseInterpolation::Linear,
    );
    assert_eq!(tf.frames.len(), FRAMES);
    for (a, b) in tf.frames.iter().zip(&s7.frames) {
        assert!(close(&a.translation, &b.translation), "{a:?} {b:?}");
        let dot: f64 = a.rotation.iter().zip(&b.rotation).map(|(x, y)| x * y).sum();
        assert!((dot.abs() - 1.0).abs() < 1e-9, "{a:?} {b:?}");
    }
    // The same database and labels; database.csv's poses are the composed
    // ones, equal to the last few bits of a double.
    assert_same_selection(&tf, &s7, "ros2-tf");
    // From odom instead of the root: the map -> odom offset is left out.
    let from_odom = open(
        &out.join("ros2-tf"),
        Ros2Options {
            pose_frame: Some("odom".into()),
            ..Ros2Options::default()
        },
        PoseInterpolation::Linear,
    );
    assert!(!close(
        &from_odom.frames[0].translation,
        &tf.frames[0].translation
    ));
    // Poses at even frames only, a second apart: the odd frames lie between
    // two samples, interpolated with a tolerance that reaches them; the last
    // (odd) frame is after the last sample and is not extrapolated.
    let sample = |i: usize| TimedPose {
        stamp: s7.frames[i].timestamp,
        translation: s7.frames[i].translation,
        rotation: s7.frames[i].rotation,
    };
    let reach = || Ros2Options {
        pose_tolerance: Some(1.0),
        ..Ros2Options::default()
    };
    for name in ["ros2-pose-half-rate", "ros2-tf-half-rate"] {
        let seq = open(&out.join(name), reach(), PoseInterpolation::Linear);
        assert_eq!(seq.frames.len(), FRAMES - 1, "{name}");
        assert_eq!(seq.frames_skipped, 1, "{name}");
        for (i, f) in seq.frames.iter().enumerate() {
            let want = match i % 2 {
                0 => sample(i),
                _ => interpolate(&sample(i - 1), &sample(i + 1), f.timestamp),
            };
            // TF interpolates each dynamic link, as tf2 does: base_link's
            // position moves on a line, and the camera, offset from it by
            // the static links, turns with it; the rotation is the same.
            let far = f
                .translation
                .iter()
                .zip(&want.translation)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            match name {
                "ros2-tf-half-rate" => assert!(far < 0.01, "{name} {i}: {far} m"),
                _ => assert!(close(&f.translation, &want.translation), "{name} {i}"),
            }
            let dot: f64 = f
                .rotation
                .iter()
                .zip(&want.rotation)
                .map(|(x, y)| x * y)
                .sum();
            assert!((dot.abs() - 1.0).abs() < 1e-9, "{name} {i}");
        }
        // The nearest rule: an odd frame takes the earlier sample whole.
        let nearest = open(&out.join(name), reach(), PoseInterpolation::Nearest);
        assert_eq!(nearest.frames.len(), FRAMES, "{name}");
        assert!(close(
            &nearest.frames[3].translation,
            &s7.frames[2].translation
        ));
        // Within the default 0.05 s, only the frames at a sample have one.
        let default = open(
            &out.join(name),
            Ros2Options::default(),
            PoseInterpolation::Linear,
        );
        assert_eq!(default.frames.len(), FRAMES / 2, "{name}");
    }
}

#[test]
fn a_scannet_export_reads_as_7scenes_without_its_lost_frame() {
    let s7 = sevenscenes();
    let dir = TempDir::new("rec-scannet");
    let out = write_recordings(dir.path(), &s7, &["scannet"]);
    let scan = out.join("scannet");
    assert_eq!(read::detect(&scan).unwrap(), Format::ScanNet);
    let seq = open(&scan, Ros2Options::default(), PoseInterpolation::Linear);
    // Frame 3's pose is ScanNet's -inf: skipped, counted; the others keep
    // their numbers and 7-Scenes' poses bit for bit.
    assert_eq!(seq.frames_skipped, 1);
    let kept: Vec<_> = s7.frames.iter().filter(|f| f.timestamp != 3.0).collect();
    assert_eq!(seq.frames.len(), kept.len());
    for (a, b) in seq.frames.iter().zip(&kept) {
        assert_eq!(
            (a.timestamp, a.translation, a.rotation),
            (b.timestamp, b.translation, b.rotation)
        );
    }
    assert_eq!(seq.camera, s7.camera);
    assert_eq!(
        blank_65535(&seq.depth(3).unwrap().data),
        s7.depth(4).unwrap().data
    );
    // The command names the lost frame and writes the database of the
    // 7-Scenes frames without it.
    let copy = dir.path().join("7scenes");
    cli_common::seven_scenes_copy(&copy, FRAMES, true);
    for ext in ["depth.png", "pose.txt", "color.jpg"] {
        let _ = std::fs::remove_file(copy.join(format!("frame-000003.{ext}")));
    }
    assert!(!copy.join("frame-000003.depth.png").exists());
    let a = placedb(&["select", &scan.to_string_lossy(), "-o", &dir.arg("a")]);
    let b = placedb(&["select", &copy.to_string_lossy(), "-q", "-o", &dir.arg("b")]);
    assert!(a.status.success() && b.status.success(), "{}", stderr(&a));
    assert!(
        stderr(&a).contains("1 of 16 frames have an invalid pose")
            && stderr(&a).contains("pose/3.txt"),
        "{}",
        stderr(&a)
    );
    for file in ["database.csv", "labels.csv"] {
        assert_eq!(
            std::fs::read(dir.path().join("a").join(file)).unwrap(),
            std::fs::read(dir.path().join("b").join(file)).unwrap(),
            "{file}"
        );
    }
    // The same export laid out as ScanNet's `scannet_frames_25k` release:
    // numbers padded to six digits, intrinsics_depth.txt beside the
    // folders. Each frame's pose and colour go by its depth file's name.
    let frames_25k = dir.path().join("frames_25k");
    for sub in ["depth", "pose", "color"] {
        std::fs::create_dir_all(frames_25k.join(sub)).unwrap();
        for entry in std::fs::read_dir(scan.join(sub)).unwrap() {
            let name = entry.unwrap().file_name().into_string().unwrap();
            let (number, ext) = name.split_once('.').unwrap();
            let padded = format!("{:06}.{ext}", number.parse::<u32>().unwrap());
            std::fs::copy(
                scan.join(sub).join(&name),
                frames_25k.join(sub).join(padded),
            )
            .unwrap();
        }
    }
    std::fs::copy(
        scan.join("intrinsic/intrinsic_depth.txt"),
        frames_25k.join("intrinsics_depth.txt"),
    )
    .unwrap();
    assert_eq!(read::detect(&frames_25k).unwrap(), Format::ScanNet);
    let padded = open(
        &frames_25k,
        Ros2Options::default(),
        PoseInterpolation::Linear,
    );
    assert_eq!(padded.frames.len(), seq.frames.len());
    for (a, b) in padded.frames.iter().zip(&seq.frames) {
        assert_eq!(
            (a.timestamp, a.translation, a.rotation),
            (b.timestamp, b.translation, b.rotation)
        );
        assert_eq!(a.color_path.is_some(), b.color_path.is_some());
    }
    let c = placedb(&["select", &frames_25k.to_string_lossy(), "-o", &dir.arg("c")]);
    assert!(c.status.success(), "{}", stderr(&c));
    assert!(stderr(&c).contains("pose/000003.txt"), "{}", stderr(&c));
    for file in ["database.csv", "labels.csv"] {
        assert_eq!(
            std::fs::read(dir.path().join("c").join(file)).unwrap(),
            std::fs::read(dir.path().join("a").join(file)).unwrap(),
            "{file}"
        );
    }
}

#[test]
fn broken_recordings_are_refused_in_words_and_nothing_is_written() {
    let s7 = sevenscenes();
    let dir = TempDir::new("rec-bad");
    let cases: [(&str, &[&str]); 5] = [
        (
            "bad-truncated-db3",
            &[
                "bad-truncated-db3.db3",
                "not a readable rosbag2 sqlite3 file",
            ],
        ),
        (
            "bad-short-compressed",
            &[
                "/camera/depth/image_rect_raw/compressedDepth",
                "t=2.000000",
                "7 bytes has no image after its 12-byte header",
            ],
        ),
        (
            "bad-8bit-png",
            &[
                "/camera/depth/image_rect_raw/compressedDepth",
                "t=2.000000",
                "8-bit",
                "16-bit",
            ],
        ),
        (
            "bad-tf-cycle",
            &["cycle", "base_link", "odom", "map", "t=0.000000"],
        ),
        (
            "bad-tf-two-parents",
            &[
                "`base_link` has two parents",
                "`odom`",
                "`map`",
                "/tf at t=",
            ],
        ),
    ];
    let out = write_recordings(dir.path(), &s7, &cases.map(|(name, _)| name));
    for (name, needles) in cases {
        let target = dir.path().join(format!("out-{name}"));
        let run = placedb(&[
            "select",
            &out.join(name).to_string_lossy(),
            "-o",
            &target.to_string_lossy(),
        ]);
        let e = stderr(&run);
        assert_eq!(run.status.code(), Some(1), "{name}: {e}");
        assert!(e.contains(name), "{name}: {e}");
        for n in needles {
            assert!(e.contains(n), "{name}: {n:?} not in {e}");
        }
        assert!(
            !e.contains("Error {") && !e.contains("Some("),
            "{name}: {e}"
        );
        assert!(!target.exists(), "{name}: wrote {}", target.display());
    }
}
