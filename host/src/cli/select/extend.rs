//! `placedb select SEQ --extend OUT_A -o OUT_AB`: a later session added to
//! the database in `OUT_A` (read from its extension file, so the earlier
//! sequences need not be present), and the extension file every `select`
//! run leaves for the next session.

use super::SelectArgs;
use crate::cli::{open_sequence, solver_params, voxel_config};
use crate::error::CommandError as Error;
use crate::extend::fixed::{self, Missing};
use crate::extend::{check_config, grid_of, measure, record};
use crate::output::dataset::DatasetError;
use crate::output::extension::{self, Extension, Measured};
use crate::output::{self, annotate, metrics_json, replace, topview, DbRow};
use crate::pipeline::{self, Outcome, Prepared, Solver, SolverParams};
use crate::replay::{self, OnlineRun};
use crate::sequence::Sequence;
use crate::yardstick::graph::CoObservation;
use crate::yardstick::metrics;
use crate::yardstick::solve;
use std::path::Path;
use std::time::Instant;

/// Writes `out/extension.bin` of a one-session run.
pub(super) fn write_first(
    out: &Path,
    seq: &Sequence,
    prep: &Prepared,
    o: &Outcome,
    params: &SolverParams,
    mu: f32,
    rows: &[DbRow],
) -> Result<(), DatasetError> {
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
    let run = record::SessionRun {
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
    let ext = record::extension(None, &run);
    extension::write(&out.join(extension::FILE_NAME), &ext)
}

/// The earlier database and the new session's frames after solving.
struct Solved {
    /// Every database frame, global indices ascending.
    database: Vec<usize>,
    /// Class of every frame of every session.
    labels: Vec<usize>,
    online: Option<OnlineRun>,
}

/// Runs `placedb select` with `--extend from`.
pub(super) fn run(a: SelectArgs, from: &Path) -> Result<(), Error> {
    let t0 = Instant::now();
    if a.dataset.is_some() || a.params.test.is_some() || a.exports.any() {
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
    let first = ext.next_index() as usize;
    let m = ext.database.len();
    let t = Instant::now();
    let solved = solve(&ext, &seq, &prep, a.solver, a.mu, &params)?;
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
    let (eval, absent) = fixed::combined_sets(&ext, &eval_sets.sets, true, Missing::Empty)?;
    let eval_co = CoObservation::new(&eval, None);
    let (metrics, measured) = measure::over_sessions(&ext, &eval, &eval_co, &db_positions, a.mu);
    // Labels judged on the solver's own sets, where coverage is promised.
    let (sets, _) = fixed::combined_sets(&ext, &prep.sets.sets, false, Missing::Empty)?;
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
                    let (_, ts, pose) = output::rows_from_sequence(&seq, &[local])[0];
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
        solver: a.solver,
        database: solved.database.clone(),
        labels: solved.labels.clone(),
        metrics,
        solve_time,
        exact: None,
        online: solved.online,
        labels_below_mu: label_ious.iter().filter(|&&x| x <= a.mu).count(),
        label_iou_min: label_ious.iter().copied().fold(1.0f32, f32::min),
    };
    let session = ext.sessions.len() as u32;
    let next = record::extension(
        Some(&ext),
        &record::SessionRun {
            seq: &seq,
            prep: &prep,
            solver: a.solver,
            mu: a.mu,
            params: &params,
            database: &o.database,
            rows: &rows,
            labels: &o.labels[first..],
            measured: &measured,
            online: o.online.as_ref(),
        },
    );
    let session_of = |g: usize| next.session_of(g as u32).unwrap_or((session, 0));
    let mut json = metrics_json::of_select(&seq, &prep, &o, a.mu, &params);
    let per_session = |f: &dyn Fn(u32) -> usize| -> Vec<usize> { (0..=session).map(f).collect() };
    json["frames"] = next.frames.len().into();
    json["sessions"] = (session + 1).into();
    json["session_frames"] = next.sessions.clone().into();
    json["session_database"] =
        per_session(&|s| next.database.iter().filter(|f| f.session == s).count()).into();
    let uncovered_of = |g: usize, f: &extension::FrameEntry| match f.measured {
        Some(x) => !x.covered,
        None => matches!(f.fate, extension::Fate::Uncovered(_)) && g < first,
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
        )?;
        let path = dir.join("topview.png");
        annotate::render(&view, &caption)
            .image
            .write_png(&path)
            .map_err(|source| DatasetError::Write { path, source })?;
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
        let st = &run.status;
        println!(
            "  online core: profile {}, window {}, {} frames by sketch, {} truncated, {} uncovered by capacity",
            params.profile, params.window, st.sketched_frames, st.truncated_frames, st.uncovered_frames
        );
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

/// The solver on the new session with the earlier database fixed.
fn solve(
    ext: &Extension,
    seq: &Sequence,
    prep: &Prepared,
    solver: Solver,
    mu: f32,
    params: &SolverParams,
) -> Result<Solved, Error> {
    let first = ext.next_index() as usize;
    let m = ext.database.len();
    if solver == Solver::Online {
        let (scan, cfg) = pipeline::online_config(seq, prep, mu, params);
        let sets = (!params.push_rows).then_some(&prep.sets);
        let run = replay::extend_from(
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
    let (sets, _) = fixed::combined_sets(ext, &prep.sets.sets, false, Missing::Refuse)?;
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
