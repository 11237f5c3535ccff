//! The watchdog, and the record a panic leaves for the next boot: a board
//! that hangs or panics restarts by itself, restores its scan from flash
//! and says why it restarted (`Status::last_reset`).
//!
//! The watchdog resets the chip unless it is fed every [`TIMEOUT_US`]. It
//! is fed where the firmware legitimately waits or works for long: each
//! turn of the main loop, the reply queue's wait for a host that reads
//! slowly (`Link::send`, `Link::flush`), and every flash operation (each
//! sector erase, up to 400 ms at the W25Q16JV's maximum; each page
//! program; each read, so that restoring a long log at boot, which reads
//! it all, is not cut short). An idle board sleeps in `wfi` and wakes at
//! least every [`IDLE_WAKE_US`] to feed it. It pauses while a debugger
//! halts the core (CTRL's PAUSE_DBG0/DBG1/JTAG), so stepping through the
//! firmware does not reset it.
//!
//! A panic writes its place (source file, line, column) into the
//! watchdog's scratch registers 0-3, which a watchdog reset keeps (only a
//! power-on or the RUN pin clears them; the boot ROM reads 4-7 only), and
//! forces a watchdog reset at once. The next boot reads them before
//! anything else ([`take_last_reset`]) and clears them: a valid record is
//! a panic, none with the watchdog's REASON.TIMER set is a hang.
//!
//! The record: SCRATCH1 the address of the file name (a `&'static str` in
//! this firmware's flash image, where it still is after the reset),
//! SCRATCH2 its length (low 16 bits) and the column (high 16), SCRATCH3
//! the line, SCRATCH0 [`MAGIC`] mixed with a hash of the other three and
//! the name's bytes: garbage, another firmware's use of the registers or
//! a name that is no longer there (a new firmware flashed since) does not
//! pass as a panic.

use placedb::protocol::{PanicPlace, ResetCause};
use rp2040_hal::pac;

/// The watchdog resets the chip after this long unfed: about five times
/// the longest legitimate stretch between two feeds (a sector erase at
/// the flash's maximum, 400 ms, with one frame's compute, tens of ms).
pub const TIMEOUT_US: u32 = 3_000_000;

/// An idle board's sleep ends at least this often, to feed the watchdog.
pub const IDLE_WAKE_US: u32 = 1_000_000;

/// SCRATCH0 of a panic record, before the hash is mixed in.
const MAGIC: u32 = 0x7061_6e63; // "panc"

/// The XIP window of this firmware's image (memory.x FLASH): where a
/// recorded file name may lie.
const IMAGE: core::ops::Range<u32> = 0x1000_0100..0x1010_0000;

/// REASON.TIMER: the last reset was the watchdog's countdown.
const REASON_TIMER: u32 = 1 << 0;

fn regs() -> &'static pac::watchdog::RegisterBlock {
    // SAFETY: the watchdog's registers, always mapped; every access here
    // is a single word read or write (LOAD, CTRL, REASON, SCRATCH0-3),
    // and this firmware runs on core 0 only. `hal::Watchdog` (owned by
    // main, for the tick generator) touches TICK, which nothing here does.
    unsafe { &*pac::WATCHDOG::PTR }
}

/// Starts the watchdog: [`TIMEOUT_US`], paused under a debugger, and a
/// reset of everything but the oscillators when it fires (PSM.WDSEL, as
/// pico-sdk's `watchdog_enable`). The tick generator must run (it does
/// once the clocks are set up: `init_clocks_and_plls`).
pub fn start(watchdog: &mut rp2040_hal::Watchdog) {
    watchdog.start(rp2040_hal::fugit::MicrosDurationU32::micros(TIMEOUT_US));
    // `Watchdog::start` writes CTRL from its reset value, which pauses on
    // debug already; said here, not left to a reset value.
    regs().ctrl().modify(|_, w| {
        w.pause_dbg0().set_bit();
        w.pause_dbg1().set_bit();
        w.pause_jtag().set_bit()
    });
}

/// Feeds the watchdog: [`TIMEOUT_US`] from now. A few cycles (one register
/// write), so callers feed freely.
#[inline]
pub fn feed() {
    // RP2040-E1: the counter counts down twice per microsecond tick.
    // SAFETY: any 24-bit value is a valid load.
    regs().load().write(|w| unsafe { w.bits(TIMEOUT_US * 2) });
}

/// Why the board started, read (and cleared) once at boot, before
/// anything could write the scratch registers.
pub fn take_last_reset() -> ResetCause {
    let w = regs();
    let [s0, s1, s2, s3] = [
        w.scratch0().read().bits(),
        w.scratch1().read().bits(),
        w.scratch2().read().bits(),
        w.scratch3().read().bits(),
    ];
    // SAFETY: writing 0 to a scratch register only clears it.
    w.scratch0().write(|w| unsafe { w.bits(0) });
    if let Some(place) = recorded_place(s0, s1, s2, s3) {
        return ResetCause::Panic(place);
    }
    if w.reason().read().bits() & REASON_TIMER != 0 {
        ResetCause::Watchdog
    } else {
        ResetCause::PowerOn
    }
}

/// The place a valid record names.
fn recorded_place(s0: u32, s1: u32, s2: u32, s3: u32) -> Option<PanicPlace> {
    let len = s2 & 0xFFFF;
    let end = s1.checked_add(len)?;
    if !(IMAGE.contains(&s1) && end <= IMAGE.end) {
        return None;
    }
    // SAFETY: s1..s1+len lies inside the XIP window of the firmware's own
    // image (checked above), always mapped and readable; no Rust object is
    // written there.
    let bytes = unsafe { core::slice::from_raw_parts(s1 as *const u8, len as usize) };
    if s0 != MAGIC ^ hash(s1, s2, s3, bytes) {
        return None;
    }
    let file = core::str::from_utf8(bytes).ok()?;
    Some(PanicPlace::new(file, s3, s2 >> 16))
}

/// FNV-1a over the record's words and the file name's bytes.
fn hash(s1: u32, s2: u32, s3: u32, name: &[u8]) -> u32 {
    let mut h: u32 = 0x811c_9dc5;
    for b in [s1, s2, s3]
        .iter()
        .flat_map(|w| w.to_le_bytes())
        .chain(name.iter().copied())
    {
        h = (h ^ u32::from(b)).wrapping_mul(0x0100_0193);
    }
    h
}

/// Records `location` for the next boot and resets the chip through the
/// watchdog (the scratch registers survive it). For the panic handler:
/// interrupts are off, nothing else runs.
pub fn panic_reset(location: Option<&core::panic::Location<'_>>) -> ! {
    let w = regs();
    if let Some(at) = location {
        let file = at.file().as_bytes();
        let s1 = file.as_ptr() as u32;
        let s2 = (file.len().min(0xFFFF) as u32) | (at.column().min(0xFFFF) << 16);
        let s3 = at.line();
        let s0 = MAGIC
            ^ hash(
                s1,
                s2,
                s3,
                file.get(..(s2 & 0xFFFF) as usize).unwrap_or(file),
            );
        // SAFETY: scratch registers hold any value.
        w.scratch1().write(|r| unsafe { r.bits(s1) });
        w.scratch2().write(|r| unsafe { r.bits(s2) });
        w.scratch3().write(|r| unsafe { r.bits(s3) });
        w.scratch0().write(|r| unsafe { r.bits(s0) });
    }
    // What the watchdog resets (a panic before `start` finds it unset):
    // everything but the oscillators, as `start` sets it.
    // SAFETY: PSM.WDSEL only selects what a watchdog reset resets; the
    // firmware ends here.
    unsafe { &*pac::PSM::PTR }
        .wdsel()
        .write(|r| unsafe { r.bits(0x0001_FFFF & !0b11) });
    w.ctrl().modify(|_, r| r.trigger().set_bit());
    // The reset takes a few cycles.
    loop {
        cortex_m::asm::nop();
    }
}
