//! A NOR flash in RAM that can lose power, for tests and fuzzing of the log
//! and the device on a workstation (feature `sim-flash`, which needs `std`).
//!
//! NOR rules are enforced so that a log relying on anything else fails here:
//! erasing sets a sector to 0xFF, writing can only clear bits (and is refused
//! over bytes not erased, where real parts misbehave). Every `erase` and
//! `write` call is one *step*; [`SimFlash::cut_at`] makes step `n` the last
//! one before the power goes, torn as [`Tear`] says, and every operation after
//! it fails until [`SimFlash::power_on`].
//!
//! Faults a real part has and a driver cannot see without reading back
//! (the RP2040 boot ROM's erase and program return nothing):
//! [`SimFlash::drop_bits`] makes every program in a sector leave some bits
//! unprogrammed (a worn sector, a supply below the part's minimum), and
//! [`SimFlash::protect`] makes a sector's erases and programs do nothing
//! (protect bits left set by earlier firmware); both report success.
//!
//! Tears a real part leaves and a prefix does not ([`Tear`]): a program
//! whose cells are just past the read threshold ([`Tear::Marginal`]: right
//! now, wrong after [`SimFlash::fade`], a later boot), a program that took
//! a random part of its bits, an erase that went from the sector's end
//! (offset 0 intact) or that stopped after the part zeroed every cell.

// Host-only test code: plain indexing of its own vector is fine here.
#![allow(clippy::indexing_slicing)]

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::vec;
use std::vec::Vec;

use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

/// What the step that loses power leaves behind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Tear {
    /// Nothing of it reached the flash.
    Before,
    /// Its first half (bytes, or the sector's first half for an erase); the
    /// first byte not written is left half programmed (its low bits).
    Half,
    /// All of it, but the caller never learns it succeeded.
    After,
    /// All of it, reading back right, but with cells just past the read
    /// threshold: [`SimFlash::fade`] (a later boot) makes it read wrong.
    Marginal,
    /// A write clears a pseudo-random subset (from the seed) of the bits it
    /// should; an erase sets a pseudo-random subset of the sector's bits.
    Scattered(u8),
    /// An erase that went from the sector's end: its second half erased,
    /// the first half (and the record at offset 0) as it was.
    KeepHead,
    /// An erase cut after the part programmed every cell to 0 and before
    /// it erased: the whole sector reads 0x00.
    Zeroed,
}

/// Why a flash operation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SimFlashError {
    /// Not aligned to the granularity.
    NotAligned,
    /// Outside the flash.
    OutOfBounds,
    /// A write over bytes that are not erased.
    NotErased,
    /// The power is off.
    PowerCut,
}

impl NorFlashError for SimFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            SimFlashError::NotAligned => NorFlashErrorKind::NotAligned,
            SimFlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            _ => NorFlashErrorKind::Other,
        }
    }
}

/// `SECTORS` sectors of 4 KiB, written in 4-byte words.
#[derive(Debug, Clone)]
pub struct SimFlash {
    bytes: Vec<u8>,
    steps: u64,
    cut: Option<(u64, Tear)>,
    off: Arc<AtomicBool>,
    /// A sector whose programs leave these bits of every byte at 1.
    weak: Option<(usize, u8)>,
    /// A sector whose erases and programs do nothing.
    protected: Option<usize>,
    /// Ranges a [`Tear::Marginal`] step left weak, erased (`true`) or
    /// programmed, until [`SimFlash::fade`] or an erase over them.
    marginal: Vec<(std::ops::Range<usize>, bool)>,
}

impl SimFlash {
    /// Sector size.
    pub const SECTOR: usize = 4096;

    /// An erased flash of `sectors` sectors.
    pub fn new(sectors: usize) -> Self {
        SimFlash {
            bytes: vec![0xFF; sectors * Self::SECTOR],
            steps: 0,
            cut: None,
            off: Arc::new(AtomicBool::new(false)),
            weak: None,
            protected: None,
            marginal: Vec::new(),
        }
    }

    /// Time passes (a later boot): what a [`Tear::Marginal`] step left
    /// weak reads wrong from now on. A programmed range gets one bit back
    /// at 1 (its first programmed byte), an erased one a bit at 0 (its
    /// first byte). Returns how many ranges faded.
    pub fn fade(&mut self) -> usize {
        let faded = self.marginal.len();
        for (range, erased) in std::mem::take(&mut self.marginal) {
            let bytes = &mut self.bytes[range];
            if erased {
                if let Some(b) = bytes.first_mut() {
                    *b &= 0xFE;
                }
            } else if let Some(b) = bytes.iter_mut().find(|b| **b != 0xFF) {
                *b |= 1 << b.trailing_ones();
            }
        }
        faded
    }

    /// Every program in sector `sector` from now on leaves the bits of
    /// `mask` at 1 in each byte it should clear them in, and reports
    /// success.
    pub fn drop_bits(&mut self, sector: usize, mask: u8) {
        self.weak = Some((sector, mask));
    }

    /// Erases and programs of sector `sector` from now on change nothing
    /// and report success (its protect bits are set).
    pub fn protect(&mut self, sector: usize) {
        self.protected = Some(sector);
    }

    fn is_protected(&self, range: &std::ops::Range<usize>) -> bool {
        self.protected.is_some_and(|s| {
            range.start / Self::SECTOR <= s && s < range.end.div_ceil(Self::SECTOR)
        })
    }

    /// Erase and write steps taken so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Step number `step` (counted from 0 by [`Self::steps`]) is the last
    /// before the power goes, torn as `tear` says.
    pub fn cut_at(&mut self, step: u64, tear: Tear) {
        self.cut = Some((step, tear));
    }

    /// Whether the power is off.
    pub fn is_off(&self) -> bool {
        self.off.load(Ordering::Relaxed)
    }

    /// A handle that tells whether the power is off, for code that cannot
    /// reach the flash (e.g. a reply callback: a device without power sends
    /// nothing).
    pub fn power(&self) -> Arc<AtomicBool> {
        Arc::clone(&self.off)
    }

    /// Power comes back: operations work again, no cut is pending.
    pub fn power_on(&mut self) {
        self.off.store(false, Ordering::Relaxed);
        self.cut = None;
    }

    /// The raw contents.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// The raw contents, to damage them in a test (not a flash step).
    pub fn bytes_mut(&mut self) -> &mut [u8] {
        &mut self.bytes
    }

    /// Places a CRC-valid log record (layout of [`super::log`]) of any
    /// generation and sequence number at byte `at`, over whatever is there,
    /// as a damaged or adversarial image may hold it (not a flash step).
    /// Returns the bytes it occupies (padded with 0xFF to the write size),
    /// or `None` when it does not fit the flash or the payload is too long.
    pub fn put_record(
        &mut self,
        at: usize,
        generation: u32,
        seq: u32,
        payload: &[u8],
    ) -> Option<usize> {
        use super::log::{header, HEADER_LEN, MAX_PAYLOAD};
        if payload.len() > MAX_PAYLOAD {
            return None;
        }
        let len = (HEADER_LEN + payload.len()).next_multiple_of(Self::WRITE_SIZE);
        let end = at.checked_add(len).filter(|&e| e <= self.bytes.len())?;
        let record = &mut self.bytes[at..end];
        record.fill(0xFF);
        let head = header(generation, seq, payload);
        for (b, v) in record.iter_mut().zip(head.iter().chain(payload)) {
            *b = *v;
        }
        Some(len)
    }

    /// Counts a step; `Some(tear)` when it is the one that loses power.
    fn step(&mut self) -> Result<Option<Tear>, SimFlashError> {
        if self.is_off() {
            return Err(SimFlashError::PowerCut);
        }
        let n = self.steps;
        self.steps += 1;
        Ok(match self.cut {
            Some((at, tear)) if at == n => {
                self.off.store(true, Ordering::Relaxed);
                Some(tear)
            }
            _ => None,
        })
    }

    fn range(
        &self,
        offset: u32,
        len: usize,
        align: usize,
    ) -> Result<std::ops::Range<usize>, SimFlashError> {
        let start = offset as usize;
        if !start.is_multiple_of(align) || !len.is_multiple_of(align) {
            return Err(SimFlashError::NotAligned);
        }
        let end = start.checked_add(len).ok_or(SimFlashError::OutOfBounds)?;
        if end > self.bytes.len() {
            return Err(SimFlashError::OutOfBounds);
        }
        Ok(start..end)
    }
}

/// How much of a torn step of `len` bytes lands.
fn landed(len: usize, tear: Option<Tear>) -> usize {
    match tear {
        Some(Tear::Before) => 0,
        Some(Tear::Half) => len / 2,
        _ => len,
    }
}

/// A pseudo-random bit mask per byte (xorshift), for [`Tear::Scattered`].
struct Scatter(u32);

impl Scatter {
    fn new(seed: u8) -> Self {
        Scatter(0x9E37_79B9 ^ u32::from(seed).wrapping_mul(0x0101_0101) | 1)
    }

    fn next(&mut self) -> u8 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 17;
        self.0 ^= self.0 << 5;
        // About one bit in four.
        let [a, b, ..] = self.0.to_le_bytes();
        a & b
    }
}

impl ErrorType for SimFlash {
    type Error = SimFlashError;
}

impl ReadNorFlash for SimFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        if self.is_off() {
            return Err(SimFlashError::PowerCut);
        }
        let range = self.range(offset, bytes.len(), 1)?;
        bytes.copy_from_slice(&self.bytes[range]);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.bytes.len()
    }
}

impl NorFlash for SimFlash {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = Self::SECTOR;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let len = (to as usize)
            .checked_sub(from as usize)
            .ok_or(SimFlashError::OutOfBounds)?;
        let range = self.range(from, len, Self::SECTOR)?;
        let tear = self.step()?;
        let n = landed(len, tear);
        if self.is_protected(&range) {
            // Protected: the part ignores the command (a whole-range erase
            // here spans one sector at a time in the log).
            return match tear {
                Some(_) => Err(SimFlashError::PowerCut),
                None => Ok(()),
            };
        }
        // A completed erase leaves nothing weak in its range.
        self.marginal
            .retain(|(r, _)| r.end <= range.start || r.start >= range.end);
        match tear {
            Some(Tear::KeepHead) => {
                let half = range.start + len / 2;
                self.bytes[half..range.end].fill(0xFF);
            }
            Some(Tear::Zeroed) => self.bytes[range.clone()].fill(0),
            Some(Tear::Scattered(seed)) => {
                let mut bits = Scatter::new(seed);
                for b in &mut self.bytes[range.clone()] {
                    *b |= bits.next();
                }
            }
            _ => self.bytes[range.start..range.start + n].fill(0xFF),
        }
        match tear {
            // The rest is left as it was but weakened: some bits set.
            Some(Tear::Half) => {
                if let Some(b) = self.bytes.get_mut(range.start + n) {
                    *b |= 0x0F;
                }
            }
            Some(Tear::Marginal) => self.marginal.push((range, true)),
            _ => {}
        }
        if tear.is_some() {
            return Err(SimFlashError::PowerCut);
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, data: &[u8]) -> Result<(), Self::Error> {
        let range = self.range(offset, data.len(), Self::WRITE_SIZE)?;
        if self.is_protected(&range) {
            // The part ignores the command: nothing changes, success.
            return match self.step()? {
                Some(_) => Err(SimFlashError::PowerCut),
                None => Ok(()),
            };
        }
        if self.bytes[range.clone()].iter().any(|&b| b != 0xFF) {
            return Err(SimFlashError::NotErased);
        }
        let tear = self.step()?;
        let n = landed(data.len(), tear);
        let keep = match self.weak {
            Some((sector, mask)) if range.start / Self::SECTOR == sector => mask,
            _ => 0,
        };
        let mut scatter = match tear {
            Some(Tear::Scattered(seed)) => Some(Scatter::new(seed)),
            _ => None,
        };
        for (b, d) in self.bytes[range.start..range.start + n]
            .iter_mut()
            .zip(data)
        {
            // Bits the scatter keeps at 1 did not program.
            let missed = scatter.as_mut().map_or(0, Scatter::next);
            *b &= d | keep | missed;
        }
        match tear {
            Some(Tear::Half) => {
                if let (Some(b), Some(d)) = (self.bytes.get_mut(range.start + n), data.get(n)) {
                    *b &= d | 0xF0;
                }
            }
            Some(Tear::Marginal) => self.marginal.push((range, false)),
            _ => {}
        }
        if tear.is_some() {
            return Err(SimFlashError::PowerCut);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nor_rules_and_power_cuts() {
        let mut f = SimFlash::new(2);
        f.write(0, &[0x0F, 0xF0, 0xFF, 0x00]).unwrap();
        assert_eq!(f.write(0, &[0; 4]), Err(SimFlashError::NotErased));
        assert_eq!(f.write(1, &[0; 4]), Err(SimFlashError::NotAligned));
        assert_eq!(f.erase(0, 100), Err(SimFlashError::NotAligned));
        assert_eq!(f.write(8192, &[0; 4]), Err(SimFlashError::OutOfBounds));
        f.erase(0, 4096).unwrap();
        assert_eq!(&f.bytes()[..4], &[0xFF; 4]);
        assert_eq!(f.steps(), 2);
        f.cut_at(2, Tear::Half);
        assert_eq!(f.write(0, &[0; 8]), Err(SimFlashError::PowerCut));
        assert_eq!(&f.bytes()[..5], &[0, 0, 0, 0, 0xF0]);
        let mut buf = [0; 4];
        assert_eq!(f.read(0, &mut buf), Err(SimFlashError::PowerCut));
        f.power_on();
        f.read(0, &mut buf).unwrap();
        assert_eq!(buf, [0; 4]);
    }

    #[test]
    fn dropped_bits_and_protected_sectors_report_success() {
        let mut f = SimFlash::new(3);
        f.drop_bits(1, 0x01);
        f.protect(2);
        f.write(0, &[0; 4]).unwrap();
        assert_eq!(&f.bytes()[..4], &[0; 4]);
        f.write(4096, &[0x00, 0x10, 0xFE, 0xFF]).unwrap();
        assert_eq!(&f.bytes()[4096..4100], &[0x01, 0x11, 0xFF, 0xFF]);
        f.write(8192, &[0; 4]).unwrap();
        assert_eq!(&f.bytes()[8192..8196], &[0xFF; 4]);
        f.bytes_mut()[8192] = 0x12;
        f.erase(8192, 12288).unwrap();
        assert_eq!(f.bytes()[8192], 0x12, "a protected sector is not erased");
        f.erase(4096, 8192).unwrap();
        assert_eq!(&f.bytes()[4096..4100], &[0xFF; 4], "a weak sector erases");
        assert_eq!(f.steps(), 5);
    }
}
