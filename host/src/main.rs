//! The `placedb` command line: select a place-recognition database from a
//! recorded RGB-D sequence (or the built-in synthetic office), compare solvers,
//! write synthetic sequences, print the device budgets.
//!
//! This file defines the command line and dispatches; each subcommand's
//! arguments and printing are in `placedb_host::cli` (host/src/cli/).

use clap::{Parser, Subcommand};
use placedb_host::cli;
use placedb_host::cli::bench::BenchArgs;
use placedb_host::cli::compare::CompareArgs;
use placedb_host::cli::device::DeviceArgs;
use placedb_host::cli::export::ExportArgs;
use placedb_host::cli::select::SelectArgs;
use placedb_host::cli::stream::StreamArgs;
use placedb_host::cli::synth::SynthArgs;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "placedb",
    version,
    about = "Select a compact visual-place-recognition database from an RGB-D scan: \
the frames whose voxelized views dominate every other frame (IoU of 0.3 m voxel sets above mu)."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Select a database from a sequence and write database.csv, labels.csv, metrics.json, topview.png.
    Select(SelectArgs),
    /// Run every solver and baseline on a sequence and print one table side by side.
    Compare(CompareArgs),
    /// Write the built-in synthetic office scan as a TUM RGB-D sequence.
    Synth(SynthArgs),
    /// Print each device capacity profile: exact state size and what it holds.
    Budget,
    /// Measure select's wall time, time split and peak memory on the synthetic
    /// 5000-frame scan and the recorded samples (each run in a child process).
    Bench(BenchArgs),
    /// Stream a sequence to a device (board or emulator) with live status.
    Stream(StreamArgs),
    /// Pull database.csv, labels.csv, metrics.json from a device (resumable, CRC-checked).
    Export(ExportArgs),
    /// Start an emulated board (--qemu: QEMU mps2-an386; --rp2040: the Pico under rp2040js) and print the port to use.
    Device(DeviceArgs),
}

/// A closed stdout (`placedb budget | head`) ends placedb quietly, as it
/// ends any Unix filter, instead of a panic in `println!`: Rust starts every
/// program with SIGPIPE ignored, so the default is put back. Nothing else
/// placedb writes can raise it: std writes sockets with `MSG_NOSIGNAL`, and
/// the emulators' pipes are only read.
#[cfg(unix)]
fn quiet_on_closed_stdout() {
    // SAFETY: sets the disposition of one signal to its default, before any
    // other thread exists.
    unsafe { libc::signal(libc::SIGPIPE, libc::SIG_DFL) };
}

#[cfg(not(unix))]
fn quiet_on_closed_stdout() {}

fn main() -> ExitCode {
    quiet_on_closed_stdout();
    // Ctrl-C leaves no partial output behind (the library alone leaves a
    // host program's signals to it).
    placedb_host::output::replace::remove_partials_on_signal();
    let cli = Cli::parse();
    let r = match cli.command {
        Command::Select(a) => cli::select::run(a),
        Command::Compare(a) => cli::compare::run(a),
        Command::Synth(a) => cli::synth::run(a),
        Command::Budget => cli::budget::run(),
        Command::Bench(a) => cli::bench::run(a),
        Command::Stream(a) => cli::stream::run(a),
        Command::Export(a) => cli::export::run(a),
        Command::Device(a) => cli::device::run(a),
    };
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // An I/O error that reached here bare is said in words too.
            match e.downcast_ref::<std::io::Error>() {
                Some(io) => eprintln!("placedb: error: {}", placedb_host::error::io_words(io)),
                None => eprintln!("placedb: error: {e}"),
            }
            // A refused command line exits as clap's refusals do.
            if e.is::<placedb_host::error::UsageError>() {
                ExitCode::from(2)
            } else {
                ExitCode::FAILURE
            }
        }
    }
}
