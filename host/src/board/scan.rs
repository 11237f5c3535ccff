//! Streaming a scan to a device: the options ([`StreamOptions`], and
//! [`Recovery`] for a lossy link), the scan and Hello configuration of a
//! sequence, one depth frame in memory ([`DepthFrame`]), what a scan has sent
//! and been told ([`ScanState`], which the public
//! [`Session`](crate::board::session::Session) drives too), and [`stream`],
//! which sends a recorded sequence (`placedb stream`).
//!
//! The device is the core's [`placedb::device::Device`], on a board or
//! in-process (`local:PROFILE`); what it selects is what `placedb select
//! --solver online` computes with the same profile and configuration.
//!
//! Over a lossy link ([`StreamOptions::retries`] > 0, e.g. `placedb stream
//! --drop-chance 0.05 --corrupt-chance 0.05`, which wraps the link in a
//! [`crate::board::link::fault::FaultInjector`]) the host goes stop-and-wait
//! and retransmits a message with the same sequence number when its reply is
//! late or says the frame was damaged
//! ([`exchange`](crate::board::client::exchange)); the device answers a
//! repeat without applying it twice.

use crate::board::client::{ask_status, check_profile, send_and_wait, Client, Received, Wait};
use crate::board::config_words;
use crate::board::error::DeviceError;
use crate::board::export::{self, ExportOptions};
use crate::board::link::fault::FaultConfig;
use crate::board::link::Link;
use crate::board::log_records;
use crate::degradation::plural;
use crate::frame_rows::{row_chunks, sampled_rows_of};
use crate::sequence::Sequence;
use crate::voxelize::{self, GridOrigin, VoxelConfig};
use indicatif::ProgressBar;
use placedb::protocol::{
    degradation, depth_rows_per_message, CapacitySlot, Config, DecisionKind, DeviceMessage,
    ErrorKind, HostMessage, Phase, Status,
};
use placedb::{Intrinsics, Pose, ScanConfig, SelectorConfig, VoxelGrid};
use std::collections::VecDeque;
use std::io;
use std::time::{Duration, Instant};

/// How to stream.
#[derive(Debug, Clone)]
pub struct StreamOptions {
    /// Strided rows per DepthRows message (0: as many as fit a frame).
    pub rows_per_message: u16,
    /// Messages sent ahead of their replies (1 = stop-and-wait).
    pub in_flight: usize,
    /// Longest wait for one reply. The default outlasts the longest flash
    /// stall of a Pico reply at the datasheet's maximum timing
    /// ([`crate::board::flash_timing::WorstStall`]).
    pub reply_timeout: Duration,
    /// Reset the device before the Hello (a new scan).
    pub reset: bool,
    /// Go on with the scan the device holds (after a power cut it restores
    /// it from flash): no Reset, the same Hello (the device accepts an
    /// identical one), frames from the device's `frames_seen` on.
    pub resume: bool,
    /// Continue the finished scan the device holds in flash with a new
    /// session (`placedb stream --extend`): no Reset, an Extend instead of
    /// the Hello (the same configuration as the first session's), the
    /// sequence's frames numbered on from the earlier sessions' frames. A
    /// session begun so and cut short (a power cut) resumes where the
    /// device stopped.
    pub extend: bool,
    /// End with Finish (decides the frames still pending).
    pub finish: bool,
    /// With `reset`: replace the scan the device holds (frames seen, or
    /// finished; `placedb stream --new-scan`). Without it such a device is
    /// refused in words naming what it holds, and nothing changes.
    pub new_scan: bool,
    /// Retransmissions allowed per message. 0: messages are pipelined
    /// (`in_flight`) and the first error or timeout ends the stream. Above 0:
    /// stop-and-wait, and a message whose terminal reply does not come within
    /// `resend_after`, or is an error saying the frame was damaged, is sent
    /// again with the same sequence number (the device answers a repeat
    /// without applying it twice).
    pub retries: usize,
    /// With `retries > 0`: how long to wait for a terminal reply before
    /// sending the message again.
    pub resend_after: Duration,
}

impl StreamOptions {
    /// The defaults, replacing any scan the device holds ([`Self::new_scan`]):
    /// for measurements, which stream to one board again and again.
    pub fn replacing() -> StreamOptions {
        StreamOptions {
            new_scan: true,
            ..StreamOptions::default()
        }
    }

    /// How a message of the scan's set-up waits for its reply: once, or
    /// stop-and-wait with retransmission when `retries > 0`.
    pub fn wait(&self) -> Wait {
        match self.retries {
            0 => Wait::Once(self.reply_timeout),
            retries => Wait::Resend {
                after: self.resend_after,
                retries,
            },
        }
    }
}

impl Default for StreamOptions {
    fn default() -> Self {
        StreamOptions {
            rows_per_message: 0,
            in_flight: 4,
            reply_timeout: Duration::from_secs(60),
            reset: true,
            resume: false,
            extend: false,
            finish: true,
            new_scan: false,
            retries: 0,
            resend_after: Duration::from_secs(2),
        }
    }
}

/// What a board that `st` describes holds, in words ("a finished scan of
/// 40 frames, 3 database frames"), when it holds a scan that a new one
/// would replace: frames seen, or finished; `None` for an empty board.
pub fn held_scan(st: &Status) -> Option<String> {
    if st.frames_seen == 0 && st.phase != Phase::Finished {
        return None;
    }
    Some(format!(
        "{} scan of {} ({} decided), {}{}",
        if st.phase == Phase::Finished {
            "a finished"
        } else {
            "an unfinished"
        },
        plural(st.frames_seen.into(), "frame", "frames"),
        st.frames_decided,
        plural(st.database_size.into(), "database frame", "database frames"),
        match st.sessions {
            0 | 1 => String::new(),
            n => format!(" in {n} sessions"),
        }
    ))
}

/// What a stream did.
#[derive(Debug, Clone)]
pub struct StreamReport {
    /// Frames sent.
    pub frames: usize,
    /// The device's index of the sequence's first frame: 0, or for an
    /// extended scan the frames of the earlier sessions.
    pub first_index: u32,
    /// Final decision of every frame, by the device's index.
    pub decisions: Vec<Option<DecisionKind>>,
    /// The device's status after Finish.
    pub status: Status,
    /// Wall time from Hello to the last reply.
    pub wall: Duration,
    /// Bytes written to the link.
    pub bytes_sent: u64,
    /// Messages sent.
    pub messages: u64,
    /// Messages sent again (lost or damaged on the way, or their reply was).
    pub retransmissions: u64,
    /// The device's flash log filled up: frames of the sequence from this
    /// one on were not scanned (the open one was dropped, the scan finished
    /// with the rest).
    pub log_full_at: Option<usize>,
}

impl StreamReport {
    /// Frames per second over the link, wall clock.
    pub fn fps(&self) -> f64 {
        self.frames as f64 / self.wall.as_secs_f64().max(1e-9)
    }

    /// Mean device clock ticks per frame (instructions for the QEMU board
    /// under `-icount shift=0`), if the device has a clock.
    pub fn ticks_per_frame(&self) -> Option<f64> {
        let c = &self.status.cost;
        (c.clock_hz > 0 && c.frames > 0).then(|| c.total as f64 / f64::from(c.frames))
    }
}

/// The scan configuration `placedb select` uses for `seq` and `vcfg`: the
/// same intrinsics, depth scale, range, stride and grid.
pub fn scan_config(seq: &Sequence, vcfg: &VoxelConfig) -> Result<ScanConfig, DeviceError> {
    let grid = match vcfg.origin {
        GridOrigin::World => VoxelGrid::new(vcfg.voxel, [0.0; 3])
            .map_err(|e| DeviceError::Input(format!("--voxel {}: {e}", vcfg.voxel)))?,
        // The scene's corner needs every frame first, as select does.
        GridOrigin::SceneMin => {
            voxelize::voxelize(seq, vcfg, None)
                .map_err(|e| DeviceError::Input(e.to_string()))?
                .grid
        }
    };
    Ok(ScanConfig {
        intrinsics: seq.intrinsics(),
        depth_scale: seq.depth_scale as f32,
        range: vcfg.range,
        stride: vcfg.stride,
        grid,
    })
}

/// The Hello for `scan` and `sel`, checked as the device will check it.
pub fn device_config(scan: &ScanConfig, sel: &SelectorConfig) -> Result<Config, DeviceError> {
    let cfg = Config::new(scan, sel);
    cfg.validate().map_err(|kind| {
        DeviceError::Input(format!(
            "the device would refuse this configuration: {kind} \
             (a strided row of {} values must fit one message: use a larger --stride)",
            cfg.width_sent()
        ))
    })?;
    Ok(cfg)
}

/// What a scan of `seq` on a `profile` device sends: the scan
/// configuration, the selector's (its window at least 1) and the Hello they
/// make, checked before a port is opened. `placedb stream`, with or
/// without `--realtime`.
pub fn stream_config(
    seq: &Sequence,
    vcfg: &VoxelConfig,
    sel: SelectorConfig,
    profile: &str,
) -> Result<(ScanConfig, SelectorConfig, Config), DeviceError> {
    if placedb::profile::by_name(profile).is_none() {
        return Err(DeviceError::Input(format!(
            "unknown --profile {profile:?}; see `placedb budget`"
        )));
    }
    let scan = scan_config(seq, vcfg)?;
    let sel = SelectorConfig {
        window: sel.window.max(1),
        ..sel
    };
    let cfg = device_config(&scan, &sel)?;
    Ok((scan, sel, cfg))
}

/// One line about the device's state, for a live status display; `window`:
/// the window the scan was configured with (the device reports its
/// profile's capacity, which the scan may use less of).
pub fn status_line(st: &Status, window: Option<u16>) -> String {
    let c = |slot| {
        let c = st.capacity(slot);
        format!("{}/{}", c.used, c.limit)
    };
    let win = st.capacity(CapacitySlot::Window);
    let win_limit = window.map_or(win.limit, |w| win.limit.min(u32::from(w)));
    let mut s = format!(
        "db {} pool {} win {}/{} labels {} flash {}/{} KiB",
        c(CapacitySlot::Database),
        c(CapacitySlot::Pool),
        win.used,
        win_limit,
        c(CapacitySlot::Labels),
        st.capacity(CapacitySlot::Flash).used / 1024,
        st.capacity(CapacitySlot::Flash).limit / 1024,
    );
    if st.cost.clock_hz > 0 && st.cost.frames > 0 {
        s += &format!(
            " | last frame {:.2} M ticks",
            f64::from(st.cost.last_rows.saturating_add(st.cost.last_end)) / 1e6
        );
    }
    // A scan restored from flash is a resume, not a degradation.
    let restored = st.degradation & degradation::RESTORED != 0;
    let degraded = st.degradation & !degradation::RESTORED;
    if degraded != 0 {
        s += &format!(" | degraded {degraded:#x}");
    }
    if restored {
        s += " | restored from flash";
    }
    s
}

/// Streams `seq` to the device behind `client`: (Reset,) Hello with `cfg`,
/// every frame as FrameBegin, DepthRows, FrameEnd (and a StatusRequest for
/// the live line), then Finish. The device must run capacity profile
/// `profile`. The frames go through the client API's code
/// ([`ScanState`], what [`crate::board::session::Session`] runs), as a robot's would.
pub fn stream<L: Link>(
    client: &mut Client<L>,
    seq: &Sequence,
    cfg: &Config,
    profile: &str,
    opts: &StreamOptions,
    progress: Option<&ProgressBar>,
) -> Result<StreamReport, DeviceError> {
    let n = seq.frames.len();
    let mut scan = ScanState::new(opts.clone());
    let timestamps: Vec<f64> = seq.frames.iter().map(|f| f.timestamp).collect();
    scan.begin(client, cfg, Some(profile), Some(&timestamps))?;
    // The device numbers the sequence's frames from `base` (the earlier
    // sessions' frames, when extending).
    let base = scan.first_index as usize;
    let first = scan.next_frame as usize - base;
    scan.decisions = vec![None; base + n];
    let started = scan.started.unwrap_or_else(Instant::now);
    if let Some(p) = progress {
        p.set_position(first as u64);
    }
    let mut log_full_at = None;
    match send_frames(client, &mut scan, seq, cfg, first..n, progress, started) {
        Ok(()) => {}
        // The device's flash log is full: it kept room to end the scan, so
        // drop the open frame and Finish with every frame so far.
        Err(e) if ScanState::is_log_full(&e) => {
            let at = scan.abandon_open_frame(client)? as usize;
            log_full_at = Some(at.saturating_sub(base));
        }
        Err(e) => return Err(e),
    }
    if opts.finish {
        scan.send(client, HostMessage::Finish, || "Finish".into())?;
    }
    scan.drain(client)?;
    let wall = started.elapsed();
    let status = scan.call_status(client)?;
    Ok(StreamReport {
        frames: log_full_at.unwrap_or(n) - first,
        first_index: scan.first_index,
        log_full_at,
        decisions: scan.decisions,
        status,
        wall,
        bytes_sent: scan.bytes,
        messages: scan.messages,
        retransmissions: scan.retransmissions,
    })
}

/// Sends frames `range` of `seq` (FrameBegin, DepthRows, FrameEnd, and a
/// StatusRequest for the live line) through `scan`.
fn send_frames<L: Link>(
    client: &mut Client<L>,
    scan: &mut ScanState,
    seq: &Sequence,
    cfg: &Config,
    range: std::ops::Range<usize>,
    progress: Option<&ProgressBar>,
    started: Instant,
) -> Result<(), DeviceError> {
    let first = range.start;
    for i in range {
        if let Some(signal) = crate::output::replace::stop_requested() {
            // Asked to stop: every frame sent answered, none left open, so
            // `--resume` goes on from the board's `frames_seen`.
            scan.drain(client)?;
            return Err(DeviceError::Stopped {
                signal,
                next: scan.next_frame,
            });
        }
        scan.push_sequence_frame(client, seq, i, cfg.intrinsics)?;
        // The live line's status; stop-and-wait without a display skips it.
        if scan.opts.retries == 0 || progress.is_some() {
            scan.send(client, HostMessage::StatusRequest, || {
                "StatusRequest".into()
            })?;
        }
        if let Some(p) = progress {
            p.set_position(i as u64 + 1);
            if let Some(st) = &scan.status {
                let fps = (i + 1 - first) as f64 / started.elapsed().as_secs_f64().max(1e-9);
                let line = status_line(st, Some(cfg.window));
                p.set_message(format!("{fps:.2} fps | {line}"));
            }
        }
    }
    Ok(())
}

/// Fault injection and recovery for `placedb stream`.
#[derive(Debug, Clone, Copy)]
pub struct Recovery {
    /// Faults injected into the link (none by default).
    pub faults: FaultConfig,
    /// Retransmissions per message; `None`: 0 without faults (pipelined), 20 with.
    pub retries: Option<usize>,
    /// How long to wait for a terminal reply before sending a message again
    /// (also the export's wait for its next record).
    pub resend_after: Duration,
    /// Resume the scan the device holds (see [`StreamOptions::resume`]).
    pub resume: bool,
    /// Extend the finished scan the device holds ([`StreamOptions::extend`]).
    pub extend: bool,
    /// End the stream with Finish ([`StreamOptions::finish`]).
    pub finish: bool,
    /// Replace the scan the device holds ([`StreamOptions::new_scan`]).
    pub new_scan: bool,
}

impl Default for Recovery {
    fn default() -> Self {
        Recovery {
            faults: FaultConfig::default(),
            retries: None,
            resend_after: Duration::from_secs(2),
            resume: false,
            extend: false,
            finish: true,
            new_scan: false,
        }
    }
}

impl Recovery {
    /// Retransmissions per message.
    pub fn retries(&self) -> usize {
        self.retries
            .unwrap_or(if self.faults.is_active() { 20 } else { 0 })
    }

    /// The stream options: stop-and-wait with retransmission when `retries() > 0`.
    pub fn stream_options(&self) -> StreamOptions {
        StreamOptions {
            retries: self.retries(),
            resend_after: self.resend_after,
            resume: self.resume,
            extend: self.extend,
            finish: self.finish,
            new_scan: self.new_scan,
            ..StreamOptions::default()
        }
    }

    /// The export options: short waits and small batches under faults.
    pub fn export_options(&self) -> ExportOptions {
        if self.retries() == 0 {
            return ExportOptions::default();
        }
        ExportOptions {
            batch: 8,
            retries: self.retries().max(5),
            reply_timeout: self.resend_after,
        }
    }
}

/// One depth frame held in memory, as a camera driver delivers it.
#[derive(Debug, Clone, Copy)]
pub struct DepthFrame<'a> {
    /// Seconds (any epoch; exported as given).
    pub timestamp: f64,
    /// Camera-to-world pose of the depth camera's optical frame.
    pub pose: Pose,
    /// The camera; must be the configured one (a scan has one camera).
    pub intrinsics: Intrinsics,
    /// `width * height` depth values, row after row, in the configured
    /// depth scale's units (0 = no measurement).
    pub depth: &'a [u16],
}

/// What a scan has sent and been told: messages in flight, decisions, the
/// last status, counters. Works on a client it is handed, so that a
/// [`Session`](crate::board::session::Session) (owning its client) and
/// [`stream`] (borrowing one) run the very same code.
pub(crate) struct ScanState {
    opts: StreamOptions,
    outstanding: VecDeque<(u32, String)>,
    /// The configuration sent in the Hello.
    cfg: Option<Config>,
    /// Strided rows per DepthRows message.
    rows_per_msg: u16,
    next_frame: u32,
    /// The device's index of this scan's first frame (see
    /// [`StreamReport::first_index`]).
    first_index: u32,
    decisions: Vec<Option<DecisionKind>>,
    new_decisions: Vec<(u32, DecisionKind)>,
    status: Option<Status>,
    bytes: u64,
    messages: u64,
    retransmissions: u64,
    /// When the Hello was sent.
    started: Option<Instant>,
}

impl ScanState {
    /// The newest status the device sent, if any.
    pub(crate) fn last_status(&self) -> Option<&Status> {
        self.status.as_ref()
    }

    /// Final decisions received since the last call, as `(frame, decision)`.
    pub(crate) fn take_new_decisions(&mut self) -> Vec<(u32, DecisionKind)> {
        std::mem::take(&mut self.new_decisions)
    }

    /// Final decision of every frame pushed so far, by index.
    pub(crate) fn decisions(&self) -> &[Option<DecisionKind>] {
        &self.decisions
    }

    /// Index the next pushed frame gets.
    pub(crate) fn next_frame(&self) -> u32 {
        self.next_frame
    }

    /// Bytes of the scan's messages, as first sent.
    pub(crate) fn bytes_sent(&self) -> u64 {
        self.bytes
    }

    /// [`ScanState::push`] with no bound on the messages in flight for this
    /// one frame (a live caller has checked the device is not busy).
    pub(crate) fn push_unbounded<L: Link>(
        &mut self,
        client: &mut Client<L>,
        frame: &DepthFrame<'_>,
    ) -> Result<u32, DeviceError> {
        let in_flight = self.opts.in_flight;
        self.opts.in_flight = usize::MAX;
        let pushed = self.push(client, frame);
        self.opts.in_flight = in_flight;
        pushed
    }

    pub(crate) fn new(opts: StreamOptions) -> Self {
        ScanState {
            opts,
            outstanding: VecDeque::new(),
            cfg: None,
            rows_per_msg: 1,
            next_frame: 0,
            first_index: 0,
            decisions: Vec::new(),
            new_decisions: Vec::new(),
            status: None,
            bytes: 0,
            messages: 0,
            retransmissions: 0,
            started: None,
        }
    }

    /// Status check, (Reset,) Hello: see [`Session::start`]. `frames`: the
    /// timestamps of the frames the host has (a resumed scan must not be
    /// past them, and the frames the device decided must be theirs).
    pub(crate) fn begin<L: Link>(
        &mut self,
        client: &mut Client<L>,
        cfg: &Config,
        profile: Option<&str>,
        frames: Option<&[f64]>,
    ) -> Result<Status, DeviceError> {
        let opts = self.opts.clone();
        client.resync()?;
        let st = self.call_status(client)?;
        if let Some(profile) = profile {
            check_profile(&st, profile)?;
        }
        self.next_frame = 0;
        self.first_index = 0;
        if opts.extend {
            self.started = Some(Instant::now());
            let st = self.extend(client, cfg, frames.map(<[f64]>::len))?;
            self.set_config(cfg);
            return Ok(st);
        }
        let mut st = st;
        if opts.resume {
            if st.phase == Phase::InFrame {
                // A host stopped mid-frame (killed, or its link lost) left
                // it open: its rows are gone with it, so it is dropped and
                // sent again.
                self.abandon_open_frame(client)?;
                st = self.call_status(client)?;
            }
            if st.frames_seen == 0 && st.phase != Phase::Finished && st.stored_records == 0 {
                return Err(DeviceError::Input(
                    "--resume: the board holds no scan to resume (it is empty, or it was \
                     reset): stream without --resume to scan from the first frame"
                        .into(),
                ));
            }
            // In a later session (`--extend`), the sequence is that session.
            self.first_index = st.session_first;
            let seen = st.frames_seen.saturating_sub(st.session_first) as usize;
            if let Some(n) = frames.map(<[f64]>::len).filter(|&n| seen > n) {
                return Err(DeviceError::Input(format!(
                    "--resume: the board has seen {seen} frames, the sequence has {n}: not this \
                     sequence?"
                )));
            }
            if let Some(timestamps) = frames {
                if let Some((frame, ours, theirs)) =
                    self.first_other_frame(client, &st, timestamps)?
                {
                    return Err(DeviceError::Input(format!(
                        "--resume: frame {} of the sequence has timestamp {ours}, the board's \
                         scan has {theirs}: not the sequence it scanned (give that one, or start \
                         a new scan with --new-scan)",
                        frame - st.session_first
                    )));
                }
            }
            self.next_frame = st.frames_seen;
        } else if opts.reset {
            if !opts.new_scan {
                if let Some(held) = held_scan(&st) {
                    return Err(DeviceError::Input(format!(
                        "the board holds {held}: export it first (placedb export --port PORT -o \
                         DIR), go on with it (--resume; --extend for a new session of a finished \
                         scan), or replace it with --new-scan"
                    )));
                }
            }
            self.call(client, HostMessage::Reset, "Reset")?;
        }
        self.started = Some(Instant::now());
        match self.call(client, HostMessage::Hello(*cfg), "Hello") {
            Err(DeviceError::Refused {
                kind: ErrorKind::NeedsReset,
                ..
            }) if opts.resume => return Err(self.other_config(client, cfg, "--resume")),
            other => other?,
        };
        self.set_config(cfg);
        Ok(st)
    }

    /// The first frame of the sequence `timestamps` (the host's, of the
    /// frames from the session's first on) whose timestamp is not the one
    /// the device decided it with, among the frames the device holds
    /// decisions of; `None` when they agree. A few label records are read
    /// however long the scan: the first and last decided frames, and when
    /// the last differs, a bisection for the first that does (exact when the
    /// sequences differ from some frame on, as another recording or a
    /// retimed tail does; a frame changed only in the middle is not looked
    /// for).
    pub(crate) fn first_other_frame<L: Link>(
        &mut self,
        client: &mut Client<L>,
        st: &Status,
        timestamps: &[f64],
    ) -> Result<Option<(u32, f64, f64)>, DeviceError> {
        let first = st.session_first;
        // The labels the device can export: its decisions in the log.
        let labels = st.capacity(CapacitySlot::Labels).used;
        let decided = st
            .frames_decided
            .min(labels)
            .min(first.saturating_add(timestamps.len() as u32));
        let mut theirs = |frame: u32| -> Result<f64, DeviceError> {
            let record = st.database_size.saturating_add(frame);
            let got = export::records(client, record, 1, st.database_size)?;
            match got.first() {
                Some(r) if r.frame == frame => Ok(r.timestamp),
                _ => Err(DeviceError::Protocol(format!(
                    "the device gave no label of frame {frame}"
                ))),
            }
        };
        let ours = |frame: u32| timestamps[(frame - first) as usize];
        let differs = |t: f64, frame: u32| t.to_bits() != ours(frame).to_bits();
        if decided <= first {
            return Ok(None);
        }
        // The last decided frame agrees: only the first is checked besides.
        let (mut lo, mut hi) = (first, decided - 1);
        let t = theirs(hi)?;
        if !differs(t, hi) {
            let t0 = theirs(first)?;
            return Ok(differs(t0, first).then(|| (first, ours(first), t0)));
        }
        let mut found = (hi, t);
        while lo < hi {
            let mid = lo + (hi - lo) / 2;
            let t = theirs(mid)?;
            if differs(t, mid) {
                found = (mid, t);
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        Ok(Some((found.0, ours(found.0), found.1)))
    }

    /// The configuration in force, and the rows per message it allows.
    fn set_config(&mut self, cfg: &Config) {
        let fit = depth_rows_per_message(cfg.width_sent());
        self.rows_per_msg = match self.opts.rows_per_message {
            0 => fit,
            r => r.min(fit),
        }
        .max(1);
        self.cfg = Some(*cfg);
    }

    /// Extend instead of the Hello: the device goes on with a new session
    /// of its finished scan (or the one begun so and cut short); the next
    /// frame is the device's `frames_seen`, the session's first its
    /// `session_first`. `frames`: how many frames the host has. Returns the
    /// status after it.
    fn extend<L: Link>(
        &mut self,
        client: &mut Client<L>,
        cfg: &Config,
        frames: Option<usize>,
    ) -> Result<Status, DeviceError> {
        match self.call(client, HostMessage::Extend(*cfg), "Extend") {
            Err(DeviceError::Refused {
                kind: ErrorKind::NothingToExtend,
                ..
            }) => {
                return Err(DeviceError::Input(
                    "--extend: the device holds no finished scan in its flash log to extend \
                     (stream a first session to it and let it finish, then extend it; a scan \
                     cut short is resumed with --resume)"
                        .into(),
                ))
            }
            Err(DeviceError::Refused {
                kind: ErrorKind::ExtendOtherConfig,
                ..
            }) => return Err(self.other_config(client, cfg, "--extend")),
            other => other?,
        };
        let st = self.call_status(client)?;
        let (first, seen) = (st.session_first, st.frames_seen);
        let done = seen.saturating_sub(first) as usize;
        if seen < first || frames.is_some_and(|n| done > n) {
            return Err(DeviceError::Input(format!(
                "--extend: the device has seen {done} frames of this session, the sequence has {}: not this sequence?",
                frames.unwrap_or(0)
            )));
        }
        self.first_index = first;
        self.next_frame = seen;
        Ok(st)
    }

    /// The refusal of a command (`--extend`, `--resume`) whose
    /// configuration `cfg` is not the device's scan's: names the first
    /// setting that differs and both values, read from the device's log
    /// (a device without one is told in general words). The device
    /// changed nothing, so the same command with its settings is taken.
    fn other_config<L: Link>(
        &mut self,
        client: &mut Client<L>,
        cfg: &Config,
        option: &str,
    ) -> DeviceError {
        // A later session may have brought another camera: then only the
        // whole log gives the configuration in force.
        let records = match self.call_status(client) {
            Ok(st) if st.sessions > 1 => st.stored_records,
            _ => 1,
        };
        let named = log_records::scan_config(client, self.opts.wait(), records)
            .ok()
            .flatten()
            .and_then(|device| config_words::difference(cfg, &device));
        DeviceError::Input(match named {
            Some(words) => format!(
                "{option}: {words}: every session of a scan has the first one's settings, \
                 and a session cut short is resumed with its own camera: give the scan's \
                 setting, or replace the board's scan with a new one (placedb stream SEQ \
                 --port PORT --new-scan)"
            ),
            None => format!(
                "{option}: the device's scan was configured otherwise: every session of a scan \
                 needs the first one's depth range, stride, voxel size, grid, --mu and \
                 --window, and a session cut short its own camera and depth scale; or replace \
                 the board's scan with a new one (placedb stream SEQ --port PORT --new-scan)"
            ),
        })
    }

    /// Sends frame `i` of `seq` (its depth decoded, its pose), the one way a
    /// recorded sequence's frames reach [`Self::push`].
    pub(crate) fn push_sequence_frame<L: Link>(
        &mut self,
        client: &mut Client<L>,
        seq: &Sequence,
        i: usize,
        intrinsics: placedb::Intrinsics,
    ) -> Result<u32, DeviceError> {
        let img = seq
            .depth(i)
            .map_err(|e| DeviceError::Input(format!("frame {i}: {e}")))?;
        let pose = seq.frames[i]
            .pose()
            .map_err(|e| DeviceError::Input(format!("frame {i}: pose: {e}")))?;
        self.push(
            client,
            &DepthFrame {
                timestamp: seq.frames[i].timestamp,
                pose,
                intrinsics,
                depth: &img.data,
            },
        )
    }

    /// Sends one frame: see [`Session::push_frame`].
    pub(crate) fn push<L: Link>(
        &mut self,
        client: &mut Client<L>,
        f: &DepthFrame<'_>,
    ) -> Result<u32, DeviceError> {
        let cfg = self
            .cfg
            .ok_or_else(|| DeviceError::Input("push_frame before configure".into()))?;
        let frame = self.next_frame;
        if f.intrinsics != cfg.intrinsics {
            let words = |k: &placedb::Intrinsics| {
                format!(
                    "{}x{} fx {} fy {} cx {} cy {}",
                    k.width, k.height, k.fx, k.fy, k.cx, k.cy
                )
            };
            return Err(DeviceError::Input(format!(
                "frame {frame}: intrinsics {} differ from the scan's {} (one camera per scan)",
                words(&f.intrinsics),
                words(&cfg.intrinsics)
            )));
        }
        let (w, h) = (f.intrinsics.width, f.intrinsics.height);
        if f.depth.len() != usize::from(w) * usize::from(h) {
            return Err(DeviceError::Input(format!(
                "frame {frame}: {} depth values for a {w}x{h} image",
                f.depth.len()
            )));
        }
        let (sampled, rows) = sampled_rows_of(f.depth, w, cfg.stride);
        let width = usize::from(cfg.width_sent());
        if sampled != width {
            return Err(DeviceError::Input(format!(
                "frame {frame}: {sampled} sampled columns, the configuration says {width}"
            )));
        }
        self.send(
            client,
            HostMessage::FrameBegin {
                frame,
                timestamp: f.timestamp,
                pose: f.pose,
            },
            || format!("FrameBegin {frame}"),
        )?;
        for chunk in row_chunks(width, &rows, usize::from(self.rows_per_msg)) {
            let first_row = chunk.first_row;
            self.send(client, chunk.message(frame), || {
                format!("DepthRows {frame}:{first_row}")
            })?;
        }
        self.send(client, HostMessage::FrameEnd { frame }, || {
            format!("FrameEnd {frame}")
        })?;
        self.next_frame = frame + 1;
        Ok(frame)
    }

    /// See [`Session::abandon_open_frame`].
    pub(crate) fn abandon_open_frame<L: Link>(
        &mut self,
        client: &mut Client<L>,
    ) -> Result<u32, DeviceError> {
        // What was in flight was refused or answered: the device said why.
        self.outstanding.clear();
        let st = self.call_status(client)?;
        let frame = st.frames_seen;
        if st.phase == Phase::InFrame {
            self.call(client, HostMessage::FrameAbort { frame }, "FrameAbort")?;
        }
        self.next_frame = frame;
        Ok(frame)
    }

    /// Sends `msg`: pipelined (at most `in_flight` unanswered), or
    /// stop-and-wait with retransmission when `retries > 0`.
    pub(crate) fn send<L: Link>(
        &mut self,
        client: &mut Client<L>,
        msg: HostMessage<'_>,
        what: impl FnOnce() -> String,
    ) -> Result<(), DeviceError> {
        while self.outstanding.len() >= self.opts.in_flight.max(1) {
            self.pump(client)?;
        }
        // The bytes are counted as the client encodes the message: once.
        let before = client.first_sent_bytes();
        self.messages += 1;
        if self.opts.retries > 0 {
            let what = what();
            let sent = send_and_wait(client, msg, &what, self.opts.wait());
            self.bytes += client.first_sent_bytes() - before;
            let (replies, resent) = sent?;
            self.retransmissions += resent;
            for item in &replies {
                self.note(item);
            }
            return Ok(());
        }
        let seq = client.send(msg);
        self.bytes += client.first_sent_bytes() - before;
        self.outstanding.push_back((seq?, what()));
        Ok(())
    }

    /// One message of the scan's set-up, waited for as the options say
    /// ([`StreamOptions::wait`]).
    pub(crate) fn call<L: Link>(
        &mut self,
        client: &mut Client<L>,
        msg: HostMessage<'_>,
        what: &str,
    ) -> Result<Vec<Received>, DeviceError> {
        let (replies, resent) = send_and_wait(client, msg, what, self.opts.wait())?;
        self.retransmissions += resent;
        Ok(replies)
    }

    /// The device's status through [`ScanState::call`].
    pub(crate) fn call_status<L: Link>(
        &mut self,
        client: &mut Client<L>,
    ) -> Result<Status, DeviceError> {
        let (status, resent) = ask_status(client, self.opts.wait())?;
        self.retransmissions += resent;
        Ok(status)
    }

    /// Keeps the final decisions and the last status.
    fn note(&mut self, item: &Received) {
        match item {
            Received::Message(DeviceMessage::Decision { frame, kind })
                if *kind != DecisionKind::Pending =>
            {
                // Only frames this scan sent: a frame index is never
                // trusted to size a buffer.
                let i = *frame as usize;
                if *frame < self.next_frame || i < self.decisions.len() {
                    if self.decisions.len() <= i {
                        self.decisions.resize(i + 1, None);
                    }
                    self.decisions[i] = Some(*kind);
                    self.new_decisions.push((*frame, *kind));
                }
            }
            Received::Message(DeviceMessage::Status(s)) => self.status = Some(*s),
            _ => {}
        }
    }

    /// Handles replies until the oldest outstanding message is answered.
    fn pump<L: Link>(&mut self, client: &mut Client<L>) -> Result<(), DeviceError> {
        while !self.answered(client, self.opts.reply_timeout)? {}
        Ok(())
    }

    /// Messages sent and not answered yet.
    pub(crate) fn unanswered(&self) -> usize {
        self.outstanding.len()
    }

    /// Handles what the device sent, waiting at most `wait` for each
    /// reply, until the oldest outstanding message is answered (true), or
    /// nothing more came within `wait` (false: only when `wait` is shorter
    /// than the reply timeout; at the reply timeout that is an error).
    pub(crate) fn answered<L: Link>(
        &mut self,
        client: &mut Client<L>,
        wait: Duration,
    ) -> Result<bool, DeviceError> {
        let Some((want, what)) = self.outstanding.front().cloned() else {
            return Ok(true);
        };
        loop {
            let item = match client.recv(wait) {
                Ok(item) => item,
                Err(e) if e.kind() == io::ErrorKind::TimedOut && wait < self.opts.reply_timeout => {
                    return Ok(false)
                }
                Err(e) => {
                    return Err(DeviceError::Io(io::Error::new(
                        e.kind(),
                        format!(
                            "waiting for the reply to {what}: {}",
                            crate::error::io_words(&e)
                        ),
                    )))
                }
            };
            self.note(&item);
            match &item {
                Received::Message(DeviceMessage::Error { seq, kind }) => {
                    return Err(DeviceError::Refused {
                        what,
                        seq: seq.unwrap_or(want),
                        kind: *kind,
                    })
                }
                Received::Damaged(e) => {
                    return Err(DeviceError::Protocol(format!(
                        "damaged reply while waiting for {what}: {e}"
                    )))
                }
                _ => {}
            }
            match item.terminal_seq() {
                Some(s) if s == want => {
                    self.outstanding.pop_front();
                    return Ok(true);
                }
                Some(s) => {
                    return Err(DeviceError::Protocol(format!(
                        "reply to seq {s} while waiting for seq {want} ({what})"
                    )))
                }
                None => {}
            }
        }
    }

    /// Waits for every outstanding reply.
    pub(crate) fn drain<L: Link>(&mut self, client: &mut Client<L>) -> Result<(), DeviceError> {
        while !self.outstanding.is_empty() {
            self.pump(client)?;
        }
        Ok(())
    }

    /// Whether a push failed because the device's flash log is full.
    pub(crate) fn is_log_full(e: &DeviceError) -> bool {
        matches!(
            e,
            DeviceError::Refused {
                kind: ErrorKind::StorageFull,
                ..
            }
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::client::status;
    use crate::board::export::{append_frames, export_to, read_partial, resume_file};
    use crate::board::link::LocalLink;
    use crate::output;
    use crate::testing::{demo, selector, voxel_config};
    use placedb::protocol::{DeviceMessage, ErrorKind};

    fn setup(seq: &Sequence, window: u16) -> (ScanConfig, SelectorConfig, Config) {
        let scan = scan_config(seq, &voxel_config(8)).unwrap();
        let sel = selector(window);
        let cfg = device_config(&scan, &sel).unwrap();
        (scan, sel, cfg)
    }

    #[test]
    fn the_local_device_matches_the_replay_and_exports_resumably() {
        let seq = demo(40);
        let (scan, sel, cfg) = setup(&seq, 6);
        let mut client = Client::new(LocalLink::start("ram256k").unwrap());
        let opts = StreamOptions {
            rows_per_message: 5,
            ..StreamOptions::default()
        };
        let report = stream(&mut client, &seq, &cfg, "ram256k", &opts, None).unwrap();
        let run = crate::replay::replay(&seq, "ram256k", scan, sel, 8, None).unwrap();
        let finals: Vec<_> = report
            .decisions
            .iter()
            .map(|d| placedb::Decision::from(d.unwrap()))
            .collect();
        assert_eq!(finals, run.decisions);
        assert_eq!(report.status.database_size as usize, run.database.len());
        // Export into a directory, interrupted after the first batch, resumed.
        let dir = std::env::temp_dir().join(format!("placedb-export-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let full = export_to(&mut client, &dir, None, true).unwrap();
        let timestamps: Vec<f64> = seq.frames.iter().map(|f| f.timestamp).collect();
        let want = output::run_csv(&run.database, &timestamps, &run.labels);
        assert_eq!(full.csv(), want);
        assert_eq!(
            std::fs::read_to_string(dir.join("database.csv")).unwrap(),
            want.0
        );
        assert!(!resume_file(&dir).exists());
        // An interrupted export leaves its checked records; --from resumes.
        let partial = resume_file(&dir);
        let mut head = vec![DeviceMessage::Status(full.status)];
        head.extend(
            full.records[..20]
                .iter()
                .map(|r| DeviceMessage::ExportRecord(*r)),
        );
        append_frames(&partial, &head).unwrap();
        let (_, saved) = read_partial(&dir).unwrap();
        assert_eq!(saved, full.records[..20]);
        let resumed = export_to(&mut client, &dir, Some(12), true).unwrap();
        assert_eq!(resumed.records, full.records);
        assert!(export_to(&mut client, &dir, Some(12), true).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_profile_mismatch_is_refused_before_anything_is_sent() {
        let seq = demo(2);
        let (_, _, cfg) = setup(&seq, 4);
        let mut client = Client::new(LocalLink::start("ram256k").unwrap());
        let err = stream(
            &mut client,
            &seq,
            &cfg,
            "ram512k",
            &StreamOptions::default(),
            None,
        )
        .unwrap_err();
        assert!(matches!(err, DeviceError::Profile(_)), "{err}");
        assert_eq!(
            status(&mut client, Duration::from_secs(5))
                .unwrap()
                .frames_seen,
            0
        );
    }

    #[test]
    fn the_device_rejects_what_the_host_should_not_send() {
        let seq = demo(3);
        let (_, _, mut cfg) = setup(&seq, 4);
        let mut client = Client::new(LocalLink::start("ram256k").unwrap());
        stream(
            &mut client,
            &seq,
            &cfg,
            "ram256k",
            &StreamOptions::default(),
            None,
        )
        .unwrap();
        // Streaming again without a reset would mix scans: refused, nothing changes.
        cfg.mu = 0.5;
        let opts = StreamOptions {
            reset: false,
            ..StreamOptions::default()
        };
        let err = stream(&mut client, &seq, &cfg, "ram256k", &opts, None).unwrap_err();
        assert!(
            matches!(
                err,
                DeviceError::Refused {
                    kind: ErrorKind::NeedsReset,
                    ..
                }
            ),
            "{err}"
        );
        assert_eq!(
            status(&mut client, Duration::from_secs(5))
                .unwrap()
                .frames_seen,
            3
        );
    }
}
