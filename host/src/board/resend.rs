//! How long a stop-and-wait exchange waits for a reply before it sends the
//! message again: the link's own round trip, measured, rather than a fixed
//! guess.
//!
//! A damaged frame that loses its sequence number can only be noticed by a
//! reply that does not come, so every such loss costs one wait. A fixed wait
//! must cover the slowest reply the device may give (seconds, while it
//! erases flash), and with it a 50-frame scan at 5 % faults took 174 s
//! where its frames took 2.5 s. The wait here is RFC 6298's retransmission
//! timeout: a smoothed round trip plus four times its mean deviation,
//! sampled only from messages answered at their first sending (Karn's rule:
//! a reply after a resend may answer either), within a floor and the
//! user's `--resend-ms` as its ceiling. After a wait that ran out, the next
//! one doubles, up to the ceiling. A reply slower than the estimate costs a
//! spurious resend, which the device answers from its cache without
//! applying the message twice.

use std::time::Duration;

/// The shortest wait: below it a loaded host's scheduling alone would look
/// like a lost reply.
pub const FLOOR: Duration = Duration::from_millis(20);

/// The round-trip estimate of one link.
#[derive(Debug, Clone, Copy, Default)]
pub struct ResendTimer {
    /// Smoothed round trip and its mean deviation, seconds; `None` before
    /// the first sample.
    estimate: Option<(f64, f64)>,
}

impl ResendTimer {
    /// The first wait for a message: the estimate, within [`FLOOR`] and
    /// `ceiling`; `ceiling` itself before any round trip was measured.
    pub fn first_wait(&self, ceiling: Duration) -> Duration {
        match self.estimate {
            None => ceiling,
            Some((srtt, rttvar)) => {
                Duration::from_secs_f64(srtt + 4.0 * rttvar).clamp(FLOOR.min(ceiling), ceiling)
            }
        }
    }

    /// The wait after one that ran out: twice as long, up to `ceiling`.
    pub fn next_wait(previous: Duration, ceiling: Duration) -> Duration {
        previous.saturating_mul(2).min(ceiling)
    }

    /// Takes the round trip of a message answered at its first sending.
    pub fn sample(&mut self, rtt: Duration) {
        let r = rtt.as_secs_f64();
        self.estimate = Some(match self.estimate {
            None => (r, r / 2.0),
            Some((srtt, rttvar)) => {
                let rttvar = 0.75 * rttvar + 0.25 * (srtt - r).abs();
                (0.875 * srtt + 0.125 * r, rttvar)
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CEILING: Duration = Duration::from_secs(2);

    #[test]
    fn the_wait_follows_the_round_trip_within_floor_and_ceiling() {
        let mut t = ResendTimer::default();
        assert_eq!(t.first_wait(CEILING), CEILING);
        for _ in 0..50 {
            t.sample(Duration::from_millis(10));
        }
        // A steady 10 ms round trip: the floor.
        assert_eq!(t.first_wait(CEILING), FLOOR);
        for _ in 0..50 {
            t.sample(Duration::from_millis(100));
        }
        let w = t.first_wait(CEILING);
        assert!(
            w > Duration::from_millis(100) && w < Duration::from_millis(200),
            "{w:?}"
        );
        // Slow replies raise it, never past the ceiling.
        for _ in 0..50 {
            t.sample(Duration::from_secs(5));
        }
        assert_eq!(t.first_wait(CEILING), CEILING);
        // A ceiling below the floor is kept.
        assert_eq!(
            t.first_wait(Duration::from_millis(5)),
            Duration::from_millis(5)
        );
    }

    #[test]
    fn a_wait_that_ran_out_doubles_up_to_the_ceiling() {
        let w = ResendTimer::next_wait(Duration::from_millis(300), CEILING);
        assert_eq!(w, Duration::from_millis(600));
        assert_eq!(
            ResendTimer::next_wait(Duration::from_millis(1500), CEILING),
            CEILING
        );
    }
}
