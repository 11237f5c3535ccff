//! The Python package (python/) as a user gets it: a virtual environment,
//! `pip install ./python` (maturin builds the extension module), then its
//! pytest suite (python/tests/), which compares it with this `placedb`
//! binary byte for byte. What the build and the suite need (maturin,
//! pytest, matplotlib, numpy) is installed by `.ci/run` from
//! python/requirements-test.txt; the environment sees them, so nothing is
//! downloaded here.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The repository's root.
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Runs `cmd`, failing the test with its output when it fails.
fn run(cmd: &mut Command, what: &str) {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("{what}: cannot run it: {e}"));
    assert!(
        out.status.success(),
        "{what} failed ({}):\n{}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn the_python_package_installs_and_passes_its_tests() {
    let root = root();
    // The environment lives in the build's target directory, made afresh
    // each run so an earlier build of the module is never what is tested.
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("target"));
    let venv = target.join("python-venv");
    let _ = std::fs::remove_dir_all(&venv);
    run(
        Command::new("python3")
            .args(["-m", "venv", "--system-site-packages"])
            .arg(&venv),
        "python3 -m venv",
    );
    let python = venv.join("bin").join("python");
    // The module is built with the tests' profile into the same target
    // directory, so the dependencies the tests built are reused.
    run(
        Command::new(&python)
            .args([
                "-m",
                "pip",
                "install",
                "--quiet",
                "--no-build-isolation",
                "--no-deps",
            ])
            .arg(root.join("python"))
            .env("MATURIN_PEP517_ARGS", "--profile checked")
            .env("CARGO_TARGET_DIR", &target),
        "pip install ./python",
    );
    // The emulated board the client tests run on, built as the board
    // tests build it.
    let firmware = placedb_host::board::emulator::qemu::built_firmware()
        .unwrap_or_else(|e| panic!("the QEMU firmware: {e}"));
    run(
        Command::new(&python)
            .args(["-m", "pytest", "-q", "-p", "no:cacheprovider"])
            .arg(root.join("python").join("tests"))
            .env("PLACEDB_BIN", env!("CARGO_BIN_EXE_placedb"))
            .env("PLACEDB_QEMU_FIRMWARE", firmware)
            .env("PLACEDB_DATA", root.join("..").join("shared").join("data"))
            .current_dir(&venv),
        "pytest python/tests",
    );
}
