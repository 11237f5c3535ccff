//! placedb host tools: sequence readers, the offline yardstick (exact overlap
//! graph, dominating-set solvers, baselines, metrics), replay of the core, and
//! the `placedb` command line built on them.

pub mod error;
pub mod read;
pub mod sequence;
pub mod voxelize;

pub use error::ReadError;
pub use sequence::{CameraModel, DepthImage, DepthSource, FrameInfo, Format, Sequence};
pub use voxelize::{voxelize, GridOrigin, VoxelConfig, VoxelSets};
