//! Pulling a scan's results from a device (`placedb export`): every record
//! in batches checked by count and CRC and asked again, shorter, when they
//! fail ([`export`]); the checked batches kept in a partial-export file so
//! that an interrupted export resumes ([`export_to_with`] with `from`); and
//! the files of [`crate::output`], all or nothing, byte-identical to
//! `placedb select --solver online`'s with the same profile and
//! configuration (the session columns of a scan of several sessions, and the
//! extension file of a finished scan, rebuilt from the device's flash log:
//! [`log_records`]).

use crate::board::client::{ask_status, device_profile, Client, Received, Wait};
use crate::board::error::DeviceError;
use crate::board::link::Link;
use crate::board::log_records;
use crate::board::resend::ResendTimer;
use crate::error::OutputError;
use crate::output::replace::{self, Outputs};
use crate::output::{self, metrics_json};
use crate::sessions::extension::{self, Extension};
use indicatif::ProgressBar;
use placedb::protocol::{
    encode, export_crc, Config, DeviceMessage, ExportRecord, Feed, FrameDecoder, HostMessage,
    Phase, RecordKind, Status, MAX_FRAME_LEN,
};
use placedb::DbRecord;
use std::io;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The kind the export's replies are timed as ([`Client::first_wait`]).
const EXPORT_REPLY: &str = "ExportRecord";

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

impl ExportOptions {
    /// How a status request of the export waits: stop-and-wait, sent again
    /// (at least once) when no reply comes within `reply_timeout`.
    pub fn wait(&self) -> Wait {
        Wait::Resend {
            after: self.reply_timeout,
            retries: self.retries.max(1),
        }
    }
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
    /// What a later session needs (`extension.bin`), read back from the
    /// device's flash log by [`pull`] when its scan is finished.
    pub extension: Option<Extension>,
    /// The configuration the device scanned with, read from its flash
    /// log's first record by [`pull`] (`None`: the device keeps no log).
    pub config: Option<Config>,
    /// Where a host resumed the scan after a restart of the device (the
    /// frames it had seen), read from a finished scan's log by [`pull`]
    /// (`None`: not read, the scan is not finished or there is no log).
    pub resumes: Option<Vec<u32>>,
    /// Which frame of the streamed sequence each of the device's frames is
    /// (the device's frame `k` is frame `sequence_frames[k]`), when the host
    /// knows: a real-time replay's sent frames (`stream --realtime -o`), or
    /// `export --sequence`'s match. [`stage`] then numbers `database.csv`
    /// and `labels.csv` by the sequence. `None`: by the device's frames, the
    /// same numbers when it was sent every frame. The extension file keeps
    /// the device's numbers, which a later session goes on from.
    pub sequence_frames: Option<Vec<usize>>,
}

/// Records `from..from + max` of the device's export (one batch, checked
/// by count and CRC) of a device holding `database` database frames: a
/// few records read without an export (a resume's check of its sequence).
pub(crate) fn records<L: Link>(
    client: &mut Client<L>,
    from: u32,
    max: u32,
    database: u32,
) -> Result<Vec<ExportRecord>, DeviceError> {
    let timeout = ExportOptions::default().reply_timeout;
    export_batch(client, from, max, database, timeout)
}

/// One batch: records `from..from+max`, checked by count and CRC, of a
/// device holding `database` database frames.
fn export_batch<L: Link>(
    client: &mut Client<L>,
    from: u32,
    max: u32,
    database: u32,
    wait: Duration,
) -> Result<Vec<ExportRecord>, DeviceError> {
    let seq = client.send(HostMessage::ExportRequest {
        from_record: from,
        max_records: max,
    })?;
    let mut got: Vec<ExportRecord> = Vec::new();
    let mut damaged = false;
    // The longest gap before a reply (the first record, each next one, the
    // end): what a clean batch tells of how long to wait for one.
    let (mut last, mut longest) = (Instant::now(), Duration::ZERO);
    loop {
        let item = client.recv(wait)?;
        longest = longest.max(last.elapsed());
        last = Instant::now();
        match item {
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
                client.note_round_trip(EXPORT_REPLY, longest);
                return Ok(got);
            }
            // The request (or a record) was damaged on the way: ask again.
            Received::Message(DeviceMessage::Error { kind, .. }) if kind.is_damage() => {
                return Err(DeviceError::Protocol(format!(
                    "export batch from {from}: the request was damaged ({kind})"
                )));
            }
            Received::Message(DeviceMessage::ExportUnreadable(u)) if u.seq == seq => {
                let r = u.record;
                let what = if r < database {
                    format!("database frame {} of {database}: frame {}", r + 1, u.frame)
                } else {
                    format!("the label of frame {}", u.frame)
                };
                let place = match (u.log_at, r < database) {
                    (Some(at), true) => format!(" (its record at log byte {at})"),
                    (Some(at), false) => format!(" (after the decision batch at log byte {at})"),
                    (None, _) => String::new(),
                };
                return Err(DeviceError::Input(format!(
                    "the device cannot read back record {r} of its export ({what}) from its flash \
                     log{place}: the flash is damaged there, and an export without it would be \
                     incomplete"
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

/// The refusal of an export from a device that saw no frame.
pub const NO_SCAN: &str =
    "the device holds no scan (no frame seen since its last reset): nothing to export";

/// Pulls every record from the device, in checked batches, starting after
/// the records in `have` (a resumed export). `saved` is called with each
/// checked batch (to persist it).
pub fn export<L: Link>(
    client: &mut Client<L>,
    mut have: Vec<ExportRecord>,
    opts: &ExportOptions,
    progress: Option<&ProgressBar>,
    saved: &mut dyn FnMut(&[ExportRecord]) -> Result<(), DeviceError>,
) -> Result<Export, DeviceError> {
    let timeout = opts.reply_timeout;
    client.resync()?;
    let first = ask_status(client, opts.wait())?.0;
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
    // How long to wait for a reply: the measured gap between replies, and
    // after a wait that ran out twice that, up to `reply_timeout`
    // (crate::board::resend); only a wait of the whole `reply_timeout`, or
    // another failure, counts against `retries`.
    let mut wait = client.first_wait(EXPORT_REPLY, timeout);
    while have.len() < total {
        let from = have.len() as u32;
        match export_batch(client, from, batch_len, first.database_size, wait) {
            Ok(batch) if !batch.is_empty() => {
                failed_in_a_row = 0;
                wait = client.first_wait(EXPORT_REPLY, timeout);
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
                let early = wait < timeout && e.is_timeout();
                if !early {
                    failed_in_a_row += 1;
                }
                wait = match e.is_timeout() {
                    true => ResendTimer::next_wait(wait, timeout),
                    false => wait,
                };
                batch_len = (batch_len / 2).max(1);
                if let Some(p) = progress {
                    p.println(format!("retrying from record {from}: {e}"));
                }
                // Let a broken reply finish, then resynchronise.
                while client.recv(Duration::from_millis(200).min(wait)).is_ok() {}
                client.resync()?;
            }
            Err(e) => return Err(e),
        }
    }
    let last = ask_status(client, opts.wait())?.0;
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
        extension: None,
        config: None,
        resumes: None,
        sequence_frames: None,
    })
}

/// Checks the layout: database records in strictly increasing frame order,
/// then one label per frame 0, 1, 2, ..., then one record per session
/// after the first (sessions 1, 2, ..., at increasing frames).
fn check_records(records: &[ExportRecord], database: usize) -> Result<(), DeviceError> {
    let bad = |what: &str| Err(DeviceError::Protocol(format!("export: {what}")));
    let (db, rest) = records.split_at(database.min(records.len()));
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
    let labels = rest
        .iter()
        .take_while(|r| matches!(r.kind, RecordKind::Label { .. }))
        .count();
    for (j, r) in rest.iter().take(labels).enumerate() {
        if r.frame as usize != j {
            return bad("label records out of order");
        }
    }
    let mut first = 0;
    for (k, r) in rest.iter().skip(labels).enumerate() {
        let next = k as u32 + 1;
        match r.kind {
            RecordKind::Session { session } if session == next && r.frame > first => {
                first = r.frame;
            }
            _ => return bad("session records out of order"),
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
                RecordKind::Label { .. } | RecordKind::Session { .. } => None,
            })
            .collect()
    }

    /// The first frame of every session (`[0]` for a scan of one session).
    pub fn sessions(&self) -> Vec<u32> {
        let later = self.records.iter().filter_map(|r| match r.kind {
            RecordKind::Session { .. } => Some(r.frame),
            _ => None,
        });
        std::iter::once(0).chain(later).collect()
    }

    /// Timestamps and class labels of every labelled frame.
    pub fn labels(&self) -> (Vec<f64>, Vec<usize>) {
        self.records
            .iter()
            .filter_map(|r| match r.kind {
                RecordKind::Label { class } => Some((r.timestamp, class as usize)),
                RecordKind::Database { .. } | RecordKind::Session { .. } => None,
            })
            .unzip()
    }

    /// The text of `database.csv` and `labels.csv` as the device numbers
    /// its frames (what `placedb export` without `--sequence` writes).
    pub fn csv(&self) -> (String, String) {
        let (timestamps, labels) = self.labels();
        output::run_csv(&self.database(), &timestamps, &labels)
    }

    /// `metrics.json` of an export: what the device knows, and the metrics
    /// that need the sequence's voxel sets when `on` has measured them.
    pub fn metrics(&self, on: Option<&metrics_json::OnSequence<'_>>) -> serde_json::Value {
        let profile = device_profile(&self.status).map(|p| p.name);
        metrics_json::of_device(
            &self.status,
            self.config.as_ref(),
            self.resumes.as_deref(),
            self.records.len(),
            profile,
            on,
        )
    }
}

/// The file holding the checked batches of an unfinished export into
/// directory `out`: `.NAME.export-partial` beside it (not inside it, which
/// an export replaces whole only when complete). Kept after a failed
/// export, for `--from`; removed by a complete one.
pub fn resume_file(out: &Path) -> PathBuf {
    let name = out.file_name().unwrap_or_default().to_string_lossy();
    let parent = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    parent.join(format!(".{name}.export-partial"))
}

/// The records of an unfinished export into `out` ([`resume_file`]) and the
/// status it began with: COBS frames of a `Status` then `ExportRecord`s, as
/// the device sent them (so timestamps and poses survive bit for bit).
pub fn read_partial(out: &Path) -> Result<(Status, Vec<ExportRecord>), DeviceError> {
    let path = resume_file(out);
    let bytes = std::fs::read(&path).map_err(|e| {
        DeviceError::Input(format!(
            "no unfinished export into {} ({}: {e})",
            out.display(),
            path.display()
        ))
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

/// Appends `msgs` as COBS frames to the partial-export file `path`.
pub(crate) fn append_frames(path: &Path, msgs: &[DeviceMessage<'_>]) -> io::Result<()> {
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

/// `placedb export` over an open link: pulls every record from the device
/// and writes `database.csv`, `labels.csv` and `metrics.json` to `out`, all
/// or nothing. `from = Some(k)` resumes an interrupted export of the same
/// device state from record `k` (the checked records before it are kept in
/// [`resume_file`]).
pub fn export_to<L: Link>(
    client: &mut Client<L>,
    out: &Path,
    from: Option<u32>,
    quiet: bool,
) -> Result<Export, DeviceError> {
    export_to_with(
        client,
        out,
        from,
        quiet,
        &ExportOptions::default(),
        &[],
        None,
    )
}

/// [`export_to`] with `opts`, `extra` files (name, text) written into
/// `out` with the export's, and the tables numbered by the sequence's
/// `sequence_frames` if given ([`Export::sequence_frames`]).
pub fn export_to_with<L: Link>(
    client: &mut Client<L>,
    out: &Path,
    from: Option<u32>,
    quiet: bool,
    opts: &ExportOptions,
    extra: &[(&str, String)],
    sequence_frames: Option<&[usize]>,
) -> Result<Export, DeviceError> {
    output::check_database_dir(out)?;
    let mut export = pull(client, out, from, quiet, opts)?;
    export.sequence_frames = sequence_frames.map(<[usize]>::to_vec);
    replace::together(|outputs| stage(outputs, out, &export, None, extra))?;
    finished(out)?;
    Ok(export)
}

/// Pulls every record from the device, saving the checked batches in
/// `out`'s [`resume_file`]; `from = Some(k)` starts after the first `k`
/// saved there by an interrupted export of the same device state.
pub fn pull<L: Link>(
    client: &mut Client<L>,
    out: &Path,
    from: Option<u32>,
    quiet: bool,
    opts: &ExportOptions,
) -> Result<Export, DeviceError> {
    let partial = resume_file(out);
    // What a resume starts from is read first: a `--from` with nothing to
    // resume fails before the device is asked.
    let saved = match from {
        Some(k) => Some((k, read_partial(out)?)),
        None => None,
    };
    client.resync()?;
    let (now, _) = ask_status(client, opts.wait())?;
    // Empty CSVs would pass for a scan that saw nothing: refused, before
    // the directory is made.
    if now.frames_seen == 0 && now.export_records() == 0 {
        return Err(DeviceError::Input(NO_SCAN.into()));
    }
    let have = match saved {
        Some((k, (was, mut records))) => {
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
    let saving = |e: io::Error| DeviceError::Output(OutputError::writing(&partial)(e));
    // Rewrite the resume file with exactly what is kept.
    remove_if_there(&partial).map_err(saving)?;
    let mut head = vec![DeviceMessage::Status(now)];
    head.extend(have.iter().map(|r| DeviceMessage::ExportRecord(*r)));
    if let Some(parent) = partial.parent() {
        std::fs::create_dir_all(parent).map_err(saving)?;
    }
    append_frames(&partial, &head).map_err(saving)?;
    let pb = (!quiet).then(|| phase_bar("records"));
    // Records saved in the resume file: where an interrupted export goes on.
    let saved = std::cell::Cell::new(have.len());
    let resume_hint = |e: DeviceError| match e {
        DeviceError::Io(io) => DeviceError::Io(io::Error::new(
            io.kind(),
            format!(
                "{io}; resume with --from {n} (the {n} checked records are saved in {})",
                partial.display(),
                n = saved.get()
            ),
        )),
        other => other,
    };
    let export = export(client, have, opts, pb.as_ref(), &mut |batch| {
        let msgs: Vec<_> = batch
            .iter()
            .map(|r| DeviceMessage::ExportRecord(*r))
            .collect();
        append_frames(&partial, &msgs).map_err(saving)?;
        saved.set(saved.get() + batch.len());
        Ok(())
    })
    .map_err(resume_hint)?;
    if let Some(pb) = &pb {
        pb.finish_and_clear();
    }
    let mut export = export;
    // A finished scan's whole log is read for its extension file, which
    // gives the configuration too; otherwise only the log's first record.
    // Reading the log is most of a long scan's export: its own bar.
    let log_pb = (!quiet).then(|| phase_bar("flash log"));
    let read_log = extension_of(client, &export, opts, log_pb.as_ref());
    if let Some(pb) = &log_pb {
        pb.finish_and_clear();
    }
    match read_log.map_err(resume_hint)? {
        Some((extension, scan)) => {
            export.extension = Some(extension);
            export.config = Some(scan.config);
            export.resumes = Some(scan.resumes);
        }
        None if export.status.stored_records > 0 => {
            export.config = log_records::scan_config(client, opts.wait(), 1)?;
        }
        None => {}
    }
    Ok(export)
}

/// A progress bar for one phase of an export, named `phase` (`records`,
/// `flash log`), counting its records.
fn phase_bar(phase: &'static str) -> ProgressBar {
    let pb = ProgressBar::new(0).with_message(phase);
    if let Ok(style) =
        indicatif::ProgressStyle::with_template("{msg:>12} [{bar:30}] {pos}/{len} {elapsed}")
    {
        pb.set_style(style);
    }
    pb
}

/// Writes `export` as output `out` of the run writing `outputs`:
/// `database.csv`, `labels.csv` (with the session columns for a scan of
/// several sessions; numbered by the sequence when
/// [`Export::sequence_frames`] says how), `metrics.json` (with the metrics
/// `on` measured on the streamed sequence, if given), the extension file of
/// a finished scan, and the `extra` files.
pub fn stage(
    outputs: &mut Outputs,
    out: &Path,
    export: &Export,
    on: Option<&metrics_json::OnSequence<'_>>,
    extra: &[(&str, String)],
) -> Result<(), OutputError> {
    let dir = output::stage_database_dir(outputs, out)?;
    let (timestamps, labels) = export.labels();
    let rows = output::rows_from_records(&export.database());
    let firsts = export.sessions();
    // A scan of several sessions: the session columns too.
    let session_of = |g: usize| log_records::session_of(&firsts, g as u32);
    let sessions =
        (firsts.len() > 1).then_some(&session_of as output::session_columns::SessionOf<'_>);
    output::write_database_dir(
        &dir,
        &rows,
        &timestamps,
        &labels,
        &export.metrics(on),
        sessions,
        export.sequence_frames.as_deref(),
    )?;
    if let Some(ext) = &export.extension {
        extension::write(&dir.join(extension::FILE_NAME), ext)?;
    }
    for (name, text) in extra {
        replace::write_text(&dir.join(name), text)?;
    }
    Ok(())
}

/// After `export` is in place in `out`: its resume file removed.
pub fn finished(out: &Path) -> Result<(), DeviceError> {
    let partial = resume_file(out);
    remove_if_there(&partial).map_err(|e| DeviceError::Output(OutputError::writing(&partial)(e)))
}

/// Removes file `path` if it is there.
fn remove_if_there(path: &Path) -> io::Result<()> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != io::ErrorKind::NotFound => Err(e),
        _ => Ok(()),
    }
}

/// The extension file of the exported scan and the configuration it was
/// made with, from the device's flash log (every record read back and
/// checked against the export); `None` when the device keeps no log or its
/// scan is not finished (nothing to extend).
fn extension_of<L: Link>(
    client: &mut Client<L>,
    export: &Export,
    opts: &ExportOptions,
    progress: Option<&ProgressBar>,
) -> Result<Option<(Extension, log_records::LoggedScan)>, DeviceError> {
    let st = &export.status;
    if st.stored_records == 0 || st.phase != Phase::Finished {
        return Ok(None);
    }
    let records = log_records::read_log(client, st.stored_records, opts.wait(), progress)?;
    let scan = log_records::scan_of(&records)?;
    let (timestamps, labels) = export.labels();
    let same = scan.sessions == export.sessions()
        && scan.decisions.len() == labels.len()
        && scan
            .decisions
            .iter()
            .zip(0u32..)
            .zip(timestamps.iter().zip(&labels))
            .all(|(((t, kind), i), (ts, &class))| {
                t.to_bits() == ts.to_bits() && kind.class(i) == Some(class as u32)
            })
        && scan
            .database
            .iter()
            .map(|f| f.meta.index)
            .eq(export.database().iter().map(|r| r.index));
    if !same {
        return Err(DeviceError::Protocol(
            "the device's flash log does not hold the scan it exported".into(),
        ));
    }
    let profile = device_profile(st).map_or("", |p| p.name);
    Ok(Some((scan.extension(profile), scan)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use placedb::protocol::{ExportUnreadable, HostFrame};
    use placedb::Pose;

    /// A device of three database frames whose second cannot be read back
    /// from its log: an ExportRequest gets the records before it, then
    /// `ExportUnreadable` (what the core's device sends).
    struct Damaged {
        decoder: FrameDecoder<MAX_FRAME_LEN>,
        out: Vec<u8>,
    }

    impl Link for Damaged {
        fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
            let mut rest = bytes;
            let mut tx = vec![0u8; 512];
            while let Feed::Frame { result, remaining } = self.decoder.feed::<HostFrame>(rest) {
                let replies = match result {
                    Ok(HostFrame {
                        seq,
                        msg: HostMessage::StatusRequest,
                    }) => vec![DeviceMessage::Status(Status {
                        database_size: 3,
                        ..Status::new(seq, Phase::Finished)
                    })],
                    Ok(HostFrame {
                        seq,
                        msg: HostMessage::ExportRequest { from_record, .. },
                    }) => {
                        let mut r: Vec<DeviceMessage> = (from_record..1)
                            .map(|record| {
                                DeviceMessage::ExportRecord(ExportRecord {
                                    record,
                                    frame: record * 4,
                                    timestamp: 0.0,
                                    kind: RecordKind::Database {
                                        pose: Pose {
                                            translation: [0.0; 3],
                                            rotation: [0.0, 0.0, 0.0, 1.0],
                                        },
                                    },
                                })
                            })
                            .collect();
                        r.push(DeviceMessage::ExportUnreadable(ExportUnreadable {
                            seq,
                            record: 1,
                            frame: 4,
                            log_at: Some(1234),
                        }));
                        r
                    }
                    _ => Vec::new(),
                };
                for m in replies {
                    self.out.extend_from_slice(encode(&m, &mut tx).unwrap());
                }
                rest = remaining;
            }
            Ok(())
        }

        fn recv(&mut self, _: Duration) -> io::Result<Vec<u8>> {
            if self.out.is_empty() {
                return Err(io::ErrorKind::TimedOut.into());
            }
            Ok(std::mem::take(&mut self.out))
        }
    }

    #[test]
    fn a_record_the_device_cannot_read_back_is_an_error_naming_it() {
        let mut client = Client::new(Damaged {
            decoder: FrameDecoder::new(),
            out: Vec::new(),
        });
        let opts = ExportOptions {
            reply_timeout: Duration::from_millis(200),
            ..ExportOptions::default()
        };
        let Err(err) = export(&mut client, Vec::new(), &opts, None, &mut |_| Ok(())) else {
            panic!("an export short of a record is an error");
        };
        let err = err.to_string();
        assert!(
            err.contains(
                "the device cannot read back record 1 of its export (database frame 2 of 3: \
                 frame 4) from its flash log (its record at log byte 1234)"
            ),
            "{err}"
        );
    }
}
