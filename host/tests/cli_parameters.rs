//! Every numeric option of the command line is checked while it is parsed:
//! a value out of range exits with clap's usage status (2) and a message
//! giving the range, before anything is read or written (no output
//! directory appears); `--mu -1` and `--mu=-1` get the same answer in every
//! command; `--window` above the profile's window is refused naming it; the
//! voxel range is in `--help`; a tiny voxel warns about its memory first.

mod cli_common;

use cli_common::{placedb, seven_scenes_copy, stderr, TempDir};

/// Clap's exit status for a command line it refuses.
const USAGE: i32 = 2;

/// `select` on a 3-frame copy of the sample with `extra` appended; checks
/// the run is refused with `code`, says `phrase` (and names `option`), and
/// left no output directory. Returns stderr.
fn refused(code: i32, extra: &[&str], phrase: &str) -> String {
    let tmp = TempDir::new("refused");
    let seq = tmp.arg("seq");
    seven_scenes_copy(tmp.path().join("seq").as_path(), 3, true);
    let out = tmp.arg("out");
    let mut args = vec!["select", seq.as_str(), "-o", out.as_str()];
    args.extend_from_slice(extra);
    let run = placedb(&args);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(code), "{extra:?}: {err}");
    assert!(
        err.contains(phrase),
        "{extra:?}: expected {phrase:?} in: {err}"
    );
    assert!(
        !tmp.path().join("out").exists(),
        "{extra:?}: the output directory was created"
    );
    err
}

#[test]
fn each_numeric_option_is_refused_with_its_range_before_any_work() {
    let cases: &[(&[&str], &str)] = &[
        (&["--mu", "1.5"], "mu must be from 0 to below 1"),
        (&["--mu", "1"], "mu must be from 0 to below 1"),
        (&["--mu", "nan"], "mu must be from 0 to below 1"),
        (&["--mu", "inf"], "mu must be from 0 to below 1"),
        (&["--mu", "x"], "`x` is not a number"),
        (&["--voxel", "0.0005"], "from 0.001 to 100 metres"),
        (&["--voxel", "0"], "from 0.001 to 100 metres"),
        (&["--voxel", "-0.3"], "from 0.001 to 100 metres"),
        (&["--voxel", "nan"], "from 0.001 to 100 metres"),
        (&["--voxel", "101"], "from 0.001 to 100 metres"),
        (&["--depth-scale", "0"], "from 1 to 1000000 units per metre"),
        (
            &["--depth-scale", "-5"],
            "from 1 to 1000000 units per metre",
        ),
        (
            &["--depth-scale", "nan"],
            "from 1 to 1000000 units per metre",
        ),
        (&["--depth-range", "3,1"], "0 <= min < max"),
        (&["--depth-range", "1,1"], "0 <= min < max"),
        (&["--depth-range", "-1,3"], "0 <= min < max"),
        (&["--depth-range", "nan,3"], "0 <= min < max"),
        (&["--distance", "0"], "above 0"),
        (&["--distance", "-1"], "above 0"),
        (&["--cube", "0"], "above 0"),
        (&["--cube", "nan"], "above 0"),
        (&["--time-limit", "0"], "above 0"),
        (&["--time-limit", "-3"], "above 0"),
        (
            &["--time-limit", "1e300"],
            "must be from above 0 to 1000000 seconds, got 1e300",
        ),
        (&["--every-nth", "0"], "1 or more"),
        (&["--every-nth", "-2"], "1 or more"),
        (&["--pose-tolerance", "-1"], "0 or more"),
        (&["--pose-tolerance", "nan"], "0 or more"),
        (
            &["--intrinsics", "0,525,320,240"],
            "focal lengths must be > 0",
        ),
        (
            &["--intrinsics", "-525,525,320,240"],
            "focal lengths must be > 0",
        ),
        (&["--intrinsics", "525,525,320"], "four numbers"),
        (
            &["--window", "0"],
            "must be a whole number from 1 to 48, got 0",
        ),
        (
            &["--window", "1000"],
            "must be a whole number from 1 to 48, got 1000",
        ),
        (
            &["--window", "-1"],
            "must be a whole number from 1 to 48, got -1",
        ),
        (
            &["--max-frames", "0"],
            "must be a whole number, 1 or more, got 0",
        ),
        (
            &["--max-frames", "-5"],
            "must be a whole number, 1 or more, got -5",
        ),
        (
            &["--max-frames", "99999999999999999999999"],
            "99999999999999999999999 is too large, 1 or more",
        ),
        (&["--max-frames", "ten"], "`ten` is not a whole number"),
        (
            &["--stride", "65"],
            "must be a whole number from 1 to 64, got 65",
        ),
        (&["--profile", "ram2m"], "ram256k"),
        (
            &["--stride", "0"],
            "must be a whole number from 1 to 64, got 0",
        ),
    ];
    for (extra, phrase) in cases {
        let err = refused(USAGE, extra, phrase);
        assert!(
            err.contains(extra[0]),
            "{extra:?}: the option is named: {err}"
        );
    }
}

/// Every other command's counts and sizes: out of range exits 2 with the
/// range in words, naming the option, before anything is made.
#[test]
fn the_counts_of_every_command_are_refused_with_their_range() {
    let tmp = TempDir::new("counts");
    let out = tmp.arg("out");
    let cases: &[(&[&str], &str)] = &[
        (
            &["synth", &out, "--frames", "0"],
            "from 1 to 1000000, got 0",
        ),
        (
            &["synth", &out, "--frames", "-3"],
            "from 1 to 1000000, got -3",
        ),
        (&["synth", &out, "--width", "1"], "from 2 to 8192, got 1"),
        (
            &["synth", &out, "--height", "9000"],
            "from 2 to 8192, got 9000",
        ),
        (&["synth", &out, "--rooms", "0"], "from 1 to 1000, got 0"),
        (
            &["synth", &out, "--seed", "-1"],
            "must be a whole number, 0 or more, got -1",
        ),
        (
            &["select", "--demo", "-o", &out, "--demo-frames", "0"],
            "from 1 to 1000000, got 0",
        ),
        (
            &[
                "stream",
                "--demo",
                "--port",
                "local:ram512k",
                "-o",
                &out,
                "--retries",
                "-1",
            ],
            "from 0 to 1000, got -1",
        ),
        (
            &[
                "stream",
                "--demo",
                "--port",
                "local:ram512k",
                "-o",
                &out,
                "--fault-seed",
                "x",
            ],
            "`x` is not a whole number",
        ),
        (
            &[
                "export",
                "--port",
                "local:ram512k",
                "-o",
                &out,
                "--from",
                "-1",
            ],
            "from 0 to 4294967295, got -1",
        ),
        (
            &["device", "--qemu", "--port", "70000"],
            "from 0 to 65535, got 70000",
        ),
        (&["bench", "--repeat", "0"], "from 1 to 1000, got 0"),
        (&["bench", "--stride", "0"], "from 1 to 64, got 0"),
        (
            &["bench", "--synthetic-frames", "0"],
            "from 1 to 1000000, got 0",
        ),
    ];
    for (args, phrase) in cases {
        let run = placedb(args);
        let err = stderr(&run);
        assert_eq!(run.status.code(), Some(USAGE), "{args:?}: {err}");
        assert!(
            err.contains(phrase),
            "{args:?}: expected {phrase:?} in: {err}"
        );
        let option = args.iter().rev().nth(1).unwrap();
        assert!(err.contains(option), "{args:?}: the option is named: {err}");
        assert!(!tmp.path().join("out").exists(), "{args:?} made its output");
    }
}

#[test]
fn mu_minus_one_gets_the_same_answer_in_both_forms_in_every_command() {
    let tmp = TempDir::new("mu-forms");
    let seq = tmp.arg("seq");
    seven_scenes_copy(tmp.path().join("seq").as_path(), 3, true);
    let out = tmp.arg("out");
    let commands: [Vec<&str>; 4] = [
        vec!["select", &seq, "-o", &out],
        vec!["compare", &seq],
        vec!["stream", &seq, "--port", "local:ram512k", "-o", &out],
        vec!["export", "--port", "local:ram512k", "-o", &out],
    ];
    for command in &commands {
        let answer = |mu: &[&str]| {
            let mut args = command.clone();
            args.extend_from_slice(mu);
            let run = placedb(&args);
            assert_eq!(run.status.code(), Some(USAGE), "{args:?}: {}", stderr(&run));
            stderr(&run)
        };
        let spaced = answer(&["--mu", "-1"]);
        let joined = answer(&["--mu=-1"]);
        assert!(
            spaced.contains("mu must be from 0 to below 1"),
            "{command:?}: {spaced}"
        );
        assert_eq!(spaced, joined, "{command:?}");
        assert!(
            !tmp.path().join("out").exists(),
            "{command:?} created its output"
        );
    }
    // compare's list: each threshold checked, a negative one in either form.
    for mu in [["--mu", "0.3,-1"], ["--mu", "-1,0.3"]] {
        let run = placedb(&["compare", &seq, mu[0], mu[1]]);
        assert_eq!(run.status.code(), Some(USAGE));
        assert!(stderr(&run).contains("mu must be from 0 to below 1"));
    }
}

#[test]
fn every_solver_refuses_a_bad_mu() {
    for solver in placedb_host::pipeline::Solver::ALL {
        for mu in ["1.5", "nan", "-1"] {
            refused(
                USAGE,
                &["--solver", solver.name(), "--mu", mu],
                "mu must be from 0 to below 1",
            );
        }
    }
}

#[test]
fn a_window_above_the_profile_is_refused_naming_its_window() {
    for (profile, window, cap) in [("ram512k", "33", "32"), ("ram512k", "48", "32")] {
        let err = refused(
            USAGE,
            &["--profile", profile, "--window", window],
            &format!("the {profile} profile holds from 1 to {cap} frames"),
        );
        assert!(err.contains(&format!("--window {cap} or less")), "{err}");
    }
    // stream: the same check, before the sequence is read or a port opened.
    let tmp = TempDir::new("stream-window");
    let out = tmp.arg("out");
    let run = placedb(&[
        "stream",
        "--demo",
        "--port",
        "local:ram512k",
        "--window",
        "33",
        "-o",
        &out,
    ]);
    assert_eq!(run.status.code(), Some(USAGE));
    assert!(
        stderr(&run).contains("from 1 to 32 frames"),
        "{}",
        stderr(&run)
    );
    assert!(!tmp.path().join("out").exists());
    // A resend wait of 0 ms is refused, not raised to 1 without a word.
    let run = placedb(&[
        "stream",
        "--demo",
        "--port",
        "local:ram512k",
        "--resend-ms",
        "0",
        "-o",
        &out,
    ]);
    assert_eq!(run.status.code(), Some(USAGE), "{}", stderr(&run));
    assert!(
        stderr(&run).contains("from 1 to 3600000, got 0"),
        "{}",
        stderr(&run)
    );
    assert!(!tmp.path().join("out").exists());
    // The profile's own window is taken, and what metrics.json records.
    let run = placedb(&[
        "select",
        "--demo",
        "--demo-frames",
        "12",
        "--profile",
        "ram1m",
        "--window",
        "48",
        "-q",
        "-o",
        &out,
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    let json = std::fs::read_to_string(tmp.path().join("out/metrics.json")).unwrap();
    assert!(json.contains("\"window\": 48"), "{json}");
}

#[test]
fn the_voxel_range_is_in_the_help() {
    for command in ["select", "compare", "stream"] {
        let run = placedb(&[command, "--help"]);
        let help = String::from_utf8_lossy(&run.stdout).into_owned();
        assert!(help.contains("from 0.001 to 100"), "{command}: {help}");
    }
}

#[test]
fn a_tiny_voxel_warns_about_its_memory_before_the_work() {
    let tmp = TempDir::new("voxel-memory");
    seven_scenes_copy(tmp.path().join("seq").as_path(), 2, true);
    let seq = tmp.arg("seq");
    let run_with = |voxel: &str| {
        let out = tmp.arg(&format!("out-{voxel}"));
        let run = placedb(&[
            "select", &seq, "-o", &out, "--solver", "in-order", "--voxel", voxel, "-q",
        ]);
        assert!(run.status.success(), "{voxel}: {}", stderr(&run));
        stderr(&run)
    };
    let fine = run_with("0.001");
    assert!(
        fine.contains("warning: --voxel 0.001") && fine.contains("MB a frame"),
        "{fine}"
    );
    let usual = run_with("0.3");
    assert!(!usual.contains("MB a frame"), "{usual}");
}

/// `placedb device` names both boards when none is given, and refuses a
/// flag of the other board, with status 2 before anything starts.
#[test]
fn device_names_both_boards_and_refuses_the_other_boards_flags() {
    let run = placedb(&["device"]);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(2), "{err}");
    assert!(err.contains("<--qemu|--rp2040>"), "{err}");
    let run = placedb(&["device", "--rp2040", "--no-icount"]);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(2), "{err}");
    assert!(
        err.contains("'--rp2040' cannot be used with '--no-icount'"),
        "{err}"
    );
}
