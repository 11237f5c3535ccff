//! The database directory (DESIGN section 6): `database.csv`, `labels.csv`,
//! `metrics.json` ([`metrics_json`]) and `topview.png` ([`topview`]), and the
//! training dataset ([`dataset`]). The one writer of each: `placedb select`,
//! `placedb export` and the tests all go through it. Scripts read these: the
//! column sets and key names are stable. Every output is all or nothing
//! ([`replace`]).

pub mod annotate;
pub mod dataset;
pub mod exports;
pub mod metrics_json;
pub mod replace;
pub mod session_columns;
pub mod topview;

use crate::error::OutputError;
use crate::output::replace::Outputs;
use crate::sequence::Sequence;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// One database row: frame index, timestamp and pose `[tx ty tz qx qy qz qw]`.
pub type DbRow = (usize, f64, [f64; 7]);

/// The rows of `database.csv` for database `db` of `seq`, from its poses.
pub fn rows_from_sequence(seq: &Sequence, db: &[usize]) -> Vec<DbRow> {
    db.iter()
        .map(|&i| {
            let f = &seq.frames[i];
            let [tx, ty, tz] = f.translation;
            let [qx, qy, qz, qw] = f.rotation;
            (i, f.timestamp, [tx, ty, tz, qx, qy, qz, qw])
        })
        .collect()
}

/// `database.csv` rows of the online selector's database records, exactly
/// as `placedb select --solver online` writes them (f32 pose widened to f64).
pub fn rows_from_records(database: &[placedb::DbRecord]) -> Vec<DbRow> {
    database
        .iter()
        .map(|r| {
            let t = r.pose.translation.map(f64::from);
            let q = r.pose.rotation.map(f64::from);
            (
                r.index as usize,
                r.timestamp,
                [t[0], t[1], t[2], q[0], q[1], q[2], q[3]],
            )
        })
        .collect()
}

/// The text of `database.csv`: header and one line per database frame, in
/// sequence order.
pub fn database_csv(rows: &[DbRow]) -> String {
    let mut s = String::from("index,timestamp,tx,ty,tz,qx,qy,qz,qw\n");
    let mut rows = rows.to_vec();
    rows.sort_by_key(|r| r.0);
    for (i, ts, p) in rows {
        let _ = write!(s, "{i},{ts:.6}");
        for c in p {
            let _ = write!(s, ",{c}");
        }
        s.push('\n');
    }
    s
}

/// The text of `labels.csv`: `index,timestamp,class_index` for every frame.
pub fn labels_csv(timestamps: &[f64], labels: &[usize]) -> String {
    let mut s = String::from("index,timestamp,class_index\n");
    for (i, (ts, l)) in timestamps.iter().zip(labels).enumerate() {
        let _ = writeln!(s, "{i},{ts:.6},{l}");
    }
    s
}

/// The text of `database.csv` and `labels.csv` of a run that kept the
/// device's records (the online replay, a device's export): the one place
/// both are built from them.
pub fn run_csv(
    database: &[placedb::DbRecord],
    timestamps: &[f64],
    labels: &[usize],
) -> (String, String) {
    (
        database_csv(&rows_from_records(database)),
        labels_csv(timestamps, labels),
    )
}

/// The database directory's name in a refusal.
pub const DATABASE_DIR: &str = "a database directory";

/// Whether `dir` holds an earlier database directory, which a run replaces
/// whole: its `database.csv` and `labels.csv`.
pub fn is_database_dir(dir: &Path) -> bool {
    dir.join("database.csv").is_file() && dir.join("labels.csv").is_file()
}

/// Refuses, before the work, a database directory `dir` that
/// [`stage_database_dir`] would refuse.
pub fn check_database_dir(dir: &Path) -> Result<(), OutputError> {
    replace::check_dir(dir, DATABASE_DIR, is_database_dir)
}

/// Refuses, before the work, what a run writing database directory `out`,
/// the dataset `dataset` and the exports `exports` would refuse at its end
/// ([`replace`]'s rule), or two of them in one place.
pub fn check_outputs(
    out: &Path,
    dataset: Option<&Path>,
    exports: &exports::ExportTargets,
) -> Result<(), OutputError> {
    check_database_dir(out)?;
    if let Some(dir) = dataset {
        dataset::check(dir)?;
    }
    exports.check_targets()?;
    let mut all = vec![out];
    all.extend(dataset);
    all.extend(exports.targets());
    replace::check_apart(&all)
}

/// The temporary directory, beside `dir`, to write the database directory
/// into; it becomes `dir` with the run's other outputs.
pub fn stage_database_dir(outputs: &mut Outputs, dir: &Path) -> Result<PathBuf, OutputError> {
    outputs.dir(dir, DATABASE_DIR, is_database_dir)
}

/// Writes `database.csv`, `labels.csv` and `metrics.json` into directory
/// `dir` (one from [`stage_database_dir`]); `metrics` must be a flat JSON
/// object. With `sessions` (a run of several sessions), the two tables
/// carry the session columns ([`session_columns`]).
pub fn write_database_dir(
    dir: &Path,
    rows: &[DbRow],
    timestamps: &[f64],
    labels: &[usize],
    metrics: &serde_json::Value,
    sessions: Option<session_columns::SessionOf<'_>>,
) -> Result<(), OutputError> {
    let metrics_path = dir.join("metrics.json");
    let metrics = metrics_json::text(metrics).map_err(OutputError::writing(&metrics_path))?;
    let (database, labels) = match sessions {
        Some(session_of) => (
            session_columns::database_csv(rows, session_of),
            session_columns::labels_csv(timestamps, labels, session_of),
        ),
        None => (database_csv(rows), labels_csv(timestamps, labels)),
    };
    replace::write_text(&dir.join("database.csv"), &database)?;
    replace::write_text(&dir.join("labels.csv"), &labels)?;
    replace::write_text(&metrics_path, &metrics)
}
