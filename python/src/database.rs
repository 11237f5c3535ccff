//! `placedb.select` and `placedb.Database`: one solver's selection on a
//! sequence, computed by the command's own code
//! ([`placedb_host::cli::select::Selection`]) and written by it, so the
//! files are the command's byte for byte.

use crate::args::select_args;
use crate::errors::{interruptible, released, Failure};
use crate::sequence::Sequence;
use numpy::{IntoPyArray, PyArray1};
use placedb_host::board::export::Export;
use placedb_host::cli::select::{extend, ExtendedSelection, Selection};
use placedb_host::output::{self, exports::ExportTargets};
use pyo3::prelude::*;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

/// What a database was made by.
pub enum Source {
    /// A solver on a sequence (`placedb.select`).
    Selection(Arc<Selection>),
    /// A later session on an earlier database (`select(..., extend=)`).
    Extended(Arc<ExtendedSelection>),
    /// A device's export (`Selector.finish`, `Device.export`): its files
    /// come from the device, `write` pulls them again.
    Export {
        /// The records and labels.
        export: Arc<Export>,
        /// The device, to write the export's files from.
        device: Py<crate::device::Device>,
    },
}

/// A selected database: its frames, every frame's class, the metrics.
#[pyclass(frozen, module = "placedb._native")]
pub struct Database {
    pub source: Source,
}

/// Selects with `argv` (`placedb select`'s arguments, the sequence first)
/// from `sequence` when given (its own reading arguments first in `argv`),
/// else from the sequence `argv` names.
#[pyfunction]
#[pyo3(signature = (argv, sequence=None))]
pub fn select(
    py: Python<'_>,
    argv: Vec<String>,
    sequence: Option<&Sequence>,
) -> PyResult<Database> {
    let t0 = Instant::now();
    let a = select_args(&argv)?;
    let given = sequence.map(|s| Arc::clone(&s.inner));
    let source = interruptible(py, move || {
        // As the command: what --extend refuses, and its directory, before
        // the sequence is read.
        let earlier = match a.extend() {
            Some(from) => {
                extend::check_extend(&a)?;
                Some((from.to_path_buf(), extend::read_earlier(from)?))
            }
            None => None,
        };
        let seq = match given {
            Some(seq) => seq,
            None => Arc::new(a.open_sequence()?),
        };
        Ok(match earlier {
            Some((from, ext)) => Source::Extended(Arc::new(ExtendedSelection::compute(
                seq, &a, &from, &ext, t0,
            )?)),
            None => Source::Selection(Arc::new(Selection::compute(seq, &a, t0)?)),
        })
    })?;
    Ok(Database { source })
}

#[pymethods]
impl Database {
    /// The database frames' indices, ascending (int64).
    #[getter]
    fn frames<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i64>> {
        let frames: Vec<i64> = match &self.source {
            Source::Selection(s) => s.outcome.database.iter().map(|&f| f as i64).collect(),
            Source::Extended(s) => s
                .extended
                .outcome
                .database
                .iter()
                .map(|&f| f as i64)
                .collect(),
            Source::Export { export, .. } => export
                .database()
                .iter()
                .map(|r| i64::from(r.index))
                .collect(),
        };
        frames.into_pyarray(py)
    }

    /// Every frame's class: the database frame it is labelled with (a
    /// database frame is its own class), int64.
    #[getter]
    fn labels<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i64>> {
        let labels: Vec<i64> = match &self.source {
            Source::Selection(s) => s.outcome.labels.iter().map(|&l| l as i64).collect(),
            Source::Extended(s) => s
                .extended
                .outcome
                .labels
                .iter()
                .map(|&l| l as i64)
                .collect(),
            Source::Export { export, .. } => export.labels().1.iter().map(|&l| l as i64).collect(),
        };
        labels.into_pyarray(py)
    }

    /// `metrics.json` as text (the Python API parses it).
    #[getter]
    fn metrics_json(&self) -> String {
        match &self.source {
            Source::Selection(s) => s.json.to_string(),
            Source::Extended(s) => s.json.to_string(),
            Source::Export { export, .. } => export.metrics(None).to_string(),
        }
    }

    /// Writes `out` (database.csv, labels.csv, metrics.json, topview.png,
    /// extension.bin) and the dataset and exports asked for, as `placedb
    /// select` writes them: all together or none. Returns one line per
    /// export written.
    #[pyo3(signature = (out, dataset=None, colmap=None, vpr_eval=None, pairs=None))]
    fn write(
        &self,
        py: Python<'_>,
        out: PathBuf,
        dataset: Option<PathBuf>,
        colmap: Option<PathBuf>,
        vpr_eval: Option<PathBuf>,
        pairs: Option<PathBuf>,
    ) -> PyResult<Vec<String>> {
        let targets = ExportTargets {
            colmap,
            vpr_eval,
            pairs,
        };
        match &self.source {
            Source::Selection(sel) => released(py, || {
                output::check_outputs(&out, dataset.as_deref(), &targets)
                    .map_err(|e| Failure::of(&e))?;
                if let Some(file) = &targets.pairs {
                    output::exports::pairs::names(&sel.seq, file).map_err(|e| Failure::of(&e))?;
                }
                let w = sel
                    .write(&out, dataset.as_deref(), &targets)
                    .map_err(Failure::from)?;
                Ok(w.exported)
            }),
            Source::Extended(sel) => {
                if dataset.is_some() || targets.any() {
                    return Err(Failure::value(
                        "an extended database is written without dataset, colmap, vpr_eval or \
                         pairs yet (as `placedb select --extend`)",
                    )
                    .into());
                }
                released(py, || sel.write(&out).map_err(Failure::from))?;
                Ok(Vec::new())
            }
            Source::Export { device, .. } => {
                if dataset.is_some() || targets.any() {
                    return Err(Failure::value(
                        "a device's database is written without the sequence's images: \
                         dataset, colmap, vpr_eval and pairs need them (write the database, \
                         then run `placedb export --sequence SEQ` on the board)",
                    )
                    .into());
                }
                device.get().write_export(py, &out)?;
                Ok(Vec::new())
            }
        }
    }
}
