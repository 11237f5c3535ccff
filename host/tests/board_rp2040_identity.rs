//! Each Pico its own identity: the firmware reads its flash chip's 64-bit
//! unique ID (command 0x4B, through the same RAM routine as erase and
//! program) and makes it its USB serial number,
//! `placedb.example:` then the ID in 16 upper-case hex digits. Two emulated
//! Picos with different IDs (`Rp2040Options::unique_id`, the harness's
//! `--unique-id`), running at once, enumerate with two different serial
//! numbers, each the one its ID gives, and both answer on their own port.
//!
//! Needs Node 20 and `cd boards/rp-pico/emulator && npm ci`; the firmware is
//! built first.

use placedb::protocol::Phase;
use placedb_host::board::client::{self, Client};
use placedb_host::board::emulator::rp2040::{Rp2040, Rp2040Options, DEFAULT_UNIQUE_ID};
use placedb_host::board::link::usb_serial::{resolve, UsbPort};
use placedb_host::testing::rp2040_firmware as firmware;
use std::time::Duration;

fn boot(unique_id: u64) -> Rp2040 {
    let options = Rp2040Options {
        unique_id,
        deadline: Duration::from_secs(300),
        ..Rp2040Options::default()
    };
    Rp2040::start_with(&firmware(), &options).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn two_picos_at_once_report_two_serial_numbers_from_their_flash_ids() {
    let a = boot(0x0123_4567_89AB_CDEF);
    let b = boot(DEFAULT_UNIQUE_ID);
    let serial_a = a.serial_number().expect("board A printed no serial number");
    let serial_b = b.serial_number().expect("board B printed no serial number");
    assert_eq!(serial_a, "placedb.example:0123456789ABCDEF");
    assert_eq!(serial_b, "placedb.example:E6614103E7452D2F");
    assert_ne!(serial_a, serial_b);

    // Both run at once and answer on their own port.
    let mut clients = [Client::new(a), Client::new(b)];
    for c in &mut clients {
        let st = client::status(c, Duration::from_secs(60)).unwrap();
        assert_eq!(st.phase, Phase::Unconfigured);
    }

    // `--port` by serial number: as if both were plugged in over USB, each
    // is found by its whole serial number or the end of its ID.
    let ports = [
        UsbPort {
            path: "/dev/ttyACM0".into(),
            serial: Some(serial_a.clone()),
        },
        UsbPort {
            path: "/dev/ttyACM1".into(),
            serial: Some(serial_b.clone()),
        },
    ];
    assert_eq!(resolve(&serial_a, &ports).unwrap(), "/dev/ttyACM0");
    assert_eq!(resolve("2D2F", &ports).unwrap(), "/dev/ttyACM1");
    assert_eq!(resolve("cdef", &ports).unwrap(), "/dev/ttyACM0");
    let [a, b] = clients;
    a.into_link().stop();
    b.into_link().stop();
}
