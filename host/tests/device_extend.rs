//! `placedb stream SEQ_B --port P --extend` on a device that holds the
//! finished scan of SEQ_A: the device's export (database.csv and labels.csv
//! with the session columns, and the extension file rebuilt from its flash
//! log) is byte-identical to the host's `placedb select SEQ_B --extend
//! OUT_A --solver online` with the same profile, where OUT_A is `placedb
//! select SEQ_A --solver online`: on the in-process device (`local:`) and
//! on the emulated Cortex-M4F (QEMU, the firmware of
//! boards/qemu-mps2-an386). The sessions are parts of the 7-Scenes sample
//! (250 frames each on `local:`, 50 on the emulated board), each a sequence
//! directory of its own (links to the sample's files in a temp dir).
//!
//! The QEMU test needs `qemu-system-arm` and builds the firmware (as
//! host/tests/board_qemu.rs does).

use placedb::SelectorConfig;
use placedb_host::board::client::Client;
use placedb_host::board::emulator::qemu::Qemu;
use placedb_host::board::emulator::qemu::QemuOptions;
use placedb_host::board::export::export_to;
use placedb_host::board::link::{Link, LocalLink};
use placedb_host::board::scan::{stream, stream_config, StreamOptions};
use placedb_host::read::{self, ReadOptions};
use placedb_host::sessions::extension::{self, Extension};
use placedb_host::testing::qemu_firmware;
use placedb_host::VoxelConfig;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

const SEVEN_SCENES: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../shared/data/7scenes-1000"
);
const PROFILE: &str = "ram512k";
const STRIDE: u16 = 8;
const MU: f32 = 0.3;
const WINDOW: u16 = 32;

/// Voxel edge and IoU threshold of a run.
#[derive(Clone, Copy)]
struct Setting {
    voxel: f32,
    mu: f32,
}

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!(
        "placedb-device-extend-{}-{name}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// 7-Scenes frames `range` as a sequence directory of their own, with the
/// sample's camera.
fn seven_scenes(dir: &Path, range: std::ops::Range<usize>) -> PathBuf {
    seven_scenes_as(dir, range, 585.0)
}

/// [`seven_scenes`] as if taken by a camera of focal length `f` pixels
/// (the sample's is 585): another camera for a later session.
fn seven_scenes_as(dir: &Path, range: std::ops::Range<usize>, f: f64) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let src = Path::new(SEVEN_SCENES);
    std::fs::write(
        dir.join("camera-intrinsics.txt"),
        format!("{f} 0 320\n0 {f} 240\n0 0 1\n"),
    )
    .unwrap();
    for i in range {
        for ext in ["depth.png", "pose.txt"] {
            let name = format!("frame-{i:06}.{ext}");
            std::os::unix::fs::symlink(src.join(&name), dir.join(&name)).unwrap();
        }
    }
    dir.to_path_buf()
}

/// `placedb select SEQ --solver online` with this file's configuration,
/// extending `extend` if given, into `out`.
fn select(seq: &Path, extend: Option<&Path>, out: &Path, set: Setting) {
    let (stride, window) = (STRIDE.to_string(), WINDOW.to_string());
    let (voxel, mu) = (set.voxel.to_string(), set.mu.to_string());
    let mut args = vec![
        "select",
        seq.to_str().unwrap(),
        "--voxel",
        &voxel,
        "--solver",
        "online",
        "--profile",
        PROFILE,
        "--stride",
        &stride,
        "--mu",
        &mu,
        "--window",
        &window,
        "-o",
        out.to_str().unwrap(),
    ];
    if let Some(e) = extend {
        args.extend(["--extend", e.to_str().unwrap()]);
    }
    let run = Command::new(env!("CARGO_BIN_EXE_placedb"))
        .args(&args)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "placedb {args:?}: {}",
        String::from_utf8_lossy(&run.stderr)
    );
}

/// What a device's extension file can hold of a host's: the host's
/// measurements, its voxel sets at stride 1 and of every frame, and the
/// keys of the frames its store kept by sketch only are not on a device.
fn device_view(mut ext: Extension) -> Extension {
    ext.all_voxels = None;
    for f in &mut ext.frames {
        f.measured = None;
    }
    for d in &mut ext.database {
        d.eval_keys = None;
        if !d.keyed {
            d.keys = None;
        }
    }
    ext
}

type Frames = std::ops::Range<usize>;

/// Streams session A (frames `parts.0` of the sample), then session B
/// (`parts.1`, as taken by a camera of focal length `focal_b`) with
/// `--extend`, to the device behind `client`, exports, and compares with
/// `select --extend`; then a third session (`parts.2`) on either export.
fn extended_scan_equals_select_extend<L: Link>(
    client: &mut Client<L>,
    name: &str,
    parts: (Frames, Frames, Frames),
    focal_b: f64,
    set: Setting,
) {
    let dir = temp(name);
    let (n_a, n_b) = (parts.0.len() as u32, parts.1.len() as u32);
    let a = seven_scenes(&dir.join("a"), parts.0);
    let b = seven_scenes_as(&dir.join("b"), parts.1, focal_b);
    let (out_a, out_ab, out_dev) = (dir.join("out-a"), dir.join("out-ab"), dir.join("dev"));
    select(&a, None, &out_a, set);
    select(&b, Some(&out_a), &out_ab, set);
    let vcfg = VoxelConfig {
        stride: STRIDE,
        voxel: set.voxel,
        ..VoxelConfig::default()
    };
    let sel = SelectorConfig {
        mu: set.mu,
        window: WINDOW,
        sketch_margin: 0.05,
    };
    let opts = ReadOptions::default();
    let (seq_a, seq_b) = (
        read::open(&a, &opts).unwrap(),
        read::open(&b, &opts).unwrap(),
    );
    let (_, _, cfg) = stream_config(&seq_a, &vcfg, sel, PROFILE).unwrap();
    let first = StreamOptions::default();
    let report_a = stream(client, &seq_a, &cfg, PROFILE, &first, None).unwrap();
    assert_eq!(report_a.status.sessions, 1);
    let (_, _, cfg_b) = stream_config(&seq_b, &vcfg, sel, PROFILE).unwrap();
    assert_eq!(cfg_b.intrinsics.fx, focal_b as f32);
    let extend = StreamOptions {
        extend: true,
        ..StreamOptions::default()
    };
    let report = stream(client, &seq_b, &cfg_b, PROFILE, &extend, None).unwrap();
    assert_eq!(report.first_index, n_a);
    assert_eq!(report.frames as u32, n_b);
    let st = report.status;
    assert_eq!(
        (st.sessions, st.session_first, st.frames_seen),
        (2, n_a, n_a + n_b)
    );
    assert!(st.database_size > report_a.status.database_size);
    export_to(client, &out_dev, None, true).unwrap();
    for file in ["database.csv", "labels.csv"] {
        let (dev, host) = (out_dev.join(file), out_ab.join(file));
        let (dev, host) = (
            std::fs::read_to_string(dev).unwrap(),
            std::fs::read_to_string(host).unwrap(),
        );
        assert!(dev.lines().next().unwrap().contains(",session"), "{file}");
        assert_eq!(
            dev, host,
            "{name}: {file} of the device and of select --extend"
        );
    }
    let dev = extension::read(&out_dev.join(extension::FILE_NAME)).unwrap();
    let host = extension::read(&out_ab.join(extension::FILE_NAME)).unwrap();
    assert_eq!(dev.sessions, vec![n_a, n_b]);
    assert_eq!(dev, device_view(host), "{name}: extension.bin");
    // The device's file extends on the host as the host's own does.
    let c = seven_scenes(&dir.join("c"), parts.2);
    let (from_dev, from_host) = (dir.join("c-dev"), dir.join("c-host"));
    select(&c, Some(&out_dev), &from_dev, set);
    select(&c, Some(&out_ab), &from_host, set);
    for file in ["database.csv", "labels.csv"] {
        let dev = std::fs::read_to_string(from_dev.join(file)).unwrap();
        let host = std::fs::read_to_string(from_host.join(file)).unwrap();
        assert_eq!(dev, host, "{name}: a third session on the device's {file}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_in_process_device_extends_as_select_extend() {
    let mut client = Client::new(LocalLink::start(PROFILE).unwrap());
    let set = Setting { voxel: 0.3, mu: MU };
    extended_scan_equals_select_extend(
        &mut client,
        "local",
        (0..250, 250..500, 500..600),
        585.0,
        set,
    );
}

/// A later session from another camera (a longer lens here) is taken by
/// the device as by `select --extend`, and decided alike.
#[test]
fn the_in_process_device_extends_with_another_camera_as_select_extend() {
    let mut client = Client::new(LocalLink::start(PROFILE).unwrap());
    let set = Setting { voxel: 0.3, mu: MU };
    extended_scan_equals_select_extend(
        &mut client,
        "local-camera",
        (0..250, 250..500, 500..600),
        700.0,
        set,
    );
}

#[test]
fn the_emulated_board_extends_as_select_extend() {
    let options = QemuOptions {
        deadline: Duration::from_secs(900),
        ..QemuOptions::default()
    };
    let qemu = Qemu::start_with(&qemu_firmware(), options).unwrap_or_else(|e| {
        panic!("cannot start qemu-system-arm (apt-get install qemu-system-arm): {e}")
    });
    assert!(
        qemu.wait_console("boot", Duration::from_secs(10)),
        "no boot line; console: {}",
        qemu.console()
    );
    let mut client = Client::new(qemu);
    // The emulated UART moves ~1 frame a second at stride 8: fewer frames,
    // from parts of the sample far apart, with 0.1 m voxels and mu 0.7 so
    // that B adds database frames (0.3 m and 0.3 see the room from one).
    let set = Setting {
        voxel: 0.1,
        mu: 0.7,
    };
    extended_scan_equals_select_extend(
        &mut client,
        "qemu",
        (0..50, 500..550, 900..920),
        585.0,
        set,
    );
}

#[test]
fn an_extend_without_a_finished_scan_or_of_another_configuration_is_refused_in_words() {
    // The command: a fresh in-process device holds no scan.
    let dir = temp("refused");
    let out = dir.join("out");
    let run = Command::new(env!("CARGO_BIN_EXE_placedb"))
        .args([
            "stream",
            "--demo",
            "--demo-frames",
            "40",
            "--max-frames",
            "3",
        ])
        .args([
            "--stride",
            "8",
            "--port",
            "local:ram512k",
            "--extend",
            "-q",
            "-o",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        err.contains("no finished scan in its flash log to extend"),
        "{err}"
    );
    assert!(!err.contains("NothingToExtend"), "{err}");
    // One sentence, not a source line's indentation in the middle of it.
    assert!(!err.contains("  "), "{err}");
    assert!(!out.exists(), "nothing written");
    // The library: a scan cut short, then a finished one with another mu.
    let seq = placedb_host::testing::demo(6);
    let vcfg = VoxelConfig {
        stride: STRIDE,
        ..VoxelConfig::default()
    };
    let sel = SelectorConfig {
        mu: MU,
        window: 4,
        sketch_margin: 0.05,
    };
    let (_, _, cfg) = stream_config(&seq, &vcfg, sel, PROFILE).unwrap();
    let mut client = Client::new(LocalLink::start(PROFILE).unwrap());
    let open = StreamOptions {
        finish: false,
        ..StreamOptions::default()
    };
    stream(&mut client, &seq, &cfg, PROFILE, &open, None).unwrap();
    let extend = StreamOptions {
        extend: true,
        ..StreamOptions::default()
    };
    let err = stream(&mut client, &seq, &cfg, PROFILE, &extend, None).unwrap_err();
    assert!(
        err.to_string()
            .contains("cut short is resumed with --resume"),
        "{err}"
    );
    let resume = StreamOptions {
        resume: true,
        ..StreamOptions::default()
    };
    // A resume with another setting names it; the correct one is taken.
    let other = placedb::protocol::Config {
        stride: STRIDE * 2,
        ..cfg
    };
    let err = stream(&mut client, &seq, &other, PROFILE, &resume, None).unwrap_err();
    let said = format!(
        "--resume: --stride {} where the device's scan has stride {STRIDE}: ",
        STRIDE * 2
    );
    assert!(err.to_string().contains(&said), "{err}");
    // The way out is a command, not a replug.
    assert!(err.to_string().contains("--new-scan"), "{err}");
    stream(&mut client, &seq, &cfg, PROFILE, &resume, None).unwrap();
    let other = placedb::protocol::Config { mu: 0.5, ..cfg };
    let err = stream(&mut client, &seq, &other, PROFILE, &extend, None).unwrap_err();
    let said = format!("--extend: --mu 0.5 where the device's scan has mu {MU}: ");
    assert!(err.to_string().contains(&said), "{err}");
    assert!(!err.to_string().contains("  "), "{err}");
    // Another camera: a later session may use one, as `select --extend`
    // takes it. A session cut short is resumed with its own camera only:
    // another is refused, naming both cameras, and changes nothing.
    let camera = placedb::Intrinsics {
        fx: cfg.intrinsics.fx + 1.0,
        ..cfg.intrinsics
    };
    let other = placedb::protocol::Config {
        intrinsics: camera,
        ..cfg
    };
    let open_extend = StreamOptions {
        finish: false,
        ..extend.clone()
    };
    let report = stream(&mut client, &seq, &other, PROFILE, &open_extend, None).unwrap();
    assert_eq!((report.first_index, report.status.sessions), (6, 2));
    let err = stream(&mut client, &seq, &cfg, PROFILE, &extend, None).unwrap_err();
    let k = &cfg.intrinsics;
    assert!(
        err.to_string().contains(&format!(
            "--extend: the camera {}x{} fx {} fy {} cx {} cy {} where the device's scan has the camera {}x{} fx {} ",
            k.width, k.height, k.fx, k.fy, k.cx, k.cy, camera.width, camera.height, camera.fx
        )),
        "{err}"
    );
    // Nothing changed: the session goes on with its own camera.
    let report = stream(&mut client, &seq, &other, PROFILE, &extend, None).unwrap();
    assert_eq!((report.first_index, report.status.sessions), (6, 2));
    assert_eq!(report.status.frames_seen, 12);
    std::fs::remove_dir_all(&dir).unwrap();
}
