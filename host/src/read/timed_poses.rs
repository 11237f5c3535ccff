//! The pose of a frame from a pose source sampled at its own times (TUM's
//! `groundtruth.txt`, ROS PoseStamped, Odometry and TF links): interpolated
//! between the two samples around the frame's stamp (the default), or the
//! nearest sample.
//!
//! A camera at 30 Hz against a pose source at 10-30 Hz is between samples at
//! almost every frame; taking the nearest sample carries up to half a pose
//! period of motion into the frame. Interpolation is linear in position and
//! spherical-linear in rotation. Both rules take a frame only when a sample
//! lies within the tolerance of its stamp, so the two rules take the same
//! frames except at the ends: interpolation never extrapolates, so a frame
//! before the first sample or after the last is not taken. A frame whose
//! stamp equals a sample's gets that sample bit for bit.

pub use crate::sequence::PoseInterpolation;
use nalgebra::{Quaternion, UnitQuaternion, Vector3};

/// A pose sample: translation (metres) and quaternion `[x, y, z, w]` at a
/// time (seconds).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimedPose {
    /// Seconds.
    pub stamp: f64,
    /// Metres.
    pub translation: [f64; 3],
    /// `[x, y, z, w]`, not necessarily of unit length.
    pub rotation: [f64; 4],
}

/// The unit quaternion of `q` (`[x, y, z, w]`); a zero one is the identity
/// (the readers refuse it before it gets here).
fn unit(q: [f64; 4]) -> UnitQuaternion<f64> {
    UnitQuaternion::new_normalize(Quaternion::new(q[3], q[0], q[1], q[2]))
}

/// Index of the sample of `sorted` (ascending stamps) nearest to `t`
/// within `tolerance`; ties go to the earlier one.
pub fn nearest(sorted: &[TimedPose], t: f64, tolerance: f64) -> Option<usize> {
    let i = sorted.partition_point(|s| s.stamp < t);
    [i.checked_sub(1), (i < sorted.len()).then_some(i)]
        .into_iter()
        .flatten()
        .map(|j| (j, (sorted[j].stamp - t).abs()))
        .filter(|&(_, d)| d <= tolerance)
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(j, _)| j)
}

/// The pose at `t` from `sorted` (ascending stamps) by `rule`, or `None`
/// when no sample lies within `tolerance` of `t` or, interpolating, `t` is
/// outside the samples' span.
pub fn pose_at(
    sorted: &[TimedPose],
    t: f64,
    tolerance: f64,
    rule: PoseInterpolation,
) -> Option<TimedPose> {
    let near = nearest(sorted, t, tolerance)?;
    if rule == PoseInterpolation::Nearest || sorted[near].stamp == t {
        return Some(sorted[near]);
    }
    let after = sorted.partition_point(|s| s.stamp < t);
    let (a, b) = (sorted.get(after.checked_sub(1)?)?, sorted.get(after)?);
    Some(interpolate(a, b, t))
}

/// The pose between samples `a` and `b` (`a.stamp < t < b.stamp`).
pub fn interpolate(a: &TimedPose, b: &TimedPose, t: f64) -> TimedPose {
    let u = (t - a.stamp) / (b.stamp - a.stamp);
    let (ta, tb) = (Vector3::from(a.translation), Vector3::from(b.translation));
    let translation = ta + (tb - ta) * u;
    let (qa, mut qb) = (unit(a.rotation), unit(b.rotation));
    // The shorter way round: q and -q are the same rotation.
    if qa.coords.dot(&qb.coords) < 0.0 {
        qb = UnitQuaternion::new_unchecked(-qb.into_inner());
    }
    // Nearly equal rotations: slerp's sin(angle) is too small to divide by,
    // and normalised linear interpolation is exact to rounding there.
    let q = qa.try_slerp(&qb, u, 1e-9).unwrap_or_else(|| {
        UnitQuaternion::new_normalize(qa.into_inner().lerp(&qb.into_inner(), u))
    });
    TimedPose {
        stamp: t,
        translation: translation.into(),
        rotation: [q.i, q.j, q.k, q.w],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(stamp: f64, x: f64, yaw: f64) -> TimedPose {
        let q = UnitQuaternion::from_euler_angles(0.0, 0.0, yaw);
        TimedPose {
            stamp,
            translation: [x, 0.0, 0.0],
            rotation: [q.i, q.j, q.k, q.w],
        }
    }

    #[test]
    fn between_samples_position_is_linear_and_rotation_spherical() {
        let track = [sample(1.0, 0.0, 0.0), sample(1.1, 1.0, 1.0)];
        let p = pose_at(&track, 1.025, 0.05, PoseInterpolation::Linear).unwrap();
        assert!((p.translation[0] - 0.25).abs() < 1e-12);
        let yaw = unit(p.rotation).euler_angles().2;
        assert!((yaw - 0.25).abs() < 1e-12, "{yaw}");
        // Nearest takes the first sample whole.
        let n = pose_at(&track, 1.025, 0.05, PoseInterpolation::Nearest).unwrap();
        assert_eq!(n, track[0]);
        // The far side of -q: the same rotation, the short way round.
        let mut flipped = track;
        flipped[1].rotation = flipped[1].rotation.map(|c| -c);
        let f = pose_at(&flipped, 1.025, 0.05, PoseInterpolation::Linear).unwrap();
        assert!((unit(f.rotation).euler_angles().2 - 0.25).abs() < 1e-12);
    }

    #[test]
    fn a_sample_at_the_stamp_is_kept_bit_for_bit_and_nothing_is_extrapolated() {
        let mut s = sample(2.0, 0.1, 0.3);
        s.rotation = s.rotation.map(|c| c * 1.0000001);
        let track = [sample(1.0, 0.0, 0.0), s, sample(3.0, 1.0, 0.0)];
        assert_eq!(
            pose_at(&track, 2.0, 0.0, PoseInterpolation::Linear),
            Some(s)
        );
        // Within the tolerance of the first sample, but before it.
        assert_eq!(pose_at(&track, 0.99, 0.05, PoseInterpolation::Linear), None);
        assert_eq!(
            pose_at(&track, 0.99, 0.05, PoseInterpolation::Nearest),
            Some(track[0])
        );
        assert_eq!(pose_at(&track, 3.01, 0.05, PoseInterpolation::Linear), None);
        // In a gap: no sample within the tolerance.
        assert_eq!(pose_at(&track, 1.5, 0.05, PoseInterpolation::Linear), None);
        assert!(pose_at(&track, 1.5, 0.5, PoseInterpolation::Linear).is_some());
        assert_eq!(pose_at(&[], 1.0, 1.0, PoseInterpolation::Linear), None);
    }
}
