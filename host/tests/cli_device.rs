//! `placedb device --qemu` and `--rp2040` as a user starts them (issue 41
//! item 8): what they print before a program connects, and what they
//! refuse before anything starts.
//!
//! - The example commands name the board's real port (the Pico's said
//!   `tcp:127.0.0.1:PORT`), and a command given it reaches the board.
//! - With `--flash FILE`, what the board restored from it at boot: no
//!   scan, or a scan of N frames, finished or not, as the board's status
//!   says it.
//! - A flash file of another size (a few bytes, the other board's, a
//!   folder) or a port in use is refused in words (the file, its size and
//!   the size expected; the port) with status 1, before anything is
//!   printed, made or changed; a flash file in a folder that does not
//!   exist yet is made, folder and all, as the docs' examples need.
//!
//! Needs what host/tests/board_qemu.rs and host/tests/board_rp2040.rs need
//! (`qemu-system-arm`; Node 20, `npm ci` in boards/rp-pico/emulator and the
//! boot ROM).

mod cli_common;

use cli_common::device::Device;
use cli_common::{names, placedb, stderr, TempDir};
use placedb_host::board::client;
use placedb_host::board::scan::held_scan;
use std::time::Duration;

/// The boards: their flag, their profile and the size of their flash file.
const BOARDS: [(&str, &str, u64); 2] = [
    ("--qemu", "ram512k", 16 << 20),
    ("--rp2040", "ram256k", 2 << 20),
];

/// The example command's port reaches the board: a stream on it runs.
fn the_example_port_reaches_the_board(board: &str, profile: &str) {
    let device = Device::start(board, &[]);
    let port = device.port();
    let run = placedb(&[
        "stream",
        "--port",
        &port,
        "--profile",
        profile,
        "--demo",
        "--stride",
        "8",
        "--max-frames",
        "4",
        "-q",
    ]);
    assert!(run.status.success(), "{board} on {port}: {}", stderr(&run));
}

#[test]
fn the_qemu_boards_example_commands_name_its_port() {
    the_example_port_reaches_the_board("--qemu", "ram512k");
}

#[test]
fn the_emulated_picos_example_commands_name_its_port() {
    the_example_port_reaches_the_board("--rp2040", "ram256k");
}

/// What `placedb device` said the board restored from `flash`, once it
/// said it: its line about the file (the QEMU board names its port before
/// it boots).
fn restored_line(device: &mut Device, flash: &str) -> String {
    device.wait_line("what the flash file held", cli_common::device::BOOT, |l| {
        l.contains(flash) && !l.contains("flash kept in")
    })
}

/// A board started on a new flash file says it holds no scan; restarted
/// after an unfinished scan, and again after it finished, it says what
/// its status says it restored.
fn says_what_it_restored(board: &str, profile: &str) {
    let tmp = TempDir::new("restored");
    let flash = tmp.arg("board.flash");
    let stream = |port: &str, more: &[&str]| {
        let mut args = vec![
            "stream",
            "--port",
            port,
            "--profile",
            profile,
            "--demo",
            "--stride",
            "8",
            "--window",
            "8",
            "--max-frames",
            "24",
            "-q",
        ];
        args.extend_from_slice(more);
        let run = placedb(&args);
        assert!(run.status.success(), "{board} {more:?}: {}", stderr(&run));
    };
    let mut device = Device::start(board, &["--flash", &flash]);
    let said = restored_line(&mut device, &flash);
    assert!(
        said.contains("holds no scan: the board starts empty"),
        "{said}"
    );
    stream(&device.port(), &["--no-finish"]);
    device.stop();

    for (finished, advice) in [
        (
            "an unfinished scan",
            "`placedb stream --resume` goes on with it",
        ),
        ("a finished scan", "`placedb export` pulls it"),
    ] {
        let mut device = Device::start(board, &["--flash", &flash]);
        let said = restored_line(&mut device, &flash);
        let mut program = client::connect(&device.port()).unwrap();
        let st = client::status(&mut program, Duration::from_secs(60)).unwrap();
        drop(program);
        let held = held_scan(&st).unwrap();
        assert!(held.starts_with(finished), "{held}");
        assert!(
            said.contains(&format!("restored from {flash}: {held}")) && said.contains(advice),
            "{board} said {said:?}, its status: {held}"
        );
        println!("{board}: {}", said.trim());
        if finished == "an unfinished scan" {
            stream(&device.port(), &["--resume"]);
        }
        device.stop();
    }
}

#[test]
fn the_qemu_board_says_what_it_restored_from_its_flash_file() {
    says_what_it_restored("--qemu", "ram512k");
}

#[test]
fn the_emulated_pico_says_what_it_restored_from_its_flash_file() {
    says_what_it_restored("--rp2040", "ram256k");
}

/// `placedb device BOARD ARGS` refused before it starts: status 1,
/// nothing on stdout, the returned stderr in words.
fn refused(board: &str, args: &[&str]) -> String {
    let firmware = cli_common::device::firmware(board);
    let mut all = vec!["device", board, "--firmware", firmware.to_str().unwrap()];
    all.extend_from_slice(args);
    let run = placedb(&all);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(1), "{board} {args:?}: {err}");
    assert!(
        run.stdout.is_empty(),
        "{board} {args:?} printed before it refused: {}",
        String::from_utf8_lossy(&run.stdout)
    );
    for rust in ["os error", "Kind(", "Custom {", "Error {", "Io("] {
        assert!(!err.contains(rust), "{rust:?} in: {err}");
    }
    err
}

#[test]
fn a_flash_file_of_another_size_is_refused_before_anything_starts() {
    let tmp = TempDir::new("flash-size");
    std::fs::create_dir(tmp.path().join("folder")).unwrap();
    for (board, _, size) in BOARDS {
        let (_, _, other) = BOARDS.into_iter().find(|b| b.0 != board).unwrap();
        for (name, bytes) in [("short.flash", 1000), ("other.flash", other)] {
            let path = tmp.arg(name);
            std::fs::write(&path, vec![0x5A; bytes as usize]).unwrap();
            let before = names(tmp.path());
            let err = refused(board, &["--flash", &path]);
            let want = format!(
                "flash file {path} holds {bytes} bytes, not the {size} bytes ({} MiB)",
                size >> 20
            );
            assert!(err.contains(&want), "{board}: no {want:?} in: {err}");
            assert_eq!(names(tmp.path()), before, "{board}: a file was made");
            assert_eq!(
                std::fs::read(&path).unwrap(),
                vec![0x5A; bytes as usize],
                "{board} changed {path}"
            );
            std::fs::remove_file(&path).unwrap();
        }
        let folder = tmp.arg("folder");
        let err = refused(board, &["--flash", &folder]);
        assert!(
            err.contains(&format!("flash file {folder} is a folder")),
            "{err}"
        );
        assert!(names(&tmp.path().join("folder")).is_empty());
    }
}

#[test]
fn a_port_in_use_is_refused_before_the_flash_file_is_made() {
    let tmp = TempDir::new("port-in-use");
    let taken = std::net::TcpListener::bind(("127.0.0.1", 0)).unwrap();
    let port = taken.local_addr().unwrap().port().to_string();
    for (board, _, _) in BOARDS {
        let flash = tmp.arg("new/board.flash");
        let err = refused(board, &["--port", &port, "--flash", &flash]);
        assert!(
            err.contains(&format!("port {port} of 127.0.0.1 is in use")),
            "{board}: {err}"
        );
        assert!(names(tmp.path()).is_empty(), "{board} made the flash file");
    }
}

/// A flash file in a folder that does not exist yet is made, folder and
/// all (`--flash out/pico.flash` in the docs' examples), erased, its size
/// the board's.
#[test]
fn a_flash_file_in_a_new_folder_is_made() {
    let tmp = TempDir::new("flash-new-folder");
    for (board, _, size) in BOARDS {
        let flash = tmp.path().join(&board[2..]).join("board.flash");
        let mut device = Device::start(board, &["--flash", flash.to_str().unwrap()]);
        let said = restored_line(&mut device, flash.to_str().unwrap());
        assert!(said.contains("holds no scan"), "{said}");
        assert_eq!(std::fs::metadata(&flash).unwrap().len(), size);
        device.stop();
    }
}
