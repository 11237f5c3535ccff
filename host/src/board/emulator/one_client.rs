//! A loopback port that lets one program at a time talk to an emulated
//! board's byte stream (the QEMU board's UART), as a serial port opened
//! exclusively does: a connection while another is open is closed at once,
//! before anything is said (the host reports it in words: see
//! [`crate::board::link::TcpLink`]), after a short wait in case the other
//! program was just killed and its end is still on the way. The board's
//! bytes go to the connected program, and nowhere while none is (as QEMU's
//! own TCP port drops them).

use std::io::{self, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::{Arc, Mutex};
use std::thread;
use std::time::{Duration, Instant};

/// How long a second connection waits for the first one's end before it
/// is refused.
pub const SECOND_CLIENT_WAIT: Duration = Duration::from_millis(300);

/// The program connected now: its number (connections are counted) and
/// the stream the board's bytes go to.
type Current = Arc<Mutex<Option<(u64, TcpStream)>>>;

/// Serves `listener` (the user's port) for `board` (the board's byte
/// stream) on threads of their own, for as long as the process runs.
pub fn serve(listener: TcpListener, board: TcpStream) -> io::Result<()> {
    let current: Current = Arc::new(Mutex::new(None));
    let mut from_board = board.try_clone()?;
    let to_client = Arc::clone(&current);
    thread::Builder::new()
        .name("board to client".into())
        .spawn(move || {
            let mut buf = [0u8; 4096];
            while let Ok(n @ 1..) = from_board.read(&mut buf) {
                if let Ok(mut slot) = to_client.lock() {
                    let gone = match slot.as_mut() {
                        Some((_, client)) => client.write_all(&buf[..n]).is_err(),
                        None => false,
                    };
                    if gone {
                        *slot = None;
                    }
                }
            }
        })?;
    thread::Builder::new()
        .name("one client".into())
        .spawn(move || accept(listener, board, current))?;
    Ok(())
}

/// Takes connections one after another: the first while none is open, a
/// later one once the open one has ended.
fn accept(listener: TcpListener, board: TcpStream, current: Current) {
    let mut number = 0u64;
    for conn in listener.incoming() {
        let Ok(conn) = conn else { continue };
        if !free_within(&current, SECOND_CLIENT_WAIT) {
            let _ = conn.shutdown(std::net::Shutdown::Both);
            continue;
        }
        number += 1;
        let (Ok(reading), Ok(mut to_board)) = (conn.try_clone(), board.try_clone()) else {
            continue;
        };
        let _ = conn.set_nodelay(true);
        if let Ok(mut slot) = current.lock() {
            *slot = Some((number, conn));
        }
        let this = number;
        let slot = Arc::clone(&current);
        let _ = thread::Builder::new()
            .name("client to board".into())
            .spawn(move || {
                let mut reading = reading;
                let mut buf = [0u8; 4096];
                while let Ok(n @ 1..) = reading.read(&mut buf) {
                    if to_board.write_all(&buf[..n]).is_err() {
                        break;
                    }
                }
                // The program closed the port: the next one may connect.
                if let Ok(mut slot) = slot.lock() {
                    if matches!(slot.as_ref(), Some((n, _)) if *n == this) {
                        *slot = None;
                    }
                }
            });
    }
}

/// Whether no program is connected, now or within `wait`.
fn free_within(current: &Current, wait: Duration) -> bool {
    let end = Instant::now() + wait;
    loop {
        if current.lock().map(|s| s.is_none()).unwrap_or(false) {
            return true;
        }
        if Instant::now() >= end {
            return false;
        }
        thread::sleep(Duration::from_millis(10));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bytes pass both ways for the first program; a second is closed at
    /// once while the first is connected, and served once it has gone.
    #[test]
    fn one_program_at_a_time() {
        let board_side = TcpListener::bind(("127.0.0.1", 0)).unwrap();
        let board_addr = board_side.local_addr().unwrap();
        let mut board = TcpStream::connect(board_addr).unwrap();
        let (emulator, _) = board_side.accept().unwrap();
        let user = TcpListener::bind(("127.0.0.1", 0)).unwrap();
        let user_addr = user.local_addr().unwrap();
        serve(user, emulator).unwrap();

        let mut first = TcpStream::connect(user_addr).unwrap();
        first.write_all(b"hello").unwrap();
        let mut got = [0u8; 5];
        board.read_exact(&mut got).unwrap();
        assert_eq!(&got, b"hello");
        board.write_all(b"world").unwrap();
        first.read_exact(&mut got).unwrap();
        assert_eq!(&got, b"world");

        let mut second = TcpStream::connect(user_addr).unwrap();
        second
            .set_read_timeout(Some(Duration::from_secs(5)))
            .unwrap();
        let mut one = [0u8; 1];
        assert_eq!(
            second.read(&mut one).unwrap(),
            0,
            "the second was not closed"
        );
        // The first goes on.
        board.write_all(b"again").unwrap();
        first.read_exact(&mut got).unwrap();
        assert_eq!(&got, b"again");

        drop(first);
        thread::sleep(Duration::from_millis(100));
        let mut third = TcpStream::connect(user_addr).unwrap();
        third.write_all(b"third").unwrap();
        board.read_exact(&mut got).unwrap();
        assert_eq!(&got, b"third");
    }
}
