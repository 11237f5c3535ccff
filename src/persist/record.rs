//! What the device writes to its log: one [`Record`] per payload, encoded
//! with postcard. A database frame's sketch follows its record as raw
//! little-endian `u32`s, so that the record type needs no sketch capacity.

use crate::frame::FrameMeta;
use crate::protocol::{Config, DecisionKind};
use crate::store::Aabb;

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
    },
    /// A frame's final decision (never `Pending`).
    Decided {
        /// Frame index.
        frame: u32,
        /// Its timestamp, seconds.
        timestamp: f64,
        /// The decision.
        kind: DecisionKind,
    },
    /// Finish: every frame seen was decided.
    Finished,
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
    /// Encodes the record, followed by `sketch` (for [`Record::Database`],
    /// whose `hashes` must be `sketch.len()`), into `buf`.
    pub fn encode<'b>(&self, sketch: &[u32], buf: &'b mut [u8]) -> Result<&'b [u8], RecordError> {
        let used = postcard::to_slice(self, buf)
            .map_err(|_| RecordError::TooLarge)?
            .len();
        let end = used + sketch.len() * 4;
        let tail = buf.get_mut(used..end).ok_or(RecordError::TooLarge)?;
        for (chunk, h) in tail.chunks_exact_mut(4).zip(sketch) {
            chunk.copy_from_slice(&h.to_le_bytes());
        }
        buf.get(..end).ok_or(RecordError::TooLarge)
    }

    /// Decodes a payload: the record and the sketch bytes after it (empty
    /// unless it is a [`Record::Database`], whose sketch must be complete).
    pub fn decode(payload: &[u8]) -> Result<(Record, Hashes<'_>), RecordError> {
        let (record, rest) =
            postcard::take_from_bytes::<Record>(payload).map_err(|_| RecordError::Malformed)?;
        let hashes = match record {
            Record::Database { hashes, .. } => usize::from(hashes),
            _ => 0,
        };
        if rest.len() != hashes * 4 {
            return Err(RecordError::Malformed);
        }
        Ok((record, Hashes(rest)))
    }
}

/// Sketch hashes stored after a database record.
#[derive(Debug, Clone, Copy)]
pub struct Hashes<'a>(&'a [u8]);

impl Hashes<'_> {
    /// The hashes, in stored order.
    pub fn iter(&self) -> impl Iterator<Item = u32> + '_ {
        self.0
            .chunks_exact(4)
            .map(|c| <[u8; 4]>::try_from(c).map_or(0, u32::from_le_bytes))
    }
}
