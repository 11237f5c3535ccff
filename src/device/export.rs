//! The export: record `r < database_size` is the `r`-th database frame in
//! frame order (from RAM if resident, else read from the log); record
//! `database_size + j` is the label of frame `j`, read back from the log's
//! decision batches; after the labels, a scan of several sessions has one
//! record per session after the first (its first frame). A cursor
//! remembers where the last request stopped, so exporting in consecutive
//! requests reads the log once, not once per request. A record the log
//! cannot give back (a damaged database frame or decision batch) ends the
//! reply with `ExportUnreadable` (the record, its frame and where in the
//! log it was looked for) instead of an `ExportEnd`: an export is never
//! shorter than the device's count with a count and CRC that agree.

use crate::persist::{Cursor, Journal, Record};
use crate::protocol::{
    DeviceMessage, ErrorKind, ExportCrc, ExportRecord, ExportUnreadable, RecordKind,
};
use crate::select::database::NOWHERE;

use super::durable::LogReader;
use super::reply::{to_u32, Out};
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
    /// Total export records now: database frames, labels, and a record per
    /// session after the first.
    pub(super) fn export_len(&self) -> usize {
        self.selector
            .database_len()
            .saturating_add(self.decisions.labels as usize)
            .saturating_add(self.sessions.len().saturating_sub(1))
    }

    /// Answers an ExportRequest: up to `max` records from `from_record`, then
    /// `ExportEnd` with their count and CRC.
    pub(super) fn export(
        &mut self,
        seq: u32,
        from_record: u32,
        max: u32,
        journal: &mut dyn Journal,
        send: &mut dyn FnMut(&[u8]),
    ) {
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
        let labels = self.decisions.labels;
        let Core {
            selector,
            tx,
            clock,
            export_cursor,
            sessions,
            refused,
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
        let db = selector.database_len();
        // A record the log cannot give back ends the reply with an error
        // naming it, never with an ExportEnd whose count and CRC agree on
        // fewer.
        let mut unreadable = None;
        for r in from.min(db)..end.min(db) {
            let Some(rec) = selector.database_record(r, &mut LogReader(journal)) else {
                let entry = selector.database_entry(r);
                unreadable = Some(ExportUnreadable {
                    seq,
                    record: to_u32(r),
                    frame: entry.map_or(0, |e| e.index),
                    log_at: entry.map(|e| e.at).filter(|&at| at != NOWHERE),
                });
                break;
            };
            emit(ExportRecord {
                record: to_u32(r),
                frame: rec.index,
                timestamp: rec.timestamp,
                kind: RecordKind::Database { pose: rec.pose },
            });
        }
        // Labels of frames `first_label .. last_label`, in log order.
        let (first_label, last_label) = (
            to_u32(from.saturating_sub(db)).min(labels),
            to_u32(end.saturating_sub(db)).min(labels),
        );
        let mut next_label = first_label;
        // The last decision batch read, for the error naming a missing one.
        let mut batch_at = None;
        if first_label < last_label && unreadable.is_none() {
            let (mut cursor, start) = *export_cursor;
            if start > first_label {
                cursor = Cursor::START;
            }
            loop {
                let before = cursor;
                let Ok(Some((at, payload))) = journal.next(&mut cursor) else {
                    break;
                };
                let Ok((record, tail)) = Record::decode(payload) else {
                    continue;
                };
                let Some((first, count)) = record.decision_batch() else {
                    continue;
                };
                if first.saturating_add(u32::from(count)) <= first_label {
                    batch_at = Some(at);
                    continue;
                }
                let mut missing = false;
                for (i, (timestamp, kind, _)) in tail.decisions(&record).enumerate() {
                    let frame = first.saturating_add(i as u32);
                    if (first_label..last_label).contains(&frame) {
                        if frame != next_label {
                            // A decision batch before this one was
                            // unreadable (or skipped): labels are missing.
                            missing = true;
                            break;
                        }
                        next_label = frame.saturating_add(1);
                        emit(ExportRecord {
                            record: to_u32(db.saturating_add(frame as usize)),
                            frame,
                            timestamp,
                            kind: RecordKind::Label {
                                class: kind.class(frame).unwrap_or(frame),
                            },
                        });
                    }
                }
                if missing || first.saturating_add(u32::from(count)) >= last_label {
                    // The next request most likely starts in this batch.
                    *export_cursor = (before, first);
                    break;
                }
                batch_at = Some(at);
            }
        }
        if unreadable.is_none() && next_label < last_label {
            unreadable = Some(ExportUnreadable {
                seq,
                record: to_u32(db.saturating_add(next_label as usize)),
                frame: next_label,
                log_at: batch_at,
            });
        }
        if let Some(what) = unreadable {
            *refused = refused.saturating_add(1);
            return out.reply(&DeviceMessage::ExportUnreadable(what));
        }
        // The sessions after the first, after the labels.
        let before_sessions = db.saturating_add(labels as usize);
        for r in from.max(before_sessions)..end {
            let session = r.saturating_sub(before_sessions).saturating_add(1);
            if let Some(&first) = sessions.get(session) {
                emit(ExportRecord {
                    record: to_u32(r),
                    frame: first,
                    timestamp: 0.0,
                    kind: RecordKind::Session {
                        session: to_u32(session),
                    },
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
