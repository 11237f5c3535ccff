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

use crate::device::client::Client;
use crate::device::error::DeviceError;
use crate::device::link::Link;
use crate::device::scan::{self, StreamOptions};
use crate::{Sequence, VoxelConfig};
use placedb::SelectorConfig;

/// The strides compared (fine, coarse), as `placedb bench --device`, the
/// README's figures and tests/end_to_end.rs use them.
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
    let runs = measure_strides(client, seq, vcfg, sel, profile, &strides)?;
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

/// Streams every frame of `seq` at each of `strides` in turn, as
/// [`measure`] does; the device's cost at each.
pub fn measure_strides<L: Link>(
    client: &mut Client<L>,
    seq: &Sequence,
    vcfg: &VoxelConfig,
    sel: SelectorConfig,
    profile: &str,
    strides: &[u16],
) -> Result<Vec<StrideCost>, DeviceError> {
    let mut runs = Vec::with_capacity(strides.len());
    for &stride in strides {
        let vcfg = VoxelConfig { stride, ..*vcfg };
        let scan = scan::scan_config(seq, &vcfg)?;
        let cfg = scan::device_config(&scan, &sel)?;
        let report = scan::stream(client, seq, &cfg, profile, &StreamOptions::default(), None)?;
        let st = &report.status;
        if st.cost.clock_hz == 0 || st.cost.frames == 0 {
            return Err(DeviceError::Input(
                "the device has no clock: it cannot measure its cost".into(),
            ));
        }
        let frames = f64::from(st.cost.frames);
        runs.push(StrideCost {
            stride,
            frames: st.cost.frames,
            ticks: st.cost.total as f64 / frames,
            core: st.cost.core as f64 / frames,
            pixels: st.valid_pixels as f64 / frames,
            bytes: report.bytes_sent as f64 / frames,
        });
    }
    Ok(runs)
}
