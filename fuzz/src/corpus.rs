//! Replays one fuzz target's committed corpus and crash reproducers
//! (`fuzz/corpus/<target>/`, `fuzz/regressions/<target>/`) through that
//! target's check, on stable. Included by path by the two test files that
//! replay the corpus under `cargo test`: `tests/fuzz_corpus.rs` (the core's
//! targets) and `host/tests/fuzz_corpus_readers.rs` (the host readers').

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

/// Runs `check` on every corpus and regression file of `target` in the fuzz
/// crate at `fuzz`; fails when the corpus is missing or empty, or a check
/// panics.
pub fn replay(fuzz: &Path, target: &str, check: fn(&[u8])) {
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
