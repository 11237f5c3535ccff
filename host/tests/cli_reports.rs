//! What the command line reports (issue 22 items 1, 6, 8, 11): a run that
//! measured nothing fails in words and writes nothing, for every solver,
//! compare, stream and `--dataset`; every degradation is in the summary,
//! in metrics.json of every solver and on stderr; the in-process device's
//! result is never silently lost; singular and plural, the user's decimals
//! and "-" for a figure that does not apply. The real binary runs on copies
//! of the sample data in a temporary directory.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::atomic::{AtomicUsize, Ordering};

const SEVEN_SCENES: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../shared/data/7scenes-1000"
);

const SOLVERS: [&str; 7] = [
    "in-order",
    "greedy",
    "exact",
    "online",
    "every-nth",
    "distance",
    "cube",
];

/// A fresh empty directory under the system temp dir, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> TempDir {
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let p =
            std::env::temp_dir().join(format!("placedb-reports-{}-{n}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).unwrap();
        TempDir(p)
    }

    fn join(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }

    fn arg(&self, name: &str) -> String {
        self.join(name).display().to_string()
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The first `frames` frames of 7scenes-1000 (depth, pose, intrinsics) in
/// `dir`/`name`, the copy's path returned.
fn seven_scenes_copy(dir: &TempDir, name: &str, frames: usize) -> String {
    let src = Path::new(SEVEN_SCENES);
    assert!(src.is_dir(), "test data {} is missing", src.display());
    let dst = dir.join(name);
    std::fs::create_dir_all(&dst).unwrap();
    std::fs::copy(
        src.join("camera-intrinsics.txt"),
        dst.join("camera-intrinsics.txt"),
    )
    .unwrap();
    for i in 0..frames {
        for ext in ["depth.png", "pose.txt"] {
            let f = format!("frame-{i:06}.{ext}");
            std::fs::copy(src.join(&f), dst.join(&f)).unwrap();
        }
    }
    dst.display().to_string()
}

/// Overwrites frame `i`'s depth PNG in a 7-Scenes copy with 640x480 of `value`.
fn flat_depth(seq: &str, i: usize, value: u16) {
    let path = Path::new(seq).join(format!("frame-{i:06}.depth.png"));
    let (w, h) = (640u32, 480u32);
    let data: Vec<u8> = std::iter::repeat_n(value.to_be_bytes(), (w * h) as usize)
        .flatten()
        .collect();
    let file = std::fs::File::create(path).unwrap();
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w, h);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Sixteen);
    enc.write_header().unwrap().write_image_data(&data).unwrap();
}

/// Moves frame `i`'s camera in a 7-Scenes copy to `x` metres on the x axis.
fn move_camera(seq: &str, i: usize, x: f64) {
    let path = Path::new(seq).join(format!("frame-{i:06}.pose.txt"));
    let text = std::fs::read_to_string(&path).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let mut first: Vec<String> = lines[0].split_whitespace().map(String::from).collect();
    first[3] = format!("{x:e}");
    lines[0] = first.join(" ");
    std::fs::write(&path, lines.join("\n") + "\n").unwrap();
}

fn placedb(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_placedb"))
        .args(args)
        .output()
        .unwrap()
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn stdout(out: &Output) -> String {
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Asserts `out` failed with a message holding every one of `words`.
fn fails_with(out: &Output, words: &[&str]) {
    let err = stderr(out);
    assert!(!out.status.success(), "succeeded: {}", stdout(out));
    for w in words {
        assert!(err.contains(w), "{w:?} not in: {err}");
    }
    for rust in ["ScaleOutOfRange", "Camera {", "Some(", "NothingMeasured"] {
        assert!(!err.contains(rust), "a Rust name in: {err}");
    }
}

fn succeeds(out: &Output) -> String {
    assert!(out.status.success(), "failed: {}", stderr(out));
    stdout(out)
}

fn metrics(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("metrics.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

/// Item 1: a depth range, a depth scale or frames that leave no valid
/// pixel fail every solver, and name what to check; nothing is written.
#[test]
fn no_valid_pixel_fails_every_solver_and_writes_nothing() {
    let t = TempDir::new("no-valid");
    let seq = seven_scenes_copy(&t, "seq", 4);
    let out = t.arg("out");
    for solver in SOLVERS {
        let r = placedb(&[
            "select",
            &seq,
            "--depth-range",
            "20,30",
            "--solver",
            solver,
            "-q",
            "-o",
            &out,
        ]);
        fails_with(
            &r,
            &[
                "none of its 4 frames has a valid depth pixel",
                "--depth-scale, now 1000 units per metre",
                "--depth-range, now 20 m < z <= 30 m",
                "frame 0 (frame-000000.depth.png)",
                " m;",
            ],
        );
        assert!(!t.join("out").exists(), "{solver}: output written");
    }
    // A scale that puts every depth beyond the range: the raw values and
    // what they mean at that scale.
    let r = placedb(&["select", &seq, "--depth-scale", "1", "-q", "-o", &out]);
    fails_with(
        &r,
        &["now 1 units per metre", "frame 1 (frame-000001.depth.png)"],
    );
    // Frames of no depth at all (0) or the 7-Scenes invalid value (65535).
    for value in [0, 65535] {
        for i in 0..4 {
            flat_depth(&seq, i, value);
        }
        let r = placedb(&["select", &seq, "-q", "-o", &out]);
        fails_with(
            &r,
            &["has a valid depth pixel", "307200 pixels, all 0 (no depth)"],
        );
    }
    assert!(!t.join("out").exists());
}

/// Item 1: no frame at all is refused too, now as the command line is
/// parsed (status 2, the range in words) before any work.
#[test]
fn no_frame_fails() {
    let t = TempDir::new("no-frame");
    let seq = seven_scenes_copy(&t, "seq", 2);
    let out = t.arg("out");
    let r = placedb(&["select", &seq, "--max-frames", "0", "-q", "-o", &out]);
    fails_with(
        &r,
        &["--max-frames", "must be a whole number, 1 or more, got 0"],
    );
    assert_eq!(r.status.code(), Some(2));
    let r = placedb(&["select", "--demo", "--demo-frames", "0", "-q", "-o", &out]);
    fails_with(
        &r,
        &[
            "--demo-frames",
            "must be a whole number from 1 to 1000000, got 0",
        ],
    );
    assert_eq!(r.status.code(), Some(2));
    let r = placedb(&["compare", &seq, "--max-frames", "0", "-q"]);
    fails_with(
        &r,
        &["--max-frames", "must be a whole number, 1 or more, got 0"],
    );
    assert!(!t.join("out").exists());
}

/// Item 1: compare, select --dataset and stream refuse the same, and
/// write nothing (stream before the device is touched).
#[test]
fn compare_dataset_and_stream_refuse_a_run_that_measured_nothing() {
    let t = TempDir::new("others");
    let seq = seven_scenes_copy(&t, "seq", 3);
    let r = placedb(&["compare", &seq, "--depth-range", "20,30", "-q"]);
    fails_with(&r, &["has a valid depth pixel"]);
    let r = placedb(&[
        "select",
        &seq,
        "--depth-range",
        "20,30",
        "-q",
        "-o",
        &t.arg("out"),
        "--dataset",
        &t.arg("ds"),
    ]);
    fails_with(&r, &["has a valid depth pixel"]);
    assert!(!t.join("out").exists() && !t.join("ds").exists());
    let r = placedb(&[
        "stream",
        &seq,
        "--depth-range",
        "20,30",
        "--port",
        "local:ram512k",
        "-q",
        "-o",
        &t.arg("exported"),
    ]);
    fails_with(&r, &["has a valid depth pixel", "--depth-range"]);
    // Refused by the host before streaming, not on the device's count after.
    assert!(!stderr(&r).contains("the device found"), "{}", stderr(&r));
    assert!(!t.join("exported").exists());
    let r = placedb(&[
        "stream",
        &seq,
        "--max-frames",
        "0",
        "--port",
        "local:ram512k",
        "-q",
        "-o",
        &t.arg("exported"),
    ]);
    fails_with(&r, &["must be a whole number, 1 or more, got 0"]);
    assert_eq!(r.status.code(), Some(2));
    assert!(!t.join("exported").exists());
}

/// Item 6: metrics.json of every solver carries the loss counts, and the
/// summary line names them.
#[test]
fn every_solver_reports_its_losses() {
    let t = TempDir::new("keys");
    for solver in SOLVERS {
        let out = t.join(solver);
        let text = succeeds(&placedb(&[
            "select",
            "--demo",
            "--demo-frames",
            "30",
            "--solver",
            solver,
            "-o",
            &out.display().to_string(),
        ]));
        let m = metrics(&out);
        for key in ["frames_skipped", "empty_frames", "out_of_range_points"] {
            assert_eq!(m[key], 0, "{solver}: {key} in {m}");
        }
        assert!(
            text.contains(
                "input: 0 frames skipped by the reader, 0 frames without a valid depth pixel, 0 points outside the voxel key range"
            ),
            "{solver}: {text}"
        );
    }
    // compare --json: the same keys in every solver's object.
    let json = succeeds(&placedb(&[
        "compare",
        "--demo",
        "--demo-frames",
        "30",
        "--json",
        "-q",
    ]));
    let all: Vec<serde_json::Value> = serde_json::from_str(&json).unwrap();
    assert_eq!(all.len(), SOLVERS.len());
    for m in &all {
        for key in ["frames_skipped", "empty_frames", "out_of_range_points"] {
            assert_eq!(m[key], 0, "{key} in {m}");
        }
    }
}

/// Items 1 and 6: a frame without a valid pixel in an otherwise good run
/// is counted and warned, offline and online.
#[test]
fn an_empty_frame_is_counted_and_warned() {
    let t = TempDir::new("empty-frame");
    let seq = seven_scenes_copy(&t, "seq", 6);
    flat_depth(&seq, 2, 0);
    for solver in ["in-order", "online"] {
        let out = t.join(solver);
        let r = placedb(&[
            "select",
            &seq,
            "--solver",
            solver,
            "-o",
            &out.display().to_string(),
        ]);
        let text = succeeds(&r);
        assert!(
            stderr(&r).contains("warning: 1 frame without a valid depth pixel"),
            "{solver}: {}",
            stderr(&r)
        );
        assert!(
            text.contains("1 frame without a valid depth pixel"),
            "{text}"
        );
        assert_eq!(metrics(&out)["empty_frames"], 1, "{solver}");
    }
}

/// Item 6: a camera 400 km away loses its points, counted and warned by
/// every solver; one beyond what the fixed-point keys can place fails in
/// words naming the frame.
#[test]
fn a_far_camera_drops_its_points_or_fails_in_words() {
    let t = TempDir::new("far");
    let seq = seven_scenes_copy(&t, "seq", 5);
    move_camera(&seq, 3, 4e5);
    for solver in ["in-order", "greedy", "online"] {
        let out = t.join(solver);
        let r = placedb(&[
            "select",
            &seq,
            "--solver",
            solver,
            "-q",
            "-o",
            &out.display().to_string(),
        ]);
        succeeds(&r);
        let err = stderr(&r);
        assert!(
            err.contains("in 1 frame dropped: outside the voxel key range"),
            "{solver}: {err}"
        );
        let points = metrics(&out)["out_of_range_points"].as_u64().unwrap();
        assert!(points > 1000, "{solver}: {points}");
        assert!(
            err.contains(&format!("{points} points in 1 frame")),
            "{err}"
        );
    }
    // stream: the device's count, in its summary, warning and export.
    let r = placedb(&[
        "stream",
        &seq,
        "--port",
        "local:ram512k",
        "-q",
        "-o",
        &t.arg("streamed"),
    ]);
    succeeds(&r);
    let points = metrics(&t.join("streamed"))["out_of_range_points"]
        .as_u64()
        .unwrap();
    assert!(points > 1000, "{points}");
    assert!(
        stderr(&r).contains(&format!("warning: {points} points dropped")),
        "{}",
        stderr(&r)
    );
    // Every camera that far: nothing measured, an error saying why.
    let all_far = seven_scenes_copy(&t, "all-far", 3);
    for i in 0..3 {
        move_camera(&all_far, i, 4e5);
    }
    let r = placedb(&["select", &all_far, "-q", "-o", &t.arg("all-far-out")]);
    fails_with(
        &r,
        &[
            "every point of its 3 frames fell outside the voxel key range",
            "(400000, ",
            "--grid-origin scene-min",
        ],
    );
    assert!(!t.join("all-far-out").exists());
    move_camera(&seq, 3, 1e12);
    for solver in ["in-order", "online"] {
        let r = placedb(&[
            "select",
            &seq,
            "--solver",
            solver,
            "-q",
            "-o",
            &t.arg("far"),
        ]);
        fails_with(
            &r,
            &["frame 3", "frame-000003.depth.png", "camera position"],
        );
        assert!(!t.join("far").exists());
    }
}

/// Item 8: the in-process device's result is kept only with -o; an export
/// from a device without a scan is an error, with or without --dataset.
#[test]
fn the_in_process_device_keeps_its_result() {
    let t = TempDir::new("local");
    let seq = seven_scenes_copy(&t, "seq", 3);
    let r = placedb(&["stream", &seq, "--port", "local:ram512k", "-q"]);
    fails_with(
        &r,
        &["in-process device ends with this command", "give -o DIR"],
    );
    let r = placedb(&[
        "export",
        "--port",
        "local:ram512k",
        "-q",
        "-o",
        &t.arg("out"),
    ]);
    fails_with(&r, &["the device holds no scan", "stream -o DIR"]);
    assert!(!t.join("out").exists());
    let r = placedb(&[
        "export",
        "--port",
        "local:ram512k",
        "-q",
        "-o",
        &t.arg("out"),
        "--dataset",
        &t.arg("ds"),
        "--sequence",
        &seq,
    ]);
    fails_with(&r, &["the device holds no scan"]);
    assert!(!t.join("out").exists() && !t.join("ds").exists());
    // With -o the stream's result is there.
    let text = succeeds(&placedb(&[
        "stream",
        &seq,
        "--port",
        "local:ram512k",
        "-q",
        "-o",
        &t.arg("kept"),
    ]));
    assert!(text.contains("3 frames -> "), "{text}");
    assert!(t.join("kept/labels.csv").is_file());
    assert!(metrics(&t.join("kept"))["out_of_range_points"] == 0);
    // Without -q, stream -o says what it exported and where, as export -o.
    let text = succeeds(&placedb(&[
        "stream",
        &seq,
        "--port",
        "local:ram512k",
        "-o",
        &t.arg("said"),
    ]));
    let said = format!(
        "labels), checked by count and CRC; wrote {}/{{database.csv,labels.csv,metrics.json",
        t.join("said").display()
    );
    assert!(text.contains("exported ") && text.contains(&said), "{text}");
    // Its metrics.json has every key select --solver online writes, the
    // scan's settings as the device scanned with them, and null (with the
    // reason) for what only the sequence gives.
    let same = ["--mu", "0.4", "--stride", "2", "--window", "8", "-q", "-o"];
    let host_args = [&seq, "--solver", "online", "--profile", "ram512k"];
    let select: Vec<&str> = ["select"].iter().chain(&host_args).copied().collect();
    let mut select = select;
    select.extend(same);
    let host_dir = t.arg("host");
    select.push(&host_dir);
    succeeds(&placedb(&select));
    let mut stream = vec!["stream", &seq, "--port", "local:ram512k"];
    stream.extend(same);
    let device_dir = t.arg("device");
    stream.push(&device_dir);
    succeeds(&placedb(&stream));
    let host = metrics(&t.join("host"));
    let device = metrics(&t.join("device"));
    let missing: Vec<&String> = host
        .as_object()
        .unwrap()
        .keys()
        .filter(|k| device.get(k.as_str()).is_none())
        .collect();
    assert!(missing.is_empty(), "the export lacks {missing:?}: {device}");
    for k in [
        "mu",
        "voxel",
        "stride",
        "depth_min",
        "depth_max",
        "window",
        "grid_origin",
        "size",
    ] {
        assert_eq!(device[k], host[k], "{k}");
    }
    assert!(device["spatial_coverage"].is_null(), "{device}");
    let why = device["not_measured"].as_str().unwrap_or_default();
    assert!(why.contains("coverage metrics need the sequence"), "{why}");
    assert!(device["solve_s"].is_null(), "{device}");
    assert_eq!(device["restored_from_flash"], false);
}

/// Item 11: "1 database frame", and the user's decimals in metrics.json.
#[test]
fn singular_and_the_users_decimals() {
    let t = TempDir::new("words");
    let seq = seven_scenes_copy(&t, "seq", 1);
    let out = t.join("out");
    let text = succeeds(&placedb(&[
        "select",
        &seq,
        "--solver",
        "in-order",
        "--mu",
        "0.1",
        "--voxel",
        "0.2",
        "--depth-range",
        "0.1,4.7",
        "-o",
        &out.display().to_string(),
    ]));
    assert!(
        text.contains("seq: 1 frame -> 1 database frame (1.0x"),
        "{text}"
    );
    let json = std::fs::read_to_string(out.join("metrics.json")).unwrap();
    for want in [
        "\"mu\": 0.1,",
        "\"voxel\": 0.2,",
        "\"depth_min\": 0.1,",
        "\"depth_max\": 4.7,",
    ] {
        assert!(json.contains(want), "{want} not in {json}");
    }
}

/// Item 11: the bench table prints "-" where a figure does not apply (the
/// decode-only floor has no solve time), never NaN.
#[test]
fn bench_prints_a_dash_not_nan() {
    let t = TempDir::new("bench");
    seven_scenes_copy(&t, "7scenes-1000", 4);
    let text = succeeds(&placedb(&[
        "bench",
        "--data",
        &t.0.display().to_string(),
        "--solvers",
        "in-order",
        "--synthetic-frames",
        "10",
        "--repeat",
        "1",
    ]));
    assert!(!text.to_lowercase().contains("nan"), "{text}");
    let floor = text
        .lines()
        .find(|l| l.contains("decode-only") && l.starts_with("7scenes-1000"))
        .unwrap_or_else(|| panic!("no floor row: {text}"));
    assert!(floor.contains(" - "), "{floor}");
}

/// `select -q` prints no summary (stdout stays empty, with or without
/// --extend) and still its warnings on stderr; `--json` still prints the
/// JSON asked for.
#[test]
fn select_quiet_prints_no_summary_only_its_warnings() {
    let t = TempDir::new("quiet");
    let seq = seven_scenes_copy(&t, "seq", 4);
    flat_depth(&seq, 2, 0);
    let warned = "warning: 1 frame without a valid depth pixel";
    for solver in ["in-order", "online"] {
        let r = placedb(&[
            "select",
            &seq,
            "--solver",
            solver,
            "-q",
            "-o",
            &t.arg(solver),
        ]);
        let text = succeeds(&r);
        assert!(text.is_empty(), "{solver}: -q printed: {text}");
        assert!(stderr(&r).contains(warned), "{solver}: {}", stderr(&r));
        assert!(t.join(solver).join("labels.csv").is_file());
    }
    let r = placedb(&[
        "select",
        &seq,
        "--extend",
        &t.arg("online"),
        "-q",
        "-o",
        &t.arg("extended"),
    ]);
    let text = succeeds(&r);
    assert!(text.is_empty(), "--extend -q printed: {text}");
    assert!(t.join("extended").join("labels.csv").is_file());
    let r = placedb(&["select", &seq, "-q", "--json", "-o", &t.arg("json")]);
    let json: serde_json::Value = serde_json::from_str(&succeeds(&r)).unwrap();
    assert_eq!(json["empty_frames"], 1, "{json}");
    assert!(stderr(&r).contains(warned), "{}", stderr(&r));
}

/// Exporting an open scan (`stream --no-finish -o`) says so, even with
/// `-q`, and `metrics.json` counts its decided and undecided frames.
#[test]
fn an_open_scans_export_says_it_is_open() {
    let t = TempDir::new("open-scan");
    let out = t.arg("out");
    let run = placedb(&[
        "stream",
        "--demo",
        "--demo-frames",
        "30",
        "--stride",
        "8",
        "--window",
        "8",
        "--no-finish",
        "--port",
        "local:ram512k",
        "-q",
        "-o",
        &out,
    ]);
    let text = succeeds(&run);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        err.contains("placedb: warning: the board's scan is open (not finished): 30 frames seen"),
        "{text}{err}"
    );
    let m = metrics(&t.join("out"));
    assert_eq!(m["scan_finished"], false, "{m}");
    let (decided, undecided) = (m["frames_decided"].as_u64(), m["frames_undecided"].as_u64());
    assert_eq!(decided.unwrap() + undecided.unwrap(), 30, "{m}");
    assert!(undecided.unwrap() > 0, "{m}");
}

/// The status line shows the window the scan was given, not the profile's.
#[test]
fn the_status_line_shows_the_chosen_window() {
    let t = TempDir::new("window");
    let out = t.arg("out");
    let run = placedb(&[
        "stream",
        "--demo",
        "--demo-frames",
        "12",
        "--stride",
        "8",
        "--window",
        "3",
        "--port",
        "local:ram512k",
        "-o",
        &out,
    ]);
    let text = succeeds(&run);
    assert!(text.contains(" win 0/3 "), "{text}");
}
