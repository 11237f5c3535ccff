//! End to end on the emulated board: the QEMU firmware (boards/qemu-mps2-an386,
//! profile ram512k, protocol on UART0) is fed real and synthetic depth through
//! its UART; what it exports is byte-identical to the host replay of the core
//! (`placedb select --solver online`: `placedb_host::replay::replay` and the
//! `placedb_host::output` writers) with the same profile and configuration.
//! Bad input over the wire gets typed errors and changes nothing.
//!
//! Needs `qemu-system-arm` and the firmware, built first with
//! `cd boards/qemu-mps2-an386 && cargo build --release` (or set
//! `PLACEDB_QEMU_FIRMWARE`). Prints the firmware's memory figures, the frame
//! rate over the emulated UART and the instructions per frame (QEMU runs with
//! `-icount shift=0`); run with `--nocapture` to see them.

mod board_common;

use board_common::{export_all, host_replay, killed_mid_scan_restores_and_resumes, Board};
use placedb::protocol::{
    CapacitySlot, DeviceMessage, ErrorKind, ExportRecord, HostMessage, Phase, MAX_FRAME_LEN,
};
use placedb::{SelectorConfig, VoxelGrid};
use placedb_host::board::client::Client;
use placedb_host::board::client::Received;
use placedb_host::board::emulator::qemu::Qemu;
use placedb_host::board::emulator::qemu::QemuOptions;
use placedb_host::board::export::ExportOptions;
use placedb_host::board::link::fault::damaged_frame;
use placedb_host::board::scan::StreamOptions;
use placedb_host::board::scan::StreamReport;
use placedb_host::board::{export, scan};
use placedb_host::read::{self, ReadOptions};
use placedb_host::synth::{self, SynthConfig};
use placedb_host::testing::qemu_firmware as firmware;
use placedb_host::{GridOrigin, Sequence, VoxelConfig};
use std::path::Path;
use std::time::{Duration, Instant};

const PROFILE: &str = "ram512k";
/// The budget of the board: memory.x.
const FLASH_BUDGET: u64 = 4 << 20;
const RAM_BUDGET: u64 = 512 << 10;
const REPLY: Duration = Duration::from_secs(30);

fn boot(deadline: Duration) -> Client<Qemu> {
    let options = QemuOptions {
        extra_args: vec!["-icount".into(), "shift=0".into()],
        deadline,
        ..QemuOptions::default()
    };
    let qemu = Qemu::start_with(&firmware(), options).unwrap_or_else(|e| {
        panic!("cannot start qemu-system-arm (apt-get install qemu-system-arm): {e}")
    });
    assert!(
        qemu.wait_console("calibration", Duration::from_secs(10)),
        "no boot lines; console: {}",
        qemu.console()
    );
    Client::new(qemu)
}

/// `.text`, `.rodata`, `.data`, `.bss` sizes of a 32-bit little-endian ELF.
fn section_sizes(elf: &Path) -> Vec<(String, u64)> {
    let b = std::fs::read(elf).unwrap();
    let u16_at = |o: usize| u16::from_le_bytes([b[o], b[o + 1]]) as usize;
    let u32_at = |o: usize| u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]) as usize;
    assert_eq!(&b[..5], b"\x7fELF\x01", "not a 32-bit ELF");
    let (shoff, shentsize, shnum, shstrndx) =
        (u32_at(0x20), u16_at(0x2E), u16_at(0x30), u16_at(0x32));
    let sh = |i: usize| shoff + i * shentsize;
    let strtab = u32_at(sh(shstrndx) + 0x10);
    (0..shnum)
        .map(|i| {
            let name_at = strtab + u32_at(sh(i));
            let end = b[name_at..].iter().position(|&c| c == 0).unwrap();
            let name = String::from_utf8_lossy(&b[name_at..name_at + end]).into_owned();
            (name, u32_at(sh(i) + 0x14) as u64)
        })
        .collect()
}

#[test]
fn firmware_fits_its_budget() {
    let sizes = section_sizes(&firmware());
    let size = |n: &str| {
        sizes
            .iter()
            .filter(|(s, _)| s == n)
            .map(|(_, v)| *v)
            .sum::<u64>()
    };
    let (text, rodata, data, bss) = (
        size(".text") + size(".vector_table"),
        size(".rodata"),
        size(".data"),
        size(".bss") + size(".uninit"),
    );
    let flash = text + rodata + data;
    let ram = data + bss;
    println!(
        "qemu-mps2-an386 firmware ({PROFILE}): flash {flash} B of {FLASH_BUDGET} \
         (.text {text}, .rodata {rodata}, .data init {data}); static RAM {ram} B of {RAM_BUDGET} \
         (.data {data} + .bss {bss}), {} B left for the stack",
        RAM_BUDGET - ram,
    );
    // A fresh device is all zero bytes: its static costs RAM (.bss) but no flash.
    assert!(
        data <= 1024,
        "{data} B of .data: the device static is not all zero, so it is stored in flash too \
         (usually a new `Option<T>` field whose T has a niche: its None is a non-zero byte; \
         use a plain flag beside T, as `RingEntry` in src/select/mod.rs does)"
    );
    assert!(flash <= FLASH_BUDGET && ram <= RAM_BUDGET);
    assert!(
        RAM_BUDGET - ram >= 16 << 10,
        "less than 16 KiB left for the stack"
    );
}

/// Streams `seq`, exports, and checks the files against the host replay.
fn stream_and_compare(
    client: &mut Client<Qemu>,
    seq: &Sequence,
    vcfg: &VoxelConfig,
    sel: SelectorConfig,
) -> (StreamReport, Vec<ExportRecord>) {
    let scan = scan::scan_config(seq, vcfg).unwrap();
    let cfg = scan::device_config(&scan, &sel).unwrap();
    let report = scan::stream(
        client,
        seq,
        &cfg,
        PROFILE,
        &StreamOptions::replacing(),
        None,
    )
    .unwrap();
    assert_eq!(report.status.phase, Phase::Finished);
    assert_eq!(report.status.frames_seen as usize, seq.frames.len());
    assert!(report.decisions.iter().all(Option::is_some));
    let export = export_all(client);
    let (db_csv, labels_csv) = export.csv();
    let (want_db, want_labels) = host_replay(PROFILE, seq, vcfg, sel);
    assert_eq!(db_csv, want_db, "database.csv differs on {}", seq.name);
    assert_eq!(
        labels_csv, want_labels,
        "labels.csv differs on {}",
        seq.name
    );
    assert_eq!(labels_csv.lines().count(), seq.frames.len() + 1);
    let instr = report.ticks_per_frame().unwrap();
    println!(
        "{}: {} frames -> {} database frames, identical to the host replay; \
         {:.2} frames/s over the emulated UART ({:.1} KB/s in); \
         {:.0} instructions per frame on the device (max {}), {} export records",
        seq.name,
        report.frames,
        report.status.database_size,
        report.fps(),
        report.bytes_sent as f64 / 1e3 / report.wall.as_secs_f64(),
        instr,
        report.status.cost.max,
        export.records.len()
    );
    (report, export.records)
}

#[test]
fn real_and_synthetic_scans_match_the_host_replay() {
    let started = Instant::now();
    let mut client = boot(Duration::from_secs(170));

    // (a) the first 24 frames of a real 7-Scenes sequence at stride 8 (9.6 KB a frame).
    let data = placedb_host::testing::data("7scenes-1000");
    let mut real = read::open(&data, &ReadOptions::default()).unwrap();
    real.frames.truncate(24);
    let vcfg = VoxelConfig {
        voxel: 0.05,
        stride: 8,
        ..VoxelConfig::default()
    };
    assert_eq!(vcfg.origin, GridOrigin::World);
    let sel = SelectorConfig {
        mu: 0.7,
        window: 8,
        sketch_margin: 0.05,
    };
    let (report, records) = stream_and_compare(&mut client, &real, &vcfg, sel);
    assert!(report.status.database_size > 1);

    // A resumed export: the checked records up to k are kept, the rest fetched.
    let k = records.len() / 2;
    let opts = ExportOptions {
        batch: 5,
        ..ExportOptions::default()
    };
    let mut batches = 0;
    let resumed = export::export(&mut client, records[..k].to_vec(), &opts, None, &mut |_| {
        batches += 1;
        Ok(())
    })
    .unwrap();
    assert_eq!(resumed.records, records);
    assert_eq!(batches, (records.len() - k).div_ceil(5));

    // (b) 30 frames of the synthetic office scan at stride 8, select's defaults.
    let mut demo = synth::sequence(&SynthConfig::demo());
    demo.frames.truncate(30);
    let vcfg = VoxelConfig {
        stride: 8,
        ..VoxelConfig::default()
    };
    let sel = SelectorConfig {
        mu: 0.3,
        window: 32,
        sketch_margin: 0.05,
    };
    stream_and_compare(&mut client, &demo, &vcfg, sel);

    let qemu = client.into_link();
    let console = qemu.console();
    if let Some(line) = console.lines().rev().find(|l| l.starts_with("stack peak")) {
        println!("firmware {line}");
    }
    println!(
        "firmware {}",
        console
            .lines()
            .find(|l| l.starts_with("calibration"))
            .unwrap_or("no calibration line")
    );
    assert!(
        qemu.try_wait().unwrap().is_none(),
        "firmware exited: {console}"
    );
    println!("end to end: {:.1} s", started.elapsed().as_secs_f64());
}

/// The Cortex-M4F's instructions per valid pixel, protocol included
/// (`placedb_host::cli::bench::pixel_cost`: the same frames at two strides; what the
/// firmware counts under `-icount shift=0`, exact up to a SysTick tick per
/// clock reading): at most 100 on 7-Scenes, the core's share reported.
#[test]
fn a_valid_pixel_costs_at_most_100_instructions() {
    use placedb_host::cli::bench::pixel_cost::{self, SELECTOR, STRIDES};
    let mut client = boot(Duration::from_secs(600));
    let data = placedb_host::testing::data("7scenes-1000");
    let mut real = read::open(&data, &ReadOptions::default()).unwrap();
    real.frames.truncate(3);
    let vcfg = VoxelConfig::default();
    let cost = pixel_cost::measure(&mut client, &real, &vcfg, SELECTOR, PROFILE, STRIDES).unwrap();
    let (total, core) = (cost.per_pixel(), cost.core_per_pixel());
    println!(
        "7scenes-1000, strides {STRIDES:?}: {total:.1} instructions per valid pixel \
         ({core:.1} core, {:.1} protocol), {:.0} per frame besides; {:.0} and {:.0} \
         valid pixels per frame",
        cost.protocol_per_pixel(),
        cost.per_frame(),
        cost.fine.pixels,
        cost.coarse.pixels,
    );
    assert!(
        cost.fine.pixels > 50_000.0,
        "not the 7-Scenes frames expected"
    );
    assert!(core > 0.0 && core < total, "core {core}, total {total}");
    assert!(
        total <= 100.0,
        "{total:.1} instructions per valid pixel on the Cortex-M4F (at most 100)"
    );
}

#[test]
fn bad_input_gets_typed_errors_and_changes_nothing() {
    let mut client = boot(Duration::from_secs(120));
    let mut demo = synth::sequence(&SynthConfig::demo());
    demo.frames.truncate(6);
    let vcfg = VoxelConfig {
        stride: 8,
        ..VoxelConfig::default()
    };
    let sel = SelectorConfig {
        mu: 0.3,
        window: 3,
        sketch_margin: 0.05,
    };
    let scan = scan::scan_config(&demo, &vcfg).unwrap();
    assert_eq!(scan.grid, VoxelGrid::new(0.3, [0.0; 3]).unwrap());
    let cfg = scan::device_config(&scan, &sel).unwrap();
    let opts = StreamOptions {
        in_flight: 1,
        ..StreamOptions::default()
    };
    scan::stream(&mut client, &demo, &cfg, PROFILE, &opts, None).unwrap();
    let before = export_all(&mut client);
    assert!(before.status.database_size >= 1);

    let refused = |client: &mut Client<Qemu>, msg: HostMessage<'_>| -> ErrorKind {
        let (seq, replies) = client.request(msg, REPLY).unwrap();
        match replies.as_slice() {
            [Received::Message(DeviceMessage::Error { seq: s, kind })] => {
                assert_eq!(*s, Some(seq));
                *kind
            }
            other => panic!("{msg:?} was not refused: {other:?}"),
        }
    };
    // A corrupted frame (a frame message that would be valid).
    let seq = client.take_seq();
    let begin = HostMessage::FrameBegin {
        frame: 6,
        timestamp: 99.0,
        pose: placedb::Pose::IDENTITY,
    };
    client
        .send_raw(&damaged_frame(seq, begin).expect("a damaging byte"))
        .unwrap();
    let replies = client.replies_to(seq, REPLY).unwrap();
    assert_eq!(
        replies,
        vec![Received::Message(DeviceMessage::Error {
            seq: Some(seq),
            kind: ErrorKind::BadCrc
        })]
    );
    // Garbage, an oversized frame, and messages out of order after Finish.
    client.send_raw(&[0x03, 0x01, 0x02, 0x00]).unwrap();
    assert!(matches!(
        client.recv(REPLY).unwrap(),
        Received::Message(DeviceMessage::Error { .. })
    ));
    let mut long = vec![0x42u8; MAX_FRAME_LEN + 50];
    long.push(0);
    client.send_raw(&long).unwrap();
    assert_eq!(
        client.recv(REPLY).unwrap(),
        Received::Message(DeviceMessage::Error {
            seq: None,
            kind: ErrorKind::Oversized
        })
    );
    assert_eq!(refused(&mut client, begin), ErrorKind::Finished);
    assert_eq!(
        refused(&mut client, HostMessage::FrameEnd { frame: 6 }),
        ErrorKind::Finished
    );
    let mut other = cfg;
    other.mu = 0.5;
    assert_eq!(
        refused(&mut client, HostMessage::Hello(other)),
        ErrorKind::NeedsReset
    );
    assert_eq!(
        refused(
            &mut client,
            HostMessage::ExportRequest {
                from_record: 10_000,
                max_records: 1
            }
        ),
        ErrorKind::ExportPastEnd
    );

    let after = export_all(&mut client);
    assert_eq!(after.records, before.records);
    assert_eq!(after.csv(), before.csv());
    assert_eq!(after.status.refused, before.status.refused + 7);
    assert_eq!(
        after.status.capacity(CapacitySlot::RxFrame).peak,
        MAX_FRAME_LEN as u32
    );
    println!(
        "bad input: 7 refusals with typed errors, database unchanged ({} records)",
        after.records.len()
    );
}

/// Power cut on the emulated board: QEMU is killed in the middle of a frame,
/// with frames still pending in the window, and booted again on the same
/// flash file. The board restores its scan from the flash log, every decision
/// it had sent is still there, and the host resumes at the first undecided
/// frame: the final export equals an uninterrupted run's.
#[test]
fn a_board_killed_mid_scan_restores_from_flash_and_resumes() {
    killed_mid_scan_restores_and_resumes::<QemuBoard>(48);
}

/// The QEMU board on a flash file; a power cut kills QEMU.
struct QemuBoard;

impl Board for QemuBoard {
    type Link = Qemu;
    const NAME: &'static str = "qemu";
    const PROFILE: &'static str = PROFILE;
    const REPLY: Duration = REPLY;

    fn boot(flash: &Path) -> (Client<Qemu>, String) {
        let blank = !flash.exists();
        let options = QemuOptions {
            extra_args: vec!["-icount".into(), "shift=0".into()],
            deadline: Duration::from_secs(120),
            flash: Some(flash.to_path_buf()),
            ..QemuOptions::default()
        };
        let qemu = Qemu::start_with(&firmware(), options).unwrap();
        // The restore line's end: the console arrives in pieces, and under
        // load "restored" alone was once read before the rest of its line.
        assert!(
            qemu.wait_console(" sectors", Duration::from_secs(10)),
            "no restore line; console: {}",
            qemu.console()
        );
        let console = qemu.console();
        if blank {
            assert!(console.contains("restored 0 records"), "{console}");
        }
        (Client::new(qemu), console)
    }

    fn power_cut(client: Client<Qemu>, _flash: &Path) {
        drop(client); // kills QEMU
    }
}
