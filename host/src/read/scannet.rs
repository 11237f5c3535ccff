//! ScanNet's exported layout (what its SensReader writes from a `.sens`
//! file): `depth/N.png` (16-bit millimetres, depth scale 1000),
//! `pose/N.txt` (4x4 camera-to-world, one row per line), `color/N.jpg`, and
//! `intrinsic/intrinsic_depth.txt` (4x4, the depth camera's K in its top
//! left), for frame numbers N without padding; and the layout of its
//! `scannet_frames_25k` release (every 100th frame, numbers padded to six
//! digits, `000100.png`, and `intrinsics_depth.txt` beside the folders). A
//! frame's pose and colour files have its depth file's name.
//!
//! Frames are sorted by frame number; the timestamp is the frame number
//! (ScanNet records at 30 Hz and the export keeps no times). ScanNet writes
//! a frame whose tracking was lost as a pose of `-inf` (or NaN): such a
//! frame is skipped with a warning naming its pose files, and counted
//! ([`Sequence::frames_skipped`]); a depth image without its pose file is
//! an error naming both.

use super::{sevenscenes, text, ReadOptions};
use crate::error::ReadError;
use crate::sequence::{CameraModel, Clock, Format, FrameInfo, Sequence};
use std::collections::HashSet;
use std::path::Path;

/// Depth units per metre (millimetres).
pub const DEPTH_SCALE: f64 = 1000.0;

/// The depth camera's intrinsics file, relative to the scene directory:
/// where SensReader's export puts it, and where `scannet_frames_25k` does.
pub const INTRINSICS: [&str; 2] = ["intrinsic/intrinsic_depth.txt", "intrinsics_depth.txt"];

/// The frame number of an `N.<ext>` file name.
fn frame_number(name: &str, ext: &str) -> Option<u64> {
    let digits = name.strip_suffix(ext)?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok()
}

/// Whether `dir` is laid out as a ScanNet export: `depth/` and `pose/`.
pub(crate) fn looks_like_scannet(dir: &Path) -> bool {
    dir.join("depth").is_dir() && dir.join("pose").is_dir()
}

/// Parses ScanNet's 4x4 intrinsics matrix: `K` in the top left, the rest
/// of the last column and row `0 0 0 1`.
fn parse_intrinsics(path: &Path) -> Result<CameraModel, ReadError> {
    let content = text::read_text(path)?;
    let rows = text::square_rows(path, &content, 4, "intrinsics")?;
    let k = |r: usize, c: usize| rows[r].1[c];
    for (r, c, want) in [
        (0, 1, 0.0),
        (1, 0, 0.0),
        (2, 0, 0.0),
        (2, 1, 0.0),
        (2, 2, 1.0),
        (0, 3, 0.0),
        (1, 3, 0.0),
        (2, 3, 0.0),
        (3, 0, 0.0),
        (3, 1, 0.0),
        (3, 2, 0.0),
        (3, 3, 1.0),
    ] {
        if (k(r, c) - want).abs() > 1e-9 {
            return Err(text::parse_error(
                path,
                rows[r].0,
                format!(
                    "K[{r}][{c}] is {}, expected {want} in [fx 0 cx 0; 0 fy cy 0; 0 0 1 0; \
                     0 0 0 1]",
                    k(r, c)
                ),
            ));
        }
    }
    let model = CameraModel {
        fx: k(0, 0),
        fy: k(1, 1),
        cx: k(0, 2),
        cy: k(1, 2),
    };
    super::check_camera(&model).map_err(|reason| text::parse_error(path, rows[0].0, reason))?;
    Ok(model)
}

/// Whether a pose file's `content` is the invalid pose ScanNet writes for
/// a frame whose tracking was lost: any `-inf`, `inf` or NaN entry.
fn is_invalid_pose(content: &str) -> bool {
    text::data_lines(content)
        .flat_map(|(_, l)| l.split_whitespace())
        .any(|w| w.parse::<f64>().is_ok_and(|v| !v.is_finite()))
}

/// Reads a ScanNet export directory.
pub(crate) fn read(dir: &Path, opts: &ReadOptions) -> Result<Sequence, ReadError> {
    let (depth_dir, pose_dir) = (dir.join("depth"), dir.join("pose"));
    let mut numbered: Vec<(u64, String)> = text::list_dir(&depth_dir)?
        .into_iter()
        .filter_map(|n| frame_number(&n, ".png").map(|k| (k, n)))
        .collect();
    numbered.sort();
    if let Some(w) = numbered.windows(2).find(|w| w[0].0 == w[1].0) {
        return Err(text::layout(
            &depth_dir,
            format!("{} and {} have the same frame number", w[0].1, w[1].1),
        ));
    }
    if numbered.is_empty() {
        return Err(text::layout(&depth_dir, "no N.png depth images"));
    }
    let poses: HashSet<String> = text::list_dir(&pose_dir)?.into_iter().collect();
    let colors: HashSet<String> = match dir.join("color").is_dir() {
        true => text::list_dir(&dir.join("color"))?.into_iter().collect(),
        false => HashSet::new(),
    };
    let camera = match opts.intrinsics {
        Some(k) => k,
        None => match INTRINSICS.iter().map(|f| dir.join(f)).find(|p| p.is_file()) {
            Some(path) => parse_intrinsics(&path)?,
            None => {
                return Err(text::layout(
                    dir,
                    format!(
                        "no intrinsics file ({}: ScanNet's exports write one); or give \
                         --intrinsics fx,fy,cx,cy",
                        INTRINSICS.join(" or ")
                    ),
                ))
            }
        },
    };
    let mut frames = Vec::with_capacity(numbered.len());
    let mut paths = Vec::with_capacity(numbered.len());
    let mut invalid: Vec<String> = Vec::new();
    for (number, depth_name) in &numbered {
        let stem = depth_name.strip_suffix(".png").unwrap_or(depth_name);
        let pose_name = format!("{stem}.txt");
        if !poses.contains(&pose_name) {
            return Err(text::layout(
                &depth_dir.join(depth_name),
                format!("has no pose file (expected pose/{pose_name})"),
            ));
        }
        let pose_path = pose_dir.join(&pose_name);
        let content = text::read_text(&pose_path)?;
        if is_invalid_pose(&content) {
            invalid.push(format!("pose/{pose_name}"));
            continue;
        }
        let (translation, rotation) = sevenscenes::parse_pose_text(&pose_path, &content)?;
        let color_name = format!("{stem}.jpg");
        frames.push(FrameInfo {
            index: frames.len(),
            timestamp: *number as f64,
            translation,
            rotation,
            depth_name: format!("depth/{depth_name}"),
            color_path: colors
                .contains(&color_name)
                .then(|| dir.join("color").join(&color_name)),
        });
        paths.push(depth_dir.join(depth_name));
    }
    if !invalid.is_empty() {
        let shown: Vec<&str> = invalid.iter().take(10).map(String::as_str).collect();
        let msg = format!(
            "{}: {} of {} frames have an invalid pose (-inf or NaN: ScanNet's tracking was \
             lost there): {}{}",
            dir.display(),
            invalid.len(),
            numbered.len(),
            shown.join(", "),
            if invalid.len() > shown.len() {
                ", ..."
            } else {
                ""
            }
        );
        if frames.is_empty() {
            return Err(text::layout(dir, msg));
        }
        crate::warning::warn(format!("{msg}: skipped"));
    }
    super::assemble(
        dir,
        Format::ScanNet,
        camera,
        opts.depth_scale.unwrap_or(DEPTH_SCALE),
        super::Found {
            frames,
            clock: Clock::FrameNumbers {
                hz: crate::sequence::FRAME_NUMBER_HZ,
            },
            paths,
            skipped: invalid.len(),
            pose_interpolation: None,
        },
        false,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_numbers_and_invalid_poses() {
        assert_eq!(frame_number("12.png", ".png"), Some(12));
        assert_eq!(frame_number("frame-1.png", ".png"), None);
        assert_eq!(frame_number(".png", ".png"), None);
        let dir = std::env::temp_dir().join(format!("placedb-scannet-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        assert!(is_invalid_pose(&"-inf -inf -inf -inf\n".repeat(4)));
        assert!(is_invalid_pose("1 0 0 nan\n0 1 0 0\n0 0 1 0\n0 0 0 1\n"));
        assert!(!is_invalid_pose("1 0 0 0.5\n0 1 0 0\n0 0 1 0\n0 0 0 1\n"));
        let k = dir.join("k.txt");
        std::fs::write(&k, "500 0 320 0\n0 501 240 0\n0 0 1 0\n0 0 0 1\n").unwrap();
        assert_eq!(parse_intrinsics(&k).unwrap().fy, 501.0);
        std::fs::write(&k, "500 0 320 0\n0 501 240 0\n0 0 1 0\n0 0 1 1\n").unwrap();
        let e = parse_intrinsics(&k).unwrap_err().to_string();
        assert!(e.contains("k.txt:4") && e.contains("K[3][2]"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
