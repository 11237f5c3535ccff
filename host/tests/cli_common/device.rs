//! `placedb device` as a user runs it, for the tests of a board that
//! outlives each command: the real binary with the firmware built first,
//! its port read from the example command it prints, what it printed so
//! far, and its emulator's process.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// How long a board may take to boot and name its port.
pub const BOOT: Duration = Duration::from_secs(120);

/// The firmware of `board` (`--qemu` or `--rp2040`), built first.
pub fn firmware(board: &str) -> PathBuf {
    match board {
        "--qemu" => placedb_host::testing::qemu_firmware(),
        "--rp2040" => placedb_host::testing::rp2040_firmware(),
        other => panic!("no board {other}"),
    }
}

/// `placedb device BOARD --port 0 --firmware FIRMWARE ARGS`, its stdout
/// read as it comes (stderr left to the test's); killed on drop, its
/// emulator with it (`PR_SET_PDEATHSIG`).
pub struct Device {
    child: Child,
    console: Arc<Mutex<String>>,
    reader: Option<std::thread::JoinHandle<()>>,
}

impl Device {
    /// Starts it and returns at once.
    pub fn spawn(board: &str, args: &[&str]) -> Device {
        Device::spawn_with(board, &firmware(board), &[], args)
    }

    /// Starts it with `firmware`, its emulator with the environment `env`
    /// too (the harness's `PICO_FAULT`), and waits until it names its port.
    pub fn start_with(
        board: &str,
        firmware: &std::path::Path,
        env: &[(&str, &str)],
        args: &[&str],
    ) -> Device {
        let mut device = Device::spawn_with(board, firmware, env, args);
        device.wait_for("placedb stream --port ", BOOT);
        device
    }

    /// [`Device::spawn`] with `firmware` and `env`.
    pub fn spawn_with(
        board: &str,
        firmware: &std::path::Path,
        env: &[(&str, &str)],
        args: &[&str],
    ) -> Device {
        let mut child = Command::new(env!("CARGO_BIN_EXE_placedb"))
            .args(["device", board, "--port", "0", "--firmware"])
            .arg(firmware)
            .args(args)
            .envs(env.iter().copied())
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .spawn()
            .expect("start placedb device");
        let console = Arc::new(Mutex::new(String::new()));
        let out = child.stdout.take().unwrap();
        let into = Arc::clone(&console);
        let reader = std::thread::spawn(move || {
            for line in BufReader::new(out).lines() {
                let Ok(line) = line else { return };
                let mut c = into.lock().unwrap();
                c.push_str(&line);
                c.push('\n');
            }
        });
        Device {
            child,
            console,
            reader: Some(reader),
        }
    }

    /// Starts it and waits until it names its port in its example command
    /// (the board then takes commands: one sent before it has booted waits).
    pub fn start(board: &str, args: &[&str]) -> Device {
        let mut device = Device::spawn(board, args);
        device.wait_for("placedb stream --port ", BOOT);
        device
    }

    /// What it printed so far.
    pub fn console(&self) -> String {
        self.console.lock().unwrap().clone()
    }

    /// Waits until it printed a line holding `needle`; fails if it exits
    /// or `timeout` passes first.
    pub fn wait_for(&mut self, needle: &str, timeout: Duration) {
        self.wait_line(needle, timeout, |l| l.contains(needle));
    }

    /// Waits until it printed a line that is `found`, and returns it;
    /// fails, saying it waited for `what`, if it exits or `timeout`
    /// passes first.
    pub fn wait_line(
        &mut self,
        what: &str,
        timeout: Duration,
        found: impl Fn(&str) -> bool,
    ) -> String {
        let end = Instant::now() + timeout;
        loop {
            if let Some(line) = self.console().lines().find(|l| found(l)) {
                return line.to_string();
            }
            if let Some(status) = self.child.try_wait().unwrap() {
                panic!("placedb device exited ({status}):\n{}", self.console());
            }
            assert!(
                Instant::now() < end,
                "no {what:?} within {timeout:?}:\n{}",
                self.console()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// The port of its example command `placedb stream --port tcp:...`.
    pub fn port(&self) -> String {
        let console = self.console();
        let line = console
            .lines()
            .find(|l| l.contains("placedb stream --port "))
            .unwrap_or_else(|| panic!("no example command in:\n{console}"));
        let port = line
            .split("--port ")
            .nth(1)
            .and_then(|rest| rest.split_whitespace().next())
            .unwrap_or_default();
        let number = port.strip_prefix("tcp:127.0.0.1:").unwrap_or_default();
        assert!(
            !number.is_empty() && number.bytes().all(|b| b.is_ascii_digit()),
            "the example command names no port number: {line}"
        );
        port.to_string()
    }

    /// placedb's process id.
    pub fn id(&self) -> u32 {
        self.child.id()
    }

    /// The pid of placedb's child named `comm` (its emulator).
    pub fn emulator(&self, comm: &str) -> u32 {
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

    /// Stops it as a service manager does (SIGTERM: it stops its emulator
    /// first) and waits for it: its exit status and all it printed.
    pub fn stop(mut self) -> (ExitStatus, String) {
        let pid = libc::pid_t::try_from(self.child.id()).unwrap();
        // SAFETY: kill(2) on our own child, not reaped yet.
        unsafe { libc::kill(pid, libc::SIGTERM) };
        let status = self.child.wait().unwrap();
        // Its emulator, which shares the pipe, is gone too: the reader
        // ends with the last line.
        if let Some(reader) = self.reader.take() {
            reader.join().unwrap();
        }
        (status, self.console())
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `database.csv` and `labels.csv` of `placedb export --port PORT -o OUT`.
pub fn exported(port: &str, out: &str) -> (String, String) {
    let run = super::placedb(&["export", "--port", port, "-q", "-o", out]);
    assert!(run.status.success(), "{}", super::stderr(&run));
    tables(out)
}

/// `database.csv` and `labels.csv` of `placedb select SEQ --solver online
/// --profile PROFILE --stride 8 -o OUT`: the host replay a board's export
/// of a scan of SEQ at stride 8 must equal.
pub fn host_replay(seq: &str, profile: &str, out: &str) -> (String, String) {
    let run = super::placedb(&[
        "select",
        seq,
        "--solver",
        "online",
        "--profile",
        profile,
        "--stride",
        "8",
        "-q",
        "-o",
        out,
    ]);
    assert!(run.status.success(), "{}", super::stderr(&run));
    tables(out)
}

/// `database.csv` and `labels.csv` of the output directory `out`.
fn tables(out: &str) -> (String, String) {
    let read = |f: &str| std::fs::read_to_string(format!("{out}/{f}")).unwrap();
    (read("database.csv"), read("labels.csv"))
}
