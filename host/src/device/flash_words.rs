//! The core's flash-log and restore failures in words, for a message: the
//! core (`no_std`) gives them no `Display`, and their `Debug` (a Rust
//! variant like `BadRange`) is no message for a user.

use placedb::device::RestoreFailure;
use placedb::persist::{FlashErrorKind, LogError};
use placedb::select::RestoreError;

/// Why the flash log refused an operation.
pub fn log_error(e: LogError) -> String {
    match e {
        LogError::Flash(kind) => format!(
            "the flash reported an error ({})",
            match kind {
                FlashErrorKind::NotAligned => "an access not aligned to its granularity",
                FlashErrorKind::OutOfBounds => "an access outside it",
                FlashErrorKind::Other => "a driver failure",
            }
        ),
        LogError::BadRange => "the log's region is not whole sectors, or fewer than two, \
                               or the flash's granularity is not supported"
            .into(),
        LogError::TooLarge => "a record is longer than the log can hold".into(),
        LogError::Full => "the log has no sector left".into(),
        LogError::NotStarted => "the log holds no scan (no live generation)".into(),
        LogError::NoRecord => "the log has no record at that place".into(),
    }
}

/// Why a restore step refused a record.
pub fn restore_error(e: RestoreError) -> String {
    match e {
        RestoreError::NotConfigured => "it comes before any scan configuration".into(),
        RestoreError::NotBetweenScans => "it comes while frames are open or undecided".into(),
        RestoreError::DatabaseFull => {
            "the database is full (the scan needs a larger capacity profile)".into()
        }
        RestoreError::Duplicate => "its frame is in the database already".into(),
        RestoreError::WrongIndex { expected } => {
            format!("it decides another frame than the next, frame {expected}")
        }
        RestoreError::BadDecision => {
            "its decision names a frame that is not in the database".into()
        }
        RestoreError::NotStored => "its frame is not in the store".into(),
    }
}

/// Why a device restored no scan from its flash log.
pub fn restore_failure(e: RestoreFailure) -> String {
    match e {
        RestoreFailure::Log(e) => format!("the flash log cannot be read: {}", log_error(e)),
        RestoreFailure::Malformed { record } => format!(
            "record {record} of the flash log is not a record of this format, or may not \
             follow the records before it"
        ),
        RestoreFailure::Refused { record, error } => format!(
            "record {record} of the flash log does not fit the scan before it: {}",
            restore_error(error)
        ),
        RestoreFailure::BadConfig { record } => {
            format!("record {record} of the flash log holds a configuration this device refuses")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_failure_is_a_sentence_without_a_variant_name() {
        let all = [
            restore_failure(RestoreFailure::Log(LogError::BadRange)),
            restore_failure(RestoreFailure::Log(LogError::Flash(
                FlashErrorKind::OutOfBounds,
            ))),
            restore_failure(RestoreFailure::Malformed { record: 3 }),
            restore_failure(RestoreFailure::Refused {
                record: 4,
                error: RestoreError::WrongIndex { expected: 9 },
            }),
            restore_failure(RestoreFailure::BadConfig { record: 0 }),
            log_error(LogError::Full),
        ];
        for text in all {
            assert!(
                !text.contains("Bad") && !text.contains("Wrong") && !text.contains('{'),
                "{text}"
            );
        }
    }
}
