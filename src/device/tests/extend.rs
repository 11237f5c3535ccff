//! Sessions: a finished scan extended with `HostMessage::Extend` decides
//! the new session's frames exactly as a selector seeded from the first
//! session's stored frames (the host's `select --extend --solver online`
//! does the same seeding), refusals change nothing, a reboot brings both
//! sessions back, and a log of format 2 (written before sessions) is read
//! and extended.

use super::*;
use crate::key_pool::{key_of, merge_count};
use crate::select::{DbSnapshot, FrameStore};

/// The first session: frames 0..A_FRAMES of the wall.
const A_FRAMES: u32 = 24;
/// The second session: B_FRAMES frames walking back over half of the first
/// session's wall and on past its end (content index `B_FROM + k`).
const B_FRAMES: u32 = 24;
const B_FROM: u32 = 12;

/// Streams frame `index` with the content (rows and pose) of wall frame
/// `content`.
fn frame_as<D: AnyDevice>(
    b: &mut Harness<D>,
    index: u32,
    content: u32,
) -> Vec<(u32, DecisionKind)> {
    b.ok(HostMessage::FrameBegin {
        frame: index,
        timestamp: timestamp(index),
        pose: pose(content),
    });
    let rows = frame_rows(content);
    let data: Vec<u8> = rows.iter().flat_map(|d| d.to_le_bytes()).collect();
    b.ok(HostMessage::DepthRows(DepthRows {
        frame: index,
        first_row: 0,
        row_count: H.div_ceil(STRIDE),
        data: &data,
    }));
    decisions(&b.ok(HostMessage::FrameEnd { frame: index }))
}

/// A store in memory that keeps what a log keeps of a database frame: its
/// snapshot and, when handed over, its exact keys.
#[derive(Default)]
struct MemStore {
    frames: Vec<(DbSnapshot<16>, Option<Vec<u32>>)>,
}

impl FrameStore<16> for MemStore {
    fn save(&mut self, frame: &DbSnapshot<16>, keys: Option<&[u32]>) -> Option<(u32, bool)> {
        self.frames.push((*frame, keys.map(<[u32]>::to_vec)));
        Some(((self.frames.len() - 1) as u32, keys.is_some()))
    }

    fn load(&mut self, at: u32) -> Option<DbSnapshot<16>> {
        self.frames.get(at as usize).map(|(f, _)| *f)
    }

    fn intersect(&mut self, at: u32, keys: &[u64]) -> Option<(u32, u32)> {
        let (frame, words) = self.frames.get(at as usize)?;
        let base = frame.aabb?.min;
        let stored = words.as_ref()?.iter().map(|&w| key_of(base, w));
        Some((merge_count(stored, keys.iter().copied()), frame.voxels))
    }
}

type SmallSelector = Selector<1024, 8192, 16, 8, 16, 64>;

/// Streams `(index, content)` frames through `sel`, then finishes; the
/// final decisions.
fn run(
    sel: &mut SmallSelector,
    store: &mut MemStore,
    frames: impl Iterator<Item = (u32, u32)>,
) -> Vec<(u32, DecisionKind)> {
    let mut got = Vec::new();
    let mut emit = |d: FrameDecision| got.push((d.index, DecisionKind::from(d.decision)));
    for (index, content) in frames {
        let meta = FrameMeta {
            index,
            timestamp: timestamp(index),
            pose: pose(content),
        };
        sel.begin_frame(meta).unwrap();
        sel.push_rows(0, &frame_rows(content)).unwrap();
        sel.end_frame_with(store, &mut emit).unwrap();
    }
    sel.finish_with(store, &mut emit).unwrap();
    finals(&got)
}

/// The core-level reference of an extended scan: session A through a
/// selector, then a new selector seeded with A's stored frames and
/// decisions (`restore_database`, `restore_decided`), continued with B.
/// The labels of both sessions, and the database frames, in frame order.
fn seeded_reference(cfg: &Config) -> (Vec<(u32, DecisionKind)>, Vec<u32>) {
    let (scan, sel_cfg) = (cfg.scan_config(), cfg.selector_config());
    let mut a = std::boxed::Box::new(SmallSelector::new());
    a.configure(scan, sel_cfg).unwrap();
    let mut store = MemStore::default();
    let labels_a = run(&mut a, &mut store, (0..A_FRAMES).map(|i| (i, i)));
    let mut sel = std::boxed::Box::new(SmallSelector::new());
    sel.configure(scan, sel_cfg).unwrap();
    let mut seeded = MemStore::default();
    for (frame, words) in &store.frames {
        let (at, keyed) = seeded.save(frame, words.as_deref()).unwrap();
        let bytes = words
            .as_deref()
            .map_or(0, |w| crate::persist::keys::encoded_size(w).1 as u32);
        sel.restore_database(frame, at, keyed, bytes).unwrap();
    }
    for &(i, kind) in &labels_a {
        sel.restore_decided(i, kind.into(), 0).unwrap();
    }
    sel.restore_finished().unwrap();
    let b = (0..B_FRAMES).map(|k| (A_FRAMES + k, B_FROM + k));
    let mut labels = labels_a;
    labels.extend(run(&mut sel, &mut seeded, b));
    let mut db: Vec<u32> = (0..sel.database_len())
        .map(|i| sel.database_record(i, &mut seeded).unwrap().index)
        .collect();
    db.sort_unstable();
    (labels, db)
}

/// Session A on `b`, finished.
fn session_a<D: AnyDevice>(b: &mut Harness<D>, cfg: Config) -> Vec<(u32, DecisionKind)> {
    b.ok(HostMessage::Hello(cfg));
    let mut got = Vec::new();
    for i in 0..A_FRAMES {
        got.extend(frame_as(b, i, i));
    }
    got.extend(decisions(&b.ok(HostMessage::Finish)));
    got
}

/// Session B's frames `from..` on `b` (extended already), finished.
fn session_b<D: AnyDevice>(b: &mut Harness<D>, from: u32) -> Vec<(u32, DecisionKind)> {
    let mut got = Vec::new();
    for k in from..B_FRAMES {
        got.extend(frame_as(b, A_FRAMES + k, B_FROM + k));
    }
    got.extend(decisions(&b.ok(HostMessage::Finish)));
    got
}

/// Pairs of frame indices: (frame, class) of labels, (session, first frame)
/// of sessions.
type Pairs = Vec<(u32, u32)>;

/// An export's labels, database frames and sessions after the first.
fn split(export: &[ExportRecord]) -> (Pairs, Vec<u32>, Pairs) {
    let (mut labels, mut db, mut sessions) = (Vec::new(), Vec::new(), Vec::new());
    for r in export {
        match r.kind {
            RecordKind::Label { class } => labels.push((r.frame, class)),
            RecordKind::Database { .. } => db.push(r.frame),
            RecordKind::Session { session } => sessions.push((session, r.frame)),
        }
    }
    (labels, db, sessions)
}

#[test]
fn an_extended_scan_decides_as_a_selector_seeded_with_the_first_session() {
    on_big_stack(|| {
        let cfg = config(8);
        let mut b = bench::<Small>();
        session_a(&mut b, cfg);
        let a_export = b.export();
        b.ok(HostMessage::Extend(cfg));
        let st = b.status();
        assert_eq!(st.phase, Phase::Ready);
        assert_eq!((st.frames_seen, st.frames_decided), (A_FRAMES, A_FRAMES));
        assert_eq!((st.sessions, st.session_first), (2, A_FRAMES));
        // Before any frame of B: A's export and the session record.
        let mut with_session = a_export.clone();
        with_session.push(ExportRecord {
            record: a_export.len() as u32,
            frame: A_FRAMES,
            timestamp: 0.0,
            kind: RecordKind::Session { session: 1 },
        });
        assert_eq!(b.export(), with_session);
        let live = finals(&session_b(&mut b, 0));
        let (want_labels, want_db) = seeded_reference(&cfg);
        assert_eq!(live, want_labels[A_FRAMES as usize..]);
        let export = b.export();
        assert_eq!(export.len() as u32, b.status().export_records());
        let (labels, db, sessions) = split(&export);
        let want: Vec<(u32, u32)> = want_labels
            .iter()
            .map(|&(i, k)| (i, k.class(i).unwrap()))
            .collect();
        assert_eq!(labels, want);
        assert_eq!(db, want_db);
        assert_eq!(sessions, vec![(1, A_FRAMES)]);
        // B added frames (it walks past A's end) and kept every one of A's.
        let (_, db_a, _) = split(&a_export);
        assert!(db_a.iter().all(|f| db.contains(f)), "{db_a:?} {db:?}");
        assert!(db.len() > db_a.len(), "{db:?}");
        // A third session goes on the same way.
        b.ok(HostMessage::Extend(cfg));
        assert_eq!(b.status().session_first, A_FRAMES + B_FRAMES);
        frame_as(&mut b, A_FRAMES + B_FRAMES, 0);
        b.ok(HostMessage::Finish);
        let (labels, _, sessions) = split(&b.export());
        assert_eq!(labels.len() as u32, A_FRAMES + B_FRAMES + 1);
        assert_eq!(sessions, vec![(1, A_FRAMES), (2, A_FRAMES + B_FRAMES)]);
    });
}

#[test]
fn extend_refusals_change_nothing_and_a_retry_is_a_no_op() {
    on_big_stack(|| {
        let cfg = config(8);
        // A device without flash has no scan to continue.
        let mut none = Harness::<Small>::without_flash();
        none.ok(HostMessage::Hello(cfg));
        none.ok(HostMessage::Finish);
        assert_eq!(
            none.refused(HostMessage::Extend(cfg)),
            ErrorKind::NothingToExtend
        );
        let mut b = bench::<Small>();
        assert_eq!(
            b.refused(HostMessage::Extend(cfg)),
            ErrorKind::NothingToExtend
        );
        b.ok(HostMessage::Hello(cfg));
        frame_as(&mut b, 0, 0);
        // Not finished: a scan to resume, not to extend.
        assert_eq!(
            b.refused(HostMessage::Extend(cfg)),
            ErrorKind::NothingToExtend
        );
        for i in 1..A_FRAMES {
            frame_as(&mut b, i, i);
        }
        b.ok(HostMessage::Finish);
        let (status, export, records) = (b.status(), b.export(), b.log.as_ref().unwrap().records());
        let other = config(4);
        assert_eq!(
            b.refused(HostMessage::Extend(other)),
            ErrorKind::ExtendOtherConfig
        );
        let bad = Config { version: 5, ..cfg };
        assert_eq!(b.refused(HostMessage::Extend(bad)), ErrorKind::WrongVersion);
        // Nothing changed but the count of refusals.
        let mut st = b.status();
        assert_eq!(st.refused, status.refused + 2);
        (st.refused, st.seq) = (status.refused, status.seq);
        assert_eq!(st, status);
        assert_eq!(b.export(), export);
        assert_eq!(b.log.as_ref().unwrap().records(), records);
        // Accepted: one session record, once; the same message again (a
        // retransmission) and another Extend before a frame are no-ops.
        b.ok(HostMessage::Extend(cfg));
        let seq = b.seq;
        b.seq = seq - 1;
        b.ok(HostMessage::Extend(cfg));
        b.ok(HostMessage::Extend(cfg));
        assert_eq!(b.log.as_ref().unwrap().records(), records + 1);
        assert_eq!(b.status().sessions, 2);
        // Inside a frame of the new session.
        b.ok(HostMessage::FrameBegin {
            frame: A_FRAMES,
            timestamp: 0.0,
            pose: pose(0),
        });
        assert_eq!(
            b.refused(HostMessage::Extend(cfg)),
            ErrorKind::MidFrameReconfig
        );
    });
}

#[test]
fn a_reboot_during_and_after_the_second_session_restores_both() {
    on_big_stack(|| {
        let cfg = config(8);
        let mut whole = bench::<Small>();
        session_a(&mut whole, cfg);
        whole.ok(HostMessage::Extend(cfg));
        session_b(&mut whole, 0);
        let want = whole.export();
        for cut in [0, 1, 7, 16, B_FRAMES] {
            let mut b = bench::<Small>();
            session_a(&mut b, cfg);
            b.ok(HostMessage::Extend(cfg));
            for k in 0..cut {
                frame_as(&mut b, A_FRAMES + k, B_FROM + k);
            }
            let (mut again, restored) = Harness::<Small>::boot(b.into_flash());
            assert!(restored.is_ok(), "cut {cut}: {restored:?}");
            let st = again.status();
            assert_eq!((st.sessions, st.session_first), (2, A_FRAMES), "cut {cut}");
            // The host resumes the session: Extend again is a no-op, then
            // the frames from `frames_seen`.
            again.ok(HostMessage::Extend(cfg));
            let from = again.status().frames_seen - A_FRAMES;
            session_b(&mut again, from);
            assert_eq!(again.export(), want, "cut {cut}");
        }
        let (mut again, restored) = Harness::<Small>::boot(whole.into_flash());
        assert!(restored.is_ok(), "{restored:?}");
        assert_eq!(again.status().phase, Phase::Finished);
        assert_eq!(again.export(), want);
    });
}

/// Another camera for session B: a wider lens whose depth counts
/// half-millimetres (another robot scanning the next wing).
fn other_camera(cfg: Config) -> Config {
    Config {
        depth_scale: 2000.0,
        intrinsics: Intrinsics {
            fx: 40.0,
            fy: 40.0,
            ..cfg.intrinsics
        },
        ..cfg
    }
}

#[test]
fn a_later_session_may_use_another_camera_which_a_reboot_keeps() {
    on_big_stack(|| {
        let cfg = config(8);
        let cam = other_camera(cfg);
        let scan = |b: &mut Harness<Small>, camera: Config| {
            session_a(b, cfg);
            b.ok(HostMessage::Extend(camera));
        };
        let mut whole = bench::<Small>();
        scan(&mut whole, cam);
        session_b(&mut whole, 0);
        let want = whole.export();
        // The camera is used: the same rows through the first camera
        // decide otherwise.
        let mut same = bench::<Small>();
        scan(&mut same, cfg);
        session_b(&mut same, 0);
        assert_ne!(same.export(), want, "the new camera made no difference");
        for cut in [0, 1, 7, B_FRAMES] {
            let mut b = bench::<Small>();
            scan(&mut b, cam);
            for k in 0..cut {
                frame_as(&mut b, A_FRAMES + k, B_FROM + k);
            }
            let (mut again, restored) = Harness::<Small>::boot(b.into_flash());
            assert!(restored.is_ok(), "cut {cut}: {restored:?}");
            // The open session is resumed with its own camera only; a
            // refusal changes nothing.
            let (status, records) = (again.status(), again.log.as_ref().unwrap().records());
            for wrong in [cfg, Config { mu: 0.4, ..cam }] {
                assert_eq!(
                    again.refused(HostMessage::Extend(wrong)),
                    ErrorKind::ExtendOtherConfig,
                    "cut {cut}"
                );
            }
            assert_eq!(again.status().frames_seen, status.frames_seen);
            assert_eq!(again.log.as_ref().unwrap().records(), records);
            again.ok(HostMessage::Extend(cam));
            let from = again.status().frames_seen - A_FRAMES;
            session_b(&mut again, from);
            assert_eq!(again.export(), want, "cut {cut}");
        }
        // After a reboot of the finished scan, a third session with the
        // first camera; another setting is still refused.
        let (mut again, restored) = Harness::<Small>::boot(whole.into_flash());
        assert!(restored.is_ok(), "{restored:?}");
        assert_eq!(again.export(), want);
        assert_eq!(
            again.refused(HostMessage::Extend(Config { mu: 0.4, ..cfg })),
            ErrorKind::ExtendOtherConfig
        );
        again.ok(HostMessage::Extend(cfg));
        assert_eq!(again.status().sessions, 3);
    });
}

/// A log written by the core of commit 3f75894 (log format 2, protocol 5):
/// `Small`, `config(8)`, frames 0..24 of `frame(.., i, 5)`, Finish, on a
/// flash of 8 sectors (trailing erased bytes trimmed), and its export
/// then, one `{:?}` line per record.
const FORMAT_2_LOG: &[u8] = include_bytes!("../../../tests/fixtures/log-format-2.bin");
const FORMAT_2_EXPORT: &str = include_str!("../../../tests/fixtures/log-format-2.export.txt");

#[test]
fn a_log_of_format_2_restores_and_extends() {
    on_big_stack(|| {
        let mut flash = SimFlash::new(8);
        flash.bytes_mut()[..FORMAT_2_LOG.len()].copy_from_slice(FORMAT_2_LOG);
        assert_eq!(FORMAT_2_LOG[4..6], [2, 0], "a log of format 2");
        let (mut b, restored) = Harness::<Small>::boot(flash);
        assert!(restored.is_ok(), "{restored:?}");
        assert_eq!(b.status().phase, Phase::Finished);
        let text: std::string::String = b.export().iter().map(|r| format!("{r:?}\n")).collect();
        assert_eq!(text, FORMAT_2_EXPORT);
        // Extended with records of format 3 after those of format 2.
        let cfg = config(8);
        b.ok(HostMessage::Extend(cfg));
        for i in 24..30 {
            frame(&mut b, i, 5);
        }
        b.ok(HostMessage::Finish);
        let export = b.export();
        let (mut again, restored) = Harness::<Small>::boot(b.into_flash());
        assert!(restored.is_ok(), "{restored:?}");
        assert_eq!(again.export(), export);
        // The same as a scan of 30 frames on this code, but for the session.
        let mut fresh = bench::<Small>();
        fresh.ok(HostMessage::Hello(cfg));
        for i in 0..24 {
            frame(&mut fresh, i, 5);
        }
        fresh.ok(HostMessage::Finish);
        fresh.ok(HostMessage::Extend(cfg));
        for i in 24..30 {
            frame(&mut fresh, i, 5);
        }
        fresh.ok(HostMessage::Finish);
        assert_eq!(fresh.export(), export);
    });
}

#[test]
fn log_read_gives_every_record_byte_for_byte() {
    on_big_stack(|| {
        let cfg = config(8);
        let mut b = bench::<Small>();
        session_a(&mut b, cfg);
        b.ok(HostMessage::Extend(cfg));
        session_b(&mut b, 0);
        let mut want = Vec::new();
        b.log
            .as_mut()
            .unwrap()
            .replay(&mut |at, p| want.push((at, p.to_vec())))
            .unwrap();
        assert_eq!(want.len() as u32, b.status().stored_records);
        let read = |b: &mut Harness<Small>, record: u32, offset: u32| match b
            .send(HostMessage::LogRead { record, offset })
            .as_slice()
        {
            [DeviceMessage::LogBytes(c)] => {
                assert_eq!((c.seq, c.record, c.offset), (b.seq, record, offset));
                Ok(*c)
            }
            [DeviceMessage::Error { kind, .. }] => Err(*kind),
            other => panic!("{other:?}"),
        };
        // In order, and again from the back (the cursor starts over).
        let mut order: Vec<usize> = (0..want.len()).collect();
        order.extend((0..want.len()).rev());
        for r in order {
            let (at, payload) = &want[r];
            let mut got = Vec::new();
            loop {
                let c = read(&mut b, r as u32, got.len() as u32).unwrap();
                assert_eq!((c.at, c.total as usize), (*at, payload.len()));
                got.extend_from_slice(c.bytes());
                if c.bytes().is_empty() || got.len() == payload.len() {
                    break;
                }
            }
            assert_eq!(&got, payload, "record {r}");
        }
        let (last, past) = (want.len() as u32 - 1, want.last().unwrap().1.len() as u32);
        assert_eq!(read(&mut b, last, past).map(|c| c.len), Ok(0));
        assert_eq!(read(&mut b, last, past + 1), Err(ErrorKind::ExportPastEnd));
        assert_eq!(read(&mut b, last + 1, 0), Err(ErrorKind::ExportPastEnd));
        let mut none = Harness::<Small>::without_flash();
        assert_eq!(read(&mut none, 0, 0), Err(ErrorKind::ExportPastEnd));
    });
}

#[test]
fn a_refused_extend_or_hello_leaves_the_device_taking_the_right_one() {
    // A host run again numbers its messages from the start: the right
    // Extend (or Hello) after a refused one can carry the refused one's
    // sequence number, and must be answered for itself, not with the
    // cached refusal.
    on_big_stack(|| {
        let cfg = config(8);
        let mut b = bench::<Small>();
        b.ok(HostMessage::Hello(cfg));
        for i in 0..4 {
            frame_as(&mut b, i, i);
        }
        // A scan in progress: a Hello of another configuration is refused,
        // the right one (the same sequence number) resumes it.
        let refused_seq = b.seq;
        assert_ne!(b.refused(HostMessage::Hello(config(4))), ErrorKind::BadCrc);
        b.seq = refused_seq;
        b.ok(HostMessage::Hello(cfg));
        for i in 4..A_FRAMES {
            frame_as(&mut b, i, i);
        }
        b.ok(HostMessage::Finish);
        let refused_seq = b.seq;
        assert_eq!(
            b.refused(HostMessage::Extend(config(4))),
            ErrorKind::ExtendOtherConfig
        );
        b.seq = refused_seq;
        b.ok(HostMessage::Extend(cfg));
        assert_eq!(b.status().sessions, 2);
        // And a retransmission of the accepted one is still a no-op.
        b.seq = refused_seq;
        b.ok(HostMessage::Extend(cfg));
        assert_eq!(b.status().sessions, 2);
    });
}
