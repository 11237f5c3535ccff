//! What the device writes to its log: one [`Record`] per payload, encoded
//! with postcard, with a tail for the variable part: a database frame's
//! sketch as raw little-endian `u32`s (so that the record type needs no
//! sketch capacity), or a batch of decisions.
//!
//! Decisions are written in batches of up to [`DECISION_BATCH`] consecutive
//! frames, one record each: a scan of 20,000 frames writes ~1,250 of them
//! instead of 20,000, whose 20-byte headers alone would fill a third of a
//! 1 MiB log. Each decision carries the key pool words its frame got on
//! arrival ([`Record::Labels`], log format 5; see
//! [`crate::select::Selector::decided_held`]): a restored selector counts
//! the last decided frames in its window rule as the uninterrupted one did.
//! Logs of older formats hold [`Record::Decisions`], read with no counts.

use super::keys::MAX_KEY_CHUNKS;
use crate::camera::Intrinsics;
use crate::frame::FrameMeta;
use crate::key_pool::Aabb;
use crate::protocol::{Config, DecisionKind};

/// Most decisions one [`Record::Decisions`] holds.
pub const DECISION_BATCH: usize = 16;

/// Bound on the encoded length of one decision of a batch: the timestamp
/// (8 bytes), the kind (tag, option tag, varint class: at most 7) and the
/// frame's key pool words (varint: at most 5).
pub const DECISION_LEN: usize = 20;

/// One decision of a batch: the frame's timestamp, its kind and the key
/// pool words it got on arrival (0 in a batch of format 4 or older, which
/// did not keep them).
pub type Decided = (f64, DecisionKind, u32);

/// One durable fact about the scan.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Record {
    /// First record of a scan's generation: the Hello in force.
    Begin(Config),
    /// First and only record of a generation written by Reset: nothing stored.
    Cleared,
    /// A frame joined the database (its sketch follows: `hashes` × 4 bytes).
    Database {
        /// Index, timestamp and pose.
        meta: FrameMeta,
        /// Voxels in the frame's set.
        voxels: u32,
        /// Box of the voxel set (`None`: empty set).
        aabb: Option<Aabb>,
        /// Hashes in the sketch that follows.
        hashes: u16,
        /// Where its exact keys are (written before it), if they were kept.
        keys: KeyChunks,
    },
    /// A chunk of a database frame's exact keys (see [`super::keys`]): the
    /// encoded bytes follow.
    Keys {
        /// The frame whose keys these are.
        frame: u32,
        /// Keys in the chunk.
        count: u16,
    },
    /// The final decisions of frames `first .. first + count` (never
    /// `Pending`), each a timestamp and a [`DecisionKind`], follow (log
    /// formats 2 to 4; read, no longer written: see [`Record::Labels`]).
    Decisions {
        /// First frame index.
        first: u32,
        /// Decisions that follow (1..=[`DECISION_BATCH`]).
        count: u16,
    },
    /// Finish: every frame seen was decided.
    Finished,
    /// A session boundary (log format 3): the finished scan before it goes
    /// on with a new session (`HostMessage::Extend`) whose first frame is
    /// `first`, the number of frames of every earlier session. Only after
    /// [`Record::Finished`].
    Session {
        /// The first frame index of the new session.
        first: u32,
    },
    /// A session boundary with the new session's camera (log format 4):
    /// as [`Record::Session`], and the frames from `first` on are from a
    /// camera with these intrinsics and depth scale (another robot or
    /// sensor may scan the next wing; the voxel sets are compared in one
    /// world frame whatever made them). Extend writes this one; a log of
    /// format 3 holds [`Record::Session`], read as a session with the
    /// earlier one's camera.
    SessionCamera {
        /// The first frame index of the new session.
        first: u32,
        /// Depth units per metre of the new session's camera.
        depth_scale: f32,
        /// Its intrinsics.
        intrinsics: Intrinsics,
    },
    /// The host went on with the scan restored from flash after a restart
    /// (a power cut, a reset), at frame `at`, the next frame it expected
    /// (log format 4): written once per restart, when a host resumes, so
    /// that an export says how often and where a scan was resumed.
    Resumed {
        /// The frames seen when it was resumed.
        at: u32,
    },
    /// The final decisions of frames `first .. first + count` (never
    /// `Pending`), each a [`Decided`] (timestamp, kind, key pool words),
    /// follow (log format 5).
    Labels {
        /// First frame index.
        first: u32,
        /// Decisions that follow (1..=[`DECISION_BATCH`]).
        count: u16,
    },
}

/// Positions in the log of a database frame's key chunks, in key order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub struct KeyChunks {
    /// Chunks (0: the keys were not kept).
    pub count: u8,
    /// Their positions; the first `count` are meaningful.
    pub at: [u32; MAX_KEY_CHUNKS],
}

impl KeyChunks {
    /// No keys kept.
    pub const NONE: KeyChunks = KeyChunks {
        count: 0,
        at: [0; MAX_KEY_CHUNKS],
    };

    /// The positions of the chunks.
    pub fn positions(&self) -> &[u32] {
        self.at.get(..usize::from(self.count)).unwrap_or(&[])
    }
}

/// Why a payload could not be encoded or decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RecordError {
    /// The buffer is too small for the record.
    TooLarge,
    /// The payload is not a record of this format.
    Malformed,
}

impl Record {
    /// Encodes a record without a tail (not [`Record::Database`] or
    /// [`Record::Decisions`], whose tail their own encoders write).
    pub fn encode<'b>(&self, buf: &'b mut [u8]) -> Result<&'b [u8], RecordError> {
        postcard::to_slice(self, buf)
            .map(|b| &*b)
            .map_err(|_| RecordError::TooLarge)
    }

    /// Encodes a [`Record::Database`] of `meta`, `voxels`, `aabb`, its
    /// sketch `hashes` and its key chunks into `buf`.
    pub fn encode_database<'b>(
        meta: FrameMeta,
        voxels: u32,
        aabb: Option<Aabb>,
        hashes: &[u32],
        keys: KeyChunks,
        buf: &'b mut [u8],
    ) -> Result<&'b [u8], RecordError> {
        let record = Record::Database {
            meta,
            voxels,
            aabb,
            hashes: u16::try_from(hashes.len()).map_err(|_| RecordError::TooLarge)?,
            keys,
        };
        let used = postcard::to_slice(&record, buf)
            .map_err(|_| RecordError::TooLarge)?
            .len();
        let end = used + hashes.len() * 4;
        let tail = buf.get_mut(used..end).ok_or(RecordError::TooLarge)?;
        for (chunk, h) in tail.chunks_exact_mut(4).zip(hashes) {
            chunk.copy_from_slice(&h.to_le_bytes());
        }
        buf.get(..end).ok_or(RecordError::TooLarge)
    }

    /// Encodes a [`Record::Keys`] chunk of frame `frame`: `count` keys
    /// whose encoding `fill` writes into the buffer it is given, returning
    /// the bytes written (`None`: it does not fit).
    pub fn encode_keys(
        frame: u32,
        count: u16,
        fill: impl FnOnce(&mut [u8]) -> Option<usize>,
        buf: &mut [u8],
    ) -> Result<&[u8], RecordError> {
        let record = Record::Keys { frame, count };
        let used = postcard::to_slice(&record, buf)
            .map_err(|_| RecordError::TooLarge)?
            .len();
        let tail = buf.get_mut(used..).ok_or(RecordError::TooLarge)?;
        let len = fill(tail).ok_or(RecordError::TooLarge)?;
        buf.get(..used + len).ok_or(RecordError::TooLarge)
    }

    /// Encodes a [`Record::Labels`] of the frames from `first`, one
    /// [`Decided`] each, into `buf`.
    pub fn encode_decisions<'b>(
        first: u32,
        decisions: &[Decided],
        buf: &'b mut [u8],
    ) -> Result<&'b [u8], RecordError> {
        let count = u16::try_from(decisions.len()).map_err(|_| RecordError::TooLarge)?;
        let record = Record::Labels { first, count };
        let mut end = postcard::to_slice(&record, buf)
            .map_err(|_| RecordError::TooLarge)?
            .len();
        for d in decisions {
            let rest = buf.get_mut(end..).ok_or(RecordError::TooLarge)?;
            end += postcard::to_slice(d, rest)
                .map_err(|_| RecordError::TooLarge)?
                .len();
        }
        buf.get(..end).ok_or(RecordError::TooLarge)
    }

    /// Decodes a payload: the record and its tail, checked complete (a
    /// sketch of `hashes` words, or `count` decisions, and nothing more).
    pub fn decode(payload: &[u8]) -> Result<(Record, Tail<'_>), RecordError> {
        let (record, rest) =
            postcard::take_from_bytes::<Record>(payload).map_err(|_| RecordError::Malformed)?;
        let ok = match record {
            Record::Database { hashes, keys, .. } => {
                rest.len() == usize::from(hashes) * 4 && usize::from(keys.count) <= MAX_KEY_CHUNKS
            }
            Record::Keys { count, .. } => super::keys::decode(rest).count() == usize::from(count),
            Record::Decisions { count, .. } | Record::Labels { count, .. } => {
                let tail = Tail(rest);
                let with_counts = matches!(record, Record::Labels { .. });
                count > 0
                    && usize::from(count) <= DECISION_BATCH
                    && tail.entries(with_counts).count() == usize::from(count)
                    && tail.entries_fit(with_counts)
            }
            _ => rest.is_empty(),
        };
        if !ok {
            return Err(RecordError::Malformed);
        }
        Ok((record, Tail(rest)))
    }
}

/// The variable part after a record.
#[derive(Debug, Clone, Copy)]
pub struct Tail<'a>(&'a [u8]);

impl<'a> Tail<'a> {
    /// Bytes in the tail.
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// Whether the tail is empty.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// A keys record's relative key words, ascending.
    pub fn key_words(&self) -> impl Iterator<Item = u32> + 'a {
        super::keys::decode(self.0)
    }

    /// A database record's sketch hashes, in stored order.
    pub fn hashes(&self) -> impl Iterator<Item = u32> + 'a {
        self.0
            .chunks_exact(4)
            .map(|c| <[u8; 4]>::try_from(c).map_or(0, u32::from_le_bytes))
    }

    /// A decision batch's decisions ([`Record::Labels`] or
    /// [`Record::Decisions`], as `record` is), in frame order; stops at
    /// the first that does not decode.
    pub fn decisions(&self, record: &Record) -> impl Iterator<Item = Decided> + 'a {
        self.entries(matches!(record, Record::Labels { .. }))
    }

    /// The decisions of a batch with key pool words or without.
    fn entries(&self, with_counts: bool) -> impl Iterator<Item = Decided> + 'a {
        let mut rest = self.0;
        core::iter::from_fn(move || {
            if rest.is_empty() {
                return None;
            }
            let (d, r) = take_decided(rest, with_counts)?;
            rest = r;
            Some(d)
        })
    }

    /// Whether the decisions use every byte (nothing undecodable after them).
    fn entries_fit(&self, with_counts: bool) -> bool {
        let mut rest = self.0;
        while !rest.is_empty() {
            match take_decided(rest, with_counts) {
                Some((_, r)) => rest = r,
                None => return false,
            }
        }
        true
    }
}

impl Record {
    /// The first frame and count of a decision batch of either format.
    pub fn decision_batch(&self) -> Option<(u32, u16)> {
        match *self {
            Record::Decisions { first, count } | Record::Labels { first, count } => {
                Some((first, count))
            }
            _ => None,
        }
    }
}

/// One decision from the front of `bytes`, and the rest.
fn take_decided(bytes: &[u8], with_counts: bool) -> Option<(Decided, &[u8])> {
    if with_counts {
        postcard::take_from_bytes::<Decided>(bytes).ok()
    } else {
        let ((t, kind), rest) = postcard::take_from_bytes::<(f64, DecisionKind)>(bytes).ok()?;
        Some(((t, kind, 0), rest))
    }
}
