//! The Raspberry Pi Pico firmware (`boards/rp-pico`) run instruction by
//! instruction under an RP2040 emulator: `rp2040js` (npm) driven by the Node
//! harness in `boards/rp-pico/emulator/harness.mjs`. The harness boots the
//! firmware through the real boot ROM (`../shared/rp2040/bootrom-b1.bin`)
//! and boot2, models the 2 MiB QSPI flash behind the ROM's flash functions
//! (backed by a file, so a restarted board restores its scan), enumerates the
//! firmware's USB CDC-ACM port as a USB host and bridges its bulk endpoints
//! to a TCP port on 127.0.0.1. [`Rp2040`] is that board as a [`Link`]; the
//! protocol, `placedb stream` and `placedb export` are unchanged.
//!
//! Needs Node (20 or later) and the harness's packages:
//! `cd boards/rp-pico/emulator && npm ci`.

use crate::board::error::DeviceError;
use crate::board::flash_timing::FlashTiming;
use crate::board::link::{Link, TcpLink};
use std::io::{self, BufRead, BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

/// Where the harness lives: `boards/rp-pico/emulator` of this source tree.
pub fn harness_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../boards/rp-pico/emulator")
}

/// How to install the harness's packages (for error messages).
pub const HARNESS_SETUP: &str = "cd boards/rp-pico/emulator && npm ci";

/// The RP2040 boot ROM image: `PLACEDB_RP2040_BOOTROM` if set, else
/// `../shared/rp2040/bootrom-b1.bin` beside this source tree.
pub fn bootrom() -> PathBuf {
    std::env::var_os("PLACEDB_RP2040_BOOTROM")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/rp2040/bootrom-b1.bin")
        })
}

/// Where the Pico firmware is built: `PLACEDB_RP2040_FIRMWARE` if set, else
/// `boards/rp-pico/target/thumbv6m-none-eabi/release/placedb-rp-pico`.
pub fn default_firmware() -> PathBuf {
    std::env::var_os("PLACEDB_RP2040_FIRMWARE")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../boards/rp-pico/target/thumbv6m-none-eabi/release/placedb-rp-pico")
        })
}

/// How to build the Pico firmware (for error messages).
pub const FIRMWARE_BUILD: &str = "cd boards/rp-pico && cargo build --release";

/// The Pico firmware, built (or brought up to date) first unless
/// `PLACEDB_RP2040_FIRMWARE` names one, as [`super::qemu::built_firmware`]
/// does for the QEMU board. Built once per process.
pub fn built_firmware() -> Result<PathBuf, String> {
    static BUILT: std::sync::OnceLock<Result<PathBuf, String>> = std::sync::OnceLock::new();
    BUILT
        .get_or_init(|| {
            super::build_board(
                "rp-pico",
                default_firmware(),
                std::env::var_os("PLACEDB_RP2040_FIRMWARE").is_none(),
                FIRMWARE_BUILD,
            )
        })
        .clone()
}

/// The fault-injection firmware (`boards/rp-pico`'s feature
/// `fault-injection`, profile `fault-injection`: a hang or a panic at the
/// frame the harness's `PICO_FAULT` plans), for the tests of the watchdog
/// and the panic handler; built (or brought up to date) first, once per
/// process. Never the firmware of a release.
pub fn built_fault_firmware() -> Result<PathBuf, String> {
    static BUILT: std::sync::OnceLock<Result<PathBuf, String>> = std::sync::OnceLock::new();
    BUILT
        .get_or_init(|| {
            super::build_board_with(
                "rp-pico",
                &[
                    "--profile",
                    "fault-injection",
                    "--features",
                    "fault-injection",
                ],
                Path::new(env!("CARGO_MANIFEST_DIR")).join(
                    "../boards/rp-pico/target/thumbv6m-none-eabi/fault-injection/placedb-rp-pico",
                ),
                true,
                "cd boards/rp-pico && cargo build --profile fault-injection --features fault-injection",
            )
        })
        .clone()
}

/// How to run the emulated Pico.
#[derive(Debug, Clone)]
pub struct Rp2040Options {
    /// The Node binary (default `node`).
    pub node: PathBuf,
    /// The boot ROM image (default [`bootrom`]).
    pub bootrom: PathBuf,
    /// The file holding the Pico's 2 MiB flash (created erased if missing);
    /// `None`: a fresh erased flash every run.
    pub flash: Option<PathBuf>,
    /// TCP port on 127.0.0.1 (0: any free port).
    pub port: u16,
    /// The harness stops by itself this long after it started (0: never).
    pub deadline: Duration,
    /// How long booting and enumerating may take.
    pub connect_timeout: Duration,
    /// How long the flash is busy per erase and program, in emulated time
    /// (default: the datasheet's typical figures).
    pub flash_timing: FlashTiming,
    /// A power cut during the firmware's `n`-th sector erase (from 1): the
    /// sector is left half erased and the emulator exits at once (code 4).
    pub cut_during_erase: Option<u32>,
    /// A power cut during the `n`-th 256-byte page programmed (from 1): the
    /// page's first half is programmed and the emulator exits at once
    /// (code 4).
    pub cut_during_program: Option<u32>,
    /// The flash chip's 64-bit unique ID (its 0x4B command's answer, first
    /// byte sent first in the high byte), from which the firmware makes its
    /// USB serial number: two boards with different IDs differ as two real
    /// Picos do. Default [`DEFAULT_UNIQUE_ID`].
    pub unique_id: u64,
    /// The host resets the bus (and enumerates again) once it has handed
    /// the firmware each of these FrameEnds (counted from 1), as a hub
    /// reset or a host's resume does mid-stream.
    pub bus_reset_after_frames: Vec<u32>,
}

/// The emulated flash chip's unique ID unless told otherwise (the harness's
/// default too).
pub const DEFAULT_UNIQUE_ID: u64 = 0xE661_4103_E745_2D2F;

impl Default for Rp2040Options {
    fn default() -> Self {
        Rp2040Options {
            node: "node".into(),
            bootrom: bootrom(),
            flash: None,
            port: 0,
            deadline: Duration::from_secs(600),
            connect_timeout: Duration::from_secs(30),
            flash_timing: FlashTiming::default(),
            cut_during_erase: None,
            cut_during_program: None,
            unique_id: DEFAULT_UNIQUE_ID,
            bus_reset_after_frames: Vec::new(),
        }
    }
}

/// The harness command line for `firmware` and `options`.
pub fn harness_command(firmware: &Path, options: &Rp2040Options) -> Command {
    let mut command = Command::new(&options.node);
    command
        .arg(harness_dir().join("harness.mjs"))
        .arg("--elf")
        .arg(firmware)
        .arg("--bootrom")
        .arg(&options.bootrom)
        .arg("--port")
        .arg(options.port.to_string())
        .arg("--flash-timing")
        .arg(options.flash_timing.name())
        .arg("--unique-id")
        .arg(format!("{:016X}", options.unique_id));
    if let Some(flash) = &options.flash {
        command.arg("--flash").arg(flash);
    }
    if let Some(n) = options.cut_during_erase {
        command.arg("--cut-during-erase").arg(n.to_string());
    }
    if let Some(n) = options.cut_during_program {
        command.arg("--cut-during-program").arg(n.to_string());
    }
    if !options.bus_reset_after_frames.is_empty() {
        let frames: Vec<String> = options
            .bus_reset_after_frames
            .iter()
            .map(u32::to_string)
            .collect();
        command
            .arg("--bus-reset-after-frames")
            .arg(frames.join(","));
    }
    if !options.deadline.is_zero() {
        command
            .arg("--deadline")
            .arg(options.deadline.as_secs_f64().to_string());
    }
    command.stdin(Stdio::null());
    command
}

/// The Pico's flash file: its 2 MiB QSPI flash, the firmware in the first
/// MiB, the log in the second ([`super::prepare_flash_file`]).
pub const FLASH_FILE: super::FlashFile = super::FlashFile {
    size: 2 << 20,
    of: "the Pico's flash",
};

/// Everything the harness needs, before it starts: what [`check_setup`]
/// checks, the port (one in use refused), and the flash file, made erased
/// if missing and refused if of another size ([`super::prepare_flash_file`]:
/// the harness would only print its usage).
pub fn prepare(firmware: &Path, options: &Rp2040Options) -> Result<(), DeviceError> {
    check_setup(firmware, options)?;
    if options.port != 0 {
        // Only tried here: the harness listens on it.
        drop(super::bind_port(options.port)?);
    }
    if let Some(flash) = &options.flash {
        super::prepare_flash_file(flash, FLASH_FILE)?;
    }
    Ok(())
}

/// Checks what the harness needs before starting it, with a message that
/// says how to fix each thing.
pub fn check_setup(firmware: &Path, options: &Rp2040Options) -> io::Result<()> {
    let missing = |what: String| Err(io::Error::new(io::ErrorKind::NotFound, what));
    if !firmware.is_file() {
        return missing(format!(
            "firmware ELF {} not found: build it with `{FIRMWARE_BUILD}`",
            firmware.display()
        ));
    }
    if !options.bootrom.is_file() {
        return missing(format!(
            "RP2040 boot ROM {} not found (../shared/rp2040/bootrom-b1.bin, or set PLACEDB_RP2040_BOOTROM)",
            options.bootrom.display()
        ));
    }
    if !harness_dir().join("node_modules/rp2040js").is_dir() {
        return missing(format!(
            "the emulator's packages are not installed: run `{HARNESS_SETUP}`"
        ));
    }
    Ok(())
}

/// The emulated Pico: the harness process and a TCP link to the firmware's
/// CDC-ACM port. The harness is killed when this is dropped (or by
/// [`Rp2040::power_cut`]); what it printed is in [`Rp2040::console`].
pub struct Rp2040 {
    link: TcpLink,
    child: Child,
    console: Arc<Mutex<String>>,
    threads: Vec<JoinHandle<()>>,
}

impl Rp2040 {
    /// Boots `firmware` with `options`, waits for USB enumeration and
    /// connects to the bridged port.
    pub fn start_with(firmware: &Path, options: &Rp2040Options) -> io::Result<Rp2040> {
        prepare(firmware, options).map_err(|e| match e {
            DeviceError::Io(e) => e,
            other => io::Error::other(other.to_string()),
        })?;
        let mut command = harness_command(firmware, options);
        command.stdout(Stdio::piped()).stderr(Stdio::piped());
        let mut child = command.spawn().map_err(|e| {
            io::Error::new(
                e.kind(),
                format!(
                    "cannot start {} (Node 20 or later is needed): {e}",
                    options.node.display()
                ),
            )
        })?;
        let console = Arc::new(Mutex::new(String::new()));
        let mut threads = Vec::new();
        if let Some(out) = child.stdout.take() {
            threads.push(collect_lines(out, Arc::clone(&console))?);
        }
        if let Some(err) = child.stderr.take() {
            threads.push(collect_lines(err, Arc::clone(&console))?);
        }
        let mut board = Booting {
            child: Some(child),
            console,
            threads,
        };
        let end = Instant::now() + options.connect_timeout;
        let port = loop {
            if let Some(port) = listening_port(&board.text()) {
                break port;
            }
            board.check_running(end)?;
            thread::sleep(Duration::from_millis(10));
        };
        while !board.text().contains("usb configured") {
            board.check_running(end)?;
            thread::sleep(Duration::from_millis(10));
        }
        let link = TcpLink::connect(("127.0.0.1", port), Duration::from_secs(5))?;
        board.into_board(link)
    }

    /// The USB serial number the firmware reported when the harness
    /// enumerated it (its serial number string descriptor, read as a host
    /// reads it), if the harness printed one.
    pub fn serial_number(&self) -> Option<String> {
        usb_serial_number(&self.console())
    }

    /// Everything the harness printed so far.
    pub fn console(&self) -> String {
        self.console.lock().map(|c| c.clone()).unwrap_or_default()
    }

    /// Waits until the console contains `needle`; false after `timeout`.
    pub fn wait_console(&self, needle: &str, timeout: Duration) -> bool {
        let end = Instant::now() + timeout;
        while !self.console().contains(needle) {
            if Instant::now() >= end {
                return false;
            }
            thread::sleep(Duration::from_millis(10));
        }
        true
    }

    /// The loopback address of the bridged port (`tcp:` + this is what
    /// `placedb --port` takes).
    pub fn address(&self) -> io::Result<std::net::SocketAddr> {
        self.link.peer_addr()
    }

    /// Closes the bridged port and opens it again, as one program closing
    /// the board's serial port and the next opening it: the harness's host
    /// drops DTR, then raises it. The new connection is made once the
    /// harness has seen the old one end.
    pub fn reopen(&mut self) -> io::Result<()> {
        let addr = self.link.peer_addr()?;
        let closed = self.console().matches("client closed").count();
        self.link.shutdown();
        let end = Instant::now() + Duration::from_secs(10);
        while self.console().matches("client closed").count() == closed {
            if Instant::now() >= end {
                return Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    "the RP2040 harness did not see the port closed within 10 s",
                ));
            }
            thread::sleep(Duration::from_millis(10));
        }
        self.link = TcpLink::connect(addr, Duration::from_secs(5))?;
        Ok(())
    }

    /// The harness's exit status if it has exited.
    pub fn try_wait(&mut self) -> io::Result<Option<ExitStatus>> {
        self.child.try_wait()
    }

    /// Stops the emulator cleanly (SIGTERM: it prints its `stats` line) and
    /// returns everything it printed.
    pub fn stop(mut self) -> String {
        self.terminate();
        self.console()
    }

    /// Kills the emulator at once (SIGKILL): a power cut. The flash file
    /// holds exactly what the firmware had erased and programmed.
    pub fn power_cut(mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    fn terminate(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            // SIGTERM through kill(1), so the harness can print its stats.
            let _ = Command::new("kill")
                .arg("-TERM")
                .arg(self.child.id().to_string())
                .status();
            let end = Instant::now() + Duration::from_secs(5);
            while matches!(self.child.try_wait(), Ok(None)) && Instant::now() < end {
                thread::sleep(Duration::from_millis(10));
            }
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// The harness while it boots: killed if dropped before it is ready.
struct Booting {
    child: Option<Child>,
    console: Arc<Mutex<String>>,
    threads: Vec<JoinHandle<()>>,
}

impl Booting {
    fn text(&self) -> String {
        self.console.lock().map(|c| c.clone()).unwrap_or_default()
    }

    /// An error if the harness exited or `end` passed.
    fn check_running(&mut self, end: Instant) -> io::Result<()> {
        let exited = match self.child.as_mut() {
            Some(child) => child.try_wait()?,
            None => return Err(io::ErrorKind::BrokenPipe.into()),
        };
        if let Some(status) = exited {
            // Let the output threads catch the harness's last words.
            for t in self.threads.drain(..) {
                let _ = t.join();
            }
            return Err(io::Error::new(
                io::ErrorKind::BrokenPipe,
                format!(
                    "the RP2040 emulator exited ({status}) before the firmware enumerated: {}",
                    self.text()
                ),
            ));
        }
        if Instant::now() >= end {
            return Err(io::Error::new(
                io::ErrorKind::TimedOut,
                format!(
                    "the emulated Pico did not enumerate on USB in time: {}",
                    self.text()
                ),
            ));
        }
        Ok(())
    }

    /// The running harness, with its link: the board.
    fn into_board(mut self, link: TcpLink) -> io::Result<Rp2040> {
        let child = self.child.take().ok_or(io::ErrorKind::BrokenPipe)?;
        Ok(Rp2040 {
            link,
            child,
            console: Arc::clone(&self.console),
            threads: std::mem::take(&mut self.threads),
        })
    }
}

impl Drop for Booting {
    fn drop(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// The serial number of the harness's "usb configured ... serial S ..." line.
fn usb_serial_number(console: &str) -> Option<String> {
    let line = console.lines().find(|l| l.starts_with("usb configured "))?;
    let serial = line.split(" serial ").nth(1)?.split(' ').next()?;
    (serial != "?").then(|| serial.to_string())
}

/// How deep the firmware's stack went, from the harness's exit line
/// "stack peak_bytes=P room_bytes=R" (the firmware paints its stack at
/// reset; the harness finds the deepest word no longer painted).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StackUse {
    /// Bytes of the deepest use since boot.
    pub peak: u64,
    /// Bytes between the statics' end and the top of RAM.
    pub room: u64,
}

/// The link-time minimum room for the stack: `STACK_RESERVE = NK;` in
/// `boards/rp-pico/memory.x`, read from that file so that the check
/// follows it (0, and every check fails, if it no longer says so).
pub fn stack_reserve() -> u64 {
    const MEMORY_X: &str = include_str!("../../../../boards/rp-pico/memory.x");
    MEMORY_X
        .lines()
        .find_map(|l| {
            let kib = l
                .trim()
                .strip_prefix("STACK_RESERVE = ")?
                .strip_suffix("K;")?;
            kib.parse::<u64>().ok()
        })
        .map_or(0, |kib| kib * 1024)
}

/// How far below [`stack_reserve`] the stack's peak must stay on the paths
/// the tests run: paths they do not run (rarer errors, other inputs) may go
/// deeper, and an overflow meets the MPU guard under the stack, which
/// restarts the board (boards/rp-pico/src/stack_guard.rs).
pub const STACK_MARGIN: u64 = 8 * 1024;

/// The [`StackUse`] a stopped harness printed, checked: an error in words
/// when it is missing or its peak is within [`STACK_MARGIN`] of
/// [`stack_reserve`].
pub fn check_stack(console: &str) -> Result<StackUse, String> {
    let st = stack_use(console).ok_or("the harness printed no stack line")?;
    let reserve = stack_reserve();
    if st.peak + STACK_MARGIN > reserve {
        return Err(format!(
            "the Pico's stack went {} bytes deep, within {} of the {} bytes reserved at link \
             time (memory.x STACK_RESERVE): raise the reserve or make the path shallower",
            st.peak, STACK_MARGIN, reserve
        ));
    }
    Ok(st)
}

/// The [`StackUse`] a stopped harness printed, if it printed one.
pub fn stack_use(console: &str) -> Option<StackUse> {
    let line = console.lines().find(|l| l.starts_with("stack "))?;
    let field = |name: &str| -> Option<u64> {
        line.split(' ')
            .find_map(|w| w.strip_prefix(name)?.strip_prefix('='))?
            .parse()
            .ok()
    };
    Some(StackUse {
        peak: field("peak_bytes")?,
        room: field("room_bytes")?,
    })
}

/// The port of the harness's "listening tcp:127.0.0.1:PORT" line.
fn listening_port(console: &str) -> Option<u16> {
    let rest = console.split("listening tcp:127.0.0.1:").nth(1)?;
    rest.lines().next()?.trim().parse().ok()
}

impl Link for Rp2040 {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.link.send(bytes)
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Vec<u8>> {
        self.link.recv(timeout)
    }
}

impl Drop for Rp2040 {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// Copies a child's output, line by line, into `console` until it closes.
fn collect_lines(
    from: impl Read + Send + 'static,
    console: Arc<Mutex<String>>,
) -> io::Result<JoinHandle<()>> {
    thread::Builder::new()
        .name("placedb-rp2040-console".into())
        .spawn(move || {
            for line in BufReader::new(from).lines() {
                let Ok(line) = line else { return };
                if let Ok(mut c) = console.lock() {
                    c.push_str(&line);
                    c.push('\n');
                }
            }
        })
}

/// The emulated Pico of `placedb device --rp2040`, started in the
/// foreground on `options.port` (0: a free port, which the harness
/// prints) once [`prepare`] has passed: returns the harness's process once
/// the firmware is up (enumerated on USB), or the signal that stopped it
/// while it booted. What the harness prints goes on to placedb's stdout as
/// it comes. `at_boot`, if given, is then called with a connection to the
/// board's port, before the port is announced, to ask the board what it
/// restored (the harness's lines on that connection are not passed on,
/// and its waits end early on a stop signal). Wait for the process with
/// [`super::wait_in_foreground`], which stops the emulator first on
/// Ctrl-C, SIGTERM or SIGHUP ([`super::foreground`]).
pub fn spawn_foreground(
    firmware: &Path,
    options: &Rp2040Options,
    at_boot: Option<super::AtBoot<'_>>,
) -> Result<Foreground, DeviceError> {
    let mut command = harness_command(firmware, options);
    command.stdout(Stdio::piped());
    // The emulator ends with placedb, whatever stops it (foreground.rs).
    let mut child = super::foreground::spawn(&mut command).map_err(|e| {
        DeviceError::Input(format!(
            "cannot start node (Node 20 or later): {}",
            crate::error::io_words(&e)
        ))
    })?;
    let console = Arc::new(Mutex::new(String::new()));
    let private = Arc::new(AtomicBool::new(false));
    if let Some(out) = child.stdout.take() {
        pass_on(out, Arc::clone(&console), Arc::clone(&private))?;
    }
    let text = || console.lock().map(|c| c.clone()).unwrap_or_default();
    let up = super::foreground::wait_until(&mut child, &mut || text().contains("usb configured"))?;
    match up {
        None => {}
        Some(super::foreground::Ended::Stopped(signal)) => return Ok(Foreground::Stopped(signal)),
        Some(super::foreground::Ended::Exited(status)) => {
            return Err(DeviceError::Io(io::Error::other(format!(
                "the RP2040 emulator exited ({status}) before the firmware was up"
            ))))
        }
    }
    let port = listening_port(&text()).ok_or_else(|| {
        DeviceError::Io(io::Error::other(
            "the RP2040 emulator named no port before the firmware was up",
        ))
    })?;
    if let Some(at_boot) = at_boot {
        let count = |what: &str| text().matches(what).count();
        let closed = count("client closed");
        private.store(true, Ordering::SeqCst);
        if let Ok(link) = TcpLink::connect(("127.0.0.1", port), Duration::from_secs(5)) {
            at_boot(&mut super::foreground::Stoppable(link));
            // Dropped: closed. Its "client closed" is not passed on either.
            let end = Instant::now() + Duration::from_secs(5);
            while count("client closed") == closed && Instant::now() < end {
                thread::sleep(Duration::from_millis(10));
            }
        }
        private.store(false, Ordering::SeqCst);
    }
    Ok(Foreground::Up(child, port))
}

/// How [`spawn_foreground`] left the emulated Pico.
pub enum Foreground {
    /// Up: the harness's process, to wait for, and the board's port.
    Up(Child, u16),
    /// Stopped by this signal while it booted.
    Stopped(i32),
}

/// Passes the harness's lines on to placedb's stdout and into `console`,
/// but for those on a connection placedb makes itself (`private`): the
/// harness's "client connected" and "client closed".
fn pass_on(
    from: impl Read + Send + 'static,
    console: Arc<Mutex<String>>,
    private: Arc<AtomicBool>,
) -> io::Result<JoinHandle<()>> {
    thread::Builder::new()
        .name("placedb-rp2040-stdout".into())
        .spawn(move || {
            for line in BufReader::new(from).lines() {
                let Ok(line) = line else { return };
                if !(private.load(Ordering::SeqCst) && line.starts_with("client ")) {
                    let mut out = io::stdout().lock();
                    let _ = writeln!(out, "{line}");
                    let _ = out.flush();
                }
                if let Ok(mut c) = console.lock() {
                    c.push_str(&line);
                    c.push('\n');
                }
            }
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_stack_line_is_read_and_checked() {
        assert!(
            stack_reserve() >= 16 * 1024,
            "memory.x's STACK_RESERVE not read"
        );
        let console = "stats pc=0x1 cycles=2\nstack peak_bytes=13048 room_bytes=33768\n";
        let st = stack_use(console).unwrap();
        assert_eq!((st.peak, st.room), (13048, 33768));
        assert_eq!(check_stack(console), Ok(st));
        let deep = "stack peak_bytes=25000 room_bytes=33768";
        assert!(check_stack(deep).unwrap_err().contains("25000 bytes deep"));
        assert!(check_stack("stats pc=0x1").is_err());
    }

    #[test]
    fn harness_command_names_every_file() {
        let options = Rp2040Options {
            flash: Some("out/pico.flash".into()),
            port: 4321,
            deadline: Duration::from_secs(90),
            ..Rp2040Options::default()
        };
        let command = harness_command(Path::new("fw.elf"), &options);
        let args: Vec<_> = command.get_args().map(|a| a.to_string_lossy()).collect();
        assert!(args[0].ends_with("boards/rp-pico/emulator/harness.mjs"));
        assert!(args.windows(2).any(|w| w == ["--elf", "fw.elf"]));
        assert!(args.windows(2).any(|w| w == ["--port", "4321"]));
        assert!(args.windows(2).any(|w| w == ["--flash", "out/pico.flash"]));
        assert!(args.windows(2).any(|w| w == ["--deadline", "90"]));
        assert!(args.windows(2).any(|w| w == ["--flash-timing", "typical"]));
        assert!(args
            .windows(2)
            .any(|w| w == ["--unique-id", "E6614103E7452D2F"]));
        assert!(args
            .windows(2)
            .any(|w| w[0] == "--bootrom" && w[1].ends_with("bootrom-b1.bin")));
    }

    #[test]
    fn the_serial_number_is_read_from_the_enumeration_line() {
        let console = "listening tcp:127.0.0.1:4000\nusb configured 16c0:27dd serial placedb.example:0123456789ABCDEF ep0 64 B, bulk in 2 out 1\n";
        assert_eq!(
            usb_serial_number(console).as_deref(),
            Some("placedb.example:0123456789ABCDEF")
        );
        assert_eq!(
            usb_serial_number("usb configured 16c0:27dd serial ? ep0 64 B"),
            None
        );
        assert_eq!(usb_serial_number("listening tcp:127.0.0.1:4000"), None);
    }

    #[test]
    fn a_missing_firmware_is_reported() {
        let err = Rp2040::start_with(Path::new("/nonexistent/fw.elf"), &Rp2040Options::default())
            .err()
            .unwrap();
        assert_eq!(err.kind(), io::ErrorKind::NotFound);
        assert!(err.to_string().contains(FIRMWARE_BUILD));
    }
}
