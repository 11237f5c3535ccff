//! Sequence readers (TUM RGB-D, 7-Scenes, the reference code's layout,
//! ScanNet's export, ROS 2 and ROS 1 bags) and format detection.
//!
//! [`open`] reads a sequence directory's metadata (poses, timestamps,
//! intrinsics, the size of the first depth image) up front; depth images are
//! decoded on demand through [`Sequence::source`], which is cheap to share
//! between threads. Every error names the file, and for text files the 1-based
//! line, so a user can fix the input without reading code.
//!
//! | format | depth scale | intrinsics when the file is absent | timestamp |
//! |---|---|---|---|
//! | [`Format::Tum`] ([`tum`]) | 5000 | fx = fy = 525, cx = 319.5, cy = 239.5 for 640x480 images only (warned) | depth.txt's |
//! | [`Format::SevenScenes`] ([`sevenscenes`]) | 1000 | fx = fy = 585, cx = 320, cy = 240 | frame number |
//! | [`Format::Vprdb`] ([`vprdb`]) | 1000 | required (`intrinsics.txt`) | pose file's, else index |
//! | [`Format::Ros2`] ([`ros2`]) | 1000 | required (CameraInfo topic) | header stamp |
//! | [`Format::Ros1`] ([`ros2`], a `.bag` file) | 1000 | required (CameraInfo topic) | header stamp |
//! | [`Format::ScanNet`] ([`scannet`]) | 1000 | required (`intrinsic/intrinsic_depth.txt`) | frame number |
//!
//! [`ReadOptions`] overrides the depth scale and the intrinsics of any format
//! (the intrinsics file is then not read).

#[doc(hidden)]
pub mod arrays;
pub mod fuzzing;
mod png;
pub mod ros2;
pub mod scannet;
pub mod sevenscenes;
mod text;
pub mod timed_poses;
pub mod tum;
mod unfilter;
pub mod vprdb;

use crate::error::ReadError;
use crate::sequence::{CameraModel, Clock, DepthImage, Format, FrameInfo, Sequence};
use crate::warning::warn;
use std::path::{Path, PathBuf};

/// How to read a sequence; `Default` detects the format and uses its defaults.
#[derive(Debug, Clone, Default)]
pub struct ReadOptions {
    /// The layout; detected with [`detect`] when `None`.
    pub format: Option<Format>,
    /// Depth units per metre, replacing the format's default.
    pub depth_scale: Option<f64>,
    /// Intrinsics, replacing the sequence's file and the format's default.
    pub intrinsics: Option<CameraModel>,
    /// ROS 2 and ROS 1 bags: which topics to read.
    pub ros2: ros2::Ros2Options,
    /// TUM and ROS 2 and ROS 1 bags: how a frame takes its pose from the pose
    /// source's samples.
    pub pose_interpolation: timed_poses::PoseInterpolation,
}

/// Reads the sequence in directory (or bag file) `path`, detecting its format when
/// `opts.format` is `None`.
pub fn open(path: &Path, opts: &ReadOptions) -> Result<Sequence, ReadError> {
    if let Some(scale) = opts.depth_scale {
        if !(scale.is_finite() && scale > 0.0) {
            return Err(text::layout(
                path,
                format!("depth scale override must be finite and > 0, got {scale}"),
            ));
        }
    }
    if let Some(k) = &opts.intrinsics {
        check_camera(k).map_err(|reason| {
            text::layout(
                path,
                format!(
                    "intrinsics override fx {} fy {} cx {} cy {}: {reason}",
                    k.fx, k.fy, k.cx, k.cy
                ),
            )
        })?;
    }
    let format = match opts.format {
        Some(f) => f,
        None => detect(path)?,
    };
    match format {
        Format::Tum => tum::read(path, opts),
        Format::SevenScenes => sevenscenes::read(path, opts),
        Format::Vprdb => vprdb::read(path, opts),
        Format::Ros2 => ros2::read(path, opts, Format::Ros2),
        Format::Ros1 => ros2::read(path, opts, Format::Ros1),
        Format::ScanNet => scannet::read(path, opts),
        Format::Synthetic => Err(text::layout(
            path,
            "the synthetic format is rendered, not read from a directory",
        )),
        Format::Arrays => Err(text::layout(
            path,
            "frames from arrays are handed over in memory, not read from a directory",
        )),
    }
}

/// Recognises the layout of `path`: a ROS 2 bag if it is a `.mcap` or `.db3`
/// file or a directory with `metadata.yaml`, `*.mcap` or `*.db3`; a ROS 1
/// bag if it is a `.bag` file; 7-Scenes if it holds `frame-*.depth.png`
/// files, TUM if it holds `depth.txt` and `groundtruth.txt`, ScanNet's
/// export if it has `depth/` and `pose/` directories, the reference layout
/// if it has a `depth/` directory and `poses.txt` (or a `depth/` directory
/// and neither `depth.txt` nor `pose/`: TUM and ScanNet keep their images in
/// `depth/` too). A directory that looks like two layouts is
/// an error naming both, since guessing would read the wrong frames.
pub fn detect(path: &Path) -> Result<Format, ReadError> {
    let meta = std::fs::metadata(path).map_err(|source| ReadError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    if !meta.is_dir() {
        if ros2::looks_like_bag(path) {
            return Ok(Format::Ros2);
        }
        if ros2::looks_like_ros1_bag(path) {
            return Ok(Format::Ros1);
        }
        return Err(text::layout(
            path,
            "not a directory (nor a .mcap, .db3 or .bag file)",
        ));
    }
    let names = text::list_dir(path)?;
    let has = |name: &str| names.iter().any(|n| n == name);
    let mut found: Vec<(Format, &str)> = Vec::new();
    if ros2::looks_like_bag(path) {
        found.push((Format::Ros2, "ros2 (metadata.yaml, *.mcap or *.db3)"));
    }
    if names.iter().any(|n| sevenscenes::frame_number(n).is_some()) {
        found.push((Format::SevenScenes, "7scenes (frame-*.depth.png)"));
    }
    if has("depth.txt") && has("groundtruth.txt") {
        found.push((Format::Tum, "tum (depth.txt and groundtruth.txt)"));
    }
    let scannet = scannet::looks_like_scannet(path);
    if scannet {
        found.push((Format::ScanNet, "scannet (depth/ and pose/ directories)"));
    }
    if path.join("depth").is_dir() && (has("poses.txt") || !(has("depth.txt") || scannet)) {
        found.push((Format::Vprdb, "vprdb (a depth/ directory and poses.txt)"));
    }
    match found.as_slice() {
        [(format, _)] => Ok(*format),
        [] => Err(text::layout(
            path,
            "unknown sequence layout: looked for frame-*.depth.png (7scenes), \
             depth.txt and groundtruth.txt (tum), depth/ and pose/ directories \
             (scannet), a depth/ directory (vprdb), metadata.yaml, *.mcap or *.db3 (ros2)",
        )),
        several => Err(text::layout(
            path,
            format!(
                "the directory looks like {}: choose one with --format",
                several
                    .iter()
                    .map(|(_, what)| *what)
                    .collect::<Vec<_>>()
                    .join(" and also like ")
            ),
        )),
    }
}

/// Decodes a 16-bit greyscale depth PNG as stored (no value mapping).
/// A truncated, corrupt, 8-bit or colour file is a [`ReadError::Png`] naming it.
pub fn decode_depth_png(path: &Path) -> Result<DepthImage, ReadError> {
    png::decode(path, false)
}

/// Parses a 3x3 pinhole matrix `K = [fx 0 cx; 0 fy cy; 0 0 1]` written as three
/// lines of three white-space separated numbers, or the one line
/// `fx fy cx cy` (blank and `#` lines are skipped). The structural zeros and
/// the 1 must be there (a transposed matrix is refused), skew is not
/// supported, and fx, fy must be finite and > 0. Anything else is an error
/// naming the file and line.
pub fn parse_intrinsics_file(path: &Path) -> Result<CameraModel, ReadError> {
    let content = text::read_text(path)?;
    let mut rows: Vec<(usize, Vec<f64>)> = Vec::with_capacity(3);
    let mut last_line = 1;
    // A one-line `fx fy cx cy`, and the line it was on.
    let mut one_line: Option<(usize, Vec<f64>)> = None;
    for (line, l) in text::data_lines(&content) {
        if let Some((first, _)) = &one_line {
            return Err(text::parse_error(
                path,
                line,
                format!("line {first} gave the intrinsics as one line `fx fy cx cy`: nothing may follow it"),
            ));
        }
        if rows.is_empty() {
            let first = text::numbers(
                path,
                line,
                l,
                &[3, 4],
                "a row of the 3x3 matrix K, or the one line `fx fy cx cy`",
            )?;
            if first.len() == 4 {
                if let Some(c) = first.iter().position(|v| !v.is_finite()) {
                    return Err(text::parse_error(
                        path,
                        line,
                        format!("column {}: {} is not finite", c + 1, first[c]),
                    ));
                }
                one_line = Some((line, first));
                continue;
            }
        }
        if rows.len() == 3 {
            return Err(text::parse_error(
                path,
                line,
                "more than 3 rows in a 3x3 intrinsics matrix",
            ));
        }
        let row = text::numbers(path, line, l, &[3], "a row of the 3x3 matrix K")?;
        if let Some(c) = row.iter().position(|v| !v.is_finite()) {
            return Err(text::parse_error(
                path,
                line,
                format!("column {}: {} is not finite", c + 1, row[c]),
            ));
        }
        rows.push((line, row));
        last_line = line;
    }
    if let Some((line, v)) = one_line {
        let model = CameraModel {
            fx: v[0],
            fy: v[1],
            cx: v[2],
            cy: v[3],
        };
        check_camera(&model).map_err(|reason| text::parse_error(path, line, reason))?;
        return Ok(model);
    }
    if rows.len() < 3 {
        return Err(text::parse_error(
            path,
            last_line,
            format!("a 3x3 intrinsics matrix has 3 rows, found {}", rows.len()),
        ));
    }
    let k = |r: usize, c: usize| rows[r].1[c];
    let expect = |r: usize, c: usize, want: f64| -> Result<(), ReadError> {
        if (k(r, c) - want).abs() > 1e-9 {
            return Err(text::parse_error(
                path,
                rows[r].0,
                format!(
                    "K[{r}][{c}] is {}, expected {want} in [fx 0 cx; 0 fy cy; 0 0 1]",
                    k(r, c)
                ),
            ));
        }
        Ok(())
    };
    expect(0, 1, 0.0)?;
    expect(1, 0, 0.0)?;
    expect(2, 0, 0.0)?;
    expect(2, 1, 0.0)?;
    expect(2, 2, 1.0)?;
    let model = CameraModel {
        fx: k(0, 0),
        fy: k(1, 1),
        cx: k(0, 2),
        cy: k(1, 2),
    };
    check_camera(&model).map_err(|reason| text::parse_error(path, rows[0].0, reason))?;
    Ok(model)
}

/// Why a camera model cannot back-project, if it cannot.
pub(crate) fn check_camera(k: &CameraModel) -> Result<(), String> {
    let finite = [k.fx, k.fy, k.cx, k.cy].iter().all(|v| v.is_finite());
    if !finite {
        return Err("intrinsics must be finite".into());
    }
    if k.fx <= 0.0 || k.fy <= 0.0 {
        return Err(format!(
            "focal lengths must be > 0, got fx {} fy {}",
            k.fx, k.fy
        ));
    }
    Ok(())
}

/// The camera of a sequence: the override, else `dir/file` when it exists,
/// else `default` with a warning naming it (a default is never silent), else
/// an error naming the file.
fn camera(
    dir: &Path,
    file: &str,
    default: Option<CameraModel>,
    opts: &ReadOptions,
) -> Result<CameraModel, ReadError> {
    match (given_camera(dir, file, opts)?, default) {
        (Some(k), _) => Ok(k),
        (None, Some(k)) => {
            warn(format!(
                "{}: no {file}: using the format's default intrinsics fx = {}, fy = {}, \
                 cx = {}, cy = {} (write {file} or give --intrinsics fx,fy,cx,cy when they \
                 differ)",
                dir.display(),
                k.fx,
                k.fy,
                k.cx,
                k.cy
            ));
            Ok(k)
        }
        (None, None) => Err(text::layout(
            &dir.join(file),
            "intrinsics file missing: write it (3x3 K) or give --intrinsics fx,fy,cx,cy",
        )),
    }
}

/// The camera the user gave: the override, else `dir/file` when it exists.
fn given_camera(
    dir: &Path,
    file: &str,
    opts: &ReadOptions,
) -> Result<Option<CameraModel>, ReadError> {
    if let Some(k) = opts.intrinsics {
        return Ok(Some(k));
    }
    let path = dir.join(file);
    if path.exists() {
        return parse_intrinsics_file(&path).map(Some);
    }
    Ok(None)
}

/// The frames a file-based reader found: frame `i` has depth PNG
/// `paths[i]`; `skipped` source frames were left out with a warning.
struct Found {
    frames: Vec<FrameInfo>,
    /// What the frames' timestamps count.
    clock: Clock,
    paths: Vec<PathBuf>,
    skipped: usize,
    /// How the frames took their poses, for layouts with timed poses.
    pose_interpolation: Option<timed_poses::PoseInterpolation>,
}

/// Width and height of the first depth image of `paths` (read from its
/// header); no image at all is an error about `dir`.
fn first_size(dir: &Path, paths: &[PathBuf]) -> Result<(u16, u16), ReadError> {
    let first = paths
        .first()
        .ok_or_else(|| text::layout(dir, "the sequence has no depth frames"))?;
    png::depth_png_size(first)
}

/// Assembles a sequence from what a file-based reader found; the size is
/// read from the first image's header.
fn assemble(
    dir: &Path,
    format: Format,
    camera: CameraModel,
    depth_scale: f64,
    found: Found,
    invalid_65535: bool,
) -> Result<Sequence, ReadError> {
    let Found {
        frames,
        clock,
        paths,
        skipped,
        pose_interpolation,
    } = found;
    debug_assert_eq!(frames.len(), paths.len());
    let size = first_size(dir, &paths)?;
    Ok(Sequence {
        name: text::dir_name(dir),
        root: Some(dir.to_path_buf()),
        format,
        camera,
        depth_scale,
        size,
        frames,
        clock,
        frames_skipped: skipped,
        pose_interpolation,
        source: Box::new(png::PngDepthSource {
            paths,
            invalid_65535,
        }),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_file(name: &str, content: &str) -> PathBuf {
        let p =
            std::env::temp_dir().join(format!("placedb-read-mod-{}-{name}", std::process::id()));
        std::fs::write(&p, content).unwrap();
        p
    }

    #[test]
    fn intrinsics_parse_and_refusals() {
        let p = temp_file("k-ok.txt", "# K\n500 0 320\n0 501 240\n\n0 0 1");
        let k = parse_intrinsics_file(&p).unwrap();
        assert_eq!(
            k,
            CameraModel {
                fx: 500.0,
                fy: 501.0,
                cx: 320.0,
                cy: 240.0
            }
        );
        std::fs::remove_file(&p).ok();

        // The one line `fx fy cx cy`, after a comment.
        let p = temp_file("k-one-line.txt", "# fx fy cx cy\n500 501 320 240\n");
        assert_eq!(parse_intrinsics_file(&p).unwrap(), k);
        std::fs::remove_file(&p).ok();

        for (name, content, line, needle) in [
            ("k-short.txt", "500 0 320\n0 501 240\n", 2, "found 2"),
            ("k-five.txt", "500 501 320 240 1\n", 1, "3 or 4"),
            (
                "k-one-line-more.txt",
                "500 501 320 240\n0 0 1\n",
                2,
                "one line `fx fy cx cy`",
            ),
            ("k-one-line-neg.txt", "500 -501 320 240\n", 1, "> 0"),
            ("k-one-line-inf.txt", "500 501 inf 240\n", 1, "not finite"),
            (
                "k-long.txt",
                "500 0 320\n0 501 240\n0 0 1\n1 2 3\n",
                4,
                "more than 3",
            ),
            ("k-cols.txt", "500 0 320\n0 501\n0 0 1\n", 2, "found 2"),
            (
                "k-transposed.txt",
                "500 0 0\n0 501 0\n320 240 1\n",
                3,
                "K[2][0]",
            ),
            ("k-neg.txt", "-500 0 320\n0 501 240\n0 0 1\n", 1, "> 0"),
            (
                "k-nan.txt",
                "500 0 320\n0 nan 240\n0 0 1\n",
                2,
                "not finite",
            ),
            (
                "k-word.txt",
                "500 0 320\n0 fy 240\n0 0 1\n",
                2,
                "not a number",
            ),
        ] {
            let p = temp_file(name, content);
            let e = parse_intrinsics_file(&p).unwrap_err();
            let msg = e.to_string();
            assert!(
                matches!(e, ReadError::Parse { line: l, .. } if l == line),
                "{name}: {msg}"
            );
            assert!(msg.contains(name) && msg.contains(needle), "{name}: {msg}");
            std::fs::remove_file(&p).ok();
        }
    }
}
