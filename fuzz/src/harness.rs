//! Per-input checks of the fuzz targets, shared with the root test
//! `tests/fuzz_corpus.rs` (which includes this file with `#[path]`), so the
//! committed corpus replays exactly these checks on stable. Depends on `std`
//! and `placedb` only.
//!
//! Every entry point panics when an invariant breaks: libFuzzer reports the
//! panic as a crash, the corpus test as a failure.
//!
//! Input layout, common to all targets: the first byte gives the number `k`
//! (its low 3 bits) of chunk-size bytes that follow; the payload after them is
//! fed in chunks of `(s + 1)` bytes (`16 * (s + 1)` when bit 3 of the first
//! byte is set), `s` cycling over the size bytes; `k = 0` feeds it whole.

use placedb::camera::{DepthRange, Intrinsics, Pose};
use placedb::device::harness::{check_export, decode_reply, durable_part, terminal};
use placedb::device::Device;
use placedb::frame::FrameMeta;
use placedb::key_pool::Aabb;
use placedb::persist::record::{KeyChunks, DECISION_BATCH};
use placedb::persist::sim::SimFlash;
use placedb::persist::{Log, Record};
use placedb::protocol::{
    degradation, depth_rows_per_message, encode, strided_len, CapacitySlot, Config, DecisionKind,
    DepthRows, DeviceMessage, ErrorKind, ExportRecord, Feed, FrameDecoder, HostFrame, HostMessage,
    Phase, ProtocolError, RecordKind, Status, MAX_FRAME_LEN, PROTOCOL_VERSION,
};

/// The device under test: far smaller than the profiles, so that an input
/// runs fast and every capacity (frame voxels, pool, database, window,
/// labels) runs out within a few frames.
pub type FuzzDevice = Device<256, 1024, 4, 4, 8, 16>;

/// Sectors of the device's flash log: small, so that inputs fill it
/// (`StorageFull`) and generations wrap around it.
const LOG_SECTORS: usize = 8;

/// Most ops one structured input runs.
const MAX_OPS: usize = 256;
/// Most synthetic depth values one structured input sends (bounds the time
/// of an input while allowing many small frames).
const MAX_FILLED_VALUES: u32 = 8192;

// ---------------------------------------------------------------- chunking

/// Cuts a byte stream into the chunks of consecutive `receive`/`feed` calls.
struct Chunker<'a> {
    sizes: &'a [u8],
    scale: usize,
    next: usize,
}

impl<'a> Chunker<'a> {
    /// The chunk plan at the start of `data`, and the payload after it.
    fn split(data: &'a [u8]) -> (Self, &'a [u8]) {
        let (head, rest) = match data.split_first() {
            Some((h, rest)) => (*h, rest),
            None => (0, data),
        };
        let k = usize::from(head & 7).min(rest.len());
        let (sizes, payload) = rest.split_at(k);
        let scale = if head & 8 != 0 { 16 } else { 1 };
        let chunker = Chunker {
            sizes,
            scale,
            next: 0,
        };
        (chunker, payload)
    }

    /// `bytes` cut into chunks, continuing the cycle of sizes.
    fn chunks<'d>(&mut self, bytes: &'d [u8]) -> Vec<&'d [u8]> {
        let mut out = Vec::new();
        let mut rest = bytes;
        while !rest.is_empty() {
            let n = match self.sizes.get(self.next % self.sizes.len().max(1)) {
                Some(&s) => (usize::from(s) + 1) * self.scale,
                None => rest.len(),
            };
            self.next = self.next.wrapping_add(1);
            let (chunk, tail) = rest.split_at(n.min(rest.len()));
            out.push(chunk);
            rest = tail;
        }
        out
    }
}

/// Number of frame events (messages or errors) a decoder of `n` bytes must
/// report for `stream`: one per non-empty 0-terminated segment, plus one for an
/// unterminated tail already too long.
fn expected_frames(stream: &[u8], n: usize) -> usize {
    let capacity = n.saturating_sub(1);
    let segments: Vec<&[u8]> = stream.split(|&b| b == 0).collect();
    let Some((tail, terminated)) = segments.split_last() else {
        return 0;
    };
    terminated.iter().filter(|s| !s.is_empty()).count() + usize::from(tail.len() > capacity)
}

// ----------------------------------------------------------- frame decoder

/// What a decoder reported for one frame: the re-encoded message or the error.
#[derive(Debug, PartialEq)]
enum Event {
    Frame(Vec<u8>),
    Error(ProtocolError),
}

/// Re-encodes a decoded message: it must fit [`MAX_FRAME_LEN`], decode again,
/// and re-encode to the same bytes (a fixed point).
macro_rules! reencode_fn {
    ($name:ident, $msg:ident) => {
        fn $name(msg: &$msg<'_>) -> Vec<u8> {
            let mut buf = vec![0u8; MAX_FRAME_LEN];
            let frame = match encode(msg, &mut buf) {
                Ok(frame) => frame.to_vec(),
                Err(e) => panic!("decoded {msg:?} does not re-encode within MAX_FRAME_LEN: {e}"),
            };
            assert!(frame.len() <= MAX_FRAME_LEN);
            let mut decoder = FrameDecoder::<MAX_FRAME_LEN>::new();
            match decoder.feed::<$msg>(&frame) {
                Feed::Frame {
                    result: Ok(again),
                    remaining: [],
                } => {
                    let mut buf2 = vec![0u8; MAX_FRAME_LEN];
                    let frame2 = encode(&again, &mut buf2).expect("re-encode");
                    assert_eq!(frame2, &frame[..], "re-encoding is not a fixed point");
                }
                other => panic!("re-encoded {msg:?} does not decode: {other:?}"),
            }
            frame
        }
    };
}

reencode_fn!(reencode_host, HostFrame);
reencode_fn!(reencode_device, DeviceMessage);

/// Feeds `chunks` to a decoder of `N` bytes for messages `$msg`; every event.
macro_rules! events_fn {
    ($name:ident, $msg:ident, $reencode:ident) => {
        fn $name<const N: usize>(chunks: &[&[u8]]) -> Vec<Event> {
            let mut decoder = FrameDecoder::<N>::new();
            let mut events = Vec::new();
            for chunk in chunks {
                let mut rest: &[u8] = chunk;
                while let Feed::Frame { result, remaining } = decoder.feed::<$msg>(rest) {
                    events.push(match result {
                        Ok(msg) => Event::Frame($reencode(&msg)),
                        Err(e) => Event::Error(e),
                    });
                    rest = remaining;
                }
                assert!(decoder.frame_len() < N.max(1));
            }
            events
        }
    };
}

events_fn!(host_events, HostFrame, reencode_host);
events_fn!(device_events, DeviceMessage, reencode_device);

/// Target `frame_decoder`: arbitrary bytes in arbitrary chunks into
/// [`FrameDecoder`]s for both directions. No panic; every decoded message
/// re-encodes within [`MAX_FRAME_LEN`]; the events do not depend on the
/// chunking; one event per frame; only host frames carry a sequence number in
/// errors, and only CRC/decode errors do.
pub fn frame_decoder(data: &[u8]) {
    let (mut chunker, payload) = Chunker::split(data);
    let chunks = chunker.chunks(payload);
    let whole = [payload];

    let host = host_events::<MAX_FRAME_LEN>(&chunks);
    assert_eq!(
        host,
        host_events::<MAX_FRAME_LEN>(&whole),
        "chunking matters"
    );
    assert_eq!(host.len(), expected_frames(payload, MAX_FRAME_LEN));
    for event in &host {
        if let Event::Error(e) = event {
            if matches!(
                e.kind,
                ErrorKind::Oversized | ErrorKind::BadFraming | ErrorKind::Truncated
            ) {
                assert_eq!(e.seq, None, "{e:?}");
            }
        }
    }

    let device = device_events::<MAX_FRAME_LEN>(&chunks);
    assert_eq!(
        device,
        device_events::<MAX_FRAME_LEN>(&whole),
        "chunking matters"
    );
    assert_eq!(device.len(), expected_frames(payload, MAX_FRAME_LEN));
    for event in &device {
        if let Event::Error(e) = event {
            assert_eq!(e.seq, None, "device messages carry no sequence prefix");
        }
    }

    // A tiny buffer: the oversize path on short inputs.
    let small = host_events::<16>(&chunks);
    assert_eq!(small, host_events::<16>(&whole), "chunking matters");
    assert_eq!(small.len(), expected_frames(payload, 16));
}

// ------------------------------------------------------------------ device

/// Invariants of any status of a [`FuzzDevice`].
fn check_status(st: &Status) {
    let limits = [
        (CapacitySlot::Database, FuzzDevice::DATABASE_FRAMES),
        // Labels and flash are bounded by the log, not by a constant.
        (CapacitySlot::Labels, usize::MAX),
        (CapacitySlot::Resident, FuzzDevice::RESIDENT),
        (CapacitySlot::Flash, usize::MAX),
        (CapacitySlot::Pool, FuzzDevice::POOL_WORDS),
        (CapacitySlot::Window, FuzzDevice::WINDOW),
        (CapacitySlot::FrameVoxels, FuzzDevice::FRAME_VOXEL_SLOTS),
        (CapacitySlot::RxFrame, MAX_FRAME_LEN),
    ];
    for (slot, most) in limits {
        let c = st.capacity(slot);
        assert!(
            c.used <= c.limit && c.peak <= c.limit && c.used <= c.peak,
            "{slot:?}: {c:?}"
        );
        assert!(
            c.limit as usize <= most,
            "{slot:?}: limit {} > {most}",
            c.limit
        );
    }
    assert_eq!(st.database_size, st.capacity(CapacitySlot::Database).used);
    assert!(st.frames_decided <= st.frames_seen, "{st:?}");
    // Every decided frame is labelled, counted as dropped, or waits in the
    // batch on its way to the log.
    let kept = st.capacity(CapacitySlot::Labels).used + st.labels_dropped;
    assert!(
        kept <= st.frames_decided && st.frames_decided - kept < DECISION_BATCH as u32,
        "every decided frame is labelled, dropped or in the batch: {st:?}"
    );
    if st.phase == Phase::Unconfigured {
        assert_eq!((st.frames_seen, st.database_size), (0, 0), "{st:?}");
    }
}

/// Sequence numbers the device must answer, in order, for `stream`: a shadow
/// decoder's view of each host frame.
fn expected_terminals(stream: &[u8]) -> Vec<Option<u32>> {
    let mut decoder = FrameDecoder::<MAX_FRAME_LEN>::new();
    let mut seqs = Vec::new();
    let mut rest = stream;
    while let Feed::Frame { result, remaining } = decoder.feed::<HostFrame>(rest) {
        seqs.push(match result {
            Ok(frame) => Some(frame.seq),
            Err(e) => e.seq,
        });
        rest = remaining;
    }
    assert_eq!(seqs.len(), expected_frames(stream, MAX_FRAME_LEN));
    seqs
}

/// A device being fed, with its flash log, everything it was fed and
/// everything it sent.
struct Run {
    device: Box<FuzzDevice>,
    log: Log<SimFlash>,
    stream: Vec<u8>,
    replies: Vec<Vec<u8>>,
}

fn open_log(flash: SimFlash) -> Log<SimFlash> {
    let end = (LOG_SECTORS * SimFlash::SECTOR) as u32;
    Log::open(flash, 0, end).expect("open the log")
}

/// Every record of a device's export, through the wire.
fn export_of(device: &mut FuzzDevice, log: &mut Log<SimFlash>) -> Vec<ExportRecord> {
    let mut buf = vec![0u8; MAX_FRAME_LEN];
    let msg = HostMessage::ExportRequest {
        from_record: 0,
        max_records: u32::MAX,
    };
    let frame = encode(&HostFrame { seq: 1, msg }, &mut buf).expect("encode");
    let mut replies = Vec::new();
    device.receive_logged(&[0], log, &mut |f: &[u8]| replies.push(f.to_vec()));
    device.receive_logged(frame, log, &mut |f: &[u8]| replies.push(f.to_vec()));
    replies
        .iter()
        .filter_map(|f| match decode_reply(f) {
            DeviceMessage::ExportRecord(r) => Some(r),
            _ => None,
        })
        .collect()
}

impl Run {
    fn new() -> Self {
        Run {
            device: Box::new(FuzzDevice::new()),
            log: open_log(SimFlash::new(LOG_SECTORS)),
            stream: Vec::new(),
            replies: Vec::new(),
        }
    }

    /// Feeds `bytes` in the chunks of `chunker`, checking the status after
    /// each chunk that completed a frame (the state changes only then).
    fn feed(&mut self, bytes: &[u8], chunker: &mut Chunker<'_>) {
        for chunk in chunker.chunks(bytes) {
            let before = self.replies.len();
            let replies = &mut self.replies;
            self.device
                .receive_logged(chunk, &mut self.log, &mut |frame: &[u8]| {
                    replies.push(frame.to_vec())
                });
            if self.replies.len() != before {
                check_status(&self.device.status());
            }
        }
        self.stream.extend_from_slice(bytes);
    }

    /// Ends any partial frame, asks for the status and a full export, then
    /// checks every reply against the stream.
    fn finish(mut self) {
        let (status_seq, export_seq) = (u32::MAX - 1, u32::MAX);
        let mut tail = vec![0u8];
        let mut buf = vec![0u8; MAX_FRAME_LEN];
        for (seq, msg) in [
            (status_seq, HostMessage::StatusRequest),
            (
                export_seq,
                HostMessage::ExportRequest {
                    from_record: 0,
                    max_records: u32::MAX,
                },
            ),
        ] {
            tail.extend_from_slice(encode(&HostFrame { seq, msg }, &mut buf).expect("encode"));
        }
        self.feed(&tail, &mut Chunker::split(&[]).0);

        let replies: Vec<DeviceMessage> = self.replies.iter().map(|f| decode_reply(f)).collect();
        let terminals: Vec<Option<u32>> = replies.iter().filter_map(terminal).collect();
        assert_eq!(
            terminals,
            expected_terminals(&self.stream),
            "one terminal reply per host frame, with its sequence number"
        );

        // Replies come in groups ending with a terminal reply: decisions
        // before an Ack, records before an ExportEnd, nothing else.
        let mut group: Vec<&DeviceMessage> = Vec::new();
        let mut last_status = None;
        let mut last_export = None;
        for reply in &replies {
            if terminal(reply).is_none() {
                group.push(reply);
                continue;
            }
            match reply {
                DeviceMessage::Ack { .. } => assert!(
                    group
                        .iter()
                        .all(|r| matches!(r, DeviceMessage::Decision { .. })),
                    "{group:?} before {reply:?}"
                ),
                DeviceMessage::ExportEnd {
                    from_record,
                    count,
                    crc32,
                    ..
                } => {
                    let records: Vec<ExportRecord> = group
                        .iter()
                        .map(|r| match r {
                            DeviceMessage::ExportRecord(rec) => *rec,
                            other => panic!("{other:?} inside an export"),
                        })
                        .collect();
                    check_export(&records, *from_record, *count, *crc32);
                    last_export = Some(records);
                }
                DeviceMessage::Status(s) => {
                    assert!(group.is_empty(), "{group:?} before a status");
                    check_status(s);
                    last_status = Some(*s);
                }
                _ => assert!(group.is_empty(), "{group:?} before {reply:?}"),
            }
            group.clear();
        }
        assert!(
            group.is_empty(),
            "replies after the last terminal: {group:?}"
        );

        // The closing status and export describe the same state.
        let (Some(st), Some(records)) = (last_status, last_export) else {
            panic!("no closing status or export");
        };
        assert_eq!(st.seq, status_seq);
        assert_eq!(records.len(), st.export_records() as usize, "{st:?}");
        let db = st.database_size as usize;
        let mut last_frame = None;
        for (i, r) in records.iter().enumerate() {
            if i < db {
                assert!(matches!(r.kind, RecordKind::Database { .. }), "{r:?}");
                assert!(last_frame < Some(r.frame), "database out of frame order");
                last_frame = Some(r.frame);
            } else if let RecordKind::Session { session } = r.kind {
                // Sessions after the first, after every label.
                let labels = st.capacity(CapacitySlot::Labels).used as usize;
                assert_eq!(i, db + labels + session as usize - 1, "{r:?}");
            } else {
                assert!(matches!(r.kind, RecordKind::Label { .. }), "{r:?}");
                assert_eq!(r.frame as usize, i - db, "labels in frame order");
            }
        }

        // Power cut now: a fresh device restores from the flash exactly the
        // durable part of what the live one exports: every label, and the
        // database frames a label names (frames still pending in the window
        // are not decided, so neither has their labels, and a frame taken for
        // a decision not yet in the log does not come back).
        assert_eq!(st.degradation & degradation::STORAGE_FAILED, 0);
        let mut log = open_log(self.log.into_flash());
        let mut restored = Box::new(FuzzDevice::new());
        restored.restore(&mut log).expect("the log restores");
        check_status(&restored.status());
        // Decided frames come back as far as their batch reached the log.
        let durable = st.capacity(CapacitySlot::Labels).used;
        assert_eq!(restored.status().frames_decided, durable);
        assert_eq!(export_of(&mut restored, &mut log), durable_part(&records));
    }
}

/// Target `device`: arbitrary bytes in arbitrary chunks into a [`FuzzDevice`];
/// then a resynchronising 0x00, a status request and a full export. No panic;
/// every reply frame at most
/// [`MAX_REPLY_LEN`](placedb::protocol::MAX_REPLY_LEN) bytes and one whole
/// [`DeviceMessage`]; exactly one terminal reply per host frame, with its
/// sequence number; capacities within their limits after every chunk; every
/// export consistent with its `ExportEnd` and the status.
pub fn device(data: &[u8]) {
    let (mut chunker, payload) = Chunker::split(data);
    let mut run = Run::new();
    run.feed(payload, &mut chunker);
    run.finish();
}

// -------------------------------------------------------- structured device

/// Reads fields from fuzz input; zeros once the input is used up.
struct Reader<'a> {
    data: &'a [u8],
}

impl<'a> Reader<'a> {
    fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    fn u8(&mut self) -> u8 {
        match self.data.split_first() {
            Some((&b, rest)) => {
                self.data = rest;
                b
            }
            None => 0,
        }
    }

    fn u16(&mut self) -> u16 {
        u16::from_le_bytes([self.u8(), self.u8()])
    }

    fn u32(&mut self) -> u32 {
        u32::from_le_bytes([self.u8(), self.u8(), self.u8(), self.u8()])
    }

    fn f32(&mut self) -> f32 {
        f32::from_bits(self.u32())
    }

    fn f64(&mut self) -> f64 {
        f64::from_bits(u64::from(self.u32()) | (u64::from(self.u32()) << 32))
    }

    /// One of `items`.
    fn pick<T: Copy>(&mut self, items: &[T]) -> T {
        items[usize::from(self.u8()) % items.len()]
    }

    fn bytes(&mut self, n: usize) -> &'a [u8] {
        let (head, rest) = self.data.split_at(n.min(self.data.len()));
        self.data = rest;
        head
    }
}

/// A valid configuration of a small camera (the fast path to deep states).
fn sane_config(r: &mut Reader<'_>) -> Config {
    let width = 1 + u16::from(r.u8() % 40);
    let height = 1 + u16::from(r.u8() % 30);
    let stride = 1 + u16::from(r.u8() % 4);
    let f = 10.0 + f32::from(r.u8());
    Config {
        version: PROTOCOL_VERSION,
        voxel_size: r.pick(&[0.02, 0.05, 0.1, 0.2, 0.5, 1.0]),
        mu: f32::from(r.u8() % 100) / 100.0,
        depth_scale: r.pick(&[1000.0, 5000.0, 1.0, 2.0]),
        intrinsics: Intrinsics {
            width,
            height,
            fx: f,
            fy: f,
            cx: f32::from(width) / 2.0,
            cy: f32::from(height) / 2.0,
        },
        stride,
        depth_range: r.pick(&[
            DepthRange::default(),
            DepthRange {
                min: 0.0,
                max: f32::INFINITY,
            },
            DepthRange { min: 1.0, max: 2.0 },
        ]),
        grid_origin: r.pick(&[[0.0; 3], [-5.0, -5.0, -5.0], [1e3, -2e3, 0.5]]),
        window: 1 + u16::from(r.u8() % 6),
        sketch_margin: f32::from(r.u8() % 30) / 100.0,
    }
}

/// A configuration of arbitrary numbers (mostly refused, sometimes extreme).
fn raw_config(r: &mut Reader<'_>) -> Config {
    Config {
        version: if r.u8() & 1 == 0 {
            PROTOCOL_VERSION
        } else {
            r.u16()
        },
        voxel_size: r.f32(),
        mu: r.f32(),
        depth_scale: r.f32(),
        intrinsics: Intrinsics {
            width: r.u16(),
            height: r.u16(),
            fx: r.f32(),
            fy: r.f32(),
            cx: r.f32(),
            cy: r.f32(),
        },
        stride: r.u16(),
        depth_range: DepthRange {
            min: r.f32(),
            max: r.f32(),
        },
        grid_origin: [r.f32(), r.f32(), r.f32()],
        window: r.u16(),
        sketch_margin: r.f32(),
    }
}

/// A valid pose near the origin.
fn sane_pose(r: &mut Reader<'_>) -> Pose {
    const H: f32 = core::f32::consts::FRAC_1_SQRT_2;
    let step = |b: u8| f32::from(b as i8) * 0.05;
    Pose {
        translation: [step(r.u8()), step(r.u8()), step(r.u8())],
        rotation: r.pick(&[
            [0.0, 0.0, 0.0, 1.0],
            [H, 0.0, 0.0, H],
            [0.0, H, 0.0, H],
            [0.0, 0.0, H, H],
            [1.0, 0.0, 0.0, 0.0],
            [0.5, 0.5, 0.5, 0.5],
        ]),
    }
}

/// A pose of arbitrary numbers.
fn raw_pose(r: &mut Reader<'_>) -> Pose {
    Pose {
        translation: [r.f32(), r.f32(), r.f32()],
        rotation: [r.f32(), r.f32(), r.f32(), r.f32()],
    }
}

/// Builds a structured conversation from the input and checks the device on it.
struct Conversation<'r, 'a> {
    r: &'r mut Reader<'a>,
    chunker: Chunker<'a>,
    run: Run,
    seq: u32,
    /// Next strided row of the open frame, as far as we sent rows.
    next_row: u16,
    filled: u32,
    buf: Vec<u8>,
}

impl Conversation<'_, '_> {
    fn send(&mut self, msg: HostMessage<'_>) {
        self.seq = self.seq.wrapping_add(1);
        let frame = encode(&HostFrame { seq: self.seq, msg }, &mut self.buf).expect("encode");
        let frame = frame.to_vec();
        self.run.feed(&frame, &mut self.chunker);
    }

    /// `(width_sent, height_sent)` of the configuration in force.
    fn strided_size(&self) -> Option<(u16, u16)> {
        let scan = self.run.device.selector().scan_config()?;
        Some((
            strided_len(scan.intrinsics.width, scan.stride),
            strided_len(scan.intrinsics.height, scan.stride),
        ))
    }

    fn open_frame(&self) -> Option<u32> {
        self.run.device.selector().current_frame().map(|m| m.index)
    }

    fn begin_next(&mut self) {
        let frame = self.run.device.status().frames_seen;
        let pose = sane_pose(self.r);
        self.send(HostMessage::FrameBegin {
            frame,
            timestamp: f64::from(frame) / 30.0,
            pose,
        });
        self.next_row = 0;
    }

    /// Sends the remaining rows of the open frame, synthesised from a pattern.
    fn fill_rows(&mut self) {
        let (Some((ws, hs)), Some(frame)) = (self.strided_size(), self.open_frame()) else {
            return;
        };
        let values = u32::from(ws) * u32::from(hs.saturating_sub(self.next_row));
        if self.filled.saturating_add(values) > MAX_FILLED_VALUES {
            return;
        }
        self.filled += values;
        let per_msg = depth_rows_per_message(ws).clamp(1, 1 + u16::from(self.r.u8() % 16));
        let pattern = self.r.u8() % 5;
        let base = self.r.u16();
        let (du, dv) = (self.r.u8() as i8, self.r.u8() as i8);
        let mut seed = self.r.u32() | 1;
        let raw = self.r.bytes(64);
        let mut data = Vec::new();
        while self.next_row < hs {
            let rows = per_msg.min(hs - self.next_row);
            data.clear();
            for v in self.next_row..self.next_row + rows {
                for u in 0..ws {
                    let d: u16 = match pattern {
                        0 => 0,
                        1 => base % 12_000,
                        2 => (i32::from(base % 8000)
                            + i32::from(du) * i32::from(u)
                            + i32::from(dv) * i32::from(v))
                        .clamp(0, 65_535) as u16,
                        3 => {
                            seed ^= seed << 13;
                            seed ^= seed >> 17;
                            seed ^= seed << 5;
                            (seed >> 16) as u16
                        }
                        _ => {
                            let i = usize::from(u) * 2 + usize::from(v);
                            match raw.len() {
                                0 => 0,
                                n => u16::from_le_bytes([raw[i % n], raw[(i + 1) % n]]),
                            }
                        }
                    };
                    data.extend_from_slice(&d.to_le_bytes());
                }
            }
            let first_row = self.next_row;
            self.next_row += rows;
            self.send(HostMessage::DepthRows(DepthRows {
                frame,
                first_row,
                row_count: rows,
                data: &data,
            }));
        }
    }

    fn end_open(&mut self) {
        let frame = self
            .open_frame()
            .unwrap_or_else(|| self.run.device.status().frames_seen);
        self.send(HostMessage::FrameEnd { frame });
    }

    fn step(&mut self, op: u8) {
        match op % 16 {
            0 => {
                let cfg = sane_config(self.r);
                self.send(HostMessage::Hello(cfg));
            }
            1 => {
                let cfg = raw_config(self.r);
                self.send(HostMessage::Hello(cfg));
            }
            2 => self.begin_next(),
            3 => {
                let (frame, timestamp, pose) = (self.r.u32(), self.r.f64(), raw_pose(self.r));
                self.send(HostMessage::FrameBegin {
                    frame,
                    timestamp,
                    pose,
                });
            }
            4 => self.fill_rows(),
            5 => {
                let frame = match self.r.u8() & 1 {
                    0 => self.open_frame().unwrap_or(0),
                    _ => self.r.u32(),
                };
                let first_row = self.r.u16() % 64;
                let row_count = u16::from(self.r.u8() % 8);
                let len = usize::from(self.r.u8()) * 2;
                let data = self.r.bytes(len);
                self.send(HostMessage::DepthRows(DepthRows {
                    frame,
                    first_row,
                    row_count,
                    data,
                }));
            }
            6 => self.end_open(),
            7 => {
                let frame = self.r.u32();
                self.send(HostMessage::FrameEnd { frame });
            }
            8 => self.send(HostMessage::Finish),
            9 => self.send(HostMessage::StatusRequest),
            10 => {
                let from_record = u32::from(self.r.u8() % 40);
                let max_records = match self.r.u8() {
                    255 => u32::MAX,
                    n => u32::from(n % 40),
                };
                self.send(HostMessage::ExportRequest {
                    from_record,
                    max_records,
                });
            }
            11 => self.send(HostMessage::Reset),
            12 => {
                // Garbage, maybe ending the frame it starts.
                let flags = self.r.u8();
                let len = usize::from(flags % 64);
                let mut junk = self.r.bytes(len).to_vec();
                if flags & 64 != 0 {
                    junk.push(0);
                }
                self.run.feed(&junk, &mut self.chunker);
            }
            13 => {
                // A valid frame with one byte damaged.
                self.seq = self.seq.wrapping_add(1);
                let msg = match self.r.u8() % 3 {
                    0 => HostMessage::StatusRequest,
                    1 => HostMessage::Finish,
                    _ => HostMessage::FrameEnd {
                        frame: self.open_frame().unwrap_or(0),
                    },
                };
                let mut frame = encode(&HostFrame { seq: self.seq, msg }, &mut self.buf)
                    .expect("encode")
                    .to_vec();
                let at = usize::from(self.r.u8()) % frame.len();
                frame[at] ^= self.r.u8() | 1;
                self.run.feed(&frame, &mut self.chunker);
            }
            14 => {
                let frame = match self.r.u8() & 1 {
                    0 => self.open_frame().unwrap_or(0),
                    _ => self.r.u32(),
                };
                self.send(HostMessage::FrameAbort { frame });
            }
            _ => {
                // Whole frames: begin, every row, end.
                for _ in 0..1 + self.r.u8() % 8 {
                    self.begin_next();
                    self.fill_rows();
                    self.end_open();
                }
            }
        }
    }
}

/// Target `device_structured`: the input describes a conversation of valid
/// messages (sane or insane Hellos, frames with synthetic depth rows, ends,
/// aborts, finish, status, export, reset) mixed with garbage and damaged frames, so
/// the fuzzer reaches full databases, windows and label stores. Same checks
/// as [`device`].
pub fn device_structured(data: &[u8]) {
    let (chunker, payload) = Chunker::split(data);
    let mut r = Reader { data: payload };
    let mut conv = Conversation {
        r: &mut r,
        chunker,
        run: Run::new(),
        seq: 0,
        next_row: 0,
        filled: 0,
        buf: vec![0u8; MAX_FRAME_LEN],
    };
    let mut ops = 0;
    while !conv.r.is_empty() && ops < MAX_OPS {
        let op = conv.r.u8();
        conv.step(op);
        ops += 1;
    }
    conv.run.finish();
}

// ------------------------------------------------------------ restore

/// One record with fuzzed fields, encoded into `buf`: every kind,
/// consistent or not.
fn fuzzed_record<'b>(r: &mut Reader<'_>, buf: &'b mut [u8]) -> Option<&'b [u8]> {
    let frame = |r: &mut Reader<'_>| {
        if r.u8() & 1 == 0 {
            r.u32() % 16
        } else {
            r.u32()
        }
    };
    let kind = |r: &mut Reader<'_>| match r.u8() % 5 {
        0 => DecisionKind::Taken,
        1 => DecisionKind::DominatedBy(r.u32() % 16),
        2 => DecisionKind::Pending,
        3 => DecisionKind::Uncovered(None),
        _ => DecisionKind::Uncovered(Some(r.u32() % 16)),
    };
    match r.u8() % 7 {
        0 => Record::Begin(sane_config(r)).encode(buf).ok(),
        1 => Record::Begin(raw_config(r)).encode(buf).ok(),
        2 => Record::Cleared.encode(buf).ok(),
        3 => {
            let n = usize::from(r.u8() % 12);
            let ascending = r.u8() & 1 == 0;
            let mut hashes = Vec::new();
            let mut h = r.u32() % 1000;
            for _ in 0..n {
                hashes.push(h);
                h = if ascending {
                    h + 1 + r.u32() % 100
                } else {
                    r.u32()
                };
            }
            let small = |r: &mut Reader<'_>| i32::from(r.u8() as i8);
            let meta = FrameMeta {
                index: frame(r),
                timestamp: r.f64(),
                pose: raw_pose(r),
            };
            let voxels = r.u32() % 64;
            let aabb = (r.u8() & 1 == 0).then(|| Aabb {
                min: [small(r), small(r), small(r)],
                max: [small(r), small(r), small(r)],
            });
            let mut keys = KeyChunks::NONE;
            keys.count = r.u8() % 3;
            for a in keys.at.iter_mut() {
                *a = r.u32() % (LOG_SECTORS as u32 * SimFlash::SECTOR as u32);
            }
            Record::encode_database(meta, voxels, aabb, &hashes, keys, buf).ok()
        }
        4 => {
            let n = 1 + usize::from(r.u8()) % DECISION_BATCH;
            let decisions: Vec<_> = (0..n).map(|_| (r.f64(), kind(r), r.u32())).collect();
            Record::encode_decisions(frame(r), &decisions, buf).ok()
        }
        5 => {
            let n = usize::from(r.u8() % 8);
            let mut words: Vec<u32> = (0..n).map(|_| r.u32() % 4096).collect();
            words.sort_unstable();
            words.dedup();
            let count = words.len() as u16;
            let fill = |tail: &mut [u8]| {
                placedb::persist::keys::encode_chunk(&words, 0, tail).map(|(len, _)| len)
            };
            if words.is_empty() {
                return None;
            }
            Record::encode_keys(frame(r), count, fill, buf).ok()
        }
        _ => Record::Finished.encode(buf).ok(),
    }
}

/// Target `restore`: the input is read three ways, each a flash image
/// restored into a fresh device:
///
/// 1. a log written through [`Log`] (records of every kind with fuzzed
///    fields, CRC-valid so that they reach the device, new generations here
///    and there), then a few damaged bytes;
/// 2. the raw input bytes as the flash contents;
/// 3. CRC-valid records placed by the input: any generation (`u32::MAX` and
///    its neighbours included), any sequence number, any place.
///
/// For each: no panic; a refused log leaves the device empty; the status
/// and the export are consistent; the device then starts a new scan (Reset,
/// Hello), which a second restore brings back, configuration and all.
pub fn restore(data: &[u8]) {
    let mut r = Reader { data };
    let flash = written_image(&mut r);
    restore_image(flash, &mut r);
    restore_image(raw_image(data), &mut Reader { data });
    let mut r = Reader { data };
    let flash = placed_image(&mut r);
    restore_image(flash, &mut r);
}

/// Image 1: a log written through [`Log`], then damaged.
fn written_image(r: &mut Reader<'_>) -> SimFlash {
    let mut log = open_log(SimFlash::new(LOG_SECTORS));
    let mut buf = vec![0u8; 1024];
    for i in 0..r.u8() % 48 {
        let Some(payload) = fuzzed_record(r, &mut buf) else {
            continue;
        };
        let _ = if i == 0 || r.u8().is_multiple_of(16) {
            log.start(payload)
        } else {
            log.append(payload).map(|_| ())
        };
    }
    let mut flash = log.into_flash();
    let len = flash.bytes_mut().len();
    for _ in 0..r.u8() % 4 {
        let at = r.u32() as usize % len;
        flash.bytes_mut()[at] ^= r.u8() | 1;
    }
    flash
}

/// Image 2: the input itself (the rest erased).
fn raw_image(data: &[u8]) -> SimFlash {
    let mut flash = SimFlash::new(LOG_SECTORS);
    let bytes = flash.bytes_mut();
    let n = data.len().min(bytes.len());
    bytes[..n].copy_from_slice(&data[..n]);
    flash
}

/// Image 3: CRC-valid records of fuzzed generations and sequence numbers.
/// Each op opens a generation at a sector's start, goes on with the next
/// record of the current one (where it would be written, or at the start
/// of another sector), or puts a record of any numbers anywhere.
fn placed_image(r: &mut Reader<'_>) -> SimFlash {
    const SECTOR: usize = SimFlash::SECTOR;
    let mut flash = SimFlash::new(LOG_SECTORS);
    let mut buf = vec![0u8; 1024];
    let (mut at, mut generation, mut seq) = (0usize, 0u32, 0u32);
    for _ in 0..r.u8() % 32 {
        match r.u8() % 4 {
            0 => {
                at = usize::from(r.u8()) % LOG_SECTORS * SECTOR;
                generation = match r.u8() % 4 {
                    0 => u32::MAX - u32::from(r.u8() % 3),
                    1 => u32::from(r.u8() % 4),
                    2 => generation.wrapping_add(1),
                    _ => r.u32(),
                };
                seq = 0;
            }
            1 => {}
            2 => at = usize::from(r.u8()) % LOG_SECTORS * SECTOR,
            _ => {
                at = usize::from(r.u16()) * 4 % (LOG_SECTORS * SECTOR);
                generation = r.u32();
                seq = r.u32();
            }
        }
        let Some(payload) = fuzzed_record(r, &mut buf) else {
            continue;
        };
        let len = (20 + payload.len()).next_multiple_of(4);
        if at % SECTOR + len > SECTOR {
            at = (at / SECTOR + 1) % LOG_SECTORS * SECTOR;
        }
        if let Some(used) = flash.put_record(at, generation, seq, payload) {
            at += used;
            seq = seq.wrapping_add(1);
        }
    }
    flash
}

/// Restores `flash` into a fresh device and checks it (see [`restore`]);
/// the new scan's configuration comes from `r`.
fn restore_image(flash: SimFlash, r: &mut Reader<'_>) {
    let mut log = open_log(flash);
    let mut device = Box::new(FuzzDevice::new());
    let restored = device.restore(&mut log);
    let st = device.status();
    check_status(&st);
    let records = export_of(&mut device, &mut log);
    assert_eq!(records.len(), st.export_records() as usize, "{st:?}");
    if restored.is_err() {
        assert_eq!(st.phase, Phase::Unconfigured, "{restored:?}");
        assert!(records.is_empty());
    }
    let db = st.database_size as usize;
    for (i, rec) in records.iter().enumerate() {
        match rec.kind {
            RecordKind::Database { .. } => assert!(i < db, "{rec:?}"),
            RecordKind::Label { .. } => assert_eq!(rec.frame as usize, i - db, "{rec:?}"),
            // Sessions after the first, after every label.
            RecordKind::Session { session } => {
                let labels = st.capacity(CapacitySlot::Labels).used as usize;
                assert_eq!(i, db + labels + session as usize - 1, "{rec:?}");
            }
        }
    }
    // A second boot on the same flash restores the same scan: a tail that
    // was dropped is gone (no `TAIL_DROPPED` then), or is dropped again.
    let mut log = open_log(log.into_flash());
    let mut twice = Box::new(FuzzDevice::new());
    assert_eq!(twice.restore(&mut log), restored);
    let dropped = |s: Status| Status {
        degradation: s.degradation | degradation::TAIL_DROPPED,
        ..s
    };
    assert_eq!(dropped(twice.status()), dropped(st));
    // Debug text: a forged pose may hold NaN, which `==` never matches.
    let text = |r: &[ExportRecord]| format!("{r:?}");
    assert_eq!(text(&export_of(&mut twice, &mut log)), text(&records));

    // The device goes on: Reset, a new scan, and that is what comes back
    // (not an older generation that outranks it).
    let mut tx = vec![0u8; MAX_FRAME_LEN];
    let cfg = sane_config(r);
    let mut replies = Vec::new();
    for (seq, msg) in [(1, HostMessage::Reset), (2, HostMessage::Hello(cfg))] {
        let frame = encode(&HostFrame { seq, msg }, &mut tx).expect("encode");
        device.receive_logged(frame, &mut log, &mut |f: &[u8]| {
            replies.push(decode_reply(f))
        });
    }
    assert!(
        matches!(
            replies.as_slice(),
            [DeviceMessage::Ack { seq: 1 }, DeviceMessage::Ack { seq: 2 }]
        ),
        "{replies:?}"
    );
    let mut again = Box::new(FuzzDevice::new());
    let mut log = open_log(log.into_flash());
    assert_eq!(again.restore(&mut log), Ok(1), "the new scan's Begin alone");
    assert_eq!(again.status().phase, Phase::Ready);
    assert_eq!(again.selector().scan_config(), Some(&cfg.scan_config()));
    let mut sel = cfg.selector_config();
    sel.window = sel.window.min(FuzzDevice::WINDOW as u16);
    assert_eq!(again.selector().config(), Some(&sel));
    assert!(export_of(&mut again, &mut log).is_empty());
}
