//! The core's one seeded generator for its unit tests: random poses, keys
//! and rows that are the same on every machine and every run, with no
//! dependency. The host's `rng.rs` is the host's (the core cannot import
//! the host); this one is compiled only for the core's own tests.
//!
//! A 64-bit linear congruential generator with Knuth's MMIX constants, read
//! from its top bits: the low bits of an LCG repeat with short periods.
//! It is the generator the core's tests each carried a copy of, so their
//! streams are the ones they were written and tuned against.

/// The generator: 64 bits of state, full period.
#[derive(Debug, Clone)]
pub(crate) struct TestRng(u64);

impl TestRng {
    /// A generator started from `seed`.
    pub(crate) const fn new(seed: u64) -> Self {
        TestRng(seed)
    }

    /// The next 31 random bits (the state's top bits after one step).
    pub(crate) fn next31(&mut self) -> u32 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 33) as u32
    }

    /// The next 64 random bits, from three steps.
    pub(crate) fn next_u64(&mut self) -> u64 {
        let (a, b, c) = (self.next31(), self.next31(), self.next31());
        (u64::from(a) << 33) | (u64::from(b) << 2) | u64::from(c & 3)
    }

    /// Uniform in `[0, 1]`: 31 bits rounded to an `f32` (the few largest
    /// round up to 1).
    pub(crate) fn unit(&mut self) -> f32 {
        self.next31() as f32 / (1u64 << 31) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_steps_and_ranges() {
        // The state after one step from 0 is the increment.
        let mut g = TestRng::new(0);
        assert_eq!(g.next31(), (1_442_695_040_888_963_407u64 >> 33) as u32);
        let mut g = TestRng::new(7);
        for _ in 0..1000 {
            assert!(g.next31() < 1 << 31);
            assert!((0.0..=1.0).contains(&g.unit()));
        }
        // The 64-bit draws set the top and the bottom bits alike.
        let (mut or, mut and) = (0u64, u64::MAX);
        for _ in 0..64 {
            let x = g.next_u64();
            (or, and) = (or | x, and & x);
        }
        assert_eq!((or, and), (u64::MAX, 0));
    }
}
