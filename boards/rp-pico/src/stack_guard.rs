//! The stack's guard: a no-access MPU region just above the statics, where
//! the stack would run into them.
//!
//! The stack grows down from the end of RAM towards `.bss` (cortex-m-rt's
//! layout, memory.x). Without a guard an overflow silently overwrites the
//! statics nearest the stack: the cached ROM flash function pointers and
//! the critical-section lock owner, so a deep path would corrupt the flash
//! log or deadlock instead of stopping. With the guard the first write into
//! it faults: on the Cortex-M0+ every fault is a HardFault, whose own
//! exception frame (eight words pushed under the stack pointer, inside the
//! guard) faults again, so the core locks up; the watchdog (its countdown
//! runs on in lockup) then restarts the board, which restores its scan from
//! flash and reports the restart (`ResetCause::Watchdog`, watchdog.rs).
//!
//! The region is the MPU's smallest, [`GUARD_BYTES`], aligned to its size
//! (the ARMv6-M MPU requires it), at the first such boundary at or above
//! `_stack_end` (the end of the statics): the stack loses at most
//! `2 * GUARD_BYTES - 4` bytes of the 32 KiB reserve. PRIVDEFENA keeps the
//! default memory map everywhere else (this firmware runs privileged).

use cortex_m::peripheral::MPU;

/// The guard's size: the ARMv6-M MPU's smallest region.
pub const GUARD_BYTES: u32 = 256;

/// RASR: execute never, no access (AP = 0b000), SIZE = log2(256) - 1,
/// region enabled.
const RASR_NO_ACCESS_256: u32 = (1 << 28) | (7 << 1) | 1;

/// CTRL: the MPU on, the default map for privileged code outside regions.
const CTRL_ENABLE_PRIVDEFENA: u32 = (1 << 2) | 1;

extern "C" {
    /// cortex-m-rt's end of the statics: the lowest address the stack
    /// may reach.
    static _stack_end: u32;
}

/// Where the guard lies: `GUARD_BYTES` at the first `GUARD_BYTES` boundary
/// at or above `stack_end`.
pub fn guard_base(stack_end: u32) -> u32 {
    stack_end.next_multiple_of(GUARD_BYTES)
}

/// Turns the guard on (once, at boot, before the stack is deep).
pub fn enable() {
    let stack_end = core::ptr::addr_of!(_stack_end) as u32;
    // SAFETY: the MPU's registers, always mapped; written once here, on
    // core 0, before anything else uses the MPU (nothing else does). The
    // region lies in the stack's reserve above every static (memory.x
    // asserts 32 KiB of it), which nothing but the stack uses.
    unsafe {
        let mpu = &*MPU::PTR;
        mpu.rnr.write(0);
        mpu.rbar.write(guard_base(stack_end));
        mpu.rasr.write(RASR_NO_ACCESS_256);
        mpu.ctrl.write(CTRL_ENABLE_PRIVDEFENA);
    }
    // The region applies from the next instruction on.
    cortex_m::asm::dsb();
    cortex_m::asm::isb();
}
