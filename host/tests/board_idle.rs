//! An idle emulated board sleeps (issue 41 item 7): `placedb device --qemu`
//! and `placedb device --rp2040`, the real binary with the firmware built
//! first, left alone once booted, and then with a program connected that
//! asked for the status and sends nothing more, keep their emulator well
//! under a quarter of a host core. Two boards spinning while they wait
//! halve each other's speed on a 2-core machine.
//!
//! What is counted is CPU use, not speed: over 2 s of wall time, the time
//! the emulator's threads ran on a CPU (`/proc/PID/task/*/schedstat`), at
//! most a tenth of the wall time. A spinning emulator runs far more even
//! on a loaded machine (31-49 % of a core with two other builds running;
//! 100 % alone), an idle one next to nothing. The time its threads waited
//! to run is printed, not counted: on a loaded machine even a rare wakeup
//! waits in the run queue, and an idle QEMU's threads' waits summed to more
//! than half the wall time during a full test run. After each wait the
//! board still answers (it wakes for its host).
//!
//! Needs what host/tests/board_qemu.rs and host/tests/board_rp2040.rs need
//! (`qemu-system-arm`; Node 20, `npm ci` in boards/rp-pico/emulator and the
//! boot ROM). Linux only (reads `/proc`).
#![cfg(target_os = "linux")]

mod cli_common;

use cli_common::device::Device;
use placedb::protocol::Phase;
use placedb_host::board::client;
use std::fmt;
use std::time::{Duration, Instant};

/// Most of a host core an idle board's emulator may run on.
const IDLE_SHARE: f64 = 0.10;
/// How long the board is left idle for each count.
const IDLE: Duration = Duration::from_secs(2);

/// What a process's threads took of the CPU, from `/proc`, at one moment.
#[derive(Clone, Copy)]
struct Taken {
    /// utime + stime, seconds.
    cpu: f64,
    /// Time on a CPU and time waiting in a run queue, seconds.
    ran: f64,
    waited: f64,
}

fn taken(pid: u32) -> Taken {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap();
    let close = stat.rfind(')').unwrap();
    // After "(comm)": state is field 3 of the line; utime and stime are 14 and 15.
    let fields: Vec<&str> = stat[close + 1..].split_whitespace().collect();
    // SAFETY: sysconf with a valid name reads a constant.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
    let ticks = |i: usize| fields[i - 3].parse::<f64>().unwrap();
    let (mut ran, mut waited) = (0.0, 0.0);
    for task in std::fs::read_dir(format!("/proc/{pid}/task")).unwrap() {
        let path = task.unwrap().path().join("schedstat");
        // A thread may end between the listing and the read.
        let Ok(text) = std::fs::read_to_string(path) else {
            continue;
        };
        let mut n = text.split_whitespace().map(|f| f.parse::<f64>().unwrap());
        ran += n.next().unwrap() / 1e9;
        waited += n.next().unwrap() / 1e9;
    }
    Taken {
        cpu: (ticks(14) + ticks(15)) / hz,
        ran,
        waited,
    }
}

/// A process's use of the CPU over a stretch of wall time.
struct Use {
    wall: f64,
    cpu: f64,
    ran: f64,
    waited: f64,
}

impl Use {
    /// The share of one core it ran on.
    fn share(&self) -> f64 {
        self.ran / self.wall
    }
}

impl fmt::Display for Use {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "ran {:.1} % of a core over {:.2} s ({:.3} s; waited {:.3} s to run; \
             utime+stime {:.2} s = {:.1} %)",
            100.0 * self.share(),
            self.wall,
            self.ran,
            self.waited,
            self.cpu,
            100.0 * self.cpu / self.wall
        )
    }
}

/// What `pid` takes of the CPU over [`IDLE`].
fn idle_use(pid: u32) -> Use {
    let (a, t0) = (taken(pid), Instant::now());
    std::thread::sleep(IDLE);
    let (b, t1) = (taken(pid), Instant::now());
    Use {
        wall: (t1 - t0).as_secs_f64(),
        cpu: b.cpu - a.cpu,
        ran: b.ran - a.ran,
        waited: b.waited - a.waited,
    }
}

/// `placedb device BOARD`, once it printed `ready`: idle alone, then with a
/// program connected that asked for the status, it runs on less than
/// [`IDLE_SHARE`] of a core, and answers after each wait.
fn an_idle_board_sleeps(board: &str, comm: &str, ready: &str) {
    let mut device = Device::start(board, &[]);
    device.wait_for(ready, Duration::from_secs(120));
    let pid = device.emulator(comm);
    // What the boot left to do (the Pico erases its log's next sector
    // once USB has been quiet for 20 ms) is done by then.
    std::thread::sleep(Duration::from_millis(500));
    let alone = idle_use(pid);

    let mut program = client::connect(&device.port()).unwrap();
    let reply = Duration::from_secs(30);
    let st = client::status(&mut program, reply).unwrap();
    assert_eq!(st.phase, Phase::Unconfigured);
    let connected = idle_use(pid);
    // Asleep, it still wakes for its host.
    client::status(&mut program, reply).unwrap();

    println!("{board}: idle after boot: {alone}");
    println!("{board}: idle with a program connected: {connected}");
    for (when, used) in [
        ("after boot", &alone),
        ("with a program connected", &connected),
    ] {
        assert!(
            used.share() < IDLE_SHARE,
            "placedb device {board}, idle {when}: its emulator {used}; \
             at most {:.0} % expected (it spins instead of sleeping)",
            100.0 * IDLE_SHARE
        );
    }
}

#[test]
fn an_idle_qemu_board_sleeps() {
    an_idle_board_sleeps(
        "--qemu",
        "qemu-system-arm",
        // The firmware's line after its restore: its loop runs.
        "restored",
    );
}

#[test]
fn an_idle_emulated_pico_sleeps() {
    an_idle_board_sleeps("--rp2040", "node", "usb configured");
}
