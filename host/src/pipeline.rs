//! One selection run end to end: voxelize once, count co-observations once,
//! then any solver, labels and metrics. `select`, `compare` and `bench` all
//! go through here, so they time and score the same way.

use crate::degradation::{self, Losses};
use crate::replay::{self as online, OnlineRun, ReplayError};
use crate::sequence::Sequence;
use crate::voxelize::{voxelize, voxelize_on, VoxelConfig, VoxelSets, VoxelizeError};
use crate::yardstick::graph::CoObservation;
use crate::yardstick::metrics::{self, Metrics};
use crate::yardstick::solve;
use indicatif::{ProgressBar, ProgressStyle};
use placedb::{ScanConfig, SelectorConfig, VoxelGrid};
use std::time::{Duration, Instant};

/// Solver names (DESIGN section 2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Solver {
    /// The paper's result: take a frame iff no taken frame overlaps it.
    InOrder,
    /// Take the frame dominating most undominated frames, repeatedly.
    Greedy,
    /// A minimum dominating set (integer program, HiGHS), within a time limit.
    Exact,
    /// The device core's streaming selector, replayed.
    Online,
    /// Baseline: every N-th frame.
    EveryNth,
    /// Baseline: a frame each D metres of path.
    Distance,
    /// Baseline: the frame nearest the centre of each C-metre cube.
    Cube,
}

impl Solver {
    /// Every solver and baseline, in report order.
    pub const ALL: [Solver; 7] = [
        Solver::InOrder,
        Solver::Greedy,
        Solver::Exact,
        Solver::Online,
        Solver::EveryNth,
        Solver::Distance,
        Solver::Cube,
    ];

    /// The name used on the command line and in files.
    pub fn name(self) -> &'static str {
        match self {
            Solver::InOrder => "in-order",
            Solver::Greedy => "greedy",
            Solver::Exact => "exact",
            Solver::Online => "online",
            Solver::EveryNth => "every-nth",
            Solver::Distance => "distance",
            Solver::Cube => "cube",
        }
    }
}

/// Parameters of the solvers that have some.
#[derive(Debug, Clone)]
pub struct SolverParams {
    /// `every-nth`: N.
    pub every_nth: usize,
    /// `distance`: metres of path between taken frames.
    pub distance: f64,
    /// `cube`: cube edge, metres.
    pub cube: f64,
    /// `exact`: time limit.
    pub time_limit: Duration,
    /// `online`: capacity profile.
    pub profile: String,
    /// `online`: window length (1 = in-order rule).
    pub window: u16,
    /// `online`: extra IoU a sketch estimate needs.
    pub sketch_margin: f32,
    /// `online`: sampled rows per pushed chunk.
    pub chunk_rows: usize,
    /// `online`: push every frame's rows instead of reusing the voxel sets.
    pub push_rows: bool,
}

impl Default for SolverParams {
    fn default() -> Self {
        SolverParams {
            every_nth: 10,
            distance: 0.5,
            cube: 1.0,
            time_limit: Duration::from_secs(60),
            profile: "ram512k".into(),
            window: 32,
            sketch_margin: 0.05,
            chunk_rows: 8,
            push_rows: false,
        }
    }
}

/// A voxelized sequence with its co-observation counts, shared by solvers.
pub struct Prepared {
    /// The configuration used.
    pub config: VoxelConfig,
    /// Voxel sets at the configured stride (what solvers see).
    pub sets: VoxelSets,
    /// Co-observation counts of `sets`.
    pub co: CoObservation,
    /// Stride-1 sets and counts for the metrics when the stride is not 1.
    pub exact: Option<(VoxelSets, CoObservation)>,
    /// Wall time of voxelization (including reading).
    pub voxelize_wall: Duration,
    /// Wall time of the co-observation count.
    pub graph_wall: Duration,
    /// What the input lost (skipped and empty frames, points out of key range).
    pub losses: Losses,
}

impl Prepared {
    /// Sets and counts the metrics are computed on (stride 1).
    pub fn eval(&self) -> (&VoxelSets, &CoObservation) {
        match &self.exact {
            Some((s, c)) => (s, c),
            None => (&self.sets, &self.co),
        }
    }
}

fn bar(len: usize, what: &str, quiet: bool) -> Option<ProgressBar> {
    if quiet {
        return None;
    }
    let pb = ProgressBar::new(len as u64);
    let style = ProgressStyle::with_template("{msg:>12} [{bar:30}] {pos}/{len} {elapsed}")
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> ");
    pb.set_style(style);
    pb.set_message(what.to_string());
    Some(pb)
}

/// Voxelizes `seq` and counts co-observations (with progress bars unless
/// `quiet`). A sequence without frames, or whose frames have no voxel (no
/// valid depth pixel, or every point out of key range), is refused: a run
/// that measured nothing is an error.
pub fn prepare(
    seq: &Sequence,
    config: VoxelConfig,
    quiet: bool,
) -> Result<Prepared, VoxelizeError> {
    prepare_with(seq, config, None, quiet)
}

/// [`prepare`] on `grid` instead of the one `config.origin` picks: a later
/// session voxelized on the grid of the sessions it extends.
pub fn prepare_on(
    seq: &Sequence,
    config: VoxelConfig,
    grid: VoxelGrid,
    quiet: bool,
) -> Result<Prepared, VoxelizeError> {
    prepare_with(seq, config, Some(grid), quiet)
}

fn prepare_with(
    seq: &Sequence,
    config: VoxelConfig,
    grid: Option<VoxelGrid>,
    quiet: bool,
) -> Result<Prepared, VoxelizeError> {
    degradation::check_frames(seq)?;
    let n = seq.frames.len();
    let t = Instant::now();
    let pb = bar(n, "voxelizing", quiet);
    let sets = match grid {
        Some(grid) => voxelize_on(seq, &config, grid, pb.as_ref())?,
        None => voxelize(seq, &config, pb.as_ref())?,
    };
    pb.inspect(|p| p.finish_and_clear());
    degradation::check_measured(seq, config.range, config.voxel, &sets)?;
    let losses = Losses::of(seq, &sets);
    let voxelize_wall = t.elapsed();
    let t = Instant::now();
    let pb = bar(n, "overlaps", quiet);
    let co = CoObservation::new(&sets.sets, pb.as_ref());
    pb.inspect(|p| p.finish_and_clear());
    let graph_wall = t.elapsed();
    let exact = if config.stride == 1 {
        None
    } else {
        let pb = bar(n, "exact sets", quiet);
        let cfg1 = VoxelConfig {
            stride: 1,
            ..config
        };
        let s1 = match grid {
            Some(grid) => voxelize_on(seq, &cfg1, grid, pb.as_ref())?,
            None => voxelize(seq, &cfg1, pb.as_ref())?,
        };
        pb.inspect(|p| p.finish_and_clear());
        let c1 = CoObservation::new(&s1.sets, None);
        Some((s1, c1))
    };
    Ok(Prepared {
        config,
        sets,
        co,
        exact,
        voxelize_wall,
        graph_wall,
        losses,
    })
}

/// What one solver produced.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// Solver used.
    pub solver: Solver,
    /// Database frames, ascending.
    pub database: Vec<usize>,
    /// Class label of every frame.
    pub labels: Vec<usize>,
    /// Metrics of DESIGN section 3 (on stride-1 sets).
    pub metrics: Metrics,
    /// Wall time of the solver itself.
    pub solve_time: Duration,
    /// `exact`: whether proven minimum, and the proven lower bound.
    pub exact: Option<(bool, usize)>,
    /// `online`: the replay (decisions, status, records).
    pub online: Option<OnlineRun>,
    /// Frames whose label is another frame and whose exact IoU with it is
    /// not above mu (0 for exact solvers; the price of sketches online).
    pub labels_below_mu: usize,
    /// Smallest exact IoU of a frame with its label (another frame); 1 if none.
    pub label_iou_min: f32,
}

/// Why a solver failed.
#[derive(Debug, thiserror::Error)]
pub enum SolveError {
    /// The online replay failed.
    #[error(transparent)]
    Replay(#[from] ReplayError),
    /// A parameter is out of range.
    #[error("{0}")]
    Param(String),
}

/// The online core's scan and selection configuration for `seq` as
/// `prep` voxelized it, at threshold `mu`.
pub fn online_config(
    seq: &Sequence,
    prep: &Prepared,
    mu: f32,
    params: &SolverParams,
) -> (ScanConfig, SelectorConfig) {
    let scan = ScanConfig {
        intrinsics: seq.intrinsics(),
        depth_scale: seq.depth_scale as f32,
        range: prep.config.range,
        stride: prep.config.stride,
        grid: prep.sets.grid,
    };
    let cfg = SelectorConfig {
        mu,
        window: params.window,
        sketch_margin: params.sketch_margin,
    };
    (scan, cfg)
}

/// Runs `solver` at threshold `mu` on a prepared sequence.
pub fn solve(
    seq: &Sequence,
    prep: &Prepared,
    solver: Solver,
    mu: f32,
    params: &SolverParams,
    quiet: bool,
) -> Result<Outcome, SolveError> {
    let n = seq.frames.len();
    let t = Instant::now();
    let mut exact = None;
    let mut online = None;
    let graph = || prep.co.graph(mu);
    let database = match solver {
        // The scan needs each frame's later overlaps only: the rows of the
        // co-observation counts, without the graph.
        Solver::InOrder => solve::in_order_by(n, |v| prep.co.later_overlaps(v, mu)),
        Solver::Greedy => solve::greedy(&graph()),
        Solver::Exact => {
            let r = solve::exact(&graph(), params.time_limit);
            exact = Some((r.optimal, r.lower_bound));
            r.set
        }
        Solver::EveryNth => {
            if params.every_nth == 0 {
                return Err(SolveError::Param("--every-nth must be at least 1".into()));
            }
            solve::every_nth(n, params.every_nth)
        }
        Solver::Distance => {
            if !(params.distance.is_finite() && params.distance > 0.0) {
                return Err(SolveError::Param(
                    "--distance must be a positive number of metres".into(),
                ));
            }
            solve::distance(&seq.frames, params.distance)
        }
        Solver::Cube => {
            if !(params.cube.is_finite() && params.cube > 0.0) {
                return Err(SolveError::Param(
                    "--cube must be a positive number of metres".into(),
                ));
            }
            solve::cube(&seq.frames, params.cube)
        }
        Solver::Online => {
            let (scan, cfg) = online_config(seq, prep, mu, params);
            let pb = bar(n, "online", quiet);
            // The replay reuses the voxel sets computed above (same stride,
            // grid and camera): only frames the device would truncate are
            // decoded again.
            let run = if params.push_rows {
                online::replay(
                    seq,
                    &params.profile,
                    scan,
                    cfg,
                    params.chunk_rows,
                    pb.as_ref(),
                )
            } else {
                online::replay_voxelized(
                    seq,
                    &prep.sets,
                    &params.profile,
                    scan,
                    cfg,
                    params.chunk_rows,
                    pb.as_ref(),
                )
            }?;
            pb.inspect(|p| p.finish_and_clear());
            let mut db: Vec<usize> = run.database.iter().map(|r| r.index as usize).collect();
            db.sort_unstable();
            online = Some(run);
            db
        }
    };
    let solve_time = t.elapsed();
    let mut database = database;
    database.sort_unstable();
    database.dedup();
    let labels = match &online {
        Some(run) => run.labels.clone(),
        None if database.is_empty() => (0..n).collect(),
        None => solve::labels(&prep.co, &database),
    };
    let measured = measure(prep, &database, &labels, mu);
    Ok(Outcome {
        solver,
        database,
        labels,
        metrics: measured.metrics,
        solve_time,
        exact,
        online,
        labels_below_mu: measured.labels_below_mu,
        label_iou_min: measured.label_iou_min,
    })
}

/// The quality of a database on a prepared sequence, however it was
/// selected (a solver here, or a device's scan of the same frames).
#[derive(Debug, Clone)]
pub struct Measured {
    /// Metrics of DESIGN section 3 (on stride-1 sets).
    pub metrics: Metrics,
    /// As [`Outcome::labels_below_mu`].
    pub labels_below_mu: usize,
    /// As [`Outcome::label_iou_min`].
    pub label_iou_min: f32,
}

/// Measures database `database` (ascending frame indices of `prep`'s
/// sequence) with class `labels` (one per frame) at threshold `mu`.
///
/// # Panics
/// When an index is not a frame of `prep`.
pub fn measure(prep: &Prepared, database: &[usize], labels: &[usize], mu: f32) -> Measured {
    let (eval_sets, eval_co) = prep.eval();
    let metrics = metrics::evaluate(&eval_sets.sets, eval_co, database, mu);
    // Labels judged on the solver's own (stride-s) sets, where coverage is promised.
    let label_ious: Vec<f32> = labels
        .iter()
        .enumerate()
        .filter(|&(f, &l)| f != l)
        .map(|(f, &l)| prep.co.iou(f, l))
        .collect();
    Measured {
        metrics,
        labels_below_mu: label_ious.iter().filter(|&&x| x <= mu).count(),
        label_iou_min: label_ious.iter().copied().fold(1.0f32, f32::min),
    }
}

impl Outcome {
    /// What the input lost for this outcome: the prepared sequence's
    /// losses, with the online core's own count of points out of key range
    /// (the device's figure, which the replay reports).
    pub fn losses(&self, prep: &Prepared) -> Losses {
        match &self.online {
            Some(run) => Losses {
                out_of_range_points: run.status.out_of_range_points.into(),
                ..prep.losses
            },
            None => prep.losses,
        }
    }

    /// Every non-zero degradation of this outcome, as warning lines.
    pub fn warnings(&self, prep: &Prepared) -> Vec<String> {
        let mut w = self.losses(prep).warnings();
        if let Some(run) = &self.online {
            w.extend(degradation::device_warnings(
                &degradation::DeviceCounters::of_selector(&run.status),
            ));
        }
        w
    }
}

/// Adds `oracle_recall@0.3` of `outcome`'s database on a test sequence's sets.
pub fn add_oracle_recall(outcome: &mut Outcome, prep: &Prepared, test_sets: &VoxelSets) {
    let (eval_sets, _) = prep.eval();
    let db: Vec<&[u64]> = outcome
        .database
        .iter()
        .map(|&i| eval_sets.sets[i].as_slice())
        .collect();
    outcome.metrics.oracle_recall_0_3 = Some(metrics::oracle_recall(&test_sets.sets, &db, 0.3));
}

/// Voxelizes a test sequence on `prep`'s grid at stride 1, for [`add_oracle_recall`].
pub fn prepare_test(
    seq: &Sequence,
    prep: &Prepared,
    quiet: bool,
) -> Result<VoxelSets, VoxelizeError> {
    let pb = bar(seq.frames.len(), "test seq", quiet);
    let cfg = VoxelConfig {
        stride: 1,
        ..prep.config
    };
    let sets = voxelize_on(seq, &cfg, prep.sets.grid, pb.as_ref())?;
    pb.inspect(|p| p.finish_and_clear());
    // A test sequence that measured nothing would score any database 0.
    degradation::check_measured(seq, cfg.range, cfg.voxel, &sets)?;
    Ok(sets)
}
