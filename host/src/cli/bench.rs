//! `placedb bench`: its arguments and its measurements, each in a file of
//! its own: the timing table ([`timing`]), and instruction counts
//! ([`instructions`]): per pixel on the QEMU board ([`pixel_cost`]), one
//! frame against a small and a large database ([`db_scaling`]), the Pico's
//! cycles under rp2040js ([`pico`], with its flash work [`flash_count`]).

use crate::error::CommandError as Error;
use crate::pipeline::Solver;
use clap::Args;
use std::path::PathBuf;

pub mod db_scaling;
pub mod flash_count;
pub mod instructions;
pub mod pico;
pub mod pixel_cost;
pub mod timing;

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
    /// `--bag`: recordings of the 7scenes-1000 frames whose reading the
    /// timing table compares with reading the PNG files.
    pub bags: Vec<PathBuf>,
    /// `--python`: an interpreter with the placedb package, for a row per
    /// solver of the Python API beside the command's.
    pub python: Option<PathBuf>,
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

#[derive(Args)]
pub struct BenchArgs {
    /// Directory holding the recorded samples (7scenes-1000, vprdb-test-db);
    /// default: ../shared/data from the current directory, else the
    /// shared/data beside the repository placedb was built from.
    #[arg(long)]
    data: Option<PathBuf>,
    /// Solvers to time, comma separated.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "in-order,greedy,exact,online"
    )]
    solvers: Vec<Solver>,
    /// Pixel stride, from 1 to 64 (as select's).
    #[arg(long, default_value_t = 1, value_parser = super::params::whole::<u16>(1, 64), allow_negative_numbers = true)]
    stride: u16,
    /// Frames of the synthetic scan.
    #[arg(long, default_value_t = 5000, value_parser = super::params::whole::<usize>(1, super::params::MAX_SYNTH_FRAMES), allow_negative_numbers = true)]
    synthetic_frames: usize,
    /// Instead: count the core's instructions per frame and per valid pixel
    /// with valgrind's callgrind (repeatable counts, not seconds).
    #[arg(long)]
    core: bool,
    /// With --core: frames of 7scenes-1000 to replay.
    #[arg(long, default_value_t = 20, value_parser = super::params::whole::<usize>(1, super::params::MAX_SYNTH_FRAMES), allow_negative_numbers = true)]
    core_frames: usize,
    /// Instead: count the instructions per valid pixel of the QEMU board's
    /// Cortex-M4F firmware (-icount shift=0), protocol included, and the
    /// core's share: the same frames at strides 2 and 4.
    #[arg(long)]
    device: bool,
    /// With --device: frames of 7scenes-1000 (twice as many synthetic ones).
    #[arg(long, default_value_t = 3, value_parser = super::params::whole::<usize>(1, super::params::MAX_SYNTH_FRAMES), allow_negative_numbers = true)]
    device_frames: usize,
    /// Instead: the Pico's Cortex-M0+ under the RP2040 emulator: cycles per
    /// valid pixel and per frame (the --device frames at strides 2 and 4),
    /// and the frames/s it sustains beside what USB full speed carries, each
    /// row measured at its own sampling density, with the flash time of a
    /// whole scan at that density (its erases and programs counted on the
    /// host).
    #[arg(long)]
    pico: bool,
    /// With --pico: frames of each stride's scan streamed before the
    /// measured ones and not counted, so that those meet a full window as
    /// in a long scan (default: the 16 frames the window holds).
    #[arg(long, requires = "pico", default_value_t = usize::from(pixel_cost::SELECTOR.window), value_parser = super::params::whole::<usize>(0, super::params::MAX_SYNTH_FRAMES), allow_negative_numbers = true)]
    warm_up: usize,
    /// With --pico: print one JSON object instead of the tables.
    #[arg(long, requires = "pico")]
    json: bool,
    /// Instead: count with callgrind the instructions of one frame decided
    /// against a database of 10 frames and of ~900 (a synthetic building at
    /// mu 0.5 on the ram256k device, its database restored from flash).
    #[arg(long)]
    db_scaling: bool,
    /// With --db-scaling: frames of the building (40 rooms).
    #[arg(long, default_value_t = 20_000, value_parser = super::params::whole::<usize>(1, super::params::MAX_SYNTH_FRAMES), allow_negative_numbers = true)]
    building_frames: usize,
    /// Internal (the callgrind child of --db-scaling): the flash image.
    #[arg(long, hide = true)]
    db_probe: Option<PathBuf>,
    /// Rounds of the timing table, each running every row of a sequence in
    /// turn; a row is its run of median wall time, a ratio to the floor the
    /// median of the rounds' (a single run of a half-second job moves by
    /// 10 % and more, and the machine's speed drifts).
    #[arg(long, default_value_t = 3, value_parser = super::params::whole::<u32>(1, 1000), allow_negative_numbers = true)]
    repeat: u32,
    /// A recording of the 7scenes-1000 frames (a ROS 2 or ROS 1 bag, say),
    /// repeatable: the timing table reads it beside the PNG files, each
    /// run beside a run of the PNG files' decode-only (the fixture writer
    /// host/tests/recordings/write_recordings.py makes such bags).
    #[arg(long = "bag", value_name = "PATH")]
    bags: Vec<PathBuf>,
    /// A Python interpreter with the placedb package installed (`pip
    /// install ./python`): the timing table gains a row per solver of
    /// `placedb.select(...).write(out)`, beside the command's.
    #[arg(long, value_name = "PYTHON")]
    python: Option<PathBuf>,
    /// Internal (a child of the timing table): only decode every depth
    /// image of this sequence, as select would, and exit.
    #[arg(long, hide = true)]
    decode_only: Option<PathBuf>,
    /// Internal (a child of the timing table): only walk this recording
    /// once (every chunk decompressed, no message decoded), and exit.
    #[arg(long, hide = true)]
    walk_only: Option<PathBuf>,
}

/// Runs `placedb bench`: the timing table, or one of the instruction counts.
pub fn run(a: BenchArgs) -> Result<(), Error> {
    let data = data_dir(a.data.clone());
    let opts = BenchOptions {
        data: data.clone(),
        solvers: a.solvers.clone(),
        stride: a.stride,
        synthetic_frames: a.synthetic_frames,
        core_frames: a.core_frames,
        device_frames: a.device_frames,
        building_frames: a.building_frames,
        repeat: a.repeat,
        bags: a.bags.clone(),
        python: a.python.clone(),
    };
    if a.core {
        return instructions::core_cost(&opts);
    }
    if a.device {
        return instructions::device_cost(&opts);
    }
    if a.pico {
        return pico::run(&data, a.device_frames, a.warm_up, a.json);
    }
    if let Some(flash) = &a.db_probe {
        return Ok(db_scaling::run_probe(flash, a.building_frames)?);
    }
    if a.db_scaling {
        return instructions::db_scaling(&opts);
    }
    if let Some(path) = &a.decode_only {
        return timing::decode_only(path);
    }
    if let Some(path) = &a.walk_only {
        return timing::walk_only(path);
    }
    timing::table(&opts)
}

/// The recorded samples' directory: `given` (`--data`) as it is, else the
/// first of [`default_data_dirs`] that exists, so `placedb bench` finds them
/// from any directory. When none does, the first, with a warning naming
/// both paths tried (the benches that need the samples then say which is
/// missing).
fn data_dir(given: Option<PathBuf>) -> PathBuf {
    if let Some(dir) = given {
        return dir;
    }
    let [cwd, repo] = default_data_dirs();
    if cwd.is_dir() {
        cwd
    } else if repo.is_dir() {
        repo
    } else {
        crate::warning::warn(format!(
            "the recorded samples are in neither {} (from the current directory) nor {}: pass --data DIR",
            cwd.display(),
            repo.display()
        ));
        cwd
    }
}

/// Where `bench` looks for the recorded samples without `--data`:
/// `../shared/data` from the current directory (the repository's root), and
/// the `shared/data` beside the repository this binary was built from.
fn default_data_dirs() -> [PathBuf; 2] {
    let host = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let beside_repo = host
        .parent()
        .and_then(std::path::Path::parent)
        .unwrap_or(host)
        .join("shared")
        .join("data");
    [PathBuf::from("../shared/data"), beside_repo]
}

#[cfg(test)]
mod data_tests {
    use super::{data_dir, default_data_dirs};
    use std::path::PathBuf;

    #[test]
    fn the_default_is_found_beside_the_repository_from_any_directory() {
        // The second default does not depend on the current directory: it
        // is the repository's sibling shared/data, which the tests read.
        let [_, repo] = default_data_dirs();
        assert!(repo.is_absolute(), "{}", repo.display());
        assert!(repo.join("7scenes-1000").is_dir(), "{}", repo.display());
        assert!(data_dir(None).join("7scenes-1000").is_dir());
    }

    #[test]
    fn a_given_directory_is_taken_as_it_is() {
        let given = PathBuf::from("somewhere/else");
        assert_eq!(data_dir(Some(given.clone())), given);
    }
}
