//! Message types of both directions. Variant order is the wire tag: append new
//! variants at the end, never reorder (or bump [`super::PROTOCOL_VERSION`]).

use crate::camera::{DepthRange, Intrinsics, Pose};
use crate::frame::ScanConfig;
use crate::select::{Decision, SelectorConfig};
use crate::voxel::VoxelGrid;
use serde::{Deserialize, Serialize};

/// Worst-case postcard bytes of a [`HostFrame`] holding a [`HostMessage::DepthRows`],
/// not counting the depth bytes themselves: sequence number (5), variant tag (1),
/// frame index (5), first row (3), row count (3), data length varint (3).
pub const DEPTH_ROWS_OVERHEAD: usize = 5 + 1 + 5 + 3 + 3 + 3;

/// Most `u16` depth values one [`HostMessage::DepthRows`] may carry (1007 for a
/// 2 KiB frame: 12 strided rows of 80 values, 1 row of 640): the device's row
/// buffer, sized so that such a message fits [`super::MAX_FRAME_LEN`] whatever
/// its sequence number, frame index and row numbers are. The one bound on
/// rows per message: [`DepthRows::check`] refuses more with
/// [`ErrorKind::CapacityExhausted`] (a frame with small varints can hold a
/// few more values), and [`super::depth_rows_per_message`] stays within it.
pub const MAX_ROW_VALUES: usize = {
    let values = (super::framing::max_message_len(super::MAX_FRAME_LEN) - DEPTH_ROWS_OVERHEAD) / 2;
    assert!(
        super::framing::max_frame_len(DEPTH_ROWS_OVERHEAD + 2 * values) <= super::MAX_FRAME_LEN,
        "a DepthRows of MAX_ROW_VALUES values must fit a frame"
    );
    values
};

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
    /// Configure the device (the hello). Accepted before the first frame of a
    /// scan (replacing any earlier configuration). Once frames were seen, the
    /// same configuration again is acknowledged without effect (a retry) and
    /// another one is refused with [`ErrorKind::NeedsReset`]; inside a frame,
    /// with [`ErrorKind::MidFrameReconfig`].
    Hello(Config),
    /// Start frame `frame`; frames are numbered 0, 1, 2, ... in sequence order
    /// and the device expects exactly the next one.
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
    /// Ask for the database and labels: records `from_record..`, at most
    /// `max_records` of them. A host exports in batches, each checked by the
    /// count and CRC of its [`DeviceMessage::ExportEnd`], and resumes from the
    /// first record it does not hold.
    ExportRequest {
        /// First record to send (0 for everything).
        from_record: u32,
        /// Most records to send (`u32::MAX`: to the end).
        max_records: u32,
    },
    /// Forget everything: configuration, database, labels, counters.
    Reset,
    /// Drop the open frame `frame`: its rows so far are forgotten and the
    /// next FrameBegin carries the same index. For a frame that cannot be
    /// completed, e.g. after FrameEnd was refused with
    /// [`ErrorKind::StorageFull`], before ending the scan with Finish.
    FrameAbort {
        /// Index of the open frame.
        frame: u32,
    },
    /// Continue the finished scan the device holds in its flash log with a
    /// new session (protocol 6), configured as the Hello of that scan was:
    /// the device writes a session boundary, rebuilds its state from the log
    /// as at boot (the earlier sessions' database frames compared from
    /// flash) and expects frame `Status::frames_seen` next, the frames of
    /// every earlier session (frames keep global indices). Sent in place of
    /// a Hello; during a session begun so (no Finish since), the same
    /// configuration again is acknowledged without effect (a host resuming
    /// it after a power cut). Refused with [`ErrorKind::NothingToExtend`]
    /// (no finished scan in flash, or a device without flash),
    /// [`ErrorKind::ExtendOtherConfig`] (a setting other than the scan's,
    /// [`Config::same_scan`]: the camera may be another; or, during a
    /// session begun so, another camera than that session's),
    /// `MidFrameReconfig`, `StorageFull`, `StorageFailed`,
    /// `CapacityExhausted` (more than [`MAX_SESSIONS`] sessions).
    Extend(Config),
    /// Ask for the bytes of record `record` (0 = the first, the `Begin`) of
    /// the scan's flash log from byte `offset` of its payload (protocol 6):
    /// answered with one [`DeviceMessage::LogBytes`] of up to [`LOG_CHUNK`]
    /// bytes. What a host needs to rebuild every database frame as the
    /// device holds it (sketch, box, exact keys: `persist::Record`), e.g.
    /// for the extension file of an export. Refused with
    /// [`ErrorKind::ExportPastEnd`] past the last record (or its end).
    LogRead {
        /// Record number in the log's live generation.
        record: u32,
        /// First payload byte wanted.
        offset: u32,
    },
}

/// Most payload bytes one [`DeviceMessage::LogBytes`] carries.
pub const LOG_CHUNK: usize = 192;

/// Terminal reply to [`HostMessage::LogRead`]: `len` bytes of a log
/// record's payload from `offset`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct LogBytes {
    /// Sequence number of the request.
    pub seq: u32,
    /// The record's number in the live generation.
    pub record: u32,
    /// Its position in the log (what a `Database` record's key chunks name).
    pub at: u32,
    /// Bytes in its whole payload.
    pub total: u32,
    /// First payload byte here.
    pub offset: u32,
    /// Bytes here (at most [`LOG_CHUNK`]).
    pub len: u8,
    /// The bytes, in `len` first bytes (the rest 0); in arrays of 32,
    /// which serde encodes without a length.
    pub data: [[u8; 32]; LOG_CHUNK / 32],
}

impl LogBytes {
    /// The payload bytes it carries.
    pub fn bytes(&self) -> &[u8] {
        let all = self.data.as_flattened();
        all.get(..usize::from(self.len)).unwrap_or(all)
    }
}

/// Most sessions one scan holds (the first and its extensions).
pub const MAX_SESSIONS: usize = 32;

/// Configuration carried by [`HostMessage::Hello`]: everything the device's
/// [`ScanConfig`] and [`SelectorConfig`] hold (see [`Config::new`]).
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
    /// World coordinates of the voxel grid's corner, metres (the world origin
    /// `[0, 0, 0]` unless the host reproduces another anchoring).
    pub grid_origin: [f32; 3],
    /// Frames the selector holds undecided (1 = the in-order rule); the device
    /// clamps it to its window capacity. At least 1.
    pub window: u16,
    /// Extra IoU a sketch estimate must show to count as an overlap (>= 0).
    pub sketch_margin: f32,
}

impl Config {
    /// A CRC-32 of the configuration's encoding: two configurations that
    /// differ in any field differ here but for a 2^-32 chance. The
    /// retransmission cache tells a resent Hello or Extend from another
    /// one by it.
    pub fn fingerprint(&self) -> u32 {
        // Every field of a Config encodes in well under 96 bytes.
        let mut buf = [0u8; 96];
        let bytes = postcard::to_slice(self, &mut buf).map_or(&[][..], |b| &*b);
        super::CRC.checksum(bytes)
    }

    /// Whether a session with configuration `next` may extend a scan made
    /// with this one: every setting but the camera (intrinsics and depth
    /// scale) is the same. The camera only turns a frame's depth into
    /// points; what sessions compare, voxel sets on one grid by one rule,
    /// depends on the rest.
    pub fn same_scan(&self, next: &Config) -> bool {
        let camera_aside = Config {
            intrinsics: next.intrinsics,
            depth_scale: next.depth_scale,
            ..*self
        };
        camera_aside == *next
    }

    /// The configuration that sets up a device exactly as `scan` and `sel` set
    /// up a [`crate::Selector`] (what the host's replay of the core uses).
    pub fn new(scan: &ScanConfig, sel: &SelectorConfig) -> Config {
        Config {
            version: super::PROTOCOL_VERSION,
            voxel_size: scan.grid.voxel_size,
            mu: sel.mu,
            depth_scale: scan.depth_scale,
            intrinsics: scan.intrinsics,
            stride: scan.stride,
            depth_range: scan.range,
            grid_origin: scan.grid.origin,
            window: sel.window,
            sketch_margin: sel.sketch_margin,
        }
    }

    /// The scan half of the configuration.
    pub fn scan_config(&self) -> ScanConfig {
        ScanConfig {
            intrinsics: self.intrinsics,
            depth_scale: self.depth_scale,
            range: self.depth_range,
            stride: self.stride,
            grid: VoxelGrid {
                voxel_size: self.voxel_size,
                origin: self.grid_origin,
            },
        }
    }

    /// The selection half of the configuration.
    pub fn selector_config(&self) -> SelectorConfig {
        SelectorConfig {
            mu: self.mu,
            window: self.window,
            sketch_margin: self.sketch_margin,
        }
    }

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
            && self.window >= 1
            && (0.0..=1.0).contains(&self.sketch_margin)
            && self.intrinsics.validate().is_ok()
            && self.depth_range.validate().is_ok()
            && self.scan_config().validate().is_ok();
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
    // As bytes (a length, then the bytes: the bytes a sequence of `u8` has
    // in postcard), so the encoder gets them as one slice, not one by one.
    #[serde(serialize_with = "as_bytes")]
    pub data: &'a [u8],
}

/// Serializes a byte slice as serde bytes ([`DepthRows::data`]).
fn as_bytes<S: serde::Serializer>(data: &&[u8], serializer: S) -> Result<S::Ok, S::Error> {
    serializer.serialize_bytes(data)
}

impl<'a> DepthRows<'a> {
    /// Checks the chunk against the strided image size: rows inside
    /// `0..height_sent` ([`ErrorKind::RowOutOfRange`]), at most
    /// [`MAX_ROW_VALUES`] depth values (`row_count * width_sent`; more are
    /// refused with [`ErrorKind::CapacityExhausted`], which is not damage:
    /// sending it again cannot help, split the rows with
    /// [`super::depth_rows_per_message`]) and exactly
    /// `row_count * width_sent * 2` data bytes ([`ErrorKind::RowTooLong`] /
    /// [`ErrorKind::RowTooShort`]). A chunk of zero rows and zero bytes is valid.
    pub fn check(&self, width_sent: u16, height_sent: u16) -> Result<(), ErrorKind> {
        let end = u32::from(self.first_row) + u32::from(self.row_count);
        if end > u32::from(height_sent) {
            return Err(ErrorKind::RowOutOfRange);
        }
        let values = usize::from(self.row_count) * usize::from(width_sent);
        if values > MAX_ROW_VALUES {
            return Err(ErrorKind::CapacityExhausted);
        }
        let expected = values * 2;
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
    /// Terminal reply to [`HostMessage::LogRead`] (protocol 6).
    LogBytes(LogBytes),
    /// Terminal reply to an [`HostMessage::ExportRequest`] that reached a
    /// record the device cannot read back from its flash log (a damaged
    /// database frame or decision batch; protocol 7): the records before it
    /// were sent, and no `ExportEnd` follows, so an export never ends short
    /// with a count and CRC that agree.
    ExportUnreadable(ExportUnreadable),
}

/// What [`DeviceMessage::ExportUnreadable`] names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ExportUnreadable {
    /// Sequence number of the export request.
    pub seq: u32,
    /// The export record that cannot be read.
    pub record: u32,
    /// Its frame: the database frame, or the frame whose label it is.
    pub frame: u32,
    /// Where in the log the device looked for it (byte position of the
    /// database frame's record, or of the last decision batch it could
    /// read before the missing one); `None` when there is none.
    pub log_at: Option<u32>,
}

impl DeviceMessage<'_> {
    /// The message without a borrow of the receive buffer, for keeping it;
    /// `None` for a [`DeviceMessage::Log`], whose text is borrowed.
    pub fn into_static(self) -> Option<DeviceMessage<'static>> {
        use DeviceMessage as M;
        Some(match self {
            M::Ack { seq } => M::Ack { seq },
            M::Error { seq, kind } => M::Error { seq, kind },
            M::Decision { frame, kind } => M::Decision { frame, kind },
            M::Status(s) => M::Status(s),
            M::ExportRecord(r) => M::ExportRecord(r),
            M::ExportEnd {
                seq,
                from_record,
                count,
                crc32,
            } => M::ExportEnd {
                seq,
                from_record,
                count,
                crc32,
            },
            M::Log(_) => return None,
            M::LogBytes(b) => M::LogBytes(b),
            M::ExportUnreadable(u) => M::ExportUnreadable(u),
        })
    }
}

/// Verdict on one frame (the wire form of [`Decision`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum DecisionKind {
    /// The frame joins the database.
    Taken,
    /// The frame overlaps database frame `.0` (its class) and is not stored.
    DominatedBy(u32),
    /// Not decided yet (held in the selector's window).
    Pending,
    /// Degraded: no database frame overlaps it and the database is full; the
    /// nearest database frame, if any, is its class.
    Uncovered(Option<u32>),
}

impl From<Decision> for DecisionKind {
    fn from(d: Decision) -> Self {
        match d {
            Decision::Taken => DecisionKind::Taken,
            Decision::DominatedBy(k) => DecisionKind::DominatedBy(k),
            Decision::Pending => DecisionKind::Pending,
            Decision::Uncovered(k) => DecisionKind::Uncovered(k),
        }
    }
}

impl From<DecisionKind> for Decision {
    fn from(d: DecisionKind) -> Self {
        match d {
            DecisionKind::Taken => Decision::Taken,
            DecisionKind::DominatedBy(k) => Decision::DominatedBy(k),
            DecisionKind::Pending => Decision::Pending,
            DecisionKind::Uncovered(k) => Decision::Uncovered(k),
        }
    }
}

impl DecisionKind {
    /// The class label of frame `frame` decided so: the covering (or nearest)
    /// database frame, or the frame itself (taken, or uncovered with no
    /// database frame at all). `None` while pending.
    pub const fn class(self, frame: u32) -> Option<u32> {
        match self {
            DecisionKind::DominatedBy(k) | DecisionKind::Uncovered(Some(k)) => Some(k),
            DecisionKind::Taken | DecisionKind::Uncovered(None) => Some(frame),
            DecisionKind::Pending => None,
        }
    }
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
    /// After Finish: only status, export, a repeated Finish and reset are accepted.
    Finished,
}

/// Number of capacity slots in [`Status::capacities`].
pub const CAPACITY_SLOTS: usize = 8;

/// Named slots of [`Status::capacities`], one per bounded resource of the device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum CapacitySlot {
    /// Database frames (taken frames).
    Database = 0,
    /// Labels (one per decided frame) stored in flash; the limit is what
    /// the log has room for beside them (0 without flash).
    Labels = 1,
    /// Key pool words: exact voxel keys of stored frames.
    Pool = 2,
    /// Undecided frames held by the selector.
    Window = 3,
    /// Distinct voxels of one frame.
    FrameVoxels = 4,
    /// Bytes of one received frame (the receive buffer).
    RxFrame = 5,
    /// Database frames held whole in RAM (the rest live in flash).
    Resident = 6,
    /// Bytes of the flash log this scan occupies (whole sectors), of the
    /// most one scan may use (0 without flash).
    Flash = 7,
}

impl CapacitySlot {
    /// Every slot in index order.
    pub const ALL: [CapacitySlot; CAPACITY_SLOTS] = [
        CapacitySlot::Database,
        CapacitySlot::Labels,
        CapacitySlot::Pool,
        CapacitySlot::Window,
        CapacitySlot::FrameVoxels,
        CapacitySlot::RxFrame,
        CapacitySlot::Resident,
        CapacitySlot::Flash,
    ];

    /// Stable snake_case name (for JSON and logs).
    pub const fn name(self) -> &'static str {
        match self {
            CapacitySlot::Database => "database",
            CapacitySlot::Labels => "labels",
            CapacitySlot::Pool => "pool",
            CapacitySlot::Window => "window",
            CapacitySlot::FrameVoxels => "frame_voxels",
            CapacitySlot::RxFrame => "rx_frame",
            CapacitySlot::Resident => "resident",
            CapacitySlot::Flash => "flash_bytes",
        }
    }
}

/// Usage of one bounded resource.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Capacity {
    /// In use now.
    pub used: u32,
    /// High-water mark since the last reset.
    pub peak: u32,
    /// Compile-time limit.
    pub limit: u32,
}

/// Degradation flag bits of [`Status::degradation`]: sticky since the last
/// reset, each set when the device kept working past an exhausted capacity.
/// The low bits are the selector's own [`crate::select::flags`].
pub mod degradation {
    use crate::select::flags;
    /// A frame had more voxels than the frame voxel set holds; its set was truncated.
    pub const FRAME_VOXELS_FULL: u32 = flags::FRAME_VOXELS_FULL;
    /// A frame's keys did not fit the key pool; it is compared by sketch.
    pub const POOL_FULL: u32 = flags::POOL_FULL;
    /// A frame could not be covered because the database is full (`Uncovered`).
    pub const DATABASE_FULL: u32 = flags::DATABASE_FULL;
    /// Points beyond the voxel key range were skipped.
    pub const OUT_OF_RANGE: u32 = flags::OUT_OF_RANGE;
    /// See [`flags::KEY_BUDGET_SPENT`].
    pub const KEY_BUDGET_SPENT: u32 = flags::KEY_BUDGET_SPENT;
    /// Labels of some frames were not stored (no flash, a full or failed
    /// log); selection went on, and the host received every decision live.
    pub const LABELS_FULL: u32 = 1 << 8;
    /// A flash write failed during a selection step: decisions from then on
    /// are not durable (until the next scan starts).
    pub const STORAGE_FAILED: u32 = 1 << 9;
    /// The scan was restored from flash at boot; the restored database
    /// frames are compared by sketch (their exact keys are not stored).
    pub const RESTORED: u32 = 1 << 10;
    /// The log held records after the restored scan that broke the record
    /// grammar or did not fit the state before them (damaged or adversarial
    /// flash): they were dropped at boot, and the scan goes on from the last
    /// good record.
    pub const TAIL_DROPPED: u32 = 1 << 11;
}

/// Cost of frames on the device, measured with a board clock (all zero when
/// the board gives none). Receiving, decoding, voxelizing and selecting are
/// counted; sending replies is not. `total - core` is the protocol's share:
/// the receive path (what the board times of its link reads that moved a
/// frame's bytes, handed in with `Device::add_receive_ticks`, and the
/// framing's delimiter scan and copy), COBS, CRC, message decoding,
/// dispatch and copying the depth samples.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameCost {
    /// Clock rate, ticks per second (0: no clock). The QEMU board counts
    /// instructions under `-icount shift=0` and reports 1e9.
    pub clock_hz: u32,
    /// Frames measured (ended) since the last reset.
    pub frames: u32,
    /// Ticks of every measured frame together, receive path included.
    pub total: u64,
    /// Ticks of the last frame's FrameBegin and DepthRows (receive, decode,
    /// voxelize).
    pub last_rows: u32,
    /// Ticks of the last frame's FrameEnd (receive, decode, overlaps,
    /// selection).
    pub last_end: u32,
    /// Most ticks of one frame.
    pub max: u32,
    /// Ticks of every measured frame inside the core alone: voxelizing its
    /// rows (projection and the frame's voxel set) and its selection step
    /// (sketch, overlaps, decisions, the database frame it writes). Never
    /// the receive path.
    pub core: u64,
}

impl FrameCost {
    /// Nothing measured, no clock (a `const`, so a device can start from it
    /// in a static).
    pub const ZERO: FrameCost = FrameCost {
        clock_hz: 0,
        frames: 0,
        total: 0,
        last_rows: 0,
        last_end: 0,
        max: 0,
        core: 0,
    };
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
    /// Frames with a final decision.
    pub frames_decided: u32,
    /// Frames in the database.
    pub database_size: u32,
    /// Usage and limit of every bounded resource, indexed by [`CapacitySlot`].
    pub capacities: [Capacity; CAPACITY_SLOTS],
    /// [`degradation`] flags.
    pub degradation: u32,
    /// Frames whose exact keys the key pool could not hold (compared by
    /// sketch; protocol 7 counts only these, not database frames whose keys
    /// are in flash).
    pub sketched_frames: u32,
    /// Frames that arrived after the key budget was spent: they keep no
    /// exact keys (none would be kept in flash) and are compared by sketch
    /// (protocol 7).
    pub unkeyed_frames: u32,
    /// Frames measured by sketch against some database or window frame:
    /// their coverage decision may rest on an estimate (protocol 7).
    pub sketch_compared_frames: u32,
    /// Frames whose voxel set was truncated.
    pub truncated_frames: u32,
    /// Frames decided `Uncovered`.
    pub uncovered_frames: u32,
    /// Frames decided without room for their label.
    pub labels_dropped: u32,
    /// Points dropped for an out-of-range voxel key.
    pub out_of_range_points: u32,
    /// Sampled pixels with a valid depth, over all frames.
    pub valid_pixels: u64,
    /// Host messages and frames refused with an error since the last reset.
    pub refused: u32,
    /// Cost of frames on the device.
    pub cost: FrameCost,
    /// Records of this scan durable in flash (0 on a device without flash).
    pub stored_records: u32,
    /// Sessions of the scan (protocol 6): 1 for a scan begun with a Hello,
    /// one more per [`HostMessage::Extend`]; 0 when unconfigured.
    pub sessions: u32,
    /// The first frame index of the latest session (0 for the first).
    pub session_first: u32,
    /// Why the board last started (protocol 8): a power-on, its watchdog
    /// (the firmware hung), or a panic and where. The board's, not the
    /// scan's: a Reset keeps it, the next boot replaces it.
    pub last_reset: ResetCause,
}

/// Why a board last started ([`Status::last_reset`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ResetCause {
    /// Nothing the firmware recorded: a power-on, the reset pin or a debug
    /// probe; also every board that keeps no record (the QEMU board, the
    /// host's simulated devices).
    PowerOn,
    /// The watchdog reset the board: the firmware stopped feeding it (it
    /// hung, or spent longer than the watchdog's timeout in one place).
    Watchdog,
    /// The firmware panicked at this place of its source, recorded it, and
    /// reset the board (through its watchdog).
    Panic(PanicPlace),
}

/// Most bytes of [`PanicPlace::file`]: the end of the source path, enough
/// for a file and its folders (`src/select/window.rs`).
pub const PANIC_FILE_LEN: usize = 32;

/// Where a firmware panicked: its source file (the path's last
/// [`PANIC_FILE_LEN`] bytes at most, cut after a `/`), line and column.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct PanicPlace {
    /// Bytes of [`Self::file`] in use.
    pub file_len: u8,
    /// The source path's end, UTF-8 (`file_len` bytes, the rest zero).
    pub file: [u8; PANIC_FILE_LEN],
    /// Line, from 1 (0: not known).
    pub line: u32,
    /// Column, from 1 (0: not known).
    pub column: u32,
}

impl PanicPlace {
    /// The place in `file` (its end kept, cut after a `/` when it is
    /// longer than [`PANIC_FILE_LEN`] bytes), `line` and `column`.
    pub fn new(file: &str, line: u32, column: u32) -> PanicPlace {
        let bytes = file.as_bytes();
        let mut start = bytes.len().saturating_sub(PANIC_FILE_LEN);
        if start > 0 {
            // Cut after a '/' (whole folder names), else at a character
            // boundary (a longer file name alone keeps its end).
            let tail = bytes.get(start..).unwrap_or_default();
            match tail.iter().position(|&b| b == b'/') {
                Some(slash) if slash + 1 < tail.len() => start += slash + 1,
                _ => {
                    while start < bytes.len() && !file.is_char_boundary(start) {
                        start += 1;
                    }
                }
            }
        }
        let kept = bytes.get(start..).unwrap_or_default();
        let mut place = PanicPlace {
            file_len: 0,
            file: [0; PANIC_FILE_LEN],
            line,
            column,
        };
        for (to, from) in place.file.iter_mut().zip(kept) {
            *to = *from;
            place.file_len += 1;
        }
        place
    }

    /// The source path's end ("" if it is not UTF-8).
    pub fn file(&self) -> &str {
        let bytes = self
            .file
            .get(..usize::from(self.file_len))
            .unwrap_or_default();
        core::str::from_utf8(bytes).unwrap_or_default()
    }
}

impl core::fmt::Display for PanicPlace {
    /// `file:line:column`, as a compiler names a place.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{}:{}:{}", self.file(), self.line, self.column)
    }
}

impl Status {
    /// A status of `phase` with every counter and capacity zero.
    pub const fn new(seq: u32, phase: Phase) -> Status {
        const ZERO: Capacity = Capacity {
            used: 0,
            peak: 0,
            limit: 0,
        };
        Status {
            seq,
            phase,
            frames_seen: 0,
            frames_decided: 0,
            database_size: 0,
            capacities: [ZERO; CAPACITY_SLOTS],
            degradation: 0,
            sketched_frames: 0,
            unkeyed_frames: 0,
            sketch_compared_frames: 0,
            truncated_frames: 0,
            uncovered_frames: 0,
            labels_dropped: 0,
            out_of_range_points: 0,
            valid_pixels: 0,
            refused: 0,
            cost: FrameCost::ZERO,
            stored_records: 0,
            sessions: 0,
            session_first: 0,
            last_reset: ResetCause::PowerOn,
        }
    }

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

    /// Records in a full export now: database records, labels, then one
    /// session record per session after the first.
    pub fn export_records(&self) -> u32 {
        self.database_size
            .saturating_add(self.capacity(CapacitySlot::Labels).used)
            .saturating_add(self.sessions.saturating_sub(1))
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
    /// Session `session` (1 for the first extension; protocol 6) began with
    /// the record's `frame`; its `timestamp` is 0. Sent only for a scan of
    /// more than one session, after the labels: a frame belongs to the
    /// latest session beginning at or before it.
    Session {
        /// The session's number (the first session, 0, has no record).
        session: u32,
    },
}

/// Typed error kinds, on the wire in [`DeviceMessage::Error`] and in
/// [`ProtocolError`]. On the wire a kind is its number (a postcard varint,
/// the encoding of a serde variant index, so the bytes are those of a plain
/// enum): append only, never renumber or reuse a number (19 is retired).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(into = "u32", try_from = "u32")]
#[repr(u8)]
pub enum ErrorKind {
    /// The frame's CRC-32 does not match.
    BadCrc = 0,
    /// The frame is not valid COBS.
    BadFraming = 1,
    /// The frame is longer than the receive buffer (or an encode buffer is too small).
    Oversized = 2,
    /// The frame is too short to hold a CRC.
    Truncated = 3,
    /// The CRC matched but the bytes are not a valid message (or have trailing bytes).
    Decode = 4,
    /// Unknown message variant (a newer protocol?).
    UnknownMessage = 5,
    /// Hello with another [`super::PROTOCOL_VERSION`].
    WrongVersion = 6,
    /// The message is not allowed now (e.g. frame index not increasing, rows of
    /// another frame, rows not consecutive).
    OutOfOrder = 7,
    /// A frame message before any valid Hello.
    NotConfigured = 8,
    /// Hello with unusable values.
    BadConfig = 9,
    /// FrameBegin with a non-finite or non-unit pose, a non-finite timestamp,
    /// or a camera so far from the grid origin that its coordinates leave the
    /// fixed-point range.
    BadPose = 10,
    /// DepthRows beyond the strided image height.
    RowOutOfRange = 11,
    /// DepthRows with more bytes than its rows need.
    RowTooLong = 12,
    /// DepthRows with fewer bytes than its rows need.
    RowTooShort = 13,
    /// FrameEnd with no open frame, or for another frame.
    FrameEndWithoutBegin = 14,
    /// Hello while a frame is open.
    MidFrameReconfig = 15,
    /// ExportRequest past the last record.
    ExportPastEnd = 16,
    /// A capacity with no defined degradation is exhausted; the message was
    /// refused: e.g. DepthRows of more than [`MAX_ROW_VALUES`] depth values,
    /// the device's row buffer (see [`DepthRows::check`]).
    CapacityExhausted = 17,
    /// A frame message after Finish (send Reset first).
    Finished = 18,
    // 19 was `Unsupported` ("the device does not implement this message"),
    // which no device ever sent: every message of a protocol version is
    // implemented, and one it does not know is `UnknownMessage`. Retired;
    // the number is never reused.
    /// Anything else (a bug): the message was refused.
    Internal = 20,
    /// Hello with another configuration after frames were seen (send Reset first).
    NeedsReset = 21,
    /// FrameEnd before every strided row of the frame arrived (the frame stays open).
    MissingRows = 22,
    /// The flash log has no room for what the message would decide: FrameEnd
    /// is refused while there is still room for a Finish (the frame stays
    /// open: FrameAbort it, then Finish); export still works.
    StorageFull = 23,
    /// The flash failed to erase or write; the message was not applied.
    StorageFailed = 24,
    /// Extend, but the device holds no finished scan in its flash log to
    /// continue (none, one not finished, one whose log writes failed, or a
    /// device without flash).
    NothingToExtend = 25,
    /// Extend with another configuration than the scan it would continue.
    ExtendOtherConfig = 26,
    /// An ExportRequest reached a record the device cannot read back from
    /// its flash log (protocol 6; since 7 the device answers
    /// [`DeviceMessage::ExportUnreadable`], which names the record).
    ExportUnreadable = 27,
}

/// A number that is no [`ErrorKind`] (a retired one, or one from a newer
/// protocol): decoding the message fails.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UnknownErrorKind(pub u32);

impl core::fmt::Display for UnknownErrorKind {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "unknown error kind {}", self.0)
    }
}

impl From<ErrorKind> for u32 {
    fn from(kind: ErrorKind) -> u32 {
        kind.code()
    }
}

impl TryFrom<u32> for ErrorKind {
    type Error = UnknownErrorKind;

    fn try_from(code: u32) -> Result<Self, Self::Error> {
        ErrorKind::ALL
            .iter()
            .copied()
            .find(|k| k.code() == code)
            .ok_or(UnknownErrorKind(code))
    }
}

impl ErrorKind {
    /// Every kind, in wire-number order.
    pub const ALL: [ErrorKind; 27] = [
        ErrorKind::BadCrc,
        ErrorKind::BadFraming,
        ErrorKind::Oversized,
        ErrorKind::Truncated,
        ErrorKind::Decode,
        ErrorKind::UnknownMessage,
        ErrorKind::WrongVersion,
        ErrorKind::OutOfOrder,
        ErrorKind::NotConfigured,
        ErrorKind::BadConfig,
        ErrorKind::BadPose,
        ErrorKind::RowOutOfRange,
        ErrorKind::RowTooLong,
        ErrorKind::RowTooShort,
        ErrorKind::FrameEndWithoutBegin,
        ErrorKind::MidFrameReconfig,
        ErrorKind::ExportPastEnd,
        ErrorKind::CapacityExhausted,
        ErrorKind::Finished,
        ErrorKind::Internal,
        ErrorKind::NeedsReset,
        ErrorKind::MissingRows,
        ErrorKind::StorageFull,
        ErrorKind::StorageFailed,
        ErrorKind::NothingToExtend,
        ErrorKind::ExtendOtherConfig,
        ErrorKind::ExportUnreadable,
    ];

    /// The kind's number on the wire.
    pub const fn code(self) -> u32 {
        self as u32
    }

    /// Whether the error says the frame was damaged on the way (CRC, framing,
    /// length or decoding): the message was not applied and sending it again
    /// (same sequence number) may succeed. Other errors are refusals of a
    /// message the device read correctly.
    pub const fn is_damage(self) -> bool {
        matches!(
            self,
            ErrorKind::BadCrc
                | ErrorKind::BadFraming
                | ErrorKind::Oversized
                | ErrorKind::Truncated
                | ErrorKind::Decode
                | ErrorKind::UnknownMessage
        )
    }

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
            ErrorKind::Internal => "internal error",
            ErrorKind::NeedsReset => "scan in progress; reset before reconfiguring",
            ErrorKind::MissingRows => "frame end before all its rows",
            ErrorKind::StorageFull => "flash log full",
            ErrorKind::StorageFailed => "flash write failed",
            ErrorKind::NothingToExtend => "no finished scan in the flash log to extend",
            ErrorKind::ExtendOtherConfig => "the scan to extend has other settings",
            ErrorKind::ExportUnreadable => "a record of the export cannot be read back from flash",
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
