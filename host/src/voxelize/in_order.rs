//! A parallel map over frame indices whose failure is the lowest failing
//! frame's, whichever thread fails first: an error names the same frame
//! run after run (rayon's own `collect` into a `Result` keeps whichever
//! error it met first).

use rayon::prelude::*;
use std::ops::Range;
use std::sync::atomic::{AtomicUsize, Ordering};

/// `f(state, i)` for every `i` of `frames` in parallel (`init` makes each
/// worker's reusable state), the results in order; on failure the error of
/// the lowest `i` that failed. Frames above a known failure are skipped:
/// every frame below it still runs, so the lowest one is always found.
pub fn try_map_init<T, E, S, I, F>(frames: Range<usize>, init: I, f: F) -> Result<Vec<T>, E>
where
    T: Send,
    E: Send,
    I: Fn() -> S + Sync + Send,
    F: Fn(&mut S, usize) -> Result<T, E> + Sync + Send,
{
    let lowest_failed = AtomicUsize::new(usize::MAX);
    let results: Vec<Option<Result<T, E>>> = frames
        .into_par_iter()
        .map_init(init, |state, i| {
            // Relaxed is enough: a stale value only means one more frame run.
            if i > lowest_failed.load(Ordering::Relaxed) {
                return None;
            }
            let r = f(state, i);
            if r.is_err() {
                lowest_failed.fetch_min(i, Ordering::Relaxed);
            }
            Some(r)
        })
        .collect();
    // Every skipped frame lies above the lowest failure, so the first error
    // in order comes before any gap: the collect stops there.
    results.into_iter().flatten().collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lowest_failing_frame_is_reported() {
        for _ in 0..20 {
            let r = try_map_init(
                0..2000,
                || (),
                |_, i| {
                    if i % 97 == 13 {
                        Err(i)
                    } else {
                        Ok(i)
                    }
                },
            );
            assert_eq!(r, Err(13));
        }
        let all: Result<Vec<usize>, ()> = try_map_init(0..100, || (), |_, i| Ok(i * 2));
        assert_eq!(all, Ok((0..100).map(|i| i * 2).collect()));
    }
}
