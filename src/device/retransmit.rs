//! The retransmission cache: the last state-changing message the device
//! handled and its terminal reply, so that a host resending it (its reply
//! was lost or late) gets the same reply and the message is not applied twice.

use crate::protocol::{DeviceMessage, ErrorKind, HostMessage};

/// A state-changing message the device handled and its terminal reply.
/// Plain integers only (no `Option`, whose `None` may be a non-zero niche):
/// a new device stays all zero bytes, in `.bss`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Applied {
    /// The message; [`MessageKey::NONE`] before any.
    pub key: MessageKey,
    pub seq: u32,
    /// Accepted (Ack), else refused with `kind`.
    pub accepted: bool,
    pub kind: ErrorKind,
}

impl Applied {
    pub const NONE: Applied = Applied {
        key: MessageKey::NONE,
        seq: 0,
        accepted: false,
        kind: ErrorKind::BadCrc,
    };

    /// The terminal reply it got.
    pub fn reply(&self) -> DeviceMessage<'static> {
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
/// A Hello (or an Extend) is identified by the configuration it carries, so
/// that a refused one (another stride, say) followed by the right one with
/// the same sequence number (a host run again) gets its own answer, not the
/// refusal again.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct MessageKey {
    /// 0: none; 1 Hello, 2 FrameBegin, 3 DepthRows, 4 FrameEnd, 5 Finish,
    /// 6 Reset, 7 FrameAbort, 8 Extend.
    tag: u8,
    /// The frame, or a Hello's or an Extend's [`crate::protocol::Config::fingerprint`].
    frame: u32,
    first_row: u16,
    row_count: u16,
}

impl MessageKey {
    pub const NONE: MessageKey = MessageKey {
        tag: 0,
        frame: 0,
        first_row: 0,
        row_count: 0,
    };

    /// The key of a state-changing message; `None` for requests that change nothing.
    pub fn of(msg: &HostMessage<'_>) -> Option<MessageKey> {
        let key = |tag, frame, first_row, row_count| MessageKey {
            tag,
            frame,
            first_row,
            row_count,
        };
        Some(match *msg {
            HostMessage::Hello(cfg) => key(1, cfg.fingerprint(), 0, 0),
            HostMessage::FrameBegin { frame, .. } => key(2, frame, 0, 0),
            HostMessage::DepthRows(r) => key(3, r.frame, r.first_row, r.row_count),
            HostMessage::FrameEnd { frame } => key(4, frame, 0, 0),
            HostMessage::Finish => key(5, 0, 0, 0),
            HostMessage::Reset => key(6, 0, 0, 0),
            HostMessage::FrameAbort { frame } => key(7, frame, 0, 0),
            HostMessage::Extend(cfg) => key(8, cfg.fingerprint(), 0, 0),
            HostMessage::StatusRequest
            | HostMessage::ExportRequest { .. }
            | HostMessage::LogRead { .. } => return None,
        })
    }
}
