//! The one writer of `metrics.json`: the flat object of a `placedb select`
//! outcome ([`of_select`]) and of a device's export ([`of_device`]), and its
//! text ([`text`]). Scripts read these: the key names are stable.

use crate::pipeline::{Measured, Outcome, Prepared, SolverParams};
use crate::sequence::Sequence;
use placedb::protocol::{CapacitySlot, Config, Status};
use std::io;

/// Peak resident memory of this process so far, MB (Linux `VmHWM`).
pub fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// The text of `metrics.json`: `metrics` pretty-printed, with a final newline.
pub fn text(metrics: &serde_json::Value) -> io::Result<String> {
    let json = serde_json::to_string_pretty(metrics).map_err(io::Error::other)?;
    Ok(json + "\n")
}

/// The flat `metrics.json` object of one outcome of `placedb select` (and
/// one entry of `placedb compare --json`).
pub fn of_select(
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
    put("depth_min", decimal(c.range.min).into());
    put(
        "depth_max",
        if c.range.max.is_finite() {
            decimal(c.range.max).into()
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
    put(
        "pose_interpolation",
        serde_json::to_value(seq.pose_interpolation).unwrap_or_default(),
    );
    let losses = o.losses(prep);
    put("frames_skipped", losses.frames_skipped.into());
    put("empty_frames", losses.empty_frames.into());
    put("out_of_range_points", losses.out_of_range_points.into());
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
        put("unkeyed_frames", st.unkeyed_frames.into());
        put("sketch_compared_frames", st.sketch_compared_frames.into());
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

/// What the host measured of a device's scan on the sequence that was
/// streamed (`export --sequence`): the sequence, its voxel sets on the
/// scan's grid, and the device's database measured on them.
pub struct OnSequence<'a> {
    /// The streamed sequence (its first `frames` frames, the device's).
    pub seq: &'a Sequence,
    /// Its voxel sets and overlaps.
    pub prep: &'a Prepared,
    /// The device's database and labels measured on them.
    pub measured: &'a Measured,
}

/// The keys of a device's `metrics.json` that it counts in RAM only, lost
/// when it restarts.
pub const RAM_COUNTERS: [&str; 11] = [
    "sketched_frames",
    "unkeyed_frames",
    "sketch_compared_frames",
    "truncated_frames",
    "uncovered_by_capacity",
    "labels_dropped",
    "out_of_range_points",
    "valid_pixels",
    "pool_peak_words",
    "frame_voxels_peak",
    "resident_peak",
];

/// The `metrics.json` object of a device's export: what the device knows
/// from its status and, when it keeps a flash log, the configuration it
/// scanned with (`config`; `profile`: the capacity profile it reports, if
/// any). It has every key [`of_select`] writes: the coverage metrics and
/// the host's reading come from the streamed sequence (`on`, `export
/// --sequence`); without it they are `null`, and `not_measured` says why,
/// as it does for the host's solving times (the device solved). A scan
/// restored from flash after a reset is a resume, not a degradation:
/// `restored_from_flash` (this boot), and from a finished scan's log
/// (`resumes`) how often and at which frames (`resumed_at`) a host resumed
/// it.
pub fn of_device(
    st: &Status,
    config: Option<&Config>,
    resumes: Option<&[u32]>,
    export_records: usize,
    profile: Option<&str>,
    on: Option<&OnSequence<'_>>,
) -> serde_json::Value {
    use placedb::protocol::degradation::RESTORED;
    let size = st.database_size;
    let frames = st.capacity(CapacitySlot::Labels).used;
    let mut m = serde_json::json!({
        "solver": "online",
        "source": "device",
        "size": size,
        "frames": frames,
        "reduction": if size > 0 { f64::from(frames) / f64::from(size) } else { 0.0 },
        "profile": profile,
        "frames_seen": st.frames_seen,
        // An open scan (not finished) exports only its decided frames.
        "scan_finished": st.phase == placedb::protocol::Phase::Finished,
        "frames_decided": st.frames_decided,
        "frames_undecided": st.frames_seen.saturating_sub(st.frames_decided),
        "sketched_frames": st.sketched_frames,
        "unkeyed_frames": st.unkeyed_frames,
        "sketch_compared_frames": st.sketch_compared_frames,
        "truncated_frames": st.truncated_frames,
        "uncovered_by_capacity": st.uncovered_frames,
        "labels_dropped": st.labels_dropped,
        "out_of_range_points": st.out_of_range_points,
        "valid_pixels": st.valid_pixels,
        "degradation_flags": st.degradation & !RESTORED,
        "restored_from_flash": st.degradation & RESTORED != 0,
        "pool_peak_words": st.capacity(CapacitySlot::Pool).peak,
        "frame_voxels_peak": st.capacity(CapacitySlot::FrameVoxels).peak,
        "export_records": export_records,
        "resident_peak": st.capacity(CapacitySlot::Resident).peak,
        "flash_bytes_used": st.capacity(CapacitySlot::Flash).used,
        "flash_bytes_limit": st.capacity(CapacitySlot::Flash).limit,
    });
    let decimal = |x: f32| x.to_string().parse::<f64>().unwrap_or(f64::from(x));
    let scan = [
        "mu",
        "voxel",
        "stride",
        "depth_min",
        "depth_max",
        "grid_origin",
        "window",
    ];
    match config {
        Some(c) => {
            m["mu"] = decimal(c.mu).into();
            m["voxel"] = decimal(c.voxel_size).into();
            m["stride"] = c.stride.into();
            m["depth_min"] = decimal(c.depth_range.min).into();
            m["depth_max"] = if c.depth_range.max.is_finite() {
                decimal(c.depth_range.max).into()
            } else {
                "inf".into()
            };
            // The device knows the grid's corner, not how the host chose
            // it: the world origin is `world`, any other corner was the
            // scene's minimum.
            m["grid_origin"] = if c.grid_origin == [0.0; 3] {
                "world"
            } else {
                "scene-min"
            }
            .into();
            m["window"] = c.window.into();
        }
        None => {
            for k in scan {
                m[k] = serde_json::Value::Null;
            }
        }
    }
    // What only the sequence's voxel sets and the host's reading give.
    let from_sequence = [
        "sequence",
        "format",
        "pose_interpolation",
        "frames_skipped",
        "empty_frames",
        "co_observing_pairs",
        "labels_below_mu",
        "label_iou_min",
        "uncovered",
        "spatial_coverage",
        "frames_coverage_mean",
        "frames_coverage_min",
        "frames_coverage_below_0_3",
        "voxelize_s",
        "read_cpu_s",
        "voxelize_cpu_s",
        "graph_s",
    ];
    // The device selected: the host's solving times are not its.
    let solved_on_device = ["solve_s", "core_s", "total_s", "peak_rss_mb"];
    for k in solved_on_device {
        m[k] = serde_json::Value::Null;
    }
    let mut why = Vec::new();
    // The device counts in RAM: after a restart it counts only the frames
    // since (a scan that had 306 frames compared by sketch would report 0),
    // so a restored scan's counters are unknown, not 0.
    if st.degradation & RESTORED != 0 {
        for k in RAM_COUNTERS {
            m[k] = serde_json::Value::Null;
        }
        why.push(
            "the board restarted and restored the scan from flash: its counters (sketched, \
             truncated and uncovered frames, dropped labels, points out of range, valid pixels, \
             peaks) are kept in RAM and count only the frames since",
        );
    }
    // How often and where a host resumed the scan after a restart, from a
    // finished scan's log.
    match resumes {
        Some(at) => {
            m["resumes"] = at.len().into();
            m["resumed_at"] = at.into();
        }
        None => {
            m["resumes"] = serde_json::Value::Null;
            m["resumed_at"] = serde_json::Value::Null;
            why.push("the resumes are read from the flash log of a finished scan");
        }
    }
    match on {
        Some(on) => {
            let (seq, prep, me) = (on.seq, on.prep, &on.measured.metrics);
            m["sequence"] = seq.name.clone().into();
            m["format"] = serde_json::to_value(seq.format).unwrap_or_default();
            m["pose_interpolation"] =
                serde_json::to_value(seq.pose_interpolation).unwrap_or_default();
            m["frames_skipped"] = prep.losses.frames_skipped.into();
            m["empty_frames"] = prep.losses.empty_frames.into();
            m["co_observing_pairs"] = prep.co.pair_count().into();
            m["labels_below_mu"] = on.measured.labels_below_mu.into();
            m["label_iou_min"] = f64::from(on.measured.label_iou_min).into();
            m["uncovered"] = me.uncovered.into();
            m["spatial_coverage"] = me.spatial_coverage.into();
            m["frames_coverage_mean"] = me.frames_coverage_mean.into();
            m["frames_coverage_min"] = me.frames_coverage_min.into();
            m["frames_coverage_below_0_3"] = me.frames_coverage_below_0_3.into();
            m["voxelize_s"] = prep.voxelize_wall.as_secs_f64().into();
            m["read_cpu_s"] = prep.sets.read_time.as_secs_f64().into();
            m["voxelize_cpu_s"] = prep.sets.voxelize_time.as_secs_f64().into();
            m["graph_s"] = prep.graph_wall.as_secs_f64().into();
        }
        None => {
            for k in from_sequence {
                m[k] = serde_json::Value::Null;
            }
            why.push(
                "a device keeps no voxel sets of its frames: the coverage metrics need the \
                 sequence (placedb export --sequence SEQ computes them)",
            );
        }
    }
    why.push(
        "the device made the selection: the host's solving times (solve_s, core_s, total_s, \
         peak_rss_mb) are not its",
    );
    if config.is_none() {
        why.push("the scan's settings need the device's flash log, which it does not keep");
    }
    m["not_measured"] = why.join("; ").into();
    if st.cost.clock_hz > 0 && st.cost.frames > 0 {
        m["device_ticks_per_frame"] = (st.cost.total as f64 / f64::from(st.cost.frames)).into();
        m["device_clock_hz"] = st.cost.clock_hz.into();
    }
    m
}
