//! `placedb compare`: every solver and baseline on one sequence, one table
//! (or a JSON array of their `metrics.json` objects).

use super::{open_sequence, open_test, solver_params, voxel_config};
use super::{ParamArgs, SeqArgs};
use crate::degradation::{self, plural, DeviceCounters};
use crate::error::CommandError as Error;
use crate::output::metrics_json;
use crate::pipeline::{self, Solver};
use clap::Args;

#[derive(Args)]
pub struct CompareArgs {
    #[command(flatten)]
    seq: SeqArgs,
    /// IoU thresholds, comma separated, each from 0 to below 1.
    #[arg(long, default_value = "0.3", value_delimiter = ',', value_parser = super::params::mu, allow_hyphen_values = true)]
    mu: Vec<f32>,
    #[command(flatten)]
    params: ParamArgs,
}

/// Runs `placedb compare`.
pub fn run(a: CompareArgs) -> Result<(), Error> {
    let params = solver_params(&a.params)?;
    let seq = open_sequence(&a.seq)?;
    super::warn_voxel_memory(&seq, &a.seq);
    let prep = pipeline::prepare(&seq, voxel_config(&a.seq), a.params.quiet)?;
    let test = match &a.params.test {
        Some(t) => Some(pipeline::prepare_test(
            &open_test(t, &a.seq)?,
            &prep,
            a.params.quiet,
        )?),
        None => None,
    };
    let mut all = Vec::new();
    // The input's losses are every solver's: warned once; the online
    // core's own, once per mu.
    crate::warning::warn_all(&prep.losses.warnings());
    for &mu in &a.mu {
        for solver in Solver::ALL {
            let mut o = pipeline::solve(&seq, &prep, solver, mu, &params, true)?;
            if let Some(t) = &test {
                pipeline::add_oracle_recall(&mut o, &prep, t);
            }
            if let Some(run) = &o.online {
                let w = degradation::device_warnings(&DeviceCounters::of_selector(&run.status));
                let w: Vec<String> = w.iter().map(|l| format!("at mu {mu}: {l}")).collect();
                crate::warning::warn_all(&w);
            }
            all.push((mu, o));
        }
    }
    if a.params.json {
        let v: Vec<_> = all
            .iter()
            .map(|(mu, o)| metrics_json::of_select(&seq, &prep, o, *mu, &params))
            .collect();
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!(
        "{}: {}, voxel {} m, stride {}, voxelize {:.3} s, overlaps {:.3} s",
        seq.name,
        plural(seq.frames.len() as u64, "frame", "frames"),
        prep.config.voxel,
        prep.config.stride,
        prep.voxelize_wall.as_secs_f64(),
        prep.graph_wall.as_secs_f64()
    );
    println!("{}", prep.losses.summary_line());
    println!(
        "{:>5} {:<10} {:>6} {:>9} {:>9} {:>8} {:>8} {:>8} {:>8} {:>8} {:>9}",
        "mu",
        "solver",
        "size",
        "reduction",
        "uncovered",
        "spatial",
        "fc_mean",
        "fc_min",
        "fc<0.3",
        "recall",
        "time_s"
    );
    for (mu, o) in &all {
        let m = &o.metrics;
        let recall = m
            .oracle_recall_0_3
            .map_or("-".to_string(), |r| format!("{r:.3}"));
        let name = match o.exact {
            Some((false, _)) => format!("{}*", o.solver.name()),
            _ => o.solver.name().to_string(),
        };
        println!(
            "{:>5} {:<10} {:>6} {:>9.1} {:>9} {:>8.3} {:>8.3} {:>8.3} {:>7.1}% {:>8} {:>9.3}",
            mu,
            name,
            m.size,
            m.reduction,
            m.uncovered,
            m.spatial_coverage,
            m.frames_coverage_mean,
            m.frames_coverage_min,
            100.0 * m.frames_coverage_below_0_3,
            recall,
            o.solve_time.as_secs_f64()
        );
    }
    for (mu, o) in &all {
        if let Some(run) = &o.online {
            let line = degradation::online_summary(&params.profile, params.window, &run.status);
            println!("at mu {mu}: {line}");
        }
    }
    if all.iter().any(|(_, o)| matches!(o.exact, Some((false, _)))) {
        println!("* exact hit its time limit: best set found, not proven minimum");
    }
    Ok(())
}
