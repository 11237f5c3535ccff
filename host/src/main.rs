//! The `placedb` command line: select a place-recognition database from a
//! recorded RGB-D sequence (or the built-in synthetic office), compare solvers,
//! write synthetic sequences, print the device budgets.

use clap::{Args, Parser, Subcommand};
use placedb_host::pipeline::{self, Outcome, Prepared, Solver, SolverParams};
use placedb_host::read::{self, ReadOptions};
use placedb_host::synth::{self, SynthConfig};
use placedb_host::{dataset, device_cli, voxelize};
use placedb_host::{output, plot, CameraModel, Format, GridOrigin, Sequence, VoxelConfig};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

mod pico_bench;

#[derive(Parser)]
#[command(
    name = "placedb",
    version,
    about = "Select a compact visual-place-recognition database from an RGB-D scan: \
the frames whose voxelized views dominate every other frame (IoU of 0.3 m voxel sets above mu)."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Select a database from a sequence and write database.csv, labels.csv, metrics.json, topview.png.
    Select(SelectArgs),
    /// Run every solver and baseline on a sequence and print one table side by side.
    Compare(CompareArgs),
    /// Write the built-in synthetic office scan as a TUM RGB-D sequence.
    Synth(SynthArgs),
    /// Print each device capacity profile: exact state size and what it holds.
    Budget,
    /// Measure select's wall time, time split and peak memory on the synthetic
    /// 5000-frame scan and the recorded samples (each run in a child process).
    Bench(BenchArgs),
    /// Stream a sequence to a device (board or emulator) with live status.
    Stream(StreamArgs),
    /// Pull database.csv, labels.csv, metrics.json from a device (resumable, CRC-checked).
    Export(ExportArgs),
    /// Start the emulated board (QEMU mps2-an386) and print the port to use.
    Device(DeviceArgs),
}

/// `placedb stream`: the sequence options of select, a port and the selector's.
#[derive(Args)]
struct StreamArgs {
    #[command(flatten)]
    seq: SeqArgs,
    /// Device: a serial port (/dev/ttyACM0), tcp:HOST:PORT (the emulator) or local:PROFILE.
    #[arg(long)]
    port: String,
    /// IoU threshold: frames overlap when IoU > mu.
    #[arg(long, default_value_t = 0.3)]
    mu: f32,
    /// Frames held undecided (capped by the device's window).
    #[arg(long, default_value_t = 32)]
    window: u16,
    /// Capacity profile the device's firmware was built with (checked).
    #[arg(long, default_value = "ram512k")]
    profile: String,
    /// Also export the result into this directory (as `placedb export -o`).
    #[arg(short, long)]
    out: Option<PathBuf>,
    /// No progress bar.
    #[arg(long, short)]
    quiet: bool,
    /// Fault injection: chance that a frame is dropped, each direction (0..1).
    #[arg(long, default_value_t = 0.0)]
    drop_chance: f64,
    /// Fault injection: chance that a frame has one bit flipped, each direction (0..1).
    #[arg(long, default_value_t = 0.0)]
    corrupt_chance: f64,
    /// Seed of the fault injector's PRNG (a run is reproducible).
    #[arg(long, default_value_t = 1)]
    fault_seed: u64,
    /// Retransmissions per message (stop-and-wait). Default: 0 (pipelined, the
    /// first error stops the stream) without fault injection, 20 with.
    #[arg(long)]
    retries: Option<usize>,
    /// With retransmission: wait this many milliseconds for a reply before sending again.
    #[arg(long, default_value_t = 2000)]
    resend_ms: u64,
    /// Go on with the scan the device holds (e.g. restored from flash after a
    /// power cut) from its first undecided frame, instead of starting over.
    #[arg(long)]
    resume: bool,
    /// Leave the scan open (no Finish): more frames can follow with --resume.
    #[arg(long)]
    no_finish: bool,
}

/// One line about a written dataset.
fn print_dataset(dir: &std::path::Path, d: &dataset::DatasetSummary) {
    println!(
        "  dataset: {} frames ({} in database/), {}, in {}",
        d.frames,
        d.database,
        if d.color {
            "with colour"
        } else {
            "no colour (the sequence has none for every frame)"
        },
        dir.display()
    );
}

/// `placedb export`.
#[derive(Args)]
struct ExportArgs {
    /// Device: a serial port (/dev/ttyACM0), tcp:HOST:PORT (the emulator) or local:PROFILE.
    #[arg(long)]
    port: String,
    /// Output directory for database.csv, labels.csv, metrics.json.
    #[arg(short, long)]
    out: PathBuf,
    /// Resume an interrupted export into the same directory from record K.
    #[arg(long)]
    from: Option<u32>,
    /// Also write a training-ready dataset (as `select --dataset`) from the
    /// exported labels and the frames of --sequence (the sequence streamed).
    #[arg(long, requires = "sequence")]
    dataset: Option<PathBuf>,
    /// With --dataset: the sequence that was streamed (directory or ROS 2 bag).
    #[arg(long, requires = "dataset")]
    sequence: Option<PathBuf>,
    /// With --dataset: the sequence's layout (detected when omitted).
    #[arg(long, value_enum)]
    format: Option<Format>,
    #[command(flatten)]
    ros2: Ros2Args,
    /// No progress bar.
    #[arg(long, short)]
    quiet: bool,
}

/// `placedb device`.
#[derive(Args)]
struct DeviceArgs {
    /// Run the QEMU board (mps2-an386, Cortex-M4F, UART) under qemu-system-arm.
    #[arg(long, required_unless_present = "rp2040", conflicts_with = "rp2040")]
    qemu: bool,
    /// Run the Raspberry Pi Pico firmware (boards/rp-pico) under the RP2040
    /// emulator (rp2040js, Node): boot ROM, boot2, QSPI flash, and its USB
    /// CDC-ACM port bridged to TCP (`cd boards/rp-pico/emulator && npm ci`).
    #[arg(long)]
    rp2040: bool,
    /// Firmware ELF (default: the one built in boards/qemu-mps2-an386, or
    /// boards/rp-pico with --rp2040).
    #[arg(long)]
    firmware: Option<PathBuf>,
    /// Loopback TCP port for the board's UART or USB port (0: any free port).
    #[arg(long, default_value_t = 0)]
    port: u16,
    /// Run without -icount shift=0 (faster, but no exact instruction counts; QEMU only).
    #[arg(long)]
    no_icount: bool,
    /// File holding the board's flash (its database log); created erased if
    /// missing and kept across runs, so a restarted board restores its scan.
    #[arg(long)]
    flash: Option<PathBuf>,
}

/// Where the frames come from and how they become voxel sets.
#[derive(Args, Clone)]
struct SeqArgs {
    /// Sequence directory (TUM RGB-D, 7-Scenes, the reference code's layout) or ROS 2 bag (folder or .mcap).
    #[arg(required_unless_present = "demo")]
    seq: Option<PathBuf>,
    /// Use the built-in synthetic office scan (600 frames, 320x240) instead of a directory.
    #[arg(long, conflicts_with = "seq")]
    demo: bool,
    /// With --demo: walk the same office in this many frames.
    #[arg(long, default_value_t = 600, requires = "demo")]
    demo_frames: usize,
    /// Sequence layout; detected from the directory's files when omitted.
    #[arg(long, value_enum)]
    format: Option<Format>,
    /// Depth units per metre (TUM 5000, 7-Scenes and the reference layout 1000).
    #[arg(long)]
    depth_scale: Option<f64>,
    /// Pinhole intrinsics "fx,fy,cx,cy" in pixels, replacing the sequence's.
    #[arg(long, value_parser = parse_intrinsics)]
    intrinsics: Option<CameraModel>,
    /// Voxel edge in metres.
    #[arg(long, default_value_t = 0.3)]
    voxel: f32,
    /// Use every s-th pixel in u and v (1 = exact voxel sets).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=64))]
    stride: u16,
    /// Valid depths "min,max" in metres: min < z <= max ("0.1,inf" keeps far points).
    #[arg(long, default_value = "0.1,10", value_parser = parse_range)]
    depth_range: (f32, f32),
    /// Anchor of the voxel grid: the world origin (as the device) or the scene's minimum corner (as the reference code).
    #[arg(long, value_enum, default_value_t = GridOrigin::World)]
    grid_origin: GridOrigin,
    /// Use only the first N frames of the sequence.
    #[arg(long)]
    max_frames: Option<usize>,
    #[command(flatten)]
    ros2: Ros2Args,
}

/// Which topics of a ROS 2 bag to read (each defaults to the only candidate).
#[derive(Args, Clone, Default)]
struct Ros2Args {
    /// ROS 2 bag: the depth topic (sensor_msgs/msg/Image, 16UC1 or 32FC1).
    #[arg(long)]
    depth_topic: Option<String>,
    /// ROS 2 bag: the pose topic (PoseStamped, Odometry, or /tf with --pose-frame).
    #[arg(long)]
    pose_topic: Option<String>,
    /// ROS 2 bag: the CameraInfo topic.
    #[arg(long)]
    camera_info_topic: Option<String>,
    /// ROS 2 bag: the colour topic (rgb8, bgr8, rgba8, bgra8, mono8), for --dataset.
    #[arg(long)]
    color_topic: Option<String>,
    /// ROS 2 bag: take poses from /tf, as the transform to this child frame (the camera's optical frame).
    #[arg(long)]
    pose_frame: Option<String>,
    /// ROS 2 bag: largest time difference between a depth frame and its pose, seconds.
    #[arg(long, default_value_t = read::ros2::POSE_TOLERANCE)]
    pose_tolerance: f64,
}

impl Ros2Args {
    fn options(&self) -> read::ros2::Ros2Options {
        read::ros2::Ros2Options {
            depth_topic: self.depth_topic.clone(),
            pose_topic: self.pose_topic.clone(),
            camera_info_topic: self.camera_info_topic.clone(),
            color_topic: self.color_topic.clone(),
            pose_frame: self.pose_frame.clone(),
            pose_tolerance: Some(self.pose_tolerance),
        }
    }
}

/// Solver parameters shared by select and compare.
#[derive(Args, Clone)]
struct ParamArgs {
    /// every-nth: take every N-th frame.
    #[arg(long, default_value_t = 10)]
    every_nth: usize,
    /// distance: take a frame each D metres of camera path.
    #[arg(long, default_value_t = 0.5)]
    distance: f64,
    /// cube: take the frame nearest the centre of each C-metre cube of the trajectory's box.
    #[arg(long, default_value_t = 1.0)]
    cube: f64,
    /// exact: time limit in seconds; past it the best set and a proven lower bound are reported.
    #[arg(long, default_value_t = 60.0)]
    time_limit: f64,
    /// online: device capacity profile (ram256k, ram512k, ram1m; see `placedb budget`).
    #[arg(long, default_value = "ram512k")]
    profile: String,
    /// online: frames held undecided (1 reproduces in-order; capped by the profile's window).
    #[arg(long, default_value_t = 32)]
    window: u16,
    /// online: decode every frame again and push its rows, as a board
    /// receives them, instead of reusing the voxel sets (same decisions;
    /// `bench --core` counts the core's voxelizing this way).
    #[arg(long, hide = true)]
    push_rows: bool,
    /// Test sequence of the same place: adds oracle_recall@0.3.
    #[arg(long)]
    test: Option<PathBuf>,
    /// Print machine-readable JSON instead of text.
    #[arg(long)]
    json: bool,
    /// No progress bars.
    #[arg(long, short)]
    quiet: bool,
}

#[derive(Args)]
struct SelectArgs {
    #[command(flatten)]
    seq: SeqArgs,
    /// Output directory for database.csv, labels.csv, metrics.json, topview.png.
    #[arg(short, long)]
    out: PathBuf,
    /// Also write a training-ready dataset here: color/, depth/, poses.txt,
    /// intrinsics.txt and classes.csv of every frame, and database/ (the reference code's layout).
    #[arg(long)]
    dataset: Option<PathBuf>,
    /// Which solver or baseline.
    #[arg(long, value_enum, default_value_t = Solver::Online)]
    solver: Solver,
    /// IoU threshold: frames overlap when IoU > mu.
    #[arg(long, default_value_t = 0.3)]
    mu: f32,
    #[command(flatten)]
    params: ParamArgs,
}

#[derive(Args)]
struct CompareArgs {
    #[command(flatten)]
    seq: SeqArgs,
    /// IoU thresholds, comma separated.
    #[arg(long, default_value = "0.3", value_delimiter = ',')]
    mu: Vec<f32>,
    #[command(flatten)]
    params: ParamArgs,
}

#[derive(Args)]
struct SynthArgs {
    /// Output directory (TUM layout).
    out: PathBuf,
    /// Number of frames.
    #[arg(long, default_value_t = 600)]
    frames: usize,
    /// Image width.
    #[arg(long, default_value_t = 320)]
    width: u16,
    /// Image height.
    #[arg(long, default_value_t = 240)]
    height: u16,
    /// Seed of the furniture layout.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Number of rooms off the corridor.
    #[arg(long, default_value_t = 4)]
    rooms: usize,
}

fn parse_intrinsics(s: &str) -> Result<CameraModel, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>().map_err(|e| format!("{x:?}: {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [fx, fy, cx, cy] => Ok(CameraModel { fx, fy, cx, cy }),
        _ => Err("expected four numbers fx,fy,cx,cy".into()),
    }
}

fn parse_range(s: &str) -> Result<(f32, f32), String> {
    let (a, b) = s.split_once(',').ok_or("expected min,max in metres")?;
    let min: f32 = a.trim().parse().map_err(|e| format!("{a:?}: {e}"))?;
    let max: f32 = b.trim().parse().map_err(|e| format!("{b:?}: {e}"))?;
    if !(min >= 0.0 && max > min) {
        return Err(format!("need 0 <= min < max, got {min},{max}"));
    }
    Ok((min, max))
}

type Error = Box<dyn std::error::Error>;

/// Peak resident memory of this process so far, MB (Linux `VmHWM`).
fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

fn open_sequence(a: &SeqArgs) -> Result<Sequence, Error> {
    let mut seq = open_full_sequence(a)?;
    if let Some(n) = a.max_frames {
        seq.frames.truncate(n);
    }
    Ok(seq)
}

fn open_full_sequence(a: &SeqArgs) -> Result<Sequence, Error> {
    if a.demo {
        let cfg = SynthConfig {
            frames: a.demo_frames,
            ..SynthConfig::demo()
        };
        return Ok(synth::sequence(&cfg));
    }
    let path = a
        .seq
        .as_ref()
        .ok_or("a sequence directory or --demo is required")?;
    let opts = ReadOptions {
        format: a.format,
        depth_scale: a.depth_scale,
        intrinsics: a.intrinsics,
        ros2: a.ros2.options(),
    };
    Ok(read::open(path, &opts)?)
}

fn open_test(path: &std::path::Path, a: &SeqArgs) -> Result<Sequence, Error> {
    let opts = ReadOptions {
        format: None,
        depth_scale: a.depth_scale,
        intrinsics: a.intrinsics,
        ros2: a.ros2.options(),
    };
    Ok(read::open(path, &opts)?)
}

fn voxel_config(a: &SeqArgs) -> VoxelConfig {
    VoxelConfig {
        voxel: a.voxel,
        stride: a.stride,
        range: placedb::DepthRange {
            min: a.depth_range.0,
            max: a.depth_range.1,
        },
        origin: a.grid_origin,
    }
}

fn solver_params(p: &ParamArgs) -> Result<SolverParams, Error> {
    if !(p.time_limit.is_finite() && p.time_limit > 0.0) {
        return Err("--time-limit must be a positive number of seconds".into());
    }
    if placedb::profile::by_name(&p.profile).is_none() {
        return Err(format!("unknown --profile {:?}; see `placedb budget`", p.profile).into());
    }
    Ok(SolverParams {
        every_nth: p.every_nth,
        distance: p.distance,
        cube: p.cube,
        time_limit: Duration::from_secs_f64(p.time_limit),
        profile: p.profile.clone(),
        window: p.window.max(1),
        push_rows: p.push_rows,
        ..SolverParams::default()
    })
}

/// The flat metrics.json object of one outcome.
fn metrics_json(
    seq: &Sequence,
    prep: &Prepared,
    o: &Outcome,
    mu: f32,
    params: &SolverParams,
) -> serde_json::Value {
    let mut m = match serde_json::to_value(&o.metrics) {
        Ok(serde_json::Value::Object(m)) => m,
        _ => serde_json::Map::new(),
    };
    // DESIGN names the recall metric `oracle_recall@0.3`.
    if let Some(r) = m.remove("oracle_recall_0_3") {
        if !r.is_null() {
            m.insert("oracle_recall@0.3".into(), r);
        }
    }
    let c = &prep.config;
    let mut put = |k: &str, v: serde_json::Value| {
        m.insert(k.to_string(), v);
    };
    put("solver", o.solver.name().into());
    // As typed (0.1), not as the f32 widened (0.10000000149011612).
    let decimal = |x: f32| x.to_string().parse::<f64>().unwrap_or(f64::from(x));
    put("mu", decimal(mu).into());
    put("voxel", decimal(c.voxel).into());
    put("stride", c.stride.into());
    put("depth_min", f64::from(c.range.min).into());
    put(
        "depth_max",
        if c.range.max.is_finite() {
            f64::from(c.range.max).into()
        } else {
            "inf".into()
        },
    );
    put(
        "grid_origin",
        serde_json::to_value(c.origin).unwrap_or_default(),
    );
    put("sequence", seq.name.clone().into());
    put(
        "format",
        serde_json::to_value(seq.format).unwrap_or_default(),
    );
    put("frames", seq.frames.len().into());
    put("voxelize_s", prep.voxelize_wall.as_secs_f64().into());
    put("read_cpu_s", prep.sets.read_time.as_secs_f64().into());
    put(
        "voxelize_cpu_s",
        prep.sets.voxelize_time.as_secs_f64().into(),
    );
    put("graph_s", prep.graph_wall.as_secs_f64().into());
    put("solve_s", o.solve_time.as_secs_f64().into());
    put("co_observing_pairs", prep.co.pair_count().into());
    put("labels_below_mu", o.labels_below_mu.into());
    put("label_iou_min", f64::from(o.label_iou_min).into());
    if let Some((optimal, lb)) = o.exact {
        put("optimal", optimal.into());
        put("lower_bound", lb.into());
    }
    if let Some(run) = &o.online {
        put("profile", params.profile.clone().into());
        put("window", params.window.into());
        let st = &run.status;
        put("sketched_frames", st.sketched_frames.into());
        put("truncated_frames", st.truncated_frames.into());
        put("uncovered_by_capacity", st.uncovered_frames.into());
        put("degradation_flags", st.flags.into());
        put("pool_peak_words", st.pool.peak.into());
        put("frame_voxels_peak", st.frame_voxels.peak.into());
        put("core_s", run.core_time.as_secs_f64().into());
        put("valid_pixels", st.valid_pixels.into());
    }
    serde_json::Value::Object(m)
}

fn select(a: SelectArgs) -> Result<(), Error> {
    let t0 = Instant::now();
    let seq = open_sequence(&a.seq)?;
    let params = solver_params(&a.params)?;
    let prep = pipeline::prepare(&seq, voxel_config(&a.seq), a.params.quiet)?;
    // The top view's map and trajectory do not depend on the solver: they
    // are projected on the other thread while it solves.
    let (solved, mut view) = rayon::join(
        || pipeline::solve(&seq, &prep, a.solver, a.mu, &params, a.params.quiet),
        || plot::project(&seq, &prep.sets.sets, prep.sets.grid),
    );
    let mut o = solved?;
    if let Some(test) = &a.params.test {
        let tseq = open_test(test, &a.seq)?;
        let tsets = pipeline::prepare_test(&tseq, &prep, a.params.quiet)?;
        pipeline::add_oracle_recall(&mut o, &prep, &tsets);
    }
    let rows = match &o.online {
        // The device's own records: what an export from a board would hold.
        Some(run) => output::rows_from_records(&run.database),
        None => output::rows_from_sequence(&seq, &o.database),
    };
    let timestamps: Vec<f64> = seq.frames.iter().map(|f| f.timestamp).collect();
    let mut json = metrics_json(&seq, &prep, &o, a.mu, &params);
    json["total_s"] = t0.elapsed().as_secs_f64().into();
    if let Some(mb) = peak_rss_mb() {
        json["peak_rss_mb"] = mb.into();
    }
    view.database.clone_from(&o.database);
    // The picture is drawn and encoded while the tables are written, into
    // the directory both need, made first.
    std::fs::create_dir_all(&a.out)?;
    let (written, drawn) = rayon::join(
        || output::write_database_dir(&a.out, &rows, &timestamps, &o.labels, &json),
        || view.render().write_png(&a.out.join("topview.png")),
    );
    written?;
    drawn?;
    let dataset = match &a.dataset {
        Some(dir) => Some((dir, dataset::write(dir, &seq, &o.labels)?)),
        None => None,
    };
    if a.params.json {
        println!("{}", serde_json::to_string_pretty(&json)?);
    } else {
        let m = &o.metrics;
        println!(
            "{}: {} frames -> {} database frames ({:.1}x reduction) with solver {} at mu {}",
            seq.name,
            seq.frames.len(),
            m.size,
            m.reduction,
            o.solver.name(),
            a.mu
        );
        println!(
            "  uncovered {}  spatial coverage {:.3}  frame coverage mean {:.3} min {:.3} (<0.3: {:.1}%)",
            m.uncovered,
            m.spatial_coverage,
            m.frames_coverage_mean,
            m.frames_coverage_min,
            100.0 * m.frames_coverage_below_0_3
        );
        if let Some(r) = m.oracle_recall_0_3 {
            println!("  oracle_recall@0.3 on the test sequence: {r:.3}");
        }
        if let Some((optimal, lb)) = o.exact {
            println!(
                "  exact: {} (lower bound {lb})",
                if optimal {
                    "proven minimum"
                } else {
                    "time limit hit, not proven"
                }
            );
        }
        if let Some(run) = &o.online {
            let st = &run.status;
            println!(
                "  online core: profile {}, window {}, {} frames by sketch, {} truncated, {} uncovered by capacity",
                params.profile, params.window, st.sketched_frames, st.truncated_frames, st.uncovered_frames
            );
        }
        println!("  database frames: {:?}", o.database);
        println!(
            "  time: voxelize {:.3} s, overlaps {:.3} s, solve {:.3} s, total {:.3} s",
            prep.voxelize_wall.as_secs_f64(),
            prep.graph_wall.as_secs_f64(),
            o.solve_time.as_secs_f64(),
            t0.elapsed().as_secs_f64()
        );
        println!(
            "  wrote {}/{{database.csv,labels.csv,metrics.json,topview.png}}",
            a.out.display()
        );
        if let Some((dir, d)) = &dataset {
            print_dataset(dir, d);
        }
    }
    Ok(())
}

fn compare(a: CompareArgs) -> Result<(), Error> {
    let seq = open_sequence(&a.seq)?;
    let params = solver_params(&a.params)?;
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
    for &mu in &a.mu {
        for solver in Solver::ALL {
            let mut o = pipeline::solve(&seq, &prep, solver, mu, &params, true)?;
            if let Some(t) = &test {
                pipeline::add_oracle_recall(&mut o, &prep, t);
            }
            all.push((mu, o));
        }
    }
    if a.params.json {
        let v: Vec<_> = all
            .iter()
            .map(|(mu, o)| metrics_json(&seq, &prep, o, *mu, &params))
            .collect();
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!(
        "{}: {} frames, voxel {} m, stride {}, voxelize {:.3} s, overlaps {:.3} s",
        seq.name,
        seq.frames.len(),
        prep.config.voxel,
        prep.config.stride,
        prep.voxelize_wall.as_secs_f64(),
        prep.graph_wall.as_secs_f64()
    );
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
    if all.iter().any(|(_, o)| matches!(o.exact, Some((false, _)))) {
        println!("* exact hit its time limit: best set found, not proven minimum");
    }
    Ok(())
}

/// `placedb export`, and the dataset of the exported labels when asked.
fn export(a: ExportArgs) -> Result<(), Error> {
    // The sequence first: a wrong path fails before the device is touched.
    let seq = match &a.sequence {
        Some(path) => {
            let opts = ReadOptions {
                format: a.format,
                ros2: a.ros2.options(),
                ..ReadOptions::default()
            };
            Some(read::open(path, &opts)?)
        }
        None => None,
    };
    let export = device_cli::export_cmd(&a.port, &a.out, a.from, a.quiet)?;
    if let (Some(dir), Some(seq)) = (&a.dataset, &seq) {
        let (timestamps, labels) = export.labels();
        // The device's timestamps are the sequence's: a different sequence shows.
        if let Some(i) = timestamps
            .iter()
            .zip(&seq.frames)
            .position(|(t, f)| *t != f.timestamp)
        {
            return Err(format!(
                "--sequence {}: frame {i} has timestamp {}, the device's has {}: not the streamed sequence?",
                seq.name, seq.frames[i].timestamp, timestamps[i]
            )
            .into());
        }
        let d = dataset::write(dir, seq, &labels)?;
        print_dataset(dir, &d);
    }
    Ok(())
}

fn synth_cmd(a: SynthArgs) -> Result<(), Error> {
    let cfg = SynthConfig {
        frames: a.frames,
        width: a.width,
        height: a.height,
        seed: a.seed,
        rooms: a.rooms,
    };
    let seq = synth::sequence(&cfg);
    let pb = indicatif::ProgressBar::new(seq.frames.len() as u64);
    synth::write_tum(&seq, &a.out, Some(&pb))?;
    pb.finish_and_clear();
    println!(
        "wrote {} frames of {}x{} to {} (TUM layout)",
        seq.frames.len(),
        a.width,
        a.height,
        a.out.display()
    );
    Ok(())
}

fn budget() -> Result<(), Error> {
    println!(
        "{:<8} {:>6} {:>10} {:>10} {:>9} {:>12} {:>9} {:>5} {:>6} {:>8} {:>6}",
        "profile",
        "ram",
        "selector",
        "device",
        "headroom",
        "frame_voxels",
        "pool_keys",
        "db",
        "window",
        "resident",
        "sketch"
    );
    for p in placedb::profile::PROFILES {
        println!(
            "{:<8} {:>5}K {:>9}B {:>9}B {:>8}K {:>12} {:>9} {:>5} {:>6} {:>8} {:>6}",
            p.name,
            p.ram / 1024,
            p.state_bytes,
            p.device_bytes,
            (p.ram as i64 - p.device_bytes as i64) / 1024,
            p.frame_voxel_slots - p.frame_voxel_slots / 4,
            p.pool_words,
            p.database_frames,
            p.window,
            p.resident,
            p.sketch
        );
    }
    println!("selector = the online core alone; device = selector + receive and reply buffers (what a board holds)");
    println!("db = database frames indexed in RAM (24 B each; the frames and every label live in the flash log); resident = database frames held whole in RAM");
    println!("headroom = ram - device, for the stack and the board's own buffers");
    Ok(())
}

#[derive(Args)]
struct BenchArgs {
    /// Directory holding the recorded samples (7scenes-1000, vprdb-test-db).
    #[arg(long, default_value = "../shared/data")]
    data: PathBuf,
    /// Solvers to time, comma separated.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "in-order,greedy,exact,online"
    )]
    solvers: Vec<Solver>,
    /// Pixel stride.
    #[arg(long, default_value_t = 1)]
    stride: u16,
    /// Frames of the synthetic scan.
    #[arg(long, default_value_t = 5000)]
    synthetic_frames: usize,
    /// Instead: count the core's instructions per frame and per valid pixel
    /// with valgrind's callgrind (repeatable counts, not seconds).
    #[arg(long)]
    core: bool,
    /// With --core: frames of 7scenes-1000 to replay.
    #[arg(long, default_value_t = 20)]
    core_frames: usize,
    /// Instead: count the instructions per valid pixel of the QEMU board's
    /// Cortex-M4F firmware (-icount shift=0), protocol included, and the
    /// core's share: the same frames at strides 2 and 4.
    #[arg(long)]
    device: bool,
    /// With --device: frames of 7scenes-1000 (twice as many synthetic ones).
    #[arg(long, default_value_t = 3)]
    device_frames: usize,
    /// Instead: the Pico's Cortex-M0+ under the RP2040 emulator: cycles per
    /// valid pixel and per frame (the --device frames at strides 2 and 4),
    /// and the frames/s it sustains beside what USB full speed carries.
    #[arg(long)]
    pico: bool,
    /// With --pico: print one JSON object instead of the tables.
    #[arg(long, requires = "pico")]
    json: bool,
    /// Instead: count with callgrind the instructions of one frame decided
    /// against a database of 10 frames and of ~900 (a synthetic building at
    /// mu 0.5 on the ram256k device, its database restored from flash).
    #[arg(long)]
    db_scaling: bool,
    /// With --db-scaling: frames of the building (40 rooms).
    #[arg(long, default_value_t = 20_000)]
    building_frames: usize,
    /// Internal (the callgrind child of --db-scaling): the flash image.
    #[arg(long, hide = true)]
    db_probe: Option<PathBuf>,
    /// Rounds of the timing table, each running every row of a sequence in
    /// turn; a row is its run of median wall time, a ratio to the floor the
    /// median of the rounds' (a single run of a half-second job moves by
    /// 10 % and more, and the machine's speed drifts).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..))]
    repeat: u32,
    /// Internal (a child of the timing table): only decode every depth
    /// image of this sequence, as select would, and exit.
    #[arg(long, hide = true)]
    decode_only: Option<PathBuf>,
}

/// The paper's reference code on this machine, 7scenes-1000 at stride 1
/// (figures from the issue that set the target): seconds and peak MB.
const PAPER_7SCENES: (f64, f64) = (51.0, 400.0);

fn bench(a: BenchArgs) -> Result<(), Error> {
    if a.core {
        return core_cost(&a);
    }
    if a.device {
        return device_cost(&a);
    }
    if a.pico {
        return pico_bench::run(&a.data, a.device_frames, a.json);
    }
    if let Some(flash) = &a.db_probe {
        return Ok(placedb_host::dbscale::run_probe(flash, a.building_frames)?);
    }
    if a.db_scaling {
        return db_scaling(&a);
    }
    if let Some(path) = &a.decode_only {
        let seq = read::open(path, &ReadOptions::default())?;
        voxelize::decode_all(&seq)?;
        let json = serde_json::json!({
            "frames": seq.frames.len(),
            "peak_rss_mb": peak_rss_mb(),
        });
        println!("{json}");
        return Ok(());
    }
    let exe = std::env::current_exe()?;
    let out = std::env::temp_dir().join(format!("placedb-bench-{}", std::process::id()));
    let mut inputs: Vec<(String, Vec<String>)> = vec![(
        format!("synthetic-{}", a.synthetic_frames),
        vec![
            "--demo".into(),
            "--demo-frames".into(),
            a.synthetic_frames.to_string(),
        ],
    )];
    for name in ["7scenes-1000", "vprdb-test-db"] {
        let p = a.data.join(name);
        if p.is_dir() {
            inputs.push((name.into(), vec![p.display().to_string()]));
        } else {
            eprintln!("placedb bench: {} not found, skipped", p.display());
        }
    }
    println!(
        "{:<16} {:<11} {:>6} {:>7} {:>7} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}",
        "sequence",
        "solver",
        "frames",
        "wall_s",
        "cpu_s",
        "total_s",
        "read*",
        "voxel*",
        "vox_wall",
        "graph_s",
        "solve_s",
        "peak_MB"
    );
    // Runs `placedb ARGS` in a child: its wall time from spawn to exit, its
    // CPU time (user and system, all threads), and the JSON it printed.
    let run = |args: &[String]| -> Result<(f64, f64, serde_json::Value), Error> {
        let (t, cpu) = (Instant::now(), children_cpu_s());
        let child = std::process::Command::new(&exe).args(args).output()?;
        let (wall, cpu) = (t.elapsed().as_secs_f64(), children_cpu_s() - cpu);
        if !child.status.success() {
            let err = String::from_utf8_lossy(&child.stderr);
            return Err(format!("placedb {}: {err}", args.join(" ")).into());
        }
        Ok((wall, cpu, serde_json::from_slice(&child.stdout)?))
    };
    // The item of median `key` (the upper one of an even count).
    fn median_by<T>(items: &[T], key: impl Fn(&T) -> f64) -> Option<&T> {
        let mut sorted: Vec<&T> = items.iter().collect();
        sorted.sort_by(|x, y| key(x).total_cmp(&key(y)));
        sorted.get(sorted.len() / 2).copied()
    }
    for (name, args) in &inputs {
        // Row 0 is the floor (decoding every depth image and nothing else),
        // where the input is a recorded sequence; then one row a solver.
        let mut rows: Vec<(&str, Vec<String>)> = Vec::new();
        if let Some(path) = args.first().filter(|p| !p.starts_with("--")) {
            rows.push((
                "decode-only",
                vec!["bench".into(), "--decode-only".into(), path.clone()],
            ));
        }
        let has_floor = !rows.is_empty();
        for solver in &a.solvers {
            let mut select: Vec<String> = vec!["select".into()];
            select.extend(args.iter().cloned());
            select.extend(
                ["--solver", solver.name(), "--stride", &a.stride.to_string()].map(String::from),
            );
            select.extend(["--json", "-q", "-o"].map(String::from));
            select.push(out.display().to_string());
            rows.push((solver.name(), select));
        }
        // Rounds of every row in turn; each round starts one row later, so
        // that no row always runs first. With a floor, every run of a
        // solver's row is paired with a run of the floor right beside it
        // (before it in even rounds, after it in odd ones): a machine's
        // speed can drift (10-15 % on ours within a bench), which a ratio
        // to a run a few rows away would count as the solver's cost.
        let mut runs: Vec<Vec<(f64, f64, serde_json::Value)>> = vec![Vec::new(); rows.len()];
        // Per row, the floor's runs beside its runs.
        let mut beside: Vec<Vec<(f64, f64)>> = vec![Vec::new(); rows.len()];
        let first = usize::from(has_floor);
        let solver_rows = rows.len() - first;
        // One untimed run first, so that every timed one finds the
        // sequence's files in the page cache: a cold first run (0.63 s on
        // 7scenes-1000 against 0.25 s) became the floor's median at
        // `--repeat 2`.
        if let Some((_, warm_up)) = rows.first() {
            run(warm_up)?;
        }
        for round in 0..a.repeat as usize {
            for i in 0..solver_rows {
                let r = first + (i + round) % solver_rows;
                if !has_floor {
                    runs[r].push(run(&rows[r].1)?);
                    continue;
                }
                let (floor, solver) = if round % 2 == 0 {
                    let floor = run(&rows[0].1)?;
                    (floor, run(&rows[r].1)?)
                } else {
                    let solver = run(&rows[r].1)?;
                    (run(&rows[0].1)?, solver)
                };
                beside[r].push((floor.0, floor.1));
                runs[0].push(floor);
                runs[r].push(solver);
            }
        }
        for (r, ((row, _), row_runs)) in rows.iter().zip(&runs).enumerate() {
            // The run of median wall time, and its figures (`--repeat` is
            // at least 1).
            let Some((wall, cpu, m)) = median_by(row_runs, |run| run.0) else {
                continue;
            };
            let f = |k: &str| m[k].as_f64().unwrap_or(f64::NAN);
            println!(
                "{:<16} {:<11} {:>6} {:>7.3} {:>7.3} {:>8.3} {:>8.3} {:>8.3} {:>8.3} {:>8.3} {:>8.3} {:>8.1}",
                name,
                row,
                f("frames"),
                wall,
                cpu,
                f("total_s"),
                f("read_cpu_s"),
                f("voxelize_cpu_s"),
                f("voxelize_s"),
                f("graph_s"),
                f("solve_s"),
                f("peak_rss_mb")
            );
            if has_floor && r > 0 {
                // Per run, against the floor's run beside it.
                let ratio = |time: fn((f64, f64)) -> f64| {
                    let ratios: Vec<f64> = row_runs
                        .iter()
                        .zip(&beside[r])
                        .map(|(s, &d)| time((s.0, s.1)) / time(d))
                        .collect();
                    median_by(&ratios, |r| *r).copied().unwrap_or(f64::NAN)
                };
                println!(
                    "{:<16} {:<11} {:.2}x the decode-only wall time, {:.2}x its CPU time, medians of the runs beside a floor run (target <= 1.3x)",
                    "",
                    "",
                    ratio(|(wall, _)| wall),
                    ratio(|(_, cpu)| cpu)
                );
            }
            if *name == "7scenes-1000" && a.stride == 1 && *row == Solver::InOrder.name() {
                let (s, mb) = PAPER_7SCENES;
                println!(
                    "{:<16} {:<11} paper's code: {s} s, {mb} MB -> {:.0}x faster, {:.1}x less memory (target 100x, 10x)",
                    "",
                    "",
                    s / wall,
                    mb / f("peak_rss_mb")
                );
            }
        }
    }
    let _ = std::fs::remove_dir_all(&out);
    println!(
        "wall_s: the child process from spawn to exit (reading, voxelizing, solving, writing),\n\
         the median of {} rounds that run every row in turn, after an untimed run that warms\n\
         the page cache (the other columns are that run's; a recorded sequence's decode-only\n\
         runs beside every run of a solver, its row the median);\n\
         cpu_s: that child's CPU time, user and system, all threads (steadier than wall time\n\
         when the machine's speed drifts); total_s: select's own clock, up to its outputs;\n\
         * read and voxel are CPU time summed over threads; the others are wall time",
        a.repeat
    );
    Ok(())
}

/// CPU time, user and system, of this process's children that have been
/// waited for; NaN where the platform does not say.
fn children_cpu_s() -> f64 {
    #[cfg(unix)]
    {
        // SAFETY: `getrusage` fills the struct it is given and reads nothing.
        let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
        // SAFETY: `usage` is a valid, writable `rusage`.
        if unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage) } == 0 {
            let s = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
            return s(usage.ru_utime) + s(usage.ru_stime);
        }
    }
    f64::NAN
}

/// The core's parts, each a function kept out of line in the core so that
/// callgrind can count it alone (`--toggle-collect`).
const CORE_PARTS: [(&str, &str); 4] = [
    ("voxelize", "*FrameIngest*push_rows*"),
    ("end frame", "*Selector*end_frame*"),
    ("- select", "*Selector*decide_oldest*"),
    ("finish", "*Selector*finish*"),
];

/// Runs this program with `args` under callgrind, counting only inside
/// functions matching `pattern`; returns the instructions and its stdout.
fn callgrind_count(
    dir: &std::path::Path,
    pattern: &str,
    args: &[std::ffi::OsString],
) -> Result<(f64, Vec<u8>), Error> {
    let child = std::process::Command::new("valgrind")
        .args(["--tool=callgrind", "--collect-atstart=no"])
        .arg(format!("--toggle-collect={pattern}"))
        .arg(format!(
            "--callgrind-out-file={}",
            dir.join("callgrind.out").display()
        ))
        .arg(std::env::current_exe()?)
        .args(args)
        .output()
        .map_err(|e| format!("cannot run valgrind ({e}); install it to count instructions"))?;
    if !child.status.success() {
        return Err(format!(
            "callgrind run failed: {}",
            String::from_utf8_lossy(&child.stderr)
        )
        .into());
    }
    // valgrind's summary line: "==PID== Collected : N" (callgrind) or "I   refs: N".
    let stderr = String::from_utf8_lossy(&child.stderr);
    let n = stderr
        .lines()
        .find_map(|l| {
            l.split_once("Collected :")
                .or_else(|| l.split_once("I   refs:"))
        })
        .and_then(|(_, n)| n.trim().replace(',', "").parse::<f64>().ok())
        .ok_or("no instruction count in callgrind's output")?;
    Ok((n, child.stdout))
}

/// Counts the core's instructions with callgrind on a replay of the first
/// frames of 7scenes-1000 and prints them per frame and per valid pixel.
fn core_cost(a: &BenchArgs) -> Result<(), Error> {
    let dir = std::env::temp_dir().join(format!("placedb-cost-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let seq = a.data.join("7scenes-1000");
    let mut counts = Vec::new();
    let mut meta = serde_json::Value::Null;
    for (_, pattern) in CORE_PARTS {
        let args: Vec<std::ffi::OsString> = [
            "select",
            "--solver",
            "online",
            "--push-rows",
            "--json",
            "-q",
            "--stride",
        ]
        .iter()
        .map(Into::into)
        .chain([
            a.stride.to_string().into(),
            "--max-frames".into(),
            a.core_frames.to_string().into(),
            seq.clone().into_os_string(),
            "-o".into(),
            dir.join("out").into_os_string(),
        ])
        .collect();
        let (n, stdout) = callgrind_count(&dir, pattern, &args)?;
        meta = serde_json::from_slice(&stdout)?;
        counts.push(n);
    }
    let frames = meta["frames"].as_f64().unwrap_or(f64::NAN);
    let pixels = meta["valid_pixels"].as_f64().unwrap_or(f64::NAN);
    println!(
        "core instructions (callgrind, x86-64), {} frames of 7scenes-1000 at stride {}, {:.0} valid pixels per frame:",
        frames,
        a.stride,
        pixels / frames
    );
    println!("{:<10} {:>14} {:>12}", "part", "instr/frame", "instr/pixel");
    let mut total = 0.0;
    for ((part, _), n) in CORE_PARTS.iter().zip(&counts) {
        // Parts marked "-" are inside "end frame".
        if !part.starts_with('-') {
            total += n;
        }
        println!("{:<10} {:>14.0} {:>12.2}", part, n / frames, n / pixels);
    }
    println!(
        "{:<10} {:>14.0} {:>12.2}",
        "all",
        total / frames,
        total / pixels
    );
    println!(
        "end frame = sort the frame's voxels, sketch, overlaps with database and window, select"
    );
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}

/// `bench --device`: instructions per valid pixel of the QEMU board's
/// firmware (see `placedb_host::pixelcost`) on the first frames of
/// 7scenes-1000 and of the synthetic scan.
fn device_cost(a: &BenchArgs) -> Result<(), Error> {
    use placedb_host::link::{self, Client, Qemu, QemuOptions};
    use placedb_host::pixelcost::{self, SELECTOR, STRIDES};
    let firmware = link::built_firmware()?;
    let qemu = Qemu::start_with(
        &firmware,
        QemuOptions {
            extra_args: vec!["-icount".into(), "shift=0".into()],
            deadline: Duration::from_secs(3600),
            ..QemuOptions::default()
        },
    )
    .map_err(|e| format!("cannot start qemu-system-arm (apt-get install qemu-system-arm): {e}"))?;
    if !qemu.wait_console("calibration", Duration::from_secs(10)) {
        return Err(format!("the firmware did not boot: {}", qemu.console()).into());
    }
    let mut client = Client::new(qemu);
    let mut real = read::open(&a.data.join("7scenes-1000"), &ReadOptions::default())?;
    real.frames.truncate(a.device_frames);
    let mut synthetic = synth::sequence(&SynthConfig::demo());
    synthetic.frames.truncate(2 * a.device_frames);
    let [fine, coarse] = STRIDES;
    println!(
        "QEMU mps2-an386 (Cortex-M4F), profile ram512k, -icount shift=0: instructions per valid \
         pixel, marginal between strides {fine} and {coarse}"
    );
    println!(
        "{:<14} {:>6} {:>10} {:>10} {:>9} {:>9} {:>9} {:>12}",
        "sequence",
        "frames",
        "px@fine",
        "px@coarse",
        "total/px",
        "core/px",
        "proto/px",
        "per frame"
    );
    for seq in [&real, &synthetic] {
        let vcfg = VoxelConfig::default();
        let cost = pixelcost::measure(&mut client, seq, &vcfg, SELECTOR, "ram512k", STRIDES)?;
        println!(
            "{:<14} {:>6} {:>10.0} {:>10.0} {:>9.1} {:>9.1} {:>9.1} {:>12.0}",
            seq.name,
            cost.fine.frames,
            cost.fine.pixels,
            cost.coarse.pixels,
            cost.per_pixel(),
            cost.core_per_pixel(),
            cost.protocol_per_pixel(),
            cost.per_frame()
        );
    }
    println!(
        "core = projection, voxel set, selection step; proto = COBS, CRC, decoding, copying \
         the samples, dispatch; per frame = the rest of a frame's instructions"
    );
    Ok(())
}

/// `bench --db-scaling`: the same frame against a small and a large
/// database, instructions counted by callgrind (see `placedb_host::dbscale`).
fn db_scaling(a: &BenchArgs) -> Result<(), Error> {
    let dir = std::env::temp_dir().join(format!("placedb-dbscale-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let (small, big) = placedb_host::dbscale::prepare(&dir, a.building_frames)?;
    let mut counts = Vec::new();
    for image in ["small.flash", "big.flash"] {
        let args = [
            "bench".into(),
            "--db-probe".into(),
            dir.join(image).into_os_string(),
            "--building-frames".into(),
            a.building_frames.to_string().into(),
        ];
        let (n, stdout) = callgrind_count(&dir, "*probe_step*", &args)?;
        counts.push((n, String::from_utf8_lossy(&stdout).trim().to_string()));
    }
    println!(
        "one frame (160x120, stride 1) of a {}-frame building, through the ram256k device \
         (protocol, voxelize, overlaps read back from flash, selection, log writes); \
         callgrind, x86-64:",
        a.building_frames
    );
    for ((n, what), db) in counts.iter().zip([small, big]) {
        println!("  against {db:>4} database frames: {n:>12.0} instructions  ({what})");
    }
    println!("  ratio: {:.2}", counts[1].0 / counts[0].0);
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}

/// A closed stdout (`placedb budget | head`) ends placedb quietly, as it
/// ends any Unix filter, instead of a panic in `println!`: Rust starts every
/// program with SIGPIPE ignored, so the default is put back. Nothing else
/// placedb writes can raise it: std writes sockets with `MSG_NOSIGNAL`, and
/// the emulators' pipes are only read.
#[cfg(unix)]
fn quiet_on_closed_stdout() {
    // SAFETY: sets the disposition of one signal to its default, before any
    // other thread exists.
    unsafe { libc::signal(libc::SIGPIPE, libc::SIG_DFL) };
}

#[cfg(not(unix))]
fn quiet_on_closed_stdout() {}

fn main() -> ExitCode {
    quiet_on_closed_stdout();
    let cli = Cli::parse();
    let r = match cli.command {
        Command::Select(a) => select(a),
        Command::Compare(a) => compare(a),
        Command::Synth(a) => synth_cmd(a),
        Command::Budget => budget(),
        Command::Bench(a) => bench(a),
        Command::Stream(a) => open_sequence(&a.seq).and_then(|seq| {
            let v = voxel_config(&a.seq);
            let sel = placedb::SelectorConfig {
                mu: a.mu,
                window: a.window,
                sketch_margin: SolverParams::default().sketch_margin,
            };
            let out = a.out.as_deref();
            let recovery = device_cli::Recovery {
                faults: placedb_host::fault::FaultConfig::new(
                    a.drop_chance,
                    a.corrupt_chance,
                    a.fault_seed,
                ),
                retries: a.retries,
                resend_after: Duration::from_millis(a.resend_ms.max(1)),
                resume: a.resume,
                finish: !a.no_finish,
            };
            device_cli::stream_cmd(&a.port, &seq, &v, sel, &a.profile, out, a.quiet, &recovery)?;
            Ok(())
        }),
        Command::Export(a) => export(a),
        Command::Device(a) if a.rp2040 => {
            placedb_host::rp2040::device_cmd(a.firmware, a.port, a.flash).map_err(Into::into)
        }
        Command::Device(a) => {
            device_cli::qemu_device_cmd(a.firmware, a.port, !a.no_icount, a.flash)
                .map_err(Into::into)
        }
    };
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("placedb: error: {e}");
            ExitCode::FAILURE
        }
    }
}
