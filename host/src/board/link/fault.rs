//! Fault injection on a [`Link`], after smoltcp's `FaultInjector`: whole
//! frames dropped, or one random bit of a frame flipped, in either direction,
//! decided by a seeded PRNG so that a run is reproducible.
//!
//! Faults act on COBS frames (the bytes up to and including a 0x00):
//!
//! - host to device: each frame handed to [`Link::send`] is dropped (delimiter
//!   and all) with probability `drop_chance`, else one bit of one of its body
//!   bytes is flipped with probability `corrupt_chance`. The device answers a
//!   damaged frame with a typed error ([`placedb::protocol::ErrorKind::is_damage`]);
//!   a dropped one with silence.
//! - device to host: received bytes are reassembled into frames and each frame
//!   is dropped or corrupted the same way before the client sees it.
//!
//! Empty frames (a lone 0x00, the resynchronisation byte) pass untouched. A
//! flipped bit can turn a byte into 0x00 and so split a frame in two: the
//! receiver then sees two damaged frames, as on a real line.
//!
//! `placedb stream --drop-chance P --corrupt-chance P --fault-seed S` wraps
//! its link in a [`FaultInjector`]; the host recovers by retransmission (see
//! [`crate::board::scan::StreamOptions::retries`]).

use crate::board::link::Link;
use crate::rng::SplitMix64;
use std::io;
use std::time::{Duration, Instant};

/// What to inject.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaultConfig {
    /// Probability that a frame is dropped, in `[0, 1]`.
    pub drop_chance: f64,
    /// Probability that a frame (not dropped) has one bit flipped, in `[0, 1]`.
    pub corrupt_chance: f64,
    /// Seed of the PRNG.
    pub seed: u64,
    /// Inject into frames sent by the host.
    pub host_to_device: bool,
    /// Inject into frames received from the device.
    pub device_to_host: bool,
}

impl Default for FaultConfig {
    /// No faults, both directions enabled, seed 1.
    fn default() -> Self {
        FaultConfig {
            drop_chance: 0.0,
            corrupt_chance: 0.0,
            seed: 1,
            host_to_device: true,
            device_to_host: true,
        }
    }
}

impl FaultConfig {
    /// Both directions, `drop` and `corrupt` chances, `seed`.
    pub fn new(drop: f64, corrupt: f64, seed: u64) -> FaultConfig {
        FaultConfig {
            drop_chance: drop,
            corrupt_chance: corrupt,
            seed,
            ..FaultConfig::default()
        }
    }

    /// Whether any fault can happen.
    pub fn is_active(&self) -> bool {
        (self.drop_chance > 0.0 || self.corrupt_chance > 0.0)
            && (self.host_to_device || self.device_to_host)
    }

    /// Checks that both chances are probabilities.
    pub fn validate(&self) -> Result<(), String> {
        for (name, p) in [
            ("drop chance", self.drop_chance),
            ("corrupt chance", self.corrupt_chance),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return Err(format!("{name} {p} is not in [0, 1]"));
            }
        }
        Ok(())
    }
}

/// Counts of what the injector did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FaultStats {
    /// Non-empty frames the host sent.
    pub sent: u64,
    /// Of those, dropped.
    pub sent_dropped: u64,
    /// Of those, corrupted.
    pub sent_corrupted: u64,
    /// Non-empty frames the device sent.
    pub received: u64,
    /// Of those, dropped.
    pub received_dropped: u64,
    /// Of those, corrupted.
    pub received_corrupted: u64,
}

/// What happened to one frame.
enum Fate {
    Pass,
    Drop,
    Corrupt,
}

/// A [`Link`] that drops and corrupts frames of the link it wraps.
pub struct FaultInjector<L: Link> {
    inner: L,
    cfg: FaultConfig,
    rng: SplitMix64,
    /// Bytes of a device frame not complete yet.
    partial: Vec<u8>,
    /// Device frames that survived, not handed out yet.
    ready: Vec<u8>,
    stats: FaultStats,
}

impl<L: Link> FaultInjector<L> {
    /// Wraps `inner`.
    pub fn new(inner: L, cfg: FaultConfig) -> FaultInjector<L> {
        FaultInjector {
            inner,
            rng: SplitMix64::new(cfg.seed),
            cfg,
            partial: Vec::new(),
            ready: Vec::new(),
            stats: FaultStats::default(),
        }
    }

    /// What was injected so far.
    pub fn stats(&self) -> FaultStats {
        self.stats
    }

    /// The wrapped link.
    pub fn inner(&self) -> &L {
        &self.inner
    }

    /// The wrapped link, mutably (bytes sent through it are not faulted).
    pub fn inner_mut(&mut self) -> &mut L {
        &mut self.inner
    }

    /// Gives the wrapped link back.
    pub fn into_inner(self) -> L {
        self.inner
    }

    fn fate(&mut self) -> Fate {
        // Always draw both numbers so that a run's faults depend only on the seed
        // and the frame count, not on the chances.
        let (d, c) = (self.rng.unit(), self.rng.unit());
        if d < self.cfg.drop_chance {
            Fate::Drop
        } else if c < self.cfg.corrupt_chance {
            Fate::Corrupt
        } else {
            Fate::Pass
        }
    }

    /// Flips one bit of one body byte of `frame` (its delimiter is kept).
    fn corrupt(&mut self, frame: &mut [u8]) {
        let body = frame.len().saturating_sub(1);
        if body == 0 {
            return;
        }
        let at = self.rng.below(body as u64) as usize;
        let bit = self.rng.below(8);
        frame[at] ^= 1 << bit;
    }

    /// Applies a fate to a complete frame (delimiter included) and appends
    /// what survives to `out`; returns (dropped, corrupted).
    fn process(&mut self, mut frame: Vec<u8>, enabled: bool, out: &mut Vec<u8>) -> (bool, bool) {
        if frame.len() <= 1 || !enabled {
            out.extend_from_slice(&frame);
            return (false, false);
        }
        match self.fate() {
            Fate::Drop => (true, false),
            Fate::Corrupt => {
                self.corrupt(&mut frame);
                out.extend_from_slice(&frame);
                (false, true)
            }
            Fate::Pass => {
                out.extend_from_slice(&frame);
                (false, false)
            }
        }
    }
}

impl<L: Link> Link for FaultInjector<L> {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        let mut out = Vec::with_capacity(bytes.len());
        for frame in bytes.split_inclusive(|&b| b == 0) {
            let whole = frame.last() == Some(&0);
            if !whole {
                // An unterminated tail (not something the client sends): as is.
                out.extend_from_slice(frame);
                continue;
            }
            let counted = frame.len() > 1;
            let (dropped, corrupted) =
                self.process(frame.to_vec(), self.cfg.host_to_device, &mut out);
            if counted {
                self.stats.sent += 1;
                self.stats.sent_dropped += u64::from(dropped);
                self.stats.sent_corrupted += u64::from(corrupted);
            }
        }
        if out.is_empty() {
            return Ok(());
        }
        self.inner.send(&out)
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Vec<u8>> {
        let end = Instant::now() + timeout;
        loop {
            if !self.ready.is_empty() {
                return Ok(std::mem::take(&mut self.ready));
            }
            let left = end.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!(
                        "no bytes from the device within {}",
                        crate::error::seconds(timeout)
                    ),
                ));
            }
            let bytes = self.inner.recv(left)?;
            let mut ready = std::mem::take(&mut self.ready);
            for &b in &bytes {
                self.partial.push(b);
                if b == 0 {
                    let frame = std::mem::take(&mut self.partial);
                    let counted = frame.len() > 1;
                    let (dropped, corrupted) =
                        self.process(frame, self.cfg.device_to_host, &mut ready);
                    if counted {
                        self.stats.received += 1;
                        self.stats.received_dropped += u64::from(dropped);
                        self.stats.received_corrupted += u64::from(corrupted);
                    }
                }
            }
            self.ready = ready;
        }
    }
}

/// `msg` with sequence number `seq`, framed, with one byte flipped so that a
/// device reports `BadCrc` and can still read the sequence number — checked
/// with the decoder the firmware runs. `None` if no single flip does that.
pub fn damaged_frame(seq: u32, msg: placedb::protocol::HostMessage<'_>) -> Option<Vec<u8>> {
    use placedb::protocol::{
        encode, ErrorKind, Feed, FrameDecoder, HostFrame, ProtocolError, MAX_FRAME_LEN,
    };
    let mut buf = vec![0u8; MAX_FRAME_LEN];
    let good = encode(&HostFrame { seq, msg }, &mut buf).ok()?.to_vec();
    // From the end (the CRC) backwards: the sequence number up front survives.
    (0..good.len().saturating_sub(1)).rev().find_map(|pos| {
        let mut bad = good.clone();
        bad[pos] ^= 0x24;
        if bad[pos] == 0 {
            return None;
        }
        let mut decoder = FrameDecoder::<MAX_FRAME_LEN>::new();
        match decoder.feed::<HostFrame>(&bad) {
            Feed::Frame {
                result:
                    Err(ProtocolError {
                        kind: ErrorKind::BadCrc,
                        seq: Some(s),
                    }),
                remaining: [],
            } if s == seq => Some(bad),
            _ => None,
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::VecDeque;

    /// A link that records what is sent and plays back scripted chunks.
    #[derive(Default)]
    struct Loop {
        sent: Vec<u8>,
        script: VecDeque<Vec<u8>>,
    }

    impl Link for Loop {
        fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
            self.sent.extend_from_slice(bytes);
            Ok(())
        }

        fn recv(&mut self, _: Duration) -> io::Result<Vec<u8>> {
            self.script
                .pop_front()
                .ok_or_else(|| io::ErrorKind::TimedOut.into())
        }
    }

    fn frames(n: usize) -> Vec<Vec<u8>> {
        (0..n)
            .map(|i| {
                let mut f: Vec<u8> = (1..=20).map(|b| (b + i) as u8 | 1).collect();
                f.push(0);
                f
            })
            .collect()
    }

    #[test]
    fn no_faults_pass_everything() {
        let mut link = FaultInjector::new(Loop::default(), FaultConfig::default());
        let all: Vec<u8> = frames(50).concat();
        link.send(&all).unwrap();
        link.send(&[0]).unwrap();
        assert_eq!(link.inner().sent[..all.len()], all[..]);
        assert_eq!(link.stats().sent, 50);
    }

    #[test]
    fn faults_are_reproducible_and_near_their_rates() {
        let run = |seed| {
            let cfg = FaultConfig::new(0.1, 0.1, seed);
            let mut link = FaultInjector::new(Loop::default(), cfg);
            for f in frames(2000) {
                link.send(&f).unwrap();
            }
            // The device's frames arrive split across chunks.
            let all: Vec<u8> = frames(2000).concat();
            link.inner_mut().script = all.chunks(37).map(<[u8]>::to_vec).collect();
            let mut got = Vec::new();
            while let Ok(b) = link.recv(Duration::from_millis(1)) {
                got.extend(b);
            }
            (link.inner().sent.clone(), got, link.stats())
        };
        let (sent, got, stats) = run(7);
        assert_eq!(run(7).0, sent);
        assert_eq!(run(7).1, got);
        assert_ne!(run(8).0, sent);
        for (n, dropped, corrupted) in [
            (stats.sent, stats.sent_dropped, stats.sent_corrupted),
            (
                stats.received,
                stats.received_dropped,
                stats.received_corrupted,
            ),
        ] {
            assert_eq!(n, 2000);
            assert!((150..250).contains(&dropped), "{stats:?}");
            assert!((130..230).contains(&corrupted), "{stats:?}");
        }
        // What passed is whole frames: dropped ones missing, corrupted ones one bit off.
        let clean = frames(2000).concat();
        let kept = 2000 - stats.sent_dropped as usize;
        assert!(sent.len() <= clean.len());
        assert!(sent.iter().filter(|&&b| b == 0).count() >= kept);
    }
}
