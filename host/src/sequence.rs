//! An RGB-D sequence as the host tools see it: per-frame metadata and poses up
//! front, depth images decoded on demand (a 20,000-frame scan does not fit in
//! memory), whatever the source: files on disk or the built-in renderer.

use crate::error::ReadError;
use crate::picture::Image;
use std::path::PathBuf;

/// A decoded depth image: row-major `u16`, 0 = no measurement.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct DepthImage {
    /// Width in pixels.
    pub width: u16,
    /// Height in pixels.
    pub height: u16,
    /// `width * height` depth values, row after row.
    pub data: Vec<u16>,
}

impl DepthImage {
    /// Row `v` of the image.
    pub fn row(&self, v: u16) -> &[u16] {
        let w = self.width as usize;
        &self.data[v as usize * w..(v as usize + 1) * w]
    }
}

/// Pinhole intrinsics in the sequence's own precision (pixels).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraModel {
    /// Focal length x.
    pub fx: f64,
    /// Focal length y.
    pub fy: f64,
    /// Principal point x.
    pub cx: f64,
    /// Principal point y.
    pub cy: f64,
}

/// One frame's metadata: everything but the pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameInfo {
    /// Position in the sequence as read, from 0: the frame's number, which
    /// the outputs name it by (`labels.csv`, the dataset, the exports). A
    /// sequence cut to the frames a device received
    /// ([`Sequence::keep_frames`]) keeps each frame's number.
    pub index: usize,
    /// Seconds; the index when the format has no timestamps.
    pub timestamp: f64,
    /// Camera-to-world translation, metres.
    pub translation: [f64; 3],
    /// Camera-to-world rotation as `[qx, qy, qz, qw]`, unit norm.
    pub rotation: [f64; 4],
    /// Where the depth comes from, for messages ("frame-000012.depth.png").
    pub depth_name: String,
    /// Colour image of the same frame, when the format has one.
    pub color_path: Option<PathBuf>,
}

impl FrameInfo {
    /// The pose in the core's form (checked again there).
    pub fn pose(&self) -> Result<placedb::Pose, placedb::CameraError> {
        let t = self.translation.map(|c| c as f32);
        let q = self.rotation.map(|c| c as f32);
        placedb::Pose::from_quaternion(t, q)
    }
}

/// How a frame takes its pose from a pose source sampled at its own times
/// (TUM's groundtruth, ROS pose topics and TF): `--pose-interpolation`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PoseInterpolation {
    /// Linear in position, spherical-linear in rotation, between the two
    /// samples around the frame's stamp.
    #[default]
    Linear,
    /// The sample nearest in time.
    Nearest,
}

/// Sequence layouts the readers understand.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// TUM RGB-D: depth.txt, rgb.txt, groundtruth.txt.
    Tum,
    /// Microsoft 7-Scenes: frame-XXXXXX.depth.png and .pose.txt.
    #[serde(rename = "7scenes")]
    SevenScenes,
    /// The reference code's layout: depth/, color/, poses file, intrinsics.txt.
    Vprdb,
    /// A ROS 2 recording (rosbag2, MCAP or sqlite3 storage): a bag folder,
    /// a `.mcap` or a `.db3` file.
    Ros2,
    /// A ROS 1 bag (format 2.0): a `.bag` file.
    Ros1,
    /// ScanNet's exported layout: depth/, pose/, color/, intrinsic/.
    #[serde(rename = "scannet")]
    ScanNet,
    /// The built-in synthetic renderer (`--demo`; not a layout to read, so
    /// `--format` does not offer it).
    Synthetic,
    /// Frames handed over in memory (the Python package's arrays,
    /// [`crate::read::arrays`]); not a layout to read either.
    Arrays,
}

/// What [`FrameInfo::timestamp`] counts, so a replay at the camera's rate
/// (`placedb stream --realtime`) knows the camera's clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Clock {
    /// Seconds the camera stamped each frame with (TUM's depth.txt, a ROS 2
    /// header stamp, the reference layout's poses file with a timestamp
    /// column, the synthetic camera's 30 Hz).
    Seconds,
    /// Frame numbers or positions, no time (7-Scenes, the reference layout
    /// without a timestamp column): the camera ran at `hz` frames per second.
    FrameNumbers {
        /// The layout's camera rate (7-Scenes' Kinect: 30).
        hz: f64,
    },
}

/// The rate of a layout that numbers its frames instead of stamping them:
/// 7-Scenes was recorded with a Kinect at 30 frames per second.
pub const FRAME_NUMBER_HZ: f64 = 30.0;

/// Produces the depth image of frame `i` on demand.
pub trait DepthSource: Send + Sync {
    /// Decodes (or renders) frame `i`'s depth.
    fn depth(&self, i: usize) -> Result<DepthImage, ReadError>;

    /// [`Self::depth`] into an existing image, so a loop over frames can
    /// reuse one buffer; sources that can decode in place override it.
    fn depth_into(&self, i: usize, image: &mut DepthImage) -> Result<(), ReadError> {
        *image = self.depth(i)?;
        Ok(())
    }

    /// Frame `i`'s colour image when the source holds it itself (a ROS 2
    /// bag); `None` when it has none, or when colour is a file
    /// ([`FrameInfo::color_path`]).
    fn color(&self, _i: usize) -> Result<Option<Image>, ReadError> {
        Ok(None)
    }

    /// The file frame `i`'s depth is read from, when it is one file (a
    /// PNG of a file layout), so that a message names it with its
    /// directory; `None` for a bag or the renderer.
    fn depth_file(&self, _i: usize) -> Option<&std::path::Path> {
        None
    }
}

/// A sequence: metadata for every frame, camera, and a way to get depth.
pub struct Sequence {
    /// Human-readable name (directory name or "synthetic").
    pub name: String,
    /// The directory (or bag) it was read from, as the user gave it: a file
    /// layout's [`FrameInfo::color_path`]s are this joined with their paths
    /// in the layout, so that `--pairs` names them relative to it. `None`
    /// for the built-in renderer.
    pub root: Option<PathBuf>,
    /// Layout it was read from.
    pub format: Format,
    /// Camera intrinsics.
    pub camera: CameraModel,
    /// Depth units per metre (TUM 5000, 7-Scenes 1000).
    pub depth_scale: f64,
    /// Width and height shared by every depth image.
    pub size: (u16, u16),
    /// Every frame, in sequence order.
    pub frames: Vec<FrameInfo>,
    /// What the frames' timestamps count (seconds or frame numbers).
    pub clock: Clock,
    /// Frames of the source that the reader skipped with a warning (a depth
    /// image without a pose): `frames_skipped` of metrics.json.
    pub frames_skipped: usize,
    /// How the frames took their poses from timed samples; `None` where each
    /// frame comes with its own pose (7-Scenes, the reference layout, the
    /// built-in renderer).
    pub pose_interpolation: Option<PoseInterpolation>,
    /// Depth images on demand.
    pub source: Box<dyn DepthSource>,
}

impl Sequence {
    /// Depth of frame `i`, checked to have the sequence's size.
    pub fn depth(&self, i: usize) -> Result<DepthImage, ReadError> {
        let mut img = DepthImage::default();
        self.depth_into(i, &mut img)?;
        Ok(img)
    }

    /// [`Self::depth`] into an existing image, reusing its buffer.
    pub fn depth_into(&self, i: usize, img: &mut DepthImage) -> Result<(), ReadError> {
        self.source.depth_into(i, img)?;
        if (img.width, img.height) != self.size {
            return Err(ReadError::SizeMismatch {
                name: self.depth_where(i),
                expected: self.size,
                found: (img.width, img.height),
            });
        }
        Ok(())
    }

    /// Frame `i`'s depth in a message: its file with the directory when it
    /// is one file, else the reader's name for it (a bag's topic and stamp).
    pub fn depth_where(&self, i: usize) -> String {
        match self.source.depth_file(i) {
            Some(path) => path.display().to_string(),
            None => self.frames[i].depth_name.clone(),
        }
    }

    /// The sequence of only the frames at `positions` (ascending), in that
    /// order: the frames a device received of it (`placedb stream
    /// --realtime` skips frames). Each keeps its [`FrameInfo::index`], its
    /// number in the whole sequence, which the outputs name it by; its depth
    /// and colour are still read from where they were.
    pub fn keep_frames(mut self, positions: &[usize]) -> Sequence {
        if positions.iter().copied().eq(0..positions.len()) {
            // The first frames: their positions are their numbers.
            self.frames.truncate(positions.len());
            return self;
        }
        let frames = positions.iter().map(|&p| self.frames[p].clone()).collect();
        Sequence {
            frames,
            source: Box::new(Kept {
                whole: self.source,
                positions: positions.to_vec(),
            }),
            ..self
        }
    }

    /// The core's intrinsics for this sequence.
    pub fn intrinsics(&self) -> placedb::Intrinsics {
        placedb::Intrinsics {
            width: self.size.0,
            height: self.size.1,
            fx: self.camera.fx as f32,
            fy: self.camera.fy as f32,
            cx: self.camera.cx as f32,
            cy: self.camera.cy as f32,
        }
    }
}

/// The depth of the frames [`Sequence::keep_frames`] kept: frame `i` is
/// frame `positions[i]` of the whole sequence's source.
struct Kept {
    whole: Box<dyn DepthSource>,
    positions: Vec<usize>,
}

impl Kept {
    /// Where frame `i` is in the whole sequence.
    fn at(&self, i: usize) -> Result<usize, ReadError> {
        self.positions
            .get(i)
            .copied()
            .ok_or_else(|| ReadError::Layout {
                path: PathBuf::new(),
                reason: format!(
                    "frame {i} requested, {} frames of the sequence were kept",
                    self.positions.len()
                ),
            })
    }
}

impl DepthSource for Kept {
    fn depth(&self, i: usize) -> Result<DepthImage, ReadError> {
        self.whole.depth(self.at(i)?)
    }

    fn depth_into(&self, i: usize, image: &mut DepthImage) -> Result<(), ReadError> {
        self.whole.depth_into(self.at(i)?, image)
    }

    fn color(&self, i: usize) -> Result<Option<Image>, ReadError> {
        self.whole.color(self.at(i)?)
    }

    fn depth_file(&self, i: usize) -> Option<&std::path::Path> {
        self.whole.depth_file(self.at(i).ok()?)
    }
}

#[cfg(test)]
mod tests {
    use crate::synth::{self, SynthConfig};

    #[test]
    fn kept_frames_keep_their_numbers_and_their_depth() {
        let whole = || {
            let mut seq = synth::sequence(&SynthConfig::demo());
            seq.frames.truncate(6);
            seq
        };
        let kept = whole().keep_frames(&[0, 2, 5]);
        let numbers: Vec<usize> = kept.frames.iter().map(|f| f.index).collect();
        assert_eq!(numbers, [0, 2, 5]);
        assert_eq!(kept.frames[2], whole().frames[5]);
        assert_eq!(kept.depth(1).unwrap(), whole().depth(2).unwrap());
        assert!(kept.depth(3).is_err(), "only three frames were kept");
        // The first frames are the sequence cut short.
        let first = whole().keep_frames(&[0, 1]);
        assert_eq!(first.frames, whole().frames[..2]);
        assert_eq!(first.depth(1).unwrap(), whole().depth(1).unwrap());
    }
}
