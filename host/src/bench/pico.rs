//! `placedb bench --pico`: what the Pico's Cortex-M0+ costs per valid pixel
//! and per frame under the RP2040 emulator, and the frames/s it sustains
//! against what USB full speed carries.
//!
//! Cycles come from the firmware's own clock (the RP2040 timer, read at 125
//! cycles a microsecond under rp2040js) through [`super::pixel_cost`]:
//! the same frames at strides 2 and 4, so that the marginal cost of a valid
//! pixel and what a frame costs besides its pixels separate. The emulator
//! runs with its flash timing off here, so the flash time of a frame is computed here from
//! the sector erases and page programs the harness counted while the frames
//! were streamed, at the W25Q16JV datasheet's typical timings (4 KiB sector
//! erase 45 ms, 256-byte page program 0.4 ms): the erases and programs of
//! the measured frames spread over them.

use super::figure;
use super::pixel_cost::{self as pixelcost, PixelCost, SELECTOR, STRIDES};
use crate::device::client::Client;
use crate::device::emulator::rp2040::{self, Rp2040, Rp2040Options};
use crate::device::flash_timing::FlashTiming;
use crate::read::{self, ReadOptions};
use crate::synth::{self, SynthConfig};
use crate::{Sequence, VoxelConfig};
use std::path::Path;
use std::time::Duration;

type Error = Box<dyn std::error::Error>;

/// rp2040js runs clk_sys at 125 MHz; the firmware's clock is the 1 MHz timer.
const CYCLES_PER_TICK: f64 = 125.0;
/// The RP2040's rated clock, at which the frames/s are given.
const CLOCK_HZ: f64 = 133e6;
/// Bulk payload USB full speed carries at best, bytes/s.
const USB_BYTES_PER_S: f64 = 1.1e6;
/// Bytes on the wire per sampled pixel: two, plus ~1 % of framing.
const USB_BYTES_PER_PIXEL: f64 = 2.0 * 1.01;
/// W25Q16JV typical sector erase (4 KiB) and page program (256 B), seconds.
const ERASE_S: f64 = 45e-3;
const PROGRAM_S: f64 = 0.4e-3;
/// The depth image sizes and strides of the table.
const DEPTHS: [(u32, u32); 2] = [(160, 120), (320, 240)];
const TABLE_STRIDES: [u32; 3] = [1, 2, 4];
/// The Pico's capacity profile.
const PROFILE: &str = "ram256k";

/// One sequence's costs on the Pico.
struct Measured {
    name: &'static str,
    cost: PixelCost,
    /// Flash busy time per frame at typical timing, seconds.
    flash_s: f64,
    erases: u64,
    programs: u64,
    frames: u32,
}

impl Measured {
    fn per_pixel(&self) -> f64 {
        self.cost.per_pixel() * CYCLES_PER_TICK
    }
    fn core_per_pixel(&self) -> f64 {
        self.cost.core_per_pixel() * CYCLES_PER_TICK
    }
    fn per_frame(&self) -> f64 {
        self.cost.per_frame() * CYCLES_PER_TICK
    }
    /// Frames/s of a `w x h` image at stride `s`, every pixel valid.
    fn fps(&self, pixels: f64, with_flash: bool) -> f64 {
        let cpu = (self.per_frame() + self.per_pixel() * pixels) / CLOCK_HZ;
        1.0 / (cpu + if with_flash { self.flash_s } else { 0.0 })
    }
}

/// Streams `seq` at strides 2 and 4 on a freshly booted emulated Pico (so
/// that its flash counts are this sequence's).
fn measure(name: &'static str, seq: &Sequence) -> Result<Measured, Error> {
    let firmware = rp2040::built_firmware()?;
    let options = Rp2040Options {
        deadline: Duration::from_secs(3600),
        // CPU cycles only; the flash time is added below from the counts.
        flash_timing: FlashTiming::None,
        ..Rp2040Options::default()
    };
    let board = Rp2040::start_with(&firmware, &options)
        .map_err(|e| format!("cannot start the RP2040 emulator: {e}"))?;
    let mut client = Client::new(board);
    let cost = pixelcost::measure(
        &mut client,
        seq,
        &VoxelConfig::default(),
        SELECTOR,
        PROFILE,
        STRIDES,
    )?;
    let console = client.into_link().stop();
    let count = |field: &str| -> Result<u64, Error> {
        console
            .lines()
            .filter(|l| l.starts_with("stats"))
            .flat_map(str::split_whitespace)
            .find_map(|w| w.strip_prefix(field)?.strip_prefix('=')?.parse().ok())
            .ok_or_else(|| format!("the emulator reported no {field}: {console}").into())
    };
    let (erases, programs) = (count("sectors_erased")?, count("pages_programmed")?);
    let frames = cost.fine.frames + cost.coarse.frames;
    let flash_s = (erases as f64 * ERASE_S + programs as f64 * PROGRAM_S) / f64::from(frames);
    Ok(Measured {
        name,
        cost,
        flash_s,
        erases,
        programs,
        frames,
    })
}

/// `bench --pico`: `frames` of 7scenes-1000 (in `data`) and twice as many
/// synthetic ones; a table, or one JSON object with `json`.
pub fn run(data: &Path, frames: usize, json: bool) -> Result<(), Error> {
    let mut real = read::open(&data.join("7scenes-1000"), &ReadOptions::default())?;
    real.frames.truncate(frames);
    let mut synthetic = synth::sequence(&SynthConfig::demo());
    synthetic.frames.truncate(2 * frames);
    let runs = [
        measure("7scenes-1000", &real)?,
        measure("synthetic", &synthetic)?,
    ];
    let mut rows = Vec::new();
    for (w, h) in DEPTHS {
        for s in TABLE_STRIDES {
            let pixels = f64::from((w / s) * (h / s));
            let usb = USB_BYTES_PER_S / (pixels * USB_BYTES_PER_PIXEL);
            for m in &runs {
                rows.push((w, h, s, m, m.fps(pixels, true), m.fps(pixels, false), usb));
            }
        }
    }
    if json {
        let by_name = |f: &dyn Fn(&Measured) -> f64| {
            runs.iter()
                .map(|m| (m.name.to_string(), serde_json::json!(f(m))))
                .collect::<serde_json::Map<_, _>>()
        };
        let fps: Vec<_> = rows
            .iter()
            .map(|(w, h, s, m, pico, cpu, usb)| {
                serde_json::json!({
                    "depth": format!("{w}x{h}"),
                    "stride": s,
                    "sequence": m.name,
                    "pico": pico,
                    "pico_without_flash": cpu,
                    "usb": usb,
                })
            })
            .collect();
        let out = serde_json::json!({
            "clock_hz": CLOCK_HZ,
            "cycles_per_valid_pixel": by_name(&Measured::per_pixel),
            "core_cycles_per_valid_pixel": by_name(&Measured::core_per_pixel),
            "cycles_per_frame": by_name(&Measured::per_frame),
            "flash_ms_per_frame": by_name(&|m| m.flash_s * 1e3),
            "fps": fps,
        });
        println!("{out}");
        return Ok(());
    }
    let [fine, coarse] = STRIDES;
    println!(
        "Pico (RP2040 emulator, Cortex-M0+), profile {PROFILE}: cycles per valid pixel, marginal \
         between strides {fine} and {coarse}, protocol included"
    );
    println!(
        "{:<14} {:>6} {:>10} {:>9} {:>11} {:>8} {:>8} {:>11}",
        "sequence",
        "frames",
        "cycles/px",
        "core/px",
        "cycles/frm",
        "erases",
        "pages",
        "flash ms/frm"
    );
    for m in &runs {
        println!(
            "{:<14} {:>6} {:>10} {:>9} {:>11} {:>8} {:>8} {:>11}",
            m.name,
            m.frames,
            figure(m.per_pixel(), 1),
            figure(m.core_per_pixel(), 1),
            figure(m.per_frame(), 0),
            m.erases,
            m.programs,
            figure(m.flash_s * 1e3, 2)
        );
    }
    println!(
        "\nframes/s at {:.0} MHz, every pixel valid (per frame + pixels x per pixel, then the \
         flash time of the measured frames at typical timing, computed from the counted erases \
         x {:.0} ms and programs x {:.1} ms, as the emulator does not time flash)",
        CLOCK_HZ / 1e6,
        ERASE_S * 1e3,
        PROGRAM_S * 1e3
    );
    println!(
        "{:<8} {:>6} {:<14} {:>10} {:>14} {:>9}",
        "depth", "stride", "sequence", "pico", "pico no flash", "usb"
    );
    for (w, h, s, m, pico, cpu, usb) in &rows {
        println!(
            "{:<8} {:>6} {:<14} {:>10} {:>14} {:>9}",
            format!("{w}x{h}"),
            s,
            m.name,
            figure(*pico, 1),
            figure(*cpu, 1),
            figure(*usb, 1)
        );
    }
    Ok(())
}
