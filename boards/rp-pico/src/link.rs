//! The byte link to the host: a polled USB CDC-ACM serial port with a queue of
//! reply bytes and backpressure.
//!
//! `SerialPort::write` takes only what fits its 128-byte buffer (or nothing:
//! `WouldBlock`) and the host reads when it likes, so reply frames go into a
//! fixed queue first and [`Link::poll`] moves them on as the host takes them.
//! Nothing is dropped: a reply that finds the queue full waits, still polling
//! USB, until there is room; and input is read only while the queue has room
//! for a whole frame, so a host that does not read stops being read from (its
//! writes are NAKed once usbd-serial's receive buffer is full). One request
//! may be answered by many frames (an export streams a record per frame): the
//! device then waits inside `receive` for the host to read.
//!
//! Nothing here depends on the RP2040: the link is generic over
//! [`UsbBus`], and the [`UsbDevice`] is the caller's (every method takes it),
//! so host tests (`host/tests/usb_link.rs`) drive this file over emulated
//! buses, with the descriptors of [`device`].

use heapless::Deque;
use placedb::protocol::MAX_REPLY_LEN;
use usb_device::bus::{InterfaceNumber, StringIndex, UsbBus, UsbBusAllocator};
use usb_device::class::{ControlIn, ControlOut, UsbClass};
use usb_device::descriptor::{BosWriter, DescriptorWriter};
use usb_device::device::{
    StringDescriptors, UsbDevice, UsbDeviceBuilder, UsbDeviceState, UsbVidPid,
};
use usb_device::endpoint::EndpointAddress;
use usb_device::prelude::BuilderError;
use usb_device::LangID;
use usbd_serial::{SerialPort, USB_CLASS_CDC};

/// Reply bytes that can wait for the host: 16 frames of the longest kind.
pub const TX_QUEUE_LEN: usize = 16 * MAX_REPLY_LEN;
/// Input is read only while at least this much of the queue is free (8 longest
/// replies), so the replies to it usually fit without waiting.
pub const RX_HEADROOM: usize = 8 * MAX_REPLY_LEN;

/// Most polls [`Link::flush`] waits for the host to take the queued
/// replies: some tens of milliseconds of polling on the Pico, far more than
/// the few 1 ms USB frames a reply of a few packets needs from a host that
/// reads, and a bound on the wait for one that does not.
pub const FLUSH_POLLS: u32 = 20_000;

/// Shared VID/PID for CDC-ACM test devices (not for products).
pub const USB_VID_PID: UsbVidPid = UsbVidPid(0x16c0, 0x27dd);
pub const MANUFACTURER: &str = "placedb";
pub const PRODUCT: &str = "placedb device";
pub const SERIAL_NUMBER: &str = "0001";

/// The firmware's USB device on `bus`: [`USB_VID_PID`], the strings above,
/// device class CDC and EP0 packets of 64 bytes. Call it after [`Link::new`]
/// (usb-device allocates the class's endpoints first).
pub fn device<B: UsbBus>(bus: &UsbBusAllocator<B>) -> Result<UsbDevice<'_, B>, BuilderError> {
    let strings = StringDescriptors::default()
        .manufacturer(MANUFACTURER)
        .product(PRODUCT)
        .serial_number(SERIAL_NUMBER);
    // EP0 packets of 64 bytes (usb-device's default is 8): the whole 9-byte
    // configuration descriptor header fits one packet, which full-speed
    // hosts (and the rp2040js USB host the CI harness uses) expect.
    Ok(UsbDeviceBuilder::new(bus, USB_VID_PID)
        .strings(&[strings])?
        .max_packet_size_0(64)?
        .device_class(USB_CLASS_CDC)
        .build())
}

/// The CDC-ACM serial port and the reply queue; the USB device it belongs to
/// is passed to every call (and polls the link as its only class).
pub struct Link<'a, B: UsbBus> {
    serial: SerialPort<'a, B>,
    tx: Deque<u8, TX_QUEUE_LEN>,
}

fn configured<B: UsbBus>(usb: &UsbDevice<'_, B>) -> bool {
    usb.state() == UsbDeviceState::Configured
}

impl<'a, B: UsbBus> Link<'a, B> {
    /// Allocates the serial port's endpoints on `bus`.
    pub fn new(bus: &'a UsbBusAllocator<B>) -> Self {
        Link {
            serial: SerialPort::new(bus),
            tx: Deque::new(),
        }
    }

    /// Services the USB device (enumeration, control requests, endpoint
    /// events) and moves queued reply bytes to the serial port.
    pub fn poll(&mut self, usb: &mut UsbDevice<'a, B>) {
        self.service(usb);
        self.drain(usb);
    }

    /// [`Self::poll`]'s first half: services the USB device only (where a
    /// received packet is taken from the controller), so that a caller can
    /// time it apart from sending replies.
    pub fn service(&mut self, usb: &mut UsbDevice<'a, B>) {
        usb.poll(&mut [&mut *self]);
    }

    /// [`Self::poll`]'s second half: hands the serial port as much of the
    /// queue as it takes.
    pub fn drain(&mut self, usb: &UsbDevice<'a, B>) {
        while configured(usb) {
            let (head, _) = self.tx.as_slices();
            if head.is_empty() {
                break;
            }
            match self.serial.write(head) {
                Ok(n) => {
                    for _ in 0..n {
                        self.tx.pop_front();
                    }
                }
                // `WouldBlock`: its buffer is full until the host reads. (The
                // RP2040 bus returns no other error for a packet of an
                // allocated endpoint; anything else is retried next poll.)
                Err(_) => break,
            }
        }
    }

    /// Polls USB until every reply byte queued so far is in the USB
    /// controller's buffers (which it sends by itself, even while the CPU
    /// is stalled by a flash erase), or [`FLUSH_POLLS`] polls have passed (a
    /// host that does not read). True if it all went.
    pub fn flush(&mut self, usb: &mut UsbDevice<'a, B>) -> bool {
        for _ in 0..FLUSH_POLLS {
            if self.tx.is_empty() && self.serial.flush().is_ok() {
                return true;
            }
            self.poll(usb);
        }
        false
    }

    /// Reads what the host sent into `buf`: 0 bytes unless configured, data
    /// waiting and the queue has [`RX_HEADROOM`] free (backpressure).
    pub fn read(&mut self, usb: &UsbDevice<'a, B>, buf: &mut [u8]) -> usize {
        if !configured(usb) || TX_QUEUE_LEN - self.tx.len() < RX_HEADROOM {
            return 0;
        }
        self.serial.read(buf).unwrap_or(0)
    }

    /// Queues one reply frame, waiting (and polling USB) while the queue is
    /// full. A USB bus reset meanwhile keeps the queue: the host's decoder
    /// resynchronises on the next frame delimiter.
    pub fn send(&mut self, usb: &mut UsbDevice<'a, B>, frame: &[u8]) {
        for &byte in frame {
            let mut byte = byte;
            while let Err(back) = self.tx.push_back(byte) {
                byte = back;
                self.poll(usb);
            }
        }
        self.drain(usb);
    }
}

/// The link is the device's class: every request and endpoint event goes to
/// the serial port unchanged (the queue only feeds it from [`Link::drain`]).
impl<B: UsbBus> UsbClass<B> for Link<'_, B> {
    fn get_configuration_descriptors(
        &self,
        writer: &mut DescriptorWriter,
    ) -> usb_device::Result<()> {
        self.serial.get_configuration_descriptors(writer)
    }

    fn get_bos_descriptors(&self, writer: &mut BosWriter) -> usb_device::Result<()> {
        self.serial.get_bos_descriptors(writer)
    }

    fn get_string(&self, index: StringIndex, lang_id: LangID) -> Option<&str> {
        self.serial.get_string(index, lang_id)
    }

    fn reset(&mut self) {
        self.serial.reset();
    }

    fn poll(&mut self) {
        UsbClass::<B>::poll(&mut self.serial);
    }

    fn control_out(&mut self, xfer: ControlOut<B>) {
        self.serial.control_out(xfer);
    }

    fn control_in(&mut self, xfer: ControlIn<B>) {
        self.serial.control_in(xfer);
    }

    fn endpoint_setup(&mut self, addr: EndpointAddress) {
        self.serial.endpoint_setup(addr);
    }

    fn endpoint_out(&mut self, addr: EndpointAddress) {
        self.serial.endpoint_out(addr);
    }

    fn endpoint_in_complete(&mut self, addr: EndpointAddress) {
        self.serial.endpoint_in_complete(addr);
    }

    fn get_alt_setting(&mut self, interface: InterfaceNumber) -> Option<u8> {
        self.serial.get_alt_setting(interface)
    }

    fn set_alt_setting(&mut self, interface: InterfaceNumber, alternative: u8) -> bool {
        self.serial.set_alt_setting(interface, alternative)
    }
}
