//! The Pico's flash work counted on the host: sector erases and 256-byte
//! page programs of a scan, without the emulator.
//!
//! `bench --pico` needs the flash time of a *steady* scan (hundreds of
//! frames), and rp2040js runs the firmware at well under a tenth of the
//! Pico's speed. The flash work does not depend on the CPU: it is what the
//! core's log ([`Log`]) asks of the flash, and which sectors the firmware
//! erases ahead ([`EraseAhead`]). [`PicoFlashLink`] runs the firmware's
//! device ([`Device256K`], the ram256k profile) in-process on a simulated
//! 1 MiB NOR flash ([`SimFlash`], the firmware's log region) and drives it
//! as `boards/rp-pico/src/main.rs` does:
//! - every host message is handed to the device on its own (the firmware
//!   splits what it reads at each frame delimiter), and after one that
//!   leaves no frame open the next sector is erased ahead unless it is
//!   erased already;
//! - once it has handled all the host sent (the firmware's idle turn of
//!   the loop, no host byte waiting) the next sector is erased ahead too.
//!
//! It counts as the emulator's harness does (`sectors_erased`,
//! `pages_programmed`): one erase per 4 KiB sector, and for every write
//! the 256-byte pages it touches, as `boards/rp-pico/src/flash.rs` programs
//! a write page by page (a page partly written is programmed whole, the
//! rest padded with 0xFF). `bench --pico` checks the counts against the
//! emulator's for the frames the emulator streams, and
//! `host/tests/cli_reports.rs` tests that they agree.

use crate::board::link::{Link, LOCAL_FLASH_SECTORS};
use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use placedb::device::Device256K;
use placedb::persist::sim::{SimFlash, SimFlashError};
use placedb::persist::{EraseAhead, Log};
use placedb::protocol::Phase;
use std::io;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// The Pico's flash program unit (W25Q16JV page).
const PAGE: u64 = 256;

/// Flash operations, as the emulator counts them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FlashCount {
    /// 4 KiB sectors erased.
    pub erases: u64,
    /// 256-byte pages programmed.
    pub programs: u64,
}

/// [`SimFlash`] counting what the Pico's flash would do.
struct CountingFlash {
    flash: SimFlash,
    count: Arc<Mutex<FlashCount>>,
}

impl CountingFlash {
    fn add(&self, f: impl FnOnce(&mut FlashCount)) {
        // A poisoned count (a panic elsewhere) is still a count.
        f(&mut self.count.lock().unwrap_or_else(|e| e.into_inner()));
    }
}

impl ErrorType for CountingFlash {
    type Error = SimFlashError;
}

impl ReadNorFlash for CountingFlash {
    const READ_SIZE: usize = <SimFlash as ReadNorFlash>::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.flash.read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl NorFlash for CountingFlash {
    const WRITE_SIZE: usize = SimFlash::WRITE_SIZE;
    const ERASE_SIZE: usize = SimFlash::ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.flash.erase(from, to)?;
        let sectors = u64::from(to.saturating_sub(from)) / Self::ERASE_SIZE as u64;
        self.add(|c| c.erases += sectors);
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.flash.write(offset, bytes)?;
        if let Some(last) = (bytes.len() as u64).checked_sub(1) {
            let first = u64::from(offset);
            let pages = (first + last) / PAGE - first / PAGE + 1;
            self.add(|c| c.programs += pages);
        }
        Ok(())
    }
}

/// The log's flash, with the sector it needs next erased ahead, as the
/// firmware's.
type LogFlash = EraseAhead<CountingFlash>;

/// The Pico's device and flash log in-process, counting its flash work
/// (see the module docs). A [`Link`]: the host's client streams to it as
/// to a board; each `send` is handled before it returns.
pub struct PicoFlashLink {
    device: Box<Device256K>,
    log: Log<LogFlash>,
    replies: Vec<u8>,
    count: Arc<Mutex<FlashCount>>,
}

impl PicoFlashLink {
    /// A device as the Pico boots with an erased log region.
    pub fn new() -> Result<Self, String> {
        let count = Arc::new(Mutex::new(FlashCount::default()));
        let flash = CountingFlash {
            flash: SimFlash::new(LOCAL_FLASH_SECTORS),
            count: Arc::clone(&count),
        };
        let end = (LOCAL_FLASH_SECTORS * SimFlash::SECTOR) as u32;
        let mut log = Log::open(EraseAhead::new(flash), 0, end)
            .map_err(|e| format!("the simulated flash log does not open: {e}"))?;
        let mut device = Box::new(Device256K::new());
        // As the firmware boots: restore (an erased log restores nothing).
        let _ = device.restore(&mut log);
        Ok(PicoFlashLink {
            device,
            log,
            replies: Vec::new(),
            count,
        })
    }

    /// The flash work so far.
    pub fn count(&self) -> FlashCount {
        *self.count.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The firmware's `erase_ahead`: the sector the log's next erase goes
    /// to, unless it is erased already (a failed erase is the log's own
    /// erase's to retry).
    fn erase_ahead(&mut self) {
        let next = self.log.next_sector();
        let _ = self.log.flash().erase_ahead(next);
    }
}

impl Link for PicoFlashLink {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        for part in bytes.split_inclusive(|&b| b == 0) {
            let replies = &mut self.replies;
            self.device
                .receive_logged(part, &mut self.log, &mut |frame| {
                    replies.extend_from_slice(frame)
                });
            let between_frames = self.device.phase() != Phase::InFrame;
            if part.last() == Some(&0) && between_frames {
                self.erase_ahead();
            }
        }
        // All handled, nothing more from the host yet: the idle turn.
        self.erase_ahead();
        Ok(())
    }

    fn recv(&mut self, _timeout: Duration) -> io::Result<Vec<u8>> {
        if self.replies.is_empty() {
            // Every message was answered as it was sent: nothing will come.
            return Err(io::ErrorKind::TimedOut.into());
        }
        Ok(std::mem::take(&mut self.replies))
    }
}
