//! Replays the committed fuzz corpus of the core's targets (the frame
//! decoder, the device, its structured variant, the restore from flash)
//! through the fuzz harness, on stable, as part of the normal test suite:
//! every file of `fuzz/corpus/<target>/` and `fuzz/regressions/<target>/`
//! must pass the very checks the fuzz targets run (`fuzz/src/harness.rs`,
//! included below). Fails when a corpus directory is missing or empty. The
//! host readers' targets replay in `host/tests/fuzz_corpus_readers.rs`.

#[path = "../fuzz/src/corpus.rs"]
mod corpus;
#[path = "../fuzz/src/harness.rs"]
mod harness;

use std::path::{Path, PathBuf};

fn replay(target: &str, check: fn(&[u8])) {
    let fuzz: PathBuf = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz");
    corpus::replay(&fuzz, target, check);
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
