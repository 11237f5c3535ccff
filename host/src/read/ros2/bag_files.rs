//! The files of a recording: which paths are recordings, what a ROS 2 bag
//! folder's `metadata.yaml` says, and the files a reading reads, with
//! rosbag2's own compression (`ros2 bag record --compression-mode file` or
//! `message`, zstd) undone: a file compressed whole (`*.db3.zstd`) is
//! decompressed into a temporary folder that lives as long as the reading
//! (an sqlite3 database is read in place, and rosbag2 itself does the
//! same), a compressed message (its first bytes a zstd frame's) as it is
//! read. Both are told by the files themselves, so a file given alone,
//! without its `metadata.yaml`, reads as well.

use super::bag::{self, Location};
use crate::error::ReadError;
use crate::read::text;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// The file name endings of the storages read, MCAP and sqlite3, as
/// recorded and as rosbag2's file compression leaves them.
const BAG_FILE_ENDINGS: [&str; 4] = [".mcap", ".db3", ".mcap.zstd", ".db3.zstd"];

/// The ending rosbag2's file compression gives a bag file.
const ZSTD_FILE: &str = ".zstd";

fn is_bag_file(name: &str) -> bool {
    BAG_FILE_ENDINGS.iter().any(|e| name.ends_with(e))
}

/// Whether `path` is a ROS 2 recording: a `.mcap` or `.db3` file (or one
/// rosbag2 compressed, `.db3.zstd`), or a directory with `metadata.yaml`
/// or such a file.
pub fn looks_like_bag(path: &Path) -> bool {
    if path.is_file() {
        return path
            .file_name()
            .is_some_and(|n| is_bag_file(&n.to_string_lossy()));
    }
    path.join("metadata.yaml").is_file()
        || text::list_dir(path).is_ok_and(|names| names.iter().any(|n| is_bag_file(n)))
}

/// Whether `path` is a ROS 1 bag: a `.bag` file (its first bytes are
/// checked when it is read).
pub fn looks_like_ros1_bag(path: &Path) -> bool {
    path.is_file() && path.extension().is_some_and(|e| e == "bag")
}

/// What the reader needs of a bag folder's `metadata.yaml` (rosbag2 writes
/// more: topics, counts, times, which are in the bag files too).
#[derive(Debug, Default, serde::Deserialize)]
struct Metadata {
    #[serde(default)]
    rosbag2_bagfile_information: BagInfo,
}

/// The `rosbag2_bagfile_information` mapping. A key can be absent or empty
/// (`compression_mode:`), and rosbag2's writers leave `''` or `""` for
/// "none": all three mean not set.
#[derive(Debug, Default, serde::Deserialize)]
#[serde(default)]
struct BagInfo {
    storage_identifier: Option<String>,
    compression_mode: Option<String>,
    compression_format: Option<String>,
    relative_file_paths: Option<Vec<String>>,
}

/// A set value: `None` for an absent, empty (null) or `''` one.
fn set(value: &Option<String>) -> Option<&str> {
    value.as_deref().map(str::trim).filter(|v| !v.is_empty())
}

/// Parses a bag folder's `metadata.yaml` (`path`, holding `yaml`), refuses
/// what the reader cannot read (another storage than MCAP or sqlite3, a
/// compression other than rosbag2's zstd, file by file or message by
/// message) and returns the bag's files as it lists them (none when it
/// lists none).
pub fn check_metadata(path: &Path, yaml: &str) -> Result<Vec<String>, ReadError> {
    let meta: Metadata = serde_saphyr::from_str(yaml)
        .map_err(|e| text::layout(path, format!("not a readable rosbag2 metadata.yaml: {e}")))?;
    let info = &meta.rosbag2_bagfile_information;
    if let Some(storage) =
        set(&info.storage_identifier).filter(|s| !["mcap", "sqlite3"].contains(s))
    {
        return Err(text::layout(
            path,
            format!(
                "storage `{storage}` is not supported, only mcap and sqlite3 \
                 (convert with `ros2 bag convert`)"
            ),
        ));
    }
    // How it was compressed needs no saying here: a file compressed whole
    // ends `.zstd`, a compressed message begins as a zstd frame.
    let mode = set(&info.compression_mode).map(str::to_ascii_lowercase);
    match mode.as_deref() {
        None | Some("none") => {}
        Some("file" | "message") => {
            let format = set(&info.compression_format).unwrap_or("unnamed");
            if !format.eq_ignore_ascii_case("zstd") {
                return Err(text::layout(
                    path,
                    format!(
                        "compression format `{format}` is not read, only zstd (rosbag2's \
                         own; convert the bag to an uncompressed one with `ros2 bag convert`)"
                    ),
                ));
            }
        }
        Some(_) => {
            return Err(text::layout(
                path,
                format!(
                    "compression mode `{}` is not one rosbag2 writes (file or message)",
                    set(&info.compression_mode).unwrap_or_default()
                ),
            ))
        }
    }
    Ok(info.relative_file_paths.clone().unwrap_or_default())
}

/// The files of a recording as a reading reads them: the bag's own, or,
/// when rosbag2 compressed them whole, copies decompressed into a
/// temporary folder that lives as long as the reading.
pub struct BagFiles {
    /// The files read, in the bag's order.
    read: Vec<PathBuf>,
    /// The same files as the recording names them, for messages.
    pub named: Vec<PathBuf>,
    /// File compression: the folder of the decompressed copies.
    _unpacked: Option<Unpacked>,
}

/// The folder a reading decompresses a bag's files into: removed when the
/// reading is dropped, or, if the run is stopped by a signal first, by the
/// command's watcher ([`crate::interrupt`]).
struct Unpacked(Option<tempfile::TempDir>);

impl Drop for Unpacked {
    fn drop(&mut self) {
        if let Some(dir) = self.0.take() {
            let path = dir.path().to_path_buf();
            drop(dir);
            crate::interrupt::forget(&mut crate::interrupt::live(), &path);
        }
    }
}

impl BagFiles {
    /// The bag files (MCAP, sqlite3 or a ROS 1 bag) of the recording at
    /// `path`: the file itself, the ones its `metadata.yaml` lists, in its
    /// order, else every one in the folder in name order; file-compressed
    /// ones decompressed.
    pub fn open(path: &Path) -> Result<BagFiles, ReadError> {
        let named = listed_files(path)?;
        let mut files = BagFiles {
            read: named.clone(),
            named,
            _unpacked: None,
        };
        if files
            .named
            .iter()
            .any(|f| f.to_string_lossy().ends_with(ZSTD_FILE))
        {
            files.unpack()?;
        }
        Ok(files)
    }

    /// How many files the recording has.
    pub fn len(&self) -> usize {
        self.read.len()
    }

    /// Whether it has none (never, once opened).
    pub fn is_empty(&self) -> bool {
        self.read.is_empty()
    }

    /// Decompresses each `*.zstd` file into a temporary folder (rosbag2
    /// compresses each file whole as it closes it; a file it had not
    /// closed, the last one of a recording cut short, is read as it is).
    fn unpack(&mut self) -> Result<(), ReadError> {
        let tmp = std::env::temp_dir();
        remove_abandoned(&tmp);
        let prefix = format!("{UNPACKED}{}-", std::process::id());
        let dir = crate::interrupt::register_made(
            || tempfile::Builder::new().prefix(&prefix).tempdir_in(&tmp),
            |dir| dir.path(),
        )
        .map_err(|e| {
            text::layout(
                &tmp,
                format!("cannot make a folder to decompress the bag's files in: {e}"),
            )
        })?;
        let folder = dir.path().to_path_buf();
        let unpacked = Unpacked(Some(dir));
        for (read, named) in self.read.iter_mut().zip(&self.named) {
            let name = named.file_name().map(|n| n.to_string_lossy().into_owned());
            let Some(plain) = name.as_deref().and_then(|n| n.strip_suffix(ZSTD_FILE)) else {
                continue;
            };
            let copy = folder.join(plain);
            decompress_file(named, &copy)?;
            *read = copy;
        }
        self._unpacked = Some(unpacked);
        Ok(())
    }

    /// A storage's refusal as a reading's error, naming the recording's own
    /// file rather than its decompressed copy.
    pub fn error(&self, (path, reason): bag::BagError) -> ReadError {
        let path = match self.read.iter().position(|r| *r == path) {
            Some(i) => self.named[i].clone(),
            None => path,
        };
        ReadError::Layout { path, reason }
    }

    /// Walks every message of file `i` ([`bag::scan`]), a message rosbag2
    /// compressed handed over decompressed: as much of it as `heads` asks
    /// (the whole message's length known from its zstd frame), else whole.
    pub fn scan(
        &self,
        i: usize,
        heads: bag::Heads<'_>,
        visit: &mut dyn FnMut(bag::Message<'_>) -> Result<(), bag::BagError>,
    ) -> Result<u64, ReadError> {
        let file = &self.read[i];
        let mut plain = Vec::new();
        bag::scan(i, file, heads, &mut |m| {
            // A channel the walk only counts is handed over as stored.
            if heads(m.channel) == Some(0) || !is_compressed(m.channel.encoding == "cdr", m.data) {
                return visit(m);
            }
            let refused = |e: String| {
                let t = m.log_time as f64 * 1e-9;
                bag::err(file, format!("{} at t={t:.6}: {e}", m.channel.topic))
            };
            // The compressed bytes whole (a head of them, an sqlite3
            // walk's, need not hold the first block).
            let fetched;
            let data = if m.data.len() < m.len {
                fetched = bag::fetch(file, m.at)?;
                &fetched[..]
            } else {
                m.data
            };
            // The frame's header says the whole length: then only the
            // head asked for is decompressed (from the first block or two).
            let stored = zstd::zstd_safe::get_frame_content_size(data)
                .ok()
                .flatten()
                .and_then(|n| usize::try_from(n).ok());
            let head = heads(m.channel).filter(|&h| stored.is_some_and(|n| h < n));
            decompress_message(data, head, &mut plain).map_err(refused)?;
            let len = match (head, stored) {
                (Some(_), Some(n)) => n,
                _ => plain.len(),
            };
            visit(bag::Message {
                data: &plain,
                len,
                ..m
            })
        })
        .map_err(|e| self.error(e))
    }

    /// The whole message at `at` in its file as read (a message of a
    /// channel whose messages are CDR, `cdr`, decompressed when rosbag2
    /// compressed it): what a walk reads when the head it was handed does
    /// not hold what it needs.
    pub fn whole(&self, at: Location, cdr: bool) -> Result<bag::MessageBytes, bag::BagError> {
        self.read_back(at, cdr, &bag::Kept::default())
    }

    /// Reads back the message at `at` ([`bag::fetch_kept`]) of a channel
    /// whose messages are CDR (`cdr`) or not, decompressed when rosbag2
    /// compressed it.
    pub fn fetch(
        &self,
        at: Location,
        cdr: bool,
        kept: &bag::Kept,
    ) -> Result<bag::MessageBytes, ReadError> {
        self.read_back(at, cdr, kept).map_err(|e| self.error(e))
    }

    /// [`BagFiles::fetch`] and [`BagFiles::whole`]: the message at `at`,
    /// `kept` what the reading keeps between messages.
    fn read_back(
        &self,
        at: Location,
        cdr: bool,
        kept: &bag::Kept,
    ) -> Result<bag::MessageBytes, bag::BagError> {
        let file = &self.read[at.file];
        let bytes = bag::fetch_kept(file, at, kept)?;
        if !is_compressed(cdr, &bytes) {
            return Ok(bytes);
        }
        let mut plain = Vec::new();
        decompress_message(&bytes, None, &mut plain)
            .map_err(|e| bag::err(file, format!("{}: {e}", at.place)))?;
        Ok(bag::MessageBytes::Own(plain))
    }
}

/// The first bytes of a zstd frame.
const ZSTD_MAGIC: [u8; 4] = [0x28, 0xb5, 0x2f, 0xfd];

/// Whether a message (`cdr`: of a CDR channel) is one rosbag2 compressed
/// (`--compression-mode message`): a CDR message begins with its
/// encapsulation, `00 00` or `00 01`, never with a zstd frame's magic, so
/// its first bytes say so with or without the bag's metadata.yaml (a ROS 1
/// message's first bytes are its own, and rosbag2 never wrote one).
fn is_compressed(cdr: bool, data: &[u8]) -> bool {
    cdr && data.starts_with(&ZSTD_MAGIC)
}

/// How the folders of decompressed bag files begin, before the id of the
/// process reading them.
const UNPACKED: &str = ".placedb-bag-";

/// Removes the folders of decompressed bag files that a reading killed
/// outright left (SIGKILL, a crash, a library host's own exit on a signal:
/// the command's watcher removes its own on SIGINT and SIGTERM): those in
/// `tmp` whose process no longer runs. Where that cannot be told (no
/// `/proc`), nothing is removed.
fn remove_abandoned(tmp: &Path) {
    let Ok(names) = text::list_dir(tmp) else {
        return;
    };
    for name in names {
        let pid = name
            .strip_prefix(UNPACKED)
            .and_then(|rest| rest.split_once('-'))
            .and_then(|(pid, _)| pid.parse::<u32>().ok());
        let gone = |pid: u32| {
            Path::new("/proc/self").exists() && !Path::new("/proc").join(pid.to_string()).exists()
        };
        if pid.is_some_and(|pid| pid != std::process::id() && gone(pid)) {
            let _ = std::fs::remove_dir_all(tmp.join(&name));
        }
    }
}

/// The most a zstd frame of `n` bytes can decompress to (no block gives
/// more than 128 KiB, and none takes less than 4 bytes): what a damaged or
/// hostile message may claim is bounded by what it holds.
fn zstd_most(n: usize) -> u64 {
    (n as u64)
        .saturating_mul(32 * 1024)
        .saturating_add(128 * 1024)
}

/// One message's zstd data (rosbag2's message compression) into `out`:
/// its first `head` bytes, or all of it.
fn decompress_message(data: &[u8], head: Option<usize>, out: &mut Vec<u8>) -> Result<(), String> {
    out.clear();
    let most = head.map_or(zstd_most(data.len()), |h| h as u64);
    // Room for what the frame says it holds, within what it can hold: one
    // allocation, not a doubling one.
    if let Ok(Some(n)) = zstd::zstd_safe::get_frame_content_size(data) {
        out.reserve(usize::try_from(n.min(most)).unwrap_or(0));
    }
    let decoder = zstd::stream::read::Decoder::with_buffer(data)
        .map_err(|e| format!("its zstd data does not decompress: {e}"))?;
    decoder
        .take(most)
        .read_to_end(out)
        .map_err(|e| format!("its zstd data does not decompress: {e}"))?;
    Ok(())
}

/// A file rosbag2 compressed whole (`named`) decompressed into `copy`; a
/// refusal says which side failed: the compressed file (cut short,
/// damaged) or the copy (no room where TMPDIR says).
fn decompress_file(named: &Path, copy: &Path) -> Result<(), ReadError> {
    let source = std::fs::File::open(named).map_err(|e| text::layout(named, e.to_string()))?;
    let most = source
        .metadata()
        .map_or(u64::MAX, |m| zstd_most(m.len() as usize));
    let refused =
        |e: std::io::Error| text::layout(named, format!("its zstd data does not decompress: {e}"));
    let mut decoder = zstd::stream::read::Decoder::new(source)
        .map_err(refused)?
        .take(most);
    let unwritable = |e: std::io::Error| {
        text::layout(
            named,
            format!(
                "cannot decompress it into {}: {e} (a bag rosbag2 compressed file by file is \
                 decompressed whole before it is read, into the folder TMPDIR names)",
                copy.display()
            ),
        )
    };
    let mut out = std::fs::File::create(copy)
        .map(std::io::BufWriter::new)
        .map_err(unwritable)?;
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = decoder.read(&mut buf).map_err(refused)?;
        if n == 0 {
            break;
        }
        out.write_all(&buf[..n]).map_err(unwritable)?;
    }
    out.flush().map_err(unwritable)
}

/// The recording's files as it names them.
fn listed_files(path: &Path) -> Result<Vec<PathBuf>, ReadError> {
    if path.is_file() {
        return Ok(vec![path.to_path_buf()]);
    }
    let meta = path.join("metadata.yaml");
    let listed = if meta.is_file() {
        check_metadata(&meta, &text::read_text(&meta)?)?
    } else {
        Vec::new()
    };
    if !listed.is_empty() {
        // A listed name is relative to the folder (early rosbag2 releases
        // put the folder's name in front: its last part is tried too); one
        // that is not there is named.
        return listed
            .iter()
            .map(|name| {
                let file = path.join(name);
                let base = Path::new(name).file_name().map(|b| path.join(b));
                if file.is_file() {
                    Ok(file)
                } else if let Some(base) = base.filter(|b| b.is_file()) {
                    Ok(base)
                } else {
                    Err(text::layout(
                        &meta,
                        format!("lists {name}, which is not in the bag folder"),
                    ))
                }
            })
            .collect();
    }
    let mut names: Vec<String> = text::list_dir(path)?
        .into_iter()
        .filter(|n| is_bag_file(n))
        .collect();
    names.sort();
    if names.is_empty() {
        return Err(text::layout(
            path,
            "no bag file (*.mcap or *.db3) in the bag folder",
        ));
    }
    Ok(names.into_iter().map(|n| path.join(n)).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_folders_of_readings_that_no_longer_run_are_removed() {
        let tmp = tempfile::tempdir().unwrap();
        let mine = format!("{UNPACKED}{}-a", std::process::id());
        // Above any pid Linux gives (pid_max is at most 2^22).
        let abandoned = format!("{UNPACKED}{}-b", u32::MAX);
        for name in [
            &mine,
            &abandoned,
            &format!("{UNPACKED}x-c"),
            &"other-1-d".to_string(),
        ] {
            std::fs::create_dir(tmp.path().join(name)).unwrap();
        }
        remove_abandoned(tmp.path());
        let mut left = text::list_dir(tmp.path()).unwrap();
        left.sort();
        let mut want = vec![format!("{UNPACKED}x-c"), mine, "other-1-d".to_string()];
        if !Path::new("/proc/self").exists() {
            want.push(abandoned);
        }
        want.sort();
        assert_eq!(left, want);
    }
}
