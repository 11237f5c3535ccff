//! The device client API: one scan on a placedb device, fed frame by frame
//! from memory. This is what a robot program (or a ROS node wrapping it)
//! calls, and what `placedb stream` calls for a recorded sequence.
//!
//! ```no_run
//! use placedb_host::board::session::{DepthFrame, Session};
//! use placedb_host::board::scan::StreamOptions;
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
//! a message whose reply is late or damaged (see [`crate::board::scan`]):
//! the same protocol behaviour whoever drives it. Decisions arrive as the
//! device makes them; [`Session::take_decisions`] hands over the new ones.

use crate::board::client::Client;
use crate::board::error::DeviceError;
use crate::board::export::{self, Export, ExportOptions};
use crate::board::link::{self, Link};
use crate::board::scan::{ScanState, StreamOptions};
use placedb::protocol::{Config, DecisionKind, HostMessage, Status};
use placedb::{ScanConfig, SelectorConfig};
use std::time::Duration;

pub use crate::board::scan::DepthFrame;

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
        let cfg = crate::board::scan::device_config(scan, sel)?;
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
        self.state.last_status()
    }

    /// Waits for every outstanding reply, then asks for the status.
    pub fn status(&mut self) -> Result<Status, DeviceError> {
        self.state.drain(&mut self.client)?;
        self.state.call_status(&mut self.client)
    }

    /// Final decisions received since the last call, as `(frame, decision)`.
    pub fn take_decisions(&mut self) -> Vec<(u32, DecisionKind)> {
        self.state.take_new_decisions()
    }

    /// Final decision of every frame pushed so far, by index (`None`: not
    /// decided yet, or its reply was lost: the export has it).
    pub fn decisions(&self) -> &[Option<DecisionKind>] {
        self.state.decisions()
    }

    /// Index the next pushed frame gets.
    pub fn next_frame(&self) -> u32 {
        self.state.next_frame()
    }

    /// Ends the scan: Finish (decides every pending frame), then waits for
    /// every reply. Returns the final status.
    pub fn finish(&mut self) -> Result<Status, DeviceError> {
        self.state
            .send(&mut self.client, HostMessage::Finish, || "Finish".into())?;
        self.status()
    }

    /// Pulls the database and every label, checked by count and CRC
    /// ([`export::export`]); [`Export::csv`] gives `database.csv` and
    /// `labels.csv`.
    pub fn export(&mut self) -> Result<Export, DeviceError> {
        self.state.drain(&mut self.client)?;
        export::export(
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
        self.export_to_with(dir, &[], None)
    }

    /// [`Session::export_to`] with `extra` files (name, text) written into
    /// `dir` with the export's, all or nothing, and `database.csv` and
    /// `labels.csv` numbered by the camera's frames when some were not
    /// pushed: `sequence_frames[k]` is the frame the device's frame `k` was
    /// ([`Export::sequence_frames`]; the frames [`Session::try_push_frame`]
    /// sent, in order).
    pub fn export_to_with(
        &mut self,
        dir: &std::path::Path,
        extra: &[(&str, String)],
        sequence_frames: Option<&[usize]>,
    ) -> Result<Export, DeviceError> {
        self.state.drain(&mut self.client)?;
        let opts = ExportOptions::default();
        export::export_to_with(
            &mut self.client,
            dir,
            None,
            true,
            &opts,
            extra,
            sequence_frames,
        )
    }

    /// After a push refused with `StorageFull` (the device's flash log is
    /// full; it kept room to end the scan): drops the open frame so that
    /// [`Session::finish`] ends the scan with every frame before it. Returns
    /// the first frame that was not scanned.
    pub fn abandon_open_frame(&mut self) -> Result<u32, DeviceError> {
        self.state.abandon_open_frame(&mut self.client)
    }

    /// The protocol client (e.g. for [`export::export_to_with`]).
    pub fn client(&mut self) -> &mut Client<L> {
        &mut self.client
    }

    /// Ends the session, giving the client back.
    pub fn into_client(self) -> Client<L> {
        self.client
    }
}
