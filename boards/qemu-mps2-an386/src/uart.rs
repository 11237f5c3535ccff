//! Polling driver for the CMSDK APB UART (UART0 of the MPS2 boards), as
//! [`embedded_io::Read`] and [`embedded_io::Write`].
//!
//! Registers (ARM CMSDK APB UART, as modelled by QEMU's `cmsdk-apb-uart`):
//! DATA +0x00, STATE +0x04 (bit 0 TX buffer full, bit 1 RX buffer full),
//! CTRL +0x08 (bit 0 TX enable, bit 1 RX enable), BAUDDIV +0x10.
//! Nothing moves until CTRL enables it; QEMU needs BAUDDIV >= 16.

use core::convert::Infallible;
use core::sync::atomic::{AtomicBool, Ordering};

/// Base address of UART0 on the MPS2 AN385/AN386/AN500 memory maps.
const UART0_BASE: usize = 0x4000_4000;

const DATA: usize = 0x00;
const STATE: usize = 0x04;
const CTRL: usize = 0x08;
const BAUDDIV: usize = 0x10;

const STATE_TX_FULL: u32 = 1 << 0;
const STATE_RX_FULL: u32 = 1 << 1;
const CTRL_TX_RX_ENABLE: u32 = 0b11;
const BAUDDIV_MIN: u32 = 16;

/// One 32-bit memory-mapped register. The only `unsafe` of the firmware lives
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

/// A CMSDK UART, polled. At most one instance per peripheral exists.
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
        uart.reg(CTRL).write(CTRL_TX_RX_ENABLE);
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
    /// Waits for at least one byte, then returns every byte already received.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        let mut n = 0;
        for slot in buf.iter_mut() {
            let byte = loop {
                match self.try_read_byte() {
                    Some(b) => break Some(b),
                    None if n == 0 => core::hint::spin_loop(),
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
