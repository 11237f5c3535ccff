//! Microsoft 7-Scenes (one `seq-XX` directory): `frame-XXXXXX.depth.png`
//! (16-bit millimetres, depth scale 1000; both 0 and 65535 mean "no
//! measurement", 65535 is decoded as 0) and `frame-XXXXXX.pose.txt` (4x4
//! camera-to-world matrix, one row per line, last row `0 0 0 1`).
//!
//! Frames are sorted by frame number; the timestamp is the frame number (the
//! dataset has none). `camera-intrinsics.txt` (3x3) gives the intrinsics when
//! present, else the dataset's fx = fy = 585, cx = 320, cy = 240. The colour
//! image is `frame-XXXXXX.color.png` or `.jpg` when one exists. A depth image
//! without its pose file is an error naming both; a pose file without its
//! depth image is a frame skipped with a warning naming it, and counted
//! ([`Sequence::frames_skipped`]): the frames after it keep their
//! timestamps (frame numbers), which is how a frame is traced to its files.

use super::{text, ReadOptions};
use crate::error::ReadError;
use crate::sequence::{CameraModel, Clock, Format, FrameInfo, Sequence};
use nalgebra::{Matrix3, UnitQuaternion};
use std::collections::HashSet;
use std::path::Path;

/// The dataset's intrinsics, used when `camera-intrinsics.txt` is absent.
pub const DEFAULT_CAMERA: CameraModel = CameraModel {
    fx: 585.0,
    fy: 585.0,
    cx: 320.0,
    cy: 240.0,
};

/// Depth units per metre (millimetres).
pub const DEPTH_SCALE: f64 = 1000.0;

/// The frame number of a `frame-<digits>.depth.png` file name.
pub(crate) fn frame_number(name: &str) -> Option<u64> {
    let digits = name.strip_prefix("frame-")?.strip_suffix(".depth.png")?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok()
}

/// Parses a 4x4 camera-to-world pose file into a translation and a unit
/// quaternion `[qx, qy, qz, qw]`.
pub(crate) fn parse_pose_file(path: &Path) -> Result<([f64; 3], [f64; 4]), ReadError> {
    parse_pose_text(path, &text::read_text(path)?)
}

/// [`parse_pose_file`] of the file's `content`, already read.
pub(crate) fn parse_pose_text(
    path: &Path,
    content: &str,
) -> Result<([f64; 3], [f64; 4]), ReadError> {
    let rows = text::square_rows(path, content, 4, "pose")?;
    let m: [[f64; 4]; 4] = std::array::from_fn(|r| std::array::from_fn(|c| rows[r].1[c]));
    matrix_pose(&m).map_err(|e| match e {
        MatrixPoseError::Pose(reason) => ReadError::Pose {
            path: path.to_path_buf(),
            line: rows[0].0,
            reason,
        },
        e @ MatrixPoseError::LastRow(_) => text::parse_error(path, rows[3].0, e.to_string()),
    })
}

/// Why a 4x4 camera-to-world matrix is not a pose.
#[derive(Debug)]
pub(crate) enum MatrixPoseError {
    /// Its rotation or translation, as the core checks a pose.
    Pose(placedb::CameraError),
    /// Its last row is not `0 0 0 1`.
    LastRow([f64; 4]),
}

impl std::fmt::Display for MatrixPoseError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MatrixPoseError::Pose(reason) => write!(f, "bad pose: {reason}"),
            MatrixPoseError::LastRow(row) => write!(
                f,
                "the last row of a 4x4 pose must be 0 0 0 1, found {row:?}"
            ),
        }
    }
}

/// A 4x4 camera-to-world matrix as a translation and a unit quaternion
/// `[qx, qy, qz, qw]`, checked as the core checks a pose (a 7-Scenes or
/// ScanNet pose file, frames handed over as arrays).
pub(crate) fn matrix_pose(m: &[[f64; 4]; 4]) -> Result<([f64; 3], [f64; 4]), MatrixPoseError> {
    let r: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| m[i][j]));
    let t = [m[0][3], m[1][3], m[2][3]];
    placedb::Pose::from_matrix(r.map(|row| row.map(|c| c as f32)), t.map(|c| c as f32))
        .map_err(MatrixPoseError::Pose)?;
    if m[3] != [0.0, 0.0, 0.0, 1.0] {
        return Err(MatrixPoseError::LastRow(m[3]));
    }
    let q = UnitQuaternion::from_matrix(&Matrix3::from_fn(|i, j| r[i][j]));
    Ok((t, [q.i, q.j, q.k, q.w]))
}

/// Reads a 7-Scenes sequence directory.
pub(crate) fn read(dir: &Path, opts: &ReadOptions) -> Result<Sequence, ReadError> {
    let names = text::list_dir(dir)?;
    let mut numbered: Vec<(u64, &String)> = names
        .iter()
        .filter_map(|n| frame_number(n).map(|k| (k, n)))
        .collect();
    numbered.sort();
    if let Some(w) = numbered.windows(2).find(|w| w[0].0 == w[1].0) {
        return Err(text::layout(
            dir,
            format!("{} and {} have the same frame number", w[0].1, w[1].1),
        ));
    }
    if numbered.is_empty() {
        return Err(text::layout(dir, "no frame-*.depth.png files"));
    }
    let present: HashSet<&str> = names.iter().map(String::as_str).collect();
    let mut without_depth: Vec<&String> = names
        .iter()
        .filter(|n| {
            n.strip_suffix(".pose.txt").is_some_and(|stem| {
                frame_number(&format!("{stem}.depth.png")).is_some()
                    && !present.contains(format!("{stem}.depth.png").as_str())
            })
        })
        .collect();
    without_depth.sort();
    if let Some(first) = without_depth.first() {
        let shown: Vec<&str> = without_depth.iter().take(10).map(|n| n.as_str()).collect();
        crate::warning::warn(format!(
            "{}: {} of {} frames have a pose file but no depth image ({}{}; from \
             {first}, the depth image of the same number is missing): skipped (a \
             frame's timestamp stays its frame number)",
            dir.display(),
            without_depth.len(),
            numbered.len() + without_depth.len(),
            shown.join(", "),
            if without_depth.len() > shown.len() {
                ", ..."
            } else {
                ""
            },
        ));
    }
    let camera = super::camera(dir, "camera-intrinsics.txt", Some(DEFAULT_CAMERA), opts)?;
    let mut frames = Vec::with_capacity(numbered.len());
    let mut paths = Vec::with_capacity(numbered.len());
    for (index, &(number, depth_name)) in numbered.iter().enumerate() {
        let stem = &depth_name[..depth_name.len() - ".depth.png".len()];
        let pose_name = format!("{stem}.pose.txt");
        if !present.contains(pose_name.as_str()) {
            return Err(text::layout(
                dir,
                format!("{depth_name} has no pose file (expected {pose_name})"),
            ));
        }
        let (translation, rotation) = parse_pose_file(&dir.join(&pose_name))?;
        let color_path = ["png", "jpg"]
            .iter()
            .map(|ext| format!("{stem}.color.{ext}"))
            .find(|n| present.contains(n.as_str()))
            .map(|n| dir.join(n));
        frames.push(FrameInfo {
            index,
            timestamp: number as f64,
            translation,
            rotation,
            depth_name: depth_name.clone(),
            color_path,
        });
        paths.push(dir.join(depth_name));
    }
    super::assemble(
        dir,
        Format::SevenScenes,
        camera,
        opts.depth_scale.unwrap_or(DEPTH_SCALE),
        super::Found {
            frames,
            clock: Clock::FrameNumbers {
                hz: crate::sequence::FRAME_NUMBER_HZ,
            },
            paths,
            skipped: without_depth.len(),
            pose_interpolation: None,
        },
        true,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_numbers() {
        assert_eq!(frame_number("frame-000012.depth.png"), Some(12));
        assert_eq!(frame_number("frame-7.depth.png"), Some(7));
        assert_eq!(frame_number("frame-000012.pose.txt"), None);
        assert_eq!(frame_number("frame-.depth.png"), None);
        assert_eq!(frame_number("frame-+1.depth.png"), None);
        assert_eq!(frame_number("xframe-000012.depth.png"), None);
    }

    #[test]
    fn pose_file_rotation_becomes_quaternion() {
        let p = std::env::temp_dir().join(format!(
            "placedb-read-7s-{}-frame-000000.pose.txt",
            std::process::id()
        ));
        // 90 degrees about z: x -> y.
        std::fs::write(&p, "0 -1 0 1\n1 0 0 2\n0 0 1 3\n0 0 0 1\n").unwrap();
        let (t, q) = parse_pose_file(&p).unwrap();
        assert_eq!(t, [1.0, 2.0, 3.0]);
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let expected = [0.0, 0.0, h, h];
        let same = q.iter().zip(expected).all(|(a, b)| (a - b).abs() < 1e-9);
        let opposite = q.iter().zip(expected).all(|(a, b)| (a + b).abs() < 1e-9);
        assert!(same || opposite, "{q:?}");
        std::fs::write(&p, "1 0 0 1\n0 1 0 2\n0 0 1 3\n0 0 1 1\n").unwrap();
        let e = parse_pose_file(&p).unwrap_err();
        assert!(matches!(e, ReadError::Parse { line: 4, .. }), "{e}");
        std::fs::remove_file(&p).ok();
    }
}
