//! The byte link to the host: the bulk endpoints of a polled USB CDC-ACM
//! port, read and written a packet at a time, with a queue of reply bytes
//! and backpressure.
//!
//! The endpoints are usbd-serial's [`CdcAcmClass`], not its `SerialPort`:
//! that one copies every received packet into a ring buffer of its own (at
//! unaligned offsets, so byte by byte on the Cortex-M0+) before the firmware
//! copies it again; here [`Link::read`] puts a packet straight where the
//! caller wants it (the device's receive buffer). Replies go into a fixed
//! queue and [`Link::drain`] moves them on a packet at a time as the host
//! takes them, ending every transfer with a short packet (a zero-length
//! one after a reply that ends on a full packet): CDC hosts see a bulk
//! transfer's data only once it ends.
//!
//! Nothing is dropped: a reply that finds the queue full waits, still polling
//! USB, until there is room; and input is read only while the queue has room
//! for a whole frame, so a host that does not read stops being read from (its
//! packets are NAKed: the controller holds one until it is read). One request
//! may be answered by many frames (an export streams a record per frame): the
//! device then waits inside `receive` for the host to read.
//!
//! A host session is a program having the port open, which the host
//! signals with DTR (SET_CONTROL_LINE_STATE: Linux, macOS and Windows raise
//! it when a program opens the port and drop it when it closes it). When
//! it falls, the replies still queued are dropped and later ones are not
//! queued (nobody reads them: the device would otherwise wait in
//! [`Link::send`] for the next program to drain them); when it rises, what
//! an earlier session left is dropped too, a lone frame delimiter (0x00)
//! ends whatever part of a reply the controller still holds for the new
//! session's decoder, and [`Link::take_new_session`] tells the caller to
//! drop the partial frame the previous program may have left in its
//! input. A host that never raises DTR changes nothing.
//!
//! Nothing here depends on the RP2040: the link is generic over
//! [`UsbBus`], and the [`UsbDevice`] is the caller's (every method takes it),
//! so host tests (`host/tests/board_usb_link.rs`) drive this file over emulated
//! buses, with the descriptors of [`device`].

#[path = "tx_queue.rs"]
mod tx_queue;

use placedb::protocol::MAX_REPLY_LEN;
use tx_queue::TxQueue;
use usb_device::bus::{InterfaceNumber, StringIndex, UsbBus, UsbBusAllocator};
use usb_device::class::{ControlIn, ControlOut, UsbClass};
use usb_device::control::RequestType;
use usb_device::descriptor::{BosWriter, DescriptorWriter};
use usb_device::device::{
    StringDescriptors, UsbDevice, UsbDeviceBuilder, UsbDeviceState, UsbVidPid,
};
use usb_device::endpoint::EndpointAddress;
use usb_device::prelude::BuilderError;
use usb_device::LangID;
use usbd_serial::{CdcAcmClass, USB_CLASS_CDC};

/// Bytes of a full-speed bulk packet, both ways: [`Link::read`] needs a
/// buffer at least this long.
pub const PACKET_LEN: usize = 64;
/// Reply bytes that can wait for the host: 16 frames of the longest kind.
pub const TX_QUEUE_LEN: usize = 16 * MAX_REPLY_LEN;
/// Input is read only while at least this much of the queue is free (8 longest
/// replies), so the replies to it usually fit without waiting.
pub const RX_HEADROOM: usize = 8 * MAX_REPLY_LEN;
/// Full packets in a row after which one is sent short (63 bytes), so that a
/// host that waits for a transfer's end sees a long stream in good time (as
/// usbd-serial's `SerialPort` does).
pub const SHORT_PACKET_INTERVAL: u32 = 10;

/// Most polls [`Link::flush`] waits for the host to take the queued
/// replies: some tens of milliseconds of polling on the Pico, far more than
/// the few 1 ms USB frames a reply of a few packets needs from a host that
/// reads, and a bound on the wait for one that does not.
pub const FLUSH_POLLS: u32 = 20_000;

/// Shared VID/PID for CDC-ACM test devices (not for products): obdev's
/// rules for this pair tell the devices on it apart by serial number, which
/// must start with a domain (or e-mail address) the vendor owns, then ":".
pub const USB_VID_PID: UsbVidPid = UsbVidPid(0x16c0, 0x27dd);
pub const MANUFACTURER: &str = "placedb";
pub const PRODUCT: &str = "placedb device";
/// The domain that opens every serial number. `placedb.example` is a
/// placeholder: `.example` is reserved (RFC 2606) and owned by no one, so
/// whoever ships these boards must replace it with a domain the project
/// owns (obdev's rules for 16c0:27dd), or move to a VID:PID of its own.
pub const SERIAL_DOMAIN: &str = "placedb.example";
/// CDC's SET_CONTROL_LINE_STATE (DTR in bit 0 of its value).
const SET_CONTROL_LINE_STATE: u8 = 0x22;

/// Characters of a serial number: the domain, ":", 16 hex digits.
pub const SERIAL_LEN: usize = SERIAL_DOMAIN.len() + 1 + 16;

/// A board's USB serial number: [`SERIAL_DOMAIN`], ":", then the flash
/// chip's 64-bit unique ID (its 0x4B command) as 16 upper-case hex digits,
/// first byte read first: `placedb.example:E6614103E7452D2F`. Unique per
/// unit, so two boards on one host differ (`/dev/serial/by-id/`, Windows'
/// COM port numbers, `placedb --port SERIAL`).
pub struct SerialNumber([u8; SERIAL_LEN]);

impl SerialNumber {
    /// The serial number of the board whose flash answered `id` (its eight
    /// bytes in the order the chip sent them).
    pub fn new(id: [u8; 8]) -> Self {
        const HEX: &[u8; 16] = b"0123456789ABCDEF";
        let mut s = [b'0'; SERIAL_LEN];
        let (domain, rest) = s.split_at_mut(SERIAL_DOMAIN.len());
        domain.copy_from_slice(SERIAL_DOMAIN.as_bytes());
        if let Some((colon, digits)) = rest.split_first_mut() {
            *colon = b':';
            for (pair, byte) in digits.chunks_exact_mut(2).zip(id) {
                if let [hi, lo] = pair {
                    *hi = HEX[usize::from(byte >> 4)];
                    *lo = HEX[usize::from(byte & 0xF)];
                }
            }
        }
        SerialNumber(s)
    }

    /// The serial number as the string descriptor carries it.
    pub fn as_str(&self) -> &str {
        core::str::from_utf8(&self.0).unwrap_or(SERIAL_DOMAIN)
    }
}

/// The firmware's USB device on `bus`: [`USB_VID_PID`], the strings above
/// with `serial` (a [`SerialNumber`]), device class CDC and EP0 packets of
/// 64 bytes. Call it after [`Link::new`] (usb-device allocates the class's
/// endpoints first).
pub fn device<'a, B: UsbBus>(
    bus: &'a UsbBusAllocator<B>,
    serial: &'a str,
) -> Result<UsbDevice<'a, B>, BuilderError> {
    let strings = StringDescriptors::default()
        .manufacturer(MANUFACTURER)
        .product(PRODUCT)
        .serial_number(serial);
    // EP0 packets of 64 bytes (usb-device's default is 8): the whole 9-byte
    // configuration descriptor header fits one packet, which full-speed
    // hosts (and the rp2040js USB host the CI harness uses) expect.
    Ok(UsbDeviceBuilder::new(bus, USB_VID_PID)
        .strings(&[strings])?
        .max_packet_size_0(64)?
        .device_class(USB_CLASS_CDC)
        .build())
}

/// The CDC-ACM endpoints and the reply queue; the USB device it belongs to
/// is passed to every call (and polls the link as its only class).
pub struct Link<'a, B: UsbBus> {
    class: CdcAcmClass<'a, B>,
    tx: TxQueue<TX_QUEUE_LEN>,
    /// Full packets written since the last short one: while not 0, the
    /// transfer is open and the next packet, if the queue is empty, is a
    /// zero-length one.
    full_run: u32,
    /// A control request or a bus reset came since
    /// [`Self::take_control_seen`] last looked.
    control_seen: bool,
    /// DTR as the host last set it.
    dtr: bool,
    /// DTR fell and no new session began since: replies are dropped.
    closed: bool,
    /// DTR rose since [`Self::take_new_session`] last looked.
    new_session: bool,
}

/// Whether the host has configured the device (enumeration is over).
pub fn configured<B: UsbBus>(usb: &UsbDevice<'_, B>) -> bool {
    usb.state() == UsbDeviceState::Configured
}

impl<'a, B: UsbBus> Link<'a, B> {
    /// Allocates the CDC-ACM endpoints (bulk packets of [`PACKET_LEN`]) on `bus`.
    pub fn new(bus: &'a UsbBusAllocator<B>) -> Self {
        Link {
            class: CdcAcmClass::new(bus, PACKET_LEN as u16),
            tx: TxQueue::new(),
            full_run: 0,
            control_seen: false,
            dtr: false,
            closed: false,
            new_session: false,
        }
    }

    /// Whether a host session began (DTR rose) since the last call: the
    /// caller drops the partial input an earlier one may have left.
    pub fn take_new_session(&mut self) -> bool {
        core::mem::take(&mut self.new_session)
    }

    /// Follows DTR after a SET_CONTROL_LINE_STATE (see the module doc).
    /// Only that request moves it: a bus reset clears the class's line
    /// state until the host sets it again, and is no new session.
    fn follow_dtr(&mut self) {
        let dtr = self.class.dtr();
        if dtr == self.dtr {
            return;
        }
        self.dtr = dtr;
        // Whatever is queued belongs to the session that ended, or to one
        // before the session that begins.
        self.tx.pop(usize::MAX);
        self.full_run = 0;
        self.closed = !dtr;
        if dtr {
            self.new_session = true;
            self.tx.push(&[0]);
        }
    }

    /// Whether a control request (every one, standard ones included, passes
    /// through the class first) or a bus reset came since the last call:
    /// the host may be enumerating, and more requests follow closely.
    pub fn take_control_seen(&mut self) -> bool {
        core::mem::take(&mut self.control_seen)
    }

    /// Services the USB device (enumeration, control requests, endpoint
    /// events) and moves queued reply bytes on.
    pub fn poll(&mut self, usb: &mut UsbDevice<'a, B>) {
        self.service(usb);
        self.drain(usb);
    }

    /// [`Self::poll`]'s first half: services the USB device only (control
    /// requests, bus events; a packet the host took lets the next one go),
    /// so that a caller can time it apart from sending replies. Received
    /// packets stay in the controller until [`Self::read`].
    pub fn service(&mut self, usb: &mut UsbDevice<'a, B>) {
        usb.poll(&mut [&mut *self]);
    }

    /// [`Self::poll`]'s second half: writes reply packets while the IN
    /// endpoint takes them (on the RP2040 it holds one).
    pub fn drain(&mut self, usb: &UsbDevice<'a, B>) {
        if (!self.tx.is_empty() || self.full_run != 0) && configured(usb) {
            while self.write_next() {}
        }
    }

    /// Writes one packet from the queue (a zero-length one to end a transfer
    /// whose last packet was full, once the queue is empty) unless the
    /// endpoint still holds the last one (`WouldBlock`: the queue keeps
    /// its bytes). True if a packet went.
    fn write_next(&mut self) -> bool {
        let max = if self.full_run >= SHORT_PACKET_INTERVAL {
            PACKET_LEN - 1
        } else {
            PACKET_LEN
        };
        let mut scratch = [0u8; PACKET_LEN];
        let packet = self.tx.front(max, &mut scratch);
        if packet.is_empty() && self.full_run == 0 {
            return false;
        }
        // `WouldBlock` is the only error of an allocated endpoint with a
        // packet that fits; anything else is retried on the next call.
        let Ok(n) = self.class.write_packet(packet) else {
            return false;
        };
        if n == 0 && !packet.is_empty() {
            // Taken as nothing (a bus whose buffer is full says so rather
            // than `WouldBlock`): not sent, or `drain` would spin on it.
            return false;
        }
        self.tx.pop(n);
        self.full_run = if n == PACKET_LEN {
            self.full_run + 1
        } else {
            0
        };
        true
    }

    /// Polls USB until every reply byte queued so far is in the USB
    /// controller's buffer (which it sends by itself, even while the CPU
    /// is stalled by a flash erase) and the transfer is ended, or
    /// [`FLUSH_POLLS`] polls have passed (a host that does not read). True
    /// if it all went.
    pub fn flush(&mut self, usb: &mut UsbDevice<'a, B>) -> bool {
        for _ in 0..FLUSH_POLLS {
            if self.tx.is_empty() && self.full_run == 0 {
                return true;
            }
            crate::watchdog::feed();
            self.poll(usb);
        }
        false
    }

    /// Reads the packet the host sent, if any, into the start of `buf` (at
    /// least [`PACKET_LEN`] bytes, or a full packet stays where it is) and
    /// returns its length: 0 unless configured, a packet waiting and the
    /// queue has [`RX_HEADROOM`] free (backpressure). Reading needs no
    /// [`Self::service`] first: the controller holds the packet.
    pub fn read(&mut self, usb: &UsbDevice<'a, B>, buf: &mut [u8]) -> usize {
        if self.tx.free() < RX_HEADROOM || !configured(usb) {
            return 0;
        }
        let n = self.class.read_packet(buf).unwrap_or(0);
        if n > 0 {
            // A host writing is a host reading, whatever DTR says (one
            // that dropped it and never raises it again).
            self.closed = false;
        }
        n
    }

    /// Queues one reply frame, waiting (and polling USB) while the queue is
    /// full. A USB bus reset meanwhile keeps the queue: the host's decoder
    /// resynchronises on the next frame delimiter. While the host has the
    /// port closed (DTR fell) the frame is dropped, and so is the rest of
    /// one it closes the port during.
    pub fn send(&mut self, usb: &mut UsbDevice<'a, B>, frame: &[u8]) {
        let mut rest = frame;
        loop {
            if self.closed {
                return;
            }
            let n = self.tx.push(rest);
            rest = rest.get(n..).unwrap_or_default();
            if rest.is_empty() {
                break;
            }
            // Waiting for a host that reads slowly (back-pressure) is no
            // hang: DTR falling, or the host reading, ends it.
            crate::watchdog::feed();
            self.poll(usb);
        }
        self.drain(usb);
    }
}

/// The link is the device's class: every request goes to the CDC-ACM class
/// unchanged; a packet the host took from the IN endpoint lets the next one
/// go at once.
impl<B: UsbBus> UsbClass<B> for Link<'_, B> {
    fn get_configuration_descriptors(
        &self,
        writer: &mut DescriptorWriter,
    ) -> usb_device::Result<()> {
        self.class.get_configuration_descriptors(writer)
    }

    fn get_bos_descriptors(&self, writer: &mut BosWriter) -> usb_device::Result<()> {
        self.class.get_bos_descriptors(writer)
    }

    fn get_string(&self, index: StringIndex, lang_id: LangID) -> Option<&str> {
        self.class.get_string(index, lang_id)
    }

    fn reset(&mut self) {
        // The queue stays; the packet in flight went with the reset.
        self.full_run = 0;
        self.control_seen = true;
        self.class.reset();
    }

    fn poll(&mut self) {
        UsbClass::<B>::poll(&mut self.class);
    }

    fn control_out(&mut self, xfer: ControlOut<B>) {
        self.control_seen = true;
        let request = xfer.request();
        let line_state =
            request.request_type == RequestType::Class && request.request == SET_CONTROL_LINE_STATE;
        self.class.control_out(xfer);
        if line_state {
            self.follow_dtr();
        }
    }

    fn control_in(&mut self, xfer: ControlIn<B>) {
        self.control_seen = true;
        self.class.control_in(xfer);
    }

    fn endpoint_setup(&mut self, addr: EndpointAddress) {
        self.class.endpoint_setup(addr);
    }

    fn endpoint_out(&mut self, addr: EndpointAddress) {
        self.class.endpoint_out(addr);
    }

    fn endpoint_in_complete(&mut self, addr: EndpointAddress) {
        if addr == self.class.write_ep().address() {
            self.write_next();
        } else {
            self.class.endpoint_in_complete(addr);
        }
    }

    fn get_alt_setting(&mut self, interface: InterfaceNumber) -> Option<u8> {
        self.class.get_alt_setting(interface)
    }

    fn set_alt_setting(&mut self, interface: InterfaceNumber, alternative: u8) -> bool {
        self.class.set_alt_setting(interface, alternative)
    }
}
