//! ROS 2 bags in: the tests write rosbag2 MCAP recordings of 7scenes-1000
//! frames (depth as `sensor_msgs/msg/Image`, intrinsics as CameraInfo, poses
//! as PoseStamped, Odometry or `/tf`, colour as rgb8; CDR as ROS 2 writes
//! it), read them back, and require the same frames, the same database and
//! the same labels as the 7-Scenes layout. Bad bags get errors naming topic
//! and time, never a panic. The dataset writer's output reads back as the
//! reference layout with the same classes.

mod bag_common;

use bag_common::database;
use placedb_host::pipeline::{self, Solver, SolverParams};
use placedb_host::read::ros2::msgs::{self, CameraInfo, Header, Image, PoseMsg, Transform};
use placedb_host::read::ros2::Ros2Options;
use placedb_host::read::{self, ReadOptions};
use placedb_host::sequence::PoseInterpolation;
use placedb_host::{output::dataset, Format, ReadError, Sequence, VoxelConfig};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Frames of 7scenes-1000 written to the bags (the whole set is 600 MB of depth).
const FRAMES: usize = 60;

fn sevenscenes() -> Sequence {
    bag_common::sevenscenes(FRAMES)
}

fn temp(name: &str) -> PathBuf {
    let p = std::env::temp_dir().join(format!("placedb-ros2-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&p);
    std::fs::create_dir_all(&p).unwrap();
    p
}

/// How to write a bag.
#[derive(Clone)]
struct Bag {
    depth_encoding: &'static str,
    big_endian: bool,
    /// "pose" (PoseStamped), "odom" (Odometry), "tf", or "" (no poses).
    poses: &'static str,
    /// Write poses only for frames whose index passes this.
    pose_for: fn(usize) -> bool,
    color: bool,
    /// Extra topics: (topic, schema) with one dummy message each.
    extra: Vec<(&'static str, &'static str)>,
}

impl Default for Bag {
    fn default() -> Self {
        Bag {
            depth_encoding: "16UC1",
            big_endian: false,
            poses: "pose",
            pose_for: |_| true,
            color: true,
            extra: Vec::new(),
        }
    }
}

const DEPTH: &str = "/camera/depth/image_rect_raw";

/// Writes `seq` as a rosbag2 folder `dir` (metadata.yaml + one .mcap).
fn write_bag(dir: &Path, seq: &Sequence, bag: &Bag) -> PathBuf {
    std::fs::write(
        dir.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n  \
         relative_file_paths:\n    - bag_0.mcap\n  compression_format: \"\"\n  compression_mode: \"\"\n",
    )
    .unwrap();
    let file = std::fs::File::create(dir.join("bag_0.mcap")).unwrap();
    let mut w = mcap::Writer::new(std::io::BufWriter::new(file)).unwrap();
    let mut channels = BTreeMap::new();
    let mut channel = |w: &mut mcap::Writer<_>, topic: &str, schema: &str| -> u16 {
        *channels.entry(topic.to_string()).or_insert_with(|| {
            let s = w.add_schema(schema, "ros2msg", b"").unwrap();
            w.add_channel(s, topic, "cdr", &BTreeMap::new()).unwrap()
        })
    };
    let put = |w: &mut mcap::Writer<_>, ch: u16, seq_no: u32, t: f64, data: &[u8]| {
        let ns = (t * 1e9) as u64;
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: ch,
                sequence: seq_no,
                log_time: ns,
                publish_time: ns,
            },
            data,
        )
        .unwrap();
    };
    let (width, height) = seq.size;
    let k = &seq.camera;
    for (topic, schema) in &bag.extra {
        let ch = channel(&mut w, topic, schema);
        let h = Header {
            stamp: 0.5,
            frame_id: "x".into(),
        };
        let data = match *schema {
            msgs::IMAGE => msgs::encode_image(&Image {
                header: h,
                height: 1,
                width: 1,
                encoding: "16UC1".into(),
                is_bigendian: false,
                step: 2,
                data: &[1, 0],
            }),
            _ => {
                // CompressedImage: header, format, data.
                let mut c = placedb_host::read::ros2::cdr::Writer::new(true);
                c.i32(0)
                    .u32(500_000_000)
                    .string("x")
                    .string("16UC1; compressedDepth")
                    .bytes(&[0; 8]);
                c.finish()
            }
        };
        put(&mut w, ch, 0, 0.5, &data);
    }
    for (i, f) in seq.frames.iter().enumerate() {
        // 7-Scenes has no timestamps: its frame numbers, in seconds.
        let t = f.timestamp;
        let header = Header {
            stamp: t,
            frame_id: "camera_depth_optical_frame".into(),
        };
        let ch = channel(&mut w, "/camera/depth/camera_info", msgs::CAMERA_INFO);
        let info = CameraInfo {
            header: header.clone(),
            height: u32::from(height),
            width: u32::from(width),
            d: vec![0.0; 5],
            k: [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0],
        };
        put(&mut w, ch, i as u32, t, &msgs::encode_camera_info(&info));
        let depth = seq.depth(i).unwrap();
        let (bpp, bytes): (u32, Vec<u8>) = match bag.depth_encoding {
            "32FC1" => (
                4,
                depth
                    .data
                    .iter()
                    .flat_map(|&v| {
                        let m = if v == 0 { f32::NAN } else { v as f32 / 1000.0 };
                        if bag.big_endian {
                            m.to_be_bytes()
                        } else {
                            m.to_le_bytes()
                        }
                    })
                    .collect(),
            ),
            _ => (
                2,
                depth
                    .data
                    .iter()
                    .flat_map(|&v| {
                        if bag.big_endian {
                            v.to_be_bytes()
                        } else {
                            v.to_le_bytes()
                        }
                    })
                    .collect(),
            ),
        };
        let img = Image {
            header: header.clone(),
            height: u32::from(height),
            width: u32::from(width),
            encoding: bag.depth_encoding.into(),
            is_bigendian: bag.big_endian,
            step: u32::from(width) * bpp,
            data: &bytes,
        };
        let ch = channel(&mut w, DEPTH, msgs::IMAGE);
        put(&mut w, ch, i as u32, t, &msgs::encode_image(&img));
        if bag.color {
            // A flat colour per frame: enough to check it lands with its frame.
            let rgb = vec![(i % 256) as u8; 3 * usize::from(width) * usize::from(height)];
            let img = Image {
                header: header.clone(),
                height: u32::from(height),
                width: u32::from(width),
                encoding: "rgb8".into(),
                is_bigendian: false,
                step: u32::from(width) * 3,
                data: &rgb,
            };
            let ch = channel(&mut w, "/camera/color/image_raw", msgs::IMAGE);
            put(&mut w, ch, i as u32, t + 0.004, &msgs::encode_image(&img));
        }
        if !(bag.pose_for)(i) {
            continue;
        }
        // The pose a little off the frame's time, as a real odometry is.
        let ph = Header {
            stamp: t + 0.003,
            frame_id: "map".into(),
        };
        let pose = PoseMsg {
            translation: f.translation,
            rotation: f.rotation,
        };
        match bag.poses {
            "pose" => {
                let ch = channel(&mut w, "/camera_pose", msgs::POSE_STAMPED);
                put(
                    &mut w,
                    ch,
                    i as u32,
                    t,
                    &msgs::encode_pose_stamped(&ph, &pose),
                );
            }
            "odom" => {
                let ch = channel(&mut w, "/odom", msgs::ODOMETRY);
                let data = msgs::encode_odometry(&ph, "camera_depth_optical_frame", &pose);
                put(&mut w, ch, i as u32, t, &data);
            }
            "tf" => {
                let ch = channel(&mut w, "/tf", msgs::TF_MESSAGE);
                let other = PoseMsg {
                    translation: [9.0, 9.0, 9.0],
                    rotation: [0.0, 0.0, 0.0, 1.0],
                };
                let tf = [
                    Transform {
                        header: ph.clone(),
                        child_frame_id: "base_link".into(),
                        pose: other,
                    },
                    Transform {
                        header: ph.clone(),
                        child_frame_id: "camera_depth_optical_frame".into(),
                        pose,
                    },
                ];
                put(&mut w, ch, i as u32, t, &msgs::encode_tf_message(&tf));
            }
            _ => {}
        }
    }
    w.finish().unwrap();
    dir.to_path_buf()
}

/// Reads with the nearest pose: these bags stamp each pose 3 ms after its
/// frame, and the nearest rule gives the 7-Scenes poses bit for bit
/// (interpolation has its own test).
fn open(path: &Path, ros2: Ros2Options) -> Result<Sequence, ReadError> {
    read::open(
        path,
        &ReadOptions {
            ros2,
            pose_interpolation: PoseInterpolation::Nearest,
            ..ReadOptions::default()
        },
    )
}

#[test]
fn a_bag_of_7scenes_frames_gives_the_7scenes_database() {
    let s7 = sevenscenes();
    let dir = temp("same");
    let bag = write_bag(&dir, &s7, &Bag::default());
    assert_eq!(read::detect(&bag).unwrap(), Format::Ros2);
    let ros = open(&bag, Ros2Options::default()).unwrap();
    assert_eq!(ros.frames.len(), s7.frames.len());
    assert_eq!(
        (ros.camera, ros.depth_scale, ros.size),
        (s7.camera, s7.depth_scale, s7.size)
    );
    for (a, b) in ros.frames.iter().zip(&s7.frames) {
        assert_eq!((a.timestamp, a.translation), (b.timestamp, b.translation));
        assert_eq!(a.rotation, b.rotation);
    }
    for i in [0, FRAMES / 2, FRAMES - 1] {
        assert_eq!(ros.depth(i).unwrap(), s7.depth(i).unwrap());
    }
    for solver in [Solver::InOrder, Solver::Online] {
        assert_eq!(database(&ros, solver), database(&s7, solver), "{solver:?}");
    }
    // The single .mcap file reads the same.
    let single = open(&bag.join("bag_0.mcap"), Ros2Options::default()).unwrap();
    assert_eq!(single.frames, ros.frames);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn every_pose_source_and_depth_encoding_reads_the_same() {
    let mut s7 = sevenscenes();
    s7.frames.truncate(8);
    let want = open(
        &write_bag(&temp("ref"), &s7, &Bag::default()),
        Ros2Options::default(),
    )
    .unwrap();
    let cases: [(&str, Bag, Ros2Options); 5] = [
        (
            "odom",
            Bag {
                poses: "odom",
                ..Bag::default()
            },
            Ros2Options::default(),
        ),
        (
            "tf",
            Bag {
                poses: "tf",
                ..Bag::default()
            },
            Ros2Options {
                pose_frame: Some("map".into()),
                ..Ros2Options::default()
            },
        ),
        (
            // No pose topic: the TF tree, from its root to the images' frame.
            "tf-auto",
            Bag {
                poses: "tf",
                ..Bag::default()
            },
            Ros2Options::default(),
        ),
        (
            "be16",
            Bag {
                big_endian: true,
                ..Bag::default()
            },
            Ros2Options::default(),
        ),
        (
            "f32be",
            Bag {
                depth_encoding: "32FC1",
                big_endian: true,
                ..Bag::default()
            },
            Ros2Options::default(),
        ),
    ];
    for (name, bag, opts) in cases {
        let dir = temp(name);
        let seq = open(&write_bag(&dir, &s7, &bag), opts).unwrap();
        assert_eq!(seq.frames, want.frames, "{name}");
        for i in 0..s7.frames.len() {
            assert_eq!(
                seq.depth(i).unwrap(),
                s7.depth(i).unwrap(),
                "{name} frame {i}"
            );
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

fn layout_reason(e: ReadError) -> String {
    match e {
        ReadError::Layout { reason, .. } => reason,
        other => panic!("expected a layout error, got {other}"),
    }
}

#[test]
fn bad_bags_get_errors_naming_topic_and_time() {
    let mut s7 = sevenscenes();
    s7.frames.truncate(4);
    let err = |name: &str, bag: Bag, opts: Ros2Options| {
        let dir = temp(name);
        let e = open(&write_bag(&dir, &s7, &bag), opts)
            .err()
            .expect("refused");
        std::fs::remove_dir_all(&dir).unwrap();
        layout_reason(e)
    };
    let e = err(
        "missing",
        Bag::default(),
        Ros2Options {
            depth_topic: Some("/nope".into()),
            ..Ros2Options::default()
        },
    );
    assert!(e.contains("/nope") && e.contains(DEPTH), "{e}");
    let e = err(
        "encoding",
        Bag {
            depth_encoding: "mono16",
            ..Bag::default()
        },
        Ros2Options {
            depth_topic: Some(DEPTH.into()),
            ..Ros2Options::default()
        },
    );
    assert!(
        e.contains(DEPTH) && e.contains("t=0.000000") && e.contains("mono16"),
        "{e}"
    );
    let e = err(
        "compressed",
        Bag {
            extra: vec![("/camera/depth/compressed", msgs::COMPRESSED_IMAGE)],
            ..Bag::default()
        },
        Ros2Options {
            depth_topic: Some("/camera/depth/compressed".into()),
            ..Ros2Options::default()
        },
    );
    assert!(
        e.contains("/camera/depth/compressed")
            && e.contains("t=0.5")
            && e.contains("8 bytes has no image after its 12-byte header"),
        "{e}"
    );
    let e = err(
        "two-depths",
        Bag {
            extra: vec![("/other/depth", msgs::IMAGE)],
            ..Bag::default()
        },
        Ros2Options::default(),
    );
    assert!(
        e.contains("/other/depth") && e.contains("--depth-topic"),
        "{e}"
    );
    // --color-topic: refused for what is wrong with the topic, in words
    // that do not contradict themselves (an Image topic is one).
    let e = err(
        "color-is-depth",
        Bag::default(),
        Ros2Options {
            color_topic: Some(DEPTH.into()),
            ..Ros2Options::default()
        },
    );
    assert!(
        e.contains("--color-topic") && e.contains("is the depth topic"),
        "{e}"
    );
    let e = err(
        "color-encoding",
        Bag {
            extra: vec![("/camera/ir/image", msgs::IMAGE)],
            ..Bag::default()
        },
        Ros2Options {
            depth_topic: Some(DEPTH.into()),
            color_topic: Some("/camera/ir/image".into()),
            ..Ros2Options::default()
        },
    );
    assert!(
        e.contains("/camera/ir/image") && e.contains("`16UC1`") && !e.contains("topic is not"),
        "{e}"
    );
    let e = err(
        "no-pose",
        Bag {
            poses: "pose",
            pose_for: |_| false,
            ..Bag::default()
        },
        Ros2Options::default(),
    );
    assert!(e.contains("pose topic"), "{e}");
    let e = err(
        "tf-no-frame",
        Bag {
            poses: "tf",
            ..Bag::default()
        },
        Ros2Options {
            camera_frame: Some("camera_link".into()),
            ..Ros2Options::default()
        },
    );
    assert!(
        e.contains("`camera_link` is never connected")
            && e.contains("camera_depth_optical_frame")
            && e.contains("t=0.000000"),
        "{e}"
    );
    let e = err(
        "tolerance",
        Bag::default(),
        Ros2Options {
            pose_tolerance: Some(0.001),
            ..Ros2Options::default()
        },
    );
    assert!(
        e.contains("4 of 4") && e.contains("/camera_pose") && e.contains("t=0.000000"),
        "{e}"
    );
}

#[test]
fn frames_without_a_pose_are_skipped_and_a_cut_bag_is_read_to_its_cut() {
    let mut s7 = sevenscenes();
    s7.frames.truncate(6);
    let dir = temp("skip");
    let bag = write_bag(
        &dir,
        &s7,
        &Bag {
            pose_for: |i| i % 2 == 0,
            ..Bag::default()
        },
    );
    let seq = open(&bag, Ros2Options::default()).unwrap();
    let kept: Vec<f64> = seq.frames.iter().map(|f| f.timestamp).collect();
    assert_eq!(kept, [0.0, 2.0, 4.0]);
    assert_eq!(seq.frames_skipped, 3);
    assert_eq!(seq.depth(1).unwrap(), s7.depth(2).unwrap());
    // A recording cut short (no summary, half a record): what came before reads.
    let file = bag.join("bag_0.mcap");
    let bytes = std::fs::read(&file).unwrap();
    for keep in [bytes.len() * 2 / 3, bytes.len() - 10, 20, 8] {
        std::fs::write(&file, &bytes[..keep]).unwrap();
        match open(&bag, Ros2Options::default()) {
            Ok(seq) => assert!(seq.frames.len() <= 3),
            Err(e) => assert!(
                e.to_string().contains("bag_0.mcap") || e.to_string().contains("topic"),
                "{e}"
            ),
        }
    }
    std::fs::write(&file, b"not a bag").unwrap();
    let e = open(&bag, Ros2Options::default()).err().expect("refused");
    assert!(e.to_string().contains("MCAP"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_dataset_has_every_frame_its_class_and_colour_and_reads_back() {
    let mut s7 = sevenscenes();
    s7.frames.truncate(20);
    let dir = temp("dataset");
    std::fs::create_dir_all(dir.join("bag")).unwrap();
    let bag = write_bag(&dir.join("bag"), &s7, &Bag::default());
    let ros = open(&bag, Ros2Options::default()).unwrap();
    let prep = pipeline::prepare(&ros, VoxelConfig::default(), true).unwrap();
    let o = pipeline::solve(
        &ros,
        &prep,
        Solver::InOrder,
        0.3,
        &SolverParams::default(),
        true,
    )
    .unwrap();
    let out = dir.join("ds");
    let d = dataset::write(&out, &ros, &o.labels).unwrap();
    assert_eq!(
        (d.frames, d.database, d.color),
        (20, o.database.len(), true)
    );
    // Every frame and the database read back as the reference layout.
    let all = read::open(&out, &ReadOptions::default()).unwrap();
    assert_eq!(all.format, Format::Vprdb);
    assert_eq!(all.frames.len(), 20);
    assert_eq!(all.depth(3).unwrap(), s7.depth(3).unwrap());
    let db = read::open(&out.join("database"), &ReadOptions::default()).unwrap();
    let db_ts: Vec<f64> = db.frames.iter().map(|f| f.timestamp).collect();
    let want: Vec<f64> = o
        .database
        .iter()
        .map(|&i| ros.frames[i].timestamp)
        .collect();
    assert_eq!(db_ts, want);
    // The classes, and the colour written with its own frame.
    let classes = std::fs::read_to_string(out.join("classes.csv")).unwrap();
    for (line, (i, l)) in classes.lines().skip(1).zip(o.labels.iter().enumerate()) {
        let f: Vec<&str> = line.split(',').collect();
        assert_eq!(f[1], i.to_string());
        assert_eq!(f[3], l.to_string());
    }
    let png = std::fs::File::open(out.join("color/000007.png")).unwrap();
    let mut r = png::Decoder::new(std::io::BufReader::new(png))
        .read_info()
        .unwrap();
    let mut buf = vec![0; r.output_buffer_size()];
    r.next_frame(&mut buf).unwrap();
    assert!(buf.iter().all(|&b| b == 7));
    // Labels that do not fit are refused.
    let mut bad = o.labels.clone();
    bad[0] = 5;
    bad[5] = 4;
    assert!(dataset::write(&dir.join("bad"), &ros, &bad).is_err());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `metadata.yaml` as rosbag2's own writer (`ros2 bag record -s mcap`,
/// Humble) leaves it.
const ROSBAG2_METADATA: &str = r#"
rosbag2_bagfile_information:
  version: 5
  storage_identifier: mcap
  duration:
    nanoseconds: 300000000
  starting_time:
    nanoseconds_since_epoch: 1700000000000000000
  message_count: 13
  topics_with_message_count:
    - topic_metadata:
        name: /camera/depth/image_rect_raw
        type: sensor_msgs/msg/Image
        serialization_format: cdr
        offered_qos_profiles: "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 2\n  deadline:\n    sec: 9223372036\n    nsec: 854775807\n  avoid_ros_namespace_conventions: false"
      message_count: 4
  compression_format: ""
  compression_mode: ""
  relative_file_paths:
    - bag_0.mcap
  files:
    - path: bag_0.mcap
      starting_time:
        nanoseconds_since_epoch: 1700000000000000000
      duration:
        nanoseconds: 300000000
      message_count: 13
  custom_data: ~
  ros_distro: humble
"#;

/// `metadata.yaml` as the `rosbags` Python writer leaves it: `''` for
/// "none", block lists at the key's indentation.
const ROSBAGS_METADATA: &str = "rosbag2_bagfile_information:
  version: 8
  storage_identifier: mcap
  relative_file_paths:
  - bag_0.mcap
  duration:
    nanoseconds: 300000000
  starting_time:
    nanoseconds_since_epoch: 0
  message_count: 13
  topics_with_message_count:
  - topic_metadata:
      name: /camera/depth/image_rect_raw
      type: sensor_msgs/msg/Image
      serialization_format: cdr
      offered_qos_profiles: ''
      type_description_hash: RIHS01_0000
    message_count: 4
  compression_format: ''
  compression_mode: ''
  files:
  - path: bag_0.mcap
    starting_time:
      nanoseconds_since_epoch: 0
    duration:
      nanoseconds: 300000000
    message_count: 13
  custom_data: {}
  ros_distro: rosbags
";

/// Item 9 of issue 22: the bag folders the standard writers leave read,
/// whatever they write for "no compression" (`""`, `''`, nothing, no
/// key); a compression other than rosbag2's zstd, another storage and a
/// broken file are refused in words naming metadata.yaml.
#[test]
fn metadata_yaml_as_the_standard_writers_leave_it() {
    let mut s7 = sevenscenes();
    s7.frames.truncate(4);
    let dir = temp("metadata");
    let bag = write_bag(&dir, &s7, &Bag::default());
    let meta = bag.join("metadata.yaml");
    let empty_values = ROSBAGS_METADATA
        .replace("compression_format: ''", "compression_format:")
        .replace("compression_mode: ''", "compression_mode:");
    let no_keys: String = ROSBAGS_METADATA
        .lines()
        .filter(|l| !l.contains("compression"))
        .map(|l| format!("{l}\n"))
        .collect();
    for (name, yaml) in [
        ("rosbag2", ROSBAG2_METADATA.to_string()),
        ("rosbags", ROSBAGS_METADATA.to_string()),
        ("empty values", empty_values),
        ("no compression keys", no_keys),
        (
            "none",
            ROSBAGS_METADATA.replace("compression_mode: ''", "compression_mode: none"),
        ),
    ] {
        std::fs::write(&meta, yaml).unwrap();
        let seq = open(&bag, Ros2Options::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(seq.frames.len(), 4, "{name}");
    }
    for (yaml, needles) in [
        (
            ROSBAGS_METADATA
                .replace("compression_format: ''", "compression_format: lz4")
                .replace("compression_mode: ''", "compression_mode: FILE"),
            ["format `lz4`", "only zstd", "ros2 bag convert"],
        ),
        (
            ROSBAG2_METADATA.replace("compression_mode: \"\"", "compression_mode: MESSAGE"),
            ["format `unnamed`", "only zstd", "ros2 bag convert"],
        ),
        (
            ROSBAGS_METADATA
                .replace("compression_format: ''", "compression_format: zstd")
                .replace("compression_mode: ''", "compression_mode: CHUNK"),
            ["mode `CHUNK`", "file or message", "metadata.yaml"],
        ),
        (
            ROSBAGS_METADATA.replace("storage_identifier: mcap", "storage_identifier: my_store"),
            ["`my_store`", "only mcap and sqlite3", "ros2 bag convert"],
        ),
        (
            ROSBAGS_METADATA.replace("- bag_0.mcap", "- bag_1.mcap"),
            ["lists bag_1.mcap", "not in the bag folder", "metadata.yaml"],
        ),
        (
            ROSBAGS_METADATA.replace("compression_mode: ''", "compression_mode: 'FILE"),
            [
                "not a readable rosbag2 metadata.yaml",
                "metadata.yaml",
                "line",
            ],
        ),
    ] {
        std::fs::write(&meta, &yaml).unwrap();
        let e = open(&bag, Ros2Options::default()).err().expect("refused");
        let msg = e.to_string();
        assert!(msg.contains("metadata.yaml"), "{msg}");
        for n in needles {
            assert!(msg.contains(n), "{n:?} not in {msg}");
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
