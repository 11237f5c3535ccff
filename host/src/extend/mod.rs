//! A later session on top of an earlier database (`placedb select SEQ
//! --extend OUT`): the earlier sessions come from `OUT`'s extension file
//! ([`crate::output::extension`]), never from their sequences.
//!
//! The sessions share one world frame and one voxel grid, so a frame of
//! the new session is compared with the earlier database frames by their
//! voxel sets as with its own session's frames. Frames keep global
//! indices: the new session's are numbered from the count of every earlier
//! session's frames. The earlier database is kept whole; the solvers add
//! only what the new frames need ([`fixed`] for the offline solvers, the
//! online core seeded by [`crate::replay::seed`]); [`measure`] scores every
//! session's frames; [`record`] writes the extension file of the result.

mod config;
pub mod fixed;
pub mod measure;
pub mod record;

pub use config::{check_config, grid_of};
