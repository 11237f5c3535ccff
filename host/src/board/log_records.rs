//! The scan as the device's flash log holds it: every record read back with
//! `LogRead` (in chunks, each checked by the link's CRC) and decoded with
//! the core's own record format ([`placedb::persist::Record`]), then the
//! finished scan they make: its configuration, sessions, final decisions and
//! database frames with what comparing new frames with them needs (sketch,
//! box, voxel count, exact keys where the log kept them, and their share
//! of the key budget). That is what the extension file of an export
//! records ([`LoggedScan::extension`]), so that a later `select --extend`
//! meets the database this device would restore.

use crate::board::client::{send_and_wait, Client, Received, Wait};
use crate::board::error::DeviceError;
use crate::board::link::Link;
use crate::sessions::extension::{DbFrame, Extension, Fate, FrameEntry, OnlineConfig, RunConfig};
use placedb::frame::FrameMeta;
use placedb::key_pool::{key_of, Aabb};
use placedb::persist::Record;
use placedb::protocol::{Config, DecisionKind, DeviceMessage, HostMessage};
use std::collections::BTreeMap;

/// One record of the log: its position and payload.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogRecord {
    /// Where the log holds it (what a database record's key chunks name).
    pub at: u32,
    /// Its payload (a [`Record`] and its tail).
    pub payload: Vec<u8>,
}

/// A database frame as the device's log keeps it.
#[derive(Debug, Clone, PartialEq)]
pub struct LoggedFrame {
    /// Index (global over the sessions), timestamp and pose.
    pub meta: FrameMeta,
    /// Voxels in its set.
    pub voxels: u32,
    /// Box of its voxel set (`None`: empty).
    pub aabb: Option<Aabb>,
    /// Its sketch's hashes, as stored.
    pub sketch: Vec<u32>,
    /// Its exact keys, ascending, when the log kept them.
    pub keys: Option<Vec<u64>>,
    /// Their share of the key budget: the encoded bytes of its key chunks
    /// (what the device counts when it restores the frame).
    pub key_bytes: u32,
}

/// A finished scan as the device's log holds it.
#[derive(Debug, Clone, PartialEq)]
pub struct LoggedScan {
    /// The Hello of its first session (a later session may have used
    /// another camera; every other setting is this one's).
    pub config: Config,
    /// The first frame of each session (`[0]` for one session).
    pub sessions: Vec<u32>,
    /// The final decision of every frame, with its timestamp, by index.
    pub decisions: Vec<(f64, DecisionKind)>,
    /// The database frames, in frame order.
    pub database: Vec<LoggedFrame>,
    /// Where a host resumed the scan after a restart of the device (the
    /// frames it had seen), in order (the log's `Resumed` records).
    pub resumes: Vec<u32>,
}

/// Reads the `records` records of the device's log, each in chunks;
/// `progress` (when given) counts them.
pub fn read_log<L: Link>(
    client: &mut Client<L>,
    records: u32,
    wait: Wait,
    progress: Option<&indicatif::ProgressBar>,
) -> Result<Vec<LogRecord>, DeviceError> {
    let mut out = Vec::with_capacity(records as usize);
    if let Some(p) = progress {
        p.set_length(u64::from(records));
        p.set_position(0);
    }
    for record in 0..records {
        if let Some(p) = progress {
            p.set_position(u64::from(record));
        }
        let mut payload = Vec::new();
        let mut at = None;
        loop {
            let offset = payload.len() as u32;
            let what = format!("LogRead of record {record} from byte {offset}");
            let (replies, _) =
                send_and_wait(client, HostMessage::LogRead { record, offset }, &what, wait)?;
            let chunk = match replies.last() {
                Some(Received::Message(DeviceMessage::LogBytes(c)))
                    if c.record == record && c.offset == offset =>
                {
                    *c
                }
                other => {
                    return Err(DeviceError::Protocol(format!(
                        "{what}: unexpected reply {other:?}"
                    )))
                }
            };
            if at.is_some_and(|a| a != chunk.at) || chunk.total as usize > payload.len() + 65536 {
                return Err(DeviceError::Protocol(format!(
                    "{what}: the record changed while it was read"
                )));
            }
            at = Some(chunk.at);
            payload.extend_from_slice(chunk.bytes());
            if payload.len() >= chunk.total as usize || chunk.bytes().is_empty() {
                if payload.len() != chunk.total as usize {
                    return Err(DeviceError::Protocol(format!(
                        "{what}: {} bytes of a record of {}",
                        payload.len(),
                        chunk.total
                    )));
                }
                break;
            }
        }
        out.push(LogRecord {
            at: at.unwrap_or(0),
            payload,
        });
    }
    if let Some(p) = progress {
        p.set_position(u64::from(records));
    }
    Ok(out)
}

/// A key chunk record: whose, its keys relative to the frame's box, and
/// its encoded bytes.
struct KeyChunk {
    frame: u32,
    words: Vec<u32>,
    bytes: u32,
}

/// The configuration of the device's scan as its first `records` log
/// records give it: the `Begin` record that opens the log, with the camera
/// of the latest session among them that brought another (a later session
/// may, [`placedb::protocol::Config::same_scan`]). One record gives the
/// scan's settings; all of them (`Status::stored_records`) the
/// configuration in force, camera included. `None` when the log holds no
/// scan, it was reset, or the device keeps no log.
pub fn scan_config<L: Link>(
    client: &mut Client<L>,
    wait: Wait,
    records: u32,
) -> Result<Option<Config>, DeviceError> {
    let records = read_log(client, records.max(1), wait, None)?;
    let mut config = match records.first().map(|r| Record::decode(&r.payload)) {
        Some(Ok((Record::Begin(cfg), _))) => cfg,
        _ => return Ok(None),
    };
    for r in &records[1..] {
        if let Ok((
            Record::SessionCamera {
                depth_scale,
                intrinsics,
                ..
            },
            _,
        )) = Record::decode(&r.payload)
        {
            config = Config {
                depth_scale,
                intrinsics,
                ..config
            };
        }
    }
    Ok(Some(config))
}

/// The finished scan `records` make (the records of one log generation,
/// in order): a database frame's latest record counts (a scan resumed
/// after a power cut writes a frame taken again anew), and the database is
/// the frames decided `Taken`.
pub fn scan_of(records: &[LogRecord]) -> Result<LoggedScan, DeviceError> {
    let bad = |n: usize, what: &str| {
        Err(DeviceError::Protocol(format!(
            "the device's log, record {n}: {what}"
        )))
    };
    let mut config = None;
    let mut sessions = Vec::new();
    let mut decisions: Vec<(f64, DecisionKind)> = Vec::new();
    let mut chunks: BTreeMap<u32, KeyChunk> = BTreeMap::new();
    let mut latest: BTreeMap<u32, LoggedFrame> = BTreeMap::new();
    let mut finished = false;
    let mut resumes = Vec::new();
    for (n, r) in records.iter().enumerate() {
        let Ok((record, tail)) = Record::decode(&r.payload) else {
            return bad(n, "not a record of this format");
        };
        match record {
            Record::Begin(cfg) if n == 0 => {
                config = Some(cfg);
                sessions.push(0);
            }
            Record::Cleared if n == 0 => {
                return Err(DeviceError::Input(
                    "the device holds no scan (it was reset)".into(),
                ))
            }
            Record::Keys { frame, .. } => {
                let chunk = KeyChunk {
                    frame,
                    words: tail.key_words().collect(),
                    bytes: tail.len() as u32,
                };
                chunks.insert(r.at, chunk);
            }
            Record::Database {
                meta,
                voxels,
                aabb,
                keys,
                ..
            } => {
                let mut words = Vec::new();
                let mut key_bytes = 0u32;
                for at in keys.positions() {
                    match chunks.get(at) {
                        Some(c) if c.frame == meta.index => {
                            words.extend_from_slice(&c.words);
                            key_bytes += c.bytes;
                        }
                        _ => return bad(n, "a database frame names key chunks the log lacks"),
                    }
                }
                let keys = match (keys.count > 0, aabb) {
                    (false, _) => None,
                    (true, Some(b)) => Some(words.iter().map(|&w| key_of(b.min, w)).collect()),
                    (true, None) => return bad(n, "keys of an empty frame"),
                };
                let frame = LoggedFrame {
                    meta,
                    voxels,
                    aabb,
                    sketch: tail.hashes().collect(),
                    keys,
                    key_bytes,
                };
                latest.insert(meta.index, frame);
            }
            Record::Decisions { first, .. } | Record::Labels { first, .. } => {
                if first as usize != decisions.len() {
                    return bad(n, "decisions out of order");
                }
                decisions.extend(tail.decisions(&record).map(|(t, kind, _)| (t, kind)));
            }
            Record::Session { first } | Record::SessionCamera { first, .. }
                if finished && first as usize == decisions.len() =>
            {
                sessions.push(first);
                finished = false;
            }
            Record::Resumed { at } if !finished => resumes.push(at),
            Record::Finished if !finished => finished = true,
            _ => return bad(n, "a record out of place"),
        }
    }
    let Some(config) = config else {
        return Err(DeviceError::Input("the device holds no scan".into()));
    };
    if !finished {
        return Err(DeviceError::Input(
            "the device's scan is not finished: finish it (placedb stream --resume) first".into(),
        ));
    }
    let mut database = Vec::new();
    for (i, (_, kind)) in decisions.iter().enumerate() {
        if *kind == DecisionKind::Taken {
            match latest.remove(&(i as u32)) {
                Some(frame) => database.push(frame),
                None => {
                    return Err(DeviceError::Protocol(format!(
                        "the device's log: frame {i} was taken but has no database record"
                    )))
                }
            }
        }
    }
    Ok(LoggedScan {
        config,
        sessions,
        decisions,
        database,
        resumes,
    })
}

impl LoggedScan {
    /// The session of global frame `index` and its index in that session.
    pub fn session_of(&self, index: u32) -> (u32, u32) {
        session_of(&self.sessions, index)
    }

    /// The extension file of this scan, selected online by a device of
    /// capacity profile `profile`: every frame's decision, every database
    /// frame as the log keeps it (the keys of a frame it kept only by
    /// sketch are unknown: `keys` is `None`).
    pub fn extension(&self, profile: &str) -> Extension {
        let c = &self.config;
        let origin = if c.grid_origin == [0.0; 3] {
            "world"
        } else {
            "scene-min"
        };
        let config = RunConfig {
            voxel: c.voxel_size,
            grid_corner: c.grid_origin,
            grid_origin: origin.to_string(),
            stride: c.stride,
            depth_range: [c.depth_range.min, c.depth_range.max],
            mu: c.mu,
            solver: "online".to_string(),
            online: Some(OnlineConfig {
                profile: profile.to_string(),
                window: c.window,
                sketch_margin: c.sketch_margin,
            }),
        };
        let total = self.decisions.len() as u32;
        let ends = self.sessions.iter().skip(1).copied().chain([total]);
        let sessions = self.sessions.iter().zip(ends).map(|(a, b)| b - a).collect();
        let frames = self
            .decisions
            .iter()
            .zip(0u32..)
            .map(|(&(timestamp, kind), i)| FrameEntry {
                timestamp,
                session: self.session_of(i).0,
                fate: match kind {
                    DecisionKind::Taken | DecisionKind::Pending => Fate::Taken,
                    DecisionKind::DominatedBy(k) => Fate::Covered(k),
                    DecisionKind::Uncovered(k) => Fate::Uncovered(k),
                },
                measured: None,
            })
            .collect();
        let database = self
            .database
            .iter()
            .map(|f| {
                let (t, q) = (f.meta.pose.translation, f.meta.pose.rotation);
                DbFrame {
                    index: f.meta.index,
                    session: self.session_of(f.meta.index).0,
                    timestamp: f.meta.timestamp,
                    pose: [t[0], t[1], t[2], q[0], q[1], q[2], q[3]].map(f64::from),
                    voxels: f.voxels,
                    aabb: f.aabb,
                    sketch: Some(f.sketch.clone()),
                    keyed: f.keys.is_some(),
                    key_bytes: f.key_bytes,
                    keys: f.keys.clone(),
                    eval_keys: None,
                }
            })
            .collect();
        Extension {
            config,
            sessions,
            frames,
            database,
            all_voxels: None,
        }
    }
}

/// The session of global frame `index` among sessions beginning at
/// `firsts` (ascending, the first 0), and its index in that session.
pub fn session_of(firsts: &[u32], index: u32) -> (u32, u32) {
    let s = firsts.partition_point(|&f| f <= index).saturating_sub(1);
    let first = firsts.get(s).copied().unwrap_or(0);
    (s as u32, index.saturating_sub(first))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::link::LocalLink;
    use crate::board::scan::{device_config, scan_config, stream, StreamOptions};
    use crate::testing::{demo, selector, voxel_config};
    use std::time::Duration;

    #[test]
    fn the_logged_scan_is_the_exported_one() {
        let seq = demo(30);
        let scan = scan_config(&seq, &voxel_config(8)).unwrap();
        let cfg = device_config(&scan, &selector(6)).unwrap();
        let mut client = Client::new(LocalLink::start("ram256k").unwrap());
        let opts = StreamOptions::default();
        let report = stream(&mut client, &seq, &cfg, "ram256k", &opts, None).unwrap();
        let wait = Wait::Once(Duration::from_secs(10));
        let bar = indicatif::ProgressBar::hidden();
        let log = read_log(&mut client, report.status.stored_records, wait, Some(&bar)).unwrap();
        // The read is counted record by record (export's "flash log" phase).
        let n = u64::from(report.status.stored_records);
        assert_eq!((bar.length(), bar.position()), (Some(n), n));
        let got = scan_of(&log).unwrap();
        assert_eq!(got.config, cfg);
        assert_eq!(got.sessions, vec![0]);
        let kinds: Vec<_> = got.decisions.iter().map(|(_, k)| Some(*k)).collect();
        assert_eq!(kinds, report.decisions);
        assert_eq!(got.database.len() as u32, report.status.database_size);
        assert!(got
            .database
            .iter()
            .all(|f| f.keys.is_some() && f.key_bytes > 0));
        assert!(got.database.iter().all(|f| f.sketch.len() == 64));
        // Cut short: not a finished scan.
        assert!(scan_of(&log[..log.len() - 1]).is_err());
        let ext = got.extension("ram256k");
        assert_eq!(ext.contradiction(), None);
        assert_eq!(ext.sessions, vec![30]);
        assert_eq!(session_of(&[0, 30, 45], 29), (0, 29));
        assert_eq!(session_of(&[0, 30, 45], 30), (1, 0));
        assert_eq!(session_of(&[0, 30, 45], 50), (2, 5));
    }
}
