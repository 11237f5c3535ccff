//! Several sessions into one database: a later session on top of an
//! earlier database (`placedb select SEQ --extend OUT`, docs/SESSIONS.md).
//! The earlier sessions come from `OUT`'s extension file ([`extension`]),
//! never from their sequences.
//!
//! The sessions share one world frame and one voxel grid, so a frame of
//! the new session is compared with the earlier database frames by their
//! voxel sets as with its own session's frames. Frames keep global
//! indices: the new session's are numbered from the count of every earlier
//! session's frames. The earlier database is kept whole; the solvers add
//! only what the new frames need ([`fixed`] for the offline solvers, the
//! online core seeded from the file by [`seed`]); [`measure`] scores every
//! session's frames; [`record`] makes the extension file of a run (every
//! `select` leaves one for the next session); [`run`] is the whole later
//! session, returning a plain outcome for the command to write and print.

mod config;
pub mod extension;
pub mod fixed;
pub mod measure;
pub mod record;
pub mod run;
pub mod seed;

pub use config::{check_config, grid_of};
