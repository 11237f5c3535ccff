//! What a run leaves on disk while it works, removed if it is stopped:
//! the hidden partial siblings of the outputs being written (registered by
//! [`crate::output::replace`]) and the folder a file-compressed bag is
//! decompressed into ([`crate::read::ros2::bag_files`]). On SIGINT or
//! SIGTERM they are removed before the process exits (130 or 143, as a
//! shell reports a process those signals ended), so a Ctrl-C leaves every
//! target as it was and nothing beside it.
//!
//! The signal handler itself only writes the signal's number to a pipe (an
//! async-signal-safe call); a watcher thread reads it, takes the registry's
//! lock (which [`Outputs::commit`](crate::output::replace::Outputs::commit)
//! holds while it renames the outputs into place, so a run stopped during
//! its commit ends committed, never half), removes every registered path
//! and exits. The handlers are installed when the first path is
//! registered, so commands that write nothing keep the default signal
//! behaviour, and only in a program that asked for them
//! ([`remove_partials_on_signal`], the `placedb` command): a library's host
//! (the Python package, whose Ctrl-C raises `KeyboardInterrupt`) keeps its
//! own handlers, which a watcher that exits the process would take over. A
//! run that can stop cleanly (`placedb stream`) defers the first signal
//! instead ([`defer_stop`]): it polls [`stop_requested`], ends what it was
//! doing and calls [`stop_now`].

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};
use std::sync::{Mutex, MutexGuard};

/// Whether this program removes the registered paths on SIGINT and
/// SIGTERM ([`remove_partials_on_signal`]).
static ENABLED: AtomicBool = AtomicBool::new(false);

/// From now on registering a path installs the SIGINT and SIGTERM
/// handlers that remove the registered paths and exit: for a program of
/// its own (the `placedb` command), not for a library's host.
pub fn remove_partials_on_signal() {
    ENABLED.store(true, Ordering::SeqCst);
}

/// Whether the first SIGINT or SIGTERM only asks the run to stop
/// ([`defer_stop`]).
static DEFER: AtomicBool = AtomicBool::new(false);
/// The signal a deferred run was asked to stop by (0: none yet).
static STOP: AtomicI32 = AtomicI32::new(0);

/// From now on the first SIGINT or SIGTERM only asks the run to stop
/// ([`stop_requested`]), so that it can end cleanly (a stream leaves no
/// frame open on the board); a second one ends the process at once, as
/// without it.
pub fn defer_stop() {
    DEFER.store(true, Ordering::SeqCst);
    watch();
}

/// Ends [`defer_stop`]: a signal from now on ends the process at once (a
/// stop asked before stays in [`stop_requested`]).
pub fn end_defer() {
    DEFER.store(false, Ordering::SeqCst);
}

/// The signal the run was asked to stop by, if it was ([`defer_stop`]).
pub fn stop_requested() -> Option<i32> {
    match STOP.load(Ordering::SeqCst) {
        0 => None,
        signal => Some(signal),
    }
}

/// Ends the process stopped by `signal`: the registered paths removed, the
/// status a shell reports for it (130, 143).
pub fn stop_now(signal: i32) -> ! {
    remove_all(&live());
    std::process::exit(128 + signal)
}

/// The paths to remove if the run is stopped.
static LIVE: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// The registry, even if a thread panicked holding it.
pub(crate) fn live() -> MutexGuard<'static, Vec<PathBuf>> {
    LIVE.lock().unwrap_or_else(|e| e.into_inner())
}

/// `path` is being written: removed if the process is stopped by SIGINT
/// or SIGTERM before [`forget`].
pub(crate) fn register(path: &Path) {
    watch();
    live().push(path.to_path_buf());
}

/// Makes a path with `make` (a temporary folder, whose name it picks) and
/// registers it ([`register`]) under one hold of the registry's lock, the
/// handlers installed first: a signal finds it registered from the moment
/// it exists.
pub(crate) fn register_made<T>(
    make: impl FnOnce() -> std::io::Result<T>,
    path: impl Fn(&T) -> &Path,
) -> std::io::Result<T> {
    watch();
    let mut live = live();
    let made = make()?;
    live.push(path(&made).to_path_buf());
    Ok(made)
}

/// `path` is gone or has become its target (under the lock of [`live`],
/// which the caller holds).
pub(crate) fn forget(live: &mut Vec<PathBuf>, path: &Path) {
    live.retain(|p| p != path);
}

/// Removes the file or folder at `path`; one already gone is no error.
pub(crate) fn remove(path: &Path) -> std::io::Result<()> {
    match std::fs::symlink_metadata(path) {
        Ok(m) if m.is_dir() => std::fs::remove_dir_all(path),
        Ok(_) => std::fs::remove_file(path),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(e),
    }
}

/// Removes every registered path (a few tries: a writer thread may still
/// be creating a file inside a partial directory).
fn remove_all(live: &[PathBuf]) {
    for p in live {
        for _ in 0..5 {
            if remove(p).is_ok() {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
    }
}

#[cfg(unix)]
fn watch() {
    use std::sync::Once;

    /// The pipe's write end (-1 until installed).
    static WRITE_END: AtomicI32 = AtomicI32::new(-1);

    extern "C" fn on_signal(signal: libc::c_int) {
        let fd = WRITE_END.load(Ordering::SeqCst);
        let byte = signal as u8;
        // SAFETY: write(2) is async-signal-safe; `byte` outlives the call.
        unsafe { libc::write(fd, std::ptr::addr_of!(byte).cast(), 1) };
    }

    if !ENABLED.load(Ordering::SeqCst) {
        return;
    }
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        let mut fds = [0 as libc::c_int; 2];
        // SAFETY: pipe(2) fills the two-element array it is given.
        if unsafe { libc::pipe(fds.as_mut_ptr()) } != 0 {
            return;
        }
        let [read_end, write_end] = fds;
        WRITE_END.store(write_end, Ordering::SeqCst);
        let spawned = std::thread::Builder::new()
            .name("placedb-outputs-on-signal".into())
            .spawn(move || loop {
                let mut byte = 0u8;
                // SAFETY: read(2) of one byte into a byte we own.
                let n = unsafe { libc::read(read_end, std::ptr::addr_of_mut!(byte).cast(), 1) };
                if n == 1 {
                    let signal = libc::c_int::from(byte);
                    if DEFER.load(Ordering::SeqCst)
                        && STOP
                            .compare_exchange(0, signal, Ordering::SeqCst, Ordering::SeqCst)
                            .is_ok()
                    {
                        continue;
                    }
                    let live = live();
                    remove_all(&live);
                    std::process::exit(128 + signal);
                }
                if n == 0 {
                    return;
                }
            });
        if spawned.is_err() {
            return;
        }
        let handler = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
        for signal in [libc::SIGINT, libc::SIGTERM] {
            // SAFETY: the handler only calls write(2), which is
            // async-signal-safe.
            unsafe { libc::signal(signal, handler) };
        }
    });
}

#[cfg(not(unix))]
fn watch() {}
