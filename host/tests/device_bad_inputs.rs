//! The catalogue of bad inputs: every way a host (or a noisy link) can send
//! the device something it must refuse, each with the typed error it must
//! produce, checked at the wire level against one in-process device that
//! holds a real scan in a durable flash log.
//!
//! Each case is one row of a table: a name, the bytes or the
//! [`HostMessage`] sent, and the [`ErrorKind`] expected. For every case:
//!
//! - the device sends exactly one reply, [`DeviceMessage::Error`] with the
//!   expected kind and sequence number: the message's own for a frame that
//!   decodes (and for a CRC-valid frame that does not, when its sequence
//!   number can be read), the number the frame *claims* for a CRC failure,
//!   `None` for a framing error that loses the frame (oversized, bad COBS,
//!   too short for a CRC);
//! - nothing stored changes: the export (database and labels), the status
//!   (but for the `refused` counter, which grows by exactly one, and the
//!   receive-buffer counters), and the flash: its bytes and its count of
//!   erase and write steps.
//!
//! The cases are grouped by the device's state, since what is refused
//! depends on it:
//!
//! 1. before any Hello (a second, fresh device): frame messages are
//!    `NotConfigured`;
//! 2. between frames of a scan (frames decided, some in the database);
//! 3. inside a frame (FrameBegin and the first rows received);
//! 4. after Finish.
//!
//! Then the device must not be wedged: the open frame completes, the scan
//! finishes, and the whole run ends with the very export and the very flash
//! contents of the same scan streamed without a single bad input. A device
//! restored from the flash after each group exports what the live one does.
//!
//! Other tests check some of these piecemeal (src/device/tests.rs
//! `refused_messages_change_nothing`, src/protocol/tests.rs,
//! tests/capacities.rs, host/tests/board_qemu.rs); this file is the one readable
//! list of every case.

use placedb::device::harness::{durable_part, on_big_stack, Harness};
use placedb::device::Device256K;
use placedb::protocol::{
    depth_rows_per_message, encode, pack_rows, CapacitySlot, Config, DepthRows, DeviceMessage,
    ErrorKind, ExportRecord, HostFrame, HostMessage, Phase, Status, CRC, MAX_FRAME_LEN,
    PROTOCOL_VERSION,
};
use placedb::{Intrinsics, Pose, SelectorConfig};
use placedb_host::board::link::fault::damaged_frame;
use placedb_host::synth::{self, SynthConfig};
use placedb_host::{board::scan, DepthImage, VoxelConfig};
use std::time::Instant;

use ErrorKind::*;

/// Sectors of the simulated NOR flash holding the log.
const FLASH_SECTORS: usize = 32;
/// Pixel stride: the 320x240 demo images travel as 80x60 strided rows.
const STRIDE: u16 = 4;
/// Frames of the demo sequence between two frames of this scan.
const SPACING: usize = 12;
/// Frames streamed before the "between frames" cases: enough that a batch
/// of decisions (16) is in the log, so there are labels to protect.
const BEFORE: u32 = 20;
/// Frames of the scan in all.
const FRAMES: u32 = 23;

// ---------------------------------------------------------------------------
// The scan.

/// The frames of the scan: demo frames `0, SPACING, 2 * SPACING, ...`,
/// renumbered from 0, and the Hello that configures the device for them.
struct Scan {
    cfg: Config,
    images: Vec<DepthImage>,
    meta: Vec<(f64, Pose)>,
}

impl Scan {
    fn new() -> Scan {
        let seq = synth::sequence(&SynthConfig::demo());
        let vcfg = VoxelConfig {
            stride: STRIDE,
            ..VoxelConfig::default()
        };
        let scan = scan::scan_config(&seq, &vcfg).unwrap();
        let sel = SelectorConfig {
            mu: 0.3,
            window: 2,
            sketch_margin: 0.05,
        };
        let cfg = scan::device_config(&scan, &sel).unwrap();
        let picks: Vec<usize> = (0..FRAMES as usize).map(|k| k * SPACING).collect();
        Scan {
            cfg,
            images: picks.iter().map(|&i| seq.depth(i).unwrap()).collect(),
            meta: picks
                .iter()
                .map(|&i| (seq.frames[i].timestamp, seq.frames[i].pose().unwrap()))
                .collect(),
        }
    }

    fn width_sent(&self) -> u16 {
        self.cfg.width_sent()
    }

    fn height_sent(&self) -> u16 {
        self.cfg.height_sent()
    }

    /// Strided rows per DepthRows message (as many as fit a frame).
    fn rows_per_message(&self) -> u16 {
        depth_rows_per_message(self.width_sent())
    }

    /// Bytes of one strided row.
    fn row_bytes(&self) -> usize {
        usize::from(self.width_sent()) * 2
    }

    /// The FrameBegin of frame `k` (any `k`: beyond the scan, its last pose).
    fn begin(&self, k: u32) -> HostMessage<'static> {
        let (timestamp, pose) = self.meta[(k as usize).min(self.meta.len() - 1)];
        HostMessage::FrameBegin {
            frame: k,
            timestamp,
            pose,
        }
    }

    /// FrameBegin of frame `k` with its pose or timestamp changed by `f`.
    fn begin_with(&self, k: u32, f: impl FnOnce(&mut f64, &mut Pose)) -> HostMessage<'static> {
        let HostMessage::FrameBegin {
            frame,
            mut timestamp,
            mut pose,
        } = self.begin(k)
        else {
            unreachable!()
        };
        f(&mut timestamp, &mut pose);
        HostMessage::FrameBegin {
            frame,
            timestamp,
            pose,
        }
    }

    /// The depth bytes of strided rows `first..first + count` of frame `k`
    /// (rows of the last frame for a `k` beyond the scan).
    fn rows(&self, k: u32, first: u16, count: u16) -> Vec<u8> {
        let img = &self.images[(k as usize).min(self.images.len() - 1)];
        let mut out = vec![0u8; usize::from(count) * self.row_bytes()];
        pack_rows(&img.data, img.width, STRIDE, first, count, &mut out)
            .unwrap()
            .to_vec()
    }

    /// The Hello with one field changed by `f`.
    fn hello_with(&self, f: impl FnOnce(&mut Config)) -> HostMessage<'static> {
        let mut cfg = self.cfg;
        f(&mut cfg);
        HostMessage::Hello(cfg)
    }
}

/// A DepthRows message.
fn depth_rows(frame: u32, first_row: u16, row_count: u16, data: &[u8]) -> HostMessage<'_> {
    HostMessage::DepthRows(DepthRows {
        frame,
        first_row,
        row_count,
        data,
    })
}

// ---------------------------------------------------------------------------
// Raw frames.

/// The complete frame (COBS, trailing 0x00) of `msg` with sequence number `seq`,
/// however long.
fn frame_of(seq: u32, msg: HostMessage<'_>) -> Vec<u8> {
    let mut buf = vec![0u8; 4 * MAX_FRAME_LEN];
    encode(&HostFrame { seq, msg }, &mut buf).unwrap().to_vec()
}

/// The postcard bytes of `msg` with sequence number `seq` (no CRC, no COBS).
fn postcard_of(seq: u32, msg: HostMessage<'_>) -> Vec<u8> {
    let mut buf = vec![0u8; 4 * MAX_FRAME_LEN];
    postcard::to_slice(&HostFrame { seq, msg }, &mut buf)
        .unwrap()
        .to_vec()
}

/// `seq` as postcard writes it (a varint), followed by `rest`.
fn seq_then(seq: u32, rest: &[u8]) -> Vec<u8> {
    let mut buf = [0u8; 5];
    let mut out = postcard::to_slice(&seq, &mut buf).unwrap().to_vec();
    out.extend_from_slice(rest);
    out
}

/// COBS of `data` and the 0x00 delimiter (postcard's flavour, as the
/// protocol's own encoder uses).
fn cobs(data: &[u8]) -> Vec<u8> {
    use postcard::ser_flavors::{Cobs, Flavor, Slice};
    let mut buf = vec![0u8; data.len() + data.len() / 254 + 2];
    let mut cobs = Cobs::try_new(Slice::new(&mut buf)).unwrap();
    cobs.try_extend(data).unwrap();
    cobs.finalize().unwrap().to_vec()
}

/// A frame of `payload` with its correct CRC: it passes the CRC check,
/// whatever the payload is.
fn with_crc(payload: &[u8]) -> Vec<u8> {
    let mut data = payload.to_vec();
    data.extend_from_slice(&CRC.checksum(payload).to_le_bytes());
    cobs(&data)
}

/// A frame of `payload` followed by a wrong CRC (the right one, one bit flipped).
fn with_wrong_crc(payload: &[u8]) -> Vec<u8> {
    let mut data = payload.to_vec();
    data.extend_from_slice(&(CRC.checksum(payload) ^ 1).to_le_bytes());
    cobs(&data)
}

/// A frame of `payload` without any CRC.
fn without_crc(payload: &[u8]) -> Vec<u8> {
    cobs(payload)
}

/// The frame of `msg` with one byte damaged (host/src/fault.rs
/// `damaged_frame`): its CRC fails, its sequence number still reads.
fn damaged(seq: u32, msg: HostMessage<'_>) -> Vec<u8> {
    damaged_frame(seq, msg).expect("a damaging bit flip")
}

/// The COBS blocks of a frame: (position of the code byte, code).
fn cobs_blocks(frame: &[u8]) -> Vec<(usize, usize)> {
    let body = &frame[..frame.len() - 1];
    let mut blocks = Vec::new();
    let mut p = 0;
    while p < body.len() {
        let code = usize::from(body[p]);
        blocks.push((p, code));
        p += code;
    }
    assert_eq!(p, body.len(), "not a COBS frame");
    blocks
}

/// `frame` without the last byte before its delimiter: its last COBS block
/// promises a byte that never comes (bad framing).
fn without_last_byte(frame: &[u8]) -> Vec<u8> {
    let &(_, code) = cobs_blocks(frame).last().unwrap();
    assert!(code >= 2, "the last COBS block is empty: cut elsewhere");
    let mut cut = frame[..frame.len() - 2].to_vec();
    cut.push(0);
    cut
}

/// The frame of `msg` with its last `lost` bytes (of postcard and CRC) lost
/// before COBS: valid COBS (as a frame cut at a block boundary), but its
/// last 4 bytes are not the CRC of the rest. The claimed sequence number reads.
fn cut_before_cobs(seq: u32, msg: HostMessage<'_>, lost: usize) -> Vec<u8> {
    let mut data = postcard_of(seq, msg);
    data.extend_from_slice(&CRC.checksum(&data).to_le_bytes());
    data.truncate(data.len() - lost);
    cobs(&data)
}

/// A frame of `len` bytes, delimiter included, of non-zero junk.
fn junk_frame(len: usize) -> Vec<u8> {
    let mut out = vec![0x42u8; len - 1];
    out.push(0);
    out
}

// ---------------------------------------------------------------------------
// The table.

/// One bad input: what is sent and the error it must get.
struct Case {
    name: String,
    bytes: Vec<u8>,
    /// Delivered in chunks of this many bytes (the whole frame at once when
    /// it is at least the frame's length).
    chunk: usize,
    seq: Option<u32>,
    kind: ErrorKind,
}

/// Builds a table of cases, handing out fresh sequence numbers (a refused
/// state-changing message is remembered with its sequence number: reusing
/// one would be a retransmission, answered from the cache).
struct Table {
    next_seq: u32,
    cases: Vec<Case>,
}

impl Table {
    fn new(first_seq: u32) -> Table {
        Table {
            next_seq: first_seq,
            cases: Vec::new(),
        }
    }

    /// A fresh sequence number for a hand-made frame.
    fn seq(&mut self) -> u32 {
        let seq = self.next_seq;
        self.next_seq += 1;
        seq
    }

    /// A well-formed frame of `msg`: the error carries its sequence number.
    fn msg(&mut self, name: impl Into<String>, msg: HostMessage<'_>, kind: ErrorKind) {
        let seq = self.seq();
        self.raw(name, frame_of(seq, msg), Some(seq), kind);
    }

    /// These bytes, at once; the error carries `seq`.
    fn raw(&mut self, name: impl Into<String>, bytes: Vec<u8>, seq: Option<u32>, kind: ErrorKind) {
        self.chunked(name, bytes, usize::MAX, seq, kind);
    }

    /// These bytes in chunks of `chunk` bytes.
    fn chunked(
        &mut self,
        name: impl Into<String>,
        bytes: Vec<u8>,
        chunk: usize,
        seq: Option<u32>,
        kind: ErrorKind,
    ) {
        let name = name.into();
        assert!(
            self.cases.iter().all(|c| c.name != name),
            "two cases named {name:?}"
        );
        self.cases.push(Case {
            name,
            bytes,
            chunk,
            seq,
            kind,
        });
    }
}

// ---------------------------------------------------------------------------
// The device under test.

/// The device under test (a harness with its flash log), and the cases
/// that went wrong.
struct Bench {
    h: Harness<Device256K>,
    /// Cases that did not get their error or changed something.
    failures: Vec<String>,
}

/// What must not change: the status (refused and receive counters masked),
/// the export, the flash.
#[derive(Debug, Clone)]
struct Snapshot {
    status: Status,
    refused: u32,
    export: Vec<ExportRecord>,
    flash: Vec<u8>,
    steps: u64,
}

impl Snapshot {
    /// How `self` differs from `before` with one more refusal (nothing
    /// when the case changed nothing).
    fn changes_since(&self, before: &Snapshot) -> Vec<String> {
        let mut changes = Vec::new();
        if self.status != before.status {
            changes.push(format!(
                "the status changed from {:?} to {:?}",
                before.status, self.status
            ));
        }
        if self.export != before.export {
            changes.push(format!(
                "the export changed from {:?} to {:?}",
                before.export, self.export
            ));
        }
        if self.steps != before.steps {
            changes.push(format!(
                "the flash took {} erase or write steps",
                self.steps - before.steps
            ));
        }
        if let Some(at) = (0..self.flash.len()).find(|&i| self.flash[i] != before.flash[i]) {
            changes.push(format!(
                "flash byte {at} changed from {:#04x} to {:#04x}",
                before.flash[at], self.flash[at]
            ));
        }
        if self.refused != before.refused + 1 {
            changes.push(format!(
                "`refused` went from {} to {}, not up by one",
                before.refused, self.refused
            ));
        }
        changes
    }
}

impl Bench {
    fn new() -> Bench {
        Bench {
            h: Harness::new(FLASH_SECTORS),
            failures: Vec::new(),
        }
    }

    fn snapshot(&mut self) -> Snapshot {
        let mut status = self.h.status();
        let refused = status.refused;
        status.seq = 0;
        status.refused = 0;
        // The receive buffer's last and peak use follow the frames received.
        *status.capacity_mut(CapacitySlot::RxFrame).unwrap() = Default::default();
        let export = self.h.export();
        let flash = self.h.flash();
        Snapshot {
            status,
            refused,
            export,
            flash: flash.bytes().to_vec(),
            steps: flash.steps(),
        }
    }

    /// Runs every case of `table`; returns how many. A case that does not
    /// get its error, or changes something, is noted in `failures`; the run
    /// goes on (to report every such case) unless something changed, which
    /// would make the rest of the scan meaningless.
    fn run(&mut self, table: Table) -> usize {
        assert!(!table.cases.is_empty());
        self.h.seq = self.h.seq.max(table.next_seq);
        let mut changed = false;
        let mut before = self.snapshot();
        for case in &table.cases {
            let replies = self.h.feed(&case.bytes, case.chunk);
            let want = DeviceMessage::Error {
                seq: case.seq,
                kind: case.kind,
            };
            if replies != [want] {
                self.failures.push(format!(
                    "{}: expected one {want:?}, got {replies:?}",
                    case.name
                ));
            }
            let after = self.snapshot();
            for change in after.changes_since(&before) {
                self.failures.push(format!("{}: {change}", case.name));
                changed = true;
            }
            before = after;
        }
        if changed {
            self.assert_no_failures(table.cases.len());
        }
        table.cases.len()
    }

    /// Panics with every failed case, if any.
    fn assert_no_failures(&self, cases: usize) {
        assert!(
            self.failures.is_empty(),
            "{} of {cases} bad inputs went wrong:\n{}",
            self.failures.len(),
            self.failures.join("\n")
        );
    }

    /// Streams frame `k` of `scan` whole: FrameBegin, every row, FrameEnd.
    fn stream_frame(&mut self, scan: &Scan, k: u32) {
        self.h.ok(scan.begin(k));
        self.stream_rows(scan, k, 0);
        self.h.ok(HostMessage::FrameEnd { frame: k });
    }

    /// Streams the rows of frame `k` from strided row `first` on.
    fn stream_rows(&mut self, scan: &Scan, k: u32, first: u16) {
        let mut row = first;
        while row < scan.height_sent() {
            let count = scan.rows_per_message().min(scan.height_sent() - row);
            self.h
                .ok(depth_rows(k, row, count, &scan.rows(k, row, count)));
            row += count;
        }
    }

    /// Panics unless a device restored from the flash exports what this one
    /// does, as far as its decisions are in the log.
    fn assert_restores(&mut self, when: &str) {
        let live = durable_part(&self.h.export());
        let (mut restored, records) = Harness::<Device256K>::boot(self.h.flash().clone());
        records.unwrap();
        assert_eq!(
            restored.export(),
            live,
            "{when}: the device restored from flash exports something else"
        );
    }
}

// ---------------------------------------------------------------------------
// The catalogue.

/// Before any Hello (a fresh device, an empty flash).
fn before_hello(scan: &Scan, t: &mut Table) {
    let row = scan.rows(0, 0, 1);
    t.msg("FrameBegin before Hello", scan.begin(0), NotConfigured);
    t.msg(
        "DepthRows before Hello",
        depth_rows(0, 0, 1, &row),
        NotConfigured,
    );
    t.msg(
        "FrameEnd before Hello",
        HostMessage::FrameEnd { frame: 0 },
        NotConfigured,
    );
    t.msg("Finish before Hello", HostMessage::Finish, NotConfigured);
    t.msg(
        "FrameAbort before Hello",
        HostMessage::FrameAbort { frame: 0 },
        NotConfigured,
    );
    t.msg(
        "ExportRequest past the end of an empty export",
        HostMessage::ExportRequest {
            from_record: 1,
            max_records: u32::MAX,
        },
        ExportPastEnd,
    );
    t.msg(
        "Hello of the next protocol version",
        scan.hello_with(|c| c.version = PROTOCOL_VERSION + 1),
        WrongVersion,
    );
    t.msg(
        "Hello with window 0",
        scan.hello_with(|c| c.window = 0),
        BadConfig,
    );
    let seq = t.seq();
    t.raw(
        "Hello with a damaged byte",
        damaged(seq, HostMessage::Hello(scan.cfg)),
        Some(seq),
        BadCrc,
    );
}

/// Framing and decoding failures: the same whatever the device's state.
/// `would_apply` is a message the device would accept now.
fn damaged_frames(scan: &Scan, t: &mut Table, would_apply: HostMessage<'_>) {
    // Too short to hold a CRC: the sequence number is not looked for.
    t.raw("frame empty after COBS", vec![0x01, 0x00], None, Truncated);
    t.raw("frame of 1 byte", without_crc(&[0x07]), None, Truncated);
    t.raw(
        "frame of 3 bytes (StatusRequest without its CRC)",
        without_crc(&seq_then(7, &[5])),
        None,
        Truncated,
    );
    // Longer than the receive buffer.
    t.raw(
        "junk frame exactly filling the receive buffer (read: not COBS)",
        junk_frame(MAX_FRAME_LEN),
        None,
        BadFraming,
    );
    t.raw(
        "junk frame one byte over the receive buffer",
        junk_frame(MAX_FRAME_LEN + 1),
        None,
        Oversized,
    );
    t.raw(
        "junk frame far over the receive buffer",
        junk_frame(3 * MAX_FRAME_LEN),
        None,
        Oversized,
    );
    t.chunked(
        "junk frame over the receive buffer, in 100-byte chunks",
        junk_frame(MAX_FRAME_LEN + 500),
        100,
        None,
        Oversized,
    );
    // Not COBS.
    t.raw(
        "COBS code past the end of the frame",
        vec![0x05, 0x01, 0x02, 0x00],
        None,
        BadFraming,
    );
    let seq = t.seq();
    t.raw(
        "frame missing its last byte",
        without_last_byte(&frame_of(seq, would_apply)),
        None,
        BadFraming,
    );
    // CRC failures: the claimed sequence number comes back when it reads.
    let seq = t.seq();
    t.raw(
        "frame with a damaged byte",
        damaged(seq, would_apply),
        Some(seq),
        BadCrc,
    );
    let seq = t.seq();
    t.raw(
        "frame with a wrong CRC",
        with_wrong_crc(&postcard_of(seq, would_apply)),
        Some(seq),
        BadCrc,
    );
    let seq = t.seq();
    t.raw(
        "frame losing its last byte before COBS",
        cut_before_cobs(seq, would_apply, 1),
        Some(seq),
        BadCrc,
    );
    t.raw(
        "CRC of nothing: 4 bytes that are not a CRC",
        vec![0x05, 0x01, 0x02, 0x03, 0x04, 0x00],
        None,
        BadCrc,
    );
    let seq = t.seq();
    t.raw(
        "Reset with a damaged byte",
        damaged(seq, HostMessage::Reset),
        Some(seq),
        BadCrc,
    );
    // The CRC matches, the message does not read.
    let seq = t.seq();
    t.raw(
        "FrameEnd without its frame index",
        with_crc(&seq_then(seq, &[3])),
        Some(seq),
        Decode,
    );
    let seq = t.seq();
    t.raw(
        "Hello cut short",
        with_crc(&postcard_of(seq, HostMessage::Hello(scan.cfg))[..12]),
        Some(seq),
        Decode,
    );
    let seq = t.seq();
    let mut trailing = postcard_of(seq, HostMessage::StatusRequest);
    trailing.push(0x00);
    t.raw(
        "StatusRequest with a trailing byte",
        with_crc(&trailing),
        Some(seq),
        Decode,
    );
    let seq = t.seq();
    let mut trailing = postcard_of(seq, HostMessage::Reset);
    trailing.push(0x06);
    t.raw(
        "Reset with a trailing byte",
        with_crc(&trailing),
        Some(seq),
        Decode,
    );
    t.raw(
        "sequence number longer than a u32",
        with_crc(&[0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x01, 5]),
        None,
        Decode,
    );
    let seq = t.seq();
    t.raw(
        "sequence number alone",
        with_crc(&seq_then(seq, &[])),
        Some(seq),
        Decode,
    );
    // The CRC matches, the message is of a later protocol.
    let seq = t.seq();
    t.raw(
        "message tag 11 (one past LogRead)",
        with_crc(&seq_then(seq, &[11])),
        Some(seq),
        UnknownMessage,
    );
    let seq = t.seq();
    t.raw(
        "message tag 200 with a body",
        with_crc(&seq_then(seq, &[0xC8, 0x01, 1, 2, 3])),
        Some(seq),
        UnknownMessage,
    );
}

/// A named change to a configuration.
type ConfigEdit = (&'static str, fn(&mut Config));

/// A named change to a FrameBegin's timestamp and pose.
type PoseEdit = (&'static str, fn(&mut f64, &mut Pose));

/// Every Hello whose values [`Config::validate`] refuses (after the version).
fn bad_configs(scan: &Scan, t: &mut Table) {
    let cases: &[ConfigEdit] = &[
        ("voxel size 0", |c| c.voxel_size = 0.0),
        ("voxel size negative", |c| c.voxel_size = -0.3),
        ("voxel size NaN", |c| c.voxel_size = f32::NAN),
        ("voxel size infinite", |c| c.voxel_size = f32::INFINITY),
        ("voxel size below 1 mm", |c| c.voxel_size = 5e-4),
        ("mu 1", |c| c.mu = 1.0),
        ("mu negative", |c| c.mu = -0.1),
        ("mu NaN", |c| c.mu = f32::NAN),
        ("mu infinite", |c| c.mu = f32::INFINITY),
        ("depth scale 0", |c| c.depth_scale = 0.0),
        ("depth scale negative", |c| c.depth_scale = -5000.0),
        ("depth scale NaN", |c| c.depth_scale = f32::NAN),
        ("depth scale infinite", |c| c.depth_scale = f32::INFINITY),
        ("depth scale absurdly small", |c| c.depth_scale = 1e-30),
        ("intrinsics all zero", |c| {
            c.intrinsics = Intrinsics {
                width: 0,
                height: 0,
                fx: 0.0,
                fy: 0.0,
                cx: 0.0,
                cy: 0.0,
            }
        }),
        ("image width 0", |c| c.intrinsics.width = 0),
        ("image height 0", |c| c.intrinsics.height = 0),
        ("image width over the largest side", |c| {
            c.intrinsics.width = Intrinsics::MAX_SIDE + 1
        }),
        ("image height over the largest side", |c| {
            c.intrinsics.height = Intrinsics::MAX_SIDE + 1
        }),
        ("focal length x 0", |c| c.intrinsics.fx = 0.0),
        ("focal length y negative", |c| c.intrinsics.fy = -256.0),
        ("focal length x NaN", |c| c.intrinsics.fx = f32::NAN),
        ("focal length y infinite", |c| {
            c.intrinsics.fy = f32::INFINITY
        }),
        ("focal length absurdly short", |c| c.intrinsics.fx = 1e-30),
        ("principal point NaN", |c| c.intrinsics.cx = f32::NAN),
        ("principal point infinite", |c| {
            c.intrinsics.cy = f32::INFINITY
        }),
        ("principal point absurdly far", |c| c.intrinsics.cx = 1e30),
        ("principal point two widths off", |c| {
            c.intrinsics.cx = -2.0 * f32::from(c.intrinsics.width)
        }),
        ("focal length below 1 px", |c| c.intrinsics.fx = 1e-3),
        ("focal length above 1e6 px", |c| c.intrinsics.fy = 1e30),
        ("depth scale absurdly large", |c| c.depth_scale = 1e30),
        ("depth scale below 1 unit per metre", |c| {
            c.depth_scale = 0.5
        }),
        ("voxel size above 100 m", |c| c.voxel_size = 1e30),
        ("sketch margin above 1", |c| c.sketch_margin = 1e30),
        ("stride 0", |c| c.stride = 0),
        ("stride over the largest side", |c| {
            c.stride = Intrinsics::MAX_SIDE + 1
        }),
        ("strided row too long for one frame", |c| {
            c.intrinsics.width = 1280;
            c.intrinsics.cx = 639.5;
            c.stride = 1;
        }),
        ("depth range empty", |c| {
            c.depth_range.min = c.depth_range.max
        }),
        ("depth range reversed", |c| {
            (c.depth_range.min, c.depth_range.max) = (10.0, 0.1)
        }),
        ("depth range negative", |c| c.depth_range.min = -1.0),
        ("depth range NaN", |c| c.depth_range.max = f32::NAN),
        ("grid origin NaN", |c| c.grid_origin[1] = f32::NAN),
        ("grid origin infinite", |c| {
            c.grid_origin[2] = f32::NEG_INFINITY
        }),
        ("window 0", |c| c.window = 0),
        ("sketch margin negative", |c| c.sketch_margin = -0.01),
        ("sketch margin NaN", |c| c.sketch_margin = f32::NAN),
        ("sketch margin infinite", |c| {
            c.sketch_margin = f32::INFINITY
        }),
        ("stride and width 0", |c| {
            c.stride = 0;
            c.intrinsics.width = 0;
        }),
        ("every float NaN", |c| {
            c.voxel_size = f32::NAN;
            c.mu = f32::NAN;
            c.depth_scale = f32::NAN;
            c.intrinsics.fx = f32::NAN;
            c.intrinsics.fy = f32::NAN;
            c.intrinsics.cx = f32::NAN;
            c.intrinsics.cy = f32::NAN;
            c.depth_range.min = f32::NAN;
            c.depth_range.max = f32::NAN;
            c.grid_origin = [f32::NAN; 3];
            c.sketch_margin = f32::NAN;
        }),
    ];
    for &(name, f) in cases {
        t.msg(format!("Hello with {name}"), scan.hello_with(f), BadConfig);
    }
}

/// Between frames: frames `0..next` decided or pending, no frame open.
fn between_frames(scan: &Scan, t: &mut Table, next: u32, export_len: u32) {
    damaged_frames(scan, t, scan.begin(next));
    // Hello.
    for (name, version) in [
        ("Hello of the next protocol version", PROTOCOL_VERSION + 1),
        (
            "Hello of the previous protocol version",
            PROTOCOL_VERSION - 1,
        ),
        ("Hello of protocol version 0", 0),
    ] {
        t.msg(name, scan.hello_with(|c| c.version = version), WrongVersion);
    }
    bad_configs(scan, t);
    t.msg(
        "another valid Hello after frames (mu)",
        scan.hello_with(|c| c.mu = 0.5),
        NeedsReset,
    );
    t.msg(
        "another valid Hello after frames (grid origin)",
        scan.hello_with(|c| c.grid_origin = [0.15, 0.0, 0.0]),
        NeedsReset,
    );
    t.msg(
        "another valid Hello after frames (window)",
        scan.hello_with(|c| c.window = 3),
        NeedsReset,
    );
    // FrameBegin with the wrong index.
    t.msg(
        "FrameBegin skipping a frame",
        scan.begin(next + 1),
        OutOfOrder,
    );
    t.msg(
        "FrameBegin of the last frame again",
        scan.begin(next - 1),
        OutOfOrder,
    );
    t.msg("FrameBegin of frame 0 again", scan.begin(0), OutOfOrder);
    t.msg(
        "FrameBegin of frame u32::MAX",
        scan.begin(u32::MAX),
        OutOfOrder,
    );
    // FrameBegin with a pose or timestamp that is not one.
    let bad_poses: &[PoseEdit] = &[
        ("FrameBegin with a NaN translation", |_, p| {
            p.translation[0] = f32::NAN
        }),
        ("FrameBegin with an infinite translation", |_, p| {
            p.translation[1] = f32::INFINITY
        }),
        ("FrameBegin with a -infinite translation", |_, p| {
            p.translation[2] = f32::NEG_INFINITY
        }),
        ("FrameBegin with a NaN quaternion component", |_, p| {
            p.rotation[3] = f32::NAN
        }),
        (
            "FrameBegin with an infinite quaternion component",
            |_, p| p.rotation[0] = f32::INFINITY,
        ),
        ("FrameBegin with a quaternion of norm 2", |_, p| {
            p.rotation = p.rotation.map(|q| 2.0 * q)
        }),
        ("FrameBegin with a quaternion of norm 1.01", |_, p| {
            p.rotation = p.rotation.map(|q| 1.01 * q)
        }),
        ("FrameBegin with an all-zero quaternion", |_, p| {
            p.rotation = [0.0; 4]
        }),
        ("FrameBegin with an infinite timestamp", |t, _| {
            *t = f64::INFINITY
        }),
        ("FrameBegin with a -infinite timestamp", |t, _| {
            *t = f64::NEG_INFINITY
        }),
        ("FrameBegin with a NaN timestamp", |t, _| *t = f64::NAN),
        // A finite pose, but a camera centre beyond the fixed-point range.
        ("FrameBegin with a translation of 1e30 m", |_, p| {
            p.translation = [1e30, 0.0, 0.0]
        }),
    ];
    for &(name, f) in bad_poses {
        t.msg(name, scan.begin_with(next, f), BadPose);
    }
    // Rows and ends with no frame open.
    let row = scan.rows(next, 0, 1);
    t.msg(
        "DepthRows of the next frame before its FrameBegin",
        depth_rows(next, 0, 1, &row),
        OutOfOrder,
    );
    t.msg(
        "DepthRows of no rows with no frame open",
        depth_rows(next, 0, 0, &[]),
        OutOfOrder,
    );
    t.msg(
        "DepthRows of the last frame after its FrameEnd",
        depth_rows(next - 1, 0, 1, &row),
        OutOfOrder,
    );
    t.msg(
        "FrameEnd of the next frame without its FrameBegin",
        HostMessage::FrameEnd { frame: next },
        FrameEndWithoutBegin,
    );
    t.msg(
        "FrameEnd of the last frame again",
        HostMessage::FrameEnd { frame: next - 1 },
        FrameEndWithoutBegin,
    );
    t.msg(
        "FrameAbort with no frame open",
        HostMessage::FrameAbort { frame: next },
        FrameEndWithoutBegin,
    );
    t.msg(
        "FrameAbort of the last frame after its FrameEnd",
        HostMessage::FrameAbort { frame: next - 1 },
        FrameEndWithoutBegin,
    );
    export_past_end(t, export_len);
}

fn export_past_end(t: &mut Table, export_len: u32) {
    t.msg(
        "ExportRequest one past the end",
        HostMessage::ExportRequest {
            from_record: export_len + 1,
            max_records: 1,
        },
        ExportPastEnd,
    );
    t.msg(
        "ExportRequest from u32::MAX",
        HostMessage::ExportRequest {
            from_record: u32::MAX,
            max_records: u32::MAX,
        },
        ExportPastEnd,
    );
}

/// Frame `open` is open with its rows `0..next_row` received.
fn in_frame(scan: &Scan, t: &mut Table, open: u32, next_row: u16, export_len: u32) {
    let rpm = scan.rows_per_message();
    let height = scan.height_sent();
    let next_rows = scan.rows(open, next_row, rpm);
    let next_chunk = depth_rows(open, next_row, rpm, &next_rows);
    damaged_frames(scan, t, next_chunk);
    let seq = t.seq();
    let mut short = postcard_of(
        seq,
        depth_rows(open, next_row, 1, &next_rows[..scan.row_bytes()]),
    );
    short.truncate(short.len() - 10);
    t.raw(
        "DepthRows with fewer data bytes than its length says",
        with_crc(&short),
        Some(seq),
        Decode,
    );
    // A well-formed message too long for the receive buffer: the frame is
    // lost before its sequence number is read.
    let too_many = scan.rows(open, next_row, rpm + 1);
    let seq = t.seq();
    t.raw(
        "DepthRows of one row more than a frame holds",
        frame_of(seq, depth_rows(open, next_row, rpm + 1, &too_many)),
        None,
        Oversized,
    );
    // Reconfiguration in the middle of the frame, whatever the Hello.
    t.msg(
        "the same Hello inside a frame",
        HostMessage::Hello(scan.cfg),
        MidFrameReconfig,
    );
    t.msg(
        "another valid Hello inside a frame",
        scan.hello_with(|c| c.mu = 0.5),
        MidFrameReconfig,
    );
    t.msg(
        "a Hello with window 0 inside a frame",
        scan.hello_with(|c| c.window = 0),
        MidFrameReconfig,
    );
    t.msg(
        "a Hello of the next protocol version inside a frame",
        scan.hello_with(|c| c.version = PROTOCOL_VERSION + 1),
        MidFrameReconfig,
    );
    // FrameBegin while a frame is open.
    t.msg(
        "FrameBegin of the next frame inside a frame",
        scan.begin(open + 1),
        OutOfOrder,
    );
    t.msg(
        "FrameBegin of the open frame again",
        scan.begin(open),
        OutOfOrder,
    );
    t.msg(
        "FrameBegin with a NaN pose inside a frame",
        scan.begin_with(open + 1, |_, p| p.translation[0] = f32::NAN),
        OutOfOrder,
    );
    // Rows of another frame, or not the next row.
    let one = &next_rows[..scan.row_bytes()];
    t.msg(
        "DepthRows of the previous frame",
        depth_rows(open - 1, next_row, 1, one),
        OutOfOrder,
    );
    t.msg(
        "DepthRows of the next frame",
        depth_rows(open + 1, next_row, 1, one),
        OutOfOrder,
    );
    t.msg(
        "DepthRows skipping a row",
        depth_rows(open, next_row + 1, 1, one),
        OutOfOrder,
    );
    t.msg(
        "DepthRows repeating the last row",
        depth_rows(open, next_row - 1, 1, one),
        OutOfOrder,
    );
    let first = scan.rows(open, 0, next_row);
    t.msg(
        "DepthRows repeating the rows received",
        depth_rows(open, 0, next_row, &first),
        OutOfOrder,
    );
    t.msg(
        "DepthRows of the last row (rows missing before it)",
        depth_rows(open, height - 1, 1, one),
        OutOfOrder,
    );
    // Rows beyond the strided image.
    t.msg(
        "DepthRows of the row after the image",
        depth_rows(open, height, 1, one),
        RowOutOfRange,
    );
    t.msg(
        "DepthRows running past the image",
        depth_rows(open, next_row, height - next_row + 1, one),
        RowOutOfRange,
    );
    t.msg(
        "DepthRows of row u16::MAX",
        depth_rows(open, u16::MAX, u16::MAX, one),
        RowOutOfRange,
    );
    // Data not row_count rows of the configured width.
    let row_plus = |extra: usize| {
        let mut d = one.to_vec();
        d.extend(std::iter::repeat_n(0x11, extra));
        d
    };
    let two = &next_rows[..2 * scan.row_bytes()];
    t.msg(
        "DepthRows row one value longer than the width",
        depth_rows(open, next_row, 1, &row_plus(2)),
        RowTooLong,
    );
    t.msg(
        "DepthRows row one byte longer than the width",
        depth_rows(open, next_row, 1, &row_plus(1)),
        RowTooLong,
    );
    t.msg(
        "DepthRows of two rows' bytes declaring one",
        depth_rows(open, next_row, 1, two),
        RowTooLong,
    );
    t.msg(
        "DepthRows of one row's bytes declaring none",
        depth_rows(open, next_row, 0, one),
        RowTooLong,
    );
    t.msg(
        "DepthRows row one value shorter than the width",
        depth_rows(open, next_row, 1, &one[..one.len() - 2]),
        RowTooShort,
    );
    t.msg(
        "DepthRows row one byte shorter than the width",
        depth_rows(open, next_row, 1, &one[..one.len() - 1]),
        RowTooShort,
    );
    t.msg(
        "DepthRows of one row's bytes declaring two",
        depth_rows(open, next_row, 2, one),
        RowTooShort,
    );
    t.msg(
        "DepthRows of no bytes declaring one row",
        depth_rows(open, next_row, 1, &[]),
        RowTooShort,
    );
    // Ends.
    t.msg(
        "FrameEnd before all rows",
        HostMessage::FrameEnd { frame: open },
        MissingRows,
    );
    t.msg(
        "FrameEnd of the previous frame",
        HostMessage::FrameEnd { frame: open - 1 },
        FrameEndWithoutBegin,
    );
    t.msg(
        "FrameEnd of the next frame",
        HostMessage::FrameEnd { frame: open + 1 },
        FrameEndWithoutBegin,
    );
    t.msg(
        "FrameAbort of another frame than the open one",
        HostMessage::FrameAbort { frame: open - 1 },
        FrameEndWithoutBegin,
    );
    t.msg("Finish inside a frame", HostMessage::Finish, OutOfOrder);
    export_past_end(t, export_len);
}

/// After Finish, `frames` frames in the scan.
fn finished(scan: &Scan, t: &mut Table, frames: u32, export_len: u32) {
    damaged_frames(scan, t, HostMessage::Reset);
    let row = scan.rows(frames, 0, 1);
    t.msg(
        "FrameBegin of the next frame after Finish",
        scan.begin(frames),
        Finished,
    );
    t.msg(
        "FrameBegin of frame 0 after Finish",
        scan.begin(0),
        Finished,
    );
    t.msg(
        "FrameAbort after Finish",
        HostMessage::FrameAbort { frame: frames },
        Finished,
    );
    t.msg(
        "FrameBegin with a NaN pose after Finish",
        scan.begin_with(frames, |_, p| p.rotation = [f32::NAN; 4]),
        Finished,
    );
    t.msg(
        "DepthRows after Finish",
        depth_rows(frames, 0, 1, &row),
        Finished,
    );
    t.msg(
        "FrameEnd of the last frame after Finish",
        HostMessage::FrameEnd { frame: frames - 1 },
        Finished,
    );
    t.msg(
        "FrameEnd of the next frame after Finish",
        HostMessage::FrameEnd { frame: frames },
        Finished,
    );
    t.msg(
        "another valid Hello after Finish",
        scan.hello_with(|c| c.mu = 0.5),
        NeedsReset,
    );
    t.msg(
        "a Hello with mu 1 after Finish",
        scan.hello_with(|c| c.mu = 1.0),
        BadConfig,
    );
    t.msg(
        "a Hello of the next protocol version after Finish",
        scan.hello_with(|c| c.version = PROTOCOL_VERSION + 1),
        WrongVersion,
    );
    export_past_end(t, export_len);
}

// ---------------------------------------------------------------------------
// The runs.

/// Streams the scan of `scan`; with `catalogue`, runs every table at its
/// point (returns the number of cases run).
fn scan_run(b: &mut Bench, scan: &Scan, catalogue: bool) -> usize {
    let mut cases = 0;
    b.h.ok(HostMessage::Hello(scan.cfg));
    for k in 0..BEFORE {
        b.stream_frame(scan, k);
    }
    if catalogue {
        let st = b.h.status();
        assert_eq!((st.phase, st.frames_seen), (Phase::Ready, BEFORE));
        assert!(st.database_size >= 2, "a database to protect: {st:?}");
        assert!(
            st.export_records() > st.database_size,
            "labels to protect: {st:?}"
        );
        assert!(st.stored_records > 1, "records in flash: {st:?}");
        let mut t = Table::new(b.h.seq + 1);
        between_frames(scan, &mut t, BEFORE, st.export_records());
        cases += b.run(t);
        b.assert_restores("between frames");
    }
    // Frame BEFORE opens with its first message of rows.
    let open = BEFORE;
    let rpm = scan.rows_per_message();
    b.h.ok(scan.begin(open));
    b.h.ok(depth_rows(open, 0, rpm, &scan.rows(open, 0, rpm)));
    if catalogue {
        let st = b.h.status();
        assert_eq!(st.phase, Phase::InFrame);
        let mut t = Table::new(b.h.seq + 1);
        in_frame(scan, &mut t, open, rpm, st.export_records());
        cases += b.run(t);
        b.assert_restores("inside a frame");
    }
    // The frame goes on where it was, the scan ends.
    b.stream_rows(scan, open, rpm);
    b.h.ok(HostMessage::FrameEnd { frame: open });
    for k in open + 1..FRAMES {
        b.stream_frame(scan, k);
    }
    b.h.ok(HostMessage::Finish);
    if catalogue {
        let st = b.h.status();
        assert_eq!((st.phase, st.frames_decided), (Phase::Finished, FRAMES));
        let mut t = Table::new(b.h.seq + 1);
        finished(scan, &mut t, FRAMES, st.export_records());
        cases += b.run(t);
        b.assert_restores("after Finish");
    }
    cases
}

#[test]
fn bad_inputs_before_hello_change_nothing() {
    on_big_stack(|| {
        let scan = Scan::new();
        let mut b = Bench::new();
        let mut t = Table::new(1);
        before_hello(&scan, &mut t);
        let n = b.run(t);
        b.assert_no_failures(n);
        let st = b.h.status();
        assert_eq!(st.phase, Phase::Unconfigured);
        // Nothing written (the one erase ahead of need leaves a blank
        // sector blank).
        assert!(
            b.h.flash().bytes().iter().all(|&byte| byte == 0xFF),
            "nothing written before Hello"
        );
        // Not wedged: the Hello is accepted, the first frame goes through.
        b.h.ok(HostMessage::Hello(scan.cfg));
        b.stream_frame(&scan, 0);
        assert_eq!(b.h.status().frames_seen, 1);
        println!("{n} bad inputs before Hello refused, nothing changed");
    });
}

#[test]
fn every_bad_input_gets_its_typed_error_and_changes_nothing() {
    on_big_stack(|| {
        let started = Instant::now();
        let scan = Scan::new();
        let mut clean = Bench::new();
        scan_run(&mut clean, &scan, false);
        let mut b = Bench::new();
        let cases = scan_run(&mut b, &scan, true);
        b.assert_no_failures(cases);
        // The catalogue left no trace: the export and the flash are those of
        // the same scan without a single bad input.
        let st = b.h.status();
        assert_eq!(st.refused as usize, cases);
        assert_eq!(b.h.export(), clean.h.export());
        assert_eq!(b.h.flash().steps(), clean.h.flash().steps());
        assert!(
            b.h.flash().bytes() == clean.h.flash().bytes(),
            "the flash differs from that of the clean run"
        );
        println!(
            "{cases} bad inputs refused with their typed errors, nothing changed ({:.2} s)",
            started.elapsed().as_secs_f64()
        );
    });
}
