extern crate std;

use super::harness::{decode_reply, on_big_stack, AnyDevice, Harness};
use super::*;
use crate::camera::{DepthRange, Intrinsics, Pose};
use crate::frame::FrameMeta;
use crate::persist::record::DECISION_BATCH;
use crate::persist::sim::SimFlash;
use crate::persist::Record;
use crate::protocol::{encode, DepthRows, PROTOCOL_VERSION};
use crate::protocol::{
    DecisionKind, DeviceMessage, ErrorKind, ExportRecord, HostMessage, RecordKind,
};
use crate::select::SelectorConfig;
use crate::{ScanConfig, VoxelGrid};
use proptest::prelude::*;
use std::format;
use std::vec;
use std::vec::Vec;

type Small = Device<1024, 8192, 16, 8, 16, 64>;
/// Runs out of database quickly.
type Tiny = Device<1024, 2048, 2, 4, 16, 5>;

const W: u16 = 64;
const H: u16 = 48;
const STRIDE: u16 = 2;

fn config(window: u16) -> Config {
    let scan = ScanConfig {
        intrinsics: Intrinsics {
            width: W,
            height: H,
            fx: 50.0,
            fy: 50.0,
            cx: 31.5,
            cy: 23.5,
        },
        depth_scale: 1000.0,
        range: DepthRange::default(),
        stride: STRIDE,
        grid: VoxelGrid {
            voxel_size: 0.1,
            origin: [0.0; 3],
        },
    };
    Config::new(
        &scan,
        &SelectorConfig {
            mu: 0.3,
            window,
            sketch_margin: 0.05,
        },
    )
}

/// Sampled rows of frame `i`: a wavy wall about 3 m ahead of a camera
/// moving sideways, every 7th frame blank.
fn frame_rows(i: u32) -> Vec<u16> {
    let (ws, hs) = (W.div_ceil(STRIDE), H.div_ceil(STRIDE));
    let mut out = Vec::new();
    for v in 0..hs {
        for u in 0..ws {
            let x = 0.15 * i as f32 + (f32::from(u * STRIDE) - 31.5) / 50.0 * 3.0;
            let d = if i % 7 == 6 {
                0
            } else {
                (3000.0 + 400.0 * libm::sinf(2.0 * x) + 5.0 * f32::from(v)) as u16
            };
            out.push(d);
        }
    }
    out
}

fn pose(i: u32) -> Pose {
    Pose {
        translation: [0.15 * i as f32, 0.0, 0.0],
        rotation: [0.0, 0.0, 0.0, 1.0],
    }
}

fn timestamp(i: u32) -> f64 {
    1_305_031_102.175_304 + f64::from(i) / 30.0
}

/// Sectors of the benches' flash log.
const BENCH_SECTORS: usize = 64;

/// A device with a log on a blank flash.
fn bench<D: AnyDevice>() -> Harness<D> {
    Harness::new(BENCH_SECTORS)
}

/// Streams frame `i` with `rows_per_msg` rows per message; returns the
/// decisions.
fn frame<D: AnyDevice>(b: &mut Harness<D>, i: u32, rows_per_msg: u16) -> Vec<(u32, DecisionKind)> {
    frame_rx(b, i, rows_per_msg, 0)
}

/// [`frame`], with `rx` ticks of board receive work handed to the device
/// before each of the frame's messages.
fn frame_rx<D: AnyDevice>(
    b: &mut Harness<D>,
    i: u32,
    rows_per_msg: u16,
    rx: u64,
) -> Vec<(u32, DecisionKind)> {
    b.device.add_receive_ticks(rx);
    b.ok(HostMessage::FrameBegin {
        frame: i,
        timestamp: timestamp(i),
        pose: pose(i),
    });
    let rows = frame_rows(i);
    let ws = usize::from(W.div_ceil(STRIDE));
    let mut first = 0u16;
    for chunk in rows.chunks(ws * usize::from(rows_per_msg)) {
        let data: Vec<u8> = chunk.iter().flat_map(|d| d.to_le_bytes()).collect();
        let n = (chunk.len() / ws) as u16;
        b.device.add_receive_ticks(rx);
        b.ok(HostMessage::DepthRows(DepthRows {
            frame: i,
            first_row: first,
            row_count: n,
            data: &data,
        }));
        first += n;
    }
    b.device.add_receive_ticks(rx);
    decisions(&b.ok(HostMessage::FrameEnd { frame: i }))
}

/// Final decisions, in the order they came (frame order).
fn finals(decided: &[(u32, DecisionKind)]) -> Vec<(u32, DecisionKind)> {
    let f: Vec<_> = decided
        .iter()
        .copied()
        .filter(|(_, k)| *k != DecisionKind::Pending)
        .collect();
    assert!(
        f.windows(2).all(|w| w[0].0 + 1 == w[1].0),
        "frame order: {f:?}"
    );
    f
}

/// The frames reported `Pending`, in order.
fn pending(decided: &[(u32, DecisionKind)]) -> Vec<u32> {
    decided
        .iter()
        .filter(|(_, k)| *k == DecisionKind::Pending)
        .map(|(i, _)| *i)
        .collect()
}

fn decisions(replies: &[DeviceMessage<'_>]) -> Vec<(u32, DecisionKind)> {
    replies
        .iter()
        .filter_map(|m| match m {
            DeviceMessage::Decision { frame, kind } => Some((*frame, *kind)),
            _ => None,
        })
        .collect()
}

/// What the selector alone decides on the same frames.
fn reference<const FV: usize, const P: usize, const DB: usize, const WN: usize, const K: usize>(
    cfg: &Config,
    frames: u32,
) -> (Vec<(u32, DecisionKind)>, Vec<ExportRecord>) {
    let mut sel = std::boxed::Box::new(Selector::<FV, P, DB, WN, K>::new());
    sel.configure(cfg.scan_config(), cfg.selector_config())
        .unwrap();
    // The database in a log, exact keys included, as the device keeps it.
    let flash = SimFlash::new(BENCH_SECTORS);
    let mut log = Log::open(flash, 0, (BENCH_SECTORS * SimFlash::SECTOR) as u32).unwrap();
    log.start(&[0]).unwrap();
    let (mut record, mut failed, mut stored) = ([0u8; durable::MAX_RECORD_LEN], false, 0);
    let mut store = durable::LogStore {
        journal: &mut log,
        record: &mut record,
        failed: &mut failed,
        stored: &mut stored,
    };
    let mut got = Vec::new();
    let mut emit = |d: FrameDecision| got.push((d.index, DecisionKind::from(d.decision)));
    for i in 0..frames {
        sel.begin_frame(FrameMeta {
            index: i,
            timestamp: timestamp(i),
            pose: pose(i),
        })
        .unwrap();
        sel.push_rows(0, &frame_rows(i)).unwrap();
        sel.end_frame_with(&mut store, &mut emit).unwrap();
    }
    sel.finish_with(&mut store, &mut emit).unwrap();
    let mut db: Vec<_> = (0..sel.database_len())
        .map(|i| sel.database_record(i, &mut store).unwrap())
        .collect();
    db.sort_by_key(|r| r.index);
    let mut records: Vec<ExportRecord> = db
        .iter()
        .map(|r| ExportRecord {
            record: 0,
            frame: r.index,
            timestamp: r.timestamp,
            kind: RecordKind::Database { pose: r.pose },
        })
        .collect();
    let finals: Vec<_> = got
        .iter()
        .filter(|(_, k)| *k != DecisionKind::Pending)
        .collect();
    for (i, k) in finals {
        records.push(ExportRecord {
            record: 0,
            frame: *i,
            timestamp: timestamp(*i),
            kind: RecordKind::Label {
                class: k.class(*i).unwrap(),
            },
        });
    }
    for (r, rec) in records.iter_mut().enumerate() {
        rec.record = r as u32;
    }
    (got, records)
}

#[test]
fn a_scan_matches_the_selector_and_exports_in_frame_order() {
    on_big_stack(|| {
        let mut b = bench::<Small>();
        assert_eq!(b.status().phase, Phase::Unconfigured);
        let cfg = config(4);
        b.ok(HostMessage::Hello(cfg));
        let n = 30;
        let mut got = Vec::new();
        for i in 0..n {
            got.extend(frame(&mut b, i, 5));
        }
        assert_eq!(b.status().phase, Phase::Ready);
        got.extend(decisions(&b.ok(HostMessage::Finish)));
        let (want, records) = reference::<1024, 8192, 16, 8, 16>(&cfg, n);
        assert_eq!(finals(&got), finals(&want));
        assert_eq!(pending(&got), pending(&want));
        let st = b.status();
        assert_eq!(st.phase, Phase::Finished);
        assert_eq!((st.frames_seen, st.frames_decided), (n, n));
        assert_eq!(st.capacity(CapacitySlot::Labels).used, n);
        assert_eq!(st.export_records() as usize, records.len());
        assert!(st.database_size > 1 && st.database_size < n);
        assert_eq!(st.degradation, 0);
        let all = b.export();
        assert_eq!(all, records);
        // Resume from any record: the tail of the full export.
        for k in [
            1,
            st.database_size,
            st.export_records() - 1,
            st.export_records(),
        ] {
            assert_eq!(b.export_from(k, u32::MAX), records[k as usize..]);
        }
        // In batches of any size.
        for batch in [1, 2, 7, st.database_size, 1000] {
            let mut got = Vec::new();
            loop {
                let part = b.export_from(got.len() as u32, batch);
                assert!(part.len() <= batch as usize);
                if part.is_empty() {
                    break;
                }
                got.extend(part);
            }
            assert_eq!(got, records);
        }
        assert_eq!(b.export_from(3, 0), vec![]);
        assert_eq!(
            b.refused(HostMessage::ExportRequest {
                from_record: st.export_records() + 1,
                max_records: 1,
            }),
            ErrorKind::ExportPastEnd
        );
        // A repeated Finish is a no-op; frames after Finish are refused.
        assert_eq!(decisions(&b.ok(HostMessage::Finish)), vec![]);
        let begin = HostMessage::FrameBegin {
            frame: n,
            timestamp: 0.0,
            pose: pose(0),
        };
        assert_eq!(b.refused(begin), ErrorKind::Finished);
        assert_eq!(b.export(), records);
        // Reset forgets everything.
        b.ok(HostMessage::Reset);
        let st = b.status();
        assert_eq!(st.phase, Phase::Unconfigured);
        assert_eq!(st.export_records(), 0);
        assert_eq!(b.refused(begin), ErrorKind::NotConfigured);
    });
}

/// The bytes a host sends for a scan of 8 frames (full-image DepthRows),
/// its Finish and an export.
fn scan_stream() -> Vec<u8> {
    let mut stream = Vec::new();
    let mut buf = vec![0u8; MAX_FRAME_LEN];
    let mut push = |seq: u32, msg: HostMessage<'_>| {
        stream.extend_from_slice(encode(&HostFrame { seq, msg }, &mut buf).unwrap());
    };
    push(1, HostMessage::Hello(config(3)));
    let mut seq = 2;
    for i in 0..8 {
        push(
            seq,
            HostMessage::FrameBegin {
                frame: i,
                timestamp: timestamp(i),
                pose: pose(i),
            },
        );
        let data: Vec<u8> = frame_rows(i).iter().flat_map(|d| d.to_le_bytes()).collect();
        push(
            seq + 1,
            HostMessage::DepthRows(DepthRows {
                frame: i,
                first_row: 0,
                row_count: H.div_ceil(STRIDE),
                data: &data,
            }),
        );
        push(seq + 2, HostMessage::FrameEnd { frame: i });
        seq += 3;
    }
    push(seq, HostMessage::Finish);
    push(
        seq + 1,
        HostMessage::ExportRequest {
            from_record: 0,
            max_records: u32::MAX,
        },
    );
    stream
}

#[test]
fn byte_by_byte_delivery_gives_the_same_replies() {
    on_big_stack(|| {
        let stream = scan_stream();
        let whole = bench::<Small>().feed(&stream, stream.len());
        assert_eq!(bench::<Small>().feed(&stream, 1), whole);
        assert_eq!(bench::<Small>().feed(&stream, 61), whole);
        assert!(matches!(
            whole.last(),
            Some(DeviceMessage::ExportEnd { .. })
        ));
    });
}

/// Input read straight into the receive buffer (`receive_room`, as the
/// Pico reads its USB packets) gives the replies `receive` gives, frame
/// for frame, whatever the packet size; a packet that finds too little
/// room (the end of a long frame) goes through `receive_message`.
#[test]
fn input_received_in_place_gives_the_same_replies() {
    on_big_stack(|| {
        let stream = scan_stream();
        let mut whole = Vec::new();
        Small::new_boxed().receive(&stream, &mut |f| whole.push(f.to_vec()));
        assert!(whole.len() > 30);
        for packet in [64, 63, 7, 1] {
            let mut device = Small::new_boxed();
            let mut replies = Vec::new();
            let mut copied = 0;
            for chunk in stream.chunks(packet) {
                let room = device.receive_room(64);
                if room.len() >= chunk.len() {
                    room[..chunk.len()].copy_from_slice(chunk);
                    device.commit_received(chunk.len());
                    while device.holds_input() {
                        device.receive_held(&mut NoJournal, &mut |f| replies.push(f.to_vec()));
                    }
                } else {
                    copied += 1;
                    let mut rest = chunk;
                    while !rest.is_empty() {
                        rest = device
                            .receive_message(rest, &mut NoJournal, &mut |f| {
                                replies.push(f.to_vec())
                            })
                            .0;
                    }
                }
            }
            assert_eq!(replies, whole, "packets of {packet}");
            assert!(copied < stream.len() / packet / 20, "{copied} copied");
        }
    });
}

/// The host's resynchronisation byte (a lone 0x00) taken by the copying
/// path, which the Pico uses whenever its in-place room is short, must not
/// shift the next frame received in place (it once was read one byte off:
/// `BadFraming` with no sequence number, so the host could only time out).
/// The lone byte is given at each of the four alignments.
#[test]
fn a_lone_delimiter_copied_then_a_frame_in_place_is_answered() {
    on_big_stack(|| {
        let mut buf = vec![0u8; crate::protocol::MAX_FRAME_LEN];
        let request = HostFrame {
            seq: 7,
            msg: HostMessage::StatusRequest,
        };
        let frame = encode(&request, &mut buf).unwrap().to_vec();
        let words = [0u32; 2];
        let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        for offset in 0..4 {
            let mut device = Small::new_boxed();
            let mut replies = Vec::new();
            let lone = &bytes[offset..offset + 1];
            device.receive_logged(lone, &mut NoJournal, &mut |f| replies.push(f.to_vec()));
            assert!(replies.is_empty(), "a lone delimiter is not a message");
            let room = device.receive_room(64);
            room[..frame.len()].copy_from_slice(&frame);
            device.commit_received(frame.len());
            while device.holds_input() {
                device.receive_held(&mut NoJournal, &mut |f| replies.push(f.to_vec()));
            }
            let got: Vec<_> = replies.iter().map(|r| decode_reply(r)).collect();
            assert!(
                matches!(got.as_slice(), [DeviceMessage::Status(s)] if s.seq == 7),
                "lone 0x00 at alignment {offset}: {got:?}"
            );
        }
    });
}

#[test]
fn a_retransmitted_message_is_answered_again_not_applied_twice() {
    on_big_stack(|| {
        let mut buf = vec![0u8; MAX_FRAME_LEN];
        let mut frames: Vec<Vec<u8>> = Vec::new();
        let mut push = |seq: u32, msg: HostMessage<'_>| {
            frames.push(encode(&HostFrame { seq, msg }, &mut buf).unwrap().to_vec());
        };
        push(1, HostMessage::Hello(config(2)));
        let mut seq = 2;
        for i in 0..8 {
            push(
                seq,
                HostMessage::FrameBegin {
                    frame: i,
                    timestamp: timestamp(i),
                    pose: pose(i),
                },
            );
            let data: Vec<u8> = frame_rows(i).iter().flat_map(|d| d.to_le_bytes()).collect();
            for (k, half) in data.chunks(data.len() / 2).enumerate() {
                push(
                    seq + 1 + k as u32,
                    HostMessage::DepthRows(DepthRows {
                        frame: i,
                        first_row: 12 * k as u16,
                        row_count: 12,
                        data: half,
                    }),
                );
            }
            // A refused message (rows again) is answered the same way too.
            push(seq + 3, HostMessage::FrameEnd { frame: i + 1 });
            push(seq + 4, HostMessage::FrameEnd { frame: i });
            seq += 5;
        }
        push(seq, HostMessage::Finish);
        let mut clean = bench::<Small>();
        let mut twice = bench::<Small>();
        for f in &frames {
            let once = clean.feed(f, f.len());
            let first = twice.feed(f, f.len());
            assert_eq!(first, once);
            // The retransmission: only the terminal reply, again.
            let again = twice.feed(f, 7);
            assert_eq!(again.len(), 1);
            assert_eq!(again.last(), once.last());
        }
        let (a, b) = (clean.status(), twice.status());
        assert_eq!(a.frames_seen, 8);
        assert_eq!(b.frames_seen, 8);
        assert_eq!(b.refused, a.refused);
        assert_eq!(twice.export(), clean.export());
        // The same sequence number with another message is not a retry.
        let mut buf = vec![0u8; MAX_FRAME_LEN];
        let reset = encode(
            &HostFrame {
                seq,
                msg: HostMessage::Reset,
            },
            &mut buf,
        )
        .unwrap()
        .to_vec();
        assert_eq!(
            twice.feed(&reset, reset.len()),
            vec![DeviceMessage::Ack { seq }]
        );
        assert_eq!(twice.status().phase, Phase::Unconfigured);
    });
}

#[test]
fn hello_rules() {
    on_big_stack(|| {
        let mut b = bench::<Small>();
        let mut bad = config(4);
        bad.version = PROTOCOL_VERSION + 1;
        assert_eq!(b.refused(HostMessage::Hello(bad)), ErrorKind::WrongVersion);
        bad = config(4);
        bad.mu = 1.5;
        assert_eq!(b.refused(HostMessage::Hello(bad)), ErrorKind::BadConfig);
        assert_eq!(b.status().phase, Phase::Unconfigured);
        // Before any frame a Hello replaces the previous one.
        b.ok(HostMessage::Hello(config(2)));
        b.ok(HostMessage::Hello(config(4)));
        frame(&mut b, 0, 24);
        b.ok(HostMessage::FrameBegin {
            frame: 1,
            timestamp: 1.0,
            pose: pose(1),
        });
        assert_eq!(
            b.refused(HostMessage::Hello(config(4))),
            ErrorKind::MidFrameReconfig
        );
        let rows = frame_rows(1);
        let data: Vec<u8> = rows.iter().flat_map(|d| d.to_le_bytes()).collect();
        b.ok(HostMessage::DepthRows(DepthRows {
            frame: 1,
            first_row: 0,
            row_count: H.div_ceil(STRIDE),
            data: &data,
        }));
        b.ok(HostMessage::FrameEnd { frame: 1 });
        // After frames: the same Hello is a harmless retry, another one is refused.
        b.ok(HostMessage::Hello(config(4)));
        assert_eq!(
            b.refused(HostMessage::Hello(config(2))),
            ErrorKind::NeedsReset
        );
        assert_eq!(b.status().frames_seen, 2);
        b.ok(HostMessage::Reset);
        b.ok(HostMessage::Hello(config(2)));
    });
}

#[test]
fn refused_messages_change_nothing() {
    on_big_stack(|| {
        let mut b = bench::<Small>();
        let begin = |i: u32| HostMessage::FrameBegin {
            frame: i,
            timestamp: timestamp(i),
            pose: pose(i),
        };
        assert_eq!(b.refused(begin(0)), ErrorKind::NotConfigured);
        assert_eq!(b.refused(HostMessage::Finish), ErrorKind::NotConfigured);
        b.ok(HostMessage::Hello(config(3)));
        for i in 0..5 {
            frame(&mut b, i, 7);
        }
        let before = b.export();
        let status = b.status();
        let ws = W.div_ceil(STRIDE);
        let row = vec![0x10u8; usize::from(ws) * 2];
        let rows = |frame: u32, first_row: u16, row_count: u16, data: &'static [u8]| {
            HostMessage::DepthRows(DepthRows {
                frame,
                first_row,
                row_count,
                data,
            })
        };
        let row: &'static [u8] = std::boxed::Box::leak(row.into_boxed_slice());
        assert_eq!(b.refused(begin(7)), ErrorKind::OutOfOrder);
        assert_eq!(b.refused(begin(4)), ErrorKind::OutOfOrder);
        assert_eq!(b.refused(rows(5, 0, 1, row)), ErrorKind::OutOfOrder);
        assert_eq!(
            b.refused(HostMessage::FrameEnd { frame: 5 }),
            ErrorKind::FrameEndWithoutBegin
        );
        let mut nan = pose(5);
        nan.translation[0] = f32::NAN;
        let bad_pose = HostMessage::FrameBegin {
            frame: 5,
            timestamp: 5.0,
            pose: nan,
        };
        assert_eq!(b.refused(bad_pose), ErrorKind::BadPose);
        let bad_time = HostMessage::FrameBegin {
            frame: 5,
            timestamp: f64::INFINITY,
            pose: pose(5),
        };
        assert_eq!(b.refused(bad_time), ErrorKind::BadPose);
        // Inside frame 5.
        b.ok(begin(5));
        assert_eq!(b.refused(begin(6)), ErrorKind::OutOfOrder);
        assert_eq!(b.refused(rows(4, 0, 1, row)), ErrorKind::OutOfOrder);
        assert_eq!(b.refused(rows(5, 1, 1, row)), ErrorKind::OutOfOrder);
        assert_eq!(b.refused(rows(5, 24, 1, row)), ErrorKind::RowOutOfRange);
        assert_eq!(b.refused(rows(5, 0, 2, row)), ErrorKind::RowTooShort);
        assert_eq!(
            b.refused(rows(5, 0, 1, &row[..row.len() - 2])),
            ErrorKind::RowTooShort
        );
        assert_eq!(b.refused(rows(5, 0, 0, row)), ErrorKind::RowTooLong);
        assert_eq!(
            b.refused(HostMessage::FrameEnd { frame: 5 }),
            ErrorKind::MissingRows
        );
        assert_eq!(
            b.refused(HostMessage::FrameEnd { frame: 4 }),
            ErrorKind::FrameEndWithoutBegin
        );
        assert_eq!(b.refused(HostMessage::Finish), ErrorKind::OutOfOrder);
        // Damaged frames: typed errors, nothing stored changes.
        let replies = b.feed(&[0x05, 0x01, 0x02, 0x03, 0x04, 0x00], 6);
        assert!(matches!(
            replies.as_slice(),
            [DeviceMessage::Error {
                kind: ErrorKind::BadCrc,
                ..
            }]
        ));
        let mut long = vec![0x11u8; MAX_FRAME_LEN + 10];
        long.push(0);
        let replies = b.feed(&long, 100);
        assert!(matches!(
            replies.as_slice(),
            [DeviceMessage::Error {
                seq: None,
                kind: ErrorKind::Oversized,
            }]
        ));
        assert_eq!(b.export(), before);
        let after = b.status();
        assert_eq!(after.phase, Phase::InFrame);
        assert_eq!(after.frames_seen, status.frames_seen);
        assert_eq!(after.database_size, status.database_size);
        assert_eq!(after.refused, status.refused + 18);
        assert_eq!(
            after.capacity(CapacitySlot::RxFrame).peak,
            MAX_FRAME_LEN as u32
        );
        // The frame in progress goes on.
        let data: Vec<u8> = frame_rows(5).iter().flat_map(|d| d.to_le_bytes()).collect();
        b.ok(HostMessage::DepthRows(DepthRows {
            frame: 5,
            first_row: 0,
            row_count: 24,
            data: &data,
        }));
        b.ok(HostMessage::FrameEnd { frame: 5 });
    });
}

/// A camera one strided column wide: a DepthRows of `MAX_ROW_VALUES + 1`
/// rows fits a frame (small varints) and passes every other check; the
/// device refuses it as a capacity (not damage), changing nothing, and
/// accepts `MAX_ROW_VALUES` rows.
#[test]
fn depth_rows_beyond_the_row_buffer_are_refused_not_damage() {
    on_big_stack(|| {
        let mut b = bench::<Small>();
        let mut cfg = config(3);
        cfg.intrinsics = Intrinsics {
            width: 1,
            height: 1100,
            fx: 500.0,
            fy: 500.0,
            cx: 0.5,
            cy: 550.0,
        };
        cfg.stride = 1;
        assert_eq!((cfg.width_sent(), cfg.height_sent()), (1, 1100));
        b.ok(HostMessage::Hello(cfg));
        b.ok(HostMessage::FrameBegin {
            frame: 0,
            timestamp: 0.0,
            pose: pose(0),
        });
        let max = MAX_ROW_VALUES as u16;
        let data: Vec<u8> = (0..=MAX_ROW_VALUES)
            .flat_map(|_| 2000u16.to_le_bytes())
            .collect();
        let rows = |first_row: u16, row_count: u16| {
            let data = &data[..usize::from(row_count) * 2];
            HostMessage::DepthRows(DepthRows {
                frame: 0,
                first_row,
                row_count,
                data,
            })
        };
        let mut buf = vec![0u8; MAX_FRAME_LEN];
        let frame = encode(
            &HostFrame {
                seq: 1,
                msg: rows(0, max + 1),
            },
            &mut buf,
        )
        .unwrap();
        assert!(frame.len() <= MAX_FRAME_LEN, "it fits a frame");
        let before = b.status();
        let kind = b.refused(rows(0, max + 1));
        assert_eq!(kind, ErrorKind::CapacityExhausted);
        assert!(!kind.is_damage(), "a refusal: the host must not resend it");
        let after = b.status();
        assert_eq!(after.refused, before.refused + 1);
        assert_eq!(after.valid_pixels, before.valid_pixels);
        assert_eq!(after.phase, Phase::InFrame);
        // The largest accepted, then the rest of the frame.
        b.ok(rows(0, max));
        b.ok(rows(max, 1100 - max));
        b.ok(HostMessage::FrameEnd { frame: 0 });
        let end = b.status();
        assert_eq!(end.frames_seen, 1);
        assert!(end.valid_pixels > 0);
    });
}

#[test]
fn full_database_and_labels_degrade_as_documented() {
    on_big_stack(|| {
        let mut b = bench::<Tiny>();
        b.ok(HostMessage::Hello(config(2)));
        let n = 12;
        let mut got = Vec::new();
        for i in 0..n {
            got.extend(frame(&mut b, i, 24));
        }
        got.extend(decisions(&b.ok(HostMessage::Finish)));
        let (want, records) = reference::<1024, 2048, 2, 4, 16>(&config(2), n);
        assert_eq!(finals(&got), finals(&want));
        assert!(got
            .iter()
            .any(|(_, k)| matches!(k, DecisionKind::Uncovered(_))));
        let st = b.status();
        assert_eq!(st.database_size, 2);
        // Labels live in flash: every frame has one, whatever the database.
        assert_eq!(st.capacity(CapacitySlot::Labels).used, n);
        assert_eq!(st.labels_dropped, 0);
        assert!(st.uncovered_frames > 0);
        assert_eq!(
            st.degradation & degradation::DATABASE_FULL,
            degradation::DATABASE_FULL
        );
        assert_eq!(st.degradation & degradation::LABELS_FULL, 0);
        assert_eq!(b.export(), records);
    });
}

#[test]
fn the_clock_measures_frames() {
    use core::sync::atomic::{AtomicU64, Ordering};
    static TICKS: AtomicU64 = AtomicU64::new(0);
    fn tick() -> u64 {
        TICKS.fetch_add(10, Ordering::Relaxed)
    }
    on_big_stack(|| {
        let mut b = bench::<Small>();
        b.device.set_clock(tick, 1000);
        b.ok(HostMessage::Hello(config(3)));
        // Each frame's cost is read right after it; the totals must add up.
        let mut costs = Vec::new();
        for i in 0..3 {
            frame(&mut b, i, 24);
            let c = b.status().cost;
            assert_eq!(c.frames, i + 1);
            assert!(c.last_rows > 0 && c.last_end > 0, "{c:?}");
            costs.push(c.last_rows + c.last_end);
        }
        let st = b.status();
        assert_eq!(st.cost.clock_hz, 1000);
        assert_eq!(
            st.cost.total,
            costs.iter().map(|&c| u64::from(c)).sum::<u64>()
        );
        assert_eq!(st.cost.max, costs.iter().copied().max().unwrap());
        // The core's share is part of the total; the protocol's is the rest.
        assert!(st.cost.core > 0 && st.cost.core < st.cost.total);
        b.ok(HostMessage::Reset);
        let st = b.status();
        assert_eq!(
            (st.cost.clock_hz, st.cost.frames, st.cost.core),
            (1000, 0, 0)
        );
    });
}

#[test]
fn receive_ticks_count_in_the_frame_total_not_in_the_core() {
    use core::sync::atomic::{AtomicU64, Ordering};
    static TICKS: AtomicU64 = AtomicU64::new(0);
    // Every reading advances the clock by 10: a message's own ticks depend
    // only on how often it reads the clock, the same on both devices.
    fn tick() -> u64 {
        TICKS.fetch_add(10, Ordering::Relaxed)
    }
    const RX: u64 = 7;
    on_big_stack(|| {
        let run = |rx: u64| {
            let mut b = bench::<Small>();
            b.device.set_clock(tick, 1000);
            b.ok(HostMessage::Hello(config(3)));
            for i in 0..3 {
                frame_rx(&mut b, i, 24, rx);
                // Receive work of a message outside a frame is no frame's.
                b.device.add_receive_ticks(rx);
                let _ = b.status();
            }
            b.status().cost
        };
        let (plain, received) = (run(0), run(RX));
        // Per frame: FrameBegin, the DepthRows messages, FrameEnd.
        let messages = 1 + u64::from(H.div_ceil(STRIDE).div_ceil(24)) + 1;
        assert_eq!(received.frames, 3);
        assert_eq!(received.total, plain.total + 3 * messages * RX);
        assert_eq!(received.core, plain.core);
        assert_eq!(received.last_end, plain.last_end + RX as u32);
        let rows_rx = (messages - 1) * RX;
        assert_eq!(
            u64::from(received.last_rows),
            u64::from(plain.last_rows) + rows_rx
        );
    });
}

#[test]
fn profiles_match_the_selector_profiles() {
    use crate::profile::by_name;
    fn check<
        const FV: usize,
        const P: usize,
        const DB: usize,
        const WN: usize,
        const K: usize,
        const L: usize,
    >(
        name: &str,
        _: fn() -> Device<FV, P, DB, WN, K, L>,
    ) {
        let p = by_name(name).unwrap();
        assert_eq!(
            (
                p.frame_voxel_slots,
                p.pool_words,
                p.database_frames,
                p.window,
                p.sketch
            ),
            (FV, P, DB, WN, K),
            "{name}"
        );
        let size = core::mem::size_of::<Device<FV, P, DB, WN, K, L>>();
        // State, plus room for the stack and the board's own buffers.
        assert!(size + 16 * 1024 <= p.ram, "{name}: {size} B");
    }
    check("ram256k", Device256K::new);
    check("ram512k", Device512K::new);
    check("ram1m", Device1M::new);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// Junk frames anywhere in a valid stream get errors and change
    /// nothing: the decisions and the export are those of the clean stream.
    #[test]
    fn junk_between_frames_changes_nothing(
        junk in proptest::collection::vec(
            (0usize..40, proptest::collection::vec(any::<u8>(), 0..300)),
            0..6,
        ),
    ) {
        let (tx, rx) = std::sync::mpsc::channel();
        on_big_stack(move || {
            let mut msgs: Vec<Vec<u8>> = Vec::new();
            let mut buf = vec![0u8; MAX_FRAME_LEN];
            let mut seq = 0;
            let mut push = |msg: HostMessage<'_>| {
                seq += 1;
                msgs.push(encode(&HostFrame { seq, msg }, &mut buf).unwrap().to_vec());
            };
            push(HostMessage::Hello(config(3)));
            for i in 0..10 {
                push(HostMessage::FrameBegin { frame: i, timestamp: timestamp(i), pose: pose(i) });
                let data: Vec<u8> = frame_rows(i).iter().flat_map(|d| d.to_le_bytes()).collect();
                for (k, half) in data.chunks(data.len() / 2).enumerate() {
                    push(HostMessage::DepthRows(DepthRows {
                        frame: i,
                        first_row: 12 * k as u16,
                        row_count: 12,
                        data: half,
                    }));
                }
                push(HostMessage::FrameEnd { frame: i });
            }
            push(HostMessage::Finish);
            push(HostMessage::ExportRequest { from_record: 0, max_records: u32::MAX });
            let clean: Vec<u8> = msgs.concat();
            let mut dirty = Vec::new();
            let mut junk_frames = 0;
            for (k, m) in msgs.iter().enumerate() {
                for (at, bytes) in &junk {
                    if *at == k {
                        dirty.extend_from_slice(bytes);
                        dirty.push(0);
                        junk_frames += bytes.split(|&b| b == 0).filter(|s| !s.is_empty()).count();
                    }
                }
                dirty.extend_from_slice(m);
            }
            let want = bench::<Small>().feed(&clean, 4096);
            let got = bench::<Small>().feed(&dirty, 97);
            let errors = got.iter().filter(|m| matches!(m, DeviceMessage::Error { .. })).count();
            let kept: Vec<_> = got
                .into_iter()
                .filter(|m| !matches!(m, DeviceMessage::Error { .. }))
                .collect();
            tx.send((kept == want, errors, junk_frames)).unwrap();
        });
        let (same, errors, junk_frames) = rx.recv().unwrap();
        prop_assert!(same);
        prop_assert_eq!(errors, junk_frames);
    }
}

/// CRC-valid records that no device can use after the first record of a
/// scan: each breaks the record grammar or contradicts the records before it.
fn unusable_records(cfg: Config) -> Vec<(&'static str, Vec<u8>)> {
    let mut buf = [0u8; 512];
    let decisions = Record::encode_decisions(1000, &[(0.0, DecisionKind::Taken, 0)], &mut buf)
        .unwrap()
        .to_vec();
    vec![
        ("a second Begin", encoded(Record::Begin(cfg))),
        ("Cleared inside a scan", encoded(Record::Cleared)),
        ("bytes that are no record", vec![0xFF; 9]),
        ("decisions out of order", decisions),
    ]
}

#[test]
fn an_unusable_record_drops_the_tail_and_the_scan_goes_on_from_before_it() {
    on_big_stack(|| {
        let cfg = config(4);
        let n = 24;
        let mut cases = unusable_records(cfg);
        cases.push(("Finished, then more", encoded(Record::Finished)));
        // Filled in from the log: its first database frame, again, once its
        // own decision is stored (before that, a second record of the frame
        // is a resumed scan taking it again: see `device::restore`).
        cases.push(("a database frame again", Vec::new()));
        let mut dropped = 0;
        for streamed in [1, 4, 9, 13, 20] {
            for (name, bad) in &cases {
                let ctx = format!("{name} after frame {streamed}");
                let finished = name.starts_with("Finished");
                let mut b = bench::<Small>();
                b.ok(HostMessage::Hello(cfg));
                for i in 0..streamed {
                    frame(&mut b, i, 5);
                }
                // The reference: the log as it was before the record, and
                // with `Finished`, which may end a scan, the record too.
                let mut before = b.log.take().unwrap();
                let mut bad = bad.clone();
                if bad.is_empty() {
                    let labels = b.status().capacity(CapacitySlot::Labels).used;
                    let mut database = Vec::new();
                    before
                        .replay(&mut |_, p| {
                            let decided = match Record::decode(p) {
                                Ok((Record::Database { meta, .. }, _)) => meta.index < labels,
                                _ => false,
                            };
                            if decided && database.is_empty() {
                                database = p.to_vec();
                            }
                        })
                        .unwrap();
                    if database.is_empty() {
                        continue; // no decided database frame yet
                    }
                    bad = database;
                }
                let bad = &bad;
                if finished {
                    before.append(bad).unwrap();
                }
                let reference_flash = before.flash().inner().clone();
                if !finished {
                    before.append(bad).unwrap();
                }
                b.log = Some(before);
                // The device writes on after it, not knowing.
                for i in streamed..n {
                    frame(&mut b, i, 5);
                }
                let (mut damaged, restored) = Harness::<Small>::boot(b.into_flash());
                let (mut reference, expected) = Harness::<Small>::boot(reference_flash);
                assert!(expected.is_ok(), "{ctx}: {expected:?}");
                assert_eq!(restored, expected, "{ctx}");
                let (got, want) = (damaged.status(), reference.status());
                assert_eq!(
                    got.degradation,
                    want.degradation | degradation::TAIL_DROPPED
                );
                let state =
                    |s: &Status| (s.phase, s.frames_seen, s.frames_decided, s.database_size);
                assert_eq!(state(&got), state(&want), "{ctx}");
                assert_eq!(got.stored_records, want.stored_records, "{ctx}");
                assert_eq!(damaged.export(), reference.export(), "{ctx}");
                // Both go on the same way to the end of the scan.
                for h in [&mut damaged, &mut reference] {
                    h.ok(HostMessage::Hello(cfg));
                    let from = h.status().frames_seen;
                    if !finished {
                        for i in from..n {
                            frame(h, i, 5);
                        }
                    }
                    h.ok(HostMessage::Finish);
                }
                let export = reference.export();
                assert_eq!(damaged.export(), export, "{ctx}");
                // The drop is complete once a record follows the kept ones:
                // then the next boot finds nothing to drop. (A finished scan
                // writes nothing more: a boot drops again what is left of
                // the tail in the last kept record's sector.)
                let (mut again, restored) = Harness::<Small>::boot(damaged.into_flash());
                assert!(restored.is_ok(), "{ctx}: {restored:?}");
                if !finished {
                    let flag = again.status().degradation & degradation::TAIL_DROPPED;
                    assert_eq!(flag, 0, "{ctx}");
                }
                assert_eq!(again.export(), export, "{ctx}");
                dropped += 1;
            }
        }
        // A database frame is repeated only once its decision is stored,
        // after 20 frames (the first batch of 16 decisions).
        assert_eq!(dropped, 26);
    });
}

#[test]
fn nothing_may_follow_cleared() {
    on_big_stack(|| {
        let mut log = blank_log();
        log.start(&encoded(Record::Cleared)).unwrap();
        log.append(&encoded(Record::Begin(config(4)))).unwrap();
        let (mut b, restored) = Harness::<Small>::boot(log.into_flash());
        assert_eq!(restored, Ok(1));
        let st = b.status();
        assert_eq!(st.phase, Phase::Unconfigured);
        assert_eq!(st.degradation, degradation::TAIL_DROPPED);
        // A Hello starts a scan as on a blank device.
        b.ok(HostMessage::Hello(config(4)));
        frame(&mut b, 0, 5);
        let (mut again, restored) = Harness::<Small>::boot(b.into_flash());
        assert!(restored.is_ok(), "{restored:?}");
        assert_eq!(again.status().degradation, degradation::RESTORED);
    });
}

#[test]
fn a_log_unusable_from_its_first_record_is_refused_whole_and_left_as_it_is() {
    on_big_stack(|| {
        let mut cases = unusable_records(config(4));
        // Begin and Cleared are what a log opens with.
        cases.retain(|(name, _)| {
            !name.starts_with("a second Begin") && !name.starts_with("Cleared")
        });
        cases.push(("Finished first", encoded(Record::Finished)));
        let mut buf = [0u8; 512];
        let meta = FrameMeta {
            index: 0,
            timestamp: 0.0,
            pose: pose(0),
        };
        let keys = crate::persist::record::KeyChunks::NONE;
        let database = Record::encode_database(meta, 1, None, &[7], keys, &mut buf).unwrap();
        cases.push(("a database frame first", database.to_vec()));
        for (name, bad) in &cases {
            let mut log = blank_log();
            log.start(bad).unwrap();
            log.append(&encoded(Record::Begin(config(4)))).unwrap();
            let flash = log.into_flash();
            let (mut b, restored) = Harness::<Small>::boot(flash.clone());
            assert_eq!(
                restored,
                Err(RestoreFailure::Malformed { record: 0 }),
                "{name}"
            );
            assert_eq!(b.status().phase, Phase::Unconfigured, "{name}");
            assert_eq!(
                b.flash().bytes(),
                flash.bytes(),
                "{name}: the flash is left as it is"
            );
            // The next Hello starts a new scan.
            b.ok(HostMessage::Hello(config(4)));
            frame(&mut b, 0, 5);
            let (mut again, restored) = Harness::<Small>::boot(b.into_flash());
            assert!(restored.is_ok(), "{name}: {restored:?}");
            assert_eq!(again.status().phase, Phase::Ready, "{name}");
        }
    });
}

/// The payload of a record without a tail.
fn encoded(record: Record) -> Vec<u8> {
    let mut buf = [0u8; 512];
    record.encode(&mut buf).unwrap().to_vec()
}

/// A log on a blank flash of the bench's size.
fn blank_log() -> Log<SimFlash> {
    let end = (BENCH_SECTORS * SimFlash::SECTOR) as u32;
    Log::open(SimFlash::new(BENCH_SECTORS), 0, end).unwrap()
}

mod extend;
mod resume;

/// `receive_message` handles exactly one frame a call (the board acts
/// between messages on what it returns) and, called until its input is
/// used up, gives what `receive_logged` gives; a refused frame and a lone
/// delimiter end nothing early, a partial frame ends nothing.
#[test]
fn receive_message_stops_after_each_frame() {
    on_big_stack(|| {
        let mut stream = Vec::new();
        let mut buf = vec![0u8; MAX_FRAME_LEN];
        let mut ends = Vec::new();
        for (seq, msg) in [
            (1, HostMessage::Hello(config(3))),
            (2, HostMessage::StatusRequest),
            (3, HostMessage::StatusRequest),
        ] {
            stream.extend_from_slice(encode(&HostFrame { seq, msg }, &mut buf).unwrap());
            ends.push(stream.len());
        }
        // A frame with a bad CRC (refused, answered), a lone delimiter
        // (skipped), then the first half of a status request.
        let mut bad = encode(
            &HostFrame {
                seq: 4,
                msg: HostMessage::StatusRequest,
            },
            &mut buf,
        )
        .unwrap()
        .to_vec();
        bad[1] ^= 0x20;
        stream.extend_from_slice(&bad);
        ends.push(stream.len());
        stream.push(0);
        let partial = encode(
            &HostFrame {
                seq: 5,
                msg: HostMessage::StatusRequest,
            },
            &mut buf,
        )
        .unwrap()
        .to_vec();
        stream.extend_from_slice(&partial[..partial.len() / 2]);

        let mut whole = Vec::new();
        Small::new_boxed().receive(&stream, &mut |f| whole.push(f.to_vec()));

        let mut device = Small::new_boxed();
        let mut replies = Vec::new();
        let mut rest: &[u8] = &stream;
        let mut ended_at = Vec::new();
        while !rest.is_empty() {
            let before = replies.len();
            let (after, ended) =
                device.receive_message(rest, &mut NoJournal, &mut |f| replies.push(f.to_vec()));
            if ended {
                ended_at.push(stream.len() - after.len());
                assert_eq!(replies.len(), before + 1, "one frame, one reply");
            } else {
                assert!(after.is_empty());
                assert_eq!(replies.len(), before);
            }
            rest = after;
        }
        assert_eq!(ended_at, ends);
        assert_eq!(replies, whole);
        assert_eq!(replies.len(), 4);
    });
}

/// A fault of the simulated flash, named.
type FlashFault = (&'static str, fn(&mut SimFlash));

/// A flash that reports success for what did not take (bits that do not
/// program, a protected sector): the device never counts a record as
/// durable that a reboot does not restore, and tells the host in its
/// status (`STORAGE_FAILED`) that writing stopped.
#[test]
fn a_flash_that_does_not_take_a_write_is_never_acknowledged_durable() {
    on_big_stack(|| {
        let faults: [FlashFault; 2] = [
            ("bits dropped", |f| f.drop_bits(1, 0x01)),
            ("sector protected", |f| f.protect(1)),
        ];
        for (what, fault) in faults {
            let mut b = bench::<Small>();
            fault(b.flash());
            b.ok(HostMessage::Hello(config(4)));
            let mut frames = 0;
            while b.status().degradation & degradation::STORAGE_FAILED == 0 {
                assert!(
                    frames < 200,
                    "{what}: the log never reached the faulty sector"
                );
                frame(&mut b, frames, 5);
                frames += 1;
            }
            // The scan goes on (replies still go out), writing nothing more.
            frame(&mut b, frames, 5);
            let st = b.status();
            assert!(st.stored_records > 1, "{what}");
            let (mut again, restored) = Harness::<Small>::boot(b.into_flash());
            assert_eq!(
                restored,
                Ok(st.stored_records),
                "{what}: every record counted durable restores, and no other"
            );
            assert_eq!(again.status().stored_records, st.stored_records, "{what}");
        }
    });
}

/// An export never ends short with a count and CRC that agree: a database
/// frame or a decision batch the flash log cannot give back ends the reply
/// with `ExportUnreadable` after the records before it.
#[test]
fn a_record_the_log_cannot_give_back_is_an_error_not_a_shorter_export() {
    on_big_stack(|| {
        // Two resident frames: the earlier database frames are read back
        // from the log when exported.
        let mut b = bench::<Device<1024, 8192, 16, 8, 16, 2>>();
        b.ok(HostMessage::Hello(config(4)));
        for i in 0..30 {
            frame(&mut b, i, 5);
        }
        b.ok(HostMessage::Finish);
        let whole = b.export();
        let st = b.status();
        let first = whole[0].frame;
        // Every record of the log: where it is and what it is.
        let mut records = Vec::new();
        for record in 0..st.stored_records {
            let mut payload = Vec::new();
            let at = loop {
                let offset = payload.len() as u32;
                match b.send(HostMessage::LogRead { record, offset }).last() {
                    Some(DeviceMessage::LogBytes(c)) => {
                        payload.extend_from_slice(c.bytes());
                        if c.bytes().is_empty() || payload.len() >= c.total as usize {
                            break c.at;
                        }
                    }
                    other => panic!("no LogBytes: {other:?}"),
                }
            };
            records.push((at as usize, Record::decode(&payload).map(|(r, _)| r)));
        }
        let before = b.flash().bytes().to_vec();
        let db = st.database_size;
        let unreadable = |b: &mut Harness<_>, at: usize, named: (u32, u32, Option<u32>)| {
            // The payload's first byte: the record's CRC no longer holds.
            b.flash().bytes_mut()[at + crate::persist::log::HEADER_LEN] ^= 0x5A;
            let replies = b.send(HostMessage::ExportRequest {
                from_record: 0,
                max_records: u32::MAX,
            });
            let Some(DeviceMessage::ExportUnreadable(u)) = replies.last() else {
                panic!("no ExportUnreadable: {replies:?}");
            };
            assert_eq!((u.record, u.frame, u.log_at), named, "{replies:?}");
            assert_eq!(replies.len() as u32, u.record + 1, "the records before it");
            assert!(
                !replies
                    .iter()
                    .any(|m| matches!(m, DeviceMessage::ExportEnd { .. })),
                "an ExportEnd over fewer records"
            );
            b.flash().bytes_mut().copy_from_slice(&before);
            assert_eq!(b.export(), whole, "the flash as it was: the same export");
        };
        // The first database frame's record (not resident).
        let (at, _) = *records
            .iter()
            .find(|(_, r)| matches!(r, Ok(Record::Database { meta, .. }) if meta.index == first))
            .expect("the first database frame's record");
        unreadable(&mut b, at, (0, first, Some(at as u32)));
        // The second decision batch: the labels from it on, after the first.
        let mut batches = records
            .iter()
            .filter(|(_, r)| matches!(r, Ok(Record::Labels { .. })));
        let (first_batch, _) = *batches.next().expect("a decision batch");
        let (at, _) = *batches.next().expect("a second decision batch");
        let after = DECISION_BATCH as u32;
        unreadable(&mut b, at, (db + after, after, Some(first_batch as u32)));
    });
}

/// The copying and in-place receive paths read one stream alike, however
/// it is split between them: a lone delimiter (the host's resynchronisation
/// byte) at each of the four alignments taken by the copying path, then a
/// frame in place, gets its Status; and every split point of a stream of
/// delimiters, frames and garbage gives the replies of the copying path
/// alone.
#[test]
fn a_stream_split_between_the_copying_and_in_place_paths_reads_alike() {
    on_big_stack(|| {
        let mut buf = vec![0u8; MAX_FRAME_LEN];
        let status = |seq| {
            encode(
                &HostFrame {
                    seq,
                    msg: HostMessage::StatusRequest,
                },
                &mut vec![0u8; MAX_FRAME_LEN],
            )
            .unwrap()
            .to_vec()
        };
        let in_place = |device: &mut Small, bytes: &[u8], replies: &mut Vec<Vec<u8>>| {
            let room = device.receive_room(bytes.len());
            assert!(room.len() >= bytes.len());
            room[..bytes.len()].copy_from_slice(bytes);
            device.commit_received(bytes.len());
            while device.holds_input() {
                device.receive_held(&mut NoJournal, &mut |f| replies.push(f.to_vec()));
            }
        };
        let copying = |device: &mut Small, mut bytes: &[u8], replies: &mut Vec<Vec<u8>>| {
            while !bytes.is_empty() {
                bytes = device
                    .receive_message(bytes, &mut NoJournal, &mut |f| replies.push(f.to_vec()))
                    .0;
            }
        };
        // The lone delimiter at each alignment of a word-aligned buffer.
        let words = [0u32; 2];
        let zeros: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        for offset in 0..4 {
            let mut device = Small::new_boxed();
            let mut replies = Vec::new();
            copying(&mut device, &zeros[offset..offset + 1], &mut replies);
            assert!(replies.is_empty());
            in_place(&mut device, &status(7), &mut replies);
            let got: Vec<_> = replies.iter().map(|r| decode_reply(r)).collect();
            assert!(
                matches!(got.as_slice(), [DeviceMessage::Status(s)] if s.seq == 7),
                "a lone 0x00 at alignment {offset}: {got:?}"
            );
        }
        // Every split of one stream between the two paths.
        let mut stream = vec![0u8];
        stream.extend(status(1));
        stream.extend([0, 0, 0x55, 0x13, 0]);
        stream.extend(status(2));
        stream.push(0);
        stream.extend(
            encode(
                &HostFrame {
                    seq: 3,
                    msg: HostMessage::Finish,
                },
                &mut buf,
            )
            .unwrap(),
        );
        stream.extend(status(4));
        let mut alone = Vec::new();
        copying(&mut Small::new_boxed(), &stream, &mut alone);
        assert!(alone.len() >= 4, "{alone:?}");
        for k in 0..=stream.len() {
            for copying_first in [true, false] {
                let mut device = Small::new_boxed();
                let mut replies = Vec::new();
                let (a, b) = stream.split_at(k);
                if copying_first {
                    copying(&mut device, a, &mut replies);
                    in_place(&mut device, b, &mut replies);
                } else {
                    in_place(&mut device, a, &mut replies);
                    copying(&mut device, b, &mut replies);
                }
                assert_eq!(
                    replies, alone,
                    "split at {k}, copying path first: {copying_first}"
                );
            }
        }
    });
}
