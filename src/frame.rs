//! Frame ingest: one frame at a time, begun with its pose, fed sampled depth
//! rows in order in chunks of any size, ended into a sorted voxel set.
//!
//! The device never holds an image: each row is voxelized as it arrives into
//! the bounded [`FrameVoxels`] set. Rows are the *sampled* rows of the image
//! (row `r` is image row `r * stride`, sample `i` is column `i * stride`),
//! which is also what travels on the wire.

use crate::camera::{CameraError, DepthRange, FrameProjector, Intrinsics, Pose};
use crate::voxel::{FrameVoxels, VoxelGrid, VoxelKey};

/// What every frame of a scan shares: camera, depth units, sampling, grid.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ScanConfig {
    /// Pinhole intrinsics and full image size.
    pub intrinsics: Intrinsics,
    /// Depth units per metre.
    pub depth_scale: f32,
    /// Valid depths, metres.
    pub range: DepthRange,
    /// Pixel stride in u and v.
    pub stride: u16,
    /// Voxel size and grid anchor.
    pub grid: VoxelGrid,
}

impl ScanConfig {
    /// Checks every field as the projector will.
    pub fn validate(&self) -> Result<(), CameraError> {
        self.projector(&Pose::IDENTITY).map(|_| ())
    }

    /// The projector of a frame taken at `pose`.
    pub fn projector(&self, pose: &Pose) -> Result<FrameProjector, CameraError> {
        FrameProjector::new(
            &self.intrinsics,
            self.depth_scale,
            self.range,
            self.stride,
            &self.grid,
            pose,
        )
    }
}

/// Identity of a frame: position in the scan, time, pose.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrameMeta {
    /// Position in the sequence; frames must arrive with indices 0, 1, 2, ...
    pub index: u32,
    /// Seconds (the index when the source has no timestamps).
    pub timestamp: f64,
    /// Camera-to-world pose.
    pub pose: Pose,
}

/// Why a frame step was refused; the frame in progress is left as it was.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum FrameError {
    /// The camera, pose or configuration is invalid.
    Camera(CameraError),
    /// A frame was begun while another is in progress.
    FrameInProgress,
    /// Rows or an end arrived with no frame begun.
    NoFrame,
    /// A frame index other than the next expected one.
    WrongIndex {
        /// The index that must come next.
        expected: u32,
    },
    /// Rows must arrive in order without gaps.
    RowOutOfOrder {
        /// The sampled row that must come next.
        expected: u16,
    },
    /// A chunk is not a whole number of sampled rows, or runs past the image.
    BadRowChunk,
    /// The frame ended before all its sampled rows arrived.
    MissingRows {
        /// Sampled rows received.
        received: u16,
        /// Sampled rows in the image.
        expected: u16,
    },
}

impl From<CameraError> for FrameError {
    fn from(e: CameraError) -> Self {
        FrameError::Camera(e)
    }
}

/// Counts gathered while a frame is voxelized.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FrameStats {
    /// Sampled pixels with a depth in range.
    pub valid_pixels: u32,
    /// Pixels whose voxel key was out of the representable range.
    pub out_of_range: u32,
    /// Pixels whose new voxel did not fit the frame set (set was full).
    pub dropped: u32,
}

/// The frame being received.
#[derive(Debug, Clone)]
pub struct FrameIngest<const FV: usize> {
    current: Option<(FrameMeta, FrameProjector)>,
    next_row: u16,
    stats: FrameStats,
    voxels: FrameVoxels<FV>,
}

impl<const FV: usize> Default for FrameIngest<FV> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const FV: usize> FrameIngest<FV> {
    /// Most distinct voxels one frame can hold.
    pub const VOXEL_LIMIT: usize = FrameVoxels::<FV>::LIMIT;

    /// No frame in progress.
    pub const fn new() -> Self {
        FrameIngest {
            current: None,
            next_row: 0,
            stats: FrameStats {
                valid_pixels: 0,
                out_of_range: 0,
                dropped: 0,
            },
            voxels: FrameVoxels::new(),
        }
    }

    /// The frame in progress, if any.
    pub fn current(&self) -> Option<&FrameMeta> {
        self.current.as_ref().map(|(m, _)| m)
    }

    /// Drops the frame in progress (reset, reconfiguration).
    pub fn abort(&mut self) {
        self.current = None;
    }

    /// Starts a frame whose index must be `expected_index`.
    pub fn begin(
        &mut self,
        meta: FrameMeta,
        expected_index: u32,
        cfg: &ScanConfig,
    ) -> Result<(), FrameError> {
        if self.current.is_some() {
            return Err(FrameError::FrameInProgress);
        }
        if meta.index != expected_index {
            return Err(FrameError::WrongIndex {
                expected: expected_index,
            });
        }
        if !meta.timestamp.is_finite() {
            return Err(FrameError::Camera(CameraError::NonFinitePose));
        }
        let projector = cfg.projector(&meta.pose)?;
        self.voxels.clear();
        self.stats = FrameStats::default();
        self.next_row = 0;
        self.current = Some((meta, projector));
        Ok(())
    }

    /// Whether the frame in progress is projected exactly as `cfg` projects
    /// it: a frame voxelized by another ingest must have been begun with its
    /// selector's configuration (see `Selector::end_frame_from`).
    pub fn begun_with(&self, cfg: &ScanConfig) -> bool {
        match &self.current {
            Some((meta, projector)) => cfg.projector(&meta.pose).is_ok_and(|p| p == *projector),
            None => false,
        }
    }

    /// Completes the frame in progress from its voxel set computed elsewhere
    /// by the same projector (a host replaying a recording it has already
    /// voxelized at this stride and grid): `keys` as [`FrameProjector`]
    /// emitted them for every sampled row (any order, repeats allowed), and
    /// the counts seen doing so. The result is what pushing the rows gives
    /// only if no voxel is dropped, so this is all or nothing: it returns
    /// `false` and changes nothing unless no row has been pushed yet and the
    /// whole set fits ([`Self::VOXEL_LIMIT`]); the caller then pushes the rows.
    pub fn fill_from_set(&mut self, keys: &[u64], valid_pixels: u32, out_of_range: u32) -> bool {
        let Some((_, projector)) = &self.current else {
            return false;
        };
        if self.next_row != 0 || keys.len() > Self::VOXEL_LIMIT {
            return false;
        }
        // Checked before anything changes: a key the projector cannot have
        // emitted is refused with the rest.
        if !keys.iter().all(|&bits| VoxelKey::from_bits(bits).is_some()) {
            return false;
        }
        let sampled_rows = projector.sampled_rows();
        for key in keys.iter().filter_map(|&bits| VoxelKey::from_bits(bits)) {
            self.voxels.insert(key);
        }
        self.stats.valid_pixels = valid_pixels;
        self.stats.out_of_range = out_of_range;
        self.next_row = sampled_rows;
        true
    }

    /// Sampled columns per row of the frame in progress.
    pub fn samples_per_row(&self) -> Option<u16> {
        self.current.as_ref().map(|(_, p)| p.samples_per_row())
    }

    /// Voxelizes `data`: whole sampled rows starting at sampled row `first_row`.
    /// Refused (nothing changes) unless `first_row` is the next row and `data`
    /// holds whole rows within the image.
    #[inline(never)]
    pub fn push_rows(&mut self, first_row: u16, data: &[u16]) -> Result<(), FrameError> {
        let (_, proj) = self.current.as_ref().ok_or(FrameError::NoFrame)?;
        if first_row != self.next_row {
            return Err(FrameError::RowOutOfOrder {
                expected: self.next_row,
            });
        }
        let width = proj.samples_per_row() as usize;
        if !data.len().is_multiple_of(width) {
            return Err(FrameError::BadRowChunk);
        }
        let rows = data.len() / width;
        if rows > (proj.sampled_rows() - self.next_row) as usize {
            return Err(FrameError::BadRowChunk);
        }
        let stride = proj.stride();
        let (voxels, stats) = (&mut self.voxels, &mut self.stats);
        for (i, row) in data.chunks_exact(width).enumerate() {
            let v = (first_row as usize + i) as u16 * stride;
            let valid = proj.project_samples(v, row, &mut stats.out_of_range, |key| {
                voxels.insert(key);
            });
            // At most width x height < 2^32 per frame; saturating keeps that
            // a checked fact (once per row, not per pixel).
            stats.valid_pixels = stats.valid_pixels.saturating_add(valid);
        }
        self.next_row += rows as u16;
        Ok(())
    }

    /// Ends the frame: its metadata, its voxel keys ascending, and its counts.
    /// Refused (the frame stays open) if rows are missing.
    pub fn end(&mut self) -> Result<(FrameMeta, &[u64], FrameStats), FrameError> {
        let (meta, proj) = self.current.as_ref().ok_or(FrameError::NoFrame)?;
        if self.next_row != proj.sampled_rows() {
            return Err(FrameError::MissingRows {
                received: self.next_row,
                expected: proj.sampled_rows(),
            });
        }
        let meta = *meta;
        self.current = None;
        self.stats.dropped = self.voxels.dropped();
        Ok((meta, self.voxels.sorted(), self.stats))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan(stride: u16) -> ScanConfig {
        ScanConfig {
            intrinsics: Intrinsics {
                width: 16,
                height: 12,
                fx: 10.0,
                fy: 10.0,
                cx: 8.0,
                cy: 6.0,
            },
            depth_scale: 1000.0,
            range: DepthRange::default(),
            stride,
            grid: VoxelGrid::new(0.3, [0.0; 3]).unwrap(),
        }
    }

    fn meta() -> FrameMeta {
        FrameMeta {
            index: 0,
            timestamp: 0.0,
            pose: Pose::from_quaternion([0.5, -1.0, 2.0], [0.0, 0.0, 0.38268343, 0.9238795])
                .unwrap(),
        }
    }

    /// Depths with a gradient, holes and an out-of-range value.
    fn image() -> [u16; 16 * 12] {
        core::array::from_fn(|i| match i % 11 {
            0 => 0,
            1 => 60_000,
            _ => 500 + 37 * i as u16,
        })
    }

    /// The sampled rows of `image()` and the keys the projector emits for
    /// them, with its counts.
    fn sampled(cfg: &ScanConfig) -> (heapless::Vec<u16, 192>, heapless::Vec<u64, 192>, u32, u32) {
        let p = cfg.projector(&meta().pose).unwrap();
        let img = image();
        let (mut rows, mut keys, mut oor) = (heapless::Vec::new(), heapless::Vec::new(), 0);
        let mut valid = 0;
        for (v, row) in img.chunks_exact(16).enumerate() {
            valid += p.project_row(v as u16, row, &mut oor, |k| keys.push(k.to_bits()).unwrap());
            if p.samples_row(v as u16) {
                rows.extend(row.iter().step_by(cfg.stride as usize).copied());
            }
        }
        (rows, keys, valid, oor)
    }

    #[test]
    fn a_frame_filled_from_its_set_ends_as_a_pushed_one() {
        for stride in [1, 2, 3] {
            let cfg = scan(stride);
            let (rows, keys, valid, oor) = sampled(&cfg);
            let mut pushed = FrameIngest::<256>::new();
            pushed.begin(meta(), 0, &cfg).unwrap();
            pushed.push_rows(0, &rows).unwrap();
            let mut filled = FrameIngest::<256>::new();
            filled.begin(meta(), 0, &cfg).unwrap();
            assert!(filled.begun_with(&cfg));
            assert!(!filled.begun_with(&scan(stride + 1)));
            assert!(filled.fill_from_set(&keys, valid, oor));
            let (m1, k1, s1) = pushed.end().unwrap();
            let (m1, k1, s1) = (m1, heapless::Vec::<u64, 192>::from_slice(k1).unwrap(), s1);
            let (m2, k2, s2) = filled.end().unwrap();
            assert_eq!((m1, k1.as_slice(), s1), (m2, k2, s2), "stride {stride}");
            assert!(!k2.is_empty());
        }
    }

    #[test]
    fn filling_is_all_or_nothing() {
        let cfg = scan(1);
        let (rows, keys, valid, oor) = sampled(&cfg);
        let mut ingest = FrameIngest::<256>::new();
        assert!(!ingest.fill_from_set(&keys, valid, oor), "no frame");
        ingest.begin(meta(), 0, &cfg).unwrap();
        ingest.push_rows(0, &rows[..16]).unwrap();
        assert!(
            !ingest.fill_from_set(&keys, valid, oor),
            "rows already pushed"
        );
        let mut ingest = FrameIngest::<256>::new();
        ingest.begin(meta(), 0, &cfg).unwrap();
        assert!(!ingest.fill_from_set(&[u64::MAX], 1, 0), "not a key");
        // A set larger than the frame can hold would lose voxels.
        let mut small = FrameIngest::<8>::new();
        small.begin(meta(), 0, &cfg).unwrap();
        let mut sorted = keys.clone();
        sorted.sort_unstable();
        let distinct = 1 + sorted.windows(2).filter(|w| w[0] != w[1]).count();
        assert!(distinct > FrameIngest::<8>::VOXEL_LIMIT);
        assert!(!small.fill_from_set(&keys, valid, oor));
        let refused = Err(FrameError::MissingRows {
            received: 0,
            expected: 12,
        });
        assert_eq!(ingest.end().map(|_| ()), refused);
        assert_eq!(small.end().map(|_| ()), refused);
    }
}
