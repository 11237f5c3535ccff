//! `placedb bench`'s timing table: select's wall time, time split and peak
//! memory on the synthetic scan and the recorded samples, each run in a
//! child process, beside a floor that only decodes the depth images.

use super::{figure, BenchOptions};
use crate::error::CommandError as Error;
use crate::output::metrics_json;
use crate::pipeline::Solver;
use crate::read::{self, ReadOptions};
use crate::sequence::Format;
use crate::voxelize;
use std::path::Path;
use std::time::Instant;

/// The paper's reference code on this machine, 7scenes-1000 at stride 1
/// (figures from the issue that set the target): seconds and peak MB.
const PAPER_7SCENES: (f64, f64) = (51.0, 400.0);

/// The timing table: every solver of `a.solvers` on each input, `a.repeat`
/// rounds, printed with the ratios to the decode-only floor.
pub fn table(a: &BenchOptions) -> Result<(), Error> {
    // A recording that is not one is refused before any row runs.
    let mut walkable = Vec::new();
    for bag in &a.bags {
        let format = read::detect(bag).map_err(|e| format!("--bag: {e}"))?;
        walkable.push(matches!(format, Format::Ros2 | Format::Ros1));
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
            crate::warning::warn(format!("{} not found, skipped", p.display()));
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
    // Runs `placedb ARGS` (or, for a row of the Python API, the
    // interpreter with ARGS) in a child: its wall time from spawn to exit,
    // its CPU time (user and system, all threads), and the JSON it printed.
    let run = |args: &[String]| -> Result<(f64, f64, serde_json::Value), Error> {
        let (program, args) = match (args.first(), &a.python) {
            (Some(first), Some(python)) if first == PYTHON_ROW => (python.as_path(), &args[1..]),
            _ => (exe.as_path(), args),
        };
        let (t, cpu) = (Instant::now(), children_cpu_s());
        let child = std::process::Command::new(program).args(args).output()?;
        let (wall, cpu) = (t.elapsed().as_secs_f64(), children_cpu_s() - cpu);
        if !child.status.success() {
            let err = String::from_utf8_lossy(&child.stderr);
            return Err(format!("{} {}: {err}", program.display(), args.join(" ")).into());
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
        let mut rows: Vec<(String, Vec<String>)> = Vec::new();
        if let Some(path) = args.first().filter(|p| !p.starts_with("--")) {
            rows.push((
                "decode-only".into(),
                vec!["bench".into(), "--decode-only".into(), path.clone()],
            ));
        }
        let has_floor = !rows.is_empty();
        // The same frames read from a recording, as a row beside the PNG
        // files' floor (its ratio to the floor is the recording's cost).
        if name == "7scenes-1000" {
            for (bag, &walkable) in a.bags.iter().zip(&walkable) {
                let file = bag.file_name().unwrap_or(bag.as_os_str());
                let child =
                    |flag: &str| vec!["bench".into(), flag.into(), bag.display().to_string()];
                rows.push((
                    format!("read {}", file.to_string_lossy()),
                    child("--decode-only"),
                ));
                // One pass over the bag's files and nothing decoded: what
                // any reading of it pays at least (its chunks'
                // decompression), so a read row's ratio can be told from
                // its container's.
                if walkable {
                    rows.push((
                        format!("{WALK_ROW}{}", file.to_string_lossy()),
                        child("--walk-only"),
                    ));
                }
            }
        }
        for solver in &a.solvers {
            let mut select: Vec<String> = vec!["select".into()];
            select.extend(args.iter().cloned());
            select.extend(
                ["--solver", solver.name(), "--stride", &a.stride.to_string()].map(String::from),
            );
            select.extend(["--json", "-q", "-o"].map(String::from));
            select.push(out.display().to_string());
            rows.push((solver.name().into(), select));
        }
        if a.python.is_some() {
            for solver in &a.solvers {
                let sequence = match args.as_slice() {
                    [path] => path.clone(),
                    _ => format!("--demo={}", a.synthetic_frames),
                };
                let py = [PYTHON_ROW, "-c", PYTHON_SELECT, &sequence, solver.name()];
                let mut py: Vec<String> = py.map(String::from).to_vec();
                py.extend([a.stride.to_string(), out.display().to_string()]);
                rows.push((format!("py {}", solver.name()), py));
            }
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
            // A figure the row's run does not report (the floor has no
            // solve time) is NaN here, and printed "-".
            let f = |k: &str| m[k].as_f64().unwrap_or(f64::NAN);
            println!(
                "{:<16} {:<11} {:>6} {:>7} {:>7} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}",
                name,
                row,
                figure(f("frames"), 0),
                figure(*wall, 3),
                figure(*cpu, 3),
                figure(f("total_s"), 3),
                figure(f("read_cpu_s"), 3),
                figure(f("voxelize_cpu_s"), 3),
                figure(f("voxelize_s"), 3),
                figure(f("graph_s"), 3),
                figure(f("solve_s"), 3),
                figure(f("peak_rss_mb"), 1)
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
                let what = if row.starts_with(WALK_ROW) {
                    "(one pass over the recording, nothing decoded: the least a reading of it costs)"
                } else {
                    "(target <= 1.3x)"
                };
                println!(
                    "{:<16} {:<11} {}x the decode-only wall time, {}x its CPU time, medians of the runs beside a floor run {what}",
                    "",
                    "",
                    figure(ratio(|(wall, _)| wall), 2),
                    figure(ratio(|(_, cpu)| cpu), 2)
                );
            }
            if let Some(solver) = row.strip_prefix("py ") {
                // The command's row of the same solver: the Python API's
                // cost is its ratio to it.
                let command = rows.iter().position(|(r, _)| r == solver);
                let command_wall = command
                    .and_then(|c| median_by(&runs[c], |run| run.0))
                    .map_or(f64::NAN, |run| run.0);
                println!(
                    "{:<16} {:<11} {}x the command's wall time for {solver}, medians (target <= 1.1x)",
                    "",
                    "",
                    figure(wall / command_wall, 2),
                );
            }
            if *name == "7scenes-1000" && a.stride == 1 && *row == Solver::InOrder.name() {
                let (s, mb) = PAPER_7SCENES;
                println!(
                    "{:<16} {:<11} paper's code: {s} s, {mb} MB -> {}x faster, {}x less memory (target 100x, 10x)",
                    "",
                    "",
                    figure(s / wall, 0),
                    figure(mb / f("peak_rss_mb"), 1)
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
         read BAG (--bag): the 7scenes-1000 frames decoded from that recording, beside the\n\
         PNG files' decode-only; walk BAG: one pass over its files, every chunk decompressed\n\
         and no message decoded;\n\
         * read and voxel are CPU time summed over threads; the others are wall time",
        a.repeat
    );
    Ok(())
}

/// The first argument of a row run by `--python`'s interpreter instead of
/// `placedb`.
const PYTHON_ROW: &str = "<python>";

/// The Python API's row: `placedb.select(SEQ, solver=..., stride=...)`
/// written to OUT, its metrics printed as JSON, as `select --json` does.
/// SEQ `--demo=N` is the synthetic scan of N frames.
const PYTHON_SELECT: &str = "import json, sys, placedb
seq, solver, stride, out = sys.argv[1:5]
demo = seq.startswith('--demo=')
kw = dict(demo=True, demo_frames=int(seq[7:])) if demo else {}
db = placedb.select(None if demo else seq, solver=solver, stride=int(stride), **kw)
db.write(out)
print(json.dumps(db.metrics))";

/// A child of the timing table (`bench --decode-only PATH`): decodes every
/// depth image of the sequence at `path`, as select would, and prints its
/// frames and peak memory as JSON.
pub fn decode_only(path: &Path) -> Result<(), Error> {
    let seq = read::open(path, &ReadOptions::default())?;
    voxelize::decode_all(&seq)?;
    let json = serde_json::json!({
        "frames": seq.frames.len(),
        "peak_rss_mb": metrics_json::peak_rss_mb(),
    });
    println!("{json}");
    Ok(())
}

/// A child of the timing table (`bench --walk-only PATH`): one pass over
/// the recording at `path`, and its messages, bytes and peak memory as
/// JSON.
pub fn walk_only(path: &Path) -> Result<(), Error> {
    let walked = read::ros2::walk(path)?;
    let json = serde_json::json!({
        "messages": walked.messages,
        "bytes": walked.bytes,
        "peak_rss_mb": metrics_json::peak_rss_mb(),
    });
    println!("{json}");
    Ok(())
}

/// The row name's start of a recording's walk.
const WALK_ROW: &str = "walk ";

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
