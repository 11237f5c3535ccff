//! The command line against a board that outlives each command: `placedb
//! device --qemu` (the emulated Cortex-M4F) holds the scan between a
//! `placedb stream` and a `placedb export`, as a real board does; a stream
//! stopped by Ctrl-C, or killed outright mid-frame, goes on with
//! `--resume`, on the QEMU board and on the emulated Pico (`placedb device
//! --rp2040`).
//!
//! Needs `qemu-system-arm` and the QEMU firmware (built first, as in
//! host/tests/board_qemu.rs, unless `PLACEDB_QEMU_FIRMWARE` names one); the
//! Pico's cases what host/tests/board_rp2040.rs needs (Node 20, `npm ci` in
//! boards/rp-pico/emulator, the boot ROM).

mod cli_common;

use cli_common::device::{exported, host_replay, Device};
use cli_common::{placedb, seven_scenes_copy, stderr, TempDir};
use placedb::protocol::Phase;
use placedb_host::board::client;
use std::process::{Child, Command, Output, Stdio};
use std::time::Duration;

/// `placedb device --qemu` (or `--rp2040`) on a free port ([`Device`]),
/// stopped (with its emulator) on drop, and its port.
struct Board {
    _device: Device,
    port: String,
}

impl Board {
    fn start() -> Board {
        Board::on("--qemu", &[])
    }

    /// A board whose flash is the file `flash` (kept across restarts).
    fn start_on(flash: &std::path::Path) -> Board {
        Board::on("--qemu", &["--flash", flash.to_str().unwrap()])
    }

    /// `placedb device BOARD ARGS`.
    fn on(board: &str, args: &[&str]) -> Board {
        let device = Device::start(board, args);
        let port = device.port();
        Board {
            _device: device,
            port,
        }
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
    // Nor beside them: a refusal keeps no records for --from.
    let left: Vec<_> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .filter(|name| name != "seq")
        .collect();
    assert!(left.is_empty(), "a refused export left {left:?}");
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

/// `export --sequence SEQ` measures the device's scan on SEQ as the scan
/// saw it (its stride, depth range, voxel size and mu, from the device's
/// log): the coverage metrics of `metrics.json` are those `select --solver
/// online` with the same settings writes, and so are its `--pairs`, at a
/// stride other than 1. Without `--sequence` they are `null`, with the
/// reason.
#[test]
fn export_with_the_sequence_measures_the_scan_as_select_does() {
    let tmp = TempDir::new("measured");
    let dir = tmp.path().join("seq");
    seven_scenes_copy(&dir, 30, true);
    let seq = tmp.arg("seq");
    let board = Board::start();
    let same = [
        "--stride",
        "8",
        "--mu",
        "0.4",
        "--voxel",
        "0.2",
        "--depth-range",
        "0.2,3.5",
        "--window",
        "8",
        "-q",
    ];
    let mut stream = vec!["stream", &seq, "--port", &board.port];
    stream.extend(same);
    let run = placedb(&stream);
    assert!(run.status.success(), "{}", stderr(&run));
    let (host, pairs_host) = (tmp.arg("host"), tmp.arg("host-pairs.txt"));
    let mut select = vec!["select", &seq, "--solver", "online", "--profile", "ram512k"];
    select.extend(same);
    select.extend(["-o", &host, "--pairs", &pairs_host]);
    let run = placedb(&select);
    assert!(run.status.success(), "{}", stderr(&run));
    let (device, pairs_device) = (tmp.arg("device"), tmp.arg("device-pairs.txt"));
    let run = placedb(&[
        "export",
        "--port",
        &board.port,
        "-q",
        "-o",
        &device,
        "--sequence",
        &seq,
        "--pairs",
        &pairs_device,
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    let read = |p: &str| std::fs::read_to_string(p).unwrap();
    let json = |d: &str| -> serde_json::Value {
        serde_json::from_str(&read(&format!("{d}/metrics.json"))).unwrap()
    };
    assert_eq!(
        read(&format!("{device}/database.csv")),
        read(&format!("{host}/database.csv"))
    );
    let (h, d) = (json(&host), json(&device));
    for k in [
        "uncovered",
        "spatial_coverage",
        "frames_coverage_mean",
        "frames_coverage_min",
        "frames_coverage_below_0_3",
        "labels_below_mu",
        "label_iou_min",
        "co_observing_pairs",
        "sequence",
        "format",
        "frames_skipped",
        "empty_frames",
        "stride",
        "depth_min",
        "depth_max",
    ] {
        assert!(!d[k].is_null(), "{k} not measured: {d}");
        assert_eq!(d[k], h[k], "{k}");
    }
    let pairs = read(&pairs_device);
    assert!(!pairs.is_empty());
    assert_eq!(pairs, read(&pairs_host), "the pairs at stride 8");
    // Without the sequence: null, and why.
    let bare = tmp.arg("bare");
    let run = placedb(&["export", "--port", &board.port, "-q", "-o", &bare]);
    assert!(run.status.success(), "{}", stderr(&run));
    let b = json(&bare);
    assert!(b["uncovered"].is_null(), "{b}");
    let why = b["not_measured"].as_str().unwrap_or_default();
    assert!(why.contains("export --sequence SEQ computes them"), "{why}");
}

/// A scan resumed after the board restarted is reported as a resume, how
/// often and where (`resumes`, `resumed_at` of `metrics.json`, read from
/// the finished scan's log), not as a degradation.
#[test]
fn a_resumed_scan_reports_its_resume_not_a_degradation() {
    let tmp = TempDir::new("resumed");
    let dir = tmp.path().join("seq");
    seven_scenes_copy(&dir, 40, true);
    let seq = tmp.arg("seq");
    let flash = tmp.path().join("flash.bin");
    let stream = |port: &str, more: &[&str]| {
        // A short window: decisions (durable in batches of 16) before the cut.
        let mut args = vec![
            "stream", &seq, "--port", port, "--stride", "8", "--window", "4", "-q",
        ];
        args.extend(more);
        placedb(&args)
    };
    let seen = {
        let board = Board::start_on(&flash);
        let run = stream(&board.port, &["--max-frames", "30", "--no-finish"]);
        assert!(run.status.success(), "{}", stderr(&run));
        30
    };
    // The board restarts (its flash kept); the scan is resumed to its end.
    let board = Board::start_on(&flash);
    let out = tmp.arg("out");
    let run = stream(&board.port, &["--resume", "-o", &out]);
    assert!(run.status.success(), "{}", stderr(&run));
    let text = std::fs::read_to_string(tmp.path().join("out/metrics.json")).unwrap();
    let m: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(m["restored_from_flash"], true, "{m}");
    assert_eq!(m["degradation_flags"], 0, "{m}");
    assert_eq!(m["resumes"], 1, "{m}");
    // What the board counted in RAM before its restart is lost: unknown,
    // not 0, and said so.
    for k in placedb_host::output::metrics_json::RAM_COUNTERS {
        assert!(m[k].is_null(), "{k}: {m}");
    }
    let why = m["not_measured"].as_str().unwrap_or_default();
    assert!(
        why.contains("kept in RAM and count only the frames since"),
        "{why}"
    );
    assert!(
        stderr(&run).contains("reports those counters as null"),
        "{}",
        stderr(&run)
    );
    let at = m["resumed_at"][0].as_u64().unwrap();
    // Where the device's durable decisions ended: at most the frames sent.
    assert!(at > 0 && at <= seen, "{m}");
}

/// A plain `stream` to a board holding a scan is refused naming it and
/// changes nothing; `--new-scan` replaces it; `--resume` after the export
/// has nothing to go on with but finishes as it was.
#[test]
fn a_board_holding_a_scan_refuses_a_new_one_until_new_scan() {
    let tmp = TempDir::new("held");
    let dir = tmp.path().join("seq");
    seven_scenes_copy(&dir, 20, true);
    let seq = tmp.arg("seq");
    let board = Board::start();
    let stream = |more: &[&str]| {
        let mut args = vec!["stream", &seq, "--port", &board.port, "--stride", "8", "-q"];
        args.extend(more);
        placedb(&args)
    };
    let run = stream(&[]);
    assert!(run.status.success(), "{}", stderr(&run));
    let export = |out: &str| {
        let run = placedb(&["export", "--port", &board.port, "-q", "-o", out]);
        assert!(run.status.success(), "{}", stderr(&run));
        std::fs::read_to_string(format!("{out}/labels.csv")).unwrap()
    };
    let before = export(&tmp.arg("before"));
    let run = stream(&[]);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(1), "{err}");
    assert!(
        err.contains("the board holds a finished scan of 20 frames (20 decided)")
            && err.contains("or replace it with --new-scan"),
        "{err}"
    );
    assert_eq!(
        export(&tmp.arg("after")),
        before,
        "the refusal changed the board"
    );
    let run = stream(&["--new-scan", "--max-frames", "5"]);
    assert!(run.status.success(), "{}", stderr(&run));
    let replaced = export(&tmp.arg("replaced"));
    assert_eq!(replaced.lines().count(), 1 + 5, "{replaced}");
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
    seven_scenes_colour(&dir, 0..frames);
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

/// `placedb stream SEQ --port P ARGS` started, not waited for.
fn stream_child(args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_placedb"))
        .arg("stream")
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// `signal` to `child` once it has streamed a while (`after`), and how it
/// ended.
fn signalled_after(child: Child, after: Duration, signal: libc::c_int) -> Output {
    std::thread::sleep(after);
    let pid = libc::pid_t::try_from(child.id()).unwrap();
    // SAFETY: kill(2) on our own child, not reaped yet.
    assert_eq!(unsafe { libc::kill(pid, signal) }, 0);
    child.wait_with_output().unwrap()
}

/// The phase of the board on `port`, asked as another program would.
fn phase(port: &str) -> Phase {
    let mut program = client::connect(port).unwrap();
    // What a killed program left of a message is dropped first.
    program.resync().unwrap();
    client::status(&mut program, Duration::from_secs(60))
        .unwrap()
        .phase
}

/// Ctrl-C during `stream` to `board` (`frames` frames of 7-Scenes at
/// stride 8, the signal `after` that long) stops it between frames with
/// status 130 and a word on how to go on; the board has no frame open, and
/// `--resume` goes on to the whole scan.
fn ctrl_c_stops_a_stream_cleanly(board: &str, profile: &str, frames: usize, after: Duration) {
    let tmp = TempDir::new("ctrl-c");
    let dir = tmp.path().join("seq");
    seven_scenes_copy(&dir, frames, true);
    let seq = tmp.arg("seq");
    let board = Board::on(board, &[]);
    let args = [
        &seq,
        "--port",
        &board.port,
        "--profile",
        profile,
        "--stride",
        "8",
        "-q",
    ];
    let run = signalled_after(stream_child(&args), after, libc::SIGINT);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(130), "{err}");
    assert!(
        err.contains("stopped by Ctrl-C before frame")
            && err.contains("none is left open")
            && err.contains("--resume"),
        "{err}"
    );
    assert_eq!(phase(&board.port), Phase::Ready, "a frame was left open");
    let mut resume = vec!["stream"];
    resume.extend_from_slice(&args);
    resume.push("--resume");
    let run = placedb(&resume);
    assert!(run.status.success(), "{}", stderr(&run));
    let (_, labels) = exported(&board.port, &tmp.arg("out"));
    assert_eq!(labels.lines().count(), 1 + frames, "{labels}");
}

/// On the QEMU board, which takes a few frames a second: some are sent by
/// 4 s.
#[test]
fn ctrl_c_stops_a_stream_cleanly_and_resume_goes_on() {
    ctrl_c_stops_a_stream_cleanly("--qemu", "ram512k", 40, Duration::from_secs(4));
}

/// On the emulated Pico, which takes about 13 of these frames a second.
#[test]
fn ctrl_c_stops_a_stream_to_the_emulated_pico_cleanly_and_resume_goes_on() {
    ctrl_c_stops_a_stream_cleanly("--rp2040", "ram256k", 200, Duration::from_secs(3));
}

/// A `stream` to `board` killed outright (SIGKILL, `after` it started)
/// leaves the board with a frame open (it is killed again, resumed, until
/// it does: a kill may fall between two frames); `stream --resume` drops
/// that frame (FrameAbort), sends it again and goes on: the export is the
/// host replay's, `placedb select --solver online` on the same sequence.
fn a_stream_killed_mid_frame_is_resumed(
    board: &str,
    profile: &str,
    frames: usize,
    after: Duration,
) {
    let tmp = TempDir::new("killed");
    let dir = tmp.path().join("seq");
    seven_scenes_copy(&dir, frames, true);
    let seq = tmp.arg("seq");
    let board = Board::on(board, &[]);
    let args = [
        &seq,
        "--port",
        &board.port,
        "--profile",
        profile,
        "--stride",
        "8",
        "-q",
    ];
    let mut resume = args.to_vec();
    resume.push("--resume");
    let mut kills = 0;
    loop {
        let run = signalled_after(
            stream_child(if kills == 0 { &args } else { &resume }),
            after,
            libc::SIGKILL,
        );
        assert_eq!(run.status.code(), None, "{}", stderr(&run));
        kills += 1;
        if phase(&board.port) == Phase::InFrame {
            break;
        }
        assert!(kills < 5, "{kills} kills left no frame open");
    }
    let mut again = vec!["stream"];
    again.extend_from_slice(&resume);
    let run = placedb(&again);
    assert!(run.status.success(), "{}", stderr(&run));
    let got = exported(&board.port, &tmp.arg("out"));
    assert!(
        got == host_replay(&seq, profile, &tmp.arg("host")),
        "the resumed scan differs from the host replay"
    );
    println!("{kills} kills, the last mid-frame: resumed to the host replay's export");
}

#[test]
fn a_stream_killed_mid_frame_is_resumed_on_the_qemu_board() {
    a_stream_killed_mid_frame_is_resumed("--qemu", "ram512k", 100, Duration::from_secs(4));
}

#[test]
fn a_stream_killed_mid_frame_is_resumed_on_the_emulated_pico() {
    a_stream_killed_mid_frame_is_resumed("--rp2040", "ram256k", 300, Duration::from_secs(3));
}

/// One program at a time (issue 41): while a program has the board's port
/// open, `placedb export` on it is refused at once in words and writes
/// nothing, and the first program goes on untouched; once it has closed
/// the port, the next one is served.
#[test]
fn a_second_program_on_the_boards_port_is_refused_and_the_first_goes_on() {
    use placedb_host::board::client::{self, Client};
    use placedb_host::board::link::TcpLink;
    let tmp = TempDir::new("second-program");
    let board = Board::start();
    let addr = board.port.trim_start_matches("tcp:").to_string();
    let reply = Duration::from_secs(30);
    let mut first = Client::new(TcpLink::connect(addr.as_str(), reply).unwrap());
    let before = client::status(&mut first, reply).unwrap();

    let out = tmp.arg("second");
    let run = placedb(&["export", "--port", &board.port, "-q", "-o", &out]);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(1), "{err}");
    assert!(err.contains("serves one connection at a time"), "{err}");
    assert!(
        !std::path::Path::new(&out).exists(),
        "the refused export wrote {out}"
    );

    let after = client::status(&mut first, reply).unwrap();
    assert_eq!(after.phase, before.phase);
    drop(first);
    std::thread::sleep(Duration::from_millis(100));
    // The next program is served: this board holds no scan yet, and the
    // refusal says so without the hint that only fits a local: device.
    let run = placedb(&["export", "--port", &board.port, "-q", "-o", &out]);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(1), "{err}");
    assert!(
        err.contains("the device holds no scan") && !err.contains("local:PROFILE"),
        "{err}"
    );
    let run = placedb(&[
        "stream",
        "--port",
        &board.port,
        "--demo",
        "--stride",
        "8",
        "--max-frames",
        "4",
        "-q",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
}

/// The rows of a CSV file after its header, split at commas.
fn csv_rows(path: &std::path::Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.lines()
        .skip(1)
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect()
}

/// Column `c` of `rows` as frame numbers.
fn numbers(rows: &[Vec<String>], c: usize) -> Vec<usize> {
    rows.iter().map(|r| r[c].parse().unwrap()).collect()
}

/// `stream --realtime -o` to a board busy for most frames (one due every
/// 10 ms; the emulated board takes far longer over one) numbers its tables
/// by the sequence, as `skipped.csv` does: `labels.csv` has a row for each
/// frame the board received, by its index in the sequence (a skipped frame
/// has none), and `database.csv` and the classes name those frames (the
/// board's own numbers were written: labels.csv's second row was sequence
/// frame 45). `export --sequence SEQ` then takes that very sequence (it
/// compared the board's frames with SEQ's first ones and refused it),
/// writes the same tables, and its dataset, COLMAP model, VPR-evaluation
/// layout and pairs name the frames alike; a sequence missing a frame the
/// board received is refused, naming it.
#[test]
fn a_realtime_scan_is_numbered_by_the_sequence_and_export_sequence_takes_it() {
    let tmp = TempDir::new("realtime-numbers");
    let board = Board::start();
    let (out, frames) = (tmp.arg("out"), 300);
    let run = placedb(&[
        "stream",
        cli_common::SEVEN_SCENES,
        "--max-frames",
        &frames.to_string(),
        "--realtime",
        "--rate",
        "100",
        "--port",
        &board.port,
        "--stride",
        "8",
        "--window",
        "8",
        "-o",
        &out,
    ]);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{}{stdout}", stderr(&run));
    let dir = tmp.path().join("out");
    let skipped = numbers(&csv_rows(&dir.join("skipped.csv")), 0);
    let sent: Vec<usize> = (0..frames).filter(|i| !skipped.contains(i)).collect();
    // Two sent frames with a skipped one before the second: else the
    // device's numbers are the sequence's and this proves nothing.
    assert!(
        sent.len() >= 2 && sent[1] > 1,
        "the board skipped no frame between two it received (sent {sent:?}): {stdout}"
    );
    let labels = csv_rows(&dir.join("labels.csv"));
    assert_eq!(numbers(&labels, 0), sent, "labels.csv's frames");
    for row in &labels {
        // 7-Scenes stamps a frame with its number: the row is that frame.
        assert_eq!(row[1], format!("{}.000000", row[0]), "{row:?}");
    }
    let database = numbers(&csv_rows(&dir.join("database.csv")), 0);
    assert!(!database.is_empty());
    for (&i, &class) in numbers(&labels, 0).iter().zip(&numbers(&labels, 2)) {
        assert!(database.contains(&class), "frame {i}'s class {class}");
        assert_eq!(database.contains(&i), class == i, "frame {i}");
    }

    // The whole sequence (1,000 frames): the board's are among them.
    let (out2, ds, colmap, vpr, pairs) = (
        tmp.arg("out2"),
        tmp.arg("ds"),
        tmp.arg("colmap"),
        tmp.arg("vpr"),
        tmp.arg("pairs.txt"),
    );
    let run = placedb(&[
        "export",
        "--port",
        &board.port,
        "-q",
        "-o",
        &out2,
        "--sequence",
        cli_common::SEVEN_SCENES,
        "--dataset",
        &ds,
        "--colmap",
        &colmap,
        "--vpr-eval",
        &vpr,
        "--pairs",
        &pairs,
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    for table in ["database.csv", "labels.csv"] {
        assert_eq!(
            std::fs::read_to_string(tmp.path().join("out2").join(table)).unwrap(),
            std::fs::read_to_string(dir.join(table)).unwrap(),
            "{table} of export --sequence and of stream --realtime -o"
        );
    }
    let classes = csv_rows(&tmp.path().join("ds/classes.csv"));
    assert_eq!(numbers(&classes, 1), sent, "the dataset's frames");
    for row in &classes {
        let depth = tmp.path().join("ds/depth").join(format!("{}.png", row[0]));
        assert_eq!(row[0], format!("{:06}", row[1].parse::<usize>().unwrap()));
        assert!(depth.is_file(), "{}", depth.display());
    }
    assert_eq!(
        numbers(&classes, 3),
        numbers(&labels, 2),
        "the dataset's classes"
    );
    let images: Vec<String> = cli_common::names(&tmp.path().join("colmap/images"));
    let want: Vec<String> = database.iter().map(|i| format!("{i:06}.jpg")).collect();
    assert_eq!(images, want, "the COLMAP model's images");
    // VPR-methods-evaluation's names: @east@north@NNNNNN@.jpg.
    let vpr_frames = |folder: &str| -> Vec<usize> {
        let mut v: Vec<usize> = cli_common::names(&tmp.path().join("vpr").join(folder))
            .iter()
            .map(|n| n.split('@').nth(3).unwrap().parse().unwrap())
            .collect();
        v.sort_unstable();
        v
    };
    assert_eq!(vpr_frames("database"), database, "VPR database images");
    let queries: Vec<usize> = sent
        .iter()
        .copied()
        .filter(|i| !database.contains(i))
        .collect();
    assert_eq!(vpr_frames("queries"), queries, "VPR query images");
    let text = std::fs::read_to_string(&pairs).unwrap();
    assert!(text.lines().count() > 0, "no pairs");
    for line in text.lines() {
        let frame = |name: &str| -> usize {
            let n = name
                .strip_prefix("frame-")
                .and_then(|r| r.strip_suffix(".color.jpg"));
            n.unwrap_or_else(|| panic!("{line}")).parse().unwrap()
        };
        let names: Vec<&str> = line.split_whitespace().collect();
        let (q, d) = (frame(names[0]), frame(names[1]));
        assert!(
            sent.contains(&q) && !database.contains(&q),
            "{line}: query {q}"
        );
        assert!(database.contains(&d), "{line}: {d} is no database frame");
    }

    // Without the second frame the board received, the sequence is not
    // the one streamed: refused, naming that frame, writing nothing.
    let short = tmp.path().join("short");
    seven_scenes_copy(&short, sent[1] + sent.len() + 1, true);
    for kind in ["depth.png", "pose.txt"] {
        std::fs::remove_file(short.join(format!("frame-{:06}.{kind}", sent[1]))).unwrap();
    }
    let out3 = tmp.arg("out3");
    let run = placedb(&[
        "export",
        "--port",
        &board.port,
        "-q",
        "-o",
        &out3,
        "--sequence",
        &tmp.arg("short"),
    ]);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(1), "{err}");
    let want = format!(
        "the device's frame 1 has timestamp {}, which no frame of the sequence has after frame 0",
        sent[1]
    );
    assert!(err.contains(&want), "{want:?} not in: {err}");
    assert!(!tmp.path().join("out3").exists());
}

/// Copies the colour images of the sample's frames `frames` into `dir`
/// (beside the depth and poses of [`seven_scenes_copy`]).
fn seven_scenes_colour(dir: &std::path::Path, frames: impl IntoIterator<Item = usize>) {
    for i in frames {
        let name = format!("frame-{i:06}.color.jpg");
        std::fs::copy(
            std::path::Path::new(cli_common::SEVEN_SCENES).join(&name),
            dir.join(&name),
        )
        .unwrap();
    }
}

/// The device path beside the host path for every export flag, on a part
/// of a sequence: a board that scanned the first 16 of its 24 frames
/// (every tenth frame of the sample, so that places differ),
/// exported with `--sequence` naming all 24 (the streamed frames are its
/// first), writes byte for byte what `select --solver online --max-frames
/// 16` with the same settings writes: `database.csv`, `labels.csv`, the
/// dataset (`--dataset`), the COLMAP model, the VPR-evaluation layout
/// (its queries the non-database frames, and with `--test` a test
/// sequence's frames) and the pairs. The same export again onto the same
/// targets replaces them with the same bytes.
#[test]
fn every_export_of_a_part_of_the_sequence_is_selects() {
    let tmp = TempDir::new("every-export");
    let (dir, test_dir) = (tmp.path().join("seq"), tmp.path().join("test"));
    let (frames, streamed) = ((0..240).step_by(10), 16);
    cli_common::seven_scenes_frames(&dir, frames.clone(), true);
    seven_scenes_colour(&dir, frames);
    seven_scenes_copy(&test_dir, 6, true);
    seven_scenes_colour(&test_dir, 0..6);
    let (seq, test) = (tmp.arg("seq"), tmp.arg("test"));
    let board = Board::start();
    // 6 database frames of 16; stride 16 keeps the emulated UART's share
    // short.
    let same = [
        "--stride", "16", "--mu", "0.7", "--voxel", "0.2", "--window", "8", "-q",
    ];
    let n = streamed.to_string();
    let mut args = vec!["stream", &seq, "--port", &board.port, "--max-frames", &n];
    args.extend(same);
    let run = placedb(&args);
    assert!(run.status.success(), "{}", stderr(&run));
    // Each side's outputs: the database directory, then one per flag.
    let outputs = |side: &str, with_test: bool| -> Vec<String> {
        let t = if with_test { "-test" } else { "" };
        ["out", "ds", "colmap", "vpr", "pairs.txt"]
            .iter()
            .map(|o| tmp.arg(&format!("{side}{t}-{o}")))
            .collect()
    };
    let flags = |o: &[String], with_test: bool| -> Vec<String> {
        let mut v: Vec<String> = ["-o", "--dataset", "--colmap", "--vpr-eval", "--pairs"]
            .iter()
            .zip(o)
            .flat_map(|(f, p)| [f.to_string(), p.clone()])
            .collect();
        if with_test {
            v.extend(["--test".to_string(), test.clone()]);
        }
        v
    };
    let read = |p: &str| -> cli_common::Tree {
        let path = std::path::Path::new(p);
        if path.is_dir() {
            cli_common::tree(path)
        } else {
            std::iter::once((String::new(), std::fs::read(path).unwrap())).collect()
        }
    };
    for with_test in [false, true] {
        let host = outputs("host", with_test);
        let mut args: Vec<String> = ["select", &seq, "--solver", "online", "--max-frames", &n]
            .iter()
            .chain(&same)
            .map(|s| s.to_string())
            .collect();
        args.extend(flags(&host, with_test));
        let run = placedb(&args);
        assert!(run.status.success(), "{}", stderr(&run));
        let device = outputs("device", with_test);
        let mut args: Vec<String> = ["export", "--port", &board.port, "-q", "--sequence", &seq]
            .iter()
            .map(|s| s.to_string())
            .collect();
        args.extend(flags(&device, with_test));
        let mut previous = None;
        // The same export twice: the second replaces the first's outputs.
        for _ in 0..2 {
            let run = placedb(&args);
            assert!(run.status.success(), "{}", stderr(&run));
            let now: Vec<cli_common::Tree> = device[1..].iter().map(|d| read(d)).collect();
            if let Some(before) = previous.replace(now.clone()) {
                assert!(before == now, "the same export again wrote other bytes");
            }
        }
        for table in ["database.csv", "labels.csv"] {
            let read = |d: &str| std::fs::read_to_string(format!("{d}/{table}")).unwrap();
            assert_eq!(read(&device[0]), read(&host[0]), "{table}");
        }
        let db = std::fs::read_to_string(format!("{}/database.csv", host[0])).unwrap();
        assert!(
            db.lines().count() > 2,
            "one database frame proves little: {db}"
        );
        for (d, h) in device[1..].iter().zip(&host[1..]) {
            let (dt, ht) = (read(d), read(h));
            assert!(!ht.is_empty() && ht.values().all(|b| !b.is_empty()), "{h}");
            let differ: Vec<&String> = ht
                .keys()
                .chain(dt.keys())
                .filter(|k| dt.get(*k) != ht.get(*k))
                .collect();
            assert!(
                differ.is_empty(),
                "{d} differs from select's {h} (with --test: {with_test}): {differ:?}"
            );
        }
    }
}

/// The same place twice on a board: `stream SEQ --extend` of the very
/// sequence the board's finished scan came from adds no database frame,
/// nor does a later session of a part of it; after each session the
/// board's tables are those of `select --extend --solver online`, and the
/// later sessions' frames are all covered by first-session frames. Then
/// `export --sequence` of that scan of three sessions is refused in words,
/// writing nothing, as `select --extend` refuses the exports (it said "the
/// device scanned 39 frames, the sequence has 16: not the streamed
/// sequence?").
#[test]
fn the_same_place_streamed_again_adds_no_database_frame_on_the_board() {
    let tmp = TempDir::new("again");
    // Every tenth frame: places apart, so that some frames are covered.
    let (dir, part_dir) = (tmp.path().join("seq"), tmp.path().join("part"));
    cli_common::seven_scenes_frames(&dir, (0..160).step_by(10), true);
    cli_common::seven_scenes_frames(&part_dir, (30..100).step_by(10), true);
    let (seq, part) = (tmp.arg("seq"), tmp.arg("part"));
    let board = Board::start();
    // 10 database frames of 16 at mu 0.8; stride 16 keeps the emulated
    // UART's share short.
    let same = [
        "--stride", "16", "--mu", "0.8", "--voxel", "0.3", "--window", "8", "-q",
    ];
    let mut previous: Option<String> = None;
    for (session, s) in [&seq, &seq, &part].into_iter().enumerate() {
        let host = tmp.arg(&format!("host-{session}"));
        let mut args = vec!["select", s.as_str(), "--solver", "online", "-o", &host];
        args.extend(same);
        if let Some(p) = &previous {
            args.extend(["--extend", p.as_str()]);
        }
        let run = placedb(&args);
        assert!(run.status.success(), "{}", stderr(&run));
        let mut args = vec!["stream", s.as_str(), "--port", &board.port];
        args.extend(same);
        if session > 0 {
            args.push("--extend");
        }
        let run = placedb(&args);
        assert!(run.status.success(), "{}", stderr(&run));
        let out = tmp.arg(&format!("device-{session}"));
        let (database, labels) = exported(&board.port, &out);
        let read = |f: &str| std::fs::read_to_string(format!("{host}/{f}")).unwrap();
        assert_eq!(database, read("database.csv"), "session {session}");
        assert_eq!(labels, read("labels.csv"), "session {session}");
        let rows = csv_rows(&tmp.path().join(format!("device-{session}/database.csv")));
        assert!(
            rows.len() > 2 && rows.len() < 16,
            "all or few frames taken: nothing to tell: {database}"
        );
        if session > 0 {
            // index,timestamp,tx,ty,tz,qx,qy,qz,qw,session,session_index
            let added: Vec<&Vec<String>> = rows.iter().filter(|r| r[9] != "0").collect();
            assert!(added.is_empty(), "session {session} added {added:?}");
            // index,timestamp,class_index,session,session_index,class_session
            let labels = csv_rows(&tmp.path().join(format!("device-{session}/labels.csv")));
            assert!(labels.iter().any(|r| r[3] == session.to_string()));
            for row in labels.iter().filter(|r| r[3] != "0") {
                assert_eq!(row[5], "0", "{row:?}: not covered by the first session");
            }
        }
        previous = Some(host);
    }
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
    assert_eq!(run.status.code(), Some(1), "{err}");
    assert!(
        err.contains(
            "the device's scan holds 3 sessions (stream --extend; they begin at frames 0, 16, 32)"
        ) && err.contains("does not combine with sessions yet"),
        "{err}"
    );
    assert!(!tmp.path().join("out").exists() && !tmp.path().join("pairs.txt").exists());
}
