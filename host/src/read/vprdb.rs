//! The paper's reference code layout (prime-slam/place-recognition-db):
//! `depth/*.png` sorted by file name = frame order (16-bit, 1000 units per
//! metre), optional `color/` sorted by name and paired by position, a poses
//! file and `intrinsics.txt` (3x3, required unless overridden).
//!
//! The poses file is `poses.txt`, or else the only `*.txt` in the directory
//! other than `intrinsics.txt`. Each line is `tx ty tz qx qy qz qw`
//! (camera to world), optionally preceded by a timestamp (8 numbers); all lines
//! must have the same form. The timestamp is that column when present, else the
//! frame index; timestamps must rise from line to line (a duplicated or
//! reordered line would pair poses with the wrong images), else an error
//! names both lines. The number of poses must equal the number of depth
//! images, and a `color/` directory, when present, must hold as many images.

use super::{text, ReadOptions};
use crate::error::ReadError;
use crate::sequence::{Clock, Format, FrameInfo, Sequence};
use std::path::{Path, PathBuf};

/// Depth units per metre.
pub const DEPTH_SCALE: f64 = 1000.0;

/// One line of the poses file.
struct PoseLine {
    timestamp: Option<f64>,
    translation: [f64; 3],
    rotation: [f64; 4],
}

/// Finds the poses file: `poses.txt`, else the only other `*.txt`.
fn poses_file(dir: &Path, names: &[String]) -> Result<PathBuf, ReadError> {
    if names.iter().any(|n| n == "poses.txt") {
        return Ok(dir.join("poses.txt"));
    }
    let candidates: Vec<&String> = names
        .iter()
        .filter(|n| n.ends_with(".txt") && n.as_str() != "intrinsics.txt")
        .collect();
    match candidates.as_slice() {
        [one] => Ok(dir.join(one)),
        [] => Err(text::layout(
            dir,
            "no poses file: expected poses.txt (or one *.txt besides intrinsics.txt)",
        )),
        many => Err(text::layout(
            dir,
            format!(
                "no poses.txt and several candidate poses files: {}",
                many.iter()
                    .map(|s| s.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )),
    }
}

fn parse_poses(path: &Path) -> Result<Vec<PoseLine>, ReadError> {
    let content = text::read_text(path)?;
    let mut out = Vec::new();
    let mut columns: Option<(usize, usize)> = None;
    // The previous timestamp and its line.
    let mut previous: Option<(f64, usize)> = None;
    for (line, l) in text::data_lines(&content) {
        let v = text::numbers(path, line, l, &[7, 8], "[timestamp] tx ty tz qx qy qz qw")?;
        match columns {
            None => columns = Some((v.len(), line)),
            Some((n, first)) if n != v.len() => {
                return Err(text::parse_error(
                    path,
                    line,
                    format!(
                        "{} numbers, but line {first} has {n}: all poses must have the same form",
                        v.len()
                    ),
                ))
            }
            Some(_) => {}
        }
        let (timestamp, p) = if v.len() == 8 {
            if !v[0].is_finite() {
                return Err(text::parse_error(
                    path,
                    line,
                    format!("timestamp {} is not finite", v[0]),
                ));
            }
            if let Some((before, before_line)) = previous.filter(|&(t, _)| v[0] <= t) {
                let how = if v[0] == before {
                    "equals"
                } else {
                    "is before"
                };
                return Err(text::parse_error(
                    path,
                    line,
                    format!(
                        "timestamp {} {how} the one of line {before_line} ({before}): \
                         timestamps must rise, one line per depth image in depth/ order",
                        v[0]
                    ),
                ));
            }
            previous = Some((v[0], line));
            (Some(v[0]), &v[1..])
        } else {
            (None, &v[..])
        };
        let translation = [p[0], p[1], p[2]];
        let rotation = text::checked_quaternion(path, line, translation, [p[3], p[4], p[5], p[6]])?;
        out.push(PoseLine {
            timestamp,
            translation,
            rotation,
        });
    }
    Ok(out)
}

/// The files of `dir/sub` with one of the extensions `exts`, sorted by name;
/// `None` when the directory does not exist.
fn sorted_images(dir: &Path, sub: &str, exts: &[&str]) -> Result<Option<Vec<String>>, ReadError> {
    let path = dir.join(sub);
    if !path.is_dir() {
        return Ok(None);
    }
    let mut names: Vec<String> = text::list_dir(&path)?
        .into_iter()
        .filter(|n| {
            let lower = n.to_ascii_lowercase();
            exts.iter().any(|e| lower.ends_with(e))
        })
        .collect();
    names.sort();
    Ok(Some(names))
}

/// Reads a directory in the reference code's layout.
pub(crate) fn read(dir: &Path, opts: &ReadOptions) -> Result<Sequence, ReadError> {
    let depth_dir = dir.join("depth");
    let depth = sorted_images(dir, "depth", &[".png"])?
        .ok_or_else(|| text::layout(&depth_dir, "depth directory missing"))?;
    if depth.is_empty() {
        return Err(text::layout(&depth_dir, "no *.png depth images"));
    }
    let names = text::list_dir(dir)?;
    let poses_path = poses_file(dir, &names)?;
    let poses = parse_poses(&poses_path)?;
    if poses.len() != depth.len() {
        return Err(text::layout(
            &poses_path,
            format!(
                "{} poses for {} depth images in {}",
                poses.len(),
                depth.len(),
                depth_dir.display()
            ),
        ));
    }
    let color = sorted_images(dir, "color", &[".png", ".jpg", ".jpeg"])?;
    if let Some(color) = &color {
        if color.len() != depth.len() {
            return Err(text::layout(
                &dir.join("color"),
                format!(
                    "{} colour images for {} depth images (remove or complete color/)",
                    color.len(),
                    depth.len()
                ),
            ));
        }
    }
    let camera = super::camera(dir, "intrinsics.txt", None, opts)?;
    let frames: Vec<FrameInfo> = poses
        .iter()
        .zip(&depth)
        .enumerate()
        .map(|(index, (p, name))| FrameInfo {
            index,
            timestamp: p.timestamp.unwrap_or(index as f64),
            translation: p.translation,
            rotation: p.rotation,
            depth_name: format!("depth/{name}"),
            color_path: color.as_ref().map(|c| dir.join("color").join(&c[index])),
        })
        .collect();
    let paths = depth.iter().map(|n| depth_dir.join(n)).collect();
    super::assemble(
        dir,
        Format::Vprdb,
        camera,
        opts.depth_scale.unwrap_or(DEPTH_SCALE),
        super::Found {
            frames,
            clock: if poses.iter().any(|p| p.timestamp.is_some()) {
                Clock::Seconds
            } else {
                Clock::FrameNumbers {
                    hz: crate::sequence::FRAME_NUMBER_HZ,
                }
            },
            paths,
            pose_interpolation: None,
            skipped: 0,
        },
        false,
    )
}
