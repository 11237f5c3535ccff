//! The device client API: one scan on a placedb device, fed frame by frame
//! from memory. This is what a robot program (or a ROS node wrapping it)
//! calls, and what `placedb stream` calls for a recorded sequence.
//!
//! ```no_run
//! use placedb_host::session::{DepthFrame, Session};
//! use placedb_host::device_cli::StreamOptions;
//! # fn frames() -> Vec<(f64, placedb::Pose, Vec<u16>)> { Vec::new() }
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let intrinsics = placedb::Intrinsics {
//!     width: 640, height: 480, fx: 585.0, fy: 585.0, cx: 320.0, cy: 240.0,
//! };
//! let scan = placedb::ScanConfig {
//!     intrinsics,
//!     depth_scale: 1000.0, // millimetres
//!     range: placedb::DepthRange { min: 0.1, max: 10.0 },
//!     stride: 8,
//!     grid: placedb::VoxelGrid::new(0.3, [0.0; 3]).map_err(|e| format!("{e:?}"))?,
//! };
//! let sel = placedb::SelectorConfig { mu: 0.3, window: 32, sketch_margin: 0.05 };
//! // "/dev/ttyACM0", "tcp:127.0.0.1:4321" (the emulator) or "local:ram512k".
//! let mut session = Session::open("local:ram512k", StreamOptions::default())?;
//! session.configure(&scan, &sel)?;
//! for (timestamp, pose, depth) in frames() {
//!     session.push_frame(&DepthFrame { timestamp, pose, intrinsics, depth: &depth })?;
//!     for (frame, decision) in session.take_decisions() {
//!         println!("frame {frame}: {decision:?}");
//!     }
//! }
//! session.finish()?;
//! let export = session.export()?; // database records and every label
//! # Ok(()) }
//! ```
//!
//! Messages are pipelined ([`StreamOptions::in_flight`]) unless
//! [`StreamOptions::retries`] > 0, which goes stop-and-wait and retransmits
//! a message whose reply is late or damaged (see [`crate::device_cli`]):
//! the same protocol behaviour whoever drives it. Decisions arrive as the
//! device makes them; [`Session::take_decisions`] hands over the new ones.

use crate::device_cli::{
    self, call, call_status, check_profile, exchange, DeviceError, Export, ExportOptions,
    StreamOptions,
};
use crate::link::{self, Client, Link, Received};
use crate::online::sampled_rows_of;
use crate::row_chunks::row_chunks;
use placedb::protocol::{
    depth_rows_per_message, encode, Config, DecisionKind, DeviceMessage, ErrorKind, HostFrame,
    HostMessage, Phase, Status, MAX_FRAME_LEN,
};
use placedb::{Intrinsics, Pose, ScanConfig, SelectorConfig};
use std::collections::VecDeque;
use std::io;
use std::time::{Duration, Instant};

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

/// One scan on a device: configure, push frames, read decisions and status,
/// finish, export. Owns the protocol client ([`Client`]) of its link.
pub struct Session<L: Link> {
    pub(crate) client: Client<L>,
    pub(crate) state: ScanState,
}

impl Session<Box<dyn Link>> {
    /// Opens the device on `port`: a serial device (`/dev/ttyACM0`,
    /// `serial:PATH`), `tcp:HOST:PORT` (the emulator) or `local:PROFILE` (the
    /// core's device in-process, no hardware).
    pub fn open(port: &str, opts: StreamOptions) -> Result<Self, DeviceError> {
        let link = link::open(port, Duration::from_secs(10))?;
        Ok(Session::new(Client::new(link), opts))
    }
}

impl<L: Link> Session<L> {
    /// A session over an open client.
    pub fn new(client: Client<L>, opts: StreamOptions) -> Self {
        Session {
            client,
            state: ScanState::new(opts),
        }
    }

    /// Starts a scan configured by `scan` and `sel` (checked as the device
    /// checks them): (Reset,) Hello. Returns the device's status before it.
    pub fn configure(
        &mut self,
        scan: &ScanConfig,
        sel: &SelectorConfig,
    ) -> Result<Status, DeviceError> {
        let cfg = device_cli::device_config(scan, sel)?;
        self.state.begin(&mut self.client, &cfg, None, None)
    }

    /// [`Session::configure`] with a ready Hello; with `profile`, the device
    /// must run that capacity profile (so its results match `placedb select
    /// --profile`). With [`StreamOptions::resume`] the scan the device holds
    /// goes on: the next pushed frame is its `frames_seen`.
    pub fn start(&mut self, cfg: &Config, profile: Option<&str>) -> Result<Status, DeviceError> {
        self.state.begin(&mut self.client, cfg, profile, None)
    }

    /// Sends one frame: FrameBegin, its strided rows, FrameEnd. Returns its
    /// index. Its decision (and those of earlier frames) arrive later:
    /// [`Session::take_decisions`].
    pub fn push_frame(&mut self, frame: &DepthFrame<'_>) -> Result<u32, DeviceError> {
        self.state.push(&mut self.client, frame)
    }

    /// Asks for the device's status without waiting for it (pipelined); the
    /// reply lands in [`Session::last_status`].
    pub fn request_status(&mut self) -> Result<(), DeviceError> {
        self.state
            .send(&mut self.client, HostMessage::StatusRequest, || {
                "StatusRequest".into()
            })
    }

    /// The newest status the device sent, if any.
    pub fn last_status(&self) -> Option<&Status> {
        self.state.status.as_ref()
    }

    /// Waits for every outstanding reply, then asks for the status.
    pub fn status(&mut self) -> Result<Status, DeviceError> {
        self.state.drain(&mut self.client)?;
        let opts = self.state.opts.clone();
        call_status(&mut self.client, &opts, &mut self.state.retransmissions)
    }

    /// Final decisions received since the last call, as `(frame, decision)`.
    pub fn take_decisions(&mut self) -> Vec<(u32, DecisionKind)> {
        std::mem::take(&mut self.state.new_decisions)
    }

    /// Final decision of every frame pushed so far, by index (`None`: not
    /// decided yet, or its reply was lost: the export has it).
    pub fn decisions(&self) -> &[Option<DecisionKind>] {
        &self.state.decisions
    }

    /// Index the next pushed frame gets.
    pub fn next_frame(&self) -> u32 {
        self.state.next_frame
    }

    /// Ends the scan: Finish (decides every pending frame), then waits for
    /// every reply. Returns the final status.
    pub fn finish(&mut self) -> Result<Status, DeviceError> {
        self.state
            .send(&mut self.client, HostMessage::Finish, || "Finish".into())?;
        self.status()
    }

    /// Pulls the database and every label, checked by count and CRC
    /// ([`device_cli::export`]); [`Export::csv`] gives `database.csv` and
    /// `labels.csv`.
    pub fn export(&mut self) -> Result<Export, DeviceError> {
        self.state.drain(&mut self.client)?;
        device_cli::export(
            &mut self.client,
            Vec::new(),
            &ExportOptions::default(),
            None,
            &mut |_| Ok(()),
        )
    }

    /// [`Session::export`] into directory `dir`: `database.csv`,
    /// `labels.csv`, `metrics.json`, as `placedb export -o DIR` writes them.
    pub fn export_to(&mut self, dir: &std::path::Path) -> Result<Export, DeviceError> {
        self.state.drain(&mut self.client)?;
        device_cli::export_to(&mut self.client, dir, None, true)
    }

    /// After a push refused with `StorageFull` (the device's flash log is
    /// full; it kept room to end the scan): drops the open frame so that
    /// [`Session::finish`] ends the scan with every frame before it. Returns
    /// the first frame that was not scanned.
    pub fn abandon_open_frame(&mut self) -> Result<u32, DeviceError> {
        self.state.abandon_open_frame(&mut self.client)
    }

    /// The protocol client (e.g. for [`device_cli::export_to`]).
    pub fn client(&mut self) -> &mut Client<L> {
        &mut self.client
    }

    /// Ends the session, giving the client back.
    pub fn into_client(self) -> Client<L> {
        self.client
    }
}

/// What a scan has sent and been told: messages in flight, decisions, the
/// last status, counters. Works on a client it is handed, so that a
/// [`Session`] (owning its client) and [`device_cli::stream`] (borrowing
/// one) run the very same code.
pub(crate) struct ScanState {
    pub(crate) opts: StreamOptions,
    outstanding: VecDeque<(u32, String)>,
    /// The configuration sent in the Hello.
    cfg: Option<Config>,
    /// Strided rows per DepthRows message.
    rows_per_msg: u16,
    pub(crate) next_frame: u32,
    pub(crate) decisions: Vec<Option<DecisionKind>>,
    new_decisions: Vec<(u32, DecisionKind)>,
    pub(crate) status: Option<Status>,
    pub(crate) bytes: u64,
    pub(crate) messages: u64,
    pub(crate) retransmissions: u64,
    /// When the Hello was sent.
    pub(crate) started: Option<Instant>,
    tx: Vec<u8>,
}

impl ScanState {
    pub(crate) fn new(opts: StreamOptions) -> Self {
        ScanState {
            opts,
            outstanding: VecDeque::new(),
            cfg: None,
            rows_per_msg: 1,
            next_frame: 0,
            decisions: Vec::new(),
            new_decisions: Vec::new(),
            status: None,
            bytes: 0,
            messages: 0,
            retransmissions: 0,
            started: None,
            tx: vec![0u8; MAX_FRAME_LEN],
        }
    }

    /// Status check, (Reset,) Hello: see [`Session::start`]. `frames`: how
    /// many frames the host has (a resumed scan must not be past them).
    pub(crate) fn begin<L: Link>(
        &mut self,
        client: &mut Client<L>,
        cfg: &Config,
        profile: Option<&str>,
        frames: Option<usize>,
    ) -> Result<Status, DeviceError> {
        let opts = self.opts.clone();
        client.resync()?;
        let st = call_status(client, &opts, &mut self.retransmissions)?;
        if let Some(profile) = profile {
            check_profile(&st, profile)?;
        }
        self.next_frame = 0;
        if opts.resume {
            if st.phase == Phase::InFrame {
                return Err(DeviceError::Input(
                    "the device has a frame open: restart it (it resumes from flash) or stream without --resume"
                        .into(),
                ));
            }
            let seen = st.frames_seen as usize;
            if let Some(n) = frames.filter(|&n| seen > n) {
                return Err(DeviceError::Input(format!(
                    "the device has seen {seen} frames, the sequence has {n}: not this sequence?"
                )));
            }
            self.next_frame = st.frames_seen;
        } else if opts.reset {
            call(
                client,
                HostMessage::Reset,
                "Reset",
                &opts,
                &mut self.retransmissions,
            )?;
        }
        self.started = Some(Instant::now());
        call(
            client,
            HostMessage::Hello(*cfg),
            "Hello",
            &opts,
            &mut self.retransmissions,
        )?;
        let fit = depth_rows_per_message(cfg.width_sent());
        self.rows_per_msg = match opts.rows_per_message {
            0 => fit,
            r => r.min(fit),
        }
        .max(1);
        self.cfg = Some(*cfg);
        Ok(st)
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
            return Err(DeviceError::Input(format!(
                "frame {frame}: intrinsics {:?} differ from the scan's {:?} (one camera per scan)",
                f.intrinsics, cfg.intrinsics
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
        let opts = self.opts.clone();
        let st = call_status(client, &opts, &mut self.retransmissions)?;
        let frame = st.frames_seen;
        if st.phase == Phase::InFrame {
            call(
                client,
                HostMessage::FrameAbort { frame },
                "FrameAbort",
                &opts,
                &mut self.retransmissions,
            )?;
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
        self.bytes += encode(&HostFrame { seq: 0, msg }, &mut self.tx)
            .map(|f| f.len() as u64)
            .unwrap_or(0);
        self.messages += 1;
        if self.opts.retries > 0 {
            let what = what();
            let (replies, resent) = exchange(
                client,
                msg,
                &what,
                self.opts.resend_after,
                self.opts.retries,
            )?;
            self.retransmissions += resent;
            for item in &replies {
                self.note(item);
            }
            return Ok(());
        }
        let seq = client.send(msg)?;
        self.outstanding.push_back((seq, what()));
        Ok(())
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
                        format!("waiting for the reply to {what}: {e}"),
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
