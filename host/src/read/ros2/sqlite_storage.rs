//! The sqlite3 files (`*.db3`) of a rosbag2 recording, the storage ROS 2
//! Humble's `ros2 bag record` writes by default, read with the bundled SQLite
//! of `rusqlite` (no system library or `sqlite3` program needed).
//!
//! rosbag2 keeps a `topics` table (`id`, `name`, `type`,
//! `serialization_format`) and a `messages` table (`id`, `topic_id`,
//! `timestamp` in nanoseconds, `data`, the serialized message). [`scan`]
//! steps through the messages one row at a time (a bag of gigabytes is never
//! loaded whole) and [`fetch`] reads one row back by its `id`.

use super::bag::{err, BagError, Channel, Location, Message, Place};
use rusqlite::{Connection, OpenFlags};
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

/// Walks every message of file `index` (`path`) in row order.
pub fn scan(
    index: usize,
    path: &Path,
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
    let mut messages = db
        .prepare("SELECT id, topic_id, timestamp, data FROM messages ORDER BY id")
        .map_err(|e| damaged(path, e, "reading its messages table"))?;
    let mut rows = messages
        .query([])
        .map_err(|e| damaged(path, e, "reading its messages table"))?;
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
        let fields = (|| -> rusqlite::Result<(i64, i64, i64, &[u8])> {
            Ok((
                row.get(0)?,
                row.get(1)?,
                row.get(2)?,
                row.get_ref(3)?.as_blob()?,
            ))
        })();
        let (id, topic_id, timestamp, data) = fields.map_err(|e| damaged(path, e, &when(&last)))?;
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
        visit(Message {
            channel,
            log_time,
            data,
            at: Location {
                file: index,
                place: Place::Row(id),
            },
        })?;
        last = Some((channel.topic.clone(), log_time));
    }
}

thread_local! {
    /// Each thread's open bag files: opening one reads its schema, a cost
    /// as large as a small message's, and depth is fetched frame by frame
    /// from the threads that voxelize.
    static OPEN: RefCell<HashMap<PathBuf, Connection>> = RefCell::new(HashMap::new());
}

/// Reads back the message of row `id` in file `path`.
pub fn fetch(path: &Path, id: i64) -> Result<Vec<u8>, BagError> {
    OPEN.with(|open| {
        let mut open = open.borrow_mut();
        let db = match open.entry(path.to_path_buf()) {
            Entry::Occupied(e) => e.into_mut(),
            Entry::Vacant(e) => e.insert(self::open(path)?),
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
        scan(3, &path, &mut |m| {
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
        let e = scan(0, &path, &mut |_| Ok(())).unwrap_err();
        assert!(e.1.contains("topic id 7"), "{}", e.1);
        std::fs::remove_file(&path).unwrap();
    }
}
