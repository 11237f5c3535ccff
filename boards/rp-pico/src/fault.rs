//! Fault injection, for the tests only (cargo feature `fault-injection`,
//! built by the tests with `--profile fault-injection`; the release build
//! has none of it): a hang, a panic or a stack overflow at a chosen frame
//! of the scan, so that the tests see the watchdog, the panic handler and
//! the stack's guard restart the board mid-scan
//! (host/tests/cli_board_restart.rs).
//!
//! The plan comes in the watchdog's SCRATCH7 at power-on, where the
//! emulator's harness puts it (its `PICO_FAULT=panic:N`, `hang:N` or `overflow:N`), and
//! is taken (read and cleared) at boot: a watchdog reset keeps the scratch
//! registers, so the restarted board, whose scan is restored past frame N,
//! must not fault again. SCRATCH7, not 0-3: those carry the panic record;
//! the boot ROM reads 7 only when SCRATCH4 holds its magic, which nothing
//! here writes.

use core::sync::atomic::{AtomicU32, Ordering};
use placedb::device::Device256K;
use placedb::protocol::Phase;
use rp2040_hal::pac;

/// SCRATCH7's top byte when it holds a plan.
const PLAN: u32 = 0xFA00_0000;
const KIND_PANIC: u32 = 1;
const KIND_HANG: u32 = 2;
const KIND_OVERFLOW: u32 = 3;

/// The plan taken at boot (0: none): kind in bits 16..24, frame below.
static TAKEN: AtomicU32 = AtomicU32::new(0);

/// Takes the plan out of SCRATCH7 (at boot, before anything else).
pub fn take_plan() {
    // SAFETY: SCRATCH7 is read and cleared once at boot, on core 0.
    let w = unsafe { &*pac::WATCHDOG::PTR };
    let plan = w.scratch7().read().bits();
    if plan & 0xFF00_0000 == PLAN {
        // SAFETY: a scratch register holds any value.
        w.scratch7().write(|r| unsafe { r.bits(0) });
        TAKEN.store(plan & 0x00FF_FFFF, Ordering::Relaxed);
    }
}

/// After each host message: once the scan is inside the frame after the
/// plan's N frames (its rows coming in: mid-frame, mid-scan), hangs (a
/// loop that never feeds the watchdog) or panics.
pub fn after_message(device: &Device256K) {
    let plan = TAKEN.load(Ordering::Relaxed);
    if plan == 0 || device.phase() != Phase::InFrame {
        return;
    }
    let (kind, frame) = (plan >> 16, plan & 0xFFFF);
    if device.status().frames_seen < frame {
        return;
    }
    TAKEN.store(0, Ordering::Relaxed);
    match kind {
        KIND_PANIC => panic!("fault injection: a panic in frame {frame}"),
        KIND_HANG => loop {
            // Busy, as a real hang is (a wait on something that never
            // comes), and never feeding the watchdog.
            cortex_m::asm::nop();
        },
        KIND_OVERFLOW => {
            let _ = deeper(0);
        }
        _ => {}
    }
}

/// Recursion that takes 512 bytes of stack a call until the stack meets
/// its guard (stack_guard.rs); the depth bound is never reached (256 KiB
/// of RAM hold fewer than 512 such calls).
#[inline(never)]
fn deeper(depth: u32) -> u32 {
    let mut frame = [0u8; 512];
    frame[0] = depth as u8;
    core::hint::black_box(&mut frame);
    if depth > 1024 {
        return 0;
    }
    deeper(depth + 1).wrapping_add(u32::from(frame[511]))
}
