//! What the emulated-board tests share (host/tests/board_qemu.rs, the QEMU board;
//! host/tests/board_rp2040.rs, the Pico under rp2040js): the host replay their exports
//! must equal, and the power cut in the middle of a scan with its resume,
//! written once over a [`Board`] that boots on a flash file and loses power.

use placedb::protocol::Phase;
use placedb::protocol::{degradation, CapacitySlot, DecisionKind, DeviceMessage, HostMessage};
use placedb_host::board::client::{self, Client, Received};
use placedb_host::board::export::{self, Export, ExportOptions};
use placedb_host::board::link::Link;
use placedb_host::board::scan::{self, StreamOptions};
pub use placedb_host::testing::demo;
use placedb_host::testing::{selector, voxel_config};
use std::path::Path;
use std::time::Duration;

/// database.csv and labels.csv of `placedb select --solver online --profile
/// PROFILE`: the host replay of the core with the same profile and
/// configuration.
pub use placedb_host::testing::replay_csv as host_replay;

/// Every record the device holds, with the default export options.
pub fn export_all<L: Link>(client: &mut Client<L>) -> Export {
    export::export(
        client,
        Vec::new(),
        &ExportOptions::default(),
        None,
        &mut |_| Ok(()),
    )
    .unwrap()
}

/// An emulated board whose flash is a file.
pub trait Board {
    type Link: Link;
    /// Its name, in file names and messages.
    const NAME: &'static str;
    /// Its memory profile (the host replay's).
    const PROFILE: &'static str;
    /// How long one reply may take.
    const REPLY: Duration;
    /// Powers the board on with the flash file `flash` (erased if missing),
    /// once it has restored its scan from it: the link, and what the board
    /// said while booting (for messages).
    fn boot(flash: &Path) -> (Client<Self::Link>, String);
    /// Cuts the power at once, and checks the flash file it left.
    fn power_cut(client: Client<Self::Link>, flash: &Path);
}

/// Power cut mid-scan: the board streams 30 frames of the `frames`-frame
/// demo scan (stride 8, window 8) without Finish, begins frame 30, and loses
/// power; booted again on the same flash file it restores every decision it
/// had sent (decisions are durable, and sent, in batches of 16: 30 frames
/// with a window of 8 make one), the host resumes at the first undecided
/// frame, and the final export equals an uninterrupted run's. Returns the
/// board after the resumed scan.
pub fn killed_mid_scan_restores_and_resumes<B: Board>(frames: usize) -> Client<B::Link> {
    let dir =
        std::env::temp_dir().join(format!("placedb-{}-flash-{}", B::NAME, std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let flash = dir.join("flash.bin");
    let _ = std::fs::remove_file(&flash);
    let all = demo(frames);
    let vcfg = voxel_config(8);
    let sel = selector(8);
    let scan = scan::scan_config(&all, &vcfg).unwrap();
    let cfg = scan::device_config(&scan, &sel).unwrap();

    // First power-on: 30 frames without Finish, then half of frame 30, then
    // the cut.
    let (mut client, _) = B::boot(&flash);
    let opts = StreamOptions {
        finish: false,
        ..StreamOptions::default()
    };
    let report = scan::stream(&mut client, &demo(30), &cfg, B::PROFILE, &opts, None)
        .unwrap_or_else(|e| panic!("stream of the first 30 frames failed: {e}"));
    let acknowledged: Vec<(u32, DecisionKind)> = report
        .decisions
        .iter()
        .enumerate()
        .filter_map(|(i, d)| d.map(|d| (i as u32, d)))
        .collect();
    let durable = report.status.capacity(CapacitySlot::Labels).used;
    assert!(report.status.frames_decided > 0 && report.status.frames_decided < 30);
    assert!(durable >= 16 && durable <= report.status.frames_decided);
    assert_eq!(
        acknowledged.len() as u32,
        durable,
        "decisions go out once durable"
    );
    assert!(
        report.status.stored_records > 0,
        "nothing was written to the flash log"
    );
    let (seq, replies) = client
        .request(
            HostMessage::FrameBegin {
                frame: 30,
                timestamp: all.frames[30].timestamp,
                pose: all.frames[30].pose().unwrap(),
            },
            B::REPLY,
        )
        .unwrap();
    assert_eq!(replies, vec![Received::Message(DeviceMessage::Ack { seq })]);
    B::power_cut(client, &flash);

    // Second power-on on the same flash.
    let (mut client, console) = B::boot(&flash);
    let st = client::status(&mut client, B::REPLY).unwrap();
    assert_eq!(st.phase, Phase::Ready, "{console}");
    assert_eq!(st.frames_seen, durable);
    assert_eq!(st.frames_decided, durable);
    assert_ne!(st.degradation & degradation::RESTORED, 0);
    let (_, labels_before) = export_all(&mut client).csv();
    for &(frame, kind) in &acknowledged {
        let class = kind.class(frame).unwrap();
        let label = labels_before.lines().nth(frame as usize + 1).unwrap();
        assert!(
            label.ends_with(&format!(",{class}")),
            "frame {frame} ({kind:?}) came back as {label}"
        );
    }
    let resume = StreamOptions {
        resume: true,
        ..StreamOptions::default()
    };
    let report2 = scan::stream(&mut client, &all, &cfg, B::PROFILE, &resume, None)
        .unwrap_or_else(|e| panic!("the resumed stream failed: {e}"));
    assert_eq!(report2.frames, frames - st.frames_seen as usize);
    assert_eq!(report2.status.phase, Phase::Finished);
    let export = export_all(&mut client);
    let (db_csv, labels_csv) = export.csv();
    let (want_db, want_labels) = host_replay(B::PROFILE, &all, &vcfg, sel);
    assert_eq!(db_csv, want_db);
    assert_eq!(labels_csv, want_labels);
    println!(
        "{} power cut in frame 30 of {frames}: {} decisions acknowledged before the cut, all \
         restored ({} log records); resumed at frame {}; final export identical to an \
         uninterrupted run ({} database frames)",
        B::NAME,
        acknowledged.len(),
        st.stored_records,
        st.frames_seen,
        export.status.database_size
    );
    let _ = std::fs::remove_dir_all(&dir);
    client
}
