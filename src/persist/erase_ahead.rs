//! Sectors erased ahead of need, so that the erase a log append would do on
//! a request's path is done while the device has nothing else to do.
//!
//! A NOR sector erase is slow (the Pico's W25Q16JV: 45 ms typically, 400 ms
//! at worst, with the CPU and USB stalled), and [`super::Log`] erases a
//! sector right before it writes the first record there. [`EraseAhead`]
//! wraps the flash under the log: a board calls
//! `log.flash().erase_ahead(log.next_sector())` when it is idle, and the
//! log's own erase of that sector, later, is skipped because the sector is
//! still erased.
//!
//! Why this keeps the log's power-cut guarantees:
//! - What is erased early is [`super::Log::next_sector`], the sector the
//!   log's next erase goes to (its next sector, or a new generation's head);
//!   it holds nothing the live generation reads. Erasing it early does what
//!   the log's own erase would do; a cut between that erase and the write
//!   that follows is a case the log already survives (the interval is just
//!   longer).
//! - An erase is skipped only for a sector this value erased completely
//!   (the flash said so) and that nothing has written since: its contents
//!   are then exactly what the skipped erase would leave. The mark is in
//!   RAM, so a power cut forgets it and the sector is erased again (a torn
//!   erase may read as all 0xFF and still be weak: it is never trusted).

use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};

/// `F` with at most one sector erased ahead of need (see the module docs).
#[derive(Debug)]
pub struct EraseAhead<F> {
    flash: F,
    /// Offset of a sector erased here and not written since.
    erased: Option<u32>,
}

impl<F: NorFlash> EraseAhead<F> {
    /// `flash`, with no sector known to be erased.
    pub fn new(flash: F) -> Self {
        EraseAhead {
            flash,
            erased: None,
        }
    }

    /// The flash underneath.
    pub fn inner(&mut self) -> &mut F {
        &mut self.flash
    }

    /// Gives the flash back.
    pub fn into_inner(self) -> F {
        self.flash
    }

    /// Whether the sector at `offset` is erased ahead (the next erase of it
    /// is skipped).
    pub fn is_erased(&self, offset: u32) -> bool {
        self.erased == Some(offset)
    }

    /// Erases the sector at `offset` (a multiple of the sector size) unless
    /// it is erased ahead already; true if it erased. Call it with
    /// [`super::Log::next_sector`] only: any other sector may hold records.
    pub fn erase_ahead(&mut self, offset: u32) -> Result<bool, F::Error> {
        if self.is_erased(offset) {
            return Ok(false);
        }
        // The one mark moves: whatever was marked before stays erased, its
        // erase is just not skipped.
        self.erased = None;
        let end = offset.saturating_add(F::ERASE_SIZE as u32);
        self.flash.erase(offset, end)?;
        self.erased = Some(offset);
        Ok(true)
    }

    /// Whether the marked sector lies in `from..to`.
    fn marked_in(&self, from: u32, to: u32) -> Option<u32> {
        self.erased.filter(|&s| s >= from && s < to)
    }
}

impl<F: NorFlash> ErrorType for EraseAhead<F> {
    type Error = F::Error;
}

impl<F: NorFlash> ReadNorFlash for EraseAhead<F> {
    const READ_SIZE: usize = F::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.flash.read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl<F: NorFlash> NorFlash for EraseAhead<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let Some(marked) = self.marked_in(from, to) else {
            return self.flash.erase(from, to);
        };
        // The marked sector is erased already: erase the rest around it.
        let after = marked.saturating_add(F::ERASE_SIZE as u32);
        if from < marked {
            self.flash.erase(from, marked)?;
        }
        if after < to {
            self.flash.erase(after, to)?;
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let end = offset.saturating_add(bytes.len() as u32);
        if let Some(marked) = self.erased {
            let marked_end = marked.saturating_add(F::ERASE_SIZE as u32);
            // Written (or perhaps written, if this fails): no longer erased.
            if offset < marked_end && end > marked && !bytes.is_empty() {
                self.erased = None;
            }
        }
        self.flash.write(offset, bytes)
    }
}

#[cfg(all(test, feature = "sim-flash"))]
mod tests {
    extern crate std;
    use super::*;
    use crate::persist::sim::{SimFlash, Tear};
    use crate::persist::Log;
    use std::format;
    use std::vec::Vec;

    const SECTORS: usize = 4;
    const RECORD: [u8; 900] = [7; 900];

    fn open(flash: EraseAhead<SimFlash>) -> Log<EraseAhead<SimFlash>> {
        let end = flash.capacity() as u32;
        Log::open(flash, 0, end).unwrap()
    }

    fn payloads(log: &mut Log<EraseAhead<SimFlash>>) -> Vec<Vec<u8>> {
        let mut out = Vec::new();
        log.replay(&mut |_, p| out.push(p.to_vec())).unwrap();
        out
    }

    /// A board's idle moment: erase the log's next sector ahead.
    fn idle(log: &mut Log<EraseAhead<SimFlash>>) -> Result<bool, ()> {
        let next = log.next_sector();
        log.flash().erase_ahead(next).map_err(|_| ())
    }

    #[test]
    fn an_append_after_an_idle_erase_does_not_erase() {
        let mut log = open(EraseAhead::new(SimFlash::new(SECTORS)));
        assert_eq!(idle(&mut log), Ok(true));
        assert_eq!(idle(&mut log), Ok(false), "erased once, not again");
        let steps = log.flash().inner().steps();
        log.start(b"first").unwrap();
        // The head's erase was skipped: one step, the write.
        assert_eq!(log.flash().inner().steps(), steps + 1);
        // Fill the head sector ("first" and 4 records of 920 bytes: the
        // next does not fit), then the next sector is erased while idle,
        // and the append that opens it only writes.
        for _ in 0..4 {
            log.append(&RECORD).unwrap();
        }
        assert_eq!(idle(&mut log), Ok(true));
        let steps = log.flash().inner().steps();
        log.append(&RECORD).unwrap();
        assert_eq!(
            log.flash().inner().steps(),
            steps + 1,
            "no erase on the path"
        );
        assert_eq!(log.sectors_used(), 2);
        // Written: the mark is gone, the next sector is the one after.
        assert!(!log.flash().is_erased(4096));
        assert_eq!(log.next_sector(), 2 * 4096);
        let mut again = open(EraseAhead::new(log.into_flash().into_inner()));
        assert_eq!(payloads(&mut again).len(), 6);
    }

    #[test]
    fn a_sector_written_after_its_early_erase_is_erased_again() {
        let mut flash = EraseAhead::new(SimFlash::new(SECTORS));
        assert_eq!(flash.erase_ahead(4096), Ok(true));
        flash.write(4096 + 8, &[0u8; 4]).unwrap();
        assert!(!flash.is_erased(4096));
        let steps = flash.inner().steps();
        flash.erase(4096, 8192).unwrap();
        assert_eq!(flash.inner().steps(), steps + 1, "the erase was done");
        assert_eq!(flash.inner().bytes()[4096 + 8], 0xFF);
        // A range around the mark erases the rest, not the marked sector.
        assert_eq!(flash.erase_ahead(4096), Ok(true));
        let steps = flash.inner().steps();
        flash.erase(0, 3 * 4096).unwrap();
        assert_eq!(flash.inner().steps(), steps + 2);
    }

    /// A scan that appends and erases ahead in turn, with a power cut at
    /// every flash step, torn every way: after the reboot every record whose
    /// append returned `Ok` is there, in order, and at most the record being
    /// appended besides; and the log goes on.
    #[test]
    fn a_power_cut_at_every_step_with_erases_ahead_loses_nothing_acknowledged() {
        let mut cuts = 0;
        for step in 0.. {
            let mut completed = false;
            for tear in [Tear::Before, Tear::Half, Tear::After] {
                let mut flash = SimFlash::new(SECTORS);
                flash.cut_at(step, tear);
                let mut log = open(EraseAhead::new(flash));
                let mut acked: Vec<Vec<u8>> = Vec::new();
                let mut trying: Option<Vec<u8>> = None;
                let _ = idle(&mut log);
                for i in 0..7u8 {
                    let payload: Vec<u8> = [i; 900].to_vec();
                    let ok = if i == 0 {
                        log.start(&payload).is_ok()
                    } else {
                        log.append(&payload).is_ok()
                    };
                    if !ok {
                        trying = Some(payload);
                        break;
                    }
                    acked.push(payload);
                    if i % 2 == 1 && idle(&mut log).is_err() {
                        break;
                    }
                }
                let off = log.flash().inner().is_off();
                let mut flash = log.into_flash().into_inner();
                flash.power_on();
                let mut log = open(EraseAhead::new(flash));
                let found = payloads(&mut log);
                let ctx = format!("cut at step {step} ({tear:?}): {} found", found.len());
                let with_trying = trying.iter().fold(acked.clone(), |mut v, t| {
                    v.push(t.clone());
                    v
                });
                assert!(found == acked || found == with_trying, "{ctx}");
                // The way out: the scan goes on (or starts, if nothing was).
                let more = b"more";
                if found.is_empty() {
                    log.start(more).unwrap();
                } else {
                    log.append(more).unwrap();
                }
                let _ = idle(&mut log);
                let mut log = open(EraseAhead::new(log.into_flash().into_inner()));
                assert_eq!(
                    payloads(&mut log).last().map(Vec::as_slice),
                    Some(&more[..]),
                    "{ctx}"
                );
                cuts += u32::from(off);
                completed |= !off;
            }
            if completed {
                break;
            }
        }
        // Seven writes and three erases, all ahead (sectors 0 and 1 for the
        // records, 2 after them), each cut three ways.
        assert_eq!(cuts, 3 * 10);
    }
}
