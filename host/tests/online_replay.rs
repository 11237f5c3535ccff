//! The online replay fed from the yardstick's voxel sets
//! (`replay::replay_voxelized`, what `select --solver online` runs) decides
//! exactly as the replay that decodes and pushes every frame's rows, as a
//! board receives them: same decisions, database records and counters, on
//! a recorded sequence at every profile, and where frames overflow the
//! device's frame set (then those frames are decoded and pushed).

use placedb::SelectorConfig;
use placedb_host::voxelize::{voxelize, VoxelConfig};
use placedb_host::{board::scan, replay, Sequence};

fn seven_scenes(frames: usize) -> Sequence {
    placedb_host::testing::sample("7scenes-1000", frames)
}

/// Both replays of `seq`; asserts they agree and returns how many frames
/// the device truncated.
fn both_agree(seq: &Sequence, vcfg: &VoxelConfig, profile: &str, mu: f32) -> u32 {
    let sets = voxelize(seq, vcfg, None).unwrap();
    let scan = scan::scan_config(seq, vcfg).unwrap();
    let cfg = SelectorConfig {
        mu,
        window: 32,
        sketch_margin: 0.05,
    };
    let pushed = replay::replay(seq, profile, scan, cfg, 8, None).unwrap();
    let filled = replay::replay_voxelized(seq, &sets, profile, scan, cfg, 8, None).unwrap();
    let what = format!("{profile} mu {mu} voxel {}", vcfg.voxel);
    assert_eq!(pushed.decisions, filled.decisions, "{what}");
    assert_eq!(pushed.labels, filled.labels, "{what}");
    assert_eq!(pushed.database, filled.database, "{what}");
    assert_eq!(pushed.status, filled.status, "{what}");
    assert!(!filled.database.is_empty(), "{what}");
    pushed.status.truncated_frames
}

#[test]
fn voxel_sets_replay_as_pushed_rows_on_every_profile() {
    let seq = seven_scenes(300);
    for profile in ["ram256k", "ram512k", "ram1m"] {
        for mu in [0.1, 0.5] {
            let truncated = both_agree(&seq, &VoxelConfig::default(), profile, mu);
            assert_eq!(truncated, 0, "0.3 m voxels fit every profile's frame set");
        }
    }
}

#[test]
fn frames_the_device_truncates_are_pushed_and_agree_too() {
    // 5 cm voxels: most frames have more voxels than ram256k's frame set holds.
    let seq = seven_scenes(120);
    let vcfg = VoxelConfig {
        voxel: 0.05,
        ..VoxelConfig::default()
    };
    let truncated = both_agree(&seq, &vcfg, "ram256k", 0.3);
    assert!(truncated > 10, "only {truncated} frames truncated");
    assert!((truncated as usize) < seq.frames.len(), "some frames fit");
}
