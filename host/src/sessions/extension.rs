//! The extension file, `extension.bin`: what a later session needs to
//! extend a database directory (`placedb select SEQ_B --extend OUT_A`)
//! without the earlier sequences on disk. Every database directory that
//! `select` writes (and that `export` writes) carries one.
//!
//! It holds the run's configuration that an extension must match, the
//! frames of every session so far (global indices: a session's frames are
//! numbered from the count of all earlier sessions' frames), the decision
//! of every frame, and for each database frame what both kinds of solver
//! need: its voxel set (the core's packed keys) for the offline solvers,
//! and what the online core's store keeps of it (box, sketch, whether its
//! exact keys were kept) so that a restored selector continues exactly as a
//! device that kept the same database in flash.
//!
//! On disk (docs/FORMATS.md): the magic `PLACEDBX`, the format version (u32
//! little-endian), the payload length (u64 little-endian), the payload
//! ([`Extension`] in postcard), and the CRC-32 (IEEE) of everything before
//! it (u32 little-endian). [`read`] refuses, in words naming the file, a
//! truncated file, another magic, a newer version, a damaged CRC and a
//! payload whose parts contradict each other.

use crate::error::OutputError;
use placedb::key_pool::Aabb;
use serde::{Deserialize, Serialize};
use std::io;
use std::path::{Path, PathBuf};

/// The file's name in a database directory.
pub const FILE_NAME: &str = "extension.bin";

/// The first bytes of every extension file.
pub const MAGIC: [u8; 8] = *b"PLACEDBX";

/// The format version this build writes and the newest it reads.
pub const FORMAT_VERSION: u32 = 1;

/// Magic, version and payload length.
const HEADER: usize = 8 + 4 + 8;

/// Everything an extension needs of the sessions so far.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Extension {
    /// The configuration every session of this database was run with.
    pub config: RunConfig,
    /// Frames of each session, in session order (session 0 first).
    pub sessions: Vec<u32>,
    /// Every frame of every session, by global frame index.
    pub frames: Vec<FrameEntry>,
    /// The database frames, by ascending global frame index.
    pub database: Vec<DbFrame>,
    /// The distinct voxels (stride 1) of every frame of every session,
    /// ascending, when the run knew them (`select`; a device does not):
    /// the denominator of `spatial_coverage` over all sessions.
    pub all_voxels: Option<Vec<u64>>,
}

/// What must match between the sessions of one database.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunConfig {
    /// Voxel edge, metres.
    pub voxel: f32,
    /// The grid's corner in world coordinates, metres (voxel (0, 0, 0)
    /// starts here): a later session voxelizes on this very grid.
    pub grid_corner: [f32; 3],
    /// How the first session chose the corner: `world` or `scene-min`.
    pub grid_origin: String,
    /// Pixel stride in u and v.
    pub stride: u16,
    /// Valid depths, metres (`max` may be infinite).
    pub depth_range: [f32; 2],
    /// IoU threshold: frames overlap when IoU > mu.
    pub mu: f32,
    /// The solver of the latest session (`online`, `in-order`, ...).
    pub solver: String,
    /// The online core's settings, when the latest session was `online`.
    pub online: Option<OnlineConfig>,
}

/// The online core's settings that a continued scan must keep.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OnlineConfig {
    /// Capacity profile (`ram256k`, `ram512k`, `ram1m`).
    pub profile: String,
    /// Window length.
    pub window: u16,
    /// Extra IoU a sketch estimate needs.
    pub sketch_margin: f32,
}

/// One frame of some session.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrameEntry {
    /// Seconds, as in `labels.csv`.
    pub timestamp: f64,
    /// Its session (0, 1, 2, ...).
    pub session: u32,
    /// What its session decided.
    pub fate: Fate,
    /// How well the database covered it when its session's run measured
    /// it (`select`; a device does not): later sessions can only improve it.
    pub measured: Option<Measured>,
}

/// A frame's coverage by the database, on exact (stride 1) voxel sets.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Measured {
    /// Frame coverage: best `|d_f ∩ d_b| / |d_f|` over the database frames
    /// `b` (1 for a database frame).
    pub coverage: f32,
    /// Some database frame overlaps it (IoU > mu), or it is one.
    pub covered: bool,
}

/// The decision about one frame, as the online core's `Decision` (a frame
/// index names a database frame, its class).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Fate {
    /// In the database.
    Taken,
    /// Overlaps this database frame (IoU > mu).
    Covered(u32),
    /// Overlaps no database frame: labelled with the nearest one, if any
    /// (the online core with a full database; `every-nth` and the other
    /// baselines).
    Uncovered(Option<u32>),
}

impl Fate {
    /// The class frame of frame `index`.
    pub fn class(self, index: u32) -> u32 {
        match self {
            Fate::Taken | Fate::Uncovered(None) => index,
            Fate::Covered(k) | Fate::Uncovered(Some(k)) => k,
        }
    }
}

/// One database frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DbFrame {
    /// Global frame index.
    pub index: u32,
    /// Its session.
    pub session: u32,
    /// Seconds.
    pub timestamp: f64,
    /// Camera to world `[tx ty tz qx qy qz qw]`, as in `database.csv`.
    pub pose: [f64; 7],
    /// Voxels in its set, as the solver counted them (the online core's
    /// count of a set it truncated is the truncated one).
    pub voxels: u32,
    /// Box of its voxel set (`None`: empty).
    pub aabb: Option<Aabb>,
    /// Its bottom-k sketch (ascending hashes) as the online core kept it;
    /// `None` when the run had no online core (computed from `keys` with
    /// the profile's size when an online extension needs it).
    pub sketch: Option<Vec<u32>>,
    /// The online store kept its exact keys (they are `keys`).
    pub keyed: bool,
    /// Bytes of the key budget its stored keys took (0 when not `keyed`).
    pub key_bytes: u32,
    /// Its voxel set at the run's stride, ascending packed keys; `None`
    /// when unknown (a device keeps only the keys of keyed frames).
    pub keys: Option<Vec<u64>>,
    /// Its voxel set at stride 1 when the run's stride is not 1 (for the
    /// metrics); `None` otherwise or when unknown.
    pub eval_keys: Option<Vec<u64>>,
}

impl Extension {
    /// The global index of the next session's first frame.
    pub fn next_index(&self) -> u32 {
        self.frames.len() as u32
    }

    /// The session of global frame `index` and its index within that
    /// session; `None` past the last frame.
    pub fn session_of(&self, index: u32) -> Option<(u32, u32)> {
        let mut first = 0u32;
        for (s, &n) in self.sessions.iter().enumerate() {
            if index < first.saturating_add(n) {
                return Some((s as u32, index - first));
            }
            first = first.saturating_add(n);
        }
        None
    }

    /// The global index of session `session`'s first frame.
    pub fn first_index_of(&self, session: u32) -> u32 {
        self.sessions.iter().take(session as usize).sum()
    }

    /// The database frame with global index `index`.
    pub fn db_frame(&self, index: u32) -> Option<&DbFrame> {
        let i = self
            .database
            .binary_search_by_key(&index, |f| f.index)
            .ok()?;
        self.database.get(i)
    }

    /// The first contradiction between the parts, in words; `None` when
    /// they agree. [`read`] refuses a file with one.
    pub fn contradiction(&self) -> Option<String> {
        let total: u64 = self.sessions.iter().map(|&n| u64::from(n)).sum();
        if self.sessions.is_empty() {
            return Some("it lists no session".into());
        }
        if total != self.frames.len() as u64 {
            return Some(format!(
                "its sessions hold {total} frames but it lists {}",
                self.frames.len()
            ));
        }
        for (i, f) in self.frames.iter().enumerate() {
            let i = i as u32;
            if self.session_of(i).map(|(s, _)| s) != Some(f.session) {
                return Some(format!("frame {i} names session {}", f.session));
            }
            let named = match f.fate {
                Fate::Taken => Some(i),
                Fate::Covered(k) | Fate::Uncovered(Some(k)) => Some(k),
                Fate::Uncovered(None) => None,
            };
            if let Some(k) = named.filter(|&k| self.db_frame(k).is_none()) {
                return Some(format!(
                    "frame {i} is labelled with frame {k}, which is not a database frame"
                ));
            }
        }
        let mut last = None;
        for d in &self.database {
            if last.is_some_and(|l| d.index <= l) {
                return Some(format!(
                    "database frame {} is out of order or repeated",
                    d.index
                ));
            }
            last = Some(d.index);
            let Some(f) = self.frames.get(d.index as usize) else {
                return Some(format!("database frame {} is past its last frame", d.index));
            };
            if f.fate != Fate::Taken || f.session != d.session {
                return Some(format!(
                    "database frame {} is not taken by its session",
                    d.index
                ));
            }
            if d.keyed && d.keys.is_none() {
                return Some(format!(
                    "database frame {} is marked keyed but has no keys",
                    d.index
                ));
            }
            let ascending = |s: &[u64]| s.windows(2).all(|w| w[0] < w[1]);
            let sets = [&d.keys, &d.eval_keys];
            if sets
                .iter()
                .any(|s| s.as_deref().is_some_and(|s| !ascending(s)))
            {
                return Some(format!(
                    "the voxel set of database frame {} is not ascending",
                    d.index
                ));
            }
            if d.sketch
                .as_deref()
                .is_some_and(|s| !s.windows(2).all(|w| w[0] < w[1]))
            {
                return Some(format!(
                    "the sketch of database frame {} is not ascending",
                    d.index
                ));
            }
        }
        None
    }
}

/// Why an extension file could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ExtensionError {
    /// The file could not be opened or read.
    #[error("{}: cannot read the extension file: {}", path.display(), crate::error::io_words(source))]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: io::Error,
    },
    /// The file ends early.
    #[error("{}: the extension file is truncated ({len} bytes, {want} expected)", path.display())]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Its length.
        len: usize,
        /// The length its header promises (at least the header's).
        want: usize,
    },
    /// Not an extension file.
    #[error("{}: not a placedb extension file (wrong magic)", path.display())]
    WrongMagic {
        /// The file.
        path: PathBuf,
    },
    /// Written by a newer placedb.
    #[error("{}: extension file format version {found} is newer than this placedb reads (up to {FORMAT_VERSION}); update placedb", path.display())]
    NewerVersion {
        /// The file.
        path: PathBuf,
        /// Its version.
        found: u32,
    },
    /// The CRC does not match: the file is damaged.
    #[error("{}: the extension file is damaged (CRC mismatch)", path.display())]
    Crc {
        /// The file.
        path: PathBuf,
    },
    /// The content does not decode, or contradicts itself.
    #[error("{}: the extension file is malformed: {what}", path.display())]
    Malformed {
        /// The file.
        path: PathBuf,
        /// What is wrong, in words.
        what: String,
    },
}

/// The bytes of the file holding `ext`.
pub fn encode(ext: &Extension) -> io::Result<Vec<u8>> {
    let payload = postcard::to_allocvec(ext).map_err(io::Error::other)?;
    let mut out = Vec::with_capacity(HEADER + payload.len() + 4);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&payload);
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    Ok(out)
}

/// The extension in `bytes`, read from `path` (named in every error).
pub fn decode(bytes: &[u8], path: &Path) -> Result<Extension, ExtensionError> {
    let path = || path.to_path_buf();
    let truncated = |want: usize| ExtensionError::Truncated {
        path: path(),
        len: bytes.len(),
        want,
    };
    let magic_part = bytes.len().min(MAGIC.len());
    if bytes.get(..magic_part) != MAGIC.get(..magic_part) {
        return Err(ExtensionError::WrongMagic { path: path() });
    }
    let (Some(version), Some(len)) = (bytes.get(8..12), bytes.get(12..HEADER)) else {
        return Err(truncated(HEADER + 4));
    };
    let version = u32::from_le_bytes(version.try_into().unwrap_or_default());
    if version > FORMAT_VERSION {
        return Err(ExtensionError::NewerVersion {
            path: path(),
            found: version,
        });
    }
    let len = u64::from_le_bytes(len.try_into().unwrap_or_default());
    let want = usize::try_from(len)
        .ok()
        .and_then(|l| l.checked_add(HEADER + 4))
        .unwrap_or(usize::MAX);
    if bytes.len() < want {
        return Err(truncated(want));
    }
    let malformed = |what: String| ExtensionError::Malformed { path: path(), what };
    if bytes.len() > want {
        return Err(malformed(format!(
            "{} bytes after its end",
            bytes.len() - want
        )));
    }
    let (body, crc) = bytes.split_at(want - 4);
    if crc32fast::hash(body).to_le_bytes() != crc {
        return Err(ExtensionError::Crc { path: path() });
    }
    if version == 0 {
        return Err(malformed("format version 0 does not exist".into()));
    }
    let payload = body.get(HEADER..).unwrap_or_default();
    let ext: Extension = match postcard::take_from_bytes(payload) {
        Ok((ext, [])) => ext,
        Ok((_, rest)) => return Err(malformed(format!("{} bytes after its content", rest.len()))),
        Err(_) => return Err(malformed("its content does not decode".into())),
    };
    match ext.contradiction() {
        Some(what) => Err(malformed(what)),
        None => Ok(ext),
    }
}

/// Writes `ext` to `path` (a file inside a staged output), naming it in an
/// error.
pub fn write(path: &Path, ext: &Extension) -> Result<(), OutputError> {
    encode(ext)
        .and_then(|bytes| std::fs::write(path, bytes))
        .map_err(OutputError::writing(path))
}

/// Reads the extension file at `path` (see [`decode`]).
pub fn read(path: &Path) -> Result<Extension, ExtensionError> {
    let bytes = std::fs::read(path).map_err(|source| ExtensionError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    decode(&bytes, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Extension {
        let frame = |session, fate| FrameEntry {
            timestamp: 1.5,
            session,
            fate,
            measured: Some(Measured {
                coverage: 0.5,
                covered: true,
            }),
        };
        Extension {
            config: RunConfig {
                voxel: 0.3,
                grid_corner: [0.0; 3],
                grid_origin: "world".into(),
                stride: 1,
                depth_range: [0.1, 10.0],
                mu: 0.3,
                solver: "online".into(),
                online: Some(OnlineConfig {
                    profile: "ram512k".into(),
                    window: 32,
                    sketch_margin: 0.05,
                }),
            },
            sessions: vec![2, 1],
            frames: vec![
                frame(0, Fate::Taken),
                frame(0, Fate::Covered(0)),
                frame(1, Fate::Uncovered(Some(0))),
            ],
            database: vec![DbFrame {
                index: 0,
                session: 0,
                timestamp: 1.5,
                pose: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
                voxels: 3,
                aabb: None,
                sketch: Some(vec![1, 5, 9]),
                keyed: true,
                key_bytes: 7,
                keys: Some(vec![1, 2, 3]),
                eval_keys: None,
            }],
            all_voxels: Some(vec![1, 2, 3, 4]),
        }
    }

    fn message(bytes: &[u8]) -> String {
        decode(bytes, Path::new("OUT/extension.bin"))
            .expect_err("refused")
            .to_string()
    }

    #[test]
    fn round_trip_and_numbering() {
        let ext = sample();
        let bytes = encode(&ext).unwrap();
        assert_eq!(decode(&bytes, Path::new("x")).unwrap(), ext);
        assert_eq!(ext.next_index(), 3);
        assert_eq!(ext.session_of(1), Some((0, 1)));
        assert_eq!(ext.session_of(2), Some((1, 0)));
        assert_eq!(ext.session_of(3), None);
        assert_eq!(ext.first_index_of(1), 2);
    }

    #[test]
    fn every_damage_is_refused_in_words_naming_the_file() {
        let bytes = encode(&sample()).unwrap();
        for cut in [0, 3, 8, 19, bytes.len() - 1] {
            let m = message(&bytes[..cut]);
            assert!(m.starts_with("OUT/extension.bin: "), "{m}");
            assert!(m.contains("truncated"), "{cut}: {m}");
        }
        let mut other = bytes.clone();
        other[0] = b'Q';
        assert!(message(&other).contains("wrong magic"));
        let mut newer = bytes.clone();
        newer[8] = 2;
        assert!(message(&newer).contains("version 2 is newer"));
        let mut flipped = bytes.clone();
        let mid = HEADER + 5;
        flipped[mid] ^= 1;
        assert!(message(&flipped).contains("CRC mismatch"));
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(message(&longer).contains("1 bytes after its end"));
    }

    #[test]
    fn contradictions_are_refused() {
        let mut ext = sample();
        ext.frames[1].fate = Fate::Covered(1);
        let m = message(&encode(&ext).unwrap());
        assert!(m.contains("frame 1 is labelled with frame 1"), "{m}");
        let mut ext = sample();
        ext.sessions = vec![3];
        let m = message(&encode(&ext).unwrap());
        assert!(m.contains("frame 2 names session 1"), "{m}");
        let mut ext = sample();
        ext.database[0].keys = None;
        let m = message(&encode(&ext).unwrap());
        assert!(m.contains("keyed but has no keys"), "{m}");
    }
}
