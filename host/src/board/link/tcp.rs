//! [`TcpLink`]: a device behind a TCP port (an emulator, or a
//! serial-to-TCP bridge).

use super::{reader_thread, recv_channel, Link};
use std::io::{self, Write};
use std::net::{Shutdown, SocketAddr, TcpStream, ToSocketAddrs};
use std::sync::mpsc::Receiver;
use std::thread::JoinHandle;
use std::time::Duration;

/// A TCP connection; a reader thread feeds a channel.
pub struct TcpLink {
    stream: TcpStream,
    rx: Receiver<io::Result<Vec<u8>>>,
    reader: Option<JoinHandle<()>>,
    closed: bool,
    /// Some byte came from the peer.
    heard: bool,
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

    /// Connects to the board at `--port tcp:ADDR` within `timeout`, as
    /// [`TcpLink::connect`] does, with a failure said in words that name the
    /// port and say what to do (see [`super::open`]).
    pub fn open(addr: &str, timeout: Duration) -> io::Result<TcpLink> {
        let port = format!("tcp:{addr}");
        let addrs: Vec<SocketAddr> = match addr.to_socket_addrs() {
            Ok(addrs) => addrs.collect(),
            Err(e) => {
                return Err(io::Error::new(
                    e.kind(),
                    format!(
                        "cannot find the board's address in {port} ({}): give it as \
                         tcp:HOST:PORT, e.g. tcp:127.0.0.1:4321",
                        crate::error::io_words(&e)
                    ),
                ))
            }
        };
        TcpLink::connect(&addrs[..], timeout).map_err(|e| {
            let why = match e.kind() {
                io::ErrorKind::ConnectionRefused => format!("nothing listens on {port}"),
                io::ErrorKind::TimedOut => format!(
                    "{port} did not answer within {}",
                    crate::error::seconds(timeout)
                ),
                _ => format!("cannot connect to {port}: {}", crate::error::io_words(&e)),
            };
            io::Error::new(
                e.kind(),
                format!(
                    "{why}: is the board running, on that port? `placedb device --qemu` \
                     (or --rp2040) starts an emulated one and prints its port"
                ),
            )
        })
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
            heard: false,
        })
    }

    /// The peer's address.
    pub fn peer_addr(&self) -> io::Result<SocketAddr> {
        self.stream.peer_addr()
    }

    /// Closes the connection both ways (the peer sees it end); what the
    /// peer sends after is not read.
    pub fn shutdown(&self) {
        let _ = self.stream.shutdown(Shutdown::Both);
    }
}

impl Link for TcpLink {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.stream.write_all(bytes)?;
        self.stream.flush()
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Vec<u8>> {
        match recv_channel(&self.rx, &mut self.closed, timeout) {
            Ok(bytes) => {
                self.heard = true;
                Ok(bytes)
            }
            // An emulated board takes one connection at a time and closes
            // a second one at once, before anything is said.
            Err(e) if e.kind() == io::ErrorKind::UnexpectedEof && !self.heard => {
                Err(io::Error::new(
                    io::ErrorKind::UnexpectedEof,
                    "the board closed the connection before it sent anything: it serves one \
                     connection at a time, so another program is probably connected to it",
                ))
            }
            Err(e) => Err(e),
        }
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
