//! The value parsers of the command line's numeric options: one per kind of
//! parameter, shared by every command that takes it, so a value out of range
//! is refused while the command line is parsed (before any file is read or
//! written) with the same words everywhere. The ranges are the core's where
//! the core has one ([`VoxelGrid::SIZE_RANGE`],
//! [`FrameProjector::DEPTH_SCALE_RANGE`], the profiles' windows).
//!
//! Options that take a negative number are declared with
//! `allow_negative_numbers` (or `allow_hyphen_values` for comma lists), so
//! `--mu -1` reaches its parser as `--mu=-1` does and both get the range.

use crate::error::UsageError;
use crate::CameraModel;
use clap::builder::PossibleValuesParser;
use placedb::{FrameProjector, VoxelGrid};

/// A number, or words saying it is not one.
fn number<T: std::str::FromStr>(s: &str) -> Result<T, String> {
    s.trim()
        .parse()
        .map_err(|_| format!("`{}` is not a number", s.trim()))
}

/// `--unique-id`: a flash chip's 64-bit unique ID, 16 hex digits.
pub fn unique_id(s: &str) -> Result<u64, String> {
    let s = s.trim();
    if s.len() != 16 || !s.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err(format!(
            "a unique ID is 16 hex digits (64 bits, as E6614103E7452D2F), got `{s}`"
        ));
    }
    u64::from_str_radix(s, 16).map_err(|_| format!("`{s}` is not 16 hex digits"))
}

/// `--mu`: the IoU threshold, from 0 to below 1 (two frames overlap when
/// their IoU is above it, so at 1 no frame would overlap another).
pub fn mu(s: &str) -> Result<f32, String> {
    let mu: f32 = number(s)?;
    if !(0.0..1.0).contains(&mu) {
        return Err(format!(
            "mu must be from 0 to below 1 (frames overlap when their IoU is above mu), got {mu}"
        ));
    }
    Ok(mu)
}

/// `--voxel`: the voxel edge, metres, within the core's
/// [`VoxelGrid::SIZE_RANGE`].
pub fn voxel(s: &str) -> Result<f32, String> {
    let v: f32 = number(s)?;
    let r = VoxelGrid::SIZE_RANGE;
    if !r.contains(&v) {
        return Err(format!(
            "the voxel edge must be from {} to {} metres, got {v}",
            r.start(),
            r.end()
        ));
    }
    Ok(v)
}

/// `--depth-scale`: depth units per metre, within the core's
/// [`FrameProjector::DEPTH_SCALE_RANGE`].
pub fn depth_scale(s: &str) -> Result<f64, String> {
    let scale: f64 = number(s)?;
    let r = FrameProjector::DEPTH_SCALE_RANGE;
    if !(f64::from(*r.start())..=f64::from(*r.end())).contains(&scale) {
        return Err(format!(
            "the depth scale must be from {} to {} units per metre (1000 for millimetres), \
             got {scale}",
            r.start(),
            r.end()
        ));
    }
    Ok(scale)
}

/// `--depth-range`: "min,max" in metres with `0 <= min < max` (max may be
/// `inf`).
pub fn depth_range(s: &str) -> Result<(f32, f32), String> {
    let (a, b) = s
        .split_once(',')
        .ok_or("expected min,max in metres, e.g. 0.1,10")?;
    let (min, max): (f32, f32) = (number(a)?, number(b)?);
    if !(min >= 0.0 && max > min) {
        return Err(format!(
            "the depth range must be min,max with 0 <= min < max metres, got {min},{max}"
        ));
    }
    Ok((min, max))
}

/// `--intrinsics`: "fx,fy,cx,cy" in pixels, checked as an intrinsics file is.
pub fn intrinsics(s: &str) -> Result<CameraModel, String> {
    let v: Vec<f64> = s.split(',').map(number).collect::<Result<_, _>>()?;
    let k = match v[..] {
        [fx, fy, cx, cy] => CameraModel { fx, fy, cx, cy },
        _ => return Err("expected four numbers fx,fy,cx,cy (pixels)".into()),
    };
    crate::read::check_camera(&k)?;
    Ok(k)
}

/// A length that must be above zero (`--distance`, `--cube`, metres).
pub fn positive(s: &str) -> Result<f64, String> {
    let x: f64 = number(s)?;
    if !(x.is_finite() && x > 0.0) {
        return Err(format!("must be a finite number above 0, got {x}"));
    }
    Ok(x)
}

/// The longest `--time-limit`, seconds (about 11.6 days): above it the
/// limit would not fit a duration, and no run waits that long.
pub const MAX_TIME_LIMIT: f64 = 1e6;

/// `--time-limit`: seconds, above 0 to [`MAX_TIME_LIMIT`].
pub fn time_limit(s: &str) -> Result<f64, String> {
    let x: f64 = number(s)?;
    if !(x > 0.0 && x <= MAX_TIME_LIMIT) {
        return Err(format!(
            "must be from above 0 to {MAX_TIME_LIMIT} seconds, got {}",
            s.trim()
        ));
    }
    Ok(x)
}

/// A time tolerance, seconds, that may be zero (`--pose-tolerance`).
pub fn non_negative_seconds(s: &str) -> Result<f64, String> {
    let x: f64 = number(s)?;
    if !(x.is_finite() && x >= 0.0) {
        return Err(format!(
            "must be a finite number of seconds, 0 or more, got {x}"
        ));
    }
    Ok(x)
}

/// A whole number from `min` to `max` (`u64::MAX`: no upper end), for
/// every count, size and seed of the command line (`--every-nth`,
/// `--max-frames`, `--stride`, `--frames`, ...): refused in words with its
/// range, a negative or a huge value as well as 0, so each says the same
/// thing ("must be a whole number from 1 to 64, got 0").
pub fn whole<T>(min: u64, max: u64) -> impl Fn(&str) -> Result<T, String> + Clone + Send + Sync
where
    T: TryFrom<u64> + Clone + Send + Sync + 'static,
{
    move |s: &str| {
        let s = s.trim();
        let range = if max == u64::MAX {
            format!(", {min} or more")
        } else {
            format!(" from {min} to {max}")
        };
        let refused = || format!("must be a whole number{range}, got {s}");
        let digits = s.strip_prefix('-').unwrap_or(s);
        if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
            return Err(format!("`{s}` is not a whole number; give one{range}"));
        }
        if max == u64::MAX && digits.len() > 19 && !s.starts_with('-') {
            return Err(format!("{s} is too large{range}"));
        }
        // Too many digits for any count is out of range, not "no number".
        let n: i128 = s.parse().map_err(|_| refused())?;
        if max == u64::MAX && n > i128::from(max) {
            return Err(format!("{s} is too large{range}"));
        }
        if n < i128::from(min) || n > i128::from(max) {
            return Err(refused());
        }
        T::try_from(n as u64).map_err(|_| refused())
    }
}

/// The most frames of a synthetic scan (`--demo-frames`, `synth --frames`,
/// the bench's scans): its poses and the sets of a million frames already
/// take gigabytes.
pub const MAX_SYNTH_FRAMES: u64 = 1_000_000;

/// The most frames any profile holds undecided: the top of `--window`'s
/// range ([`check_window`] then holds it to the chosen profile's).
fn widest_window() -> u64 {
    placedb::profile::PROFILES
        .iter()
        .map(|p| p.window as u64)
        .max()
        .unwrap_or(1)
}

/// `stream --rate`: frames per second, above 0 to
/// [`crate::board::pacing::MAX_RATE`].
pub fn rate(s: &str) -> Result<f64, String> {
    let hz: f64 = number(s)?;
    let max = crate::board::pacing::MAX_RATE;
    if !(hz > 0.0 && hz <= max) {
        return Err(format!(
            "a replay rate is from above 0 to {max} frames per second, got {hz}"
        ));
    }
    Ok(hz)
}

/// A chance from 0 to 1 (`stream --drop-chance`, `--corrupt-chance`).
pub fn chance(s: &str) -> Result<f64, String> {
    let p: f64 = number(s)?;
    if !(0.0..=1.0).contains(&p) {
        return Err(format!("must be a chance from 0 to 1, got {p}"));
    }
    Ok(p)
}

/// `--profile`: one of the core's capacity profiles, by name.
pub fn profile() -> PossibleValuesParser {
    PossibleValuesParser::new(placedb::profile::PROFILES.iter().map(|p| p.name))
}

/// `--window`: frames held undecided, from 1 to the widest profile's
/// window; [`check_window`] then holds it to the chosen profile's window,
/// naming it.
pub fn window() -> impl Fn(&str) -> Result<u16, String> + Clone + Send + Sync {
    whole(1, widest_window())
}

/// Refuses a `--window` above what `profile` holds (the profile's window
/// is the most frames a device of that profile keeps undecided), naming
/// the cap, so the window printed and recorded is the one used; a usage
/// error (status 2) as a value out of its parser's range is.
pub fn check_window(profile: &str, window: u16) -> Result<(), UsageError> {
    let caps = placedb::profile::by_name(profile).ok_or_else(|| {
        UsageError(format!(
            "unknown --profile `{profile}`; see `placedb budget`"
        ))
    })?;
    if window == 0 || usize::from(window) > caps.window {
        return Err(UsageError(format!(
            "--window {window}: the {profile} profile holds from 1 to {} frames undecided; \
             give --window {} or less (or a larger --profile, see `placedb budget`)",
            caps.window, caps.window
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_refuse_their_edges_and_nan() {
        assert_eq!(mu("0"), Ok(0.0));
        assert!(mu("0.999").is_ok());
        for bad in ["1", "1.5", "-1", "nan", "inf", "x"] {
            assert!(mu(bad).is_err(), "{bad}");
        }
        assert_eq!(voxel("0.001"), Ok(0.001));
        assert_eq!(voxel("100"), Ok(100.0));
        for bad in ["0.0005", "0", "-0.3", "nan", "101"] {
            let e = voxel(bad).unwrap_err();
            assert!(e.contains("from 0.001 to 100 metres"), "{e}");
        }
        for bad in ["0", "-1", "nan", "0.5", "2e6"] {
            assert!(depth_scale(bad).is_err(), "{bad}");
        }
        assert_eq!(depth_range("0.1,inf"), Ok((0.1, f32::INFINITY)));
        for bad in ["1,1", "2,1", "-1,3", "nan,3", "1"] {
            assert!(depth_range(bad).is_err(), "{bad}");
        }
        for bad in ["0", "-1", "nan", "inf"] {
            assert!(positive(bad).is_err(), "{bad}");
        }
        for bad in ["0", "-1", "nan", "inf", "1e300"] {
            let e = time_limit(bad).unwrap_err();
            assert!(e.contains("from above 0 to 1000000 seconds"), "{bad}: {e}");
        }
        assert_eq!(time_limit("1000000"), Ok(1e6));
        assert_eq!(non_negative_seconds("0"), Ok(0.0));
        assert!(non_negative_seconds("-0.1").is_err());
        let count = whole::<usize>(1, u64::MAX);
        assert_eq!(count("1"), Ok(1));
        assert!(count("0").is_err() && count("-3").is_err());
        let stride = whole::<u16>(1, 64);
        assert_eq!(stride("64"), Ok(64));
        for bad in [
            "0",
            "65",
            "-1",
            "99999999999999999999999999999999999999999",
            "1.5",
        ] {
            let e = stride(bad).unwrap_err();
            assert!(e.contains("from 1 to 64"), "{bad}: {e}");
        }
        assert_eq!(
            whole::<u16>(0, 65535)("65536").unwrap_err(),
            "must be a whole number from 0 to 65535, got 65536"
        );
        assert!(chance("1").is_ok() && chance("1.1").is_err() && chance("nan").is_err());
        assert!(intrinsics("0,525,320,240").is_err());
        assert!(intrinsics("525,525,320").is_err());
    }

    #[test]
    fn the_window_is_held_to_the_profile() {
        for p in placedb::profile::PROFILES {
            assert!(check_window(p.name, p.window as u16).is_ok());
            let e = check_window(p.name, p.window as u16 + 1).unwrap_err();
            assert!(e.to_string().contains(&p.window.to_string()), "{e}");
        }
    }
}
