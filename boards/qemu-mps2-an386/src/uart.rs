//! Driver for the CMSDK APB UART (UART0 of the MPS2 boards), as
//! [`embedded_io::Read`] and [`embedded_io::Write`]: polled, except that a
//! read with nothing received sleeps (`wfi`) until a byte comes.
//!
//! Registers (ARM CMSDK APB UART, as modelled by QEMU's `cmsdk-apb-uart`):
//! DATA +0x00, STATE +0x04 (bit 0 TX buffer full, bit 1 RX buffer full),
//! CTRL +0x08 (bit 0 TX enable, bit 1 RX enable, bit 3 RX interrupt
//! enable), INTSTATUS +0x0C (bit 1 RX; write 1 to clear), BAUDDIV +0x10.
//! Nothing moves until CTRL enables it; QEMU needs BAUDDIV >= 16.
//!
//! Why the read sleeps: a board waiting for its host spun on STATE, a whole
//! host core for QEMU (issue 41). UART0's RX interrupt (IRQ 0 of the
//! AN385/AN386) is unmasked only for the `wfi`, with PRIMASK set, and masked
//! again before PRIMASK is cleared: it ends the wait, no handler ever runs,
//! and a frame's handling meets no interrupt it did not meet before.

use core::convert::Infallible;
use core::sync::atomic::{AtomicBool, Ordering};
use cortex_m::interrupt::InterruptNumber;
use cortex_m::peripheral::NVIC;

/// Base address of UART0 on the MPS2 AN385/AN386/AN500 memory maps.
const UART0_BASE: usize = 0x4000_4000;

const DATA: usize = 0x00;
const STATE: usize = 0x04;
const CTRL: usize = 0x08;
const INTSTATUS: usize = 0x0C;
const BAUDDIV: usize = 0x10;

const STATE_TX_FULL: u32 = 1 << 0;
const STATE_RX_FULL: u32 = 1 << 1;
/// TX and RX enabled, and the RX interrupt (raised when a byte comes in).
const CTRL_TX_RX_ENABLE_RX_INTERRUPT: u32 = 0b1011;
const INT_RX: u32 = 1 << 1;
const BAUDDIV_MIN: u32 = 16;

/// UART0's RX interrupt line on the MPS2 AN385/AN386 (QEMU's `mps2.c`:
/// UART0 RX is IRQ 0, its TX IRQ 1).
#[derive(Clone, Copy)]
struct Uart0Rx;

// SAFETY: 0 is an interrupt this board has (UART0 RX), as the trait requires.
unsafe impl InterruptNumber for Uart0Rx {
    fn number(self) -> u16 {
        0
    }
}

/// One 32-bit memory-mapped register. The UART's register accesses live
/// in its two methods.
#[derive(Clone, Copy)]
struct Reg(usize);

impl Reg {
    fn read(self) -> u32 {
        // SAFETY: `self.0` is one of the UART0 register addresses above: fixed,
        // 4-byte aligned, always mapped device memory on this board, and not
        // aliased by any Rust object, so a volatile read has no effect on memory
        // safety (reading DATA pops the RX byte, which is the intent).
        unsafe { core::ptr::read_volatile(self.0 as *const u32) }
    }

    fn write(self, value: u32) {
        // SAFETY: as in `read`: a fixed, aligned, mapped device register that no
        // Rust object occupies; the write only changes UART state.
        unsafe { core::ptr::write_volatile(self.0 as *mut u32, value) }
    }
}

/// A CMSDK UART. At most one instance per peripheral exists.
pub struct Uart {
    base: usize,
}

static UART0_TAKEN: AtomicBool = AtomicBool::new(false);

impl Uart {
    /// UART0, enabled for TX and RX; `None` if it was taken before.
    pub fn take_uart0() -> Option<Uart> {
        if UART0_TAKEN.swap(true, Ordering::AcqRel) {
            return None;
        }
        let uart = Uart { base: UART0_BASE };
        uart.reg(BAUDDIV).write(BAUDDIV_MIN);
        uart.reg(CTRL).write(CTRL_TX_RX_ENABLE_RX_INTERRUPT);
        Some(uart)
    }

    fn reg(&self, offset: usize) -> Reg {
        Reg(self.base + offset)
    }

    /// The received byte, if one is waiting.
    pub fn try_read_byte(&mut self) -> Option<u8> {
        if self.reg(STATE).read() & STATE_RX_FULL != 0 {
            Some(self.reg(DATA).read() as u8)
        } else {
            None
        }
    }

    /// Sleeps until a byte has been received (at once if one waits).
    /// Another interrupt or exception (SysTick) may end the sleep early:
    /// the caller looks again.
    pub fn wait_for_byte(&mut self) {
        cortex_m::interrupt::free(|_| {
            // From here on a byte raises the line: what an earlier byte
            // left (in the UART and pending in the NVIC) is cleared first,
            // so that only a byte after the check below ends the `wfi`,
            // and a byte between the check and the `wfi` ends it at once.
            self.reg(INTSTATUS).write(INT_RX);
            NVIC::unpend(Uart0Rx);
            if self.reg(STATE).read() & STATE_RX_FULL != 0 {
                return;
            }
            // SAFETY: unmasked with PRIMASK set and masked again before
            // this critical section ends, so its handler never runs (and
            // no critical section is broken): the line only ends the `wfi`
            // (which PRIMASK does not stop).
            unsafe { NVIC::unmask(Uart0Rx) };
            cortex_m::asm::wfi();
            NVIC::mask(Uart0Rx);
        });
    }

    /// Sends one byte, waiting while the TX buffer is full.
    pub fn write_byte(&mut self, byte: u8) {
        while self.reg(STATE).read() & STATE_TX_FULL != 0 {
            core::hint::spin_loop();
        }
        self.reg(DATA).write(u32::from(byte));
    }
}

impl embedded_io::ErrorType for Uart {
    type Error = Infallible;
}

impl embedded_io::Read for Uart {
    /// Waits for at least one byte (asleep, [`Uart::wait_for_byte`]), then
    /// returns every byte already received.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        let mut n = 0;
        for slot in buf.iter_mut() {
            let byte = loop {
                match self.try_read_byte() {
                    Some(b) => break Some(b),
                    None if n == 0 => self.wait_for_byte(),
                    None => break None,
                }
            };
            match byte {
                Some(b) => {
                    *slot = b;
                    n += 1;
                }
                None => break,
            }
        }
        Ok(n)
    }
}

impl embedded_io::ReadReady for Uart {
    fn read_ready(&mut self) -> Result<bool, Infallible> {
        Ok(self.reg(STATE).read() & STATE_RX_FULL != 0)
    }
}

impl embedded_io::Write for Uart {
    /// Sends every byte (blocking).
    fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        for &b in buf {
            self.write_byte(b);
        }
        Ok(buf.len())
    }

    /// Waits until the TX buffer has room (the CMSDK UART has no "TX idle" flag).
    fn flush(&mut self) -> Result<(), Infallible> {
        while self.reg(STATE).read() & STATE_TX_FULL != 0 {
            core::hint::spin_loop();
        }
        Ok(())
    }
}

impl embedded_io::WriteReady for Uart {
    fn write_ready(&mut self) -> Result<bool, Infallible> {
        Ok(self.reg(STATE).read() & STATE_TX_FULL == 0)
    }
}
