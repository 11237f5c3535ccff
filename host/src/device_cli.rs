//! Talking to a device: `placedb stream` (send a recorded sequence), `placedb
//! export` (pull the database and labels, resumable, checked by count and
//! CRC) and `placedb device --qemu` (start the emulated board).
//!
//! The device is the core's [`placedb::device::Device`], on a board or
//! in-process (`local:PROFILE`); what it selects is what `placedb select
//! --solver online` computes with the same profile and configuration, and the
//! exported files are written by the same writers ([`crate::output`]), so they
//! are byte-identical.
//!
//! Over a lossy link ([`StreamOptions::retries`] > 0, e.g. `placedb stream
//! --drop-chance 0.05 --corrupt-chance 0.05`, which wraps the link in a
//! [`crate::fault::FaultInjector`]) the host goes stop-and-wait and retransmits
//! a message with the same sequence number when its reply is late or says the
//! frame was damaged ([`exchange`]); the device answers a repeat without
//! applying it twice. Export batches are checked by count and CRC and asked
//! again, shorter, when they fail.

use crate::fault::{FaultConfig, FaultInjector};
use crate::link::{self, Client, Link, QemuOptions, Received};
use crate::output;
use crate::sequence::Sequence;
use crate::session::{DepthFrame, ScanState};
use crate::voxelize::{self, GridOrigin, VoxelConfig};
use indicatif::ProgressBar;
use placedb::profile::{Capacities, PROFILES};
use placedb::protocol::{
    encode, export_crc, CapacitySlot, Config, DecisionKind, DeviceMessage, ErrorKind, ExportRecord,
    Feed, FrameDecoder, HostMessage, RecordKind, Status, MAX_FRAME_LEN,
};
use placedb::{DbRecord, ScanConfig, SelectorConfig, VoxelGrid};
use std::io;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Why talking to a device failed.
#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    /// The link failed or timed out.
    #[error("link: {0}")]
    Io(#[from] io::Error),
    /// The device refused a message with a typed error.
    #[error("the device refused {what} (seq {seq}): {kind}")]
    Refused {
        /// Which message.
        what: String,
        /// Its sequence number.
        seq: u32,
        /// The device's reason.
        kind: ErrorKind,
    },
    /// The conversation went wrong (damaged or unexpected replies).
    #[error("protocol: {0}")]
    Protocol(String),
    /// The device runs another capacity profile than asked for.
    #[error("{0}")]
    Profile(String),
    /// Bad input on the host side (sequence, options, files).
    #[error("{0}")]
    Input(String),
}

/// How to stream.
#[derive(Debug, Clone)]
pub struct StreamOptions {
    /// Strided rows per DepthRows message (0: as many as fit a frame).
    pub rows_per_message: u16,
    /// Messages sent ahead of their replies (1 = stop-and-wait).
    pub in_flight: usize,
    /// Longest wait for one reply. The default outlasts the longest flash
    /// stall of a Pico reply at the datasheet's maximum timing
    /// ([`crate::flash_timing::WorstStall`]).
    pub reply_timeout: Duration,
    /// Reset the device before the Hello (a new scan).
    pub reset: bool,
    /// Go on with the scan the device holds (after a power cut it restores
    /// it from flash): no Reset, the same Hello (the device accepts an
    /// identical one), frames from the device's `frames_seen` on.
    pub resume: bool,
    /// End with Finish (decides the frames still pending).
    pub finish: bool,
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

impl Default for StreamOptions {
    fn default() -> Self {
        StreamOptions {
            rows_per_message: 0,
            in_flight: 4,
            reply_timeout: Duration::from_secs(60),
            reset: true,
            resume: false,
            finish: true,
            retries: 0,
            resend_after: Duration::from_secs(2),
        }
    }
}

/// What a stream did.
#[derive(Debug, Clone)]
pub struct StreamReport {
    /// Frames sent.
    pub frames: usize,
    /// Final decision of every frame, by index.
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
    /// The device's flash log filled up: frames from this one on were not
    /// scanned (the open one was dropped, the scan finished with the rest).
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
            .map_err(|e| DeviceError::Input(format!("voxel grid: {e:?}")))?,
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

/// The profile whose capacities the device reports, if any.
pub fn device_profile(st: &Status) -> Option<&'static Capacities> {
    PROFILES.iter().find(|p| {
        st.capacity(CapacitySlot::Database).limit as usize == p.database_frames
            && st.capacity(CapacitySlot::Pool).limit as usize == p.pool_words
            && st.capacity(CapacitySlot::Window).limit as usize == p.window
            && st.capacity(CapacitySlot::FrameVoxels).limit as usize
                == p.frame_voxel_slots - p.frame_voxel_slots / 4
    })
}

pub(crate) fn check_profile(st: &Status, profile: &str) -> Result<(), DeviceError> {
    match device_profile(st) {
        Some(p) if p.name == profile => Ok(()),
        Some(p) => Err(DeviceError::Profile(format!(
            "the device runs profile {} but --profile {profile} was given: \
             the results would not match `placedb select --profile {profile}`",
            p.name
        ))),
        None => Err(DeviceError::Profile(format!(
            "the device's capacities (database {}, pool {}, window {}) match no profile",
            st.capacity(CapacitySlot::Database).limit,
            st.capacity(CapacitySlot::Pool).limit,
            st.capacity(CapacitySlot::Window).limit
        ))),
    }
}

/// Sends one message and waits for its terminal reply (other messages before
/// it are returned too).
fn request<L: Link>(
    client: &mut Client<L>,
    msg: HostMessage<'_>,
    what: &str,
    timeout: Duration,
) -> Result<Vec<Received>, DeviceError> {
    let (seq, replies) = client.request(msg, timeout)?;
    match replies.last() {
        Some(Received::Message(DeviceMessage::Error { kind, .. })) => Err(DeviceError::Refused {
            what: what.to_string(),
            seq,
            kind: *kind,
        }),
        _ => Ok(replies),
    }
}

/// The device's status.
pub fn status<L: Link>(client: &mut Client<L>, timeout: Duration) -> Result<Status, DeviceError> {
    let replies = request(client, HostMessage::StatusRequest, "StatusRequest", timeout)?;
    match replies.last() {
        Some(Received::Message(DeviceMessage::Status(s))) => Ok(*s),
        other => Err(DeviceError::Protocol(format!(
            "expected a Status, got {other:?}"
        ))),
    }
}

/// Sends `msg` and waits for its terminal reply, stop-and-wait: when none
/// comes within `resend_after`, or an error says a frame was damaged on the
/// way ([`ErrorKind::is_damage`]), the link is resynchronised and the same
/// message is sent again with the same sequence number, at most `retries`
/// times. Returns what arrived for it (decisions, logs, the terminal reply
/// last; replies to other sequence numbers are dropped) and the number of
/// retransmissions. A refusal (any other error) is returned as
/// [`DeviceError::Refused`].
pub fn exchange<L: Link>(
    client: &mut Client<L>,
    msg: HostMessage<'_>,
    what: &str,
    resend_after: Duration,
    retries: usize,
) -> Result<(Vec<Received>, u64), DeviceError> {
    let seq = client.take_seq();
    let mut got = Vec::new();
    for attempt in 0..=retries {
        if attempt > 0 {
            client.resync()?;
        }
        client.send_as(seq, msg)?;
        let deadline = Instant::now() + resend_after;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let item = match client.recv(left) {
                Ok(item) => item,
                Err(e) if e.kind() == io::ErrorKind::TimedOut => break,
                Err(e) => return Err(e.into()),
            };
            match &item {
                // Under stop-and-wait a damaged frame is ours (or a harmless
                // repeat): send again at once.
                Received::Message(DeviceMessage::Error { kind, .. }) if kind.is_damage() => break,
                Received::Message(DeviceMessage::Error { seq: Some(s), kind }) if *s == seq => {
                    return Err(DeviceError::Refused {
                        what: what.to_string(),
                        seq,
                        kind: *kind,
                    })
                }
                _ => {}
            }
            match item.terminal_seq() {
                Some(s) if s == seq => {
                    got.push(item);
                    return Ok((got, attempt as u64));
                }
                // A late reply to an earlier message.
                Some(_) => {}
                None => got.push(item),
            }
        }
    }
    Err(DeviceError::Protocol(format!(
        "no reply to {what} (seq {seq}) after {retries} retransmissions, {resend_after:?} apart"
    )))
}

/// One message of a stream's set-up, with or without retransmission.
pub(crate) fn call<L: Link>(
    client: &mut Client<L>,
    msg: HostMessage<'_>,
    what: &str,
    opts: &StreamOptions,
    resent: &mut u64,
) -> Result<Vec<Received>, DeviceError> {
    if opts.retries == 0 {
        return request(client, msg, what, opts.reply_timeout);
    }
    let (replies, n) = exchange(client, msg, what, opts.resend_after, opts.retries)?;
    *resent += n;
    Ok(replies)
}

/// A StatusRequest through [`call`].
pub(crate) fn call_status<L: Link>(
    client: &mut Client<L>,
    opts: &StreamOptions,
    resent: &mut u64,
) -> Result<Status, DeviceError> {
    status_of(&call(
        client,
        HostMessage::StatusRequest,
        "StatusRequest",
        opts,
        resent,
    )?)
}

fn status_of(replies: &[Received]) -> Result<Status, DeviceError> {
    match replies.last() {
        Some(Received::Message(DeviceMessage::Status(s))) => Ok(*s),
        other => Err(DeviceError::Protocol(format!(
            "expected a Status, got {other:?}"
        ))),
    }
}

/// One line about the device's state, for a live status display.
pub fn status_line(st: &Status) -> String {
    let c = |slot| {
        let c = st.capacity(slot);
        format!("{}/{}", c.used, c.limit)
    };
    let mut s = format!(
        "db {} pool {} win {} labels {} flash {}/{} KiB",
        c(CapacitySlot::Database),
        c(CapacitySlot::Pool),
        c(CapacitySlot::Window),
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
    if st.degradation != 0 {
        s += &format!(" | degraded {:#x}", st.degradation);
    }
    s
}

/// Streams `seq` to the device behind `client`: (Reset,) Hello with `cfg`,
/// every frame as FrameBegin, DepthRows, FrameEnd (and a StatusRequest for
/// the live line), then Finish. The device must run capacity profile
/// `profile`. The frames go through the client API's code
/// ([`crate::session`]), as a robot's would.
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
    scan.begin(client, cfg, Some(profile), Some(n))?;
    let first = scan.next_frame as usize;
    scan.decisions = vec![None; n];
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
            log_full_at = Some(scan.abandon_open_frame(client)? as usize);
        }
        Err(e) => return Err(e),
    }
    if opts.finish {
        scan.send(client, HostMessage::Finish, || "Finish".into())?;
    }
    scan.drain(client)?;
    let wall = started.elapsed();
    let status = call_status(client, opts, &mut scan.retransmissions)?;
    Ok(StreamReport {
        frames: log_full_at.unwrap_or(n) - first,
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
        let img = seq
            .depth(i)
            .map_err(|e| DeviceError::Input(format!("frame {i}: {e}")))?;
        let pose = seq.frames[i]
            .pose()
            .map_err(|e| DeviceError::Input(format!("frame {i}: pose: {e:?}")))?;
        scan.push(
            client,
            &DepthFrame {
                timestamp: seq.frames[i].timestamp,
                pose,
                intrinsics: cfg.intrinsics,
                depth: &img.data,
            },
        )?;
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
                p.set_message(format!("{fps:.2} fps | {}", status_line(st)));
            }
        }
    }
    Ok(())
}

/// How to export.
#[derive(Debug, Clone)]
pub struct ExportOptions {
    /// Most records per ExportRequest; each batch is checked by count and
    /// CRC. After a failed batch the next one is half as long (down to 1
    /// record), after a good one a record longer (up to this).
    pub batch: u32,
    /// Failed attempts in a row (a batch re-requested from its first record,
    /// a status request sent again) before giving up.
    pub retries: usize,
    /// Longest wait for one reply (the next record or the batch's end).
    pub reply_timeout: Duration,
}

impl Default for ExportOptions {
    fn default() -> Self {
        ExportOptions {
            batch: 256,
            retries: 5,
            reply_timeout: Duration::from_secs(30),
        }
    }
}

/// Every record of the device's export, checked.
#[derive(Debug, Clone)]
pub struct Export {
    /// The records, numbered from 0.
    pub records: Vec<ExportRecord>,
    /// The device's status when the export ended.
    pub status: Status,
    /// Batches that had to be retried.
    pub retried: usize,
}

/// One batch: records `from..from+max`, checked by count and CRC.
fn export_batch<L: Link>(
    client: &mut Client<L>,
    from: u32,
    max: u32,
    timeout: Duration,
) -> Result<Vec<ExportRecord>, DeviceError> {
    let seq = client.send(HostMessage::ExportRequest {
        from_record: from,
        max_records: max,
    })?;
    let mut got: Vec<ExportRecord> = Vec::new();
    let mut damaged = false;
    loop {
        match client.recv(timeout)? {
            Received::Message(DeviceMessage::ExportRecord(r)) => got.push(r),
            Received::Damaged(_) => damaged = true,
            Received::Message(DeviceMessage::ExportEnd {
                seq: s,
                from_record,
                count,
                crc32,
            }) if s == seq => {
                let numbered = got
                    .iter()
                    .enumerate()
                    .all(|(k, r)| r.record == from + k as u32);
                if damaged || from_record != from || count as usize != got.len() || !numbered {
                    return Err(DeviceError::Protocol(format!(
                        "export batch from {from}: {} records received, {count} sent",
                        got.len()
                    )));
                }
                if crc32 != export_crc(&got) {
                    return Err(DeviceError::Protocol(format!(
                        "export batch from {from}: CRC mismatch"
                    )));
                }
                return Ok(got);
            }
            // The request (or a record) was damaged on the way: ask again.
            Received::Message(DeviceMessage::Error { kind, .. }) if kind.is_damage() => {
                return Err(DeviceError::Protocol(format!(
                    "export batch from {from}: the request was damaged ({kind})"
                )));
            }
            Received::Message(DeviceMessage::Error { seq: s, kind }) if s == Some(seq) => {
                return Err(DeviceError::Refused {
                    what: format!("ExportRequest from {from}"),
                    seq,
                    kind,
                })
            }
            // Anything else (a reply to an earlier request, a log) is not ours.
            _ => {}
        }
    }
}

/// Pulls every record from the device, in checked batches, starting after
/// the records in `have` (a resumed export). `saved` is called with each
/// checked batch (to persist it).
pub fn export<L: Link>(
    client: &mut Client<L>,
    mut have: Vec<ExportRecord>,
    opts: &ExportOptions,
    progress: Option<&ProgressBar>,
    saved: &mut dyn FnMut(&[ExportRecord]) -> io::Result<()>,
) -> Result<Export, DeviceError> {
    let timeout = opts.reply_timeout;
    let retries = opts.retries.max(1);
    client.resync()?;
    let ask_status = |client: &mut Client<L>| {
        exchange(
            client,
            HostMessage::StatusRequest,
            "StatusRequest",
            timeout,
            retries,
        )
        .and_then(|(replies, _)| status_of(&replies))
    };
    let first = ask_status(client)?;
    let total = first.export_records() as usize;
    if have.len() > total {
        return Err(DeviceError::Input(format!(
            "resuming from record {} but the device holds {total}",
            have.len()
        )));
    }
    if let Some(p) = progress {
        p.set_length(total as u64);
        p.set_position(have.len() as u64);
    }
    let mut retried = 0;
    let mut failed_in_a_row = 0;
    let mut batch_len = opts.batch.max(1);
    while have.len() < total {
        let from = have.len() as u32;
        match export_batch(client, from, batch_len, timeout) {
            Ok(batch) if !batch.is_empty() => {
                failed_in_a_row = 0;
                batch_len = batch_len.saturating_add(1).min(opts.batch.max(1));
                saved(&batch)?;
                have.extend(batch);
                if let Some(p) = progress {
                    p.set_position(have.len() as u64);
                }
            }
            Ok(_) => {
                return Err(DeviceError::Protocol(format!(
                    "the device sent no record from {from} of {total}"
                )))
            }
            Err(e @ DeviceError::Refused { .. }) => return Err(e),
            Err(e) if failed_in_a_row < opts.retries => {
                retried += 1;
                failed_in_a_row += 1;
                batch_len = (batch_len / 2).max(1);
                if let Some(p) = progress {
                    p.println(format!("retrying from record {from}: {e}"));
                }
                // Let a broken reply finish, then resynchronise.
                while client.recv(Duration::from_millis(200).min(timeout)).is_ok() {}
                client.resync()?;
            }
            Err(e) => return Err(e),
        }
    }
    let last = ask_status(client)?;
    if last.export_records() as usize != have.len()
        || (last.frames_seen, last.database_size) != (first.frames_seen, first.database_size)
    {
        return Err(DeviceError::Protocol(
            "the device's state changed during the export".into(),
        ));
    }
    check_records(&have, last.database_size as usize)?;
    Ok(Export {
        records: have,
        status: last,
        retried,
    })
}

/// Checks the layout: database records in strictly increasing frame order,
/// then one label per frame 0, 1, 2, ...
fn check_records(records: &[ExportRecord], database: usize) -> Result<(), DeviceError> {
    let bad = |what: &str| Err(DeviceError::Protocol(format!("export: {what}")));
    let (db, labels) = records.split_at(database.min(records.len()));
    if db.len() != database {
        return bad("fewer records than database frames");
    }
    let mut last = None;
    for r in db {
        if !matches!(r.kind, RecordKind::Database { .. }) || last.is_some_and(|l| r.frame <= l) {
            return bad("database records out of order");
        }
        last = Some(r.frame);
    }
    for (j, r) in labels.iter().enumerate() {
        if !matches!(r.kind, RecordKind::Label { .. }) || r.frame as usize != j {
            return bad("label records out of order");
        }
    }
    Ok(())
}

impl Export {
    /// The database records as the core's [`DbRecord`]s (voxel counts are not
    /// exported: 0).
    pub fn database(&self) -> Vec<DbRecord> {
        self.records
            .iter()
            .filter_map(|r| match r.kind {
                RecordKind::Database { pose } => Some(DbRecord {
                    index: r.frame,
                    timestamp: r.timestamp,
                    pose,
                    voxels: 0,
                }),
                RecordKind::Label { .. } => None,
            })
            .collect()
    }

    /// Timestamps and class labels of every labelled frame.
    pub fn labels(&self) -> (Vec<f64>, Vec<usize>) {
        self.records
            .iter()
            .filter_map(|r| match r.kind {
                RecordKind::Label { class } => Some((r.timestamp, class as usize)),
                RecordKind::Database { .. } => None,
            })
            .unzip()
    }

    /// The text of `database.csv` and `labels.csv`.
    pub fn csv(&self) -> (String, String) {
        let (timestamps, labels) = self.labels();
        (
            output::database_csv(&output::rows_from_records(&self.database())),
            output::labels_csv(&timestamps, &labels),
        )
    }

    /// `metrics.json` of an export: what the device knows (the metrics that
    /// need the sequence's voxel sets are computed by `placedb select`).
    pub fn metrics(&self) -> serde_json::Value {
        let st = &self.status;
        let size = st.database_size;
        let frames = st.capacity(CapacitySlot::Labels).used;
        let mut m = serde_json::json!({
            "solver": "online",
            "source": "device",
            "size": size,
            "frames": frames,
            "reduction": if size > 0 { f64::from(frames) / f64::from(size) } else { 0.0 },
            "profile": device_profile(st).map(|p| p.name),
            "frames_seen": st.frames_seen,
            "sketched_frames": st.sketched_frames,
            "truncated_frames": st.truncated_frames,
            "uncovered_by_capacity": st.uncovered_frames,
            "labels_dropped": st.labels_dropped,
            "degradation_flags": st.degradation,
            "pool_peak_words": st.capacity(CapacitySlot::Pool).peak,
            "frame_voxels_peak": st.capacity(CapacitySlot::FrameVoxels).peak,
            "export_records": self.records.len(),
            "resident_peak": st.capacity(CapacitySlot::Resident).peak,
            "flash_bytes_used": st.capacity(CapacitySlot::Flash).used,
            "flash_bytes_limit": st.capacity(CapacitySlot::Flash).limit,
        });
        if st.cost.clock_hz > 0 && st.cost.frames > 0 {
            m["device_ticks_per_frame"] = (st.cost.total as f64 / f64::from(st.cost.frames)).into();
            m["device_clock_hz"] = st.cost.clock_hz.into();
        }
        m
    }
}

/// Name of the file holding the checked batches of an unfinished export.
pub const PARTIAL_EXPORT: &str = ".export-partial";

/// The records of an unfinished export in `dir` and the status it began
/// with: COBS frames of a `Status` then `ExportRecord`s, as the device sent
/// them (so timestamps and poses survive bit for bit).
pub fn read_partial(dir: &Path) -> Result<(Status, Vec<ExportRecord>), DeviceError> {
    let path = dir.join(PARTIAL_EXPORT);
    let bytes = std::fs::read(&path).map_err(|e| {
        DeviceError::Input(format!("no unfinished export in {}: {e}", path.display()))
    })?;
    let mut decoder = Box::new(FrameDecoder::<MAX_FRAME_LEN>::new());
    let mut rest: &[u8] = &bytes;
    let (mut status, mut records) = (None, Vec::new());
    while let Feed::Frame { result, remaining } = decoder.feed::<DeviceMessage>(rest) {
        match result {
            Ok(DeviceMessage::Status(s)) if status.is_none() => status = Some(s),
            Ok(DeviceMessage::ExportRecord(r)) if status.is_some() => records.push(r),
            // A torn last write: keep what was whole.
            _ => break,
        }
        rest = remaining;
    }
    let status = status
        .ok_or_else(|| DeviceError::Input(format!("{} holds no export header", path.display())))?;
    Ok((status, records))
}

fn append_frames(path: &Path, msgs: &[DeviceMessage<'_>]) -> io::Result<()> {
    use std::io::Write;
    let mut file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)?;
    let mut buf = vec![0u8; MAX_FRAME_LEN];
    for m in msgs {
        let frame = encode(m, &mut buf).map_err(io::Error::other)?;
        file.write_all(frame)?;
    }
    file.sync_data()
}

/// Opens the link `port` for the device subcommands.
pub fn connect(port: &str) -> Result<Client<Box<dyn Link>>, DeviceError> {
    let link = link::open(port, Duration::from_secs(10))?;
    Ok(Client::new(link))
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
    /// End the stream with Finish ([`StreamOptions::finish`]).
    pub finish: bool,
}

impl Default for Recovery {
    fn default() -> Self {
        Recovery {
            faults: FaultConfig::default(),
            retries: None,
            resend_after: Duration::from_secs(2),
            resume: false,
            finish: true,
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
            finish: self.finish,
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

/// `placedb stream`: streams `seq` (configured by `vcfg` and `sel`, as
/// `placedb select` is) to the device on `port`, which must run `profile`;
/// prints a summary, and exports into `out` if given. `recovery` injects
/// faults into the link and sets the retransmission policy.
#[allow(clippy::too_many_arguments)]
pub fn stream_cmd(
    port: &str,
    seq: &Sequence,
    vcfg: &VoxelConfig,
    sel: SelectorConfig,
    profile: &str,
    out: Option<&Path>,
    quiet: bool,
    recovery: &Recovery,
) -> Result<StreamReport, DeviceError> {
    recovery.faults.validate().map_err(DeviceError::Input)?;
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
    let link = link::open(port, Duration::from_secs(10))?;
    let mut client = Client::new(FaultInjector::new(link, recovery.faults));
    let pb = (!quiet).then(|| {
        let pb = ProgressBar::new(seq.frames.len() as u64);
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} frames {msg}",
        ) {
            pb.set_style(style);
        }
        pb
    });
    let report = stream(
        &mut client,
        seq,
        &cfg,
        profile,
        &recovery.stream_options(),
        pb.as_ref(),
    )?;
    if let Some(pb) = &pb {
        pb.finish_and_clear();
    }
    let st = &report.status;
    println!(
        "{}: {} frames -> {} database frames on the device ({} profile, mu {}, window {}, stride {})",
        seq.name,
        report.frames,
        st.database_size,
        profile,
        sel.mu,
        sel.window,
        scan.stride
    );
    println!(
        "  link: {:.1} s, {:.2} frames/s, {} messages, {:.1} KB sent ({:.1} KB/s)",
        report.wall.as_secs_f64(),
        report.fps(),
        report.messages,
        report.bytes_sent as f64 / 1e3,
        report.bytes_sent as f64 / 1e3 / report.wall.as_secs_f64().max(1e-9)
    );
    if let Some(t) = report.ticks_per_frame() {
        println!(
            "  device: {:.3} M clock ticks per frame (max {:.3} M) at {} Hz: {:.2} ms of device time per frame \
             (the QEMU board counts instructions under -icount shift=0)",
            t / 1e6,
            f64::from(st.cost.max) / 1e6,
            st.cost.clock_hz,
            1e3 * t / f64::from(st.cost.clock_hz)
        );
    }
    if st.degradation & placedb::protocol::degradation::STORAGE_FAILED != 0 {
        println!(
            "  WARNING: the device's flash failed a write: only {} records of this scan are \
             durable; a power cut now would lose the rest (export it now)",
            st.stored_records
        );
    }
    if st.degradation & placedb::protocol::degradation::TAIL_DROPPED != 0 {
        println!(
            "  WARNING: at boot the device found records in its flash log that no scan can \
             hold (damaged flash) and dropped them with everything after them; the scan went \
             on from the last good record"
        );
    }
    if let Some(k) = report.log_full_at {
        println!(
            "  the device's flash log is full: frames {k}..{} were not scanned; the scan \
             was finished with frames 0..{k} (Reset the device, or give it more flash, \
             for a longer scan)",
            seq.frames.len()
        );
    }
    if recovery.faults.is_active() {
        let f = client.link().stats();
        let lost = report.decisions.iter().filter(|d| d.is_none()).count();
        println!(
            "  faults (seed {}): host->device {} of {} frames dropped, {} corrupted; \
             device->host {} of {} dropped, {} corrupted; {} retransmissions; \
             {lost} decisions lost on the way (the export has them)",
            recovery.faults.seed,
            f.sent_dropped,
            f.sent,
            f.sent_corrupted,
            f.received_dropped,
            f.received,
            f.received_corrupted,
            report.retransmissions
        );
    }
    println!("  {}", status_line(st));
    match out {
        Some(dir) => {
            export_to_with(&mut client, dir, None, quiet, &recovery.export_options())?;
        }
        None => println!("  pull the result with: placedb export --port {port} -o DIR"),
    }
    Ok(report)
}

/// `placedb export`: pulls every record from the device on `port` and
/// writes `database.csv`, `labels.csv` and `metrics.json` to `out`.
/// `from = Some(k)` resumes an interrupted export of the same device state
/// from record `k` (the checked records before it are kept in `out`).
pub fn export_cmd(
    port: &str,
    out: &Path,
    from: Option<u32>,
    quiet: bool,
) -> Result<Export, DeviceError> {
    let mut client = connect(port)?;
    export_to(&mut client, out, from, quiet)
}

/// [`export_cmd`] over an open link.
pub fn export_to<L: Link>(
    client: &mut Client<L>,
    out: &Path,
    from: Option<u32>,
    quiet: bool,
) -> Result<Export, DeviceError> {
    export_to_with(client, out, from, quiet, &ExportOptions::default())
}

/// [`export_to`] with `opts`.
pub fn export_to_with<L: Link>(
    client: &mut Client<L>,
    out: &Path,
    from: Option<u32>,
    quiet: bool,
    opts: &ExportOptions,
) -> Result<Export, DeviceError> {
    std::fs::create_dir_all(out)?;
    let partial = out.join(PARTIAL_EXPORT);
    let timeout = opts.reply_timeout;
    client.resync()?;
    let (replies, _) = exchange(
        client,
        HostMessage::StatusRequest,
        "StatusRequest",
        timeout,
        opts.retries.max(1),
    )?;
    let now = status_of(&replies)?;
    let have = match from {
        Some(k) => {
            let (was, mut records) = read_partial(out)?;
            if (was.frames_seen, was.database_size, was.export_records())
                != (now.frames_seen, now.database_size, now.export_records())
            {
                return Err(DeviceError::Input(
                    "the device's state changed since the interrupted export: export from 0".into(),
                ));
            }
            if records.len() < k as usize {
                return Err(DeviceError::Input(format!(
                    "--from {k}: only {} checked records were saved",
                    records.len()
                )));
            }
            records.truncate(k as usize);
            records
        }
        None => Vec::new(),
    };
    // Rewrite the partial file with exactly what is kept.
    let _ = std::fs::remove_file(&partial);
    let mut head = vec![DeviceMessage::Status(now)];
    head.extend(have.iter().map(|r| DeviceMessage::ExportRecord(*r)));
    append_frames(&partial, &head)?;
    let pb = (!quiet).then(|| ProgressBar::new(0));
    let export = export(client, have, opts, pb.as_ref(), &mut |batch| {
        let msgs: Vec<_> = batch
            .iter()
            .map(|r| DeviceMessage::ExportRecord(*r))
            .collect();
        append_frames(&partial, &msgs)
    })
    .map_err(|e| match e {
        DeviceError::Io(io) => DeviceError::Io(io::Error::new(
            io.kind(),
            format!("{io}; resume with --from N (checked records are saved)"),
        )),
        other => other,
    })?;
    if let Some(pb) = &pb {
        pb.finish_and_clear();
    }
    let (db_csv, labels_csv) = export.csv();
    std::fs::write(out.join("database.csv"), db_csv)?;
    std::fs::write(out.join("labels.csv"), labels_csv)?;
    let json = serde_json::to_string_pretty(&export.metrics()).map_err(io::Error::other)?;
    std::fs::write(out.join("metrics.json"), json + "\n")?;
    std::fs::remove_file(&partial)?;
    if !quiet {
        println!(
            "exported {} records ({} database frames, {} labels), checked by count and CRC{}; wrote {}/{{database.csv,labels.csv,metrics.json}}",
            export.records.len(),
            export.status.database_size,
            export.status.capacity(CapacitySlot::Labels).used,
            if export.retried > 0 {
                format!(" ({} batches retried)", export.retried)
            } else {
                String::new()
            },
            out.display()
        );
    }
    Ok(export)
}

/// `placedb device --qemu`: boots the emulated board with UART0 listening on
/// `tcp:127.0.0.1:PORT` (0: a free port) and waits until QEMU exits. Ctrl-C,
/// SIGTERM or SIGHUP stop QEMU first, and on Linux QEMU is killed if placedb
/// dies any other way ([`crate::foreground`]). `icount` makes instruction
/// counting exact.
pub fn qemu_device_cmd(
    firmware: Option<PathBuf>,
    port: u16,
    icount: bool,
    flash: Option<PathBuf>,
) -> Result<(), DeviceError> {
    let firmware = firmware.unwrap_or_else(link::default_firmware);
    if !firmware.is_file() {
        return Err(DeviceError::Input(format!(
            "firmware {} not found: build it with `{}` (or pass --firmware ELF)",
            firmware.display(),
            link::FIRMWARE_BUILD
        )));
    }
    let port = match port {
        0 => std::net::TcpListener::bind(("127.0.0.1", 0))?
            .local_addr()?
            .port(),
        p => p,
    };
    if let Some(f) = &flash {
        link::prepare_flash_file(f)?;
    }
    let mut options = QemuOptions {
        flash,
        ..QemuOptions::default()
    };
    if icount {
        options.extra_args = vec!["-icount".into(), "shift=0".into()];
    }
    let mut command = link::qemu_command(
        &firmware,
        &options,
        &format!("tcp:127.0.0.1:{port},server,nowait"),
    );
    // QEMU ends with placedb, whatever stops it (host/src/foreground.rs).
    let mut child = crate::foreground::spawn(&mut command).map_err(|e| {
        DeviceError::Io(io::Error::new(
            e.kind(),
            format!(
                "cannot start {} (apt-get install qemu-system-arm): {e}",
                options.program.display()
            ),
        ))
    })?;
    println!("emulated board (mps2-an386, profile ram512k) on port tcp:127.0.0.1:{port}");
    println!("  e.g. placedb stream --port tcp:127.0.0.1:{port} --demo --stride 8 --max-frames 30");
    println!("       placedb export --port tcp:127.0.0.1:{port} -o out");
    match &options.flash {
        Some(f) => println!(
            "  flash kept in {}: after a restart, `placedb stream --resume` goes on with the scan",
            f.display()
        ),
        None => println!("  no --flash file: the board starts empty every time"),
    }
    println!("  Ctrl-C (or SIGTERM, SIGHUP) stops it, QEMU with it");
    match crate::foreground::wait(&mut child)? {
        crate::foreground::Ended::Exited(status) if status.success() => Ok(()),
        crate::foreground::Ended::Exited(status) => Err(DeviceError::Io(io::Error::other(
            format!("QEMU exited: {status}"),
        ))),
        crate::foreground::Ended::Stopped(signal) => {
            println!("stopped (signal {signal}): QEMU ended");
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::LocalLink;
    use crate::synth::{self, SynthConfig};

    fn demo(frames: usize) -> Sequence {
        let mut seq = synth::sequence(&SynthConfig::demo());
        seq.frames.truncate(frames);
        seq
    }

    fn setup(seq: &Sequence, window: u16) -> (ScanConfig, SelectorConfig, Config) {
        let vcfg = VoxelConfig {
            stride: 8,
            ..VoxelConfig::default()
        };
        let scan = scan_config(seq, &vcfg).unwrap();
        let sel = SelectorConfig {
            mu: 0.3,
            window,
            sketch_margin: 0.05,
        };
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
        let run = crate::online::replay(&seq, "ram256k", scan, sel, 8, None).unwrap();
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
        let want = (
            output::database_csv(&output::rows_from_records(&run.database)),
            output::labels_csv(&timestamps, &run.labels),
        );
        assert_eq!(full.csv(), want);
        assert_eq!(
            std::fs::read_to_string(dir.join("database.csv")).unwrap(),
            want.0
        );
        assert!(!dir.join(PARTIAL_EXPORT).exists());
        // An interrupted export leaves its checked records; --from resumes.
        let partial = dir.join(PARTIAL_EXPORT);
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
