//! Writes seed inputs for the host readers' targets (valid files a mutator
//! would take long to forge: CRC-checked PNG chunks, MCAP records, CDR):
//! `cargo run --release --example reader_seeds -- corpus`, which fills
//! `corpus/depth_png/` and `corpus/ros2/`.
//!
//! depth_png: 16-bit greyscale PNGs of several sizes, each filter and the
//! adaptive choice, fast (fdeflate's path) and default (libdeflate's)
//! compression. ros2: small bags (16UC1 or 32FC1 depth, CameraInfo,
//! PoseStamped / Odometry / `/tf`, rgb8 colour) unchunked and in chunks
//! (uncompressed, zstd, lz4), and each CDR message alone.

use placedb_host::read::ros2::msgs::{self, CameraInfo, Header, Image, PoseMsg, Transform};
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
}
