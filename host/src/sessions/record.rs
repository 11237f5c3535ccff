//! The extension file of a `select` run: what the next session needs of
//! this one and of every session before it ([`crate::sessions::extension`]).

use crate::output::DbRow;
use crate::pipeline::{Outcome, Prepared, Solver, SolverParams};
use crate::replay::OnlineRun;
use crate::sequence::Sequence;
use crate::sessions::config::origin_name;
use crate::sessions::extension::Fate;
use crate::sessions::extension::{
    DbFrame, Extension, FrameEntry, Measured, OnlineConfig, RunConfig,
};
use crate::yardstick::metrics;
use placedb::key_pool::Aabb;
use placedb::Decision;

/// One session's run, as `select` ends it.
pub struct SessionRun<'a> {
    /// The session's sequence.
    pub seq: &'a Sequence,
    /// Its voxel sets (on the database's grid).
    pub prep: &'a Prepared,
    /// The solver.
    pub solver: Solver,
    /// The threshold.
    pub mu: f32,
    /// The solver's parameters.
    pub params: &'a SolverParams,
    /// Every database frame (global indices, ascending), earlier sessions' included.
    pub database: &'a [usize],
    /// The rows of `database.csv`, one per database frame.
    pub rows: &'a [DbRow],
    /// The class (a global frame index) of each of the session's frames.
    pub labels: &'a [usize],
    /// What was measured of each of the session's frames.
    pub measured: &'a [Measured],
    /// The online replay, for `online`.
    pub online: Option<&'a OnlineRun>,
}

/// The extension file of a one-session run (every `select` writes one, so
/// that its output directory can be extended later).
pub fn first_session(
    seq: &Sequence,
    prep: &Prepared,
    o: &Outcome,
    params: &SolverParams,
    mu: f32,
    rows: &[DbRow],
) -> Extension {
    let (eval_sets, eval_co) = prep.eval();
    let per = metrics::per_frame(&eval_sets.sets, eval_co, &o.database, mu);
    let measured: Vec<Measured> = per
        .coverage
        .iter()
        .zip(&per.covered)
        .map(|(&c, &covered)| Measured {
            coverage: c as f32,
            covered,
        })
        .collect();
    let run = SessionRun {
        seq,
        prep,
        solver: o.solver,
        mu,
        params,
        database: &o.database,
        rows,
        labels: &o.labels,
        measured: &measured,
        online: o.online.as_ref(),
    };
    extension(None, &run)
}

/// The extension file after `run`, on top of `earlier` (`None`: the first session).
pub fn extension(earlier: Option<&Extension>, run: &SessionRun<'_>) -> Extension {
    let first = earlier.map_or(0, Extension::next_index);
    let session = earlier.map_or(0, |e| e.sessions.len() as u32);
    let c = &run.prep.config;
    let config = RunConfig {
        voxel: c.voxel,
        grid_corner: run.prep.sets.grid.origin,
        grid_origin: origin_name(c),
        stride: c.stride,
        depth_range: [c.range.min, c.range.max],
        mu: run.mu,
        solver: run.solver.name().to_string(),
        online: run.online.map(|_| OnlineConfig {
            profile: run.params.profile.clone(),
            window: run.params.window,
            sketch_margin: run.params.sketch_margin,
        }),
    };
    let in_db = |g: usize| run.database.binary_search(&g).is_ok();
    let mut frames = earlier.map_or_else(Vec::new, |e| e.frames.clone());
    for (i, f) in run.seq.frames.iter().enumerate() {
        let g = first as usize + i;
        let fate = match run.online.and_then(|o| o.decisions.get(g)) {
            Some(Decision::Taken) => Fate::Taken,
            Some(Decision::DominatedBy(k)) => Fate::Covered(*k),
            Some(Decision::Uncovered(k)) => Fate::Uncovered(*k),
            _ if in_db(g) => Fate::Taken,
            _ => {
                let class = run.labels[i] as u32;
                match run.measured.get(i) {
                    Some(m) if !m.covered && class as usize != g => Fate::Uncovered(Some(class)),
                    _ if class as usize == g => Fate::Uncovered(None),
                    _ => Fate::Covered(class),
                }
            }
        };
        frames.push(FrameEntry {
            timestamp: f.timestamp,
            session,
            fate,
            measured: run.measured.get(i).copied(),
        });
    }
    let mut database = Vec::with_capacity(run.database.len());
    for (k, &g) in run.database.iter().enumerate() {
        if let Some(kept) = earlier.and_then(|e| e.db_frame(g as u32)) {
            database.push(kept.clone());
            continue;
        }
        let local = g - first as usize;
        let keys = &run.prep.sets.sets[local];
        let stored = run.online.and_then(|o| o.stored.get(k));
        let record = run.online.and_then(|o| o.database.get(k));
        let (_, timestamp, pose) = run.rows[k];
        database.push(DbFrame {
            index: g as u32,
            session,
            timestamp,
            pose,
            voxels: record.map_or(keys.len() as u32, |r| r.voxels),
            aabb: stored.map_or_else(|| Aabb::of_sorted(keys), |s| s.aabb),
            sketch: stored.map(|s| s.sketch.clone()),
            keyed: stored.is_some_and(|s| s.keys.is_some()),
            key_bytes: stored.map_or(0, |s| s.key_bytes),
            // The core's own keys where its store kept them (a truncated
            // set is the truncated one), else the run's voxel set.
            keys: Some(
                stored
                    .and_then(|s| s.keys.clone())
                    .unwrap_or_else(|| keys.clone()),
            ),
            eval_keys: run.prep.exact.as_ref().map(|(s, _)| s.sets[local].clone()),
        });
    }
    let (eval, _) = run.prep.eval();
    let mut parts: Vec<&[u64]> = eval.sets.iter().map(Vec::as_slice).collect();
    let earlier_all = earlier.and_then(|e| e.all_voxels.as_deref());
    // An earlier session a device ran has no voxels to add: the union is
    // then unknown (`None`), not a part of it.
    let all_voxels = match (earlier, earlier_all) {
        (Some(_), None) => None,
        (_, Some(all)) => {
            parts.push(all);
            Some(metrics::union(&parts))
        }
        (None, None) => Some(metrics::union(&parts)),
    };
    let mut sessions = earlier.map_or_else(Vec::new, |e| e.sessions.clone());
    sessions.push(run.seq.frames.len() as u32);
    Extension {
        config,
        sessions,
        frames,
        database,
        all_voxels,
    }
}
