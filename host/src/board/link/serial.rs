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
