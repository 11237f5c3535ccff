//! `placedb device` leaves nothing running: stopped with SIGTERM sent to
//! placedb alone (not Ctrl-C, which signals the whole process group), it
//! stops its emulator (`qemu-system-arm`, or `node` running the RP2040
//! harness) before it exits; killed with SIGKILL, the kernel kills QEMU after
//! it (`PR_SET_PDEATHSIG`). Linux only (reads `/proc`).
//!
//! Needs `qemu-system-arm` and the QEMU firmware (built first, as in
//! host/tests/board_qemu.rs, unless `PLACEDB_QEMU_FIRMWARE` names one); the
//! RP2040 case needs what host/tests/board_rp2040.rs needs (Node 20, `npm ci` in
//! boards/rp-pico/emulator, the Pico firmware, the boot ROM).
#![cfg(target_os = "linux")]

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// `/proc/PID/stat`: (command name, state, parent pid), if the process exists.
fn stat(pid: u32) -> Option<(String, char, u32)> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // "pid (comm) state ppid ...": comm may hold spaces and parentheses.
    let (open, close) = (text.find('(')?, text.rfind(')')?);
    let comm = text.get(open + 1..close)?.to_string();
    let mut rest = text.get(close + 1..)?.split_whitespace();
    let state = rest.next()?.chars().next()?;
    let ppid = rest.next()?.parse().ok()?;
    Some((comm, state, ppid))
}

/// Whether `pid` is a running (not zombie) process named `comm`.
fn running(pid: u32, comm: &str) -> bool {
    stat(pid).is_some_and(|(c, state, _)| c == comm && state != 'Z')
}

/// The child of `parent` named `comm`, waited for up to `timeout`.
fn child_named(parent: &mut Child, comm: &str, timeout: Duration) -> u32 {
    let end = Instant::now() + timeout;
    loop {
        let found = std::fs::read_dir("/proc")
            .unwrap()
            .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
            .find(|&pid| stat(pid).is_some_and(|(c, _, ppid)| ppid == parent.id() && c == comm));
        if let Some(pid) = found {
            return pid;
        }
        if let Some(status) = parent.try_wait().unwrap() {
            panic!("placedb device exited ({status}) without starting {comm}");
        }
        if Instant::now() > end {
            let _ = parent.kill();
            panic!("placedb device started no {comm}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Starts `placedb device BOARD --firmware FIRMWARE` on a free port.
fn placedb_device(board: &str, firmware: PathBuf) -> Child {
    Command::new(env!("CARGO_BIN_EXE_placedb"))
        .args(["device", board, "--port", "0", "--firmware"])
        .arg(firmware)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .spawn()
        .expect("start placedb device")
}

fn signal(pid: u32, signal: libc::c_int) {
    let pid = libc::pid_t::try_from(pid).unwrap();
    // SAFETY: kill(2) on a process this test started (or its child).
    assert_eq!(unsafe { libc::kill(pid, signal) }, 0);
}

/// Kills an emulator left behind (this test's own, by its pid), then fails.
fn fail_left_running(pid: u32, comm: &str, how: &str) -> ! {
    if running(pid, comm) {
        signal(pid, libc::SIGKILL);
    }
    panic!("{comm} (pid {pid}) still runs after placedb {how}");
}

/// SIGTERM to `placedb device BOARD`: once placedb has exited, its emulator
/// `comm` is gone (placedb reaped it first: nothing to wait for).
fn sigterm_ends_the_emulator(board: &str, firmware: PathBuf, comm: &str) {
    let mut placedb = placedb_device(board, firmware);
    let emulator = child_named(&mut placedb, comm, Duration::from_secs(60));
    assert!(running(emulator, comm));
    signal(placedb.id(), libc::SIGTERM);
    let status = placedb.wait().unwrap();
    if running(emulator, comm) {
        fail_left_running(emulator, comm, "exited on SIGTERM");
    }
    assert!(status.success(), "placedb stopped by SIGTERM: {status}");
}

#[test]
fn sigterm_to_placedb_device_qemu_ends_qemu() {
    let firmware =
        placedb_host::board::emulator::qemu::built_firmware().unwrap_or_else(|e| panic!("{e}"));
    sigterm_ends_the_emulator("--qemu", firmware, "qemu-system-arm");
}

#[test]
fn sigterm_to_placedb_device_rp2040_ends_the_emulator() {
    let firmware =
        placedb_host::board::emulator::rp2040::built_firmware().unwrap_or_else(|e| panic!("{e}"));
    sigterm_ends_the_emulator("--rp2040", firmware, "node");
}

#[test]
fn sigkill_to_placedb_device_qemu_ends_qemu() {
    // Orphans of this test process come to it rather than to a PID 1 that
    // may never reap them: QEMU, once placedb is gone, is reaped here.
    // SAFETY: prctl(2) with integer arguments.
    assert_eq!(unsafe { libc::prctl(libc::PR_SET_CHILD_SUBREAPER, 1) }, 0);
    let firmware =
        placedb_host::board::emulator::qemu::built_firmware().unwrap_or_else(|e| panic!("{e}"));
    let mut placedb = placedb_device("--qemu", firmware);
    let qemu = child_named(&mut placedb, "qemu-system-arm", Duration::from_secs(60));
    signal(placedb.id(), libc::SIGKILL);
    placedb.wait().unwrap();
    // The kernel sends QEMU SIGKILL as placedb dies: wait (bounded) for it
    // to be gone, then reap it.
    let end = Instant::now() + Duration::from_secs(30);
    while running(qemu, "qemu-system-arm") {
        if Instant::now() > end {
            fail_left_running(qemu, "qemu-system-arm", "was killed");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    if stat(qemu).is_some_and(|(_, _, ppid)| ppid == std::process::id()) {
        let mut status = 0;
        // SAFETY: waitpid(2) on our (adopted) child, which has exited.
        unsafe { libc::waitpid(libc::pid_t::try_from(qemu).unwrap(), &mut status, 0) };
    }
}
