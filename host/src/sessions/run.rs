//! A later session on top of an earlier database, start to end: the
//! solver with the earlier database fixed (the online core seeded from the
//! extension file, or `in-order` / `greedy` over the combined sets), the
//! metrics over every session, the rows of `database.csv` and the next
//! extension file. It returns a plain outcome; `placedb select --extend`
//! (host/src/cli/select/extend.rs) writes and prints it.

use crate::output::{self, metrics_json, DbRow};
use crate::pipeline::{self, Outcome, Prepared, Solver, SolverParams};
use crate::replay::{self, OnlineRun, ReplayError};
use crate::sequence::Sequence;
use crate::sessions::extension::{Extension, Fate, FrameEntry};
use crate::sessions::fixed::{self, Missing};
use crate::sessions::{measure, record};
use crate::yardstick::graph::CoObservation;
use crate::yardstick::solve;
use std::time::Instant;

/// Why a later session could not be added.
#[derive(Debug, thiserror::Error)]
pub enum ExtendError {
    /// The earlier sessions cannot serve this run (words say why).
    #[error("{0}")]
    Refused(String),
    /// The online replay failed.
    #[error(transparent)]
    Replay(#[from] ReplayError),
}

/// A later session's result over every session.
pub struct Extended {
    /// The run as `select` reports one: every session's database frames
    /// (global indices) and labels, the metrics over every session.
    pub outcome: Outcome,
    /// The rows of `database.csv`, one per database frame.
    pub rows: Vec<DbRow>,
    /// The extension file after this session.
    pub next: Extension,
    /// `metrics.json`'s keys (without the run's times).
    pub metrics: serde_json::Value,
    /// Earlier database frames that have no voxel set in the file (a
    /// device keeps only the keys it compared exactly): counted as empty.
    pub absent: usize,
    /// The global index of this session's first frame.
    pub first: usize,
}

/// Adds session `seq` (voxelized on the earlier sessions' grid: `prep`) to
/// the database of `ext` with `solver` at `mu`.
pub fn extend(
    ext: &Extension,
    seq: &Sequence,
    prep: &Prepared,
    solver: Solver,
    mu: f32,
    params: &SolverParams,
) -> Result<Extended, ExtendError> {
    let first = ext.next_index() as usize;
    let m = ext.database.len();
    let t = Instant::now();
    let solved = solve(ext, seq, prep, solver, mu, params)?;
    let solve_time = t.elapsed();
    // Combined positions: 0..m the earlier database frames, m.. this session's.
    let position = |g: usize| match g.checked_sub(first) {
        Some(local) => m + local,
        None => ext
            .database
            .binary_search_by_key(&(g as u32), |f| f.index)
            .unwrap_or(0),
    };
    let db_positions: Vec<usize> = solved.database.iter().map(|&g| position(g)).collect();
    let (eval_sets, _) = prep.eval();
    let (eval, absent) = fixed::combined_sets(ext, &eval_sets.sets, true, Missing::Empty)
        .map_err(ExtendError::Refused)?;
    let eval_co = CoObservation::new(&eval, None);
    let (metrics, measured) = measure::over_sessions(ext, &eval, &eval_co, &db_positions, mu);
    // Labels judged on the solver's own sets, where coverage is promised.
    let (sets, _) = fixed::combined_sets(ext, &prep.sets.sets, false, Missing::Empty)
        .map_err(ExtendError::Refused)?;
    let co = CoObservation::new(&sets, None);
    let label_ious: Vec<f32> = (first..first + seq.frames.len())
        .filter(|&g| solved.labels[g] != g)
        .map(|g| co.iou(position(g), position(solved.labels[g])))
        .collect();
    let rows: Vec<DbRow> = match &solved.online {
        Some(run) => output::rows_from_records(&run.database),
        None => solved
            .database
            .iter()
            .map(|&g| match g.checked_sub(first) {
                Some(local) => {
                    let (_, ts, pose) = output::rows_from_sequence(seq, &[local])[0];
                    (g, ts, pose)
                }
                None => {
                    let f = &ext.database[position(g)];
                    (g, f.timestamp, f.pose)
                }
            })
            .collect(),
    };
    let o = Outcome {
        solver,
        database: solved.database.clone(),
        labels: solved.labels.clone(),
        metrics,
        solve_time,
        exact: None,
        online: solved.online,
        labels_below_mu: label_ious.iter().filter(|&&x| x <= mu).count(),
        label_iou_min: label_ious.iter().copied().fold(1.0f32, f32::min),
    };
    let session = ext.sessions.len() as u32;
    let next = record::extension(
        Some(ext),
        &record::SessionRun {
            seq,
            prep,
            solver,
            mu,
            params,
            database: &o.database,
            rows: &rows,
            labels: &o.labels[first..],
            measured: &measured,
            online: o.online.as_ref(),
        },
    );
    let mut json = metrics_json::of_select(seq, prep, &o, mu, params);
    let per_session = |f: &dyn Fn(u32) -> usize| -> Vec<usize> { (0..=session).map(f).collect() };
    json["frames"] = next.frames.len().into();
    json["sessions"] = (session + 1).into();
    json["session_frames"] = next.sessions.clone().into();
    json["session_database"] =
        per_session(&|s| next.database.iter().filter(|f| f.session == s).count()).into();
    let uncovered_of = |g: usize, f: &FrameEntry| match f.measured {
        Some(x) => !x.covered,
        None => matches!(f.fate, Fate::Uncovered(_)) && g < first,
    };
    json["session_uncovered"] = per_session(&|s| {
        next.frames
            .iter()
            .enumerate()
            .filter(|(g, f)| f.session == s && uncovered_of(*g, f))
            .count()
    })
    .into();
    json["database_frames_without_voxels"] = absent.into();
    Ok(Extended {
        outcome: o,
        rows,
        next,
        metrics: json,
        absent,
        first,
    })
}

/// The earlier database and the new session's frames after solving.
struct Solved {
    /// Every database frame, global indices ascending.
    database: Vec<usize>,
    /// Class of every frame of every session.
    labels: Vec<usize>,
    online: Option<OnlineRun>,
}

/// The solver on the new session with the earlier database fixed.
fn solve(
    ext: &Extension,
    seq: &Sequence,
    prep: &Prepared,
    solver: Solver,
    mu: f32,
    params: &SolverParams,
) -> Result<Solved, ExtendError> {
    let first = ext.next_index() as usize;
    let m = ext.database.len();
    if solver == Solver::Online {
        let (scan, cfg) = pipeline::online_config(seq, prep, mu, params);
        let sets = (!params.push_rows).then_some(&prep.sets);
        let run = replay::replay_after(
            ext,
            seq,
            sets,
            &params.profile,
            scan,
            cfg,
            params.chunk_rows,
            None,
        )?;
        let mut database: Vec<usize> = run.database.iter().map(|r| r.index as usize).collect();
        database.sort_unstable();
        return Ok(Solved {
            database,
            labels: run.labels.clone(),
            online: Some(run),
        });
    }
    let (sets, _) = fixed::combined_sets(ext, &prep.sets.sets, false, Missing::Refuse)
        .map_err(ExtendError::Refused)?;
    let co = CoObservation::new(&sets, None);
    let taken = match solver {
        Solver::InOrder => fixed::in_order(&co, m, mu),
        _ => fixed::greedy(&co, m, mu),
    };
    let mut positions: Vec<usize> = (0..m).collect();
    positions.extend(&taken);
    let global = |p: usize| {
        if p < m {
            ext.database[p].index as usize
        } else {
            first + p - m
        }
    };
    let by_position = solve::labels(&co, &positions);
    let mut labels: Vec<usize> = ext
        .frames
        .iter()
        .enumerate()
        .map(|(i, f)| f.fate.class(i as u32) as usize)
        .collect();
    labels.extend(by_position[m..].iter().map(|&p| global(p)));
    let mut database: Vec<usize> = positions.iter().map(|&p| global(p)).collect();
    database.sort_unstable();
    Ok(Solved {
        database,
        labels,
        online: None,
    })
}
