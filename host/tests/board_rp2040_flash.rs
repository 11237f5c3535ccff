//! The emulated Pico's flash log under load (issue 24, item 4): a scan that
//! erases dozens of sectors, at the W25Q16JV's typical and maximum erase and
//! program times (the harness holds the emulated RP2040 for them), and
//! power cuts in the middle of a sector erase and of a page program after
//! dozens of acknowledged decisions.
//!
//! The scan is [`new_places::new_place_every_frame`]: every frame is a new
//! place stored with ~2.5 KiB of exact keys, so its 80 frames fill 56
//! sectors of the log (a real scan stores a database frame every few dozen
//! frames).
//! Whether an answer waited for an erase is counted by the harness from
//! emulated-time events (an erase that ended between a frame's last
//! `DepthRows` handed to the firmware and its answer leaving), not from
//! wall time: the 0 asserted here holds whatever the machine's speed (only
//! the idle turns the firmware gets while the host is slow vary, and the
//! erases between frames do not need them).
//!
//! Needs what host/tests/board_rp2040.rs needs (Node 20, `npm ci` in
//! `boards/rp-pico/emulator`, the firmware built). Run with `--nocapture`
//! for the figures.

#[path = "board_common/new_places.rs"]
mod new_places;
#[path = "board_common/pico.rs"]
mod pico;

use new_places::new_place_every_frame;
use pico::{boot, boot_with_bus_resets, exit_field, export_csv, latency, stream, Cut, PROFILE};
use placedb::protocol::DecisionKind;
use placedb_host::board::client::Client;
use placedb_host::board::emulator::rp2040::check_stack;
use placedb_host::board::flash_timing::FlashTiming;
use placedb_host::board::scan::StreamOptions;
use placedb_host::board::session::{DepthFrame, Session};
use placedb_host::board::{client, scan};
use placedb_host::testing::{replay_csv as host_replay, selector};
use std::collections::BTreeSet;
use std::time::{Duration, Instant};

/// Frames of the scan: about 56 sectors of log, and 2 sectors erased at
/// boot and at the Hello.
const FRAMES: usize = 80;
/// The selector's window (frames held undecided).
const WINDOW: u16 = 8;
/// At least this many erases, or the scan does not show what it is for.
const MIN_ERASES: u64 = 50;

/// Streams the scan at `timing` with the host's default options
/// (pipelined, 60 s reply timeout: a stall the host did not outlast would
/// end the stream with an error), the host resetting the bus after each
/// FrameEnd in `bus_resets`; checks the export against the host replay
/// and that the host never had to reset the port (an erase the firmware
/// started while it enumerated: see the harness), and returns the
/// harness's exit lines.
fn scan_with_many_erases(timing: FlashTiming, bus_resets: &[u32]) -> String {
    let started = Instant::now();
    let seq = new_place_every_frame(FRAMES);
    let (vcfg, sel) = (new_places::voxel_config(), selector(WINDOW));
    let mut client = Client::new(boot_with_bus_resets(None, timing, Cut::Never, bus_resets));
    let opts = StreamOptions::default();
    let report = stream(&mut client, &seq, &vcfg, sel, &opts);
    assert_eq!(report.status.frames_seen as usize, FRAMES);
    assert!(report.decisions.iter().all(Option::is_some));
    if bus_resets.is_empty() {
        assert_eq!(report.retransmissions, 0, "the host sent a message again");
    }
    let csv = export_csv(&mut client);
    assert_eq!(
        csv,
        host_replay(PROFILE, &seq, &vcfg, sel),
        "the export differs from the host replay at {timing} flash timing"
    );
    let console = client.into_link().stop();
    let erases = exit_field(&console, "stats", "sectors_erased");
    let pages = exit_field(&console, "stats", "pages_programmed");
    check_stack(&console).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        exit_field(&console, "stats", "bus_resets"),
        bus_resets.len() as u64,
        "{console}"
    );
    assert_eq!(
        exit_field(&console, "stats", "usb_host_resets"),
        0,
        "the host had to reset the port: {console}"
    );
    assert_eq!(
        exit_field(&console, "stats", "erases_while_enumerating"),
        0,
        "the firmware erased while the host enumerated: {console}"
    );
    // No legitimate wait starves the watchdog, at the flash's maximum
    // erase and program times too, bus resets included.
    assert_eq!(
        exit_field(&console, "stats", "watchdog_resets"),
        0,
        "the watchdog reset the board: {console}"
    );
    // The stack's guard is on and nothing deep reached it.
    assert!(
        console.contains("mpu guard 0x"),
        "no stack guard: {console}"
    );
    assert_eq!(
        exit_field(&console, "stats", "guard_faults"),
        0,
        "the stack reached its guard: {console}"
    );
    assert!(
        erases >= MIN_ERASES,
        "{erases} sectors erased, fewer than the {MIN_ERASES} the test is for: {console}"
    );
    let lat = latency(&console);
    assert_eq!(lat.frames as usize, FRAMES, "{console}");
    // The emulated time of the worst answer is what a host on silicon
    // would wait: within its reply timeout, so it would not give up.
    assert!(
        Duration::from_micros(lat.worst_us) < opts.reply_timeout,
        "{console}"
    );
    println!(
        "pico, {FRAMES} frames of {} at {timing} flash timing: {erases} sectors erased, {pages} \
         pages programmed; frame answer latency median {} us, worst {} us of emulated time; \
         {} answers waited for an erase; {} bus resets, {} host port resets; export identical \
         to the host replay, {} messages sent again; {} database frames; {:.1} s",
        seq.name,
        lat.median_us,
        lat.worst_us,
        lat.waited,
        bus_resets.len(),
        exit_field(&console, "stats", "usb_host_resets"),
        report.retransmissions,
        report.status.database_size,
        started.elapsed().as_secs_f64()
    );
    console
}

/// At typical timing every erase of a steady scan is done ahead, off every
/// frame's path: no answer waits for one.
#[test]
fn many_erases_at_typical_timing_no_answer_waits_for_one() {
    let console = scan_with_many_erases(FlashTiming::Typical, &[]);
    let lat = latency(&console);
    assert_eq!(lat.waited, 0, "answers waited for an erase: {console}");
}

/// At the datasheet's maximum (400 ms an erase, 3 ms a page) the erases are
/// still all ahead: the order of events does not depend on their length.
#[test]
fn many_erases_at_max_timing_no_answer_waits_for_one() {
    let console = scan_with_many_erases(FlashTiming::Max, &[]);
    let lat = latency(&console);
    assert_eq!(lat.waited, 0, "answers waited for an erase: {console}");
}

/// USB first (issue 40): the host resets the bus mid-stream (a hub reset,
/// a host's resume) after every fifth frame, at the maximum erase time,
/// while the log opens a sector every frame or two: the device takes its
/// new address and answers every enumeration request in time (the
/// firmware erases nothing until it is configured and USB has been quiet
/// for a while), and the scan goes on to the host replay's export.
#[test]
fn bus_resets_mid_stream_at_max_timing_and_the_scan_goes_on() {
    let resets: Vec<u32> = (1..FRAMES as u32 / 5).map(|k| 5 * k).collect();
    scan_with_many_erases(FlashTiming::Max, &resets);
}

/// Line `i` (from 0, after the header) of a CSV text.
fn row(csv: &str, i: usize) -> Option<&str> {
    csv.lines().nth(i + 1)
}

/// The power goes at `cut` in the middle of the scan, at max flash timing,
/// after at least `min_acknowledged` decisions reached the host. Booted
/// again on the same flash the Pico gives back the durable part: every
/// acknowledged decision, the labels a prefix of the uninterrupted run's
/// and its database frames among that run's; the host resumes and the
/// final export equals the uninterrupted run's (the host replay).
fn cut_restore_and_resume(cut: Cut, min_acknowledged: usize) {
    let started = Instant::now();
    let dir =
        std::env::temp_dir().join(format!("placedb-pico-cut-{:?}-{}", cut, std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let flash = dir.join("flash.bin");
    let _ = std::fs::remove_file(&flash);
    let seq = new_place_every_frame(FRAMES);
    let (vcfg, sel) = (new_places::voxel_config(), selector(WINDOW));
    let scan = scan::scan_config(&seq, &vcfg).unwrap();
    let cfg = scan::device_config(&scan, &sel).unwrap();
    let (want_db, want_labels) = host_replay(PROFILE, &seq, &vcfg, sel);

    let board = boot(Some(&flash), FlashTiming::Max, cut);
    let mut session = Session::new(Client::new(board), StreamOptions::default());
    session.start(&cfg, Some(PROFILE)).unwrap();
    let mut acknowledged: Vec<(u32, DecisionKind)> = Vec::new();
    let mut cut_at = None;
    for i in 0..FRAMES {
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
            cut_at = Some(i);
            break;
        }
    }
    let mut board = session.into_client().into_link();
    let console = board.console();
    assert!(
        cut_at.is_some() && board.wait_console(cut.message(), Duration::from_secs(10)),
        "the power was not cut ({cut:?}): {console}"
    );
    let _ = board.try_wait();
    drop(board);
    assert!(
        acknowledged.len() >= min_acknowledged,
        "only {} decisions acknowledged before the cut ({cut:?})",
        acknowledged.len()
    );

    let mut client = Client::new(boot(Some(&flash), FlashTiming::Max, Cut::Never));
    let st = client::status(&mut client, StreamOptions::default().reply_timeout).unwrap();
    let decided = st.frames_decided as usize;
    assert!(
        decided >= acknowledged.len(),
        "{decided} decisions restored"
    );
    let (db, labels) = export_csv(&mut client);
    for &(frame, kind) in &acknowledged {
        let class = kind.class(frame).unwrap();
        let label = row(&labels, frame as usize).unwrap();
        assert!(
            label.ends_with(&format!(",{class}")),
            "frame {frame}: {label}"
        );
    }
    assert_eq!(labels.lines().count(), decided + 1);
    for i in 0..decided {
        assert_eq!(row(&labels, i), row(&want_labels, i), "label of frame {i}");
    }
    let want_rows: BTreeSet<&str> = want_db.lines().skip(1).collect();
    for r in db.lines().skip(1) {
        assert!(
            want_rows.contains(r),
            "restored database frame {r} is not the run's"
        );
    }

    let resume = StreamOptions {
        resume: true,
        ..StreamOptions::default()
    };
    let report = stream(&mut client, &seq, &vcfg, sel, &resume);
    assert_eq!(report.frames, FRAMES - st.frames_seen as usize);
    let csv = export_csv(&mut client);
    assert!(
        csv == (want_db.clone(), want_labels.clone()),
        "the resumed scan's export differs from the uninterrupted run's"
    );
    // USB first: what the restore erased, it erased before USB started.
    let console = client.into_link().stop();
    assert_eq!(
        exit_field(&console, "stats", "erases_while_enumerating"),
        0,
        "the restored board erased while the host enumerated: {console}"
    );
    // Restoring and resuming are the deepest paths of all.
    let stack = check_stack(&console).unwrap_or_else(|e| panic!("{e}"));
    println!(
        "stack after restore and resume: {} bytes at the deepest",
        stack.peak
    );
    println!(
        "pico, {cut:?} at max flash timing, in frame {} of {FRAMES}: {} decisions acknowledged \
         before, {decided} restored ({} database frames) and identical to the uninterrupted \
         run's; resumed at frame {}; final export identical to the host replay; {:.1} s",
        cut_at.unwrap_or(0),
        acknowledged.len(),
        db.lines().count() - 1,
        st.frames_seen,
        started.elapsed().as_secs_f64()
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Erase 40 of the scan's 58 comes about 54 frames in: two or three
/// batches of decisions (16 each) are durable and acknowledged by then (48
/// when measured).
#[test]
fn a_pico_cut_during_an_erase_late_in_the_scan_restores_and_resumes() {
    cut_restore_and_resume(Cut::DuringErase(40), 32);
}

/// Page 600 of the scan's 1,129 comes about 42 frames in, in the middle of
/// a record: 32 decisions acknowledged when measured; one batch is
/// asserted, as the one written last may not have reached the host.
#[test]
fn a_pico_cut_during_a_page_program_late_in_the_scan_restores_and_resumes() {
    cut_restore_and_resume(Cut::DuringProgram(600), 16);
}
