//! `placedb bench`'s instruction counts, repeatable where seconds are not:
//! the core's parts under callgrind (`--core`), the QEMU board's
//! instructions per valid pixel (`--device`), and one frame against a small
//! and a large database (`--db-scaling`).

use super::{db_scaling, figure, pixel_cost, BenchOptions};
use crate::board::client::Client;
use crate::board::emulator::qemu::{self, Qemu, QemuOptions};
use crate::error::CommandError as Error;
use crate::read::{self, ReadOptions};
use crate::synth::{self, SynthConfig};
use crate::VoxelConfig;
use pixel_cost::{SELECTOR, STRIDES};
use std::time::Duration;

/// The core's parts, each a function kept out of line in the core so that
/// callgrind can count it alone (`--toggle-collect`).
const CORE_PARTS: [(&str, &str); 4] = [
    ("voxelize", "*FrameIngest*push_rows*"),
    ("end frame", "*Selector*end_frame*"),
    ("- select", "*Selector*decide_oldest*"),
    ("finish", "*Selector*finish*"),
];

/// Runs this program with `args` under callgrind, counting only inside
/// functions matching `pattern`; returns the instructions and its stdout.
fn callgrind_count(
    dir: &std::path::Path,
    pattern: &str,
    args: &[std::ffi::OsString],
) -> Result<(f64, Vec<u8>), Error> {
    let child = std::process::Command::new("valgrind")
        .args(["--tool=callgrind", "--collect-atstart=no"])
        .arg(format!("--toggle-collect={pattern}"))
        .arg(format!(
            "--callgrind-out-file={}",
            dir.join("callgrind.out").display()
        ))
        .arg(std::env::current_exe()?)
        .args(args)
        .output()
        .map_err(|e| {
            format!(
                "cannot run valgrind ({}); install it to count instructions",
                crate::error::io_words(&e)
            )
        })?;
    if !child.status.success() {
        return Err(format!(
            "callgrind run failed: {}",
            String::from_utf8_lossy(&child.stderr)
        )
        .into());
    }
    // valgrind's summary line: "==PID== Collected : N" (callgrind) or "I   refs: N".
    let stderr = String::from_utf8_lossy(&child.stderr);
    let n = stderr
        .lines()
        .find_map(|l| {
            l.split_once("Collected :")
                .or_else(|| l.split_once("I   refs:"))
        })
        .and_then(|(_, n)| n.trim().replace(',', "").parse::<f64>().ok())
        .ok_or("no instruction count in callgrind's output")?;
    Ok((n, child.stdout))
}

/// Counts the core's instructions with callgrind on a replay of the first
/// frames of 7scenes-1000 and prints them per frame and per valid pixel.
pub fn core_cost(a: &BenchOptions) -> Result<(), Error> {
    let dir = std::env::temp_dir().join(format!("placedb-cost-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let seq = a.data.join("7scenes-1000");
    let mut counts = Vec::new();
    let mut meta = serde_json::Value::Null;
    for (_, pattern) in CORE_PARTS {
        let args: Vec<std::ffi::OsString> = [
            "select",
            "--solver",
            "online",
            "--push-rows",
            "--json",
            "-q",
            "--stride",
        ]
        .iter()
        .map(Into::into)
        .chain([
            a.stride.to_string().into(),
            "--max-frames".into(),
            a.core_frames.to_string().into(),
            seq.clone().into_os_string(),
            "-o".into(),
            dir.join("out").into_os_string(),
        ])
        .collect();
        let (n, stdout) = callgrind_count(&dir, pattern, &args)?;
        meta = serde_json::from_slice(&stdout)?;
        counts.push(n);
    }
    let frames = meta["frames"].as_f64().unwrap_or(f64::NAN);
    let pixels = meta["valid_pixels"].as_f64().unwrap_or(f64::NAN);
    println!(
        "core instructions (callgrind, x86-64), {} frames of 7scenes-1000 at stride {}, {} valid pixels per frame:",
        figure(frames, 0),
        a.stride,
        figure(pixels / frames, 0)
    );
    println!("{:<10} {:>14} {:>12}", "part", "instr/frame", "instr/pixel");
    let mut total = 0.0;
    for ((part, _), n) in CORE_PARTS.iter().zip(&counts) {
        // Parts marked "-" are inside "end frame".
        if !part.starts_with('-') {
            total += n;
        }
        println!(
            "{:<10} {:>14} {:>12}",
            part,
            figure(n / frames, 0),
            figure(n / pixels, 2)
        );
    }
    println!(
        "{:<10} {:>14} {:>12}",
        "all",
        figure(total / frames, 0),
        figure(total / pixels, 2)
    );
    println!(
        "end frame = sort the frame's voxels, sketch, overlaps with database and window, select"
    );
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}

/// `bench --device`: instructions per valid pixel of the QEMU board's
/// firmware (see [`pixel_cost`]) on the first frames of
/// 7scenes-1000 and of the synthetic scan.
pub fn device_cost(a: &BenchOptions) -> Result<(), Error> {
    let firmware = qemu::built_firmware()?;
    let qemu = Qemu::start_with(
        &firmware,
        QemuOptions {
            extra_args: vec!["-icount".into(), "shift=0".into()],
            deadline: Duration::from_secs(3600),
            ..QemuOptions::default()
        },
    )
    .map_err(|e| {
        format!(
            "cannot start qemu-system-arm (apt-get install qemu-system-arm): {}",
            crate::error::io_words(&e)
        )
    })?;
    if !qemu.wait_console("calibration", Duration::from_secs(10)) {
        return Err(format!("the firmware did not boot: {}", qemu.console()).into());
    }
    let mut client = Client::new(qemu);
    let mut real = read::open(&a.data.join("7scenes-1000"), &ReadOptions::default())?;
    real.frames.truncate(a.device_frames);
    let mut synthetic = synth::sequence(&SynthConfig::demo());
    synthetic.frames.truncate(2 * a.device_frames);
    let [fine, coarse] = STRIDES;
    println!(
        "QEMU mps2-an386 (Cortex-M4F), profile ram512k, -icount shift=0: instructions per valid \
         pixel, marginal between strides {fine} and {coarse}"
    );
    println!(
        "{:<14} {:>6} {:>10} {:>10} {:>9} {:>9} {:>9} {:>12}",
        "sequence",
        "frames",
        "px@fine",
        "px@coarse",
        "total/px",
        "core/px",
        "proto/px",
        "per frame"
    );
    for seq in [&real, &synthetic] {
        let vcfg = VoxelConfig::default();
        let cost = pixel_cost::measure(&mut client, seq, &vcfg, SELECTOR, "ram512k", STRIDES)?;
        println!(
            "{:<14} {:>6} {:>10} {:>10} {:>9} {:>9} {:>9} {:>12}",
            seq.name,
            cost.fine.frames,
            figure(cost.fine.pixels, 0),
            figure(cost.coarse.pixels, 0),
            figure(cost.per_pixel(), 1),
            figure(cost.core_per_pixel(), 1),
            figure(cost.protocol_per_pixel(), 1),
            figure(cost.per_frame(), 0)
        );
    }
    println!(
        "core = projection, voxel set, selection step; proto = COBS, CRC, decoding, copying \
         the samples, dispatch; per frame = the rest of a frame's instructions"
    );
    Ok(())
}

/// `bench --db-scaling`: the same frame against a small and a large
/// database, instructions counted by callgrind (see [`db_scaling`]).
pub fn db_scaling(a: &BenchOptions) -> Result<(), Error> {
    let dir = std::env::temp_dir().join(format!("placedb-dbscale-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let (small, big) = db_scaling::prepare(&dir, a.building_frames)?;
    let mut counts = Vec::new();
    for image in ["small.flash", "big.flash"] {
        let args = [
            "bench".into(),
            "--db-probe".into(),
            dir.join(image).into_os_string(),
            "--building-frames".into(),
            a.building_frames.to_string().into(),
        ];
        let (n, stdout) = callgrind_count(&dir, "*probe_step*", &args)?;
        counts.push((n, String::from_utf8_lossy(&stdout).trim().to_string()));
    }
    println!(
        "one frame (160x120, stride 1) of a {}-frame building, through the ram256k device \
         (protocol, voxelize, overlaps read back from flash, selection, log writes); \
         callgrind, x86-64:",
        a.building_frames
    );
    for ((n, what), db) in counts.iter().zip([small, big]) {
        println!("  against {db:>4} database frames: {n:>12.0} instructions  ({what})");
    }
    println!("  ratio: {}", figure(counts[1].0 / counts[0].0, 2));
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}
