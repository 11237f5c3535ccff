//! `select --colmap/--vpr-eval/--pairs` and `export --sequence`: the COLMAP
//! model read back against database.csv, the VPR-evaluation names parsed
//! back to the poses, the pairs above mu and best first and named by the
//! sequence's colour files (frame indices without them), the outputs
//! without the new options unchanged, a failed export leaving the previous
//! one, and a device's exports equal to select's.

mod cli_common;

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use placedb_host::board::client::Client;
use placedb_host::board::link::LocalLink;
use placedb_host::board::scan::StreamOptions;
use placedb_host::board::{export, scan};
use placedb_host::cli::export::{measure, streamed_frames, write_from_device, StreamedWith};
use placedb_host::output::exports::{self, vpr_eval, ExportTargets};
use placedb_host::output::replace;
use placedb_host::pipeline::{self, SolverParams};
use placedb_host::read::{self, ReadOptions};
use placedb_host::{synth, VoxelConfig};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

const SEVEN_SCENES: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../shared/data/7scenes-1000"
);
const FRAMES: usize = 60;

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("placedb-exports-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn placedb(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_placedb"))
        .args(args)
        .output()
        .unwrap()
}

fn select(args: &[&str]) -> String {
    let out = placedb(args);
    assert!(
        out.status.success(),
        "select failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// database.csv: frame index -> (tx, ty, tz).
fn database_csv(dir: &Path) -> BTreeMap<usize, [f64; 3]> {
    let text = std::fs::read_to_string(dir.join("database.csv")).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|c| c.parse().unwrap()).collect();
            (v[0] as usize, [v[2], v[3], v[4]])
        })
        .collect()
}

/// images.txt: image name -> camera centre `-R^T T`, and the lines after
/// each image line (COLMAP's POINTS2D, empty here).
fn colmap_centres(dir: &Path) -> BTreeMap<String, [f64; 3]> {
    let text = std::fs::read_to_string(dir.join("sparse/0/images.txt")).unwrap();
    let lines: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
    assert_eq!(lines.len() % 2, 0, "two lines per image");
    lines
        .chunks(2)
        .enumerate()
        .map(|(k, pair)| {
            let f: Vec<&str> = pair[0].split(' ').collect();
            assert_eq!(f.len(), 10, "{}", pair[0]);
            assert_eq!(f[0], (k + 1).to_string());
            assert_eq!(f[8], "1");
            assert_eq!(pair[1], "", "no 2D points");
            let n: Vec<f64> = f[1..8].iter().map(|c| c.parse().unwrap()).collect();
            let r = UnitQuaternion::from_quaternion(Quaternion::new(n[0], n[1], n[2], n[3]));
            let c = -(r.inverse() * Vector3::new(n[4], n[5], n[6]));
            (f[9].to_string(), [c.x, c.y, c.z])
        })
        .collect()
}

/// The frame of a 7-Scenes colour file's name in the pairs,
/// `frame-NNNNNN.color.jpg` (the sample numbers its frames from 0).
fn colour_index(name: &str) -> usize {
    let n = name
        .strip_prefix("frame-")
        .and_then(|r| r.strip_suffix(".color.jpg"))
        .unwrap_or_else(|| panic!("{name:?} is no 7-Scenes colour file"));
    assert_eq!(n.len(), 6, "{name:?}");
    n.parse().unwrap()
}

fn files(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    v.sort();
    v
}

#[test]
fn colmap_vpr_eval_and_pairs_of_a_recorded_sequence() {
    let root = temp("7scenes");
    let (out, plain) = (root.join("out"), root.join("plain"));
    let (colmap, vpr, pairs) = (
        root.join("colmap"),
        root.join("vpr"),
        root.join("pairs.txt"),
    );
    let n = FRAMES.to_string();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let base = ["select", SEVEN_SCENES, "--max-frames", &n];
    let mut with: Vec<String> = base.iter().map(|a| a.to_string()).collect();
    with.extend(["-o".into(), s(&out), "--colmap".into(), s(&colmap)]);
    with.extend(["--vpr-eval".into(), s(&vpr), "--pairs".into(), s(&pairs)]);
    let said = select(&with.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(
        said.contains("colmap:") && said.contains("pairs:"),
        "{said}"
    );
    let mut without: Vec<&str> = base.to_vec();
    without.extend(["-o", plain.to_str().unwrap()]);
    select(&without);

    // Without the options: the same outputs, byte for byte (metrics.json
    // holds timings).
    assert_eq!(files(&out), files(&plain));
    for f in ["database.csv", "labels.csv"] {
        assert_eq!(
            std::fs::read(out.join(f)).unwrap(),
            std::fs::read(plain.join(f)).unwrap(),
            "{f}"
        );
    }

    // COLMAP: every camera centre is database.csv's position.
    let db = database_csv(&out);
    assert!(!db.is_empty());
    let centres = colmap_centres(&colmap);
    assert_eq!(centres.len(), db.len());
    for (i, t) in &db {
        let c = centres[&exports::image_name(*i)];
        for a in 0..3 {
            assert!((c[a] - t[a]).abs() < 1e-9, "frame {i}: {c:?} against {t:?}");
        }
        // The colour JPEG as the sequence has it.
        let src = format!("{SEVEN_SCENES}/frame-{i:06}.color.jpg");
        assert_eq!(
            std::fs::read(colmap.join("images").join(exports::image_name(*i))).unwrap(),
            std::fs::read(src).unwrap()
        );
    }
    let cameras = std::fs::read_to_string(colmap.join("sparse/0/cameras.txt")).unwrap();
    assert!(
        cameras.contains("\n1 PINHOLE 640 480 585 585 320.5 240.5\n"),
        "{cameras}"
    );
    let points = std::fs::read_to_string(colmap.join("sparse/0/points3D.txt")).unwrap();
    assert!(points.lines().all(|l| l.starts_with('#')));
    // sources.csv: each exported image's frame and the sequence file it is.
    for (dir, images) in [(&colmap, db.len()), (&vpr, FRAMES)] {
        let sources = std::fs::read_to_string(dir.join(exports::SOURCES)).unwrap();
        let mut rows = sources.lines();
        assert_eq!(rows.next(), Some("image,frame,timestamp,source"));
        let rows: Vec<Vec<&str>> = rows.map(|l| l.split(',').collect()).collect();
        assert_eq!(rows.len(), images, "{sources}");
        for r in &rows {
            assert!(dir.join(r[0]).is_file(), "{r:?}");
            let i: usize = r[1].parse().unwrap();
            assert_eq!(r[3], format!("frame-{i:06}.color.jpg"), "{r:?}");
            assert_eq!(
                std::fs::read(dir.join(r[0])).unwrap(),
                std::fs::read(Path::new(SEVEN_SCENES).join(r[3])).unwrap()
            );
        }
    }

    // VPR-evaluation: names parse back to the database poses on the top
    // view's axes; the queries are the other frames.
    let mut seq = read::open(Path::new(SEVEN_SCENES), &ReadOptions::default()).unwrap();
    seq.frames.truncate(FRAMES);
    let proj = placedb_host::output::topview::horizontal(&seq.frames);
    let names = files(&vpr.join("database"));
    assert_eq!(names.len(), db.len());
    for name in &names {
        let (en, i) = vpr_eval::parse(name).unwrap();
        let want = exports::east_north_of(&proj, db[&i]);
        assert!(
            (en[0] - want[0]).abs() <= 5e-5 && (en[1] - want[1]).abs() <= 5e-5,
            "{name}"
        );
    }
    let queries = files(&vpr.join("queries"));
    assert_eq!(queries.len(), FRAMES - db.len());
    for name in &queries {
        let (en, i) = vpr_eval::parse(name).unwrap();
        assert!(!db.contains_key(&i));
        let want = exports::east_north_of(&proj, seq.frames[i].translation);
        assert!(
            (en[0] - want[0]).abs() <= 5e-5 && (en[1] - want[1]).abs() <= 5e-5,
            "{name}"
        );
    }

    // Pairs: every non-database frame with each database frame above mu,
    // best first.
    let prep = pipeline::prepare(&seq, VoxelConfig::default(), true).unwrap();
    let text = std::fs::read_to_string(&pairs).unwrap();
    let mut listed: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for line in text.lines() {
        let (q, d) = line.split_once(' ').unwrap();
        listed
            .entry(colour_index(q))
            .or_default()
            .push(colour_index(d));
    }
    for q in (0..FRAMES).filter(|q| !db.contains_key(q)) {
        let got = listed.remove(&q).unwrap_or_default();
        let ious: Vec<f32> = got.iter().map(|&d| prep.co.iou(q, d)).collect();
        assert!(ious.iter().all(|&v| v > 0.3), "frame {q}: {ious:?}");
        assert!(
            ious.windows(2).all(|w| w[0] >= w[1]),
            "frame {q}: not best first"
        );
        let above = db.keys().filter(|&&d| prep.co.iou(q, d) > 0.3).count();
        assert_eq!(got.len(), above, "frame {q}");
    }
    assert!(listed.is_empty(), "pairs for database frames: {listed:?}");
    std::fs::remove_dir_all(&root).ok();
}

#[test]
fn a_failed_export_leaves_the_one_before() {
    let root = temp("failed");
    // Ten frames of the recorded sequence, copied.
    let seq_dir = root.join("seq");
    std::fs::create_dir_all(&seq_dir).unwrap();
    for f in std::fs::read_dir(SEVEN_SCENES).unwrap() {
        let f = f.unwrap();
        let name = f.file_name().into_string().unwrap();
        let frame = name
            .strip_prefix("frame-")
            .and_then(|r| r.get(..6))
            .and_then(|n| n.parse::<usize>().ok());
        if frame.is_none_or(|k| k < 10) && f.path().is_file() {
            std::fs::copy(f.path(), seq_dir.join(&name)).unwrap();
        }
    }
    let colmap = root.join("colmap");
    let args = |out: &str| {
        vec![
            "select".to_string(),
            seq_dir.to_str().unwrap().into(),
            "-q".into(),
            "-o".into(),
            root.join(out).to_str().unwrap().into(),
            "--colmap".into(),
            colmap.to_str().unwrap().into(),
        ]
    };
    let run = |out: &str| placedb(&args(out).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(run("out1").status.success());
    let before = std::fs::read(colmap.join("sparse/0/images.txt")).unwrap();
    let images = files(&colmap.join("images"));
    // Every colour image broken: the second export fails.
    for f in std::fs::read_dir(&seq_dir).unwrap() {
        let p = f.unwrap().path();
        if p.to_str().unwrap().ends_with(".color.jpg") {
            std::fs::write(&p, b"broken").unwrap();
        }
    }
    let failed = run("out2");
    assert!(!failed.status.success());
    let err = String::from_utf8_lossy(&failed.stderr);
    assert!(err.contains("not a readable JPEG file"), "{err}");
    assert_eq!(
        std::fs::read(colmap.join("sparse/0/images.txt")).unwrap(),
        before
    );
    assert_eq!(files(&colmap.join("images")), images);
    // Nothing half-written beside it.
    assert!(
        files(&root).iter().all(|f| !f.starts_with('.')),
        "{:?}",
        files(&root)
    );
    // A directory of other files is not replaced.
    let other = root.join("seq");
    let refused = placedb(&[
        "select",
        "--demo",
        "--demo-frames",
        "20",
        "-q",
        "-o",
        root.join("out3").to_str().unwrap(),
        "--colmap",
        other.to_str().unwrap(),
    ]);
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("is not a COLMAP export"));
    // Refused before the work: select's own directory was not written.
    assert!(!root.join("out3").exists());
    // A file where a directory goes, and a directory where the pairs go:
    // refused in words, before the work.
    let file = root.join("file.txt");
    std::fs::write(&file, "keep").unwrap();
    for (flag, target, says) in [
        ("--vpr-eval", &file, "is not a directory"),
        ("--pairs", &other, "is a directory"),
    ] {
        let refused = placedb(&[
            "select",
            "--demo",
            "--demo-frames",
            "20",
            "-q",
            "-o",
            root.join("out4").to_str().unwrap(),
            flag,
            target.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&refused.stderr);
        assert!(
            !refused.status.success() && err.contains(says),
            "{flag}: {err}"
        );
        assert!(!root.join("out4").exists(), "{flag}");
    }
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "keep");
    std::fs::remove_dir_all(&root).ok();
}

/// Every file under `dir`, relative path -> bytes.
fn tree(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut all = BTreeMap::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                todo.push(p);
            } else {
                let rel = p.strip_prefix(dir).unwrap().to_path_buf();
                all.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    all
}

#[test]
fn a_devices_exports_are_selects() {
    let root = temp("device");
    let frames = 60;
    let dirs = |side: &str| {
        (
            root.join(side).join("colmap"),
            root.join(side).join("vpr"),
            root.join(side).join("pairs.txt"),
        )
    };
    let (colmap, vpr, pairs) = dirs("select");
    let n = frames.to_string();
    select(&[
        "select",
        "--demo",
        "--demo-frames",
        &n,
        "--solver",
        "online",
        "-q",
        "-o",
        root.join("select/out").to_str().unwrap(),
        "--colmap",
        colmap.to_str().unwrap(),
        "--vpr-eval",
        vpr.to_str().unwrap(),
        "--pairs",
        pairs.to_str().unwrap(),
    ]);
    // The same scan through the in-process device, exported.
    let seq = synth::sequence(&synth::SynthConfig {
        frames,
        ..synth::SynthConfig::demo()
    });
    let sel = placedb::SelectorConfig {
        mu: 0.3,
        window: 32,
        sketch_margin: SolverParams::default().sketch_margin,
    };
    let scan = scan::scan_config(&seq, &VoxelConfig::default()).unwrap();
    let cfg = scan::device_config(&scan, &sel).unwrap();
    let mut client = Client::new(LocalLink::start("ram512k").unwrap());
    scan::stream(
        &mut client,
        &seq,
        &cfg,
        "ram512k",
        &StreamOptions::default(),
        None,
    )
    .unwrap();
    let export = export::export_to(&mut client, &root.join("device/out"), None, true).unwrap();
    let (colmap2, vpr2, pairs2) = dirs("device");
    let flags = ExportTargets {
        colmap: Some(colmap2.clone()),
        vpr_eval: Some(vpr2.clone()),
        pairs: Some(pairs2.clone()),
    };
    let streamed = StreamedWith {
        mu: Some(0.3),
        voxel: Some(0.3),
        test: None,
    };
    // As `export --sequence` does: the frames the device labelled, then
    // measured.
    let seq = streamed_frames(seq, &export).unwrap();
    let measuring = measure(&seq, &export, &streamed, true).unwrap().unwrap();
    replace::together(|outputs| write_from_device(&flags, &measuring, &seq, &export, outputs))
        .unwrap();
    assert_eq!(
        std::fs::read(root.join("select/out/database.csv")).unwrap(),
        std::fs::read(root.join("device/out/database.csv")).unwrap()
    );
    let (a, b) = (tree(&colmap), tree(&colmap2));
    assert!(a.len() > 3, "{:?}", a.keys());
    assert!(a == b, "COLMAP exports differ");
    assert!(tree(&vpr) == tree(&vpr2), "VPR-evaluation exports differ");
    let p = std::fs::read_to_string(&pairs).unwrap();
    assert!(!p.is_empty());
    assert_eq!(p, std::fs::read_to_string(&pairs2).unwrap());
    std::fs::remove_dir_all(&root).ok();
}

/// labels.csv: each frame's class, by frame index.
fn labels_csv(dir: &Path) -> Vec<usize> {
    let text = std::fs::read_to_string(dir.join("labels.csv")).unwrap();
    text.lines()
        .skip(1)
        .enumerate()
        .map(|(i, l)| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f[0], i.to_string(), "{l}");
            f[2].parse().unwrap()
        })
        .collect()
}

/// `--pairs` names the images the user has, so that hloc finds them with
/// the sequence directory as its image_dir: every line is exactly two
/// whitespace-free names (hloc's parse_retrieval splits at whitespace),
/// each an existing colour file under the sequence directory, the first a
/// non-database frame, the second a database frame.
#[test]
fn pairs_name_the_sequences_colour_files() {
    let root = temp("pairs-colour");
    let (out, pairs) = (root.join("out"), root.join("pairs.txt"));
    let run = placedb(&[
        "select",
        SEVEN_SCENES,
        "--max-frames",
        "40",
        "-q",
        "-o",
        out.to_str().unwrap(),
        "--pairs",
        pairs.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{err}");
    assert!(!err.contains("--pairs"), "a note about the names: {err}");
    let labels = labels_csv(&out);
    assert_eq!(labels.len(), 40);
    let db = database_csv(&out);
    let text = std::fs::read_to_string(&pairs).unwrap();
    assert!(text.lines().count() > 0, "no pairs");
    for line in text.lines() {
        let names: Vec<&str> = line.split_whitespace().collect();
        assert_eq!(names.len(), 2, "{line:?}");
        assert_eq!(line, names.join(" "), "one space between two names");
        for name in &names {
            assert!(!name.starts_with('/'), "{name}: not relative");
            let file = Path::new(SEVEN_SCENES).join(name);
            assert!(file.is_file(), "{name}: no file {}", file.display());
        }
        let (q, d) = (colour_index(names[0]), colour_index(names[1]));
        assert!(labels[q] != q && !db.contains_key(&q), "{line}: query {q}");
        assert!(
            labels[d] == d && db.contains_key(&d),
            "{line}: database {d}"
        );
    }
    std::fs::remove_dir_all(&root).ok();
}

/// A sequence without colour files keeps the frame-index names and says
/// so in one line on stderr; a colour file whose name holds whitespace is
/// refused before anything is written, naming it.
#[test]
fn pairs_without_colour_or_with_unwritable_names() {
    let root = temp("pairs-names");
    let depth_only = root.join("depth-only");
    cli_common::seven_scenes_copy(&depth_only, 20, true);
    let pairs = root.join("pairs.txt");
    let run = placedb(&[
        "select",
        depth_only.to_str().unwrap(),
        "-q",
        "-o",
        root.join("out").to_str().unwrap(),
        "--pairs",
        pairs.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{err}");
    let said: Vec<&str> = err.lines().filter(|l| l.contains("--pairs")).collect();
    assert_eq!(said.len(), 1, "{err}");
    assert!(
        said[0].contains("has no colour image file")
            && said[0].contains("the pairs name frames by index, NNNNNN.jpg"),
        "{err}"
    );
    let text = std::fs::read_to_string(&pairs).unwrap();
    assert!(text.lines().count() > 0);
    for name in text.split_whitespace() {
        let i: usize = name.strip_suffix(".jpg").unwrap().parse().unwrap();
        assert_eq!(name, exports::image_name(i));
    }

    // The reference layout lists its colour files from color/: one with a
    // space in its name cannot be written as hloc's pairs.
    let spaced = root.join("spaced");
    let src = Path::new(SEVEN_SCENES);
    std::fs::create_dir_all(spaced.join("depth")).unwrap();
    std::fs::create_dir_all(spaced.join("color")).unwrap();
    let mut poses = String::new();
    for i in 0..3 {
        std::fs::copy(
            src.join(format!("frame-{i:06}.depth.png")),
            spaced.join(format!("depth/{i}.png")),
        )
        .unwrap();
        let colour = if i == 1 {
            "c 1.jpg".to_string()
        } else {
            format!("c{i}.jpg")
        };
        std::fs::copy(
            src.join(format!("frame-{i:06}.color.jpg")),
            spaced.join("color").join(colour),
        )
        .unwrap();
        poses.push_str("0 0 0 0 0 0 1\n");
    }
    std::fs::write(spaced.join("poses.txt"), poses).unwrap();
    std::fs::write(
        spaced.join("intrinsics.txt"),
        "585 0 320\n0 585 240\n0 0 1\n",
    )
    .unwrap();
    let (out, pairs) = (root.join("out2"), root.join("pairs2.txt"));
    let run = placedb(&[
        "select",
        spaced.to_str().unwrap(),
        "-q",
        "-o",
        out.to_str().unwrap(),
        "--pairs",
        pairs.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&format!("--pairs {}", pairs.display()))
            && err.contains("color/c 1.jpg")
            && err.contains("has whitespace or a line break in its name"),
        "{err}"
    );
    assert!(!out.exists() && !pairs.exists(), "something was written");
    std::fs::remove_dir_all(&root).ok();
}

/// What exports.md says is refused, before anything is written: a colour
/// image of another size than the depth images (the COLMAP camera is the
/// depth camera's), named with its frame and file, for `--colmap` and
/// `--vpr-eval`; a `--vpr-eval` path holding `@`, which the tool splits
/// names at.
#[test]
fn a_colour_image_of_another_size_or_an_at_in_the_vpr_eval_path_is_refused() {
    let root = temp("refused");
    let seq = root.join("seq");
    std::fs::create_dir_all(&seq).unwrap();
    for i in 0..6 {
        for kind in ["depth.png", "pose.txt", "color.jpg"] {
            let name = format!("frame-{i:06}.{kind}");
            std::fs::copy(Path::new(SEVEN_SCENES).join(&name), seq.join(&name)).unwrap();
        }
    }
    std::fs::copy(
        Path::new(SEVEN_SCENES).join("camera-intrinsics.txt"),
        seq.join("camera-intrinsics.txt"),
    )
    .unwrap();
    // Frame 0: in-order takes it, so both exports write its image.
    let small = seq.join("frame-000000.color.jpg");
    jpeg_encoder::Encoder::new_file(&small, 90)
        .unwrap()
        .encode(
            &[128; 320 * 240 * 3],
            320,
            240,
            jpeg_encoder::ColorType::Rgb,
        )
        .unwrap();
    let run = |flag: &str, target: &Path| {
        placedb(&[
            "select",
            seq.to_str().unwrap(),
            "--stride",
            "16",
            "--solver",
            "in-order",
            "-q",
            "-o",
            root.join("out").to_str().unwrap(),
            flag,
            target.to_str().unwrap(),
        ])
    };
    for (flag, target) in [("--colmap", "colmap"), ("--vpr-eval", "vpr")] {
        let out = run(flag, &root.join(target));
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{flag}: {err}");
        let want = format!(
            "frame 0: colour image {} is 320x240, the depth images",
            small.display()
        );
        assert!(err.contains(&want), "{flag}: {want:?} not in {err}");
        assert!(!root.join(target).exists() && !root.join("out").exists());
    }
    std::fs::remove_file(&small).unwrap();
    let at = root.join("a@b");
    let out = run("--vpr-eval", &at);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("the directory's path must hold none"), "{err}");
    assert!(!at.exists() && !root.join("out").exists());
    std::fs::remove_dir_all(&root).ok();
}
