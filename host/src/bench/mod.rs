//! `placedb bench`'s measurements: the timing table ([`timing`]), and
//! instruction counts ([`instructions`]): per pixel on the QEMU board
//! ([`pixel_cost`]) and one frame against a small and a large database
//! ([`db_scaling`]).

pub mod db_scaling;
pub mod flash_count;
pub mod instructions;
pub mod pico;
pub mod pixel_cost;
pub mod timing;

use crate::pipeline::Solver;
use std::path::PathBuf;

/// What the measurements of `placedb bench` are run on (its arguments, see
/// `placedb bench --help`).
#[derive(Debug, Clone)]
pub struct BenchOptions {
    /// Directory holding the recorded samples (7scenes-1000, vprdb-test-db).
    pub data: PathBuf,
    /// Solvers of the timing table.
    pub solvers: Vec<Solver>,
    /// Pixel stride.
    pub stride: u16,
    /// Frames of the synthetic scan.
    pub synthetic_frames: usize,
    /// `--core`: frames of 7scenes-1000 to replay.
    pub core_frames: usize,
    /// `--device`: frames of 7scenes-1000 (twice as many synthetic ones).
    pub device_frames: usize,
    /// `--db-scaling`: frames of the building.
    pub building_frames: usize,
    /// Rounds of the timing table.
    pub repeat: u32,
}

/// `x` with `decimals` decimals, or "-" where it does not apply (NaN, or
/// infinite: a figure the run did not report, or a ratio to nothing).
pub fn figure(x: f64, decimals: usize) -> String {
    if x.is_finite() {
        format!("{x:.decimals$}")
    } else {
        "-".to_string()
    }
}
