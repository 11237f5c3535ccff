//! Errors a user can cause are in words: what is wrong and what to do, with
//! no Rust type or variant name and no struct dump; a failing frame is
//! named the same run after run (the lowest one); a directory that looks
//! like two layouts is refused naming both; `--format` offers only what
//! works; and a default the reader takes is named, never silent.

mod cli_common;

use cli_common::{placedb, seven_scenes_copy, stderr, TempDir};
use std::path::Path;

/// A word like `NonFinitePose` or `CameraModel` (a variant or type name):
/// two or more capitals each followed by a lower-case letter ("NaN" and
/// "PNG" are words).
fn camel_case_words(text: &str) -> Vec<&str> {
    text.split(|c: char| !c.is_ascii_alphanumeric())
        .filter(|w| {
            let b = w.as_bytes();
            let humps = b
                .windows(2)
                .filter(|p| p[0].is_ascii_uppercase() && p[1].is_ascii_lowercase())
                .count();
            humps >= 2
        })
        .collect()
}

/// The error of a failed run, checked to be in words.
fn in_words(err: &str) -> &str {
    assert!(
        camel_case_words(err).is_empty(),
        "a Rust name in the message: {:?}: {err}",
        camel_case_words(err)
    );
    assert!(
        !err.contains(" { ") && !err.contains("{:?}"),
        "a struct dump: {err}"
    );
    err
}

/// Writes a 7-Scenes pose file: rotation rows `r`, translation `t`.
fn write_pose(path: &Path, r: [[f64; 3]; 3], t: [f64; 3]) {
    let mut s = String::new();
    for (row, ti) in r.iter().zip(t) {
        s += &format!("{} {} {} {ti}\n", row[0], row[1], row[2]);
    }
    s += "0 0 0 1\n";
    std::fs::write(path, s).unwrap();
}

const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// `select` on `seq` with `extra`, expected to fail: its stderr.
fn select_fails(tmp: &TempDir, seq: &str, extra: &[&str]) -> String {
    let out = tmp.arg("out");
    let mut args = vec!["select", seq, "-o", &out, "-q"];
    args.extend_from_slice(extra);
    let run = placedb(&args);
    assert_eq!(run.status.code(), Some(1), "{extra:?}: {}", stderr(&run));
    assert!(
        !tmp.path().join("out").exists(),
        "{extra:?}: output written"
    );
    stderr(&run)
}

#[test]
fn the_core_refusals_are_in_words() {
    let tmp = TempDir::new("words");
    let dir = tmp.path().join("seq");
    let seq = tmp.arg("seq");
    seven_scenes_copy(&dir, 4, true);
    let pose2 = dir.join("frame-000002.pose.txt");
    // A pose value that is not a number.
    write_pose(&pose2, IDENTITY, [0.0, f64::NAN, 0.0]);
    let e = select_fails(&tmp, &seq, &[]);
    assert!(in_words(&e).contains("not a finite number"), "{e}");
    assert!(e.contains("frame-000002.pose.txt"), "{e}");
    // A reflection, not a rotation.
    let mirror = [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    write_pose(&pose2, mirror, [0.0; 3]);
    let e = select_fails(&tmp, &seq, &[]);
    assert!(in_words(&e).contains("is not a rotation"), "{e}");
    write_pose(&pose2, IDENTITY, [0.0; 3]);
    // Intrinsics the reader takes and the core refuses (the principal
    // point far off the image), with every solver: the offline ones and
    // the online core.
    std::fs::write(
        dir.join("camera-intrinsics.txt"),
        "585 0 5000\n0 585 240\n0 0 1\n",
    )
    .unwrap();
    for solver in ["in-order", "online"] {
        let e = select_fails(&tmp, &seq, &["--solver", solver]);
        assert!(in_words(&e).contains("intrinsics are out of range"), "{e}");
        assert!(e.contains("frame 0 "), "{e}");
    }
    // A device refuses it in words too.
    let run = placedb(&["stream", &seq, "--port", "local:ram512k", "-q"]);
    assert_eq!(run.status.code(), Some(1));
    in_words(&stderr(&run));
    // A camera 1e12 m from the origin: whatever the run does, it says it
    // in words.
    seven_scenes_copy(&dir, 4, true);
    write_pose(&pose2, IDENTITY, [1e12, 0.0, 0.0]);
    let out = tmp.arg("far");
    let run = placedb(&["select", &seq, "-o", &out, "-q"]);
    in_words(&stderr(&run));
}

#[test]
fn the_frame_named_is_the_lowest_failing_one_in_every_run() {
    let tmp = TempDir::new("lowest-frame");
    let dir = tmp.path().join("seq");
    let seq = tmp.arg("seq");
    seven_scenes_copy(&dir, 40, true);
    // Two frames whose depth cannot be decoded, far apart so that two
    // threads meet them at about the same time.
    for i in [9, 29] {
        std::fs::write(dir.join(format!("frame-{i:06}.depth.png")), b"not a png").unwrap();
    }
    let first = select_fails(&tmp, &seq, &["--solver", "in-order"]);
    assert!(
        in_words(&first).contains("frame-000009.depth.png"),
        "{first}"
    );
    for _ in 0..5 {
        assert_eq!(select_fails(&tmp, &seq, &["--solver", "in-order"]), first);
    }
}

#[test]
fn a_directory_of_two_layouts_is_refused_naming_both() {
    let tmp = TempDir::new("ambiguous");
    let dir = tmp.path().join("seq");
    let seq = tmp.arg("seq");
    seven_scenes_copy(&dir, 3, true);
    std::fs::write(dir.join("depth.txt"), "# depth\n").unwrap();
    std::fs::write(dir.join("groundtruth.txt"), "# poses\n").unwrap();
    let e = select_fails(&tmp, &seq, &[]);
    assert!(
        in_words(&e).contains("7scenes") && e.contains("tum") && e.contains("--format"),
        "{e}"
    );
    // Chosen, it reads.
    let out = tmp.arg("out");
    let run = placedb(&[
        "select", &seq, "-o", &out, "-q", "--format", "7scenes", "--solver", "in-order",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
}

#[test]
fn format_offers_only_the_layouts_it_reads() {
    let run = placedb(&["select", "--help"]);
    let help = String::from_utf8_lossy(&run.stdout).into_owned();
    for format in ["tum", "7scenes", "vprdb", "ros2", "ros1"] {
        assert!(help.contains(&format!("- {format}:")), "{format}: {help}");
    }
    assert!(!help.contains("- synthetic:"), "{help}");
    let run = placedb(&["select", "--demo", "-o", "x", "--format", "synthetic"]);
    assert_eq!(run.status.code(), Some(2));
    assert!(stderr(&run).contains("possible values"), "{}", stderr(&run));
}

#[test]
fn the_default_intrinsics_of_7_scenes_are_named_and_change_no_output() {
    let tmp = TempDir::new("default-intrinsics");
    let with = tmp.path().join("with");
    let without = tmp.path().join("without");
    seven_scenes_copy(&with, 6, true);
    seven_scenes_copy(&without, 6, false);
    let run = |seq: &Path, out: &str| {
        let out = tmp.arg(out);
        let seq = seq.to_str().unwrap();
        let run = placedb(&["select", seq, "-o", &out, "-q", "--solver", "in-order"]);
        assert!(run.status.success(), "{}", stderr(&run));
        stderr(&run)
    };
    let named = run(&without, "out-without");
    assert!(
        named.contains("camera-intrinsics.txt")
            && named.contains("fx = 585, fy = 585, cx = 320, cy = 240"),
        "{named}"
    );
    let quiet = run(&with, "out-with");
    assert!(!quiet.contains("default intrinsics"), "{quiet}");
    // The sample's file holds the default: the outputs are the same.
    for file in ["database.csv", "labels.csv"] {
        assert_eq!(
            std::fs::read(tmp.path().join("out-without").join(file)).unwrap(),
            std::fs::read(tmp.path().join("out-with").join(file)).unwrap(),
            "{file}"
        );
    }
}

/// `bench --db-scaling` restores a device from each flash image it wrote
/// (`--db-probe FLASH`, its callgrind child): one it cannot restore is
/// refused in words naming the file, never a Rust variant or a panic.
#[test]
fn the_db_scaling_probe_refuses_a_flash_image_in_words() {
    let tmp = TempDir::new("db-probe");
    // Sectors of 4 KiB: none, a part of one, and two of noise.
    let noise: Vec<u8> = (0..2 * 4096u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 24) as u8)
        .collect();
    for (name, bytes, says) in [
        ("empty.flash", Vec::new(), "not a flash log image"),
        (
            "short.flash",
            vec![0xFF; 5000],
            "not a flash image of whole",
        ),
        ("noise.flash", noise, "no scan in this flash log"),
    ] {
        let path = tmp.arg(name);
        std::fs::write(&path, bytes).unwrap();
        let run = placedb(&["bench", "--db-probe", &path, "--building-frames", "10"]);
        let err = stderr(&run);
        assert_eq!(run.status.code(), Some(1), "{name}: {err}");
        assert!(in_words(&err).contains(says), "{name}: {err}");
        assert!(err.contains(&path), "{name}: {err}");
    }
}

/// An I/O error is in words, without Rust's "(os error N)": a sequence
/// that is not there is named, and the reason said plainly.
#[test]
fn io_errors_are_in_words_without_the_os_error_number() {
    let tmp = TempDir::new("io-words");
    let missing = tmp.arg("no-such-scan");
    let err = select_fails(&tmp, &missing, &[]);
    assert!(!err.contains("os error"), "{err}");
    assert!(
        err.contains(&format!("{missing}: no such file or directory")),
        "{err}"
    );
}

/// A depth image of another size than the sequence's is named with its
/// directory, so the user finds the file.
#[test]
fn a_frame_of_the_wrong_size_is_named_with_its_directory() {
    let tmp = TempDir::new("wrong-size");
    let seq = tmp.path().join("seq");
    seven_scenes_copy(&seq, 3, true);
    let small = tmp.arg("small");
    let synth = placedb(&[
        "synth", &small, "--frames", "1", "--width", "64", "--height", "48",
    ]);
    assert!(synth.status.success(), "{}", stderr(&synth));
    let png = std::fs::read_dir(tmp.path().join("small/depth"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let bad = seq.join("frame-000001.depth.png");
    std::fs::copy(&png, &bad).unwrap();
    let err = select_fails(&tmp, &tmp.arg("seq"), &[]);
    assert!(
        err.contains(&format!("{}: depth image is 64x48", bad.display())),
        "{err}"
    );
}

#[test]
fn bench_refuses_a_bag_that_is_not_a_recording_before_it_times_anything() {
    let tmp = TempDir::new("bench-bag");
    let missing = tmp.arg("missing.mcap");
    let run = placedb(&["bench", "--bag", &missing, "--solvers", "in-order"]);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(1), "{err}");
    assert!(
        err.contains("--bag") && err.contains("missing.mcap"),
        "{err}"
    );
    // Refused at once: no row of the table was printed.
    assert!(String::from_utf8_lossy(&run.stdout).is_empty());
}
