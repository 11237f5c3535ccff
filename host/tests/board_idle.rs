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

use placedb::protocol::Phase;
use placedb_host::board::client;
use std::fmt;
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Most of a host core an idle board's emulator may run on.
const IDLE_SHARE: f64 = 0.10;
/// How long the board is left idle for each count.
const IDLE: Duration = Duration::from_secs(2);

/// `placedb device BOARD` on a free port, what it printed so far (its
/// emulator's output included), and its emulator; killed (with the
/// emulator, `PR_SET_PDEATHSIG`) on drop.
struct Device {
    child: Child,
    console: Arc<Mutex<String>>,
}

impl Device {
    fn start(board: &str, firmware: PathBuf) -> Device {
        let mut child = Command::new(env!("CARGO_BIN_EXE_placedb"))
            .args(["device", board, "--port", "0", "--firmware"])
            .arg(firmware)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .spawn()
            .expect("start placedb device");
        let console = Arc::new(Mutex::new(String::new()));
        let out = child.stdout.take().unwrap();
        let into = Arc::clone(&console);
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines() {
                let Ok(line) = line else { return };
                let mut c = into.lock().unwrap();
                c.push_str(&line);
                c.push('\n');
            }
        });
        Device { child, console }
    }

    fn console(&self) -> String {
        self.console.lock().unwrap().clone()
    }

    /// Waits until the console holds `needle`.
    fn wait_for(&mut self, needle: &str, timeout: Duration) {
        let end = Instant::now() + timeout;
        while !self.console().contains(needle) {
            if let Some(status) = self.child.try_wait().unwrap() {
                panic!("placedb device exited ({status}):\n{}", self.console());
            }
            assert!(
                Instant::now() < end,
                "no {needle:?} within {timeout:?}:\n{}",
                self.console()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// The board's port: the first `tcp:127.0.0.1:PORT` with a number.
    fn port(&self) -> String {
        let console = self.console();
        console
            .split("tcp:127.0.0.1:")
            .skip(1)
            .find_map(|rest| {
                let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
                (!digits.is_empty()).then(|| format!("tcp:127.0.0.1:{digits}"))
            })
            .unwrap_or_else(|| panic!("no port in:\n{console}"))
    }

    /// The pid of placedb's child named `comm` (its emulator).
    fn emulator(&self, comm: &str) -> u32 {
        let parent = self.child.id();
        std::fs::read_dir("/proc")
            .unwrap()
            .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
            .find(|&pid| {
                let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
                    return false;
                };
                // "pid (comm) state ppid ...": comm may hold spaces.
                let (Some(open), Some(close)) = (stat.find('('), stat.rfind(')')) else {
                    return false;
                };
                let ppid = stat[close + 1..].split_whitespace().nth(1);
                &stat[open + 1..close] == comm && ppid == Some(&parent.to_string())
            })
            .unwrap_or_else(|| panic!("placedb device has no child {comm}"))
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

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
fn an_idle_board_sleeps(board: &str, firmware: PathBuf, comm: &str, ready: &str) {
    let mut device = Device::start(board, firmware);
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
        placedb_host::testing::qemu_firmware(),
        "qemu-system-arm",
        // The firmware's line after its restore: its loop runs.
        "restored",
    );
}

#[test]
fn an_idle_emulated_pico_sleeps() {
    an_idle_board_sleeps(
        "--rp2040",
        placedb_host::testing::rp2040_firmware(),
        "node",
        "usb configured",
    );
}
