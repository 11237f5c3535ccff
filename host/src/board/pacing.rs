//! Live pacing: a robot's camera does not wait for the device. A callback
//! that gets a frame every 33 ms asks [`Session::busy`] whether the device
//! is still working on earlier frames and, if so, skips this one instead of
//! blocking or queueing frames without bound; [`Session::try_push_frame`]
//! does both in one call. [`stream_realtime`] (`placedb stream
//! --realtime`) replays a recorded sequence so, at its recorded rate, and
//! names every frame it skipped.

use super::error::DeviceError;
use super::link::Link;
use super::scan::DepthFrame;
use super::session::Session;
use crate::degradation::plural;
use crate::sequence::Clock;
use crate::Sequence;
use placedb::protocol::{Config, Status};
use std::time::{Duration, Instant};

/// The longest [`Session::busy`] waits for a reply that is on its way.
pub const POLL: Duration = Duration::from_millis(1);

impl<L: Link> Session<L> {
    /// Whether the device is still busy with earlier frames: a message sent
    /// to it is not answered yet. Takes the replies that have arrived (their
    /// decisions land in [`Session::take_decisions`]); never waits for the
    /// device, only up to [`POLL`] for bytes already on their way.
    pub fn busy(&mut self) -> Result<bool, DeviceError> {
        while self.state.unanswered() > 0 {
            if !self.state.answered(&mut self.client, POLL)? {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// Sends `frame` unless the device is [`busy`](Session::busy): its
    /// index if sent, `None` if skipped (the device never sees it, and the
    /// next sent frame takes the next index). A sent frame's messages go
    /// out without waiting for their replies (at most this one frame is
    /// unanswered, as the device was not busy), so this does not wait for
    /// the device either. With [`StreamOptions::retries`] > 0 every message
    /// waits for its reply (stop-and-wait), so the call takes as long as the
    /// device takes for the frame.
    pub fn try_push_frame(&mut self, frame: &DepthFrame<'_>) -> Result<Option<u32>, DeviceError> {
        if self.busy()? {
            return Ok(None);
        }
        self.state.push_unbounded(&mut self.client, frame).map(Some)
    }
}

/// When each frame of a real-time replay is due, and where that rate came
/// from.
#[derive(Debug, Clone, PartialEq)]
pub struct Pace {
    /// Seconds after the first frame's due time that frame `i` is due.
    pub offsets: Vec<f64>,
    /// Frames per second of the replay: the rate given, the layout's, or
    /// the recorded timestamps' mean (0 for a single frame).
    pub rate: f64,
    /// Where the rate comes from, for the summary ("--rate 10", "the
    /// 7-Scenes layout's camera rate", "the recorded timestamps").
    pub source: String,
}

/// The most frames per second `--rate` takes.
pub const MAX_RATE: f64 = 1000.0;

impl Pace {
    /// The pace of `seq`: with `rate` (`--rate HZ`), frame `i` is due `i /
    /// rate` seconds after the first; else a layout that numbers its frames
    /// ([`Clock::FrameNumbers`], 7-Scenes) is replayed at its camera's
    /// rate by position in the sequence, so a gap in the numbering (a
    /// renumbered or thinned-out sequence) never idles; a stamped layout
    /// ([`Clock::Seconds`]) is replayed at its stamps, as `ros2 bag play`
    /// does.
    pub fn of(seq: &Sequence, rate: Option<f64>) -> Result<Pace, DeviceError> {
        let n = seq.frames.len();
        let by_position = |hz: f64, source: String| Pace {
            offsets: (0..n).map(|i| i as f64 / hz).collect(),
            rate: hz,
            source,
        };
        if let Some(hz) = rate {
            if !(hz > 0.0 && hz <= MAX_RATE) {
                return Err(DeviceError::Input(format!(
                    "--rate {hz}: a replay rate is from above 0 to {MAX_RATE} frames per second"
                )));
            }
            return Ok(by_position(hz, format!("--rate {hz}")));
        }
        match seq.clock {
            Clock::FrameNumbers { hz } => Ok(by_position(
                hz,
                format!("the layout's camera rate, {hz} Hz: its frames are numbered, not stamped"),
            )),
            Clock::Seconds => {
                let first = seq.frames.first().map_or(0.0, |f| f.timestamp);
                let offsets: Vec<f64> = seq
                    .frames
                    .iter()
                    .map(|f| (f.timestamp - first).max(0.0))
                    .collect();
                let duration = offsets.last().copied().unwrap_or(0.0);
                Ok(Pace {
                    rate: if n > 1 && duration > 0.0 {
                        (n - 1) as f64 / duration
                    } else {
                        0.0
                    },
                    offsets,
                    source: "the recorded timestamps".to_string(),
                })
            }
        }
    }
}

/// What a real-time replay did.
#[derive(Debug, Clone)]
pub struct RealtimeReport {
    /// Sequence frames sent, in order: the device's frame `k` is sequence
    /// frame `sent[k]`.
    pub sent: Vec<usize>,
    /// Sequence frames skipped because the device was busy when they were
    /// due: they have no label.
    pub skipped: Vec<usize>,
    /// The replay's rate, frames per second ([`Pace::rate`]).
    pub rate: f64,
    /// Where the rate came from ([`Pace::source`]).
    pub rate_source: String,
    /// Wall time from the first frame's due time to the last reply.
    pub wall: Duration,
    /// The device's status after Finish.
    pub status: Status,
}

/// Replays `seq` on `session` at `pace` (frame `i` is due
/// `pace.offsets[i]` seconds after the first), skipping every frame that
/// finds the device busy, then ends the scan with Finish. Frames are read
/// from disk before they are due (as a camera driver delivers them ready);
/// a host that falls behind offers each frame as soon as it has it.
pub fn stream_realtime<L: Link>(
    session: &mut Session<L>,
    seq: &Sequence,
    cfg: &Config,
    profile: &str,
    pace: &Pace,
) -> Result<RealtimeReport, DeviceError> {
    session.start(cfg, Some(profile))?;
    let mut sent = Vec::new();
    let mut skipped = Vec::new();
    let start = Instant::now();
    for (i, info) in seq.frames.iter().enumerate() {
        let img = seq
            .depth(i)
            .map_err(|e| DeviceError::Input(format!("frame {i}: {e}")))?;
        let pose = info
            .pose()
            .map_err(|e| DeviceError::Input(format!("frame {i}: pose: {e}")))?;
        let offset = pace.offsets.get(i).copied().unwrap_or(0.0);
        let due = start + Duration::from_secs_f64(offset);
        // Until it is due, take the replies (decisions) as they come.
        while let Some(left) = due.checked_duration_since(Instant::now()) {
            if left.is_zero() || !session.busy()? {
                std::thread::sleep(left.min(POLL));
            }
        }
        let frame = DepthFrame {
            timestamp: info.timestamp,
            pose,
            intrinsics: cfg.intrinsics,
            depth: &img.data,
        };
        match session.try_push_frame(&frame)? {
            Some(_) => sent.push(i),
            None => skipped.push(i),
        }
    }
    let status = session.finish()?;
    Ok(RealtimeReport {
        rate: pace.rate,
        rate_source: pace.source.clone(),
        sent,
        skipped,
        wall: start.elapsed(),
        status,
    })
}

/// Frame indices as ranges: `3, 7-9, 12`.
pub fn index_ranges(frames: &[usize]) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut i = 0;
    while let Some(&a) = frames.get(i) {
        let mut j = i;
        while frames.get(j + 1) == Some(&(frames[j] + 1)) {
            j += 1;
        }
        out.push(if j == i {
            a.to_string()
        } else {
            format!("{a}-{}", frames[j])
        });
        i = j + 1;
    }
    out.join(", ")
}

impl RealtimeReport {
    /// Refuses a replay whose sent frames gave the device no valid depth
    /// pixel (`placedb stream`'s refusal): it measured nothing, however many
    /// frames went out, and must not read as a success. Happens when the
    /// frames with depth were all skipped (the sequence has some: it was
    /// checked before the device was touched). The skipped frames are named.
    pub fn check_measured(&self, seq: &Sequence) -> Result<(), DeviceError> {
        if self.status.valid_pixels > 0 {
            return Ok(());
        }
        let skipped = if self.skipped.is_empty() {
            "none was skipped".to_string()
        } else {
            format!(
                "{} skipped because the device was busy when they were due (they have no label): {}",
                plural(self.skipped.len() as u64, "frame", "frames"),
                index_ranges(&self.skipped)
            )
        };
        Err(DeviceError::Input(format!(
            "{}: the device found no valid depth pixel in the {} it was sent ({}), so the \
             real-time replay measured nothing; {skipped}. Stream it without --realtime to send \
             every frame",
            seq.name,
            plural(self.sent.len() as u64, "frame", "frames"),
            index_ranges(&self.sent)
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::client::Client;
    use crate::board::link::LocalLink;
    use crate::board::scan::StreamOptions;
    use crate::synth::{self, SynthConfig};
    use crate::VoxelConfig;
    use placedb::SelectorConfig;
    use std::io;

    fn demo(frames: usize) -> Sequence {
        let mut seq = synth::sequence(&SynthConfig::demo());
        seq.frames.truncate(frames);
        seq
    }

    fn config(seq: &Sequence) -> Config {
        let vcfg = VoxelConfig {
            stride: 8,
            ..VoxelConfig::default()
        };
        let sel = SelectorConfig {
            mu: 0.3,
            window: 8,
            sketch_margin: 0.05,
        };
        crate::board::scan::device_config(
            &crate::board::scan::scan_config(seq, &vcfg).unwrap(),
            &sel,
        )
        .unwrap()
    }

    /// A device that has answered the Hello and then goes silent: every
    /// byte sent is kept, nothing more comes back.
    struct Silent {
        inner: LocalLink,
        mute: bool,
        sent: Vec<u8>,
    }

    impl Link for Silent {
        fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
            if self.mute {
                self.sent.extend_from_slice(bytes);
                return Ok(());
            }
            self.inner.send(bytes)
        }

        fn recv(&mut self, timeout: Duration) -> io::Result<Vec<u8>> {
            if self.mute {
                return Err(io::ErrorKind::TimedOut.into());
            }
            self.inner.recv(timeout)
        }
    }

    #[test]
    fn a_busy_device_makes_the_next_frame_skip_without_waiting() {
        let seq = demo(2);
        let cfg = config(&seq);
        let link = Silent {
            inner: LocalLink::start("ram256k").unwrap(),
            mute: false,
            sent: Vec::new(),
        };
        // Two rows a message: the 30 strided rows take 15 DepthRows.
        let opts = StreamOptions {
            rows_per_message: 2,
            ..StreamOptions::default()
        };
        let mut session = Session::new(Client::new(link), opts);
        session.start(&cfg, Some("ram256k")).unwrap();
        assert!(!session.busy().unwrap(), "the Hello was answered");
        session.client().link().mute = true;
        let img = seq.depth(0).unwrap();
        let frame = DepthFrame {
            timestamp: 1.0,
            pose: seq.frames[0].pose().unwrap(),
            intrinsics: cfg.intrinsics,
            depth: &img.data,
        };
        assert_eq!(session.try_push_frame(&frame).unwrap(), Some(0));
        // The whole frame went out though nothing was answered (more
        // messages than the in-flight window of 4).
        let frames = session
            .client()
            .link()
            .sent
            .iter()
            .filter(|&&b| b == 0)
            .count();
        let messages = 2 + 15;
        assert_eq!(frames, messages);
        assert!(messages > StreamOptions::default().in_flight);
        assert!(session.busy().unwrap());
        assert_eq!(session.try_push_frame(&frame).unwrap(), None, "skipped");
        assert_eq!(session.next_frame(), 1, "a skipped frame takes no index");
    }

    #[test]
    fn a_device_that_answered_takes_the_next_frame() {
        let seq = demo(3);
        let cfg = config(&seq);
        let link = LocalLink::start("ram256k").unwrap();
        let mut session = Session::new(Client::new(link), StreamOptions::default());
        session.start(&cfg, Some("ram256k")).unwrap();
        for i in 0..3 {
            let img = seq.depth(i).unwrap();
            let frame = DepthFrame {
                timestamp: seq.frames[i].timestamp,
                pose: seq.frames[i].pose().unwrap(),
                intrinsics: cfg.intrinsics,
                depth: &img.data,
            };
            while session.busy().unwrap() {}
            assert_eq!(session.try_push_frame(&frame).unwrap(), Some(i as u32));
        }
        let st = session.finish().unwrap();
        assert_eq!(st.frames_seen, 3);
    }

    #[test]
    fn a_realtime_replay_names_every_frame_it_skipped() {
        // Ten times the recorded rate: whatever the device keeps up with,
        // every frame is either sent (and labelled) or named as skipped.
        let seq = demo(20);
        let cfg = config(&seq);
        let link = LocalLink::start("ram256k").unwrap();
        let mut session = Session::new(Client::new(link), StreamOptions::default());
        let pace = Pace::of(&seq, Some(300.0)).unwrap();
        let report = stream_realtime(&mut session, &seq, &cfg, "ram256k", &pace).unwrap();
        let mut all: Vec<usize> = report.sent.iter().chain(&report.skipped).copied().collect();
        all.sort_unstable();
        assert_eq!(all, (0..20).collect::<Vec<_>>());
        assert_eq!(
            report.sent.first(),
            Some(&0),
            "the first frame finds the device idle"
        );
        assert_eq!(report.status.frames_seen as usize, report.sent.len());
        let export = session.export().unwrap();
        let (timestamps, _) = export.labels();
        let sent: Vec<f64> = report
            .sent
            .iter()
            .map(|&i| seq.frames[i].timestamp)
            .collect();
        assert_eq!(
            timestamps, sent,
            "a label for every sent frame, none for a skipped one"
        );
        assert_eq!(report.rate, 300.0);
    }

    /// `demo(n)` with frame numbers for timestamps (the 7-Scenes clock).
    fn numbered(numbers: &[u32]) -> Sequence {
        let mut seq = demo(numbers.len());
        seq.clock = Clock::FrameNumbers { hz: 30.0 };
        for (f, &n) in seq.frames.iter_mut().zip(numbers) {
            f.timestamp = f64::from(n);
        }
        seq
    }

    #[test]
    fn frame_numbers_are_paced_at_the_camera_rate_by_position_never_idling_on_a_gap() {
        // Frames 0, 1, 2 and then 2,000 (a renumbered sequence): the fourth
        // is due 3/30 s after the first, not 2,000 s (or 2,000/30 s).
        let pace = Pace::of(&numbered(&[0, 1, 2, 2000]), None).unwrap();
        let want = [0.0, 1.0 / 30.0, 2.0 / 30.0, 3.0 / 30.0];
        assert_eq!(pace.offsets.len(), 4);
        for (got, want) in pace.offsets.iter().zip(want) {
            assert!((got - want).abs() < 1e-12, "{:?}", pace.offsets);
        }
        assert_eq!(pace.rate, 30.0);
        assert!(pace.source.contains("camera rate"), "{}", pace.source);
    }

    #[test]
    fn stamps_are_replayed_as_recorded_and_rate_overrides_them() {
        // The synthetic camera stamps its frames at 30 Hz from 1.0 s.
        let seq = demo(4);
        assert_eq!(seq.clock, Clock::Seconds);
        let pace = Pace::of(&seq, None).unwrap();
        assert!((pace.offsets[3] - 0.1).abs() < 1e-5, "{:?}", pace.offsets);
        assert!((pace.rate - 30.0).abs() < 0.01, "{}", pace.rate);
        let fast = Pace::of(&seq, Some(10.0)).unwrap();
        for (got, want) in fast.offsets.iter().zip([0.0, 0.1, 0.2, 0.3]) {
            assert!((got - want).abs() < 1e-12, "{:?}", fast.offsets);
        }
        assert_eq!(fast.source, "--rate 10");
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY, 1000.5] {
            let e = Pace::of(&seq, Some(bad)).unwrap_err().to_string();
            assert!(e.contains("from above 0 to 1000 frames per second"), "{e}");
        }
    }

    #[test]
    fn index_ranges_are_compact() {
        assert_eq!(index_ranges(&[]), "");
        assert_eq!(index_ranges(&[3, 7, 8, 9, 12]), "3, 7-9, 12");
    }
}
