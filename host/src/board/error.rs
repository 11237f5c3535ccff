//! [`DeviceError`]: why talking to a device failed, for every layer of the
//! device client.

use placedb::protocol::ErrorKind;
use std::io;

/// Why talking to a device failed.
#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    /// The link failed or timed out.
    #[error("{}", link_words(.0))]
    Io(#[from] io::Error),
    /// The device refused a message with a typed error.
    #[error("the device refused {what} (seq {seq}): {kind}")]
    Refused {
        /// Which message.
        what: String,
        /// Its sequence number.
        seq: u32,
        /// The device's reason.
        kind: ErrorKind,
    },
    /// The conversation went wrong (damaged or unexpected replies).
    #[error("protocol: {0}")]
    Protocol(String),
    /// The device runs another capacity profile than asked for.
    #[error("{0}")]
    Profile(String),
    /// Bad input on the host side (sequence, options, files).
    #[error("{0}")]
    Input(String),
    /// An output (directory or file) refused or not written; names it.
    #[error(transparent)]
    Output(#[from] crate::error::OutputError),
    /// The run was asked to stop (SIGINT, SIGTERM) and stopped between
    /// frames: every frame sent was answered, none is left open.
    #[error("stopped by signal {signal} before frame {next}")]
    Stopped {
        /// The signal.
        signal: i32,
        /// The next frame (global index) it would have sent.
        next: u32,
    },
}

/// A link's error in words: one made with a message says what happened
/// and where (a port that does not open names it and what to do); a bare
/// one from the operating system ("no answer in time") is said to be the
/// link's.
fn link_words(e: &io::Error) -> String {
    let words = crate::error::io_words(e);
    if e.get_ref().is_some() {
        words
    } else {
        format!("link: {words}")
    }
}

impl DeviceError {
    /// Whether the link waited in vain (no reply in time).
    pub fn is_timeout(&self) -> bool {
        matches!(self, DeviceError::Io(e) if e.kind() == io::ErrorKind::TimedOut)
    }
}
