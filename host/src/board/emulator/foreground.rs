//! Emulators that `placedb device` runs in the foreground end with it.
//!
//! `placedb device --qemu` and `--rp2040` start `qemu-system-arm` or `node`
//! (the RP2040 harness) as a child and wait for it. Ctrl-C reaches both (the
//! terminal signals the whole process group), but a SIGTERM or SIGHUP sent to
//! placedb alone (a service manager, `kill PID`, a test) left the emulator
//! running, holding its TCP port and its flash file. So:
//!
//! - while placedb waits ([`wait`]), SIGTERM, SIGINT and SIGHUP stop the
//!   child first: it gets SIGTERM (QEMU and the harness exit cleanly on it)
//!   and SIGKILL if it is still there after [`GRACE`]; placedb exits after it;
//! - on Linux the child also gets SIGKILL from the kernel when placedb dies
//!   any other way (SIGKILL, a crash): `PR_SET_PDEATHSIG`, set by [`spawn`].
//!
//! For the board either is a power cut: its flash holds what was written.
//!
//! While the board boots (until [`wait_until`] finds it up) and while
//! placedb asks it what it restored ([`Stoppable`]), the same signals
//! stop it.

use crate::board::link::Link;
use std::io;
use std::process::{Child, Command, ExitStatus};
use std::time::{Duration, Instant};

/// How long a stopped child may take to exit after SIGTERM before SIGKILL.
pub const GRACE: Duration = Duration::from_secs(5);

/// How often [`wait`] looks at the child and the signals.
const POLL: Duration = Duration::from_millis(50);

/// How the child ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ended {
    /// It exited by itself.
    Exited(ExitStatus),
    /// Placedb received this signal and stopped it.
    Stopped(i32),
}

/// Starts `command` as a child that ends with this process: the stop
/// signals are caught from now on (see [`wait`]) and, on Linux, the kernel
/// kills the child when the calling thread ends, so call it from the thread
/// that waits (the main thread of `placedb device`).
pub fn spawn(command: &mut Command) -> io::Result<Child> {
    #[cfg(unix)]
    signals::catch();
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::process::CommandExt;
        let parent = std::process::id();
        // SAFETY: between fork and exec the closure makes only
        // async-signal-safe calls (prctl, getppid, _exit) and allocates nothing.
        unsafe {
            command.pre_exec(move || {
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                    return Err(io::Error::last_os_error());
                }
                // The parent died before the prctl: nothing would signal us.
                if libc::getppid() as u32 != parent {
                    libc::_exit(1);
                }
                Ok(())
            });
        }
    }
    command.spawn()
}

/// Waits until `child` exits, or until this process receives SIGTERM,
/// SIGINT or SIGHUP: then stops the child (SIGTERM, SIGKILL after
/// [`GRACE`]) and returns once it is gone.
pub fn wait(child: &mut Child) -> io::Result<Ended> {
    loop {
        if let Some(ended) = wait_until(child, &mut || false)? {
            return Ok(ended);
        }
    }
}

/// Waits as [`wait`] does, but only until `ready()` says so: `None` then,
/// with the child still running; how it ended otherwise.
pub fn wait_until(child: &mut Child, ready: &mut dyn FnMut() -> bool) -> io::Result<Option<Ended>> {
    loop {
        if let Some(signal) = stop_signal() {
            stop(child)?;
            return Ok(Some(Ended::Stopped(signal)));
        }
        if let Some(status) = child.try_wait()? {
            return Ok(Some(Ended::Exited(status)));
        }
        if ready() {
            return Ok(None);
        }
        std::thread::sleep(POLL);
    }
}

/// The stop signal (SIGTERM, SIGINT, SIGHUP) received since [`spawn`], if
/// any (never off Unix, where none is caught).
pub fn stop_signal() -> Option<i32> {
    #[cfg(unix)]
    return signals::received();
    #[cfg(not(unix))]
    None
}

/// A link whose waits a stop signal cuts short (an `Interrupted` error),
/// so that `placedb device` stays stoppable while it asks its board
/// something at boot.
pub struct Stoppable<L>(pub L);

impl<L: Link> Link for Stoppable<L> {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.0.send(bytes)
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Vec<u8>> {
        let end = Instant::now() + timeout;
        loop {
            if stop_signal().is_some() {
                return Err(io::Error::new(io::ErrorKind::Interrupted, "stopped"));
            }
            let left = end.saturating_duration_since(Instant::now());
            match self.0.recv(left.min(POLL)) {
                Err(e) if e.kind() == io::ErrorKind::TimedOut && !left.is_zero() => {}
                Err(e) if e.kind() == io::ErrorKind::TimedOut => {
                    return Err(io::Error::new(
                        io::ErrorKind::TimedOut,
                        format!(
                            "no bytes from the board within {}",
                            crate::error::seconds(timeout)
                        ),
                    ))
                }
                got => return got,
            }
        }
    }
}

/// Kills `child` and reaps it (no signals off Unix).
#[cfg(not(unix))]
fn stop(child: &mut Child) -> io::Result<ExitStatus> {
    child.kill()?;
    child.wait()
}

/// SIGTERM to `child`, SIGKILL if it has not exited after [`GRACE`]; reaps it.
#[cfg(unix)]
fn stop(child: &mut Child) -> io::Result<ExitStatus> {
    if let Some(status) = child.try_wait()? {
        return Ok(status);
    }
    if let Ok(pid) = libc::pid_t::try_from(child.id()) {
        // SAFETY: kill(2) on our own child, which is not reaped yet (so the
        // pid is still its own).
        unsafe { libc::kill(pid, libc::SIGTERM) };
    }
    let end = Instant::now() + GRACE;
    while Instant::now() < end {
        if let Some(status) = child.try_wait()? {
            return Ok(status);
        }
        std::thread::sleep(POLL);
    }
    child.kill()?;
    child.wait()
}

#[cfg(unix)]
mod signals {
    use std::sync::atomic::{AtomicI32, Ordering};
    use std::sync::Once;

    /// The last stop signal received (0: none).
    static RECEIVED: AtomicI32 = AtomicI32::new(0);

    extern "C" fn on_signal(signal: libc::c_int) {
        RECEIVED.store(signal, Ordering::SeqCst);
    }

    /// Catches SIGTERM, SIGINT and SIGHUP from now on (once per process).
    pub fn catch() {
        static ONCE: Once = Once::new();
        ONCE.call_once(|| {
            let handler = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
            for signal in [libc::SIGTERM, libc::SIGINT, libc::SIGHUP] {
                // SAFETY: the handler only stores to an atomic, which is
                // async-signal-safe.
                unsafe { libc::signal(signal, handler) };
            }
        });
    }

    /// The stop signal received, if any.
    pub fn received() -> Option<i32> {
        match RECEIVED.load(Ordering::SeqCst) {
            0 => None,
            s => Some(s),
        }
    }
}
