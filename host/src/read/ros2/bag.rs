//! The files of a bag, whatever their storage: what a message is and where
//! it lies, one walk over a file ([`scan`]) and one read of a message back
//! ([`fetch`]). MCAP files are read by [`super::mcap_storage`], sqlite3
//! files (`.db3`, ROS 2 Humble's default) by [`super::sqlite_storage`], ROS 1
//! bags (`.bag`, format 2.0) by [`super::ros1_storage`]; the file's own
//! first bytes say which.

use super::{kept_chunks, mcap_storage, ros1_storage, sqlite_storage};
use std::fmt;
use std::io::Read;
use std::ops::{Deref, Range};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Where a message is, to read it again.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Location {
    /// Index of the file in the bag.
    pub file: usize,
    /// Where in that file.
    pub place: Place,
}

/// A message's place in its file, by storage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Place {
    /// An MCAP message record, or the `in_chunk`-th message of a chunk
    /// record: the top-level record's body is `len` bytes at `offset`.
    Mcap {
        offset: u64,
        len: u64,
        in_chunk: Option<u32>,
    },
    /// A row of an sqlite3 file's `messages` table, by its `id`.
    Row(i64),
    /// A ROS 1 message record, or the message record at byte `in_chunk`
    /// of a chunk's decompressed data: the top-level record (header and
    /// data) is `len` bytes at `offset`. `walked` is the CRC-32 of the
    /// chunk's data as the walk read and verified it (0 outside a chunk, or
    /// for a chunk with no checksums to skip): reading those same bytes
    /// back skips the checksums the walk verified.
    Ros1 {
        offset: u64,
        len: u64,
        in_chunk: Option<u32>,
        walked: u32,
    },
}

impl fmt::Display for Place {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Place::Mcap { offset, .. } => write!(f, "byte {offset}"),
            Place::Row(id) => write!(f, "message row {id}"),
            Place::Ros1 {
                offset,
                in_chunk: None,
                ..
            } => write!(f, "byte {offset}"),
            Place::Ros1 {
                offset,
                in_chunk: Some(k),
                ..
            } => write!(f, "byte {k} of the chunk at byte {offset}"),
        }
    }
}

/// A channel: its topic, the schema's name and the message encoding.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Channel {
    /// `/camera/depth/image_rect_raw`.
    pub topic: String,
    /// `sensor_msgs/msg/Image` (a ROS 1 type by its ROS 2 name).
    pub schema: String,
    /// `cdr` for ROS 2, `ros1` for ROS 1.
    pub encoding: String,
}

/// One message handed to a visitor.
pub struct Message<'a> {
    /// Its channel.
    pub channel: &'a Channel,
    /// Log time, nanoseconds.
    pub log_time: u64,
    /// The serialized message, or its first bytes when the walk asked only
    /// for those ([`Heads`]) and the storage reads a message at a time
    /// (sqlite3): then shorter than [`Message::len`].
    pub data: &'a [u8],
    /// The whole message's length in bytes.
    pub len: usize,
    /// Where to find it again.
    pub at: Location,
}

/// How much of a channel's messages a walk needs: `None` all of each,
/// `Some(n)` its first `n` bytes (an image's fields, not its pixels; 0 for
/// a channel the walk only counts). A storage that reads a message at a
/// time (sqlite3: a row) reads only that much; one whose messages lie in
/// chunks it decompresses anyway (MCAP, ROS 1) hands over the whole message.
pub type Heads<'a> = &'a dyn Fn(&Channel) -> Option<usize>;

/// What went wrong, for [`super`] to turn into a `ReadError` naming the file.
pub type BagError = (PathBuf, String);

pub(super) fn err(path: &Path, reason: impl Into<String>) -> BagError {
    (path.to_path_buf(), reason.into())
}

/// The first bytes of an sqlite3 database file.
const SQLITE_MAGIC: &[u8; 16] = b"SQLite format 3\0";

/// How a bag file stores its messages.
enum Storage {
    Mcap,
    Sqlite,
    Ros1,
}

/// The storage the first bytes of the file at `path` name, if any.
fn by_magic(path: &Path) -> Result<Option<Storage>, BagError> {
    let mut head = [0u8; 16];
    let mut file = std::fs::File::open(path).map_err(|e| err(path, e.to_string()))?;
    let mut got = 0;
    while got < head.len() {
        match file.read(&mut head[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) => return Err(err(path, e.to_string())),
        }
    }
    Ok(if &head == SQLITE_MAGIC {
        Some(Storage::Sqlite)
    } else if head.starts_with(ros1_storage::MAGIC) {
        Some(Storage::Ros1)
    } else {
        None
    })
}

/// The storage of the file at `path`, by its first bytes; when they are
/// neither sqlite3's nor a ROS 1 bag's, by its name (`.db3`, `.bag`), else
/// MCAP: the reader of that storage then says in its words what the file
/// is not.
fn storage(path: &Path) -> Result<Storage, BagError> {
    if let Some(storage) = by_magic(path)? {
        return Ok(storage);
    }
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default();
    Ok(if name.ends_with(".db3") {
        Storage::Sqlite
    } else if name.ends_with(".bag") {
        Storage::Ros1
    } else {
        Storage::Mcap
    })
}

/// Whether the file at `path` is a ROS 1 bag of format 2.0, by its first bytes.
pub fn is_ros1(path: &Path) -> Result<bool, BagError> {
    Ok(matches!(by_magic(path)?, Some(Storage::Ros1)))
}

/// Walks every message of file `index` (`path`), in file order, `heads`
/// saying how much of each it needs. Returns how many bytes at its end were
/// cut short (a recording that stopped mid-write), 0 for a whole file.
pub fn scan(
    index: usize,
    path: &Path,
    heads: Heads<'_>,
    visit: &mut dyn FnMut(Message<'_>) -> Result<(), BagError>,
) -> Result<u64, BagError> {
    match storage(path)? {
        Storage::Sqlite => sqlite_storage::scan(index, path, heads, visit).map(|()| 0),
        Storage::Ros1 => ros1_storage::scan(index, path, visit),
        Storage::Mcap => mcap_storage::scan(index, path, visit),
    }
}

/// What one reading of a bag keeps between the messages it reads back:
/// the chunks it decompressed last (`kept_chunks::Chunks`). Made
/// with the reading and dropped with it.
#[derive(Default)]
pub struct Kept {
    chunks: kept_chunks::Chunks,
}

/// A message's bytes read back: its own, or where they lie in a chunk a
/// reading keeps (not copied out: a depth image is hundreds of kilobytes).
pub enum MessageBytes {
    Own(Vec<u8>),
    InChunk(Arc<Vec<u8>>, Range<usize>),
}

impl Deref for MessageBytes {
    type Target = [u8];

    fn deref(&self) -> &[u8] {
        match self {
            MessageBytes::Own(bytes) => bytes,
            MessageBytes::InChunk(chunk, range) => &chunk[range.clone()],
        }
    }
}

/// Reads back the message at `at` in file `path`.
pub fn fetch(path: &Path, at: Location) -> Result<Vec<u8>, BagError> {
    fetch_kept(path, at, &Kept::default()).map(|bytes| bytes.to_vec())
}

/// [`fetch`] for a reading that keeps `kept` between its messages.
pub fn fetch_kept(path: &Path, at: Location, kept: &Kept) -> Result<MessageBytes, BagError> {
    let own = |bytes: Result<Vec<u8>, BagError>| bytes.map(MessageBytes::Own);
    match at.place {
        Place::Mcap {
            offset,
            len,
            in_chunk,
        } => mcap_storage::fetch(path, at.file, offset, len, in_chunk, &kept.chunks),
        Place::Row(id) => own(sqlite_storage::fetch(path, id)),
        Place::Ros1 {
            offset,
            len,
            in_chunk,
            walked,
        } => ros1_storage::fetch(path, at.file, (offset, len), in_chunk, walked, &kept.chunks),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_of_no_storage_is_refused_in_the_words_of_the_one_its_name_says() {
        let dir = std::env::temp_dir().join(format!("placedb-bag-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for (name, says) in [
            ("a.db3", "sqlite3"),
            ("a.bag", "not a ROS 1 bag"),
            ("a.mcap", "not an MCAP file"),
        ] {
            let path = dir.join(name);
            std::fs::write(&path, b"garbage, not a bag at all").unwrap();
            let e = scan(0, &path, &|_| None, &mut |_| Ok(())).unwrap_err();
            assert!(e.1.contains(says), "{name}: {}", e.1);
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
