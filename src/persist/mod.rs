//! Durable scan state: what a device has decided survives a power cut.
//!
//! The device writes a [`record::Record`] for every database frame and every
//! final decision *before* it tells the host (so anything the host saw
//! acknowledged is in flash), into a [`log::Log`] over any `embedded-storage`
//! NOR flash. At boot, `Device::restore` replays the log: configuration,
//! database, labels and the finished flag come back, and the host resumes
//! the scan at the first undecided frame (`Status::frames_seen`).
//!
//! A device without flash uses [`NoJournal`] and keeps everything in RAM.

pub mod erase_ahead;
pub mod keys;
pub mod log;
pub mod record;
#[cfg(all(test, feature = "sim-flash"))]
mod room_tests;
#[cfg(feature = "sim-flash")]
pub mod sim;

pub use erase_ahead::EraseAhead;
pub use log::{Cursor, FlashErrorKind, Log, LogError};
pub use record::{Record, RecordError};

use embedded_storage::nor_flash::NorFlash;

/// Where a device makes its records durable, and reads them back: a
/// [`Log`], or [`NoJournal`].
pub trait Journal {
    /// Starts a new generation whose first record is `payload`, replacing
    /// the previous one only once durable.
    fn start(&mut self, payload: &[u8]) -> Result<(), LogError>;
    /// Appends a record; `Ok` means durable, with the record's position
    /// (`None` when records are not kept).
    fn append(&mut self, payload: &[u8]) -> Result<Option<u32>, LogError>;
    /// Whether `count` records of up to `len` bytes are sure to fit.
    fn has_room(&self, count: usize, len: usize) -> bool;
    /// Whether `first.0` records of up to `first.1` bytes, then `then.0`
    /// of up to `then.1`, are sure to fit (by default: all of them at the
    /// longer length).
    fn has_room_then(&self, first: (usize, usize), then: (usize, usize)) -> bool {
        self.has_room(first.0.saturating_add(then.0), first.1.max(then.1))
    }
    /// Whether appended records are kept (false for [`NoJournal`]).
    fn keeps(&self) -> bool {
        true
    }
    /// The payload of the record at `at`.
    fn read_at(&mut self, at: u32) -> Result<&[u8], LogError>;
    /// The record at `cursor` and its position; `None` after the last one.
    fn next(&mut self, cursor: &mut Cursor) -> Result<Option<(u32, &[u8])>, LogError>;
    /// Bytes in use and the most one scan may use.
    fn usage(&self) -> (u32, u32);
}

impl<F: NorFlash> Journal for Log<F> {
    fn start(&mut self, payload: &[u8]) -> Result<(), LogError> {
        Log::start(self, payload)
    }

    fn append(&mut self, payload: &[u8]) -> Result<Option<u32>, LogError> {
        Log::append(self, payload).map(Some)
    }

    fn has_room(&self, count: usize, len: usize) -> bool {
        Log::has_room(self, count, len)
    }

    fn has_room_then(&self, first: (usize, usize), then: (usize, usize)) -> bool {
        Log::has_room_then(self, first, then)
    }

    fn read_at(&mut self, at: u32) -> Result<&[u8], LogError> {
        Log::read_at(self, at)
    }

    fn next(&mut self, cursor: &mut Cursor) -> Result<Option<(u32, &[u8])>, LogError> {
        Log::next(self, cursor)
    }

    fn usage(&self) -> (u32, u32) {
        Log::usage(self)
    }
}

/// No flash: nothing is written, there is always room, nothing reads back.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoJournal;

impl Journal for NoJournal {
    fn start(&mut self, _: &[u8]) -> Result<(), LogError> {
        Ok(())
    }

    fn append(&mut self, _: &[u8]) -> Result<Option<u32>, LogError> {
        Ok(None)
    }

    fn has_room(&self, _: usize, _: usize) -> bool {
        true
    }

    fn keeps(&self) -> bool {
        false
    }

    fn read_at(&mut self, _: u32) -> Result<&[u8], LogError> {
        Err(LogError::NoRecord)
    }

    fn next(&mut self, _: &mut Cursor) -> Result<Option<(u32, &[u8])>, LogError> {
        Ok(None)
    }

    fn usage(&self) -> (u32, u32) {
        (0, 0)
    }
}
