//! `placedb device`: an emulated board (QEMU or the Pico under rp2040js) in
//! the foreground, its port printed, and what it restored from its flash
//! file at boot (asked over its port before any program is served).

use crate::board::client::{self, flash_warnings, Client};
use crate::board::emulator::rp2040::{self, Foreground, Rp2040Options};
use crate::board::emulator::{qemu, wait_in_foreground, AtBoot};
use crate::board::error::DeviceError;
use crate::board::flash_timing::FlashTiming;
use crate::board::link::usb_serial::SERIAL_DOMAIN;
use crate::board::link::Link;
use crate::board::scan::held_scan;
use crate::cli::params;
use crate::error::CommandError as Error;
use crate::warning;
use clap::Args;
use placedb::protocol::{Phase, Status};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// `placedb device`: one of the two boards, named by its flag.
#[derive(Args)]
#[command(group(clap::ArgGroup::new("board").required(true).args(["qemu", "rp2040"])))]
pub struct DeviceArgs {
    /// Run the QEMU board (mps2-an386, Cortex-M4F, UART) under qemu-system-arm.
    #[arg(long)]
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
    #[arg(long, default_value_t = 0, value_parser = params::whole::<u16>(0, 65535), allow_negative_numbers = true)]
    port: u16,
    /// Run without -icount shift=0 (faster, but no exact instruction counts; QEMU only).
    #[arg(long, conflicts_with = "rp2040")]
    no_icount: bool,
    /// File holding the board's flash (its database log); created erased if
    /// missing and kept across runs, so a restarted board restores its scan.
    #[arg(long)]
    flash: Option<PathBuf>,
    /// With --rp2040: how long the Pico's flash is busy per sector erase and
    /// page program, in emulated time (W25Q16JV datasheet: typical 45 ms and
    /// 0.4 ms, max 400 ms and 3 ms; none: no time).
    #[arg(long, default_value = "typical", requires = "rp2040")]
    flash_timing: FlashTiming,
    /// With --rp2040: the emulated flash chip's 64-bit unique ID, 16 hex
    /// digits (default E6614103E7452D2F). The firmware makes its USB serial
    /// number from it, so two emulated Picos given different IDs differ as
    /// two real ones do.
    #[arg(long, value_parser = params::unique_id, requires = "rp2040")]
    unique_id: Option<u64>,
}

/// Runs `placedb device`.
pub fn run(a: DeviceArgs) -> Result<(), Error> {
    let (stopped, ended) = if a.rp2040 {
        (run_rp2040(a)?, "the emulator")
    } else {
        (run_qemu(a)?, "QEMU")
    };
    if let Some(signal) = stopped {
        println!("stopped (signal {signal}): {ended} ended");
    }
    Ok(())
}

/// How long the board may take to say what it restored at boot (its
/// restore of a full log included).
const RESTORED_WAIT: Duration = Duration::from_secs(60);

/// What the board on `link` restored from its flash file at boot: its
/// status, asked once it is up and before any program is served.
fn ask_restored(link: &mut dyn Link) -> Result<Status, DeviceError> {
    client::status(&mut Client::new(link), RESTORED_WAIT)
}

/// Says what the board restored from `flash` at boot, or why it could not
/// be asked (nothing when a signal stopped the asking: placedb is ending).
fn say_restored(flash: &Path, restored: Option<Result<Status, DeviceError>>) {
    match restored {
        Some(Ok(st)) => {
            match held_scan(&st) {
                Some(scan) if st.phase == Phase::Finished => println!(
                    "  restored from {}: {scan}; `placedb export` pulls it, \
                     `placedb stream --extend` adds a session",
                    flash.display()
                ),
                Some(scan) => println!(
                    "  restored from {}: {scan}; `placedb stream --resume` goes on with it",
                    flash.display()
                ),
                None => println!(
                    "  {} holds no scan: the board starts empty",
                    flash.display()
                ),
            }
            if let Some(restart) = client::restart_words(&st) {
                println!("  {restart}");
            }
            warning::warn_all(&flash_warnings(&st));
        }
        Some(Err(DeviceError::Io(e))) if e.kind() == std::io::ErrorKind::Interrupted => {}
        Some(Err(e)) => warning::warn(format!(
            "the board did not say what it restored from {}: {e}",
            flash.display()
        )),
        None => {}
    }
}

/// `placedb device --qemu`: QEMU in the foreground, its port printed.
fn run_qemu(a: DeviceArgs) -> Result<Option<i32>, Error> {
    let flash = a.flash.clone();
    let mut restored = None;
    let mut ask = |link: &mut dyn Link| restored = Some(ask_restored(link));
    let mut child = qemu::spawn_foreground(
        a.firmware,
        a.port,
        !a.no_icount,
        a.flash.as_deref(),
        &mut |port| {
            println!("emulated board (mps2-an386, profile ram512k) on port tcp:127.0.0.1:{port}");
            println!(
                "  e.g. placedb stream --port tcp:127.0.0.1:{port} --demo --stride 8 --max-frames 30"
            );
            println!("       placedb export --port tcp:127.0.0.1:{port} -o out");
            match &flash {
                Some(f) => println!(
                    "  flash kept in {}: after a restart, `placedb stream --resume` goes on with the scan",
                    f.display()
                ),
                None => println!("  no --flash file: the board starts empty every time"),
            }
            println!("  Ctrl-C (or SIGTERM, SIGHUP) stops it, QEMU with it");
        },
        a.flash.is_some().then_some(&mut ask as AtBoot),
    )?;
    if let Some(f) = &a.flash {
        say_restored(f, restored);
    }
    Ok(wait_in_foreground(&mut child, "QEMU")?)
}

/// `placedb device --rp2040`: the emulated Pico in the foreground, its
/// port printed once its firmware is up.
fn run_rp2040(a: DeviceArgs) -> Result<Option<i32>, Error> {
    let firmware = a.firmware.unwrap_or_else(rp2040::default_firmware);
    let flash_timing = a.flash_timing;
    let options = Rp2040Options {
        flash: a.flash.clone(),
        port: a.port,
        deadline: Duration::ZERO,
        flash_timing,
        unique_id: a.unique_id.unwrap_or(rp2040::DEFAULT_UNIQUE_ID),
        ..Rp2040Options::default()
    };
    // Refusals (a missing firmware, a port in use, a flash file of another
    // size) come before anything is printed or made.
    rp2040::prepare(&firmware, &options)?;
    println!("emulated Raspberry Pi Pico (rp2040js, profile ram256k), USB CDC-ACM bridged to TCP");
    println!(
        "  flash timing {flash_timing}: {:?} per sector erase, {:?} per page program (W25Q16JV datasheet), in emulated time",
        flash_timing.sector_erase(),
        flash_timing.page_program()
    );
    println!(
        "  flash unique ID {:016X}: USB serial number {}:{:016X}",
        options.unique_id, SERIAL_DOMAIN, options.unique_id
    );
    let mut restored = None;
    let mut ask = |link: &mut dyn Link| restored = Some(ask_restored(link));
    let board = rp2040::spawn_foreground(
        &firmware,
        &options,
        a.flash.is_some().then_some(&mut ask as AtBoot),
    )?;
    let (mut child, port) = match board {
        Foreground::Up(child, port) => (child, port),
        Foreground::Stopped(signal) => return Ok(Some(signal)),
    };
    println!("emulated Pico up on port tcp:127.0.0.1:{port}");
    println!(
        "  e.g. placedb stream --port tcp:127.0.0.1:{port} --profile ram256k --demo --stride 8 --max-frames 30"
    );
    println!("       placedb export --port tcp:127.0.0.1:{port} -o out");
    match &a.flash {
        Some(f) => {
            println!(
                "  flash kept in {} (2 MiB): after a restart, `placedb stream --resume` goes on with the scan",
                f.display()
            );
            say_restored(f, restored);
        }
        None => println!("  no --flash file: the board starts with an erased flash every time"),
    }
    println!("  Ctrl-C (or SIGTERM, SIGHUP) stops it, the emulator with it");
    Ok(wait_in_foreground(&mut child, "the RP2040 emulator")?)
}
