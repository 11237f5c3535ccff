//! Writes a sequence in the TUM RGB-D layout: `depth/<ts>.png` (16-bit grey),
//! `rgb/<ts>.png` (8-bit RGB, shaded from the depth), `depth.txt`, `rgb.txt`,
//! `groundtruth.txt`, plus `intrinsics.txt` (3x3 K, since the camera is not one
//! of the Freiburg cameras TUM readers know).

use super::shade::shade;
use crate::error::ReadError;
use crate::picture::png::Samples;
use crate::sequence::Sequence;
use indicatif::ProgressBar;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// A sequence `placedb synth` wrote, in a refusal.
pub const SYNTH_OUTPUT: &str = "a sequence written by placedb synth";

/// Whether `dir` holds a sequence `placedb synth` wrote (which a run
/// replaces whole): a `depth.txt` that names the synthetic sequence, as
/// [`write_tum`] writes it (a recorded TUM sequence names its bag).
pub fn is_synth_output(dir: &Path) -> bool {
    std::fs::read_to_string(dir.join("depth.txt"))
        .is_ok_and(|t| t.lines().nth(1) == Some("# file: 'synthetic'"))
}

/// Writes `seq` under `dir` (created if needed; existing files of the same
/// names are replaced; `placedb synth` gives it an empty directory). Frames are rendered and encoded in parallel;
/// `progress` advances once per frame. Depth values are written as they are:
/// the layout states 5000 units per metre, so `seq.depth_scale` should be 5000.
pub fn write_tum(
    seq: &Sequence,
    dir: &Path,
    progress: Option<&ProgressBar>,
) -> Result<(), ReadError> {
    for sub in ["depth", "rgb"] {
        let d = dir.join(sub);
        std::fs::create_dir_all(&d).map_err(|source| ReadError::Io { path: d, source })?;
    }
    seq.frames
        .par_iter()
        .try_for_each(|f| -> Result<(), ReadError> {
            let depth = seq.depth(f.index)?;
            let ts = stamp(f.timestamp);
            let size = (depth.width, depth.height);
            write_png(
                &dir.join(format!("depth/{ts}.png")),
                size,
                Samples::Grey16(&depth.data),
            )?;
            let rgb = shade(&depth, &seq.camera, seq.depth_scale, f.rotation);
            write_png(
                &dir.join(format!("rgb/{ts}.png")),
                size,
                Samples::Rgb8(&rgb),
            )?;
            if let Some(p) = progress {
                p.inc(1);
            }
            Ok(())
        })?;
    let header =
        |what: &str, columns: &str| format!("# {what}\n# file: '{}'\n# {columns}\n", seq.name);
    let mut depth_txt = header("depth maps", "timestamp filename");
    let mut rgb_txt = header("color images", "timestamp filename");
    let mut gt_txt = header("ground truth trajectory", "timestamp tx ty tz qx qy qz qw");
    for f in &seq.frames {
        let ts = stamp(f.timestamp);
        depth_txt += &format!("{ts} depth/{ts}.png\n");
        rgb_txt += &format!("{ts} rgb/{ts}.png\n");
        let [tx, ty, tz] = f.translation;
        let [qx, qy, qz, qw] = f.rotation;
        // Shortest exact decimal forms: the poses read back bit for bit.
        gt_txt += &format!("{ts} {tx} {ty} {tz} {qx} {qy} {qz} {qw}\n");
    }
    let c = &seq.camera;
    let k = format!("{} 0 {}\n0 {} {}\n0 0 1\n", c.fx, c.cx, c.fy, c.cy);
    for (name, text) in [
        ("depth.txt", depth_txt),
        ("rgb.txt", rgb_txt),
        ("groundtruth.txt", gt_txt),
        ("intrinsics.txt", k),
    ] {
        let path = dir.join(name);
        std::fs::write(&path, text).map_err(|source| ReadError::Io { path, source })?;
    }
    Ok(())
}

/// A timestamp as TUM writes it: seconds with 6 decimals.
fn stamp(t: f64) -> String {
    format!("{t:.6}")
}

/// Writes `samples` as a PNG with the one PNG writer ([`crate::picture::png`]).
fn write_png(path: &Path, (w, h): (u16, u16), samples: Samples<'_>) -> Result<(), ReadError> {
    crate::picture::png::write(path, u32::from(w), u32::from(h), samples).map_err(|source| {
        ReadError::Io {
            path: PathBuf::from(path),
            source,
        }
    })
}
