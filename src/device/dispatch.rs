//! Message dispatch: one host message in, its effect on the core, exactly
//! one terminal reply out (see the table in [`super`]).

use crate::frame::FrameMeta;
use crate::persist::{Journal, Record};
use crate::protocol::{
    Config, DecisionKind, DeviceMessage, ErrorKind, HostFrame, HostMessage, ProtocolError,
};
use crate::select::{FrameDecision, FrameStore, SelectError, Selector};

use super::durable::{self, step_records, LogStore};
use super::reply::{delta, now, select_error, storage_error, Out};
use super::retransmit::{Applied, MessageKey};
use super::Core;

impl<
        const FV: usize,
        const POOL: usize,
        const DB: usize,
        const W: usize,
        const K: usize,
        const R: usize,
    > Core<FV, POOL, DB, W, K, R>
{
    /// Handles one received frame (decoded at tick `t0`) with exactly one
    /// terminal reply.
    pub(super) fn handle(
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
        if key == Some(self.last.key) && self.last.seq == seq {
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
                .map(|()| {
                    self.rows_ticks = delta(clock, t0, 0);
                    self.core_ticks = 0;
                }),
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
                return self.export(seq, from_record, max_records, journal, send);
            }
            HostMessage::LogRead { record, offset } => {
                return self.log_read(seq, (record, offset), journal, send);
            }
            HostMessage::Reset => self.reset_logged(journal),
            HostMessage::FrameAbort { frame } => self.frame_abort(frame),
            HostMessage::Extend(cfg) => self.extend(cfg, journal),
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
                self.log_resume(journal);
                Ok(())
            } else {
                Err(ErrorKind::NeedsReset)
            };
        }
        // A new scan: a new log generation, replacing the old one once
        // durable; a refusal leaves the old one and the state as they were.
        let payload = Record::Begin(cfg)
            .encode(&mut self.record)
            .map_err(|_| ErrorKind::Internal)?;
        journal.start(payload).map_err(storage_error)?;
        // No frame was seen, but a restore may have brought back a database
        // frame taken before its first decision was stored: not this scan's.
        self.selector.reset();
        self.decisions.clear();
        self.export_cursor = (crate::persist::Cursor::START, 0);
        self.log_cursor = crate::persist::Cursor::START;
        self.restored = false;
        self.configure(cfg)?;
        self.sessions.clear();
        let _ = self.sessions.push(0);
        self.stored = u32::from(journal.keeps());
        self.storage_failed = false;
        Ok(())
    }

    /// Configures the selector with `cfg` (no frames seen yet).
    pub(super) fn configure(&mut self, cfg: Config) -> Result<(), ErrorKind> {
        // The key budget is the log's: a restore (which configures from the
        // log's Begin) counts it as the scan did.
        let budget = crate::select::database::key_budget_for_log(self.flash.1);
        self.selector.set_key_budget(budget);
        self.selector
            .configure(cfg.scan_config(), cfg.selector_config())
            .map_err(select_error)?;
        self.hello = Some(cfg);
        Ok(())
    }

    /// Reset: forgets the scan, in the log first.
    fn reset_logged(&mut self, journal: &mut dyn Journal) -> Result<(), ErrorKind> {
        let payload = Record::Cleared
            .encode(&mut self.record)
            .map_err(|_| ErrorKind::Internal)?;
        journal.start(payload).map_err(storage_error)?;
        self.reset();
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
        let slot = meta.index as usize % self.timestamps.len();
        if let Some(t) = self.timestamps.get_mut(slot) {
            *t = meta.timestamp;
        }
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
        // The one bound on values per message (`MAX_ROW_VALUES`, the length
        // of `self.rows`) is enforced by the check: refused, not damage.
        rows.check(cfg.width_sent(), cfg.height_sent())?;
        let n = rows.data.len() / 2;
        let values = self.rows.get_mut(..n).ok_or(ErrorKind::Internal)?;
        for (v, b) in values.iter_mut().zip(rows.data.chunks_exact(2)) {
            *v = match b {
                [lo, hi] => u16::from_le_bytes([*lo, *hi]),
                _ => 0,
            };
        }
        let values = self.rows.get(..n).ok_or(ErrorKind::Internal)?;
        let t0 = now(self.clock);
        let pushed = self.selector.push_rows(rows.first_row, values);
        self.core_ticks = self.core_ticks.saturating_add(delta(self.clock, t0, 0));
        pushed.map_err(select_error)
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
        // Room for this step (with the key chunks it may write) and, after
        // it, a Finish of a full window without keys, so that a scan whose
        // log is full still ends with every frame decided.
        let records = 2 * step_records(W) + 1;
        let key_chunks = self.selector.key_chunks_next_frame();
        let ticks = self.decide(
            journal,
            (records, key_chunks),
            false,
            send,
            |s, store, emit| s.end_frame_with(store, emit),
        )?;
        let end = delta(self.clock, t0, ticks.sending);
        let rows = self.rows_ticks;
        let core = self.core_ticks.saturating_add(ticks.step);
        let c = &mut self.cost;
        c.frames = c.frames.saturating_add(1);
        c.total = c.total.saturating_add(rows.saturating_add(end));
        c.core = c.core.saturating_add(core);
        c.last_rows = u32::try_from(rows).unwrap_or(u32::MAX);
        c.last_end = u32::try_from(end).unwrap_or(u32::MAX);
        c.max = c.max.max(c.last_rows.saturating_add(c.last_end));
        self.rows_ticks = 0;
        self.core_ticks = 0;
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
        self.core_ticks = 0;
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
        // The frames taken now keep their keys (a later session is compared
        // with them) when the log has room for them; FrameEnd reserved room
        // for a Finish without keys, so a full log still finishes.
        let records = step_records(W) + 1;
        let key_chunks = self.selector.key_chunks_finish();
        let keyed = key_chunks > 0
            && journal.has_room_then(
                (key_chunks, durable::KEY_RECORD_LEN),
                (records, Self::STEP_RECORD_LEN),
            );
        self.decide(
            journal,
            (records, if keyed { key_chunks } else { 0 }),
            true,
            send,
            |s, store, emit| {
                if keyed {
                    s.finish_with(store, emit)
                } else {
                    s.finish_without_keys(store, emit)
                }
            },
        )?;
        self.finished = true;
        self.persist(journal, &Record::Finished);
        Ok(())
    }

    /// The first resume of a scan restored from flash unfinished goes to
    /// the log when a host resumes it (its Hello, or the Extend of its
    /// session), so that its export says how often and where it was resumed;
    /// only when the log has room for it and a Finish after it (the room a
    /// scan keeps to end cleanly is not spent on it).
    pub(super) fn log_resume(&mut self, journal: &mut dyn Journal) {
        if !core::mem::take(&mut self.resume_unlogged) {
            return;
        }
        let resumed = Record::Resumed {
            at: self.selector.status().frames_seen,
        };
        let Ok(len) = resumed.encode(&mut self.record).map(|p| p.len()) else {
            return;
        };
        let finish = (step_records(W) + 1, Self::STEP_RECORD_LEN);
        if journal.has_room_then((1, len), finish) {
            self.persist(journal, &resumed);
        }
    }

    /// Appends a record unless a write already failed in this scan (a later
    /// record after a missing one would not restore).
    fn persist(&mut self, journal: &mut dyn Journal, record: &Record) {
        if self.storage_failed {
            return;
        }
        let written = match record.encode(&mut self.record) {
            Ok(payload) => journal.append(payload),
            Err(_) => Err(crate::persist::LogError::TooLarge),
        };
        match written {
            Ok(kept) => self.stored = self.stored.saturating_add(u32::from(kept.is_some())),
            Err(_) => self.storage_failed = true,
        }
    }

    /// Runs a selector step that decides frames, if the journal has room for
    /// `records` (records, and key chunk records on top): database frames
    /// taken go to the journal during the
    /// step; final decisions join the batch on its way to the journal (and
    /// go out once it is written; all of them when `flush`); Pending ones go
    /// out at once. Returns the ticks spent sending, which the frame cost
    /// leaves out (they measure the link, not the device), and in the step.
    fn decide(
        &mut self,
        journal: &mut dyn Journal,
        (records, key_chunks): (usize, usize),
        flush: bool,
        send: &mut dyn FnMut(&[u8]),
        step: impl FnOnce(
            &mut Selector<FV, POOL, DB, W, K, R>,
            &mut dyn FrameStore<K>,
            &mut dyn FnMut(FrameDecision),
        ) -> Result<(), SelectError>,
    ) -> Result<StepTicks, ErrorKind> {
        // `records` bounds what may be written; checked first so that a
        // refusal changes nothing. A frame's key chunks come first (before
        // its database record, the decisions and a Finish after them).
        let room = journal.has_room_then(
            (key_chunks, durable::KEY_RECORD_LEN),
            (records, Self::STEP_RECORD_LEN),
        );
        if !self.storage_failed && !room {
            return Err(ErrorKind::StorageFull);
        }
        let Core {
            selector,
            step: decided,
            record,
            storage_failed,
            stored,
            decisions,
            timestamps,
            tx,
            clock,
            ..
        } = self;
        decided.clear();
        let t0 = now(*clock);
        let mut store = LogStore {
            journal,
            record,
            failed: storage_failed,
            stored,
        };
        step(selector, &mut store, &mut |d| {
            // At most W final decisions and one Pending per step.
            let _ = decided.push(d);
        })
        .map_err(select_error)?;
        let step_ticks = delta(*clock, t0, 0);
        let mut out = Out {
            tx,
            send,
            clock: *clock,
            ticks: 0,
        };
        for d in decided.iter() {
            let kind = DecisionKind::from(d.decision);
            if kind == DecisionKind::Pending {
                continue;
            }
            let timestamp = timestamps
                .get(d.index as usize % timestamps.len())
                .copied()
                .unwrap_or(0.0);
            let held = selector.decided_held(d.index).unwrap_or(0);
            decisions.push(d.index, (timestamp, kind, held), &mut store, &mut out);
        }
        if flush {
            decisions.flush(&mut store, &mut out);
        }
        for d in decided
            .iter()
            .filter(|d| d.decision == crate::Decision::Pending)
        {
            out.reply(&DeviceMessage::Decision {
                frame: d.index,
                kind: DecisionKind::Pending,
            });
        }
        Ok(StepTicks {
            sending: out.ticks,
            step: step_ticks,
        })
    }
}

/// Where a selection step's ticks went.
struct StepTicks {
    /// Sending replies (left out of the frame cost).
    sending: u64,
    /// The selector's step itself (the core's share).
    step: u64,
}
