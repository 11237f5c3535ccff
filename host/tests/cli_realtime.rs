//! `placedb stream --realtime` on the real binary, to the in-process device,
//! on every layout the tests use: a 7-Scenes layout (frames numbered, not
//! stamped) is replayed at its camera's 30 Hz by position, so a gap in the
//! numbering never idles; a TUM sequence (`placedb synth`) and the demo at
//! their stamps; `--rate HZ` overrides either and is refused out of range
//! (exit 2) before any work; the summary numbers the sent frames right.

mod cli_common;

use cli_common::{placedb, seven_scenes_copy, stderr, TempDir, SEVEN_SCENES};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Runs `placedb args`, killed after `limit` (a replay that idles).
fn placedb_within(args: &[String], limit: Duration) -> (Output, Duration) {
    let start = Instant::now();
    let mut child = Command::new(env!("CARGO_BIN_EXE_placedb"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the placedb binary runs");
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > limit {
            child.kill().unwrap();
            let out = child.wait_with_output().unwrap();
            panic!(
                "{args:?} still running after {limit:?} (idling on the frame numbers?); \
                 stdout: {}",
                String::from_utf8_lossy(&out.stdout)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let took = start.elapsed();
    (child.wait_with_output().unwrap(), took)
}

fn realtime_args(seq: &str, extra: &[&str], out: &str) -> Vec<String> {
    let mut args: Vec<String> = ["stream", seq, "--realtime", "--port", "local:ram256k"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    args.extend(
        [
            "--profile",
            "ram256k",
            "--window",
            "8",
            "--stride",
            "4",
            "-o",
            out,
        ]
        .iter()
        .map(|s| s.to_string()),
    );
    args.extend(extra.iter().map(|s| s.to_string()));
    args
}

/// The summary's numbers agree: "N sent" on the first line and "the N sent
/// frames 0 to N-1" on the database line.
fn check_numbering(stdout: &str, frames: usize) {
    let first = stdout.lines().next().unwrap_or_default();
    let sent: usize = first
        .split(" sent, ")
        .next()
        .and_then(|head| head.rsplit(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no sent count in {first:?}"));
    assert!(sent >= 1 && sent <= frames, "{stdout}");
    let want = if sent == 1 {
        "the device numbers the 1 sent frame 0 (positions".to_string()
    } else {
        format!(
            "the device numbers the {sent} sent frames 0 to {} (positions",
            sent - 1
        )
    };
    assert!(stdout.contains(&want), "want {want:?} in {stdout}");
}

#[test]
fn a_seven_scenes_layout_replays_at_30_hz_by_position_and_a_numbering_gap_never_idles() {
    let tmp = TempDir::new("rt-7scenes");
    let seq = tmp.path().join("seq");
    seven_scenes_copy(&seq, 6, true);
    // Renumber the last frame 2,000: today's replay took frame numbers as
    // seconds and idled for 33 minutes before it.
    for kind in ["depth.png", "pose.txt"] {
        std::fs::rename(
            seq.join(format!("frame-000005.{kind}")),
            seq.join(format!("frame-002000.{kind}")),
        )
        .unwrap();
    }
    let (out, took) = placedb_within(
        &realtime_args(&seq.to_string_lossy(), &[], &tmp.arg("out")),
        Duration::from_secs(60),
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{}{stdout}", stderr(&out));
    assert!(
        stdout.contains(
            "6 frames replayed at 30.0 frames/s (the layout's camera rate, 30 Hz: its frames \
             are numbered, not stamped)"
        ),
        "{stdout}"
    );
    // Six frames at 30 Hz are due within 1/6 s; the device answers well
    // inside the rest.
    assert!(took < Duration::from_secs(20), "took {took:?}");
    check_numbering(&stdout, 6);
}

#[test]
fn the_seven_scenes_sample_replays_at_30_hz() {
    let tmp = TempDir::new("rt-sample");
    let (out, took) = placedb_within(
        &realtime_args(SEVEN_SCENES, &["--max-frames", "8"], &tmp.arg("out")),
        Duration::from_secs(60),
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{}{stdout}", stderr(&out));
    assert!(
        stdout.contains("8 frames replayed at 30.0 frames/s (the layout's camera rate"),
        "{stdout}"
    );
    assert!(took < Duration::from_secs(20), "took {took:?}");
    check_numbering(&stdout, 8);
}

#[test]
fn a_tum_sequence_replays_at_its_stamps_and_rate_overrides_them() {
    let tmp = TempDir::new("rt-tum");
    let seq = tmp.arg("tum");
    let made = placedb(&[
        "synth", &seq, "--frames", "4", "--width", "64", "--height", "48",
    ]);
    assert!(made.status.success(), "{}", stderr(&made));
    let (out, _) = placedb_within(
        &realtime_args(&seq, &[], &tmp.arg("a")),
        Duration::from_secs(60),
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{}{stdout}", stderr(&out));
    assert!(
        stdout.contains("4 frames replayed at 30.0 frames/s (the recorded timestamps)"),
        "{stdout}"
    );
    check_numbering(&stdout, 4);
    // At 3 Hz the fourth frame is due a whole second after the first.
    let (out, took) = placedb_within(
        &realtime_args(&seq, &["--rate", "3"], &tmp.arg("b")),
        Duration::from_secs(60),
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{}{stdout}", stderr(&out));
    assert!(
        stdout.contains("4 frames replayed at 3.0 frames/s (--rate 3)"),
        "{stdout}"
    );
    assert!(took >= Duration::from_secs(1), "took {took:?}");
    check_numbering(&stdout, 4);
}

#[test]
fn the_demo_replays_at_its_stamps() {
    let tmp = TempDir::new("rt-demo");
    let (out, _) = placedb_within(
        &realtime_args("--demo", &["--max-frames", "6"], &tmp.arg("out")),
        Duration::from_secs(60),
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{}{stdout}", stderr(&out));
    assert!(
        stdout.contains("6 frames replayed at 30.0 frames/s (the recorded timestamps)"),
        "{stdout}"
    );
    check_numbering(&stdout, 6);
}

#[test]
fn a_rate_out_of_range_exits_2_with_the_range_before_any_work() {
    let tmp = TempDir::new("rt-rate");
    for bad in ["0", "-1", "nan", "inf", "1001"] {
        let out = placedb(&realtime_args(
            SEVEN_SCENES,
            &["--max-frames", "2", "--rate", bad],
            &tmp.arg("out"),
        ));
        assert_eq!(out.status.code(), Some(2), "--rate {bad}: {}", stderr(&out));
        assert!(
            stderr(&out).contains("a replay rate is from above 0 to 1000 frames per second"),
            "--rate {bad}: {}",
            stderr(&out)
        );
        assert!(!tmp.path().join("out").exists());
    }
}

/// The dataset `select --dataset` writes is a layout the tool reads (the
/// reference layout) and replays at its source's rate: a 7-Scenes scan's
/// (frames numbered, not stamped) at the camera's 30 Hz by position, its
/// `database/` too, whose numbering has gaps (the dataset stamped each
/// frame with its number, so the replay took the numbers as seconds: 0.1
/// frames/s for this sequence of every tenth frame, idling 10 s on each
/// gap); a TUM scan's (stamped) at its stamps.
#[test]
fn a_dataset_replays_at_its_sequences_rate() {
    let tmp = TempDir::new("rt-dataset");
    let seq = tmp.path().join("seq");
    cli_common::seven_scenes_frames(&seq, (0..60).step_by(10), true);
    let tum = tmp.arg("tum");
    let made = placedb(&[
        "synth", &tum, "--frames", "4", "--width", "64", "--height", "48",
    ]);
    assert!(made.status.success(), "{}", stderr(&made));
    for (source, want) in [
        (
            seq.to_string_lossy().into_owned(),
            "replayed at 30.0 frames/s (the layout's camera rate, 30 Hz: its frames are \
             numbered, not stamped)",
        ),
        (tum, "replayed at 30.0 frames/s (the recorded timestamps)"),
    ] {
        let ds = tmp.arg("ds");
        let run = placedb(&[
            "select",
            &source,
            "--stride",
            "8",
            "--mu",
            "0.8",
            "--voxel",
            "0.2",
            "-q",
            "-o",
            &tmp.arg("sel"),
            "--dataset",
            &ds,
        ]);
        assert!(run.status.success(), "{}", stderr(&run));
        for dir in [ds.clone(), format!("{ds}/database")] {
            let (out, took) = placedb_within(
                &realtime_args(&dir, &[], &tmp.arg("out")),
                Duration::from_secs(30),
            );
            let stdout = String::from_utf8_lossy(&out.stdout);
            assert_eq!(out.status.code(), Some(0), "{}{stdout}", stderr(&out));
            assert!(stdout.contains(want), "{dir}: want {want:?} in {stdout}");
            assert!(took < Duration::from_secs(20), "{dir}: took {took:?}");
        }
    }
}

/// The reference layout without a timestamp column (the sample
/// `vprdb-test-db`) numbers its frames: 30 Hz by position.
#[test]
fn the_reference_layout_without_timestamps_replays_at_30_hz() {
    let tmp = TempDir::new("rt-vprdb");
    let sample = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../shared/data/vprdb-test-db"
    );
    let (out, took) = placedb_within(
        &realtime_args(sample, &[], &tmp.arg("out")),
        Duration::from_secs(60),
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{}{stdout}", stderr(&out));
    assert!(
        stdout.contains(
            "5 frames replayed at 30.0 frames/s (the layout's camera rate, 30 Hz: its frames \
             are numbered, not stamped)"
        ),
        "{stdout}"
    );
    assert!(took < Duration::from_secs(20), "took {took:?}");
    check_numbering(&stdout, 5);
}
