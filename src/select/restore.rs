//! Rebuilding a selector from durable records after a restart: the
//! database frames (back in the index, read from the store when a frame
//! near them needs them, compared exactly where the key budget let the
//! store keep their keys, else by sketch) and
//! the final decisions, in order. The scan then goes on with the first
//! undecided frame. Which records make the state at the last durable
//! decision is the caller's to say (the device's rule is in
//! `device::restore`): a frame restored too early is taken back with
//! [`Selector::forget_database`].

use super::database::{entry_of, NOWHERE};
use super::{flags, Decision, Selector};
use crate::frame::FrameMeta;
use crate::key_pool::Aabb;
use crate::sketch::Sketch;

/// A database frame as a durable store keeps it: what comparing new frames
/// with it by sketch, and exporting it, needs.
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
    /// The frame is not in the store (`at` is [`NOWHERE`]).
    NotStored,
}

impl<
        const FV: usize,
        const POOL: usize,
        const DB: usize,
        const W: usize,
        const K: usize,
        const R: usize,
    > Selector<FV, POOL, DB, W, K, R>
{
    fn restorable(&self) -> Result<(), RestoreError> {
        if self.config.is_none() {
            Err(RestoreError::NotConfigured)
        } else if self.ingest.current().is_some() || self.len > 0 {
            Err(RestoreError::NotBetweenScans)
        } else {
            Ok(())
        }
    }

    /// Puts back a database frame that the store keeps at `at` (with its
    /// exact keys when `keyed`, which took `key_bytes` of the key budget). It
    /// may be a frame not decided yet (taken while still in the window, for
    /// the decision of an older frame): when that frame is streamed again it
    /// takes its place back, whole in RAM.
    pub fn restore_database(
        &mut self,
        frame: &DbSnapshot<K>,
        at: u32,
        keyed: bool,
        key_bytes: u32,
    ) -> Result<(), RestoreError> {
        self.restorable()?;
        if at == NOWHERE {
            return Err(RestoreError::NotStored);
        }
        if self.db.find(frame.meta.index).is_some() {
            return Err(RestoreError::Duplicate);
        }
        let entry = super::database::DbEntry {
            key_units: super::database::key_units(keyed, key_bytes),
            ..entry_of(frame, at)
        };
        if !self.db.add(entry) {
            return Err(RestoreError::DatabaseFull);
        }
        self.settled = (0, 0);
        if keyed {
            let st = &mut self.status;
            st.stored_key_bytes = st.stored_key_bytes.saturating_add(key_bytes);
        }
        self.note_usage();
        Ok(())
    }

    /// Takes back a database frame restored by [`Self::restore_database`]
    /// (with `key_bytes` of the key budget, as given there) that the
    /// durable state turns out not to hold: a frame taken for a decision
    /// that was never stored, which the resumed scan decides again.
    pub fn forget_database(&mut self, index: u32, key_bytes: u32) -> Result<(), RestoreError> {
        self.restorable()?;
        let entry = self.db.remove(index).ok_or(RestoreError::BadDecision)?;
        self.settled = (0, 0);
        if entry.keyed() {
            let st = &mut self.status;
            st.stored_key_bytes = st.stored_key_bytes.saturating_sub(key_bytes);
        }
        self.note_usage();
        Ok(())
    }

    /// Records the stored final decision of the next frame (frame
    /// `frames_decided`), which got `held` key pool words on arrival (see
    /// [`Selector::decided_held`]); the next frame to stream is the one
    /// after it. The window rule counts these words of the last decided
    /// frames (see [`Selector::end_frame_with`]); 0 where a store did not
    /// keep them (a log written before they were kept, a database read from
    /// files) decides as a window without them.
    pub fn restore_decided(
        &mut self,
        index: u32,
        decision: Decision,
        held: u32,
    ) -> Result<(), RestoreError> {
        self.restorable()?;
        let expected = self.status.frames_decided;
        if index != expected {
            return Err(RestoreError::WrongIndex { expected });
        }
        let known = |k: u32| self.db.find(k).is_some();
        let ok = match decision {
            Decision::Taken => known(index),
            Decision::DominatedBy(k) | Decision::Uncovered(Some(k)) => known(k),
            Decision::Uncovered(None) => true,
            Decision::Pending => false,
        };
        if !ok {
            return Err(RestoreError::BadDecision);
        }
        if let Decision::Uncovered(_) = decision {
            self.status.uncovered_frames = self.status.uncovered_frames.saturating_add(1);
            self.status.flags |= flags::DATABASE_FULL;
        }
        if let Some(v) = self.recent.get_mut(index as usize % W) {
            *v = held;
        }
        self.status.frames_decided = self.status.frames_decided.saturating_add(1);
        self.status.frames_seen = self.status.frames_decided;
        Ok(())
    }

    /// The restored scan was finished after the decisions restored so far:
    /// its window emptied there, so the frames that follow (a new session)
    /// start a window of their own, as after [`Selector::finish_with`].
    pub fn restore_finished(&mut self) -> Result<(), RestoreError> {
        self.restorable()?;
        self.recent_from = self.status.frames_decided;
        Ok(())
    }
}
