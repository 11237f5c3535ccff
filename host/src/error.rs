//! Errors of the host tools: each names the file (and line) it is about, so a
//! user can fix the input without reading code.

use std::path::{Path, PathBuf};

/// Why a `placedb` command failed: any error, printed as
/// `placedb: error: {error}`.
pub type CommandError = Box<dyn std::error::Error>;

/// A command line refused after clap parsed it, for what takes two
/// options to see (`--window` above `--profile`'s window): `placedb` exits
/// with status 2 for it, as for a value out of its parser's range.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct UsageError(pub String);

/// Why a sequence could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// A file or directory could not be opened or read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's reason.
        source: std::io::Error,
    },
    /// A depth PNG is truncated, corrupt or not 16-bit grey.
    #[error("{path}: cannot decode depth PNG: {reason}")]
    Png {
        /// The file.
        path: PathBuf,
        /// What the decoder said.
        reason: String,
    },
    /// A text line does not parse.
    #[error("{path}:{line}: {reason}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong with it.
        reason: String,
    },
    /// A pose is not finite or not a rotation.
    #[error("{path}:{line}: bad pose: {reason}")]
    Pose {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// The core's verdict.
        reason: placedb::CameraError,
    },
    /// A depth image has another size than the first one of the sequence.
    #[error(
        "{name}: depth image is {}x{}, the sequence's images are {}x{}",
        found.0,
        found.1,
        expected.0,
        expected.1
    )]
    SizeMismatch {
        /// The image.
        name: String,
        /// Size of the first image.
        expected: (u16, u16),
        /// Size of this one.
        found: (u16, u16),
    },
    /// The directory is not any supported layout, or is inconsistent.
    #[error("{path}: {reason}")]
    Layout {
        /// The directory.
        path: PathBuf,
        /// What is missing or inconsistent.
        reason: String,
    },
}

/// Why an output of a run could not be written: the database directory,
/// the top view, the extension file, a dataset or an export (the one error
/// of `output/`).
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// Reading a frame (or a colour file) for it failed.
    #[error(transparent)]
    Read(#[from] ReadError),
    /// Writing a file failed.
    #[error("{path}: {source}")]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A target refused, or labels, a database or a frame that do not fit
    /// the sequence.
    #[error("{0}")]
    Mismatch(String),
}

impl OutputError {
    /// The error of a failed write (or directory creation) of `path`, for
    /// `map_err`: the one way `output/` names the file it could not write.
    pub fn writing(path: &Path) -> impl FnOnce(std::io::Error) -> OutputError + '_ {
        move |source| OutputError::Write {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// A duration in an error message, in plain seconds ("30 s", "2.5 s"):
/// rounded to the millisecond, so a deadline computed by subtraction
/// (29.999999642 s) reads as the timeout the user knows.
pub fn seconds(d: std::time::Duration) -> String {
    let ms = d.as_secs_f64() * 1e3;
    let s = format!("{:.3}", ms.round() / 1e3);
    let s = s.trim_end_matches('0').trim_end_matches('.');
    format!("{s} s")
}

/// A run that measured nothing: no frame, no valid depth pixel, or every
/// point outside the key range. The text says what to check.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct NothingMeasured(pub String);

#[cfg(test)]
mod tests {
    use super::seconds;
    use std::time::Duration;

    #[test]
    fn durations_read_as_plain_seconds() {
        assert_eq!(seconds(Duration::from_nanos(29_999_999_642)), "30 s");
        assert_eq!(seconds(Duration::from_millis(2500)), "2.5 s");
        assert_eq!(seconds(Duration::from_millis(45)), "0.045 s");
        assert_eq!(seconds(Duration::ZERO), "0 s");
    }
}
