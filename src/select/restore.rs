//! Rebuilding a selector from durable records after a restart: the
//! database frames (compared by sketch from then on: their exact keys are
//! not kept in flash) and the final decisions, in order. The scan then goes
//! on with the first undecided frame.

use super::{flags, Decision, Selector, Stored};
use crate::frame::FrameMeta;
use crate::sketch::Sketch;
use crate::store::Aabb;

/// A database frame as a durable log keeps it: what comparing new frames
/// with it by sketch needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DbSnapshot<const K: usize> {
    /// Index, timestamp and pose.
    pub meta: FrameMeta,
    /// Voxels in its set.
    pub voxels: u32,
    /// Box of its voxel set (`None`: empty).
    pub aabb: Option<Aabb>,
    /// Its bottom-k sketch.
    pub sketch: Sketch<K>,
}

/// Why a restore step was refused; nothing changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum RestoreError {
    /// No scan configuration yet.
    NotConfigured,
    /// Frames are open or undecided: restore comes before any new frame.
    NotBetweenScans,
    /// The database is full.
    DatabaseFull,
    /// The frame is in the database already.
    Duplicate,
    /// Decisions must come in frame order: this one is for another frame.
    WrongIndex {
        /// The frame whose decision comes next.
        expected: u32,
    },
    /// The decision names a frame that is not in the database, or is `Pending`.
    BadDecision,
}

impl<const FV: usize, const POOL: usize, const DB: usize, const W: usize, const K: usize>
    Selector<FV, POOL, DB, W, K>
{
    /// Database entry `i` (in the order frames were taken) as a durable log keeps it.
    pub fn database_snapshot(&self, i: usize) -> Option<DbSnapshot<K>> {
        self.db.get(i).map(|s| DbSnapshot {
            meta: s.meta,
            voxels: s.len,
            aabb: s.aabb,
            sketch: s.sketch,
        })
    }

    fn restorable(&self) -> Result<(), RestoreError> {
        if self.config.is_none() {
            Err(RestoreError::NotConfigured)
        } else if self.ingest.current().is_some() || self.len > 0 {
            Err(RestoreError::NotBetweenScans)
        } else {
            Ok(())
        }
    }

    fn in_database(&self, index: u32) -> bool {
        self.db.iter().any(|d| d.meta.index == index)
    }

    /// Puts a stored database frame back. It may be a frame not decided yet
    /// (taken while still in the window): when that frame is streamed again
    /// it takes its place back with exact keys.
    pub fn restore_database(&mut self, frame: &DbSnapshot<K>) -> Result<(), RestoreError> {
        self.restorable()?;
        if self.in_database(frame.meta.index) {
            return Err(RestoreError::Duplicate);
        }
        let stored = Stored {
            meta: frame.meta,
            len: frame.voxels,
            aabb: frame.aabb,
            keys: None,
            sketch: frame.sketch,
        };
        self.db
            .push(stored)
            .map_err(|_| RestoreError::DatabaseFull)?;
        self.status.sketched_frames += 1;
        self.note_usage();
        Ok(())
    }

    /// Records the stored final decision of the next frame (frame
    /// `frames_decided`); the next frame to stream is the one after it.
    pub fn restore_decided(&mut self, index: u32, decision: Decision) -> Result<(), RestoreError> {
        self.restorable()?;
        let expected = self.status.frames_decided;
        if index != expected {
            return Err(RestoreError::WrongIndex { expected });
        }
        let known = match decision {
            Decision::Taken => self.in_database(index),
            Decision::DominatedBy(k) | Decision::Uncovered(Some(k)) => self.in_database(k),
            Decision::Uncovered(None) => true,
            Decision::Pending => false,
        };
        if !known {
            return Err(RestoreError::BadDecision);
        }
        if let Decision::Uncovered(_) = decision {
            self.status.uncovered_frames += 1;
            self.status.flags |= flags::DATABASE_FULL;
        }
        self.status.frames_decided += 1;
        self.status.frames_seen = self.status.frames_decided;
        Ok(())
    }
}
