//! A sequence handed over in memory (the Python package's numpy arrays):
//! a stack of depth images with a camera-to-world matrix and a time each,
//! checked as the file readers check theirs, so a bad pose or camera is
//! refused naming the frame.

use super::check_camera;
use super::sevenscenes::matrix_pose;
use crate::error::ReadError;
use crate::sequence::{CameraModel, Clock, DepthImage, DepthSource, Format, FrameInfo, Sequence};
use std::path::PathBuf;

/// Frames in memory: `depth` holds every image, row after row, image
/// after image.
struct Stack {
    width: u16,
    height: u16,
    depth: Vec<u16>,
}

impl DepthSource for Stack {
    fn depth(&self, i: usize) -> Result<DepthImage, ReadError> {
        let n = self.width as usize * self.height as usize;
        let data = self
            .depth
            .get(i * n..(i + 1) * n)
            .ok_or_else(|| ReadError::Layout {
                path: PathBuf::from("<arrays>"),
                reason: format!("frame {i} is not in the stack"),
            })?
            .to_vec();
        Ok(DepthImage {
            width: self.width,
            height: self.height,
            data,
        })
    }
}

/// What a sequence from memory is made of.
pub struct Arrays {
    /// The sequence's name, for messages and the top view.
    pub name: String,
    /// The camera (pixels).
    pub camera: CameraModel,
    /// Depth units per metre (1000 for millimetres).
    pub depth_scale: f64,
    /// Width and height of every image.
    pub size: (u16, u16),
    /// `frames * width * height` depth values.
    pub depth: Vec<u16>,
    /// Each frame's camera-to-world matrix, row-major.
    pub poses: Vec<[[f64; 4]; 4]>,
    /// Each frame's time, seconds; `None`: 30 frames per second.
    pub timestamps: Option<Vec<f64>>,
}

/// Why frame `i`'s input is refused.
fn refused(i: usize, reason: impl std::fmt::Display) -> ReadError {
    ReadError::Layout {
        path: PathBuf::from(format!("frame {i}")),
        reason: reason.to_string(),
    }
}

/// The sequence of `a`, every pose and the camera checked.
pub fn sequence(a: Arrays) -> Result<Sequence, ReadError> {
    let arrays = || PathBuf::from("<arrays>");
    check_camera(&a.camera).map_err(|reason| ReadError::Layout {
        path: arrays(),
        reason: format!("intrinsics: {reason}"),
    })?;
    let scales = placedb::FrameProjector::DEPTH_SCALE_RANGE;
    if !(f64::from(*scales.start())..=f64::from(*scales.end())).contains(&a.depth_scale) {
        return Err(ReadError::Layout {
            path: arrays(),
            reason: format!(
                "the depth scale must be from {} to {} units per metre (1000 for millimetres), got {}",
                scales.start(),
                scales.end(),
                a.depth_scale
            ),
        });
    }
    let n = a.poses.len();
    let pixels = a.size.0 as usize * a.size.1 as usize;
    if pixels == 0 || a.depth.len() != n * pixels {
        return Err(ReadError::Layout {
            path: arrays(),
            reason: format!(
                "{} depth values for {n} poses of {}x{} images",
                a.depth.len(),
                a.size.0,
                a.size.1
            ),
        });
    }
    if let Some(t) = &a.timestamps {
        if t.len() != n {
            return Err(ReadError::Layout {
                path: arrays(),
                reason: format!("{} timestamps for {n} poses", t.len()),
            });
        }
    }
    let mut frames = Vec::with_capacity(n);
    for (i, m) in a.poses.iter().enumerate() {
        let (t, rotation) = matrix_pose(m).map_err(|e| refused(i, e))?;
        let timestamp = match &a.timestamps {
            Some(t) if t[i].is_finite() => t[i],
            Some(t) => return Err(refused(i, format!("timestamp {} is not finite", t[i]))),
            None => i as f64 / crate::sequence::FRAME_NUMBER_HZ,
        };
        frames.push(FrameInfo {
            index: i,
            timestamp,
            translation: t,
            rotation,
            depth_name: format!("frame {i}"),
            color_path: None,
        });
    }
    Ok(Sequence {
        name: a.name,
        root: None,
        format: Format::Arrays,
        camera: a.camera,
        depth_scale: a.depth_scale,
        size: a.size,
        frames,
        clock: Clock::Seconds,
        frames_skipped: 0,
        pose_interpolation: None,
        source: Box::new(Stack {
            width: a.size.0,
            height: a.size.1,
            depth: a.depth,
        }),
    })
}
