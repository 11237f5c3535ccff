//! NOR-flash storage for the core's log: the last 1 MiB of the Pico's 2 MiB
//! QSPI flash (flash offsets 0x10_0000..0x20_0000, XIP 0x1010_0000), as
//! `embedded-storage` 0.3 [`NorFlash`] with offsets relative to that region.
//! memory.x ends the program's FLASH at 0x1010_0000, so nothing linked can lie
//! in it.
//!
//! Reads come from the XIP window. Erase (per 4 KiB sector) and program (per
//! 256-byte page, the bytes not written padded with 0xFF, which leaves them as
//! they are) call the boot ROM's flash functions from a RAM function with
//! interrupts disabled, then re-run a RAM copy of the second-stage bootloader
//! to restore fast XIP, as the Pico SDK does. Every erase and program is
//! read back (the ROM's functions return nothing): a sector not all 0xFF, or
//! page bytes not as programmed, is an error, never `Ok`, so the log does
//! not acknowledge what did not take. The same RAM routine reads the chip's
//! 64-bit unique ID ([`unique_id`], the USB serial number).
//!
//! Not supported: the second core running from flash, DMA reading flash, or
//! an interrupt handler in flash during an operation (this firmware starts no
//! second core and uses no DMA or interrupts). USB is polled from the main
//! loop and is not serviced while the device handles a request anyway; an
//! erase adds ~45 ms per sector (W25Q16JV typical, 400 ms worst case), a
//! write ~0.4 ms per page, with interrupts off. The USB controller NAKs bulk
//! traffic by itself meanwhile, but host control requests wait too (Linux
//! gives up after 5 s), so erase a few sectors per request, not the whole
//! region (256 sectors: ~12 s). Power loss during an erase leaves the sector
//! undefined, during a write the bytes being written; the rest of the page
//! is unchanged.

use embedded_storage::nor_flash::{
    check_erase, check_read, check_write, ErrorType, NorFlash, NorFlashErrorKind, ReadNorFlash,
};
use rp2040_hal::rom_data;

/// Flash offset of the storage region (the second MiB).
const REGION_OFFSET: u32 = 0x10_0000;
/// Size of the storage region.
pub const REGION_LEN: usize = 0x10_0000;
/// Where flash is mapped for reading (XIP, cached).
const XIP_BASE: usize = 0x1000_0000;
/// The flash's program unit.
const PAGE: usize = 256;
/// The second-stage bootloader's size (memory.x BOOT2).
const BOOT2_WORDS: usize = 64;

/// The last 1 MiB of the Pico's flash. Errors: bounds and alignment
/// (checked before anything is done), and `Other` when an erase or a
/// program does not read back as asked (the boot ROM's functions report
/// nothing, so every one is read back through XIP after the cache flush).
pub struct PicoFlash {
    _private: (),
}

impl PicoFlash {
    /// # Safety
    ///
    /// While the returned value is used, nothing else may access flash during
    /// an erase or write: no code may run from flash on the second core, and
    /// no DMA may read flash (interrupts on this core are disabled here).
    pub unsafe fn new() -> Self {
        PicoFlash { _private: () }
    }
}

impl ErrorType for PicoFlash {
    type Error = NorFlashErrorKind;
}

impl ReadNorFlash for PicoFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        check_read(self, offset, bytes.len())?;
        // Restoring a long log at boot reads it all: progress, not a hang.
        crate::watchdog::feed();
        let src = (XIP_BASE + REGION_OFFSET as usize + offset as usize) as *const u8;
        // SAFETY: check_read keeps src..src+len inside the mapped, always
        // readable XIP window of the region, which no Rust object occupies
        // (memory.x), and `bytes` is a distinct RAM buffer.
        unsafe { core::ptr::copy_nonoverlapping(src, bytes.as_mut_ptr(), bytes.len()) };
        Ok(())
    }

    fn capacity(&self) -> usize {
        REGION_LEN
    }
}

impl NorFlash for PicoFlash {
    const WRITE_SIZE: usize = 1;
    const ERASE_SIZE: usize = 4096;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        check_erase(self, from, to)?;
        for sector in (from..to).step_by(Self::ERASE_SIZE) {
            // Each erase stalls the chip up to 400 ms: a full timeout for
            // each (the read-back below feeds it again).
            crate::watchdog::feed();
            rom_op(REGION_OFFSET + sector, None);
            // Read back: a sector that is not all 0xFF now did not erase
            // (protect bits left set, a worn sector, the supply too low).
            let mut chunk = [0u8; PAGE];
            for at in (sector..sector + Self::ERASE_SIZE as u32).step_by(PAGE) {
                self.read(at, &mut chunk)?;
                if chunk.iter().any(|&b| b != 0xFF) {
                    return Err(NorFlashErrorKind::Other);
                }
            }
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        check_write(self, offset, bytes.len())?;
        let (mut at, mut rest) = (offset as usize, bytes);
        while !rest.is_empty() {
            let (page, skip) = (at - at % PAGE, at % PAGE);
            let n = rest.len().min(PAGE - skip);
            let mut buf = [0xFF_u8; PAGE];
            buf[skip..skip + n].copy_from_slice(&rest[..n]);
            crate::watchdog::feed();
            rom_op(REGION_OFFSET + page as u32, Some(&buf));
            // Read back: bytes that are not what was programmed did not take.
            let mut got = [0u8; PAGE];
            self.read(at as u32, &mut got[..n])?;
            if got[..n] != rest[..n] {
                return Err(NorFlashErrorKind::Other);
            }
            (at, rest) = (at + n, &rest[n..]);
        }
        Ok(())
    }
}

/// What [`ram_rom_op`] runs: ROM function addresses, then its arguments.
#[repr(C)]
struct RomOp {
    connect_internal_flash: usize,
    flash_exit_xip: usize,
    /// `flash_range_erase(addr, 4096, 1 << 16, 0xD8)` if not 0.
    flash_range_erase: usize,
    /// `flash_range_program(addr, data, 256)` if not 0.
    flash_range_program: usize,
    flash_flush_cache: usize,
    /// The RAM copy of boot2 (Thumb bit set): re-enters fast XIP.
    enter_xip: usize,
    addr: u32,
    data: *const u8,
    /// If not null: a [`CMD_LEN`]-byte buffer sent to the flash as one
    /// command with chip select held low, each byte replaced by the one the
    /// chip sent back meanwhile (pico-sdk's `flash_do_cmd`).
    cmd: *mut u8,
    /// The SSI's base address (its SR at +0x28, DR0 at +0x60).
    ssi: usize,
    /// IO_QSPI's GPIO_QSPI_SS_CTRL: its OUTOVER field (bits 9:8) forces
    /// the chip select low (2) or high (3).
    ss_ctrl: usize,
}

/// Bytes of the unique-ID command: 0x4B, four dummy bytes, the 8-byte ID.
const CMD_LEN: usize = 13;
/// The SSI (the QSPI controller) and the chip select's pad control.
const SSI_BASE: usize = 0x1800_0000;
const IO_QSPI_SS_CTRL: usize = 0x4001_800C;

/// The flash chip's 64-bit unique ID (W25Q16JV "Read Unique ID Number",
/// 0x4B), its bytes in the order the chip sends them; read with interrupts
/// off through the same RAM routine as erase and program (XIP is off while
/// the command runs), as pico-sdk's `flash_get_unique_id` does.
pub fn unique_id() -> [u8; 8] {
    let mut cmd = [0u8; CMD_LEN];
    cmd[0] = 0x4B;
    run(0, None, false, cmd.as_mut_ptr());
    let mut id = [0u8; 8];
    id.copy_from_slice(&cmd[CMD_LEN - 8..]);
    id
}

/// Erases the 4 KiB sector at flash offset `addr`, or programs the 256-byte
/// page there with `page`, with interrupts disabled.
fn rom_op(addr: u32, page: Option<&[u8; PAGE]>) {
    run(addr, page, page.is_none(), core::ptr::null_mut());
}

/// One trip through [`ram_rom_op`]: an erase of the sector at `addr` if
/// `erase`, else a program of `page` there if given, else the command in
/// `cmd` if not null.
fn run(addr: u32, page: Option<&[u8; PAGE]>, erase: bool, cmd: *mut u8) {
    // SAFETY: copies the 256-byte boot2 from the start of the XIP window
    // (always mapped and readable) into a word-aligned RAM buffer.
    let boot2 = unsafe { core::ptr::read(XIP_BASE as *const [u32; BOOT2_WORDS]) };
    let op = RomOp {
        connect_internal_flash: rom_data::connect_internal_flash::ptr() as usize,
        flash_exit_xip: rom_data::flash_exit_xip::ptr() as usize,
        flash_range_erase: if erase {
            rom_data::flash_range_erase::ptr() as usize
        } else {
            0
        },
        flash_range_program: match page {
            Some(_) => rom_data::flash_range_program::ptr() as usize,
            None => 0,
        },
        flash_flush_cache: rom_data::flash_flush_cache::ptr() as usize,
        enter_xip: boot2.as_ptr() as usize | 1,
        addr,
        data: page.map_or(core::ptr::null(), |p| p.as_ptr()),
        cmd,
        ssi: SSI_BASE,
        ss_ctrl: IO_QSPI_SS_CTRL,
    };
    critical_section::with(|_| {
        // SAFETY: interrupts are off and, per `PicoFlash::new`'s contract,
        // nothing else reads flash; `op`, `boot2`, the page and the command
        // buffer (stack copies) are in RAM; `addr` is a sector/page inside the
        // storage region, which holds no code or data (memory.x); the command
        // (0x4B, read-only) is `CMD_LEN` bytes long; boot2 is the pico-sdk
        // W25Q080 image, callable as a function once copied to RAM.
        unsafe { ram_rom_op(&op) }
    });
}

/// Runs `op` from RAM (`.data` is copied to RAM at reset) without touching
/// flash: the ROM calls are made from assembly through the pointers in `op`,
/// held in r4, which the ROM functions and boot2 preserve (AAPCS).
// `unsafe(link_section)`: `.data.ram_func` is part of cortex-m-rt's `.data`,
// copied to RAM before main; the code there is executable (no MPU set up).
#[inline(never)]
#[unsafe(link_section = ".data.ram_func")]
unsafe fn ram_rom_op(op: *const RomOp) {
    // SAFETY: see `rom_op`; the asm only reads `*op` and calls the ROM and
    // boot2, and tells the compiler which registers those calls clobber.
    unsafe {
        core::arch::asm!(
            "ldr r5, [r4, #0]",
            "blx r5", // connect_internal_flash()
            "ldr r5, [r4, #4]",
            "blx r5", // flash_exit_xip()
            // The command in op.cmd, if any (pico-sdk's flash_do_cmd): chip
            // select forced low, then every byte sent while the chip's
            // answers are read back into the same buffer, then high. r1 is
            // the buffer, r2 the bytes sent, r3 the bytes received. The 13
            // bytes fit the SSI's 16-entry FIFOs, so nothing overflows.
            "ldr r1, [r4, #32]",
            "cmp r1, #0",
            "beq 5f",
            "ldr r0, [r4, #40]",
            "ldr r5, [r0]",
            "movs r2, #3",
            "lsls r2, r2, #8",
            "bics r5, r2",
            "movs r2, #2",
            "lsls r2, r2, #8",
            "orrs r5, r2",
            "str r5, [r0]", // SS_CTRL.OUTOVER = low
            "ldr r0, [r4, #36]",
            "movs r2, #0",
            "movs r3, #0",
            "6:",
            "cmp r2, #13",
            "bhs 7f",
            "ldr r5, [r0, #0x28]",
            "lsrs r5, r5, #2", // SR.TFNF (bit 1) into carry
            "bcc 7f",
            "ldrb r5, [r1, r2]",
            "str r5, [r0, #0x60]", // DR0 = byte to send
            "adds r2, #1",
            "7:",
            "ldr r5, [r0, #0x28]",
            "lsrs r5, r5, #4", // SR.RFNE (bit 3) into carry
            "bcc 6b",
            "ldr r5, [r0, #0x60]",
            "strb r5, [r1, r3]", // the byte the chip sent
            "adds r3, #1",
            "cmp r3, #13",
            "blo 6b",
            "ldr r0, [r4, #40]",
            "ldr r5, [r0]",
            "movs r2, #3",
            "lsls r2, r2, #8",
            "orrs r5, r2",
            "str r5, [r0]", // SS_CTRL.OUTOVER = high
            "5:",
            "ldr r5, [r4, #8]",
            "cmp r5, #0",
            "beq 3f",
            "ldr r0, [r4, #24]",
            "movs r1, #1",
            "lsls r1, r1, #12", // 4096
            "movs r2, #1",
            "lsls r2, r2, #16", // 64 KiB block (unused for one sector)
            "movs r3, #0xD8",
            "blx r5", // flash_range_erase(addr, 4096, 1 << 16, 0xD8)
            "3:",
            "ldr r5, [r4, #12]",
            "cmp r5, #0",
            "beq 4f",
            "ldr r0, [r4, #24]",
            "ldr r1, [r4, #28]",
            "movs r2, #1",
            "lsls r2, r2, #8", // 256
            "blx r5", // flash_range_program(addr, data, 256)
            "4:",
            "ldr r5, [r4, #16]",
            "blx r5", // flash_flush_cache()
            "ldr r5, [r4, #20]",
            "blx r5", // boot2: back to fast XIP
            in("r4") op,
            out("r5") _,
            clobber_abi("C"),
        );
    }
}
