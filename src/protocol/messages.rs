//! Message types of both directions. Variant order is the wire tag: append new
//! variants at the end, never reorder (or bump [`super::PROTOCOL_VERSION`]).

use crate::camera::{DepthRange, Intrinsics, Pose};
use serde::{Deserialize, Serialize};

/// Worst-case postcard bytes of a [`HostFrame`] holding a [`HostMessage::DepthRows`],
/// not counting the depth bytes themselves: sequence number (5), variant tag (1),
/// frame index (5), first row (3), row count (3), data length varint (3).
pub const DEPTH_ROWS_OVERHEAD: usize = 5 + 1 + 5 + 3 + 3 + 3;

/// Most `u16` depth values one [`HostMessage::DepthRows`] frame can carry within
/// [`super::MAX_FRAME_LEN`] (1007 for a 2 KiB frame): 12 strided rows of 80 values,
/// 1 row of 640.
pub const MAX_ROW_VALUES: usize =
    (super::framing::max_message_len(super::MAX_FRAME_LEN) - DEPTH_ROWS_OVERHEAD) / 2;

/// What goes on the wire from host to device: a sequence number and a message.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HostFrame<'a> {
    /// Chosen by the host, echoed by the device in the terminal reply.
    pub seq: u32,
    /// The message.
    #[serde(borrow)]
    pub msg: HostMessage<'a>,
}

/// Messages from host to device.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum HostMessage<'a> {
    /// Configure the device (the hello). Allowed when no frame is open; a
    /// reconfiguration discards the selection state as [`HostMessage::Reset`] does.
    Hello(Config),
    /// Start frame `frame`; frame indices strictly increase within a run.
    FrameBegin {
        /// Index of the frame in the sequence.
        frame: u32,
        /// Timestamp, seconds.
        timestamp: f64,
        /// Camera-to-world pose.
        pose: Pose,
    },
    /// Consecutive strided depth rows of the open frame.
    #[serde(borrow)]
    DepthRows(DepthRows<'a>),
    /// Close frame `frame`: the device decides (or defers) it.
    FrameEnd {
        /// Index of the frame being closed.
        frame: u32,
    },
    /// End of the sequence: decide every pending frame.
    Finish,
    /// Ask for a [`DeviceMessage::Status`].
    StatusRequest,
    /// Ask for the database and labels, from record `from_record` on.
    ExportRequest {
        /// First record to send (0 for everything); resumes an interrupted export.
        from_record: u32,
    },
    /// Forget everything: configuration, database, labels, counters.
    Reset,
}

/// Configuration carried by [`HostMessage::Hello`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Config {
    /// The host's [`super::PROTOCOL_VERSION`].
    pub version: u16,
    /// Voxel edge, metres.
    pub voxel_size: f32,
    /// IoU threshold of the overlap graph, in `[0, 1)`.
    pub mu: f32,
    /// Depth units per metre.
    pub depth_scale: f32,
    /// Intrinsics of the full-resolution image.
    pub intrinsics: Intrinsics,
    /// Pixel stride the host subsamples with (1 = every pixel).
    pub stride: u16,
    /// Valid depth range, metres.
    pub depth_range: DepthRange,
}

impl Config {
    /// Columns per strided row on the wire: `ceil(width / stride)`.
    pub fn width_sent(&self) -> u16 {
        super::strided_len(self.intrinsics.width, self.stride)
    }

    /// Strided rows per frame on the wire: `ceil(height / stride)`.
    pub fn height_sent(&self) -> u16 {
        super::strided_len(self.intrinsics.height, self.stride)
    }

    /// Checks the version ([`ErrorKind::WrongVersion`]) and that every field is
    /// usable and one strided row fits a frame ([`ErrorKind::BadConfig`]).
    pub fn validate(&self) -> Result<(), ErrorKind> {
        if self.version != super::PROTOCOL_VERSION {
            return Err(ErrorKind::WrongVersion);
        }
        let positive = |x: f32| x.is_finite() && x > 0.0;
        let fields_ok = positive(self.voxel_size)
            && positive(self.depth_scale)
            && self.mu.is_finite()
            && (0.0..1.0).contains(&self.mu)
            && self.stride >= 1
            && self.stride <= Intrinsics::MAX_SIDE
            && self.intrinsics.validate().is_ok()
            && self.depth_range.validate().is_ok();
        if !fields_ok || super::depth_rows_per_message(self.width_sent()) == 0 {
            return Err(ErrorKind::BadConfig);
        }
        Ok(())
    }
}

/// A chunk of consecutive strided depth rows (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct DepthRows<'a> {
    /// Index of the open frame these rows belong to.
    pub frame: u32,
    /// First strided row (image row `first_row * stride`).
    pub first_row: u16,
    /// Number of strided rows in `data`.
    pub row_count: u16,
    /// `row_count * width_sent` little-endian `u16` depth values, row-major.
    pub data: &'a [u8],
}

impl<'a> DepthRows<'a> {
    /// Checks the chunk against the strided image size: rows inside
    /// `0..height_sent` ([`ErrorKind::RowOutOfRange`]) and exactly
    /// `row_count * width_sent * 2` data bytes ([`ErrorKind::RowTooLong`] /
    /// [`ErrorKind::RowTooShort`]). A chunk of zero rows and zero bytes is valid.
    pub fn check(&self, width_sent: u16, height_sent: u16) -> Result<(), ErrorKind> {
        let end = u32::from(self.first_row) + u32::from(self.row_count);
        if end > u32::from(height_sent) {
            return Err(ErrorKind::RowOutOfRange);
        }
        let expected = usize::from(self.row_count) * usize::from(width_sent) * 2;
        match self.data.len() {
            n if n > expected => Err(ErrorKind::RowTooLong),
            n if n < expected => Err(ErrorKind::RowTooShort),
            _ => Ok(()),
        }
    }

    /// The rows as `(strided row index, row bytes)`; each row is `width_sent * 2`
    /// bytes (a trailing partial row, which [`Self::check`] refuses, is skipped).
    /// Yields nothing when `width_sent` is 0.
    pub fn rows(&self, width_sent: u16) -> impl Iterator<Item = (u16, &'a [u8])> + 'a {
        let row_bytes = (usize::from(width_sent) * 2).max(1);
        let data = if width_sent == 0 { &[][..] } else { self.data };
        let first = self.first_row;
        data.chunks_exact(row_bytes)
            .take(usize::from(self.row_count))
            .enumerate()
            .map(move |(i, row)| (first.saturating_add(i as u16), row))
    }

    /// Decodes the little-endian depth values of one row's bytes.
    pub fn values(row: &'a [u8]) -> impl Iterator<Item = u16> + 'a {
        row.chunks_exact(2).map(|b| match b {
            [lo, hi] => u16::from_le_bytes([*lo, *hi]),
            _ => 0,
        })
    }
}

/// Messages from device to host.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum DeviceMessage<'a> {
    /// Terminal reply: message `seq` was accepted.
    Ack {
        /// Sequence number of the accepted message.
        seq: u32,
    },
    /// Terminal reply: a message was refused or a frame could not be read.
    Error {
        /// Sequence number of the offending message; for [`ErrorKind::BadCrc`] the
        /// number the damaged frame claims; `None` when unknown.
        seq: Option<u32>,
        /// What went wrong.
        kind: ErrorKind,
    },
    /// The selector's verdict on a frame (sent before the terminal reply of the
    /// message that caused it; a `Pending` frame gets a final decision later).
    Decision {
        /// Index of the decided frame.
        frame: u32,
        /// The verdict.
        kind: DecisionKind,
    },
    /// Terminal reply to [`HostMessage::StatusRequest`].
    Status(Status),
    /// One exported record (database entry or label), in record order.
    ExportRecord(ExportRecord),
    /// Terminal reply to [`HostMessage::ExportRequest`].
    ExportEnd {
        /// Sequence number of the export request.
        seq: u32,
        /// First record sent (the request's `from_record`).
        from_record: u32,
        /// Number of records sent in this export.
        count: u32,
        /// [`super::export_crc`] of the records sent, in order.
        crc32: u32,
    },
    /// Free-form diagnostic text; never a reply, hosts may print or ignore it.
    #[serde(borrow)]
    Log(&'a str),
}

/// Verdict on one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum DecisionKind {
    /// The frame joins the database.
    Taken,
    /// The frame overlaps database frame `.0` (its class) and is not stored.
    DominatedBy(u32),
    /// Not decided yet (held in the selector's window).
    Pending,
}

/// Device state reported by [`Status`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Phase {
    /// No valid [`HostMessage::Hello`] yet (after boot or reset).
    Unconfigured,
    /// Configured, no frame open.
    Ready,
    /// Between FrameBegin and FrameEnd.
    InFrame,
    /// After Finish: only status, export and reset are accepted.
    Finished,
}

/// Number of capacity slots in [`Status::capacities`].
pub const CAPACITY_SLOTS: usize = 8;

/// Named slots of [`Status::capacities`]; a device fills the slots its
/// design has and leaves the others `(0, 0)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum CapacitySlot {
    /// Database records (taken frames).
    Database = 0,
    /// Label records (one per decided frame).
    Labels = 1,
    /// Entries of the bounded world voxel hash.
    WorldVoxels = 2,
    /// Inverted-index entries (voxel, database frame).
    Postings = 3,
    /// Voxels of the frame being built.
    FrameVoxels = 4,
    /// Undecided frames held by the selector.
    Window = 5,
    /// Per-frame sketches (e.g. MinHash / bottom-k).
    Sketches = 6,
    /// Not assigned yet.
    Reserved = 7,
}

impl CapacitySlot {
    /// Every slot in index order.
    pub const ALL: [CapacitySlot; CAPACITY_SLOTS] = [
        CapacitySlot::Database,
        CapacitySlot::Labels,
        CapacitySlot::WorldVoxels,
        CapacitySlot::Postings,
        CapacitySlot::FrameVoxels,
        CapacitySlot::Window,
        CapacitySlot::Sketches,
        CapacitySlot::Reserved,
    ];

    /// Stable snake_case name (for JSON and logs).
    pub const fn name(self) -> &'static str {
        match self {
            CapacitySlot::Database => "database",
            CapacitySlot::Labels => "labels",
            CapacitySlot::WorldVoxels => "world_voxels",
            CapacitySlot::Postings => "postings",
            CapacitySlot::FrameVoxels => "frame_voxels",
            CapacitySlot::Window => "window",
            CapacitySlot::Sketches => "sketches",
            CapacitySlot::Reserved => "reserved",
        }
    }
}

/// Usage of one bounded resource.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Capacity {
    /// Entries in use (or the high-water mark, as the device documents).
    pub used: u32,
    /// Compile-time limit.
    pub limit: u32,
}

/// Degradation flag bits of [`Status::degradation`]: sticky since the last
/// reset, each set when the device kept working past an exhausted capacity.
pub mod degradation {
    /// A frame had more voxels than the frame voxel set holds; the rest were dropped.
    pub const FRAME_VOXELS_TRUNCATED: u32 = 1 << 0;
    /// The world voxel hash was full; new voxels were not indexed.
    pub const WORLD_VOXELS_FULL: u32 = 1 << 1;
    /// The inverted index was full; some postings were not stored.
    pub const POSTINGS_FULL: u32 = 1 << 2;
    /// The database was full; frames that should have been taken were not stored.
    pub const DATABASE_FULL: u32 = 1 << 3;
    /// The label store was full; later labels were not stored.
    pub const LABELS_FULL: u32 = 1 << 4;
    /// The selector window was full; a frame was decided before its lookahead ended.
    pub const WINDOW_FORCED: u32 = 1 << 5;
    /// Points beyond the voxel key range were skipped.
    pub const VOXEL_OUT_OF_RANGE: u32 = 1 << 6;
    /// Overlaps were estimated from sketches instead of exact voxel sets.
    pub const SKETCH_ESTIMATES: u32 = 1 << 7;
}

/// Terminal reply to [`HostMessage::StatusRequest`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Status {
    /// Sequence number of the status request.
    pub seq: u32,
    /// Device state.
    pub phase: Phase,
    /// Frames closed with FrameEnd since the last reset.
    pub frames_seen: u32,
    /// Frames in the database.
    pub database_size: u32,
    /// Usage and limit of every bounded resource, indexed by [`CapacitySlot`].
    pub capacities: [Capacity; CAPACITY_SLOTS],
    /// [`degradation`] flags.
    pub degradation: u32,
}

impl Status {
    /// The capacity in `slot`.
    pub fn capacity(&self, slot: CapacitySlot) -> Capacity {
        self.capacities
            .get(slot as usize)
            .copied()
            .unwrap_or_default()
    }

    /// Mutable access to the capacity in `slot`.
    pub fn capacity_mut(&mut self, slot: CapacitySlot) -> Option<&mut Capacity> {
        self.capacities.get_mut(slot as usize)
    }
}

/// One exported record; [`super::export_crc`] covers these encodings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ExportRecord {
    /// Position in the export (0-based, over all records).
    pub record: u32,
    /// Index of the frame the record is about.
    pub frame: u32,
    /// Timestamp of that frame, seconds.
    pub timestamp: f64,
    /// Database entry or label.
    pub kind: RecordKind,
}

/// What an [`ExportRecord`] holds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum RecordKind {
    /// The frame is in the database, with its pose.
    Database {
        /// Camera-to-world pose of the frame.
        pose: Pose,
    },
    /// The frame's class label: the database frame index that covers it.
    Label {
        /// Class index (a database frame index).
        class: u32,
    },
}

/// Typed error kinds, on the wire in [`DeviceMessage::Error`] and in
/// [`ProtocolError`]. Append only.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum ErrorKind {
    /// The frame's CRC-32 does not match.
    BadCrc,
    /// The frame is not valid COBS.
    BadFraming,
    /// The frame is longer than the receive buffer (or an encode buffer is too small).
    Oversized,
    /// The frame is too short to hold a CRC.
    Truncated,
    /// The CRC matched but the bytes are not a valid message (or have trailing bytes).
    Decode,
    /// Unknown message variant (a newer protocol?).
    UnknownMessage,
    /// Hello with another [`super::PROTOCOL_VERSION`].
    WrongVersion,
    /// The message is not allowed now (e.g. frame index not increasing, rows of
    /// another frame, rows not consecutive).
    OutOfOrder,
    /// A frame message before any valid Hello.
    NotConfigured,
    /// Hello with unusable values.
    BadConfig,
    /// FrameBegin with a non-finite or non-unit pose, or a non-finite timestamp.
    BadPose,
    /// DepthRows beyond the strided image height.
    RowOutOfRange,
    /// DepthRows with more bytes than its rows need.
    RowTooLong,
    /// DepthRows with fewer bytes than its rows need.
    RowTooShort,
    /// FrameEnd with no open frame, or for another frame.
    FrameEndWithoutBegin,
    /// Hello while a frame is open.
    MidFrameReconfig,
    /// ExportRequest past the last record.
    ExportPastEnd,
    /// A capacity with no defined degradation is exhausted; the message was refused.
    CapacityExhausted,
    /// A frame message after Finish (send Reset first).
    Finished,
    /// The device does not implement this message.
    Unsupported,
    /// Anything else (a bug): the message was refused.
    Internal,
}

impl ErrorKind {
    /// Short human-readable description.
    pub const fn describe(self) -> &'static str {
        match self {
            ErrorKind::BadCrc => "CRC mismatch",
            ErrorKind::BadFraming => "invalid COBS framing",
            ErrorKind::Oversized => "frame larger than the buffer",
            ErrorKind::Truncated => "frame too short",
            ErrorKind::Decode => "undecodable message",
            ErrorKind::UnknownMessage => "unknown message",
            ErrorKind::WrongVersion => "wrong protocol version",
            ErrorKind::OutOfOrder => "message out of order",
            ErrorKind::NotConfigured => "device not configured",
            ErrorKind::BadConfig => "invalid configuration",
            ErrorKind::BadPose => "invalid pose or timestamp",
            ErrorKind::RowOutOfRange => "depth rows out of range",
            ErrorKind::RowTooLong => "depth rows longer than declared",
            ErrorKind::RowTooShort => "depth rows shorter than declared",
            ErrorKind::FrameEndWithoutBegin => "frame end without matching begin",
            ErrorKind::MidFrameReconfig => "reconfiguration inside a frame",
            ErrorKind::ExportPastEnd => "export past the last record",
            ErrorKind::CapacityExhausted => "capacity exhausted",
            ErrorKind::Finished => "sequence finished; reset first",
            ErrorKind::Unsupported => "unsupported message",
            ErrorKind::Internal => "internal error",
        }
    }
}

impl core::fmt::Display for ErrorKind {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.describe())
    }
}

impl core::error::Error for ErrorKind {}

/// A framing or encoding failure, with the sequence number it concerns when known.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ProtocolError {
    /// What went wrong.
    pub kind: ErrorKind,
    /// Sequence number claimed by the damaged frame, if readable.
    pub seq: Option<u32>,
}

impl ProtocolError {
    /// An error without a sequence number.
    pub const fn new(kind: ErrorKind) -> Self {
        ProtocolError { kind, seq: None }
    }

    /// The [`DeviceMessage::Error`] reply reporting this error.
    pub const fn reply(self) -> DeviceMessage<'static> {
        DeviceMessage::Error {
            seq: self.seq,
            kind: self.kind,
        }
    }
}

impl From<ErrorKind> for ProtocolError {
    fn from(kind: ErrorKind) -> Self {
        ProtocolError::new(kind)
    }
}

impl core::fmt::Display for ProtocolError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self.seq {
            Some(seq) => write!(f, "{} (seq {seq})", self.kind),
            None => write!(f, "{}", self.kind),
        }
    }
}

impl core::error::Error for ProtocolError {}
