//! `placedb bench --pico`: what the Pico's Cortex-M0+ costs per valid pixel
//! and per frame under the RP2040 emulator, and the frames/s it sustains
//! against what USB full speed carries.
//!
//! Cycles come from the firmware's own clock (the RP2040 timer, read at 125
//! cycles a microsecond under rp2040js) through [`super::pixel_cost`]: the
//! first frames of each sequence streamed at several strides on one
//! emulated Pico, its flash timing off (CPU cycles only). Each stride is a
//! scan of its own (a Reset: the device's window and its cost counters
//! start empty), so each first streams a warm-up of `--warm-up` frames
//! (default 16, the window [`SELECTOR`] holds) at that stride, not counted
//! (their cycles and pixels apart, from the status taken after them): the
//! frames measured meet a full window, as a long scan's frames do, and the
//! figures are steady-state ones. Without it the first frames cost far
//! less (7scenes-1000 at stride 16: ~0.58 M cycles a frame over the first 3
//! frames, 0.86 M over all 1,000 by the device's clock under `placedb
//! device --rp2040`). `--device-frames` sets the frames measured after it.
//!
//! - **Headline** (`cycles_per_valid_pixel`, `cycles_per_frame`): the
//!   marginal cost of a valid pixel between strides 2 and 4 and what a frame
//!   costs besides its pixels, as before, so that the figures compare with
//!   earlier ones.
//! - **Each row at its own sampling density.** A frame's own work grows with
//!   its voxels, and a pixel's cost depends on how many neighbouring samples
//!   share a voxel, so a row is not extrapolated from the headline. A
//!   `w x h` camera at stride `s` samples what the sequence's `W x H` frames
//!   sample at stride `d = s * W / w` (7-Scenes' 640x480: 4s for 160x120, 2s
//!   for 320x240; the 320x240 synthetic scan: 2s and s), the same number of
//!   samples a frame. The row's cycles a frame are the measured cycles of a
//!   frame at stride `d` plus its invalid samples at the marginal cost of a
//!   valid pixel between strides `d` and `2d`: every pixel valid, as the
//!   issue's table assumes, with everything else as measured.
//! - **Flash at steady state.** The row's flash time a frame is that of a
//!   long scan at stride `d` (all frames of the 7-Scenes sequence given, the
//!   600 frames of the synthetic demo scan) on the ram256k profile, its
//!   sector erases x 45 ms and page programs x 0.4 ms (W25Q16JV typical)
//!   over its frames. The erases and programs are counted on the host
//!   ([`super::flash_count`]: the firmware's device and log on a simulated
//!   flash, driven as the firmware drives it), because the emulator runs
//!   the firmware far slower than the Pico; the host's counts of the
//!   emulator's own streams are checked against the emulator's, in the
//!   output.

use super::figure;
use super::flash_count::{FlashCount, PicoFlashLink};
use super::pixel_cost::{self as pixelcost, PixelCost, StrideCost, SELECTOR, STRIDES};
use crate::board::client::Client;
use crate::board::emulator::rp2040::{self, Rp2040, Rp2040Options};
use crate::board::flash_timing::FlashTiming;
use crate::board::link::Link;
use crate::board::scan::{self, StreamOptions};
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
/// Frames of the synthetic demo scan whose flash work is counted (all).
const SYNTHETIC_FLASH_FRAMES: usize = 600;

/// Flash work of a scan, and its time a frame at typical timing.
#[derive(Debug, Clone, Copy)]
struct Flash {
    frames: usize,
    count: FlashCount,
}

impl Flash {
    fn seconds_per_frame(&self) -> f64 {
        let busy = self.count.erases as f64 * ERASE_S + self.count.programs as f64 * PROGRAM_S;
        busy / self.frames.max(1) as f64
    }
}

/// One sequence's costs on the Pico.
struct Measured {
    name: &'static str,
    /// The sequence's image size.
    size: (u32, u32),
    /// The headline: strides 2 and 4.
    cost: PixelCost,
    /// Frames of each stride's scan streamed first and not counted.
    warm_up: usize,
    /// The emulator's cost at every stride streamed, in ticks.
    strides: Vec<StrideCost>,
    /// The warm-up's cost at each stride, apart.
    warm: Vec<StrideCost>,
    /// Steady-state flash work at each row's stride.
    flash: Vec<(u16, Flash)>,
    /// The emulator's count of its own streams, and the host's of the same.
    check: FlashCheck,
}

/// The emulator's streams counted twice.
struct FlashCheck {
    frames: usize,
    emulator: FlashCount,
    host: FlashCount,
}

/// One row of the frames/s table.
struct Row {
    depth: (u32, u32),
    stride: u32,
    name: &'static str,
    /// The sequence's stride that samples as this camera does.
    measured_at: u16,
    /// Samples a frame.
    samples: f64,
    /// Valid samples a frame at `measured_at` (of `samples`).
    valid: f64,
    /// Marginal cycles of a valid pixel between `measured_at` and twice it.
    per_pixel: f64,
    /// Cycles a frame, every pixel valid.
    per_frame: f64,
    /// Flash time a frame at steady state, seconds.
    flash_s: f64,
    usb: f64,
}

impl Row {
    fn fps(&self, with_flash: bool) -> f64 {
        let cpu = self.per_frame / CLOCK_HZ;
        1.0 / (cpu + if with_flash { self.flash_s } else { 0.0 })
    }
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

    fn at(&self, stride: u16) -> Result<StrideCost, Error> {
        self.strides
            .iter()
            .find(|c| c.stride == stride)
            .copied()
            .ok_or_else(|| format!("{}: stride {stride} not measured", self.name).into())
    }

    /// The table's row for a `w x h` camera at stride `s` (see the module
    /// docs).
    fn row(&self, (w, h): (u32, u32), s: u32) -> Result<Row, Error> {
        let d = row_stride(self.size, (w, h), s)?;
        let here = self.at(d)?;
        let cost = PixelCost::of(here, self.at(2 * d)?)?;
        let samples = f64::from((w / s) * (h / s));
        let per_pixel = cost.per_pixel() * CYCLES_PER_TICK;
        let per_frame = here.ticks * CYCLES_PER_TICK + (samples - here.pixels) * per_pixel;
        let flash = self
            .flash
            .iter()
            .find(|(stride, _)| *stride == d)
            .map(|(_, f)| f.seconds_per_frame())
            .ok_or_else(|| format!("{}: no flash count at stride {d}", self.name))?;
        Ok(Row {
            depth: (w, h),
            stride: s,
            name: self.name,
            measured_at: d,
            samples,
            valid: here.pixels,
            per_pixel,
            per_frame,
            flash_s: flash,
            usb: USB_BYTES_PER_S / (samples * USB_BYTES_PER_PIXEL),
        })
    }
}

/// The stride of a `size` sequence that samples as a `w x h` camera at
/// stride `s`: `s * W / w`, the same for both sides.
fn row_stride(size: (u32, u32), (w, h): (u32, u32), s: u32) -> Result<u16, Error> {
    let (sw, sh) = size;
    if sw % w != 0 || sh % h != 0 || sw / w != sh / h {
        return Err(format!("a {sw}x{sh} sequence does not sample as a {w}x{h} camera").into());
    }
    Ok(u16::try_from(s * sw / w)?)
}

/// The strides a sequence of `size` is streamed at: the headline's first
/// (so its figures are measured as before), then every row's and twice it.
fn strides_for(size: (u32, u32)) -> Result<Vec<u16>, Error> {
    let mut all = STRIDES.to_vec();
    for depth in DEPTHS {
        for s in TABLE_STRIDES {
            let d = row_stride(size, depth, s)?;
            for stride in [d, 2 * d] {
                if !all.contains(&stride) {
                    all.push(stride);
                }
            }
        }
    }
    Ok(all)
}

/// The strides whose steady-state flash work a row needs.
fn row_strides(size: (u32, u32)) -> Result<Vec<u16>, Error> {
    let mut all = Vec::new();
    for depth in DEPTHS {
        for s in TABLE_STRIDES {
            let d = row_stride(size, depth, s)?;
            if !all.contains(&d) {
                all.push(d);
            }
        }
    }
    all.sort_unstable();
    Ok(all)
}

/// Streams `seq` at each of `strides` in turn to `client`, as
/// [`pixelcost::measure`] does, without asking for a clock; the
/// frames it scanned (up to a full log).
fn stream_strides<L: Link>(
    client: &mut Client<L>,
    seq: &Sequence,
    strides: &[u16],
) -> Result<usize, Error> {
    let mut frames = 0;
    for &stride in strides {
        let vcfg = VoxelConfig {
            stride,
            ..VoxelConfig::default()
        };
        let scan = scan::scan_config(seq, &vcfg)?;
        let cfg = scan::device_config(&scan, &SELECTOR)?;
        let report = scan::stream(
            client,
            seq,
            &cfg,
            PROFILE,
            &StreamOptions::replacing(),
            None,
        )?;
        frames += report.log_full_at.unwrap_or(report.frames);
    }
    Ok(frames)
}

/// The flash work of `seq` streamed at each of `strides` in turn on the
/// host's model of the Pico ([`PicoFlashLink`], booted with an erased log).
pub fn host_flash_count(seq: &Sequence, strides: &[u16]) -> Result<(usize, FlashCount), Error> {
    let mut client = Client::new(PicoFlashLink::new()?);
    let frames = stream_strides(&mut client, seq, strides)?;
    Ok((frames, client.into_link().count()))
}

/// The flash work of `seq` streamed at each of `strides` in turn as the
/// emulator is streamed ([`pixelcost::stream_warmed`], its status taken
/// after `warm_up` frames too) on the host's model of the Pico: the frames
/// streamed, warm-up included, and their count.
fn host_flash_count_warmed(
    seq: &Sequence,
    strides: &[u16],
    warm_up: usize,
) -> Result<(usize, FlashCount), Error> {
    let mut client = Client::new(PicoFlashLink::new()?);
    let mut frames = 0;
    for &stride in strides {
        let cfg = pixelcost::config_at(seq, &VoxelConfig::default(), SELECTOR, stride)?;
        frames += pixelcost::stream_warmed(&mut client, seq, &cfg, PROFILE, warm_up)?.frames;
    }
    Ok((frames, client.into_link().count()))
}

/// `emulated` (the first frames of a sequence, the first `warm_up` of them
/// not counted) on a freshly booted emulated Pico at every stride it needs;
/// `long` (the whole sequence) through the host's flash count at every
/// row's stride.
fn measure(
    name: &'static str,
    emulated: &Sequence,
    warm_up: usize,
    long: &Sequence,
) -> Result<Measured, Error> {
    let size = (u32::from(emulated.size.0), u32::from(emulated.size.1));
    let strides = strides_for(size)?;
    let firmware = rp2040::built_firmware()?;
    let options = Rp2040Options {
        deadline: Duration::from_secs(3600),
        // CPU cycles only; the flash time is added from the counts.
        flash_timing: FlashTiming::None,
        ..Rp2040Options::default()
    };
    let board = Rp2040::start_with(&firmware, &options).map_err(|e| {
        format!(
            "cannot start the RP2040 emulator: {}",
            crate::error::io_words(&e)
        )
    })?;
    let mut client = Client::new(board);
    let runs = pixelcost::measure_strides_warmed(
        &mut client,
        emulated,
        &VoxelConfig::default(),
        SELECTOR,
        PROFILE,
        &strides,
        warm_up,
    )?;
    let costs: Vec<StrideCost> = runs.iter().map(|r| r.0).collect();
    let warm: Vec<StrideCost> = runs.iter().map(|r| r.1).collect();
    let console = client.into_link().stop();
    let count = |field: &str| -> Result<u64, Error> {
        console
            .lines()
            .filter(|l| l.starts_with("stats"))
            .flat_map(str::split_whitespace)
            .find_map(|w| w.strip_prefix(field)?.strip_prefix('=')?.parse().ok())
            .ok_or_else(|| format!("the emulator reported no {field}: {console}").into())
    };
    let emulator = FlashCount {
        erases: count("sectors_erased")?,
        programs: count("pages_programmed")?,
    };
    let (frames, host) = host_flash_count_warmed(emulated, &strides, warm_up)?;
    let cost = PixelCost::of(costs[0], costs[1])?;
    let mut flash = Vec::new();
    for d in row_strides(size)? {
        let (frames, count) = host_flash_count(long, &[d])?;
        flash.push((d, Flash { frames, count }));
    }
    Ok(Measured {
        name,
        size,
        cost,
        warm_up,
        strides: costs,
        warm,
        flash,
        check: FlashCheck {
            frames,
            emulator,
            host,
        },
    })
}

/// `bench --pico`: `frames` of 7scenes-1000 (in `data`) and twice as many
/// synthetic ones on the emulator; the flash work of all of 7scenes-1000
/// and of the 600-frame synthetic demo scan on the host; a table, or one
/// JSON object with `json`.
pub fn run(data: &Path, frames: usize, warm_up: usize, json: bool) -> Result<(), Error> {
    let dir = data.join("7scenes-1000");
    let real = read::open(&dir, &ReadOptions::default())?;
    let mut real_first = read::open(&dir, &ReadOptions::default())?;
    real_first.frames.truncate(warm_up + frames);
    let demo = SynthConfig {
        frames: SYNTHETIC_FLASH_FRAMES,
        ..SynthConfig::demo()
    };
    let synthetic = synth::sequence(&demo);
    let mut synthetic_first = synth::sequence(&demo);
    synthetic_first.frames.truncate(warm_up + 2 * frames);
    let runs = [
        measure("7scenes-1000", &real_first, warm_up, &real)?,
        measure("synthetic", &synthetic_first, warm_up, &synthetic)?,
    ];
    let mut rows = Vec::new();
    for depth in DEPTHS {
        for s in TABLE_STRIDES {
            for m in &runs {
                rows.push(m.row(depth, s)?);
            }
        }
    }
    if json {
        print_json(&runs, &rows);
    } else {
        print_table(&runs, &rows);
    }
    Ok(())
}

fn count_json(c: FlashCount) -> serde_json::Value {
    serde_json::json!({"erases": c.erases, "programs": c.programs})
}

fn print_json(runs: &[Measured], rows: &[Row]) {
    let by_name = |f: &dyn Fn(&Measured) -> serde_json::Value| {
        runs.iter()
            .map(|m| (m.name.to_string(), f(m)))
            .collect::<serde_json::Map<_, _>>()
    };
    let fps: Vec<_> = rows
        .iter()
        .map(|r| {
            serde_json::json!({
                "depth": format!("{}x{}", r.depth.0, r.depth.1),
                "stride": r.stride,
                "sequence": r.name,
                "pico": r.fps(true),
                "usb": r.usb,
                "pico_without_flash": r.fps(false),
                "measured_at_stride": r.measured_at,
                "samples": r.samples,
                "valid_samples": r.valid,
                "cycles_per_valid_pixel": r.per_pixel,
                "cycles_per_frame": r.per_frame,
                "flash_ms_per_frame": r.flash_s * 1e3,
            })
        })
        .collect();
    let out = serde_json::json!({
        "clock_hz": CLOCK_HZ,
        "cycles_per_valid_pixel": by_name(&|m| m.per_pixel().into()),
        "core_cycles_per_valid_pixel": by_name(&|m| m.core_per_pixel().into()),
        "cycles_per_frame": by_name(&|m| m.per_frame().into()),
        "warm_up": by_name(&|m| m.warm_up.into()),
        "emulated": by_name(&|m| m.strides.iter().zip(&m.warm).map(|(c, w)| serde_json::json!({
            "stride": c.stride,
            "frames": c.frames,
            "cycles": c.ticks * CYCLES_PER_TICK,
            "core_cycles": c.core * CYCLES_PER_TICK,
            "valid_pixels": c.pixels,
            "warm_up": {
                "frames": w.frames,
                "cycles": w.ticks * CYCLES_PER_TICK,
                "valid_pixels": w.pixels,
            },
        })).collect::<Vec<_>>().into()),
        "flash": by_name(&|m| m.flash.iter().map(|(stride, f)| serde_json::json!({
            "stride": stride,
            "frames": f.frames,
            "erases": f.count.erases,
            "programs": f.count.programs,
            "ms_per_frame": f.seconds_per_frame() * 1e3,
        })).collect::<Vec<_>>().into()),
        "flash_check": by_name(&|m| serde_json::json!({
            "frames": m.check.frames,
            "emulator": count_json(m.check.emulator),
            "host": count_json(m.check.host),
            "agree": m.check.emulator == m.check.host,
        })),
        "fps": fps,
    });
    println!("{out}");
}

fn print_table(runs: &[Measured], rows: &[Row]) {
    let [fine, coarse] = STRIDES;
    let warm_up = runs.first().map_or(0, |m| m.warm_up);
    println!(
        "Pico (RP2040 emulator, Cortex-M0+), profile {PROFILE}: cycles per valid pixel, marginal \
         between strides {fine} and {coarse}, protocol included; cycles per frame besides its pixels; \
         each stride's scan after a warm-up of {warm_up} frames at that stride, not counted (window \
         {}: {})",
        SELECTOR.window,
        if warm_up >= usize::from(SELECTOR.window) {
            "the frames measured meet a full window, as in a long scan"
        } else {
            "NOT FULL: the frames measured cost less than a long scan's"
        }
    );
    println!(
        "{:<14} {:>6} {:>10} {:>9} {:>11}",
        "sequence", "frames", "cycles/px", "core/px", "cycles/frm"
    );
    for m in runs {
        println!(
            "{:<14} {:>6} {:>10} {:>9} {:>11}",
            m.name,
            m.cost.fine.frames,
            figure(m.per_pixel(), 1),
            figure(m.core_per_pixel(), 1),
            figure(m.per_frame(), 0),
        );
    }
    println!(
        "\nflash work at steady state (counted on the host: the firmware's device and log on a \
         simulated flash), typical timing: erases x {:.0} ms + pages x {:.1} ms over the frames",
        ERASE_S * 1e3,
        PROGRAM_S * 1e3
    );
    println!(
        "{:<14} {:>6} {:>6} {:>8} {:>8} {:>12}",
        "sequence", "stride", "frames", "erases", "pages", "flash ms/frm"
    );
    for m in runs {
        for (stride, f) in &m.flash {
            println!(
                "{:<14} {:>6} {:>6} {:>8} {:>8} {:>12}",
                m.name,
                stride,
                f.frames,
                f.count.erases,
                f.count.programs,
                figure(f.seconds_per_frame() * 1e3, 2)
            );
        }
    }
    for m in runs {
        let c = &m.check;
        println!(
            "{}: the emulator's {} frames (strides {}): emulator {} erases {} pages, host {} \
             erases {} pages: {}",
            m.name,
            c.frames,
            m.strides
                .iter()
                .map(|s| s.stride.to_string())
                .collect::<Vec<_>>()
                .join(","),
            c.emulator.erases,
            c.emulator.programs,
            c.host.erases,
            c.host.programs,
            if c.emulator == c.host {
                "equal"
            } else {
                "DIFFERENT: the steady-state flash figures are not the firmware's"
            }
        );
    }
    println!(
        "\nframes/s at {:.0} MHz, every pixel valid: each row measured at the sequence's stride \
         that samples as its camera (at), its cycles a frame = the measured cycles of a frame \
         there + its invalid samples x the marginal cycles of a valid pixel between that stride \
         and twice it (cycles/px); then its flash time at steady state",
        CLOCK_HZ / 1e6
    );
    println!(
        "{:<8} {:>6} {:<14} {:>3} {:>6} {:>9} {:>10} {:>9} {:>8} {:>13} {:>7}",
        "depth",
        "stride",
        "sequence",
        "at",
        "valid",
        "cycles/px",
        "Mcycles/frm",
        "flash ms",
        "pico",
        "pico no flash",
        "usb"
    );
    for r in rows {
        println!(
            "{:<8} {:>6} {:<14} {:>3} {:>5}% {:>9} {:>10} {:>9} {:>8} {:>13} {:>7}",
            format!("{}x{}", r.depth.0, r.depth.1),
            r.stride,
            r.name,
            r.measured_at,
            figure(100.0 * r.valid / r.samples, 0),
            figure(r.per_pixel, 1),
            figure(r.per_frame / 1e6, 3),
            figure(r.flash_s * 1e3, 2),
            figure(r.fps(true), 1),
            figure(r.fps(false), 1),
            figure(r.usb, 1)
        );
    }
}
