//! Replays the committed fuzz corpus through the fuzz harness, on stable, as
//! part of the normal test suite: every file of `fuzz/corpus/<target>/` and
//! `fuzz/regressions/<target>/` must pass the very checks the fuzz targets
//! run (`fuzz/src/harness.rs`, included below). Fails when a corpus
//! directory is missing or empty.

#[path = "../fuzz/src/harness.rs"]
mod harness;
#[path = "../fuzz/src/readers.rs"]
mod readers;

use std::path::{Path, PathBuf};

/// Files of `dir`, sorted; none when it does not exist.
fn files(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut files: Vec<PathBuf> = entries
        .map(|e| e.expect("read corpus directory").path())
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    files
}

fn replay(target: &str, check: fn(&[u8])) {
    let fuzz = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz");
    let corpus = files(&fuzz.join("corpus").join(target));
    assert!(
        !corpus.is_empty(),
        "fuzz/corpus/{target}/ is missing or empty"
    );
    let regressions = files(&fuzz.join("regressions").join(target));
    for path in corpus.iter().chain(&regressions) {
        let data = std::fs::read(path).expect("read corpus file");
        let outcome = std::panic::catch_unwind(|| check(&data));
        assert!(outcome.is_ok(), "{target}: {} fails", path.display());
    }
}

#[test]
fn frame_decoder_corpus() {
    replay("frame_decoder", harness::frame_decoder);
}

#[test]
fn device_corpus() {
    replay("device", harness::device);
}

#[test]
fn device_structured_corpus() {
    replay("device_structured", harness::device_structured);
}

#[test]
fn restore_corpus() {
    replay("restore", harness::restore);
}

#[test]
fn ros2_corpus() {
    replay("ros2", readers::ros2);
}

#[test]
fn depth_png_corpus() {
    replay("depth_png", readers::depth_png);
}
