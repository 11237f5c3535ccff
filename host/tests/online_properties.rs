//! Property tests of the online selector (`placedb::Selector`) over random
//! scenes: a random box room with a few box obstacles, rendered from camera
//! poses along a random walk (so consecutive frames overlap), with random
//! intrinsics, pixel strides, voxel sizes, thresholds, windows, dropped
//! pixels, blank frames and row chunkings.
//!
//! Checked:
//! a. every frame gets exactly one final decision, final decisions come in
//!    frame order, `Pending` at most once, only at the frame's own end and
//!    before its final decision, and a frame is decided at most `window - 1`
//!    frames after it arrived;
//! b. exact mode (no capacity reached, `flags == 0`): every frame is `Taken`
//!    or `DominatedBy(k)` with `k` taken and `IoU(d_i, d_k) > mu`, where the
//!    sets are computed independently from the full-resolution rows with
//!    `FrameProjector::project_row`;
//! c. decisions, database and status do not depend on the row chunking;
//! d. no capacity is ever exceeded (used and peak <= limit, after every frame);
//! e. the same input gives the same output;
//! f. window = 1 reproduces `in-order` on the exact overlap graph, and each
//!    label is the best-IoU earlier database frame;
//! g. in exact mode the database is a dominating set of G(mu) for any window;
//! h. in exact mode the whole decision stream (including `Pending`) equals a
//!    plain reference model of the rule documented in src/select/mod.rs, run on
//!    the exact sets: a frame is covered once a database frame overlaps it
//!    (label: best IoU, ties lowest index); an uncovered oldest frame makes
//!    the selector take, among itself and the open window frames overlapping
//!    it, the one overlapping the most uncovered open window frames (itself
//!    included; ties: the latest frame).
//!
//! h also runs at the profiles' windows (16, 32, 48) on scans longer than
//! the window, and on the sketch path (a key pool of 0 words: every overlap
//! is a sketch estimate) against the same rule over the estimates. A quarter
//! of the scans anchor the grid so that the voxel key range ends mid-room:
//! the points beyond are dropped and counted, and nothing else changes.
//!
//! Degraded mode (tiny capacities): a, c, d, e and the consistency of the
//! counters, flags and decisions; never a panic.

use placedb::key_pool::Aabb;
use placedb::select::database::CoarseBox;
use placedb::select::flags;
use placedb::sketch::Sketch;
use placedb::voxel::{intersection_size, iou};
use placedb::{
    DbRecord, Decision, DepthRange, FrameDecision, FrameMeta, FrameProjector, Intrinsics, Pose,
    ScanConfig, Selector, SelectorConfig, Status, VoxelGrid,
};
use placedb_host::rng::SplitMix64 as Rng;
use placedb_host::yardstick::graph::CoObservation;
use placedb_host::yardstick::solve::{in_order, is_dominating};
use proptest::prelude::*;

// ---------------------------------------------------------------------------
// Capacities under test.

/// Large enough that nothing degrades on the generated scenes: the frame set
/// holds 3072 keys >= 64 * 48 pixels, the pool holds 40 frames of 3072 keys
/// (at most 40 frames are ever stored), the database holds 64 >= 40 frames.
type Exact = Selector<4096, 131_072, 64, 8, 32>;
/// Frame voxel set of 192 keys, a pool of about five frames, a database of 4,
/// a window of 4 and sketches of 16 hashes: every capacity runs out.
type Tiny = Selector<256, 1024, 4, 4, 16>;

const MAX_FRAMES: usize = 40;

/// A selector built on a thread with a large stack (the exact profile is
/// ~0.5 MiB and debug builds move it by value before boxing).
fn new_selector<
    const FV: usize,
    const POOL: usize,
    const DB: usize,
    const W: usize,
    const K: usize,
    const R: usize,
>() -> Box<Selector<FV, POOL, DB, W, K, R>> {
    std::thread::Builder::new()
        .stack_size(64 << 20)
        .spawn(|| Box::new(Selector::<FV, POOL, DB, W, K, R>::new()))
        .expect("spawn")
        .join()
        .expect("selector construction panicked")
}

// ---------------------------------------------------------------------------
// Scene generation.

/// Everything a scene is derived from (small, so proptest can print and
/// shrink it); the pixels are a pure function of these.
#[derive(Debug, Clone)]
struct Params {
    seed: u64,
    width: u16,
    height: u16,
    frames: usize,
    stride: u16,
    mu: f32,
    window: u16,
    voxel: f32,
    /// Largest camera step between frames, metres.
    step: f64,
    /// Largest yaw change between frames, radians.
    turn: f64,
    /// Share of pixels with no measurement.
    dropout: f64,
    /// The grid anchored so that the voxel key range ends mid-room: the
    /// points beyond it are out of range (dropped and counted).
    edge: bool,
}

fn params() -> impl Strategy<Value = Params> {
    (
        any::<u64>(),
        32u16..=64,
        24u16..=48,
        6usize..=MAX_FRAMES,
        1u16..=3,
        0.05f32..0.6,
        1u16..=8,
        prop::sample::select(vec![0.2f32, 0.3, 0.4]),
        0.02f64..0.5,
        0.0f64..0.6,
        0.0f64..0.3,
        prop::bool::weighted(0.25),
    )
        .prop_map(
            |(
                seed,
                width,
                height,
                frames,
                stride,
                mu,
                window,
                voxel,
                step,
                turn,
                dropout,
                edge,
            )| {
                Params {
                    seed,
                    width,
                    height,
                    frames,
                    stride,
                    mu,
                    window,
                    voxel,
                    step,
                    turn,
                    dropout,
                    edge,
                }
            },
        )
}

/// Scans for the profiles' own windows (16, 32, 48): more frames than the
/// window, smaller images so that a run stays quick.
fn wide_params() -> impl Strategy<Value = Params> {
    (
        params(),
        prop::sample::select(vec![16u16, 32, 48]),
        24u16..=40,
        18u16..=30,
        1u16..=2,
        10usize..=60,
    )
        .prop_map(|(p, window, width, height, stride, extra)| Params {
            window,
            width,
            height,
            stride,
            frames: usize::from(window) + extra,
            ..p
        })
}

/// An axis-aligned box, metres.
#[derive(Debug, Clone, Copy)]
struct Aabb3 {
    min: [f64; 3],
    max: [f64; 3],
}

/// A rendered frame.
#[derive(Debug, Clone)]
struct Frame {
    pose: Pose,
    timestamp: f64,
    /// Full-resolution depth, row-major.
    depth: Vec<u16>,
}

/// A rendered scan and the scan configuration the selector gets.
#[derive(Debug, Clone)]
struct Scan {
    scan: ScanConfig,
    frames: Vec<Frame>,
}

impl Scan {
    fn width(&self) -> usize {
        self.scan.intrinsics.width as usize
    }

    fn height(&self) -> usize {
        self.scan.intrinsics.height as usize
    }

    fn row(&self, f: usize, v: usize) -> &[u16] {
        let w = self.width();
        &self.frames[f].depth[v * w..(v + 1) * w]
    }

    /// Sampled rows of frame `f` as a board receives them (see
    /// `placedb_host::frame_rows::sampled_rows`): row `r` is image row
    /// `r * stride`, sample `i` is column `i * stride`.
    fn sampled(&self, f: usize) -> (usize, Vec<u16>) {
        let s = self.scan.stride as usize;
        let width = self.width().div_ceil(s);
        let mut out = Vec::new();
        for v in (0..self.height()).step_by(s) {
            out.extend(self.row(f, v).iter().step_by(s));
        }
        (width, out)
    }
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalize(a: [f64; 3]) -> [f64; 3] {
    let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    [a[0] / n, a[1] / n, a[2] / n]
}

/// Camera-to-world rotation (rows) of a camera looking along yaw/pitch with
/// a roll about its optical axis; OpenCV axes (x right, y down, z forward),
/// world z up.
fn look(yaw: f64, pitch: f64, roll: f64) -> [[f64; 3]; 3] {
    let f = [
        yaw.cos() * pitch.cos(),
        yaw.sin() * pitch.cos(),
        pitch.sin(),
    ];
    let right0 = normalize(cross(f, [0.0, 0.0, 1.0]));
    let down0 = cross(f, right0);
    let (c, s) = (roll.cos(), roll.sin());
    let right = [0, 1, 2].map(|a| c * right0[a] + s * down0[a]);
    let down = cross(f, right);
    // Columns are the camera axes in world coordinates.
    [0, 1, 2].map(|r| [right[r], down[r], f[r]])
}

/// Distance along `d` (un-normalised) from `o` inside the room to the first
/// surface: the room's walls from inside or an obstacle from outside.
fn cast(room: &Aabb3, obstacles: &[Aabb3], o: [f64; 3], d: [f64; 3]) -> f64 {
    let mut t = f64::INFINITY;
    for a in 0..3 {
        if d[a] > 0.0 {
            t = t.min((room.max[a] - o[a]) / d[a]);
        } else if d[a] < 0.0 {
            t = t.min((room.min[a] - o[a]) / d[a]);
        }
    }
    for b in obstacles {
        let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
        let mut miss = false;
        for a in 0..3 {
            if d[a] == 0.0 {
                if o[a] < b.min[a] || o[a] > b.max[a] {
                    miss = true;
                }
                continue;
            }
            let (p, q) = ((b.min[a] - o[a]) / d[a], (b.max[a] - o[a]) / d[a]);
            t0 = t0.max(p.min(q));
            t1 = t1.min(p.max(q));
        }
        if !miss && t0 <= t1 && t0 > 1e-9 {
            t = t.min(t0);
        }
    }
    t
}

/// The scan of `p`: a room of 3-8 m with up to three obstacles, a random walk
/// of the camera inside it, depth in 1000 or 5000 units per metre.
fn render(p: &Params) -> Scan {
    let mut rng = Rng::new(p.seed);
    let (w, h) = (p.width, p.height);
    let fx = rng.range(0.5, 1.2) * w as f64;
    let intrinsics = Intrinsics {
        width: w,
        height: h,
        fx: fx as f32,
        fy: (fx * rng.range(0.9, 1.1)) as f32,
        cx: ((w as f64 - 1.0) / 2.0 + rng.range(-3.0, 3.0)) as f32,
        cy: ((h as f64 - 1.0) / 2.0 + rng.range(-3.0, 3.0)) as f32,
    };
    let depth_scale = if rng.unit() < 0.5 { 1000.0 } else { 5000.0 };
    let mut origin = [0, 1, 2].map(|_| rng.range(-1.0, 1.0) as f32);
    let room = Aabb3 {
        min: [0.0; 3],
        max: [
            rng.range(3.0, 8.0),
            rng.range(3.0, 8.0),
            rng.range(2.4, 3.2),
        ],
    };
    if p.edge {
        // Keys span 2^20 voxels either side of the origin on each axis.
        let span = f64::from(1u32 << 20) * f64::from(p.voxel);
        origin[0] = (room.max[0] / 2.0 - span) as f32;
    }
    let scan = ScanConfig {
        intrinsics,
        depth_scale,
        range: DepthRange::default(),
        stride: p.stride,
        grid: VoxelGrid::new(p.voxel, origin).expect("grid"),
    };
    let obstacles: Vec<Aabb3> = (0..rng.next_u64() % 4)
        .map(|_| {
            let (sx, sy, sz) = (
                rng.range(0.3, 1.2),
                rng.range(0.3, 1.2),
                rng.range(0.5, 2.0),
            );
            let x = rng.range(0.0, room.max[0] - sx);
            let y = rng.range(0.0, room.max[1] - sy);
            Aabb3 {
                min: [x, y, 0.0],
                max: [x + sx, y + sy, sz],
            }
        })
        .collect();
    let margin = 0.3;
    let clamp = |c: f64, a: usize| c.clamp(margin, room.max[a] - margin);
    let mut pos = [
        rng.range(margin, room.max[0] - margin),
        rng.range(margin, room.max[1] - margin),
        rng.range(1.0, 1.8),
    ];
    let mut yaw = rng.range(-std::f64::consts::PI, std::f64::consts::PI);
    let mut frames = Vec::with_capacity(p.frames);
    for i in 0..p.frames {
        if i > 0 {
            yaw += rng.range(-p.turn, p.turn);
            let dist = rng.range(0.0, p.step);
            let heading = yaw + rng.range(-0.5, 0.5);
            pos[0] = clamp(pos[0] + dist * heading.cos(), 0);
            pos[1] = clamp(pos[1] + dist * heading.sin(), 1);
            pos[2] = clamp(pos[2] + rng.range(-0.05, 0.05), 2);
        }
        let pitch = rng.range(-0.3, 0.3);
        let roll = rng.range(-0.1, 0.1);
        let r = look(yaw, pitch, roll);
        let r32 = r.map(|row| row.map(|c| c as f32));
        let pose = Pose::from_matrix(r32, pos.map(|c| c as f32)).expect("pose");
        // Render with the very rotation the core will use.
        let r = pose.rotation_matrix().map(|row| row.map(|c| c as f64));
        let o = pose.translation.map(|c| c as f64);
        let blank = rng.unit() < 0.05;
        let mut depth = Vec::with_capacity(w as usize * h as usize);
        for v in 0..h as usize {
            let y = (v as f64 - intrinsics.cy as f64) / intrinsics.fy as f64;
            for u in 0..w as usize {
                let x = (u as f64 - intrinsics.cx as f64) / intrinsics.fx as f64;
                let d = [0, 1, 2].map(|a| r[a][0] * x + r[a][1] * y + r[a][2]);
                let t = cast(&room, &obstacles, o, d);
                let units = (t * depth_scale as f64).round();
                let drop = rng.unit() < p.dropout;
                depth.push(if blank || drop || !units.is_finite() || units > 65535.0 {
                    0
                } else {
                    units as u16
                });
            }
        }
        frames.push(Frame {
            pose,
            timestamp: 1.0 + i as f64 / 30.0,
            depth,
        });
    }
    Scan { scan, frames }
}

/// The voxel set of every frame, computed from the full-resolution rows with
/// the core's projector (not through the selector's ingest), and the points
/// out of the key range in all of them.
fn voxel_sets(scan: &Scan) -> (Vec<Vec<u64>>, u32) {
    let c = &scan.scan;
    let mut out_of_range = 0;
    let sets = (0..scan.frames.len())
        .map(|f| {
            let proj = FrameProjector::new(
                &c.intrinsics,
                c.depth_scale,
                c.range,
                c.stride,
                &c.grid,
                &scan.frames[f].pose,
            )
            .expect("projector");
            let mut keys = Vec::new();
            let mut oor = 0;
            for v in 0..scan.height() {
                proj.project_row(v as u16, scan.row(f, v), &mut oor, |k| {
                    keys.push(k.to_bits())
                });
            }
            out_of_range += oor;
            keys.sort_unstable();
            keys.dedup();
            keys
        })
        .collect();
    (sets, out_of_range)
}

fn set_iou(a: &[u64], b: &[u64]) -> f32 {
    iou(a.len() as u32, b.len() as u32, intersection_size(a, b))
}

// ---------------------------------------------------------------------------
// Running the selector.

/// How sampled rows are cut into `push_rows` chunks.
#[derive(Debug, Clone, Copy)]
enum Chunking {
    PerRow,
    Whole,
    /// Random chunk sizes from this seed.
    Random(u64),
}

/// Everything observable of one run.
#[derive(Debug, Clone, PartialEq)]
struct Run {
    /// `(step, decision)`: step `i` is `end_frame` of frame `i`, step `n` is `finish`.
    log: Vec<(usize, FrameDecision)>,
    database: Vec<DbRecord>,
    status: Status,
    /// Status after every `end_frame`, then after `finish`.
    trace: Vec<Status>,
    config: SelectorConfig,
}

impl Run {
    /// Final decision of every frame (panics unless there is exactly one).
    fn finals(&self, n: usize) -> Vec<Decision> {
        let mut out = vec![None; n];
        for &(_, d) in &self.log {
            if d.decision != Decision::Pending {
                let slot = &mut out[d.index as usize];
                assert!(slot.is_none(), "frame {} decided twice", d.index);
                *slot = Some(d.decision);
            }
        }
        out.into_iter()
            .enumerate()
            .map(|(i, d)| d.unwrap_or_else(|| panic!("frame {i} never decided")))
            .collect()
    }

    fn database_indices(&self) -> Vec<usize> {
        let mut v: Vec<usize> = self.database.iter().map(|r| r.index as usize).collect();
        v.sort_unstable();
        v
    }
}

fn run<
    const FV: usize,
    const POOL: usize,
    const DB: usize,
    const W: usize,
    const K: usize,
    const R: usize,
>(
    scan: &Scan,
    cfg: SelectorConfig,
    chunking: Chunking,
) -> Run {
    let mut sel = new_selector::<FV, POOL, DB, W, K, R>();
    sel.configure(scan.scan, cfg).expect("configure");
    let mut log = Vec::new();
    let mut trace = Vec::new();
    let mut rng = Rng::new(match chunking {
        Chunking::Random(s) => s,
        _ => 0,
    });
    for (i, frame) in scan.frames.iter().enumerate() {
        let meta = FrameMeta {
            index: i as u32,
            timestamp: frame.timestamp,
            pose: frame.pose,
        };
        sel.begin_frame(meta).expect("begin_frame");
        let (width, data) = scan.sampled(i);
        assert_eq!(sel.samples_per_row(), Some(width as u16));
        let rows = data.len() / width;
        let mut r = 0;
        while r < rows {
            let take = match chunking {
                Chunking::PerRow => 1,
                Chunking::Whole => rows,
                Chunking::Random(_) => 1 + rng.below((rows - r) as u64) as usize,
            };
            sel.push_rows(r as u16, &data[r * width..(r + take) * width])
                .expect("push_rows");
            r += take;
        }
        sel.end_frame(|d| log.push((i, d))).expect("end_frame");
        trace.push(sel.status());
    }
    let n = scan.frames.len();
    sel.finish(|d| log.push((n, d))).expect("finish");
    trace.push(sel.status());
    let database = (0..sel.database_len())
        .map(|i| {
            sel.database_record(i, &mut placedb::select::NoStore)
                .expect("record")
        })
        .collect();
    Run {
        log,
        database,
        status: sel.status(),
        trace,
        config: *sel.config().expect("configured"),
    }
}

fn config(p: &Params) -> SelectorConfig {
    SelectorConfig {
        mu: p.mu,
        window: p.window,
        ..SelectorConfig::default()
    }
}

// ---------------------------------------------------------------------------
// Checks shared by the properties.

/// a: one final decision per frame, in frame order; `Pending` at most once,
/// at the frame's own step, before its final decision; decided within the
/// window. Returns the final decisions.
fn check_decision_stream(r: &Run, n: usize) -> Result<Vec<Decision>, TestCaseError> {
    let w = r.config.window as usize;
    let mut pending = vec![false; n];
    let mut final_at: Vec<Option<usize>> = vec![None; n];
    let mut next_final = 0usize;
    for &(step, d) in &r.log {
        let i = d.index as usize;
        prop_assert!(i < n, "decision for unknown frame {}", i);
        prop_assert!(
            i <= step,
            "frame {} decided at step {} before it arrived",
            i,
            step
        );
        if d.decision == Decision::Pending {
            prop_assert_eq!(step, i, "Pending for frame {} at step {}", i, step);
            prop_assert!(!pending[i], "frame {} Pending twice", i);
            prop_assert!(final_at[i].is_none(), "frame {} Pending after its final", i);
            pending[i] = true;
        } else {
            prop_assert!(final_at[i].is_none(), "frame {} decided twice", i);
            prop_assert_eq!(i, next_final, "final decisions out of frame order");
            next_final += 1;
            final_at[i] = Some(step);
            if step < n {
                prop_assert!(
                    step < i + w,
                    "frame {} decided at step {}, window {}",
                    i,
                    step,
                    w
                );
            }
        }
    }
    prop_assert_eq!(next_final, n, "not every frame decided");
    for i in 0..n {
        let at = final_at[i].expect("decided");
        // Pending exactly when the frame stayed in the window at its own step.
        prop_assert_eq!(pending[i], at != i, "frame {}: Pending/final mismatch", i);
    }
    if w == 1 {
        prop_assert!(!pending.iter().any(|&p| p), "Pending with window 1");
    }
    prop_assert_eq!(r.status.frames_seen as usize, n);
    prop_assert_eq!(r.status.frames_decided as usize, n);
    Ok(r.finals(n))
}

/// d: every capacity respected after every step.
fn check_capacities(r: &Run, limits: [u32; 4]) -> Result<(), TestCaseError> {
    for s in &r.trace {
        let usages = [s.database, s.pool, s.window, s.frame_voxels];
        for (u, &limit) in usages.iter().zip(&limits) {
            prop_assert_eq!(u.limit, limit);
            prop_assert!(u.used <= u.peak, "{:?}", u);
            prop_assert!(u.peak <= u.limit, "{:?}", u);
        }
        prop_assert!(s.window.peak <= r.config.window as u32);
    }
    // After finish the window is empty.
    prop_assert_eq!(r.status.window.used, 0);
    Ok(())
}

/// Decisions refer to database frames; counters agree with the decisions.
fn check_consistency(r: &Run, finals: &[Decision]) -> Result<(), TestCaseError> {
    let taken: Vec<usize> = (0..finals.len())
        .filter(|&i| finals[i] == Decision::Taken)
        .collect();
    prop_assert_eq!(r.database_indices(), taken.clone());
    prop_assert_eq!(r.status.database.used as usize, r.database.len());
    let mut uncovered = 0;
    for (i, d) in finals.iter().enumerate() {
        match *d {
            Decision::Taken | Decision::Pending => {}
            Decision::DominatedBy(k) => {
                prop_assert!(k as usize != i, "frame {} dominated by itself", i);
                prop_assert_eq!(finals[k as usize], Decision::Taken, "frame {} -> {}", i, k);
            }
            Decision::Uncovered(k) => {
                uncovered += 1;
                // Only when the database is full, hence never without a nearest frame.
                prop_assert_eq!(r.database.len() as u32, r.status.database.limit);
                let k = k.expect("Uncovered with a non-empty database has a nearest frame");
                prop_assert_eq!(finals[k as usize], Decision::Taken);
            }
        }
    }
    prop_assert_eq!(r.status.uncovered_frames, uncovered);
    let flag = |f: u32| r.status.flags & f != 0;
    prop_assert_eq!(flag(flags::DATABASE_FULL), r.status.uncovered_frames > 0);
    prop_assert_eq!(flag(flags::POOL_FULL), r.status.sketched_frames > 0);
    prop_assert_eq!(
        flag(flags::FRAME_VOXELS_FULL),
        r.status.truncated_frames > 0
    );
    prop_assert_eq!(flag(flags::OUT_OF_RANGE), r.status.out_of_range_points > 0);
    Ok(())
}

/// b and g: exact mode. Returns the final decisions and the overlap graph's
/// in-order solution for reuse.
fn check_exact(
    r: &Run,
    scan: &Scan,
    (sets, out_of_range): &(Vec<Vec<u64>>, u32),
    mu: f32,
) -> Result<Vec<Decision>, TestCaseError> {
    let n = sets.len();
    // Points out of the key range are dropped and counted, nothing else.
    prop_assert_eq!(r.status.out_of_range_points, *out_of_range);
    prop_assert_eq!(
        r.status.flags & !flags::OUT_OF_RANGE,
        0,
        "exact mode degraded: {:?}",
        r.status
    );
    prop_assert_eq!(r.status.sketched_frames, 0);
    prop_assert_eq!(r.status.truncated_frames, 0);
    let finals = check_decision_stream(r, n)?;
    check_consistency(r, &finals)?;
    for (i, d) in finals.iter().enumerate() {
        match *d {
            Decision::Taken => {}
            Decision::DominatedBy(k) => {
                let x = set_iou(&sets[i], &sets[k as usize]);
                prop_assert!(x > mu, "frame {} -> {}: IoU {} <= mu {}", i, k, x, mu);
            }
            other => prop_assert!(false, "frame {}: {:?} in exact mode", i, other),
        }
    }
    for rec in &r.database {
        let f = &scan.frames[rec.index as usize];
        prop_assert_eq!(rec.voxels as usize, sets[rec.index as usize].len());
        prop_assert_eq!(rec.pose, f.pose);
        prop_assert_eq!(rec.timestamp, f.timestamp);
    }
    let peak = sets.iter().map(Vec::len).max().unwrap_or(0) as u32;
    prop_assert_eq!(r.status.frame_voxels.peak, peak);
    // g: a dominating set of G(mu) on the exact sets.
    let graph = CoObservation::new(sets, None).graph(mu);
    prop_assert!(is_dominating(&graph, &r.database_indices()));
    Ok(finals)
}

/// h: the documented window rule, written plainly over exact IoUs.
fn model(sets: &[Vec<u64>], mu: f32, window: usize) -> Vec<(usize, FrameDecision)> {
    let n = sets.len();
    let ious: Vec<Vec<f32>> = (0..n)
        .map(|a| (0..n).map(|b| set_iou(&sets[a], &sets[b])).collect())
        .collect();
    model_on(&ious, mu, window)
}

/// The rule when every frame is compared by sketch (no key fits the pool):
/// the bottom-`K` Jaccard estimate of sets whose boxes touch, counted as an
/// overlap only above `mu + margin`, and only where the bound of the later
/// frame's voxels inside the earlier one's box allows an IoU above mu.
fn sketch_model<const K: usize>(
    sets: &[Vec<u64>],
    mu: f32,
    margin: f32,
    window: usize,
) -> Vec<(usize, FrameDecision)> {
    let boxes: Vec<Option<Aabb>> = sets.iter().map(|s| Aabb::of_sorted(s)).collect();
    let sketches: Vec<Sketch<K>> = sets
        .iter()
        .map(|s| Sketch::from_keys(s.iter().copied()))
        .collect();
    let n = sets.len();
    let bound_allows = |a: usize, b: usize| {
        let (later, earlier) = (a.max(b), a.min(b));
        boxes[earlier].as_ref().is_some_and(|e| {
            let inside = CoarseBox::of(e).count_in(&sets[later]);
            let (l, r) = (sets[later].len() as u32, sets[earlier].len() as u32);
            iou(l, r, inside) > mu
        })
    };
    let estimates: Vec<Vec<f32>> = (0..n)
        .map(|a| {
            (0..n)
                .map(|b| match (&boxes[a], &boxes[b]) {
                    (Some(x), Some(y)) if x.touches(y) && bound_allows(a, b) => {
                        sketches[a].jaccard(&sketches[b])
                    }
                    _ => 0.0,
                })
                .collect()
        })
        .collect();
    model_on(&estimates, mu + margin, window)
}

/// The window rule over a symmetric matrix of overlap scores: `a` and `b`
/// overlap when their score is above `threshold`; labels go to the highest
/// score.
fn model_on(ious: &[Vec<f32>], mu: f32, window: usize) -> Vec<(usize, FrameDecision)> {
    let n = ious.len();
    let overlaps = |a: usize, b: usize| a != b && ious[a][b] > mu;
    let mut taken = vec![false; n];
    let mut db: Vec<usize> = Vec::new();
    let mut win: std::collections::VecDeque<usize> = Default::default();
    let mut log = Vec::new();
    let decide = |step: usize,
                  win: &mut std::collections::VecDeque<usize>,
                  taken: &mut Vec<bool>,
                  db: &mut Vec<usize>,
                  log: &mut Vec<(usize, FrameDecision)>| {
        let o = win.pop_front().expect("window not empty");
        // Best overlapping database frame: highest IoU, ties lowest index.
        let cover = |f: usize, db: &[usize]| {
            let mut best: Option<(f32, usize)> = None;
            for &b in db {
                let x = ious[f][b];
                if overlaps(f, b) && best.is_none_or(|(bx, bi)| x > bx || (x == bx && b < bi)) {
                    best = Some((x, b));
                }
            }
            best.map(|(_, b)| b)
        };
        let decision = if taken[o] {
            Decision::Taken
        } else if let Some(k) = cover(o, db) {
            Decision::DominatedBy(k as u32)
        } else {
            let open: Vec<usize> = std::iter::once(o)
                .chain(win.iter().copied())
                .filter(|&f| !taken[f])
                .collect();
            let uncovered: Vec<usize> = open
                .iter()
                .copied()
                .filter(|&f| cover(f, db).is_none())
                .collect();
            let mut best: Option<(usize, usize)> = None; // (score, frame)
            for &c in open.iter().filter(|&&c| c == o || overlaps(o, c)) {
                let score = uncovered
                    .iter()
                    .filter(|&&u| u == c || overlaps(c, u))
                    .count();
                if best.is_none_or(|(bs, bc)| score > bs || (score == bs && c > bc)) {
                    best = Some((score, c));
                }
            }
            let (_, c) = best.expect("the oldest frame is a candidate");
            taken[c] = true;
            db.push(c);
            if c == o {
                Decision::Taken
            } else {
                Decision::DominatedBy(c as u32)
            }
        };
        log.push((
            step,
            FrameDecision {
                index: o as u32,
                decision,
            },
        ));
    };
    for i in 0..n {
        win.push_back(i);
        while win.len() >= window {
            decide(i, &mut win, &mut taken, &mut db, &mut log);
        }
        if win.back() == Some(&i) {
            log.push((
                i,
                FrameDecision {
                    index: i as u32,
                    decision: Decision::Pending,
                },
            ));
        }
    }
    while !win.is_empty() {
        decide(n, &mut win, &mut taken, &mut db, &mut log);
    }
    log
}

fn exact_limits() -> [u32; 4] {
    [64, 131_072, 8, 3072]
}

fn tiny_limits() -> [u32; 4] {
    [4, 1024, 4, 192]
}

fn wide_limits() -> [u32; 4] {
    [128, 262_144, 48, 1536]
}

fn sketch_limits() -> [u32; 4] {
    [64, 0, 8, 3072]
}

// ---------------------------------------------------------------------------
// Properties.

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// a, b, c, d, e, g with the window of the case (1..=8).
    #[test]
    fn exact_mode(p in params(), chunk_seed in any::<u64>()) {
        let scan = render(&p);
        let voxels = voxel_sets(&scan);
        let sets = &voxels.0;
        let cfg = config(&p);
        let base = run::<4096, 131_072, 64, 8, 32, 64>(&scan, cfg, Chunking::PerRow);
        prop_assert_eq!(base.config.window, p.window);
        check_capacities(&base, exact_limits())?;
        check_exact(&base, &scan, &voxels, p.mu)?;
        // h: the documented rule.
        let expected = model(sets, p.mu, p.window as usize);
        prop_assert!(base.log == expected, "log {:?}\nmodel {:?}", base.log, expected);
        // c: any chunking gives the same run.
        for chunking in [Chunking::Whole, Chunking::Random(chunk_seed)] {
            let other = run::<4096, 131_072, 64, 8, 32, 64>(&scan, cfg, chunking);
            prop_assert!(other == base, "{:?} differs from one row per push", chunking);
        }
        // e: same input, same output.
        let again = run::<4096, 131_072, 64, 8, 32, 64>(&scan, cfg, Chunking::PerRow);
        prop_assert!(again == base, "second run differs");
    }

    /// f: window 1 is the paper's in-order rule on the exact overlap graph,
    /// and each frame's label is its best-IoU earlier database frame.
    #[test]
    fn window_one_is_in_order(p in params()) {
        let scan = render(&p);
        let voxels = voxel_sets(&scan);
        let sets = &voxels.0;
        let cfg = SelectorConfig { window: 1, ..config(&p) };
        let r = run::<4096, 131_072, 64, 8, 32, 64>(&scan, cfg, Chunking::Whole);
        check_capacities(&r, exact_limits())?;
        let finals = check_exact(&r, &scan, &voxels, p.mu)?;
        let graph = CoObservation::new(sets, None).graph(p.mu);
        prop_assert_eq!(r.database_indices(), in_order(&graph));
        prop_assert!(r.log == model(sets, p.mu, 1), "window 1 differs from the model");
        // Window 1 takes frames in frame order.
        let order: Vec<usize> = r.database.iter().map(|d| d.index as usize).collect();
        prop_assert_eq!(&order, &r.database_indices());
        for (i, d) in finals.iter().enumerate() {
            if let Decision::DominatedBy(k) = *d {
                // Best IoU among earlier database frames; ties: lowest index.
                let mut best: Option<(f32, usize)> = None;
                for &b in order.iter().filter(|&&b| b < i) {
                    let x = set_iou(&sets[i], &sets[b]);
                    if x > p.mu && best.is_none_or(|(bx, _)| x > bx) {
                        best = Some((x, b));
                    }
                }
                prop_assert_eq!(best.map(|(_, b)| b as u32), Some(k), "label of frame {}", i);
            }
        }
    }

    /// Every capacity of a tiny selector runs out: a, c, d, e and consistent
    /// counters, flags and decisions; no panic.
    #[test]
    fn degraded_mode(p in params(), chunk_seed in any::<u64>()) {
        let scan = render(&p);
        let cfg = config(&p);
        let base = run::<256, 1024, 4, 4, 16, 64>(&scan, cfg, Chunking::Whole);
        prop_assert_eq!(base.config.window, p.window.min(4));
        check_capacities(&base, tiny_limits())?;
        let finals = check_decision_stream(&base, scan.frames.len())?;
        check_consistency(&base, &finals)?;
        for rec in &base.database {
            prop_assert!(rec.voxels <= 192);
        }
        for chunking in [Chunking::PerRow, Chunking::Random(chunk_seed)] {
            let other = run::<256, 1024, 4, 4, 16, 64>(&scan, cfg, chunking);
            prop_assert!(other == base, "{:?} differs from whole frames", chunking);
        }
        let again = run::<256, 1024, 4, 4, 16, 64>(&scan, cfg, Chunking::Whole);
        prop_assert!(again == base, "second run differs");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// h at the profiles' own windows (16, 32, 48), on scans longer than the
    /// window: the decision stream equals the reference model; with a, b, d, g.
    #[test]
    fn profile_windows_follow_the_model(p in wide_params()) {
        let scan = render(&p);
        let voxels = voxel_sets(&scan);
        let r = run::<2048, 262_144, 128, 48, 32, 128>(&scan, config(&p), Chunking::Whole);
        prop_assert_eq!(r.config.window, p.window);
        check_capacities(&r, wide_limits())?;
        check_exact(&r, &scan, &voxels, p.mu)?;
        let expected = model(&voxels.0, p.mu, p.window as usize);
        prop_assert!(r.log == expected, "log {:?}\nmodel {:?}", r.log, expected);
    }

    /// The sketch path against the model: a key pool of 0 words keeps no
    /// frame's keys, so every overlap is the sketch estimate, above
    /// `mu + sketch_margin`; the decision stream equals the rule run on
    /// those estimates. With a, c, d and consistent counters.
    #[test]
    fn sketch_mode_follows_the_model(p in params(), chunk_seed in any::<u64>()) {
        let scan = render(&p);
        let (sets, _) = voxel_sets(&scan);
        let cfg = config(&p);
        let r = run::<4096, 0, 64, 8, 32, 64>(&scan, cfg, Chunking::Whole);
        check_capacities(&r, sketch_limits())?;
        let finals = check_decision_stream(&r, sets.len())?;
        check_consistency(&r, &finals)?;
        let non_empty = sets.iter().filter(|s| !s.is_empty()).count() as u32;
        prop_assert_eq!(r.status.sketched_frames, non_empty);
        let expected = sketch_model::<32>(&sets, p.mu, cfg.sketch_margin, p.window as usize);
        prop_assert!(r.log == expected, "log {:?}\nmodel {:?}", r.log, expected);
        let other = run::<4096, 0, 64, 8, 32, 64>(&scan, cfg, Chunking::Random(chunk_seed));
        prop_assert!(other == r, "random chunks differ from whole frames");
    }
}

/// The generator makes scans where selection matters: frames overlap (many
/// are dominated), windows above 1 sometimes pick a later frame, and the tiny
/// selector actually degrades. Guards the properties against vacuity.
#[test]
fn generated_scans_are_not_trivial() {
    let (mut frames, mut dominated, mut forward) = (0, 0, 0);
    let (mut degraded, mut out_of_range) = (0u32, 0u32);
    for seed in 0..12u64 {
        let p = Params {
            seed,
            width: 48,
            height: 36,
            frames: 30,
            stride: 1 + (seed % 3) as u16,
            mu: 0.2,
            window: 8,
            voxel: 0.3,
            step: 0.2,
            turn: 0.3,
            dropout: 0.1,
            edge: seed % 4 == 0,
        };
        let scan = render(&p);
        out_of_range += voxel_sets(&scan).1;
        let r = run::<4096, 131_072, 64, 8, 32, 64>(&scan, config(&p), Chunking::Whole);
        for (i, d) in r.finals(p.frames).into_iter().enumerate() {
            frames += 1;
            if let Decision::DominatedBy(k) = d {
                dominated += 1;
                if k as usize > i {
                    forward += 1;
                }
            }
        }
        let t = run::<256, 1024, 4, 4, 16, 64>(&scan, config(&p), Chunking::Whole);
        degraded |= t.status.flags;
    }
    assert!(dominated * 3 > frames, "{dominated} of {frames} dominated");
    assert!(forward > 0, "the window never picked a later frame");
    assert!(out_of_range > 0, "no point left the key range");
    assert_eq!(
        degraded,
        flags::FRAME_VOXELS_FULL | flags::POOL_FULL | flags::DATABASE_FULL | flags::OUT_OF_RANGE,
        "tiny selector did not hit every capacity and the key range"
    );
}

// Keep the type aliases honest: they are the capacities the tests use.
#[test]
fn aliases_match_limits() {
    let e = new_selector::<4096, 131_072, 64, 8, 32, 64>();
    let t = new_selector::<256, 1024, 4, 4, 16, 64>();
    let w = new_selector::<2048, 262_144, 128, 48, 32, 128>();
    let k = new_selector::<4096, 0, 64, 8, 32, 64>();
    let lim = |s: &Status| {
        [
            s.database.limit,
            s.pool.limit,
            s.window.limit,
            s.frame_voxels.limit,
        ]
    };
    assert_eq!(lim(&e.status()), exact_limits());
    assert_eq!(lim(&t.status()), tiny_limits());
    assert_eq!(lim(&w.status()), wide_limits());
    assert_eq!(lim(&k.status()), sketch_limits());
    let _: Option<Box<Exact>> = Some(e);
    let _: Option<Box<Tiny>> = Some(t);
}
