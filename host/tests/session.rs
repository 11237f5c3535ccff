//! The device client API (`placedb_host::board::session`): frames pushed from
//! memory reach the device (in-process `local:` device, no hardware) and
//! give the decisions, database and labels of the host replay of the core
//! (`placedb select --solver online`), with and without retransmission;
//! misuse gets a typed error and leaves the scan as it was.

use placedb::protocol::DecisionKind;
use placedb::{Decision, SelectorConfig};
use placedb_host::board::error::DeviceError;
use placedb_host::board::link::Link;
use placedb_host::board::scan::{scan_config, StreamOptions};
use placedb_host::board::session::{DepthFrame, Session};
use placedb_host::testing::{demo, selector, voxel_config};
use placedb_host::{output, replay, Sequence, VoxelConfig};

const PROFILE: &str = "ram256k";

type LocalSession = Session<Box<dyn Link>>;

/// The selector of these tests: a window of 6.
fn sel() -> SelectorConfig {
    selector(6)
}

/// Their stride.
fn vcfg() -> VoxelConfig {
    voxel_config(8)
}

/// Pushes every frame of `seq` from memory; returns the decisions taken
/// along the way and the session.
fn push_all(seq: &Sequence, opts: StreamOptions) -> (LocalSession, Vec<(u32, DecisionKind)>) {
    let scan = scan_config(seq, &vcfg()).unwrap();
    let mut session = Session::open(&format!("local:{PROFILE}"), opts).unwrap();
    session.configure(&scan, &sel()).unwrap();
    let mut seen = Vec::new();
    for (i, f) in seq.frames.iter().enumerate() {
        let depth = seq.depth(i).unwrap().data;
        let index = session
            .push_frame(&DepthFrame {
                timestamp: f.timestamp,
                pose: f.pose().unwrap(),
                intrinsics: scan.intrinsics,
                depth: &depth,
            })
            .unwrap();
        assert_eq!(index as usize, i);
        seen.extend(session.take_decisions());
    }
    session.finish().unwrap();
    seen.extend(session.take_decisions());
    (session, seen)
}

#[test]
fn frames_from_memory_give_the_replay_of_the_core() {
    let seq = demo(30);
    let scan = scan_config(&seq, &vcfg()).unwrap();
    let run = replay::replay(&seq, PROFILE, scan, sel(), 8, None).unwrap();
    for opts in [
        StreamOptions::default(),
        StreamOptions {
            retries: 3,
            ..StreamOptions::default()
        },
    ] {
        let (mut session, seen) = push_all(&seq, opts);
        // Every frame is decided once, as the replay decided it.
        let mut by_frame = vec![None; seq.frames.len()];
        for (frame, kind) in &seen {
            assert!(by_frame[*frame as usize].is_none(), "frame {frame} twice");
            by_frame[*frame as usize] = Some(Decision::from(*kind));
        }
        let want: Vec<_> = run.decisions.iter().copied().map(Some).collect();
        assert_eq!(by_frame, want);
        assert!(session.take_decisions().is_empty());
        let st = session.status().unwrap();
        assert_eq!(st.frames_seen as usize, seq.frames.len());
        assert_eq!(st.database_size as usize, run.database.len());
        let timestamps: Vec<f64> = seq.frames.iter().map(|f| f.timestamp).collect();
        let export = session.export().unwrap();
        assert_eq!(
            export.csv(),
            output::run_csv(&run.database, &timestamps, &run.labels)
        );
    }
}

#[test]
fn misuse_is_a_typed_error_and_changes_nothing() {
    let seq = demo(3);
    let scan = scan_config(&seq, &vcfg()).unwrap();
    let mut session = Session::open(&format!("local:{PROFILE}"), StreamOptions::default()).unwrap();
    let depth = seq.depth(0).unwrap().data;
    let frame = DepthFrame {
        timestamp: 0.0,
        pose: seq.frames[0].pose().unwrap(),
        intrinsics: scan.intrinsics,
        depth: &depth,
    };
    // Before configure.
    assert!(matches!(
        session.push_frame(&frame),
        Err(DeviceError::Input(_))
    ));
    session.configure(&scan, &sel()).unwrap();
    // A buffer of the wrong size, another camera.
    let short = DepthFrame {
        depth: &depth[1..],
        ..frame
    };
    let e = session.push_frame(&short).unwrap_err();
    assert!(e.to_string().contains("depth values"), "{e}");
    let mut other = scan.intrinsics;
    other.fx += 1.0;
    let e = session
        .push_frame(&DepthFrame {
            intrinsics: other,
            ..frame
        })
        .unwrap_err();
    assert!(e.to_string().contains("intrinsics"), "{e}");
    assert_eq!(session.next_frame(), 0);
    assert_eq!(session.status().unwrap().frames_seen, 0);
    // A bad configuration is refused before anything is sent.
    let bad = SelectorConfig { mu: 1.5, ..sel() };
    assert!(session.configure(&scan, &bad).is_err());
    // The scan still works.
    assert_eq!(session.push_frame(&frame).unwrap(), 0);
    assert_eq!(session.status().unwrap().frames_seen, 1);
}

#[test]
fn export_to_writes_the_device_files() {
    let seq = demo(12);
    let (mut session, _) = push_all(&seq, StreamOptions::default());
    let dir = std::env::temp_dir().join(format!("placedb-session-{}", std::process::id()));
    let export = session.export_to(&dir).unwrap();
    let (db, labels) = export.csv();
    assert_eq!(
        std::fs::read_to_string(dir.join("database.csv")).unwrap(),
        db
    );
    assert_eq!(
        std::fs::read_to_string(dir.join("labels.csv")).unwrap(),
        labels
    );
    assert!(dir.join("metrics.json").is_file());
    std::fs::remove_dir_all(&dir).unwrap();
}
