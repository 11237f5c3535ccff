//! Fault injection: frames dropped and corrupted in both directions of the
//! link (`placedb_host::board::link::fault::FaultInjector`, seeded), recovered by
//! retransmission (stop-and-wait, same sequence number; the device answers a
//! repeat from its cache without applying it twice) and by re-requested
//! export batches (checked by count and CRC). The exported database.csv and
//! labels.csv must equal, byte for byte, those of the clean host replay of
//! the core (`placedb select --solver online`).
//!
//! - in-process (`local:` device, no QEMU): 10 % drops and 10 % corruption
//!   each way, several seeds;
//! - the emulated board (QEMU firmware, as host/tests/board_qemu.rs): 5 % drops and
//!   5 % corruption each way, 20 frames of the synthetic scan at stride 8.
//!
//! Run with `--nocapture` to see what was injected and how long recovery took.

use placedb::SelectorConfig;
use placedb_host::board::client::Client;
use placedb_host::board::emulator::qemu::{Qemu, QemuOptions};
use placedb_host::board::export::{self, ExportOptions};
use placedb_host::board::link::fault::{FaultConfig, FaultInjector, FaultStats};
use placedb_host::board::link::{Link, LocalLink};
use placedb_host::board::scan::{self, StreamOptions};
use placedb_host::testing::{demo, qemu_firmware, replay_csv, selector, voxel_config};
use placedb_host::{Sequence, VoxelConfig};
use std::time::{Duration, Instant};

const PROFILE: &str = "ram512k";

/// database.csv and labels.csv of the clean host replay of the core.
fn host_replay(seq: &Sequence) -> (String, String) {
    replay_csv(PROFILE, seq, &vcfg(), sel())
}

/// The stride of these tests.
fn vcfg() -> VoxelConfig {
    voxel_config(8)
}

/// Their selector: a window of 8.
fn sel() -> SelectorConfig {
    selector(8)
}

/// What one faulty run did.
struct Run {
    csv: (String, String),
    stats: FaultStats,
    retransmissions: u64,
    export_retries: usize,
    stream_s: f64,
    export_s: f64,
}

/// Streams `seq` over `client` (faults injected by its link), exports, and
/// returns the files.
fn stream_and_export<L: Link>(
    client: &mut Client<FaultInjector<L>>,
    seq: &Sequence,
    resend_after: Duration,
) -> Run {
    let scan = scan::scan_config(seq, &vcfg()).unwrap();
    let cfg = scan::device_config(&scan, &sel()).unwrap();
    let opts = StreamOptions {
        retries: 40,
        resend_after,
        ..StreamOptions::default()
    };
    let t = Instant::now();
    let report = scan::stream(client, seq, &cfg, PROFILE, &opts, None)
        .unwrap_or_else(|e| panic!("stream failed under faults: {e}"));
    let stream_s = t.elapsed().as_secs_f64();
    assert_eq!(report.status.frames_seen as usize, seq.frames.len());
    let t = Instant::now();
    let export = export::export(
        client,
        Vec::new(),
        &ExportOptions {
            batch: 8,
            retries: 40,
            reply_timeout: resend_after,
        },
        None,
        &mut |_| Ok(()),
    )
    .unwrap_or_else(|e| panic!("export failed under faults: {e}"));
    Run {
        csv: export.csv(),
        stats: client.link().stats(),
        retransmissions: report.retransmissions,
        export_retries: export.retried,
        stream_s,
        export_s: t.elapsed().as_secs_f64(),
    }
}

fn describe(run: &Run) -> String {
    let s = &run.stats;
    format!(
        "host->device {}/{} frames dropped, {} corrupted; device->host {}/{} dropped, {} corrupted; \
         {} retransmissions, {} export batches retried; stream {:.1} s, export {:.1} s",
        s.sent_dropped,
        s.sent,
        s.sent_corrupted,
        s.received_dropped,
        s.received,
        s.received_corrupted,
        run.retransmissions,
        run.export_retries,
        run.stream_s,
        run.export_s
    )
}

fn check(run: &Run, want: &(String, String), what: &str) {
    let s = &run.stats;
    assert!(
        s.sent_dropped > 0 && s.sent_corrupted > 0,
        "{what}: no host->device faults"
    );
    assert!(
        s.received_dropped > 0 && s.received_corrupted > 0,
        "{what}: no device->host faults"
    );
    assert!(run.retransmissions > 0, "{what}: nothing was retransmitted");
    assert_eq!(run.csv.0, want.0, "{what}: database.csv differs");
    assert_eq!(run.csv.1, want.1, "{what}: labels.csv differs");
}

#[test]
fn the_local_device_recovers_from_heavy_faults() {
    let started = Instant::now();
    let seq = demo(30);
    let want = host_replay(&seq);
    for seed in [1, 2, 3, 4] {
        let link = LocalLink::start(PROFILE).unwrap();
        let mut client = Client::new(FaultInjector::new(link, FaultConfig::new(0.1, 0.1, seed)));
        let run = stream_and_export(&mut client, &seq, Duration::from_millis(40));
        check(&run, &want, &format!("local, seed {seed}"));
        println!(
            "local, 10 % drops + 10 % corruption, seed {seed}: identical to the clean replay; {}",
            describe(&run)
        );
    }
    println!("local fault runs: {:.1} s", started.elapsed().as_secs_f64());
}

#[test]
fn faults_in_one_direction_only_are_recovered_too() {
    let seq = demo(12);
    let want = host_replay(&seq);
    for (to_device, to_host) in [(true, false), (false, true)] {
        let cfg = FaultConfig {
            host_to_device: to_device,
            device_to_host: to_host,
            ..FaultConfig::new(0.15, 0.15, 9)
        };
        let mut client = Client::new(FaultInjector::new(LocalLink::start(PROFILE).unwrap(), cfg));
        let run = stream_and_export(&mut client, &seq, Duration::from_millis(40));
        assert_eq!(
            run.csv, want,
            "host->device {to_device}, device->host {to_host}"
        );
        assert_eq!(run.stats.sent_dropped > 0, to_device);
        assert_eq!(run.stats.received_dropped > 0, to_host);
    }
}

#[test]
fn the_emulated_board_recovers_from_5_percent_faults() {
    let started = Instant::now();
    let firmware = qemu_firmware();
    let options = QemuOptions {
        extra_args: vec!["-icount".into(), "shift=0".into()],
        deadline: Duration::from_secs(150),
        ..QemuOptions::default()
    };
    let qemu = Qemu::start_with(&firmware, options).unwrap_or_else(|e| {
        panic!("cannot start qemu-system-arm (apt-get install qemu-system-arm): {e}")
    });
    assert!(
        qemu.wait_console("calibration", Duration::from_secs(10)),
        "no boot lines; console: {}",
        qemu.console()
    );
    let seq = demo(20);
    let want = host_replay(&seq);
    let mut client = Client::new(FaultInjector::new(qemu, FaultConfig::new(0.05, 0.05, 5)));
    let run = stream_and_export(&mut client, &seq, Duration::from_millis(1000));
    check(&run, &want, "QEMU");
    let qemu = client.into_link().into_inner();
    assert!(
        qemu.try_wait().unwrap().is_none(),
        "firmware exited: {}",
        qemu.console()
    );
    println!(
        "QEMU board, 5 % drops + 5 % corruption each way, {} frames: identical to the clean replay; {}; total {:.1} s",
        seq.frames.len(),
        describe(&run),
        started.elapsed().as_secs_f64()
    );
}

#[test]
fn a_lost_frame_costs_a_measured_round_trip_not_the_whole_resend_wait() {
    // The user's 2 s is the ceiling; the in-process link answers in well
    // under a millisecond, so after a few messages a lost reply is noticed
    // at the floor's 20 ms, not after 2 s (a 50-frame scan at 5 % faults
    // took minutes with a fixed wait).
    let seq = demo(50);
    let want = host_replay(&seq);
    let link = LocalLink::start(PROFILE).unwrap();
    let mut client = Client::new(FaultInjector::new(link, FaultConfig::new(0.05, 0.05, 11)));
    let ceiling = Duration::from_secs(2);
    assert_eq!(client.first_wait("DepthRows", ceiling), ceiling);
    let run = stream_and_export(&mut client, &seq, ceiling);
    check(&run, &want, "local, 2 s ceiling");
    println!(
        "local, 5 % drops + 5 % corruption, 50 frames, 2 s ceiling: {}",
        describe(&run)
    );
    for kind in ["FrameBegin", "DepthRows", "FrameEnd", "ExportRecord"] {
        let wait = client.first_wait(kind, ceiling);
        assert!(
            wait < Duration::from_millis(500),
            "{kind}: first wait {wait:?} of a {ceiling:?} ceiling"
        );
    }
}
