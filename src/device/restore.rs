//! Rebuilding the device from its log at boot: the records of the live
//! generation replayed in order, each checked against the record grammar
//!
//! ```text
//! log     := Cleared | Begin session (Finished Session session)* Finished?
//! session := (Keys | Database | Decisions | Labels)*
//! ```
//!
//! (a log of format 2, written before sessions, has no `Session` record;
//! each `Session` starts a new session of the finished scan before it, at
//! the frame after its last: see [`super::extend`])
//!
//! and against the state before it (the selector refuses a decision for a
//! frame out of order, or naming a frame not in the database). Every prefix
//! of a valid log is valid (a power cut ends the log anywhere), so the
//! records before the first that fails are a scan to go on from: the device
//! keeps them and drops the rest ([`super::Device::restore`]).
//!
//! The state restored is exactly the state at the last durable decision. A
//! database frame is written when it is taken, the decision it was taken
//! for only with its batch: a `Database` record after the last batch, or
//! before a batch that does not reach its decision (Finish decides many
//! frames in one step), is the state after a decision the log does not
//! hold. Such a frame is restored tentatively and leaves again unless a
//! stored decision names it ([`Ahead`]); the resumed scan then meets the
//! database the uninterrupted one met, decides its frames the same way and,
//! taking the frame again, writes a new record of it, which replaces the
//! earlier one at the next restore. Nothing is written to mark any of
//! this: the rule costs no flash, reads every log written so far, and needs
//! no new format.

use crate::camera::Intrinsics;
use crate::persist::keys::MAX_KEY_CHUNKS;
use crate::persist::record::DECISION_BATCH;
use crate::persist::{Cursor, Journal, LogError, Record};
use crate::protocol::{Config, PROTOCOL_VERSION};
use crate::select::{DbSnapshot, Decision, RestoreError};
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

/// Where the replay is: its place in the record grammar, the key chunks
/// just read (a `Database` record names its own by position), and the
/// database frames not decided yet.
#[derive(Debug, Clone)]
pub(super) struct Replay {
    grammar: Grammar,
    /// The latest `Keys` records, oldest first: a frame's chunks come right
    /// before its `Database` record, which lists their positions.
    chunks: heapless::Vec<Chunk, MAX_KEY_CHUNKS>,
    /// The database frames at or after the first frame without a stored
    /// decision, in log order (see [`Ahead`]).
    ahead: heapless::Vec<Ahead, AHEAD>,
}

/// A `Keys` record: where, whose, and its encoded key bytes.
#[derive(Debug, Clone, Copy)]
struct Chunk {
    at: u32,
    frame: u32,
    bytes: u32,
}

/// A database frame restored before its own decision. It was taken for the
/// decision of an older frame, which names it (`DominatedBy`, or `Taken`
/// for itself). Until a stored decision names it, it is *tentative*: the
/// power may have gone before that decision's batch was written, and the
/// state at the last durable decision does not hold it. A tentative frame
/// leaves the database again when its own decision is not `Taken`, when a
/// later `Database` record of the same frame replaces it (the resumed scan
/// took it again), or when the log ends.
#[derive(Debug, Clone, Copy)]
struct Ahead {
    frame: u32,
    /// Its keys' share of the key budget, to give back if it leaves.
    key_bytes: u32,
    /// A stored decision names it.
    confirmed: bool,
}

/// Most database frames at or after the first undecided frame: they lie
/// in the window of the cut (at most 64 frames) and the batch of decisions
/// not yet written before it (fewer than [`DECISION_BATCH`]); frames of an
/// earlier resumed run lie in the same span, since labels only grow.
const AHEAD: usize = 64 + DECISION_BATCH;

impl Replay {
    /// Before the first record.
    pub const START: Replay = Replay {
        grammar: Grammar::Start,
        chunks: heapless::Vec::new(),
        ahead: heapless::Vec::new(),
    };

    /// Notes the `Keys` record at `at`.
    fn add_keys(&mut self, at: u32, frame: u32, bytes: usize) {
        if self.chunks.is_full() {
            self.chunks.remove(0);
        }
        let bytes = u32::try_from(bytes).unwrap_or(u32::MAX);
        let _ = self.chunks.push(Chunk { at, frame, bytes });
    }

    /// The key bytes of `frame`'s chunks at `positions`, as the selector
    /// counted them when it took the frame. Chunks are matched by position,
    /// not by frame: chunks of the same frame written before a power cut,
    /// which no `Database` record names, do not count.
    fn take_keys(&mut self, frame: u32, positions: &[u32]) -> u32 {
        let bytes = self
            .chunks
            .iter()
            .filter(|c| c.frame == frame && positions.contains(&c.at))
            .fold(0u32, |sum, c| sum.saturating_add(c.bytes));
        self.chunks.clear();
        bytes
    }

    fn ahead(&self, frame: u32) -> Option<usize> {
        self.ahead.iter().position(|a| a.frame == frame)
    }
}

/// Where the replay is in the record grammar.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Grammar {
    /// Nothing replayed yet.
    Start,
    /// After `Begin`: database frames and decisions.
    Scan,
    /// After `Finished`: only a `Session` may follow.
    Finished,
    /// After `Cleared`: nothing may follow.
    Closed,
}

/// The oldest protocol version whose firmware wrote a log (durable storage
/// came with 3); the [`Config`] a log's `Begin` holds is encoded the same
/// since version 2.
const OLDEST_LOGGED_PROTOCOL: u16 = 3;

/// A logged configuration as the Hello of this protocol version would carry
/// it: a log written by an older firmware is restored as it is (and a host
/// of this version resumes or extends its scan with an equal Hello); a
/// version outside the range is left as it is, which `validate` refuses.
fn current_version(cfg: Config) -> Config {
    if (OLDEST_LOGGED_PROTOCOL..=PROTOCOL_VERSION).contains(&cfg.version) {
        Config {
            version: PROTOCOL_VERSION,
            ..cfg
        }
    } else {
        cfg
    }
}

/// A source of log records: hands each `(position, payload)` of a live
/// generation, in order, to the visitor it is given; returns how many.
pub(super) type Records<'a> = dyn FnMut(&mut dyn FnMut(u32, &[u8])) -> Result<u32, LogError> + 'a;

/// Hands every record of `journal`'s live generation, in order, with its
/// position, to `visit` (what [`crate::persist::Log::replay`] does, through
/// the [`Journal`] a message handler holds); returns how many.
pub(super) fn journal_records(
    journal: &mut dyn Journal,
    visit: &mut dyn FnMut(u32, &[u8]),
) -> Result<u32, LogError> {
    let (mut cursor, mut n) = (Cursor::START, 0u32);
    while let Some((at, payload)) = journal.next(&mut cursor)? {
        visit(at, payload);
        n = n.saturating_add(1);
    }
    Ok(n)
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
    /// Rebuilds the scan from the records `records` hands to its visitor
    /// (the live generation of a log, in order; `usage`: the log's bytes in
    /// use and limit), from a reset state: at boot, and when a finished scan
    /// is extended (so that both restore its database the same way). On
    /// failure the core is reset again.
    pub(super) fn replay(
        &mut self,
        records: &mut Records<'_>,
        usage: (u32, u32),
    ) -> Result<u32, RestoreFailure> {
        self.reset();
        // The log's size sets the key budget the restored scan counts.
        self.flash = usage;
        let (mut n, mut failure, mut replay) = (0u32, None, Replay::START);
        let replayed = records(&mut |at, payload| {
            if failure.is_none() {
                failure = self.apply(at, payload, n, &mut replay).err();
                // A log cannot hold 2^32 records, but the count comes from
                // flash contents: it stops at u32::MAX rather than wrap.
                n = n.saturating_add(1);
            }
        });
        match (replayed, failure) {
            (Ok(records), None) => {
                self.settle(&replay);
                // A log holding only `Cleared` (a Reset) restores nothing.
                let scan = self.hello.is_some();
                self.stored = if scan { records } else { 0 };
                self.flash = usage;
                Ok(records)
            }
            (Err(e), _) => {
                self.reset();
                Err(RestoreFailure::Log(e))
            }
            (_, Some(f)) => {
                self.reset();
                Err(f)
            }
        }
    }

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
                let cfg = current_version(cfg);
                cfg.validate()
                    .map_err(|_| RestoreFailure::BadConfig { record: n })?;
                self.configure(cfg)
                    .map_err(|_| RestoreFailure::BadConfig { record: n })?;
                self.sessions.clear();
                self.sessions.push(0).map_err(|_| malformed)?;
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
                let key_bytes = replay.take_keys(meta.index, keys.positions());
                let undecided = meta.index >= self.decisions.labels;
                if let Some(i) = replay.ahead(meta.index).filter(|_| undecided) {
                    // Taken again by a resumed scan: the earlier record was
                    // never decided (a decided one is not taken again).
                    let earlier = replay.ahead.remove(i);
                    if earlier.confirmed {
                        return Err(refused(RestoreError::Duplicate));
                    }
                    self.selector
                        .forget_database(earlier.frame, earlier.key_bytes)
                        .map_err(refused)?;
                }
                self.selector
                    .restore_database(&frame, at, keys.count > 0, key_bytes)
                    .map_err(refused)?;
                if undecided {
                    let ahead = Ahead {
                        frame: meta.index,
                        key_bytes,
                        confirmed: false,
                    };
                    replay.ahead.push(ahead).map_err(|_| malformed)?;
                }
            }
            (Grammar::Scan, Record::Keys { frame, .. }) => {
                replay.add_keys(at, frame, tail.len());
            }
            (Grammar::Scan, Record::Decisions { first, .. } | Record::Labels { first, .. }) => {
                if first != self.decisions.labels {
                    return Err(malformed);
                }
                let mut labels = first;
                for (i, (_, kind, held)) in tail.decisions(&record).enumerate() {
                    let frame = first.saturating_add(i as u32);
                    let decision = Decision::from(kind);
                    if let Some(j) = replay.ahead(frame) {
                        // Its own decision: a database frame is decided
                        // Taken; one that is not was tentative, never taken
                        // in the durable state.
                        let own = replay.ahead.remove(j);
                        if decision != Decision::Taken {
                            if own.confirmed {
                                return Err(malformed);
                            }
                            self.selector
                                .forget_database(own.frame, own.key_bytes)
                                .map_err(refused)?;
                        }
                    }
                    if let Decision::DominatedBy(k) | Decision::Uncovered(Some(k)) = decision {
                        if let Some(named) = replay.ahead(k).and_then(|j| replay.ahead.get_mut(j)) {
                            named.confirmed = true;
                        }
                    }
                    self.selector
                        .restore_decided(frame, decision, held)
                        .map_err(refused)?;
                    labels = frame.saturating_add(1);
                }
                self.decisions.restored(labels);
            }
            // A resume changes no state: the export reads it from the log.
            (Grammar::Scan, Record::Resumed { .. }) => {}
            (Grammar::Scan, Record::Finished) => {
                self.selector.restore_finished().map_err(refused)?;
                self.finished = true;
                *grammar = Grammar::Finished;
            }
            (Grammar::Finished, Record::Session { first }) => {
                self.begin_session(first, None, n)?;
                *grammar = Grammar::Scan;
            }
            (
                Grammar::Finished,
                Record::SessionCamera {
                    first,
                    depth_scale,
                    intrinsics,
                },
            ) => {
                self.begin_session(first, Some((depth_scale, intrinsics)), n)?;
                *grammar = Grammar::Scan;
            }
            _ => return Err(malformed),
        }
        Ok(())
    }

    /// Record `n`, a session boundary: the finished scan goes on with frame
    /// `first`, from `camera` (depth scale, intrinsics) when the record
    /// names one, else from the earlier session's.
    fn begin_session(
        &mut self,
        first: u32,
        camera: Option<(f32, Intrinsics)>,
        n: u32,
    ) -> Result<(), RestoreFailure> {
        let malformed = RestoreFailure::Malformed { record: n };
        // The next session begins with the frame after the last decided
        // one: every frame seen was decided at Finish.
        let decided = self.selector.status().frames_decided;
        let hello = self.hello.ok_or(malformed)?;
        if first != self.decisions.labels || first != decided || self.sessions.is_full() {
            return Err(malformed);
        }
        if let Some((depth_scale, intrinsics)) = camera {
            let cfg = Config {
                depth_scale,
                intrinsics,
                ..hello
            };
            let bad = RestoreFailure::BadConfig { record: n };
            cfg.validate().map_err(|_| bad)?;
            self.configure(cfg).map_err(|_| bad)?;
        }
        let _ = self.sessions.push(first);
        self.finished = false;
        Ok(())
    }

    /// After the last record: the tentative database frames leave (taken
    /// for a decision the log does not hold), so that the restored state is
    /// exactly the state at the last durable decision, and the resumed scan
    /// decides the frames after it as the uninterrupted one did.
    pub(super) fn settle(&mut self, replay: &Replay) {
        for a in replay.ahead.iter().filter(|a| !a.confirmed) {
            // In the index by construction: `apply` put it there.
            let _ = self.selector.forget_database(a.frame, a.key_bytes);
        }
    }
}
