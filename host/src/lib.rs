//! placedb host tools: sequence readers, the offline yardstick (exact overlap
//! graph, dominating-set solvers, baselines, metrics), replay of the core, and
//! the `placedb` command line built on them.

pub mod dataset;
pub mod dbscale;
pub mod device_cli;
pub mod error;
pub mod fault;
pub mod flash_timing;
pub mod foreground;
pub mod frame_keys;
pub mod graph;
pub(crate) mod key_cells;
pub mod link;
pub mod metrics;
pub mod online;
pub mod output;
pub mod pacing;
pub mod pipeline;
pub mod pixelcost;
pub mod plot;
pub mod read;
pub mod rng;
pub mod row_chunks;
pub mod rp2040;
pub mod sequence;
pub mod session;
pub mod solve;
pub mod synth;
pub mod voxelize;

pub use error::ReadError;
pub use sequence::{CameraModel, ColorImage, DepthImage, DepthSource, Format, FrameInfo, Sequence};
pub use voxelize::{voxelize, voxelize_on, GridOrigin, VoxelConfig, VoxelSets};
