//! The sqlite3 files (`*.db3`) of a rosbag2 recording, the storage ROS 2
//! Humble's `ros2 bag record` writes by default, read with the bundled SQLite
//! of `rusqlite` (no system library or `sqlite3` program needed).
//!
//! rosbag2 keeps a `topics` table (`id`, `name`, `type`,
//! `serialization_format`) and a `messages` table (`id`, `topic_id`,
//! `timestamp` in nanoseconds, `data`, the serialized message). [`scan`]
//! steps through the messages one row at a time (a bag of gigabytes is never
//! loaded whole) and [`fetch`] reads one row back by its `id`.

use super::bag::{err, BagError, Channel, Heads, Location, Message, Place};
use rusqlite::blob::Blob;
use rusqlite::types::ValueRef;
use rusqlite::{Connection, OpenFlags, MAIN_DB};
use std::cell::RefCell;
use std::collections::hash_map::Entry;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Opens `path` read-only: reading a bag never changes it.
fn open(path: &Path) -> Result<Connection, BagError> {
    Connection::open_with_flags(
        path,
        OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(|e| err(path, format!("cannot open the sqlite3 bag file: {e}")))
}

/// An SQLite error in words, with what was being read when it happened.
fn damaged(path: &Path, e: rusqlite::Error, when: &str) -> BagError {
    err(
        path,
        format!("not a readable rosbag2 sqlite3 file ({when}): {e}"),
    )
}

/// Walks every message of file `index` (`path`) in row order, reading of
/// each only what `heads` asks for: a row is read on its own, so the pixels
/// of an image the walk only needs the fields of stay on disk.
pub fn scan(
    index: usize,
    path: &Path,
    heads: Heads<'_>,
    visit: &mut dyn FnMut(Message<'_>) -> Result<(), BagError>,
) -> Result<(), BagError> {
    let db = open(path)?;
    let channels: HashMap<i64, Channel> = db
        .prepare("SELECT id, name, type, serialization_format FROM topics")
        .and_then(|mut topics| {
            topics
                .query_map([], |row| {
                    let channel = Channel {
                        topic: row.get(1)?,
                        schema: row.get(2)?,
                        encoding: row.get(3)?,
                    };
                    Ok((row.get(0)?, channel))
                })?
                .collect()
        })
        .map_err(|e| damaged(path, e, "reading its topics table"))?;
    // The topics whose messages are read in part: their rows' data is left
    // out of the query (SQLite would read all of it) and their first bytes
    // are read through the blob interface. The ids are the table's integers.
    let head_of: HashMap<i64, usize> = channels
        .iter()
        .filter_map(|(&id, channel)| heads(channel).map(|n| (id, n)))
        .collect();
    let ids: Vec<String> = head_of.keys().map(i64::to_string).collect();
    let query = format!(
        "SELECT id, topic_id, timestamp, length(data), typeof(data), \
         CASE WHEN topic_id IN ({}) THEN NULL ELSE data END FROM messages ORDER BY id",
        ids.join(", ")
    );
    let mut messages = db
        .prepare(&query)
        .map_err(|e| damaged(path, e, "reading its messages table"))?;
    let mut rows = messages
        .query([])
        .map_err(|e| damaged(path, e, "reading its messages table"))?;
    // One blob handle moved from row to row (opening one compiles a
    // statement), and the head it reads into.
    let mut blob: Option<Blob<'_>> = None;
    let mut head = Vec::new();
    // What was read last, to say where a damaged file stops being readable.
    let mut last: Option<(String, u64)> = None;
    let when = |last: &Option<(String, u64)>| match last {
        Some((topic, t)) => format!("after the message on {topic} at t={:.6}", *t as f64 * 1e-9),
        None => "at its first message".to_string(),
    };
    loop {
        let row = match rows.next() {
            Ok(Some(row)) => row,
            Ok(None) => return Ok(()),
            Err(e) => return Err(damaged(path, e, &when(&last))),
        };
        let fields =
            (|| -> rusqlite::Result<(i64, i64, i64, Option<i64>, String, ValueRef<'_>)> {
                Ok((
                    row.get(0)?,
                    row.get(1)?,
                    row.get(2)?,
                    row.get(3)?,
                    row.get(4)?,
                    row.get_ref(5)?,
                ))
            })();
        let (id, topic_id, timestamp, len, kind, whole) =
            fields.map_err(|e| damaged(path, e, &when(&last)))?;
        let channel = channels.get(&topic_id).ok_or_else(|| {
            err(
                path,
                format!("message row {id} is on topic id {topic_id}, which the topics table lacks"),
            )
        })?;
        let log_time = u64::try_from(timestamp).map_err(|_| {
            err(
                path,
                format!(
                    "message row {id} on {} has a negative timestamp {timestamp}",
                    channel.topic
                ),
            )
        })?;
        let len = match (kind.as_str(), len.and_then(|n| usize::try_from(n).ok())) {
            ("blob", Some(len)) => len,
            _ => {
                return Err(err(
                    path,
                    format!(
                        "message row {id} on {}: its data is {kind}, not a serialized message \
                         (a blob)",
                        channel.topic
                    ),
                ))
            }
        };
        let data = match head_of.get(&topic_id) {
            None => whole
                .as_blob()
                .map_err(|_| err(path, format!("message row {id}: its data is not a blob")))?,
            Some(&n) => {
                let n = n.min(len);
                head.resize(n, 0);
                if n > 0 {
                    let read = match &mut blob {
                        Some(b) => b.reopen(id).and_then(|()| b.read_at_exact(&mut head, 0)),
                        None => match db.blob_open(MAIN_DB, "messages", "data", id, true) {
                            Ok(b) => blob.insert(b).read_at_exact(&mut head, 0),
                            Err(e) => Err(e),
                        },
                    };
                    read.map_err(|e| damaged(path, e, &format!("reading message row {id}")))?;
                }
                &head[..]
            }
        };
        visit(Message {
            channel,
            log_time,
            data,
            len,
            at: Location {
                file: index,
                place: Place::Row(id),
            },
        })?;
        last = Some((channel.topic.clone(), log_time));
    }
}

/// Which file a path named when it was opened: a bag recorded again at the
/// same path is another file, which a connection to the old one would not
/// see (a file changed in place, SQLite notices itself).
#[derive(Clone, Copy, PartialEq, Eq)]
struct FileId {
    #[cfg(unix)]
    device_inode: (u64, u64),
    #[cfg(not(unix))]
    length_modified: (u64, Option<std::time::SystemTime>),
}

fn file_id(path: &Path) -> Result<FileId, BagError> {
    let meta = std::fs::metadata(path).map_err(|e| err(path, e.to_string()))?;
    #[cfg(unix)]
    let id = {
        use std::os::unix::fs::MetadataExt;
        FileId {
            device_inode: (meta.dev(), meta.ino()),
        }
    };
    #[cfg(not(unix))]
    let id = FileId {
        length_modified: (meta.len(), meta.modified().ok()),
    };
    Ok(id)
}

thread_local! {
    /// Each thread's open bag files: opening one reads its schema, a cost
    /// as large as a small message's, and depth is fetched frame by frame
    /// from the threads that voxelize. Each is kept with the file it opened.
    static OPEN: RefCell<HashMap<PathBuf, (FileId, Connection)>> = RefCell::new(HashMap::new());
}

/// Reads back the message of row `id` in file `path`.
pub fn fetch(path: &Path, id: i64) -> Result<Vec<u8>, BagError> {
    let file = file_id(path)?;
    OPEN.with(|open| {
        let mut open = open.borrow_mut();
        let db = match open.entry(path.to_path_buf()) {
            Entry::Occupied(e) if e.get().0 == file => &e.into_mut().1,
            Entry::Occupied(mut e) => {
                e.insert((file, self::open(path)?));
                &e.into_mut().1
            }
            Entry::Vacant(e) => &e.insert((file, self::open(path)?)).1,
        };
        db.prepare_cached("SELECT data FROM messages WHERE id = ?1")
            .and_then(|mut q| q.query_row([id], |row| row.get::<_, Vec<u8>>(0)))
            .map_err(|e| damaged(path, e, &format!("reading message row {id}")))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bag file as rosbag2's sqlite3 storage lays it out.
    fn write(path: &Path, messages: &[(i64, i64, &[u8])]) {
        let db = Connection::open(path).unwrap();
        db.execute_batch(
            "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL, \
             serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
             CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, \
             timestamp INTEGER NOT NULL, data BLOB NOT NULL);
             INSERT INTO topics VALUES (1, '/a', 'std_msgs/msg/String', 'cdr', '');",
        )
        .unwrap();
        for (topic, t, data) in messages {
            db.execute(
                "INSERT INTO messages(topic_id, timestamp, data) VALUES (?1, ?2, ?3)",
                rusqlite::params![topic, t, data],
            )
            .unwrap();
        }
    }

    #[test]
    fn messages_are_walked_in_row_order_and_fetched_back() {
        let path = std::env::temp_dir().join(format!("placedb-sqlite-{}.db3", std::process::id()));
        let _ = std::fs::remove_file(&path);
        write(&path, &[(1, 20, b"first"), (1, 10, b"second")]);
        let mut seen = Vec::new();
        scan(3, &path, &|_| None, &mut |m| {
            seen.push((m.channel.topic.clone(), m.log_time, m.data.to_vec(), m.at));
            Ok(())
        })
        .unwrap();
        assert_eq!(seen.len(), 2);
        assert_eq!((seen[0].1, seen[1].1), (20, 10));
        assert_eq!(seen[0].3.file, 3);
        assert_eq!(fetch(&path, 2).unwrap(), b"second");
        assert!(fetch(&path, 9).unwrap_err().1.contains("message row 9"));
        // A row on a topic the table lacks is named.
        std::fs::remove_file(&path).unwrap();
        write(&path, &[(7, 5, b"x")]);
        let e = scan(0, &path, &|_| None, &mut |_| Ok(())).unwrap_err();
        assert!(e.1.contains("topic id 7"), "{}", e.1);
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn a_bag_file_written_anew_at_the_same_path_is_read_anew() {
        let path =
            std::env::temp_dir().join(format!("placedb-sqlite-anew-{}.db3", std::process::id()));
        let _ = std::fs::remove_file(&path);
        write(&path, &[(1, 10, b"first"), (1, 20, b"second")]);
        assert_eq!(fetch(&path, 2).unwrap(), b"second");
        // Recorded again (a new file at the path), then read in the same
        // process and thread: its rows, not the old file's.
        std::fs::remove_file(&path).unwrap();
        write(&path, &[(1, 10, b"again"), (1, 20, b"anew")]);
        assert_eq!(fetch(&path, 2).unwrap(), b"anew");
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn a_walk_reads_the_heads_it_is_asked_for() {
        let path =
            std::env::temp_dir().join(format!("placedb-sqlite-heads-{}.db3", std::process::id()));
        let _ = std::fs::remove_file(&path);
        write(&path, &[(1, 10, b"a whole message"), (1, 20, b"xy")]);
        for (head, want) in [
            (None, [&b"a whole message"[..], b"xy"]),
            (Some(7), [b"a whole", b"xy"]),
            (Some(0), [b"", b""]),
        ] {
            let mut seen = Vec::new();
            scan(0, &path, &|c| head.filter(|_| c.topic == "/a"), &mut |m| {
                seen.push((m.data.to_vec(), m.len));
                Ok(())
            })
            .unwrap();
            assert_eq!(
                seen,
                [(want[0].to_vec(), 15), (want[1].to_vec(), 2)],
                "{head:?}"
            );
        }
        // A row whose data is not a blob is refused in words.
        let db = Connection::open(&path).unwrap();
        db.execute("UPDATE messages SET data = 'text' WHERE id = 2", [])
            .unwrap();
        drop(db);
        for head in [None, Some(4)] {
            let e = scan(0, &path, &|_| head, &mut |_| Ok(())).unwrap_err();
            assert!(
                e.1.contains("message row 2 on /a: its data is text"),
                "{}",
                e.1
            );
        }
        std::fs::remove_file(&path).unwrap();
    }
}
