//! The device state machine: bytes in, reply frames out. Every board runs this
//! very type over its own transport (UART, USB CDC-ACM, TCP to an emulator),
//! and the host can run it in-process, so all of them behave identically.
//!
//! ```
//! use placedb::device::Device256K;
//! use placedb::protocol::{encode, HostFrame, HostMessage};
//! # std::thread::Builder::new().stack_size(8 << 20).spawn(|| {
//! let mut device = Box::new(Device256K::new());
//! let mut tx = [0u8; 64];
//! let frame = encode(&HostFrame { seq: 1, msg: HostMessage::StatusRequest }, &mut tx).unwrap();
//! let mut replies = 0;
//! device.receive(frame, &mut |reply: &[u8]| {
//!     assert_eq!(reply.last(), Some(&0));
//!     replies += 1;
//! });
//! assert_eq!(replies, 1);
//! # }).unwrap().join().unwrap();
//! # extern crate std;
//! ```
//!
//! # Behaviour
//!
//! Every host frame gets exactly one terminal reply with its sequence number
//! (see [`crate::protocol`]); a refused message changes nothing stored.
//!
//! | message | accepted when | effect | refusals |
//! |---|---|---|---|
//! | Hello | no frame open, no frame seen since reset | configures (replaces an earlier Hello) | `WrongVersion`, `BadConfig`, `MidFrameReconfig`; after frames: `NeedsReset` unless identical (then a no-op Ack) |
//! | FrameBegin | configured, not finished, no frame open | opens frame `frames_seen` | `NotConfigured`, `Finished`, `OutOfOrder` (open frame or wrong index), `BadPose` |
//! | DepthRows | the open frame, next strided row | voxelizes the rows | `OutOfOrder`, `RowOutOfRange`, `RowTooLong`, `RowTooShort` |
//! | FrameEnd | the open frame, all rows in | selection step; `Decision`s, then Ack | `FrameEndWithoutBegin`, `MissingRows` (frame stays open), `StorageFull` (idem) |
//! | FrameAbort | the open frame | drops it; the next FrameBegin has its index | `FrameEndWithoutBegin`, `NotConfigured`, `Finished` |
//! | Finish | configured, no frame open | decides every pending frame (`Decision`s); phase Finished; a repeated Finish is a no-op | `NotConfigured`, `OutOfOrder`, `StorageFull` |
//! | StatusRequest | always | `Status` | — |
//! | ExportRequest | always | up to `max_records` `ExportRecord`s from `from_record`, then `ExportEnd` | `ExportPastEnd` (`from_record` beyond the last record + 1) |
//! | Reset | always | forgets configuration, frames, database, labels, counters | `StorageFailed` |
//!
//! Durability ([`Device::receive_logged`] with a [`Log`]): the Hello, every
//! database frame and every final decision are written before the replies
//! that acknowledge them. FrameEnd is refused with `StorageFull` unless the
//! log has room for its worst case *and* a Finish after it, so a scan whose
//! log fills up still ends cleanly: FrameAbort the open frame, then Finish.
//! A failed write (not a full log) sets `STORAGE_FAILED`; the step's replies
//! still go out but nothing more is written in this scan.
//!
//! Retransmission: the device remembers the sequence number, the message and
//! the terminal reply of the last state-changing message it handled (Hello,
//! FrameBegin, DepthRows, FrameEnd, Finish, Reset, FrameAbort). The same message again
//! with the same sequence number (a host retransmitting because the reply was
//! lost or late) gets that reply again and is not applied twice; its
//! `Decision`s are not sent again. StatusRequest and ExportRequest change
//! nothing and are simply answered again.
//!
//! Labels: one per frame with a final decision, in frame order: its timestamp
//! and class (the covering or nearest database frame, or itself). When the
//! store of `LABELS` entries is full, later labels are counted in
//! `labels_dropped`, [`degradation::LABELS_FULL`] is set, and selection goes on.
//!
//! Export: record `r < database_size` is the `r`-th database frame in frame
//! order (pose and timestamp); record `database_size + j` is the label of frame
//! `j`. The `ExportEnd` count and CRC cover exactly the records sent.

#![cfg_attr(
    not(test),
    deny(
        clippy::indexing_slicing,
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic
    )
)]

use crate::frame::FrameMeta;
use crate::persist::{Journal, Log, LogError, NoJournal, Record};
use crate::protocol::{
    degradation, encode, Capacity, CapacitySlot, Config, DecisionKind, DeviceMessage, ErrorKind,
    ExportCrc, ExportRecord, FrameCost, FrameDecoder, HostFrame, HostMessage, Phase, ProtocolError,
    Push, RecordKind, Status, CAPACITY_SLOTS, MAX_FRAME_LEN, MAX_REPLY_LEN, MAX_ROW_VALUES,
};
use crate::select::{DbSnapshot, RestoreError};
use crate::select::{FrameDecision, SelectError, Selector};
use crate::sketch::Sketch;
use crate::FrameError;

pub use crate::profile::{Device1M, Device256K, Device512K};

/// One device: a [`Selector`] of capacities `FV`, `POOL`, `DB`, `W`, `K` (see
/// [`crate::profile`]), a receive buffer of [`MAX_FRAME_LEN`] bytes, and a
/// label store of `LABELS` frames. All zero when new, so a `static` of it
/// costs RAM (`.bss`) but no flash.
#[derive(Debug)]
pub struct Device<
    const FV: usize,
    const POOL: usize,
    const DB: usize,
    const W: usize,
    const K: usize,
    const LABELS: usize,
> {
    decoder: FrameDecoder<MAX_FRAME_LEN>,
    core: Core<FV, POOL, DB, W, K, LABELS>,
}

/// Everything but the receive buffer (which a decoded message borrows).
#[derive(Debug)]
struct Core<
    const FV: usize,
    const POOL: usize,
    const DB: usize,
    const W: usize,
    const K: usize,
    const LABELS: usize,
> {
    selector: Selector<FV, POOL, DB, W, K>,
    labels: Labels<LABELS>,
    /// The Hello in force; `None` until configured.
    hello: Option<Config>,
    finished: bool,
    /// Depth values of one DepthRows message, decoded from its bytes.
    rows: [u16; MAX_ROW_VALUES],
    tx: [u8; MAX_REPLY_LEN],
    refused: u32,
    rx_last: u32,
    rx_peak: u32,
    clock: Option<fn() -> u64>,
    cost: FrameCost,
    /// Ticks of the open frame's FrameBegin and DepthRows so far.
    rows_ticks: u64,
    /// The last state-changing message handled, to answer its retransmission.
    last: Applied,
    /// Decisions of the selection step in progress, held until durable.
    decisions: heapless::Vec<FrameDecision, MAX_STEP_DECISIONS>,
    /// Encoding buffer of one log record.
    record: [u8; MAX_RECORD_LEN],
    /// Database entries (in take order) already in the log.
    durable_db: usize,
    /// Records of this scan in the log (journals that keep records only).
    stored: u32,
    /// A log write failed during this scan; nothing more is written.
    storage_failed: bool,
    /// The scan came back from the log at boot.
    restored: bool,
}

/// Most decisions one selection step makes: a full window and the Pending
/// of the new frame.
const MAX_STEP_DECISIONS: usize = 65;

/// The largest log record: a database frame with its sketch (`K` ≤ 168,
/// checked at compile time by `DB_RECORD_LEN`).
const MAX_RECORD_LEN: usize = 768;

/// Why [`Device::restore`] found no usable scan; the device is left reset.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RestoreFailure {
    /// The log could not be read.
    Log(LogError),
    /// Record `record` (0-based) is not a record of this format.
    Malformed {
        /// Its position in the log.
        record: u32,
    },
    /// Record `record` does not fit the state before it.
    Refused {
        /// Its position in the log.
        record: u32,
        /// What the selector said.
        error: RestoreError,
    },
    /// Record `record` holds a configuration this device refuses.
    BadConfig {
        /// Its position in the log.
        record: u32,
    },
}

/// A state-changing message the device handled and its terminal reply.
/// Plain integers only (no `Option`, whose `None` may be a non-zero niche):
/// a new device stays all zero bytes, in `.bss`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Applied {
    /// The message; [`MessageKey::NONE`] before any.
    key: MessageKey,
    seq: u32,
    /// Accepted (Ack), else refused with `kind`.
    accepted: bool,
    kind: ErrorKind,
}

impl Applied {
    const NONE: Applied = Applied {
        key: MessageKey::NONE,
        seq: 0,
        accepted: false,
        kind: ErrorKind::BadCrc,
    };

    /// The terminal reply it got.
    fn reply(&self) -> DeviceMessage<'static> {
        if self.accepted {
            DeviceMessage::Ack { seq: self.seq }
        } else {
            DeviceMessage::Error {
                seq: Some(self.seq),
                kind: self.kind,
            }
        }
    }
}

/// What identifies a state-changing message besides its sequence number (so
/// that a restarted host reusing sequence numbers is not taken for a retry).
/// A Hello is identified by its configuration: the one in force.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct MessageKey {
    /// 0: none; 1 Hello, 2 FrameBegin, 3 DepthRows, 4 FrameEnd, 5 Finish,
    /// 6 Reset, 7 FrameAbort.
    tag: u8,
    frame: u32,
    first_row: u16,
    row_count: u16,
}

impl MessageKey {
    const NONE: MessageKey = MessageKey {
        tag: 0,
        frame: 0,
        first_row: 0,
        row_count: 0,
    };

    /// The key of a state-changing message; `None` for requests that change nothing.
    fn of(msg: &HostMessage<'_>) -> Option<MessageKey> {
        let key = |tag, frame, first_row, row_count| MessageKey {
            tag,
            frame,
            first_row,
            row_count,
        };
        Some(match *msg {
            HostMessage::Hello(_) => key(1, 0, 0, 0),
            HostMessage::FrameBegin { frame, .. } => key(2, frame, 0, 0),
            HostMessage::DepthRows(r) => key(3, r.frame, r.first_row, r.row_count),
            HostMessage::FrameEnd { frame } => key(4, frame, 0, 0),
            HostMessage::Finish => key(5, 0, 0, 0),
            HostMessage::Reset => key(6, 0, 0, 0),
            HostMessage::FrameAbort { frame } => key(7, frame, 0, 0),
            HostMessage::StatusRequest | HostMessage::ExportRequest { .. } => return None,
        })
    }
}

/// Timestamps and classes of decided frames, by frame index.
#[derive(Debug)]
struct Labels<const N: usize> {
    timestamps: [f64; N],
    classes: [u32; N],
    /// Frames `0..len` have a label.
    len: usize,
    dropped: u32,
}

impl<const N: usize> Labels<N> {
    const fn new() -> Self {
        Labels {
            timestamps: [0.0; N],
            classes: [0; N],
            len: 0,
            dropped: 0,
        }
    }

    /// Notes frame `index`'s timestamp (when it begins).
    fn begin(&mut self, index: u32, timestamp: f64) {
        if let Some(t) = self.timestamps.get_mut(index as usize) {
            *t = timestamp;
        }
    }

    /// Stores frame `index`'s class (final decisions arrive in frame order).
    fn decide(&mut self, index: u32, class: u32) {
        let i = index as usize;
        match self.classes.get_mut(i) {
            Some(c) if i == self.len => {
                *c = class;
                self.len += 1;
            }
            _ => self.dropped = self.dropped.saturating_add(1),
        }
    }

    /// Frame `index`'s timestamp as noted at its begin (0 beyond the store).
    fn timestamp(&self, index: u32) -> f64 {
        self.timestamps.get(index as usize).copied().unwrap_or(0.0)
    }

    fn get(&self, i: usize) -> Option<(f64, u32)> {
        if i >= self.len {
            return None;
        }
        Some((*self.timestamps.get(i)?, *self.classes.get(i)?))
    }
}

/// Sends encoded replies; measures the time spent sending.
struct Out<'a> {
    tx: &'a mut [u8; MAX_REPLY_LEN],
    send: &'a mut dyn FnMut(&[u8]),
    clock: Option<fn() -> u64>,
    /// Ticks spent inside `send` so far.
    ticks: u64,
}

impl Out<'_> {
    fn reply(&mut self, msg: &DeviceMessage<'_>) {
        let t0 = now(self.clock);
        match encode(msg, &mut self.tx[..]) {
            Ok(frame) => (self.send)(frame),
            Err(_) => {
                // Only a `Log` can exceed the buffer: drop it. Anything else
                // would be a bug, reported as such to keep one reply per message.
                if !matches!(msg, DeviceMessage::Log(_)) {
                    let fallback = DeviceMessage::Error {
                        seq: None,
                        kind: ErrorKind::Internal,
                    };
                    if let Ok(frame) = encode(&fallback, &mut self.tx[..]) {
                        (self.send)(frame);
                    }
                }
            }
        }
        self.ticks = self.ticks.wrapping_add(now(self.clock).wrapping_sub(t0));
    }
}

fn now(clock: Option<fn() -> u64>) -> u64 {
    clock.map_or(0, |f| f())
}

/// Maps a failure of the journal to the wire.
fn storage_error(e: LogError) -> ErrorKind {
    match e {
        LogError::Full | LogError::TooLarge => ErrorKind::StorageFull,
        LogError::Flash(_) | LogError::BadRange | LogError::NotStarted => ErrorKind::StorageFailed,
    }
}

/// Maps a refusal of the selector to the wire.
fn select_error(e: SelectError) -> ErrorKind {
    match e {
        SelectError::NotConfigured => ErrorKind::NotConfigured,
        SelectError::FrameInProgress => ErrorKind::OutOfOrder,
        SelectError::BadConfig => ErrorKind::BadConfig,
        SelectError::Frame(f) => match f {
            // The configuration was checked at Hello: at FrameBegin only the
            // pose can be at fault (non-finite, not a rotation, or so far
            // away that coordinates leave the fixed-point range).
            FrameError::Camera(_) => ErrorKind::BadPose,
            FrameError::FrameInProgress
            | FrameError::WrongIndex { .. }
            | FrameError::RowOutOfOrder { .. } => ErrorKind::OutOfOrder,
            FrameError::NoFrame => ErrorKind::FrameEndWithoutBegin,
            FrameError::BadRowChunk => ErrorKind::RowOutOfRange,
            FrameError::MissingRows { .. } => ErrorKind::MissingRows,
        },
    }
}

fn to_u32(n: usize) -> u32 {
    u32::try_from(n).unwrap_or(u32::MAX)
}

fn delta(clock: Option<fn() -> u64>, since: u64, minus: u64) -> u64 {
    now(clock).wrapping_sub(since).saturating_sub(minus)
}

impl<
        const FV: usize,
        const POOL: usize,
        const DB: usize,
        const W: usize,
        const K: usize,
        const LABELS: usize,
    > Default for Device<FV, POOL, DB, W, K, LABELS>
{
    fn default() -> Self {
        Self::new()
    }
}

impl<
        const FV: usize,
        const POOL: usize,
        const DB: usize,
        const W: usize,
        const K: usize,
        const LABELS: usize,
    > Device<FV, POOL, DB, W, K, LABELS>
{
    /// Slots of the per-frame voxel set.
    pub const FRAME_VOXEL_SLOTS: usize = FV;
    /// Key pool words.
    pub const POOL_WORDS: usize = POOL;
    /// Database frames.
    pub const DATABASE_FRAMES: usize = DB;
    /// Window frames.
    pub const WINDOW: usize = W;
    /// Hashes per sketch.
    pub const SKETCH: usize = K;
    /// Labels (frames) the export can hold.
    pub const LABELS: usize = LABELS;

    /// A device after power-on: unconfigured, all state zero (lands in `.bss`).
    pub const fn new() -> Self {
        Device {
            decoder: FrameDecoder::new(),
            core: Core {
                selector: Selector::new(),
                labels: Labels::new(),
                hello: None,
                finished: false,
                rows: [0; MAX_ROW_VALUES],
                tx: [0; MAX_REPLY_LEN],
                refused: 0,
                rx_last: 0,
                rx_peak: 0,
                clock: None,
                cost: FrameCost::ZERO,
                rows_ticks: 0,
                last: Applied::NONE,
                decisions: heapless::Vec::new(),
                record: [0; MAX_RECORD_LEN],
                durable_db: 0,
                stored: 0,
                storage_failed: false,
                restored: false,
            },
        }
    }

    /// Feeds received bytes (any chunking); every complete frame is handled and
    /// each reply is passed to `send` as one complete encoded frame (COBS,
    /// trailing 0x00 included, at most [`MAX_REPLY_LEN`] bytes).
    pub fn receive(&mut self, bytes: &[u8], send: &mut dyn FnMut(&[u8])) {
        self.receive_logged(bytes, &mut NoJournal, send);
    }

    /// As [`Self::receive`], making every state change durable in `journal`
    /// first: a reply goes out only once what it acknowledges is stored.
    pub fn receive_logged(
        &mut self,
        bytes: &[u8],
        journal: &mut dyn Journal,
        send: &mut dyn FnMut(&[u8]),
    ) {
        let core = &mut self.core;
        let mut rest = bytes;
        loop {
            match self.decoder.push(rest) {
                Push::NeedMore => return,
                Push::Error { error, remaining } => {
                    core.note_rx(MAX_FRAME_LEN);
                    let mut out = core.out(send);
                    out.reply(&error.reply());
                    core.refused = core.refused.saturating_add(1);
                    rest = remaining;
                }
                Push::Ready { remaining } => {
                    // The delimiter counts: the buffer holds frame_len + 1 bytes.
                    core.note_rx(self.decoder.frame_len().saturating_add(1));
                    let t0 = now(core.clock);
                    let frame = self.decoder.decode::<HostFrame>();
                    core.handle(frame, t0, journal, send);
                    rest = remaining;
                }
            }
        }
    }

    /// Gives the device a monotonic clock: `ticks()` counting at `hz` ticks
    /// per second. The status then reports the cost of each frame.
    pub fn set_clock(&mut self, ticks: fn() -> u64, hz: u32) {
        self.core.clock = Some(ticks);
        self.core.cost.clock_hz = hz;
    }

    /// Forgets everything but the clock, as [`HostMessage::Reset`] does; a
    /// partly received frame is dropped too.
    pub fn reset(&mut self) {
        self.decoder.clear();
        self.core.reset();
    }

    /// Rebuilds the scan kept in `log` (at boot): configuration, database,
    /// labels, finished flag. Returns the records replayed; the host resumes
    /// with frame `status().frames_seen`. On failure the device is reset
    /// (the log is left as it is; the next Hello starts over).
    pub fn restore<F: embedded_storage::nor_flash::NorFlash>(
        &mut self,
        log: &mut Log<F>,
    ) -> Result<u32, RestoreFailure> {
        self.reset();
        let core = &mut self.core;
        let (mut n, mut failure) = (0u32, None);
        let replayed = log.replay(&mut |payload| {
            if failure.is_none() {
                failure = core.apply(payload, n).err();
                n += 1;
            }
        });
        match (replayed, failure) {
            (Ok(records), None) => {
                // A log holding only `Cleared` (a Reset) restores nothing.
                let scan = core.hello.is_some();
                core.durable_db = core.selector.database_len();
                core.stored = if scan { records } else { 0 };
                core.restored = scan;
                Ok(records)
            }
            (Err(e), _) => {
                self.reset();
                Err(RestoreFailure::Log(e))
            }
            (_, Some(f)) => {
                self.reset();
                Err(f)
            }
        }
    }

    /// The current status (with sequence number 0).
    pub fn status(&self) -> Status {
        self.core.status(0)
    }

    /// The device state.
    pub fn phase(&self) -> Phase {
        self.core.phase()
    }

    /// The selector inside.
    pub fn selector(&self) -> &Selector<FV, POOL, DB, W, K> {
        &self.core.selector
    }
}

impl<
        const FV: usize,
        const POOL: usize,
        const DB: usize,
        const W: usize,
        const K: usize,
        const LABELS: usize,
    > Core<FV, POOL, DB, W, K, LABELS>
{
    /// Bound on the encoded length of a database record: postcard fields
    /// (at most 96 bytes) and the sketch.
    const DB_RECORD_LEN: usize = {
        let len = 96 + 4 * K;
        assert!(len <= MAX_RECORD_LEN, "sketch too large for a log record");
        len
    };

    fn out<'a>(&'a mut self, send: &'a mut dyn FnMut(&[u8])) -> Out<'a> {
        Out {
            tx: &mut self.tx,
            send,
            clock: self.clock,
            ticks: 0,
        }
    }

    fn note_rx(&mut self, len: usize) {
        self.rx_last = to_u32(len);
        self.rx_peak = self.rx_peak.max(self.rx_last);
    }

    fn reset(&mut self) {
        self.selector.reset();
        self.labels.len = 0;
        self.labels.dropped = 0;
        self.hello = None;
        self.finished = false;
        self.refused = 0;
        self.rx_last = 0;
        self.rx_peak = 0;
        self.cost = FrameCost {
            clock_hz: self.cost.clock_hz,
            ..FrameCost::ZERO
        };
        self.rows_ticks = 0;
        self.last = Applied::NONE;
        self.durable_db = 0;
        self.stored = 0;
        self.storage_failed = false;
        self.restored = false;
    }

    fn phase(&self) -> Phase {
        if self.hello.is_none() {
            Phase::Unconfigured
        } else if self.selector.current_frame().is_some() {
            Phase::InFrame
        } else if self.finished {
            Phase::Finished
        } else {
            Phase::Ready
        }
    }

    fn status(&self, seq: u32) -> Status {
        let st = self.selector.status();
        let usage = |u: crate::select::Usage| Capacity {
            used: u.used,
            peak: u.peak,
            limit: u.limit,
        };
        let labels = to_u32(self.labels.len);
        let mut capacities = [Capacity::default(); CAPACITY_SLOTS];
        for (slot, c) in CapacitySlot::ALL.iter().zip(capacities.iter_mut()) {
            *c = match slot {
                CapacitySlot::Database => usage(st.database),
                CapacitySlot::Labels => Capacity {
                    used: labels,
                    peak: labels,
                    limit: to_u32(LABELS),
                },
                CapacitySlot::Pool => usage(st.pool),
                CapacitySlot::Window => usage(st.window),
                CapacitySlot::FrameVoxels => usage(st.frame_voxels),
                CapacitySlot::RxFrame => Capacity {
                    used: self.rx_last,
                    peak: self.rx_peak,
                    limit: to_u32(MAX_FRAME_LEN),
                },
            };
        }
        let flag = |on: bool, bit: u32| if on { bit } else { 0 };
        let device_flags = flag(self.labels.dropped > 0, degradation::LABELS_FULL)
            | flag(self.storage_failed, degradation::STORAGE_FAILED)
            | flag(self.restored, degradation::RESTORED);
        Status {
            seq,
            phase: self.phase(),
            frames_seen: st.frames_seen,
            frames_decided: st.frames_decided,
            database_size: to_u32(self.selector.database_len()),
            capacities,
            degradation: st.flags | device_flags,
            sketched_frames: st.sketched_frames,
            truncated_frames: st.truncated_frames,
            uncovered_frames: st.uncovered_frames,
            labels_dropped: self.labels.dropped,
            out_of_range_points: st.out_of_range_points,
            valid_pixels: st.valid_pixels,
            refused: self.refused,
            cost: self.cost,
            stored_records: self.stored,
        }
    }

    /// Handles one received frame (decoded at tick `t0`) with exactly one
    /// terminal reply.
    fn handle(
        &mut self,
        frame: Result<HostFrame<'_>, ProtocolError>,
        t0: u64,
        journal: &mut dyn Journal,
        send: &mut dyn FnMut(&[u8]),
    ) {
        let HostFrame { seq, msg } = match frame {
            Ok(frame) => frame,
            Err(error) => {
                self.refused = self.refused.saturating_add(1);
                return self.out(send).reply(&error.reply());
            }
        };
        let key = MessageKey::of(&msg);
        let same_hello = match msg {
            HostMessage::Hello(cfg) => self.hello == Some(cfg),
            _ => true,
        };
        if key == Some(self.last.key) && self.last.seq == seq && same_hello {
            // A retransmission of the message just handled: same reply, no effect.
            let reply = self.last.reply();
            return self.out(send).reply(&reply);
        }
        let clock = self.clock;
        let result = match msg {
            HostMessage::Hello(cfg) => self.hello(cfg, journal),
            HostMessage::FrameBegin {
                frame,
                timestamp,
                pose,
            } => self
                .frame_begin(FrameMeta {
                    index: frame,
                    timestamp,
                    pose,
                })
                .map(|()| self.rows_ticks = delta(clock, t0, 0)),
            HostMessage::DepthRows(rows) => self.depth_rows(&rows).map(|()| {
                self.rows_ticks = self.rows_ticks.saturating_add(delta(clock, t0, 0));
            }),
            HostMessage::FrameEnd { frame } => self.frame_end(frame, t0, journal, send),
            HostMessage::Finish => self.finish(journal, send),
            HostMessage::StatusRequest => {
                let status = self.status(seq);
                self.out(send).reply(&DeviceMessage::Status(status));
                return;
            }
            HostMessage::ExportRequest {
                from_record,
                max_records,
            } => {
                return self.export(seq, from_record, max_records, send);
            }
            HostMessage::Reset => self.reset_logged(journal),
            HostMessage::FrameAbort { frame } => self.frame_abort(frame),
        };
        if result.is_err() {
            self.refused = self.refused.saturating_add(1);
        }
        let applied = Applied {
            key: key.unwrap_or(MessageKey::NONE),
            seq,
            accepted: result.is_ok(),
            kind: result.err().unwrap_or(ErrorKind::Internal),
        };
        if key.is_some() {
            self.last = applied;
        }
        self.out(send).reply(&applied.reply());
    }

    fn hello(&mut self, cfg: Config, journal: &mut dyn Journal) -> Result<(), ErrorKind> {
        if self.selector.current_frame().is_some() {
            return Err(ErrorKind::MidFrameReconfig);
        }
        cfg.validate()?;
        if self.finished || self.selector.status().frames_seen > 0 {
            return if self.hello == Some(cfg) {
                Ok(())
            } else {
                Err(ErrorKind::NeedsReset)
            };
        }
        // A new scan: a new log generation, replacing the old one once
        // durable; a refusal leaves the old one and the state as they were.
        let payload = Record::Begin(cfg)
            .encode(&[], &mut self.record)
            .map_err(|_| ErrorKind::Internal)?;
        journal.start(payload).map_err(storage_error)?;
        // No frame was seen, but a restore may have brought back a database
        // frame taken before its first decision was stored: not this scan's.
        self.selector.reset();
        self.restored = false;
        self.configure(cfg)?;
        self.stored = u32::from(journal.keeps());
        self.durable_db = 0;
        self.storage_failed = false;
        Ok(())
    }

    /// Configures the selector with `cfg` (no frames seen yet).
    fn configure(&mut self, cfg: Config) -> Result<(), ErrorKind> {
        self.selector
            .configure(cfg.scan_config(), cfg.selector_config())
            .map_err(select_error)?;
        self.hello = Some(cfg);
        Ok(())
    }

    /// Reset: forgets the scan, in the log first.
    fn reset_logged(&mut self, journal: &mut dyn Journal) -> Result<(), ErrorKind> {
        let payload = Record::Cleared
            .encode(&[], &mut self.record)
            .map_err(|_| ErrorKind::Internal)?;
        journal.start(payload).map_err(storage_error)?;
        self.reset();
        Ok(())
    }

    /// Replays log record number `n` at boot.
    fn apply(&mut self, payload: &[u8], n: u32) -> Result<(), RestoreFailure> {
        let malformed = RestoreFailure::Malformed { record: n };
        let refused = |error| RestoreFailure::Refused { record: n, error };
        let (record, hashes) = Record::decode(payload).map_err(|_| malformed)?;
        match record {
            Record::Begin(cfg) if n == 0 => {
                cfg.validate()
                    .and_then(|()| self.configure(cfg))
                    .map_err(|_| RestoreFailure::BadConfig { record: n })?;
            }
            Record::Cleared if n == 0 => {}
            Record::Begin(_) | Record::Cleared => return Err(malformed),
            Record::Database {
                meta, voxels, aabb, ..
            } => {
                let sketch = Sketch::from_hashes(hashes.iter()).ok_or(malformed)?;
                let frame = DbSnapshot {
                    meta,
                    voxels,
                    aabb,
                    sketch,
                };
                self.selector.restore_database(&frame).map_err(refused)?;
            }
            Record::Decided {
                frame,
                timestamp,
                kind,
            } => {
                self.selector
                    .restore_decided(frame, kind.into())
                    .map_err(refused)?;
                self.labels.begin(frame, timestamp);
                if let Some(class) = kind.class(frame) {
                    self.labels.decide(frame, class);
                }
            }
            Record::Finished => self.finished = true,
        }
        Ok(())
    }

    /// Checks that frame messages are allowed now.
    fn scanning(&self) -> Result<(), ErrorKind> {
        if self.hello.is_none() {
            Err(ErrorKind::NotConfigured)
        } else if self.finished {
            Err(ErrorKind::Finished)
        } else {
            Ok(())
        }
    }

    fn frame_begin(&mut self, meta: FrameMeta) -> Result<(), ErrorKind> {
        self.scanning()?;
        self.selector.begin_frame(meta).map_err(select_error)?;
        self.labels.begin(meta.index, meta.timestamp);
        Ok(())
    }

    fn depth_rows(&mut self, rows: &crate::protocol::DepthRows<'_>) -> Result<(), ErrorKind> {
        self.scanning()?;
        let open = self.selector.current_frame().map(|m| m.index);
        let (Some(cfg), Some(index)) = (self.hello.as_ref(), open) else {
            return Err(ErrorKind::OutOfOrder);
        };
        if rows.frame != index {
            return Err(ErrorKind::OutOfOrder);
        }
        rows.check(cfg.width_sent(), cfg.height_sent())?;
        let n = rows.data.len() / 2;
        let values = self.rows.get_mut(..n).ok_or(ErrorKind::Oversized)?;
        for (v, b) in values.iter_mut().zip(rows.data.chunks_exact(2)) {
            *v = match b {
                [lo, hi] => u16::from_le_bytes([*lo, *hi]),
                _ => 0,
            };
        }
        let values = self.rows.get(..n).ok_or(ErrorKind::Internal)?;
        self.selector
            .push_rows(rows.first_row, values)
            .map_err(select_error)
    }

    fn frame_end(
        &mut self,
        frame: u32,
        t0: u64,
        journal: &mut dyn Journal,
        send: &mut dyn FnMut(&[u8]),
    ) -> Result<(), ErrorKind> {
        self.scanning()?;
        match self.selector.current_frame() {
            Some(m) if m.index == frame => {}
            _ => return Err(ErrorKind::FrameEndWithoutBegin),
        }
        // Room for this step and, after it, a Finish of a full window, so
        // that a scan whose log is full still ends with every frame decided.
        let sending = self.decide(journal, 4 * W + 2, send, |s, emit| s.end_frame(emit))?;
        let end = delta(self.clock, t0, sending);
        let rows = self.rows_ticks;
        let c = &mut self.cost;
        c.frames = c.frames.saturating_add(1);
        c.total = c.total.saturating_add(rows.saturating_add(end));
        c.last_rows = u32::try_from(rows).unwrap_or(u32::MAX);
        c.last_end = u32::try_from(end).unwrap_or(u32::MAX);
        c.max = c.max.max(c.last_rows.saturating_add(c.last_end));
        self.rows_ticks = 0;
        Ok(())
    }

    fn frame_abort(&mut self, frame: u32) -> Result<(), ErrorKind> {
        self.scanning()?;
        match self.selector.current_frame() {
            Some(m) if m.index == frame => {}
            _ => return Err(ErrorKind::FrameEndWithoutBegin),
        }
        self.selector.abort_frame();
        self.rows_ticks = 0;
        Ok(())
    }

    fn finish(
        &mut self,
        journal: &mut dyn Journal,
        send: &mut dyn FnMut(&[u8]),
    ) -> Result<(), ErrorKind> {
        if self.hello.is_none() {
            return Err(ErrorKind::NotConfigured);
        }
        if self.finished {
            return Ok(());
        }
        self.decide(journal, 2 * W + 1, send, |s, emit| s.finish(emit))?;
        self.finished = true;
        self.persist(journal, &Record::Finished);
        Ok(())
    }

    /// Appends a record unless a write already failed in this scan (a later
    /// record after a missing one would not restore).
    fn persist(&mut self, journal: &mut dyn Journal, record: &Record) {
        self.persist_with(journal, record, &[]);
    }

    fn persist_with(&mut self, journal: &mut dyn Journal, record: &Record, sketch: &[u32]) {
        if self.storage_failed {
            return;
        }
        let written = record
            .encode(sketch, &mut self.record)
            .map_err(|_| LogError::TooLarge)
            .and_then(|payload| journal.append(payload));
        match written {
            Ok(()) => self.stored = self.stored.saturating_add(u32::from(journal.keeps())),
            Err(_) => self.storage_failed = true,
        }
    }

    /// Runs a selector step that decides frames, if the journal has room for
    /// `records` records: each decision is sent and
    /// its label stored. Returns the ticks spent sending, which the frame
    /// cost leaves out (they measure the link, not the device).
    ///
    /// The decisions are held until the database frames taken and the final
    /// decisions are in the journal; only then do they go out.
    fn decide(
        &mut self,
        journal: &mut dyn Journal,
        records: usize,
        send: &mut dyn FnMut(&[u8]),
        step: impl FnOnce(
            &mut Selector<FV, POOL, DB, W, K>,
            &mut dyn FnMut(FrameDecision),
        ) -> Result<(), SelectError>,
    ) -> Result<u64, ErrorKind> {
        // `records` bounds what may be written (worst case of a step: every
        // window frame decided and taken, and the Finished mark). Checked
        // first so that a refusal changes nothing.
        if !self.storage_failed && !journal.has_room(records, Self::DB_RECORD_LEN) {
            return Err(ErrorKind::StorageFull);
        }
        let Core {
            selector,
            decisions,
            ..
        } = self;
        decisions.clear();
        step(selector, &mut |d| {
            // At most W final decisions and one Pending per step.
            let _ = decisions.push(d);
        })
        .map_err(select_error)?;
        for i in self.durable_db..self.selector.database_len() {
            if let Some(f) = self.selector.database_snapshot(i) {
                let record = Record::Database {
                    meta: f.meta,
                    voxels: f.voxels,
                    aabb: f.aabb,
                    hashes: f.sketch.hashes().len() as u16,
                };
                self.persist_with(journal, &record, f.sketch.hashes());
            }
        }
        self.durable_db = self.selector.database_len();
        for i in 0..self.decisions.len() {
            let Some(&d) = self.decisions.get(i) else {
                break;
            };
            if d.decision != crate::Decision::Pending {
                let record = Record::Decided {
                    frame: d.index,
                    timestamp: self.labels.timestamp(d.index),
                    kind: d.decision.into(),
                };
                self.persist(journal, &record);
            }
        }
        let clock = self.clock;
        let Core {
            labels,
            tx,
            decisions,
            ..
        } = self;
        let mut out = Out {
            tx,
            send,
            clock,
            ticks: 0,
        };
        for &d in decisions.iter() {
            decided(labels, &mut out, d);
        }
        Ok(out.ticks)
    }

    /// Total export records now.
    fn export_len(&self) -> usize {
        self.selector.database_len().saturating_add(self.labels.len)
    }

    fn export(&mut self, seq: u32, from_record: u32, max: u32, send: &mut dyn FnMut(&[u8])) {
        let total = self.export_len();
        let from = from_record as usize;
        let end = from.saturating_add(max as usize).min(total);
        if from > total {
            self.refused = self.refused.saturating_add(1);
            return self.out(send).reply(&DeviceMessage::Error {
                seq: Some(seq),
                kind: ErrorKind::ExportPastEnd,
            });
        }
        let Core {
            selector,
            labels,
            tx,
            clock,
            ..
        } = self;
        let mut out = Out {
            tx,
            send,
            clock: *clock,
            ticks: 0,
        };
        let mut crc = ExportCrc::new();
        let mut emit = |record: ExportRecord| {
            crc.add(&record);
            out.reply(&DeviceMessage::ExportRecord(record));
        };
        // Database records in frame order: repeatedly the smallest frame index
        // above the last one (the database holds distinct frames).
        let db = selector.database_len();
        let mut last: Option<u32> = None;
        for r in 0..db.min(end) {
            let next = (0..db)
                .filter_map(|i| selector.database_record(i))
                .filter(|rec| last.is_none_or(|l| rec.index > l))
                .min_by_key(|rec| rec.index);
            let Some(rec) = next else { break };
            last = Some(rec.index);
            if r >= from {
                emit(ExportRecord {
                    record: to_u32(r),
                    frame: rec.index,
                    timestamp: rec.timestamp,
                    kind: RecordKind::Database { pose: rec.pose },
                });
            }
        }
        for j in from.saturating_sub(db)..end.saturating_sub(db) {
            if let Some((timestamp, class)) = labels.get(j) {
                emit(ExportRecord {
                    record: to_u32(db + j),
                    frame: to_u32(j),
                    timestamp,
                    kind: RecordKind::Label { class },
                });
            }
        }
        let (count, crc32) = (crc.count(), crc.value());
        out.reply(&DeviceMessage::ExportEnd {
            seq,
            from_record,
            count,
            crc32,
        });
    }
}

/// One decision of the selector: label store, then the Decision message.
fn decided<const N: usize>(labels: &mut Labels<N>, out: &mut Out<'_>, d: FrameDecision) {
    let kind = DecisionKind::from(d.decision);
    if let Some(class) = kind.class(d.index) {
        labels.decide(d.index, class);
    }
    out.reply(&DeviceMessage::Decision {
        frame: d.index,
        kind,
    });
}

#[cfg(test)]
mod tests {
    extern crate std;

    use super::*;
    use crate::camera::{DepthRange, Intrinsics, Pose};
    use crate::protocol::{encode, DepthRows, Feed, PROTOCOL_VERSION};
    use crate::select::SelectorConfig;
    use crate::{ScanConfig, VoxelGrid};
    use proptest::prelude::*;
    use std::vec;
    use std::vec::Vec;

    type Small = Device<1024, 8192, 16, 8, 16, 64>;
    /// Runs out of database and labels quickly.
    type Tiny = Device<1024, 2048, 2, 4, 16, 5>;

    const W: u16 = 64;
    const H: u16 = 48;
    const STRIDE: u16 = 2;

    fn config(window: u16) -> Config {
        let scan = ScanConfig {
            intrinsics: Intrinsics {
                width: W,
                height: H,
                fx: 50.0,
                fy: 50.0,
                cx: 31.5,
                cy: 23.5,
            },
            depth_scale: 1000.0,
            range: DepthRange::default(),
            stride: STRIDE,
            grid: VoxelGrid {
                voxel_size: 0.1,
                origin: [0.0; 3],
            },
        };
        Config::new(
            &scan,
            &SelectorConfig {
                mu: 0.3,
                window,
                sketch_margin: 0.05,
            },
        )
    }

    /// Sampled rows of frame `i`: a wavy wall about 3 m ahead of a camera
    /// moving sideways, every 7th frame blank.
    fn frame_rows(i: u32) -> Vec<u16> {
        let (ws, hs) = (W.div_ceil(STRIDE), H.div_ceil(STRIDE));
        let mut out = Vec::new();
        for v in 0..hs {
            for u in 0..ws {
                let x = 0.15 * i as f32 + (f32::from(u * STRIDE) - 31.5) / 50.0 * 3.0;
                let d = if i % 7 == 6 {
                    0
                } else {
                    (3000.0 + 400.0 * libm::sinf(2.0 * x) + 5.0 * f32::from(v)) as u16
                };
                out.push(d);
            }
        }
        out
    }

    fn pose(i: u32) -> Pose {
        Pose {
            translation: [0.15 * i as f32, 0.0, 0.0],
            rotation: [0.0, 0.0, 0.0, 1.0],
        }
    }

    fn timestamp(i: u32) -> f64 {
        1_305_031_102.175_304 + f64::from(i) / 30.0
    }

    /// Owned copies of the messages a device can send (it never logs).
    fn owned(msg: DeviceMessage<'_>) -> DeviceMessage<'static> {
        msg.into_static().expect("the device does not log")
    }

    fn terminal(msg: &DeviceMessage<'_>) -> Option<Option<u32>> {
        match msg {
            DeviceMessage::Ack { seq } | DeviceMessage::ExportEnd { seq, .. } => Some(Some(*seq)),
            DeviceMessage::Status(s) => Some(Some(s.seq)),
            DeviceMessage::Error { seq, .. } => Some(*seq),
            _ => None,
        }
    }

    /// A device and a host-side decoder of its replies.
    struct Bench<D> {
        device: std::boxed::Box<D>,
        seq: u32,
    }

    macro_rules! bench_impl {
        ($t:ty) => {
            #[allow(dead_code)]
            impl Bench<$t> {
                fn new() -> Self {
                    Bench {
                        device: std::boxed::Box::new(<$t>::new()),
                        seq: 0,
                    }
                }

                /// Feeds `bytes` in chunks of `chunk` and decodes every reply.
                fn feed(&mut self, bytes: &[u8], chunk: usize) -> Vec<DeviceMessage<'static>> {
                    let mut raw = Vec::new();
                    for c in bytes.chunks(chunk.max(1)) {
                        self.device.receive(c, &mut |f: &[u8]| raw.push(f.to_vec()));
                    }
                    raw.iter()
                        .map(|f| {
                            assert!(f.len() <= MAX_REPLY_LEN);
                            assert_eq!(f.last(), Some(&0));
                            assert!(!f[..f.len() - 1].contains(&0));
                            let mut dec = FrameDecoder::<MAX_REPLY_LEN>::new();
                            match dec.feed::<DeviceMessage>(f) {
                                Feed::Frame {
                                    result: Ok(m),
                                    remaining: [],
                                } => owned(m),
                                other => panic!("bad reply frame: {other:?}"),
                            }
                        })
                        .collect()
                }

                /// Sends one message; checks it gets exactly one terminal reply,
                /// last, with its sequence number; returns every reply.
                fn send(&mut self, msg: HostMessage<'_>) -> Vec<DeviceMessage<'static>> {
                    self.seq += 1;
                    let mut buf = vec![0u8; MAX_FRAME_LEN];
                    let frame = encode(&HostFrame { seq: self.seq, msg }, &mut buf).unwrap();
                    let frame = frame.to_vec();
                    let replies = self.feed(&frame, frame.len());
                    let terminals: Vec<_> = replies.iter().filter_map(terminal).collect();
                    assert_eq!(terminals, vec![Some(self.seq)], "{msg:?} -> {replies:?}");
                    assert!(terminal(replies.last().unwrap()).is_some());
                    replies
                }

                fn ok(&mut self, msg: HostMessage<'_>) -> Vec<DeviceMessage<'static>> {
                    let replies = self.send(msg);
                    assert!(
                        matches!(replies.last(), Some(DeviceMessage::Ack { .. })),
                        "{msg:?} -> {replies:?}"
                    );
                    replies
                }

                fn refused(&mut self, msg: HostMessage<'_>) -> ErrorKind {
                    match self.send(msg).as_slice() {
                        [DeviceMessage::Error { kind, .. }] => *kind,
                        other => panic!("{msg:?} accepted: {other:?}"),
                    }
                }

                fn status(&mut self) -> Status {
                    match self.send(HostMessage::StatusRequest).as_slice() {
                        [DeviceMessage::Status(s)] => *s,
                        other => panic!("no status: {other:?}"),
                    }
                }

                /// Streams frame `i` with `rows_per_msg` rows per message;
                /// returns the decisions.
                fn frame(&mut self, i: u32, rows_per_msg: u16) -> Vec<(u32, DecisionKind)> {
                    self.ok(HostMessage::FrameBegin {
                        frame: i,
                        timestamp: timestamp(i),
                        pose: pose(i),
                    });
                    let rows = frame_rows(i);
                    let ws = usize::from(W.div_ceil(STRIDE));
                    let mut first = 0u16;
                    for chunk in rows.chunks(ws * usize::from(rows_per_msg)) {
                        let data: Vec<u8> = chunk.iter().flat_map(|d| d.to_le_bytes()).collect();
                        let n = (chunk.len() / ws) as u16;
                        self.ok(HostMessage::DepthRows(DepthRows {
                            frame: i,
                            first_row: first,
                            row_count: n,
                            data: &data,
                        }));
                        first += n;
                    }
                    decisions(&self.ok(HostMessage::FrameEnd { frame: i }))
                }

                fn export(&mut self, from: u32) -> Vec<ExportRecord> {
                    self.export_some(from, u32::MAX)
                }

                fn export_some(&mut self, from: u32, max: u32) -> Vec<ExportRecord> {
                    let replies = self.send(HostMessage::ExportRequest {
                        from_record: from,
                        max_records: max,
                    });
                    let (last, records) = replies.split_last().unwrap();
                    let records: Vec<ExportRecord> = records
                        .iter()
                        .map(|m| match m {
                            DeviceMessage::ExportRecord(r) => *r,
                            other => panic!("unexpected {other:?}"),
                        })
                        .collect();
                    match last {
                        DeviceMessage::ExportEnd {
                            from_record,
                            count,
                            crc32,
                            ..
                        } => {
                            assert_eq!(*from_record, from);
                            assert_eq!(*count as usize, records.len());
                            assert_eq!(*crc32, crate::protocol::export_crc(&records));
                        }
                        other => panic!("no export end: {other:?}"),
                    }
                    for (k, r) in records.iter().enumerate() {
                        assert_eq!(r.record, from + k as u32);
                    }
                    records
                }
            }
        };
    }
    bench_impl!(Small);
    bench_impl!(Tiny);

    fn decisions(replies: &[DeviceMessage<'_>]) -> Vec<(u32, DecisionKind)> {
        replies
            .iter()
            .filter_map(|m| match m {
                DeviceMessage::Decision { frame, kind } => Some((*frame, *kind)),
                _ => None,
            })
            .collect()
    }

    /// What the selector alone decides on the same frames.
    fn reference<
        const FV: usize,
        const P: usize,
        const DB: usize,
        const WN: usize,
        const K: usize,
    >(
        cfg: &Config,
        frames: u32,
    ) -> (Vec<(u32, DecisionKind)>, Vec<ExportRecord>) {
        let mut sel = std::boxed::Box::new(Selector::<FV, P, DB, WN, K>::new());
        sel.configure(cfg.scan_config(), cfg.selector_config())
            .unwrap();
        let mut got = Vec::new();
        let mut emit = |d: FrameDecision| got.push((d.index, DecisionKind::from(d.decision)));
        for i in 0..frames {
            sel.begin_frame(FrameMeta {
                index: i,
                timestamp: timestamp(i),
                pose: pose(i),
            })
            .unwrap();
            sel.push_rows(0, &frame_rows(i)).unwrap();
            sel.end_frame(&mut emit).unwrap();
        }
        sel.finish(&mut emit).unwrap();
        let mut db: Vec<_> = (0..sel.database_len())
            .map(|i| sel.database_record(i).unwrap())
            .collect();
        db.sort_by_key(|r| r.index);
        let mut records: Vec<ExportRecord> = db
            .iter()
            .map(|r| ExportRecord {
                record: 0,
                frame: r.index,
                timestamp: r.timestamp,
                kind: RecordKind::Database { pose: r.pose },
            })
            .collect();
        let finals: Vec<_> = got
            .iter()
            .filter(|(_, k)| *k != DecisionKind::Pending)
            .collect();
        for (i, k) in finals {
            records.push(ExportRecord {
                record: 0,
                frame: *i,
                timestamp: timestamp(*i),
                kind: RecordKind::Label {
                    class: k.class(*i).unwrap(),
                },
            });
        }
        for (r, rec) in records.iter_mut().enumerate() {
            rec.record = r as u32;
        }
        (got, records)
    }

    fn on_big_stack(f: impl FnOnce() + Send + 'static) {
        std::thread::Builder::new()
            .stack_size(32 << 20)
            .spawn(f)
            .unwrap()
            .join()
            .unwrap();
    }

    #[test]
    fn a_scan_matches_the_selector_and_exports_in_frame_order() {
        on_big_stack(|| {
            let mut b = Bench::<Small>::new();
            assert_eq!(b.status().phase, Phase::Unconfigured);
            let cfg = config(4);
            b.ok(HostMessage::Hello(cfg));
            let n = 30;
            let mut got = Vec::new();
            for i in 0..n {
                got.extend(b.frame(i, 5));
            }
            assert_eq!(b.status().phase, Phase::Ready);
            got.extend(decisions(&b.ok(HostMessage::Finish)));
            let (want, records) = reference::<1024, 8192, 16, 8, 16>(&cfg, n);
            assert_eq!(got, want);
            let st = b.status();
            assert_eq!(st.phase, Phase::Finished);
            assert_eq!((st.frames_seen, st.frames_decided), (n, n));
            assert_eq!(st.capacity(CapacitySlot::Labels).used, n);
            assert_eq!(st.export_records() as usize, records.len());
            assert!(st.database_size > 1 && st.database_size < n);
            assert_eq!(st.degradation, 0);
            let all = b.export(0);
            assert_eq!(all, records);
            // Resume from any record: the tail of the full export.
            for k in [
                1,
                st.database_size,
                st.export_records() - 1,
                st.export_records(),
            ] {
                assert_eq!(b.export(k), records[k as usize..]);
            }
            // In batches of any size.
            for batch in [1, 2, 7, st.database_size, 1000] {
                let mut got = Vec::new();
                loop {
                    let part = b.export_some(got.len() as u32, batch);
                    assert!(part.len() <= batch as usize);
                    if part.is_empty() {
                        break;
                    }
                    got.extend(part);
                }
                assert_eq!(got, records);
            }
            assert_eq!(b.export_some(3, 0), vec![]);
            assert_eq!(
                b.refused(HostMessage::ExportRequest {
                    from_record: st.export_records() + 1,
                    max_records: 1,
                }),
                ErrorKind::ExportPastEnd
            );
            // A repeated Finish is a no-op; frames after Finish are refused.
            assert_eq!(decisions(&b.ok(HostMessage::Finish)), vec![]);
            let begin = HostMessage::FrameBegin {
                frame: n,
                timestamp: 0.0,
                pose: pose(0),
            };
            assert_eq!(b.refused(begin), ErrorKind::Finished);
            assert_eq!(b.export(0), records);
            // Reset forgets everything.
            b.ok(HostMessage::Reset);
            let st = b.status();
            assert_eq!(st.phase, Phase::Unconfigured);
            assert_eq!(st.export_records(), 0);
            assert_eq!(b.refused(begin), ErrorKind::NotConfigured);
        });
    }

    #[test]
    fn byte_by_byte_delivery_gives_the_same_replies() {
        on_big_stack(|| {
            let mut stream = Vec::new();
            let mut buf = vec![0u8; MAX_FRAME_LEN];
            let mut push = |seq: u32, msg: HostMessage<'_>| {
                stream.extend_from_slice(encode(&HostFrame { seq, msg }, &mut buf).unwrap());
            };
            push(1, HostMessage::Hello(config(3)));
            let mut seq = 2;
            for i in 0..8 {
                push(
                    seq,
                    HostMessage::FrameBegin {
                        frame: i,
                        timestamp: timestamp(i),
                        pose: pose(i),
                    },
                );
                let data: Vec<u8> = frame_rows(i).iter().flat_map(|d| d.to_le_bytes()).collect();
                push(
                    seq + 1,
                    HostMessage::DepthRows(DepthRows {
                        frame: i,
                        first_row: 0,
                        row_count: H.div_ceil(STRIDE),
                        data: &data,
                    }),
                );
                push(seq + 2, HostMessage::FrameEnd { frame: i });
                seq += 3;
            }
            push(seq, HostMessage::Finish);
            push(
                seq + 1,
                HostMessage::ExportRequest {
                    from_record: 0,
                    max_records: u32::MAX,
                },
            );
            let whole = Bench::<Small>::new().feed(&stream, stream.len());
            assert_eq!(Bench::<Small>::new().feed(&stream, 1), whole);
            assert_eq!(Bench::<Small>::new().feed(&stream, 61), whole);
            assert!(matches!(
                whole.last(),
                Some(DeviceMessage::ExportEnd { .. })
            ));
        });
    }

    #[test]
    fn a_retransmitted_message_is_answered_again_not_applied_twice() {
        on_big_stack(|| {
            let mut buf = vec![0u8; MAX_FRAME_LEN];
            let mut frames: Vec<Vec<u8>> = Vec::new();
            let mut push = |seq: u32, msg: HostMessage<'_>| {
                frames.push(encode(&HostFrame { seq, msg }, &mut buf).unwrap().to_vec());
            };
            push(1, HostMessage::Hello(config(2)));
            let mut seq = 2;
            for i in 0..8 {
                push(
                    seq,
                    HostMessage::FrameBegin {
                        frame: i,
                        timestamp: timestamp(i),
                        pose: pose(i),
                    },
                );
                let data: Vec<u8> = frame_rows(i).iter().flat_map(|d| d.to_le_bytes()).collect();
                for (k, half) in data.chunks(data.len() / 2).enumerate() {
                    push(
                        seq + 1 + k as u32,
                        HostMessage::DepthRows(DepthRows {
                            frame: i,
                            first_row: 12 * k as u16,
                            row_count: 12,
                            data: half,
                        }),
                    );
                }
                // A refused message (rows again) is answered the same way too.
                push(seq + 3, HostMessage::FrameEnd { frame: i + 1 });
                push(seq + 4, HostMessage::FrameEnd { frame: i });
                seq += 5;
            }
            push(seq, HostMessage::Finish);
            let mut clean = Bench::<Small>::new();
            let mut twice = Bench::<Small>::new();
            for f in &frames {
                let once = clean.feed(f, f.len());
                let first = twice.feed(f, f.len());
                assert_eq!(first, once);
                // The retransmission: only the terminal reply, again.
                let again = twice.feed(f, 7);
                assert_eq!(again.len(), 1);
                assert_eq!(again.last(), once.last());
            }
            let (a, b) = (clean.status(), twice.status());
            assert_eq!(a.frames_seen, 8);
            assert_eq!(b.frames_seen, 8);
            assert_eq!(b.refused, a.refused);
            assert_eq!(twice.export(0), clean.export(0));
            // The same sequence number with another message is not a retry.
            let mut buf = vec![0u8; MAX_FRAME_LEN];
            let reset = encode(
                &HostFrame {
                    seq,
                    msg: HostMessage::Reset,
                },
                &mut buf,
            )
            .unwrap()
            .to_vec();
            assert_eq!(
                twice.feed(&reset, reset.len()),
                vec![DeviceMessage::Ack { seq }]
            );
            assert_eq!(twice.status().phase, Phase::Unconfigured);
        });
    }

    #[test]
    fn hello_rules() {
        on_big_stack(|| {
            let mut b = Bench::<Small>::new();
            let mut bad = config(4);
            bad.version = PROTOCOL_VERSION + 1;
            assert_eq!(b.refused(HostMessage::Hello(bad)), ErrorKind::WrongVersion);
            bad = config(4);
            bad.mu = 1.5;
            assert_eq!(b.refused(HostMessage::Hello(bad)), ErrorKind::BadConfig);
            assert_eq!(b.status().phase, Phase::Unconfigured);
            // Before any frame a Hello replaces the previous one.
            b.ok(HostMessage::Hello(config(2)));
            b.ok(HostMessage::Hello(config(4)));
            b.frame(0, 24);
            b.ok(HostMessage::FrameBegin {
                frame: 1,
                timestamp: 1.0,
                pose: pose(1),
            });
            assert_eq!(
                b.refused(HostMessage::Hello(config(4))),
                ErrorKind::MidFrameReconfig
            );
            let rows = frame_rows(1);
            let data: Vec<u8> = rows.iter().flat_map(|d| d.to_le_bytes()).collect();
            b.ok(HostMessage::DepthRows(DepthRows {
                frame: 1,
                first_row: 0,
                row_count: H.div_ceil(STRIDE),
                data: &data,
            }));
            b.ok(HostMessage::FrameEnd { frame: 1 });
            // After frames: the same Hello is a harmless retry, another one is refused.
            b.ok(HostMessage::Hello(config(4)));
            assert_eq!(
                b.refused(HostMessage::Hello(config(2))),
                ErrorKind::NeedsReset
            );
            assert_eq!(b.status().frames_seen, 2);
            b.ok(HostMessage::Reset);
            b.ok(HostMessage::Hello(config(2)));
        });
    }

    #[test]
    fn refused_messages_change_nothing() {
        on_big_stack(|| {
            let mut b = Bench::<Small>::new();
            let begin = |i: u32| HostMessage::FrameBegin {
                frame: i,
                timestamp: timestamp(i),
                pose: pose(i),
            };
            assert_eq!(b.refused(begin(0)), ErrorKind::NotConfigured);
            assert_eq!(b.refused(HostMessage::Finish), ErrorKind::NotConfigured);
            b.ok(HostMessage::Hello(config(3)));
            for i in 0..5 {
                b.frame(i, 7);
            }
            let before = b.export(0);
            let status = b.status();
            let ws = W.div_ceil(STRIDE);
            let row = vec![0x10u8; usize::from(ws) * 2];
            let rows = |frame: u32, first_row: u16, row_count: u16, data: &'static [u8]| {
                HostMessage::DepthRows(DepthRows {
                    frame,
                    first_row,
                    row_count,
                    data,
                })
            };
            let row: &'static [u8] = std::boxed::Box::leak(row.into_boxed_slice());
            assert_eq!(b.refused(begin(7)), ErrorKind::OutOfOrder);
            assert_eq!(b.refused(begin(4)), ErrorKind::OutOfOrder);
            assert_eq!(b.refused(rows(5, 0, 1, row)), ErrorKind::OutOfOrder);
            assert_eq!(
                b.refused(HostMessage::FrameEnd { frame: 5 }),
                ErrorKind::FrameEndWithoutBegin
            );
            let mut nan = pose(5);
            nan.translation[0] = f32::NAN;
            let bad_pose = HostMessage::FrameBegin {
                frame: 5,
                timestamp: 5.0,
                pose: nan,
            };
            assert_eq!(b.refused(bad_pose), ErrorKind::BadPose);
            let bad_time = HostMessage::FrameBegin {
                frame: 5,
                timestamp: f64::INFINITY,
                pose: pose(5),
            };
            assert_eq!(b.refused(bad_time), ErrorKind::BadPose);
            // Inside frame 5.
            b.ok(begin(5));
            assert_eq!(b.refused(begin(6)), ErrorKind::OutOfOrder);
            assert_eq!(b.refused(rows(4, 0, 1, row)), ErrorKind::OutOfOrder);
            assert_eq!(b.refused(rows(5, 1, 1, row)), ErrorKind::OutOfOrder);
            assert_eq!(b.refused(rows(5, 24, 1, row)), ErrorKind::RowOutOfRange);
            assert_eq!(b.refused(rows(5, 0, 2, row)), ErrorKind::RowTooShort);
            assert_eq!(
                b.refused(rows(5, 0, 1, &row[..row.len() - 2])),
                ErrorKind::RowTooShort
            );
            assert_eq!(b.refused(rows(5, 0, 0, row)), ErrorKind::RowTooLong);
            assert_eq!(
                b.refused(HostMessage::FrameEnd { frame: 5 }),
                ErrorKind::MissingRows
            );
            assert_eq!(
                b.refused(HostMessage::FrameEnd { frame: 4 }),
                ErrorKind::FrameEndWithoutBegin
            );
            assert_eq!(b.refused(HostMessage::Finish), ErrorKind::OutOfOrder);
            // Damaged frames: typed errors, nothing stored changes.
            let replies = b.feed(&[0x05, 0x01, 0x02, 0x03, 0x04, 0x00], 6);
            assert!(matches!(
                replies.as_slice(),
                [DeviceMessage::Error {
                    kind: ErrorKind::BadCrc,
                    ..
                }]
            ));
            let mut long = vec![0x11u8; MAX_FRAME_LEN + 10];
            long.push(0);
            let replies = b.feed(&long, 100);
            assert!(matches!(
                replies.as_slice(),
                [DeviceMessage::Error {
                    seq: None,
                    kind: ErrorKind::Oversized,
                }]
            ));
            assert_eq!(b.export(0), before);
            let after = b.status();
            assert_eq!(after.phase, Phase::InFrame);
            assert_eq!(after.frames_seen, status.frames_seen);
            assert_eq!(after.database_size, status.database_size);
            assert_eq!(after.refused, status.refused + 18);
            assert_eq!(
                after.capacity(CapacitySlot::RxFrame).peak,
                MAX_FRAME_LEN as u32
            );
            // The frame in progress goes on.
            let data: Vec<u8> = frame_rows(5).iter().flat_map(|d| d.to_le_bytes()).collect();
            b.ok(HostMessage::DepthRows(DepthRows {
                frame: 5,
                first_row: 0,
                row_count: 24,
                data: &data,
            }));
            b.ok(HostMessage::FrameEnd { frame: 5 });
        });
    }

    #[test]
    fn full_database_and_labels_degrade_as_documented() {
        on_big_stack(|| {
            let mut b = Bench::<Tiny>::new();
            b.ok(HostMessage::Hello(config(2)));
            let n = 12;
            let mut got = Vec::new();
            for i in 0..n {
                got.extend(b.frame(i, 24));
            }
            got.extend(decisions(&b.ok(HostMessage::Finish)));
            let (want, records) = reference::<1024, 2048, 2, 4, 16>(&config(2), n);
            assert_eq!(got, want);
            assert!(got
                .iter()
                .any(|(_, k)| matches!(k, DecisionKind::Uncovered(_))));
            let st = b.status();
            assert_eq!(st.database_size, 2);
            assert_eq!(st.capacity(CapacitySlot::Labels).used, 5);
            assert_eq!(st.labels_dropped, n - 5);
            assert!(st.uncovered_frames > 0);
            let flags = degradation::LABELS_FULL | degradation::DATABASE_FULL;
            assert_eq!(st.degradation & flags, flags);
            // The export holds the database and the first 5 labels.
            assert_eq!(b.export(0), records[..2 + 5]);
        });
    }

    #[test]
    fn the_clock_measures_frames() {
        use core::sync::atomic::{AtomicU64, Ordering};
        static TICKS: AtomicU64 = AtomicU64::new(0);
        fn tick() -> u64 {
            TICKS.fetch_add(10, Ordering::Relaxed)
        }
        on_big_stack(|| {
            let mut b = Bench::<Small>::new();
            b.device.set_clock(tick, 1000);
            b.ok(HostMessage::Hello(config(3)));
            b.frame(0, 24);
            b.frame(1, 24);
            let st = b.status();
            assert_eq!(st.cost.clock_hz, 1000);
            assert_eq!(st.cost.frames, 2);
            assert!(st.cost.last_rows > 0 && st.cost.last_end > 0);
            assert!(st.cost.total >= u64::from(st.cost.max));
            b.ok(HostMessage::Reset);
            let st = b.status();
            assert_eq!((st.cost.clock_hz, st.cost.frames), (1000, 0));
        });
    }

    #[test]
    fn profiles_match_the_selector_profiles() {
        use crate::profile::by_name;
        fn check<
            const FV: usize,
            const P: usize,
            const DB: usize,
            const WN: usize,
            const K: usize,
            const L: usize,
        >(
            name: &str,
            _: fn() -> Device<FV, P, DB, WN, K, L>,
        ) {
            let p = by_name(name).unwrap();
            assert_eq!(
                (
                    p.frame_voxel_slots,
                    p.pool_words,
                    p.database_frames,
                    p.window,
                    p.sketch
                ),
                (FV, P, DB, WN, K),
                "{name}"
            );
            let size = core::mem::size_of::<Device<FV, P, DB, WN, K, L>>();
            // State, plus room for the stack and the board's own buffers.
            assert!(size + 16 * 1024 <= p.ram, "{name}: {size} B");
        }
        check("ram256k", Device256K::new);
        check("ram512k", Device512K::new);
        check("ram1m", Device1M::new);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]

        /// Junk frames anywhere in a valid stream get errors and change
        /// nothing: the decisions and the export are those of the clean stream.
        #[test]
        fn junk_between_frames_changes_nothing(
            junk in proptest::collection::vec(
                (0usize..40, proptest::collection::vec(any::<u8>(), 0..300)),
                0..6,
            ),
        ) {
            let (tx, rx) = std::sync::mpsc::channel();
            on_big_stack(move || {
                let mut msgs: Vec<Vec<u8>> = Vec::new();
                let mut buf = vec![0u8; MAX_FRAME_LEN];
                let mut seq = 0;
                let mut push = |msg: HostMessage<'_>| {
                    seq += 1;
                    msgs.push(encode(&HostFrame { seq, msg }, &mut buf).unwrap().to_vec());
                };
                push(HostMessage::Hello(config(3)));
                for i in 0..10 {
                    push(HostMessage::FrameBegin { frame: i, timestamp: timestamp(i), pose: pose(i) });
                    let data: Vec<u8> = frame_rows(i).iter().flat_map(|d| d.to_le_bytes()).collect();
                    for (k, half) in data.chunks(data.len() / 2).enumerate() {
                        push(HostMessage::DepthRows(DepthRows {
                            frame: i,
                            first_row: 12 * k as u16,
                            row_count: 12,
                            data: half,
                        }));
                    }
                    push(HostMessage::FrameEnd { frame: i });
                }
                push(HostMessage::Finish);
                push(HostMessage::ExportRequest { from_record: 0, max_records: u32::MAX });
                let clean: Vec<u8> = msgs.concat();
                let mut dirty = Vec::new();
                let mut junk_frames = 0;
                for (k, m) in msgs.iter().enumerate() {
                    for (at, bytes) in &junk {
                        if *at == k {
                            dirty.extend_from_slice(bytes);
                            dirty.push(0);
                            junk_frames += bytes.split(|&b| b == 0).filter(|s| !s.is_empty()).count();
                        }
                    }
                    dirty.extend_from_slice(m);
                }
                let want = Bench::<Small>::new().feed(&clean, 4096);
                let got = Bench::<Small>::new().feed(&dirty, 97);
                let errors = got.iter().filter(|m| matches!(m, DeviceMessage::Error { .. })).count();
                let kept: Vec<_> = got
                    .into_iter()
                    .filter(|m| !matches!(m, DeviceMessage::Error { .. }))
                    .collect();
                tx.send((kept == want, errors, junk_frames)).unwrap();
            });
            let (same, errors, junk_frames) = rx.recv().unwrap();
            prop_assert!(same);
            prop_assert_eq!(errors, junk_frames);
        }
    }
}
