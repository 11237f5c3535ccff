//! `placedb select SEQ --extend OUT_A -o OUT_AB`: the arguments, outputs
//! and summary of a later session added to the database in `OUT_A` (read
//! from its extension file, so the earlier sequences need not be present).
//! The session itself is [`crate::sessions::run`].

use super::SelectArgs;
use crate::cli::{open_sequence, solver_params, voxel_config};
use crate::degradation;
use crate::error::CommandError as Error;
use crate::error::{OutputError, UsageError};
use crate::output::{self, annotate, metrics_json, replace, topview};
use crate::pipeline::{self, Prepared, Solver, SolverParams};
use crate::sessions::extension;
use crate::sessions::run::{self, Extended};
use crate::sessions::{check_config, grid_of};
use crate::{ReadError, Sequence};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// A later session computed and not yet written: what `select --extend`
/// writes, in memory (the Python package writes it later, as
/// [`super::Selection`] does a first session).
pub struct ExtendedSelection {
    /// The session's sequence.
    pub seq: Arc<Sequence>,
    /// The directory extended.
    pub from: PathBuf,
    /// The voxel sets, on the earlier sessions' grid.
    pub prep: Prepared,
    /// Every session's database, labels, rows and metrics.
    pub extended: Extended,
    /// The earlier sessions' database frames.
    pub earlier_database: usize,
    /// This session's number (0 is the first).
    pub session: u32,
    /// `metrics.json`, with the run's times.
    pub json: serde_json::Value,
    params: SolverParams,
    view: topview::TopView,
    caption: annotate::Caption,
}

/// What `--extend` refuses to combine with, and solvers it cannot extend
/// with, before any work.
pub fn check_extend(a: &SelectArgs) -> Result<(), Error> {
    if a.dataset.is_some() || a.params.test.is_some() || a.exports.targets().any() {
        return Err(UsageError(
            "--extend does not combine with --dataset, --test, --colmap, --vpr-eval or --pairs yet"
                .into(),
        )
        .into());
    }
    match a.solver {
        Solver::Online | Solver::InOrder | Solver::Greedy => Ok(()),
        Solver::Exact => Err(UsageError(
            "--extend works with --solver online, in-order or greedy; exact is not supported with --extend"
                .into(),
        )
        .into()),
        other => Err(UsageError(format!(
            "--extend works with --solver online, in-order or greedy; {} ignores what the earlier database covers, so extending with it makes no sense",
            other.name()
        ))
        .into()),
    }
}

/// Refuses `out` as the extended database's directory: the directory
/// being extended, or a directory that is not a database directory.
pub fn check_out(out: &Path, from: &Path) -> Result<(), Error> {
    // The earlier session's directory stays as it is: it is the record of
    // that session (and `OUT_AB` may be extended again instead).
    let same = |p: &Path| p.canonicalize().ok();
    if same(out).is_some() && same(out) == same(from) {
        return Err(OutputError::Mismatch(format!(
            "-o {} is the directory being extended: write the extended database to another directory",
            out.display()
        ))
        .into());
    }
    Ok(output::check_database_dir(out)?)
}

/// The extension file of the directory `from` being extended.
pub fn read_earlier(from: &Path) -> Result<extension::Extension, Error> {
    let path = from.join(extension::FILE_NAME);
    if !path.exists() {
        return Err(ReadError::Layout {
            path: from.to_path_buf(),
            reason: format!(
                "no {} here: --extend needs a directory written by `placedb select` or `placedb export`",
                extension::FILE_NAME
            ),
        }
        .into());
    }
    Ok(extension::read(&path)?)
}

impl ExtendedSelection {
    /// Adds `seq` as a new session to the database `ext` of the directory
    /// `from` ([`read_earlier`]) as `a` says.
    pub fn compute(
        seq: Arc<Sequence>,
        a: &SelectArgs,
        from: &Path,
        ext: &extension::Extension,
        t0: Instant,
    ) -> Result<ExtendedSelection, Error> {
        check_extend(a)?;
        let params = solver_params(&a.params)?;
        let config = voxel_config(&a.seq);
        check_config(ext, from, &config, a.mu, a.solver, &params)?;
        let prep = pipeline::prepare_on(&seq, config, grid_of(ext), a.params.quiet)?;
        let mut extended = run::extend(ext, &seq, &prep, a.solver, a.mu, &params)?;
        let mut json = std::mem::take(&mut extended.metrics);
        json["total_s"] = t0.elapsed().as_secs_f64().into();
        if let Some(mb) = metrics_json::peak_rss_mb() {
            json["peak_rss_mb"] = mb.into();
        }
        let o = &extended.outcome;
        let first = extended.first;
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
        Ok(ExtendedSelection {
            seq,
            from: from.to_path_buf(),
            prep,
            earlier_database: ext.database.len(),
            session: ext.sessions.len() as u32,
            extended,
            json,
            params,
            view,
            caption,
        })
    }

    /// Writes the extended database into `out`: every file together, or none.
    pub fn write(&self, out: &Path) -> Result<(), Error> {
        check_out(out, &self.from)?;
        let Extended {
            outcome: o,
            rows,
            next,
            ..
        } = &self.extended;
        let session = self.session;
        let session_of = |g: usize| next.session_of(g as u32).unwrap_or((session, 0));
        let timestamps: Vec<f64> = next.frames.iter().map(|f| f.timestamp).collect();
        replace::together(|outputs| {
            let dir = output::stage_database_dir(outputs, out)?;
            output::write_database_dir(
                &dir,
                rows,
                &timestamps,
                &o.labels,
                &self.json,
                Some(&session_of),
                None,
            )?;
            let path = dir.join("topview.png");
            annotate::render(&self.view, &self.caption)
                .image
                .write_png(&path)
                .map_err(|source| OutputError::Write { path, source })?;
            extension::write(&dir.join(extension::FILE_NAME), next)
        })?;
        Ok(())
    }
}

/// Runs `placedb select` with `--extend from`.
pub(super) fn run(a: SelectArgs, from: &Path) -> Result<(), Error> {
    let t0 = Instant::now();
    check_extend(&a)?;
    // A refused or unwritable output fails the run before the work.
    check_out(&a.out, from)?;
    // A directory without an extension file (or an unreadable one) fails
    // the run before the sequence is read.
    let ext = read_earlier(from)?;
    let seq = Arc::new(open_sequence(&a.seq)?);
    let sel = ExtendedSelection::compute(Arc::clone(&seq), &a, from, &ext, t0)?;
    sel.write(&a.out)?;
    let (prep, json, params) = (&sel.prep, &sel.json, &sel.params);
    let Extended {
        outcome: o,
        next,
        absent,
        first,
        ..
    } = &sel.extended;
    let (first, absent) = (*first, *absent);
    let m = sel.earlier_database;
    let session = sel.session;
    if a.params.json {
        println!("{}", serde_json::to_string_pretty(json)?);
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
