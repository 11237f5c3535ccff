//! The built-in synthetic scan: determinism, ground truth to the millimetre,
//! agreement with the core's projector, loops in the path, and the TUM files it
//! writes (read back with the TUM reader).

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use placedb::{DepthRange, FrameProjector, VoxelGrid};
use placedb_host::read::{self, ReadOptions};
use placedb_host::synth::{self, Scene, SynthConfig};
use placedb_host::{Format, FrameInfo, Sequence};
use std::path::PathBuf;
use std::time::Instant;

/// A small, quick configuration.
fn small() -> SynthConfig {
    SynthConfig {
        frames: 90,
        width: 160,
        height: 120,
        seed: 5,
        rooms: 3,
    }
}

fn rotation(f: &FrameInfo) -> UnitQuaternion<f64> {
    let [x, y, z, w] = f.rotation;
    UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z))
}

/// A fresh directory under the system temp dir.
fn temp_dir(tag: &str) -> PathBuf {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos();
    let dir = std::env::temp_dir().join(format!(
        "placedb-synth-{tag}-{}-{nanos}",
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn sequence_metadata() {
    let cfg = SynthConfig::demo();
    let seq = synth::sequence(&cfg);
    assert_eq!(seq.name, "synthetic");
    assert_eq!(seq.format, Format::Synthetic);
    assert_eq!(seq.depth_scale, 5000.0);
    assert_eq!(seq.size, (320, 240));
    assert_eq!(seq.frames.len(), cfg.frames);
    assert_eq!((seq.camera.fx, seq.camera.fy), (256.0, 256.0));
    assert_eq!((seq.camera.cx, seq.camera.cy), (159.5, 119.5));
    for (i, f) in seq.frames.iter().enumerate() {
        assert_eq!(f.index, i);
        assert!((f.timestamp - (1.0 + i as f64 / 30.0)).abs() < 1e-6);
        f.pose().unwrap();
    }
    assert!(seq.depth(cfg.frames).is_err());
    assert_eq!(SynthConfig::bench().frames, 5000);
    assert_eq!(
        synth::sequence(&SynthConfig {
            frames: 0,
            ..small()
        })
        .frames
        .len(),
        0
    );
    assert_eq!(
        synth::sequence(&SynthConfig {
            frames: 1,
            ..small()
        })
        .frames
        .len(),
        1
    );
}

#[test]
fn deterministic_across_builds_and_threads() {
    let a = synth::sequence(&small());
    let b = synth::sequence(&small());
    assert_eq!(a.frames, b.frames);
    let picks = [0usize, 13, 44, 89];
    let here: Vec<_> = picks.iter().map(|&i| a.depth(i).unwrap()).collect();
    let b = std::sync::Arc::new(b);
    let handles: Vec<_> = picks
        .iter()
        .map(|&i| {
            let b = b.clone();
            std::thread::spawn(move || b.depth(i).unwrap())
        })
        .collect();
    for (img, h) in here.iter().zip(handles) {
        assert_eq!(*img, h.join().unwrap());
        assert!(img.data.iter().filter(|&&d| d != 0).count() > img.data.len() / 2);
    }
    // Another seed furnishes the rooms differently.
    let c = synth::sequence(&SynthConfig { seed: 6, ..small() });
    assert!(picks
        .iter()
        .any(|&i| c.depth(i).unwrap() != here[picks.iter().position(|&p| p == i).unwrap()]));
}

/// Frames spread over the demo: corridor, doors, rooms.
fn sample_frames(seq: &Sequence) -> Vec<usize> {
    (0..12).map(|k| k * (seq.frames.len() - 1) / 11).collect()
}

#[test]
fn back_projection_hits_surfaces_to_the_millimetre() {
    let cfg = SynthConfig::demo();
    let scene = Scene::office(&cfg);
    let seq = synth::sequence(&cfg);
    let k = seq.camera;
    let (mut checked, mut empty) = (0, 0);
    for i in sample_frames(&seq) {
        let f = &seq.frames[i];
        let img = seq.depth(i).unwrap();
        let q = rotation(f);
        let t = Vector3::from(f.translation);
        for v in (0..img.height).step_by(7) {
            for u in (0..img.width).step_by(5) {
                let raw = img.row(v)[u as usize];
                let dc = Vector3::new((u as f64 - k.cx) / k.fx, (v as f64 - k.cy) / k.fy, 1.0);
                let dir = q * dc.normalize();
                let truth = scene.ray_distance(f.translation, dir.into());
                if raw == 0 {
                    // Nothing within 10 m of ray.
                    assert!(
                        truth.is_none_or(|d| d > 10.0 - 1e-9),
                        "frame {i} ({u}, {v}): {truth:?}"
                    );
                    empty += 1;
                    continue;
                }
                let z = raw as f64 / 5000.0;
                let pc = Vector3::new(
                    (u as f64 - k.cx) * z / k.fx,
                    (v as f64 - k.cy) * z / k.fy,
                    z,
                );
                let pw = q * pc + t;
                let range = pc.norm();
                let truth = truth.expect("a rendered pixel has a surface");
                let tol = 1e-3 + 1e-4 * dc.norm() + 1e-4;
                assert!(
                    (range - truth).abs() <= tol,
                    "frame {i} ({u}, {v}): {range} vs {truth}"
                );
                // Independently of the caster: the point is on some box's boundary.
                let on_surface = scene.boxes().iter().any(|b| {
                    let inside =
                        |m: f64| (0..3).all(|a| pw[a] >= b.min[a] - m && pw[a] <= b.max[a] + m);
                    inside(1e-3) && !inside(-1e-3)
                });
                assert!(on_surface, "frame {i} ({u}, {v}): {pw:?} is on no surface");
                checked += 1;
            }
        }
    }
    assert!(checked > 10_000, "{checked} pixels checked, {empty} empty");
}

#[test]
fn projector_voxel_keys_match_f64_reference() {
    let cfg = SynthConfig::demo();
    let seq = synth::sequence(&cfg);
    let voxel = 0.3;
    let grid = VoxelGrid::new(voxel as f32, [0.0; 3]).unwrap();
    let k = seq.camera;
    let (mut checked, mut skipped) = (0usize, 0usize);
    for i in sample_frames(&seq) {
        let f = &seq.frames[i];
        let img = seq.depth(i).unwrap();
        let proj = FrameProjector::new(
            &seq.intrinsics(),
            seq.depth_scale as f32,
            DepthRange::default(),
            1,
            &grid,
            &f.pose().unwrap(),
        )
        .unwrap();
        let q = rotation(f);
        let t = Vector3::from(f.translation);
        for v in 0..img.height {
            let row = img.row(v);
            let mut keys = Vec::new();
            let mut oor = 0;
            proj.project_row(v, row, &mut oor, |key| keys.push(key.coords()));
            assert_eq!(oor, 0);
            // The projector's validity test, in its own f32 arithmetic.
            let valid: Vec<usize> = (0..row.len())
                .filter(|&u| {
                    let z = row[u] as f32 * (1.0 / 5000.0f32);
                    row[u] != 0 && z > 0.1 && z <= 10.0
                })
                .collect();
            assert_eq!(keys.len(), valid.len(), "frame {i} row {v}");
            for (&u, key) in valid.iter().zip(&keys) {
                let z = row[u] as f64 / 5000.0;
                let pc = Vector3::new(
                    (u as f64 - k.cx) * z / k.fx,
                    (v as f64 - k.cy) * z / k.fy,
                    z,
                );
                let g = (q * pc + t) / voxel;
                if (0..3).any(|a| (g[a] - g[a].round()).abs() * voxel < 1e-3) {
                    skipped += 1;
                    continue;
                }
                let want = (g.x.floor() as i32, g.y.floor() as i32, g.z.floor() as i32);
                assert_eq!(*key, want, "frame {i} pixel ({u}, {v})");
                checked += 1;
            }
        }
    }
    assert!(
        checked > 100_000 && skipped < checked / 10,
        "{checked} checked, {skipped} skipped"
    );
}

#[test]
fn path_revisits_places() {
    let cfg = SynthConfig::demo();
    let seq = synth::sequence(&cfg);
    let fr = &seq.frames;
    let mut loops = 0;
    for i in 0..fr.len() {
        for j in i + 101..fr.len() {
            let d = Vector3::from(fr[i].translation) - Vector3::from(fr[j].translation);
            if d.norm() < 0.3 && rotation(&fr[i]).angle_to(&rotation(&fr[j])) < 20f64.to_radians() {
                loops += 1;
            }
        }
    }
    assert!(loops >= 20, "{loops} revisits");
    // Camera height and a mostly level view.
    for f in fr {
        assert!(f.translation[2].abs() < 0.05);
        let forward = rotation(f) * Vector3::z();
        assert!(
            forward.z.abs() < 0.35,
            "frame {} looks {forward:?}",
            f.index
        );
    }
}

#[test]
fn writes_tum_layout_that_reads_back() {
    let cfg = SynthConfig {
        frames: 24,
        width: 64,
        height: 48,
        ..small()
    };
    let seq = synth::sequence(&cfg);
    let dir = temp_dir("tum");
    synth::write_tum(&seq, &dir, None).unwrap();
    let lines = |name: &str| std::fs::read_to_string(dir.join(name)).unwrap();
    for name in ["depth.txt", "rgb.txt", "groundtruth.txt"] {
        let text = lines(name);
        assert_eq!(
            text.lines().filter(|l| l.starts_with('#')).count(),
            3,
            "{name}"
        );
        assert_eq!(
            text.lines().filter(|l| !l.starts_with('#')).count(),
            24,
            "{name}"
        );
    }
    let gt = lines("groundtruth.txt");
    let first = gt.lines().find(|l| !l.starts_with('#')).unwrap();
    assert!(first.starts_with("1.000000 "), "{first}");
    assert_eq!(first.split_whitespace().count(), 8);
    assert!(lines("depth.txt").contains("1.033333 depth/1.033333.png"));
    assert_eq!(lines("intrinsics.txt"), "51.2 0 31.5\n0 51.2 23.5\n0 0 1\n");
    let decode = |path: PathBuf| {
        let mut reader = png::Decoder::new(std::fs::File::open(path).unwrap())
            .read_info()
            .unwrap();
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).unwrap();
        (info.width, info.height, info.color_type, info.bit_depth)
    };
    assert_eq!(
        decode(dir.join("depth/1.000000.png")),
        (64, 48, png::ColorType::Grayscale, png::BitDepth::Sixteen)
    );
    assert_eq!(
        decode(dir.join("rgb/1.766667.png")),
        (64, 48, png::ColorType::Rgb, png::BitDepth::Eight)
    );

    let back = read::open(&dir, &ReadOptions::default()).unwrap();
    assert_eq!(back.format, Format::Tum);
    assert_eq!(back.camera, seq.camera);
    assert_eq!(back.depth_scale, 5000.0);
    assert_eq!(back.size, seq.size);
    assert_eq!(back.frames.len(), seq.frames.len());
    for (a, b) in seq.frames.iter().zip(&back.frames) {
        assert!((a.timestamp - b.timestamp).abs() < 1e-9);
        for c in 0..3 {
            assert!((a.translation[c] - b.translation[c]).abs() < 1e-6);
        }
        for c in 0..4 {
            assert!((a.rotation[c] - b.rotation[c]).abs() < 1e-6);
        }
        assert_eq!(a.pose().unwrap(), b.pose().unwrap(), "frame {}", a.index);
        assert_eq!(
            seq.depth(a.index).unwrap(),
            back.depth(b.index).unwrap(),
            "frame {}",
            a.index
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// This thread's CPU time in seconds (Linux), else wall time since `start`:
/// the machine may be busy with other builds, CPU time is what rendering costs.
fn cpu_seconds(start: Instant) -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok())
        .map(|ns| ns * 1e-9)
        .unwrap_or_else(|| start.elapsed().as_secs_f64())
}

/// Render speed, single-threaded: `cargo test --release -p placedb-host --test
/// synth -- --ignored --nocapture`. Reports the fastest of 5 rounds over 100
/// frames spread along the bench path, in CPU time.
#[test]
#[ignore]
fn render_speed() {
    let cfg = SynthConfig::bench();
    let seq = synth::sequence(&cfg);
    let n = 100;
    let step = seq.frames.len() / n;
    let mut best = f64::INFINITY;
    let mut valid = 0usize;
    let mut counts = Vec::new();
    let origin = Instant::now();
    for _ in 0..5 {
        let start = cpu_seconds(origin);
        valid = 0;
        for k in 0..n {
            valid += seq
                .depth(k * step)
                .unwrap()
                .data
                .iter()
                .filter(|&&d| d != 0)
                .count();
        }
        best = best.min((cpu_seconds(origin) - start) / n as f64);
        counts.push(valid);
    }
    // Rendering is deterministic, and the office has walls in view.
    assert!(counts.iter().all(|&c| c == valid), "{counts:?}");
    assert!(
        valid * 2 > n * cfg.width as usize * cfg.height as usize,
        "{valid}"
    );
    println!(
        "render {}x{}: {:.3} ms per frame single-threaded ({:.0} % of pixels valid)",
        cfg.width,
        cfg.height,
        best * 1e3,
        100.0 * valid as f64 / (n * cfg.width as usize * cfg.height as usize) as f64
    );
}
