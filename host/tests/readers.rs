//! Sequence readers: the real samples in `../shared/data`, format detection,
//! overrides, and a catalogue of broken inputs built in a temporary directory.

use placedb_host::read::{self, ReadOptions};
use placedb_host::sequence::PoseInterpolation;
use placedb_host::{CameraModel, Format, ReadError};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

const SEVEN_SCENES: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../shared/data/7scenes-1000"
);
const VPRDB: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../shared/data/vprdb-test-db"
);

/// A sample directory; panics (fails the test) when the data is absent.
fn sample(dir: &str) -> &Path {
    let p = Path::new(dir);
    assert!(
        p.is_dir(),
        "test data {} is missing: the readers tests need ../shared/data",
        p.display()
    );
    p
}

/// A fresh empty directory under the system temp dir, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> TempDir {
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let p =
            std::env::temp_dir().join(format!("placedb-readers-{}-{n}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).unwrap();
        TempDir(p)
    }

    fn path(&self) -> &Path {
        &self.0
    }

    fn write(&self, name: &str, content: &str) -> PathBuf {
        let p = self.0.join(name);
        if let Some(parent) = p.parent() {
            std::fs::create_dir_all(parent).unwrap();
        }
        std::fs::write(&p, content).unwrap();
        p
    }

    /// A 16-bit greyscale PNG of `w x h` pixels, all `value`.
    fn depth_png(&self, name: &str, w: u32, h: u32, value: u16) -> PathBuf {
        let data: Vec<u8> = std::iter::repeat_n(value.to_be_bytes(), (w * h) as usize)
            .flatten()
            .collect();
        self.png(
            name,
            w,
            h,
            png::ColorType::Grayscale,
            png::BitDepth::Sixteen,
            &data,
        )
    }

    fn png(
        &self,
        name: &str,
        w: u32,
        h: u32,
        color: png::ColorType,
        depth: png::BitDepth,
        data: &[u8],
    ) -> PathBuf {
        let p = self.0.join(name);
        if let Some(parent) = p.parent() {
            std::fs::create_dir_all(parent).unwrap();
        }
        let mut enc = png::Encoder::new(std::fs::File::create(&p).unwrap(), w, h);
        enc.set_color(color);
        enc.set_depth(depth);
        enc.write_header().unwrap().write_image_data(data).unwrap();
        p
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

const IDENTITY_4X4: &str = "1 0 0 0.5\n0 1 0 -0.25\n0 0 1 2\n0 0 0 1\n";

/// A tiny valid 7-Scenes directory with `n` frames of 4x3 pixels.
fn seven_scenes_dir(name: &str, n: usize) -> TempDir {
    let d = TempDir::new(name);
    for i in 0..n {
        d.depth_png(&format!("frame-{i:06}.depth.png"), 4, 3, 1000);
        d.write(&format!("frame-{i:06}.pose.txt"), IDENTITY_4X4);
    }
    d
}

/// A tiny valid reference-layout directory with `n` frames of 4x3 pixels.
fn vprdb_dir(name: &str, n: usize) -> TempDir {
    let d = TempDir::new(name);
    let mut poses = String::new();
    for i in 0..n {
        d.depth_png(&format!("depth/{i:03}.png"), 4, 3, 1000);
        poses.push_str(&format!("{i} 0 0 0 0 0 1\n"));
    }
    d.write("poses.txt", &poses);
    d.write("intrinsics.txt", "100 0 2\n0 100 1.5\n0 0 1\n");
    d
}

/// Asserts `msg` names `needle`, showing the message otherwise.
fn names(err: &ReadError, needle: &str) {
    let msg = err.to_string();
    assert!(msg.contains(needle), "{needle:?} not in {msg:?}");
}

/// The error of a read that must fail (`Sequence` is not `Debug`).
fn err<T>(r: Result<T, ReadError>) -> ReadError {
    match r {
        Ok(_) => panic!("the read succeeded, an error was expected"),
        Err(e) => e,
    }
}

fn open(path: &Path) -> Result<placedb_host::Sequence, ReadError> {
    read::open(path, &ReadOptions::default())
}

// ---------------------------------------------------------------- samples

#[test]
fn seven_scenes_sample() {
    let dir = sample(SEVEN_SCENES);
    assert_eq!(read::detect(dir).unwrap(), Format::SevenScenes);
    let seq = open(dir).unwrap();
    assert_eq!(seq.format, Format::SevenScenes);
    assert_eq!(seq.name, "7scenes-1000");
    assert_eq!(seq.frames.len(), 1000);
    assert_eq!(seq.size, (640, 480));
    assert_eq!(seq.depth_scale, 1000.0);
    assert_eq!(
        seq.camera,
        CameraModel {
            fx: 585.0,
            fy: 585.0,
            cx: 320.0,
            cy: 240.0
        }
    );
    for (i, f) in seq.frames.iter().enumerate() {
        assert_eq!(f.index, i);
        assert_eq!(f.timestamp, i as f64);
        let n: f64 = f.rotation.iter().map(|c| c * c).sum();
        assert!((n - 1.0).abs() < 1e-12, "frame {i}: |q|^2 = {n}");
        f.pose().unwrap();
    }
    let f0 = &seq.frames[0];
    assert_eq!(f0.depth_name, "frame-000000.depth.png");
    assert_eq!(
        f0.color_path.as_deref(),
        Some(dir.join("frame-000000.color.jpg").as_path())
    );
    // The pose file's translation column, and (as the quaternion) its
    // rotation block, which is orthonormal only to ~1e-4: the nearest rotation
    // differs by that much.
    let file: Vec<Vec<f64>> = std::fs::read_to_string(dir.join("frame-000000.pose.txt"))
        .unwrap()
        .lines()
        .map(|l| l.split_whitespace().map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(f0.translation, [file[0][3], file[1][3], file[2][3]]);
    assert!((f0.translation[0] - -0.34045634).abs() < 1e-12);
    let r = f0.pose().unwrap().rotation_matrix();
    for i in 0..3 {
        for j in 0..3 {
            let d = (r[i][j] as f64 - file[i][j]).abs();
            assert!(d < 3e-4, "R[{i}][{j}]: {} vs {}", r[i][j], file[i][j]);
        }
    }
    // 65535 ("no measurement") never comes out; find a frame that stores it.
    let mut raw_with_65535 = 0;
    for i in (0..1000).step_by(50) {
        let img = seq.depth(i).unwrap();
        assert_eq!(img.data.len(), 640 * 480);
        assert!(!img.data.contains(&u16::MAX), "frame {i} has 65535");
        assert!(img.data.iter().any(|&v| v > 0), "frame {i} is empty");
        let raw = read::decode_depth_png(&dir.join(&seq.frames[i].depth_name)).unwrap();
        if raw.data.contains(&u16::MAX) {
            raw_with_65535 += 1;
            let mapped: Vec<u16> = raw
                .data
                .iter()
                .map(|&v| if v == u16::MAX { 0 } else { v })
                .collect();
            assert_eq!(mapped, img.data);
        } else {
            assert_eq!(raw, img);
        }
    }
    // The mapping above was checked: some sampled frame stores 65535.
    assert!(
        raw_with_65535 > 0,
        "no sampled 7-Scenes frame stores 65535: the mapping to 0 went unchecked"
    );
    eprintln!("{raw_with_65535} of 20 sampled 7-Scenes frames store 65535");
}

#[test]
fn vprdb_sample() {
    let dir = sample(VPRDB);
    assert_eq!(read::detect(dir).unwrap(), Format::Vprdb);
    let seq = open(dir).unwrap();
    assert_eq!(seq.format, Format::Vprdb);
    assert_eq!(seq.frames.len(), 5);
    assert_eq!(seq.size, (1920, 1080));
    assert_eq!(seq.depth_scale, 1000.0);
    assert_eq!(
        seq.camera,
        CameraModel {
            fx: 945.4777832,
            fy: 938.16333008,
            cx: 960.16769378,
            cy: 543.55953406
        }
    );
    let names: Vec<&str> = seq.frames.iter().map(|f| f.depth_name.as_str()).collect();
    assert_eq!(
        names,
        [
            "depth/000000401822.png",
            "depth/000053735188.png",
            "depth/000117068533.png",
            "depth/000233735177.png",
            "depth/000571135188.png"
        ]
    );
    let timestamps: Vec<f64> = seq.frames.iter().map(|f| f.timestamp).collect();
    assert_eq!(timestamps, [0.0, 1.0, 2.0, 3.0, 4.0]);
    assert_eq!(seq.frames[0].translation, [0.0; 3]);
    assert_eq!(seq.frames[0].rotation, [0.0, 0.0, 0.0, 1.0]);
    assert_eq!(
        seq.frames[1].translation,
        [-8.467759132, 0.157996297, -0.461750031]
    );
    assert!((seq.frames[1].rotation[1] - -0.724121749).abs() < 1e-6);
    assert!(seq.frames.iter().all(|f| f.color_path.is_none()));
    let img = seq.depth(4).unwrap();
    assert_eq!((img.width, img.height), (1920, 1080));
    assert!(img.data.iter().any(|&v| v > 0));
}

// -------------------------------------------------------------- detection

#[test]
fn detection() {
    let s = seven_scenes_dir("detect-7s", 1);
    assert_eq!(read::detect(s.path()).unwrap(), Format::SevenScenes);
    let v = vprdb_dir("detect-vprdb", 1);
    assert_eq!(read::detect(v.path()).unwrap(), Format::Vprdb);
    let t = tum_dir("detect-tum");
    assert_eq!(read::detect(t.path()).unwrap(), Format::Tum);

    let u = TempDir::new("detect-unknown");
    u.write("notes.txt", "nothing here\n");
    u.write("depth.txt", "1.0 depth/1.png\n"); // no groundtruth.txt
    for e in [read::detect(u.path()).unwrap_err(), err(open(u.path()))] {
        assert!(matches!(e, ReadError::Layout { .. }), "{e}");
        names(&e, &u.path().display().to_string());
        names(&e, "frame-*.depth.png");
        names(&e, "groundtruth.txt");
        names(&e, "depth/");
    }

    let missing = u.path().join("does-not-exist");
    let e = read::detect(&missing).unwrap_err();
    assert!(matches!(e, ReadError::Io { .. }), "{e}");
    names(&e, "does-not-exist");

    let file = u.write("plain-file", "");
    let e = read::detect(&file).unwrap_err();
    assert!(matches!(e, ReadError::Layout { .. }), "{e}");
    names(&e, "plain-file");
}

#[test]
fn explicit_format_wins_over_detection() {
    let v = vprdb_dir("explicit-format", 2);
    let opts = ReadOptions {
        format: Some(Format::SevenScenes),
        ..Default::default()
    };
    let e = err(read::open(v.path(), &opts));
    assert!(matches!(e, ReadError::Layout { .. }), "{e}");
    names(&e, "frame-*.depth.png");
    let opts = ReadOptions {
        format: Some(Format::Vprdb),
        ..Default::default()
    };
    assert_eq!(read::open(v.path(), &opts).unwrap().frames.len(), 2);
}

// -------------------------------------------------------------------- TUM

/// A tiny TUM directory: 4 depth frames, one without groundtruth in 0.02 s.
fn tum_dir(name: &str) -> TempDir {
    let d = TempDir::new(name);
    d.write(
        "depth.txt",
        "# depth maps\n# file: 'x.bag'\n# timestamp filename\n\
         1.000 depth/1.000.png\n\
         1.100 depth/1.100.png\n\
         1.500 depth/1.500.png\n\
         1.200 depth/1.200.png\n",
    );
    for t in ["1.000", "1.100", "1.200", "1.500"] {
        d.depth_png(&format!("depth/{t}.png"), 4, 3, 5000);
    }
    d.write(
        "rgb.txt",
        "# color images\n1.001 rgb/1.001.png\n1.099 rgb/1.099.png\n",
    );
    d.write(
        "groundtruth.txt",
        "# ground truth trajectory\n# timestamp tx ty tz qx qy qz qw\n\
         0.990 1 2 3 0 0 0 1\n\
         1.005 4 5 6 0 0 0 1\n\
         1.110 7 8 9 0 0 0.7071068 0.7071068\n\
         1.215 1 1 1 0 0 0 1.0001\n",
    );
    // TUM's default intrinsics are for 640x480 images only.
    d.write("intrinsics.txt", "4 0 1.5\n0 4 1\n0 0 1\n");
    d
}

#[test]
fn tum_association_and_defaults() {
    let d = tum_dir("tum");
    let seq = open(d.path()).unwrap();
    assert_eq!(seq.format, Format::Tum);
    assert_eq!(seq.depth_scale, 5000.0);
    assert_eq!(
        seq.camera,
        CameraModel {
            fx: 4.0,
            fy: 4.0,
            cx: 1.5,
            cy: 1.0
        }
    );
    assert_eq!(seq.size, (4, 3));
    // 1.5 has no groundtruth within 0.02 s and is skipped (counted); order
    // is by time.
    let ts: Vec<f64> = seq.frames.iter().map(|f| f.timestamp).collect();
    assert_eq!(ts, [1.0, 1.1, 1.2]);
    assert_eq!(seq.frames_skipped, 1);
    // Interpolated between the groundtruth lines around each frame: 1.000
    // is 2/3 of the way from 0.990 to 1.005.
    let close = |a: [f64; 3], b: [f64; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-9);
    assert!(
        close(seq.frames[0].translation, [3.0, 4.0, 5.0]),
        "{:?}",
        seq.frames[0]
    );
    let u = 0.095 / 0.105;
    assert!(close(
        seq.frames[1].translation,
        [4.0 + 3.0 * u, 5.0 + 3.0 * u, 6.0 + 3.0 * u]
    ));
    assert_eq!(seq.pose_interpolation, Some(PoseInterpolation::Linear));
    // The nearest line's pose, whole, with --pose-interpolation nearest.
    let nearest = read::open(
        d.path(),
        &ReadOptions {
            pose_interpolation: PoseInterpolation::Nearest,
            ..ReadOptions::default()
        },
    )
    .unwrap();
    assert_eq!(nearest.frames_skipped, 1);
    assert_eq!(nearest.frames[0].translation, [4.0, 5.0, 6.0]);
    assert_eq!(nearest.frames[1].translation, [7.0, 8.0, 9.0]);
    assert_eq!(nearest.frames[2].translation, [1.0, 1.0, 1.0]);
    assert!((nearest.frames[2].rotation[3] - 1.0).abs() < 1e-15);
    let idx: Vec<usize> = seq.frames.iter().map(|f| f.index).collect();
    assert_eq!(idx, [0, 1, 2]);
    assert_eq!(seq.frames[1].depth_name, "depth/1.100.png");
    assert_eq!(
        seq.frames[0].color_path.as_deref(),
        Some(d.path().join("rgb/1.001.png").as_path())
    );
    assert_eq!(
        seq.frames[1].color_path.as_deref(),
        Some(d.path().join("rgb/1.099.png").as_path())
    );
    assert_eq!(seq.frames[2].color_path, None);
    assert!(seq.depth(2).unwrap().data.iter().all(|&v| v == 5000));

    // The intrinsics.txt in the directory is what is used.
    d.write("intrinsics.txt", "517.3 0 318.6\n0 516.5 255.3\n0 0 1\n");
    let seq = open(d.path()).unwrap();
    assert_eq!(seq.camera.fx, 517.3);
    assert_eq!(seq.camera.cy, 255.3);

    // Or the one line `fx fy cx cy`; five numbers are refused at their line.
    d.write("intrinsics.txt", "# fx fy cx cy\n517.3 516.5 318.6 255.3\n");
    let seq = open(d.path()).unwrap();
    assert_eq!(
        (seq.camera.fx, seq.camera.fy, seq.camera.cx, seq.camera.cy),
        (517.3, 516.5, 318.6, 255.3)
    );
    d.write("intrinsics.txt", "517.3 516.5 318.6 255.3 1\n");
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Parse { line: 1, .. }), "{e}");
    names(&e, "intrinsics.txt:1");
}

#[test]
fn tum_missing_depth_image_names_list_line() {
    let d = tum_dir("tum-missing-image");
    std::fs::remove_file(d.path().join("depth/1.100.png")).unwrap();
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Parse { line: 5, .. }), "{e}");
    names(&e, "depth.txt:5");
    names(&e, "1.100.png");
}

#[test]
fn tum_bad_groundtruth_line() {
    let d = tum_dir("tum-bad-gt");
    d.write(
        "groundtruth.txt",
        "# gt\n1.0 1 2 3 0 0 0 1\n1.1 1 2 3 0 0 1\n",
    );
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Parse { line: 3, .. }), "{e}");
    names(&e, "groundtruth.txt:3");
}

#[test]
fn tum_no_association_at_all() {
    let d = tum_dir("tum-none");
    d.write("groundtruth.txt", "50.0 1 2 3 0 0 0 1\n");
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Layout { .. }), "{e}");
    names(&e, "0.02");
}

// -------------------------------------------------------------- overrides

#[test]
fn overrides_replace_defaults_and_files() {
    let k = CameraModel {
        fx: 600.0,
        fy: 601.0,
        cx: 310.0,
        cy: 250.0,
    };
    let opts = ReadOptions {
        format: None,
        depth_scale: Some(2500.0),
        intrinsics: Some(k),
        ..Default::default()
    };
    // 7-Scenes without and with a camera-intrinsics.txt.
    let s = seven_scenes_dir("override-7s", 2);
    assert_eq!(open(s.path()).unwrap().camera.fx, 585.0);
    s.write("camera-intrinsics.txt", "500 0 320\n0 500 240\n0 0 1\n");
    assert_eq!(open(s.path()).unwrap().camera.fx, 500.0);
    let seq = read::open(s.path(), &opts).unwrap();
    assert_eq!((seq.camera, seq.depth_scale), (k, 2500.0));
    // The reference layout: an overridden intrinsics file is not even needed.
    let v = vprdb_dir("override-vprdb", 2);
    std::fs::remove_file(v.path().join("intrinsics.txt")).unwrap();
    let e = err(open(v.path()));
    assert!(matches!(e, ReadError::Layout { .. }), "{e}");
    names(&e, "intrinsics.txt");
    let seq = read::open(v.path(), &opts).unwrap();
    assert_eq!((seq.camera, seq.depth_scale), (k, 2500.0));
    // TUM.
    let t = tum_dir("override-tum");
    let seq = read::open(t.path(), &opts).unwrap();
    assert_eq!((seq.camera, seq.depth_scale), (k, 2500.0));
}

#[test]
fn invalid_overrides_are_refused() {
    let s = seven_scenes_dir("bad-override", 1);
    for scale in [0.0, -1000.0, f64::NAN, f64::INFINITY] {
        let opts = ReadOptions {
            depth_scale: Some(scale),
            ..Default::default()
        };
        let e = err(read::open(s.path(), &opts));
        assert!(matches!(e, ReadError::Layout { .. }), "{e}");
        names(&e, "depth scale");
    }
    let good = CameraModel {
        fx: 500.0,
        fy: 500.0,
        cx: 320.0,
        cy: 240.0,
    };
    for k in [
        CameraModel { fx: 0.0, ..good },
        CameraModel { fy: -1.0, ..good },
        CameraModel {
            cx: f64::NAN,
            ..good
        },
        CameraModel {
            fx: f64::INFINITY,
            ..good
        },
    ] {
        let opts = ReadOptions {
            intrinsics: Some(k),
            ..Default::default()
        };
        let e = err(read::open(s.path(), &opts));
        assert!(matches!(e, ReadError::Layout { .. }), "{e}");
        names(&e, "intrinsics");
    }
}

// ---------------------------------------------------- catalogue of errors

#[test]
fn truncated_png() {
    let d = seven_scenes_dir("truncated", 2);
    let p = d.path().join("frame-000001.depth.png");
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
    let e = read::decode_depth_png(&p).unwrap_err();
    assert!(matches!(e, ReadError::Png { .. }), "{e}");
    names(&e, "frame-000001.depth.png");
    // Only the first image is decoded at open; the second fails on demand.
    let seq = open(d.path()).unwrap();
    seq.depth(0).unwrap();
    let e = seq.depth(1).unwrap_err();
    assert!(matches!(e, ReadError::Png { .. }), "{e}");
    names(&e, "frame-000001.depth.png");
    // Cut inside the header: refused at open.
    std::fs::write(d.path().join("frame-000000.depth.png"), &bytes[..20]).unwrap();
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Png { .. }), "{e}");
    names(&e, "frame-000000.depth.png");
}

#[test]
fn png_missing_only_its_end_is_refused() {
    let d = TempDir::new("no-iend");
    let p = d.depth_png("cut.png", 4, 3, 7);
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() - 12]).unwrap(); // IEND chunk
    let e = read::decode_depth_png(&p).unwrap_err();
    assert!(matches!(e, ReadError::Png { .. }), "{e}");
    names(&e, "cut.png");
}

#[test]
fn corrupt_png() {
    let d = TempDir::new("corrupt");
    let p = d.path().join("garbage.png");
    std::fs::write(&p, b"this is not a PNG file at all").unwrap();
    let e = read::decode_depth_png(&p).unwrap_err();
    assert!(matches!(e, ReadError::Png { .. }), "{e}");
    names(&e, "garbage.png");
}

#[test]
fn eight_bit_and_colour_png() {
    let d = seven_scenes_dir("eight-bit", 1);
    let p = d.png(
        "frame-000000.depth.png",
        4,
        3,
        png::ColorType::Grayscale,
        png::BitDepth::Eight,
        &[9; 12],
    );
    let e = read::decode_depth_png(&p).unwrap_err();
    assert!(matches!(e, ReadError::Png { .. }), "{e}");
    names(&e, "frame-000000.depth.png");
    names(&e, "8-bit");
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Png { .. }), "{e}");
    names(&e, "frame-000000.depth.png");

    let p = d.png(
        "rgb.png",
        4,
        3,
        png::ColorType::Rgb,
        png::BitDepth::Sixteen,
        &[0; 72],
    );
    let e = read::decode_depth_png(&p).unwrap_err();
    assert!(matches!(e, ReadError::Png { .. }), "{e}");
    names(&e, "rgb.png");
}

#[test]
fn missing_depth_png() {
    let d = TempDir::new("missing-png");
    let e = read::decode_depth_png(&d.path().join("nope.png")).unwrap_err();
    assert!(matches!(e, ReadError::Io { .. }), "{e}");
    names(&e, "nope.png");
}

#[test]
fn missing_pose_file() {
    let d = seven_scenes_dir("missing-pose", 3);
    std::fs::remove_file(d.path().join("frame-000001.pose.txt")).unwrap();
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Layout { .. }), "{e}");
    names(&e, "frame-000001.depth.png");
    names(&e, "frame-000001.pose.txt");
}

#[test]
fn seven_scenes_pose_errors() {
    let cases: [(&str, &str, usize, &str); 6] = [
        // 3 columns on line 2.
        ("1 0 0 0\n0 1 0\n0 0 1 0\n0 0 0 1\n", "parse", 2, "found 3"),
        ("1 0 0 0\n0 1 0 0\n0 0 1 0\n", "parse", 3, "found 3"),
        ("1 0 0 0\n0 1 0 x\n0 0 1 0\n0 0 0 1\n", "parse", 2, "\"x\""),
        (
            "1 0 0 nan\n0 1 0 0\n0 0 1 0\n0 0 0 1\n",
            "pose",
            1,
            "not a finite number",
        ),
        (
            "1 0 0 0\n0 2 0 0\n0 0 1 0\n0 0 0 1\n",
            "pose",
            1,
            "is not a rotation",
        ),
        (
            "1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 1 1\n",
            "parse",
            4,
            "0 0 0 1",
        ),
    ];
    for (i, (content, kind, line, needle)) in cases.into_iter().enumerate() {
        let d = seven_scenes_dir(&format!("7s-pose-{i}"), 2);
        d.write("frame-000001.pose.txt", content);
        let e = err(open(d.path()));
        match (kind, &e) {
            ("parse", ReadError::Parse { line: l, .. })
            | ("pose", ReadError::Pose { line: l, .. }) => {
                assert_eq!(*l, line, "case {i}: {e}")
            }
            _ => panic!("case {i}: expected a {kind} error, got {e}"),
        }
        names(&e, &format!("frame-000001.pose.txt:{line}"));
        names(&e, needle);
    }
}

#[test]
fn vprdb_pose_line_with_six_columns() {
    let d = vprdb_dir("six-columns", 3);
    d.write("poses.txt", "0 0 0 0 0 0 1\n1 0 0 0 0 1\n2 0 0 0 0 0 1\n");
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Parse { line: 2, .. }), "{e}");
    names(&e, "poses.txt:2");
    names(&e, "found 6");
}

#[test]
fn vprdb_nan_and_non_rotation_poses() {
    let d = vprdb_dir("nan-pose", 3);
    d.write(
        "poses.txt",
        "0 0 0 0 0 0 1\n1 0 0 0 0 0 1\nNaN 0 0 0 0 0 1\n",
    );
    let e = err(open(d.path()));
    assert!(
        matches!(
            e,
            ReadError::Pose {
                line: 3,
                reason: placedb::CameraError::NonFinitePose,
                ..
            }
        ),
        "{e}"
    );
    names(&e, "poses.txt:3");

    d.write(
        "poses.txt",
        "0 0 0 0 0 0 1\n1 0 0 0.5 0.5 0.5 0.1\n2 0 0 0 0 0 1\n",
    );
    let e = err(open(d.path()));
    assert!(
        matches!(
            e,
            ReadError::Pose {
                line: 2,
                reason: placedb::CameraError::NotARotation,
                ..
            }
        ),
        "{e}"
    );
    names(&e, "poses.txt:2");
}

#[test]
fn vprdb_timestamps_and_layout_errors() {
    let d = vprdb_dir("vprdb-ts", 3);
    // Leading timestamps, comments, unnormalised-by-rounding quaternion.
    d.write(
        "poses.txt",
        "# t tx ty tz qx qy qz qw\n10.5 0 0 0 0 0 0 1\n11.5 1 0 0 0 0 0 1\n12.5 2 0 0 0 0 0 0.9999\n",
    );
    let seq = open(d.path()).unwrap();
    let ts: Vec<f64> = seq.frames.iter().map(|f| f.timestamp).collect();
    assert_eq!(ts, [10.5, 11.5, 12.5]);
    assert_eq!(seq.frames[2].rotation, [0.0, 0.0, 0.0, 1.0]);

    // Mixed forms.
    d.write(
        "poses.txt",
        "0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n2 0 0 0 0 0 1\n",
    );
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Parse { line: 2, .. }), "{e}");
    names(&e, "poses.txt:2");

    // Count mismatch.
    d.write("poses.txt", "0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n");
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Layout { .. }), "{e}");
    names(&e, "poses.txt");
    names(&e, "2 poses for 3 depth images");

    // Another name for the poses file when it is the only one.
    std::fs::remove_file(d.path().join("poses.txt")).unwrap();
    d.write(
        "trajectory.txt",
        "0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n2 0 0 0 0 0 1\n",
    );
    assert_eq!(open(d.path()).unwrap().frames.len(), 3);
    // ... but not when ambiguous, nor when absent.
    d.write("other.txt", "");
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Layout { .. }), "{e}");
    names(&e, "other.txt");
    names(&e, "trajectory.txt");
    std::fs::remove_file(d.path().join("other.txt")).unwrap();
    std::fs::remove_file(d.path().join("trajectory.txt")).unwrap();
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Layout { .. }), "{e}");
    names(&e, "poses.txt");

    // Colour images are paired by position, and must match in number.
    d.write("poses.txt", "0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n2 0 0 0 0 0 1\n");
    for i in 0..3 {
        d.write(&format!("color/c{i}.jpg"), "");
    }
    let seq = open(d.path()).unwrap();
    assert_eq!(
        seq.frames[2].color_path.as_deref(),
        Some(d.path().join("color/c2.jpg").as_path())
    );
    std::fs::remove_file(d.path().join("color/c2.jpg")).unwrap();
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Layout { .. }), "{e}");
    names(&e, "color");
}

#[test]
fn depth_size_mismatch_is_reported_on_demand() {
    let d = seven_scenes_dir("size-mismatch", 2);
    d.depth_png("frame-000001.depth.png", 5, 3, 1000);
    let seq = open(d.path()).unwrap();
    let e = seq.depth(1).unwrap_err();
    assert!(matches!(e, ReadError::SizeMismatch { .. }), "{e}");
    names(&e, "frame-000001.depth.png");
}

#[test]
fn bad_intrinsics_file_names_file_and_line() {
    let d = seven_scenes_dir("bad-k", 1);
    d.write("camera-intrinsics.txt", "585 0 320\n0 585 240\n320 240 1\n");
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Parse { line: 3, .. }), "{e}");
    names(&e, "camera-intrinsics.txt:3");
    let k = read::parse_intrinsics_file(&sample(VPRDB).join("intrinsics.txt")).unwrap();
    assert_eq!(k.fx, 945.4777832);
}

// ------------------------------------------------------------------ speed

/// CPU time of the calling thread in nanoseconds (Linux), so that timing is
/// not distorted by other processes on a busy machine.
fn thread_cpu_ns() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    s.split_whitespace().next()?.parse().ok()
}

/// Decode time per 640x480 frame; run with
/// `cargo test --release -p placedb-host --test readers -- --ignored --nocapture`.
#[test]
#[ignore = "timing; run in release"]
fn decode_speed() {
    let seq = open(sample(SEVEN_SCENES)).unwrap();
    let n = seq.frames.len();
    for i in 0..n {
        seq.depth(i).unwrap(); // warm the page cache
    }
    let cpu = thread_cpu_ns();
    let t = std::time::Instant::now();
    let mut sum = 0u64;
    for i in 0..n {
        sum += seq.depth(i).unwrap().data[320 * 480] as u64;
    }
    let wall = t.elapsed().as_secs_f64() / n as f64;
    let cpu = thread_cpu_ns()
        .zip(cpu)
        .map(|(b, a)| (b - a) as f64 / 1e9 / n as f64);
    use rayon::prelude::*;
    let t = std::time::Instant::now();
    let par: u64 = (0..n)
        .into_par_iter()
        .map(|i| seq.depth(i).unwrap().data[320 * 480] as u64)
        .sum();
    let par_wall = t.elapsed().as_secs_f64() / n as f64;
    assert_eq!(sum, par);
    eprintln!(
        "decode 640x480: one thread {:.3} ms/frame wall, {} CPU; {} rayon threads {:.3} ms/frame wall",
        wall * 1e3,
        cpu.map_or("n/a".into(), |c| format!("{:.3} ms/frame", c * 1e3)),
        rayon::current_num_threads(),
        par_wall * 1e3,
    );
}

// ------------------------------- issue 22: no frame dropped, no default silent

/// A temporary copy of the first `n` frames of 7scenes-1000 (depth, pose,
/// the camera file).
fn seven_scenes_copy(name: &str, n: usize) -> TempDir {
    let src = sample(SEVEN_SCENES);
    let d = TempDir::new(name);
    std::fs::copy(
        src.join("camera-intrinsics.txt"),
        d.path().join("camera-intrinsics.txt"),
    )
    .unwrap();
    for i in 0..n {
        for ext in ["depth.png", "pose.txt"] {
            let f = format!("frame-{i:06}.{ext}");
            std::fs::copy(src.join(&f), d.path().join(&f)).unwrap();
        }
    }
    d
}

/// A TUM directory of `n` frames whose depth images are 7scenes-1000's
/// (640x480), 0.1 s apart, each with its groundtruth line; no intrinsics.
fn tum_copy(name: &str, n: usize) -> TempDir {
    let src = sample(SEVEN_SCENES);
    let d = TempDir::new(name);
    std::fs::create_dir_all(d.path().join("depth")).unwrap();
    let (mut depth, mut gt) = (String::new(), String::new());
    for i in 0..n {
        let t = format!("{}.{}00", 10 + i / 10, i % 10);
        std::fs::copy(
            src.join(format!("frame-{i:06}.depth.png")),
            d.path().join(format!("depth/{t}.png")),
        )
        .unwrap();
        depth.push_str(&format!("{t} depth/{t}.png\n"));
        gt.push_str(&format!("{t} {} 0 0 0 0 0 1\n", i as f64 * 0.05));
    }
    d.write("depth.txt", &format!("# timestamp filename\n{depth}"));
    d.write(
        "groundtruth.txt",
        &format!("# timestamp tx ty tz qx qy qz qw\n{gt}"),
    );
    d
}

/// Runs the `placedb` binary; returns (success, stdout, stderr).
fn placedb(args: &[&std::ffi::OsStr]) -> (bool, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_placedb"))
        .args(args)
        .output()
        .expect("run placedb");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// `placedb select DIR -o DIR/../out --quiet` plus `extra`; the output
/// directory and the command's outcome.
fn select(seq: &TempDir, extra: &[&str]) -> (PathBuf, bool, String, String) {
    let out = seq.path().with_extension("out");
    let _ = std::fs::remove_dir_all(&out);
    let mut args: Vec<&std::ffi::OsStr> = vec![
        "select".as_ref(),
        seq.path().as_os_str(),
        "-o".as_ref(),
        out.as_os_str(),
        "--quiet".as_ref(),
    ];
    args.extend(extra.iter().map(|a| std::ffi::OsStr::new(*a)));
    let (ok, stdout, stderr) = placedb(&args);
    (out, ok, stdout, stderr)
}

fn metrics(out: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(out.join("metrics.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

/// Item 5, 7-Scenes: a pose file whose depth image is missing is a counted,
/// warned skip that renumbers nothing silently: the later frames keep their
/// frame numbers as timestamps, and metrics.json says how many were skipped.
#[test]
fn seven_scenes_missing_depth_is_skipped_counted_and_traceable() {
    let d = seven_scenes_copy("7s-missing-depth", 10);
    std::fs::remove_file(d.path().join("frame-000007.depth.png")).unwrap();
    let seq = open(d.path()).unwrap();
    assert_eq!((seq.frames.len(), seq.frames_skipped), (9, 1));
    assert_eq!(seq.frames[7].timestamp, 8.0);
    assert_eq!(seq.frames[7].depth_name, "frame-000008.depth.png");

    let (out, ok, _, stderr) = select(&d, &[]);
    assert!(ok, "{stderr}");
    assert!(
        stderr.contains("warning")
            && stderr.contains("1 of 10 frames")
            && stderr.contains("frame-000007.pose.txt")
            && stderr.contains("skipped"),
        "{stderr}"
    );
    let m = metrics(&out);
    assert_eq!(
        (m["frames"].as_u64(), m["frames_skipped"].as_u64()),
        (Some(9), Some(1))
    );
    let _ = std::fs::remove_dir_all(&out);
    // A whole sequence skips nothing, and says so.
    let whole = seven_scenes_copy("7s-whole", 3);
    let (out, ok, _, stderr) = select(&whole, &[]);
    assert!(ok && !stderr.contains("skipped"), "{stderr}");
    assert_eq!(metrics(&out)["frames_skipped"].as_u64(), Some(0));
    let _ = std::fs::remove_dir_all(&out);
}

/// Item 5, TUM: a depth line without groundtruth is a counted skip (the
/// warning names its line); two lines with one timestamp, a duplicated
/// line among them, are an error naming both lines.
#[test]
fn tum_skips_are_counted_and_duplicate_timestamps_refused() {
    let d = tum_copy("tum-skip", 5);
    d.write("intrinsics.txt", "525 0 319.5\n0 525 239.5\n0 0 1\n");
    let gt = std::fs::read_to_string(d.path().join("groundtruth.txt")).unwrap();
    let without_third: String = gt
        .lines()
        .filter(|l| !l.starts_with("10.200"))
        .map(|l| format!("{l}\n"))
        .collect();
    d.write("groundtruth.txt", &without_third);
    let seq = open(d.path()).unwrap();
    assert_eq!((seq.frames.len(), seq.frames_skipped), (4, 1));
    assert_eq!(seq.frames[2].depth_name, "depth/10.300.png");
    let (out, ok, _, stderr) = select(&d, &[]);
    assert!(ok, "{stderr}");
    assert!(
        stderr.contains("depth.txt")
            && stderr.contains("1 of 5 depth frames have no groundtruth")
            && stderr.contains("line 4"),
        "{stderr}"
    );
    assert_eq!(metrics(&out)["frames_skipped"].as_u64(), Some(1));
    let _ = std::fs::remove_dir_all(&out);
    d.write("groundtruth.txt", &gt);

    let list = std::fs::read_to_string(d.path().join("depth.txt")).unwrap();
    // A duplicated line (line 3 again as line 7).
    let dup = format!("{list}10.100 depth/10.100.png\n");
    d.write("depth.txt", &dup);
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Parse { line: 7, .. }), "{e}");
    names(&e, "depth.txt:7");
    names(&e, "line 3");
    // Two images at one time.
    d.write("depth.txt", &list.replace("10.400 depth", "10.100 depth"));
    let e = err(open(d.path()));
    names(&e, "depth.txt:6");
    names(&e, "line 3");
    d.write("depth.txt", &list);
    // Two poses at one time.
    d.write("groundtruth.txt", &format!("{gt}10.300 9 9 9 0 0 0 1\n"));
    let e = err(open(d.path()));
    names(&e, "groundtruth.txt:7");
    names(&e, "line 5");
}

/// Item 5, the reference layout: timestamps must rise; a duplicated or
/// reordered line is an error naming both lines.
#[test]
fn vprdb_duplicate_and_descending_timestamps_are_refused() {
    let d = vprdb_dir("vprdb-order", 3);
    d.write(
        "poses.txt",
        "0.5 0 0 0 0 0 0 1\n0.6 1 0 0 0 0 0 1\n0.7 2 0 0 0 0 0 1\n",
    );
    assert_eq!(open(d.path()).unwrap().frames.len(), 3);
    d.write(
        "poses.txt",
        "0.5 0 0 0 0 0 0 1\n0.5 1 0 0 0 0 0 1\n0.7 2 0 0 0 0 0 1\n",
    );
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Parse { line: 2, .. }), "{e}");
    names(&e, "poses.txt:2");
    names(&e, "equals the one of line 1");
    d.write(
        "poses.txt",
        "0.5 0 0 0 0 0 0 1\n0.7 1 0 0 0 0 0 1\n0.6 2 0 0 0 0 0 1\n",
    );
    let e = err(open(d.path()));
    names(&e, "poses.txt:3");
    names(&e, "is before the one of line 2");
}

/// Item 7: TUM's default intrinsics for 640x480 images, with a warning
/// naming them; another size without intrinsics is an error asking for
/// them, before any output is written.
#[test]
fn tum_default_intrinsics_only_for_640x480_and_never_silent() {
    let d = tum_copy("tum-default-k", 3);
    let seq = open(d.path()).unwrap();
    assert_eq!(seq.camera, read::tum::DEFAULT_CAMERA);
    let (out, ok, _, stderr) = select(&d, &[]);
    assert!(ok, "{stderr}");
    assert!(
        stderr.contains("warning")
            && stderr.contains("no intrinsics.txt")
            && stderr.contains("fx = fy = 525, cx = 319.5, cy = 239.5"),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&out);

    let small = tum_dir("tum-160x120");
    std::fs::remove_file(small.path().join("intrinsics.txt")).unwrap();
    for t in ["1.000", "1.100", "1.200", "1.500"] {
        small.depth_png(&format!("depth/{t}.png"), 160, 120, 5000);
    }
    let e = err(open(small.path()));
    names(&e, "intrinsics.txt");
    names(&e, "160x120");
    names(&e, "--intrinsics");
    let (out, ok, _, stderr) = select(&small, &[]);
    assert!(
        !ok && stderr.contains("160x120") && stderr.contains("--intrinsics"),
        "{stderr}"
    );
    assert!(!out.join("metrics.json").exists());
    // Given intrinsics are used without a word.
    let (out, ok, _, stderr) = select(&small, &["--intrinsics", "200,200,79.5,59.5"]);
    assert!(ok && !stderr.contains("intrinsics"), "{stderr}");
    let _ = std::fs::remove_dir_all(&out);
}

/// Item 10: a directory that two layouts match is an error naming both and
/// asking for --format (which then decides); `--format` offers only
/// layouts it can read; reader errors carry no Rust names.
#[test]
fn ambiguous_layouts_and_errors_in_words() {
    let d = seven_scenes_copy("ambiguous", 2);
    d.write("depth.txt", "1.0 depth/1.0.png\n");
    d.write("groundtruth.txt", "1.0 0 0 0 0 0 0 1\n");
    let e = err(open(d.path()));
    assert!(matches!(e, ReadError::Layout { .. }), "{e}");
    names(&e, "7scenes (frame-*.depth.png)");
    names(&e, "tum (depth.txt and groundtruth.txt)");
    names(&e, "--format");
    let (out, ok, _, stderr) = select(&d, &[]);
    assert!(
        !ok && stderr.contains("--format") && stderr.contains("7scenes"),
        "{stderr}"
    );
    let (out2, ok, _, stderr) = select(&d, &["--format", "7scenes"]);
    assert!(ok, "{stderr}");
    assert_eq!(metrics(&out2)["frames"].as_u64(), Some(2));
    let _ = std::fs::remove_dir_all(&out);
    let _ = std::fs::remove_dir_all(&out2);

    let (ok, help, _) = placedb(&["select".as_ref(), "--help".as_ref()]);
    let values = help
        .split("Possible values:")
        .nth(1)
        .and_then(|rest| rest.split("--depth-scale").next())
        .expect("--format lists its values");
    assert!(
        ok && values.contains("- 7scenes:") && !values.contains("synthetic"),
        "{help}"
    );
    let (_, _, _, stderr) = select(&d, &["--format", "synthetic"]);
    assert!(stderr.contains("invalid value"), "{stderr}");

    // A NaN in a pose file and an impossible override, in words.
    d.write(
        "frame-000001.pose.txt",
        "1 0 0 nan\n0 1 0 0\n0 0 1 0\n0 0 0 1\n",
    );
    let e = err(read::open(
        d.path(),
        &ReadOptions {
            format: Some(Format::SevenScenes),
            ..Default::default()
        },
    ));
    names(&e, "not a finite number");
    assert!(!e.to_string().contains("NonFinitePose"), "{e}");
    let opts = ReadOptions {
        intrinsics: Some(CameraModel {
            fx: 0.0,
            fy: 500.0,
            cx: 320.0,
            cy: 240.0,
        }),
        ..Default::default()
    };
    let e = err(read::open(d.path(), &opts));
    assert!(!e.to_string().contains("CameraModel"), "{e}");
    names(&e, "fx 0 fy 500");
}
