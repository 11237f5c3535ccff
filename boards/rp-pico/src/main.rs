//! placedb firmware for the Raspberry Pi Pico (RP2040, Cortex-M0+): the placedb
//! wire protocol over USB CDC-ACM serial.
//!
//! One polled loop: read the packet the host sent straight into the
//! receive buffer of the [`Device256K`] (a `static`, so its RAM is
//! accounted for at link time; servicing USB only when no packet waits),
//! let it handle every message that ends there and queue every reply frame
//! it produces on the [`link::Link`], which never drops a reply byte and
//! stops reading while its queue is full. The on-board LED (GPIO25) toggles
//! on every reply frame.
//!
//! Idle, it sleeps: a turn of the loop that found nothing to do (no packet,
//! no erase ahead to start) ends in [`sleep_until_usb`], a `wfi` that the USB
//! controller's interrupt ends (a packet, a control request, a bus reset, a
//! reply packet taken by the host), so the core waits for its host instead
//! of polling it: on silicon it draws less, and under the emulator an idle
//! board leaves the host's CPU alone. The interrupt only ends the wait: USB
//! is still serviced by the loop, and no handler runs on silicon.
//!
//! The scan is durable: the device writes its database frames and decisions
//! to a log in the second MiB of flash ([`flash`]) before it acknowledges
//! them, and restores the scan from it at boot, so a board that lost power
//! goes on where it was (`placedb stream --resume`).
//!
//! Erases happen off the frame path: a sector erase stalls the chip for
//! 45 ms (400 ms at worst) with USB unserviced, so the sector the log will
//! need next is erased ahead ([`EraseAhead`]) whenever a turn of the loop
//! finds no host byte waiting, or between two frames (after a frame's
//! answer has left, before the next frame is read), and the append that
//! opens it only writes.
//!
//! A hang or a panic restarts the board ([`watchdog`]): the watchdog is
//! fed each turn of the loop, while a reply waits for a slow host and at
//! every flash operation; a panic records its place for the next boot,
//! which reports it (`Status::last_reset`) and restores the scan.
//!
//! USB first: an erase while the host enumerates makes the device miss its
//! new address (usb-device applies SET_ADDRESS at its next poll; the host
//! then reports "device descriptor read/64, error -71" and resets the
//! port). So what a boot must erase (the restore's, and the first sector
//! ahead) is erased before USB starts, and later erases ahead wait until
//! the device is configured and no control request or bus reset has come
//! for [`USB_QUIET_US`] (a host sends its requests in bursts: a bus reset,
//! a re-enumeration, a port opened).
#![no_std]
#![no_main]

#[cfg(feature = "fault-injection")]
mod fault;
mod flash;
mod link;
mod stack_guard;
mod watchdog;

use core::cell::RefCell;
use core::sync::atomic::{AtomicBool, Ordering};
use cortex_m::peripheral::NVIC;
use critical_section::Mutex;
use embedded_hal::digital::StatefulOutputPin;
use placedb::device::Device256K;
use placedb::persist::{EraseAhead, Log};
use placedb::protocol::Phase;
use rp2040_hal::pac::interrupt;
use rp2040_hal::{self as hal, pac, usb::UsbBus};
use usb_device::class_prelude::UsbBusAllocator;
use usb_device::device::UsbDevice;

/// Second-stage bootloader for the Pico's W25Q16 flash (W25Q080 image): the
/// first 256 bytes of flash (memory.x), loaded and checked by the boot ROM.
// `unsafe(link_section)`: the attribute is unsafe in general (a section can
// hold anything); `.boot2` is a 256-byte region of its own that only the boot
// ROM reads, and the value is the vendor's checksummed image.
#[unsafe(link_section = ".boot2")]
#[used]
pub static BOOT2: [u8; 256] = rp2040_boot2::BOOT_LOADER_W25Q080;

/// The Pico's crystal.
const XTAL_FREQ_HZ: u32 = 12_000_000;
/// The RP2040 timer counts microseconds.
const TIMER_HZ: u32 = 1_000_000;
/// Most packets read between two polls of USB while the host keeps one
/// waiting: a bound on how long a control request (or a bus reset) waits,
/// a few milliseconds of 64-byte frames' work.
const MAX_UNPOLLED: u32 = 16;
/// No erase ahead within this long of a control request or a bus reset
/// (the gaps inside an enumeration are a few milliseconds; USB 2.0 gives
/// the device 2 ms to take a new address, 50 ms for a request).
const USB_QUIET_US: u64 = 20_000;

/// One bulk packet, for the rare packet the device's receive buffer has no
/// room for: word-aligned as the controller's buffers are, so that the
/// copy out of the controller moves words (the Cortex-M0+ `memcpy` moves
/// bytes between differently aligned buffers), and so is the copy into
/// the framing's buffer after it (which aligns the frame to it).
#[repr(C, align(4))]
struct Packet([u8; link::PACKET_LEN]);

/// The device, all zero at power-on, in `.bss`: a firmware whose statics and
/// stack reserve do not fit the 256 KiB RAM fails to link (memory.x).
static DEVICE: Mutex<RefCell<Device256K>> = Mutex::new(RefCell::new(Device256K::new()));

/// Set once the timer runs: [`ticks`] reads it only then.
static TIMER_RUNNING: AtomicBool = AtomicBool::new(false);

/// Microseconds since boot (0 before the timer is set up).
///
/// Called a few times per received packet (the receive path is timed) and
/// per message by the device, so it reads the counter registers directly:
/// the `hal::Timer` kept in a critical-section mutex cost a critical section
/// (interrupts off, the hardware spinlock taken and released) on every read.
fn ticks() -> u64 {
    if !TIMER_RUNNING.load(Ordering::Acquire) {
        return 0;
    }
    // SAFETY: only the read-only raw counter registers are read (reads have
    // no side effect), and only once `hal::Timer::new` has taken the timer
    // out of reset (TIMER_RUNNING). The high word is read around the low
    // one, as `hal::Timer::get_counter` does, so a carry between is seen.
    let timer = unsafe { &*pac::TIMER::PTR };
    let mut high = timer.timerawh().read().bits();
    loop {
        let low = timer.timerawl().read().bits();
        let again = timer.timerawh().read().bits();
        if again == high {
            return (u64::from(high) << 32) | u64::from(low);
        }
        high = again;
    }
}

#[hal::entry]
fn main() -> ! {
    // Before anything else: why the board started (a panic's record in
    // the watchdog's scratch registers, cleared as it is read).
    let last_reset = watchdog::take_last_reset();
    #[cfg(feature = "fault-injection")]
    fault::take_plan();
    // Before the stack is deep: an overflow faults at the guard instead of
    // overwriting the statics.
    stack_guard::enable();
    let Some(mut pac) = pac::Peripherals::take() else {
        halt()
    };
    let mut watchdog = hal::Watchdog::new(pac.WATCHDOG);
    let Ok(clocks) = hal::clocks::init_clocks_and_plls(
        XTAL_FREQ_HZ,
        pac.XOSC,
        pac.CLOCKS,
        pac.PLL_SYS,
        pac.PLL_USB,
        &mut pac.RESETS,
        &mut watchdog,
    ) else {
        halt()
    };
    // Started once its tick runs (set up with the clocks): from here on a
    // hang resets the board. Restoring the scan is covered: every flash
    // read feeds it.
    watchdog::start(&mut watchdog);
    // Kept alive (not read through: `ticks` reads the registers) so the
    // timer is owned by this firmware for as long as it runs.
    let _timer = hal::Timer::new(pac.TIMER, &mut pac.RESETS, &clocks);
    TIMER_RUNNING.store(true, Ordering::Release);
    critical_section::with(|cs| {
        let mut device = DEVICE.borrow_ref_mut(cs);
        device.set_clock(ticks, TIMER_HZ);
        device.set_last_reset(last_reset);
    });

    // SAFETY: this firmware never starts core 1 and uses no DMA, so nothing
    // but PicoFlash accesses flash during its erases and writes.
    let storage = unsafe { flash::PicoFlash::new() };
    let Ok(mut log) = Log::open(EraseAhead::new(storage), 0, flash::REGION_LEN as u32) else {
        halt()
    };
    // A log that does not restore leaves the device empty: the host sees an
    // unconfigured device and starts over.
    critical_section::with(|cs| {
        let _ = DEVICE.borrow_ref_mut(cs).restore(&mut log);
    });
    // USB first: the first erase ahead too happens before USB starts.
    erase_ahead(&mut log);

    let sio = hal::Sio::new(pac.SIO);
    let pins = hal::gpio::Pins::new(
        pac.IO_BANK0,
        pac.PADS_BANK0,
        sio.gpio_bank0,
        &mut pac.RESETS,
    );
    let mut led = pins.gpio25.into_push_pull_output();

    // Each board its own USB serial number: the flash chip's unique ID,
    // read before USB starts (XIP is off while it is read).
    let serial = link::SerialNumber::new(flash::unique_id());

    let bus = UsbBusAllocator::new(UsbBus::new(
        pac.USBCTRL_REGS,
        pac.USBCTRL_DPRAM,
        clocks.usb_clock,
        true,
        &mut pac.RESETS,
    ));
    let mut link = link::Link::new(&bus);
    let Ok(mut usb) = link::device(&bus, serial.as_str()) else {
        halt()
    };

    let mut packet = Packet([0; link::PACKET_LEN]);
    let mut unpolled = 0u32;
    let mut quiet = UsbQuiet { control_at: 0 };
    let mut idle = false;
    loop {
        watchdog::feed();
        link.drain(&usb);
        // After the replies have gone to the controller: a turn that found
        // nothing to do waits for USB's next event.
        if idle {
            sleep_until_usb();
        }
        // One critical section (one borrow of the device) a turn, not one
        // for the read and one for each message: no interrupt handler
        // shares anything with the loop, and the turn's flash work nests
        // its own.
        idle = critical_section::with(|cs| {
            let mut device = DEVICE.borrow_ref_mut(cs);
            // The receive path is part of a frame's cost (FrameCost):
            // reading a packet out of the controller and, when it came
            // after one, servicing USB are timed; sending queued replies
            // (`drain`) is not, and a turn that reads nothing (an idle
            // poll) is no frame's work. USB is serviced only once no
            // packet is waiting (or after MAX_UNPOLLED packets, for
            // control requests): the controller holds a received packet
            // and takes the next reply packet without it.
            let t_read = ticks();
            let mut got = if unpolled < MAX_UNPOLLED {
                read_packet(&mut link, &usb, &mut device, &mut packet)
            } else {
                Got::Nothing
            };
            let mut received = ticks().wrapping_sub(t_read);
            if got == Got::Nothing {
                unpolled = 0;
                let t_service = ticks();
                link.service(&mut usb);
                let serviced = ticks().wrapping_sub(t_service);
                link.drain(&usb);
                let t_read = ticks();
                got = read_packet(&mut link, &usb, &mut device, &mut packet);
                received = serviced.wrapping_add(ticks().wrapping_sub(t_read));
            }
            // One host message at a time, so that the gap after a frame's
            // answer is seen even when the next frame's first bytes came
            // in the same packet; the framing's scan finds where each
            // message ends (the only pass over the bytes before their
            // decode). The turn's USB time goes with the first message.
            match got {
                Got::Nothing => {
                    // Nothing from the host: the time to erase what the
                    // log needs next (a failed erase is the log's own
                    // erase's to retry), once USB has settled. Then the
                    // board is idle until USB's next event, unless an
                    // erase waits for the quiet period to end (polled:
                    // at most USB_QUIET_US after the last control request).
                    if quiet.now(&mut link, &mut usb) {
                        erase_ahead(&mut log);
                        return true;
                    }
                    return erased_ahead(&mut log) || !link::configured(&usb);
                }
                Got::InPlace => loop {
                    device.add_receive_ticks(received);
                    received = 0;
                    let ended = device.receive_held(&mut log, &mut |frame| {
                        let Ok(()) = led.toggle();
                        link.send(&mut usb, frame);
                    });
                    if ended && device.phase() != Phase::InFrame {
                        erase_between_frames(&mut link, &mut usb, &mut log, &mut quiet);
                    }
                    #[cfg(feature = "fault-injection")]
                    fault::after_message(&device);
                    // USB first: a bus reset (a re-enumeration) stops the
                    // held frames' work until the device is configured
                    // again, so that no frame's computing keeps the
                    // firmware from its polls while the host enumerates
                    // (a SET_ADDRESS not applied within 2 ms is missed).
                    if !device.holds_input() || !link::configured(&usb) {
                        break;
                    }
                },
                Got::Packet(n) => {
                    let mut rest = packet.0.get(..n).unwrap_or_default();
                    while !rest.is_empty() {
                        device.add_receive_ticks(received);
                        received = 0;
                        let (after, ended) = device.receive_message(rest, &mut log, &mut |frame| {
                            let Ok(()) = led.toggle();
                            link.send(&mut usb, frame);
                        });
                        rest = after;
                        if ended && device.phase() != Phase::InFrame {
                            erase_between_frames(&mut link, &mut usb, &mut log, &mut quiet);
                        }
                        #[cfg(feature = "fault-injection")]
                        fault::after_message(&device);
                    }
                }
            }
            unpolled += 1;
            false
        });
    }
}

/// Sleeps (`wfi`) until the USB controller raises its interrupt, at once if
/// it has raised it already: an event the loop has not serviced yet (it
/// looks at the controller first thing after); or until the timer's alarm
/// 0, set [`watchdog::IDLE_WAKE_US`] ahead, so that an idle board wakes to
/// feed its watchdog (the loop's next turn does).
///
/// The interrupt is unmasked only for the `wfi`, with PRIMASK set, and
/// masked again before PRIMASK is cleared, so on silicon it only ends the
/// wait and its handler never runs. Its pending state is cleared first (it
/// stays latched after the loop serviced the event that raised it, and
/// would end every later sleep at once), and the controller's interrupt
/// status is read after that: an event before the read is seen there, one
/// after it pends the interrupt and ends the `wfi`.
fn sleep_until_usb() {
    cortex_m::interrupt::free(|_| {
        NVIC::unpend(pac::Interrupt::USBCTRL_IRQ);
        // SAFETY: a read of the read-only INTS register, which has no side
        // effect; the USB bus driver owns the controller, and never
        // depends on this read.
        let raised = unsafe { &*pac::USBCTRL_REGS::PTR }.ints().read().bits() != 0;
        if raised {
            return;
        }
        // SAFETY: the timer's alarm 0 and its interrupt enable, which
        // nothing else in this firmware uses (`ticks` only reads the
        // counter); writing ALARM0 arms it.
        let timer = unsafe { &*pac::TIMER::PTR };
        let wake = timer
            .timerawl()
            .read()
            .bits()
            .wrapping_add(watchdog::IDLE_WAKE_US);
        timer.intr().write(|w| w.alarm_0().clear_bit_by_one());
        timer.inte().modify(|_, w| w.alarm_0().set_bit());
        timer.alarm0().write(|w| unsafe { w.bits(wake) });
        NVIC::unpend(pac::Interrupt::TIMER_IRQ_0);
        // SAFETY: unmasked with PRIMASK set and masked again before the
        // critical section ends: no critical section is broken, and no
        // handler runs on silicon (see `USBCTRL_IRQ` for the emulator).
        unsafe {
            NVIC::unmask(pac::Interrupt::USBCTRL_IRQ);
            NVIC::unmask(pac::Interrupt::TIMER_IRQ_0);
        }
        cortex_m::asm::wfi();
        NVIC::mask(pac::Interrupt::USBCTRL_IRQ);
        NVIC::mask(pac::Interrupt::TIMER_IRQ_0);
        // Disarmed (if USB ended the sleep first) and cleared: the next
        // sleep sets it again.
        timer.armed().write(|w| unsafe { w.bits(1) });
        timer.intr().write(|w| w.alarm_0().clear_bit_by_one());
        timer.inte().modify(|_, w| w.alarm_0().clear_bit());
    });
}

/// The USB controller's interrupt, which only ends [`sleep_until_usb`]'s
/// `wfi`: masks itself and leaves USB to the loop. Never entered on
/// silicon (the interrupt is masked again before PRIMASK is cleared), but
/// rp2040js takes an interrupt that ends a `wfi` even under PRIMASK.
#[interrupt]
fn USBCTRL_IRQ() {
    NVIC::mask(pac::Interrupt::USBCTRL_IRQ);
}

/// The timer's alarm 0, which only ends [`sleep_until_usb`]'s `wfi` (an
/// idle board's wake to feed its watchdog): masks itself, as
/// [`USBCTRL_IRQ`] does, and for the same reason.
#[interrupt]
fn TIMER_IRQ_0() {
    NVIC::mask(pac::Interrupt::TIMER_IRQ_0);
}

/// What [`read_packet`] read.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Got {
    Nothing,
    /// A packet, into the device's receive buffer (held there).
    InPlace,
    /// A packet of this many bytes, into the packet buffer: the device's
    /// receive buffer had no room for a whole one (the end of a frame
    /// close to the longest).
    Packet(usize),
}

/// Reads the packet the host sent, if any, straight into the device's
/// receive buffer (the framing then scans it where it lies: no copy
/// between the USB controller and the frame's decode), or into `packet`
/// when that has no room for a whole packet; or, when input is held
/// already, reads nothing and says so once USB is configured. The only
/// place input is read, so where a new host session's start is taken.
fn read_packet<'a>(
    link: &mut link::Link<'a, UsbBus>,
    usb: &UsbDevice<'a, UsbBus>,
    device: &mut Device256K,
    packet: &mut Packet,
) -> Got {
    // A new host session (DTR rose, before its program wrote anything):
    // input the previous program left (a partial frame, killed mid-write)
    // is not the start of the new one's.
    if link.take_new_session() {
        device.drop_input();
    }
    if device.holds_input() {
        // Input held back while USB was not configured (the receive loop).
        return if link::configured(usb) {
            Got::InPlace
        } else {
            Got::Nothing
        };
    }
    let room = device.receive_room(link::PACKET_LEN);
    if room.len() >= link::PACKET_LEN {
        let n = link.read(usb, room);
        device.commit_received(n);
        if n == 0 {
            Got::Nothing
        } else {
            Got::InPlace
        }
    } else {
        match link.read(usb, &mut packet.0) {
            0 => Got::Nothing,
            n => Got::Packet(n),
        }
    }
}

/// After a message that leaves no frame open: a host that keeps the link
/// busy (a pipelined stream: the next frame is always waiting) leaves no
/// idle turn, so the sector the log needs next is erased here, once the
/// answers are out of the chip (`flush` waits, boundedly, until the USB
/// controller holds them: it sends them from its own buffers during the
/// erase). The erase then delays the next frame's start, not a frame's
/// answer. USB is looked at after the flush: its polls are where a bus
/// reset or a request shows.
fn erase_between_frames<'a>(
    link: &mut link::Link<'a, UsbBus>,
    usb: &mut UsbDevice<'a, UsbBus>,
    log: &mut Log<LogFlash>,
    quiet: &mut UsbQuiet,
) {
    if !erased_ahead(log) {
        link.flush(usb);
        if quiet.now(link, usb) {
            erase_ahead(log);
        }
    }
}

/// When USB last saw a control request or a bus reset: erases ahead wait
/// [`USB_QUIET_US`] after it.
struct UsbQuiet {
    /// [`ticks`] when [`Self::now`] last found one had come.
    control_at: u64,
}

impl UsbQuiet {
    /// Whether an erase may start now: the device configured, and no
    /// control request or bus reset for [`USB_QUIET_US`]. USB is polled
    /// first: a bus reset shows at once in the controller, and the work
    /// since the last poll (a frame's) may have been long.
    fn now<'a>(
        &mut self,
        link: &mut link::Link<'a, UsbBus>,
        usb: &mut UsbDevice<'a, UsbBus>,
    ) -> bool {
        link.service(usb);
        let now = ticks();
        if link.take_control_seen() {
            self.control_at = now;
        }
        link::configured(usb) && now.wrapping_sub(self.control_at) >= USB_QUIET_US
    }
}

/// The log's flash, with its next sector erased ahead of need.
type LogFlash = EraseAhead<flash::PicoFlash>;

/// Whether the sector the log's next erase goes to is erased already.
fn erased_ahead(log: &mut Log<LogFlash>) -> bool {
    let next = log.next_sector();
    log.flash().is_erased(next)
}

/// Erases the sector the log's next erase goes to, unless it is erased
/// already (a failed erase is the log's own erase's to retry).
fn erase_ahead(log: &mut Log<LogFlash>) {
    let next = log.next_sector();
    let _ = log.flash().erase_ahead(next);
}

/// Stops: a board that cannot start. Once the watchdog runs, it restarts
/// the board (which tries again) after [`watchdog::TIMEOUT_US`].
fn halt() -> ! {
    loop {
        cortex_m::asm::wfi();
    }
}

/// A panic restarts the board, its place recorded for the next boot
/// ([`watchdog::panic_reset`]), which restores the scan from flash.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    cortex_m::interrupt::disable();
    watchdog::panic_reset(info.location())
}
