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
    /// Opens `path` (115200 baud, 8N1; CDC-ACM ignores the rate).
    pub fn open(path: &str) -> io::Result<SerialLink> {
        let port = serialport::new(path, 115_200)
            .timeout(Duration::from_millis(100))
            .open()
            .map_err(|e| io::Error::other(open_error(path, &e)))?;
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

/// Why `path` did not open, in words. A port another program holds is
/// refused at once (serialport opens ports exclusively: `TIOCEXCL` and an
/// exclusive `flock`), and that is the usual reason: a board serves one
/// program at a time.
fn open_error(path: &str, e: &serialport::Error) -> String {
    let busy = matches!(
        e.kind,
        serialport::ErrorKind::Io(io::ErrorKind::ResourceBusy)
    ) || e.description.contains("exclusive lock")
        || e.description.contains("resource busy");
    if busy {
        format!(
            "{path} is open in another program (a scan or export from another connection?): \
             a board serves one program at a time; wait for it or stop it"
        )
    } else {
        format!("cannot open serial port {path}: {e}")
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
}
