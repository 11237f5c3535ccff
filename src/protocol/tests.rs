//! Unit tests of messages and framing.

extern crate std;

use super::*;
use crate::camera::{DepthRange, Intrinsics, Pose};
use proptest::prelude::*;
use std::format;
use std::vec;
use std::vec::Vec;

const N: usize = MAX_FRAME_LEN;

fn config() -> Config {
    Config {
        version: PROTOCOL_VERSION,
        voxel_size: 0.3,
        mu: 0.3,
        depth_scale: 5000.0,
        intrinsics: Intrinsics {
            width: 640,
            height: 480,
            fx: 525.0,
            fy: 525.0,
            cx: 319.5,
            cy: 239.5,
        },
        stride: 8,
        depth_range: DepthRange::default(),
        grid_origin: [0.0; 3],
        window: 32,
        sketch_margin: 0.05,
    }
}

fn pose() -> Pose {
    Pose {
        translation: [1.5, -2.25, 0.125],
        rotation: [
            0.0,
            0.0,
            core::f32::consts::FRAC_1_SQRT_2,
            core::f32::consts::FRAC_1_SQRT_2,
        ],
    }
}

/// 8 strided rows of 80 values, with zeros and 0xFF bytes to exercise COBS.
fn depth_bytes() -> Vec<u8> {
    (0..8 * 80u32)
        .flat_map(|i| ((i * 37 % 5000) as u16 * (i % 3) as u16).to_le_bytes())
        .collect()
}

fn host_messages(data: &[u8]) -> Vec<HostMessage<'_>> {
    vec![
        HostMessage::Hello(config()),
        HostMessage::FrameBegin {
            frame: 42,
            timestamp: 1_305_031_102.25,
            pose: pose(),
        },
        HostMessage::DepthRows(DepthRows {
            frame: 42,
            first_row: 8,
            row_count: 8,
            data,
        }),
        HostMessage::FrameEnd { frame: 42 },
        HostMessage::Finish,
        HostMessage::StatusRequest,
        HostMessage::ExportRequest {
            from_record: 3,
            max_records: 100,
        },
        HostMessage::Reset,
        HostMessage::FrameAbort { frame: 42 },
        HostMessage::Extend(config()),
        HostMessage::LogRead {
            record: 70_000,
            offset: 192,
        },
    ]
}

fn record(i: u32) -> ExportRecord {
    ExportRecord {
        record: i,
        frame: 10 * i,
        timestamp: 12.5 + f64::from(i),
        kind: if i.is_multiple_of(2) {
            RecordKind::Database { pose: pose() }
        } else {
            RecordKind::Label {
                class: 10 * (i - 1),
            }
        },
    }
}

/// A LogBytes reply of `len` bytes (`0x00` and `0xFF` among them).
fn log_bytes(len: u8, seq: u32) -> LogBytes {
    let mut data = [[0u8; 32]; LOG_CHUNK / 32];
    for (i, b) in data
        .as_flattened_mut()
        .iter_mut()
        .take(len.into())
        .enumerate()
    {
        *b = (i * 51) as u8;
    }
    LogBytes {
        seq,
        record: 3,
        at: 4096 + 20,
        total: 700,
        offset: 192,
        len,
        data,
    }
}

fn device_messages() -> Vec<DeviceMessage<'static>> {
    let mut status = Status {
        frames_seen: 120,
        database_size: 17,
        sessions: 2,
        session_first: 100,
        degradation: degradation::POOL_FULL | degradation::LABELS_FULL,
        last_reset: ResetCause::Panic(PanicPlace::new("src/main.rs", 412, 9)),
        ..Status::new(9, Phase::InFrame)
    };
    if let Some(c) = status.capacity_mut(CapacitySlot::Database) {
        *c = Capacity {
            used: 17,
            peak: 17,
            limit: 512,
        };
    }
    vec![
        DeviceMessage::Ack { seq: u32::MAX },
        DeviceMessage::Error {
            seq: Some(5),
            kind: ErrorKind::RowTooLong,
        },
        DeviceMessage::Error {
            seq: None,
            kind: ErrorKind::Oversized,
        },
        DeviceMessage::Decision {
            frame: 7,
            kind: DecisionKind::Taken,
        },
        DeviceMessage::Decision {
            frame: 8,
            kind: DecisionKind::DominatedBy(7),
        },
        DeviceMessage::Decision {
            frame: 9,
            kind: DecisionKind::Pending,
        },
        DeviceMessage::Decision {
            frame: 10,
            kind: DecisionKind::Uncovered(Some(7)),
        },
        DeviceMessage::Decision {
            frame: 11,
            kind: DecisionKind::Uncovered(None),
        },
        DeviceMessage::Status(status),
        DeviceMessage::ExportRecord(record(0)),
        DeviceMessage::ExportRecord(record(1)),
        DeviceMessage::ExportRecord(ExportRecord {
            record: 2,
            frame: 120,
            timestamp: 0.0,
            kind: RecordKind::Session { session: 1 },
        }),
        DeviceMessage::ExportEnd {
            seq: 3,
            from_record: 0,
            count: 2,
            crc32: export_crc(&[record(0), record(1)]),
        },
        DeviceMessage::Log("boot ok"),
        DeviceMessage::LogBytes(log_bytes(5, 0)),
        DeviceMessage::ExportUnreadable(ExportUnreadable {
            seq: u32::MAX,
            record: u32::MAX,
            frame: u32::MAX,
            log_at: Some(u32::MAX),
        }),
    ]
}

fn encode_vec<T: serde::Serialize>(msg: &T) -> Vec<u8> {
    let mut buf = vec![0u8; 4 * N];
    encode(msg, &mut buf).unwrap().to_vec()
}

fn plain_vec<T: serde::Serialize>(msg: &T) -> Result<Vec<u8>, postcard::Error> {
    let mut buf = vec![0u8; 4 * N];
    postcard::to_slice(msg, &mut buf).map(|b| b.to_vec())
}

fn host_frames(data: &[u8]) -> Vec<HostFrame<'_>> {
    host_messages(data)
        .into_iter()
        .enumerate()
        .map(|(i, msg)| HostFrame {
            seq: 1000 + i as u32,
            msg,
        })
        .collect()
}

/// Host frames decoded and re-encoded (a byte-exact owned form).
fn run_host(chunks: &[&[u8]]) -> Vec<Result<Vec<u8>, ProtocolError>> {
    let mut decoder = FrameDecoder::<N>::new();
    let mut out = Vec::new();
    for chunk in chunks {
        let mut rest: &[u8] = chunk;
        while let Feed::Frame { result, remaining } = decoder.feed::<HostFrame>(rest) {
            out.push(result.map(|f| encode_vec(&f)));
            rest = remaining;
        }
    }
    out
}

/// A frame of raw payload bytes (plus CRC unless `crc` is false), COBS-encoded
/// by postcard's flavour (as [`encode`] does) with its 0x00 delimiter.
fn raw_frame(payload: &[u8], crc: bool) -> Vec<u8> {
    use postcard::ser_flavors::{Cobs, Flavor, Slice};
    let mut data = payload.to_vec();
    if crc {
        data.extend_from_slice(&CRC.checksum(payload).to_le_bytes());
    }
    let mut buf = vec![0u8; data.len() + data.len() / 254 + 2];
    let mut cobs = Cobs::try_new(Slice::new(&mut buf)).unwrap();
    cobs.try_extend(&data).unwrap();
    cobs.finalize().unwrap().to_vec()
}

#[test]
fn host_messages_round_trip() {
    let data = depth_bytes();
    for frame in host_frames(&data) {
        let bytes = encode_vec(&frame);
        assert_eq!(bytes.last(), Some(&0));
        assert!(!bytes[..bytes.len() - 1].contains(&0));
        assert!(bytes.len() <= MAX_FRAME_LEN, "{frame:?}");
        let mut decoder = FrameDecoder::<N>::new();
        match decoder.feed::<HostFrame>(&bytes) {
            Feed::Frame { result, remaining } => {
                assert_eq!(result, Ok(frame));
                assert!(remaining.is_empty());
            }
            Feed::NeedMore => panic!("no frame"),
        }
    }
}

#[test]
fn depth_rows_borrow_the_decoder_buffer() {
    let data = depth_bytes();
    let frame = host_frames(&data)[2];
    let bytes = encode_vec(&frame);
    let mut decoder = FrameDecoder::<N>::new();
    let Feed::Frame { result, .. } = decoder.feed::<HostFrame>(&bytes) else {
        panic!("no frame")
    };
    let HostFrame {
        msg: HostMessage::DepthRows(rows),
        ..
    } = result.unwrap()
    else {
        panic!("not rows")
    };
    assert_eq!(rows.data, &data[..]);
    assert_eq!(rows.check(80, 60), Ok(()));
    let decoded: Vec<(u16, Vec<u16>)> = rows
        .rows(80)
        .map(|(r, row)| (r, DepthRows::values(row).collect()))
        .collect();
    assert_eq!(decoded.len(), 8);
    assert_eq!(decoded[0].0, 8);
    assert_eq!(decoded[7].0, 15);
    assert_eq!(decoded[1].1[3], u16::from_le_bytes([data[166], data[167]]));
}

#[test]
fn device_messages_round_trip() {
    for msg in device_messages() {
        let bytes = encode_vec(&msg);
        let mut decoder = FrameDecoder::<N>::new();
        // Byte by byte, to exercise accumulation.
        let mut frames = 0;
        for b in bytes.chunks(1) {
            if let Feed::Frame { result, remaining } = decoder.feed::<DeviceMessage>(b) {
                assert_eq!(result, Ok(msg));
                assert!(remaining.is_empty());
                frames += 1;
            }
        }
        assert_eq!(frames, 1);
    }
}

#[test]
fn frame_format_is_postcard_crc_cobs() {
    let frame = HostFrame {
        seq: 300,
        msg: HostMessage::ExportRequest {
            from_record: 5,
            max_records: 7,
        },
    };
    let mut plain = [0u8; 32];
    let message = postcard::to_slice(&frame, &mut plain).unwrap();
    assert_eq!(message, &[0xAC, 0x02, 6, 5, 7]);
    assert_eq!(encode_vec(&frame), raw_frame(message, true));
    // And the same holds for a message with zeros and long runs.
    let data = depth_bytes();
    for frame in host_frames(&data) {
        let message = plain_vec(&frame).unwrap();
        assert_eq!(encode_vec(&frame), raw_frame(&message, true));
    }
    for msg in device_messages() {
        let message = plain_vec(&msg).unwrap();
        assert_eq!(encode_vec(&msg), raw_frame(&message, true));
    }
    // Zero-free runs of every length around COBS's 254-byte block, ending
    // anywhere in the message and its CRC.
    for run in 240..270 {
        let data: Vec<u8> = (0..2 * MAX_ROW_VALUES)
            .map(|i| {
                if i % (run + 1) == run {
                    0
                } else {
                    1 + (i % 255) as u8
                }
            })
            .collect();
        for len in [run - 8, run, 2 * run + 1, data.len()] {
            let frame = HostFrame {
                seq: run as u32,
                msg: HostMessage::DepthRows(DepthRows {
                    frame: 7,
                    first_row: 0,
                    row_count: 1,
                    data: &data[..len & !1],
                }),
            };
            let message = plain_vec(&frame).unwrap();
            assert_eq!(encode_vec(&frame), raw_frame(&message, true), "run {run}");
        }
    }
}

#[test]
fn depth_rows_data_is_a_length_then_the_bytes() {
    // What serde's derive gives a `&[u8]` field: a sequence of `u8`, in
    // postcard a length and then each byte. The field is serialized as
    // bytes (one slice for the encoder), which must not change the wire.
    let data = depth_bytes();
    let rows = DepthRows {
        frame: 300,
        first_row: 8,
        row_count: 8,
        data: &data,
    };
    let as_sequence = (rows.frame, rows.first_row, rows.row_count, data.as_slice());
    assert_eq!(plain_vec(&rows).unwrap(), plain_vec(&as_sequence).unwrap());
}

/// The wire tag of every host message, by an exhaustive `match` with no
/// wildcard: a new variant does not compile until it is numbered here.
fn host_tag(msg: &HostMessage<'_>) -> u32 {
    match msg {
        HostMessage::Hello(_) => 0,
        HostMessage::FrameBegin { .. } => 1,
        HostMessage::DepthRows(_) => 2,
        HostMessage::FrameEnd { .. } => 3,
        HostMessage::Finish => 4,
        HostMessage::StatusRequest => 5,
        HostMessage::ExportRequest { .. } => 6,
        HostMessage::Reset => 7,
        HostMessage::FrameAbort { .. } => 8,
        HostMessage::Extend(_) => 9,
        HostMessage::LogRead { .. } => 10,
    }
}

/// The wire tag of every device message (see [`host_tag`]).
fn device_tag(msg: &DeviceMessage<'_>) -> u32 {
    match msg {
        DeviceMessage::Ack { .. } => 0,
        DeviceMessage::Error { .. } => 1,
        DeviceMessage::Decision { .. } => 2,
        DeviceMessage::Status(_) => 3,
        DeviceMessage::ExportRecord(_) => 4,
        DeviceMessage::ExportEnd { .. } => 5,
        DeviceMessage::Log(_) => 6,
        DeviceMessage::LogBytes(_) => 7,
        DeviceMessage::ExportUnreadable(_) => 8,
    }
}

/// Every variant is in the test lists (so every round-trip test covers it),
/// is encoded with the tag its `match` arm gives, and `VARIANTS` counts them.
#[test]
fn variant_counts_match_the_enums() {
    let data = depth_bytes();
    let mut host_tags = Vec::new();
    for frame in host_frames(&data) {
        let bytes = plain_vec(&frame).unwrap();
        let (_, rest) = postcard::take_from_bytes::<u32>(&bytes).unwrap();
        let (tag, _) = postcard::take_from_bytes::<u32>(rest).unwrap();
        assert_eq!(tag, host_tag(&frame.msg), "{frame:?}");
        host_tags.push(tag);
    }
    host_tags.sort_unstable();
    host_tags.dedup();
    let all: Vec<u32> = (0..<HostFrame as WireMessage>::VARIANTS).collect();
    assert_eq!(host_tags, all, "host_messages() misses a variant");

    let mut device_tags = Vec::new();
    for msg in device_messages() {
        let bytes = plain_vec(&msg).unwrap();
        let (tag, _) = postcard::take_from_bytes::<u32>(&bytes).unwrap();
        assert_eq!(tag, device_tag(&msg), "{msg:?}");
        device_tags.push(tag);
    }
    device_tags.sort_unstable();
    device_tags.dedup();
    let all: Vec<u32> = (0..<DeviceMessage as WireMessage>::VARIANTS).collect();
    assert_eq!(device_tags, all, "device_messages() misses a variant");
}

/// The wire numbers of the error kinds: those of the enum as first shipped
/// (a serde variant index each), with 19 (`Unsupported`, retired) no kind.
#[test]
fn error_kinds_keep_their_wire_numbers() {
    let pinned: [(ErrorKind, u8); 27] = [
        (ErrorKind::BadCrc, 0),
        (ErrorKind::BadFraming, 1),
        (ErrorKind::Oversized, 2),
        (ErrorKind::Truncated, 3),
        (ErrorKind::Decode, 4),
        (ErrorKind::UnknownMessage, 5),
        (ErrorKind::WrongVersion, 6),
        (ErrorKind::OutOfOrder, 7),
        (ErrorKind::NotConfigured, 8),
        (ErrorKind::BadConfig, 9),
        (ErrorKind::BadPose, 10),
        (ErrorKind::RowOutOfRange, 11),
        (ErrorKind::RowTooLong, 12),
        (ErrorKind::RowTooShort, 13),
        (ErrorKind::FrameEndWithoutBegin, 14),
        (ErrorKind::MidFrameReconfig, 15),
        (ErrorKind::ExportPastEnd, 16),
        (ErrorKind::CapacityExhausted, 17),
        (ErrorKind::Finished, 18),
        (ErrorKind::Internal, 20),
        (ErrorKind::NeedsReset, 21),
        (ErrorKind::MissingRows, 22),
        (ErrorKind::StorageFull, 23),
        (ErrorKind::StorageFailed, 24),
        (ErrorKind::NothingToExtend, 25),
        (ErrorKind::ExtendOtherConfig, 26),
        (ErrorKind::ExportUnreadable, 27),
    ];
    assert_eq!(ErrorKind::ALL, pinned.map(|(k, _)| k));
    for (kind, code) in pinned {
        // An Error reply: tag 1, `Some(7)`, then the kind's number.
        let msg = DeviceMessage::Error { seq: Some(7), kind };
        let bytes = [1, 1, 7, code];
        assert_eq!(plain_vec(&msg).unwrap(), bytes, "{kind:?}");
        let (back, _) = postcard::take_from_bytes::<DeviceMessage>(&bytes).unwrap();
        assert_eq!(back, msg);
    }
    // The retired number and the next unused one are no kind.
    for code in [19u8, 28] {
        let raw = raw_frame(&[1, 1, 7, code], true);
        let mut decoder = FrameDecoder::<N>::new();
        let Feed::Frame { result, .. } = decoder.feed::<DeviceMessage>(&raw) else {
            panic!("no frame")
        };
        assert_eq!(result.unwrap_err().kind, ErrorKind::Decode, "code {code}");
        assert_eq!(
            ErrorKind::try_from(u32::from(code)),
            Err(UnknownErrorKind(u32::from(code)))
        );
    }
}

#[test]
fn corrupting_any_byte_is_an_error_and_the_next_frame_decodes() {
    let data = depth_bytes();
    let frames = host_frames(&data);
    let good = encode_vec(&frames[5]);
    for victim in [&frames[1], &frames[2], &frames[6]] {
        let bytes = encode_vec(victim);
        for pos in 0..bytes.len() - 1 {
            for flip in [0x01u8, 0x80, 0xFF, 0x5A] {
                let mut bad = bytes.clone();
                bad[pos] ^= flip;
                let got = run_host(&[&bad, &good]);
                let (last, errors) = got.split_last().unwrap();
                assert_eq!(last, &Ok(good.clone()), "pos {pos} flip {flip:#x}");
                if bad[pos] == 0 {
                    // The frame became two (possibly one empty); each is an error.
                    assert!(!errors.is_empty() && errors.len() <= 2);
                } else {
                    assert_eq!(errors.len(), 1, "pos {pos} flip {flip:#x}");
                }
                assert!(errors.iter().all(|e| e.is_err()), "pos {pos} {errors:?}");
            }
        }
    }
}

#[test]
fn bad_crc_reports_the_claimed_sequence_number() {
    let frame = HostFrame {
        seq: 77,
        msg: HostMessage::FrameEnd { frame: 123_456 },
    };
    let mut bytes = encode_vec(&frame);
    let n = bytes.len();
    bytes[n - 3] ^= 0x10; // inside the CRC, not a COBS code byte here
    let got = run_host(&[&bytes]);
    assert_eq!(
        got,
        vec![Err(ProtocolError {
            kind: ErrorKind::BadCrc,
            seq: Some(77)
        })]
    );
}

#[test]
fn unknown_and_undecodable_messages_are_typed() {
    // seq 9, variant 11 (one past LogRead), valid CRC.
    let got = run_host(&[&raw_frame(&[9, 11], true)]);
    assert_eq!(
        got,
        vec![Err(ProtocolError {
            kind: ErrorKind::UnknownMessage,
            seq: Some(9)
        })]
    );
    // seq 9, FrameEnd without its frame index.
    let got = run_host(&[&raw_frame(&[9, 3], true)]);
    assert_eq!(got[0].as_ref().unwrap_err().kind, ErrorKind::Decode);
    // Trailing bytes after a complete message.
    let got = run_host(&[&raw_frame(&[9, 5, 0], true)]);
    assert_eq!(got[0].as_ref().unwrap_err().kind, ErrorKind::Decode);
    // Too short for a CRC.
    let got = run_host(&[&raw_frame(&[1, 2], false)]);
    assert_eq!(got[0].as_ref().unwrap_err().kind, ErrorKind::Truncated);
    // Invalid COBS: a code byte pointing past the end.
    let got = run_host(&[&[9, 1, 2, 0]]);
    assert_eq!(got[0].as_ref().unwrap_err().kind, ErrorKind::BadFraming);
    // Hello with a wrong version decodes; validation says why.
    let mut c = config();
    c.version += 1;
    assert_eq!(c.validate(), Err(ErrorKind::WrongVersion));
    assert_eq!(config().validate(), Ok(()));
    c = config();
    c.stride = 0;
    assert_eq!(c.validate(), Err(ErrorKind::BadConfig));
    c = config();
    c.stride = 1;
    c.intrinsics.width = 1280; // a full row no longer fits one frame
    assert_eq!(c.validate(), Err(ErrorKind::BadConfig));
    c = config();
    c.window = 0;
    assert_eq!(c.validate(), Err(ErrorKind::BadConfig));
    c = config();
    c.sketch_margin = f32::NAN;
    assert_eq!(c.validate(), Err(ErrorKind::BadConfig));
    c = config();
    c.grid_origin[1] = f32::INFINITY;
    assert_eq!(c.validate(), Err(ErrorKind::BadConfig));
    c = config();
    assert_eq!(Config::new(&c.scan_config(), &c.selector_config()), c);
}

#[test]
fn the_largest_replies_fit_the_reply_buffer() {
    let big = Capacity {
        used: u32::MAX,
        peak: u32::MAX,
        limit: u32::MAX,
    };
    let status = Status {
        frames_seen: u32::MAX,
        frames_decided: u32::MAX,
        database_size: u32::MAX,
        capacities: [big; CAPACITY_SLOTS],
        degradation: u32::MAX,
        sketched_frames: u32::MAX,
        unkeyed_frames: u32::MAX,
        sketch_compared_frames: u32::MAX,
        truncated_frames: u32::MAX,
        uncovered_frames: u32::MAX,
        labels_dropped: u32::MAX,
        out_of_range_points: u32::MAX,
        valid_pixels: u64::MAX,
        refused: u32::MAX,
        cost: FrameCost {
            clock_hz: u32::MAX,
            frames: u32::MAX,
            total: u64::MAX,
            last_rows: u32::MAX,
            last_end: u32::MAX,
            max: u32::MAX,
            core: u64::MAX,
        },
        stored_records: u32::MAX,
        sessions: u32::MAX,
        session_first: u32::MAX,
        last_reset: ResetCause::Panic(PanicPlace {
            line: u32::MAX,
            column: u32::MAX,
            ..PanicPlace::new(&"x".repeat(PANIC_FILE_LEN), 0, 0)
        }),
        ..Status::new(u32::MAX, Phase::Finished)
    };
    let record = ExportRecord {
        record: u32::MAX,
        frame: u32::MAX,
        timestamp: f64::MAX,
        kind: RecordKind::Database { pose: pose() },
    };
    let mut buf = [0u8; MAX_REPLY_LEN];
    for msg in [
        DeviceMessage::Status(status),
        DeviceMessage::ExportRecord(record),
        DeviceMessage::ExportEnd {
            seq: u32::MAX,
            from_record: u32::MAX,
            count: u32::MAX,
            crc32: u32::MAX,
        },
        DeviceMessage::Decision {
            frame: u32::MAX,
            kind: DecisionKind::Uncovered(Some(u32::MAX)),
        },
        DeviceMessage::Error {
            seq: Some(u32::MAX),
            kind: ErrorKind::MissingRows,
        },
        DeviceMessage::LogBytes(LogBytes {
            seq: u32::MAX,
            record: u32::MAX,
            at: u32::MAX,
            total: u32::MAX,
            offset: u32::MAX,
            ..log_bytes(LOG_CHUNK as u8, 0)
        }),
        DeviceMessage::LogBytes(LogBytes {
            data: [[0; 32]; LOG_CHUNK / 32],
            ..log_bytes(LOG_CHUNK as u8, u32::MAX)
        }),
    ] {
        assert!(encode(&msg, &mut buf).is_ok(), "{msg:?} does not fit");
    }
}

#[test]
fn empty_frames_are_skipped() {
    let good = encode_vec(&HostFrame {
        seq: 1,
        msg: HostMessage::Reset,
    });
    let got = run_host(&[&[0, 0, 0], &good, &[0], &good]);
    assert_eq!(got, vec![Ok(good.clone()), Ok(good)]);
}

#[test]
fn oversized_frames_are_refused_and_the_decoder_resynchronises() {
    let good = encode_vec(&HostFrame {
        seq: 2,
        msg: HostMessage::StatusRequest,
    });
    let long = vec![0x42u8; 3 * N];
    // In one chunk, in many chunks, and byte by byte.
    let mut stream = long.clone();
    stream.push(0);
    stream.extend_from_slice(&good);
    for chunk_len in [stream.len(), 100, 1] {
        let chunks: Vec<&[u8]> = stream.chunks(chunk_len).collect();
        let got = run_host(&chunks);
        assert_eq!(
            got,
            vec![
                Err(ProtocolError::new(ErrorKind::Oversized)),
                Ok(good.clone())
            ],
            "chunk {chunk_len}"
        );
    }
    // Exactly N bytes with the delimiter fit; N + 1 do not.
    let fits = raw_frame(&vec![0x11u8; N - 2 - (N - 2) / 255 - 4], true);
    assert!(fits.len() <= N);
    let mut decoder = FrameDecoder::<N>::new();
    assert!(matches!(decoder.push(&fits), Push::Ready { remaining: [] }));
    let mut exact = vec![0x01u8; N - 1];
    exact.push(0);
    assert!(matches!(
        FrameDecoder::<N>::new().push(&exact),
        Push::Ready { .. }
    ));
    let mut over = vec![0x01u8; N];
    over.push(0);
    assert!(matches!(
        FrameDecoder::<N>::new().push(&over),
        Push::Error { .. }
    ));
}

#[test]
fn truncated_frames_are_errors_and_the_next_frame_decodes() {
    let data = depth_bytes();
    let frames = host_frames(&data);
    let full = encode_vec(&frames[2]);
    let good = encode_vec(&frames[3]);
    for cut in 1..full.len() - 1 {
        // Cut, resynchronising delimiter, good frame.
        let got = run_host(&[&full[..cut], &[0], &good]);
        assert_eq!(got.len(), 2, "cut {cut}");
        assert!(got[0].is_err());
        assert_eq!(got[1], Ok(good.clone()));
        // Cut directly followed by two good frames: the first merges with the cut.
        let got = run_host(&[&full[..cut], &good, &good]);
        assert_eq!(got.len(), 2, "cut {cut}");
        assert!(got[0].is_err());
        assert_eq!(got[1], Ok(good.clone()));
    }
}

#[test]
fn splitting_the_stream_anywhere_gives_the_same_frames() {
    let data = depth_bytes();
    let mut stream = Vec::new();
    for frame in host_frames(&data) {
        stream.extend_from_slice(&encode_vec(&frame));
    }
    let whole = run_host(&[&stream]);
    assert_eq!(whole.len(), 11);
    assert!(whole.iter().all(|r| r.is_ok()));
    for cut in 0..=stream.len() {
        let (a, b) = stream.split_at(cut);
        assert_eq!(run_host(&[a, b]), whole, "cut {cut}");
    }
    let bytes: Vec<&[u8]> = stream.chunks(1).collect();
    assert_eq!(run_host(&bytes), whole);
}

#[test]
fn max_depth_rows_fit_the_receive_buffer() {
    assert_eq!(MAX_ROW_VALUES, 1007);
    assert_eq!(depth_rows_per_message(80), 12);
    assert_eq!(depth_rows_per_message(640), 1);
    assert_eq!(depth_rows_per_message(1007), 1);
    assert_eq!(depth_rows_per_message(1008), 0);
    assert_eq!(depth_rows_per_message(0), 0);
    assert_eq!(depth_rows_per_message(1), 1007);
    for width in [1u16, 7, 80, 160, 320, 640, 1007] {
        let rows = depth_rows_per_message(width);
        // Worst case: maximal varints and no zero byte anywhere (max COBS overhead).
        let data = vec![0xFFu8; usize::from(rows) * usize::from(width) * 2];
        let frame = HostFrame {
            seq: u32::MAX,
            msg: HostMessage::DepthRows(DepthRows {
                frame: u32::MAX,
                first_row: u16::MAX,
                row_count: rows.max(0x4000),
                data: &data,
            }),
        };
        let bytes = encode_vec(&frame);
        assert!(
            bytes.len() <= MAX_FRAME_LEN,
            "width {width}: {}",
            bytes.len()
        );
        let mut decoder = FrameDecoder::<MAX_FRAME_LEN>::new();
        assert!(matches!(
            decoder.feed::<HostFrame>(&bytes),
            Feed::Frame { result: Ok(_), .. }
        ));
    }
    // One more value does not fit.
    let data = vec![0xFFu8; (MAX_ROW_VALUES + 1) * 2];
    let frame = HostFrame {
        seq: u32::MAX,
        msg: HostMessage::DepthRows(DepthRows {
            frame: u32::MAX,
            first_row: u16::MAX,
            row_count: u16::MAX,
            data: &data,
        }),
    };
    assert!(encode_vec(&frame).len() > MAX_FRAME_LEN);
    assert!(max_frame_len(plain_vec(&frame).unwrap().len()) > MAX_FRAME_LEN);
}

/// The one bound on depth values per DepthRows: the device's row buffer
/// (`MAX_ROW_VALUES`). The largest message it accepts fits a frame whatever
/// its varints; the smallest it refuses may fit a frame too (small varints)
/// and is refused by the message check, with an error that is not damage.
#[test]
fn depth_rows_values_are_bounded_by_the_row_buffer() {
    let max = u16::try_from(MAX_ROW_VALUES).unwrap();
    // (width_sent, rows at the bound): the bound met exactly, and not.
    for (width, rows) in [(1u16, max), (19, 53), (80, 12), (1007, 1)] {
        assert_eq!(depth_rows_per_message(width), rows);
        let height = rows + 1;
        for (count, accepted) in [(rows, true), (rows + 1, false)] {
            let values = usize::from(count) * usize::from(width);
            assert_eq!(values <= MAX_ROW_VALUES, accepted, "width {width}");
            let data = vec![0x5Au8; values * 2];
            let msg = DepthRows {
                frame: 0,
                first_row: 0,
                row_count: count,
                data: &data,
            };
            let ctx = format!("width {width}, {count} rows");
            if accepted {
                assert_eq!(msg.check(width, height), Ok(()), "{ctx}");
                // Fits a frame with the largest varints and no zero byte.
                let worst = HostFrame {
                    seq: u32::MAX,
                    msg: HostMessage::DepthRows(DepthRows {
                        frame: u32::MAX,
                        data: &vec![0xFFu8; values * 2],
                        ..msg
                    }),
                };
                assert!(encode_vec(&worst).len() <= MAX_FRAME_LEN, "{ctx}");
            } else {
                let refused = msg.check(width, height);
                assert_eq!(refused, Err(ErrorKind::CapacityExhausted), "{ctx}");
                assert!(!ErrorKind::CapacityExhausted.is_damage());
                // Before the length checks: a wrong length is refused the same.
                let short = DepthRows {
                    data: &data[2..],
                    ..msg
                };
                assert_eq!(short.check(width, height), refused, "{ctx}");
            }
        }
    }
    // The smallest refused message, with small varints, fits a frame and
    // decodes: the frame layer lets it through, the message check does not.
    let data = vec![0x5Au8; (MAX_ROW_VALUES + 1) * 2];
    let frame = HostFrame {
        seq: 1,
        msg: HostMessage::DepthRows(DepthRows {
            frame: 0,
            first_row: 0,
            row_count: max + 1,
            data: &data,
        }),
    };
    let bytes = encode_vec(&frame);
    assert!(bytes.len() <= MAX_FRAME_LEN);
    let mut decoder = FrameDecoder::<MAX_FRAME_LEN>::new();
    match decoder.feed::<HostFrame>(&bytes) {
        Feed::Frame {
            result:
                Ok(HostFrame {
                    msg: HostMessage::DepthRows(rows),
                    ..
                }),
            ..
        } => assert_eq!(rows.check(1, max + 1), Err(ErrorKind::CapacityExhausted)),
        other => panic!("{other:?}"),
    }
}

#[test]
fn encode_into_small_buffers_fails_cleanly() {
    let data = depth_bytes();
    for frame in host_frames(&data) {
        let needed = encode_vec(&frame).len();
        let message_len = plain_vec(&frame).unwrap().len();
        assert!(needed <= max_frame_len(message_len));
        for size in 0..needed {
            let mut buf = vec![0u8; size];
            assert_eq!(
                encode(&frame, &mut buf).unwrap_err().kind,
                ErrorKind::Oversized,
                "size {size}"
            );
        }
        let mut buf = vec![0u8; needed];
        assert_eq!(encode(&frame, &mut buf).unwrap().len(), needed);
    }
}

#[test]
fn depth_rows_checks_and_packing() {
    // A 10 x 7 image with value 100 * v + u, stride 3: 4 x 3 strided.
    let (w, h, s) = (10u16, 7u16, 3u16);
    let image: Vec<u16> = (0..h)
        .flat_map(|v| (0..w).map(move |u| 100 * v + u))
        .collect();
    let (ws, hs) = (strided_len(w, s), strided_len(h, s));
    assert_eq!((ws, hs), (4, 3));
    let mut buf = [0u8; 64];
    let bytes = pack_rows(&image, w, s, 1, 2, &mut buf).unwrap().to_vec();
    let rows = DepthRows {
        frame: 0,
        first_row: 1,
        row_count: 2,
        data: &bytes,
    };
    assert_eq!(rows.check(ws, hs), Ok(()));
    let got: Vec<(u16, Vec<u16>)> = rows
        .rows(ws)
        .map(|(r, row)| (r, DepthRows::values(row).collect()))
        .collect();
    assert_eq!(
        got,
        vec![(1, vec![300, 303, 306, 309]), (2, vec![600, 603, 606, 609])]
    );
    assert_eq!(
        pack_rows(&image, w, s, 2, 2, &mut buf),
        Err(ErrorKind::RowOutOfRange)
    );
    assert_eq!(
        pack_rows(&image, w, s, 0, 3, &mut buf[..23]),
        Err(ErrorKind::Oversized)
    );
    assert_eq!(
        pack_rows(&image, w, 0, 0, 1, &mut buf),
        Err(ErrorKind::BadConfig)
    );
    let short = DepthRows {
        data: &bytes[..bytes.len() - 2],
        ..rows
    };
    assert_eq!(short.check(ws, hs), Err(ErrorKind::RowTooShort));
    let mut long_bytes = bytes.clone();
    long_bytes.push(1);
    let long = DepthRows {
        data: &long_bytes,
        ..rows
    };
    assert_eq!(long.check(ws, hs), Err(ErrorKind::RowTooLong));
    let beyond = DepthRows {
        first_row: 2,
        ..rows
    };
    assert_eq!(beyond.check(ws, hs), Err(ErrorKind::RowOutOfRange));
    assert_eq!(rows.rows(0).count(), 0);
}

#[test]
fn export_crc_is_order_sensitive_and_matches_the_encodings() {
    let records: Vec<ExportRecord> = (0..5).map(record).collect();
    let mut concatenated = Vec::new();
    for r in &records {
        concatenated.extend_from_slice(&plain_vec(r).unwrap());
    }
    assert_eq!(export_crc(&records), CRC.checksum(&concatenated));
    let mut running = ExportCrc::new();
    for r in &records {
        running.add(r);
    }
    assert_eq!(running.count(), 5);
    assert_eq!(running.value(), export_crc(&records));
    let mut swapped = records.clone();
    swapped.swap(1, 2);
    assert_ne!(export_crc(&swapped), export_crc(&records));
    assert_eq!(export_crc(&[]), CRC.checksum(&[]));
}

#[test]
fn status_capacity_slots() {
    let mut status = Status::new(0, Phase::Ready);
    for (i, slot) in CapacitySlot::ALL.iter().enumerate() {
        assert_eq!(*slot as usize, i);
        status.capacity_mut(*slot).unwrap().limit = i as u32 + 1;
    }
    assert_eq!(status.capacity(CapacitySlot::Window).limit, 4);
    assert_eq!(CapacitySlot::FrameVoxels.name(), "frame_voxels");
    let e = ProtocolError {
        kind: ErrorKind::BadCrc,
        seq: Some(4),
    };
    assert_eq!(
        e.reply(),
        DeviceMessage::Error {
            seq: Some(4),
            kind: ErrorKind::BadCrc
        }
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..5000),
                                   chunk in 1usize..300) {
        let mut decoder = FrameDecoder::<256>::new();
        for part in bytes.chunks(chunk) {
            let mut rest = part;
            while let Feed::Frame { remaining, .. } = decoder.feed::<HostFrame>(rest) {
                rest = remaining;
            }
            let mut rest = part;
            while let Feed::Frame { remaining, .. } = decoder.feed::<DeviceMessage>(rest) {
                rest = remaining;
            }
        }
    }

    #[test]
    fn garbage_then_resync_then_good_frame(garbage in proptest::collection::vec(any::<u8>(), 0..3000)) {
        let good = encode_vec(&HostFrame { seq: 5, msg: HostMessage::StatusRequest });
        let got = run_host(&[&garbage, &[0], &good]);
        prop_assert_eq!(got.last(), Some(&Ok(good.clone())));
    }

    #[test]
    fn random_depth_rows_round_trip(data in proptest::collection::vec(any::<u8>(), 0..=MAX_ROW_VALUES),
                                    seq in any::<u32>(), frame in any::<u32>()) {
        let data: Vec<u8> = data.iter().flat_map(|b| [*b, b.wrapping_mul(7)]).collect();
        let msg = HostFrame { seq, msg: HostMessage::DepthRows(DepthRows { frame, first_row: 3, row_count: 1, data: &data }) };
        let bytes = encode_vec(&msg);
        prop_assert!(bytes.len() <= MAX_FRAME_LEN);
        let mut decoder = FrameDecoder::<N>::new();
        match decoder.feed::<HostFrame>(&bytes) {
            Feed::Frame { result, remaining } => {
                prop_assert_eq!(result, Ok(msg));
                prop_assert!(remaining.is_empty());
            }
            Feed::NeedMore => prop_assert!(false),
        }
    }
}

/// Depth rows decode the same whatever the alignment of the bytes received
/// and however they are chunked: the decoder starts each frame at the
/// input's alignment (word copies on the M0+), and a frame too long for
/// that start moves to the buffer's start, so a frame of exactly the
/// buffer's capacity still fits at every alignment.
#[test]
fn frames_decode_at_every_input_alignment_and_chunking() {
    let data: Vec<u8> = (0..2 * N as u32).map(|i| (i * 7 % 251) as u8 + 1).collect();
    let frame_of = |k: usize| HostFrame {
        seq: 3,
        msg: HostMessage::DepthRows(DepthRows {
            frame: 9,
            first_row: 1,
            row_count: 2,
            data: &data[..k],
        }),
    };
    // The longest frame the decoder holds: N bytes with its delimiter.
    let longest = (0..data.len())
        .rev()
        .find(|&k| encode_vec(&frame_of(k)).len() == N)
        .expect("some data length encodes to exactly N bytes");
    for k in [0, 1, 61, 300, longest] {
        let expected = frame_of(k);
        let bytes = encode_vec(&expected);
        for offset in 0..4 {
            // Two frames back to back, the second starting at another
            // alignment than the first.
            let mut stream = vec![0xAA; offset];
            stream.extend_from_slice(&bytes);
            stream.extend_from_slice(&bytes);
            let input = &stream[offset..];
            for chunk_len in [input.len(), 64, 63, 5, 1] {
                let mut decoder = FrameDecoder::<N>::new();
                let mut got = 0;
                for chunk in input.chunks(chunk_len) {
                    let mut rest = chunk;
                    while let Feed::Frame { result, remaining } = decoder.feed::<HostFrame>(rest) {
                        assert_eq!(
                            result,
                            Ok(expected),
                            "k {k} offset {offset} chunk {chunk_len}"
                        );
                        got += 1;
                        rest = remaining;
                    }
                }
                assert_eq!(got, 2, "k {k} offset {offset} chunk {chunk_len}");
            }
        }
    }
}

/// Input received in place (`spare`, `commit`, `push_held`: how the Pico
/// reads its USB packets straight into the decoder) decodes as pushed input
/// does, at every packet size: frames that end mid-packet (the rest stays
/// held for the next frame), the longest frame, one too long (its error,
/// then the next frame), a lone delimiter. A packet that finds less room
/// than it needs (the end of a long frame) is pushed instead, and that
/// happens only there. With 64-byte packets the room always starts
/// word-aligned, so the copies into it move words.
#[test]
fn input_received_in_place_decodes_as_pushed_input() {
    let data: Vec<u8> = (0..2 * N as u32).map(|i| (i * 7 % 251) as u8 + 1).collect();
    let frame_of = |k: usize| {
        encode_vec(&HostFrame {
            seq: k as u32,
            msg: HostMessage::DepthRows(DepthRows {
                frame: 9,
                first_row: 1,
                row_count: 2,
                data: &data[..k],
            }),
        })
    };
    let longest = (0..data.len())
        .rev()
        .find(|&k| frame_of(k).len() == N)
        .expect("some data length encodes to exactly N bytes");
    let mut stream = Vec::new();
    for k in [0, 61, longest, 300] {
        stream.extend_from_slice(&frame_of(k));
    }
    stream.extend_from_slice(&[0x01; N + 10]);
    stream.push(0);
    stream.push(0);
    for k in [1, 1000, longest, 2] {
        stream.extend_from_slice(&frame_of(k));
    }
    let expected = run_host(&[&stream]);
    assert_eq!(expected.len(), 9);
    assert_eq!(expected[4], Err(ProtocolError::new(ErrorKind::Oversized)));
    assert_eq!(expected.iter().filter(|r| r.is_ok()).count(), 8);

    for packet in [64, 63, 200, 5, 1] {
        let mut decoder = FrameDecoder::<N>::new();
        let mut got = Vec::new();
        let mut pushed = 0;
        for chunk in stream.chunks(packet) {
            let room = decoder.spare(packet);
            if packet == 64 && room.len() >= packet {
                assert_eq!(room.as_ptr() as usize % 4, 0, "room not word-aligned");
            }
            if room.len() < chunk.len() {
                pushed += 1;
                let mut rest: &[u8] = chunk;
                while let Feed::Frame { result, remaining } = decoder.feed::<HostFrame>(rest) {
                    got.push(result.map(|f| encode_vec(&f)));
                    rest = remaining;
                }
                continue;
            }
            room[..chunk.len()].copy_from_slice(chunk);
            decoder.commit(chunk.len());
            while decoder.holds_input() {
                match decoder.push_held() {
                    Held::NeedMore => assert!(!decoder.holds_input()),
                    Held::Ready => got.push(decoder.decode::<HostFrame>().map(|f| encode_vec(&f))),
                    Held::Error(error) => got.push(Err(error)),
                }
            }
        }
        assert_eq!(got, expected, "packets of {packet}");
        // Only the ends of the two longest frames and of the one too long.
        assert!(pushed <= 6, "{pushed} pushed, packets of {packet}");
        assert!(!decoder.is_mid_frame());
    }
}

/// The device takes a packet in place when the decoder has room for it and
/// pushes (copies) it otherwise, so the two paths alternate on one stream.
/// Whatever the path of each packet, the frames are the ones a pushed-only
/// stream gives: in particular a lone delimiter (the host's resynchronisation
/// byte) taken by the copying path must not shift the next in-place frame.
#[test]
fn copying_and_in_place_receive_mix_on_one_stream() {
    let data: Vec<u8> = (0..300u32).map(|i| (i * 11 % 251) as u8 + 1).collect();
    let frame_of = |seq: u32, k: usize| {
        encode_vec(&HostFrame {
            seq,
            msg: HostMessage::DepthRows(DepthRows {
                frame: 3,
                first_row: 0,
                row_count: 1,
                data: &data[..k],
            }),
        })
    };
    // Packets: a lone delimiter, frames, a delimiter then a frame, two frames.
    let mut packets: Vec<Vec<u8>> = vec![vec![0], frame_of(1, 10), vec![0]];
    packets.push([&[0u8][..], &frame_of(2, 40)].concat());
    packets.push(frame_of(3, 0));
    packets.push([frame_of(4, 7), frame_of(5, 200)].concat());
    packets.push(vec![0, 0]);
    packets.push(frame_of(6, 1));
    let stream = packets.concat();
    let expected = run_host(&[&stream]);
    assert_eq!(expected.len(), 6);
    assert!(expected.iter().all(|r| r.is_ok()));
    // Every assignment of the two paths to the packets.
    for paths in 0u32..1 << packets.len() {
        let mut decoder = FrameDecoder::<N>::new();
        let mut got = Vec::new();
        for (i, packet) in packets.iter().enumerate() {
            if paths & 1 << i != 0 {
                let mut rest: &[u8] = packet;
                while let Feed::Frame { result, remaining } = decoder.feed::<HostFrame>(rest) {
                    got.push(result.map(|f| encode_vec(&f)));
                    rest = remaining;
                }
                continue;
            }
            let room = decoder.spare(packet.len());
            assert!(room.len() >= packet.len());
            room[..packet.len()].copy_from_slice(packet);
            decoder.commit(packet.len());
            while decoder.holds_input() {
                match decoder.push_held() {
                    Held::NeedMore => {}
                    Held::Ready => got.push(decoder.decode::<HostFrame>().map(|f| encode_vec(&f))),
                    Held::Error(error) => got.push(Err(error)),
                }
            }
        }
        assert_eq!(got, expected, "paths {paths:#b}");
        assert!(!decoder.is_mid_frame());
    }
}

/// A panic's place keeps the end of its source path, cut after a `/` when
/// it is longer than the status has room for, and names itself as a
/// compiler does.
#[test]
fn a_panic_place_keeps_the_end_of_its_path() {
    let short = PanicPlace::new("src/main.rs", 412, 9);
    assert_eq!(short.file(), "src/main.rs");
    assert_eq!(format!("{short}"), "src/main.rs:412:9");
    let long = PanicPlace::new("/home/someone/work/placedb/src/select/window.rs", 7, 1);
    assert_eq!(long.file(), "placedb/src/select/window.rs");
    let name = "a_file_name_longer_than_the_room_is.rs";
    let one = PanicPlace::new(name, 1, 1);
    assert_eq!(one.file(), &name[name.len() - PANIC_FILE_LEN..]);
    // A cut never splits a character.
    let wide = PanicPlace::new(&"é".repeat(PANIC_FILE_LEN), 1, 1);
    assert!(wide.file().chars().all(|c| c == 'é') && !wide.file().is_empty());
    assert_eq!(PanicPlace::new("", 0, 0).file(), "");
}
