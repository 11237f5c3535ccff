//! What a user of a board does by accident, on the core's device in-process
//! (one client across commands, as a board outlives them): a new scan on a
//! board holding one is refused naming what it holds (`--new-scan`
//! replaces it), `--resume` on an empty board and with another sequence is
//! refused naming the first frame that differs, and a frame a killed host
//! left open is cleared by `--resume`, which then decides as an
//! uninterrupted scan. `host/tests/cli_board.rs` runs the first case on the
//! real binary and the emulated board.

use placedb::protocol::{HostMessage, Phase};
use placedb_host::board::client::{ask_status, Client, Wait};
use placedb_host::board::export::export_to;
use placedb_host::board::link::{Link, LocalLink};
use placedb_host::board::scan::{stream, stream_config, StreamOptions};
use placedb_host::sequence::Sequence;
use placedb_host::testing::{demo, selector, voxel_config};
use std::path::PathBuf;

const PROFILE: &str = "ram512k";

fn board() -> Client<LocalLink> {
    Client::new(LocalLink::start(PROFILE).unwrap())
}

fn config(seq: &Sequence) -> placedb::protocol::Config {
    stream_config(seq, &voxel_config(8), selector(4), PROFILE)
        .unwrap()
        .2
}

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("placedb-lifecycle-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn opts(f: impl FnOnce(&mut StreamOptions)) -> StreamOptions {
    let mut o = StreamOptions::default();
    f(&mut o);
    o
}

fn status_of<L: Link>(client: &mut Client<L>) -> placedb::protocol::Status {
    let wait = Wait::Once(std::time::Duration::from_secs(5));
    ask_status(client, wait).unwrap().0
}

/// The export of `seq` streamed whole to a fresh board: what a resumed
/// scan must come to (exported through temp dir `name`, one per test:
/// the tests run at once in one process).
fn uninterrupted(seq: &Sequence, cfg: &placedb::protocol::Config, name: &str) -> (String, String) {
    let mut whole = board();
    stream(
        &mut whole,
        seq,
        cfg,
        PROFILE,
        &StreamOptions::default(),
        None,
    )
    .unwrap();
    exported(&mut whole, name)
}

/// The database and labels of the device's export.
fn exported<L: Link>(client: &mut Client<L>, name: &str) -> (String, String) {
    let dir = temp(name);
    export_to(client, &dir, None, true).unwrap();
    let read = |f: &str| std::fs::read_to_string(dir.join(f)).unwrap();
    let got = (read("database.csv"), read("labels.csv"));
    std::fs::remove_dir_all(&dir).unwrap();
    got
}

#[test]
fn a_board_holding_a_scan_refuses_a_new_one_naming_it_until_told_to_replace_it() {
    let seq = demo(30);
    let cfg = config(&seq);
    let mut client = board();
    // An empty board takes a scan; a finished one is kept.
    stream(
        &mut client,
        &seq,
        &cfg,
        PROFILE,
        &StreamOptions::default(),
        None,
    )
    .unwrap();
    let before = exported(&mut client, "held-before");
    let status = |c: &mut Client<LocalLink>| {
        let st = status_of(c);
        (st.phase, st.frames_seen, st.database_size)
    };
    let held = status(&mut client);
    let other = demo(12);
    let err = stream(
        &mut client,
        &other,
        &cfg,
        PROFILE,
        &StreamOptions::default(),
        None,
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains(&format!(
            "the board holds a finished scan of 30 frames (30 decided), {} database frame",
            held.2
        )) && err.contains("--new-scan"),
        "{err}"
    );
    assert_eq!(status(&mut client), held, "the refusal changed the board");
    assert_eq!(exported(&mut client, "held-after"), before);
    // An unfinished scan is held too.
    let replace = opts(|o| {
        o.new_scan = true;
        o.finish = false;
    });
    stream(&mut client, &other, &cfg, PROFILE, &replace, None).unwrap();
    let err = stream(
        &mut client,
        &seq,
        &cfg,
        PROFILE,
        &StreamOptions::default(),
        None,
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("the board holds an unfinished scan of 12 frames"),
        "{err}"
    );
    // --new-scan replaces it: the scan of `seq` alone, as on a fresh board.
    let again = opts(|o| o.new_scan = true);
    stream(&mut client, &seq, &cfg, PROFILE, &again, None).unwrap();
    assert_eq!(exported(&mut client, "replaced"), before);
}

#[test]
fn resume_refuses_an_empty_board_and_another_sequence_naming_the_frame() {
    let seq = demo(40);
    let cfg = config(&seq);
    let resume = opts(|o| o.resume = true);
    let mut client = board();
    let err = stream(&mut client, &seq, &cfg, PROFILE, &resume, None)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("--resume: the board holds no scan to resume"),
        "{err}"
    );
    // 30 frames of the scan, left open.
    let part = demo(30);
    stream(
        &mut client,
        &part,
        &cfg,
        PROFILE,
        &opts(|o| o.finish = false),
        None,
    )
    .unwrap();
    // Another recording: the same frames but retimed from frame 9 on.
    let mut other = demo(40);
    for f in &mut other.frames[9..] {
        f.timestamp += 0.5;
    }
    let err = stream(&mut client, &other, &cfg, PROFILE, &resume, None)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("--resume: frame 9 of the sequence has timestamp"),
        "{err}"
    );
    // Nothing changed: the right sequence resumes to the uninterrupted scan.
    stream(&mut client, &seq, &cfg, PROFILE, &resume, None).unwrap();
    assert_eq!(
        exported(&mut client, "resumed"),
        uninterrupted(&seq, &cfg, "resumed-whole")
    );
}

#[test]
fn resume_clears_a_frame_a_killed_host_left_open_and_goes_on() {
    let seq = demo(30);
    let cfg = config(&seq);
    let mut client = board();
    let part = demo(20);
    stream(
        &mut client,
        &part,
        &cfg,
        PROFILE,
        &opts(|o| o.finish = false),
        None,
    )
    .unwrap();
    // The host is killed after opening frame 20.
    let f = &seq.frames[20];
    client
        .send(HostMessage::FrameBegin {
            frame: 20,
            timestamp: f.timestamp,
            pose: f.pose().unwrap(),
        })
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(50));
    assert_eq!(status_of(&mut client).phase, Phase::InFrame);
    let resume = opts(|o| o.resume = true);
    stream(&mut client, &seq, &cfg, PROFILE, &resume, None).unwrap();
    assert_eq!(
        exported(&mut client, "cleared"),
        uninterrupted(&seq, &cfg, "uninterrupted")
    );
}

/// A link that fails (the board unplugged) once `left` replies went through.
struct Cut {
    inner: LocalLink,
    left: usize,
}

impl Link for Cut {
    fn send(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.inner.send(bytes)
    }

    fn recv(&mut self, timeout: std::time::Duration) -> std::io::Result<Vec<u8>> {
        if self.left == 0 {
            return Err(std::io::ErrorKind::ConnectionReset.into());
        }
        self.left -= 1;
        self.inner.recv(timeout)
    }
}

/// An interrupted export names the `--from N` to go on with, N the checked
/// records it saved, and that export goes on to the whole one.
#[test]
fn an_interrupted_export_names_its_from() {
    use placedb_host::board::export::{export_to_with, read_partial, ExportOptions};
    let seq = demo(60);
    let cfg = config(&seq);
    let link = Cut {
        inner: LocalLink::start(PROFILE).unwrap(),
        left: usize::MAX,
    };
    let mut client = Client::new(link);
    stream(
        &mut client,
        &seq,
        &cfg,
        PROFILE,
        &StreamOptions::default(),
        None,
    )
    .unwrap();
    let dir = temp("interrupted");
    let small = ExportOptions {
        batch: 8,
        ..ExportOptions::default()
    };
    client.link().left = 40;
    let err = export_to_with(&mut client, &dir, None, true, &small, &[], None)
        .unwrap_err()
        .to_string();
    let (_, saved) = read_partial(&dir).unwrap();
    assert!(saved.len() >= 8, "{} saved: {err}", saved.len());
    let from = format!(
        "resume with --from {n} (the {n} checked records",
        n = saved.len()
    );
    assert!(err.contains(&from), "{err}");
    client.link().left = usize::MAX;
    let from = Some(saved.len() as u32);
    let resumed = export_to_with(&mut client, &dir, from, true, &small, &[], None).unwrap();
    let whole = export_to_with(&mut client, &temp("whole"), None, true, &small, &[], None).unwrap();
    assert_eq!(resumed.records, whole.records);
    std::fs::remove_dir_all(&dir).unwrap();
    std::fs::remove_dir_all(temp("whole")).ok();
}
