//! How long the Pico's flash is busy, as the RP2040 emulator models it
//! (`placedb device --rp2040 --flash-timing none|typical|max`), and the
//! longest a device reply can wait for its flash: what the host's reply
//! timeout must cover so that a stall is never taken for a lost device.
//!
//! Figures: Winbond W25Q16JV datasheet (the Pico's 2 MiB QSPI flash), AC
//! electrical characteristics: sector erase (4 KiB) tSE 45 ms typical,
//! 400 ms max; page program (256 bytes) tPP 0.4 ms typical, 3 ms max. The
//! harness (`boards/rp-pico/emulator/harness.mjs`) holds the emulated core
//! for that long per operation, in emulated time.

use placedb::persist::keys::MAX_KEY_CHUNKS;
use placedb::persist::log::{HEADER_LEN, MAX_PAYLOAD};
use placedb::persist::record::DECISION_BATCH;
use std::fmt;
use std::str::FromStr;
use std::time::Duration;

/// The flash's busy time per operation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FlashTiming {
    /// Erase and program take no time (the emulator before flash timing).
    None,
    /// The datasheet's typical figures.
    #[default]
    Typical,
    /// The datasheet's maximum figures: the worst a part may do.
    Max,
}

/// The flash's erase unit.
pub const SECTOR: usize = 4096;
/// The flash's program unit.
pub const PAGE: usize = 256;

impl FlashTiming {
    /// The name `--flash-timing` takes.
    pub fn name(self) -> &'static str {
        match self {
            FlashTiming::None => "none",
            FlashTiming::Typical => "typical",
            FlashTiming::Max => "max",
        }
    }

    /// Busy time of one 4 KiB sector erase (tSE).
    pub fn sector_erase(self) -> Duration {
        match self {
            FlashTiming::None => Duration::ZERO,
            FlashTiming::Typical => Duration::from_millis(45),
            FlashTiming::Max => Duration::from_millis(400),
        }
    }

    /// Busy time of one 256-byte page program (tPP).
    pub fn page_program(self) -> Duration {
        match self {
            FlashTiming::None => Duration::ZERO,
            FlashTiming::Typical => Duration::from_micros(400),
            FlashTiming::Max => Duration::from_millis(3),
        }
    }

    /// The longest one reply of a device with selector window `window`
    /// waits for its flash ([`WorstStall`]).
    pub fn worst_stall(self, window: usize) -> WorstStall {
        WorstStall::of(self, window)
    }
}

impl fmt::Display for FlashTiming {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for FlashTiming {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "none" => Ok(FlashTiming::None),
            "typical" => Ok(FlashTiming::Typical),
            "max" => Ok(FlashTiming::Max),
            other => Err(format!("flash timing {other:?}: say none, typical or max")),
        }
    }
}

/// A bound on the flash work behind one device reply, and its time.
///
/// The most one message makes a device write is one selection step that
/// decides its whole window (a FrameEnd after a long run of pending frames,
/// or the Finish): every one of `window` frames a database record with
/// [`MAX_KEY_CHUNKS`] key records, and the decision batches. Each record is
/// taken at its largest ([`MAX_PAYLOAD`] bytes and its header: 3 to a
/// sector, 6 pages when it straddles page boundaries). The sectors are the
/// ones those records fill, one more for the sector left part-filled (a new
/// record never straddles sectors), and one erase ahead that may have just
/// begun when the message arrived (the firmware erases ahead when idle and
/// between frames).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WorstStall {
    /// Records written.
    pub records: usize,
    /// Sectors erased.
    pub sectors: usize,
    /// Pages programmed.
    pub pages: usize,
    /// The time the flash is busy for them.
    pub time: Duration,
}

impl WorstStall {
    fn of(timing: FlashTiming, window: usize) -> WorstStall {
        let record = HEADER_LEN + MAX_PAYLOAD;
        let records = window * (1 + MAX_KEY_CHUNKS) + window.div_ceil(DECISION_BATCH);
        let sectors = records.div_ceil(SECTOR / record) + 2;
        let pages = records * (record.div_ceil(PAGE) + 1);
        let time = timing.sector_erase() * sectors as u32 + timing.page_program() * pages as u32;
        WorstStall {
            records,
            sectors,
            pages,
            time,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::scan::StreamOptions;

    /// The Pico runs profile ram256k: its window.
    fn pico_window() -> usize {
        placedb::profile::by_name("ram256k").unwrap().window
    }

    #[test]
    fn names_round_trip() {
        for t in [FlashTiming::None, FlashTiming::Typical, FlashTiming::Max] {
            assert_eq!(t.name().parse::<FlashTiming>(), Ok(t));
        }
        assert!("slow"
            .parse::<FlashTiming>()
            .unwrap_err()
            .contains("none, typical or max"));
        assert_eq!(FlashTiming::default(), FlashTiming::Typical);
    }

    #[test]
    fn the_worst_stall_of_the_pico_is_bounded() {
        let w = pico_window();
        assert_eq!(w, 32);
        let max = FlashTiming::Max.worst_stall(w);
        // 32 frames x 9 records + 2 decision batches; 3 records a sector.
        assert_eq!((max.records, max.sectors, max.pages), (290, 99, 1740));
        assert_eq!(max.time, Duration::from_millis(99 * 400 + 1740 * 3));
        let typical = FlashTiming::Typical.worst_stall(w);
        assert_eq!(
            typical.time,
            Duration::from_micros(99 * 45_000 + 1740 * 400)
        );
        assert_eq!(FlashTiming::None.worst_stall(w).time, Duration::ZERO);
    }

    /// The host's default reply timeout covers the Pico's longest flash
    /// stall at the datasheet's maximum timing, with 10 s to spare for the
    /// step's own computation: a stall never makes the host give up.
    #[test]
    fn the_default_reply_timeout_outlasts_the_worst_stall() {
        let worst = FlashTiming::Max.worst_stall(pico_window()).time;
        let timeout = StreamOptions::default().reply_timeout;
        assert!(
            timeout >= worst + Duration::from_secs(10),
            "reply timeout {timeout:?} against a worst stall of {worst:?}"
        );
    }
}
