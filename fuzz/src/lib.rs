//! Fuzz harnesses of placedb. The checks live in [`harness`] (the core) and
//! [`readers`] (the host's sequence readers), which the root test
//! `tests/fuzz_corpus.rs` includes too, so the committed corpus replays the
//! very same checks under `cargo test`.

pub mod harness;
pub mod readers;
