//! Replays the committed fuzz corpus of the host readers' targets (ROS 2
//! bags, ROS 1 bags, compressed depth, depth PNGs) through the checks the fuzz targets run
//! (`fuzz/src/readers.rs`, included below), on stable: every file of
//! `fuzz/corpus/<target>/` and `fuzz/regressions/<target>/`. Fails when a
//! corpus directory is missing or empty. The core's targets replay in
//! `tests/fuzz_corpus.rs` at the workspace root.

#[path = "../../fuzz/src/corpus.rs"]
mod corpus;
#[path = "../../fuzz/src/readers.rs"]
mod readers;

use std::path::{Path, PathBuf};

fn replay(target: &str, check: fn(&[u8])) {
    let fuzz: PathBuf = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz");
    corpus::replay(&fuzz, target, check);
}

#[test]
fn ros2_corpus() {
    replay("ros2", readers::ros2);
}

#[test]
fn compressed_depth_corpus() {
    replay("compressed_depth", readers::compressed_depth);
}

#[test]
fn ros1_corpus() {
    replay("ros1", readers::ros1);
}

#[test]
fn depth_png_corpus() {
    replay("depth_png", readers::depth_png);
}
