//! placedb core: voxelize streamed depth frames and keep a dominating-set
//! place-recognition database online, inside fixed memory budgets.
//!
//! `no_std`, no heap, no `unsafe`: every capacity is a const generic or a
//! named profile, and every fallible step returns a typed error instead of
//! panicking. The host tools and every board run this very crate, so the
//! decisions a device makes can be replayed bit for bit on a workstation.
//!
//! # The layers
//!
//! The crate is built in layers, bottom up; a frame travels up through them
//! (`docs/ARCHITECTURE.md` follows it function by function).
//!
//! ## Geometry
//!
//! [`camera`] holds the pinhole model, poses and the fixed-point projection
//! of a sampled depth row into voxel keys ([`FrameProjector::project_row`],
//! integer only, so every CPU computes the same keys). [`voxel`] packs keys
//! and bounds one frame's voxel set ([`FrameVoxels`]); [`frame`] ingests one
//! frame: begun with its pose, fed rows in any chunking, ended into its
//! sorted set.
//!
//! ## Frame storage
//!
//! The key pool keeps the exact keys of the frames the selector holds, one
//! fixed array of 32-bit words relative to each frame's box; [`sketch`] has
//! the bottom-k MinHash sketches that stand in when keys do not fit.
//!
//! ## Selection
//!
//! [`select`] is the online dominating-set [`Selector`]: a window of
//! undecided frames, the database index in RAM, and the database frames in
//! a [`select::FrameStore`] (the flash log on a device); each frame is
//! decided when it leaves the window, and every exhausted capacity is a
//! counted degradation in its [`Status`].
//!
//! ## Formats
//!
//! [`protocol`] is the wire: postcard messages with a CRC-32, COBS-framed,
//! one terminal reply per host message. [`persist`] is the record log on
//! any `embedded-storage` NOR flash that survives a power cut at any
//! instant, and the records a device writes to it.
//!
//! ## The device
//!
//! [`device`] is the state machine every board runs: bytes in, reply frames
//! out; it makes each step durable before replying, exports, and restores
//! from its log at boot. [`profile`] names the capacity profiles (`ram256k`,
//! `ram512k`, `ram1m`): one selector and one device type per class of board.
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
#[cfg(test)]
mod test_rng;
pub mod voxel;
mod words;

pub use camera::{CameraError, DepthRange, FrameProjector, Intrinsics, Pose};
pub use frame::{FrameError, FrameMeta, ScanConfig};
pub use select::{
    DbRecord, Decision, FrameDecision, SelectError, Selector, SelectorConfig, Status,
};
pub use voxel::{FrameVoxels, VoxelGrid, VoxelKey};
