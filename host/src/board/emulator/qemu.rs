//! The QEMU board (`boards/qemu-mps2-an386`, mps2-an386, Cortex-M4F): its
//! command line, its flash file, building its firmware, and [`Qemu`], the
//! running board as a [`Link`] (its UART0 over loopback TCP).

use crate::board::error::DeviceError;
use crate::board::link::{Link, TcpLink};
use std::io::{self, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

/// How to launch the emulated board.
#[derive(Debug, Clone)]
pub struct QemuOptions {
    /// The emulator binary (default `qemu-system-arm`).
    pub program: PathBuf,
    /// The QEMU machine (default `mps2-an386`).
    pub machine: String,
    /// The CPU (default `cortex-m4`).
    pub cpu: String,
    /// Extra arguments, e.g. `-icount shift=0` for deterministic timing.
    pub extra_args: Vec<String>,
    /// How long QEMU may take to connect its UART to the host.
    pub connect_timeout: Duration,
    /// QEMU is killed this long after the start, whatever happens.
    pub deadline: Duration,
    /// A file holding the board's emulated NOR flash (PSRAM); kept across
    /// runs. QEMU maps the board's 16 MiB PSRAM (`0x2100_0000`, QEMU's machine
    /// RAM) from it, shared, so what the firmware stores there survives QEMU
    /// being killed; the firmware uses its first 1 MiB as flash. A missing (or
    /// empty) file is created holding [`FLASH_FILE_SIZE`] bytes of 0xFF, an
    /// erased chip. `None` (the default): the PSRAM is fresh zeroed memory.
    pub flash: Option<PathBuf>,
}

/// Size of a [`QemuOptions::flash`] file: the whole PSRAM of `mps2-an386`
/// (QEMU insists the machine RAM of the MPS2 boards is exactly 16 MiB).
pub const FLASH_FILE_SIZE: u64 = 16 << 20;

/// QEMU object id of the memory backend holding the flash file.
const FLASH_BACKEND_ID: &str = "placedb-flash";

/// The QEMU board's flash file ([`super::prepare_flash_file`]).
pub const FLASH_FILE: super::FlashFile = super::FlashFile {
    size: FLASH_FILE_SIZE,
    of: "the QEMU board's flash (its PSRAM)",
};

/// Creates the flash file `path` (holding [`FLASH_FILE_SIZE`] bytes of 0xFF, an
/// erased chip) if it is missing or empty; leaves an existing one as it is.
/// Errors if it exists with another size (QEMU would refuse it).
pub fn prepare_flash_file(path: &Path) -> io::Result<()> {
    super::prepare_flash_file(path, FLASH_FILE)
}

/// `path` as a QEMU option value: commas doubled.
fn qemu_option_path(path: &Path) -> std::ffi::OsString {
    match path.to_str() {
        Some(text) => text.replace(',', ",,").into(),
        None => path.as_os_str().to_os_string(),
    }
}

impl Default for QemuOptions {
    fn default() -> Self {
        QemuOptions {
            program: "qemu-system-arm".into(),
            machine: "mps2-an386".into(),
            cpu: "cortex-m4".into(),
            extra_args: Vec::new(),
            connect_timeout: Duration::from_secs(10),
            deadline: Duration::from_secs(600),
            flash: None,
        }
    }
}

/// The QEMU command line booting `firmware` with UART0 on chardev `serial`
/// (e.g. `tcp:127.0.0.1:PORT` to connect to a host listening there, or
/// `tcp:127.0.0.1:PORT,server,nowait` to listen). Standard input is closed.
///
/// With [`QemuOptions::flash`] the machine RAM comes from that file:
/// `-machine MACHINE,memory-backend=placedb-flash -object
/// memory-backend-file,id=placedb-flash,size=16M,mem-path=FILE,share=on`;
/// the caller creates the file first ([`prepare_flash_file`], as
/// [`Qemu::start_with`] does).
pub fn qemu_command(firmware: &Path, options: &QemuOptions, serial: &str) -> Command {
    let mut command = Command::new(&options.program);
    command.args(["-cpu", &options.cpu]);
    match &options.flash {
        None => {
            command.args(["-machine", &options.machine]);
        }
        Some(file) => {
            let mut backend = std::ffi::OsString::from(format!(
                "memory-backend-file,id={FLASH_BACKEND_ID},size={FLASH_FILE_SIZE},share=on,mem-path="
            ));
            backend.push(qemu_option_path(file));
            command
                .arg("-machine")
                .arg(format!(
                    "{},memory-backend={FLASH_BACKEND_ID}",
                    options.machine
                ))
                .arg("-object")
                .arg(backend);
        }
    }
    command
        .args(["-display", "none", "-monitor", "none"])
        .args(["-semihosting-config", "enable=on,target=native"])
        .arg("-serial")
        .arg(serial)
        .args(&options.extra_args)
        .arg("-kernel")
        .arg(firmware)
        .stdin(Stdio::null());
    command
}

/// Where the QEMU board's firmware is built: `PLACEDB_QEMU_FIRMWARE` if set,
/// else `boards/qemu-mps2-an386/target/thumbv7em-none-eabihf/release/placedb-qemu-mps2-an386`
/// of this source tree.
pub fn default_firmware() -> PathBuf {
    std::env::var_os("PLACEDB_QEMU_FIRMWARE")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR")).join(
                "../boards/qemu-mps2-an386/target/thumbv7em-none-eabihf/release/placedb-qemu-mps2-an386",
            )
        })
}

/// How to build the QEMU firmware (for error messages).
pub const FIRMWARE_BUILD: &str = "cd boards/qemu-mps2-an386 && cargo build --release";

/// The QEMU firmware, built (or brought up to date) first unless
/// `PLACEDB_QEMU_FIRMWARE` names one: tests then always run the firmware of
/// the core they test. Built once per process.
pub fn built_firmware() -> Result<PathBuf, String> {
    static BUILT: std::sync::OnceLock<Result<PathBuf, String>> = std::sync::OnceLock::new();
    BUILT
        .get_or_init(|| {
            super::build_board(
                "qemu-mps2-an386",
                default_firmware(),
                std::env::var_os("PLACEDB_QEMU_FIRMWARE").is_none(),
                FIRMWARE_BUILD,
            )
        })
        .clone()
}

/// Shared between the owner and the watchdog thread.
struct Watch {
    child: Mutex<Child>,
    stop: Mutex<bool>,
    wake: Condvar,
}

/// An emulated board running a firmware ELF, its UART0 connected to the host
/// over loopback TCP.
///
/// The host listens on `127.0.0.1:0` and starts
/// `qemu-system-arm -cpu cortex-m4 -machine mps2-an386 -display none -monitor none
/// -semihosting-config enable=on,target=native -serial tcp:127.0.0.1:PORT -kernel ELF`;
/// without `,server` QEMU's `tcp:` chardev is a *client* and connects to the
/// host at start-up. Semihosting output (stdout and stderr of QEMU) is collected
/// in [`Qemu::console`]. QEMU is killed when the `Qemu` is dropped and, by a
/// watchdog, at the deadline.
pub struct Qemu {
    link: TcpLink,
    watch: Arc<Watch>,
    console: Arc<Mutex<Vec<u8>>>,
    threads: Vec<JoinHandle<()>>,
}

impl Qemu {
    /// Boots `firmware` with default options and the given deadline.
    pub fn start(firmware: &Path, deadline: Duration) -> io::Result<Qemu> {
        Qemu::start_with(
            firmware,
            QemuOptions {
                deadline,
                ..QemuOptions::default()
            },
        )
    }

    /// Boots `firmware` with `options`.
    pub fn start_with(firmware: &Path, options: QemuOptions) -> io::Result<Qemu> {
        if !firmware.is_file() {
            return Err(io::Error::new(
                io::ErrorKind::NotFound,
                format!("firmware ELF {} not found", firmware.display()),
            ));
        }
        if let Some(file) = &options.flash {
            prepare_flash_file(file)?;
        }
        let started = Instant::now();
        let listener = TcpListener::bind(("127.0.0.1", 0))?;
        let port = listener.local_addr()?.port();
        let mut command = qemu_command(firmware, &options, &format!("tcp:127.0.0.1:{port}"));
        command.stdout(Stdio::piped()).stderr(Stdio::piped());
        let mut child = command.spawn().map_err(|e| {
            io::Error::new(
                e.kind(),
                format!(
                    "cannot start {}: {}",
                    options.program.display(),
                    crate::error::io_words(&e)
                ),
            )
        })?;
        let console = Arc::new(Mutex::new(Vec::new()));
        let mut threads = Vec::new();
        if let Some(out) = child.stdout.take() {
            threads.push(collect(out, Arc::clone(&console))?);
        }
        if let Some(err) = child.stderr.take() {
            threads.push(collect(err, Arc::clone(&console))?);
        }
        let watch = Arc::new(Watch {
            child: Mutex::new(child),
            stop: Mutex::new(false),
            wake: Condvar::new(),
        });
        threads.push(watchdog(Arc::clone(&watch), started + options.deadline)?);
        let accepted = accept_within(&listener, options.connect_timeout, &mut || {
            let mut child = watch.child.lock().ok()?;
            child.try_wait().ok().flatten()
        });
        let stream = match accepted {
            Ok(stream) => stream,
            Err(e) => {
                let mut qemu_fail = Qemu::stop(&watch, &mut threads);
                let text =
                    String::from_utf8_lossy(&console.lock().map(|c| c.clone()).unwrap_or_default())
                        .into_owned();
                qemu_fail.push_str(&text);
                return Err(io::Error::new(
                    e.kind(),
                    format!("QEMU did not connect its UART: {e}; QEMU said: {qemu_fail}"),
                ));
            }
        };
        let link = TcpLink::from_stream(stream)?;
        Ok(Qemu {
            link,
            watch,
            console,
            threads,
        })
    }

    /// Kills QEMU and joins the helper threads; returns a note on how it ended.
    fn stop(watch: &Watch, threads: &mut Vec<JoinHandle<()>>) -> String {
        if let Ok(mut stop) = watch.stop.lock() {
            *stop = true;
        }
        watch.wake.notify_all();
        let mut note = String::new();
        if let Ok(mut child) = watch.child.lock() {
            if let Ok(Some(status)) = child.try_wait() {
                note = format!("(exited: {status}) ");
            }
            let _ = child.kill();
            let _ = child.wait();
        }
        for t in threads.drain(..) {
            let _ = t.join();
        }
        note
    }

    /// Everything QEMU printed so far (semihosting output and QEMU's messages).
    pub fn console(&self) -> String {
        let bytes = self.console.lock().map(|c| c.clone()).unwrap_or_default();
        String::from_utf8_lossy(&bytes).into_owned()
    }

    /// Waits until the console contains `needle`; false after `timeout`.
    pub fn wait_console(&self, needle: &str, timeout: Duration) -> bool {
        let end = Instant::now() + timeout;
        loop {
            if self.console().contains(needle) {
                return true;
            }
            if Instant::now() >= end {
                return false;
            }
            thread::sleep(Duration::from_millis(10));
        }
    }

    /// QEMU's exit status if it has exited (semihosting exit: 0 success, 1 failure).
    pub fn try_wait(&self) -> io::Result<Option<ExitStatus>> {
        match self.watch.child.lock() {
            Ok(mut child) => child.try_wait(),
            Err(_) => Err(io::Error::other("QEMU watch poisoned")),
        }
    }

    /// Waits up to `timeout` for QEMU to exit by itself.
    pub fn wait_exit(&self, timeout: Duration) -> io::Result<Option<ExitStatus>> {
        let end = Instant::now() + timeout;
        loop {
            if let Some(status) = self.try_wait()? {
                return Ok(Some(status));
            }
            if Instant::now() >= end {
                return Ok(None);
            }
            thread::sleep(Duration::from_millis(10));
        }
    }

    /// The link to the board's UART0.
    pub fn link(&mut self) -> &mut TcpLink {
        &mut self.link
    }
}

impl Link for Qemu {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.link.send(bytes)
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Vec<u8>> {
        self.link.recv(timeout)
    }
}

impl Drop for Qemu {
    fn drop(&mut self) {
        Qemu::stop(&self.watch, &mut self.threads);
    }
}

/// Copies a child's output stream into `console` until it closes.
fn collect(
    mut from: impl Read + Send + 'static,
    console: Arc<Mutex<Vec<u8>>>,
) -> io::Result<JoinHandle<()>> {
    thread::Builder::new()
        .name("placedb-qemu-console".into())
        .spawn(move || {
            let mut buf = [0u8; 4096];
            loop {
                match from.read(&mut buf) {
                    Ok(0) => return,
                    Ok(n) => {
                        if let Ok(mut c) = console.lock() {
                            c.extend_from_slice(&buf[..n]);
                        }
                    }
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                    Err(_) => return,
                }
            }
        })
}

/// Kills the child at `deadline` unless told to stop first.
fn watchdog(watch: Arc<Watch>, deadline: Instant) -> io::Result<JoinHandle<()>> {
    thread::Builder::new()
        .name("placedb-qemu-watchdog".into())
        .spawn(move || {
            let Ok(mut stop) = watch.stop.lock() else {
                return;
            };
            while !*stop {
                let left = deadline.saturating_duration_since(Instant::now());
                if left.is_zero() {
                    drop(stop);
                    if let Ok(mut child) = watch.child.lock() {
                        let _ = child.kill();
                    }
                    return;
                }
                stop = match watch.wake.wait_timeout(stop, left) {
                    Ok((guard, _)) => guard,
                    Err(_) => return,
                };
            }
        })
}

/// Accepts one connection within `timeout`, giving up early if QEMU exits
/// (`exited` says so).
fn accept_within(
    listener: &TcpListener,
    timeout: Duration,
    exited: &mut dyn FnMut() -> Option<ExitStatus>,
) -> io::Result<TcpStream> {
    listener.set_nonblocking(true)?;
    let end = Instant::now() + timeout;
    loop {
        match listener.accept() {
            Ok((stream, peer)) => {
                if !peer.ip().is_loopback() {
                    continue;
                }
                stream.set_nonblocking(false)?;
                return Ok(stream);
            }
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => {}
            Err(e) => return Err(e),
        }
        if let Some(status) = exited() {
            return Err(io::Error::new(
                io::ErrorKind::BrokenPipe,
                format!("QEMU exited ({status}) before connecting"),
            ));
        }
        if Instant::now() >= end {
            return Err(io::Error::new(
                io::ErrorKind::TimedOut,
                format!("no connection within {}", crate::error::seconds(timeout)),
            ));
        }
        thread::sleep(Duration::from_millis(5));
    }
}

/// The emulated board of `placedb device --qemu`, started in the
/// foreground with UART0 on `tcp:127.0.0.1:PORT` (0: a free port), one
/// program at a time ([`super::one_client`]: placedb listens there and
/// QEMU's UART connects to placedb): returns QEMU's process. Wait for it with
/// [`super::wait_in_foreground`]: Ctrl-C, SIGTERM or SIGHUP stop QEMU first,
/// and on Linux QEMU is killed if placedb dies any other way
/// ([`super::foreground`]). `icount` makes instruction counting exact.
/// `announce` is called with the port once it is listening, before QEMU
/// starts (so what it prints comes before the firmware's boot line).
/// `at_boot`, if given, is called with the board's UART before any program
/// is served (one connecting meanwhile waits), to ask the board what it
/// restored; its waits end early on a stop signal.
pub fn spawn_foreground(
    firmware: Option<PathBuf>,
    port: u16,
    icount: bool,
    flash: Option<&Path>,
    announce: &mut dyn FnMut(u16),
    at_boot: Option<super::AtBoot<'_>>,
) -> Result<std::process::Child, DeviceError> {
    let firmware = firmware.unwrap_or_else(default_firmware);
    if !firmware.is_file() {
        return Err(DeviceError::Input(format!(
            "firmware {} not found: build it with `{}` (or pass --firmware ELF)",
            firmware.display(),
            FIRMWARE_BUILD
        )));
    }
    // The user's port first: a port in use is refused before anything
    // (the flash file included) is made.
    let listener = super::bind_port(port)?;
    let port = listener.local_addr()?.port();
    if let Some(f) = flash {
        prepare_flash_file(f)?;
    }
    let uart = TcpListener::bind(("127.0.0.1", 0))?;
    let uart_port = uart.local_addr()?.port();
    announce(port);
    let mut options = QemuOptions {
        flash: flash.map(Path::to_path_buf),
        ..QemuOptions::default()
    };
    if icount {
        options.extra_args = vec!["-icount".into(), "shift=0".into()];
    }
    let mut command = qemu_command(&firmware, &options, &format!("tcp:127.0.0.1:{uart_port}"));
    // QEMU ends with placedb, whatever stops it (foreground.rs).
    let mut child = super::foreground::spawn(&mut command).map_err(|e| {
        DeviceError::Io(io::Error::new(
            e.kind(),
            format!(
                "cannot start {} (apt-get install qemu-system-arm): {e}",
                options.program.display()
            ),
        ))
    })?;
    let connected = accept_within(&uart, Duration::from_secs(30), &mut || {
        child.try_wait().ok().flatten()
    });
    let board = match connected {
        Ok(board) => board,
        Err(e) => {
            let _ = child.kill();
            let _ = child.wait();
            return Err(DeviceError::Io(io::Error::new(
                e.kind(),
                format!("QEMU did not connect its UART: {e}"),
            )));
        }
    };
    if let Some(at_boot) = at_boot {
        at_boot(&mut super::foreground::Stoppable(UartAtBoot(&board)));
    }
    super::one_client::serve(listener, board)?;
    Ok(child)
}

/// The board's UART as a link while placedb alone holds it, at boot before
/// [`super::one_client`] serves it: a read waits on the stream itself (no
/// reader thread, which would keep reading), so the stream is handed on
/// whole.
struct UartAtBoot<'a>(&'a TcpStream);

impl Link for UartAtBoot<'_> {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        let mut stream = self.0;
        stream.write_all(bytes)?;
        stream.flush()
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Vec<u8>> {
        let mut stream = self.0;
        stream.set_read_timeout(Some(timeout.max(Duration::from_millis(1))))?;
        let mut buf = vec![0u8; 4096];
        let read = stream.read(&mut buf);
        stream.set_read_timeout(None)?;
        match read {
            Ok(0) => Err(io::Error::new(
                io::ErrorKind::UnexpectedEof,
                "QEMU closed the board's UART",
            )),
            Ok(n) => {
                buf.truncate(n);
                Ok(buf)
            }
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) =>
            {
                Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!(
                        "no bytes from the board within {}",
                        crate::error::seconds(timeout)
                    ),
                ))
            }
            Err(e) => Err(e),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn qemu_command_maps_the_flash_file() {
        let plain = qemu_command(Path::new("fw.elf"), &QemuOptions::default(), "null");
        let args: Vec<_> = plain.get_args().map(|a| a.to_string_lossy()).collect();
        assert!(args.windows(2).any(|w| w == ["-machine", "mps2-an386"]));
        assert!(!args.iter().any(|a| a.contains("memory-backend")));

        let dir = std::env::temp_dir().join(format!("placedb-flash-cmd-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("a,b.flash");
        let options = QemuOptions {
            flash: Some(file.clone()),
            ..QemuOptions::default()
        };
        let command = qemu_command(Path::new("fw.elf"), &options, "null");
        let args: Vec<_> = command.get_args().map(|a| a.to_string_lossy()).collect();
        assert!(args
            .windows(2)
            .any(|w| w == ["-machine", "mps2-an386,memory-backend=placedb-flash"]));
        let object = format!(
            "memory-backend-file,id=placedb-flash,size=16777216,share=on,mem-path={}",
            file.display().to_string().replace(',', ",,")
        );
        assert!(args.windows(2).any(|w| w[0] == "-object" && w[1] == object));
        // Building the command touches no file.
        assert!(!file.exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn flash_file_is_created_erased_and_then_kept() {
        let dir = std::env::temp_dir().join(format!("placedb-flash-file-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("board.flash");
        prepare_flash_file(&file).unwrap();
        let bytes = std::fs::read(&file).unwrap();
        assert_eq!(bytes.len() as u64, FLASH_FILE_SIZE);
        assert!(bytes.iter().all(|&b| b == 0xFF));
        // An existing image is left alone.
        let mut kept = bytes;
        kept[0] = 0x12;
        std::fs::write(&file, &kept).unwrap();
        prepare_flash_file(&file).unwrap();
        assert_eq!(std::fs::read(&file).unwrap()[0], 0x12);
        // An empty file is filled; a file of another size is refused.
        std::fs::write(&file, b"").unwrap();
        prepare_flash_file(&file).unwrap();
        assert_eq!(std::fs::metadata(&file).unwrap().len(), FLASH_FILE_SIZE);
        std::fs::write(&file, [0u8; 10]).unwrap();
        let err = prepare_flash_file(&file).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::InvalidData);
        assert_eq!(
            std::fs::read_dir(&dir).unwrap().count(),
            1,
            "no temporary left"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn qemu_reports_a_missing_firmware() {
        let err = Qemu::start(Path::new("/nonexistent/fw.elf"), Duration::from_secs(1)).err();
        assert_eq!(err.map(|e| e.kind()), Some(io::ErrorKind::NotFound));
    }
}
