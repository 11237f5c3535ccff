//! Every output all or nothing, also when interrupted, on the real binary:
//! a run stopped by SIGINT (Ctrl-C) or SIGTERM while it writes removes its
//! hidden `.NAME.partial-PID-K` siblings, leaves every target as it was and
//! exits 130 or 143; `--pairs FILE` replaces only an earlier pairs file,
//! never another file of the user's.

mod cli_common;

use cli_common::{names, placedb, stderr, tree, TempDir, SEVEN_SCENES};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// A dataset and a database of the demo walked in `frames` frames.
fn demo_args(root: &TempDir, frames: &str) -> Vec<String> {
    [
        "select",
        "--demo",
        "--demo-frames",
        frames,
        "--dataset",
        &root.arg("ds"),
        "-o",
        &root.arg("out"),
    ]
    .iter()
    .map(|s| s.to_string())
    .collect()
}

/// Starts a long run over an earlier one's outputs, sends `signal` once a
/// partial sibling exists, and checks the run removed its siblings, left
/// the earlier outputs as they were and exited `code`.
fn interrupted(signal: &str, code: i32) {
    let root = TempDir::new(&format!("interrupt-{signal}"));
    let first = placedb(&demo_args(&root, "30"));
    assert!(first.status.success(), "{}", stderr(&first));
    let before = (
        tree(&root.path().join("ds")),
        tree(&root.path().join("out")),
    );
    let mut child = Command::new(env!("CARGO_BIN_EXE_placedb"))
        .args(demo_args(&root, "4000"))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    loop {
        if names(root.path()).iter().any(|n| n.contains(".partial-")) {
            break;
        }
        assert!(
            child.try_wait().unwrap().is_none(),
            "the run ended before it wrote a partial output"
        );
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "no partial output"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let killed = Command::new("kill")
        .args([format!("-{signal}"), child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(code), "{}", stderr(&out));
    assert_eq!(
        names(root.path()),
        ["ds", "out"],
        "a partial sibling was left"
    );
    assert!(
        (
            tree(&root.path().join("ds")),
            tree(&root.path().join("out"))
        ) == before,
        "the earlier outputs changed"
    );
}

#[test]
fn sigint_mid_write_removes_the_partial_siblings_and_leaves_the_targets() {
    interrupted("INT", 130);
}

#[test]
fn sigterm_mid_write_removes_the_partial_siblings_and_leaves_the_targets() {
    interrupted("TERM", 143);
}

#[test]
fn pairs_replaces_an_earlier_pairs_file_and_refuses_any_other_file() {
    let root = TempDir::new("pairs-rule");
    let pairs = root.arg("pairs.txt");
    let run = |pairs: &str| {
        placedb(&[
            "select",
            SEVEN_SCENES,
            "--max-frames",
            "20",
            "--pairs",
            pairs,
            "-o",
            &root.arg("out"),
        ])
    };
    // A user's file at the path: refused before any work, left as it was.
    let notes = "my notes\nabout this scan\n";
    std::fs::write(&pairs, notes).unwrap();
    let out = run(&pairs);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    assert!(
        stderr(&out).contains(&format!(
            "{pairs} exists and is not a pairs file (lines of two image names): give a new file \
             name (or remove that file)"
        )),
        "{}",
        stderr(&out)
    );
    assert_eq!(std::fs::read_to_string(&pairs).unwrap(), notes);
    assert!(!root.path().join("out").exists(), "work was done");
    // A new name, then the same again: an earlier pairs file is replaced.
    std::fs::remove_file(&pairs).unwrap();
    let first = run(&pairs);
    assert!(first.status.success(), "{}", stderr(&first));
    let again = run(&pairs);
    assert!(again.status.success(), "{}", stderr(&again));
    // An empty file is replaced too.
    let empty = root.arg("empty.txt");
    std::fs::write(&empty, "").unwrap();
    let out = run(&empty);
    assert!(out.status.success(), "{}", stderr(&out));
}
