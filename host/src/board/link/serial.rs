//! [`SerialLink`]: a board over USB CDC-ACM or a UART.

use super::{reader_thread, recv_channel, Link};
use std::io::{self, Write};
use std::sync::mpsc::Receiver;
use std::time::Duration;

/// A serial port (USB CDC-ACM or a UART); a reader thread feeds a channel.
pub struct SerialLink {
    port: Box<dyn serialport::SerialPort>,
    rx: Receiver<io::Result<Vec<u8>>>,
    closed: bool,
}

impl SerialLink {
    /// Opens `path` (115200 baud, 8N1; CDC-ACM ignores the rate); a port
    /// that does not open is said in words naming it, with what to do.
    pub fn open(path: &str) -> io::Result<SerialLink> {
        let port = serialport::new(path, 115_200)
            .timeout(Duration::from_millis(100))
            .open()
            .map_err(|e| open_error(path, &e))?;
        let reading = port.try_clone().map_err(|e| open_error(path, &e))?;
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

/// Where the boards plugged in are listed (said when a port does not open).
const LIST_PORTS: &str = "`ls /dev/serial/by-id` lists the serial ports plugged in";

/// Why `path` did not open, in words that name it and say what to do; the
/// error keeps its kind. A port another program holds is refused at once
/// (serialport opens ports exclusively: `TIOCEXCL` and an exclusive
/// `flock`), and that is the usual reason: a board serves one program at a
/// time.
fn open_error(path: &str, e: &serialport::Error) -> io::Error {
    use io::ErrorKind as K;
    let kind = match e.kind {
        serialport::ErrorKind::Io(kind) => kind,
        serialport::ErrorKind::NoDevice => K::ResourceBusy,
        serialport::ErrorKind::InvalidInput => K::InvalidInput,
        serialport::ErrorKind::Unknown => K::Other,
    };
    let said = e.description.to_lowercase();
    let busy = kind == K::ResourceBusy
        || said.contains("exclusive lock")
        || said.contains("resource busy");
    let words = if busy {
        format!(
            "{path} is open in another program (a scan or export from another connection?): \
             a board serves one program at a time; wait for it or stop it"
        )
    } else if kind == K::NotFound {
        format!(
            "there is no serial port {path}: is the board plugged in? Check the cable; \
             {LIST_PORTS}"
        )
    } else if kind == K::PermissionDenied {
        format!(
            "no permission to open {path}: add your user to the group that owns it \
             (`ls -l {path}`: usually dialout) and log in again"
        )
    } else {
        // The operating system's reason, without an "(os error N)".
        let reason = match said.find(" (os error ") {
            Some(at) => &said[..at],
            None => &said,
        };
        let reason = if reason.contains("ioctl") || reason.contains("typewriter") {
            "it is not a serial port"
        } else {
            reason
        };
        format!("cannot open {path} as the board's serial port: {reason}; {LIST_PORTS}")
    };
    io::Error::new(kind, words)
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

#[cfg(test)]
mod tests {
    use super::*;
    use serialport::SerialPort;

    /// A port another program holds is refused in words (one program at a
    /// time), not as "Unable to acquire exclusive lock".
    #[cfg(unix)]
    #[test]
    fn a_port_held_by_another_program_is_refused_in_words() {
        let (_master, slave) = serialport::TTYPort::pair().unwrap();
        let path = slave.name().unwrap();
        drop(slave);
        let _first = SerialLink::open(&path).unwrap();
        let second = SerialLink::open(&path).err().unwrap().to_string();
        assert!(
            second.contains("open in another program") && second.contains(&path),
            "{second}"
        );
    }

    /// A port that is not there, or is no serial port, is named with what
    /// to do, and keeps its kind (Python raises FileNotFoundError for it).
    #[cfg(unix)]
    #[test]
    fn a_port_that_does_not_open_is_named_with_what_to_do() {
        let missing = SerialLink::open("/nonexistent/ttyACM9").err().unwrap();
        assert_eq!(missing.kind(), io::ErrorKind::NotFound);
        let said = missing.to_string();
        assert!(
            said.contains("there is no serial port /nonexistent/ttyACM9")
                && said.contains("ls /dev/serial/by-id"),
            "{said}"
        );
        let not_a_tty = SerialLink::open("/dev/null").err().unwrap().to_string();
        assert!(
            not_a_tty.contains("/dev/null") && not_a_tty.contains("ls /dev/serial/by-id"),
            "{not_a_tty}"
        );
        assert!(!not_a_tty.contains("os error"), "{not_a_tty}");
    }
}
