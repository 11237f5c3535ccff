//! placedb core: voxelize streamed depth frames and keep a dominating-set
//! place-recognition database online, inside fixed memory budgets.
//!
//! `no_std`, no heap, no `unsafe`: every capacity is a const generic or a
//! named profile, and every fallible step returns a typed error instead of
//! panicking. The host tools and every board run this very crate, so the
//! decisions a device makes can be replayed bit for bit on a workstation.
#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]
// No panicking path on any input, checked rather than argued: every module
// of the core is under this block (tests may index and unwrap; the std-only
// test support, `persist::sim` and `device::harness`, opts out).
#![cfg_attr(
    not(test),
    deny(
        clippy::indexing_slicing,
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic
    )
)]

// Only the test flash (feature `sim-flash`) uses std.
#[cfg(feature = "sim-flash")]
extern crate std;

pub mod camera;
pub mod device;
pub mod frame;
pub mod key_pool;
pub mod persist;
pub mod profile;
pub mod protocol;
pub mod select;
pub mod sketch;
pub mod voxel;

pub use camera::{CameraError, DepthRange, FrameProjector, Intrinsics, Pose};
pub use frame::{FrameError, FrameMeta, ScanConfig};
pub use select::{
    DbRecord, Decision, FrameDecision, SelectError, Selector, SelectorConfig, Status,
};
pub use voxel::{FrameVoxels, VoxelGrid, VoxelKey};

/// The key pool's former path.
#[doc(hidden)]
pub use key_pool as store;
