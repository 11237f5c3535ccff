//! The printing commands end quietly when their reader has gone
//! (`placedb budget | head`): killed by SIGPIPE like any Unix filter, with
//! no panic message, rather than a panic in `println!`.
#![cfg(unix)]

use std::os::unix::process::ExitStatusExt;
use std::process::{Command, Stdio};

/// Runs `placedb ARGS` with stdout a pipe whose read end is already closed;
/// asserts it died of SIGPIPE and printed nothing on stderr.
fn into_closed_pipe(args: &[&str]) {
    let (reader, writer) = std::io::pipe().expect("a pipe");
    drop(reader);
    let out = Command::new(env!("CARGO_BIN_EXE_placedb"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .expect("placedb runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        out.status.signal(),
        Some(libc::SIGPIPE),
        "placedb {args:?}: {:?}, stderr: {stderr}",
        out.status
    );
    assert!(stderr.is_empty(), "placedb {args:?}: stderr: {stderr}");
}

#[test]
fn budget_into_a_closed_pipe_is_quiet() {
    into_closed_pipe(&["budget"]);
}

#[test]
fn compare_into_a_closed_pipe_is_quiet() {
    into_closed_pipe(&["compare", "--demo", "--max-frames", "12", "--mu", "0.3"]);
}
