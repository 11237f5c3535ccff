//! What a run lost, counted once for every command that voxelizes: frames
//! the reader skipped, frames without a valid depth pixel, points outside
//! the voxel key range ([`Losses`]), each non-zero one a warning line on
//! stderr; and the refusal of a run that measured nothing
//! ([`NothingMeasured`]), which says what to check: the depth scale, the
//! depth range, and what the first frames' raw depths mean in metres.

use crate::error::NothingMeasured;
use crate::sequence::Sequence;
use crate::voxelize::VoxelSets;
use placedb::DepthRange;

/// Voxels per axis on either side of the grid origin a key can name (keys
/// have 21 bits an axis, biased): points beyond are dropped and counted.
pub const KEY_HALF_RANGE_VOXELS: f64 = (1u64 << 20) as f64;

/// Frames whose raw depths [`NothingMeasured`] describes.
const FIRST_FRAMES: usize = 3;

/// What a run's input lost before any solver saw it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Losses {
    /// Source frames the reader skipped with a warning (`frames_skipped`).
    pub frames_skipped: usize,
    /// Frames without a valid depth pixel at the run's stride (`empty_frames`).
    pub empty_frames: usize,
    /// Points dropped because their voxel lies outside the key range
    /// (`out_of_range_points`).
    pub out_of_range_points: u64,
    /// Frames that lost at least one such point.
    pub out_of_range_frames: usize,
}

impl Losses {
    /// The losses of `seq` voxelized into `sets`.
    pub fn of(seq: &Sequence, sets: &VoxelSets) -> Losses {
        Losses {
            frames_skipped: seq.frames_skipped,
            empty_frames: sets.valid_pixels.iter().filter(|&&v| v == 0).count(),
            out_of_range_points: sets.out_of_range,
            out_of_range_frames: sets.frame_out_of_range.iter().filter(|&&p| p > 0).count(),
        }
    }

    /// One line of a text summary naming every count, zero or not.
    pub fn summary_line(&self) -> String {
        format!(
            "  input: {} skipped by the reader, {} without a valid depth pixel, {} outside the voxel key range",
            plural(self.frames_skipped as u64, "frame", "frames"),
            plural(self.empty_frames as u64, "frame", "frames"),
            plural(self.out_of_range_points, "point", "points"),
        )
    }

    /// A warning for each non-zero count (the reader has already warned
    /// about each skipped frame; this is the total).
    pub fn warnings(&self) -> Vec<String> {
        let mut w = Vec::new();
        if self.frames_skipped > 0 {
            w.push(format!(
                "{} of the source skipped by the reader, each named above (frames_skipped)",
                plural(self.frames_skipped as u64, "frame", "frames")
            ));
        }
        if self.empty_frames > 0 {
            w.push(format!(
                "{} without a valid depth pixel (empty_frames: no depth, or none in --depth-range): they overlap nothing",
                plural(self.empty_frames as u64, "frame", "frames")
            ));
        }
        if self.out_of_range_points > 0 {
            // A device counts points only, not the frames they came from.
            let frames = match self.out_of_range_frames {
                0 => String::new(),
                n => format!(" in {}", plural(n as u64, "frame", "frames")),
            };
            w.push(format!(
                "{}{frames} dropped: outside the voxel key range (out_of_range_points): a camera far from the grid origin?",
                plural(self.out_of_range_points, "point", "points"),
            ));
        }
        w
    }
}

/// The one summary line of an online run (`select`, `select --extend` and
/// `compare` print it): the core's profile and window, then each of its
/// counters, zero or not.
pub fn online_summary(profile: &str, window: u16, st: &placedb::Status) -> String {
    format!(
        "online core: profile {profile}, window {window}, {} without exact keys ({} for the key pool, {} after the key budget; {} measured by sketch), {} truncated, {} uncovered by capacity, {} outside the key range",
        plural(
            u64::from(st.sketched_frames) + u64::from(st.unkeyed_frames),
            "frame",
            "frames"
        ),
        st.sketched_frames,
        st.unkeyed_frames,
        st.sketch_compared_frames,
        st.truncated_frames,
        st.uncovered_frames,
        plural(st.out_of_range_points.into(), "point", "points"),
    )
}

/// The degradations the online core (a device, or its replay) counted
/// beyond [`Losses`], as warning lines: empty when it lost nothing.
pub fn device_warnings(st: &DeviceCounters) -> Vec<String> {
    let mut w = Vec::new();
    let mut say = |n: u64, one: &str, many: &str, what: &str| {
        if n > 0 {
            w.push(format!("the online core: {} {what}", plural(n, one, many)));
        }
    };
    say(
        st.sketched_frames,
        "frame",
        "frames",
        "compared by sketch (its key pool was full): sketched_frames",
    );
    say(
        st.unkeyed_frames,
        "frame",
        "frames",
        "compared by sketch (the key budget of the flash log was spent): unkeyed_frames",
    );
    say(
        st.sketch_compared_frames,
        "frame",
        "frames",
        "measured by sketch against some frame (a coverage decision may rest on an estimate): sketch_compared_frames",
    );
    say(
        st.truncated_frames,
        "frame",
        "frames",
        "truncated (more voxels than a frame holds): truncated_frames",
    );
    say(
        st.uncovered_frames,
        "frame",
        "frames",
        "decided uncovered for lack of room: uncovered_by_capacity",
    );
    say(
        st.labels_dropped,
        "label",
        "labels",
        "dropped for lack of room: labels_dropped",
    );
    w
}

/// The counters of [`device_warnings`], from a replay's or a device's status.
#[derive(Debug, Clone, Copy, Default)]
pub struct DeviceCounters {
    /// Frames compared by sketch.
    pub sketched_frames: u64,
    /// Frames without exact keys because the key budget was spent.
    pub unkeyed_frames: u64,
    /// Frames measured by sketch against some frame.
    pub sketch_compared_frames: u64,
    /// Frames whose voxel set was truncated.
    pub truncated_frames: u64,
    /// Frames decided uncovered for lack of capacity.
    pub uncovered_frames: u64,
    /// Labels dropped for lack of room (a device's status only).
    pub labels_dropped: u64,
}

impl DeviceCounters {
    /// The counters of a replay's selector status.
    pub fn of_selector(st: &placedb::Status) -> Self {
        DeviceCounters {
            sketched_frames: st.sketched_frames.into(),
            unkeyed_frames: st.unkeyed_frames.into(),
            sketch_compared_frames: st.sketch_compared_frames.into(),
            truncated_frames: st.truncated_frames.into(),
            uncovered_frames: st.uncovered_frames.into(),
            labels_dropped: 0,
        }
    }

    /// The counters of a device's status message.
    pub fn of_device(st: &placedb::protocol::Status) -> Self {
        DeviceCounters {
            sketched_frames: st.sketched_frames.into(),
            unkeyed_frames: st.unkeyed_frames.into(),
            sketch_compared_frames: st.sketch_compared_frames.into(),
            truncated_frames: st.truncated_frames.into(),
            uncovered_frames: st.uncovered_frames.into(),
            labels_dropped: st.labels_dropped.into(),
        }
    }
}

/// "1 frame", "2 frames", "0 frames".
pub fn plural(n: u64, one: &str, many: &str) -> String {
    if n == 1 {
        format!("1 {one}")
    } else {
        format!("{n} {many}")
    }
}

/// Refuses a sequence without frames.
pub fn check_frames(seq: &Sequence) -> Result<(), NothingMeasured> {
    if seq.frames.is_empty() {
        return Err(NothingMeasured(format!(
            "{}: no frame to work on (--max-frames 0, --demo-frames 0, or an empty sequence): nothing was measured",
            seq.name
        )));
    }
    Ok(())
}

/// Refuses `sets` (of `seq` voxelized with `range`) when no frame has a
/// voxel: no valid depth pixel anywhere, or every point out of key range.
pub fn check_measured(
    seq: &Sequence,
    range: DepthRange,
    voxel: f32,
    sets: &VoxelSets,
) -> Result<(), NothingMeasured> {
    check_frames(seq)?;
    if sets.sets.iter().any(|s| !s.is_empty()) {
        return Ok(());
    }
    if sets.valid_pixels.iter().all(|&v| v == 0) {
        return Err(no_valid_pixel(seq, range));
    }
    let km = KEY_HALF_RANGE_VOXELS * f64::from(voxel) / 1e3;
    let t = seq.frames[0].translation;
    Err(NothingMeasured(format!(
        "{}: every point of its {} fell outside the voxel key range (±2^20 voxels of {voxel} m \
         from the grid origin on each axis: ±{km:.0} km), so nothing was measured; the first \
         camera is at ({:.0}, {:.0}, {:.0}) m: check the poses' units, or anchor the grid at the \
         scene with --grid-origin scene-min",
        seq.name,
        plural(seq.frames.len() as u64, "frame", "frames"),
        t[0],
        t[1],
        t[2]
    )))
}

/// The refusal of a run whose frames have no valid depth pixel in `range`:
/// what the first frames' raw depths are and mean at the sequence's scale.
pub fn no_valid_pixel(seq: &Sequence, range: DepthRange) -> NothingMeasured {
    let scale = seq.depth_scale;
    let mut seen = Vec::new();
    for (i, f) in seq.frames.iter().enumerate().take(FIRST_FRAMES) {
        let what = match seq.depth(i) {
            Err(e) => format!("unreadable ({e})"),
            Ok(img) => {
                let data = &img.data;
                let zero = data.iter().filter(|&&d| d == 0).count();
                let nonzero = data.iter().copied().filter(|&d| d != 0);
                match (nonzero.clone().min(), nonzero.max()) {
                    (Some(lo), Some(hi)) => format!(
                        "{} pixels, {zero} of them 0 (no depth), the others {lo}..{hi} = {:.3}..{:.3} m",
                        data.len(),
                        f64::from(lo) / scale,
                        f64::from(hi) / scale
                    ),
                    _ => format!("{} pixels, all 0 (no depth)", data.len()),
                }
            }
        };
        seen.push(format!("frame {i} ({}): {what}", f.depth_name));
    }
    let max = if range.max.is_finite() {
        format!("{} m", range.max)
    } else {
        "inf".to_string()
    };
    NothingMeasured(format!(
        "{}: none of its {} has a valid depth pixel, so nothing was measured. Check the depth \
         scale (--depth-scale, now {scale} units per metre) and the depth range (--depth-range, \
         now {} m < z <= {max}). Raw depths at this scale: {}",
        seq.name,
        plural(seq.frames.len() as u64, "frame", "frames"),
        range.min,
        seen.join("; ")
    ))
}

/// Refuses `seq` before it is streamed when no frame has a valid depth
/// pixel in `range` at `stride` (as [`check_measured`] would after
/// voxelizing): frames are decoded in order until one has, so a good
/// sequence costs one frame.
pub fn check_depth(seq: &Sequence, range: DepthRange, stride: u16) -> Result<(), NothingMeasured> {
    check_frames(seq)?;
    let s = usize::from(stride.max(1));
    let valid = |raw: u16| {
        let z = f64::from(raw) / seq.depth_scale;
        raw != 0 && z > f64::from(range.min) && z <= f64::from(range.max)
    };
    let mut img = crate::sequence::DepthImage::default();
    for i in 0..seq.frames.len() {
        // An unreadable frame is the stream's to report, with its name.
        if seq.depth_into(i, &mut img).is_err() {
            return Ok(());
        }
        let w = usize::from(img.width).max(1);
        if img
            .data
            .chunks_exact(w)
            .step_by(s)
            .any(|row| row.iter().step_by(s).any(|&d| valid(d)))
        {
            return Ok(());
        }
    }
    Err(no_valid_pixel(seq, range))
}
