//! The command line against a board that outlives each command: `placedb
//! device --qemu` (the emulated Cortex-M4F) holds the scan between a
//! `placedb stream` and a `placedb export`, as a real board does.
//!
//! Needs `qemu-system-arm` and the QEMU firmware (built first, as in
//! host/tests/board_qemu.rs, unless `PLACEDB_QEMU_FIRMWARE` names one).

mod cli_common;

use cli_common::{placedb, seven_scenes_copy, stderr, TempDir};
use std::io::{BufRead, BufReader};
use std::net::TcpStream;
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::{Duration, Instant};

/// `placedb device --qemu` on a free port, stopped (with QEMU) on drop.
struct Board {
    child: Child,
    /// Kept open: placedb prints to it while it runs.
    _stdout: BufReader<ChildStdout>,
    port: String,
}

impl Board {
    fn start() -> Board {
        let firmware = placedb_host::testing::qemu_firmware();
        let mut child = Command::new(env!("CARGO_BIN_EXE_placedb"))
            .args(["device", "--qemu", "--port", "0", "--firmware"])
            .arg(firmware)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .spawn()
            .expect("start placedb device");
        let mut stdout = BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        stdout.read_line(&mut line).unwrap();
        let port = line
            .split_whitespace()
            .find(|w| w.starts_with("tcp:"))
            .unwrap_or_else(|| panic!("no port in {line:?}"))
            .to_string();
        // QEMU listens a moment after placedb names the port.
        let addr = port.trim_start_matches("tcp:").to_string();
        let end = Instant::now() + Duration::from_secs(30);
        while TcpStream::connect(&addr).is_err() {
            assert!(Instant::now() < end, "the board never listened on {addr}");
            std::thread::sleep(Duration::from_millis(50));
        }
        Board {
            child,
            _stdout: stdout,
            port,
        }
    }
}

impl Drop for Board {
    fn drop(&mut self) {
        // SIGKILL: the kernel kills QEMU after placedb (PR_SET_PDEATHSIG).
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A scan whose frames are all still undecided (streamed without Finish,
/// fewer frames than the window) has no label to make a dataset of:
/// `export --dataset` says so and what to do, and writes neither the
/// export nor the dataset (all or nothing); the export alone is written.
#[test]
fn export_dataset_of_a_scan_that_labelled_no_frame_is_refused_and_writes_nothing() {
    let tmp = TempDir::new("unlabelled");
    let dir = tmp.path().join("seq");
    seven_scenes_copy(&dir, 3, true);
    let seq = tmp.arg("seq");
    let board = Board::start();
    let run = placedb(&[
        "stream",
        &seq,
        "--port",
        &board.port,
        "--stride",
        "8",
        "--no-finish",
        "-q",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    let (out, ds) = (tmp.arg("out"), tmp.arg("ds"));
    let run = placedb(&[
        "export",
        "--port",
        &board.port,
        "-q",
        "-o",
        &out,
        "--dataset",
        &ds,
        "--sequence",
        &seq,
    ]);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(1), "{err}");
    for want in [
        "has no labelled frame",
        "no dataset written",
        "--resume",
        "without --dataset",
    ] {
        assert!(err.contains(want), "{want:?} not in: {err}");
    }
    assert!(!tmp.path().join("out").exists() && !tmp.path().join("ds").exists());
    // Without --dataset the export is written: the scan's state as it is.
    let run = placedb(&["export", "--port", &board.port, "-q", "-o", &out]);
    assert!(run.status.success(), "{}", stderr(&run));
    let labels = std::fs::read_to_string(tmp.path().join("out/labels.csv")).unwrap();
    assert_eq!(labels.lines().count(), 1, "header only: {labels}");
    // What the refusal advises: the scan finished, the dataset is written,
    // every frame of it labelled.
    let run = placedb(&[
        "stream",
        &seq,
        "--port",
        &board.port,
        "--stride",
        "8",
        "--resume",
        "-q",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    let run = placedb(&[
        "export",
        "--port",
        &board.port,
        "-q",
        "-o",
        &out,
        "--dataset",
        &ds,
        "--sequence",
        &seq,
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    let classes = std::fs::read_to_string(tmp.path().join("ds/classes.csv")).unwrap();
    assert_eq!(classes.lines().count(), 1 + 3, "{classes}");
}

/// `export --sequence` uses the scan's own settings, read from the
/// device's log: a `--mu` that contradicts the scan's is refused naming
/// both values before anything is written, and without `--mu` the pairs
/// are those of the scan's mu (the same as with it given).
#[test]
fn export_uses_the_scans_own_mu_and_refuses_another() {
    let tmp = TempDir::new("scan-mu");
    let dir = tmp.path().join("seq");
    seven_scenes_copy(&dir, 30, true);
    let seq = tmp.arg("seq");
    let board = Board::start();
    let run = placedb(&[
        "stream",
        &seq,
        "--port",
        &board.port,
        "--stride",
        "8",
        "--mu",
        "0.4",
        "-q",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    let export = |out: &str, pairs: &str, mu: Option<&str>| {
        let mut args = vec![
            "export",
            "--port",
            &board.port,
            "-q",
            "-o",
            out,
            "--sequence",
            &seq,
            "--pairs",
            pairs,
        ];
        if let Some(mu) = mu {
            args.extend(["--mu", mu]);
        }
        placedb(&args)
    };
    let (out, pairs) = (tmp.arg("out"), tmp.arg("pairs.txt"));
    let run = export(&out, &pairs, Some("0.3"));
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(1), "{err}");
    assert!(
        err.contains("--mu 0.3 does not match the device's scan, made with mu 0.4"),
        "{err}"
    );
    assert!(!tmp.path().join("out").exists() && !tmp.path().join("pairs.txt").exists());
    let run = export(&out, &pairs, None);
    assert!(run.status.success(), "{}", stderr(&run));
    let by_default = std::fs::read_to_string(&pairs).unwrap();
    let metrics = std::fs::read_to_string(tmp.path().join("out/metrics.json")).unwrap();
    assert!(metrics.contains("\"mu\": 0.4"), "{metrics}");
    let (out2, pairs2) = (tmp.arg("out2"), tmp.arg("pairs2.txt"));
    let run = export(&out2, &pairs2, Some("0.4"));
    assert!(run.status.success(), "{}", stderr(&run));
    assert_eq!(std::fs::read_to_string(&pairs2).unwrap(), by_default);
}

/// `export --sequence SEQ --pairs` names the frames by their colour files
/// relative to SEQ, as `select` does: each pairs name is a file under SEQ,
/// the query a frame the device did not keep, the database one it kept.
#[test]
fn export_pairs_name_the_sequences_colour_files() {
    let tmp = TempDir::new("export-pairs-colour");
    let dir = tmp.path().join("seq");
    let frames = 20;
    seven_scenes_copy(&dir, frames, true);
    for i in 0..frames {
        let name = format!("frame-{i:06}.color.jpg");
        std::fs::copy(
            std::path::Path::new(cli_common::SEVEN_SCENES).join(&name),
            dir.join(&name),
        )
        .unwrap();
    }
    let seq = tmp.arg("seq");
    let board = Board::start();
    // Stride 8 keeps the emulated board's scan short.
    let run = placedb(&["stream", &seq, "--port", &board.port, "--stride", "8", "-q"]);
    assert!(run.status.success(), "{}", stderr(&run));
    let (out, pairs) = (tmp.arg("out"), tmp.arg("pairs.txt"));
    let run = placedb(&[
        "export",
        "--port",
        &board.port,
        "-q",
        "-o",
        &out,
        "--sequence",
        &seq,
        "--pairs",
        &pairs,
    ]);
    let err = stderr(&run);
    assert!(run.status.success(), "{err}");
    assert!(!err.contains("--pairs"), "a note about the names: {err}");
    let labels: Vec<usize> = std::fs::read_to_string(tmp.path().join("out/labels.csv"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(2).unwrap().parse().unwrap())
        .collect();
    let text = std::fs::read_to_string(&pairs).unwrap();
    assert!(text.lines().count() > 0, "no pairs");
    for line in text.lines() {
        let names: Vec<&str> = line.split_whitespace().collect();
        assert_eq!(names.len(), 2, "{line:?}");
        let index = |name: &str| -> usize {
            assert!(dir.join(name).is_file(), "{name}: no file under {seq}");
            let n = name
                .strip_prefix("frame-")
                .and_then(|r| r.strip_suffix(".color.jpg"));
            n.unwrap_or_else(|| panic!("{name}")).parse().unwrap()
        };
        let (q, d) = (index(names[0]), index(names[1]));
        assert!(labels[q] != q, "{line}: query {q} is a database frame");
        assert!(labels[d] == d, "{line}: {d} is no database frame");
    }
}
