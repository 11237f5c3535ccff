//! `placedb select`: one solver on a sequence, the database directory
//! written (and a dataset when asked), a summary printed.

use super::{open_sequence, open_test, print_dataset, solver_params, voxel_config};
use super::{ParamArgs, SeqArgs};
use crate::degradation::{self, plural};
use crate::error::CommandError as Error;
use crate::output::{self, dataset, metrics_json, topview};
use crate::output::{annotate, exports, replace};
use crate::pipeline::{self, Solver};
use crate::sessions::{extension, record};
use clap::Args;
use std::path::PathBuf;
use std::time::Instant;

mod extend;

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

/// Runs `placedb select`.
pub fn run(a: SelectArgs) -> Result<(), Error> {
    if let Some(from) = a.extend.clone() {
        return extend::run(a, &from);
    }
    let t0 = Instant::now();
    let params = solver_params(&a.params)?;
    // A refused or unwritable output fails the run before the work.
    let targets = a.exports.targets();
    output::check_outputs(&a.out, a.dataset.as_deref(), &targets)?;
    let seq = open_sequence(&a.seq)?;
    if let Some(file) = &targets.pairs {
        // A colour file the pairs cannot name fails the run before the work.
        exports::pairs::names(&seq, file)?;
    }
    super::warn_voxel_memory(&seq, &a.seq);
    let prep = pipeline::prepare(&seq, voxel_config(&a.seq), a.params.quiet)?;
    // The top view's map and trajectory do not depend on the solver: they
    // are projected on the other thread while it solves.
    let (solved, mut view) = rayon::join(
        || pipeline::solve(&seq, &prep, a.solver, a.mu, &params, a.params.quiet),
        || topview::project(&seq, &prep.sets.sets, prep.sets.grid),
    );
    let mut o = solved?;
    crate::warning::warn_all(&o.warnings(&prep));
    let test_seq = match &a.params.test {
        Some(test) => Some(open_test(test, &a.seq)?),
        None => None,
    };
    if let Some(tseq) = &test_seq {
        let tsets = pipeline::prepare_test(tseq, &prep, a.params.quiet)?;
        pipeline::add_oracle_recall(&mut o, &prep, &tsets);
    }
    let rows = match &o.online {
        // The device's own records: what an export from a board would hold.
        Some(run) => output::rows_from_records(&run.database),
        None => output::rows_from_sequence(&seq, &o.database),
    };
    let timestamps: Vec<f64> = seq.frames.iter().map(|f| f.timestamp).collect();
    let mut json = metrics_json::of_select(&seq, &prep, &o, a.mu, &params);
    json["total_s"] = t0.elapsed().as_secs_f64().into();
    if let Some(mb) = metrics_json::peak_rss_mb() {
        json["peak_rss_mb"] = mb.into();
    }
    view.database.clone_from(&o.database);
    view.classes.clone_from(&o.labels);
    let caption = annotate::Caption::of_selection(
        &seq.name,
        o.solver.name(),
        a.mu,
        o.database.len(),
        seq.frames.len(),
        topview::horizontal(&seq.frames),
    );
    // Every output of the run appears together, or none does.
    let (dataset, exported) = replace::together(|outputs| {
        let dir = output::stage_database_dir(outputs, &a.out)?;
        // The picture is drawn and encoded while the tables are written.
        let (written, drawn) = rayon::join(
            || output::write_database_dir(&dir, &rows, &timestamps, &o.labels, &json, None),
            || {
                let path = dir.join("topview.png");
                annotate::render(&view, &caption)
                    .image
                    .write_png(&path)
                    .map_err(|source| crate::error::OutputError::Write { path, source })
            },
        );
        written?;
        drawn?;
        let first = record::first_session(&seq, &prep, &o, &params, a.mu, &rows);
        extension::write(&dir.join(extension::FILE_NAME), &first)?;
        let dataset = match &a.dataset {
            Some(dir) => Some((dir, dataset::stage(outputs, dir, &seq, &o.labels)?)),
            None => None,
        };
        let exported = exports::write_all(
            &targets,
            &exports::Selection {
                seq: &seq,
                rows: &rows,
                labels: &o.labels,
                overlaps: Some(&prep.co),
                mu: a.mu,
                test: test_seq.as_ref(),
            },
            outputs,
        )?;
        Ok((dataset, exported))
    })?;
    if a.params.json {
        println!("{}", serde_json::to_string_pretty(&json)?);
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
        println!("{}", o.losses(&prep).summary_line());
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
