//! Host-side transports to a placedb device: [`Link`], a byte pipe with a
//! receive timeout, and its implementations: [`TcpLink`] (`tcp:HOST:PORT`:
//! an emulator such as `placedb device --qemu`, or a serial-to-TCP bridge),
//! [`SerialLink`] (`serial:PATH` or a bare device path such as
//! `/dev/ttyACM0`, or a board's USB serial number or the end of it,
//! [`usb_serial`]: a board over USB CDC-ACM or a UART), [`LocalLink`]
//! (`local:PROFILE`: the device state machine of the core in-process, no
//! hardware) and [`fault::FaultInjector`] (faults on any link). The emulated
//! boards are links too ([`crate::board::emulator`]); the protocol client on
//! top is [`crate::board::client::Client`].
//!
//! Every link reads in a background thread into a channel, so writing a long
//! stream never deadlocks against a device that is itself blocked writing
//! replies (the emulated UART moves only about 10 KB/s into the firmware).

pub mod fault;
pub mod local;
pub mod serial;
pub mod tcp;
pub mod usb_serial;

pub use local::{LocalLink, LOCAL_FLASH_SECTORS};
pub use serial::SerialLink;
pub use tcp::TcpLink;

use std::io::{self, Read};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
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

impl<L: Link + ?Sized> Link for &mut L {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        (**self).send(bytes)
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Vec<u8>> {
        (**self).recv(timeout)
    }
}

/// Opens a link from its command-line spelling: `tcp:HOST:PORT`,
/// `serial:PATH` (or a bare path such as `/dev/ttyACM0` or `COM3`), a
/// board's USB serial number (`placedb.example:E6614103E7452D2F`) or the
/// end of its hex ID (`2D2F`), or `local:PROFILE` (`local:ram512k`: the
/// core's device in-process). The one place every command and the library
/// open a board's port, so a board that is not there is said once, in
/// words that name the port and say what to do ([`TcpLink::open`],
/// [`SerialLink::open`]); the error keeps its kind.
pub fn open(spec: &str, timeout: Duration) -> io::Result<Box<dyn Link>> {
    if let Some(addr) = spec.strip_prefix("tcp:") {
        return Ok(Box::new(TcpLink::open(addr, timeout)?));
    }
    if let Some(profile) = spec.strip_prefix("local:") {
        return Ok(Box::new(LocalLink::start(profile)?));
    }
    let path = spec.strip_prefix("serial:").unwrap_or(spec);
    let com = path.get(..3).is_some_and(|c| c.eq_ignore_ascii_case("COM"))
        && path.len() > 3
        && path.bytes().skip(3).all(|b| b.is_ascii_digit());
    let looks_like_port = spec.starts_with("serial:") || path.starts_with('/') || com;
    if looks_like_port && !path.is_empty() {
        return Ok(Box::new(SerialLink::open(path)?));
    }
    if usb_serial::looks_like_serial(spec) {
        return Ok(Box::new(SerialLink::open(&usb_serial::find(spec)?)?));
    }
    Err(io::Error::new(
        io::ErrorKind::InvalidInput,
        format!(
            "unknown port `{spec}`: expected tcp:HOST:PORT, a serial device path \
             (/dev/ttyACM0, serial:PATH), a board's USB serial number (or the end \
             of its hex ID) or local:PROFILE"
        ),
    ))
}

/// Chunks of bytes (or the error that ended them) from a reader thread.
pub(crate) type Chunks = Receiver<io::Result<Vec<u8>>>;

/// Reads `from` in a thread into a channel until it fails or closes.
pub(crate) fn reader_thread(
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
                        let _ = tx.send(Err(closed_by_board()));
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

/// The link's end of stream, in words: an `UnexpectedEof` (what a lost
/// board's callers match) that says who closed it, since the same kind
/// from a file means a short read.
fn closed_by_board() -> io::Error {
    io::Error::new(
        io::ErrorKind::UnexpectedEof,
        "the board closed the connection",
    )
}

/// Waits on a reader channel, skipping empty keep-alive chunks.
pub(crate) fn recv_channel(
    rx: &Receiver<io::Result<Vec<u8>>>,
    closed: &mut bool,
    timeout: Duration,
) -> io::Result<Vec<u8>> {
    if *closed {
        return Err(closed_by_board());
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
                    format!(
                        "no bytes from the device within {}",
                        crate::error::seconds(timeout)
                    ),
                ))
            }
            Err(RecvTimeoutError::Disconnected) => {
                *closed = true;
                return Err(closed_by_board());
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        // A serial number no connected board has: said in words.
        let err = open(
            "placedb.example:0000000000000BAD",
            Duration::from_millis(10),
        )
        .err()
        .unwrap();
        assert!(
            err.to_string().contains("no board has a USB serial number"),
            "{err}"
        );
        assert_eq!(
            open("udp:1.2.3.4:5", Duration::from_millis(10))
                .err()
                .map(|e| e.kind()),
            Some(io::ErrorKind::InvalidInput)
        );
    }
}
