//! A Pico that panics or hangs mid-scan restarts by itself (issue 40 item
//! 2): the real `placedb` against `placedb device --rp2040` running the
//! fault-injection firmware (boards/rp-pico/src/fault.rs; its harness
//! plans the fault with `PICO_FAULT`). The panic handler records its place
//! and resets the chip through the watchdog; a hang stops feeding the
//! watchdog, which resets it; a stack overflow meets the MPU guard under
//! the stack (the core locks up and the watchdog resets it). Either way the board leaves the bus (the
//! stream loses it), boots again, restores its scan from flash, says why
//! it restarted (`Status::last_reset`), and `placedb stream --resume` goes
//! on to the export `placedb select --solver online` gives.
//!
//! Needs what host/tests/board_rp2040.rs needs (Node 20, `npm ci` in
//! boards/rp-pico/emulator, the boot ROM); builds the fault-injection
//! firmware first (`--profile fault-injection --features fault-injection`).

mod cli_common;

use cli_common::device::{exported, host_replay, Device, BOOT};
use cli_common::{placedb, seven_scenes_copy, stderr, TempDir};
use placedb::protocol::ResetCause;
use placedb_host::board::client;
use std::time::{Duration, Instant};

/// Frames of the scan; the fault comes in the frame after [`FAULT_AT`].
const FRAMES: usize = 60;
const FAULT_AT: usize = 45;

/// `PICO_FAULT=fault` on a scan of [`FRAMES`] frames: the stream loses the
/// board, the harness names the reset (`harness_says`), the board comes
/// back with `want` as its last reset and the words `words` in the resumed
/// stream's summary, and the resumed scan's export is the host replay's.
fn a_fault_mid_scan_restarts_the_board(
    fault: &str,
    harness_says: &str,
    want: fn(&ResetCause) -> bool,
    words: &str,
) {
    let started = Instant::now();
    let tmp = TempDir::new("restart");
    let dir = tmp.path().join("seq");
    seven_scenes_copy(&dir, FRAMES, true);
    let seq = tmp.arg("seq");
    let firmware = placedb_host::testing::rp2040_fault_firmware();
    let mut device = Device::start_with("--rp2040", &firmware, &[("PICO_FAULT", fault)], &[]);
    let port = device.port();
    let args = [
        seq.as_str(),
        "--port",
        &port,
        "--profile",
        "ram256k",
        "--stride",
        "8",
    ];
    let mut stream = vec!["stream"];
    stream.extend_from_slice(&args);
    let run = placedb(&stream);
    let err = stderr(&run);
    assert!(
        !run.status.success(),
        "the stream outlived the fault: {err}"
    );
    device.wait_for(harness_says, BOOT);
    // Back on the bus: enumerated a second time, on the same port.
    let end = Instant::now() + BOOT;
    while device.console().matches("usb configured").count() < 2 {
        assert!(
            Instant::now() < end,
            "the board did not come back:\n{}",
            device.console()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let st = client::status(
        &mut client::connect(&port).unwrap(),
        Duration::from_secs(60),
    )
    .unwrap();
    assert!(want(&st.last_reset), "last reset {:?}", st.last_reset);
    // The scan came back from flash: its durable records (decisions are
    // logged in batches, so those of the last frames may not be yet).
    assert!(st.stored_records > 0, "nothing restored: {st:?}");
    let mut resume = stream.clone();
    resume.push("--resume");
    let run = placedb(&resume);
    let out = String::from_utf8_lossy(&run.stdout).into_owned();
    assert!(run.status.success(), "{}", stderr(&run));
    assert!(out.contains(words), "{words:?} not in: {out}");
    let (database, labels) = exported(&port, &tmp.arg("out"));
    let (host_database, host_labels) = host_replay(&seq, "ram256k", &tmp.arg("host"));
    assert!(
        database == host_database,
        "database.csv of the resumed scan differs from the host replay's"
    );
    assert!(
        labels == host_labels,
        "labels.csv of the resumed scan differs from the host replay's"
    );
    let (_, console) = device.stop();
    let resets = console
        .lines()
        .find_map(|l| l.split(" watchdog_resets=").nth(1))
        .and_then(|r| r.split(' ').next())
        .unwrap_or_else(|| panic!("no stats line:\n{console}"));
    assert_eq!(resets, "1", "{console}");
    println!(
        "{fault}: the stream lost the board ({}), which restarted ({}), restored {} records \
         ({} frames decided); resumed to the host replay's export; {:.1} s",
        err.lines().last().unwrap_or_default(),
        match st.last_reset {
            ResetCause::Panic(place) => format!("a panic at {place}"),
            other => format!("{other:?}"),
        },
        st.stored_records,
        st.frames_decided,
        started.elapsed().as_secs_f64()
    );
}

/// A panic mid-scan: recorded (its place in fault.rs), the board reset
/// through the watchdog at once.
#[test]
fn a_panic_mid_scan_restarts_the_pico_which_says_where_and_resume_goes_on() {
    a_fault_mid_scan_restarts_the_board(
        &format!("panic:{FAULT_AT}"),
        "chip reset by the watchdog: forced by the firmware",
        |cause| matches!(cause, ResetCause::Panic(p) if p.file().ends_with("src/fault.rs") && p.line > 0),
        "the board restarted after a panic at src/fault.rs:",
    );
}

/// A stack overflow mid-scan (recursion, 512 bytes a call): the first
/// write into the MPU guard under the stack faults (the harness models the
/// region the firmware programs; on silicon a HardFault, then lockup) and
/// the watchdog resets the board, instead of the stack overwriting the
/// statics.
#[test]
fn a_stack_overflow_mid_scan_meets_the_guard_and_resume_goes_on() {
    a_fault_mid_scan_restarts_the_board(
        &format!("overflow:{FAULT_AT}"),
        "stack overflow: a write to 0x",
        |cause| *cause == ResetCause::Watchdog,
        "the board restarted after its watchdog fired",
    );
}

/// A hang mid-scan (a loop that never feeds the watchdog): the watchdog
/// resets the board once its timeout has passed.
#[test]
fn a_hang_mid_scan_is_ended_by_the_watchdog_and_resume_goes_on() {
    a_fault_mid_scan_restarts_the_board(
        &format!("hang:{FAULT_AT}"),
        "chip reset by the watchdog: its countdown ran out",
        |cause| *cause == ResetCause::Watchdog,
        "the board restarted after its watchdog fired",
    );
}
