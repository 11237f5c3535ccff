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

use heapless::Deque;
use placedb::protocol::MAX_REPLY_LEN;
use usb_device::bus::UsbBus;
use usb_device::device::{UsbDevice, UsbDeviceState};
use usbd_serial::SerialPort;

/// Reply bytes that can wait for the host: 16 frames of the longest kind.
pub const TX_QUEUE_LEN: usize = 16 * MAX_REPLY_LEN;
/// Input is read only while at least this much of the queue is free (8 longest
/// replies), so the replies to it usually fit without waiting.
const RX_HEADROOM: usize = 8 * MAX_REPLY_LEN;

/// USB device, its CDC-ACM serial port and the reply queue.
pub struct Link<'a, B: UsbBus> {
    usb: UsbDevice<'a, B>,
    serial: SerialPort<'a, B>,
    tx: Deque<u8, TX_QUEUE_LEN>,
}

impl<'a, B: UsbBus> Link<'a, B> {
    pub fn new(usb: UsbDevice<'a, B>, serial: SerialPort<'a, B>) -> Self {
        Link {
            usb,
            serial,
            tx: Deque::new(),
        }
    }

    fn configured(&self) -> bool {
        self.usb.state() == UsbDeviceState::Configured
    }

    /// Services the USB device (enumeration, control requests, endpoint
    /// events) and moves queued reply bytes to the serial port.
    pub fn poll(&mut self) {
        self.usb.poll(&mut [&mut self.serial]);
        self.drain();
    }

    /// Hands the serial port as much of the queue as it takes.
    fn drain(&mut self) {
        while self.configured() {
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

    /// Reads what the host sent into `buf`: 0 bytes unless configured, data
    /// waiting and the queue has [`RX_HEADROOM`] free (backpressure).
    pub fn read(&mut self, buf: &mut [u8]) -> usize {
        if !self.configured() || TX_QUEUE_LEN - self.tx.len() < RX_HEADROOM {
            return 0;
        }
        self.serial.read(buf).unwrap_or(0)
    }

    /// Queues one reply frame, waiting (and polling USB) while the queue is
    /// full. A USB bus reset meanwhile keeps the queue: the host's decoder
    /// resynchronises on the next frame delimiter.
    pub fn send(&mut self, frame: &[u8]) {
        for &byte in frame {
            let mut byte = byte;
            while let Err(back) = self.tx.push_back(byte) {
                byte = back;
                self.poll();
            }
        }
        self.drain();
    }
}
