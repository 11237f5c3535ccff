//! A board that is not there (nothing listens on its TCP port, no such
//! serial port) is named by every command, with what to do: start the
//! emulated board, or check the cable and the port's name. A board that
//! goes away mid-stream (reset, unplugged: its connection reset) is named,
//! and `placedb stream` says how to go on: restart it and run the same
//! command again with `--resume`. The board is the core's device in this
//! test's process behind a loopback TCP port that drops the connection
//! after the first frames.

mod cli_common;

use cli_common::{placedb, stderr};
use placedb_host::board::link::local::LocalLink;
use placedb_host::board::link::Link;
use std::io::{ErrorKind, Read, Write};
use std::net::TcpListener;
use std::time::Duration;

/// Bytes from the host passed on before the connection drops: the
/// handshake and a few frames of the demo scan.
const BEFORE_THE_DROP: usize = 40_000;

#[test]
fn a_board_lost_mid_stream_says_to_go_on_with_resume() {
    let listener = TcpListener::bind(("127.0.0.1", 0)).unwrap();
    let port = format!("tcp:127.0.0.1:{}", listener.local_addr().unwrap().port());
    let board = std::thread::spawn(move || {
        let (mut tcp, _) = listener.accept().unwrap();
        let mut device = LocalLink::start("ram512k").unwrap();
        tcp.set_read_timeout(Some(Duration::from_millis(2)))
            .unwrap();
        let mut buf = vec![0u8; 1 << 16];
        let mut passed = 0;
        while passed < BEFORE_THE_DROP {
            match tcp.read(&mut buf) {
                Ok(0) => return,
                Ok(n) => {
                    device.send(&buf[..n]).unwrap();
                    passed += n;
                }
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
                Err(_) => return,
            }
            while let Ok(reply) = device.recv(Duration::from_millis(1)) {
                if tcp.write_all(&reply).is_err() {
                    return;
                }
            }
        }
        // Closed with bytes unread: the host sees its connection reset, as
        // when a board vanishes.
        std::thread::sleep(Duration::from_millis(100));
        drop(tcp);
    });
    let run = placedb(&[
        "stream",
        "--demo",
        "--demo-frames",
        "200",
        "--port",
        &port,
        "-q",
    ]);
    board.join().unwrap();
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&format!("the board on {port} went away mid-stream")),
        "{err}"
    );
    assert!(
        err.contains(
            "restart it (its scan is kept in flash) and run the same command again with --resume"
        ),
        "{err}"
    );
    assert!(!err.contains("os error"), "{err}");
}

/// `stream` and `export` to a port where no board is: the refusal names
/// the port and says what to do, in words (no Rust type, no "os error"),
/// before anything is written.
#[test]
fn a_board_that_is_not_there_is_named_with_what_to_do() {
    // A port nothing listens on: bound, then closed.
    let free = TcpListener::bind(("127.0.0.1", 0)).unwrap();
    let tcp = format!("tcp:127.0.0.1:{}", free.local_addr().unwrap().port());
    drop(free);
    let out = std::env::temp_dir().join(format!("placedb-no-board-{}", std::process::id()));
    let out = out.to_str().unwrap();
    let serial = "/dev/ttyACM9-placedb-none";
    for (port, says) in [
        (
            tcp.as_str(),
            ["nothing listens on", "placedb device --qemu"],
        ),
        (serial, ["there is no serial port", "ls /dev/serial/by-id"]),
    ] {
        for args in [
            vec!["stream", "--demo", "--port", port, "-q"],
            vec!["export", "--port", port, "-o", out, "-q"],
        ] {
            let run = placedb(&args);
            let err = stderr(&run);
            assert_eq!(run.status.code(), Some(1), "{args:?}: {err}");
            assert!(err.contains(port), "{args:?}: the port is not named: {err}");
            for want in says {
                assert!(err.contains(want), "{args:?}: no {want:?} in: {err}");
            }
            for rust in ["os error", "Kind(", "Custom {", "Error {", "Io("] {
                assert!(!err.contains(rust), "{args:?}: {rust:?} in: {err}");
            }
            assert!(!std::path::Path::new(out).exists(), "{args:?} wrote {out}");
        }
    }
}
