//! placedb firmware for the MPS2 AN386 board (Cortex-M4F) under
//! `qemu-system-arm -machine mps2-an386`: the placedb wire protocol on UART0,
//! served by [`placedb::device::Device512K`] (the `ram512k` profile; the root
//! `memory.x` gives RAM 512 KiB, so a device that does not fit fails to link).
//!
//! The loop is transport-agnostic: read what the UART has, hand it to the
//! device, write every reply frame back. A read with nothing received
//! sleeps (`wfi`) until a byte comes, so an idle board leaves QEMU's host
//! core alone (under `-icount`, QEMU's default `sleep=on` then lets virtual
//! time follow real time). Frame costs are measured with SysTick
//! (25 MHz on this board; with `qemu -icount shift=0` one instruction takes
//! 1 ns of virtual time, so one tick is 40 instructions) and reported by the
//! device's status in nanoseconds of virtual time = instructions under
//! `-icount shift=0`.
//!
//! The scan is durable: the device writes its decisions to a log in an
//! emulated NOR flash (the board's PSRAM, see [`flash`]) before it
//! acknowledges them, and restores them at boot. Start QEMU with the PSRAM
//! backed by a file (`placedb_host::board::emulator::qemu::QemuOptions::flash`) for the log to
//! outlive the emulator; without it every boot starts empty.
//!
//! Semihosting prints a boot line, what was restored, the SysTick
//! calibration, and the stack high-water mark whenever a scan finishes
//! (`stack peak N of M bytes`).
#![no_std]
#![no_main]

mod flash;
mod uart;

use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::{debug, hprintln};
use embedded_io::{Read, Write};
use placedb::device::Device512K;
use placedb::persist::Log;
use placedb::protocol::{degradation, Phase, MAX_FRAME_LEN, PROTOCOL_VERSION};

/// Bytes read from the transport per call (the UART returns what it has).
const RX_CHUNK: usize = 64;
/// SysTick reload: the full 24-bit range.
const RELOAD: u32 = 0x00FF_FFFF;
/// SysTick ticks (25 MHz) to nanoseconds of virtual time.
const NS_PER_TICK: u64 = 40;

/// SysTick wraps since boot.
static WRAPS: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    WRAPS.fetch_add(1, Ordering::Relaxed);
}

/// SysTick ticks since boot.
fn ticks() -> u64 {
    loop {
        let before = WRAPS.load(Ordering::Acquire);
        let current = SYST::get_current();
        if WRAPS.load(Ordering::Acquire) == before {
            let elapsed = u64::from(RELOAD - current);
            return u64::from(before) * (u64::from(RELOAD) + 1) + elapsed;
        }
    }
}

/// Nanoseconds of virtual time since boot (instructions under `-icount shift=0`).
fn nanos() -> u64 {
    ticks() * NS_PER_TICK
}

fn start_systick(mut syst: SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(RELOAD);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
}

/// SysTick ticks taken by `2 * n` instructions (a two-instruction loop).
fn calibrate(n: u32) -> u64 {
    let t0 = ticks();
    let mut left = n;
    // SAFETY: a register-only countdown loop: no memory access, no stack use.
    unsafe {
        core::arch::asm!(
            "2:",
            "subs {0}, {0}, #1",
            "bne 2b",
            inout(reg) left,
            options(nomem, nostack),
        );
    }
    let _ = left;
    ticks() - t0
}

extern "C" {
    static _stack_end: u32;
    static _stack_start: u32;
}

/// Bytes of stack ever used (cortex-m-rt's `paint-stack` fills it with
/// 0xCCCC_CCCC at reset), and the stack size.
fn stack_peak() -> (usize, usize) {
    let end = core::ptr::addr_of!(_stack_end) as usize;
    let start = core::ptr::addr_of!(_stack_start) as usize;
    let mut addr = end;
    while addr < start {
        // SAFETY: `addr` is a 4-byte aligned word of the stack region, which
        // is ordinary RAM between two linker symbols; reading it is harmless.
        let word = unsafe { core::ptr::read_volatile(addr as *const u32) };
        if word != 0xCCCC_CCCC {
            break;
        }
        addr += 4;
    }
    (start - addr, start - end)
}

#[entry]
fn main() -> ! {
    // cortex-m-rt turns this into a `&'static mut` owned by `main`: the device
    // lives in `.bss`, where the linker counts it against the RAM budget.
    static mut DEVICE: Device512K = Device512K::new();
    let device: &'static mut Device512K = DEVICE;

    let Some(core) = cortex_m::Peripherals::take() else {
        hprintln!("core peripherals unavailable");
        fail();
    };
    start_systick(core.SYST);
    let Some(mut uart) = uart::Uart::take_uart0() else {
        hprintln!("UART0 unavailable");
        fail();
    };
    let (_, stack) = stack_peak();
    hprintln!(
        "placedb-qemu-mps2-an386 boot: protocol v{}, profile ram512k, device {} B, stack {} B, rx frame {} B",
        PROTOCOL_VERSION,
        core::mem::size_of::<Device512K>(),
        stack,
        MAX_FRAME_LEN
    );
    let n = 1_000_000;
    hprintln!(
        "calibration: {} instructions = {} SysTick ticks",
        2 * n,
        calibrate(n)
    );
    device.set_clock(nanos, 1_000_000_000);

    let Some(flash) = flash::PsramFlash::take() else {
        hprintln!("flash unavailable");
        fail();
    };
    let mut log = match Log::open(flash, 0, flash::FLASH_SIZE as u32) {
        Ok(log) => log,
        Err(e) => {
            hprintln!("flash log unusable: {:?}", e);
            fail();
        }
    };
    match device.restore(&mut log) {
        Ok(records) => {
            let st = device.status();
            hprintln!(
                "restored {} records: {} frames decided, database {}, log {} of {} sectors",
                records,
                st.frames_decided,
                st.database_size,
                log.sectors_used(),
                log.sector_count()
            );
            if st.degradation & degradation::TAIL_DROPPED != 0 {
                hprintln!("records after those were unusable and were dropped");
            }
        }
        Err(e) => hprintln!("nothing restored ({:?}): starting empty", e),
    }

    let mut rx = [0u8; RX_CHUNK];
    let mut finished = false;
    loop {
        // The UART's error type is `Infallible`.
        let Ok(n) = uart.read(&mut rx);
        let bytes = rx.get(..n).unwrap_or_default();
        device.receive_logged(bytes, &mut log, &mut |frame: &[u8]| {
            let _ = uart.write_all(frame);
        });
        let now_finished = device.phase() == Phase::Finished;
        if now_finished && !finished {
            let (used, size) = stack_peak();
            hprintln!("stack peak {} of {} bytes", used, size);
        }
        finished = now_finished;
    }
}

fn fail() -> ! {
    debug::exit(debug::EXIT_FAILURE);
    halt()
}

fn halt() -> ! {
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("panic: {}", info);
    fail()
}

// cortex-m-rt requires the HardFault handler to be an `unsafe fn`; it performs
// no unsafe operation: it reports and makes QEMU exit with status 1.
#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    hprintln!("hard fault at pc {:#010x}", frame.pc());
    fail()
}
