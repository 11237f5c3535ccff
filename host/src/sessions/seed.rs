//! The online core seeded with the earlier sessions of an extension file,
//! exactly as a device restores its flash log before it continues: the one
//! place an extended replay is seeded (`select --extend --solver online`
//! runs `replay::replay_after` with an [`Extension`], and the tests that
//! compare it with a device go through it).

use crate::replay::{MemStore, ReplayError, Seed};
use crate::sessions::extension::{Extension, Fate};
use placedb::key_pool::Aabb;
use placedb::select::DbSnapshot;
use placedb::sketch::Sketch;
use placedb::{Decision, FrameMeta, Pose, ScanConfig, Selector, SelectorConfig};

/// The core's decision of a frame of an earlier session.
fn decision_of(fate: Fate) -> Decision {
    match fate {
        Fate::Taken => Decision::Taken,
        Fate::Covered(k) => Decision::DominatedBy(k),
        Fate::Uncovered(k) => Decision::Uncovered(k),
    }
}

/// An extension file's earlier sessions seed a fresh selector and its
/// store, exactly as a device restores its flash log before it continues:
/// configured with `scan` and `cfg`, every database frame put back
/// (`Selector::restore_database`: in the store with its exact keys where
/// the earlier run kept them, else compared by sketch) and every frame's
/// decision restored in order (`Selector::restore_decided`). Returns the
/// global index of the next frame.
impl Seed for Extension {
    fn seed<
        const FV: usize,
        const POOL: usize,
        const DB: usize,
        const W: usize,
        const K: usize,
        const R: usize,
    >(
        &self,
        sel: &mut Selector<FV, POOL, DB, W, K, R>,
        store: &mut MemStore<K>,
        scan: ScanConfig,
        cfg: SelectorConfig,
    ) -> Result<u32, ReplayError> {
        let refused = |what: String| ReplayError::Seed(what);
        sel.configure(scan, cfg)
            .map_err(|reason| ReplayError::Core { frame: 0, reason })?;
        for f in &self.database {
            let sketch = match (&f.sketch, &f.keys) {
                (Some(hashes), _) => {
                    Sketch::<K>::from_hashes(hashes.iter().copied()).ok_or_else(|| {
                        refused(format!(
                            "frame {}: its sketch of {} hashes does not fit this profile's {K}",
                            f.index,
                            hashes.len()
                        ))
                    })?
                }
                (None, Some(keys)) => Sketch::<K>::from_keys(keys.iter().copied()),
                (None, None) => {
                    return Err(refused(format!(
                        "frame {} has neither a sketch nor a voxel set",
                        f.index
                    )))
                }
            };
            let aabb = f
                .aabb
                .or_else(|| f.keys.as_deref().and_then(Aabb::of_sorted));
            let [tx, ty, tz, qx, qy, qz, qw] = f.pose.map(|c| c as f32);
            let snapshot = DbSnapshot {
                meta: FrameMeta {
                    index: f.index,
                    timestamp: f.timestamp,
                    pose: Pose {
                        translation: [tx, ty, tz],
                        rotation: [qx, qy, qz, qw],
                    },
                },
                voxels: f.voxels,
                aabb,
                sketch,
            };
            let keys = f.keys.clone().filter(|_| f.keyed);
            let key_bytes = if f.keyed { f.key_bytes } else { 0 };
            let at = store.put(snapshot, keys, key_bytes);
            sel.restore_database(&snapshot, at, f.keyed, key_bytes)
                .map_err(|e| {
                    refused(match e {
                        placedb::select::RestoreError::DatabaseFull => format!(
                            "its {} database frames do not fit this profile's database ({} frames)",
                            self.database.len(),
                            DB
                        ),
                        _ => format!("frame {} cannot be restored", f.index),
                    })
                })?;
        }
        for (i, f) in self.frames.iter().enumerate() {
            // Files keep no voxel counts: the window rule needs none after
            // a finished scan (its window emptied at the finish).
            sel.restore_decided(i as u32, decision_of(f.fate), 0)
                .map_err(|_| refused(format!("the decision of frame {i} cannot be restored")))?;
        }
        sel.restore_finished()
            .map_err(|_| refused("the finished scan cannot be restored".to_string()))?;
        Ok(self.next_index())
    }

    fn decisions(&self) -> Vec<Decision> {
        self.frames.iter().map(|f| decision_of(f.fate)).collect()
    }
}
