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
//! | DepthRows | the open frame, next strided row, at most `MAX_ROW_VALUES` values | voxelizes the rows | `OutOfOrder`, `RowOutOfRange`, `CapacityExhausted` (more values than the row buffer), `RowTooLong`, `RowTooShort` |
//! | FrameEnd | the open frame, all rows in | selection step; `Decision`s, then Ack | `FrameEndWithoutBegin`, `MissingRows` (frame stays open), `StorageFull` (idem) |
//! | FrameAbort | the open frame | drops it; the next FrameBegin has its index | `FrameEndWithoutBegin`, `NotConfigured`, `Finished` |
//! | Finish | configured, no frame open | decides every pending frame (`Decision`s); phase Finished; a repeated Finish is a no-op | `NotConfigured`, `OutOfOrder`, `StorageFull` |
//! | StatusRequest | always | `Status` | — |
//! | ExportRequest | always | up to `max_records` `ExportRecord`s from `from_record`, then `ExportEnd` | `ExportPastEnd` (`from_record` beyond the last record + 1), `ExportUnreadable` after the records before one the flash log cannot give back |
//! | Reset | always | forgets configuration, frames, database, labels, counters | `StorageFailed` |
//! | LogRead | always | `LogBytes`: up to `LOG_CHUNK` bytes of log record `record` from `offset` | `ExportPastEnd` (no such record, or an offset past its end) |
//! | Extend | a finished scan in the log, the same settings (`Config::same_scan`: the camera may be another), no frame open | writes a session boundary with the new camera, then restores the scan from the log as at boot; the next frame is `frames_seen`; during a session begun so, its very configuration is a no-op Ack | `NothingToExtend` (no finished scan, no flash, a failed write), `ExtendOtherConfig`, `MidFrameReconfig`, `WrongVersion`, `BadConfig`, `StorageFull`, `StorageFailed`, `CapacityExhausted` (`MAX_SESSIONS`) |
//!
//! Durability ([`Device::receive_logged`] with a [`Log`]): the Hello, every
//! database frame and every final decision are written before the replies
//! that acknowledge them (a final decision is acknowledged by its
//! `Decision` message, which waits for its batch). FrameEnd is refused with `StorageFull` unless the
//! log has room for its worst case *and* a Finish after it, so a scan whose
//! log fills up still ends cleanly: FrameAbort the open frame, then Finish.
//! A failed write (not a full log) sets `STORAGE_FAILED`; the step's replies
//! still go out but nothing more is written in this scan. At boot
//! [`Device::restore`] replays the log; records that no scan can hold
//! (damaged flash) end it, and are dropped with everything after them
//! (`TAIL_DROPPED`).
//!
//! Retransmission: the device remembers the sequence number, the message and
//! the terminal reply of the last state-changing message it handled (Hello,
//! FrameBegin, DepthRows, FrameEnd, Finish, Reset, FrameAbort). The same message again
//! with the same sequence number (a host retransmitting because the reply was
//! lost or late) gets that reply again and is not applied twice; its
//! `Decision`s are not sent again. StatusRequest and ExportRequest change
//! nothing and are simply answered again.
//!
//! Where things live: the database frames and the labels live in the
//! journal (the flash log); RAM keeps the window, `R` resident database
//! frames and a 24-byte index entry per database frame (see
//! [`crate::select`]). A device without flash ([`Device::receive`]) keeps
//! its database in RAM (at most `R` frames) and no labels.
//!
//! Labels: one per frame with a final decision, in frame order: its timestamp
//! and class (the covering or nearest database frame, or itself), written to
//! the log in batches of [`crate::persist::record::DECISION_BATCH`] before
//! their `Decision` messages go out (Finish writes the last, partial batch).
//! Labels that cannot be kept (no flash, a failed write) are counted in
//! `labels_dropped`, [`degradation::LABELS_FULL`] is set, and selection goes on.
//!
//! Export: record `r < database_size` is the `r`-th database frame in frame
//! order (pose and timestamp, read from the log unless resident); record
//! `database_size + j` is the label of frame `j`, read from the log. The
//! `ExportEnd` count and CRC cover exactly the records sent.

mod dispatch;
mod durable;
mod export;
mod extend;
#[cfg(feature = "sim-flash")]
pub mod harness;
mod log_read;
mod reply;
mod restore;
mod retransmit;
#[cfg(test)]
mod tests;

pub use restore::RestoreFailure;

use crate::persist::{Cursor, Journal, Log, NoJournal};
use crate::protocol::{
    degradation, Capacity, CapacitySlot, Config, FrameCost, FrameDecoder, Held, HostFrame, Phase,
    Push, ResetCause, Status, CAPACITY_SLOTS, MAX_FRAME_LEN, MAX_REPLY_LEN, MAX_ROW_VALUES,
    MAX_SESSIONS,
};
use crate::select::{FrameDecision, Selector};

use durable::{Decisions, MAX_RECORD_LEN};
use reply::{delta, now, to_u32, Out};
use retransmit::Applied;

pub use crate::profile::{Device1M, Device256K, Device512K};

/// One device: a [`Selector`] of capacities `FV`, `POOL`, `DB`, `W`, `K`, `R`
/// (see [`crate::profile`]) and a receive buffer of [`MAX_FRAME_LEN`] bytes.
/// All zero when new, so a `static` of it costs RAM (`.bss`) but no flash.
#[derive(Debug)]
pub struct Device<
    const FV: usize,
    const POOL: usize,
    const DB: usize,
    const W: usize,
    const K: usize,
    const R: usize,
> {
    decoder: FrameDecoder<MAX_FRAME_LEN>,
    core: Core<FV, POOL, DB, W, K, R>,
}

/// Everything but the receive buffer (which a decoded message borrows).
#[derive(Debug)]
struct Core<
    const FV: usize,
    const POOL: usize,
    const DB: usize,
    const W: usize,
    const K: usize,
    const R: usize,
> {
    selector: Selector<FV, POOL, DB, W, K, R>,
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
    /// Of those, ticks inside the core (voxelizing the rows).
    core_ticks: u64,
    /// Ticks of receive work (the board's USB reads, the framing's scans
    /// and copies) for the message not complete yet: the message they
    /// bring in is charged for them once it is decoded.
    rx_ticks: u64,
    /// The board counts its receive path (it has handed in receive ticks):
    /// only then is the framing's push timed too, as part of it. A board
    /// that does not (QEMU: its UART reads come a few bytes at a time, and
    /// two clock readings a push would be most of what they measured) keeps
    /// the cost as it was.
    rx_timed: bool,
    /// The last state-changing message handled, to answer its retransmission.
    last: Applied,
    /// Decisions of the selection step in progress.
    step: heapless::Vec<FrameDecision, MAX_STEP_DECISIONS>,
    /// Timestamps of the frames not decided yet, by frame index modulo 65
    /// (the window holds at most 64 frames, plus the one being ended).
    timestamps: [f64; 65],
    /// Final decisions on their way to the log, and the labels in it.
    decisions: Decisions,
    /// Where the last export stopped reading labels, and the first frame
    /// of the record there.
    export_cursor: (Cursor, u32),
    /// Encoding buffer of one log record.
    record: [u8; MAX_RECORD_LEN],
    /// Records of this scan in the log (journals that keep records only).
    stored: u32,
    /// Flash bytes this scan occupies, and the most it may.
    flash: (u32, u32),
    /// A log write failed during this scan; nothing more is written.
    storage_failed: bool,
    /// The scan came back from the log at boot.
    restored: bool,
    /// The scan came back from the log at boot unfinished and no host has
    /// resumed it since: the first that does is logged
    /// ([`crate::persist::Record::Resumed`]).
    resume_unlogged: bool,
    /// Records after the restored scan were dropped at boot.
    tail_dropped: bool,
    /// The first frame of each session of the scan, in order (empty until
    /// configured; `[0]` for a scan begun with a Hello).
    sessions: heapless::Vec<u32, MAX_SESSIONS>,
    /// Where the last LogRead found its record (before it).
    log_cursor: Cursor,
    /// Why the board last started (the board says, [`Device::set_last_reset`]);
    /// kept by a Reset.
    last_reset: ResetCause,
}

/// Most decisions one selection step makes: a full window and the Pending
/// of the new frame.
const MAX_STEP_DECISIONS: usize = 65;

impl<
        const FV: usize,
        const POOL: usize,
        const DB: usize,
        const W: usize,
        const K: usize,
        const R: usize,
    > Default for Device<FV, POOL, DB, W, K, R>
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
        const R: usize,
    > Device<FV, POOL, DB, W, K, R>
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
    /// Database frames held whole in RAM.
    pub const RESIDENT: usize = R;

    /// A device after power-on: unconfigured, all state zero (lands in `.bss`).
    pub const fn new() -> Self {
        Device {
            decoder: FrameDecoder::new(),
            core: Core {
                selector: Selector::new(),
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
                core_ticks: 0,
                rx_ticks: 0,
                rx_timed: false,
                last: Applied::NONE,
                step: heapless::Vec::new(),
                timestamps: [0.0; 65],
                decisions: Decisions::new(),
                export_cursor: (Cursor::START, 0),
                record: [0; MAX_RECORD_LEN],
                stored: 0,
                flash: (0, 0),
                storage_failed: false,
                restored: false,
                resume_unlogged: false,
                tail_dropped: false,
                sessions: heapless::Vec::new(),
                log_cursor: Cursor::START,
                last_reset: ResetCause::PowerOn,
            },
        }
    }

    /// Feeds received bytes (any chunking) to a device without flash; see
    /// [`Self::receive_logged`]. Its database is what RAM holds (`R`
    /// frames) and it keeps no labels.
    pub fn receive(&mut self, bytes: &[u8], send: &mut dyn FnMut(&[u8])) {
        self.receive_logged(bytes, &mut NoJournal, send);
    }

    /// Feeds received bytes (any chunking); every complete frame is handled and
    /// each reply is passed to `send` as one complete encoded frame (COBS,
    /// trailing 0x00 included, at most [`MAX_REPLY_LEN`] bytes). Every state
    /// change is made durable in `journal` first: a reply goes out only once
    /// what it acknowledges is stored; the database and labels live there.
    pub fn receive_logged(
        &mut self,
        bytes: &[u8],
        journal: &mut dyn Journal,
        send: &mut dyn FnMut(&[u8]),
    ) {
        let mut rest = bytes;
        while !rest.is_empty() {
            rest = self.receive_message(rest, journal, send).0;
        }
    }

    /// [`Self::receive_logged`] up to the end of the first frame in `bytes`
    /// (its delimiter included): handles that frame, if one ends there, and
    /// returns the bytes after it and whether one ended. A board that acts
    /// between messages (erasing flash ahead once a frame's answer is out)
    /// calls this in a loop instead of scanning for the delimiters itself:
    /// the framing's scan is the only pass over the bytes.
    pub fn receive_message<'i>(
        &mut self,
        bytes: &'i [u8],
        journal: &mut dyn Journal,
        send: &mut dyn FnMut(&[u8]),
    ) -> (&'i [u8], bool) {
        // The framing's pass over the bytes (delimiter scan, copy into
        // the receive buffer) is receive work of the message they end.
        let clock = self.core.clock.filter(|_| self.core.rx_timed);
        let t_push = now(clock);
        let pushed = self.decoder.push(bytes);
        self.core.add_receive_ticks(delta(clock, t_push, 0));
        let (held, remaining) = match pushed {
            Push::NeedMore => (Held::NeedMore, &[][..]),
            Push::Ready { remaining } => (Held::Ready, remaining),
            Push::Error { error, remaining } => (Held::Error(error), remaining),
        };
        (remaining, self.handle_pushed(held, journal, send))
    }

    /// The receive buffer's free room, for a board to read its link's next
    /// bytes straight into (a USB packet: no copy in between); then
    /// [`Self::commit_received`] the bytes read and
    /// [`Self::receive_held`] until [`Self::holds_input`] is false. At
    /// least `want` bytes unless a frame that long is open: see
    /// [`FrameDecoder::spare`] (receive those bytes with
    /// [`Self::receive_message`]). Call it with no input held.
    pub fn receive_room(&mut self, want: usize) -> &mut [u8] {
        self.decoder.spare(want)
    }

    /// Holds the first `n` bytes of the room [`Self::receive_room`] lent as
    /// received input.
    pub fn commit_received(&mut self, n: usize) {
        self.decoder.commit(n);
    }

    /// Whether received input waits for [`Self::receive_held`].
    pub fn holds_input(&self) -> bool {
        self.decoder.holds_input()
    }

    /// [`Self::receive_message`] for the input held
    /// ([`Self::commit_received`]): handles the first frame that ends in it,
    /// if one does, and returns whether one ended; the bytes after it stay
    /// held for the next call.
    pub fn receive_held(&mut self, journal: &mut dyn Journal, send: &mut dyn FnMut(&[u8])) -> bool {
        let clock = self.core.clock.filter(|_| self.core.rx_timed);
        let t_push = now(clock);
        let held = self.decoder.push_held();
        self.core.add_receive_ticks(delta(clock, t_push, 0));
        self.handle_pushed(held, journal, send)
    }

    /// Handles what the framing made of the input: a complete frame's
    /// message, or the refusal of a frame lost. True if a frame ended.
    fn handle_pushed(
        &mut self,
        held: Held,
        journal: &mut dyn Journal,
        send: &mut dyn FnMut(&[u8]),
    ) -> bool {
        let core = &mut self.core;
        match held {
            Held::NeedMore => false,
            Held::Error(error) => {
                // A refused frame's receive work is charged to nobody.
                core.rx_ticks = 0;
                core.note_rx(MAX_FRAME_LEN);
                let mut out = core.out(send);
                out.reply(&error.reply());
                core.refused = core.refused.saturating_add(1);
                true
            }
            Held::Ready => {
                // The delimiter counts: the buffer holds frame_len + 1 bytes.
                core.note_rx(self.decoder.frame_len().saturating_add(1));
                // The message's cost starts when its receive work did:
                // every tick its handling measures from `t0` then
                // includes the receive ticks too (they are protocol
                // work, never the core's share). A message that is not
                // part of a frame drops them.
                let t0 = now(core.clock).wrapping_sub(core.rx_ticks);
                core.rx_ticks = 0;
                core.flash = journal.usage();
                let frame = self.decoder.decode::<HostFrame>();
                core.handle(frame, t0, journal, send);
                core.flash = journal.usage();
                true
            }
        }
    }

    /// Adds `ticks` of the board's receive work (reading the bytes passed
    /// to the next [`Self::receive_logged`] from its link, finding the
    /// message ends in them) to the cost of the message they complete: the
    /// frame's [`FrameCost::total`] includes them, its
    /// [`FrameCost::core`] does not. Count only reads that moved bytes
    /// (idle polls are no frame's work); ignored without a clock. Once a
    /// board has called this, the framing's own pass over the bytes is
    /// timed as receive work as well.
    pub fn add_receive_ticks(&mut self, ticks: u64) {
        self.core.rx_timed = true;
        self.core.add_receive_ticks(ticks);
    }

    /// Gives the device a monotonic clock: `ticks()` counting at `hz` ticks
    /// per second. The status then reports the cost of each frame.
    pub fn set_clock(&mut self, ticks: fn() -> u64, hz: u32) {
        self.core.clock = Some(ticks);
        self.core.cost.clock_hz = hz;
    }

    /// Why the board last started, for [`Status::last_reset`] (the board
    /// reads it at boot; [`ResetCause::PowerOn`] until it is set). A Reset
    /// keeps it: it is the board's, not the scan's.
    pub fn set_last_reset(&mut self, cause: ResetCause) {
        self.core.last_reset = cause;
    }

    /// Drops received input that no message ended yet (a partial frame):
    /// a new host session began (the port was opened again), and its
    /// bytes do not continue the previous session's. The scan is kept.
    pub fn drop_input(&mut self) {
        self.decoder.clear();
    }

    /// Forgets everything but the clock, as [`crate::protocol::HostMessage::Reset`]
    /// does; a partly received frame is dropped too.
    pub fn reset(&mut self) {
        self.decoder.clear();
        self.core.reset();
    }

    /// Rebuilds the scan kept in `log` (at boot): configuration, database,
    /// labels, finished flag. Returns the records replayed; the host resumes
    /// with frame `status().frames_seen`.
    ///
    /// A record that breaks the record grammar or contradicts the records
    /// before it ([`RestoreFailure::unusable_record`]) ends the scan there:
    /// the records before it are kept, the rest are dropped from the log
    /// ([`Log::truncate`]), the scan is restored from what is kept and the
    /// status carries [`degradation::TAIL_DROPPED`]. Otherwise (the first
    /// record is unusable, the log cannot be read, a record needs more than
    /// this device has, or the drop fails) the device is reset and the
    /// failure returned; the log is then left as it is and the next Hello
    /// starts over.
    pub fn restore<F: embedded_storage::nor_flash::NorFlash>(
        &mut self,
        log: &mut Log<F>,
    ) -> Result<u32, RestoreFailure> {
        match self.replay(log) {
            Err(failure) => {
                let keep = failure
                    .unusable_record()
                    .filter(|&n| n > 0)
                    .ok_or(failure)?;
                log.truncate(keep).map_err(|_| failure)?;
                // The same records again, now only the ones kept: the first
                // pass may have applied part of the unusable one.
                let records = self.replay(log)?;
                self.core.tail_dropped = true;
                Ok(records)
            }
            Ok(records) => {
                // The tail a cut may have left weak is made whole before
                // anything is acknowledged on it (see the log's "A record
                // that reads valid once"); the positions just read still
                // read it. A settle that fails changes nothing the log
                // reads: the scan is restored as it is, and a flash that
                // failed here fails the next record, which the status
                // reports. (After a drop there is nothing to settle: what
                // is kept was followed by other writes.)
                let _ = log.settle();
                // What the scan occupies now, as the status reports it
                // before any message refreshes it.
                self.core.flash = Journal::usage(log);
                Ok(records)
            }
        }
    }

    /// Replays the live generation of `log` into a reset device; on failure
    /// the device is reset again.
    fn replay<F: embedded_storage::nor_flash::NorFlash>(
        &mut self,
        log: &mut Log<F>,
    ) -> Result<u32, RestoreFailure> {
        self.decoder.clear();
        let usage = Journal::usage(log);
        let replayed = self.core.replay(&mut |visit| log.replay(visit), usage);
        if replayed.is_ok() {
            self.core.restored = self.core.hello.is_some();
            self.core.resume_unlogged = self.core.restored && !self.core.finished;
        }
        replayed
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
    pub fn selector(&self) -> &Selector<FV, POOL, DB, W, K, R> {
        &self.core.selector
    }
}

impl<
        const FV: usize,
        const POOL: usize,
        const DB: usize,
        const W: usize,
        const K: usize,
        const R: usize,
    > Core<FV, POOL, DB, W, K, R>
{
    /// Bound on the encoded length of a database record: postcard fields
    /// (at most [`durable::DB_FIELDS_LEN`] bytes) and the sketch.
    const DB_RECORD_LEN: usize = {
        let len = durable::DB_FIELDS_LEN + 4 * K;
        assert!(len <= MAX_RECORD_LEN, "sketch too large for a log record");
        len
    };

    /// The longest record a selection step writes.
    const STEP_RECORD_LEN: usize = {
        let d = durable::DECISIONS_RECORD_LEN;
        assert!(
            d <= MAX_RECORD_LEN,
            "decision batch too large for a log record"
        );
        if Self::DB_RECORD_LEN > d {
            Self::DB_RECORD_LEN
        } else {
            d
        }
    };

    fn out<'a>(&'a mut self, send: &'a mut dyn FnMut(&[u8])) -> Out<'a> {
        Out {
            tx: &mut self.tx,
            send,
            clock: self.clock,
            ticks: 0,
        }
    }

    fn add_receive_ticks(&mut self, ticks: u64) {
        if self.clock.is_some() {
            self.rx_ticks = self.rx_ticks.saturating_add(ticks);
        }
    }

    fn note_rx(&mut self, len: usize) {
        self.rx_last = to_u32(len);
        self.rx_peak = self.rx_peak.max(self.rx_last);
    }

    fn reset(&mut self) {
        self.selector.reset();
        self.decisions.clear();
        self.export_cursor = (Cursor::START, 0);
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
        self.core_ticks = 0;
        self.rx_ticks = 0;
        self.last = Applied::NONE;
        self.stored = 0;
        self.storage_failed = false;
        self.restored = false;
        self.resume_unlogged = false;
        self.tail_dropped = false;
        self.sessions.clear();
        self.log_cursor = Cursor::START;
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
        let labels = self.decisions.labels;
        let (flash_used, flash_limit) = self.flash;
        // A label costs about 14 bytes of log (timestamp, kind, its share of
        // the batch header): the limit is an estimate of what still fits.
        let label_room = flash_limit.saturating_sub(flash_used) / 14;
        let mut capacities = [Capacity::default(); CAPACITY_SLOTS];
        for (slot, c) in CapacitySlot::ALL.iter().zip(capacities.iter_mut()) {
            *c = match slot {
                CapacitySlot::Database => usage(st.database),
                CapacitySlot::Labels => Capacity {
                    used: labels,
                    peak: labels,
                    limit: labels.saturating_add(label_room),
                },
                CapacitySlot::Pool => usage(st.pool),
                CapacitySlot::Window => usage(st.window),
                CapacitySlot::FrameVoxels => usage(st.frame_voxels),
                CapacitySlot::RxFrame => Capacity {
                    used: self.rx_last,
                    peak: self.rx_peak,
                    limit: to_u32(MAX_FRAME_LEN),
                },
                CapacitySlot::Resident => usage(st.resident),
                CapacitySlot::Flash => Capacity {
                    used: flash_used,
                    peak: flash_used,
                    limit: flash_limit,
                },
            };
        }
        let flag = |on: bool, bit: u32| if on { bit } else { 0 };
        let device_flags = flag(self.decisions.dropped > 0, degradation::LABELS_FULL)
            | flag(self.storage_failed, degradation::STORAGE_FAILED)
            | flag(self.restored, degradation::RESTORED)
            | flag(self.tail_dropped, degradation::TAIL_DROPPED);
        Status {
            seq,
            phase: self.phase(),
            frames_seen: st.frames_seen,
            frames_decided: st.frames_decided,
            database_size: to_u32(self.selector.database_len()),
            capacities,
            degradation: st.flags | device_flags,
            sketched_frames: st.sketched_frames,
            unkeyed_frames: st.unkeyed_frames,
            sketch_compared_frames: st.sketch_compared_frames,
            truncated_frames: st.truncated_frames,
            uncovered_frames: st.uncovered_frames,
            labels_dropped: self.decisions.dropped,
            out_of_range_points: st.out_of_range_points,
            valid_pixels: st.valid_pixels,
            refused: self.refused,
            cost: self.cost,
            stored_records: self.stored,
            sessions: to_u32(self.sessions.len()),
            session_first: self.sessions.last().copied().unwrap_or(0),
            last_reset: self.last_reset,
        }
    }
}
