//! What the core's refusals mean, in words for a user: the `Display` of
//! [`CameraError`], [`FrameError`], [`SelectError`], and of the flash log's
//! and a restore's failures ([`LogError`], [`FlashErrorKind`],
//! [`RestoreError`], [`RestoreFailure`]), so that no tool built on the core
//! has to show a variant name or word them itself. Each says what is wrong
//! and, where the core knows it, the accepted range; the tools add the
//! file, frame or option it is about. (The protocol's `ErrorKind` is worded
//! beside it: its words go on the wire's side too.)

use crate::camera::{CameraError, FrameProjector, Intrinsics};
use crate::device::RestoreFailure;
use crate::frame::FrameError;
use crate::persist::{FlashErrorKind, LogError};
use crate::select::{RestoreError, SelectError};
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

impl fmt::Display for FlashErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            FlashErrorKind::NotAligned => "an access not aligned to its granularity",
            FlashErrorKind::OutOfBounds => "an access outside it",
            FlashErrorKind::Other => "a driver failure",
        })
    }
}

impl fmt::Display for LogError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LogError::Flash(kind) => write!(f, "the flash reported an error ({kind})"),
            LogError::BadRange => f.write_str(
                "the log's region is not whole sectors, or fewer than two, or the flash's \
                 granularity is not supported",
            ),
            LogError::TooLarge => f.write_str("a record is longer than the log can hold"),
            LogError::Full => f.write_str("the log has no sector left"),
            LogError::NotStarted => f.write_str("the log holds no scan (no live generation)"),
            LogError::NoRecord => f.write_str("the log has no record at that place"),
        }
    }
}

impl core::error::Error for LogError {}

/// Said of a record a restore step refused, so that [`RestoreFailure`] can
/// name the record before it.
impl fmt::Display for RestoreError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RestoreError::NotConfigured => f.write_str("it comes before any scan configuration"),
            RestoreError::NotBetweenScans => {
                f.write_str("it comes while frames are open or undecided")
            }
            RestoreError::DatabaseFull => {
                f.write_str("the database is full (the scan needs a larger capacity profile)")
            }
            RestoreError::Duplicate => f.write_str("its frame is in the database already"),
            RestoreError::WrongIndex { expected } => {
                write!(
                    f,
                    "it decides another frame than the next, frame {expected}"
                )
            }
            RestoreError::BadDecision => {
                f.write_str("its decision names a frame that is not in the database")
            }
            RestoreError::NotStored => f.write_str("its frame is not in the store"),
        }
    }
}

impl core::error::Error for RestoreError {}

impl fmt::Display for RestoreFailure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RestoreFailure::Log(e) => write!(f, "the flash log cannot be read: {e}"),
            RestoreFailure::Malformed { record } => write!(
                f,
                "record {record} of the flash log is not a record of this format, or may not \
                 follow the records before it"
            ),
            RestoreFailure::Refused { record, error } => write!(
                f,
                "record {record} of the flash log does not fit the scan before it: {error}"
            ),
            RestoreFailure::BadConfig { record } => write!(
                f,
                "record {record} of the flash log holds a configuration this device refuses"
            ),
        }
    }
}

impl core::error::Error for RestoreFailure {}

#[cfg(test)]
mod tests {
    use super::*;
    use std::string::{String, ToString};

    #[test]
    fn every_failure_is_a_sentence_without_a_variant_name() {
        let all: [String; 6] = [
            RestoreFailure::Log(LogError::BadRange).to_string(),
            RestoreFailure::Log(LogError::Flash(FlashErrorKind::OutOfBounds)).to_string(),
            RestoreFailure::Malformed { record: 3 }.to_string(),
            RestoreFailure::Refused {
                record: 4,
                error: RestoreError::WrongIndex { expected: 9 },
            }
            .to_string(),
            RestoreFailure::BadConfig { record: 0 }.to_string(),
            LogError::Full.to_string(),
        ];
        for text in all {
            assert!(
                !text.contains("Bad") && !text.contains("Wrong") && !text.contains('{'),
                "{text}"
            );
        }
        assert_eq!(
            RestoreFailure::Log(LogError::Flash(FlashErrorKind::NotAligned)).to_string(),
            "the flash log cannot be read: the flash reported an error (an access not \
             aligned to its granularity)"
        );
    }
}
