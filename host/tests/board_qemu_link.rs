//! The link to the emulated board: host -> loopback TCP -> QEMU UART0 ->
//! firmware -> `placedb::device::Device` -> UART0 -> host. (The full scan
//! end to end is host/tests/board_qemu.rs at the workspace root.)
//!
//! Needs `qemu-system-arm` and the firmware built first:
//! `cd boards/qemu-mps2-an386 && cargo build --release`
//! (or point `PLACEDB_QEMU_FIRMWARE` at another ELF).

use placedb::protocol::{DeviceMessage, ErrorKind, HostMessage, Phase, MAX_FRAME_LEN};
use placedb_host::board::client::Client;
use placedb_host::board::client::Received;
use placedb_host::board::emulator::qemu::Qemu;
use placedb_host::board::link::fault::damaged_frame;
use placedb_host::testing::qemu_firmware as firmware;
use std::time::Duration;

const REPLY_TIMEOUT: Duration = Duration::from_secs(5);

fn expect_status(replies: &[Received], seq: u32) {
    match replies {
        [Received::Message(DeviceMessage::Status(status))] => {
            assert_eq!(status.seq, seq);
            assert_eq!(status.phase, Phase::Unconfigured);
        }
        other => panic!("expected one Status for seq {seq}, got {other:?}"),
    }
}

#[test]
fn status_then_damaged_frame_then_status() {
    let firmware = firmware();
    let qemu = Qemu::start(&firmware, Duration::from_secs(25)).unwrap_or_else(|e| {
        panic!("cannot start qemu-system-arm (apt-get install qemu-system-arm): {e}")
    });
    assert!(
        qemu.wait_console("boot", REPLY_TIMEOUT),
        "no boot line; console: {}",
        qemu.console()
    );
    let mut client = Client::new(qemu);
    client.resync().unwrap();

    let (seq, replies) = client
        .request(HostMessage::StatusRequest, REPLY_TIMEOUT)
        .unwrap();
    expect_status(&replies, seq);

    let seq = client.take_seq();
    client
        .send_raw(&damaged_frame(seq, HostMessage::StatusRequest).expect("a damaging byte"))
        .unwrap();
    let replies = client.replies_to(seq, REPLY_TIMEOUT).unwrap();
    assert_eq!(
        replies,
        vec![Received::Message(DeviceMessage::Error {
            seq: Some(seq),
            kind: ErrorKind::BadCrc
        })]
    );

    let (seq, replies) = client
        .request(HostMessage::StatusRequest, REPLY_TIMEOUT)
        .unwrap();
    expect_status(&replies, seq);

    // Frame messages before a Hello are refused with a typed error.
    let (seq, replies) = client.request(HostMessage::Finish, REPLY_TIMEOUT).unwrap();
    assert_eq!(
        replies,
        vec![Received::Message(DeviceMessage::Error {
            seq: Some(seq),
            kind: ErrorKind::NotConfigured
        })]
    );

    let qemu = client.into_link();
    assert!(
        qemu.try_wait().unwrap().is_none(),
        "firmware exited: {}",
        qemu.console()
    );
    drop(qemu);
}

#[test]
fn largest_depth_rows_fit_and_oversized_frames_are_refused() {
    use placedb::protocol::{depth_rows_per_message, DepthRows, MAX_ROW_VALUES};
    let qemu = Qemu::start(&firmware(), Duration::from_secs(25)).unwrap();
    let mut client = Client::new(qemu);
    client.resync().unwrap();

    // A full-size DepthRows frame (worst-case COBS: no zero byte) reaches the
    // device intact: unconfigured, it answers NotConfigured with its seq.
    let rows = depth_rows_per_message(80);
    assert!(usize::from(rows) * 80 <= MAX_ROW_VALUES);
    let data = vec![0xA5u8; usize::from(rows) * 80 * 2];
    let msg = HostMessage::DepthRows(DepthRows {
        frame: 1,
        first_row: 0,
        row_count: rows,
        data: &data,
    });
    let (seq, replies) = client.request(msg, REPLY_TIMEOUT).unwrap();
    assert_eq!(
        replies,
        vec![Received::Message(DeviceMessage::Error {
            seq: Some(seq),
            kind: ErrorKind::NotConfigured
        })]
    );

    // A frame longer than the device's buffer: Oversized (no seq), then the
    // device resynchronises on the delimiter and answers the next request.
    let mut long = vec![0x11u8; MAX_FRAME_LEN + 100];
    long.push(0);
    client.send_raw(&long).unwrap();
    match client.recv(REPLY_TIMEOUT).unwrap() {
        Received::Message(DeviceMessage::Error {
            seq: None,
            kind: ErrorKind::Oversized,
        }) => {}
        other => panic!("expected Oversized, got {other:?}"),
    }
    let (seq, replies) = client
        .request(HostMessage::StatusRequest, REPLY_TIMEOUT)
        .unwrap();
    expect_status(&replies, seq);
}

#[test]
fn qemu_is_killed_at_its_deadline() {
    // Long enough for QEMU to connect its UART first on a loaded machine
    // (with 1 s the deadline once struck before the connection did).
    let qemu = Qemu::start(&firmware(), Duration::from_secs(3)).unwrap();
    let status = qemu.wait_exit(Duration::from_secs(10)).unwrap();
    assert!(
        matches!(status, Some(s) if !s.success()),
        "QEMU still running or exited cleanly: {status:?}"
    );
}
