//! placedb host tools: sequence readers, the offline yardstick (exact overlap
//! graph, dominating-set solvers, baselines, metrics), replay of the core, the
//! client of a board, and the `placedb` command line built on them.
//!
//! The folders are the jobs, in layers that import only downward
//! (docs/ARCHITECTURE.md; `host/tests/layers.rs` checks it): [`cli`] (each
//! command's arguments, printing and orchestration) → [`board`] (the client
//! of the device on a board: session, scan and export → client → link and
//! emulators) → [`sessions`] (a later session on an earlier database) →
//! [`output`] (the one writer of a run's files) → [`pipeline`] (voxelize →
//! yardstick or replay) → [`replay`], [`yardstick`], [`voxelize`] → the
//! readers ([`read`], [`synth`]) → [`sequence`] and the small shared parts
//! ([`picture`], [`vector_unit`], [`rng`], [`error`], [`warning`]).

pub mod board;
pub mod cli;
pub mod degradation;
pub mod error;
pub mod frame_rows;
pub mod interrupt;
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
pub use sequence::{CameraModel, Clock, DepthImage, DepthSource, Format, FrameInfo, Sequence};
pub use voxelize::{voxelize, voxelize_on, GridOrigin, VoxelConfig, VoxelSets};
