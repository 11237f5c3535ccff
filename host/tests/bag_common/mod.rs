//! What the tests of recorded bags share (`ros2.rs`, `ros1.rs`,
//! `robot_recordings.rs`): the first frames of the 7-Scenes sample, the
//! fixture writer that records them as robots do
//! (`host/tests/recordings/write_recordings.py`), and the database a solver
//! selects from a sequence, to compare a recording with the sample.

#![allow(dead_code)]

use placedb_host::pipeline::{self, Solver, SolverParams};
use placedb_host::read::{self, ReadOptions};
use placedb_host::{output, Sequence, VoxelConfig};
use std::path::{Path, PathBuf};
use std::process::Command;

/// The 7-Scenes sample of `../shared/data`.
pub const SEVEN_SCENES: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../shared/data/7scenes-1000"
);

const FIXTURE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/recordings/write_recordings.py"
);

/// The first `frames` frames of the 7-Scenes sample.
pub fn sevenscenes(frames: usize) -> Sequence {
    let mut seq = read::open(Path::new(SEVEN_SCENES), &ReadOptions::default())
        .expect("tests read ../shared/data");
    seq.frames.truncate(frames);
    seq
}

/// Writes the recordings `only` of `s7`'s frames (the first frames of the
/// sample) into `dir/recordings` and returns that folder. The poses are
/// this reader's own 7-Scenes poses, written so that they parse back to the
/// same bits. A missing python3 or rosbags fails the test with what to
/// install: these tests must never pass without running.
pub fn write_recordings(dir: &Path, s7: &Sequence, only: &[&str]) -> PathBuf {
    let poses: String = s7
        .frames
        .iter()
        .map(|f| {
            let [x, y, z] = f.translation;
            let [qx, qy, qz, qw] = f.rotation;
            format!("{} {x} {y} {z} {qx} {qy} {qz} {qw}\n", f.timestamp)
        })
        .collect();
    let poses_file = dir.join("poses.txt");
    std::fs::write(&poses_file, poses).unwrap();
    let out = dir.join("recordings");
    let run = Command::new("python3")
        .arg(FIXTURE)
        .arg("--sevenscenes")
        .arg(SEVEN_SCENES)
        .arg("--poses")
        .arg(&poses_file)
        .arg("--frames")
        .arg(s7.frames.len().to_string())
        .arg("--out")
        .arg(&out)
        .arg("--only")
        .args(only)
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .output()
        .unwrap_or_else(|e| {
            panic!(
                "cannot run python3 ({e}): these tests need python3 and \
                 `pip install -r host/tests/recordings/requirements.txt`"
            )
        });
    assert!(
        run.status.success(),
        "the fixture writer failed ({}); if a module is missing: pip install -r \
         host/tests/recordings/requirements.txt\n{}",
        run.status,
        String::from_utf8_lossy(&run.stderr)
    );
    out
}

/// database.csv and labels.csv of `solver` at mu 0.3.
pub fn database(seq: &Sequence, solver: Solver) -> (String, String) {
    let prep = pipeline::prepare(seq, VoxelConfig::default(), true).unwrap();
    let o = pipeline::solve(seq, &prep, solver, 0.3, &SolverParams::default(), true).unwrap();
    let rows = match &o.online {
        Some(run) => output::rows_from_records(&run.database),
        None => output::rows_from_sequence(seq, &o.database),
    };
    let ts: Vec<f64> = seq.frames.iter().map(|f| f.timestamp).collect();
    (
        output::database_csv(&rows),
        output::labels_csv(&ts, &o.labels),
    )
}

/// `got` selects what `want` selects with `in-order` and `online`: the same
/// labels.csv, and database.csv's rows the same frames and timestamps with
/// poses equal to 1e-9 (composed poses, a TF tree's, differ in their last
/// bits).
pub fn assert_same_selection(got: &Sequence, want: &Sequence, what: &str) {
    for solver in [Solver::InOrder, Solver::Online] {
        let ((got_db, got_labels), (want_db, want_labels)) =
            (database(got, solver), database(want, solver));
        assert_eq!(got_labels, want_labels, "{what} {solver:?}");
        let rows = |csv: &str| -> Vec<Vec<String>> {
            csv.lines()
                .map(|l| l.split(',').map(String::from).collect())
                .collect()
        };
        let (g, w) = (rows(&got_db), rows(&want_db));
        assert_eq!(g.len(), w.len(), "{what} {solver:?}\n{got_db}\n{want_db}");
        assert_eq!(g[0], w[0], "{what} {solver:?}: the column names");
        for (g, w) in g.iter().zip(&w).skip(1) {
            assert_eq!(g[..2], w[..2], "{what} {solver:?}: index and timestamp");
            for (x, y) in g[2..].iter().zip(&w[2..]) {
                let (x, y): (f64, f64) = (x.parse().unwrap(), y.parse().unwrap());
                assert!((x - y).abs() <= 1e-9, "{what} {solver:?}: {g:?} vs {w:?}");
            }
        }
    }
}
