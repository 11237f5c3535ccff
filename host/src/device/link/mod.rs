//! Host-side transports to a placedb device, and a protocol client on top.
//!
//! - [`Link`]: a byte pipe with a receive timeout. Implementations: [`TcpLink`]
//!   (`tcp:HOST:PORT`: an emulator such as `placedb device --qemu`, or a
//!   serial-to-TCP bridge), [`SerialLink`] (`serial:PATH` or a bare device path
//!   such as `/dev/ttyACM0`: a board over USB CDC-ACM or a UART), [`LocalLink`]
//!   (`local:PROFILE`: the device state machine of the core in-process, no
//!   hardware) and [`Qemu`] (launches the emulated board and talks to its UART0
//!   over loopback TCP).
//! - [`Client`]: frames [`HostMessage`]s with sequence numbers, decodes
//!   [`DeviceMessage`]s, and matches terminal replies to requests.
//!
//! Every link reads in a background thread into a channel, so writing a long
//! stream never deadlocks against a device that is itself blocked writing
//! replies (the emulated UART moves only about 10 KB/s into the firmware).

pub mod fault;

use placedb::protocol::{
    encode, DeviceMessage, FrameDecoder, HostFrame, HostMessage, ProtocolError, Push, MAX_FRAME_LEN,
};
use std::io::{self, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream, ToSocketAddrs};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

/// A bidirectional byte stream to a device.
pub trait Link: Send {
    /// Writes every byte.
    fn send(&mut self, bytes: &[u8]) -> io::Result<()>;

    /// Waits up to `timeout` for bytes and returns those available (never
    /// empty). Errors: `TimedOut` when nothing arrived, `UnexpectedEof` when the
    /// device closed the link.
    fn recv(&mut self, timeout: Duration) -> io::Result<Vec<u8>>;
}

impl<L: Link + ?Sized> Link for Box<L> {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        (**self).send(bytes)
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Vec<u8>> {
        (**self).recv(timeout)
    }
}

/// Opens a link from its command-line spelling: `tcp:HOST:PORT`,
/// `serial:PATH` (or a bare path such as `/dev/ttyACM0` or `COM3`), or
/// `local:PROFILE` (`local:ram512k`: the core's device in-process).
pub fn open(spec: &str, timeout: Duration) -> io::Result<Box<dyn Link>> {
    if let Some(addr) = spec.strip_prefix("tcp:") {
        return Ok(Box::new(TcpLink::connect(addr, timeout)?));
    }
    if let Some(profile) = spec.strip_prefix("local:") {
        return Ok(Box::new(LocalLink::start(profile)?));
    }
    let path = spec.strip_prefix("serial:").unwrap_or(spec);
    let looks_like_port = spec.starts_with("serial:")
        || path.starts_with('/')
        || path.to_ascii_uppercase().starts_with("COM");
    if looks_like_port && !path.is_empty() {
        return Ok(Box::new(SerialLink::open(path)?));
    }
    Err(io::Error::new(
        io::ErrorKind::InvalidInput,
        format!(
            "unknown port `{spec}`: expected tcp:HOST:PORT, a serial device path \
             (/dev/ttyACM0, serial:PATH) or local:PROFILE"
        ),
    ))
}

/// Chunks of bytes (or the error that ended them) from a reader thread.
type Chunks = Receiver<io::Result<Vec<u8>>>;

/// Reads `from` in a thread into a channel until it fails or closes.
fn reader_thread(
    mut from: impl Read + Send + 'static,
    tolerate_timeouts: bool,
) -> io::Result<(Chunks, JoinHandle<()>)> {
    let (tx, rx) = mpsc::channel();
    let handle = thread::Builder::new()
        .name("placedb-link-rx".into())
        .spawn(move || {
            let mut buf = vec![0u8; 64 * 1024];
            loop {
                match from.read(&mut buf) {
                    Ok(0) => {
                        let _ = tx.send(Err(io::ErrorKind::UnexpectedEof.into()));
                        return;
                    }
                    Ok(n) => {
                        if tx.send(Ok(buf[..n].to_vec())).is_err() {
                            return;
                        }
                    }
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                    Err(e) if tolerate_timeouts && e.kind() == io::ErrorKind::TimedOut => {
                        // A serial read timed out: check the owner still listens.
                        if tx.send(Ok(Vec::new())).is_err() {
                            return;
                        }
                    }
                    Err(e) => {
                        let _ = tx.send(Err(e));
                        return;
                    }
                }
            }
        })?;
    Ok((rx, handle))
}

/// Waits on a reader channel, skipping empty keep-alive chunks.
fn recv_channel(
    rx: &Receiver<io::Result<Vec<u8>>>,
    closed: &mut bool,
    timeout: Duration,
) -> io::Result<Vec<u8>> {
    if *closed {
        return Err(io::ErrorKind::UnexpectedEof.into());
    }
    let end = Instant::now() + timeout;
    loop {
        let left = end.saturating_duration_since(Instant::now());
        match rx.recv_timeout(left) {
            Ok(Ok(bytes)) if bytes.is_empty() => continue,
            Ok(Ok(bytes)) => return Ok(bytes),
            Ok(Err(e)) => {
                *closed = true;
                return Err(e);
            }
            Err(RecvTimeoutError::Timeout) => {
                return Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!("no bytes from the device within {timeout:?}"),
                ))
            }
            Err(RecvTimeoutError::Disconnected) => {
                *closed = true;
                return Err(io::ErrorKind::UnexpectedEof.into());
            }
        }
    }
}

/// A serial port (USB CDC-ACM or a UART); a reader thread feeds a channel.
pub struct SerialLink {
    port: Box<dyn serialport::SerialPort>,
    rx: Receiver<io::Result<Vec<u8>>>,
    closed: bool,
}

impl SerialLink {
    /// Opens `path` (115200 baud, 8N1; CDC-ACM ignores the rate).
    pub fn open(path: &str) -> io::Result<SerialLink> {
        let port = serialport::new(path, 115_200)
            .timeout(Duration::from_millis(100))
            .open()
            .map_err(|e| io::Error::other(format!("cannot open serial port {path}: {e}")))?;
        let reading = port
            .try_clone()
            .map_err(|e| io::Error::other(format!("cannot clone serial port {path}: {e}")))?;
        // The reader thread ends when the port fails or this link is dropped
        // (its next keep-alive send fails).
        let (rx, _reader) = reader_thread(reading, true)?;
        Ok(SerialLink {
            port,
            rx,
            closed: false,
        })
    }
}

impl Link for SerialLink {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.port.write_all(bytes)?;
        self.port.flush()
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Vec<u8>> {
        recv_channel(&self.rx, &mut self.closed, timeout)
    }
}

/// Sectors of the in-process device's flash log: 1 MiB, the log region of
/// both boards (the Pico's second MiB of QSPI flash, the QEMU board's PSRAM).
pub const LOCAL_FLASH_SECTORS: usize = 256;

/// The core's device state machine run in-process on a thread, behind the
/// same byte interface as a board: what every board runs, without hardware,
/// with its flash log on a simulated 1 MiB NOR flash.
pub struct LocalLink {
    to_device: Option<mpsc::Sender<Vec<u8>>>,
    rx: Receiver<io::Result<Vec<u8>>>,
    closed: bool,
    worker: Option<JoinHandle<()>>,
}

impl LocalLink {
    /// A fresh device of capacity profile `profile` (`ram256k`, `ram512k`, `ram1m`).
    pub fn start(profile: &str) -> io::Result<LocalLink> {
        use placedb::device::{Device1M, Device256K, Device512K};
        use placedb::persist::{sim::SimFlash, Log};
        let (to_device, inbox) = mpsc::channel::<Vec<u8>>();
        let (tx, rx) = mpsc::channel();
        /// `Device::receive` of some profile.
        type Receive<'a> = dyn FnMut(&[u8], &mut dyn FnMut(&[u8])) + 'a;
        /// Hands every chunk from the inbox to `receive` and the replies back.
        fn serve(
            receive: &mut Receive<'_>,
            inbox: Receiver<Vec<u8>>,
            tx: mpsc::Sender<io::Result<Vec<u8>>>,
        ) {
            for bytes in inbox {
                let mut out = Vec::new();
                receive(&bytes, &mut |frame: &[u8]| out.extend_from_slice(frame));
                if !out.is_empty() && tx.send(Ok(out)).is_err() {
                    return;
                }
            }
        }
        let profile = profile.to_string();
        if placedb::profile::by_name(&profile).is_none() {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("unknown profile {profile:?} (known: ram256k, ram512k, ram1m)"),
            ));
        }
        let worker = thread::Builder::new()
            .name("placedb-local-device".into())
            // A device is built on this stack before it is boxed (debug builds).
            .stack_size(64 << 20)
            .spawn(move || {
                // The boards' flash log: 1 MiB of 4 KiB sectors, in RAM here.
                let flash = SimFlash::new(LOCAL_FLASH_SECTORS);
                let end = (LOCAL_FLASH_SECTORS * SimFlash::SECTOR) as u32;
                let mut log = Log::open(flash, 0, end).expect("an erased flash opens");
                match profile.as_str() {
                    "ram256k" => {
                        let mut d = Box::new(Device256K::new());
                        serve(&mut |b, s| d.receive_logged(b, &mut log, s), inbox, tx)
                    }
                    "ram512k" => {
                        let mut d = Box::new(Device512K::new());
                        serve(&mut |b, s| d.receive_logged(b, &mut log, s), inbox, tx)
                    }
                    _ => {
                        let mut d = Box::new(Device1M::new());
                        serve(&mut |b, s| d.receive_logged(b, &mut log, s), inbox, tx)
                    }
                }
            })?;
        Ok(LocalLink {
            to_device: Some(to_device),
            rx,
            closed: false,
            worker: Some(worker),
        })
    }
}

impl Link for LocalLink {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        match &self.to_device {
            Some(tx) if tx.send(bytes.to_vec()).is_ok() => Ok(()),
            _ => Err(io::ErrorKind::BrokenPipe.into()),
        }
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Vec<u8>> {
        recv_channel(&self.rx, &mut self.closed, timeout)
    }
}

impl Drop for LocalLink {
    fn drop(&mut self) {
        self.to_device = None;
        if let Some(worker) = self.worker.take() {
            let _ = worker.join();
        }
    }
}

/// A TCP connection; a reader thread feeds a channel.
pub struct TcpLink {
    stream: TcpStream,
    rx: Receiver<io::Result<Vec<u8>>>,
    reader: Option<JoinHandle<()>>,
    closed: bool,
}

impl TcpLink {
    /// Connects to `addr` (`HOST:PORT`) within `timeout`.
    pub fn connect(addr: impl ToSocketAddrs, timeout: Duration) -> io::Result<TcpLink> {
        let mut last = io::Error::new(io::ErrorKind::NotFound, "address resolves to nothing");
        for a in addr.to_socket_addrs()? {
            match TcpStream::connect_timeout(&a, timeout) {
                Ok(stream) => return TcpLink::from_stream(stream),
                Err(e) => last = e,
            }
        }
        Err(last)
    }

    /// Wraps a connected stream.
    pub fn from_stream(stream: TcpStream) -> io::Result<TcpLink> {
        stream.set_nodelay(true)?;
        stream.set_nonblocking(false)?;
        let reading = stream.try_clone()?;
        let (rx, reader) = reader_thread(reading, false)?;
        Ok(TcpLink {
            stream,
            rx,
            reader: Some(reader),
            closed: false,
        })
    }

    /// The peer's address.
    pub fn peer_addr(&self) -> io::Result<SocketAddr> {
        self.stream.peer_addr()
    }
}

impl Link for TcpLink {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.stream.write_all(bytes)?;
        self.stream.flush()
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Vec<u8>> {
        recv_channel(&self.rx, &mut self.closed, timeout)
    }
}

impl Drop for TcpLink {
    fn drop(&mut self) {
        let _ = self.stream.shutdown(Shutdown::Both);
        if let Some(reader) = self.reader.take() {
            let _ = reader.join();
        }
    }
}

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

/// Creates the flash file `path` (holding [`FLASH_FILE_SIZE`] bytes of 0xFF, an
/// erased chip) if it is missing or empty; leaves an existing one as it is.
/// Errors if it exists with another size (QEMU would refuse it).
pub fn prepare_flash_file(path: &Path) -> io::Result<()> {
    match std::fs::metadata(path) {
        Ok(meta) if meta.len() == FLASH_FILE_SIZE => return Ok(()),
        Ok(meta) if meta.len() != 0 => {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                format!(
                    "flash file {} holds {} bytes, expected {FLASH_FILE_SIZE} (16 MiB)",
                    path.display(),
                    meta.len()
                ),
            ))
        }
        Ok(_) => {}
        Err(e) if e.kind() == io::ErrorKind::NotFound => {}
        Err(e) => return Err(e),
    }
    // Written beside the target and renamed into place, so a file cut short
    // by a crash is never taken for a flash image.
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(format!(".tmp{}", std::process::id()));
    let tmp = path.with_file_name(name);
    let written = (|| {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)?;
        }
        let mut file = std::fs::File::create(&tmp)?;
        let erased = vec![0xFFu8; 1 << 20];
        for _ in 0..FLASH_FILE_SIZE / (1 << 20) {
            file.write_all(&erased)?;
        }
        file.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written.map_err(|e| {
        io::Error::new(
            e.kind(),
            format!("cannot create flash file {}: {e}", path.display()),
        )
    })
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
            build_board(
                "qemu-mps2-an386",
                default_firmware(),
                std::env::var_os("PLACEDB_QEMU_FIRMWARE").is_none(),
                FIRMWARE_BUILD,
            )
        })
        .clone()
}

/// Builds the firmware of `boards/BOARD` (`cargo build --release` there, if
/// `build`) and returns `elf` if it exists; `how` says how to build it by
/// hand in the error.
pub fn build_board(board: &str, elf: PathBuf, build: bool, how: &str) -> Result<PathBuf, String> {
    if build {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../boards")
            .join(board);
        let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
        let out = Command::new(cargo)
            .args(["build", "--release"])
            .current_dir(&dir)
            .output()
            .map_err(|e| format!("cannot run cargo to build the firmware: {e}"))?;
        if !out.status.success() {
            return Err(format!(
                "building the firmware (`{how}`) failed:\n{}",
                String::from_utf8_lossy(&out.stderr)
            ));
        }
    }
    if elf.is_file() {
        Ok(elf)
    } else {
        Err(format!(
            "firmware {} is missing: build it with `{how}`",
            elf.display()
        ))
    }
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
                format!("cannot start {}: {e}", options.program.display()),
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
        let accepted = accept_within(&listener, options.connect_timeout, &watch);
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

/// Accepts one connection within `timeout`, giving up early if QEMU exits.
fn accept_within(
    listener: &TcpListener,
    timeout: Duration,
    watch: &Watch,
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
        if let Ok(mut child) = watch.child.lock() {
            if let Ok(Some(status)) = child.try_wait() {
                return Err(io::Error::new(
                    io::ErrorKind::BrokenPipe,
                    format!("QEMU exited ({status}) before connecting"),
                ));
            }
        }
        if Instant::now() >= end {
            return Err(io::Error::new(
                io::ErrorKind::TimedOut,
                format!("no connection within {timeout:?}"),
            ));
        }
        thread::sleep(Duration::from_millis(5));
    }
}

/// One thing received from a device.
#[derive(Debug, Clone, PartialEq)]
pub enum Received {
    /// A decoded message (every variant but `Log`, which is [`Received::Log`]).
    Message(DeviceMessage<'static>),
    /// A `DeviceMessage::Log` line.
    Log(String),
    /// A frame that could not be read (damaged on the way, or oversized).
    Damaged(ProtocolError),
}

impl Received {
    fn from_message(msg: DeviceMessage<'_>) -> Received {
        match (msg, msg.into_static()) {
            (_, Some(owned)) => Received::Message(owned),
            (DeviceMessage::Log(text), None) => Received::Log(text.to_owned()),
            (other, None) => Received::Log(format!("{other:?}")),
        }
    }

    /// The sequence number if this is the terminal reply of a host message
    /// (Ack, Status, ExportEnd, or Error with a known sequence number).
    pub fn terminal_seq(&self) -> Option<u32> {
        match self {
            Received::Message(DeviceMessage::Ack { seq })
            | Received::Message(DeviceMessage::ExportEnd { seq, .. }) => Some(*seq),
            Received::Message(DeviceMessage::Status(status)) => Some(status.seq),
            Received::Message(DeviceMessage::Error { seq, .. }) => *seq,
            _ => None,
        }
    }
}

/// The protocol on top of a [`Link`]: numbered host frames out, device
/// messages in.
pub struct Client<L: Link> {
    link: L,
    decoder: Box<FrameDecoder<MAX_FRAME_LEN>>,
    pending: Vec<u8>,
    next_seq: u32,
    tx: Vec<u8>,
}

impl<L: Link> Client<L> {
    /// A client whose first sequence number is 1.
    pub fn new(link: L) -> Client<L> {
        Client {
            link,
            decoder: Box::new(FrameDecoder::new()),
            pending: Vec::new(),
            next_seq: 1,
            tx: vec![0u8; MAX_FRAME_LEN],
        }
    }

    /// The underlying link.
    pub fn link(&mut self) -> &mut L {
        &mut self.link
    }

    /// Gives the link back.
    pub fn into_link(self) -> L {
        self.link
    }

    /// Takes the next sequence number (for frames built by hand).
    pub fn take_seq(&mut self) -> u32 {
        let seq = self.next_seq;
        self.next_seq = self.next_seq.wrapping_add(1);
        seq
    }

    /// Sends `msg` with the next sequence number and returns that number.
    /// A frame larger than [`MAX_FRAME_LEN`] is refused with `InvalidInput`.
    pub fn send(&mut self, msg: HostMessage<'_>) -> io::Result<u32> {
        let seq = self.take_seq();
        let frame = encode(&HostFrame { seq, msg }, &mut self.tx)
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
        self.link.send(frame)?;
        Ok(seq)
    }

    /// Sends `msg` with sequence number `seq` (a retransmission keeps the
    /// number of the first transmission; see [`placedb::protocol`]).
    pub fn send_as(&mut self, seq: u32, msg: HostMessage<'_>) -> io::Result<()> {
        let frame = encode(&HostFrame { seq, msg }, &mut self.tx)
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
        self.link.send(frame)
    }

    /// Sends raw bytes (e.g. a deliberately damaged frame).
    pub fn send_raw(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.link.send(bytes)
    }

    /// Sends a lone 0x00 so the device drops any partial frame.
    pub fn resync(&mut self) -> io::Result<()> {
        self.link.send(&[0])
    }

    /// The next thing the device sends, within `timeout`.
    pub fn recv(&mut self, timeout: Duration) -> io::Result<Received> {
        let end = Instant::now() + timeout;
        loop {
            if !self.pending.is_empty() {
                let total = self.pending.len();
                let (consumed, outcome) = match self.decoder.push(&self.pending) {
                    Push::NeedMore => (total, None),
                    Push::Ready { remaining } => (total - remaining.len(), Some(Ok(()))),
                    Push::Error { error, remaining } => (total - remaining.len(), Some(Err(error))),
                };
                self.pending.drain(..consumed);
                match outcome {
                    Some(Ok(())) => {
                        return Ok(match self.decoder.decode::<DeviceMessage>() {
                            Ok(msg) => Received::from_message(msg),
                            Err(e) => Received::Damaged(e),
                        })
                    }
                    Some(Err(e)) => return Ok(Received::Damaged(e)),
                    None => {}
                }
            }
            let left = end.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!("no complete frame from the device within {timeout:?}"),
                ));
            }
            let bytes = self.link.recv(left)?;
            self.pending.extend_from_slice(&bytes);
        }
    }

    /// Everything received until the terminal reply for `seq` (included, last),
    /// within `timeout` overall.
    pub fn replies_to(&mut self, seq: u32, timeout: Duration) -> io::Result<Vec<Received>> {
        let end = Instant::now() + timeout;
        let mut got = Vec::new();
        loop {
            let left = end.saturating_duration_since(Instant::now());
            let item = self.recv(left)?;
            let done = item.terminal_seq() == Some(seq);
            got.push(item);
            if done {
                return Ok(got);
            }
        }
    }

    /// Sends `msg` and collects the replies up to its terminal reply.
    pub fn request(
        &mut self,
        msg: HostMessage<'_>,
        timeout: Duration,
    ) -> io::Result<(u32, Vec<Received>)> {
        let seq = self.send(msg)?;
        let replies = self.replies_to(seq, timeout)?;
        Ok((seq, replies))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use placedb::protocol::{ErrorKind, Feed, Phase, Status};

    /// A fake device on loopback: answers StatusRequest with Status, logs once,
    /// refuses anything else, reports framing errors.
    fn fake_device(listener: TcpListener) -> JoinHandle<()> {
        thread::spawn(move || {
            let (mut stream, _) = listener.accept().unwrap();
            let mut decoder = FrameDecoder::<MAX_FRAME_LEN>::new();
            let mut tx = vec![0u8; 256];
            let mut buf = [0u8; 100];
            loop {
                let n = match stream.read(&mut buf) {
                    Ok(0) | Err(_) => return,
                    Ok(n) => n,
                };
                let mut rest = &buf[..n];
                while let Feed::Frame { result, remaining } = decoder.feed::<HostFrame>(rest) {
                    let mut replies = Vec::new();
                    match result {
                        Ok(HostFrame {
                            seq,
                            msg: HostMessage::StatusRequest,
                        }) => {
                            replies.push(
                                encode(&DeviceMessage::Log("status"), &mut tx)
                                    .unwrap()
                                    .to_vec(),
                            );
                            let status = DeviceMessage::Status(Status {
                                frames_seen: 3,
                                database_size: 1,
                                ..Status::new(seq, Phase::Ready)
                            });
                            replies.push(encode(&status, &mut tx).unwrap().to_vec());
                        }
                        Ok(HostFrame { seq, .. }) => {
                            let e = DeviceMessage::Error {
                                seq: Some(seq),
                                kind: ErrorKind::Internal,
                            };
                            replies.push(encode(&e, &mut tx).unwrap().to_vec());
                        }
                        Err(e) => replies.push(encode(&e.reply(), &mut tx).unwrap().to_vec()),
                    }
                    for r in replies {
                        // Byte by byte, to exercise reassembly on the host.
                        for b in r {
                            stream.write_all(&[b]).unwrap();
                        }
                    }
                    rest = remaining;
                }
            }
        })
    }

    #[test]
    fn client_over_tcp_matches_replies() {
        let listener = TcpListener::bind(("127.0.0.1", 0)).unwrap();
        let port = listener.local_addr().unwrap().port();
        let device = fake_device(listener);
        let link = open(&format!("tcp:127.0.0.1:{port}"), Duration::from_secs(5)).unwrap();
        let mut client = Client::new(link);
        client.resync().unwrap();
        let (seq, replies) = client
            .request(HostMessage::StatusRequest, Duration::from_secs(5))
            .unwrap();
        assert_eq!(replies.len(), 2);
        assert_eq!(replies[0], Received::Log("status".into()));
        assert!(matches!(
            replies[1],
            Received::Message(DeviceMessage::Status(Status { seq: s, frames_seen: 3, .. })) if s == seq
        ));
        let (seq, replies) = client
            .request(HostMessage::Reset, Duration::from_secs(5))
            .unwrap();
        assert_eq!(
            replies,
            vec![Received::Message(DeviceMessage::Error {
                seq: Some(seq),
                kind: ErrorKind::Internal
            })]
        );
        // Nothing more: a timeout, not a hang.
        let err = client.recv(Duration::from_millis(50)).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::TimedOut);
        drop(client);
        device.join().unwrap();
    }

    #[test]
    fn open_refuses_unknown_links_and_missing_ports() {
        assert!(open("serial:/nonexistent/ttyACM9", Duration::from_millis(10)).is_err());
        assert!(open("/nonexistent/ttyACM9", Duration::from_millis(10)).is_err());
        assert_eq!(
            open("local:ram2k", Duration::from_millis(10))
                .err()
                .map(|e| e.kind()),
            Some(io::ErrorKind::InvalidInput)
        );
        assert_eq!(
            open("udp:1.2.3.4:5", Duration::from_millis(10))
                .err()
                .map(|e| e.kind()),
            Some(io::ErrorKind::InvalidInput)
        );
    }

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
