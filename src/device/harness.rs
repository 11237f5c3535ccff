//! The host's side of a conversation with one in-process [`Device`], for
//! tests (feature `sim-flash`, which needs `std`): the one harness of the
//! device's unit tests (`src/device/tests.rs`) and of the integration tests
//! that drive a device over its wire protocol (`host/tests/device_bad_inputs.rs`,
//! `host/tests/device_power_cut.rs`); the fuzz targets (`fuzz/src/harness.rs`) decode
//! and check replies with its [`decode_reply`], [`terminal`] and
//! [`check_export`].
//!
//! A [`Harness`] holds a device, its log on a [`SimFlash`] under the
//! boards' [`EraseAhead`] (or no journal) and the host's sequence numbers.
//! Between messages, when a board is idle, it erases the log's next sector
//! ahead of need as the boards do, so that power cuts land in those erases
//! too. It encodes each message as a host would,
//! decodes every reply frame the device sends, and checks what every reply
//! must be: one complete frame within [`MAX_REPLY_LEN`], and exactly one
//! terminal reply per message, last, with the message's sequence number.
//! [`Harness::ok`], [`Harness::refused`], [`Harness::status`] and
//! [`Harness::export`] add what the answer to each kind of message must be.
//!
//! It lives in the core, not in `placedb-host`, because the core's own unit
//! tests use it too (they cannot depend on the host crate).

// Host-only test code: a failed check panics, as a test must.
#![allow(
    clippy::indexing_slicing,
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic
)]

use std::boxed::Box;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::vec;
use std::vec::Vec;

use super::{Device, RestoreFailure};
use crate::persist::sim::SimFlash;
use crate::persist::{EraseAhead, Journal, Log, NoJournal};
use crate::protocol::{
    encode, export_crc, DeviceMessage, ErrorKind, ExportRecord, Feed, FrameDecoder, HostFrame,
    HostMessage, RecordKind, Status, MAX_FRAME_LEN, MAX_REPLY_LEN,
};

/// The log of a harness: on a simulated flash, under the boards' erase-ahead.
pub type HarnessLog = Log<EraseAhead<SimFlash>>;

/// A [`Device`] of any capacities (it has six const parameters), as the
/// harness drives it.
pub trait AnyDevice: Send + 'static {
    /// A new device (all state as after power-on), on the heap.
    fn new_boxed() -> Box<Self>;
    /// [`Device::receive_logged`].
    fn receive_into(
        &mut self,
        bytes: &[u8],
        journal: &mut dyn Journal,
        send: &mut dyn FnMut(&[u8]),
    );
    /// [`Device::restore`].
    fn restore_from(&mut self, log: &mut HarnessLog) -> Result<u32, RestoreFailure>;
    /// [`Device::add_receive_ticks`].
    fn add_receive_ticks(&mut self, ticks: u64);
    /// The counters of [`Device::selector`].
    fn selector_status(&self) -> crate::select::Status;
}

impl<
        const FV: usize,
        const POOL: usize,
        const DB: usize,
        const W: usize,
        const K: usize,
        const R: usize,
    > AnyDevice for Device<FV, POOL, DB, W, K, R>
{
    fn new_boxed() -> Box<Self> {
        Box::new(Self::new())
    }

    fn receive_into(
        &mut self,
        bytes: &[u8],
        journal: &mut dyn Journal,
        send: &mut dyn FnMut(&[u8]),
    ) {
        self.receive_logged(bytes, journal, send);
    }

    fn restore_from(&mut self, log: &mut HarnessLog) -> Result<u32, RestoreFailure> {
        self.restore(log)
    }

    fn add_receive_ticks(&mut self, ticks: u64) {
        Device::add_receive_ticks(self, ticks);
    }

    fn selector_status(&self) -> crate::select::Status {
        self.selector().status()
    }
}

/// A device, its log on a simulated flash (or no journal), and the host's
/// side of the link.
pub struct Harness<D> {
    /// The device under test.
    pub device: Box<D>,
    /// `None`: a device without flash ([`Device::receive`], no journal).
    pub log: Option<HarnessLog>,
    /// The sequence number of the last message sent.
    pub seq: u32,
    /// While this flag is set the host hears nothing the device sends
    /// (`host/tests/device_power_cut.rs` sets it to the flash's power switch: a device
    /// without power sends nothing). `None`: the host hears everything.
    pub silent_while: Option<Arc<AtomicBool>>,
    /// Whether the board erases the log's next sector ahead while idle
    /// (after each message [`Self::send`] sends), as both boards do; a test
    /// of the log's own failure paths may turn it off.
    pub erase_ahead_when_idle: bool,
}

impl<D: AnyDevice> Harness<D> {
    /// A new device with a log on a blank flash of `sectors` sectors (not
    /// restored: nothing to restore).
    pub fn new(sectors: usize) -> Self {
        let flash = SimFlash::new(sectors);
        let end = (sectors * SimFlash::SECTOR) as u32;
        Harness {
            device: D::new_boxed(),
            log: Some(Log::open(EraseAhead::new(flash), 0, end).unwrap()),
            seq: 0,
            silent_while: None,
            erase_ahead_when_idle: true,
        }
    }

    /// A new device without flash.
    pub fn without_flash() -> Self {
        Harness {
            device: D::new_boxed(),
            log: None,
            seq: 0,
            silent_while: None,
            erase_ahead_when_idle: true,
        }
    }

    /// Power on: a new device, the log opened on `flash` (power back on
    /// it), and the scan restored from it.
    pub fn boot(mut flash: SimFlash) -> (Self, Result<u32, RestoreFailure>) {
        flash.power_on();
        let end = flash.bytes().len() as u32;
        let mut log =
            Log::open(EraseAhead::new(flash), 0, end).expect("the log opens on any flash contents");
        let mut device = D::new_boxed();
        let restored = device.restore_from(&mut log);
        let harness = Harness {
            device,
            log: Some(log),
            seq: 0,
            silent_while: None,
            erase_ahead_when_idle: true,
        };
        (harness, restored)
    }

    /// The flash (a device with flash).
    pub fn flash(&mut self) -> &mut SimFlash {
        self.log
            .as_mut()
            .expect("a device with flash")
            .flash()
            .inner()
    }

    /// The flash, the device gone.
    pub fn into_flash(self) -> SimFlash {
        self.log
            .expect("a device with flash")
            .into_flash()
            .into_inner()
    }

    /// What a board does when idle: erases the sector the log's next erase
    /// goes to (a failure is the log's to meet when it writes there).
    pub fn erase_ahead(&mut self) {
        if let Some(log) = self.log.as_mut() {
            let next = log.next_sector();
            let _ = log.flash().erase_ahead(next);
        }
    }

    /// Whether the host hears the device now (see `silent_while`).
    pub fn hears(&self) -> bool {
        self.silent_while
            .as_ref()
            .is_none_or(|silent| !silent.load(Ordering::Relaxed))
    }

    /// Feeds `bytes` in chunks of `chunk` bytes; every reply the host
    /// hears, decoded by [`decode_reply`].
    pub fn feed(&mut self, bytes: &[u8], chunk: usize) -> Vec<DeviceMessage<'static>> {
        let mut heard: Vec<Vec<u8>> = Vec::new();
        let silent = self.silent_while.clone();
        let mut hear = |f: &[u8]| {
            if silent.as_ref().is_none_or(|s| !s.load(Ordering::Relaxed)) {
                heard.push(f.to_vec());
            }
        };
        for part in bytes.chunks(chunk.max(1)) {
            match self.log.as_mut() {
                Some(log) => self.device.receive_into(part, log, &mut hear),
                None => self.device.receive_into(part, &mut NoJournal, &mut hear),
            }
        }
        heard.iter().map(|f| decode_reply(f)).collect()
    }

    /// Sends `msg` with the next sequence number; every reply heard. A
    /// message heard to the end gets exactly one terminal reply, last, with
    /// its sequence number. The host does not talk to a device it cannot
    /// hear.
    pub fn send(&mut self, msg: HostMessage<'_>) -> Vec<DeviceMessage<'static>> {
        let replies = self.exchange(msg);
        if self.erase_ahead_when_idle {
            // The message handled, the board is idle until the next.
            self.erase_ahead();
        }
        replies
    }

    /// [`Self::send`] without the idle time after it: what [`Self::status`]
    /// and [`Self::export_from`] use, so that a test's looks at the device
    /// move no flash step.
    fn exchange(&mut self, msg: HostMessage<'_>) -> Vec<DeviceMessage<'static>> {
        assert!(self.hears(), "the host talks to a device it cannot hear");
        self.seq = self.seq.wrapping_add(1);
        let mut buf = vec![0u8; MAX_FRAME_LEN];
        let frame = encode(&HostFrame { seq: self.seq, msg }, &mut buf)
            .unwrap()
            .to_vec();
        let replies = self.feed(&frame, frame.len());
        if self.hears() {
            let terminals: Vec<_> = replies.iter().filter_map(terminal).collect();
            assert_eq!(terminals, vec![Some(self.seq)], "{msg:?} -> {replies:?}");
            assert!(
                replies.last().and_then(terminal).is_some(),
                "{msg:?} -> {replies:?}"
            );
        }
        replies
    }

    /// Sends `msg`, which must be accepted: its decisions, then its Ack.
    pub fn ok(&mut self, msg: HostMessage<'_>) -> Vec<DeviceMessage<'static>> {
        let replies = self.send(msg);
        assert!(self.hears(), "{msg:?}: the device went silent");
        let (last, decisions) = replies.split_last().expect("a reply");
        assert_eq!(
            *last,
            DeviceMessage::Ack { seq: self.seq },
            "{msg:?} -> {replies:?}"
        );
        assert!(
            decisions
                .iter()
                .all(|m| matches!(m, DeviceMessage::Decision { .. })),
            "{msg:?} -> {replies:?}"
        );
        replies
    }

    /// Sends `msg`, which must be refused, and nothing else said; why.
    pub fn refused(&mut self, msg: HostMessage<'_>) -> ErrorKind {
        match self.send(msg).as_slice() {
            [DeviceMessage::Error {
                seq: Some(seq),
                kind,
            }] if *seq == self.seq => *kind,
            other => panic!("{msg:?} not refused: {other:?}"),
        }
    }

    /// The device's status.
    pub fn status(&mut self) -> Status {
        match self.exchange(HostMessage::StatusRequest).as_slice() {
            [DeviceMessage::Status(s)] if s.seq == self.seq => *s,
            other => panic!("no status: {other:?}"),
        }
    }

    /// The whole export, checked by [`Harness::export_from`].
    pub fn export(&mut self) -> Vec<ExportRecord> {
        self.export_from(0, u32::MAX)
    }

    /// Up to `max` export records from record `from`, checked: records
    /// numbered from `from` on, then an ExportEnd whose sequence number,
    /// start, count and CRC are those of the request and the records.
    pub fn export_from(&mut self, from: u32, max: u32) -> Vec<ExportRecord> {
        let replies = self.exchange(HostMessage::ExportRequest {
            from_record: from,
            max_records: max,
        });
        let (last, records) = replies.split_last().expect("an ExportEnd");
        let records: Vec<ExportRecord> = records
            .iter()
            .map(|m| match m {
                DeviceMessage::ExportRecord(r) => *r,
                other => panic!("not an export record: {other:?}"),
            })
            .collect();
        match last {
            DeviceMessage::ExportEnd {
                seq,
                from_record,
                count,
                crc32,
            } => {
                assert_eq!((*seq, *from_record), (self.seq, from), "export end");
                check_export(&records, from, *count, *crc32);
            }
            other => panic!("no ExportEnd: {other:?}"),
        }
        records
    }
}

/// What a restore gives back of a live device's export: every label, and
/// the database frames a label names (a frame taken for a decision not yet
/// in the log does not come back: see `device::restore`), numbered again.
/// The whole export, once the scan is finished.
pub fn durable_part(export: &[ExportRecord]) -> Vec<ExportRecord> {
    let named: Vec<u32> = export
        .iter()
        .filter_map(|r| match r.kind {
            RecordKind::Label { class } => Some(class),
            RecordKind::Database { .. } | RecordKind::Session { .. } => None,
        })
        .collect();
    let kept = export.iter().filter(|r| {
        matches!(
            r.kind,
            RecordKind::Label { .. } | RecordKind::Session { .. }
        ) || named.contains(&r.frame)
    });
    kept.zip(0u32..)
        .map(|(r, record)| ExportRecord { record, ..*r })
        .collect()
}

/// Checks the records of one export against its ExportEnd: their count,
/// their CRC, and their numbers, from `from_record` on.
pub fn check_export(records: &[ExportRecord], from_record: u32, count: u32, crc32: u32) {
    assert_eq!(count as usize, records.len(), "ExportEnd count");
    assert_eq!(crc32, export_crc(records), "ExportEnd CRC");
    for (k, r) in records.iter().enumerate() {
        assert_eq!(
            Some(r.record),
            from_record.checked_add(k as u32),
            "export record numbers: {r:?}"
        );
    }
}

/// Decodes one reply frame, checking that it is exactly one complete frame
/// (a single 0x00, at its end) within the device's transmit buffer, and not
/// a log line (a device never logs).
pub fn decode_reply(frame: &[u8]) -> DeviceMessage<'static> {
    assert!(
        frame.len() <= MAX_REPLY_LEN,
        "reply of {} bytes",
        frame.len()
    );
    assert_eq!(frame.last(), Some(&0), "reply frame not delimited");
    assert!(!frame[..frame.len() - 1].contains(&0), "two frames in one");
    let mut decoder = FrameDecoder::<MAX_REPLY_LEN>::new();
    match decoder.feed::<DeviceMessage>(frame) {
        Feed::Frame {
            result: Ok(msg),
            remaining: [],
        } => match msg {
            DeviceMessage::Log(text) => panic!("the device logged {text:?}"),
            msg => msg.into_static().expect("not a log line"),
        },
        other => panic!("bad reply frame {frame:?}: {other:?}"),
    }
}

/// The sequence number a terminal reply answers (`Some(None)` for an error
/// about a frame whose sequence number was lost); `None` for the replies
/// that come before it.
pub fn terminal(msg: &DeviceMessage<'_>) -> Option<Option<u32>> {
    match msg {
        DeviceMessage::Ack { seq } | DeviceMessage::ExportEnd { seq, .. } => Some(Some(*seq)),
        DeviceMessage::Status(s) => Some(Some(s.seq)),
        DeviceMessage::LogBytes(b) => Some(Some(b.seq)),
        DeviceMessage::ExportUnreadable(u) => Some(Some(u.seq)),
        DeviceMessage::Error { seq, .. } => Some(*seq),
        DeviceMessage::Decision { .. } | DeviceMessage::ExportRecord(_) | DeviceMessage::Log(_) => {
            None
        }
    }
}

/// Runs `f` on a thread with a stack large enough for a device built on it
/// (a `Device::new()` is moved to the heap from the stack).
pub fn on_big_stack<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
    std::thread::Builder::new()
        .stack_size(64 << 20)
        .spawn(f)
        .unwrap()
        .join()
        .unwrap()
}
