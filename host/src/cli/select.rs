//! `placedb select`: one solver on a sequence, the database directory
//! written (and a dataset when asked), a summary printed.

use super::{open_sequence, print_dataset, solver_params};
use super::{ParamArgs, SeqArgs};
use crate::degradation::{self, plural};
use crate::error::CommandError as Error;
use crate::output::{self, exports};
use crate::pipeline::Solver;
use crate::Sequence;
use clap::Args;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

pub mod extend;
pub mod selection;

pub use extend::ExtendedSelection;
pub use selection::{Selection, Written};

#[derive(Args)]
pub struct SelectArgs {
    #[command(flatten)]
    seq: SeqArgs,
    /// Output directory for database.csv, labels.csv, metrics.json, topview.png.
    #[arg(short, long)]
    out: PathBuf,
    /// Also write a training-ready dataset here: color/, depth/, poses.txt,
    /// intrinsics.txt and classes.csv of every frame, and database/ (the reference code's layout).
    #[arg(long)]
    dataset: Option<PathBuf>,
    /// Which solver or baseline.
    #[arg(long, value_enum, default_value_t = Solver::Online)]
    solver: Solver,
    /// IoU threshold, from 0 to below 1: frames overlap when IoU > mu.
    #[arg(long, default_value_t = 0.3, value_parser = super::params::mu, allow_negative_numbers = true)]
    mu: f32,
    #[command(flatten)]
    params: ParamArgs,
    #[command(flatten)]
    exports: super::ExportFlags,
    /// Add this sequence as a new session to the database in this earlier
    /// output directory (its extension file; the earlier sequences need not
    /// be present): its database frames are kept, only what the new frames
    /// need is added (docs/SESSIONS.md).
    #[arg(long, value_name = "OUT_A")]
    extend: Option<PathBuf>,
}

impl SelectArgs {
    /// Reads the sequence these arguments name (or renders `--demo`).
    pub fn open_sequence(&self) -> Result<Sequence, Error> {
        open_sequence(&self.seq)
    }

    /// Refuses what takes two options to see (`--window` above
    /// `--profile`'s window), as the command does before any work.
    pub fn check(&self) -> Result<(), Error> {
        solver_params(&self.params).map(|_| ())
    }

    /// `--extend`'s directory, when a later session is asked for.
    pub fn extend(&self) -> Option<&Path> {
        self.extend.as_deref()
    }
}

/// Runs `placedb select`.
pub fn run(a: SelectArgs) -> Result<(), Error> {
    if let Some(from) = a.extend.clone() {
        return extend::run(a, &from);
    }
    let t0 = Instant::now();
    solver_params(&a.params)?;
    // A refused or unwritable output fails the run before the work.
    let targets = a.exports.targets();
    output::check_outputs(&a.out, a.dataset.as_deref(), &targets)?;
    let seq = a.open_sequence()?;
    if let Some(file) = &targets.pairs {
        // A colour file the pairs cannot name fails the run before the work.
        exports::pairs::names(&seq, file)?;
    }
    super::warn_voxel_memory(&seq, &a.seq);
    let sel = Selection::compute(Arc::new(seq), &a, t0)?;
    let Written { dataset, exported } = sel.write(&a.out, a.dataset.as_deref(), &targets)?;
    let (seq, prep, o, params) = (&*sel.seq, &sel.prep, &sel.outcome, &sel.params);
    let json = &sel.json;
    if a.params.json {
        println!("{}", serde_json::to_string_pretty(json)?);
    } else if !a.params.quiet {
        let m = &o.metrics;
        println!(
            "{}: {} -> {} ({:.1}x reduction) with solver {} at mu {}",
            seq.name,
            plural(seq.frames.len() as u64, "frame", "frames"),
            plural(m.size as u64, "database frame", "database frames"),
            m.reduction,
            o.solver.name(),
            a.mu
        );
        println!("{}", o.losses(prep).summary_line());
        println!(
            "  uncovered {}  spatial coverage {:.3}  frame coverage mean {:.3} min {:.3} (<0.3: {:.1}%)",
            m.uncovered,
            m.spatial_coverage,
            m.frames_coverage_mean,
            m.frames_coverage_min,
            100.0 * m.frames_coverage_below_0_3
        );
        if let Some(r) = m.oracle_recall_0_3 {
            println!("  oracle_recall@0.3 on the test sequence: {r:.3}");
        }
        if let Some((optimal, lb)) = o.exact {
            println!(
                "  exact: {} (lower bound {lb})",
                if optimal {
                    "proven minimum"
                } else {
                    "time limit hit, not proven"
                }
            );
        }
        if let Some(run) = &o.online {
            let line = degradation::online_summary(&params.profile, params.window, &run.status);
            println!("  {line}");
        }
        println!("  database frames: {:?}", o.database);
        println!(
            "  time: voxelize {:.3} s, overlaps {:.3} s, solve {:.3} s, total {:.3} s",
            prep.voxelize_wall.as_secs_f64(),
            prep.graph_wall.as_secs_f64(),
            o.solve_time.as_secs_f64(),
            t0.elapsed().as_secs_f64()
        );
        println!(
            "  wrote {}/{{database.csv,labels.csv,metrics.json,topview.png,extension.bin}}",
            a.out.display()
        );
        if let Some((dir, d)) = &dataset {
            print_dataset(dir, d);
        }
        for line in &exported {
            println!("{line}");
        }
    }
    Ok(())
}
