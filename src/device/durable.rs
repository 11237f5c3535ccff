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
use crate::persist::record::{Decided, KeyChunks, DECISION_BATCH, DECISION_LEN};
use crate::persist::{Journal, Record};
use crate::protocol::DeviceMessage;
use crate::select::{DbSnapshot, FrameStore};
use crate::sketch::Sketch;

use super::reply::Out;

/// The largest log record: a database frame with its sketch (`K` ≤ 161,
/// checked at compile time by the device), or a batch of decisions.
pub(super) const MAX_RECORD_LEN: usize = 768;

/// Bound on the encoded length of a key chunk record: the chunk and its
/// record fields (tag, frame, count: at most 1 + 5 + 3 bytes).
pub(super) const KEY_RECORD_LEN: usize = keys::KEY_CHUNK_BYTES + 9;

/// A key chunk record fits the record buffer.
const _: () = assert!(KEY_RECORD_LEN <= MAX_RECORD_LEN);

/// Postcard's worst case for the fields of a [`Record::Database`] (its
/// sketch follows them): the variant tag (1 byte); the frame's index
/// (varint, up to 5), timestamp (8) and pose (7 `f32`s, 28); its voxel count
/// (varint, up to 5); its box (option tag and 6 zigzag varints of up to 5
/// bytes: 31); the hash count (varint `u16`, up to 3); the key chunks (a
/// count byte and 8 varint positions of up to 5 bytes: 41). Checked against
/// a record of extreme values in the tests.
pub(super) const DB_FIELDS_LEN: usize = 1 + (5 + 8 + 28) + 5 + 31 + 3 + (1 + 5 * MAX_KEY_CHUNKS);

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
    /// when they are more than a frame may have or a write failed. The log
    /// has room for them: the selector offers keys by its rule alone
    /// (`select::KeyOffer`), and the step was accepted only with room for
    /// the chunks it may offer ([`crate::select::Selector::key_chunks_next_frame`]).
    fn save_keys(&mut self, frame: u32, words: &[u32]) -> Option<KeyChunks> {
        let (n, _) = keys::encoded_size(words);
        if n > MAX_KEY_CHUNKS {
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
    batch: heapless::Vec<Decided, DECISION_BATCH>,
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
        decided: Decided,
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
        if self.batch.push(decided).is_err() {
            self.flush(store, out);
            self.first = frame;
            let _ = self.batch.push(decided);
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
        for (i, &(_, kind, _)) in self.batch.iter().enumerate() {
            out.reply(&DeviceMessage::Decision {
                frame: self.first.saturating_add(i as u32),
                kind,
            });
        }
        self.batch.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Pose;
    use crate::frame::FrameMeta;
    use crate::persist::record::KeyChunks;

    /// A database record of extreme field values: the longest postcard can
    /// make them is exactly [`DB_FIELDS_LEN`] (the bound the log's room
    /// checks rely on), and with a sketch of `K` hashes the record fits
    /// the record buffer for every `K` the device accepts.
    #[test]
    fn database_fields_at_their_longest_take_db_fields_len() {
        let meta = FrameMeta {
            index: u32::MAX,
            timestamp: f64::MAX,
            pose: Pose {
                translation: [f32::MAX; 3],
                rotation: [f32::MIN; 4],
            },
        };
        let record = Record::Database {
            meta,
            voxels: u32::MAX,
            aabb: Some(Aabb {
                min: [i32::MIN; 3],
                max: [i32::MAX; 3],
            }),
            hashes: u16::MAX,
            keys: KeyChunks {
                count: u8::MAX,
                at: [u32::MAX; MAX_KEY_CHUNKS],
            },
        };
        let mut buf = [0u8; MAX_RECORD_LEN];
        assert_eq!(record.encode(&mut buf).map(<[u8]>::len), Ok(DB_FIELDS_LEN));
        // The largest sketch allowed (the device's compile-time check).
        let k = (MAX_RECORD_LEN - DB_FIELDS_LEN) / 4;
        let hashes = [u32::MAX; 161];
        assert_eq!(k, hashes.len());
        let keys = KeyChunks {
            count: MAX_KEY_CHUNKS as u8,
            at: [u32::MAX; MAX_KEY_CHUNKS],
        };
        let aabb = Some(Aabb {
            min: [i32::MIN; 3],
            max: [i32::MAX; 3],
        });
        let len =
            Record::encode_database(meta, u32::MAX, aabb, &hashes, keys, &mut buf).map(<[u8]>::len);
        assert!(len.is_ok_and(|n| n <= MAX_RECORD_LEN), "{len:?}");
    }

    /// A key chunk record at its longest fits [`KEY_RECORD_LEN`].
    #[test]
    fn a_full_key_chunk_takes_at_most_key_record_len() {
        // Words whose deltas take 5 bytes each fill a chunk unevenly; a
        // long run of 1-byte deltas fills it to the byte.
        let words: [u32; 800] = core::array::from_fn(|i| i as u32);
        let mut buf = [0u8; MAX_RECORD_LEN];
        let fill = |tail: &mut [u8]| keys::encode_chunk(&words, 0, tail).map(|(len, _)| len);
        let (_, count) = keys::chunk_size(&words, 0).unwrap();
        let len = Record::encode_keys(u32::MAX, count as u16, fill, &mut buf).map(<[u8]>::len);
        assert_eq!(count, keys::KEY_CHUNK_BYTES);
        assert!(len.is_ok_and(|n| n <= KEY_RECORD_LEN), "{len:?}");
    }
}
