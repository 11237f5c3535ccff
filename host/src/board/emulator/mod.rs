//! The emulated boards, each a [`Link`](crate::board::link::Link) once it
//! runs: the QEMU board ([`qemu`]) and the Pico under rp2040js ([`rp2040`]);
//! what both share: building their firmware ([`build_board`]), their flash
//! file ([`prepare_flash_file`]), the port `placedb device` serves them on
//! ([`bind_port`]) and running one in the foreground for it
//! ([`wait_in_foreground`], with the process plumbing of [`foreground`]);
//! the QEMU board's port serves one program at a time ([`one_client`]; the
//! Pico's harness does the same).

pub mod foreground;
pub mod one_client;
pub mod qemu;
pub mod rp2040;

use crate::board::error::DeviceError;
use std::io::{self, Write};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::Command;

/// What `placedb device` does with its board once it is up and before any
/// program is served, over a link of its own (it asks what the board
/// restored): the `at_boot` of [`qemu::spawn_foreground`] and
/// [`rp2040::spawn_foreground`].
pub type AtBoot<'a> = &'a mut dyn FnMut(&mut dyn crate::board::link::Link);

/// A board's flash held in a file: its size and the board's name, for
/// [`prepare_flash_file`] and its messages.
#[derive(Debug, Clone, Copy)]
pub struct FlashFile {
    /// Bytes of the file: the board's whole flash.
    pub size: u64,
    /// Whose flash it is, in words ("the Pico's flash").
    pub of: &'static str,
}

/// Makes `path` the board's flash file: one of `flash.size` bytes is left
/// as it is (it holds the board's log); a missing or empty one is created
/// erased (0xFF), its folder too, written beside it and renamed into place
/// so that a file cut short by a crash is never taken for a flash image.
/// One of another size (another board's, or not a flash image) or a
/// folder is refused in words naming it, its size and the size expected,
/// and nothing is made or changed.
pub fn prepare_flash_file(path: &Path, flash: FlashFile) -> io::Result<()> {
    let refuse = |what: String| {
        Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!(
                "flash file {} {what}: give a file of its own (a missing or empty one is made \
                 an erased flash)",
                path.display()
            ),
        ))
    };
    match std::fs::metadata(path) {
        Ok(meta) if meta.is_dir() => return refuse("is a folder".into()),
        Ok(meta) if meta.len() == flash.size => return Ok(()),
        Ok(meta) if meta.len() != 0 => {
            return refuse(format!(
                "holds {} bytes, not the {} bytes ({} MiB) of {}",
                meta.len(),
                flash.size,
                flash.size >> 20,
                flash.of
            ))
        }
        Ok(_) => {}
        Err(e) if e.kind() == io::ErrorKind::NotFound => {}
        Err(e) => {
            return Err(io::Error::new(
                e.kind(),
                format!(
                    "cannot read flash file {}: {}",
                    path.display(),
                    crate::error::io_words(&e)
                ),
            ))
        }
    }
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(format!(".tmp{}", std::process::id()));
    let tmp = path.with_file_name(name);
    let written = (|| {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)?;
        }
        let mut file = std::fs::File::create(&tmp)?;
        let erased = vec![0xFFu8; 1 << 20];
        let mut left = flash.size;
        while left > 0 {
            let n = left.min(erased.len() as u64);
            file.write_all(&erased[..n as usize])?;
            left -= n;
        }
        file.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written.map_err(|e| {
        io::Error::new(
            e.kind(),
            format!(
                "cannot create flash file {}: {}",
                path.display(),
                crate::error::io_words(&e)
            ),
        )
    })
}

/// Listens on the loopback port `port` (0: any free one) that `placedb
/// device` serves its board on; a port in use is refused in words, before
/// anything else is made.
pub fn bind_port(port: u16) -> Result<TcpListener, DeviceError> {
    TcpListener::bind(("127.0.0.1", port)).map_err(|e| {
        let why = match e.kind() {
            io::ErrorKind::AddrInUse => format!(
                "port {port} of 127.0.0.1 is in use (another board or program listens there): \
                 choose another --port, or 0 for any free one"
            ),
            _ => format!(
                "cannot listen on 127.0.0.1:{port}: {}",
                crate::error::io_words(&e)
            ),
        };
        DeviceError::Io(io::Error::new(e.kind(), why))
    })
}

/// Builds the firmware of `boards/BOARD` (`cargo build --release` there, if
/// `build`) and returns `elf` if it exists; `how` says how to build it by
/// hand in the error.
pub fn build_board(board: &str, elf: PathBuf, build: bool, how: &str) -> Result<PathBuf, String> {
    build_board_with(board, &["--release"], elf, build, how)
}

/// [`build_board`] with `cargo build ARGS` (a profile, features).
pub fn build_board_with(
    board: &str,
    args: &[&str],
    elf: PathBuf,
    build: bool,
    how: &str,
) -> Result<PathBuf, String> {
    if build {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../boards")
            .join(board);
        let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
        let out = Command::new(cargo)
            .arg("build")
            .args(args)
            .current_dir(&dir)
            // The board's own target folder, where `elf` is looked for,
            // whatever CARGO_TARGET_DIR the caller runs with (a test run
            // with one set built the firmware elsewhere, and took a stale
            // or missing ELF for it).
            .env("CARGO_TARGET_DIR", dir.join("target"))
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
