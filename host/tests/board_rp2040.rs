//! End to end on the real board's firmware: `boards/rp-pico` (RP2040,
//! Cortex-M0+, profile ram256k, USB CDC-ACM) run instruction by instruction
//! under rp2040js (`placedb_host::board::emulator::rp2040`, the Node harness in
//! `boards/rp-pico/emulator`): boot ROM, boot2, the 2 MiB QSPI flash behind the
//! ROM's flash functions, and a USB host bridging the CDC-ACM data endpoints
//! to TCP. What the emulated Pico exports is byte-identical to the host replay
//! of the core (`placedb select --solver online --profile ram256k`); killed
//! mid-scan and restarted on the same flash file it restores every
//! acknowledged decision and `stream --resume` completes the scan; 5 % drops
//! and 5 % corruption over its USB link still give the clean export.
//!
//! Needs Node 20 and `cd boards/rp-pico/emulator && npm ci`; the firmware is
//! built first (`cd boards/rp-pico && cargo build --release`, or set
//! `PLACEDB_RP2040_FIRMWARE`). Prints the Cortex-M0+ cycles per frame and per
//! valid pixel (rp2040js counts cycles; the firmware's timer is read at
//! 125 cycles per microsecond); run with `--nocapture` to see them.

mod board_common;

use board_common::{demo, host_replay, killed_mid_scan_restores_and_resumes, Board};
use placedb::protocol::{DeviceMessage, HostMessage, Phase, Status};
use placedb::SelectorConfig;
use placedb_host::board::client::{Client, Received};
use placedb_host::board::emulator::rp2040::{check_stack, Rp2040, Rp2040Options};
use placedb_host::board::export::ExportOptions;
use placedb_host::board::flash_timing::FlashTiming;
use placedb_host::board::link::fault::{FaultConfig, FaultInjector};
use placedb_host::board::link::Link;
use placedb_host::board::scan::StreamOptions;
use placedb_host::board::scan::StreamReport;
use placedb_host::board::session::{DepthFrame, Session};
use placedb_host::board::{client, export, scan};
use placedb_host::cli::bench::pixel_cost;
use placedb_host::testing::rp2040_firmware as firmware;
use placedb_host::testing::{selector as sel, voxel_config as stride};
use placedb_host::{Sequence, VoxelConfig};
use std::path::Path;
use std::time::{Duration, Instant};

const PROFILE: &str = "ram256k";
/// rp2040js runs clk_sys at 125 MHz (8 ns a cycle) and the firmware's clock
/// is the RP2040 timer (1 MHz): cycles per timer tick.
const CYCLES_PER_TICK: f64 = 125.0;
const REPLY: Duration = Duration::from_secs(60);

fn boot(flash: Option<&Path>, deadline: Duration) -> Rp2040 {
    let options = Rp2040Options {
        flash: flash.map(Path::to_path_buf),
        deadline,
        ..Rp2040Options::default()
    };
    Rp2040::start_with(&firmware(), &options).unwrap_or_else(|e| panic!("{e}"))
}

fn seven_scenes(frames: usize) -> Sequence {
    placedb_host::testing::sample("7scenes-1000", frames)
}

fn export_csv<L: Link>(client: &mut Client<L>, opts: &ExportOptions) -> (String, String) {
    export::export(client, Vec::new(), opts, None, &mut |_| Ok(()))
        .unwrap()
        .csv()
}

fn stream<L: Link>(
    client: &mut Client<L>,
    seq: &Sequence,
    vcfg: &VoxelConfig,
    sel: SelectorConfig,
    opts: &StreamOptions,
) -> StreamReport {
    let scan = scan::scan_config(seq, vcfg).unwrap();
    let cfg = scan::device_config(&scan, &sel).unwrap();
    scan::stream(client, seq, &cfg, PROFILE, opts, None)
        .unwrap_or_else(|e| panic!("stream of {} failed: {e}", seq.name))
}

/// Cortex-M0+ cycles per frame and per valid pixel from a status.
fn cycles(st: &Status) -> (f64, f64) {
    let c = &st.cost;
    assert_eq!(c.clock_hz, 1_000_000, "the Pico's clock is its 1 MHz timer");
    let total = c.total as f64 * CYCLES_PER_TICK;
    (
        total / f64::from(c.frames.max(1)),
        total / (st.valid_pixels.max(1) as f64),
    )
}

/// Streams `seq`, exports, checks both files against the host replay.
fn stream_and_compare(
    client: &mut Client<Rp2040>,
    seq: &Sequence,
    vcfg: &VoxelConfig,
    sel: SelectorConfig,
) -> StreamReport {
    let report = stream(client, seq, vcfg, sel, &StreamOptions::replacing());
    assert_eq!(report.status.phase, Phase::Finished);
    assert_eq!(report.status.frames_seen as usize, seq.frames.len());
    assert!(report.decisions.iter().all(Option::is_some));
    let (db, labels) = export_csv(client, &ExportOptions::default());
    let (want_db, want_labels) = host_replay(PROFILE, seq, vcfg, sel);
    assert_eq!(db, want_db, "database.csv differs on {}", seq.name);
    assert_eq!(labels, want_labels, "labels.csv differs on {}", seq.name);
    let (per_frame, per_pixel) = cycles(&report.status);
    println!(
        "{} at stride {}: {} frames -> {} database frames, identical to the host replay; \
         {:.0} Cortex-M0+ cycles per frame, {:.0} per valid pixel ({} valid pixels); \
         {:.1} frames/s of wall time through the emulator",
        seq.name,
        vcfg.stride,
        report.frames,
        report.status.database_size,
        per_frame,
        per_pixel,
        report.status.valid_pixels,
        report.fps(),
    );
    report
}

#[test]
fn the_emulated_pico_matches_the_host_replay() {
    let started = Instant::now();
    let mut client = Client::new(boot(None, Duration::from_secs(600)));
    let real = seven_scenes(1000);
    stream_and_compare(&mut client, &real, &stride(8), sel(16));
    let synthetic = demo(60);
    stream_and_compare(&mut client, &synthetic, &stride(8), sel(16));
    let board = client.into_link();
    let console = board.stop();
    assert!(
        !console.contains("error:"),
        "the harness reported an error: {console}"
    );
    if let Some(line) = console.lines().find(|l| l.starts_with("stats")) {
        println!("emulator {line}");
    }
    let stack = check_stack(&console).unwrap_or_else(|e| panic!("{e}"));
    println!(
        "stack: {} bytes at the deepest, of {} ({} reserved at link time)",
        stack.peak,
        stack.room,
        placedb_host::board::emulator::rp2040::stack_reserve()
    );
    println!("pico end to end: {:.1} s", started.elapsed().as_secs_f64());
}

/// The marginal cost of a valid pixel on the Cortex-M0+
/// (`placedb_host::cli::bench::pixel_cost`: the same frames at two strides; the difference
/// in cycles over the difference in valid pixels, so what a frame costs
/// besides its pixels cancels out).
#[test]
fn cortex_m0_cycles_per_valid_pixel() {
    // CPU cycles only: the flash's busy time would stop the timer's clock
    // for the CPU too, and `placedb bench --pico` adds it separately.
    let options = Rp2040Options {
        deadline: Duration::from_secs(600),
        flash_timing: FlashTiming::None,
        ..Rp2040Options::default()
    };
    let board = Rp2040::start_with(&firmware(), &options).unwrap_or_else(|e| panic!("{e}"));
    let mut client = Client::new(board);
    for (name, seq) in [("7scenes-1000", seven_scenes(3)), ("synthetic", demo(6))] {
        let cost = pixel_cost::measure(
            &mut client,
            &seq,
            &stride(1),
            sel(16),
            PROFILE,
            pixel_cost::STRIDES,
        )
        .unwrap_or_else(|e| panic!("{name}: {e}"));
        let [f, c] = [cost.fine, cost.coarse];
        let per_pixel = cost.per_pixel() * CYCLES_PER_TICK;
        let core = cost.core_per_pixel() * CYCLES_PER_TICK;
        let fixed = cost.per_frame() * CYCLES_PER_TICK;
        println!(
            "{name}: stride {}: {:.0} cycles/frame, {:.0} valid pixels, {:.0} bytes sent; \
             stride {}: {:.0} cycles/frame, {:.0} valid pixels, {:.0} bytes sent; \
             marginal {per_pixel:.1} cycles per valid pixel ({core:.1} in the core), \
             {fixed:.0} cycles per frame besides",
            f.stride,
            f.ticks * CYCLES_PER_TICK,
            f.pixels,
            f.bytes,
            c.stride,
            c.ticks * CYCLES_PER_TICK,
            c.pixels,
            c.bytes,
        );
        assert!(per_pixel > 0.0 && f.ticks > c.ticks);
        // The 32-bit projection loop (src/camera/narrow.rs) and the row
        // set-up once per frame: 222.3 and 234.0 cycles per valid pixel on
        // 2026-12-02, against 442 and 488 before the loop; 212.8 and 224.2
        // with the ray's low half stepped by add-with-carry. Issue 24 asks
        // for at most 240 on both. Since the cost counts the receive path
        // too (the USB reads, the framing's scans; uncounted before): 324.8
        // and 328.7 on the same code; 282.7 and 283.9 once the ROM's
        // function table is cached, the timer read without a critical
        // section, the framing's copies aligned and its scan done once;
        // 221.7 and 226.2 with one 32-bit multiply an axis in the
        // projection and USB packets read straight into the framing: the
        // issue's 240 is the bound now.
        assert!(
            per_pixel <= 240.0,
            "{name}: {per_pixel:.1} cycles per valid pixel, above 240"
        );
        // What a frame costs besides its pixels: 548 k and 870 k cycles on
        // 2026-12-02 (the radix sort of the keys, the sketch's heap, the row
        // set-up once per frame), 887 k and 1,143 k before; 463 k and 576 k
        // with the receive path counted and cut (this measure's first
        // frames; `placedb bench --pico` measures a full window's).
        let frame_bound = if name == "synthetic" { 650e3 } else { 520e3 };
        assert!(
            fixed <= frame_bound,
            "{name}: {fixed:.0} cycles per frame besides its pixels, above {frame_bound}"
        );
        // At 133 MHz, every pixel valid (the worst case), and what USB full
        // speed carries: ~1.1 MB/s of bulk payload at best; the host sends
        // 2 bytes per sampled pixel plus ~1 % framing.
        for (w, h) in [(160, 120), (320, 240)] {
            for s in [1, 2, 4] {
                let px = (w / s * h / s) as f64;
                let fps = 133e6 / (fixed + per_pixel * px);
                let usb = 1.1e6 / (px * 2.0 * 1.01);
                println!(
                    "  {name} model: {w}x{h} stride {s}: {fps:.1} frames/s on the Pico at 133 MHz; \
                     USB full speed carries {usb:.0} frames/s"
                );
            }
        }
    }
}

/// Power cut on the emulated Pico: the emulator is killed (SIGKILL) in the
/// middle of a frame, with frames pending in the window, and started again
/// on the same flash file. The firmware restores its scan from the flash log
/// (written through the boot ROM's flash functions), every decision it had
/// sent is still there, and the host resumes at the first undecided frame:
/// the final export equals an uninterrupted run's.
#[test]
fn a_pico_killed_mid_scan_restores_from_flash_and_resumes() {
    let client = killed_mid_scan_restores_and_resumes::<Pico>(60);
    let console = client.into_link().stop();
    if let Some(line) = console.lines().find(|l| l.starts_with("stats")) {
        println!("emulator after the restart: {line}");
    }
}

/// The emulated Pico on a flash file; a power cut kills the emulator
/// (SIGKILL).
struct Pico;

impl Board for Pico {
    type Link = Rp2040;
    const NAME: &'static str = "pico";
    const PROFILE: &'static str = PROFILE;
    const REPLY: Duration = REPLY;

    fn boot(flash: &Path) -> (Client<Rp2040>, String) {
        // The emulator's console is read when it stops.
        (
            Client::new(boot(Some(flash), Duration::from_secs(300))),
            String::new(),
        )
    }

    fn power_cut(client: Client<Rp2040>, flash: &Path) {
        client.into_link().power_cut();
        let image = std::fs::read(flash).unwrap();
        assert_eq!(image.len(), 2 << 20, "the flash file is the Pico's 2 MiB");
        assert!(
            image[1 << 20..].iter().any(|&b| b != 0xFF),
            "nothing was written to the log region (the second MiB)"
        );
    }
}

#[test]
fn the_emulated_pico_recovers_from_5_percent_faults_over_usb() {
    let started = Instant::now();
    let seq = demo(30);
    let (vcfg, sel) = (stride(8), sel(8));
    let want = host_replay(PROFILE, &seq, &vcfg, sel);
    let board = boot(None, Duration::from_secs(300));
    let mut client = Client::new(FaultInjector::new(board, FaultConfig::new(0.05, 0.05, 5)));
    let resend_after = Duration::from_millis(250);
    let opts = StreamOptions {
        retries: 40,
        resend_after,
        ..StreamOptions::default()
    };
    let report = stream(&mut client, &seq, &vcfg, sel, &opts);
    assert_eq!(report.status.frames_seen as usize, seq.frames.len());
    let export = ExportOptions {
        batch: 8,
        retries: 40,
        reply_timeout: resend_after,
    };
    let csv = export_csv(&mut client, &export);
    let stats = client.link().stats();
    assert!(stats.sent_dropped > 0 && stats.sent_corrupted > 0);
    assert!(stats.received_dropped > 0 && stats.received_corrupted > 0);
    assert!(report.retransmissions > 0);
    assert_eq!(csv.0, want.0, "database.csv differs");
    assert_eq!(csv.1, want.1, "labels.csv differs");
    println!(
        "pico, 5 % drops + 5 % corruption each way over USB, {} frames: identical to the clean \
         replay; host->device {}/{} dropped, {} corrupted; device->host {}/{} dropped, {} corrupted; \
         {} retransmissions; {:.1} s",
        seq.frames.len(),
        stats.sent_dropped,
        stats.sent,
        stats.sent_corrupted,
        stats.received_dropped,
        stats.received,
        stats.received_corrupted,
        report.retransmissions,
        started.elapsed().as_secs_f64()
    );
}

/// The harness's exit line of frame answer latencies ("latency frames=N
/// median_us=M worst_us=W answers_after_erase=K ...") as (N, M, W, K).
fn latency_line(console: &str) -> (u64, u64, u64, u64) {
    let line = console
        .lines()
        .find(|l| l.starts_with("latency "))
        .unwrap_or_else(|| panic!("no latency line: {console}"));
    let field = |name: &str| -> u64 {
        line.split_whitespace()
            .find_map(|w| w.strip_prefix(name)?.strip_prefix('=')?.parse().ok())
            .unwrap_or_else(|| panic!("no {name} in {line}"))
    };
    (
        field("frames"),
        field("median_us"),
        field("worst_us"),
        field("answers_after_erase"),
    )
}

fn boot_timed(flash: Option<&Path>, timing: FlashTiming, cut: Option<u32>) -> Rp2040 {
    let options = Rp2040Options {
        flash: flash.map(Path::to_path_buf),
        deadline: Duration::from_secs(300),
        flash_timing: timing,
        cut_during_erase: cut,
        ..Rp2040Options::default()
    };
    Rp2040::start_with(&firmware(), &options).unwrap_or_else(|e| panic!("{e}"))
}

/// At the datasheet's maximum flash timing (400 ms a sector erase, 3 ms a
/// page, the core held that long in emulated time) the host neither gives
/// up nor resends (its reply timeout outlasts the worst stall:
/// `placedb_host::board::flash_timing`), and the export equals the host replay.
#[test]
fn the_emulated_pico_at_max_flash_timing_matches_the_host_replay() {
    let started = Instant::now();
    let seq = demo(40);
    let (vcfg, sel) = (stride(8), sel(8));
    let mut client = Client::new(boot_timed(None, FlashTiming::Max, None));
    let report = stream(&mut client, &seq, &vcfg, sel, &StreamOptions::default());
    assert_eq!(report.status.frames_seen as usize, seq.frames.len());
    assert_eq!(report.retransmissions, 0);
    let csv = export_csv(&mut client, &ExportOptions::default());
    assert_eq!(csv, host_replay(PROFILE, &seq, &vcfg, sel));
    let console = client.into_link().stop();
    let stats = console.lines().find(|l| l.starts_with("stats")).unwrap();
    assert!(!stats.contains("sectors_erased=0 "), "{stats}");
    let (frames, median, worst, waited) = latency_line(&console);
    assert_eq!(frames as usize, seq.frames.len());
    println!(
        "pico at max flash timing, {} frames: identical to the host replay, no resend; \
         answer latency median {median} us, worst {worst} us of emulated time, {waited} \
         answers waited for an erase; {stats}; {:.1} s",
        seq.frames.len(),
        started.elapsed().as_secs_f64()
    );
}

/// A power cut in the middle of a sector erase (the harness leaves the
/// sector half erased and dies), at max flash timing: booted again on the
/// same flash the Pico restores every decision it had sent, the host
/// resumes, and the export equals an uninterrupted run's.
#[test]
fn a_pico_cut_during_an_erase_restores_and_resumes() {
    let started = Instant::now();
    let dir = std::env::temp_dir().join(format!("placedb-pico-erase-cut-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let flash = dir.join("flash.bin");
    let _ = std::fs::remove_file(&flash);
    let seq = demo(40);
    let (vcfg, sel) = (stride(8), sel(8));
    let scan = scan::scan_config(&seq, &vcfg).unwrap();
    let cfg = scan::device_config(&scan, &sel).unwrap();
    // Erase 1 readies the head sector at boot, 2 the next one after the
    // Hello: the third is in the middle of the scan.
    let board = boot_timed(Some(&flash), FlashTiming::Max, Some(3));
    let mut session = Session::new(Client::new(board), StreamOptions::default());
    session.start(&cfg, Some(PROFILE)).unwrap();
    let mut acknowledged = Vec::new();
    let mut cut = false;
    for i in 0..seq.frames.len() {
        let img = seq.depth(i).unwrap();
        let frame = DepthFrame {
            timestamp: seq.frames[i].timestamp,
            pose: seq.frames[i].pose().unwrap(),
            intrinsics: cfg.intrinsics,
            depth: &img.data,
        };
        let pushed = session.push_frame(&frame);
        acknowledged.extend(session.take_decisions());
        if pushed.is_err() {
            cut = true;
            break;
        }
    }
    let mut board = session.into_client().into_link();
    let console = board.console();
    assert!(
        cut && board.wait_console("power cut during the erase", Duration::from_secs(10)),
        "the power was not cut: {console}"
    );
    let _ = board.try_wait();
    drop(board);

    let mut client = Client::new(boot_timed(Some(&flash), FlashTiming::Max, None));
    let st = client::status(&mut client, REPLY).unwrap();
    assert!(st.frames_decided as usize >= acknowledged.len());
    let (_, labels) = export_csv(&mut client, &ExportOptions::default());
    for &(frame, kind) in &acknowledged {
        let class = kind.class(frame).unwrap();
        let label = labels.lines().nth(frame as usize + 1).unwrap();
        assert!(
            label.ends_with(&format!(",{class}")),
            "frame {frame}: {label}"
        );
    }
    let resume = StreamOptions {
        resume: true,
        ..StreamOptions::default()
    };
    stream(&mut client, &seq, &vcfg, sel, &resume);
    let csv = export_csv(&mut client, &ExportOptions::default());
    assert_eq!(csv, host_replay(PROFILE, &seq, &vcfg, sel));
    println!(
        "pico cut during its third erase at max flash timing: {} decisions acknowledged \
         before, all restored; resumed at frame {}; export identical to the host replay; {:.1} s",
        acknowledged.len(),
        st.frames_seen,
        started.elapsed().as_secs_f64()
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A fresh emulated Pico that scanned `frames` synthetic frames (stride
/// 8, window 8), and its export.
fn scanned(frames: usize) -> (Client<Rp2040>, (String, String)) {
    let mut client = Client::new(boot(None, Duration::from_secs(300)));
    let seq = demo(frames);
    stream(
        &mut client,
        &seq,
        &stride(8),
        sel(8),
        &StreamOptions::replacing(),
    );
    let export = export_csv(&mut client, &ExportOptions::default());
    (client, export)
}

/// A new host session starts clean (issue 40): one program asks the board
/// for its export and closes the port once the first record came; the
/// next program to open the port gets nothing of that export but the one
/// 64-byte packet the USB controller held (as from a real board: at most
/// three small records and the start of another, which it reads as one
/// damaged frame, and no terminal reply), its first request is answered
/// at once (the firmware did not go on waiting to send the export to
/// nobody), and the export it asks for is whole.
#[test]
fn a_port_closed_with_replies_pending_leaves_the_next_session_clean() {
    // An export of some 300 records: far more than leave the board before
    // the first one reaches the test and it closes the port.
    let (mut client, want) = scanned(300);

    client
        .send(HostMessage::ExportRequest {
            from_record: 0,
            max_records: u32::MAX,
        })
        .unwrap();
    let first = client.recv(REPLY).unwrap();
    assert!(
        matches!(first, Received::Message(DeviceMessage::ExportRecord(_))),
        "{first:?}"
    );
    let mut board = client.into_link();
    board.reopen().unwrap();

    let mut client = Client::new(board);
    let (seq_no, replies) = client.request(HostMessage::StatusRequest, REPLY).unwrap();
    let stale: Vec<&Received> = replies
        .iter()
        .filter(|r| matches!(r, Received::Message(_)) && r.terminal_seq() != Some(seq_no))
        .collect();
    let damaged = replies
        .iter()
        .filter(|r| matches!(r, Received::Damaged(_)))
        .count();
    let stale_ends = stale.iter().filter(|r| r.terminal_seq().is_some()).count();
    assert!(
        stale.len() <= 3 && stale_ends == 0 && damaged <= 1,
        "the new session got {} replies of the earlier one ({stale_ends} terminal) and \
         {damaged} damaged frames: {:?}",
        stale.len(),
        stale.iter().take(3).collect::<Vec<_>>()
    );
    assert_eq!(export_csv(&mut client, &ExportOptions::default()), want);
    let console = client.into_link().stop();
    assert!(!console.contains("error:"), "{console}");
    check_stack(&console).unwrap_or_else(|e| panic!("{e}"));
    println!(
        "port closed with an export pending, opened again: {} replies to the new session's \
         first request, {} of them the earlier session's (the packet the controller held), \
         {damaged} damaged; export whole",
        replies.len(),
        stale.len()
    );
}

/// One program at a time (issue 41): while a session has the emulated
/// Pico's port open, `placedb export` on the same port is refused at once
/// in words, writes nothing, and the first session goes on untouched.
#[test]
fn a_second_program_on_the_port_is_refused_and_the_first_goes_on() {
    let (mut client, want) = scanned(20);
    let port = format!("tcp:{}", client.link().address().unwrap());
    let out = std::env::temp_dir().join(format!("placedb-second-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let second = std::process::Command::new(env!("CARGO_BIN_EXE_placedb"))
        .args(["export", "--port", &port, "-o"])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&second.stderr);
    assert_eq!(second.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("serves one connection at a time"),
        "the refusal is not in words: {stderr}"
    );
    assert!(!out.exists(), "the refused export wrote {}", out.display());
    assert_eq!(export_csv(&mut client, &ExportOptions::default()), want);
    let console = client.into_link().stop();
    assert!(console.contains("client refused"), "{console}");
    println!("second program refused: {}", stderr.trim());
}
