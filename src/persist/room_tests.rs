//! [`Log::has_room_then`] against the log itself: for a log filled to many
//! points, records of two lengths in order fit exactly when it says so.

extern crate std;
use super::log::{Log, LogError};
use super::sim::SimFlash;
use std::vec;

const SECTORS: usize = 6;
/// A key chunk record and a step's other records, as the device writes them.
const BIG: usize = 745;
const SMALL: usize = 252;

/// A log holding its start record and `filled` records of `SMALL` bytes.
fn log_with(filled: usize) -> Log<SimFlash> {
    let flash = SimFlash::new(SECTORS);
    let end = flash.bytes().len() as u32;
    let mut log = Log::open(flash, 0, end).unwrap();
    log.start(&[0]).unwrap();
    for _ in 0..filled {
        log.append(&[1; SMALL]).unwrap();
    }
    log
}

#[test]
fn room_for_two_lengths_is_exact() {
    let mut checked = (0, 0);
    for filled in (0..60).step_by(3) {
        for big in 0..10 {
            for small in (0..60).step_by(4) {
                let said = log_with(filled).has_room_then((big, BIG), (small, SMALL));
                let mut log = log_with(filled);
                let appended = (0..big)
                    .map(|_| vec![2u8; BIG])
                    .chain((0..small).map(|_| vec![3u8; SMALL]))
                    .try_for_each(|p| log.append(&p).map(|_| ()));
                assert!(
                    matches!(appended, Ok(()) | Err(LogError::Full)),
                    "{appended:?}"
                );
                assert_eq!(
                    said,
                    appended.is_ok(),
                    "{filled} records in, then {big} of {BIG} bytes and {small} of {SMALL}"
                );
                if said {
                    checked.0 += 1;
                } else {
                    checked.1 += 1;
                }
            }
        }
    }
    // Both answers were tried.
    assert!(checked.0 > 100 && checked.1 > 100, "{checked:?}");
}
