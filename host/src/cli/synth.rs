//! `placedb synth`: the built-in synthetic office (or a building) written
//! as a TUM RGB-D sequence, all or nothing.

use super::params;
use crate::error::CommandError as Error;
use crate::output::replace;
use crate::synth::{self, SynthConfig};
use clap::Args;
use std::path::PathBuf;

#[derive(Args)]
pub struct SynthArgs {
    /// Output directory (TUM layout).
    out: PathBuf,
    /// Number of frames, 1 to 1000000.
    #[arg(long, default_value_t = 600, value_parser = params::whole::<usize>(1, params::MAX_SYNTH_FRAMES), allow_negative_numbers = true)]
    frames: usize,
    /// Image width, 2 to 8192 pixels.
    #[arg(long, default_value_t = 320, value_parser = params::whole::<u16>(2, placedb::Intrinsics::MAX_SIDE.into()), allow_negative_numbers = true)]
    width: u16,
    /// Image height, 2 to 8192 pixels.
    #[arg(long, default_value_t = 240, value_parser = params::whole::<u16>(2, placedb::Intrinsics::MAX_SIDE.into()), allow_negative_numbers = true)]
    height: u16,
    /// Seed of the furniture layout.
    #[arg(long, default_value_t = 1, value_parser = params::whole::<u64>(0, u64::MAX), allow_negative_numbers = true)]
    seed: u64,
    /// Number of rooms off the corridor, 1 to 1000.
    #[arg(long, default_value_t = 4, value_parser = params::whole::<usize>(1, 1000), allow_negative_numbers = true)]
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
    // An impossible configuration or a refused target fails before
    // anything is made.
    cfg.check()?;
    replace::check_dir(&a.out, synth::SYNTH_OUTPUT, synth::is_synth_output)?;
    let seq = synth::sequence(&cfg);
    let pb = indicatif::ProgressBar::new(seq.frames.len() as u64);
    replace::together(|outputs| {
        let dir = outputs.dir(&a.out, synth::SYNTH_OUTPUT, synth::is_synth_output)?;
        Ok(synth::write_tum(&seq, &dir, Some(&pb))?)
    })?;
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
