//! A training-ready dataset (`placedb select --dataset DIR`, `placedb export
//! --dataset DIR --sequence SEQ`): the frames of a selection in the
//! reference code's layout, with the class of every frame, for fine-tuning
//! and querying a VPR network (NetVLAD, CosPlace):
//!
//! ```text
//! DIR/
//!   color/NNNNNN.{png,jpg}  every labelled frame's colour image (when the sequence has colour)
//!   depth/NNNNNN.png        its depth, 16-bit PNG in millimetres (0 = no measurement)
//!   poses.txt               "timestamp tx ty tz qx qy qz qw" per frame, camera to world
//!                           (no timestamp when the sequence numbers its frames)
//!   intrinsics.txt          3x3 K
//!   classes.csv             name,index,timestamp,class_index,in_database
//!   database/               the database frames alone, same layout (its classes.csv: its frames)
//! ```
//!
//! `NNNNNN` is the frame's index in the sequence
//! ([`FrameInfo::index`](crate::sequence::FrameInfo::index): a
//! device's frames, cut from the sequence it was streamed, keep theirs), so
//! names sort in frame order and `DIR` and `DIR/database` read back as the
//! reference layout (`--format vprdb`). A frame's class is the index of the
//! database frame that covers it (itself for a database frame), as in
//! `labels.csv`.
//! A sequence that numbers its frames instead of stamping them (7-Scenes,
//! ScanNet: [`Clock::FrameNumbers`]) gets no timestamp column in
//! `poses.txt`: a frame number read back as seconds made `stream
//! --realtime` of the dataset replay at 1 frame/s and idle on every gap in
//! the numbering; without it the layout reads back as numbered, replayed
//! at the camera's rate by position. `classes.csv` keeps the frames'
//! numbers.
//! Colour files are copied as they are; colour held in the sequence itself
//! (a ROS 2 bag's colour topic) is written as PNG. When some frames have no
//! colour, `color/` is left out (the layout needs one per depth image).

use crate::error::OutputError;
use crate::picture::png::Samples;
use crate::sequence::{Clock, Sequence};
use rayon::prelude::*;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Depth units per metre of the layout's depth PNGs.
pub const DEPTH_SCALE: f64 = 1000.0;

/// The dataset's name in a refusal.
pub const DATASET: &str = "a dataset";

/// Whether `dir` holds an earlier dataset, which a run replaces whole: its
/// `classes.csv` and `poses.txt`.
pub fn is_dataset(dir: &Path) -> bool {
    dir.join("classes.csv").is_file() && dir.join("poses.txt").is_file()
}

/// Refuses, before the work, a target [`stage`] would refuse.
pub fn check(dir: &Path) -> Result<(), OutputError> {
    crate::output::replace::check_dir(dir, DATASET, is_dataset)
}

/// Writes the dataset (as [`write`]) as output `dir` of the run writing
/// `outputs`: it appears with the run's other outputs, or not at all.
pub fn stage(
    outputs: &mut crate::output::replace::Outputs,
    dir: &Path,
    seq: &Sequence,
    labels: &[usize],
) -> Result<DatasetSummary, OutputError> {
    let d = outputs.dir(dir, DATASET, is_dataset)?;
    write(&d, seq, labels)
}

/// What was written.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DatasetSummary {
    /// Labelled frames written.
    pub frames: usize,
    /// Database frames written (also under `database/`).
    pub database: usize,
    /// Whether `color/` was written.
    pub color: bool,
}

/// Where frame `i`'s colour comes from.
enum Color {
    File(PathBuf),
    Held,
}

/// Writes the dataset of `seq` labelled by `labels` (one class, a frame's
/// position in `seq`, per frame from 0; a device's export may hold fewer
/// frames than the sequence) into `dir`.
pub fn write(dir: &Path, seq: &Sequence, labels: &[usize]) -> Result<DatasetSummary, OutputError> {
    if labels.len() > seq.frames.len() {
        return Err(OutputError::Mismatch(format!(
            "{} labels for a sequence of {} frames",
            labels.len(),
            seq.frames.len()
        )));
    }
    if let Some((i, &c)) = labels
        .iter()
        .enumerate()
        .find(|&(_, &c)| c >= labels.len() || labels[c] != c)
    {
        return Err(OutputError::Mismatch(format!(
            "frame {} has class {c}, which is not a database frame",
            seq.frames[i].index
        )));
    }
    let frames: Vec<usize> = (0..labels.len()).collect();
    let database: Vec<usize> = frames.iter().copied().filter(|&i| labels[i] == i).collect();
    // Colour for every frame, or none at all.
    let mut colors = Vec::with_capacity(frames.len());
    for &i in &frames {
        colors.push(match &seq.frames[i].color_path {
            Some(p) => Some(Color::File(p.clone())),
            None if seq.source.color(i)?.is_some() => Some(Color::Held),
            None => None,
        });
    }
    let color = !colors.is_empty() && colors.iter().all(Option::is_some);
    let database_dir = dir.join("database");
    for d in [dir, &database_dir] {
        std::fs::create_dir_all(d.join("depth")).map_err(OutputError::writing(d))?;
        if color {
            std::fs::create_dir_all(d.join("color")).map_err(OutputError::writing(d))?;
        }
    }
    // Named by its number in the sequence, not its position in `seq`.
    let name = |i: usize| format!("{:06}", seq.frames[i].index);
    frames
        .par_iter()
        .try_for_each(|&i| -> Result<(), OutputError> {
            let in_db = labels[i] == i;
            let targets: Vec<&Path> = if in_db {
                vec![dir, &database_dir]
            } else {
                vec![dir]
            };
            let depth = seq.depth(i)?;
            let mm: Vec<u16> = depth
                .data
                .iter()
                .map(|&v| {
                    let m = (f64::from(v) * DEPTH_SCALE / seq.depth_scale).round();
                    if m > 0.0 && m <= f64::from(u16::MAX) {
                        m as u16
                    } else {
                        0
                    }
                })
                .collect();
            for t in &targets {
                let path = t.join("depth").join(format!("{}.png", name(i)));
                let (w, h) = (u32::from(depth.width), u32::from(depth.height));
                write_png(&path, w, h, Samples::Grey16(&mm))?;
            }
            if color {
                match &colors[i] {
                    Some(Color::File(src)) => {
                        let ext = src.extension().and_then(|e| e.to_str()).unwrap_or("png");
                        for t in &targets {
                            let path = t.join("color").join(format!("{}.{ext}", name(i)));
                            std::fs::copy(src, &path).map_err(|e| OutputError::Write {
                                source: std::io::Error::new(
                                    e.kind(),
                                    format!(
                                        "copying {}: {}",
                                        src.display(),
                                        crate::error::io_words(&e)
                                    ),
                                ),
                                path: path.clone(),
                            })?;
                        }
                    }
                    _ => {
                        let img = seq.source.color(i)?.ok_or_else(|| {
                            OutputError::Mismatch(format!("{}: colour vanished", name(i)))
                        })?;
                        for t in &targets {
                            let path = t.join("color").join(format!("{}.png", name(i)));
                            write_png(&path, img.width, img.height, Samples::Rgb8(&img.rgb))?;
                        }
                    }
                }
            }
            Ok(())
        })?;
    let k = &seq.camera;
    let intrinsics = format!("{} 0 {}\n0 {} {}\n0 0 1\n", k.fx, k.cx, k.fy, k.cy);
    let poses = |which: &[usize]| {
        let mut s = String::new();
        for &i in which {
            let f = &seq.frames[i];
            let [tx, ty, tz] = f.translation;
            let [qx, qy, qz, qw] = f.rotation;
            if let Clock::Seconds = seq.clock {
                let _ = write!(s, "{:.6} ", f.timestamp);
            }
            let _ = writeln!(s, "{tx} {ty} {tz} {qx} {qy} {qz} {qw}");
        }
        s
    };
    let classes = |which: &[usize]| {
        let mut s = String::from("name,index,timestamp,class_index,in_database\n");
        for &i in which {
            let _ = writeln!(
                s,
                "{},{},{:.6},{},{}",
                name(i),
                seq.frames[i].index,
                seq.frames[i].timestamp,
                seq.frames[labels[i]].index,
                u8::from(labels[i] == i)
            );
        }
        s
    };
    for (d, which) in [(dir, &frames), (&database_dir, &database)] {
        for (file, text) in [
            ("poses.txt", poses(which)),
            ("intrinsics.txt", intrinsics.clone()),
            ("classes.csv", classes(which)),
        ] {
            let path = d.join(file);
            std::fs::write(&path, text).map_err(OutputError::writing(&path))?;
        }
    }
    Ok(DatasetSummary {
        frames: frames.len(),
        database: database.len(),
        color,
    })
}

/// Writes `path` with the one PNG writer ([`crate::picture::png`]).
fn write_png(
    path: &Path,
    width: u32,
    height: u32,
    samples: Samples<'_>,
) -> Result<(), OutputError> {
    crate::picture::png::write(path, width, height, samples).map_err(OutputError::writing(path))
}
