//! Rebuilding the device from its log at boot: the records of the live
//! generation replayed in order, each checked against the record grammar
//!
//! ```text
//! log := Cleared | Begin (Keys | Database | Decisions)* Finished?
//! ```
//!
//! and against the state before it (the selector refuses a decision for a
//! frame out of order, or naming a frame not in the database). Every prefix
//! of a valid log is valid (a power cut ends the log anywhere), so the
//! records before the first that fails are a scan to go on from: the device
//! keeps them and drops the rest ([`super::Device::restore`]).

use crate::persist::{LogError, Record};
use crate::select::{DbSnapshot, RestoreError};
use crate::sketch::Sketch;

use super::Core;

/// Why [`super::Device::restore`] found no usable scan; the device is left reset.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RestoreFailure {
    /// The log could not be read.
    Log(LogError),
    /// Record `record` (0-based) is not a record of this format, or not one
    /// that may follow the records before it.
    Malformed {
        /// Its position in the log.
        record: u32,
    },
    /// Record `record` does not fit the state before it.
    Refused {
        /// Its position in the log.
        record: u32,
        /// What the selector said.
        error: RestoreError,
    },
    /// Record `record` holds a configuration this device refuses.
    BadConfig {
        /// Its position in the log.
        record: u32,
    },
}

impl RestoreFailure {
    /// The record from which the log is unusable to any device: one that
    /// does not decode, breaks the grammar or contradicts the records before
    /// it. `None` when the flash could not be read, or when the record needs
    /// a capacity or configuration this device lacks (firmware built for
    /// it may still read the log, so it is not dropped).
    pub fn unusable_record(&self) -> Option<u32> {
        match *self {
            RestoreFailure::Log(_)
            | RestoreFailure::BadConfig { .. }
            | RestoreFailure::Refused {
                error: RestoreError::DatabaseFull,
                ..
            } => None,
            RestoreFailure::Malformed { record } | RestoreFailure::Refused { record, .. } => {
                Some(record)
            }
        }
    }
}

/// Where the replay is: its place in the record grammar, and the key bytes
/// of the frame whose `Keys` chunks came last (its `Database` record follows).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Replay {
    grammar: Grammar,
    keys_of: u32,
    key_bytes: u32,
}

impl Replay {
    /// Before the first record.
    pub const START: Replay = Replay {
        grammar: Grammar::Start,
        keys_of: u32::MAX,
        key_bytes: 0,
    };

    fn add_keys(&mut self, frame: u32, bytes: usize) {
        if self.keys_of != frame {
            (self.keys_of, self.key_bytes) = (frame, 0);
        }
        self.key_bytes = self
            .key_bytes
            .saturating_add(u32::try_from(bytes).unwrap_or(u32::MAX));
    }

    fn take_keys(&mut self, frame: u32) -> u32 {
        let bytes = if self.keys_of == frame {
            self.key_bytes
        } else {
            0
        };
        (self.keys_of, self.key_bytes) = (u32::MAX, 0);
        bytes
    }
}

/// Where the replay is in the record grammar.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Grammar {
    /// Nothing replayed yet.
    Start,
    /// After `Begin`: database frames and decisions.
    Scan,
    /// After `Cleared` or `Finished`: nothing may follow.
    Closed,
}

impl<
        const FV: usize,
        const POOL: usize,
        const DB: usize,
        const W: usize,
        const K: usize,
        const R: usize,
    > Core<FV, POOL, DB, W, K, R>
{
    /// Replays log record number `n`, found at `at`.
    pub(super) fn apply(
        &mut self,
        at: u32,
        payload: &[u8],
        n: u32,
        replay: &mut Replay,
    ) -> Result<(), RestoreFailure> {
        let malformed = RestoreFailure::Malformed { record: n };
        let refused = |error| RestoreFailure::Refused { record: n, error };
        let (record, tail) = Record::decode(payload).map_err(|_| malformed)?;
        let grammar = &mut replay.grammar;
        match (*grammar, record) {
            (Grammar::Start, Record::Begin(cfg)) => {
                cfg.validate()
                    .map_err(|_| RestoreFailure::BadConfig { record: n })?;
                self.configure(cfg)
                    .map_err(|_| RestoreFailure::BadConfig { record: n })?;
                *grammar = Grammar::Scan;
            }
            (Grammar::Start, Record::Cleared) => *grammar = Grammar::Closed,
            (
                Grammar::Scan,
                Record::Database {
                    meta,
                    voxels,
                    aabb,
                    keys,
                    ..
                },
            ) => {
                let sketch = Sketch::from_hashes(tail.hashes()).ok_or(malformed)?;
                let frame = DbSnapshot {
                    meta,
                    voxels,
                    aabb,
                    sketch,
                };
                // Its keys' share of the key budget, as the selector counted
                // it when the frame was taken.
                let key_bytes = replay.take_keys(meta.index);
                self.selector
                    .restore_database(&frame, at, keys.count > 0, key_bytes)
                    .map_err(refused)?;
            }
            (Grammar::Scan, Record::Keys { frame, .. }) => {
                replay.add_keys(frame, tail.len());
            }
            (Grammar::Scan, Record::Decisions { first, .. }) => {
                if first != self.decisions.labels {
                    return Err(malformed);
                }
                let mut labels = first;
                for (i, (_, kind)) in tail.decisions().enumerate() {
                    let frame = first.saturating_add(i as u32);
                    self.selector
                        .restore_decided(frame, kind.into())
                        .map_err(refused)?;
                    labels = frame.saturating_add(1);
                }
                self.decisions.restored(labels);
            }
            (Grammar::Scan, Record::Finished) => {
                self.finished = true;
                *grammar = Grammar::Closed;
            }
            _ => return Err(malformed),
        }
        Ok(())
    }
}
