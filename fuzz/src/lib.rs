//! Fuzz harnesses of placedb. The checks live in [`harness`] (the core) and
//! [`readers`] (the host's sequence readers), which `tests/fuzz_corpus.rs`
//! and `host/tests/fuzz_corpus_readers.rs` include too (with `corpus.rs`,
//! the replay of a target's files, which only those tests use), so the
//! committed corpus replays the very same checks under `cargo test`.

pub mod harness;
pub mod readers;
