//! `placedb select SEQ --extend OUT_A -o OUT_AB`: the arguments, outputs
//! and summary of a later session added to the database in `OUT_A` (read
//! from its extension file, so the earlier sequences need not be present).
//! The session itself is [`crate::sessions::run`].

use super::SelectArgs;
use crate::cli::{open_sequence, solver_params, voxel_config};
use crate::degradation;
use crate::error::CommandError as Error;
use crate::error::OutputError;
use crate::output::{self, annotate, metrics_json, replace, topview};
use crate::pipeline::{self, Solver};
use crate::sessions::extension;
use crate::sessions::run::{self, Extended};
use crate::sessions::{check_config, grid_of};
use std::path::Path;
use std::time::Instant;

/// Runs `placedb select` with `--extend from`.
pub(super) fn run(a: SelectArgs, from: &Path) -> Result<(), Error> {
    let t0 = Instant::now();
    if a.dataset.is_some() || a.params.test.is_some() || a.exports.targets().any() {
        return Err(
            "--extend does not combine with --dataset, --test, --colmap, --vpr-eval or --pairs yet"
                .into(),
        );
    }
    match a.solver {
        Solver::Online | Solver::InOrder | Solver::Greedy => {}
        Solver::Exact => {
            return Err(
                "--extend works with --solver online, in-order or greedy; exact is not supported with --extend"
                    .into(),
            )
        }
        other => {
            return Err(format!(
                "--extend works with --solver online, in-order or greedy; {} ignores what the earlier database covers, so extending with it makes no sense",
                other.name()
            )
            .into())
        }
    }
    // The earlier session's directory stays as it is: it is the record of
    // that session (and `OUT_AB` may be extended again instead).
    let same = |p: &Path| p.canonicalize().ok();
    if same(&a.out).is_some() && same(&a.out) == same(from) {
        return Err(format!(
            "-o {} is the directory being extended: write the extended database to another directory",
            a.out.display()
        )
        .into());
    }
    let path = from.join(extension::FILE_NAME);
    if !path.exists() {
        return Err(format!(
            "{}: no {} here: --extend needs a directory written by `placedb select` or `placedb export`",
            from.display(),
            extension::FILE_NAME
        )
        .into());
    }
    // A refused or unwritable output fails the run before the work.
    output::check_database_dir(&a.out)?;
    let ext = extension::read(&path)?;
    let seq = open_sequence(&a.seq)?;
    let params = solver_params(&a.params)?;
    let config = voxel_config(&a.seq);
    check_config(&ext, from, &config, a.mu, a.solver, &params)?;
    let prep = pipeline::prepare_on(&seq, config, grid_of(&ext), a.params.quiet)?;
    let Extended {
        outcome: o,
        rows,
        next,
        metrics: mut json,
        absent,
        first,
    } = run::extend(&ext, &seq, &prep, a.solver, a.mu, &params)?;
    let m = ext.database.len();
    let session = ext.sessions.len() as u32;
    let session_of = |g: usize| next.session_of(g as u32).unwrap_or((session, 0));
    json["total_s"] = t0.elapsed().as_secs_f64().into();
    if let Some(mb) = metrics_json::peak_rss_mb() {
        json["peak_rss_mb"] = mb.into();
    }
    // The top view: this session's map and trajectory, its database frames.
    let mut view = topview::project(&seq, &prep.sets.sets, prep.sets.grid);
    view.database = o
        .database
        .iter()
        .filter_map(|&g| g.checked_sub(first))
        .collect();
    view.classes = o.labels[first..].to_vec();
    let caption = annotate::Caption::of_selection(
        &seq.name,
        o.solver.name(),
        a.mu,
        view.database.len(),
        seq.frames.len(),
        topview::horizontal(&seq.frames),
    );
    let timestamps: Vec<f64> = next.frames.iter().map(|f| f.timestamp).collect();
    // Every file of the run appears together, or none does.
    replace::together(|outputs| {
        let dir = output::stage_database_dir(outputs, &a.out)?;
        output::write_database_dir(
            &dir,
            &rows,
            &timestamps,
            &o.labels,
            &json,
            Some(&session_of),
            None,
        )?;
        let path = dir.join("topview.png");
        annotate::render(&view, &caption)
            .image
            .write_png(&path)
            .map_err(|source| OutputError::Write { path, source })?;
        extension::write(&dir.join(extension::FILE_NAME), &next)
    })?;
    if a.params.json {
        println!("{}", serde_json::to_string_pretty(&json)?);
        return Ok(());
    }
    if a.params.quiet {
        return Ok(());
    }
    let mm = &o.metrics;
    let added = o.database.len() - m;
    println!(
        "{}: session {} of {} frames on top of {} ({} frames, {} database frames): {} database frames added, {} in all, with solver {} at mu {}",
        seq.name,
        session,
        seq.frames.len(),
        from.display(),
        first,
        m,
        added,
        o.database.len(),
        o.solver.name(),
        a.mu
    );
    println!(
        "  every session: {} frames, uncovered {}  spatial coverage {:.3}  frame coverage mean {:.3} min {:.3} (<0.3: {:.1}%)",
        next.frames.len(),
        mm.uncovered,
        mm.spatial_coverage,
        mm.frames_coverage_mean,
        mm.frames_coverage_min,
        100.0 * mm.frames_coverage_below_0_3
    );
    if absent > 0 {
        println!("  {absent} earlier database frames have no voxel set in the file (a device keeps only the keys it compared exactly): counted as empty in the metrics");
    }
    if let Some(run) = &o.online {
        let line = degradation::online_summary(&params.profile, params.window, &run.status);
        println!("  {line}");
    }
    println!(
        "  time: voxelize {:.3} s, solve {:.3} s, total {:.3} s",
        prep.voxelize_wall.as_secs_f64(),
        o.solve_time.as_secs_f64(),
        t0.elapsed().as_secs_f64()
    );
    println!(
        "  wrote {}/{{database.csv,labels.csv,metrics.json,topview.png,{}}}",
        a.out.display(),
        extension::FILE_NAME
    );
    Ok(())
}
