//! An emulated NOR flash in the first 1 MiB of the board's PSRAM, as
//! [`embedded_storage::nor_flash`] ([`ReadNorFlash`], [`NorFlash`],
//! [`MultiwriteNorFlash`]).
//!
//! What it is for: giving the firmware a persistent store it can lose power
//! on. The AN386 has no flash the firmware may write; its 16 MiB PSRAM at
//! `0x2100_0000` is QEMU's machine RAM (`mps.ram`), which QEMU can back with a
//! host file. The firmware's own RAM is at `0x2000_0000` (the root `memory.x`),
//! so no Rust object lives in the PSRAM and this window
//! (`0x2100_0000..0x2110_0000`) belongs to [`PsramFlash`] alone. A host test
//! "cuts the power" by killing QEMU and boots again on the same file.
//!
//! For the contents to survive, QEMU must be started with the machine RAM
//! mapped from a shared file:
//!
//! ```text
//! qemu-system-arm -machine mps2-an386,memory-backend=placedb-flash \
//!     -object memory-backend-file,id=placedb-flash,size=16M,mem-path=FILE,share=on ...
//! ```
//!
//! (`placedb_host::board::emulator::qemu::QemuOptions::flash` does this, and creates FILE
//! filled with 0xFF, an erased chip, when it is missing). Without it the PSRAM
//! is anonymous memory: zero at every start of QEMU, which this driver reads
//! as programmed-to-zero flash, not as erased. The ELF loaded by `-kernel` and
//! a system reset leave the PSRAM alone.
//!
//! Modelled: NOR semantics, so that code which would break on a real chip
//! breaks here. [`NorFlash::erase`] sets every byte of whole 4 KiB sectors to
//! 0xFF; [`NorFlash::write`] can only clear bits (`new = old & data`), so
//! writing without erasing first silently ANDs. Reads are byte-granular,
//! writes 4-byte aligned words, erases 4 KiB aligned sectors; a misaligned or
//! out-of-range request returns [`FlashError`] and touches nothing.
//!
//! Not modelled: timing (erase and write are instantaneous), wear and erase
//! limits, read disturb, and torn operations. A power cut under QEMU is a kill
//! of the emulator between two guest instructions, so every word store either
//! happened or did not: an interrupted `write` or `erase` leaves a prefix of
//! its words done (a torn *sequence*), but a single word is never half
//! programmed and an erase never leaves a sector half-erased with random
//! bits. The core's host tests simulate that finer tearing.

use core::sync::atomic::{AtomicBool, Ordering};
use embedded_storage::nor_flash::{
    ErrorType, MultiwriteNorFlash, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

/// Start of the emulated flash: the AN386 PSRAM (QEMU `mps.ram`).
pub const FLASH_BASE: usize = 0x2100_0000;
/// Size of the emulated flash: the first 1 MiB of the 16 MiB PSRAM.
pub const FLASH_SIZE: usize = 1 << 20;

/// Why a flash operation was refused (nothing was read or changed).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FlashError {
    /// The range leaves `0..FLASH_SIZE`, or an erase has `from > to`.
    OutOfBounds,
    /// The offset or length is not a multiple of the operation's unit
    /// (`WRITE_SIZE` for writes, `ERASE_SIZE` for erases).
    NotAligned,
}

impl NorFlashError for FlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            FlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            FlashError::NotAligned => NorFlashErrorKind::NotAligned,
        }
    }
}

/// The emulated NOR flash over `FLASH_BASE..FLASH_BASE + FLASH_SIZE`. At most
/// one instance exists ([`PsramFlash::take`]), so `&mut self` is exclusive
/// access to the window.
pub struct PsramFlash {
    _private: (),
}

static FLASH_TAKEN: AtomicBool = AtomicBool::new(false);

impl PsramFlash {
    /// The flash; `None` if it was taken before.
    pub fn take() -> Option<PsramFlash> {
        if FLASH_TAKEN.swap(true, Ordering::AcqRel) {
            return None;
        }
        Some(PsramFlash { _private: () })
    }

    /// The byte range `offset..offset + len` if it lies in the flash and both
    /// ends are multiples of `unit`.
    fn range(offset: u32, len: usize, unit: usize) -> Result<(usize, usize), FlashError> {
        let start = usize::try_from(offset).map_err(|_| FlashError::OutOfBounds)?;
        let end = start.checked_add(len).ok_or(FlashError::OutOfBounds)?;
        if end > FLASH_SIZE {
            return Err(FlashError::OutOfBounds);
        }
        if !start.is_multiple_of(unit) || !len.is_multiple_of(unit) {
            return Err(FlashError::NotAligned);
        }
        Ok((start, end))
    }

    fn read_byte(offset: usize) -> u8 {
        debug_assert!(offset < FLASH_SIZE);
        // SAFETY: callers pass `offset < FLASH_SIZE` (checked by `range`), so
        // the address is inside the PSRAM window, which is always mapped RAM on
        // this board (QEMU `mps.ram`) and holds no Rust object (the linker
        // places nothing there), so a volatile read cannot alias or fault.
        unsafe { core::ptr::read_volatile((FLASH_BASE + offset) as *const u8) }
    }

    fn read_word(offset: usize) -> u32 {
        debug_assert!(offset.is_multiple_of(4) && offset + 4 <= FLASH_SIZE);
        // SAFETY: callers pass a 4-byte aligned `offset` with `offset + 4 <=
        // FLASH_SIZE` (checked by `range`); FLASH_BASE is aligned, so this is
        // an aligned word of the mapped, otherwise unused PSRAM window.
        unsafe { core::ptr::read_volatile((FLASH_BASE + offset) as *const u32) }
    }

    fn write_word(&mut self, offset: usize, value: u32) {
        debug_assert!(offset.is_multiple_of(4) && offset + 4 <= FLASH_SIZE);
        // SAFETY: as in `read_word`, an aligned word of the mapped PSRAM
        // window; no Rust object lives there and `&mut self` (one instance,
        // `take`) makes this the only access, so the store races nothing.
        unsafe { core::ptr::write_volatile((FLASH_BASE + offset) as *mut u32, value) }
    }
}

impl ErrorType for PsramFlash {
    type Error = FlashError;
}

impl ReadNorFlash for PsramFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        let (start, _) = Self::range(offset, bytes.len(), Self::READ_SIZE)?;
        for (i, b) in bytes.iter_mut().enumerate() {
            *b = Self::read_byte(start + i);
        }
        Ok(())
    }

    fn capacity(&self) -> usize {
        FLASH_SIZE
    }
}

impl NorFlash for PsramFlash {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = 4096;

    /// Sets every byte of the sectors `from..to` to 0xFF; both ends must be
    /// multiples of `ERASE_SIZE` and `from <= to <= FLASH_SIZE`.
    fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        if from > to {
            return Err(FlashError::OutOfBounds);
        }
        let len = usize::try_from(to - from).map_err(|_| FlashError::OutOfBounds)?;
        let (start, end) = Self::range(from, len, Self::ERASE_SIZE)?;
        for word in (start..end).step_by(4) {
            self.write_word(word, 0xFFFF_FFFF);
        }
        Ok(())
    }

    /// Programs `bytes` at `offset`: each bit can only go from 1 to 0
    /// (`new = old & data`); both must be multiples of `WRITE_SIZE`.
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        let (start, _) = Self::range(offset, bytes.len(), Self::WRITE_SIZE)?;
        for (i, chunk) in bytes.chunks_exact(4).enumerate() {
            let word = start + 4 * i;
            let mut data = [0u8; 4];
            data.copy_from_slice(chunk);
            let old = Self::read_word(word);
            self.write_word(word, old & u32::from_le_bytes(data));
        }
        Ok(())
    }
}

/// A word may be programmed again without an erase: it ANDs, as on real NOR.
impl MultiwriteNorFlash for PsramFlash {}
