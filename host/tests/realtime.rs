//! `placedb stream --realtime` (`placedb_host::board::pacing`): a replay
//! whose sent frames gave the device no valid depth pixel measured nothing
//! and is an error, never a success, however many frames went out; the
//! frames it skipped are counted and named in it. The device is the
//! in-process one (`local:`) behind a link that answers late, so that the
//! frames after the first are due while it is busy, whatever the machine.

use placedb_host::board::link::{Link, LocalLink};
use placedb_host::cli::stream::realtime::realtime_on;
use placedb_host::testing::{demo, selector, voxel_config};
use placedb_host::{DepthImage, DepthSource, ReadError};
use std::collections::VecDeque;
use std::io;
use std::time::{Duration, Instant};

const PROFILE: &str = "ram256k";

/// The in-process device, each of whose replies reaches the host `delay`
/// after the device sent it.
struct Late {
    inner: LocalLink,
    delay: Duration,
    held: VecDeque<(Instant, Vec<u8>)>,
}

impl Link for Late {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.inner.send(bytes)
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Vec<u8>> {
        let end = Instant::now() + timeout;
        loop {
            loop {
                match self.inner.recv(Duration::ZERO) {
                    Ok(bytes) => self.held.push_back((Instant::now() + self.delay, bytes)),
                    Err(e) if e.kind() == io::ErrorKind::TimedOut => break,
                    Err(e) => return Err(e),
                }
            }
            let now = Instant::now();
            if self.held.front().is_some_and(|(due, _)| *due <= now) {
                return Ok(self.held.pop_front().map(|(_, b)| b).unwrap_or_default());
            }
            if now >= end {
                return Err(io::ErrorKind::TimedOut.into());
            }
            std::thread::sleep((end - now).min(Duration::from_millis(1)));
        }
    }
}

/// A sequence's depth with frame 0's emptied (no measurement anywhere).
struct FirstBlank(Box<dyn DepthSource>);

impl DepthSource for FirstBlank {
    fn depth(&self, i: usize) -> Result<DepthImage, ReadError> {
        let mut img = self.0.depth(i)?;
        if i == 0 {
            img.data.fill(0);
        }
        Ok(img)
    }
}

#[test]
fn a_realtime_replay_that_sent_only_frames_without_depth_is_an_error_naming_the_skipped() {
    // Three frames 33 ms apart; the device answers 400 ms late, so the
    // first (blank) frame is sent and the two with depth are skipped.
    let mut seq = demo(3);
    seq.source = Box::new(FirstBlank(seq.source));
    let link = Late {
        inner: LocalLink::start(PROFILE).unwrap(),
        delay: Duration::from_millis(400),
        held: VecDeque::new(),
    };
    let err = realtime_on(
        link,
        "local:ram256k",
        &seq,
        &voxel_config(8),
        selector(6),
        PROFILE,
        None,
        false,
        None,
    )
    .expect_err("a replay that measured nothing succeeded")
    .to_string();
    for want in [
        "no valid depth pixel in the 1 frame it was sent (0)",
        "measured nothing",
        "2 frames skipped because the device was busy",
        "no label): 1-2",
        "without --realtime",
    ] {
        assert!(err.contains(want), "{want:?} not in: {err}");
    }
}
