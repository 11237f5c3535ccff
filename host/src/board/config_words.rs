//! A device's scan configuration beside the one a host sends, in words:
//! the first setting in which they differ, with both values, so that a
//! refused `--extend` says what to change (as `select --extend` does for a
//! database directory, sessions/config.rs).

use placedb::protocol::Config;

/// The first setting in which `ours` (the configuration this command
/// sends) differs from `device`'s (the one its scan was made with), in
/// words naming the option and both values; `None` when they are equal.
pub fn difference(ours: &Config, device: &Config) -> Option<String> {
    let say = |option: &str, ours: String, theirs: String| {
        Some(format!(
            "{option} {ours} where the device's scan has {theirs}"
        ))
    };
    let (a, b) = (ours, device);
    if a.version != b.version {
        return say(
            "protocol version",
            a.version.to_string(),
            format!("version {}", b.version),
        );
    }
    if a.voxel_size != b.voxel_size {
        return say(
            "--voxel",
            a.voxel_size.to_string(),
            format!("voxel {}", b.voxel_size),
        );
    }
    if a.mu != b.mu {
        return say("--mu", a.mu.to_string(), format!("mu {}", b.mu));
    }
    if a.stride != b.stride {
        return say(
            "--stride",
            a.stride.to_string(),
            format!("stride {}", b.stride),
        );
    }
    let range = |c: &Config| format!("{},{}", c.depth_range.min, c.depth_range.max);
    if a.depth_range != b.depth_range {
        return say(
            "--depth-range",
            range(a),
            format!("depth range {}", range(b)),
        );
    }
    if a.window != b.window {
        return say(
            "--window",
            a.window.to_string(),
            format!("window {}", b.window),
        );
    }
    if a.sketch_margin != b.sketch_margin {
        return say(
            "--sketch-margin",
            a.sketch_margin.to_string(),
            format!("sketch margin {}", b.sketch_margin),
        );
    }
    let corner = |c: &Config| {
        let [x, y, z] = c.grid_origin;
        format!("({x}, {y}, {z})")
    };
    if a.grid_origin != b.grid_origin {
        return say(
            "the grid corner",
            corner(a),
            format!("the grid corner {} (--grid-origin)", corner(b)),
        );
    }
    let camera = |c: &Config| {
        let k = &c.intrinsics;
        format!(
            "{}x{} fx {} fy {} cx {} cy {}",
            k.width, k.height, k.fx, k.fy, k.cx, k.cy
        )
    };
    if a.intrinsics != b.intrinsics {
        return say("the camera", camera(a), format!("the camera {}", camera(b)));
    }
    if a.depth_scale != b.depth_scale {
        return say(
            "the depth scale",
            format!("{} units per metre", a.depth_scale),
            format!("{} units per metre", b.depth_scale),
        );
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use placedb::protocol::PROTOCOL_VERSION;

    fn config() -> Config {
        Config {
            version: PROTOCOL_VERSION,
            voxel_size: 0.3,
            mu: 0.3,
            depth_scale: 1000.0,
            intrinsics: placedb::Intrinsics {
                width: 640,
                height: 480,
                fx: 525.0,
                fy: 525.0,
                cx: 320.0,
                cy: 240.0,
            },
            stride: 4,
            depth_range: placedb::DepthRange { min: 0.1, max: 8.0 },
            grid_origin: [0.0; 3],
            window: 32,
            sketch_margin: 0.05,
        }
    }

    #[test]
    fn each_setting_is_named_with_both_values() {
        let c = config();
        assert_eq!(difference(&c, &c), None);
        let cases = [
            (
                Config { mu: 0.7, ..c },
                "--mu 0.7 where the device's scan has mu 0.3",
            ),
            (
                Config { stride: 2, ..c },
                "--stride 2 where the device's scan has stride 4",
            ),
            (
                Config { window: 8, ..c },
                "--window 8 where the device's scan has window 32",
            ),
            (
                Config {
                    voxel_size: 0.2,
                    ..c
                },
                "--voxel 0.2 where the device's scan has voxel 0.3",
            ),
            (
                Config {
                    depth_range: placedb::DepthRange { min: 0.1, max: 4.0 },
                    ..c
                },
                "--depth-range 0.1,4 where the device's scan has depth range 0.1,8",
            ),
            (
                Config {
                    intrinsics: placedb::Intrinsics {
                        fx: 600.0,
                        ..c.intrinsics
                    },
                    ..c
                },
                "the camera 640x480 fx 600 fy 525 cx 320 cy 240 where the device's scan has \
                 the camera 640x480 fx 525 fy 525 cx 320 cy 240",
            ),
            (
                Config {
                    depth_scale: 5000.0,
                    ..c
                },
                "the depth scale 5000 units per metre where the device's scan has 1000 units \
                 per metre",
            ),
        ];
        for (ours, words) in cases {
            assert_eq!(difference(&ours, &c).as_deref(), Some(words));
        }
    }
}
