//! A selection computed and not yet written: everything `placedb select`
//! writes, held in memory, so the command and the Python package
//! (python/) compute and write through the same code and give the same
//! bytes.

use super::SelectArgs;
use crate::cli::{open_test, solver_params, voxel_config};
use crate::error::CommandError as Error;
use crate::output::dataset::{self, DatasetSummary};
use crate::output::exports::{self, ExportTargets};
use crate::output::{self, annotate, metrics_json, replace, topview, DbRow};
use crate::pipeline::{self, Outcome, Prepared, SolverParams};
use crate::sequence::Sequence;
use crate::sessions::{extension, record};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// One solver's selection on a sequence, with what its files are made of.
pub struct Selection {
    /// The sequence selected from (shared: the Python package keeps it).
    pub seq: Arc<Sequence>,
    /// `--test`'s sequence, when one was given.
    pub test: Option<Sequence>,
    /// The voxel sets and overlaps.
    pub prep: Prepared,
    /// The solver's database, labels and metrics.
    pub outcome: Outcome,
    /// The solver parameters.
    pub params: SolverParams,
    /// The IoU threshold.
    pub mu: f32,
    /// The rows of `database.csv`.
    pub rows: Vec<DbRow>,
    /// `metrics.json`.
    pub json: serde_json::Value,
    view: topview::TopView,
    caption: annotate::Caption,
}

/// What [`Selection::write`] wrote besides the database directory.
pub struct Written {
    /// The dataset, when one was asked for.
    pub dataset: Option<(PathBuf, DatasetSummary)>,
    /// One line per export written.
    pub exported: Vec<String>,
}

impl Selection {
    /// Selects from `seq` as `a` says (its sequence and output options
    /// aside): voxelize, count overlaps, solve, measure. `t0` is when the
    /// run began, for `total_s`.
    pub fn compute(seq: Arc<Sequence>, a: &SelectArgs, t0: Instant) -> Result<Selection, Error> {
        let params = solver_params(&a.params)?;
        let quiet = a.params.quiet;
        let prep = pipeline::prepare(&seq, voxel_config(&a.seq), quiet)?;
        // The top view's map and trajectory do not depend on the solver:
        // they are projected on the other thread while it solves.
        let (solved, mut view) = rayon::join(
            || pipeline::solve(&seq, &prep, a.solver, a.mu, &params, quiet),
            || topview::project(&seq, &prep.sets.sets, prep.sets.grid),
        );
        let mut o = solved?;
        crate::warning::warn_all(&o.warnings(&prep));
        let test = match &a.params.test {
            Some(test) => Some(open_test(test, &a.seq)?),
            None => None,
        };
        if let Some(tseq) = &test {
            let tsets = pipeline::prepare_test(tseq, &prep, quiet)?;
            pipeline::add_oracle_recall(&mut o, &prep, &tsets);
        }
        let rows = match &o.online {
            // The device's own records: what an export from a board would hold.
            Some(run) => output::rows_from_records(&run.database),
            None => output::rows_from_sequence(&seq, &o.database),
        };
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
        Ok(Selection {
            seq,
            test,
            prep,
            outcome: o,
            params,
            mu: a.mu,
            rows,
            json,
            view,
            caption,
        })
    }

    /// Writes the database directory `out` (database.csv, labels.csv,
    /// metrics.json, topview.png, the extension file), the dataset and the
    /// exports asked for: every output appears together, or none does.
    pub fn write(
        &self,
        out: &Path,
        dataset: Option<&Path>,
        targets: &ExportTargets,
    ) -> Result<Written, Error> {
        let seq = &*self.seq;
        let o = &self.outcome;
        let timestamps: Vec<f64> = seq.frames.iter().map(|f| f.timestamp).collect();
        let (dataset, exported) = replace::together(|outputs| {
            let dir = output::stage_database_dir(outputs, out)?;
            // The picture is drawn and encoded while the tables are written.
            let (written, drawn) = rayon::join(
                || {
                    output::write_database_dir(
                        &dir,
                        &self.rows,
                        &timestamps,
                        &o.labels,
                        &self.json,
                        None,
                        None,
                    )
                },
                || {
                    let path = dir.join("topview.png");
                    annotate::render(&self.view, &self.caption)
                        .image
                        .write_png(&path)
                        .map_err(|source| crate::error::OutputError::Write { path, source })
                },
            );
            written?;
            drawn?;
            let first =
                record::first_session(seq, &self.prep, o, &self.params, self.mu, &self.rows);
            extension::write(&dir.join(extension::FILE_NAME), &first)?;
            let dataset = match dataset {
                Some(dir) => Some((
                    dir.to_path_buf(),
                    dataset::stage(outputs, dir, seq, &o.labels)?,
                )),
                None => None,
            };
            let exported = exports::write_all(
                targets,
                &exports::Selection {
                    seq,
                    rows: &self.rows,
                    labels: &o.labels,
                    overlaps: Some(&self.prep.co),
                    mu: self.mu,
                    test: self.test.as_ref(),
                },
                outputs,
            )?;
            Ok((dataset, exported))
        })?;
        Ok(Written { dataset, exported })
    }
}
