//! What the core's refusals mean, in words for a user: the `Display` of
//! [`CameraError`], [`FrameError`] and [`SelectError`], so that no tool
//! built on the core has to show a variant name. Each says what is wrong
//! and, where the core knows it, the accepted range; the tools add the
//! file, frame or option it is about.

use crate::camera::{CameraError, FrameProjector, Intrinsics};
use crate::frame::FrameError;
use crate::select::SelectError;
use crate::voxel::VoxelGrid;
use core::fmt;

impl fmt::Display for CameraError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CameraError::BadIntrinsics => {
                let r = Intrinsics::FOCAL_RANGE;
                write!(
                    f,
                    "the intrinsics are out of range: focal lengths must be finite and from \
                     {} to {} pixels, the principal point finite and within an image side of \
                     the image",
                    r.start(),
                    r.end()
                )
            }
            CameraError::BadImageSize => write!(
                f,
                "the image size is zero or larger than {} pixels a side",
                Intrinsics::MAX_SIDE
            ),
            CameraError::BadDepthScale => {
                let r = FrameProjector::DEPTH_SCALE_RANGE;
                write!(
                    f,
                    "the depth scale must be from {} to {} units per metre",
                    r.start(),
                    r.end()
                )
            }
            CameraError::BadDepthRange => {
                f.write_str("the depth range must be min,max with 0 <= min < max (neither NaN)")
            }
            CameraError::BadStride => write!(
                f,
                "the pixel stride must be from 1 to {}",
                Intrinsics::MAX_SIDE
            ),
            CameraError::NonFinitePose => {
                f.write_str("a pose value is not a finite number (NaN or infinity)")
            }
            CameraError::NotARotation => f.write_str(
                "the rotation is not a rotation (not orthonormal, a reflection, or a \
                 quaternion far from unit length)",
            ),
            CameraError::BadVoxelSize => {
                let r = VoxelGrid::SIZE_RANGE;
                write!(
                    f,
                    "the voxel size must be from {} to {} m, and the grid origin finite",
                    r.start(),
                    r.end()
                )
            }
            CameraError::ScaleOutOfRange => f.write_str(
                "depth scale, voxel size, image size or camera position are too extreme for \
                 the fixed-point voxel keys (a camera thousands of kilometres from the origin, \
                 or a tiny voxel with a huge depth scale)",
            ),
        }
    }
}

impl core::error::Error for CameraError {}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FrameError::Camera(e) => e.fmt(f),
            FrameError::FrameInProgress => {
                f.write_str("a frame was begun while another one is in progress")
            }
            FrameError::NoFrame => f.write_str("rows or a frame end arrived with no frame begun"),
            FrameError::WrongIndex { expected } => {
                write!(f, "frames out of order: frame {expected} must come next")
            }
            FrameError::RowOutOfOrder { expected } => {
                write!(
                    f,
                    "rows out of order: sampled row {expected} must come next"
                )
            }
            FrameError::BadRowChunk => f.write_str(
                "a chunk of rows is not a whole number of sampled rows, or runs past the image",
            ),
            FrameError::MissingRows { received, expected } => write!(
                f,
                "the frame ended after {received} of its {expected} sampled rows"
            ),
        }
    }
}

impl core::error::Error for FrameError {}

impl fmt::Display for SelectError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SelectError::NotConfigured => {
                f.write_str("a frame arrived before the scan was configured")
            }
            SelectError::FrameInProgress => {
                f.write_str("the configuration cannot change while a frame is in progress")
            }
            SelectError::BadConfig => f.write_str(
                "the configuration is invalid: mu must be from 0 to below 1, the window at \
                 least 1, and the scan's camera, depth scale, range, stride and voxel grid \
                 valid (and the same for every frame of the scan)",
            ),
            SelectError::Frame(e) => e.fmt(f),
        }
    }
}

impl core::error::Error for SelectError {}
