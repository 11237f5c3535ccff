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

/// An I/O error in words, for every message that carries one: the
/// operating system's reason without Rust's "(os error N)" suffix, the
/// common ones said plainly ("no space left on the device"); an error made
/// with words of our own keeps them.
pub fn io_words(e: &std::io::Error) -> String {
    use std::io::ErrorKind as K;
    let said = match e.kind() {
        K::NotFound => "no such file or directory",
        K::PermissionDenied => "permission denied",
        K::AlreadyExists => "it already exists",
        K::StorageFull => "no space left on the device",
        K::QuotaExceeded => "the disk quota is exceeded",
        K::ReadOnlyFilesystem => "the file system is read-only",
        K::NotADirectory => "a part of the path is not a directory",
        K::IsADirectory => "it is a directory",
        K::ConnectionReset => "the connection was reset by the board",
        K::ConnectionAborted => "the connection was aborted",
        K::ConnectionRefused => "the connection was refused (nothing listens there)",
        K::BrokenPipe => "the other end closed the connection",
        // A file read short as well as a link closed mid-message.
        K::UnexpectedEof => "it ended before all its bytes were read",
        K::TimedOut => "no answer in time",
        _ => "",
    };
    // Only the operating system's errors and bare kinds get our words: one
    // made with a message (`io::Error::new`) already says what happened.
    if e.get_ref().is_none() && !said.is_empty() {
        return said.to_string();
    }
    let text = e.to_string();
    match text.find(" (os error ") {
        Some(at) => text[..at].to_string(),
        None => text,
    }
}

/// Why a sequence could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// A file or directory could not be opened or read.
    #[error("{}: {}", path.display(), io_words(source))]
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
    #[error("{}: {}", path.display(), io_words(source))]
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
    use super::{io_words, seconds};
    use std::time::Duration;

    #[test]
    fn durations_read_as_plain_seconds() {
        assert_eq!(seconds(Duration::from_nanos(29_999_999_642)), "30 s");
        assert_eq!(seconds(Duration::from_millis(2500)), "2.5 s");
        assert_eq!(seconds(Duration::from_millis(45)), "0.045 s");
        assert_eq!(seconds(Duration::ZERO), "0 s");
    }

    #[test]
    fn io_errors_are_words_without_the_os_error_number() {
        use std::io::{Error, ErrorKind};
        for (code, words) in [
            (28, "no space left on the device"),
            (104, "the connection was reset by the board"),
            (2, "no such file or directory"),
        ] {
            assert_eq!(io_words(&Error::from_raw_os_error(code)), words);
        }
        // An errno without words of ours: the system's text, no number.
        let other = io_words(&Error::from_raw_os_error(5));
        assert!(!other.contains("os error") && !other.is_empty(), "{other}");
        assert_eq!(
            io_words(&Error::new(ErrorKind::NotFound, "no board answers")),
            "no board answers"
        );
        assert_eq!(
            io_words(&ErrorKind::UnexpectedEof.into()),
            "it ended before all its bytes were read"
        );
    }
}
