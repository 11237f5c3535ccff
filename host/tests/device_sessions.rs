//! A second session on a device (`HostMessage::Extend`, `placedb stream
//! --extend`) under power cuts and a full flash, on the host's simulated
//! NOR flash (`placedb::persist::sim::SimFlash`):
//!
//! - A power cut at every erase and write step of the second session (the
//!   session boundary's write included), torn before, half way through or
//!   after it: the device reboots, restores both sessions (every final
//!   decision the host received, of either session, is in the restored
//!   export with its class), the host resumes (Extend again: a no-op on the
//!   session in progress, a new boundary if the cut came before the first
//!   one was durable; then the frames from `frames_seen`, Finish), and the
//!   export is byte-identical to the uninterrupted extended run's. The
//!   counts are printed with `--nocapture`.
//! - A second session that fills the flash ends cleanly, as a full log does
//!   today: FrameEnd refused `StorageFull` with the frame open, FrameAbort,
//!   Finish; every frame of both sessions up to it is labelled, with the
//!   decisions a device with room made; a reboot restores the same.
//! - An Extend the log has no room for (a boundary and a Finish after it)
//!   is refused `StorageFull`, changing nothing.
//!
//! No sleeps, no clocks.

use placedb::device::harness::{on_big_stack, AnyDevice, Harness};
use placedb::device::{Device, Device512K};
use placedb::persist::sim::Tear;
use placedb::protocol::{
    depth_rows_per_message, CapacitySlot, Config, DecisionKind, DepthRows, DeviceMessage,
    ErrorKind, ExportRecord, HostMessage, Phase, RecordKind,
};
use placedb::{DepthRange, Intrinsics, Pose, ScanConfig, SelectorConfig, VoxelGrid};
use placedb_host::frame_rows::{row_chunks, RowChunk};
use placedb_host::synth::{self, SynthConfig};
use placedb_host::{board::scan, VoxelConfig};
use std::collections::BTreeMap;

/// The device of the power cuts: window 8, sketches of 16 hashes, 64
/// database frames, all resident (as host/tests/device_power_cut.rs's small device).
type Small = Device<4096, 16384, 64, 8, 16, 512>;
const SECTORS: usize = 64;
const TEARS: [Tear; 3] = [Tear::Before, Tear::Half, Tear::After];

/// Session A: frames 0..A of the route; session B: route frames
/// `B_FROM..B_FROM + B` (half of them over A's ground) as frames A.. .
const A: u32 = 50;
const B: u32 = 60;
const B_FROM: u32 = 25;

/// One frame as the host sends it.
struct Frame {
    timestamp: f64,
    pose: Pose,
    rows: Vec<RowChunk>,
}

/// The demo route walked in 150 frames at stride 8, window 8, mu 0.3.
fn route() -> (Config, Vec<Frame>) {
    let seq = synth::sequence(&SynthConfig {
        frames: 150,
        ..SynthConfig::demo()
    });
    let vcfg = VoxelConfig {
        stride: 8,
        ..VoxelConfig::default()
    };
    let scan = scan::scan_config(&seq, &vcfg).unwrap();
    let sel = SelectorConfig {
        mu: 0.3,
        window: 8,
        sketch_margin: 0.05,
    };
    let cfg = scan::device_config(&scan, &sel).unwrap();
    let per_msg = usize::from(depth_rows_per_message(cfg.width_sent()));
    let frames = (0..seq.frames.len())
        .map(|i| {
            let img = seq.depth(i).unwrap();
            let (w, values) = placedb_host::frame_rows::sampled_rows(&img, cfg.stride);
            Frame {
                timestamp: seq.frames[i].timestamp,
                pose: seq.frames[i].pose().unwrap(),
                rows: row_chunks(w, &values, per_msg).collect(),
            }
        })
        .collect();
    (cfg, frames)
}

/// The route frame that frame `g` of the extended scan shows.
fn content(g: u32) -> usize {
    if g < A {
        g as usize
    } else {
        (B_FROM + g - A) as usize
    }
}

/// What the host received: final decisions by frame.
type Finals = BTreeMap<u32, DecisionKind>;

/// Sends `msg`; `false` when the device went silent (its power went).
fn step(h: &mut Harness<Small>, msg: HostMessage<'_>, finals: &mut Finals) -> bool {
    let replies = h.send(msg);
    for r in &replies {
        if let DeviceMessage::Decision { frame, kind } = *r {
            if kind != DecisionKind::Pending {
                finals.insert(frame, kind);
            }
        }
    }
    if !h.hears() {
        return false;
    }
    assert_eq!(
        replies.last(),
        Some(&DeviceMessage::Ack { seq: h.seq }),
        "{msg:?} not acknowledged"
    );
    true
}

/// Streams frame `g` (the route's `content(g)`); `false` when the power went.
fn send_frame(h: &mut Harness<Small>, frames: &[Frame], g: u32, finals: &mut Finals) -> bool {
    let f = &frames[content(g)];
    let begin = HostMessage::FrameBegin {
        frame: g,
        timestamp: f.timestamp,
        pose: f.pose,
    };
    step(h, begin, finals)
        && f.rows.iter().all(|r| step(h, r.message(g), finals))
        && step(h, HostMessage::FrameEnd { frame: g }, finals)
}

/// Session B from the device's `frames_seen` on, then Finish; `false` when
/// the power went. Extend first unless `extended`.
fn session_b(h: &mut Harness<Small>, cfg: Config, frames: &[Frame], finals: &mut Finals) -> bool {
    if !step(h, HostMessage::Extend(cfg), finals) {
        return false;
    }
    let from = h.status().frames_seen;
    (from..A + B).all(|g| send_frame(h, frames, g, finals)) && step(h, HostMessage::Finish, finals)
}

/// The labels (frame, class) of an export.
fn classes(export: &[ExportRecord]) -> BTreeMap<u32, u32> {
    export
        .iter()
        .filter_map(|r| match r.kind {
            RecordKind::Label { class } => Some((r.frame, class)),
            _ => None,
        })
        .collect()
}

#[test]
fn a_power_cut_anywhere_in_the_second_session_restores_both() {
    on_big_stack(|| {
        let (cfg, frames) = route();
        // The uninterrupted extended run.
        let mut whole = Harness::<Small>::new(SECTORS);
        let mut finals = Finals::new();
        assert!(step(&mut whole, HostMessage::Hello(cfg), &mut finals));
        assert!((0..A).all(|g| send_frame(&mut whole, &frames, g, &mut finals)));
        assert!(step(&mut whole, HostMessage::Finish, &mut finals));
        let b_starts = whole.flash().steps();
        assert!(session_b(&mut whole, cfg, &frames, &mut finals));
        let b_ends = whole.flash().steps();
        let want = whole.export();
        let st = whole.status();
        assert_eq!((st.sessions, st.frames_seen), (2, A + B));
        assert!(st.database_size as usize > classes(&want).len() / 10);
        let mut cuts = 0;
        for k in b_starts..b_ends {
            for tear in TEARS {
                let ctx = format!("cut at step {k} of {b_starts}..{b_ends} ({tear:?})");
                let mut h = Harness::<Small>::new(SECTORS);
                h.silent_while = Some(h.flash().power());
                let mut seen = Finals::new();
                assert!(step(&mut h, HostMessage::Hello(cfg), &mut seen));
                assert!((0..A).all(|g| send_frame(&mut h, &frames, g, &mut seen)));
                assert!(step(&mut h, HostMessage::Finish, &mut seen));
                h.flash().cut_at(k, tear);
                assert!(!session_b(&mut h, cfg, &frames, &mut seen), "{ctx}: no cut");
                cuts += 1;
                let (mut again, restored) = Harness::<Small>::boot(h.into_flash());
                assert!(restored.is_ok(), "{ctx}: {restored:?}");
                let st = again.status();
                let restored = classes(&again.export());
                for (frame, kind) in &seen {
                    assert_eq!(
                        restored.get(frame).copied(),
                        kind.class(*frame),
                        "{ctx}: frame {frame} received {kind:?}"
                    );
                }
                assert!(st.sessions == 2 || st.phase == Phase::Finished, "{ctx}");
                assert!(restored.len() as u32 >= A, "{ctx}: session A lost");
                let complete = st.sessions == 2 && st.phase == Phase::Finished;
                if !complete {
                    let mut more = Finals::new();
                    assert!(session_b(&mut again, cfg, &frames, &mut more), "{ctx}");
                }
                assert_eq!(again.export(), want, "{ctx}: the resumed export differs");
            }
        }
        println!(
            "second session: {} flash steps, {cuts} cuts, every one restored both \
             sessions and resumed to the uninterrupted export",
            b_ends - b_starts
        );
    });
}

// ------------------------------------------------------------ a full flash

/// One row of 16 pixels on a wall 3.05 m ahead (16 voxels), places 10 m
/// apart: every frame is a new place (host/tests/replay_equals_device.rs).
fn wall_config() -> Config {
    let scan = ScanConfig {
        intrinsics: Intrinsics {
            width: 16,
            height: 1,
            fx: 12.2,
            fy: 12.2,
            cx: 7.5,
            cy: 0.5,
        },
        depth_scale: 1000.0,
        range: DepthRange::default(),
        stride: 1,
        grid: VoxelGrid {
            voxel_size: 0.1,
            origin: [0.0; 3],
        },
    };
    let sel = SelectorConfig {
        mu: 0.5,
        window: 1,
        sketch_margin: 0.05,
    };
    Config::new(&scan, &sel)
}

/// Streams place `g` as frame `g`: the FrameEnd's replies.
fn place<D: AnyDevice>(h: &mut Harness<D>, g: u32) -> Vec<DeviceMessage<'static>> {
    let row: Vec<u8> = [3050u16; 16].iter().flat_map(|d| d.to_le_bytes()).collect();
    h.ok(HostMessage::FrameBegin {
        frame: g,
        timestamp: f64::from(g),
        pose: Pose {
            translation: [0.0, 10.0 * g as f32, 0.0],
            rotation: [0.0, 0.0, 0.0, 1.0],
        },
    });
    h.ok(HostMessage::DepthRows(DepthRows {
        frame: g,
        first_row: 0,
        row_count: 1,
        data: &row,
    }));
    h.send(HostMessage::FrameEnd { frame: g })
}

fn refused_full(replies: &[DeviceMessage<'_>]) -> bool {
    matches!(
        replies.last(),
        Some(DeviceMessage::Error {
            kind: ErrorKind::StorageFull,
            ..
        })
    )
}

#[test]
fn a_second_session_that_fills_the_flash_ends_cleanly() {
    on_big_stack(|| {
        let cfg = wall_config();
        const FIRST: u32 = 150;
        // 24 sectors hold ~350 places (a database frame, its keys and its
        // label each): session A fits, session B does not.
        let mut h = Harness::<Device512K>::new(24);
        // The same scan on a flash with room for all of it.
        let mut roomy = Harness::<Device512K>::new(256);
        for d in [&mut h, &mut roomy] {
            d.ok(HostMessage::Hello(cfg));
            for g in 0..FIRST {
                assert!(!refused_full(&place(d, g)), "session A fits");
            }
            d.ok(HostMessage::Finish);
            d.ok(HostMessage::Extend(cfg));
        }
        let mut g = FIRST;
        loop {
            let replies = place(&mut h, g);
            if refused_full(&replies) {
                break;
            }
            assert!(g < 5000, "the flash never filled");
            assert!(!refused_full(&place(&mut roomy, g)));
            g += 1;
        }
        // The frame stays open: FrameAbort, Finish, as a full log does.
        assert_eq!(h.status().phase, Phase::InFrame);
        h.ok(HostMessage::FrameAbort { frame: g });
        h.ok(HostMessage::Finish);
        roomy.ok(HostMessage::Finish);
        let st = h.status();
        assert_eq!(
            (st.phase, st.frames_seen, st.sessions),
            (Phase::Finished, g, 2)
        );
        assert!(g > FIRST + 50, "session B scanned {} frames", g - FIRST);
        let export = h.export();
        assert_eq!(
            export,
            roomy.export(),
            "the decisions of a device with room"
        );
        assert_eq!(classes(&export).len() as u32, g, "every frame labelled");
        let (mut again, restored) = Harness::<Device512K>::boot(h.into_flash());
        assert!(restored.is_ok(), "{restored:?}");
        assert_eq!(again.export(), export);
        println!(
            "full flash: session A {FIRST} frames, session B {} frames until StorageFull",
            g - FIRST
        );
    });
}

#[test]
fn an_extend_the_flash_has_no_room_for_is_refused_and_changes_nothing() {
    on_big_stack(|| {
        let cfg = wall_config();
        // The smallest log (2 sectors: one of records): no frame fits,
        // a Finish does, and a session boundary with room for a Finish
        // after it fits a few times. Sessions of no frame until it does not.
        let mut h = Harness::<Small>::new(2);
        h.ok(HostMessage::Hello(cfg));
        let mut refused = None;
        for _ in 0..placedb::protocol::MAX_SESSIONS {
            let frame = h.status().frames_seen;
            assert_eq!(frame, 0, "no frame fits");
            assert!(refused_full(&place(&mut h, frame)));
            h.ok(HostMessage::FrameAbort { frame });
            h.ok(HostMessage::Finish);
            let (before, records, export) =
                (h.status(), h.log.as_ref().unwrap().records(), h.export());
            match h.send(HostMessage::Extend(cfg)).as_slice() {
                [DeviceMessage::Error {
                    kind: ErrorKind::StorageFull,
                    ..
                }] => {
                    let mut after = h.status();
                    assert_eq!(after.refused, before.refused + 1);
                    (after.refused, after.seq) = (before.refused, before.seq);
                    // The one thing that moves: the largest frame received.
                    let rx = CapacitySlot::RxFrame as usize;
                    after.capacities[rx] = before.capacities[rx];
                    assert_eq!(after, before, "a refused Extend changed the status");
                    assert_eq!(h.log.as_ref().unwrap().records(), records);
                    assert_eq!(h.export(), export);
                    refused = Some(before.sessions);
                    break;
                }
                [DeviceMessage::Ack { .. }] => {}
                other => panic!("Extend on a full log: {other:?}"),
            }
        }
        let sessions = refused.expect("an Extend refused for a full log");
        let (mut again, restored) = Harness::<Small>::boot(h.into_flash());
        assert!(restored.is_ok(), "{restored:?}");
        let st = again.status();
        assert_eq!((st.phase, st.sessions), (Phase::Finished, sessions));
        println!("a 2-sector log: {sessions} sessions of no frame, then Extend refused");
    });
}
