//! `placedb synth`: the built-in synthetic office (or a building) written
//! as a TUM RGB-D sequence.

use crate::error::CommandError as Error;
use crate::synth::{self, SynthConfig};
use clap::Args;
use std::path::PathBuf;

#[derive(Args)]
pub struct SynthArgs {
    /// Output directory (TUM layout).
    out: PathBuf,
    /// Number of frames.
    #[arg(long, default_value_t = 600)]
    frames: usize,
    /// Image width.
    #[arg(long, default_value_t = 320)]
    width: u16,
    /// Image height.
    #[arg(long, default_value_t = 240)]
    height: u16,
    /// Seed of the furniture layout.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Number of rooms off the corridor.
    #[arg(long, default_value_t = 4)]
    rooms: usize,
}

/// Runs `placedb synth`.
pub fn run(a: SynthArgs) -> Result<(), Error> {
    let cfg = SynthConfig {
        frames: a.frames,
        width: a.width,
        height: a.height,
        seed: a.seed,
        rooms: a.rooms,
    };
    let seq = synth::sequence(&cfg);
    let pb = indicatif::ProgressBar::new(seq.frames.len() as u64);
    synth::write_tum(&seq, &a.out, Some(&pb))?;
    pb.finish_and_clear();
    println!(
        "wrote {} frames of {}x{} to {} (TUM layout)",
        seq.frames.len(),
        a.width,
        a.height,
        a.out.display()
    );
    Ok(())
}
