//! `placedb device`: an emulated board (QEMU or the Pico under rp2040js) in
//! the foreground, its port printed.

use crate::device::emulator::{qemu, rp2040};
use crate::error::CommandError as Error;
use clap::Args;
use std::path::PathBuf;

/// `placedb device`.
#[derive(Args)]
pub struct DeviceArgs {
    /// Run the QEMU board (mps2-an386, Cortex-M4F, UART) under qemu-system-arm.
    #[arg(long, required_unless_present = "rp2040", conflicts_with = "rp2040")]
    qemu: bool,
    /// Run the Raspberry Pi Pico firmware (boards/rp-pico) under the RP2040
    /// emulator (rp2040js, Node): boot ROM, boot2, QSPI flash, and its USB
    /// CDC-ACM port bridged to TCP (`cd boards/rp-pico/emulator && npm ci`).
    #[arg(long)]
    rp2040: bool,
    /// Firmware ELF (default: the one built in boards/qemu-mps2-an386, or
    /// boards/rp-pico with --rp2040).
    #[arg(long)]
    firmware: Option<PathBuf>,
    /// Loopback TCP port for the board's UART or USB port (0: any free port).
    #[arg(long, default_value_t = 0)]
    port: u16,
    /// Run without -icount shift=0 (faster, but no exact instruction counts; QEMU only).
    #[arg(long)]
    no_icount: bool,
    /// File holding the board's flash (its database log); created erased if
    /// missing and kept across runs, so a restarted board restores its scan.
    #[arg(long)]
    flash: Option<PathBuf>,
    /// With --rp2040: how long the Pico's flash is busy per sector erase and
    /// page program, in emulated time (W25Q16JV datasheet: typical 45 ms and
    /// 0.4 ms, max 400 ms and 3 ms; none: no time).
    #[arg(long, default_value = "typical", requires = "rp2040")]
    flash_timing: crate::device::flash_timing::FlashTiming,
}

/// Runs `placedb device`.
pub fn run(a: DeviceArgs) -> Result<(), Error> {
    if a.rp2040 {
        rp2040::device_cmd(a.firmware, a.port, a.flash, a.flash_timing)?;
    } else {
        qemu::device_cmd(a.firmware, a.port, !a.no_icount, a.flash)?;
    }
    Ok(())
}
