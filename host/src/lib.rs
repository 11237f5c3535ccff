//! placedb host tools: sequence readers, the offline yardstick (exact overlap
//! graph, dominating-set solvers, baselines, metrics), replay of the core, and
//! the `placedb` command line built on them.

pub mod bench;
pub mod device;
pub mod error;
pub mod output;
pub mod pipeline;
pub mod read;
pub mod replay;
pub mod rng;
pub mod row_chunks;
pub mod sequence;
pub mod synth;
pub mod voxelize;
pub mod yardstick;

pub use error::ReadError;
pub use sequence::{CameraModel, ColorImage, DepthImage, DepthSource, Format, FrameInfo, Sequence};
pub use voxelize::{voxelize, voxelize_on, GridOrigin, VoxelConfig, VoxelSets};

// The paths of the flat layout, for code written against them.
pub use bench::{db_scaling as dbscale, pixel_cost as pixelcost};
pub use device::emulator::{foreground, rp2040};
pub use device::link::{self as link, fault};
pub use device::scan as device_cli;
pub use device::session;
pub use output::{dataset, topview as plot};
pub use replay as online;
pub(crate) use voxelize::key_cells;
pub use voxelize::frame_keys;
pub use yardstick::{graph, metrics, solve};
