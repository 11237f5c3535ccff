//! The Pico firmware's USB link (`boards/rp-pico/src/link.rs`, compiled here
//! for the host) driven as a USB host would drive it.
//!
//! usbd-class-tester (its `EmulatedUsbBus` and host-side `Device`) checks
//! enumeration, the descriptors, CDC line coding and bulk bytes both ways.
//! Its bus cannot show backpressure: an IN endpoint there takes packet after
//! packet (up to 1 KiB, then silently drops them), so a host that stops
//! reading never makes the device wait. For that, [`Wire`] is a bus with a
//! scripted host where, as on the RP2040, an endpoint holds one packet at a
//! time: a write while the host has not taken the last packet is
//! `WouldBlock`, and packets the host sends wait on the host side (NAKed)
//! until the device reads them (the link reads them straight from the
//! endpoint: there is no buffer between).

#[path = "../../boards/rp-pico/src/link.rs"]
mod link;

/// The firmware's watchdog, as `link.rs` sees it: here it counts the
/// feeds, so that a test sees a wait for the host feed it.
mod watchdog {
    use std::sync::atomic::{AtomicUsize, Ordering};

    pub static FEEDS: AtomicUsize = AtomicUsize::new(0);

    pub fn feed() {
        FEEDS.fetch_add(1, Ordering::Relaxed);
    }
}

use link::{Link, FLUSH_POLLS, RX_HEADROOM, SHORT_PACKET_INTERVAL, TX_QUEUE_LEN};
use placedb::protocol::MAX_REPLY_LEN;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};
use usb_device::bus::{PollResult, UsbBus, UsbBusAllocator};
use usb_device::device::{UsbDevice, UsbDeviceState};
use usb_device::endpoint::{EndpointAddress, EndpointType};
use usb_device::{UsbDirection, UsbError};
use usbd_class_tester::prelude::*;

/// The firmware's class and device (VID/PID, strings, EP0 size) on the
/// emulated bus.
struct Pico;

/// The flash unique ID the tests' board reports (as the chip sends it).
const ID: [u8; 8] = [0x01, 0x23, 0x45, 0x67, 0x89, 0xAB, 0xCD, 0xEF];

impl UsbDeviceCtx for Pico {
    type C<'c> = Link<'c, EmulatedUsbBus>;

    fn create_class<'a>(
        &mut self,
        alloc: &'a UsbBusAllocator<EmulatedUsbBus>,
    ) -> AnyResult<Link<'a, EmulatedUsbBus>> {
        Ok(Link::new(alloc))
    }

    fn build_usb_device<'a>(
        &mut self,
        alloc: &'a UsbBusAllocator<EmulatedUsbBus>,
    ) -> AnyResult<UsbDevice<'a, EmulatedUsbBus>> {
        // The serial number lives as long as the test's bus (leaked: a few
        // bytes per test).
        let serial: &'static link::SerialNumber = Box::leak(Box::new(link::SerialNumber::new(ID)));
        link::device(alloc, serial.as_str()).map_err(AnyUsbError::UsbDeviceBuilder)
    }
}

type Host<'a> = Device<'a, Link<'a, EmulatedUsbBus>, Pico>;

/// The descriptors in a configuration descriptor, each with its type first.
fn split(config: &[u8]) -> Vec<&[u8]> {
    let mut out = Vec::new();
    let mut rest = config;
    while !rest.is_empty() {
        let len = usize::from(rest[0]);
        assert!(len >= 2 && len <= rest.len(), "bad descriptor length {len}");
        out.push(&rest[1..len]);
        rest = &rest[len..];
    }
    out
}

fn config_descriptor<'a>(link: &mut Link<'a, EmulatedUsbBus>, host: &mut Host<'a>) -> Vec<u8> {
    let head = host.device_get_descriptor(link, 2, 0, 0, 9).unwrap();
    let total = u16::from_le_bytes([head[2], head[3]]);
    let config = host.device_get_descriptor(link, 2, 0, 0, total).unwrap();
    assert_eq!(config.len(), usize::from(total));
    config
}

/// (endpoint address, transfer type bits, max packet size) of every endpoint.
fn endpoints(config: &[u8]) -> Vec<(u8, u8, u16)> {
    split(config)
        .into_iter()
        .filter(|d| d[0] == 5)
        .map(|d| (d[1], d[2] & 3, u16::from_le_bytes([d[3], d[4]])))
        .collect()
}

/// Endpoint indices of the bulk OUT (host to device) and bulk IN endpoints.
fn bulk_endpoints(config: &[u8]) -> (usize, usize) {
    let eps = endpoints(config);
    let find = |dir: u8| {
        let ep = eps.iter().find(|e| e.1 == 2 && e.0 & 0x80 == dir).unwrap();
        usize::from(ep.0 & 0x0f)
    };
    (find(0x00), find(0x80))
}

fn check_descriptors<'a>(mut link: Link<'a, EmulatedUsbBus>, mut host: Host<'a>) {
    // The tester enumerated the device (address, configuration 1).
    assert_eq!(host.usb_dev().state(), UsbDeviceState::Configured);
    assert_eq!(host.device_get_configuration(&mut link).unwrap(), 1);

    let dev = host.device_get_descriptor(&mut link, 1, 0, 0, 18).unwrap();
    assert_eq!(dev.len(), 18);
    assert_eq!(&dev[..2], &[18, 1]);
    assert_eq!(dev[4], 0x02, "device class CDC");
    assert_eq!(dev[7], 64, "EP0 max packet size");
    assert_eq!(u16::from_le_bytes([dev[8], dev[9]]), 0x16c0);
    assert_eq!(u16::from_le_bytes([dev[10], dev[11]]), 0x27dd);
    assert_eq!(dev[17], 1, "one configuration");
    let lang = 0x0409;
    let strings: Vec<String> = dev[14..17]
        .iter()
        .map(|&i| host.device_get_string(&mut link, i, lang).unwrap())
        .collect();
    assert_eq!(
        strings,
        [
            "placedb",
            "placedb device",
            "placedb.example:0123456789ABCDEF"
        ]
    );

    let config = config_descriptor(&mut link, &mut host);
    assert_eq!(config[1], 2);
    assert_eq!(config[4], 2, "two interfaces");
    let descs = split(&config);
    // Interfaces: (number, class, subclass, protocol, endpoints).
    let interfaces: Vec<[u8; 5]> = descs
        .iter()
        .filter(|d| d[0] == 4)
        .map(|d| [d[1], d[4], d[5], d[6], d[3]])
        .collect();
    assert_eq!(
        interfaces,
        [[0, 0x02, 0x02, 0x00, 1], [1, 0x0a, 0x00, 0x00, 2]],
        "CDC ACM communication interface (1 endpoint) and CDC data interface (2)"
    );
    // CDC functional descriptors: header 1.10, ACM, union 0 -> 1, call
    // management with data interface 1.
    let functional: Vec<&[u8]> = descs.iter().copied().filter(|d| d[0] == 0x24).collect();
    assert_eq!(
        functional,
        [
            &[0x24, 0x00, 0x10, 0x01][..],
            &[0x24, 0x02, 0x00],
            &[0x24, 0x06, 0, 1],
            &[0x24, 0x01, 0x00, 1]
        ]
    );
    let mut eps = endpoints(&config);
    eps.sort();
    let (out_ep, in_ep) = bulk_endpoints(&config);
    let (out_ep, in_ep) = (out_ep as u8, in_ep as u8 | 0x80);
    let notify = eps.iter().find(|e| e.1 == 3).unwrap().0;
    assert!(notify & 0x80 != 0, "notification endpoint is IN");
    let mut want = vec![(notify, 3, 8), (out_ep, 2, 64), (in_ep, 2, 64)];
    want.sort();
    assert_eq!(eps, want, "interrupt IN (8 bytes), bulk OUT and IN (64)");
}

#[test]
fn descriptors() {
    Pico.with_usb(check_descriptors).unwrap();
}

/// CDC class requests to the communication interface (0).
const SET_LINE_CODING: u8 = 0x20;
const GET_LINE_CODING: u8 = 0x21;
const SET_CONTROL_LINE_STATE: u8 = 0x22;

fn check_line_coding<'a>(mut link: Link<'a, EmulatedUsbBus>, mut host: Host<'a>) {
    let to_device = CtrRequestType::to_device().class().interface();
    let to_host = CtrRequestType::to_host().class().interface();
    // usbd-serial's default: 9600 baud, 1 stop bit, no parity, 8 data bits.
    let coding = host
        .control_read(&mut link, to_host, GET_LINE_CODING, 0, 0, 7)
        .unwrap();
    assert_eq!(coding, [0x80, 0x25, 0, 0, 0, 0, 8]);

    // 115200 baud, 2 stop bits, even parity, 7 data bits.
    let set = [0x00, 0xc2, 0x01, 0x00, 2, 2, 7];
    let reply = host
        .control_write(&mut link, to_device, SET_LINE_CODING, 0, 0, 7, &set)
        .unwrap();
    assert!(reply.is_empty());
    let coding = host
        .control_read(&mut link, to_host, GET_LINE_CODING, 0, 0, 7)
        .unwrap();
    assert_eq!(coding, set);

    // DTR and RTS up (what a host's open() sends) is accepted.
    host.control_write(&mut link, to_device, SET_CONTROL_LINE_STATE, 3, 0, 0, &[])
        .unwrap();
    // Control requests are seen (the firmware erases nothing for a while
    // after one), and told once.
    assert!(link.take_control_seen());
    assert!(!link.take_control_seen());
    // Requests for another interface or unknown CDC requests are stalled.
    assert_eq!(
        host.control_read(&mut link, to_host, GET_LINE_CODING, 0, 1, 7),
        Err(AnyUsbError::EP0Stalled)
    );
    assert_eq!(
        host.control_read(&mut link, to_host, 0x01, 0, 0, 8),
        Err(AnyUsbError::EP0Stalled)
    );

    // The line coding has no effect on the data: bytes pass unchanged.
    let config = config_descriptor(&mut link, &mut host);
    let (out_ep, in_ep) = bulk_endpoints(&config);
    let data: Vec<u8> = (0..=255).collect();
    assert_eq!(host.ep_write(&mut link, out_ep, &data).unwrap(), 256);
    let got = device_read(&mut link, &mut host, data.len());
    assert_eq!(got, data);
    link.send(host.usb_dev(), &data);
    // DTR rose above (a host session began): a lone delimiter went first.
    assert_eq!(
        host.ep_read(&mut link, in_ep, 1024).unwrap(),
        [&[0u8][..], &data[..]].concat()
    );
    // The descriptor read was one; bulk data is none.
    assert!(link.take_control_seen());
    assert_eq!(host.ep_write(&mut link, out_ep, &data).unwrap(), 256);
    assert_eq!(device_read(&mut link, &mut host, data.len()), data);
    assert!(
        !link.take_control_seen(),
        "bulk data is not a control request"
    );
}

#[test]
fn line_coding() {
    Pico.with_usb(check_line_coding).unwrap();
}

/// What the firmware's main loop reads (64 bytes a turn) until `len` bytes
/// arrived or a turn finds nothing.
fn device_read<'a>(
    link: &mut Link<'a, EmulatedUsbBus>,
    host: &mut Host<'a>,
    len: usize,
) -> Vec<u8> {
    let mut got = Vec::new();
    let mut rx = [0u8; 64];
    while got.len() < len {
        link.poll(host.usb_dev());
        let n = link.read(host.usb_dev(), &mut rx);
        if n == 0 {
            break;
        }
        got.extend_from_slice(&rx[..n]);
    }
    got
}

fn check_bulk<'a>(mut link: Link<'a, EmulatedUsbBus>, mut host: Host<'a>) {
    let config = config_descriptor(&mut link, &mut host);
    let (out_ep, in_ep) = bulk_endpoints(&config);

    // Host to device: 5 packets and a short one, read 64 bytes a turn.
    let request: Vec<u8> = (0..300u32).map(|i| (i * 7 + 3) as u8).collect();
    assert_eq!(host.ep_write(&mut link, out_ep, &request).unwrap(), 300);
    assert_eq!(device_read(&mut link, &mut host, 1000), request);
    // Nothing more is read.
    assert!(device_read(&mut link, &mut host, 1).is_empty());

    // Device to host: two reply frames, the bytes in order, nothing more.
    let frame_a: Vec<u8> = (0..MAX_REPLY_LEN).map(|i| (i % 255 + 1) as u8).collect();
    let frame_b = [1u8, 2, 3, 0];
    link.send(host.usb_dev(), &frame_a);
    link.send(host.usb_dev(), &frame_b);
    let got = host.ep_read(&mut link, in_ep, 1024).unwrap();
    assert_eq!(got, [&frame_a[..], &frame_b[..]].concat());
    link.poll(host.usb_dev());
    assert!(host.ep_read(&mut link, in_ep, 1024).unwrap().is_empty());

    // Both ways at once: a request in flight while a reply goes out.
    host.ep_write(&mut link, out_ep, &frame_b).unwrap();
    link.send(host.usb_dev(), &request[..100]);
    assert_eq!(device_read(&mut link, &mut host, 4), frame_b);
    assert_eq!(
        host.ep_read(&mut link, in_ep, 1024).unwrap(),
        &request[..100]
    );
}

#[test]
fn bulk_both_ways() {
    Pico.with_usb(check_bulk).unwrap();
}

/// SET_CONTROL_LINE_STATE with DTR (bit 0) and RTS (bit 1) as `dtr` says:
/// what a host sends when a program opens (true) or closes (false) the port.
fn set_dtr<'a>(link: &mut Link<'a, EmulatedUsbBus>, host: &mut Host<'a>, dtr: bool) {
    let to_device = CtrRequestType::to_device().class().interface();
    let value = if dtr { 3 } else { 0 };
    host.control_write(link, to_device, SET_CONTROL_LINE_STATE, value, 0, 0, &[])
        .unwrap();
}

/// Host sessions (issue 40): a host that never raises DTR is answered as
/// ever; when DTR falls (the port closed) the queued replies and later ones
/// are dropped, and the device never waits for a reader that is gone; when
/// it rises (the port opened again) the new session gets no reply of an
/// earlier one, only a lone delimiter ending whatever part of one the
/// controller still held, and the caller is told to drop its partial input.
fn check_sessions<'a>(mut link: Link<'a, EmulatedUsbBus>, mut host: Host<'a>) {
    let config = config_descriptor(&mut link, &mut host);
    let (out_ep, in_ep) = bulk_endpoints(&config);
    let reply = |tag: u8| -> Vec<u8> { vec![tag; 40].into_iter().chain([0]).collect() };

    // DTR never raised: replies go as ever, no session is announced.
    link.send(host.usb_dev(), &reply(1));
    assert_eq!(host.ep_read(&mut link, in_ep, 1024).unwrap(), reply(1));
    assert!(!link.take_new_session());

    // The port opened: a delimiter, then the session's replies.
    set_dtr(&mut link, &mut host, true);
    assert!(link.take_new_session());
    assert!(!link.take_new_session());
    link.send(host.usb_dev(), &reply(2));
    assert_eq!(
        host.ep_read(&mut link, in_ep, 1024).unwrap(),
        [&[0u8][..], &reply(2)].concat()
    );

    // Replies the program did not read when it closed the port: what the
    // controller took (this emulated bus takes up to 1 KiB; the RP2040 one
    // packet), the rest queued. Closed, the queue is dropped and nothing
    // more is queued, however much (more than the queue holds: a send that
    // waited for a reader would never return).
    let unread = 40 * reply(3).len();
    for _ in 0..40 {
        link.send(host.usb_dev(), &reply(3));
    }
    set_dtr(&mut link, &mut host, false);
    for _ in 0..2 * TX_QUEUE_LEN / reply(4).len() {
        link.send(host.usb_dev(), &reply(4));
    }
    // Opened again: what the controller held, a delimiter ending it, and
    // nothing of what stayed queued or was sent while the port was closed.
    set_dtr(&mut link, &mut host, true);
    assert!(link.take_new_session());
    let stale = host.ep_read(&mut link, in_ep, 4096).unwrap();
    assert!(
        stale.len() <= 1024 + 1 && stale.len() < unread,
        "{} bytes of the {unread} unread went to the new session",
        stale.len()
    );
    assert_eq!(
        stale.last(),
        Some(&0),
        "no delimiter after the stale packet"
    );
    assert!(
        !stale.contains(&4),
        "a reply sent while the port was closed went out"
    );
    link.send(host.usb_dev(), &reply(5));
    assert_eq!(host.ep_read(&mut link, in_ep, 1024).unwrap(), reply(5));

    // A program that drops DTR and then writes is a reader again.
    set_dtr(&mut link, &mut host, false);
    host.ep_write(&mut link, out_ep, &[9, 9, 0]).unwrap();
    assert_eq!(device_read(&mut link, &mut host, 3), [9, 9, 0]);
    link.send(host.usb_dev(), &reply(6));
    assert_eq!(host.ep_read(&mut link, in_ep, 1024).unwrap(), reply(6));
}

#[test]
fn host_sessions_follow_dtr() {
    Pico.with_usb(check_sessions).unwrap();
}

/// A full-speed USB bus and a scripted host: every endpoint holds one packet,
/// the host takes a waiting IN packet (one per endpoint) at each poll while
/// it reads, and its OUT packets wait until the device reads them.
#[derive(Default)]
struct Wire {
    /// (address, type, max packet size) of the allocated endpoints.
    alloc: Vec<(EndpointAddress, EndpointType, u16)>,
    setup: Option<[u8; 8]>,
    /// The packet the device wrote on IN endpoint i, until the host takes it.
    in_packet: [Option<Vec<u8>>; 16],
    /// Packets the host sends to OUT endpoint i, NAKed until read.
    out_packets: [VecDeque<Vec<u8>>; 16],
    /// IN endpoints whose packet the host took since the last poll.
    in_complete: u16,
    stalled: Vec<EndpointAddress>,
    /// Whether the host takes IN packets of endpoints other than 0.
    reading: bool,
    /// Polls to wait before `reading` becomes true.
    start_reading_after: Option<u64>,
    /// Bytes the host took from the bulk IN endpoint.
    received: Vec<u8>,
    /// The length of every packet the host took from the bulk IN endpoint.
    in_lengths: Vec<usize>,
    polls: u64,
}

struct WireBus(Arc<Mutex<Wire>>);

impl WireBus {
    fn wire(&self) -> MutexGuard<'_, Wire> {
        self.0.lock().unwrap()
    }
}

impl UsbBus for WireBus {
    fn alloc_ep(
        &mut self,
        dir: UsbDirection,
        addr: Option<EndpointAddress>,
        ep_type: EndpointType,
        max_packet_size: u16,
        _interval: u8,
    ) -> usb_device::Result<EndpointAddress> {
        let mut w = self.wire();
        let taken = |w: &Wire, a: EndpointAddress| w.alloc.iter().any(|e| e.0 == a);
        let addr = match addr {
            Some(a) if taken(&w, a) => return Err(UsbError::InvalidEndpoint),
            Some(a) => a,
            None => (1..16)
                .map(|i| EndpointAddress::from_parts(i, dir))
                .find(|&a| !taken(&w, a))
                .ok_or(UsbError::EndpointOverflow)?,
        };
        w.alloc.push((addr, ep_type, max_packet_size));
        Ok(addr)
    }

    fn enable(&mut self) {}

    fn reset(&self) {}

    fn set_device_address(&self, _addr: u8) {}

    fn write(&self, ep: EndpointAddress, buf: &[u8]) -> usb_device::Result<usize> {
        let mut w = self.wire();
        let max = w.alloc.iter().find(|e| e.0 == ep).unwrap().2;
        if buf.len() > usize::from(max) {
            return Err(UsbError::BufferOverflow);
        }
        let slot = &mut w.in_packet[ep.index()];
        if slot.is_some() {
            return Err(UsbError::WouldBlock);
        }
        *slot = Some(buf.to_vec());
        Ok(buf.len())
    }

    fn read(&self, ep: EndpointAddress, buf: &mut [u8]) -> usb_device::Result<usize> {
        let mut w = self.wire();
        let packet = match (ep.index(), w.setup.take()) {
            (0, Some(setup)) => setup.to_vec(),
            (_, setup) => {
                w.setup = setup;
                w.out_packets[ep.index()]
                    .pop_front()
                    .ok_or(UsbError::WouldBlock)?
            }
        };
        let n = packet.len();
        buf.get_mut(..n)
            .ok_or(UsbError::BufferOverflow)?
            .copy_from_slice(&packet);
        Ok(n)
    }

    fn set_stalled(&self, ep: EndpointAddress, stalled: bool) {
        let mut w = self.wire();
        w.stalled.retain(|&a| a != ep);
        if stalled {
            w.stalled.push(ep);
        }
    }

    fn is_stalled(&self, ep: EndpointAddress) -> bool {
        self.wire().stalled.contains(&ep)
    }

    fn suspend(&self) {}

    fn resume(&self) {}

    fn poll(&self) -> PollResult {
        let mut w = self.wire();
        w.polls += 1;
        if w.start_reading_after.is_some_and(|n| w.polls > n) {
            w.reading = true;
            w.start_reading_after = None;
        }
        for i in 0..16 {
            if i != 0 && !w.reading {
                continue;
            }
            if let Some(packet) = w.in_packet[i].take() {
                if i != 0 {
                    w.received.extend_from_slice(&packet);
                    w.in_lengths.push(packet.len());
                }
                w.in_complete |= 1 << i;
            }
        }
        let ep_in_complete = std::mem::take(&mut w.in_complete);
        let ep_setup = u16::from(w.setup.is_some());
        let ep_out = (0..16)
            .filter(|&i| !w.out_packets[i].is_empty())
            .fold(ep_setup, |m, i| m | 1 << i);
        if ep_in_complete | ep_out | ep_setup == 0 {
            PollResult::None
        } else {
            PollResult::Data {
                ep_out,
                ep_in_complete,
                ep_setup,
            }
        }
    }
}

/// Index of the bulk endpoint allocated in direction `dir`.
fn bulk_index(wire: &Mutex<Wire>, dir: UsbDirection) -> usize {
    let w = wire.lock().unwrap();
    let ep = w
        .alloc
        .iter()
        .find(|e| e.1 == EndpointType::Bulk && e.0.direction() == dir);
    ep.unwrap().0.index()
}

/// Reply frame `i`: the longest kind, its bytes depending on `i`.
fn frame(i: usize) -> Vec<u8> {
    (0..MAX_REPLY_LEN)
        .map(|j| (i * 37 + j * 11) as u8)
        .collect()
}

/// Configures the link's device on `wire` (SET_CONFIGURATION 1).
fn configure<'a>(
    wire: &Mutex<Wire>,
    link: &mut Link<'a, WireBus>,
    usb: &mut UsbDevice<'a, WireBus>,
) {
    wire.lock().unwrap().setup = Some([0x00, 0x09, 1, 0, 0, 0, 0, 0]);
    for _ in 0..4 {
        link.poll(usb);
    }
    assert_eq!(usb.state(), UsbDeviceState::Configured);
}

/// Replies go out a packet at a time and every transfer ends with a short
/// packet: a zero-length one after a reply that ends on a full packet (a
/// CDC host sees a transfer's data only once it ends), one of 63 bytes
/// after `SHORT_PACKET_INTERVAL` (10) full ones in a row, so a long stream
/// is seen in good time. The endpoint holds one packet: the next waits in
/// the queue (`WouldBlock`) and none is lost.
#[test]
fn every_transfer_ends_with_a_short_packet() {
    let wire = Arc::new(Mutex::new(Wire::default()));
    let bus = UsbBusAllocator::new(WireBus(wire.clone()));
    let mut link = Link::new(&bus);
    let serial = link::SerialNumber::new(ID);
    let mut usb = link::device(&bus, serial.as_str()).unwrap();
    configure(&wire, &mut link, &mut usb);
    assert_eq!(SHORT_PACKET_INTERVAL, 10);
    wire.lock().unwrap().reading = true;
    let cases: [(usize, Vec<usize>); 6] = [
        (128, vec![64, 64, 0]),
        (100, vec![64, 36]),
        (64, vec![64, 0]),
        (1, vec![1]),
        (12 * 64, [vec![64; 10], vec![63, 64, 1]].concat()),
        (11 * 64 - 1, [vec![64; 10], vec![63]].concat()),
    ];
    for (i, (len, packets)) in cases.into_iter().enumerate() {
        let reply: Vec<u8> = (0..len).map(|j| (i * 31 + j) as u8).collect();
        {
            let mut w = wire.lock().unwrap();
            w.received.clear();
            w.in_lengths.clear();
        }
        link.send(&mut usb, &reply);
        for _ in 0..2 * packets.len() + 4 {
            link.poll(&mut usb);
        }
        let w = wire.lock().unwrap();
        assert_eq!(w.in_lengths, packets, "a reply of {len} bytes");
        assert_eq!(w.received, reply);
    }
}

#[test]
fn reply_queue_backpressure() {
    let wire = Arc::new(Mutex::new(Wire::default()));
    let bus = UsbBusAllocator::new(WireBus(wire.clone()));
    let mut link = Link::new(&bus);
    let serial = link::SerialNumber::new(ID);
    let mut usb = link::device(&bus, serial.as_str()).unwrap();
    configure(&wire, &mut link, &mut usb);
    let out_ep = bulk_index(&wire, UsbDirection::Out);
    let in_ep = bulk_index(&wire, UsbDirection::In);

    // The host sends 40 packets of input and stops reading.
    let input: Vec<u8> = (0..40 * 64u32).map(|i| (i * 13 + i / 7) as u8).collect();
    {
        let mut w = wire.lock().unwrap();
        w.reading = false;
        for packet in input.chunks(64) {
            w.out_packets[out_ep].push_back(packet.to_vec());
        }
    }

    // The device replies with 16 longest frames (the queue's size) and reads
    // 64 bytes of input after each. Nothing waits: the IN endpoint holds a
    // packet (64 bytes), the queue the rest. Input is read while half of
    // the queue is free: after frames 1..=8 (8 * MAX_REPLY_LEN - 64 bytes queued),
    // not after 9..=16.
    assert_eq!(TX_QUEUE_LEN, 16 * MAX_REPLY_LEN);
    assert_eq!(RX_HEADROOM, TX_QUEUE_LEN / 2);
    let mut input_got = Vec::new();
    let mut reads = Vec::new();
    let mut rx = [0u8; 64];
    let mut pending_when_stopped = None;
    for i in 0..16 {
        link.send(&mut usb, &frame(i));
        link.poll(&mut usb);
        let n = link.read(&usb, &mut rx);
        input_got.extend_from_slice(&rx[..n]);
        reads.push(n);
        if i == 8 {
            pending_when_stopped = Some(wire.lock().unwrap().out_packets[out_ep].len());
        }
    }
    assert_eq!(reads, [[64; 8], [0; 8]].concat());
    {
        let w = wire.lock().unwrap();
        assert!(w.received.is_empty(), "the host read nothing");
        assert_eq!(w.in_packet[in_ep].as_deref(), Some(&frame(0)[..64]));
        // The host's input stays where it is (NAKed): the device took the 8
        // packets it read and nothing more (no buffer between).
        let pending = w.out_packets[out_ep].len();
        assert_eq!(Some(pending), pending_when_stopped);
        assert_eq!(pending, 40 - 8);
    }
    assert_eq!(input_got, input[..8 * 64]);

    // A 17th frame does not fit: `send` waits, polling USB, until the host
    // reads again (after 100 more polls), and drops nothing.
    let polls_before = {
        let mut w = wire.lock().unwrap();
        w.start_reading_after = Some(w.polls + 100);
        w.polls
    };
    let feeds = watchdog::FEEDS.load(std::sync::atomic::Ordering::Relaxed);
    link.send(&mut usb, &frame(16));
    // The wait fed the firmware's watchdog: a host that reads slowly is
    // no hang.
    assert!(watchdog::FEEDS.load(std::sync::atomic::Ordering::Relaxed) > feeds);
    {
        let w = wire.lock().unwrap();
        assert!(w.reading);
        assert!(
            w.polls > polls_before + 100,
            "send returned before the host read"
        );
        // It returned as soon as the frame fitted: all but 64 bytes of it
        // had to leave the full queue (64 fitted at once), so the host has
        // taken as many packets as that needs, and no more.
        assert_eq!(w.received.len(), (MAX_REPLY_LEN - 64).div_ceil(64) * 64);
    }

    // The host reads everything: every reply byte arrives once, in order;
    // input is read again once half of the queue is free, all of it.
    let replies: Vec<u8> = (0..17).flat_map(frame).collect();
    let mut turns = 0;
    loop {
        link.poll(&mut usb);
        let n = link.read(&usb, &mut rx);
        input_got.extend_from_slice(&rx[..n]);
        let received = wire.lock().unwrap().received.len();
        if received >= replies.len() && input_got.len() >= input.len() {
            break;
        }
        turns += 1;
        assert!(
            turns < 10_000,
            "stuck: {received} reply bytes, {} input",
            input_got.len()
        );
    }
    assert_eq!(wire.lock().unwrap().received, replies);
    assert_eq!(input_got, input);
    for _ in 0..4 {
        link.poll(&mut usb);
    }
    assert_eq!(wire.lock().unwrap().received.len(), replies.len());
    assert_eq!(link.read(&usb, &mut rx), 0);
}

/// `Link::flush` (what the firmware calls before a flash erase stalls the
/// chip): with a host that does not read it gives up after `FLUSH_POLLS`
/// polls, the replies still queued; with one that reads it returns once
/// every reply byte has left the queue (the last packet may still sit in
/// the endpoint, which the controller sends alone).
#[test]
fn flush_waits_for_the_host_and_gives_up_on_one_that_does_not_read() {
    let wire = Arc::new(Mutex::new(Wire::default()));
    let bus = UsbBusAllocator::new(WireBus(wire.clone()));
    let mut link = Link::new(&bus);
    let serial = link::SerialNumber::new(ID);
    let mut usb = link::device(&bus, serial.as_str()).unwrap();
    configure(&wire, &mut link, &mut usb);
    let in_ep = bulk_index(&wire, UsbDirection::In);

    wire.lock().unwrap().reading = false;
    let replies: Vec<u8> = (0..3).flat_map(frame).collect();
    for i in 0..3 {
        link.send(&mut usb, &frame(i));
    }
    let polls = wire.lock().unwrap().polls;
    assert!(
        !link.flush(&mut usb),
        "flushed to a host that does not read"
    );
    {
        let w = wire.lock().unwrap();
        assert!(w.polls >= polls + u64::from(FLUSH_POLLS));
        assert!(w.received.is_empty());
    }

    wire.lock().unwrap().reading = true;
    assert!(link.flush(&mut usb));
    let w = wire.lock().unwrap();
    let mut sent = w.received.clone();
    sent.extend(w.in_packet[in_ep].iter().flatten());
    assert_eq!(
        sent, replies,
        "a reply byte had not left when flush returned"
    );
    assert!(w.polls < polls + u64::from(FLUSH_POLLS) + 100);
}

/// The serial number: the domain, ":", the unique ID's bytes in the order
/// the chip sent them as 16 upper-case hex digits; the host's lookup by
/// serial number (`--port`) expects the same domain.
#[test]
fn the_serial_number_is_the_domain_then_the_flash_id_in_hex() {
    let serial = link::SerialNumber::new([0xE6, 0x61, 0x41, 0x03, 0xE7, 0x45, 0x2D, 0x2F]);
    assert_eq!(serial.as_str(), "placedb.example:E6614103E7452D2F");
    assert_eq!(serial.as_str().len(), link::SERIAL_LEN);
    assert_eq!(
        link::SerialNumber::new([0; 8]).as_str(),
        "placedb.example:0000000000000000"
    );
    assert_eq!(
        link::SERIAL_DOMAIN,
        placedb_host::board::link::usb_serial::SERIAL_DOMAIN
    );
    assert!(placedb_host::board::link::usb_serial::looks_like_serial(
        serial.as_str()
    ));
}
