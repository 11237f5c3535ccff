//! Partial outputs a killed run left behind. A run writes each output into
//! `.NAME.partial-PID-K` beside it ([`super`]) and removes that when it
//! fails; a run killed outright (SIGKILL, a power cut) cannot, and the
//! partial sibling stays. The next run that writes NAME removes them
//! ([`remove_stale`]): only names of exactly that pattern for that NAME,
//! and only those whose process PID no longer runs (a live one may be
//! another run writing NAME at this moment), so nothing else in the folder
//! is touched: not another output's partial, not the resumable export's
//! `.NAME.export-partial`, not a file of the user's. Until then nothing
//! reads them as output: they are hidden, a run renames only its own, and
//! their names end in `-PID-K`, no extension a reader looks for.

use std::path::Path;

/// The process id in `entry` if it names a partial sibling of output
/// `name`: `.NAME.partial-PID-K`, PID and K decimal digits.
pub fn partial_pid(entry: &str, name: &str) -> Option<u32> {
    let rest = entry
        .strip_prefix('.')?
        .strip_prefix(name)?
        .strip_prefix(".partial-")?;
    let (pid, k) = rest.split_once('-')?;
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    if !digits(pid) || !digits(k) {
        return None;
    }
    pid.parse().ok()
}

/// Whether process `pid` may still run: it is this one, or the system
/// knows it. Where that cannot be asked, every process may.
fn may_run(pid: u32) -> bool {
    if pid == std::process::id() {
        return true;
    }
    #[cfg(unix)]
    {
        // 0 and negative ids name process groups, not a process.
        let Some(pid) = libc::pid_t::try_from(pid).ok().filter(|&p| p > 0) else {
            return true;
        };
        // SAFETY: kill(2) with signal 0 sends nothing: it only asks whether
        // the process exists (EPERM: it does, another user's).
        if unsafe { libc::kill(pid, 0) } == 0 {
            return true;
        }
        std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
    }
    #[cfg(not(unix))]
    {
        true
    }
}

/// Removes from `parent` the partial siblings of output `name` left by runs
/// that no longer run (see the module doc). One that cannot be removed is
/// warned about and left: it is no output, and this run writes its own.
pub fn remove_stale(parent: &Path, name: &str) {
    let Ok(entries) = std::fs::read_dir(parent) else {
        return;
    };
    for entry in entries.flatten() {
        let file_name = entry.file_name();
        let Some(pid) = file_name.to_str().and_then(|n| partial_pid(n, name)) else {
            continue;
        };
        if may_run(pid) {
            continue;
        }
        let path = entry.path();
        if let Err(e) = super::remove(&path) {
            crate::warning::warn(format!(
                "{}, left by a run that was killed, could not be removed: {e}",
                path.display()
            ));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_our_own_pattern_for_that_name_is_a_partial() {
        assert_eq!(partial_pid(".out.partial-123-0", "out"), Some(123));
        assert_eq!(partial_pid(".a.b.partial-7-12", "a.b"), Some(7));
        for other in [
            ".out.partial-123",
            ".out.partial-123-",
            ".out.partial--0",
            ".out.partial-12a-0",
            ".out.partial-1-0x",
            ".out.export-partial",
            ".out.old-123-0",
            ".outer.partial-123-0",
            "out.partial-123-0",
            ".out.partial-1.partial-2-3",
        ] {
            assert_eq!(partial_pid(other, "out"), None, "{other}");
        }
    }

    #[test]
    fn this_process_runs() {
        assert!(may_run(std::process::id()));
        assert!(may_run(0));
    }
}
