//! The one warning printer: every warning the tools give (a reader's
//! default taken or frame skipped, what a run lost, a large voxel set, an
//! earlier output that could not be removed) is printed here, on stderr as
//! `placedb: warning: ...`, where a user and a script find them all in one
//! form. It sits at the bottom of the layers, so that a reader and the
//! command line alike can warn without importing each other.

use std::fmt::Display;

/// Prints `msg` as a warning on stderr.
pub fn warn(msg: impl Display) {
    eprintln!("placedb: warning: {msg}");
}

/// Prints each line as a warning ([`warn`]).
pub fn warn_all(lines: &[String]) {
    for line in lines {
        warn(line);
    }
}
