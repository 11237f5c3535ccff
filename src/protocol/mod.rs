//! The wire protocol between a host and a device: messages and framing.
//!
//! # Layers
//!
//! One *frame* on the byte stream (UART, USB CDC-ACM, TCP to an emulator) is
//!
//! ```text
//! COBS( postcard(message) ++ crc32_le(postcard(message)) ) ++ 0x00
//! ```
//!
//! - `message` is a [`HostFrame`] (host to device: a sequence number followed by a
//!   [`HostMessage`]) or a [`DeviceMessage`] (device to host), encoded with
//!   `postcard` (varint integers, little-endian `f32`/`f64`, enum variants as a
//!   varint index, byte slices as a varint length followed by the bytes).
//! - `crc32_le` is CRC-32/ISO-HDLC (the zlib/Ethernet CRC, [`crc::CRC_32_ISO_HDLC`])
//!   of the postcard bytes, appended as 4 little-endian bytes (exactly what
//!   postcard's `use-crc` flavour appends).
//! - COBS removes every 0x00 from the frame body, so 0x00 only ever delimits frames.
//!
//! A frame, delimiter included, is at most [`MAX_FRAME_LEN`] bytes: the device's
//! receive buffer. An empty frame (two consecutive 0x00) is ignored without a
//! reply, so a sender may write a lone 0x00 at any time to resynchronise the
//! receiver after an aborted frame.
//!
//! # Conversation rules
//!
//! - Every host message travels in a [`HostFrame`] with a `u32` sequence number
//!   chosen by the host (normally incrementing, wrapping). The device treats it as
//!   opaque and echoes it back.
//! - Every host frame gets exactly one *terminal* reply carrying its sequence
//!   number: [`DeviceMessage::Ack`] (Hello, FrameBegin, DepthRows, FrameEnd,
//!   Finish, Reset, FrameAbort, Extend), [`DeviceMessage::Status`] (StatusRequest),
//!   [`DeviceMessage::ExportEnd`] (ExportRequest), [`DeviceMessage::LogBytes`]
//!   (LogRead), or [`DeviceMessage::Error`]
//!   (anything refused). Decisions and export records caused by a message are sent
//!   before its terminal reply, so a host may keep several messages in flight and
//!   match replies by sequence number.
//! - A scan is: Hello, then for each frame `i = 0, 1, ...` FrameBegin, DepthRows
//!   (every strided row, in order, any chunking), FrameEnd; then Finish. Export
//!   and status requests are accepted at any time; Reset starts over;
//!   FrameAbort drops a frame that cannot be completed (the next FrameBegin
//!   reuses its index).
//! - Sessions: a finished scan in a device's flash log goes on with a new
//!   session when the host sends Extend (with the scan's configuration)
//!   instead of a Hello, then the new session's frames, numbered on from
//!   the earlier sessions' (`Status::frames_seen`), then Finish.
//! - A device with a flash log (see [`crate::persist`]) replies only once
//!   what it acknowledges is durable, and comes back from a power cut with
//!   the scan it held: `Status::frames_seen` says where to resume.
//! - An export is every database record (in frame order), then one label record
//!   per decided frame (in frame order), then (a scan of several sessions)
//!   one session record per session after the first, numbered from 0; ExportRequest
//!   `from_record = k, max_records = m` sends records `k..k+m` (as many as
//!   exist) and an ExportEnd whose count and CRC ([`export_crc`]) cover
//!   exactly the records sent.
//! - A refused message leaves the device's database exactly as it was.
//! - Retransmission: a host that gets no terminal reply within its timeout, or
//!   an error saying the frame was damaged ([`ErrorKind::is_damage`]), sends the
//!   *same* message with the *same* sequence number again (stop-and-wait: one
//!   message in flight). The device remembers the last state-changing message
//!   (Hello, FrameBegin, DepthRows, FrameEnd, Finish, Reset, FrameAbort, Extend) and its terminal
//!   reply; the same message with the same sequence number gets that reply
//!   again and is not applied twice (its decisions are not repeated: the export
//!   is the record). StatusRequest, ExportRequest and LogRead change nothing
//!   and are answered afresh.
//! - For a frame that fails CRC, [`DeviceMessage::Error::seq`] carries the sequence
//!   number *claimed* by the damaged frame (its first varint) when one can be read;
//!   it is a hint, not a verified value. Framing errors that lose the frame
//!   boundary (oversized, bad COBS) carry `None`.
//!
//! # Depth rows
//!
//! The host pre-subsamples depth: with pixel stride `s` it sends the *strided
//! image* of `width_sent = ceil(width / s)` columns and `height_sent = ceil(height
//! / s)` rows, where strided pixel `(i, j)` is image pixel `(i * s, j * s)`.
//! [`HostMessage::DepthRows`] carries `row_count` consecutive strided rows starting
//! at strided row `first_row`, as little-endian `u16` depth values, row-major,
//! `row_count * width_sent * 2` bytes. [`depth_rows_per_message`] says how many
//! strided rows fit one frame; [`pack_rows`] builds the payload from a
//! full-resolution image.

mod cobs;
mod framing;
mod messages;

pub use framing::{
    encode, export_crc, max_frame_len, pack_rows, strided_len, ExportCrc, Feed, FrameDecoder, Held,
    Push, WireMessage, CRC, MAX_FRAME_LEN,
};
pub use messages::{
    degradation, Capacity, CapacitySlot, Config, DecisionKind, DepthRows, DeviceMessage, ErrorKind,
    ExportRecord, ExportUnreadable, FrameCost, HostFrame, HostMessage, LogBytes, PanicPlace, Phase,
    ProtocolError, RecordKind, ResetCause, Status, UnknownErrorKind, CAPACITY_SLOTS,
    DEPTH_ROWS_OVERHEAD, LOG_CHUNK, MAX_ROW_VALUES, MAX_SESSIONS, PANIC_FILE_LEN,
};

/// Version of this wire protocol; a device refuses a [`HostMessage::Hello`] whose
/// version differs with [`ErrorKind::WrongVersion`]. Bump it on any change of the
/// encoding of an existing message.
///
/// - 1: first version.
/// - 2: `Config` carries the grid origin, window and sketch margin;
///   `DecisionKind::Uncovered`; `ExportRequest::max_records`; `Status` reports every selector counter, peak
///   usage and frame cost; `ErrorKind::NeedsReset` and `MissingRows`.
/// - 3: durable storage: `Status::stored_records`, `ErrorKind::StorageFull`
///   and `StorageFailed`, degradations `STORAGE_FAILED` and `RESTORED`;
///   `HostMessage::FrameAbort`.
/// - 4: the database lives in flash: capacity slots `Resident` and `Flash`;
///   final decisions are sent once durable (in batches, with a flash log).
/// - 5: `FrameCost::core`, the core's share of the frame cost; degradation
///   `TAIL_DROPPED` (a new bit, no change of encoding).
/// - 6: sessions: `HostMessage::Extend`, `Status::sessions` and
///   `session_first`, `RecordKind::Session` (after the labels of a scan of
///   several sessions), `ErrorKind::NothingToExtend` and `ExtendOtherConfig`;
///   `HostMessage::LogRead` and `DeviceMessage::LogBytes` (a log record's
///   bytes).
/// - 7: `Status::unkeyed_frames` and `sketch_compared_frames` (why and how
///   often coverage rests on a sketch estimate);
///   `DeviceMessage::ExportUnreadable` (the record, frame and log position
///   an export cannot read back) replaces `Error` with
///   `ErrorKind::ExportUnreadable`.
/// - 8: `Status::last_reset`, why the board last started (`ResetCause`:
///   power-on, its watchdog, or a panic and its `PanicPlace`).
pub const PROTOCOL_VERSION: u16 = 8;

/// Largest encoded frame (delimiter included) of any [`DeviceMessage`] but a
/// [`DeviceMessage::Log`]: a device's transmit buffer. Longer logs are dropped.
pub const MAX_REPLY_LEN: usize = 320;

/// How many strided rows of `width_sent` depth values fit in one
/// [`HostMessage::DepthRows`] frame of at most [`MAX_FRAME_LEN`] bytes, whatever
/// the sequence number, frame index and row numbers are (worst-case varints).
///
/// Returns 0 when `width_sent` is 0 or when not even one row fits
/// (`width_sent > MAX_ROW_VALUES`): the host must then use a larger stride.
pub const fn depth_rows_per_message(width_sent: u16) -> u16 {
    if width_sent == 0 {
        return 0;
    }
    let rows = MAX_ROW_VALUES / width_sent as usize;
    if rows > u16::MAX as usize {
        u16::MAX
    } else {
        rows as u16
    }
}

#[cfg(test)]
mod tests;
