//! The selection step made durable: database frames go to the journal as
//! they are taken (the journal is the database's home: see
//! [`crate::select::FrameStore`]), final decisions are collected into
//! batches of [`DECISION_BATCH`] and each batch is written before its
//! `Decision` messages go out. So whatever the host saw decided is in
//! flash, and a 20,000-frame scan writes ~1,250 decision records, not 20,000.
//!
//! Without a journal that keeps records ([`crate::persist::NoJournal`]),
//! decisions go out at once and no label is kept (`labels_dropped`).

use crate::key_pool::{key_of, Aabb};
use crate::persist::keys::{self, MAX_KEY_CHUNKS};
use crate::persist::log::MAX_PAYLOAD;
use crate::persist::record::{KeyChunks, DECISION_BATCH, DECISION_LEN};
use crate::persist::{Journal, Record};
use crate::protocol::{DecisionKind, DeviceMessage};
use crate::select::{DbSnapshot, FrameStore};
use crate::sketch::Sketch;

use super::reply::Out;

/// The largest log record: a database frame with its sketch (`K` ≤ 168,
/// checked at compile time by the device), or a batch of decisions.
pub(super) const MAX_RECORD_LEN: usize = 768;

/// A key chunk and its record fields (tag, frame, count: at most 9 bytes)
/// fit the record buffer.
const _: () = assert!(keys::KEY_CHUNK_BYTES + 9 <= MAX_RECORD_LEN);

/// Bound on the encoded length of a decisions record.
pub(super) const DECISIONS_RECORD_LEN: usize = 12 + DECISION_BATCH * DECISION_LEN;

/// Records one selection step may write, for a window of `w` frames: a
/// database frame per decision, and the decision batches they fill.
pub(super) const fn step_records(w: usize) -> usize {
    w + (DECISION_BATCH - 1 + w).div_ceil(DECISION_BATCH)
}

/// The journal as the selector's [`FrameStore`] during a step: a frame
/// taken is appended as a database record; a stored frame is read back.
pub(super) struct LogStore<'a> {
    pub journal: &'a mut dyn Journal,
    pub record: &'a mut [u8; MAX_RECORD_LEN],
    /// A write failed in this scan: nothing more is written (a record after
    /// a missing one would not restore).
    pub failed: &'a mut bool,
    /// Records of this scan in the journal.
    pub stored: &'a mut u32,
    /// Records the rest of the step (and a Finish) may still need: key
    /// chunks are written only if they leave room for these.
    pub reserve: usize,
}

impl LogStore<'_> {
    /// Appends a record; its position, or `None` (and `failed`) on error.
    fn append(&mut self, payload_of: impl FnOnce(&mut [u8]) -> Option<usize>) -> Option<u32> {
        let len = payload_of(&mut self.record[..])?;
        let payload = self.record.get(..len)?;
        match self.journal.append(payload) {
            Ok(Some(at)) => {
                *self.stored = self.stored.saturating_add(1);
                Some(at)
            }
            Ok(None) => None,
            Err(_) => {
                *self.failed = true;
                None
            }
        }
    }

    /// Writes the key chunks of frame `frame`; their positions, or `None`
    /// when they do not fit (with room for the rest of the step) or a
    /// write failed.
    fn save_keys(&mut self, frame: u32, words: &[u32]) -> Option<KeyChunks> {
        let (n, _) = keys::encoded_size(words);
        if n > MAX_KEY_CHUNKS || !self.journal.has_room(self.reserve + n, MAX_PAYLOAD) {
            return None;
        }
        let mut chunks = KeyChunks::NONE;
        for c in 0..n {
            let (_, count) = keys::chunk_size(words, c)?;
            let count = u16::try_from(count).ok()?;
            let at = self.append(|buf| {
                let fill = |tail: &mut [u8]| keys::encode_chunk(words, c, tail).map(|(len, _)| len);
                Record::encode_keys(frame, count, fill, buf)
                    .ok()
                    .map(|p| p.len())
            })?;
            *chunks.at.get_mut(c)? = at;
            chunks.count = chunks.count.saturating_add(1);
        }
        Some(chunks)
    }
}

impl<const K: usize> FrameStore<K> for LogStore<'_> {
    fn save(&mut self, f: &DbSnapshot<K>, words: Option<&[u32]>) -> Option<(u32, bool)> {
        if *self.failed || !self.journal.keeps() {
            return None;
        }
        let chunks = match words {
            Some(w) => self.save_keys(f.meta.index, w).unwrap_or(KeyChunks::NONE),
            None => KeyChunks::NONE,
        };
        if *self.failed {
            return None;
        }
        let hashes = f.sketch.hashes();
        let at = self.append(|buf| {
            Record::encode_database(f.meta, f.voxels, f.aabb, hashes, chunks, buf)
                .ok()
                .map(|p| p.len())
        })?;
        Some((at, chunks.count > 0))
    }

    fn load(&mut self, at: u32) -> Option<DbSnapshot<K>> {
        load(self.journal, at)
    }

    fn intersect(&mut self, at: u32, keys: &[u64]) -> Option<(u32, u32)> {
        intersect(self.journal, at, keys)
    }
}

/// The journal as a read-only [`FrameStore`] (the export).
pub(super) struct LogReader<'a>(pub &'a mut dyn Journal);

impl<const K: usize> FrameStore<K> for LogReader<'_> {
    fn save(&mut self, _: &DbSnapshot<K>, _: Option<&[u32]>) -> Option<(u32, bool)> {
        None
    }

    fn load(&mut self, at: u32) -> Option<DbSnapshot<K>> {
        load(self.0, at)
    }

    fn intersect(&mut self, at: u32, keys: &[u64]) -> Option<(u32, u32)> {
        intersect(self.0, at, keys)
    }
}

/// The database record at `at`: voxels, box and key chunks.
fn database_at(journal: &mut dyn Journal, at: u32) -> Option<(u32, u32, Option<Aabb>, KeyChunks)> {
    let payload = journal.read_at(at).ok()?;
    match Record::decode(payload).ok()? {
        (
            Record::Database {
                meta,
                voxels,
                aabb,
                keys,
                ..
            },
            _,
        ) => Some((meta.index, voxels, aabb, keys)),
        _ => None,
    }
}

/// Voxels the frame recorded at `at` shares with ascending `keys`, merged
/// chunk by chunk from the log, and its voxel count; `None` unless its keys
/// are all there.
fn intersect(journal: &mut dyn Journal, at: u32, keys: &[u64]) -> Option<(u32, u32)> {
    let (index, voxels, aabb, chunks) = database_at(journal, at)?;
    let base = aabb?.min;
    if chunks.count == 0 {
        return None;
    }
    let (mut j, mut common, mut seen) = (0usize, 0u32, 0u32);
    for &p in chunks.positions() {
        let payload = journal.read_at(p).ok()?;
        let (Record::Keys { frame, .. }, tail) = Record::decode(payload).ok()? else {
            return None;
        };
        if frame != index {
            return None;
        }
        for w in tail.key_words() {
            seen = seen.saturating_add(1);
            let k = key_of(base, w);
            while keys.get(j).is_some_and(|&x| x < k) {
                j += 1;
            }
            if keys.get(j) == Some(&k) {
                // At most `keys.len()`, but counted as `seen` is: no wrap.
                common = common.saturating_add(1);
                j += 1;
            }
        }
    }
    (seen == voxels).then_some((common, voxels))
}

/// The database frame recorded at `at`.
fn load<const K: usize>(journal: &mut dyn Journal, at: u32) -> Option<DbSnapshot<K>> {
    let payload = journal.read_at(at).ok()?;
    match Record::decode(payload).ok()? {
        (
            Record::Database {
                meta, voxels, aabb, ..
            },
            tail,
        ) => Some(DbSnapshot {
            meta,
            voxels,
            aabb,
            sketch: Sketch::from_hashes(tail.hashes())?,
        }),
        _ => None,
    }
}

/// Final decisions on their way to the journal, and the labels it holds.
#[derive(Debug)]
pub(super) struct Decisions {
    /// Timestamp and kind of frames `first ..`, not yet durable.
    batch: heapless::Vec<(f64, DecisionKind), DECISION_BATCH>,
    first: u32,
    /// Frames `0 .. labels` have their decision in the journal.
    pub labels: u32,
    /// Final decisions that could not be kept.
    pub dropped: u32,
}

impl Decisions {
    pub const fn new() -> Self {
        Decisions {
            batch: heapless::Vec::new(),
            first: 0,
            labels: 0,
            dropped: 0,
        }
    }

    /// Forgets everything (a new scan).
    pub fn clear(&mut self) {
        *self = Self::new();
    }

    /// Labels restored from the journal: frames `0 .. labels`.
    pub fn restored(&mut self, labels: u32) {
        self.clear();
        self.labels = labels;
    }

    /// Queues the final decision of `frame` (frames come in order), writing
    /// and sending the batch when it is full.
    pub fn push(
        &mut self,
        frame: u32,
        timestamp: f64,
        kind: DecisionKind,
        store: &mut LogStore<'_>,
        out: &mut Out<'_>,
    ) {
        let next = self.first.saturating_add(self.batch.len() as u32);
        if !self.batch.is_empty() && frame != next {
            // Not the next frame: impossible by construction; keep batches
            // consecutive anyway.
            self.flush(store, out);
        }
        if self.batch.is_empty() {
            self.first = frame;
        }
        if self.batch.push((timestamp, kind)).is_err() {
            self.flush(store, out);
            self.first = frame;
            let _ = self.batch.push((timestamp, kind));
        }
        if self.batch.is_full() || !store.journal.keeps() {
            self.flush(store, out);
        }
    }

    /// Writes the batch (unless writing failed earlier), then sends its
    /// decisions.
    pub fn flush(&mut self, store: &mut LogStore<'_>, out: &mut Out<'_>) {
        if self.batch.is_empty() {
            return;
        }
        let n = self.batch.len() as u32;
        let durable = !*store.failed
            && store.journal.keeps()
            && match Record::encode_decisions(self.first, &self.batch, store.record) {
                Ok(payload) => match store.journal.append(payload) {
                    Ok(Some(_)) => {
                        *store.stored = store.stored.saturating_add(1);
                        true
                    }
                    Ok(None) => false,
                    Err(_) => {
                        *store.failed = true;
                        false
                    }
                },
                Err(_) => false,
            };
        // Labels stay a prefix of the scan: once one batch is lost, so are
        // all later ones (`failed` stops writing).
        if durable && self.first == self.labels {
            self.labels = self.labels.saturating_add(n);
        } else {
            self.dropped = self.dropped.saturating_add(n);
        }
        for (i, &(_, kind)) in self.batch.iter().enumerate() {
            out.reply(&DeviceMessage::Decision {
                frame: self.first.saturating_add(i as u32),
                kind,
            });
        }
        self.batch.clear();
    }
}
