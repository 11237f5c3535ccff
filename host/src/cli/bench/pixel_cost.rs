//! What one valid pixel costs a device: the same frames streamed at two
//! strides; the difference in device clock ticks over the difference in
//! valid pixels is the cost of one more valid pixel (what a frame costs
//! besides its pixels cancels out). The device's [`FrameCost::core`] splits
//! it into the core's share (projection, voxel set, selection) and the
//! protocol's (COBS, CRC, message decoding, copying the samples, dispatch).
//!
//! Ticks are the device clock's: instructions on the QEMU board under
//! `-icount shift=0` (exact up to the 40 instructions of one SysTick tick per
//! clock reading), microseconds of the RP2040's timer on the Pico.
//!
//! [`FrameCost::core`]: placedb::protocol::FrameCost::core

use crate::board::client::Client;
use crate::board::error::DeviceError;
use crate::board::link::Link;
use crate::board::scan::{self, ScanState, StreamOptions};
use crate::{Sequence, VoxelConfig};
use placedb::protocol::{Config, HostMessage, Status};
use placedb::SelectorConfig;

/// The strides compared (fine, coarse), as `placedb bench --device`, the
/// README's figures and host/tests/board_qemu.rs use them.
pub const STRIDES: [u16; 2] = [2, 4];

/// The selection settings of those measurements (`placedb stream`'s mu, the
/// default sketch margin, a 16-frame window).
pub const SELECTOR: SelectorConfig = SelectorConfig {
    mu: 0.3,
    window: 16,
    sketch_margin: 0.05,
};

/// The device's cost of a scan at one stride, per frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StrideCost {
    /// Pixel stride.
    pub stride: u16,
    /// Frames measured.
    pub frames: u32,
    /// Device clock ticks per frame.
    pub ticks: f64,
    /// Of those, ticks inside the core.
    pub core: f64,
    /// Valid pixels per frame.
    pub pixels: f64,
    /// Bytes the host sent per frame.
    pub bytes: f64,
}

impl StrideCost {
    /// The per-frame figures of `frames` frames at `stride` from their
    /// totals: ticks, core ticks, valid pixels and bytes sent.
    fn of_totals(stride: u16, frames: u32, [ticks, core, pixels, bytes]: [u64; 4]) -> StrideCost {
        let per = |x: u64| x as f64 / f64::from(frames.max(1));
        StrideCost {
            stride,
            frames,
            ticks: per(ticks),
            core: per(core),
            pixels: per(pixels),
            bytes: per(bytes),
        }
    }
}

/// The cost of the same frames at a fine and a coarse stride.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelCost {
    /// The fine stride's cost.
    pub fine: StrideCost,
    /// The coarse stride's cost.
    pub coarse: StrideCost,
}

impl PixelCost {
    /// Ticks per valid pixel, everything included.
    pub fn per_pixel(&self) -> f64 {
        self.marginal(|s| s.ticks)
    }

    /// Ticks per valid pixel inside the core.
    pub fn core_per_pixel(&self) -> f64 {
        self.marginal(|s| s.core)
    }

    /// Ticks per valid pixel of the protocol (the rest).
    pub fn protocol_per_pixel(&self) -> f64 {
        self.per_pixel() - self.core_per_pixel()
    }

    /// Ticks per frame besides its valid pixels.
    pub fn per_frame(&self) -> f64 {
        self.coarse.ticks - self.per_pixel() * self.coarse.pixels
    }

    fn marginal(&self, ticks: impl Fn(&StrideCost) -> f64) -> f64 {
        (ticks(&self.fine) - ticks(&self.coarse)) / (self.fine.pixels - self.coarse.pixels)
    }
}

/// Streams every frame of `seq` at each of `strides` (fine first) with the
/// rest of `vcfg`, `sel` and device profile `profile`, and returns what the
/// device reported. The device needs a clock; the scan is reset each time.
pub fn measure<L: Link>(
    client: &mut Client<L>,
    seq: &Sequence,
    vcfg: &VoxelConfig,
    sel: SelectorConfig,
    profile: &str,
    strides: [u16; 2],
) -> Result<PixelCost, DeviceError> {
    let mut runs = Vec::with_capacity(strides.len());
    for stride in strides {
        let cfg = config_at(seq, vcfg, sel, stride)?;
        let report = scan::stream(
            client,
            seq,
            &cfg,
            profile,
            &StreamOptions::replacing(),
            None,
        )?;
        let (st, c) = (&report.status, &report.status.cost);
        if c.clock_hz == 0 || c.frames == 0 {
            return Err(DeviceError::Input(
                "the device has no clock: it cannot measure its cost".into(),
            ));
        }
        runs.push(StrideCost::of_totals(
            stride,
            c.frames,
            [c.total, c.core, st.valid_pixels, report.bytes_sent],
        ));
    }
    let [fine, coarse] = <[StrideCost; 2]>::try_from(runs)
        .map_err(|_| DeviceError::Input("one cost per stride".into()))?;
    PixelCost::of(fine, coarse)
}

impl PixelCost {
    /// The cost of `fine` and `coarse`, which must differ in valid pixels.
    pub fn of(fine: StrideCost, coarse: StrideCost) -> Result<PixelCost, DeviceError> {
        if fine.pixels <= coarse.pixels {
            return Err(DeviceError::Input(format!(
                "stride {} saw no more valid pixels than stride {}",
                fine.stride, coarse.stride
            )));
        }
        Ok(PixelCost { fine, coarse })
    }
}

/// One scan at one stride whose first frames only warm the device up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WarmedScan {
    /// The device's status after the warm-up frames (before any measured
    /// one): its counters since the scan's Reset cover the warm-up alone.
    pub warm: Status,
    /// Its status after the measured frames and Finish.
    pub end: Status,
    /// Bytes sent by the end of the warm-up, and by the end.
    pub warm_bytes: u64,
    pub end_bytes: u64,
    /// Frames streamed in all, warm-up included.
    pub frames: usize,
}

/// Streams `seq` to `client` as [`scan::stream`] does (Reset, Hello with
/// `cfg`, each frame followed by a StatusRequest, Finish), with the status
/// taken once more after its first `warm_up` frames. A Reset clears the
/// device's window (and its cost counters), so every scan needs its own
/// warm-up: the frames after it meet a window as full as a long scan's.
pub fn stream_warmed<L: Link>(
    client: &mut Client<L>,
    seq: &Sequence,
    cfg: &Config,
    profile: &str,
    warm_up: usize,
) -> Result<WarmedScan, DeviceError> {
    let n = seq.frames.len();
    if warm_up >= n {
        return Err(DeviceError::Input(format!(
            "a warm-up of {warm_up} frames leaves none of {n} to measure"
        )));
    }
    // A measurement: the board's earlier scan (a bench's, usually) goes.
    let mut state = ScanState::new(StreamOptions::replacing());
    state.begin(client, cfg, Some(profile), None)?;
    let mut warm = None;
    for i in 0..n {
        if i == warm_up {
            state.drain(client)?;
            warm = Some((state.call_status(client)?, state.bytes_sent()));
        }
        state.push_sequence_frame(client, seq, i, cfg.intrinsics)?;
        state.send(client, HostMessage::StatusRequest, || {
            "StatusRequest".into()
        })?;
    }
    state.send(client, HostMessage::Finish, || "Finish".into())?;
    state.drain(client)?;
    let end = state.call_status(client)?;
    let (warm, warm_bytes) = warm.ok_or_else(|| DeviceError::Input("no warm-up status".into()))?;
    Ok(WarmedScan {
        warm,
        end,
        warm_bytes,
        end_bytes: state.bytes_sent(),
        frames: n,
    })
}

/// The scan's config for `seq` at `stride` with the rest of `vcfg` and `sel`.
pub fn config_at(
    seq: &Sequence,
    vcfg: &VoxelConfig,
    sel: SelectorConfig,
    stride: u16,
) -> Result<Config, DeviceError> {
    let vcfg = VoxelConfig { stride, ..*vcfg };
    scan::device_config(&scan::scan_config(seq, &vcfg)?, &sel)
}

/// [`measure_strides`] at steady state: each stride's scan streams the
/// first `warm_up` frames of `seq` first, not counted (their ticks, pixels
/// and bytes are the status's before the measured frames, subtracted), so
/// that the frames measured meet a full window as in a long scan. Each
/// stride's cost of its measured frames, and of its warm-up apart.
pub fn measure_strides_warmed<L: Link>(
    client: &mut Client<L>,
    seq: &Sequence,
    vcfg: &VoxelConfig,
    sel: SelectorConfig,
    profile: &str,
    strides: &[u16],
    warm_up: usize,
) -> Result<Vec<(StrideCost, StrideCost)>, DeviceError> {
    let mut runs = Vec::with_capacity(strides.len());
    for &stride in strides {
        let cfg = config_at(seq, vcfg, sel, stride)?;
        let r = stream_warmed(client, seq, &cfg, profile, warm_up)?;
        let (w, e) = (&r.warm.cost, &r.end.cost);
        if e.clock_hz == 0 || e.frames <= w.frames {
            return Err(DeviceError::Input(
                "the device has no clock: it cannot measure its cost".into(),
            ));
        }
        let measured = StrideCost::of_totals(
            stride,
            e.frames - w.frames,
            [
                e.total.saturating_sub(w.total),
                e.core.saturating_sub(w.core),
                r.end.valid_pixels.saturating_sub(r.warm.valid_pixels),
                r.end_bytes.saturating_sub(r.warm_bytes),
            ],
        );
        let warm = StrideCost::of_totals(
            stride,
            w.frames,
            [w.total, w.core, r.warm.valid_pixels, r.warm_bytes],
        );
        runs.push((measured, warm));
    }
    Ok(runs)
}
