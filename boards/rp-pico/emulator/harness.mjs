#!/usr/bin/env node
// The placedb Raspberry Pi Pico firmware under rp2040js, instruction by
// instruction: the real boot ROM and boot2, the Pico's 2 MiB QSPI flash
// (backed by a file), and a USB host that enumerates the firmware's CDC-ACM
// port and bridges its bulk endpoints to one TCP connection on 127.0.0.1.
//
//   node harness.mjs --elf FIRMWARE.elf --bootrom bootrom-b1.bin
//                    [--port N] [--flash FILE] [--deadline SECONDS]
//                    [--flash-timing none|typical|max] [--cut-during-erase N]
//                    [--cut-during-program N] [--unique-id HEX16]
//                    [--bus-reset-after-frames N[,N...]]
//
// stdout, one line each (tests and `placedb device --rp2040` read them):
//   "listening tcp:127.0.0.1:PORT"     ready for the host (one client at a time)
//   "usb configured ... serial S ..."  enumeration done, descriptors parsed
//                                      (S: the serial number string descriptor)
//   "client connected" / "client closed"
//   "client refused: another one is connected"   (one client at a time)
//   "bus reset after frame N"          --bus-reset-after-frames (below)
//   "usb: REQUEST not done within ..." a control transfer the firmware was
//                                      too late for (below)
//   "chip reset by the watchdog: ..."  the watchdog reset the chip: its
//                                      countdown ran out (a hang) or the
//                                      firmware forced it (its panic
//                                      handler); see Watchdog below
//   "client refused: the board is restarting"   (no port until enumerated)
//   "mpu guard 0xLO..0xHI"             the firmware turned its stack's guard on
//   "stack overflow: ..."              a write into that guard (see MPU below)
//   "stats cycles=N ..."               on exit (SIGTERM, SIGINT, deadline)
//   "latency frames=N ..."             on exit: frame answer latencies (below)
//   "stack peak_bytes=P room_bytes=R"  on exit: the stack's high-water mark
//                                      (the firmware paints its stack)
// A fatal condition prints "error: ..." on stderr and exits 2 (3: deadline).
// PICO_PROFILE=FILE: on exit, the cycles spent at each instruction address
// are appended to FILE ("address cycles" lines; see docs/PERFORMANCE.md).
// --cut-during-erase N: the power goes during the firmware's N-th sector
// erase (counted from 1): the sector's first half is erased, the rest left
// as it was (a torn erase), and the harness exits at once with code 4 after
// "power cut during the erase of flash offset 0x..." on stdout (no stats).
// --cut-during-program N: the same during the N-th 256-byte page programmed
// (counted from 1): the page's first half is programmed, the rest left as
// it was (a torn program), then "power cut during the program of flash
// offset 0x..." and exit code 4.
// --unique-id HEX16: the flash chip's 64-bit unique ID (what its 0x4B
// command answers, 16 hex digits, first byte sent first; default
// E6614103E7452D2F), which the firmware makes its USB serial number: two
// emulated boards with different IDs differ as two real ones do.
// Watchdog: rp2040js models the RP2040's watchdog (its countdown, REASON,
// the scratch registers); this harness does what its reset does. When it
// fires, the chip is rebuilt between two instructions: the flash contents,
// the watchdog's scratch registers and REASON are kept (a watchdog reset
// does not reset the watchdog: a panic's record reaches the next boot
// there), the rest comes out of reset and the boot ROM boots the firmware
// again. The board leaves the bus: the TCP client is disconnected (as a
// program loses a serial port whose device went away), connections are
// refused until the firmware has enumerated again, and then the same port
// serves it, as udev's by-id name of a re-enumerated board is the same.
// The stats line counts the resets (watchdog_resets). While the firmware
// sleeps and only its own alarms are set (the watchdog's countdown, the
// timer's alarms it wakes on to feed it), emulated time stands still until
// the host does something (see Idle below), so an idle board is not reset.
// PICO_FAULT=panic:N, hang:N or overflow:N: the plan of the fault-injection
// firmware (boards/rp-pico/src/fault.rs: a panic, a loop that never feeds
// the watchdog, or recursion that overflows the stack, in the frame after
// its N-th), put in the watchdog's SCRATCH7 at power-on only (the firmware
// takes it at boot).
// MPU: rp2040js has none; this harness models the one region the firmware
// programs (boards/rp-pico/src/stack_guard.rs: no access, under the stack).
// A write into it is what faults on silicon: a HardFault whose exception
// frame, pushed into the guard, faults again, so the core locks up and the
// watchdog resets the chip when its countdown runs out. Here the chip is
// reset at once, as by the watchdog's countdown (REASON.TIMER), after
// "stack overflow: a write to 0x... in the MPU guard ... (pc 0x...)": the
// three seconds of lockup are not emulated.
//
// The TCP client is a program with the serial port open, and the host
// says so as Linux's cdc-acm driver does: SET_CONTROL_LINE_STATE with DTR
// and RTS up when a client connects (after enumeration, with them up if a
// client is connected then, down if not) and down when it goes. While no
// client is connected the host does not read the bulk IN endpoint: a
// packet the firmware arms stays in its buffer (NAKed) until the next
// client's DTR is up, as it stays in a real device while no program has
// the port open.
// --bus-reset-after-frames N,M,...: once the host has handed the firmware
// the N-th FrameEnd (counted from 1), it resets the bus and enumerates
// again, as a hub reset or a host's resume does mid-stream; the bytes the
// TCP client sends meanwhile wait until the port is configured again.
//
// The host enumerates 20 ms after it starts a bus reset (10 ms of reset,
// 10 ms of reset recovery: USB 2.0 section 7.1.7.5), whatever the firmware
// is doing then, and times control transfers as Linux does: 5 s for a
// transfer (USB_CTRL_GET_TIMEOUT, USB_CTRL_SET_TIMEOUT; USB 2.0's 50 ms
// for a request without data stage, section 9.2.6.4, is not enforced by
// it), and 2 ms after SET_ADDRESS (section 9.2.6.3) the next request goes
// to the new address, which the firmware must have written to the
// controller by then (usb-device applies it at its next poll after the
// status stage, so a firmware busy in a flash erase, or computing a frame,
// misses it). A transfer that fails so makes the host print "usb: ..."
// and reset the port 100 ms later, as Linux does ("device descriptor
// read/64, error -71"); after four in a row it gives up (exit 2, "error:
// ... unable to enumerate"). The stats line counts them (usb_host_resets),
// and the sectors the firmware began to erase while the host enumerated
// (erases_while_enumerating: from a bus reset until the port is configured
// again; an erase begun before the reset is not the firmware's choice).
// The firmware sees a bus reset as soon as it starts, as on silicon
// (SIE_STATUS.BUS_RESET; rp2040js alone raises it after 10 ms).
//
// Flash: rp2040js does not model the QSPI flash chip; the boot ROM's flash
// functions run but change nothing. This harness stops the core at the
// entry of `flash_range_erase` and `flash_range_program` (found through the
// ROM's function table, as firmware finds them), does the operation on the
// emulator's flash array (erase: 0xFF; program: bitwise AND, as NOR does),
// writes the touched bytes through to the --flash file at once (so a killed
// emulator leaves exactly what was programmed), and returns to the caller.
// Every ROM flash call (connect_internal_flash, flash_exit_xip, erase,
// program, flash_flush_cache, flash_enter_cmd_xip) made from outside the ROM
// must return into RAM: on silicon XIP is off during these calls, so code in
// flash cannot run; a call that would return into XIP flash ends the run.
//
// Flash timing (--flash-timing, default typical): the W25Q16JV is busy for
// tSE per 4 KiB sector erased and tPP per 256-byte page programmed (Winbond
// W25Q16JV datasheet, AC electrical characteristics: tSE 45 ms typical,
// 400 ms max; tPP 0.4 ms typical, 3 ms max), and the ROM call returns only
// then. The harness holds the core for that long in emulated time: no
// instruction runs and the firmware services nothing (USB included), while
// the emulated clock, and with it the RP2040 timer the firmware reads, goes
// on; the USB controller's own transfers already under way complete, as on
// silicon. `none`: flash operations take no time (the call's 50 cycles).
//
// Latency: the harness reads the protocol's frames on both endpoints (COBS,
// then the postcard header: a host frame's sequence number and message
// kind, a reply's kind and sequence number). For every FrameEnd it takes the
// emulated time at which the frame's last DepthRows was handed to the
// firmware and the time at which the FrameEnd's terminal reply (its answer)
// left on the IN endpoint; the exit line gives their median and worst, in
// microseconds of emulated time, and how many answers waited for a sector
// erase (one ended between those two moments: an answer the firmware had
// handed to the USB controller before the erase began leaves during it,
// as on silicon, and did not wait).

import { RP2040, BasePeripheral } from 'rp2040js';
import fs from 'node:fs';
import net from 'node:net';
import process from 'node:process';

const FLASH_SIZE = 2 * 1024 * 1024; // the Pico's W25Q16JV
const XIP_BASE = 0x10000000;
const XIP_END = 0x14000000; // XIP, XIP_NOALLOC, XIP_NOCACHE, XIP_NOCACHE_NOALLOC
const ROM_END = 0x4000;
const SECTOR = 4096;
const PAGE = 256;
const NANOS_PER_CYCLE = 8; // clk_sys 125 MHz, as rp2040-hal's init_clocks_and_plls sets it
const CHUNK = 200000; // instructions between looks at the event loop
/** Busy time per sector erase and per page program, nanoseconds (see the
 * header: Winbond W25Q16JV datasheet, tSE and tPP). */
/** The flash chip's unique ID unless --unique-id says otherwise. */
const DEFAULT_UNIQUE_ID = 'E6614103E7452D2F';
const FLASH_TIMING = {
  none: { erase: 0, program: 0 },
  typical: { erase: 45e6, program: 0.4e6 },
  max: { erase: 400e6, program: 3e6 },
};

function usage(msg) {
  if (msg) process.stderr.write(`error: ${msg}\n`);
  process.stderr.write(
    'usage: node harness.mjs --elf FIRMWARE.elf --bootrom bootrom-b1.bin [--port N] [--flash FILE] [--deadline SECONDS] [--flash-timing none|typical|max] [--cut-during-erase N] [--cut-during-program N] [--unique-id HEX16] [--bus-reset-after-frames N[,N...]]\n',
  );
  process.exit(2);
}

function parseArgs(argv) {
  const opts = { port: 0, flash: null, deadline: 0, elf: null, bootrom: null, quiet: false, timing: 'typical', cutErase: 0, cutProgram: 0, uniqueId: DEFAULT_UNIQUE_ID, busResets: [] };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    const value = () => {
      if (i + 1 >= argv.length) usage(`${a} needs a value`);
      return argv[++i];
    };
    switch (a) {
      case '--elf':
        opts.elf = value();
        break;
      case '--bootrom':
        opts.bootrom = value();
        break;
      case '--flash':
        opts.flash = value();
        break;
      case '--port': {
        const p = Number(value());
        if (!Number.isInteger(p) || p < 0 || p > 65535) usage('--port takes 0..65535');
        opts.port = p;
        break;
      }
      case '--deadline': {
        const d = Number(value());
        if (!(d >= 0)) usage('--deadline takes seconds');
        opts.deadline = d;
        break;
      }
      case '--flash-timing': {
        const t = value();
        if (!(t in FLASH_TIMING)) usage('--flash-timing takes none, typical or max');
        opts.timing = t;
        break;
      }
      case '--cut-during-erase': {
        const n = Number(value());
        if (!Number.isInteger(n) || n < 1) usage('--cut-during-erase takes an erase number from 1');
        opts.cutErase = n;
        break;
      }
      case '--cut-during-program': {
        const n = Number(value());
        if (!Number.isInteger(n) || n < 1) usage('--cut-during-program takes a page number from 1');
        opts.cutProgram = n;
        break;
      }
      case '--unique-id': {
        const h = value();
        if (!/^[0-9a-fA-F]{16}$/.test(h)) usage('--unique-id takes 16 hex digits (the flash chip\'s 64-bit unique ID)');
        opts.uniqueId = h.toUpperCase();
        break;
      }
      case '--bus-reset-after-frames': {
        const list = value().split(',').map(Number);
        if (!list.every((n) => Number.isInteger(n) && n >= 1)) usage('--bus-reset-after-frames takes frame numbers from 1, comma-separated');
        opts.busResets = list;
        break;
      }
      case '--quiet':
        opts.quiet = true;
        break;
      case '-h':
      case '--help':
        usage();
        break;
      default:
        usage(`unknown argument ${a}`);
    }
  }
  if (!opts.elf) usage('--elf is required');
  if (!opts.bootrom) usage('--bootrom is required');
  return opts;
}

function fatal(msg, code = 2) {
  process.stderr.write(`error: ${msg}\n`);
  finish(code);
}

const hex = (n) => '0x' + (n >>> 0).toString(16).padStart(8, '0');

// ---------------------------------------------------------------- ELF

/** PT_LOAD segments of a 32-bit little-endian ARM ELF: [{ paddr, bytes }]. */
function elfSegments(buf) {
  const bad = (why) => {
    throw new Error(`not a 32-bit little-endian ARM ELF: ${why}`);
  };
  if (buf.length < 52 || buf.readUInt32BE(0) !== 0x7f454c46) bad('no ELF magic');
  if (buf[4] !== 1 || buf[5] !== 1) bad('class or byte order');
  if (buf.readUInt16LE(18) !== 40) bad('machine is not ARM');
  const phoff = buf.readUInt32LE(28);
  const phentsize = buf.readUInt16LE(42);
  const phnum = buf.readUInt16LE(44);
  const segments = [];
  for (let i = 0; i < phnum; i++) {
    const at = phoff + i * phentsize;
    if (at + 32 > buf.length) bad('program header out of the file');
    const type = buf.readUInt32LE(at);
    const offset = buf.readUInt32LE(at + 4);
    const paddr = buf.readUInt32LE(at + 12);
    const filesz = buf.readUInt32LE(at + 16);
    if (type !== 1 || filesz === 0) continue;
    if (offset + filesz > buf.length) bad('segment out of the file');
    segments.push({ paddr, bytes: buf.subarray(offset, offset + filesz) });
  }
  return segments;
}

/** The end of the statics in RAM (.data, .bss, .uninit): the highest end
 * of a load segment in RAM, 4-aligned, which is cortex-m-rt's `_stack_end`
 * (the lowest address the stack may reach). */
function elfRamEnd(buf) {
  const phoff = buf.readUInt32LE(28);
  const phentsize = buf.readUInt16LE(42);
  const phnum = buf.readUInt16LE(44);
  let end = 0x20000000;
  for (let i = 0; i < phnum; i++) {
    const at = phoff + i * phentsize;
    if (at + 32 > buf.length || buf.readUInt32LE(at) !== 1) continue;
    const vaddr = buf.readUInt32LE(at + 8);
    const memsz = buf.readUInt32LE(at + 20);
    if (vaddr >= 0x20000000 && vaddr < 0x20042000) end = Math.max(end, vaddr + memsz);
  }
  return Math.ceil(end / 4) * 4;
}

// ---------------------------------------------------------------- flash file

/** Opens (creating it erased if missing or empty) the flash image file. */
function openFlashFile(path) {
  let size = -1;
  try {
    size = fs.statSync(path).size;
  } catch (e) {
    if (e.code !== 'ENOENT') throw e;
  }
  if (size > 0 && size !== FLASH_SIZE) {
    throw new Error(`flash file ${path} holds ${size} bytes, expected ${FLASH_SIZE} (2 MiB)`);
  }
  if (size <= 0) {
    const tmp = `${path}.tmp${process.pid}`;
    fs.writeFileSync(tmp, Buffer.alloc(FLASH_SIZE, 0xff));
    fs.renameSync(tmp, path);
  }
  const fd = fs.openSync(path, 'r+');
  const image = Buffer.alloc(FLASH_SIZE);
  fs.readSync(fd, image, 0, FLASH_SIZE, 0);
  return { fd, image };
}

// ---------------------------------------------------------------- machine

const opts = parseArgs(process.argv.slice(2));
const uniqueId = Buffer.from(opts.uniqueId, 'hex');
const debug = process.env.PICO_DEBUG ? (line) => process.stderr.write(`debug: ${line}\n`) : () => {};
const log = (line) => {
  if (!opts.quiet || line.startsWith('listening') || line.startsWith('stats')) {
    process.stdout.write(line + '\n');
  }
};

/** The chip: rebuilt by a watchdog reset ([chipReset]), so always read
 * through this binding. */
let mcu = null;
/** Emulated time and cycles of the chips before the current one (a
 * watchdog reset starts a new chip at time 0): the run's totals. */
let nanosBefore = 0;
let cyclesBefore = 0;
/** Emulated nanoseconds since the harness started, across chip resets. */
const now = () => nanosBefore + mcu.clock.nanos;

/** VREG_AND_CHIP_RESET, which rp2040js leaves unimplemented (its reads give
 * 0xFFFFFFFF, and the boot ROM takes a set PSM_RESTART_FLAG in CHIP_RESET for
 * a debugger's rescue request and halts): a power-on reset. */
class VregAndChipReset extends BasePeripheral {
  constructor(rp2040, name) {
    super(rp2040, name);
    this.regs = [0xb1, 0x91, 0x100]; // VREG, BOD, CHIP_RESET (HAD_POR)
  }
  readUint32(offset) {
    return this.regs[offset >> 2] ?? 0;
  }
  writeUint32(offset, value) {
    if (offset === 8) this.regs[2] &= ~(value & 0x01000000); // PSM_RESTART_FLAG: write 1 to clear
    else if (offset < 8) this.regs[offset >> 2] = value;
  }
}

/** The QSPI flash chip behind the SSI, as far as the boot ROM and boot2
 * talk to it in serial mode (rp2040js's SSI answers every read with 0, so the
 * ROM cannot load boot2): one response byte per byte sent. Commands: 0x03
 * read data (3 address bytes, then data until chip select goes high), 0x05 /
 * 0x35 read status register 1 / 2 (not busy; QE set, so boot2 leaves the
 * status registers alone), 0x9F JEDEC id (W25Q16JV), 0x4B unique ID (four
 * dummy bytes, then the 8 bytes of --unique-id), anything else answered
 * with 0. Erase and program are not done here: the ROM's functions for them
 * are stopped at their entry (see flashCall). A transaction ends when the
 * chip select is forced high (IO_QSPI SS override) or the SSI is disabled. */
const spi = {
  cmd: -1,
  n: 0,
  addr: 0,
  rx: [],
  end() {
    this.cmd = -1;
    this.n = 0;
    this.rx = [];
  },
  byte(b) {
    if (this.cmd < 0) {
      this.cmd = b;
      this.n = 0;
      return 0;
    }
    const i = this.n++;
    switch (this.cmd) {
      case 0x03:
        if (i < 3) {
          this.addr = ((this.addr << 8) | b) & 0xffffff;
          return 0;
        }
        return mcu.flash[this.addr++ % FLASH_SIZE];
      case 0x05:
        return 0x00;
      case 0x35:
        return 0x02;
      case 0x9f:
        return [0xef, 0x40, 0x15][i] ?? 0;
      case 0x4b:
        return i < 4 ? 0 : uniqueId[i - 4] ?? 0;
      default:
        return 0;
    }
  },
};
function patchSsi(chip) {
  const ssi = chip.peripherals[0x18000];
  const [read, write] = [ssi.readUint32.bind(ssi), ssi.writeUint32.bind(ssi)];
  ssi.readUint32 = (offset) => {
    switch (offset) {
      case 0x60: // DR0
        return spi.rx.shift() ?? 0;
      case 0x20: // TXFLR: sent at once
        return 0;
      case 0x24: // RXFLR
        return Math.min(spi.rx.length, 16);
      case 0x28: // SR: TX FIFO empty and not full, RX FIFO not empty if so, never busy
        return 0x6 | (spi.rx.length ? 0x8 : 0);
      default:
        return read(offset);
    }
  };
  ssi.writeUint32 = (offset, value) => {
    if (offset === 0x60) {
      // The status reads of boot2's read_flash_sreg are a fresh command
      // each: their transactions end when the TX FIFO empties, which an
      // instant model cannot see, so they end after their one data byte.
      const cmd = spi.cmd;
      spi.rx.push(spi.byte(value & 0xff));
      if ((cmd === 0x05 || cmd === 0x35) && spi.n >= 1) spi.cmd = -1;
    } else if (offset === 0x08) {
      spi.end();
    }
    write(offset, value);
  };
}
/** IO_QSPI (unimplemented in rp2040js): registers kept; forcing the chip
 * select high ends a flash transaction. */
class IoQspi extends BasePeripheral {
  constructor(rp2040, name) {
    super(rp2040, name);
    this.regs = new Array(12).fill(0);
  }
  readUint32(offset) {
    return this.regs[offset >> 2] ?? 0;
  }
  writeUint32(offset, value) {
    const before = this.regs[3];
    if (offset >> 2 < this.regs.length) this.regs[offset >> 2] = value;
    // SS_CTRL OUTOVER: forced high ends a transaction, forced low (from
    // anything else) starts one.
    const outover = (value >> 8) & 3;
    if (offset === 0x0c && (outover === 3 || (outover === 2 && ((before >> 8) & 3) !== 2))) spi.end();
  }
}

let bootrom;
try {
  bootrom = fs.readFileSync(opts.bootrom);
} catch (e) {
  usage(`cannot read the boot ROM ${opts.bootrom}: ${e.message}`);
}
if (bootrom.length !== 16384) usage(`boot ROM ${opts.bootrom} is ${bootrom.length} bytes, expected 16384`);
const bootromWords = new Uint32Array(bootrom.buffer.slice(bootrom.byteOffset, bootrom.byteOffset + 16384));

/** A chip as it comes out of reset, the boot ROM loaded, its flash erased
 * (the caller fills it): rp2040js with this harness's models. */
function newChip() {
  const chip = new RP2040();
  // rp2040js logs to the console and throws on errors by default: keep
  // warnings quiet, turn errors into a failed run with the message.
  chip.logger = {
    debug() {},
    info() {},
    warn() {},
    error(component, message) {
      fatal(`rp2040js ${component}: ${message} (pc ${hex(chip.core.PC)})`);
    },
  };
  chip.peripherals[0x40064] = new VregAndChipReset(chip, 'VREG_AND_CHIP_RESET_BASE');
  // BOOTSEL not pressed: the QSPI chip select reads high (the boot ROM
  // samples it to choose between flash boot and USB mass-storage boot).
  // rp2040js's QSPI pads come up with their input disabled, so the pin is
  // pinned high.
  Object.defineProperty(chip.qspi[1], 'inputValue', { get: () => true });
  patchSsi(chip);
  chip.peripherals[0x40018] = new IoQspi(chip, 'IO_QSPI_BASE');
  chip.loadBootrom(bootromWords);
  // The watchdog: what it resets is the whole chip here (the firmware
  // selects everything but the oscillators, PSM.WDSEL), between two
  // instructions (see the run loop).
  modelMpuGuard(chip);
  const watchdog = chip.peripherals[0x40058];
  watchdog.onWatchdogTrigger = () => {
    resetPending = watchdog.reason;
    // Stopped: rp2040js 1.4.1 reschedules a fired countdown's alarm 0 ns
    // ahead (its decrementing timer reads 0 then), so the clock would fire
    // it again and again, forever, within one tick. The chip is reset
    // before it could count again anyway.
    watchdog.alarm.enable = false;
    watchdog.timer.enable = false;
  };
  return chip;
}
/** The ARMv6-M MPU's registers (TYPE at 0xe000ed90), as far as the
 * firmware's stack guard needs them: region 0's base and attributes, and
 * CTRL. A core write into an enabled no-access region is a stack overflow
 * (see MPU above). Every write of the core goes through the chip's
 * writeUint8/16/32, which this wraps. */
/** The top of the stack's guard (0: none): the stack's room ends there. */
let guardTop = 0;
const MPU_CTRL = 0xe000ed94;
const MPU_RNR = 0xe000ed98;
const MPU_RBAR = 0xe000ed9c;
const MPU_RASR = 0xe000eda0;
function modelMpuGuard(chip) {
  const mpu = { ctrl: 0, rnr: 0, rbar: 0, rasr: 0, lo: 0, hi: 0 };
  const update = () => {
    const on = mpu.ctrl & 1 && mpu.rnr === 0 && mpu.rasr & 1;
    // SIZE (bits 1..5): 2^(SIZE+1) bytes; AP (bits 24..26) 0: no access.
    const noAccess = ((mpu.rasr >>> 24) & 7) === 0;
    const [lo, hi] = on && noAccess ? [mpu.rbar & ~0xff, (mpu.rbar & ~0xff) + 2 ** (((mpu.rasr >>> 1) & 0x1f) + 1)] : [0, 0];
    if (lo !== mpu.lo || hi !== mpu.hi) {
      [mpu.lo, mpu.hi] = [lo, hi];
      guardTop = hi;
      if (hi > lo) log(`mpu guard ${hex(lo)}..${hex(hi)}`);
    }
  };
  for (const [name, width] of [
    ['writeUint32', 4],
    ['writeUint16', 2],
    ['writeUint8', 1],
  ]) {
    const write = chip[name].bind(chip);
    chip[name] = (address, value) => {
      address >>>= 0;
      if (address < mpu.hi && address + width > mpu.lo) {
        if (!resetPending) {
          log(
            `stack overflow: a write to ${hex(address)} in the MPU guard ${hex(mpu.lo)}..${hex(mpu.hi)} ` +
              `(pc ${hex(chip.core.PC)}): on silicon a HardFault, then lockup until the watchdog resets the chip`,
          );
          stats.guardFaults++;
          resetPending = 1;
        }
        return;
      }
      if (width === 4 && address >= MPU_CTRL && address <= MPU_RASR) {
        if (address === MPU_CTRL) mpu.ctrl = value >>> 0;
        else if (address === MPU_RNR) mpu.rnr = value & 0xff;
        else if (address === MPU_RBAR) mpu.rbar = value >>> 0;
        else mpu.rasr = value >>> 0;
        update();
        return;
      }
      write(address, value);
    };
  }
}

/** REASON of a watchdog that fired (1 its countdown, 2 forced by the
 * firmware), until the run loop resets the chip; 0: none. */
let resetPending = 0;
mcu = newChip();

// PICO_FAULT=panic:N or hang:N (tests): the fault-injection firmware's plan
// (boards/rp-pico/src/fault.rs), in the watchdog's SCRATCH7 at power-on
// only; the firmware takes it at boot.
if (process.env.PICO_FAULT) {
  const m = /^(panic|hang|overflow):(\d+)$/.exec(process.env.PICO_FAULT);
  if (!m || Number(m[2]) > 0xffff) usage('PICO_FAULT takes panic:N, hang:N or overflow:N (a frame number below 65536)');
  const kind = { panic: 1, hang: 2, overflow: 3 }[m[1]];
  mcu.peripherals[0x40058].scratchData[7] = (0xfa000000 | (kind << 16) | Number(m[2])) >>> 0;
}

let flashFd = null;
if (opts.flash) {
  try {
    const { fd, image } = openFlashFile(opts.flash);
    flashFd = fd;
    mcu.flash.set(image, 0);
  } catch (e) {
    usage(e.message);
  }
}

// Program the firmware into flash, like a UF2 drag and drop: every sector the
// ELF's load segments touch is erased and programmed; the rest is kept.
let elf;
let stackFloor;
try {
  const image = fs.readFileSync(opts.elf);
  elf = elfSegments(image);
  stackFloor = elfRamEnd(image);
} catch (e) {
  usage(`${opts.elf}: ${e.message}`);
}
const programmed = new Set();
for (const { paddr, bytes } of elf) {
  if (paddr >= 0x20000000) continue; // RAM-only (e.g. .bss has no file bytes anyway)
  if (paddr < XIP_BASE || paddr + bytes.length > XIP_BASE + FLASH_SIZE) {
    usage(`${opts.elf}: segment at ${hex(paddr)} (${bytes.length} bytes) is not in the 2 MiB flash`);
  }
  const off = paddr - XIP_BASE;
  const first = off - (off % SECTOR);
  const end = Math.ceil((off + bytes.length) / SECTOR) * SECTOR;
  for (let s = first; s < end; s += SECTOR) {
    // Sectors shared by two segments: erase once (the first segment's bytes stay).
    if (!programmed.has(s)) mcu.flash.fill(0xff, s, s + SECTOR);
    programmed.add(s);
  }
  mcu.flash.set(bytes, off);
  persist(first, end - first);
}
function persist(offset, length) {
  if (flashFd === null) return;
  fs.writeSync(flashFd, mcu.flash, offset, length, offset);
}

// ---------------------------------------------------------------- boot ROM hooks

/** The ROM's function table: code ('I','F' -> 0x4649) to address. */
function romFunctions() {
  const rd16 = (a) => bootrom.readUInt16LE(a);
  const table = new Map();
  for (let at = rd16(0x14); at + 4 <= bootrom.length; at += 4) {
    const code = rd16(at);
    if (code === 0) break;
    table.set(String.fromCharCode(code & 0xff, code >> 8), rd16(at + 2));
  }
  return table;
}
const rom = romFunctions();
const FLASH_CALLS = {
  IF: 'connect_internal_flash',
  EX: 'flash_exit_xip',
  RE: 'flash_range_erase',
  RP: 'flash_range_program',
  FC: 'flash_flush_cache',
  CX: 'flash_enter_cmd_xip',
};
/** hooks[pc >> 1] for pc in the ROM: the flash call starting there. */
const hooks = new Array(ROM_END >> 1).fill(null);
for (const [code, name] of Object.entries(FLASH_CALLS)) {
  const addr = rom.get(code);
  if (addr === undefined) usage(`the boot ROM's function table has no ${code} (${name})`);
  hooks[(addr & ~1) >> 1] = code;
}

const stats = {
  erases: 0,
  programs: 0,
  romFlashCalls: 0,
  bytesIn: 0,
  bytesOut: 0,
  flashBusyNs: 0,
  busResets: 0, // --bus-reset-after-frames resets done
  hostResets: 0, // control transfers the firmware was too late for
  erasesWhileEnumerating: 0, // sectors erased between a bus reset and configured
  watchdogResets: 0, // chip resets by the watchdog (its countdown, or forced)
  guardFaults: 0, // writes into the stack's MPU guard (each resets the chip)
};

const inRam = (a) => a >= 0x20000000 && a < 0x20042000;
const inXip = (a) => a >= XIP_BASE && a < XIP_END;

/** Runs at the first instruction of a ROM flash function; true if it was
 * completed here (the core then returns to the caller). */
function flashCall(code) {
  const core = mcu.core;
  const lr = core.LR >>> 0;
  const ret = lr & ~1;
  if (ret < ROM_END) return false; // the ROM's own boot path
  stats.romFlashCalls++;
  if (inXip(ret)) {
    fatal(
      `${FLASH_CALLS[code]} called from XIP flash (return address ${hex(lr)}): ` +
        'on silicon XIP is off during ROM flash calls, so this would crash',
    );
    return true;
  }
  if (!inRam(ret)) {
    fatal(`${FLASH_CALLS[code]} would return to ${hex(lr)}, outside RAM`);
    return true;
  }
  const r = core.registers;
  if (code === 'RE') {
    const [addr, count] = [r[0] >>> 0, r[1] >>> 0];
    if (addr % SECTOR || count % SECTOR || addr + count > FLASH_SIZE) {
      fatal(`flash_range_erase(${hex(addr)}, ${count}): not whole 4 KiB sectors inside the 2 MiB flash`);
      return true;
    }
    if (opts.cutErase && stats.erases + count / SECTOR >= opts.cutErase) {
      const at = addr + (opts.cutErase - 1 - stats.erases) * SECTOR;
      mcu.flash.fill(0xff, addr, at + SECTOR / 2);
      powerCut('erase', addr, at, at + SECTOR / 2);
    }
    mcu.flash.fill(0xff, addr, addr + count);
    persist(addr, count);
    stats.erases += count / SECTOR;
    if (host.enumerating) stats.erasesWhileEnumerating += count / SECTOR;
    hold((count / SECTOR) * FLASH_TIMING[opts.timing].erase);
    latency.erased(); // when it ends (see the header: Latency)
  } else if (code === 'RP') {
    const [addr, data, count] = [r[0] >>> 0, r[1] >>> 0, r[2] >>> 0];
    if (addr % PAGE || count % PAGE || addr + count > FLASH_SIZE) {
      fatal(`flash_range_program(${hex(addr)}, ${hex(data)}, ${count}): not whole 256-byte pages inside the 2 MiB flash`);
      return true;
    }
    if (!inRam(data) || !inRam(data + count - 1)) {
      fatal(`flash_range_program source ${hex(data)} is not in RAM (XIP is off during the call)`);
      return true;
    }
    let end = addr + count;
    if (opts.cutProgram && stats.programs + count / PAGE >= opts.cutProgram) {
      const at = addr + (opts.cutProgram - 1 - stats.programs) * PAGE;
      end = at + PAGE / 2;
    }
    for (let i = 0; i < end - addr; i++) {
      mcu.flash[addr + i] &= mcu.readUint8(data + i);
    }
    if (end < addr + count) powerCut('program', addr, end - PAGE / 2, end);
    persist(addr, count);
    stats.programs += count / PAGE;
    hold((count / PAGE) * FLASH_TIMING[opts.timing].program);
  } else {
    return false; // the others run in the ROM (they change nothing here)
  }
  core.PC = ret;
  core.cycles += 50; // the call itself; the flash's busy time is the hold
  return true;
}

/** The power goes in the middle of a flash operation: what it did to
 * `from..to` (the torn `what` at flash offset `at` ends there) is written
 * through to the flash file, and the harness dies at once (code 4). */
function powerCut(what, from, at, to) {
  persist(from, to - from);
  if (flashFd !== null) fs.fsyncSync(flashFd);
  process.stdout.write(`power cut during the ${what} of flash offset ${hex(at)}\n`);
  process.exit(4);
}

/** The flash is busy for `ns`: the core runs nothing that long, the clock
 * (timer alarms, the USB controller's own delays) goes on. */
function hold(ns) {
  if (ns <= 0) return;
  stats.flashBusyNs += ns;
  mcu.clock.tick(ns);
}

// ---------------------------------------------------------------- latency

/** One direction's byte stream cut into COBS frames at each 0x00; `onFrame`
 * gets the decoded body (null if it does not decode). */
function frameSplitter(onFrame) {
  let buf = [];
  return (bytes) => {
    for (const b of bytes) {
      if (b !== 0) {
        if (buf.length < 4096) buf.push(b);
        continue;
      }
      if (buf.length) onFrame(cobsDecode(buf));
      buf = [];
    }
  };
}

function cobsDecode(enc) {
  const out = [];
  for (let i = 0; i < enc.length; ) {
    const code = enc[i++];
    if (code === 0 || i + code - 1 > enc.length) return null;
    for (let j = 1; j < code; j++) out.push(enc[i++]);
    if (code < 0xff && i < enc.length) out.push(0);
  }
  return out;
}

/** A postcard varint at `at`: [value, next offset] or null. */
function varint(bytes, at) {
  let v = 0;
  for (let shift = 0; shift < 35 && at < bytes.length; shift += 7) {
    const b = bytes[at++];
    v += (b & 0x7f) * 2 ** shift;
    if (!(b & 0x80)) return [v, at];
  }
  return null;
}

const HOST_DEPTH_ROWS = 2; // HostMessage variant indices
const HOST_FRAME_END = 3;
const DEVICE_ACK = 0; // DeviceMessage variant indices
const DEVICE_ERROR = 1;

const latency = {
  lastRows: null, // when the last DepthRows so far was handed over
  pending: new Map(), // FrameEnd seq -> { rows: time, erases: count then }
  erases: 0,
  samples: [], // microseconds
  waited: 0, // answers that waited for an erase
  erased() {
    this.erases++;
  },
  hostFrame(body) {
    if (!body) return;
    const seq = varint(body, 0);
    const kind = seq && varint(body, seq[1]);
    if (!kind) return;
    const t = now();
    if (kind[0] === HOST_DEPTH_ROWS) this.lastRows = t;
    else if (kind[0] === HOST_FRAME_END && this.lastRows !== null && !this.pending.has(seq[0])) {
      this.pending.set(seq[0], { rows: this.lastRows, erases: this.erases });
    }
  },
  deviceFrame(body) {
    if (!body) return;
    const kind = varint(body, 0);
    if (!kind) return;
    let seq = null;
    if (kind[0] === DEVICE_ACK) seq = varint(body, kind[1]);
    else if (kind[0] === DEVICE_ERROR && body[kind[1]] === 1) seq = varint(body, kind[1] + 1);
    const p = seq && this.pending.get(seq[0]);
    if (!p) return;
    this.pending.delete(seq[0]);
    this.samples.push((now() - p.rows) / 1000);
    if (this.erases > p.erases) this.waited++;
  },
  line() {
    const s = [...this.samples].sort((a, b) => a - b);
    const median = s.length ? s[(s.length - 1) >> 1] : 0;
    const worst = s.length ? s[s.length - 1] : 0;
    return (
      `latency frames=${s.length} median_us=${median.toFixed(0)} worst_us=${worst.toFixed(0)} ` +
      `answers_after_erase=${this.waited} flash_timing=${opts.timing}`
    );
  },
};
/** --bus-reset-after-frames: counts the FrameEnds handed to the firmware. */
const framesEnded = {
  seen: new Set(),
  hostFrame(body) {
    const seq = body && varint(body, 0);
    const kind = seq && varint(body, seq[1]);
    if (!kind || kind[0] !== HOST_FRAME_END || this.seen.has(seq[0])) return;
    this.seen.add(seq[0]);
    if (opts.busResets.includes(this.seen.size)) {
      log(`bus reset after frame ${this.seen.size}`);
      stats.busResets++;
      resetBus();
    }
  },
};
const hostFrames = frameSplitter((body) => {
  latency.hostFrame(body);
  framesEnded.hostFrame(body);
});
const deviceFrames = frameSplitter((body) => latency.deviceFrame(body));

// ---------------------------------------------------------------- USB host

/** The chip's USB controller (the current chip's: [attachUsb]). */
let usb = null;
const host = {
  configured: false,
  control: null, // the control transfer in progress
  queue: [], // control transfers still to do
  ep0OutArmed: false,
  bulkIn: -1,
  bulkOut: -1,
  outArmed: 0, // bytes the firmware's bulk OUT buffer takes (0: not armed)
  rx: [], // Buffers from the TCP client, for bulk OUT
  rxBytes: 0,
  descriptors: {},
  lateInARow: 0, // control transfers failed since the port was last configured
  address: null, // what the firmware last wrote to ADDR_ENDP since the last reset
  awaitingAddress: false, // SET_ADDRESS done, the next request goes to address 1
  enumerating: false, // from a bus reset until the port is configured
  heldIn: null, // a bulk IN packet armed while no client is connected
  gap: false, // the next control transfer is scheduled (nextControl)
  dtrUp: false, // the connected client's DTR is up: its bytes go to the device
  absent: false, // reset by its watchdog, not enumerated again yet: no port
};

/** How long a host waits (see the header), in emulated nanoseconds. */
const CONTROL_TIMEOUT_NS = 5000e6;
const RESET_TO_ENUMERATION_NS = 20e6;
const SET_ADDRESS_RECOVERY_NS = 2e6;
const RETRY_GAP_NS = 100e6;
/** Failed transfers in a row before the host gives up on the device. */
const ENUMERATION_TRIES = 4;
// The host's timers, on the current chip's clock ([attachUsb]).
let controlDeadline = null;
let enumerateAfterReset = null;
let nextControl = null;

/** The host resets the bus and enumerates `after` ns later: no bulk OUT
 * until the port is configured again. */
function resetBus(after = RESET_TO_ENUMERATION_NS) {
  host.configured = false;
  host.enumerating = true;
  host.outArmed = 0;
  host.control = null;
  host.queue = [];
  host.address = null;
  host.heldIn = null;
  host.gap = false;
  nextControl.cancel();
  controlDeadline.cancel();
  // rp2040js's resetDevice() raises BUS_RESET at the reset's end (10 ms);
  // the controller raises it at its start.
  usb.resetAlarm.schedule(1000);
  enumerateAfterReset.schedule(after);
}

/** A transfer the firmware was too late for: the host resets the port. */
function hostGivesUp(what) {
  stats.hostResets++;
  log(`usb: ${what}, at ${(now() / 1e6).toFixed(1)} ms: the host resets the port (device descriptor read/64, error -71)`);
  if (++host.lateInARow >= ENUMERATION_TRIES) {
    fatal(`usb: ${ENUMERATION_TRIES} control transfers in a row failed: the host gives up (unable to enumerate USB device)`);
    return;
  }
  resetBus(RETRY_GAP_NS + RESET_TO_ENUMERATION_NS);
}


function setup(bmRequestType, bRequest, wValue, wIndex, wLength, data = null, name = '') {
  const s = new Uint8Array(8);
  s[0] = bmRequestType;
  s[1] = bRequest;
  s[2] = wValue & 0xff;
  s[3] = wValue >> 8;
  s[4] = wIndex & 0xff;
  s[5] = wIndex >> 8;
  s[6] = wLength & 0xff;
  s[7] = wLength >> 8;
  return { setup: s, data, wLength, name, received: [], sentData: false, inDir: !!(bmRequestType & 0x80) };
}

function startNextControl() {
  host.gap = false;
  if (host.awaitingAddress) {
    host.awaitingAddress = false;
    if (host.address !== 1) {
      return hostGivesUp('the device had not taken its new address 2 ms after SET_ADDRESS');
    }
  }
  host.control = host.queue.shift() ?? null;
  debug(`control ${host.control ? host.control.name : 'done'}`);
  if (!host.control) return;
  controlDeadline.schedule(CONTROL_TIMEOUT_NS);
  usb.sendSetupPacket(host.control.setup);
}

/** The next control transfer starts this long after one ends, so that the
 * status stage (delivered after rp2040js's 10 us read delay) reaches the
 * firmware before the next SETUP does, as on a real bus. */
const CONTROL_GAP_NS = 100000;

function controlDone(c) {
  const bytes = Buffer.concat(c.received.map((b) => Buffer.from(b)));
  controlDeadline.cancel();
  host.control = null;
  if (c.onDone) c.onDone(bytes);
  host.awaitingAddress = c.name === 'SET_ADDRESS';
  host.gap = true;
  nextControl.schedule(host.awaitingAddress ? SET_ADDRESS_RECOVERY_NS : CONTROL_GAP_NS);
}

function enumerate() {
  const lineCoding = new Uint8Array([0x00, 0xc2, 0x01, 0x00, 0, 0, 8]); // 115200 8N1
  const q = [
    setup(0x00, 5, 1, 0, 0, null, 'SET_ADDRESS'),
    Object.assign(setup(0x80, 6, 0x0100, 0, 18, null, 'GET_DESCRIPTOR(device)'), {
      onDone: (b) => (host.descriptors.device = b),
    }),
    Object.assign(setup(0x80, 6, 0x0200, 0, 9, null, 'GET_DESCRIPTOR(configuration, 9)'), {
      onDone: (b) => {
        const total = b.length >= 4 ? b.readUInt16LE(2) : 0;
        if (total < 9) return fatal(`configuration descriptor header is ${b.length} bytes`);
        host.queue.unshift(
          Object.assign(setup(0x80, 6, 0x0200, 0, total, null, 'GET_DESCRIPTOR(configuration)'), {
            onDone: (all) => {
              host.descriptors.configuration = all;
              parseConfiguration(all);
            },
          }),
        );
      },
    }),
    // The string descriptors' languages, then the serial number in the
    // first (what a host names the port by: /dev/serial/by-id/, COM ports).
    Object.assign(setup(0x80, 6, 0x0300, 0, 255, null, 'GET_DESCRIPTOR(string 0)'), {
      onDone: (b) => {
        const lang = b.length >= 4 ? b.readUInt16LE(2) : 0x0409;
        const index = host.descriptors.device?.[16] ?? 0;
        if (index === 0) return fatal('the device descriptor names no serial number string');
        host.queue.unshift(
          Object.assign(setup(0x80, 6, 0x0300 | index, lang, 255, null, 'GET_DESCRIPTOR(string serial)'), {
            onDone: (d) => {
              if (d.length < 2 || d[1] !== 3) return fatal(`serial number string descriptor is not one (${d.toString('hex')})`);
              host.descriptors.serial = d.subarray(2, Math.min(d[0], d.length)).toString('utf16le');
            },
          }),
        );
      },
    }),
    setup(0x00, 9, 1, 0, 0, null, 'SET_CONFIGURATION'),
    // CDC-ACM class requests, to the communication interface.
    setup(0x21, 0x20, 0, 0, 7, lineCoding, 'SET_LINE_CODING'),
    Object.assign(setup(0xa1, 0x21, 0, 0, 7, null, 'GET_LINE_CODING'), {
      onDone: (b) => (host.descriptors.lineCoding = b),
    }),
    Object.assign(setup(0x21, 0x22, clientOpen() ? 0x0003 : 0, 0, 0, null, 'SET_CONTROL_LINE_STATE'), {
      onDone: () => {
        host.configured = true;
        host.enumerating = false;
        host.absent = false;
        host.dtrUp = clientOpen();
        if (host.dtrUp) releaseIn();
        host.lateInARow = 0;
        const d = host.descriptors.device ?? Buffer.alloc(0);
        const vidpid = d.length >= 12 ? `${d.readUInt16LE(8).toString(16).padStart(4, '0')}:${d.readUInt16LE(10).toString(16).padStart(4, '0')}` : '?';
        const lc = host.descriptors.lineCoding ?? Buffer.alloc(0);
        const baud = lc.length === 7 ? lc.readUInt32LE(0) : 0;
        log(
          `usb configured ${vidpid} serial ${host.descriptors.serial ?? '?'} ep0 ${d[7] ?? '?'} B, bulk in ${host.bulkIn} out ${host.bulkOut}, ` +
            `line coding ${baud} baud, at ${(now() / 1e6).toFixed(1)} ms`,
        );
        feedOut();
      },
    }),
  ];
  host.queue = q;
  startNextControl();
}

const clientOpen = () => client !== null && !client.destroyed;

/** DTR and RTS up (a program opened the port) or down (it closed it);
 * bulk IN is read again once they are up. */
function lineState(up) {
  const s = Object.assign(setup(0x21, 0x22, up ? 0x0003 : 0, 0, 0, null, 'SET_CONTROL_LINE_STATE'), {
    onDone: () => {
      if (!up) return;
      // The program's open() returns once DTR is up: only then does it
      // write, and is the device's IN endpoint read.
      host.dtrUp = true;
      releaseIn();
      feedOut();
    },
  });
  host.queue.push(s);
  if (host.configured && !host.control && !host.gap) startNextControl();
  wake();
}

/** The bulk IN buffer control word the firmware armed while no program had
 * the port open, handed on now. */
function releaseIn() {
  const held = host.heldIn;
  host.heldIn = null;
  if (held) dpramUpdated(held.offset, held.value);
}

const BUF_CTRL_AVAILABLE = 1 << 10;
/** The controller's own DPRAMUpdated ([attachUsb]). */
let dpramUpdated = null;

function parseConfiguration(d) {
  for (let i = 0; i + 2 <= d.length && d[i] >= 2; i += d[i]) {
    if (d[i + 1] === 5 && d[i] === 7 && (d[i + 3] & 3) === 2) {
      if (d[i + 2] & 0x80) host.bulkIn = d[i + 2] & 0xf;
      else host.bulkOut = d[i + 2] & 0xf;
    }
  }
  if (host.bulkIn < 0 || host.bulkOut < 0) fatal('no bulk IN and OUT endpoints in the configuration descriptor');
}


const onEndpointWrite = (ep, buffer) => {
  debug(`IN ep${ep} ${buffer.length} B ${ep === 0 ? Buffer.from(buffer).toString('hex') : ''}`);
  if (ep === 0) {
    const c = host.control;
    if (!c) return;
    if (c.inDir) {
      if (buffer.length > 0) {
        c.received.push(buffer);
        const got = c.received.reduce((n, b) => n + b.length, 0);
        const mps = host.descriptors.device?.[7] ?? 64;
        if (got >= c.wLength || buffer.length < mps) {
          c.awaitingStatus = true;
          answerEp0Out();
        }
      } else if (c.awaitingStatus) {
        controlDone(c); // not expected: IN status on an IN transfer
      } else if (c.received.length) {
        // A zero-length packet ends a data stage that filled its last packet.
        c.awaitingStatus = true;
        answerEp0Out();
      }
    } else if (buffer.length === 0) {
      // The status stage of a control OUT (or no-data) transfer.
      controlDone(c);
    }
    return;
  }
  if (ep === host.bulkIn) {
    stats.bytesOut += buffer.length;
    deviceFrames(buffer);
    if (client && !client.destroyed) client.write(Buffer.from(buffer));
  }
};

const onEndpointRead = (ep, size) => {
  debug(`OUT ep${ep} armed ${size} B`);
  if (ep === 0) {
    host.ep0OutArmed = true;
    answerEp0Out();
    return;
  }
  if (ep === host.bulkOut || (host.bulkOut < 0 && ep !== 0)) {
    host.outArmed = size;
    feedOut();
  }
};

/** EP0 OUT armed by the firmware: the data stage of a control OUT, or the
 * zero-length status stage of a control IN. */
function answerEp0Out() {
  const c = host.control;
  if (!c || !host.ep0OutArmed) return;
  if (!c.inDir && c.data && !c.sentData) {
    host.ep0OutArmed = false;
    c.sentData = true;
    usb.endpointReadDone(0, c.data);
  } else if (c.inDir && c.awaitingStatus) {
    host.ep0OutArmed = false;
    usb.endpointReadDone(0, new Uint8Array(0));
    controlDone(c);
  }
}

/** Hands the firmware one bulk OUT packet if it has a buffer armed. */
function feedOut() {
  if (!host.configured || !host.dtrUp || host.outArmed === 0 || host.rxBytes === 0) return;
  const want = Math.min(host.outArmed, 64);
  const chunks = [];
  let n = 0;
  while (n < want && host.rx.length) {
    const head = host.rx[0];
    const take = Math.min(want - n, head.length);
    chunks.push(head.subarray(0, take));
    n += take;
    if (take === head.length) host.rx.shift();
    else host.rx[0] = head.subarray(take);
  }
  host.rxBytes -= n;
  host.outArmed = 0;
  stats.bytesIn += n;
  const packet = new Uint8Array(Buffer.concat(chunks));
  usb.endpointReadDone(host.bulkOut, packet);
  hostFrames(packet);
  if (client && client.isPaused() && host.rxBytes < 64 * 1024) client.resume();
}

/** The USB host on the current chip's controller: at power-on, and again
 * on the new chip after a watchdog reset (the host's timers run on the
 * chip's clock). */
function attachUsb() {
  usb = mcu.usbCtrl;
  controlDeadline = mcu.clock.createAlarm(() => {
    const c = host.control;
    if (c) hostGivesUp(`${c.name} not done within ${CONTROL_TIMEOUT_NS / 1e6} ms of its SETUP`);
  });
  enumerateAfterReset = mcu.clock.createAlarm(() => enumerate());
  nextControl = mcu.clock.createAlarm(() => startNextControl());
  // The address the firmware wrote to the controller (ADDR_ENDP), and when.
  const usbWrite = usb.writeUint32.bind(usb);
  usb.writeUint32 = (offset, value) => {
    if (offset === 0) host.address = value & 0x7f;
    usbWrite(offset, value);
  };
  dpramUpdated = usb.DPRAMUpdated.bind(usb);
  usb.DPRAMUpdated = (offset, value) => {
    if (host.bulkIn > 0 && offset === 0x80 + host.bulkIn * 8 && value & BUF_CTRL_AVAILABLE && !clientOpen()) {
      host.heldIn = { offset, value };
      return;
    }
    dpramUpdated(offset, value);
  };
  if (process.env.PICO_DEBUG) {
    const dpram = usb.DPRAMUpdated.bind(usb);
    usb.DPRAMUpdated = (offset, value) => {
      if (offset >= 0x80 && offset < 0x100) debug(`bufctrl ${offset.toString(16)} = ${(value >>> 0).toString(16)}`);
      dpram(offset, value);
    };
  }
  usb.onUSBEnabled = () => {
    debug('usb enabled');
    resetBus();
  };
  usb.onResetReceived = () => debug('bus reset seen by the firmware');
  usb.onEndpointWrite = onEndpointWrite;
  usb.onEndpointRead = onEndpointRead;
}
attachUsb();

// ---------------------------------------------------------------- TCP bridge

let client = null;
/** How long a second connection waits for the first one's end (a program
 * killed just before the next one started) before it is refused. */
const SECOND_CLIENT_WAIT_MS = 300;

const server = net.createServer({ noDelay: true }, (socket) => {
  // A board restarting (its watchdog reset it) has no port until it has
  // enumerated again: as opening a serial port that is not there, the
  // connection ends at once.
  if (host.absent) {
    log('client refused: the board is restarting');
    socket.on('error', () => {});
    socket.destroy();
    return;
  }
  // One program at a time, as a real port opened exclusively: a
  // connection while another is open is closed at once, unsaid (the host
  // reports it in words), after a short wait for the other's end.
  if (clientOpen()) {
    socket.on('error', () => {});
    socket.pause();
    setTimeout(() => {
      if (clientOpen()) {
        log('client refused: another one is connected');
        socket.destroy();
      } else {
        socket.resume();
        accept(socket);
      }
    }, SECOND_CLIENT_WAIT_MS);
    return;
  }
  accept(socket);
});

/** The program of `socket` has the port open. */
function accept(socket) {
  host.rx = [];
  host.rxBytes = 0;
  client = socket;
  socket.setNoDelay(true);
  log('client connected');
  host.dtrUp = false;
  lineState(true);
  socket.on('data', (data) => {
    if (client !== socket) return;
    host.rx.push(data);
    host.rxBytes += data.length;
    if (host.rxBytes >= 256 * 1024) socket.pause();
    feedOut();
    wake();
  });
  socket.on('drain', wake);
  socket.on('error', () => {});
  socket.on('close', () => {
    log('client closed');
    if (client !== socket) return;
    client = null;
    host.dtrUp = false;
    lineState(false);
    // Bytes not yet taken by the firmware are lost with the connection, as
    // unread data of a closed serial port is.
    host.rx = [];
    host.rxBytes = 0;
  });
}
server.on('error', (e) => fatal(`cannot listen on 127.0.0.1:${opts.port}: ${e.message}`));
server.listen(opts.port, '127.0.0.1', () => {
  log(`listening tcp:127.0.0.1:${server.address().port}`);
});

// ---------------------------------------------------------------- run loop

/** PICO_PROFILE=FILE: the cycles spent at each instruction address, written
 * to FILE on exit as "address cycles" lines for `nm`/`addr2line` to name: a
 * flat profile of the firmware for whoever tunes it. Off by default. */
const profile = process.env.PICO_PROFILE
  ? {
      cycles: new Map(),
      add(pc, n) {
        this.cycles.set(pc, (this.cycles.get(pc) ?? 0) + n);
      },
      write() {
        const lines = [...this.cycles].map(([pc, n]) => `${hex(pc)} ${n}`);
        fs.appendFileSync(process.env.PICO_PROFILE, lines.join('\n') + '\n');
      },
    }
  : null;

// Idle: the firmware waits for an interrupt (wfi) when it has nothing to
// do. The harness then moves emulated time on to the next alarm at once (a
// timer alarm, the USB controller's delays, the USB host's next step); with
// no alarm left, only the host can give the firmware something to do, so
// the harness stops running until the TCP client connects, sends, leaves
// or drains its socket (wake), and takes no CPU meanwhile. Emulated time
// stands still while the harness waits for the host, as it always has.

let stopped = false;
/** While the run loop is stopped: the timer that resumes it, or WAITING_FOR_HOST
 * (only wake resumes it). null while it runs. */
let parked = null;
const WAITING_FOR_HOST = 'host';
const started = Date.now();

/** The host did something: the run loop goes on if it was stopped. */
function wake() {
  if (parked === null) return;
  if (parked !== WAITING_FOR_HOST) clearTimeout(parked);
  parked = null;
  setImmediate(run);
}

function run() {
  if (stopped) return;
  const { core, clock } = mcu;
  let waitForHost = false;
  for (let i = 0; i < CHUNK && !stopped; i++) {
    if (resetPending) break;
    if (core.waiting) {
      // An interrupt raised before the wfi ends it too (on silicon it
      // returns at once; rp2040js wakes the core only when one is raised
      // while it waits). A wfi may always return early: the firmware
      // looks again.
      if (core.pendingInterrupts & core.enabledInterrupts || core.pendingSystick) {
        core.waiting = false;
        core.interruptsUpdated = true;
        continue;
      }
      if (!hostAlarmPending()) {
        waitForHost = true;
        break;
      }
      clock.tick(Math.max(clock.nanosToNextAlarm, 0));
      if (resetPending) break;
      continue;
    }
    const pc = core.PC;
    if (pc < ROM_END) {
      const code = hooks[pc >> 1];
      if (code !== null && flashCall(code)) continue;
    }
    const cycles = core.executeInstruction();
    if (profile) profile.add(pc, cycles);
    clock.tick(cycles * NANOS_PER_CYCLE);
    // The watchdog fired during that instruction (a write forcing it) or
    // that clock step (its countdown): the chip is a new one from here.
    if (resetPending) break;
  }
  if (stopped) return;
  if (resetPending) {
    chipReset();
    setImmediate(run);
    return;
  }
  // Back-pressure: a TCP client that does not read stops the board.
  const blocked = client && client.writableLength > 1024 * 1024;
  if (waitForHost) {
    parked = WAITING_FOR_HOST;
  } else if (blocked) {
    parked = setTimeout(() => {
      parked = null;
      run();
    }, 10);
  } else {
    setImmediate(run);
  }
}

/** Whether an alarm other than the firmware's own idle ones is set: the
 * watchdog's countdown and the timer's alarms (an idle firmware wakes to
 * feed its watchdog) do not keep emulated time going while the firmware
 * waits for the host (see Idle above: time stands still then, so the
 * watchdog does not count either); any other alarm (the USB host's steps,
 * the controller's delays) does. */
function hostAlarmPending() {
  const idle = new Set([mcu.peripherals[0x40058].alarm.clockAlarm, ...mcu.peripherals[0x40054].alarms.map((a) => a.clockAlarm)]);
  for (let a = mcu.clock.nextAlarm; a; a = a.next) {
    if (!idle.has(a)) return true;
  }
  return false;
}

/** The watchdog reset the chip (REASON in resetPending: its countdown ran
 * out, or the firmware forced it, as its panic handler does). A new chip
 * comes out of reset as the firmware selected (PSM.WDSEL: everything but
 * the oscillators): the same flash contents, the watchdog's scratch
 * registers and REASON kept (the watchdog is not reset by its own reset,
 * which is how a panic's record reaches the next boot), everything else
 * as at power-on; it boots from the boot ROM again. The board leaves the
 * bus as a real one does: the program that had its port open loses its
 * connection, and until the firmware has enumerated again the port is
 * absent (a connection is refused at once); then it is back on the same
 * port. */
function chipReset() {
  const reason = resetPending;
  resetPending = 0;
  stats.watchdogResets++;
  const old = mcu;
  const oldWatchdog = old.peripherals[0x40058];
  log(
    `chip reset by the watchdog: ${reason & 2 ? 'forced by the firmware (its panic handler)' : 'its countdown ran out (the firmware stopped feeding it: a hang)'}` +
      `, at ${(now() / 1e6).toFixed(1)} ms (pc ${hex(old.core.PC)})`,
  );
  nanosBefore += old.clock.nanos;
  cyclesBefore += old.core.cycles;
  mcu = newChip();
  mcu.flash.set(old.flash.subarray(0, FLASH_SIZE), 0);
  const watchdog = mcu.peripherals[0x40058];
  watchdog.scratchData.set(oldWatchdog.scratchData);
  watchdog.reason = reason;
  // The USB host: the device is gone from the bus, its port with it.
  host.configured = false;
  host.enumerating = false;
  host.control = null;
  host.queue = [];
  host.ep0OutArmed = false;
  host.bulkIn = -1;
  host.bulkOut = -1;
  host.outArmed = 0;
  host.descriptors = {};
  host.lateInARow = 0;
  host.address = null;
  host.awaitingAddress = false;
  host.heldIn = null;
  host.gap = false;
  host.dtrUp = false;
  host.rx = [];
  host.rxBytes = 0;
  host.absent = true;
  latency.lastRows = null;
  latency.pending.clear();
  attachUsb();
  if (client) {
    // Its close handler says "client closed".
    const gone = client;
    client = null;
    gone.destroy();
  }
}

/** The stack's high-water mark: the firmware paints its stack at reset
 * (cortex-m-rt's `paint-stack`: 0xCCCCCCCC from `_stack_end` to the initial
 * stack pointer), so the lowest word no longer painted is as deep as it
 * went. "stack peak_bytes=P room_bytes=R": P deepest use, R the stack's
 * whole room (from the top of its MPU guard, or the statics' end without
 * one, to the top of RAM). */
function stackLine() {
  const flash = new DataView(mcu.flash.buffer, mcu.flash.byteOffset);
  const top = flash.getUint32(0x100, true); // the vector table's initial SP
  let low = stackFloor;
  while (low < top && mcu.readUint32(low) === 0xcccccccc) low += 4;
  return `stack peak_bytes=${top - low} room_bytes=${top - Math.max(stackFloor, guardTop)}`;
}

function finish(code = 0) {
  if (stopped) return;
  stopped = true;
  if (parked !== null && parked !== WAITING_FOR_HOST) clearTimeout(parked);
  const cycles = cyclesBefore + mcu.core.cycles;
  process.stdout.write(
    `stats pc=${hex(mcu.core.PC)} cycles=${cycles} emulated_ms=${(now() / 1e6).toFixed(1)} ` +
      `wall_ms=${Date.now() - started} rom_flash_calls=${stats.romFlashCalls} ` +
      `sectors_erased=${stats.erases} pages_programmed=${stats.programs} ` +
      `flash_busy_ms=${(stats.flashBusyNs / 1e6).toFixed(1)} ` +
      `bus_resets=${stats.busResets} usb_host_resets=${stats.hostResets} ` +
      `erases_while_enumerating=${stats.erasesWhileEnumerating} ` +
      `watchdog_resets=${stats.watchdogResets} ` +
      `guard_faults=${stats.guardFaults} ` +
      `usb_bytes_in=${stats.bytesIn} usb_bytes_out=${stats.bytesOut}\n`,
  );
  process.stdout.write(latency.line() + '\n');
  process.stdout.write(stackLine() + '\n');
  if (profile) profile.write();
  if (flashFd !== null) {
    try {
      fs.fsyncSync(flashFd);
    } catch {}
  }
  process.exit(code);
}

// Whoever started the harness (a test, `placedb device --rp2040`) owns it:
// when that process dies, so does the emulator (no orphan keeps the port).
const parent = process.ppid;
setInterval(() => {
  if (process.ppid !== parent) finish(0);
}, 500).unref();
process.on('SIGTERM', () => finish(0));
process.on('SIGINT', () => finish(0));
// A timer, not a check in the run loop: the loop may be waiting for a host
// that never comes.
if (opts.deadline) {
  setTimeout(() => {
    process.stderr.write(`error: deadline of ${opts.deadline} s reached\n`);
    finish(3);
  }, opts.deadline * 1000);
}
setImmediate(run);
