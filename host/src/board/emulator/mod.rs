//! The emulated boards, each a [`Link`](crate::board::link::Link) once it
//! runs: the QEMU board ([`qemu`]) and the Pico under rp2040js ([`rp2040`]);
//! what both share: building their firmware ([`build_board`]) and running
//! one in the foreground for `placedb device` ([`wait_in_foreground`], with
//! the process plumbing of [`foreground`]); the QEMU board's port serves one
//! program at a time ([`one_client`]; the Pico's harness does the same).

pub mod foreground;
pub mod one_client;
pub mod qemu;
pub mod rp2040;

use crate::board::error::DeviceError;
use std::io;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Builds the firmware of `boards/BOARD` (`cargo build --release` there, if
/// `build`) and returns `elf` if it exists; `how` says how to build it by
/// hand in the error.
pub fn build_board(board: &str, elf: PathBuf, build: bool, how: &str) -> Result<PathBuf, String> {
    if build {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../boards")
            .join(board);
        let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
        let out = Command::new(cargo)
            .args(["build", "--release"])
            .current_dir(&dir)
            .output()
            .map_err(|e| {
                format!(
                    "cannot run cargo to build the firmware: {}",
                    crate::error::io_words(&e)
                )
            })?;
        if !out.status.success() {
            return Err(format!(
                "building the firmware (`{how}`) failed:\n{}",
                String::from_utf8_lossy(&out.stderr)
            ));
        }
    }
    if elf.is_file() {
        Ok(elf)
    } else {
        Err(format!(
            "firmware {} is missing: build it with `{how}`",
            elf.display()
        ))
    }
}

/// Waits for an emulator started with [`foreground::spawn`] until it exits
/// or a signal stops placedb (Ctrl-C, SIGTERM, SIGHUP), which stops the
/// emulator first; on Linux the emulator is also killed if placedb dies any
/// other way. `exited` names it when it exits by itself. Returns the
/// signal that stopped it, if one did. The one launcher of `placedb
/// device`'s boards.
pub fn wait_in_foreground(
    child: &mut std::process::Child,
    exited: &str,
) -> Result<Option<i32>, DeviceError> {
    match foreground::wait(child)? {
        foreground::Ended::Exited(status) if status.success() => Ok(None),
        foreground::Ended::Exited(status) => Err(DeviceError::Io(io::Error::other(format!(
            "{exited} exited: {status}"
        )))),
        foreground::Ended::Stopped(signal) => Ok(Some(signal)),
    }
}
