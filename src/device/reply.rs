//! Sending replies, and what the core's refusals look like on the wire.

use crate::persist::LogError;
use crate::protocol::{encode, DeviceMessage, ErrorKind, MAX_REPLY_LEN};
use crate::select::SelectError;
use crate::FrameError;

/// Sends encoded replies; measures the time spent sending.
pub(super) struct Out<'a> {
    pub tx: &'a mut [u8; MAX_REPLY_LEN],
    pub send: &'a mut dyn FnMut(&[u8]),
    pub clock: Option<fn() -> u64>,
    /// Ticks spent inside `send` so far.
    pub ticks: u64,
}

impl Out<'_> {
    pub fn reply(&mut self, msg: &DeviceMessage<'_>) {
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

/// The board clock's reading (0 without a clock).
pub(super) fn now(clock: Option<fn() -> u64>) -> u64 {
    clock.map_or(0, |f| f())
}

/// Ticks since `since`, less `minus`.
pub(super) fn delta(clock: Option<fn() -> u64>, since: u64, minus: u64) -> u64 {
    now(clock).wrapping_sub(since).saturating_sub(minus)
}

/// A count for the wire.
pub(super) fn to_u32(n: usize) -> u32 {
    u32::try_from(n).unwrap_or(u32::MAX)
}

/// Maps a failure of the journal to the wire.
pub(super) fn storage_error(e: LogError) -> ErrorKind {
    match e {
        LogError::Full | LogError::TooLarge => ErrorKind::StorageFull,
        LogError::Flash(_) | LogError::BadRange | LogError::NotStarted | LogError::NoRecord => {
            ErrorKind::StorageFailed
        }
    }
}

/// Maps a refusal of the selector to the wire.
pub(super) fn select_error(e: SelectError) -> ErrorKind {
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
