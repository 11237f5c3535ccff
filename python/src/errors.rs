//! Errors into Python exceptions: a parameter refused as the command line
//! refuses it is a `ValueError`, a file the system could not open or write
//! an `OSError` of its kind (`FileNotFoundError`, `PermissionError`, ...),
//! anything else a `RuntimeError`; the message is the command line's. A
//! panic (a bug) never crosses into Python: it becomes a `RuntimeError`
//! that says so.

use placedb_host::error::{OutputError, UsageError};
use placedb_host::ReadError;
use pyo3::exceptions::{
    PyConnectionError, PyFileExistsError, PyFileNotFoundError, PyIsADirectoryError,
    PyNotADirectoryError, PyOSError, PyPermissionError, PyRuntimeError, PyTimeoutError,
    PyValueError,
};
use pyo3::prelude::*;
use std::error::Error;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::mpsc;
use std::time::Duration;

/// Which exception an error becomes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A value or an input's content is wrong.
    Value,
    /// The operating system refused a file or a connection.
    Os(std::io::ErrorKind),
    /// Anything else (a device's refusal, a run that measured nothing).
    Runtime,
}

/// An error made sendable between threads: its kind and its words.
#[derive(Debug, Clone)]
pub struct Failure {
    /// The exception it becomes.
    pub kind: Kind,
    /// The message, as `placedb` prints it after "error: ".
    pub message: String,
}

impl Failure {
    /// A `ValueError` with these words.
    pub fn value(message: impl Into<String>) -> Failure {
        Failure {
            kind: Kind::Value,
            message: message.into(),
        }
    }

    /// Classifies `e` by the errors in its chain: the message stays the
    /// outermost one's, which names the file, line or frame.
    pub fn of(e: &(dyn Error + 'static)) -> Failure {
        let message = e.to_string();
        let mut kind = Kind::Runtime;
        let mut at: Option<&(dyn Error + 'static)> = Some(e);
        while let Some(err) = at {
            if let Some(io) = err.downcast_ref::<std::io::Error>() {
                kind = Kind::Os(io.kind());
                break;
            }
            if let Some(read) = err.downcast_ref::<ReadError>() {
                kind = match read {
                    ReadError::Io { source, .. } => Kind::Os(source.kind()),
                    _ => Kind::Value,
                };
                break;
            }
            // A refused target or labels that do not fit: the caller's value.
            if let Some(OutputError::Mismatch(_)) = err.downcast_ref::<OutputError>() {
                kind = Kind::Value;
                break;
            }
            if err.is::<UsageError>() || err.is::<clap::Error>() {
                kind = Kind::Value;
                break;
            }
            at = err.source();
        }
        Failure { kind, message }
    }

    /// The Python exception.
    pub fn into_py(self) -> PyErr {
        use std::io::ErrorKind as K;
        let m = self.message;
        match self.kind {
            Kind::Value => PyValueError::new_err(m),
            Kind::Runtime => PyRuntimeError::new_err(m),
            Kind::Os(k) => match k {
                K::NotFound => PyFileNotFoundError::new_err(m),
                K::PermissionDenied => PyPermissionError::new_err(m),
                K::AlreadyExists => PyFileExistsError::new_err(m),
                K::IsADirectory => PyIsADirectoryError::new_err(m),
                K::NotADirectory => PyNotADirectoryError::new_err(m),
                K::TimedOut => PyTimeoutError::new_err(m),
                K::ConnectionRefused
                | K::ConnectionReset
                | K::ConnectionAborted
                | K::BrokenPipe => PyConnectionError::new_err(m),
                _ => PyOSError::new_err(m),
            },
        }
    }
}

impl From<Box<dyn Error>> for Failure {
    fn from(e: Box<dyn Error>) -> Failure {
        Failure::of(&*e)
    }
}

impl From<Failure> for PyErr {
    fn from(f: Failure) -> PyErr {
        f.into_py()
    }
}

/// The words of a panic's payload.
fn panic_words(payload: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        (*s).to_string()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "a panic without a message".to_string()
    }
}

/// Runs `f`, a panic in it caught as a `RuntimeError` naming it a bug.
pub fn guarded<T>(f: impl FnOnce() -> Result<T, Failure>) -> Result<T, Failure> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(payload) => Err(Failure {
            kind: Kind::Runtime,
            message: format!(
                "internal error in placedb (a bug; please report it with the call that \
                 caused it): {}",
                panic_words(&*payload)
            ),
        }),
    }
}

/// Runs the long call `f` on its own thread with the GIL released, so
/// other Python threads go on, and checks for Ctrl-C every 100 ms: an
/// interrupt raises `KeyboardInterrupt` at once. The abandoned call has no
/// side effects left to make (it computes in memory), so it is only left
/// to end on its own.
pub fn interruptible<T: Send + 'static>(
    py: Python<'_>,
    f: impl FnOnce() -> Result<T, Failure> + Send + 'static,
) -> PyResult<T> {
    let (tx, rx) = mpsc::channel();
    std::thread::Builder::new()
        .name("placedb".into())
        .spawn(move || {
            // The receiver is gone when the call was interrupted.
            let _ = tx.send(guarded(f));
        })
        .map_err(|e| PyRuntimeError::new_err(format!("cannot start a thread: {e}")))?;
    let mut rx = rx;
    loop {
        // The receiver goes with the wait (it is Send, not Sync).
        let (back, got) = py.allow_threads(move || {
            let got = rx.recv_timeout(Duration::from_millis(100));
            (rx, got)
        });
        rx = back;
        match got {
            Ok(r) => return r.map_err(Failure::into_py),
            Err(mpsc::RecvTimeoutError::Timeout) => py.check_signals()?,
            Err(mpsc::RecvTimeoutError::Disconnected) => {
                return Err(PyRuntimeError::new_err(
                    "internal error in placedb: the call's thread ended without a result",
                ))
            }
        }
    }
}

/// Runs the call `f`, which writes files or talks to a board, with the
/// GIL released and to its end (an interrupt mid-way would leave a board
/// or an output half done; their own all-or-nothing rules apply either
/// way), then lets a pending Ctrl-C raise.
pub fn released<T: Send>(
    py: Python<'_>,
    f: impl FnOnce() -> Result<T, Failure> + Send,
) -> PyResult<T> {
    let r = py.allow_threads(|| guarded(f));
    let v = r.map_err(Failure::into_py)?;
    py.check_signals()?;
    Ok(v)
}
