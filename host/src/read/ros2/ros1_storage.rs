//! ROS 1 bags (`.bag`, format 2.0), the container: `#ROSBAG V2.0\n`, then
//! records, each a header (`u32` length, then fields, each a `u32` length
//! and `name=value`) and data (`u32` length, then bytes). The `op` field
//! says what a record is: a bag header (0x03), a chunk (0x05: `compression`
//! `none`, `bz2` or `lz4`, `size` its uncompressed size; its data holds
//! connection and message records), a connection (0x07: `conn`, `topic`;
//! its data a header of `type`, `md5sum`, `message_definition`, ...), a
//! message (0x02: `conn`, `time` as `u32` seconds and nanoseconds), and the
//! index records (0x04 index data, 0x06 chunk info), which are not needed.
//!
//! As for MCAP ([`super::mcap_storage`]), nothing is kept whole: [`scan`]
//! walks the file once, a few chunks at a time (`read_ahead`), and hands
//! every message to the visitor with its [`Place::Ros1`] (the top-level
//! record and, inside a chunk, the message record's offset in the
//! decompressed data); [`fetch`]
//! reads one back, a chunk decompressed once for the messages read from it
//! in turn (`kept_chunks::Chunks`, kept by the reading). A channel's
//! schema is the ROS 2 name of the type (`sensor_msgs/Image` is
//! `sensor_msgs/msg/Image`; `tf/tfMessage`, the same layout, is
//! `tf2_msgs/msg/TFMessage`) and its encoding `ros1`, so the reader takes
//! ROS 1 and ROS 2 messages down one path.
//!
//! Every length is checked against what holds it before it is used; a
//! chunk's data is decompressed only as far as its header's `size`, into a
//! buffer that grows with what really comes out (a damaged `size` cannot
//! ask for gigabytes). A file cut at its end is read up to the cut, except
//! inside a chunk: a chunk cut short is an error naming the byte.

use super::bag::{err, BagError, Channel, Location, Message, MessageBytes, Place};
use super::kept_chunks::Chunks;
use super::lz4_frame::{self, Checksums};
use super::read_ahead::ReadAhead;
use std::collections::HashMap;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::ops::Range;
use std::path::Path;

/// The first bytes of a ROS 1 bag of format 2.0.
pub const MAGIC: &[u8; 13] = b"#ROSBAG V2.0\n";

/// Record opcodes (the `op` header field).
mod op {
    pub const MESSAGE: u8 = 0x02;
    pub const BAG_HEADER: u8 = 0x03;
    pub const CHUNK: u8 = 0x05;
    pub const CONNECTION: u8 = 0x07;
}

/// The longest record header read: headers are a few short fields (op,
/// conn, time, topic, compression, size...); a longer one is damage.
const MAX_HEADER: u32 = 1 << 20;

/// A record's header fields, borrowed from its bytes.
struct Fields<'a>(Vec<(&'a [u8], &'a [u8])>);

impl<'a> Fields<'a> {
    /// Splits header bytes into `name=value` fields.
    fn parse(bytes: &'a [u8]) -> Result<Self, String> {
        let mut fields = Vec::new();
        let mut rest = bytes;
        while !rest.is_empty() {
            let at = bytes.len() - rest.len();
            let (len, tail) = split_u32(rest)
                .ok_or_else(|| format!("a header field length at byte {at} is cut short"))?;
            let field = tail.get(..len as usize).ok_or_else(|| {
                format!(
                    "a header field at byte {at} claims {len} bytes, only {} left",
                    tail.len()
                )
            })?;
            let eq = field
                .iter()
                .position(|&b| b == b'=')
                .ok_or_else(|| format!("the header field at byte {at} has no `=`"))?;
            fields.push((&field[..eq], &field[eq + 1..]));
            rest = &tail[len as usize..];
        }
        Ok(Fields(fields))
    }

    fn get(&self, name: &str) -> Option<&'a [u8]> {
        self.0
            .iter()
            .find(|(n, _)| *n == name.as_bytes())
            .map(|(_, v)| *v)
    }

    fn need(&self, name: &str) -> Result<&'a [u8], String> {
        self.get(name)
            .ok_or_else(|| format!("the record header has no `{name}` field"))
    }

    fn op(&self) -> Result<u8, String> {
        match self.need("op")? {
            [op] => Ok(*op),
            other => Err(format!("`op` field of {} bytes, expected 1", other.len())),
        }
    }

    fn u32(&self, name: &str) -> Result<u32, String> {
        let v = self.need(name)?;
        <[u8; 4]>::try_from(v)
            .map(u32::from_le_bytes)
            .map_err(|_| format!("`{name}` field of {} bytes, expected 4", v.len()))
    }

    fn text(&self, name: &str) -> Result<String, String> {
        String::from_utf8(self.need(name)?.to_vec())
            .map_err(|_| format!("`{name}` field is not UTF-8"))
    }

    /// A message's `time`: nanoseconds.
    fn time(&self) -> Result<u64, String> {
        let v = self.need("time")?;
        match <[u8; 8]>::try_from(v) {
            Ok(b) => {
                let sec = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                let nsec = u32::from_le_bytes([b[4], b[5], b[6], b[7]]);
                Ok(u64::from(sec) * 1_000_000_000 + u64::from(nsec))
            }
            Err(_) => Err(format!("`time` field of {} bytes, expected 8", v.len())),
        }
    }
}

fn split_u32(bytes: &[u8]) -> Option<(u32, &[u8])> {
    let (head, tail) = bytes.split_first_chunk::<4>()?;
    Some((u32::from_le_bytes(*head), tail))
}

/// One record of a decompressed chunk: header and data, borrowed.
struct InnerRecord<'a> {
    /// Offset of the record in the chunk's data.
    offset: usize,
    fields: Fields<'a>,
    data: &'a [u8],
}

/// Splits the next record off `rest` (the chunk's data from `offset` on).
fn inner_record<'a>(rest: &'a [u8], offset: usize) -> Result<(InnerRecord<'a>, &'a [u8]), String> {
    let past = || format!("the record at byte {offset} of its data runs past its end");
    let (hlen, tail) = split_u32(rest).ok_or_else(past)?;
    let header = tail.get(..hlen as usize).ok_or_else(past)?;
    let (dlen, tail) = split_u32(&tail[hlen as usize..]).ok_or_else(past)?;
    let data = tail.get(..dlen as usize).ok_or_else(past)?;
    let fields = Fields::parse(header)
        .map_err(|e| format!("the record at byte {offset} of its data: {e}"))?;
    Ok((
        InnerRecord {
            offset,
            fields,
            data,
        },
        &tail[dlen as usize..],
    ))
}

/// Walks the records of a decompressed chunk.
fn inner_records<'a>(
    data: &'a [u8],
    visit: &mut dyn FnMut(InnerRecord<'a>) -> Result<(), String>,
) -> Result<(), String> {
    let mut rest = data;
    while !rest.is_empty() {
        let (record, tail) = inner_record(rest, data.len() - rest.len())?;
        visit(record)?;
        rest = tail;
    }
    Ok(())
}

/// The largest a chunk's data can grow per compressed byte: no lz4 block
/// expands more than 255 times (as [`super::mcap_storage`] bounds it); a
/// bz2 stream has no such bound, its output is capped by `size` alone.
const LZ4_MOST_PER_BYTE: u64 = 255;

/// A chunk's data, decompressed: exactly `size` bytes, else an error;
/// `data` itself when it is not compressed, else `out`'s (its room reused
/// without zeroing: fresh memory costs a page fault a 4 KiB, and zeroing
/// it as much again).
fn decompress<'a>(
    compression: &[u8],
    size: u32,
    data: &'a [u8],
    out: &'a mut Vec<u8>,
    checksums: Checksums,
) -> Result<&'a [u8], String> {
    let size = u64::from(size);
    let claims = |got: usize| {
        format!("it claims {size} bytes uncompressed, its data gives {got} (a damaged chunk)")
    };
    match compression {
        b"none" => {
            if data.len() as u64 != size {
                return Err(claims(data.len()));
            }
            return Ok(data);
        }
        b"lz4" => {
            if size > (data.len() as u64).saturating_mul(LZ4_MOST_PER_BYTE) + 64 {
                return Err(format!(
                    "{} bytes of lz4 cannot hold the {size} bytes it claims uncompressed \
                     (a damaged chunk header)",
                    data.len()
                ));
            }
            lz4_frame::decompress_into(data, size as usize, out, checksums)
                .map_err(|e| format!("its lz4 data does not decompress: {e}"))?;
        }
        b"bz2" => read_at_most(bzip2::read::BzDecoder::new(data), size, out)
            .map_err(|e| format!("its data does not decompress: {e}"))?,
        other => {
            return Err(format!(
                "compression `{}` is not supported (none, bz2 or lz4)",
                String::from_utf8_lossy(other)
            ))
        }
    };
    if out.len() as u64 != size {
        return Err(claims(out.len()));
    }
    let out: &'a Vec<u8> = out;
    Ok(out)
}

/// Reads what `r` gives into `out`, up to `size` bytes and one more (so a
/// chunk claiming too little shows), into the room `out` already has
/// where it can (new room is zeroed before it is read into). Room beyond
/// [`RESERVE_AT_ONCE`] grows with what really comes out: a bz2 stream's
/// output has no bound but `size`, which a damaged header sets.
fn read_at_most(mut r: impl Read, size: u64, out: &mut Vec<u8>) -> std::io::Result<()> {
    let most = usize::try_from(size.saturating_add(1)).unwrap_or(usize::MAX);
    let mut filled = 0usize;
    while filled < most {
        if filled == out.len() {
            // Double, from the reserve; never past `most`.
            let grown = out.len().max(RESERVE_AT_ONCE as usize / 2) * 2;
            out.resize(grown.min(most), 0);
        }
        let end = out.len().min(most);
        match r.read(&mut out[filled..end]) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    out.truncate(filled);
    Ok(())
}

/// Most bytes a decompression reserves before it sees its output: 16 MiB,
/// many depth images (a damaged header claiming gigabytes reserves no more).
const RESERVE_AT_ONCE: u64 = 16 << 20;

/// Decompresses the chunk record whose header is `fields` and data `data`
/// (`out` as [`decompress`] takes it), its checksums verified or not: the
/// walk verifies them, a frame read back from the same chunk does not again.
fn chunk_data<'a>(
    fields: &Fields<'_>,
    data: &'a [u8],
    out: &'a mut Vec<u8>,
    checksums: Checksums,
) -> Result<&'a [u8], String> {
    let (compression, size) = (fields.need("compression")?, fields.u32("size")?);
    decompress(compression, size, data, out, checksums)
}

/// The ROS 2 name of a ROS 1 message type: `pkg/Name` is `pkg/msg/Name`;
/// `tf/tfMessage` (tf's own, laid out as tf2's) is `tf2_msgs/msg/TFMessage`.
pub fn ros2_type_name(ros1: &str) -> String {
    match ros1 {
        "tf/tfMessage" | "tf2_msgs/TFMessage" => "tf2_msgs/msg/TFMessage".into(),
        _ => match ros1.split_once('/') {
            Some((pkg, name)) if !name.contains('/') => format!("{pkg}/msg/{name}"),
            _ => ros1.into(),
        },
    }
}

/// Connections seen so far, by `conn` id.
#[derive(Default)]
struct Connections(HashMap<u32, Channel>);

impl Connections {
    /// Notes a connection record (`fields`, `data`).
    fn note(&mut self, fields: &Fields<'_>, data: &[u8]) -> Result<(), String> {
        let conn = fields.u32("conn")?;
        let topic = fields.text("topic")?;
        let inner = Fields::parse(data).map_err(|e| format!("connection {conn}'s data: {e}"))?;
        let ty = inner.text("type")?;
        self.0.insert(
            conn,
            Channel {
                topic,
                schema: ros2_type_name(&ty),
                encoding: "ros1".into(),
            },
        );
        Ok(())
    }

    fn of(&self, fields: &Fields<'_>) -> Result<&Channel, String> {
        let conn = fields.u32("conn")?;
        self.0
            .get(&conn)
            .ok_or_else(|| format!("message on connection {conn}, which no record defines"))
    }
}

/// The head of a top-level record: its header bytes and its data length.
struct RecordHead {
    header: Vec<u8>,
    data_len: u32,
}

/// How reading a top-level record's head ended.
enum Head {
    Record(RecordHead),
    /// The end of the file, between records.
    End,
    /// The file ends inside the head.
    Cut,
}

/// Reads up to `buf.len()` bytes; how many there were before the end.
fn read_full(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match r.read(&mut buf[got..])? {
            0 => break,
            n => got += n,
        }
    }
    Ok(got)
}

/// Reads a record's head at byte `pos` of a file of `size` bytes.
fn record_head(r: &mut impl Read, pos: u64, size: u64) -> Result<Head, String> {
    let io = |e: std::io::Error| e.to_string();
    let mut len = [0u8; 4];
    match read_full(r, &mut len).map_err(io)? {
        0 => return Ok(Head::End),
        4 => {}
        _ => return Ok(Head::Cut),
    }
    let hlen = u32::from_le_bytes(len);
    if u64::from(hlen) + 8 > size.saturating_sub(pos) {
        return Ok(Head::Cut);
    }
    if hlen > MAX_HEADER {
        return Err(format!(
            "record at byte {pos}: a header of {hlen} bytes (a damaged record)"
        ));
    }
    let mut header = vec![0u8; hlen as usize];
    r.read_exact(&mut header).map_err(io)?;
    r.read_exact(&mut len).map_err(io)?;
    Ok(Head::Record(RecordHead {
        header,
        data_len: u32::from_le_bytes(len),
    }))
}

/// Checks the magic at the start of `r`.
fn check_magic(path: &Path, r: &mut impl Read) -> Result<(), BagError> {
    let mut magic = [0u8; 13];
    let got = read_full(r, &mut magic).map_err(|e| err(path, e.to_string()))?;
    if got < magic.len() || &magic != MAGIC {
        return Err(err(
            path,
            "not a ROS 1 bag of format 2.0 (no `#ROSBAG V2.0`)",
        ));
    }
    Ok(())
}

/// A chunk record read but not yet walked: its place, header and data.
struct Pending {
    pos: u64,
    record_len: u64,
    header: Vec<u8>,
    data: Vec<u8>,
}

/// Walks every message of file `index` (`path`), in file order. Returns
/// how many bytes at its end were cut short (a recording that stopped
/// mid-write), 0 for a whole file.
///
/// Chunks are read a few at a time and decompressed in parallel, then
/// walked in order: what the visitor sees, and the first error, are as if
/// they were read one by one.
pub fn scan(
    index: usize,
    path: &Path,
    visit: &mut dyn FnMut(Message<'_>) -> Result<(), BagError>,
) -> Result<u64, BagError> {
    let mut walk = Walk {
        index,
        path,
        connections: Connections::default(),
        ahead: ReadAhead::default(),
        visit,
    };
    let cut = walk.records();
    // What was read before the end, a cut or an error is walked first.
    walk.walk_pending()?;
    cut
}

/// A walk of one file's records.
struct Walk<'v, 'p> {
    index: usize,
    path: &'p Path,
    connections: Connections,
    /// Chunks read, not yet walked.
    ahead: ReadAhead<Pending>,
    visit: &'v mut dyn FnMut(Message<'_>) -> Result<(), BagError>,
}

impl Walk<'_, '_> {
    /// Reads the file's records, walking them in turn; [`Self::ahead`]
    /// holds chunks still to walk when it returns.
    fn records(&mut self) -> Result<u64, BagError> {
        let path = self.path;
        let io = |e: std::io::Error| err(path, e.to_string());
        let file = File::open(path).map_err(io)?;
        let size = file.metadata().map_err(io)?.len();
        let mut r = BufReader::with_capacity(1 << 16, file);
        check_magic(path, &mut r)?;
        let mut pos = MAGIC.len() as u64;
        let mut data = Vec::new();
        loop {
            let head = match record_head(&mut r, pos, size).map_err(|e| err(path, e))? {
                Head::End => return Ok(0),
                Head::Cut => return Ok(size - pos),
                Head::Record(head) => head,
            };
            let at_record = |e: String| err(path, format!("record at byte {pos}: {e}"));
            let fields = Fields::parse(&head.header).map_err(at_record)?;
            let opcode = fields.op().map_err(at_record)?;
            let data_at = pos + 8 + head.header.len() as u64;
            let end = data_at + u64::from(head.data_len);
            if end > size {
                if opcode == op::CHUNK {
                    return Err(err(
                        path,
                        format!(
                            "the chunk at byte {pos} is cut short: its data runs to byte {end}, \
                             the file ends at byte {size} (a truncated bag)"
                        ),
                    ));
                }
                // The recording stopped mid-record: keep what came before.
                return Ok(size - pos);
            }
            let record_len = end - pos;
            if ![op::CHUNK, op::CONNECTION, op::MESSAGE].contains(&opcode) {
                r.seek_relative(i64::from(head.data_len)).map_err(io)?;
                pos = end;
                continue;
            }
            if opcode == op::CHUNK {
                let claims = fields.u32("size").map_or(0, u64::from);
                if self.ahead.is_full_for(claims) {
                    self.walk_pending()?;
                }
                let mut data = self.ahead.buffer();
                data.resize(head.data_len as usize, 0);
                r.read_exact(&mut data).map_err(io)?;
                let chunk = Pending {
                    pos,
                    record_len,
                    header: head.header,
                    data,
                };
                self.ahead.push(chunk, claims);
                pos = end;
                continue;
            }
            self.walk_pending()?;
            data.resize(head.data_len as usize, 0);
            r.read_exact(&mut data).map_err(io)?;
            if opcode == op::CONNECTION {
                self.connections.note(&fields, &data).map_err(at_record)?;
            } else {
                let channel = self.connections.of(&fields).map_err(at_record)?;
                let log_time = fields.time().map_err(at_record)?;
                let at = self.place(pos, record_len, None);
                (self.visit)(Message {
                    channel,
                    log_time,
                    data: &data,
                    len: data.len(),
                    at,
                })?;
            }
            pos = end;
        }
    }

    fn place(&self, offset: u64, len: u64, in_chunk: Option<u32>) -> Location {
        Location {
            file: self.index,
            place: Place::Ros1 {
                offset,
                len,
                in_chunk,
                walked: 0,
            },
        }
    }

    /// Decompresses the pending chunks in parallel and walks them in order.
    fn walk_pending(&mut self) -> Result<(), BagError> {
        let Walk {
            index,
            path,
            connections,
            ahead,
            visit,
        } = self;
        let (index, path) = (*index, *path);
        ahead.walk(
            |c, out| {
                let at_chunk = |e: String| err(path, format!("chunk at byte {}: {e}", c.pos));
                let fields = Fields::parse(&c.header).map_err(at_chunk)?;
                let chunk = chunk_data(&fields, &c.data, out, Checksums::Verify);
                // What a read back recognises these bytes by, where they
                // carry checksums to skip then (0: none to skip).
                let lz4 = fields.get("compression") == Some(&b"lz4"[..]);
                let walked = match lz4 && lz4_frame::has_checksums(&c.data) {
                    true => crc32fast::hash(&c.data),
                    false => 0,
                };
                Ok((chunk.map_err(at_chunk)?, walked))
            },
            |c, chunk, walked| walk_chunk(path, index, connections, &mut **visit, c, chunk, walked),
            |c| c.data,
        )
    }
}

/// Hands on the messages of chunk `c` (its data decompressed: `chunk`, the
/// CRC-32 of its data as read: `walked`) of file `index` (`path`) to
/// `visit`, noting its connections.
fn walk_chunk(
    path: &Path,
    index: usize,
    connections: &mut Connections,
    visit: &mut dyn FnMut(Message<'_>) -> Result<(), BagError>,
    c: &Pending,
    chunk: &[u8],
    walked: u32,
) -> Result<(), BagError> {
    let at_chunk = |e: String| err(path, format!("chunk at byte {}: {e}", c.pos));
    let mut visit_err = None;
    inner_records(chunk, &mut |rec| {
        let inner_op = rec.fields.op()?;
        if inner_op == op::CONNECTION {
            return connections.note(&rec.fields, rec.data);
        }
        if inner_op != op::MESSAGE {
            return Ok(());
        }
        let channel = connections.of(&rec.fields)?;
        let log_time = rec.fields.time()?;
        // In-chunk offsets fit: a chunk's `size` is a u32.
        let in_chunk = u32::try_from(rec.offset).unwrap_or(u32::MAX);
        visit(Message {
            channel,
            log_time,
            data: rec.data,
            len: rec.data.len(),
            at: Location {
                file: index,
                place: Place::Ros1 {
                    offset: c.pos,
                    len: c.record_len,
                    in_chunk: Some(in_chunk),
                    walked,
                },
            },
        })
        .map_err(|e| {
            visit_err = Some(e);
            String::new()
        })
    })
    // The visitor's own error passes through as it is.
    .map_err(|e| visit_err.take().unwrap_or_else(|| at_chunk(e)))
}

/// Reads back the message of the top-level record of `len` bytes at byte
/// `offset` of file `path` (`in_chunk`: the message record's offset in that
/// chunk's decompressed data; `walked`: the CRC-32 of the chunk's data when
/// the walk read it). A chunk is looked for in `chunks` (under `file`, the
/// file's index in its bag) before it is read, and kept there.
pub fn fetch(
    path: &Path,
    file: usize,
    (offset, len): (u64, u64),
    in_chunk: Option<u32>,
    walked: u32,
    chunks: &Chunks,
) -> Result<MessageBytes, BagError> {
    let at_record = |e: String| err(path, format!("record at byte {offset}: {e}"));
    if let Some(k) = in_chunk {
        if let Some(chunk) = chunks.get(file, offset) {
            let range = message_in_chunk(&chunk, k).map_err(at_record)?;
            return Ok(MessageBytes::InChunk(chunk, range));
        }
    }
    let io = |e: std::io::Error| err(path, e.to_string());
    let mut handle = File::open(path).map_err(io)?;
    let size = handle.metadata().map_err(io)?.len();
    if len < 8 || offset.checked_add(len).is_none_or(|end| end > size) {
        return Err(err(
            path,
            format!("no record of {len} bytes at byte {offset} (the file has {size})"),
        ));
    }
    handle.seek(SeekFrom::Start(offset)).map_err(io)?;
    let mut record = vec![0u8; len as usize];
    handle.read_exact(&mut record).map_err(io)?;
    let (top, _) = inner_record(&record, 0).map_err(at_record)?;
    let op = top.fields.op().map_err(at_record)?;
    match (op, in_chunk) {
        (op::MESSAGE, None) => Ok(MessageBytes::Own(top.data.to_vec())),
        (op::CHUNK, Some(k)) => {
            let mut out = chunks.buffer();
            // The walk verified the checksums of these very bytes (a
            // rosbag-written lz4 chunk's cost a third as much as its
            // decompression); bytes that changed since are checked again.
            let checksums = if walked != 0 && crc32fast::hash(top.data) == walked {
                Checksums::Skip
            } else {
                Checksums::Verify
            };
            let chunk =
                chunk_data(&top.fields, top.data, &mut out, checksums).map_err(at_record)?;
            let range = message_in_chunk(chunk, k).map_err(at_record)?;
            // An uncompressed chunk is its record's data: kept as a copy.
            let uncompressed = top.fields.get("compression") == Some(&b"none"[..]);
            let kept = if uncompressed { chunk.to_vec() } else { out };
            Ok(MessageBytes::InChunk(
                chunks.keep(file, offset, kept),
                range,
            ))
        }
        _ => Err(at_record("not the message record expected".into())),
    }
}

/// Where the data of the message record at byte `k` of a decompressed
/// `chunk` lies in it.
fn message_in_chunk(chunk: &[u8], k: u32) -> Result<Range<usize>, String> {
    let rest = chunk.get(k as usize..).unwrap_or(&[]);
    let (msg, after) = inner_record(rest, k as usize)?;
    match msg.fields.op()? {
        op::MESSAGE => {
            // The data ends where the rest after the record begins.
            let end = chunk.len() - after.len();
            Ok(end - msg.data.len()..end)
        }
        _ => Err(format!("no message record at byte {k} of the chunk")),
    }
}

/// Writes ROS 1 bags, for tests and fuzz seeds: records as [`scan`] reads
/// them, without the index records (which the reader skips).
#[doc(hidden)]
pub mod write {
    use super::{op, MAGIC};

    /// One record: header fields, then data.
    pub fn record(fields: &[(&str, &[u8])], data: &[u8]) -> Vec<u8> {
        let header: Vec<u8> = fields
            .iter()
            .flat_map(|(name, value)| {
                let len = (name.len() + 1 + value.len()) as u32;
                [&len.to_le_bytes()[..], name.as_bytes(), b"=", value].concat()
            })
            .collect();
        [
            &(header.len() as u32).to_le_bytes()[..],
            &header,
            &(data.len() as u32).to_le_bytes(),
            data,
        ]
        .concat()
    }

    /// A connection record of `conn` on `topic` for ROS 1 type `ty`.
    pub fn connection(conn: u32, topic: &str, ty: &str) -> Vec<u8> {
        let data = record(&[("type", ty.as_bytes()), ("md5sum", b"*")], &[]);
        // The data is a header alone: drop the empty data's length.
        let data = &data[4..data.len() - 4];
        record(
            &[
                ("op", &[op::CONNECTION]),
                ("conn", &conn.to_le_bytes()),
                ("topic", topic.as_bytes()),
            ],
            data,
        )
    }

    /// A message record on `conn` at `sec` seconds.
    pub fn message(conn: u32, sec: u32, data: &[u8]) -> Vec<u8> {
        let time = [sec.to_le_bytes(), 0u32.to_le_bytes()].concat();
        record(
            &[
                ("op", &[op::MESSAGE]),
                ("conn", &conn.to_le_bytes()),
                ("time", &time),
            ],
            data,
        )
    }

    /// A chunk of `records` (concatenated), compressed as `compression`
    /// (`none`, `bz2` or `lz4`).
    pub fn chunk(compression: &str, records: &[u8]) -> Vec<u8> {
        use std::io::Write;
        let data = match compression {
            "bz2" => {
                let mut e = bzip2::write::BzEncoder::new(Vec::new(), bzip2::Compression::default());
                e.write_all(records).ok();
                e.finish().unwrap_or_default()
            }
            "lz4" => match lz4::EncoderBuilder::new().build(Vec::new()) {
                Ok(mut e) => {
                    e.write_all(records).ok();
                    e.finish().0
                }
                Err(_) => Vec::new(),
            },
            _ => records.to_vec(),
        };
        record(
            &[
                ("op", &[op::CHUNK]),
                ("compression", compression.as_bytes()),
                ("size", &(records.len() as u32).to_le_bytes()),
            ],
            &data,
        )
    }

    /// A whole bag: the magic, a bag header, then `records`.
    pub fn bag(records: &[u8]) -> Vec<u8> {
        let header = record(
            &[
                ("op", &[op::BAG_HEADER]),
                ("index_pos", &0u64.to_le_bytes()),
                ("conn_count", &0u32.to_le_bytes()),
                ("chunk_count", &0u32.to_le_bytes()),
            ],
            &[b' '; 16],
        );
        [&MAGIC[..], &header, records].concat()
    }
}

#[cfg(test)]
mod tests {
    use super::write::*;
    use super::*;

    fn temp_bag(name: &str, bytes: &[u8]) -> std::path::PathBuf {
        let p = std::env::temp_dir().join(format!(
            "placedb-ros1-unit-{}-{name}.bag",
            std::process::id()
        ));
        std::fs::write(&p, bytes).unwrap();
        p
    }

    /// (topic, schema, encoding, log time, data, place) of every message.
    type Seen = Vec<(String, String, String, u64, Vec<u8>, Location)>;

    fn walk(path: &Path) -> Result<(Seen, u64), BagError> {
        let mut seen = Vec::new();
        let cut = scan(0, path, &mut |m| {
            seen.push((
                m.channel.topic.clone(),
                m.channel.schema.clone(),
                m.channel.encoding.clone(),
                m.log_time,
                m.data.to_vec(),
                m.at,
            ));
            Ok(())
        })?;
        Ok((seen, cut))
    }

    fn sample(compression: &str) -> Vec<u8> {
        let inner = [
            connection(0, "/depth", "sensor_msgs/Image"),
            message(0, 1, b"first"),
            connection(1, "/tf", "tf/tfMessage"),
            message(1, 2, b"second"),
        ]
        .concat();
        bag(&[
            chunk(compression, &inner),
            message(0, 3, b"top-level"),
            // An index record: skipped.
            record(&[("op", &[0x04]), ("ver", &1u32.to_le_bytes())], b"xx"),
        ]
        .concat())
    }

    #[test]
    fn every_compression_walks_and_fetches_the_same() {
        for compression in ["none", "bz2", "lz4"] {
            let path = temp_bag(compression, &sample(compression));
            let (seen, cut) = walk(&path).unwrap();
            assert_eq!(cut, 0);
            let got: Vec<_> = seen
                .iter()
                .map(|s| {
                    (
                        s.0.as_str(),
                        s.1.as_str(),
                        s.2.as_str(),
                        s.3,
                        s.4.as_slice(),
                    )
                })
                .collect();
            assert_eq!(
                got,
                [
                    (
                        "/depth",
                        "sensor_msgs/msg/Image",
                        "ros1",
                        1_000_000_000,
                        &b"first"[..]
                    ),
                    (
                        "/tf",
                        "tf2_msgs/msg/TFMessage",
                        "ros1",
                        2_000_000_000,
                        b"second"
                    ),
                    (
                        "/depth",
                        "sensor_msgs/msg/Image",
                        "ros1",
                        3_000_000_000,
                        b"top-level"
                    ),
                ],
                "{compression}"
            );
            for s in &seen {
                assert_eq!(super::super::bag::fetch(&path, s.5).unwrap(), s.4);
            }
            std::fs::remove_file(&path).unwrap();
        }
    }

    /// A bag of one lz4 chunk holding two messages, `a` and `b`.
    fn two_in_a_chunk(a: &[u8], b: &[u8]) -> Vec<u8> {
        let inner = [
            connection(0, "/depth", "sensor_msgs/Image"),
            message(0, 1, a),
            message(0, 2, b),
        ]
        .concat();
        bag(&chunk("lz4", &inner))
    }

    #[test]
    fn a_reading_decompresses_a_chunk_once_and_the_next_reading_sees_the_file_anew() {
        let path = temp_bag("rewritten", &two_in_a_chunk(b"old-1", b"old-2"));
        let (seen, _) = walk(&path).unwrap();
        let place = |i: usize| match seen[i].5.place {
            Place::Ros1 {
                offset,
                len,
                in_chunk,
                walked,
            } => ((offset, len), in_chunk, walked),
            other => panic!("{other:?}"),
        };
        let ((r1, k1, w1), (r2, k2, w2)) = (place(0), place(1));
        assert_eq!(r1, r2, "both messages in the one chunk");
        let first = Chunks::default();
        assert_eq!(&fetch(&path, 0, r1, k1, w1, &first).unwrap()[..], b"old-1");
        // Rewritten in place, the same layout: the reading that has the
        // chunk reads it from what it kept, a new reading from the file.
        std::fs::write(&path, two_in_a_chunk(b"new-1", b"new-2")).unwrap();
        assert_eq!(&fetch(&path, 0, r2, k2, w2, &first).unwrap()[..], b"old-2");
        let second = Chunks::default();
        assert_eq!(&fetch(&path, 0, r2, k2, w2, &second).unwrap()[..], b"new-2");
        assert_eq!(&fetch(&path, 0, r1, k1, w1, &second).unwrap()[..], b"new-1");
        // Kept by file and offset: the same offset in another file is read.
        assert_eq!(&fetch(&path, 1, r1, k1, w1, &first).unwrap()[..], b"new-1");
        assert_eq!(
            super::super::bag::fetch(&path, seen[0].5).unwrap(),
            b"new-1"
        );
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn a_chunk_changed_since_the_walk_has_its_checksum_verified_when_read_back() {
        // Incompressible messages: the lz4 frame stores them as they are, so
        // a changed byte changes the output and only the frame's content
        // checksum (which the lz4 crate's writer sets) can tell.
        let mut rng = crate::rng::SplitMix64::new(5);
        let noise: Vec<u8> = (0..200_000).map(|_| rng.next_u64() as u8).collect();
        let bytes = bag(&chunk(
            "lz4",
            &[
                connection(0, "/depth", "sensor_msgs/Image"),
                message(0, 1, &noise),
            ]
            .concat(),
        ));
        let path = temp_bag("changed", &bytes);
        let (seen, _) = walk(&path).unwrap();
        let Place::Ros1 {
            offset,
            len,
            in_chunk,
            walked,
        } = seen[0].5.place
        else {
            panic!("{:?}", seen[0].5)
        };
        assert_ne!(walked, 0);
        // Read back as walked: the same bytes, the walk's check trusted.
        let read = fetch(
            &path,
            0,
            (offset, len),
            in_chunk,
            walked,
            &Chunks::default(),
        );
        assert_eq!(&read.unwrap()[..], &noise[..]);
        // A byte of the stored message changed after the walk: refused.
        let mut changed = bytes.clone();
        let end = changed.len() - 1000;
        changed[end] ^= 0x40;
        std::fs::write(&path, &changed).unwrap();
        match fetch(
            &path,
            0,
            (offset, len),
            in_chunk,
            walked,
            &Chunks::default(),
        ) {
            Err(e) => assert!(e.1.contains(&format!("record at byte {offset}")), "{}", e.1),
            Ok(_) => panic!("a changed chunk was read back unchecked"),
        }
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn a_cut_is_read_to_the_cut_except_inside_a_chunk() {
        let whole = sample("none");
        // Cut inside the last (index) record: everything before is read.
        let path = temp_bag("cut-end", &whole[..whole.len() - 3]);
        let (seen, cut) = walk(&path).unwrap();
        assert_eq!((seen.len(), cut > 0), (3, true));
        // Cut inside the chunk: an error naming its byte.
        let chunk_at = bag(&[]).len();
        let path = temp_bag("cut-chunk", &whole[..chunk_at + 100]);
        let e = walk(&path).unwrap_err().1;
        assert!(
            e.contains("chunk at byte") && e.contains("cut short"),
            "{e}"
        );
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn damaged_lengths_are_refused_in_words() {
        let inner = [
            connection(0, "/depth", "sensor_msgs/Image"),
            message(0, 1, b"first"),
        ]
        .concat();
        // A chunk claiming 4 GiB uncompressed.
        let mut big = chunk("bz2", &inner);
        let size_at = big.windows(5).position(|w| w == b"size=").unwrap() + 5;
        big[size_at..size_at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        let path = temp_bag("claims", &bag(&big));
        let e = walk(&path).unwrap_err().1;
        assert!(e.contains("claims 4294967295 bytes uncompressed"), "{e}");
        // A record inside a chunk running past its end.
        let mut inner_bad = inner.clone();
        let last = inner_bad.len() - 9; // the data length of the message record
        inner_bad[last..last + 4].copy_from_slice(&1000u32.to_le_bytes());
        let path = temp_bag("inner", &bag(&chunk("none", &inner_bad)));
        let e = walk(&path).unwrap_err().1;
        assert!(e.contains("runs past its end"), "{e}");
        // A huge header length: read as a cut file, nothing allocated.
        let mut huge = bag(&[]);
        huge.extend_from_slice(&u32::MAX.to_le_bytes());
        let path = temp_bag("header", &huge);
        assert_eq!(walk(&path).unwrap().1, 4);
        // Not a bag at all.
        let path = temp_bag("magic", b"#ROSBAG V1.2\n");
        assert!(walk(&path).unwrap_err().1.contains("not a ROS 1 bag"));
        // Any cut of a compressed bag: an error or a shorter walk, no panic.
        let whole = sample("lz4");
        for n in 0..whole.len() {
            let path = temp_bag("any-cut", &whole[..n]);
            let _ = walk(&path);
        }
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn ros1_type_names_become_ros2_names() {
        assert_eq!(ros2_type_name("sensor_msgs/Image"), "sensor_msgs/msg/Image");
        assert_eq!(ros2_type_name("nav_msgs/Odometry"), "nav_msgs/msg/Odometry");
        assert_eq!(ros2_type_name("tf/tfMessage"), "tf2_msgs/msg/TFMessage");
        assert_eq!(
            ros2_type_name("tf2_msgs/TFMessage"),
            "tf2_msgs/msg/TFMessage"
        );
    }
}
