//! placedb host tools: sequence readers, the offline yardstick (exact overlap
//! graph, dominating-set solvers, baselines, metrics), replay of the core, the
//! device client, and the `placedb` command line built on them.
//!
//! The folders are the jobs, and imports go one way, from the command line
//! down: [`cli`] (one file per subcommand) → [`device`] (session, scan and
//! export → client → link and emulators), [`pipeline`] (voxelize → yardstick
//! or replay) and [`bench`] → [`output`] (the one writer of a run's files),
//! [`read`] and [`synth`] (sequences in) → [`sequence`].

pub mod cli;
pub mod degradation;
pub mod device;
pub mod error;
pub mod frame_rows;
pub mod output;
pub mod picture;
pub mod pipeline;
pub mod read;
pub mod replay;
pub mod rng;
pub mod sequence;
pub mod sessions;
pub mod synth;
#[cfg(any(test, feature = "testing"))]
pub mod testing;
pub mod vector_unit;
pub mod voxelize;
pub mod warning;
pub mod yardstick;

pub use error::ReadError;
pub use sequence::{CameraModel, DepthImage, DepthSource, Format, FrameInfo, Sequence};
pub use voxelize::{voxelize, voxelize_on, GridOrigin, VoxelConfig, VoxelSets};
