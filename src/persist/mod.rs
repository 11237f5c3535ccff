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

// What runs on a device never panics: no indexing, unwrap or panic. (The
// test flash `sim` is host-only and exempt.)
#![cfg_attr(
    not(test),
    deny(
        clippy::indexing_slicing,
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic
    )
)]

pub mod log;
pub mod record;
#[cfg(feature = "sim-flash")]
pub mod sim;

pub use log::{FlashErrorKind, Log, LogError};
pub use record::{Record, RecordError};

use embedded_storage::nor_flash::NorFlash;

/// Where a device makes its records durable: a [`Log`], or [`NoJournal`].
pub trait Journal {
    /// Starts a new generation whose first record is `payload`, replacing
    /// the previous one only once durable.
    fn start(&mut self, payload: &[u8]) -> Result<(), LogError>;
    /// Appends a record; `Ok` means durable.
    fn append(&mut self, payload: &[u8]) -> Result<(), LogError>;
    /// Whether `count` records of up to `len` bytes are sure to fit.
    fn has_room(&self, count: usize, len: usize) -> bool;
    /// Whether appended records are kept (false for [`NoJournal`]).
    fn keeps(&self) -> bool {
        true
    }
}

impl<F: NorFlash> Journal for Log<F> {
    fn start(&mut self, payload: &[u8]) -> Result<(), LogError> {
        Log::start(self, payload)
    }

    fn append(&mut self, payload: &[u8]) -> Result<(), LogError> {
        Log::append(self, payload)
    }

    fn has_room(&self, count: usize, len: usize) -> bool {
        Log::has_room(self, count, len)
    }
}

/// No flash: nothing is written, there is always room.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoJournal;

impl Journal for NoJournal {
    fn start(&mut self, _: &[u8]) -> Result<(), LogError> {
        Ok(())
    }

    fn append(&mut self, _: &[u8]) -> Result<(), LogError> {
        Ok(())
    }

    fn has_room(&self, _: usize, _: usize) -> bool {
        true
    }

    fn keeps(&self) -> bool {
        false
    }
}
