//! Writes seed inputs for the host readers' targets (valid files a mutator
//! would take long to forge: CRC-checked PNG chunks, MCAP records, CDR):
//! `cargo run --release --example reader_seeds -- corpus`, which fills
//! `corpus/depth_png/`, `corpus/ros2/` and `corpus/ros1/`.
//!
//! depth_png: 16-bit greyscale PNGs of several sizes, each filter and the
//! adaptive choice, fast (fdeflate's path) and default (libdeflate's)
//! compression. ros2: small bags (16UC1 or 32FC1 depth, CameraInfo,
//! PoseStamped / Odometry / `/tf`, rgb8 colour) unchunked and in chunks
//! (uncompressed, zstd, lz4), and each CDR message alone. ros1: small ROS 1
//! bags (16UC1 depth, CameraInfo, PoseStamped / Odometry / `tf/tfMessage`,
//! rgb8 colour) in chunks (none, bz2, lz4) and unchunked, and each ROS 1
//! message alone.

use placedb_host::read::ros2::msgs::{self, CameraInfo, Header, Image, PoseMsg, Transform};
use placedb_host::read::ros2::ros1_msgs::encode as ros1;
use placedb_host::read::ros2::ros1_storage::write as ros1_bag;
// Linked for the coverage hooks a fuzz build compiles every crate with.
use libfuzzer_sys as _;
use std::collections::BTreeMap;
use std::io::Cursor;
use std::path::Path;

fn png(w: u32, h: u32, filter: Option<png::FilterType>, fast: bool, pixels: &[u16]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, w, h);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Sixteen);
    match filter {
        Some(f) => enc.set_filter(f),
        None => enc.set_adaptive_filter(png::AdaptiveFilterType::Adaptive),
    }
    enc.set_compression(if fast {
        png::Compression::Fast
    } else {
        png::Compression::Default
    });
    let bytes: Vec<u8> = pixels.iter().flat_map(|v| v.to_be_bytes()).collect();
    enc.write_header()
        .unwrap()
        .write_image_data(&bytes)
        .unwrap();
    out
}

fn depth_png_seeds(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    let filters = [
        Some(png::FilterType::NoFilter),
        Some(png::FilterType::Sub),
        Some(png::FilterType::Up),
        Some(png::FilterType::Avg),
        Some(png::FilterType::Paeth),
        None,
    ];
    let mut n = 0;
    for (w, h) in [(1, 1), (4, 3), (9, 5), (17, 3), (33, 20), (40, 17)] {
        for (f, filter) in filters.iter().enumerate() {
            // A ramp with jumps, some 0 and 65535: every predictor has work.
            let pixels: Vec<u16> = (0..w * h)
                .map(|i| match (i * 7 + f as u32) % 11 {
                    0 => 0,
                    1 => u16::MAX,
                    k => (i * 613 + k * 97) as u16,
                })
                .collect();
            let fast = n % 2 == 0;
            let mut seed = vec![((w as u8 % 64) << 1) | (n as u8 & 1)];
            seed.extend(png(w, h, *filter, fast, &pixels));
            std::fs::write(dir.join(format!("seed-{w}x{h}-{f}")), seed).unwrap();
            n += 1;
        }
    }
}

fn header(t: f64, frame: &str) -> Header {
    Header {
        stamp: t,
        frame_id: frame.into(),
    }
}

/// How one seed bag is written.
struct BagSeed {
    name: &'static str,
    depth: &'static str,
    big_endian: bool,
    /// "pose", "odom" or "tf".
    poses: &'static str,
    color: bool,
    compression: Option<mcap::Compression>,
    chunks: bool,
}

fn bag(seed: &BagSeed) -> Vec<u8> {
    let opts = mcap::WriteOptions::new()
        .compression(seed.compression)
        .use_chunks(seed.chunks);
    let mut w = opts.create(Cursor::new(Vec::new())).unwrap();
    let mut channels = BTreeMap::new();
    let mut channel = |w: &mut mcap::Writer<_>, topic: &str, schema: &str| -> u16 {
        *channels.entry(topic.to_string()).or_insert_with(|| {
            let s = w.add_schema(schema, "ros2msg", b"").unwrap();
            w.add_channel(s, topic, "cdr", &BTreeMap::new()).unwrap()
        })
    };
    let put = |w: &mut mcap::Writer<_>, ch: u16, t: f64, data: &[u8]| {
        let ns = (t * 1e9) as u64;
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: ch,
                sequence: 0,
                log_time: ns,
                publish_time: ns,
            },
            data,
        )
        .unwrap();
    };
    let (width, height) = (4u32, 3u32);
    let info = channel(&mut w, "/camera/depth/camera_info", msgs::CAMERA_INFO);
    let data = msgs::encode_camera_info(&CameraInfo {
        header: header(1.0, "camera"),
        height,
        width,
        d: vec![0.0; 5],
        k: [3.0, 0.0, 1.5, 0.0, 3.0, 1.0, 0.0, 0.0, 1.0],
    });
    put(&mut w, info, 1.0, &data);
    for i in 0..3u32 {
        let t = 1.0 + f64::from(i) * 0.1;
        let bytes: Vec<u8> = (0..width * height)
            .flat_map(|p| {
                let mm = 500 + 37 * p + 100 * i;
                match seed.depth {
                    "32FC1" => {
                        let m = mm as f32 / 1000.0;
                        if seed.big_endian {
                            m.to_be_bytes().to_vec()
                        } else {
                            m.to_le_bytes().to_vec()
                        }
                    }
                    _ if seed.big_endian => (mm as u16).to_be_bytes().to_vec(),
                    _ => (mm as u16).to_le_bytes().to_vec(),
                }
            })
            .collect();
        let bpp = if seed.depth == "32FC1" { 4 } else { 2 };
        let depth = channel(&mut w, "/camera/depth/image_rect_raw", msgs::IMAGE);
        let data = msgs::encode_image(&Image {
            header: header(t, "camera"),
            height,
            width,
            encoding: seed.depth.into(),
            is_bigendian: seed.big_endian,
            step: width * bpp,
            data: &bytes,
        });
        put(&mut w, depth, t, &data);
        if seed.color {
            let rgb: Vec<u8> = (0..3 * width * height)
                .map(|b| (b * 11 + i) as u8)
                .collect();
            let color = channel(&mut w, "/camera/color/image_raw", msgs::IMAGE);
            let data = msgs::encode_image(&Image {
                header: header(t + 0.001, "camera"),
                height,
                width,
                encoding: "rgb8".into(),
                is_bigendian: false,
                step: 3 * width,
                data: &rgb,
            });
            put(&mut w, color, t + 0.001, &data);
        }
        let pose = PoseMsg {
            translation: [f64::from(i) * 0.2, 0.0, 1.0],
            rotation: [0.0, 0.0, 0.0, 1.0],
        };
        let h = header(t + 0.002, "map");
        let (topic, schema, data) = match seed.poses {
            "odom" => (
                "/odom",
                msgs::ODOMETRY,
                msgs::encode_odometry(&h, "camera", &pose),
            ),
            "tf" => (
                "/tf",
                msgs::TF_MESSAGE,
                msgs::encode_tf_message(&[Transform {
                    header: h,
                    child_frame_id: "camera".into(),
                    pose,
                }]),
            ),
            _ => (
                "/pose",
                msgs::POSE_STAMPED,
                msgs::encode_pose_stamped(&h, &pose),
            ),
        };
        let ch = channel(&mut w, topic, schema);
        put(&mut w, ch, t + 0.002, &data);
    }
    w.finish().unwrap();
    w.into_inner().into_inner()
}

fn ros2_seeds(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    let seeds = [
        BagSeed {
            name: "16uc1-pose-unchunked",
            depth: "16UC1",
            big_endian: false,
            poses: "pose",
            color: false,
            compression: None,
            chunks: false,
        },
        BagSeed {
            name: "16uc1-be-odom-chunks",
            depth: "16UC1",
            big_endian: true,
            poses: "odom",
            color: true,
            compression: None,
            chunks: true,
        },
        BagSeed {
            name: "32fc1-tf-zstd",
            depth: "32FC1",
            big_endian: false,
            poses: "tf",
            color: true,
            compression: Some(mcap::Compression::Zstd),
            chunks: true,
        },
        BagSeed {
            name: "32fc1-be-pose-lz4",
            depth: "32FC1",
            big_endian: true,
            poses: "pose",
            color: false,
            compression: Some(mcap::Compression::Lz4),
            chunks: true,
        },
    ];
    for seed in &seeds {
        std::fs::write(dir.join(format!("seed-bag-{}", seed.name)), bag(seed)).unwrap();
    }
    let pose = PoseMsg {
        translation: [1.0, -2.0, 0.5],
        rotation: [0.0, 0.0, 0.7071068, 0.7071068],
    };
    let messages: [(&str, Vec<u8>); 5] = [
        (
            "image",
            msgs::encode_image(&Image {
                header: header(2.5, "camera"),
                height: 2,
                width: 3,
                encoding: "16UC1".into(),
                is_bigendian: false,
                step: 6,
                data: &[1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12],
            }),
        ),
        (
            "camera-info",
            msgs::encode_camera_info(&CameraInfo {
                header: header(2.5, "camera"),
                height: 2,
                width: 3,
                d: vec![0.1, 0.0, 0.0, 0.0, 0.0],
                k: [3.0, 0.0, 1.5, 0.0, 3.0, 1.0, 0.0, 0.0, 1.0],
            }),
        ),
        (
            "pose-stamped",
            msgs::encode_pose_stamped(&header(2.5, "map"), &pose),
        ),
        (
            "odometry",
            msgs::encode_odometry(&header(2.5, "map"), "camera", &pose),
        ),
        (
            "tf",
            msgs::encode_tf_message(&[Transform {
                header: header(2.5, "map"),
                child_frame_id: "camera".into(),
                pose,
            }]),
        ),
    ];
    for (name, bytes) in messages {
        std::fs::write(dir.join(format!("seed-cdr-{name}")), bytes).unwrap();
    }
}

fn main() {
    let out = std::env::args()
        .nth(1)
        .expect("usage: reader_seeds <corpus dir>");
    let out = Path::new(&out);
    depth_png_seeds(&out.join("depth_png"));
    ros2_seeds(&out.join("ros2"));
    ros1_seeds(&out.join("ros1"));
}

/// A ROS 1 bag of 3 frames of 4x3 depth: `poses` "pose", "odom" or "tf";
/// chunks compressed as `compression` (`none`, `bz2`, `lz4`), or every
/// record at the top level when `None`.
fn ros1_bag_seed(poses: &str, color: bool, compression: Option<&str>) -> Vec<u8> {
    let pose_topic = match poses {
        "odom" => ("/odom", "nav_msgs/Odometry"),
        "tf" => ("/tf", "tf/tfMessage"),
        _ => ("/pose", "geometry_msgs/PoseStamped"),
    };
    let mut records = [
        ros1_bag::connection(0, "/camera/depth/camera_info", "sensor_msgs/CameraInfo"),
        ros1_bag::connection(1, "/camera/depth/image_rect_raw", "sensor_msgs/Image"),
        ros1_bag::connection(2, pose_topic.0, pose_topic.1),
        ros1_bag::connection(3, "/camera/color/image_raw", "sensor_msgs/Image"),
    ]
    .concat();
    let (width, height) = (4u32, 3u32);
    let info = ros1::camera_info(&CameraInfo {
        header: header(1.0, "camera"),
        height,
        width,
        d: vec![0.0; 5],
        k: [3.0, 0.0, 1.5, 0.0, 3.0, 1.0, 0.0, 0.0, 1.0],
    });
    records.extend(ros1_bag::message(0, 1, &info));
    for i in 0..3u32 {
        let t = 1.0 + f64::from(i);
        let depth: Vec<u8> = (0..width * height)
            .flat_map(|p| ((500 + 37 * p + 100 * i) as u16).to_le_bytes())
            .collect();
        let image = ros1::image(&Image {
            header: header(t, "camera"),
            height,
            width,
            encoding: "16UC1".into(),
            is_bigendian: false,
            step: width * 2,
            data: &depth,
        });
        records.extend(ros1_bag::message(1, 1 + i, &image));
        let pose = PoseMsg {
            translation: [f64::from(i) * 0.2, 0.0, 1.0],
            rotation: [0.0, 0.0, 0.0, 1.0],
        };
        let h = header(t, "map");
        let data = match poses {
            "odom" => ros1::odometry(&h, "camera", &pose),
            "tf" => ros1::tf_message(&[Transform {
                header: h,
                child_frame_id: "camera".into(),
                pose,
            }]),
            _ => ros1::pose_stamped(&h, &pose),
        };
        records.extend(ros1_bag::message(2, 1 + i, &data));
        if color {
            let rgb: Vec<u8> = (0..3 * width * height)
                .map(|b| (b * 11 + i) as u8)
                .collect();
            let image = ros1::image(&Image {
                header: header(t, "camera"),
                height,
                width,
                encoding: "rgb8".into(),
                is_bigendian: false,
                step: 3 * width,
                data: &rgb,
            });
            records.extend(ros1_bag::message(3, 1 + i, &image));
        }
    }
    match compression {
        Some(c) => ros1_bag::bag(&ros1_bag::chunk(c, &records)),
        None => ros1_bag::bag(&records),
    }
}

fn ros1_seeds(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    let bags = [
        ("pose-none", "pose", true, Some("none")),
        ("odom-bz2", "odom", false, Some("bz2")),
        ("tf-lz4", "tf", false, Some("lz4")),
        ("pose-unchunked", "pose", false, None),
    ];
    for (name, poses, color, compression) in bags {
        let bytes = ros1_bag_seed(poses, color, compression);
        std::fs::write(dir.join(format!("seed-bag-{name}")), bytes).unwrap();
    }
    let pose = PoseMsg {
        translation: [1.0, -2.0, 0.5],
        rotation: [0.0, 0.0, 0.7071068, 0.7071068],
    };
    let data = [1u8, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12];
    let messages: [(&str, Vec<u8>); 6] = [
        (
            "image",
            ros1::image(&Image {
                header: header(2.5, "camera"),
                height: 2,
                width: 3,
                encoding: "16UC1".into(),
                is_bigendian: false,
                step: 6,
                data: &data,
            }),
        ),
        (
            "compressed-image",
            ros1::compressed_image(&msgs::CompressedImage {
                header: header(2.5, "camera"),
                format: "16UC1; compressedDepth png".into(),
                data: &data,
            }),
        ),
        (
            "camera-info",
            ros1::camera_info(&CameraInfo {
                header: header(2.5, "camera"),
                height: 2,
                width: 3,
                d: vec![0.1, 0.0, 0.0, 0.0, 0.0],
                k: [3.0, 0.0, 1.5, 0.0, 3.0, 1.0, 0.0, 0.0, 1.0],
            }),
        ),
        (
            "pose-stamped",
            ros1::pose_stamped(&header(2.5, "map"), &pose),
        ),
        (
            "odometry",
            ros1::odometry(&header(2.5, "map"), "camera", &pose),
        ),
        (
            "tf",
            ros1::tf_message(&[Transform {
                header: header(2.5, "map"),
                child_frame_id: "camera".into(),
                pose,
            }]),
        ),
    ];
    for (name, bytes) in messages {
        std::fs::write(dir.join(format!("seed-ros1-{name}")), bytes).unwrap();
    }
}
