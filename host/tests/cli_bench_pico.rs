//! `placedb bench --pico --json` (issue 24, item 2): its keys and rows, each
//! row's figures as the bench's model says they follow from what it
//! measured (the emulator's cycles at the row's own stride, the host's
//! steady-state flash count), and the host's flash count equal to the
//! emulator's on the frames both ran (counts, not times: deterministic);
//! each stride's scan after a warm-up (here of one frame, to keep the test
//! cheap), its cycles and pixels kept apart from the frames measured.
//!
//! Needs what host/tests/board_rp2040.rs needs: Node 20 and `npm ci` in
//! boards/rp-pico/emulator, the boot ROM in ../shared/rp2040; the firmware
//! is built on first use.

mod cli_common;

use cli_common::{placedb, seven_scenes_copy, stderr, TempDir};
use serde_json::Value;

const CLOCK_HZ: f64 = 133e6;
/// Frames of the 7-Scenes copy (the whole sequence the flash is counted on).
const FRAMES: usize = 3;
/// Frames of each stride's scan not counted.
const WARM_UP: f64 = 1.0;

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1.0)
}

fn num(v: &Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("no number {key} in {v}"))
}

/// The entry of `list` (an array of objects) whose "stride" is `stride`.
fn at_stride(list: &Value, stride: f64) -> &Value {
    list.as_array()
        .unwrap_or_else(|| panic!("not a list: {list}"))
        .iter()
        .find(|e| num(e, "stride") == stride)
        .unwrap_or_else(|| panic!("no stride {stride} in {list}"))
}

#[test]
fn bench_pico_json_rows_follow_from_what_was_measured() {
    let t = TempDir::new("bench-pico");
    seven_scenes_copy(&t.path().join("7scenes-1000"), FRAMES, true);
    let out = placedb(&[
        "bench",
        "--pico",
        "--json",
        "--device-frames",
        "1",
        "--warm-up",
        "1",
        "--data",
        &t.path().display().to_string(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let j: Value = serde_json::from_slice(&out.stdout).expect("one JSON object");
    let sequences = [("7scenes-1000", 640.0, 1.0), ("synthetic", 320.0, 2.0)];

    for (name, _, emulated_frames) in sequences {
        // The headline: the marginal between strides 2 and 4, as before.
        let emulated = &j["emulated"][name];
        let (fine, coarse) = (at_stride(emulated, 2.0), at_stride(emulated, 4.0));
        assert_eq!(num(&j["warm_up"], name), WARM_UP, "{j}");
        for e in emulated.as_array().unwrap() {
            // The warm-up's frames and pixels are not the measured ones'.
            assert_eq!(num(e, "frames"), emulated_frames, "{e}");
            assert_eq!(num(&e["warm_up"], "frames"), WARM_UP, "{e}");
            assert!(num(&e["warm_up"], "cycles") > 0.0, "{e}");
            assert!(num(&e["warm_up"], "valid_pixels") > 0.0, "{e}");
        }
        let marginal = (num(fine, "cycles") - num(coarse, "cycles"))
            / (num(fine, "valid_pixels") - num(coarse, "valid_pixels"));
        let headline = num(&j["cycles_per_valid_pixel"], name);
        assert!(
            close(headline, marginal),
            "{name}: {headline} vs {marginal}"
        );
        let per_frame = num(coarse, "cycles") - marginal * num(coarse, "valid_pixels");
        assert!(
            close(num(&j["cycles_per_frame"], name), per_frame),
            "{name}"
        );
        assert!(num(&j["core_cycles_per_valid_pixel"], name) < headline);

        // The host counts the flash work of the emulator's own streams as
        // the emulator does.
        let check = &j["flash_check"][name];
        assert_eq!(check["agree"], Value::Bool(true), "{name}: {check}");
        assert_eq!(check["emulator"], check["host"], "{name}: {check}");
        assert_eq!(
            num(check, "frames"),
            5.0 * (WARM_UP + emulated_frames),
            "{check}"
        );
        assert!(num(&check["emulator"], "programs") > 0.0, "{check}");

        // The steady-state flash count runs over the whole sequence.
        let whole = if name == "synthetic" {
            600.0
        } else {
            FRAMES as f64
        };
        for f in j["flash"][name].as_array().unwrap() {
            assert_eq!(num(f, "frames"), whole, "{f}");
            let ms = (num(f, "erases") * 45.0 + num(f, "programs") * 0.4) / whole;
            assert!(close(num(f, "ms_per_frame"), ms), "{f}");
        }
    }

    let rows = j["fps"].as_array().expect("fps rows");
    assert_eq!(rows.len(), 12, "{rows:?}");
    let mut k = 0;
    for (w, h) in [(160.0, 120.0), (320.0, 240.0)] {
        for s in [1.0, 2.0, 4.0] {
            for (name, width, _) in sequences {
                let r = &rows[k];
                k += 1;
                assert_eq!(r["depth"], format!("{w}x{h}"), "{r}");
                assert_eq!(num(r, "stride"), s, "{r}");
                assert_eq!(r["sequence"], name, "{r}");
                let samples = (w / s) * (h / s);
                assert_eq!(num(r, "samples"), samples, "{r}");
                assert!(close(num(r, "usb"), 1.1e6 / (samples * 2.02)), "{r}");
                // Measured at the sequence's stride that samples as the
                // camera does, the marginal between it and twice it.
                let d = s * width / w;
                assert_eq!(num(r, "measured_at_stride"), d, "{r}");
                let emulated = &j["emulated"][name];
                let (here, next) = (at_stride(emulated, d), at_stride(emulated, 2.0 * d));
                let valid = num(here, "valid_pixels");
                assert_eq!(num(r, "valid_samples"), valid, "{r}");
                assert!(valid <= samples, "{r}");
                let marginal = (num(here, "cycles") - num(next, "cycles"))
                    / (valid - num(next, "valid_pixels"));
                assert!(close(num(r, "cycles_per_valid_pixel"), marginal), "{r}");
                let cycles = num(here, "cycles") + (samples - valid) * marginal;
                assert!(close(num(r, "cycles_per_frame"), cycles), "{r}");
                let flash = num(at_stride(&j["flash"][name], d), "ms_per_frame");
                assert!(close(num(r, "flash_ms_per_frame"), flash), "{r}");
                let fps = 1.0 / (cycles / CLOCK_HZ + flash / 1e3);
                assert!(close(num(r, "pico"), fps), "{r}: {fps}");
                assert!(
                    close(num(r, "pico_without_flash"), CLOCK_HZ / cycles),
                    "{r}"
                );
            }
        }
    }
}
