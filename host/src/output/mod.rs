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

/// Which frame of its sequence each frame of a run is, as the index
/// columns of `database.csv` and `labels.csv` (and `class_index`) write it:
/// frame `k` of the run is frame `numbers[k]` of the sequence. A device
/// numbers the frames it received 0, 1, 2, ...; when it was not sent every
/// frame (`stream --realtime` skips frames while it is busy) the host
/// knows which ones it got. `None`: frame `k` is frame `k`.
pub type Numbers<'a> = Option<&'a [usize]>;

/// Frame `k`'s number by `numbers` ([`Numbers`]); checked by
/// [`check_numbers`] first.
fn number(numbers: Numbers<'_>, k: usize) -> usize {
    numbers.map_or(k, |n| n[k])
}

/// Refuses `numbers` that do not name, in increasing order, a sequence
/// frame for every frame the tables name (the database rows' frames, each
/// labelled frame and its class).
fn check_numbers(
    numbers: Numbers<'_>,
    rows: &[DbRow],
    labels: &[usize],
) -> Result<(), OutputError> {
    let Some(n) = numbers else { return Ok(()) };
    if n.windows(2).any(|w| w[0] >= w[1]) {
        return Err(OutputError::Mismatch(
            "the frames' numbers in the sequence are not increasing".into(),
        ));
    }
    let named = rows.iter().map(|r| r.0).chain(labels.iter().copied());
    match named.chain(labels.len().checked_sub(1)).max() {
        Some(k) if k >= n.len() => Err(OutputError::Mismatch(format!(
            "frame {k} of the run has no number in the sequence (it numbers {} frames)",
            n.len()
        ))),
        _ => Ok(()),
    }
}

/// The text of `database.csv`: header and one line per database frame, in
/// sequence order.
pub fn database_csv(rows: &[DbRow]) -> String {
    database_csv_numbered(rows, None)
}

/// [`database_csv`] with the frames numbered by `numbers`.
fn database_csv_numbered(rows: &[DbRow], numbers: Numbers<'_>) -> String {
    let mut s = String::from("index,timestamp,tx,ty,tz,qx,qy,qz,qw\n");
    let mut rows = rows.to_vec();
    rows.sort_by_key(|r| r.0);
    for (i, ts, p) in rows {
        let _ = write!(s, "{},{ts:.6}", number(numbers, i));
        for c in p {
            let _ = write!(s, ",{c}");
        }
        s.push('\n');
    }
    s
}

/// The text of `labels.csv`: `index,timestamp,class_index` for every frame.
pub fn labels_csv(timestamps: &[f64], labels: &[usize]) -> String {
    labels_csv_numbered(timestamps, labels, None)
}

/// [`labels_csv`] with the frames (and classes) numbered by `numbers`: a
/// frame the run has no label of (one a device never received) has no row.
fn labels_csv_numbered(timestamps: &[f64], labels: &[usize], numbers: Numbers<'_>) -> String {
    let mut s = String::from("index,timestamp,class_index\n");
    for (i, (ts, &l)) in timestamps.iter().zip(labels).enumerate() {
        let _ = writeln!(s, "{},{ts:.6},{}", number(numbers, i), number(numbers, l));
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
/// carry the session columns ([`session_columns`]); with `numbers`, their
/// index columns number the frames by the sequence ([`Numbers`]).
pub fn write_database_dir(
    dir: &Path,
    rows: &[DbRow],
    timestamps: &[f64],
    labels: &[usize],
    metrics: &serde_json::Value,
    sessions: Option<session_columns::SessionOf<'_>>,
    numbers: Numbers<'_>,
) -> Result<(), OutputError> {
    check_numbers(numbers, rows, labels)?;
    let metrics_path = dir.join("metrics.json");
    let metrics = metrics_json::text(metrics).map_err(OutputError::writing(&metrics_path))?;
    let (database, labels) = match sessions {
        Some(session_of) => (
            session_columns::database_csv(rows, session_of, numbers),
            session_columns::labels_csv(timestamps, labels, session_of, numbers),
        ),
        None => (
            database_csv_numbered(rows, numbers),
            labels_csv_numbered(timestamps, labels, numbers),
        ),
    };
    replace::write_text(&dir.join("database.csv"), &database)?;
    replace::write_text(&dir.join("labels.csv"), &labels)?;
    replace::write_text(&metrics_path, &metrics)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_name_the_frames_and_classes_by_the_sequence() {
        // A device received frames 0, 4 and 9 of the sequence; its frame 2
        // (frame 9) is the database frame.
        let rows: Vec<DbRow> = vec![(2, 9.0, [0.0; 7])];
        let numbers = [0, 4, 9];
        assert!(check_numbers(Some(&numbers), &rows, &[2, 2, 2]).is_ok());
        assert_eq!(
            labels_csv_numbered(&[0.0, 4.0, 9.0], &[2, 2, 2], Some(&numbers)),
            "index,timestamp,class_index\n0,0.000000,9\n4,4.000000,9\n9,9.000000,9\n"
        );
        assert!(
            database_csv_numbered(&rows, Some(&numbers)).ends_with("\n9,9.000000,0,0,0,0,0,0,0\n")
        );
        assert_eq!(database_csv_numbered(&rows, None), database_csv(&rows));
        // A frame without a number, or numbers out of order, are refused.
        let e = check_numbers(Some(&numbers[..2]), &rows, &[2, 2, 2]).unwrap_err();
        assert!(
            e.to_string().contains("frame 2 of the run has no number"),
            "{e}"
        );
        assert!(check_numbers(Some(&[0, 4, 4]), &rows, &[2, 2, 2]).is_err());
    }
}
