//! LogRead: the bytes of one record of the scan's flash log, in chunks of
//! [`LOG_CHUNK`], so that a host can rebuild every database frame exactly
//! as the device keeps it (its sketch, box and exact keys), e.g. for the
//! extension file of an export. A cursor remembers the record last read,
//! so reading the log record after record, chunk after chunk, reads it once.

use crate::persist::{Cursor, Journal};
use crate::protocol::{DeviceMessage, ErrorKind, LogBytes, LOG_CHUNK};

use super::reply::to_u32;
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
    /// Answers a LogRead of record `record` from byte `offset`.
    pub(super) fn log_read(
        &mut self,
        seq: u32,
        (record, offset): (u32, u32),
        journal: &mut dyn Journal,
        send: &mut dyn FnMut(&[u8]),
    ) {
        let mut cursor = self.log_cursor;
        if cursor.records() > record {
            cursor = Cursor::START;
        }
        let mut reply = None;
        loop {
            let before = cursor;
            let Ok(Some((at, payload))) = journal.next(&mut cursor) else {
                break;
            };
            if before.records() < record {
                continue;
            }
            self.log_cursor = before;
            let from = offset as usize;
            // An offset at the very end is a valid (empty) read of a record.
            if let Some(rest) = payload.get(from..) {
                let len = rest.len().min(LOG_CHUNK);
                let mut chunk = LogBytes {
                    seq,
                    record,
                    at,
                    total: to_u32(payload.len()),
                    offset,
                    len: len as u8,
                    data: [[0; 32]; LOG_CHUNK / 32],
                };
                let data = chunk.data.as_flattened_mut();
                for (d, b) in data.iter_mut().zip(rest.iter().take(len)) {
                    *d = *b;
                }
                reply = Some(DeviceMessage::LogBytes(chunk));
            }
            break;
        }
        let reply = reply.unwrap_or_else(|| {
            self.refused = self.refused.saturating_add(1);
            DeviceMessage::Error {
                seq: Some(seq),
                kind: ErrorKind::ExportPastEnd,
            }
        });
        self.out(send).reply(&reply);
    }
}
