//! TUM RGB-D: `depth.txt` (`timestamp path` per line), `groundtruth.txt`
//! (`timestamp tx ty tz qx qy qz qw`), optional `rgb.txt` (`timestamp path`);
//! `#` lines are comments. Depth PNGs are 16-bit, 5000 units per metre.
//!
//! Each depth frame takes its pose from the groundtruth lines around it in
//! time, interpolated ([`super::timed_poses`]; `--pose-interpolation
//! nearest`: the nearest line's); a depth frame with no groundtruth within
//! [`MAX_DIFFERENCE`] (0.02 s, the default of TUM's `associate.py`), or,
//! interpolating, before the first line or after the last, is skipped with a
//! warning naming its lines, and counted ([`Sequence::frames_skipped`]). Two lines of one file with the same
//! timestamp (a duplicated line, say) are an error naming both. Frames are
//! in timestamp order; the timestamp is the depth image's, and the depth
//! name its `depth.txt` path. The colour image is the nearest `rgb.txt`
//! entry within the same 0.02 s.
//!
//! Intrinsics come from `intrinsics.txt` (3x3 K, or the one line
//! `fx fy cx cy`; docs/FORMATS.md) when present, else, for 640x480 images
//! only, the Freiburg default ROS values fx = fy = 525, cx = 319.5,
//! cy = 239.5, with a warning (the per-camera calibrations
//! fr1/fr2/fr3 differ by up to 10 %: give them with an intrinsics file or
//! override when it matters). Other sizes need the file or the override.

use super::timed_poses::{pose_at, PoseInterpolation, TimedPose};
use super::{text, ReadOptions};
use crate::error::ReadError;
use crate::sequence::{CameraModel, Clock, Format, FrameInfo, Sequence};
use std::path::{Path, PathBuf};

/// Default intrinsics (TUM's "ROS default" for all Freiburg sequences).
pub const DEFAULT_CAMERA: CameraModel = CameraModel {
    fx: 525.0,
    fy: 525.0,
    cx: 319.5,
    cy: 239.5,
};

/// Depth units per metre.
pub const DEPTH_SCALE: f64 = 5000.0;

/// Largest time difference, seconds, between a depth frame and the
/// groundtruth (or colour) entry associated with it.
pub const MAX_DIFFERENCE: f64 = 0.02;

/// A `timestamp path` line.
struct Entry {
    line: usize,
    timestamp: f64,
    path: String,
}

/// A groundtruth line.
struct GroundTruth {
    line: usize,
    timestamp: f64,
    translation: [f64; 3],
    rotation: [f64; 4],
}

fn parse_list(path: &Path) -> Result<Vec<Entry>, ReadError> {
    let content = text::read_text(path)?;
    let mut out = Vec::new();
    for (line, l) in text::data_lines(&content) {
        let fields: Vec<&str> = l.split_whitespace().collect();
        if fields.len() != 2 {
            return Err(text::parse_error(
                path,
                line,
                format!(
                    "expected 2 columns (timestamp path), found {}",
                    fields.len()
                ),
            ));
        }
        let timestamp = parse_timestamp(path, line, fields[0])?;
        out.push(Entry {
            line,
            timestamp,
            path: fields[1].to_owned(),
        });
    }
    out.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
    let lines: Vec<(usize, f64)> = out.iter().map(|e| (e.line, e.timestamp)).collect();
    distinct_timestamps(path, &lines)?;
    Ok(out)
}

/// Refuses two lines with one timestamp (`lines` sorted by time): a
/// duplicated line would be read as two frames, and two different entries
/// at one time leave no way to tell which one is meant.
fn distinct_timestamps(path: &Path, lines: &[(usize, f64)]) -> Result<(), ReadError> {
    if let Some(w) = lines.windows(2).find(|w| w[0].1 == w[1].1) {
        let (first, second) = (w[0].0.min(w[1].0), w[0].0.max(w[1].0));
        return Err(text::parse_error(
            path,
            second,
            format!(
                "timestamp {} is also the one of line {first}: each line needs its own time \
                 (remove the duplicate)",
                w[0].1
            ),
        ));
    }
    Ok(())
}

fn parse_timestamp(path: &Path, line: usize, field: &str) -> Result<f64, ReadError> {
    match field.parse::<f64>() {
        Ok(t) if t.is_finite() => Ok(t),
        _ => Err(text::parse_error(
            path,
            line,
            format!("timestamp {field:?} is not a finite number"),
        )),
    }
}

fn parse_groundtruth(path: &Path) -> Result<Vec<GroundTruth>, ReadError> {
    let content = text::read_text(path)?;
    let mut out = Vec::new();
    for (line, l) in text::data_lines(&content) {
        let v = text::numbers(path, line, l, &[8], "timestamp tx ty tz qx qy qz qw")?;
        if !v[0].is_finite() {
            return Err(text::parse_error(
                path,
                line,
                format!("timestamp {} is not finite", v[0]),
            ));
        }
        let translation = [v[1], v[2], v[3]];
        let rotation = text::checked_quaternion(path, line, translation, [v[4], v[5], v[6], v[7]])?;
        out.push(GroundTruth {
            line,
            timestamp: v[0],
            translation,
            rotation,
        });
    }
    out.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
    let lines: Vec<(usize, f64)> = out.iter().map(|g| (g.line, g.timestamp)).collect();
    distinct_timestamps(path, &lines)?;
    Ok(out)
}

/// Index of the entry of `sorted` (ascending) nearest to `t`, if within
/// [`MAX_DIFFERENCE`]; ties go to the earlier entry.
fn nearest(sorted: &[f64], t: f64) -> Option<usize> {
    let i = sorted.partition_point(|&s| s < t);
    let candidates = [i.checked_sub(1), (i < sorted.len()).then_some(i)];
    candidates
        .into_iter()
        .flatten()
        .map(|j| (j, (sorted[j] - t).abs()))
        .filter(|&(_, d)| d <= MAX_DIFFERENCE)
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(j, _)| j)
}

/// Reads a TUM RGB-D sequence directory.
pub(crate) fn read(dir: &Path, opts: &ReadOptions) -> Result<Sequence, ReadError> {
    let depth_list = dir.join("depth.txt");
    let depth = parse_list(&depth_list)?;
    let gt = parse_groundtruth(&dir.join("groundtruth.txt"))?;
    let rgb_list = dir.join("rgb.txt");
    let rgb = if rgb_list.exists() {
        parse_list(&rgb_list)?
    } else {
        Vec::new()
    };
    let given = super::given_camera(dir, "intrinsics.txt", opts)?;

    let track: Vec<TimedPose> = gt
        .iter()
        .map(|g| TimedPose {
            stamp: g.timestamp,
            translation: g.translation,
            rotation: g.rotation,
        })
        .collect();
    let rgb_times: Vec<f64> = rgb.iter().map(|e| e.timestamp).collect();
    let mut frames = Vec::with_capacity(depth.len());
    let mut paths: Vec<PathBuf> = Vec::with_capacity(depth.len());
    let mut skipped: Vec<&Entry> = Vec::new();
    for entry in &depth {
        let Some(g) = pose_at(
            &track,
            entry.timestamp,
            MAX_DIFFERENCE,
            opts.pose_interpolation,
        ) else {
            skipped.push(entry);
            continue;
        };
        let path = dir.join(&entry.path);
        if !path.is_file() {
            return Err(text::parse_error(
                &depth_list,
                entry.line,
                format!("depth image {} does not exist", path.display()),
            ));
        }
        frames.push(FrameInfo {
            index: frames.len(),
            timestamp: entry.timestamp,
            translation: g.translation,
            rotation: g.rotation,
            depth_name: entry.path.clone(),
            color_path: nearest(&rgb_times, entry.timestamp).map(|j| dir.join(&rgb[j].path)),
        });
        paths.push(path);
    }
    if !skipped.is_empty() {
        let mut lines: Vec<usize> = skipped.iter().map(|e| e.line).collect();
        lines.sort_unstable();
        let shown: Vec<String> = lines.iter().take(10).map(|l| l.to_string()).collect();
        let more = if lines.len() > shown.len() {
            ", ..."
        } else {
            ""
        };
        let msg = format!(
            "{}: {} of {} depth frames have no groundtruth within {MAX_DIFFERENCE} s{} \
             (line{} {}{more})",
            depth_list.display(),
            skipped.len(),
            depth.len(),
            match opts.pose_interpolation {
                PoseInterpolation::Linear => {
                    " or lie outside its time span (interpolation does not extrapolate)"
                }
                PoseInterpolation::Nearest => "",
            },
            if lines.len() == 1 { "" } else { "s" },
            shown.join(", ")
        );
        if frames.is_empty() {
            return Err(text::layout(dir, msg));
        }
        crate::warning::warn(format!("{msg}: skipped"));
    }
    let size = super::first_size(dir, &paths)?;
    let camera = match given {
        Some(k) => k,
        None => default_camera(dir, size)?,
    };
    super::assemble(
        dir,
        Format::Tum,
        camera,
        opts.depth_scale.unwrap_or(DEPTH_SCALE),
        super::Found {
            frames,
            clock: Clock::Seconds,
            paths,
            skipped: skipped.len(),
            pose_interpolation: Some(opts.pose_interpolation),
        },
        false,
    )
}

/// [`DEFAULT_CAMERA`] for 640x480 images, with a warning that says so; for
/// any other size an error asking for the intrinsics (the default's
/// principal point would be off the image's centre, and its focal length
/// for another sensor).
fn default_camera(dir: &Path, size: (u16, u16)) -> Result<CameraModel, ReadError> {
    let k = DEFAULT_CAMERA;
    let default = format!(
        "TUM's default intrinsics fx = fy = {}, cx = {}, cy = {}",
        k.fx, k.cx, k.cy
    );
    if size == (640, 480) {
        crate::warning::warn(format!(
            "{}: no intrinsics.txt: using {default} (the Freiburg cameras' ROS default; \
             write intrinsics.txt or give --intrinsics fx,fy,cx,cy when they differ)",
            dir.display()
        ));
        return Ok(k);
    }
    Err(text::layout(
        &dir.join("intrinsics.txt"),
        format!(
            "missing, and the depth images are {}x{}: {default} are for 640x480 images; \
             write intrinsics.txt (3x3 K or one line fx fy cx cy) or give --intrinsics fx,fy,cx,cy",
            size.0, size.1
        ),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_within_tolerance() {
        let t = [1.0, 1.01, 1.05, 2.0];
        assert_eq!(nearest(&t, 0.5), None);
        assert_eq!(nearest(&t, 0.99), Some(0));
        assert_eq!(nearest(&t, 1.004), Some(0));
        assert_eq!(nearest(&t, 1.006), Some(1));
        assert_eq!(nearest(&t, 1.04), Some(2));
        assert_eq!(nearest(&t, 1.5), None);
        assert_eq!(nearest(&t, 2.019), Some(3));
        assert_eq!(nearest(&t, 2.021), None);
        assert_eq!(nearest(&[], 1.0), None);
    }
}
