//! The MCAP files of a rosbag2 recording, read with the `mcap` crate's record
//! parser and chunk reader (which decompresses zstd and lz4 chunks).
//!
//! A bag can hold gigabytes of depth, so nothing is kept whole: [`scan`] walks
//! the top-level records once (reading one chunk at a time) and hands every
//! message to a visitor with its [`Place`] — the top-level record's offset and
//! length and, for a message inside a chunk, its ordinal there — and [`fetch`]
//! reads one message back on demand. This works on indexed and unindexed files
//! alike (a recording cut short has no summary).

use super::bag::{err, BagError, Channel, Location, Message, Place};
use mcap::records::{op, Record};
use std::collections::HashMap;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

/// Channels and schemas seen so far (by id, per file).
#[derive(Default)]
struct Channels {
    schemas: HashMap<u16, String>,
    channels: HashMap<u16, Channel>,
}

impl Channels {
    fn note(&mut self, path: &Path, record: &Record<'_>) -> Result<(), BagError> {
        match record {
            Record::Schema { header, .. } => {
                self.schemas.insert(header.id, header.name.clone());
            }
            Record::Channel(c) => {
                let schema = match c.schema_id {
                    0 => String::new(),
                    id => self.schemas.get(&id).cloned().ok_or_else(|| {
                        err(
                            path,
                            format!("channel {} names unknown schema {id}", c.topic),
                        )
                    })?,
                };
                self.channels.insert(
                    c.id,
                    Channel {
                        topic: c.topic.clone(),
                        schema,
                        encoding: c.message_encoding.clone(),
                    },
                );
            }
            _ => {}
        }
        Ok(())
    }
}

/// Reads the 9-byte record head (opcode, body length) at the reader's position;
/// `None` at the end of the file.
fn record_head(r: &mut impl Read) -> std::io::Result<Option<(u8, u64)>> {
    let mut head = [0u8; 9];
    let mut got = 0;
    while got < head.len() {
        match r.read(&mut head[got..])? {
            0 if got == 0 => return Ok(None),
            0 => return Err(std::io::ErrorKind::UnexpectedEof.into()),
            n => got += n,
        }
    }
    let len = u64::from_le_bytes(head[1..].try_into().unwrap_or([0; 8]));
    Ok(Some((head[0], len)))
}

/// Walks every message of file `index` (`path`), in file order. Returns
/// how many bytes at its end were cut short (a recording that stopped
/// mid-write), 0 for a whole file.
pub fn scan(
    index: usize,
    path: &Path,
    visit: &mut dyn FnMut(Message<'_>) -> Result<(), BagError>,
) -> Result<u64, BagError> {
    let io = |e: std::io::Error| err(path, e.to_string());
    let file = File::open(path).map_err(io)?;
    let size = file.metadata().map_err(io)?.len();
    let mut r = BufReader::with_capacity(1 << 16, file);
    let mut magic = [0u8; 8];
    r.read_exact(&mut magic)
        .map_err(|_| err(path, "too short for an MCAP file"))?;
    if magic != mcap::MAGIC {
        return Err(err(path, "not an MCAP file (bad magic)"));
    }
    let mut channels = Channels::default();
    let mut pos = 8u64;
    let mut body = Vec::new();
    loop {
        let Some((opcode, len)) = record_head(&mut r).map_err(io)? else {
            return Ok(0);
        };
        let offset = pos + 9;
        if len > size.saturating_sub(offset) {
            // The recording stopped mid-record: keep what came before.
            return Ok(size - pos);
        }
        pos = offset + len;
        match opcode {
            op::DATA_END | op::FOOTER => return Ok(0),
            op::SCHEMA | op::CHANNEL | op::MESSAGE | op::CHUNK => {}
            _ => {
                r.seek_relative(len as i64).map_err(io)?;
                continue;
            }
        }
        body.resize(len as usize, 0);
        r.read_exact(&mut body).map_err(io)?;
        let record = mcap::parse_record(opcode, &body)
            .map_err(|e| err(path, format!("record at byte {offset}: {e}")))?;
        let at = Location {
            file: index,
            place: Place::Mcap {
                offset,
                len,
                in_chunk: None,
            },
        };
        match record {
            Record::Chunk { header, data } => {
                let mut ordinal = 0u32;
                let bound = check_chunk(path, offset, &header, &data)?;
                chunk_records(path, offset, &body, bound, &mut |inner| {
                    if let Record::Message { header, data } = &inner {
                        let at = Location {
                            file: index,
                            place: Place::Mcap {
                                offset,
                                len,
                                in_chunk: Some(ordinal),
                            },
                        };
                        ordinal += 1;
                        deliver(path, &channels, header, data, at, visit)
                    } else {
                        channels.note(path, &inner)
                    }
                })?;
            }
            Record::Message { header, data } => {
                deliver(path, &channels, &header, &data, at, visit)?
            }
            other => channels.note(path, &other)?,
        }
    }
}

/// Refuses a chunk whose claimed uncompressed size its data cannot hold:
/// the chunk reader makes a buffer of that size before decompressing, and
/// a damaged header (a few bytes) could ask for terabytes. No lz4 block
/// expands more than 255 times, no zstd block more than 128 KiB from 4
/// bytes; uncompressed data is its own size, and its records must tile it
/// exactly (the chunk reader counts them off the chunk's size without a
/// check, and overflows on a record that runs past the end). Returns the
/// largest a record of the chunk can be.
fn check_chunk(
    path: &Path,
    offset: u64,
    header: &mcap::records::ChunkHeader,
    data: &[u8],
) -> Result<usize, BagError> {
    let compressed = data.len();
    let n = compressed as u64;
    if header.compression.is_empty() {
        let mut rest = data;
        while !rest.is_empty() {
            let len = rest
                .get(1..9)
                .and_then(|l| <[u8; 8]>::try_from(l).ok())
                .map(u64::from_le_bytes);
            match len.filter(|&l| l <= (rest.len() - 9) as u64) {
                Some(l) => rest = &rest[9 + l as usize..],
                None => {
                    return Err(err(
                        path,
                        format!(
                            "chunk at byte {offset}: a record at byte {} of its data runs past \
                             its end",
                            compressed - rest.len()
                        ),
                    ))
                }
            }
        }
    }
    let most = match header.compression.as_str() {
        "" => n,
        "lz4" => n.saturating_mul(255).saturating_add(64),
        _ => n.saturating_mul(32 * 1024).saturating_add(128 * 1024),
    };
    if header.uncompressed_size > most {
        return Err(err(
            path,
            format!(
                "chunk at byte {offset}: {} bytes cannot hold the {} bytes it claims \
                 uncompressed (a damaged chunk header)",
                compressed, header.uncompressed_size
            ),
        ));
    }
    Ok(usize::try_from(most.max(n)).unwrap_or(usize::MAX))
}

/// Hands the records of a chunk (`body`, the chunk record's body at
/// `offset`) to `visit`, decompressed, CRC-checked, every record at most
/// `bound` bytes: the reader reserves a record's claimed length before
/// decompressing it, so a damaged length inside the chunk must be capped
/// too (`mcap::read::ChunkReader` has no such cap).
fn chunk_records(
    path: &Path,
    offset: u64,
    body: &[u8],
    bound: usize,
    visit: &mut dyn FnMut(Record<'_>) -> Result<(), BagError>,
) -> Result<(), BagError> {
    use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
    let bad = |e: mcap::McapError| err(path, format!("chunk at byte {offset}: {e}"));
    // An uncompressed chunk (what rosbag2 writes by default) is walked in
    // place: its records are slices of `body`, where the chunk reader would
    // copy the chunk twice (depth messages are hundreds of kilobytes).
    if let Record::Chunk { header, data } = mcap::parse_record(op::CHUNK, body).map_err(bad)? {
        if header.compression.is_empty() {
            return plain_chunk_records(path, offset, header.uncompressed_crc, &data, bound, visit);
        }
    }
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_start_magic(true)
            .with_skip_end_magic(true)
            .with_validate_chunk_crcs(true)
            .with_record_length_limit(bound),
    );
    // The chunk as a record of its own, as the file holds it.
    let mut framed = Vec::with_capacity(9 + body.len());
    framed.push(op::CHUNK);
    framed.extend_from_slice(&(body.len() as u64).to_le_bytes());
    framed.extend_from_slice(body);
    let mut rest = framed.as_slice();
    while let Some(event) = reader.next_event() {
        match event.map_err(bad)? {
            LinearReadEvent::ReadRequest(need) => {
                let n = need.min(rest.len());
                reader.insert(n).copy_from_slice(&rest[..n]);
                reader.notify_read(n);
                rest = &rest[n..];
            }
            LinearReadEvent::Record { data, opcode } => {
                visit(mcap::parse_record(opcode, data).map_err(bad)?)?
            }
        }
    }
    Ok(())
}

/// [`chunk_records`] of an uncompressed chunk's `data`: CRC-checked (when
/// the chunk has a CRC), each record a slice of `data`, at most `bound`
/// bytes.
fn plain_chunk_records(
    path: &Path,
    offset: u64,
    crc: u32,
    data: &[u8],
    bound: usize,
    visit: &mut dyn FnMut(Record<'_>) -> Result<(), BagError>,
) -> Result<(), BagError> {
    if crc != 0 && crc32fast::hash(data) != crc {
        return Err(err(
            path,
            format!("chunk at byte {offset}: its data does not match its CRC (damaged)"),
        ));
    }
    let mut rest = data;
    while !rest.is_empty() {
        let at = data.len() - rest.len();
        let len = rest
            .get(1..9)
            .and_then(|l| <[u8; 8]>::try_from(l).ok())
            .map(u64::from_le_bytes)
            .and_then(|l| usize::try_from(l).ok())
            .filter(|&l| l <= rest.len() - 9 && l <= bound)
            .ok_or_else(|| {
                err(
                    path,
                    format!(
                        "chunk at byte {offset}: a record at byte {at} of its data runs past its end"
                    ),
                )
            })?;
        let record = mcap::parse_record(rest[0], &rest[9..9 + len])
            .map_err(|e| err(path, format!("chunk at byte {offset}: {e}")))?;
        visit(record)?;
        rest = &rest[9 + len..];
    }
    Ok(())
}

fn deliver(
    path: &Path,
    channels: &Channels,
    header: &mcap::records::MessageHeader,
    data: &[u8],
    at: Location,
    visit: &mut dyn FnMut(Message<'_>) -> Result<(), BagError>,
) -> Result<(), BagError> {
    let channel = channels.channels.get(&header.channel_id).ok_or_else(|| {
        err(
            path,
            format!(
                "message at {} is on unknown channel {}",
                at.place, header.channel_id
            ),
        )
    })?;
    visit(Message {
        channel,
        log_time: header.log_time,
        data,
        at,
    })
}

/// Reads back the message whose top-level record's body is `len` bytes at
/// `offset` of file `path` (`in_chunk`: its ordinal in that chunk).
pub fn fetch(
    path: &Path,
    offset: u64,
    len: u64,
    in_chunk: Option<u32>,
) -> Result<Vec<u8>, BagError> {
    let io = |e: std::io::Error| err(path, e.to_string());
    let mut file = File::open(path).map_err(io)?;
    file.seek(SeekFrom::Start(offset)).map_err(io)?;
    let mut body = vec![0u8; len as usize];
    file.read_exact(&mut body).map_err(io)?;
    let op = if in_chunk.is_some() {
        op::CHUNK
    } else {
        op::MESSAGE
    };
    let bad = |e: mcap::McapError| err(path, format!("record at byte {offset}: {e}"));
    match (mcap::parse_record(op, &body).map_err(bad)?, in_chunk) {
        (Record::Message { data, .. }, None) => Ok(data.into_owned()),
        (Record::Chunk { header, data }, Some(k)) => {
            let bound = check_chunk(path, offset, &header, &data)?;
            let (mut n, mut found) = (0, None);
            chunk_records(path, offset, &body, bound, &mut |inner| {
                if let Record::Message { data, .. } = inner {
                    if n == k && found.is_none() {
                        found = Some(data.into_owned());
                    }
                    n += 1;
                }
                Ok(())
            })?;
            found.ok_or_else(|| err(path, format!("chunk at byte {offset} has no message {k}")))
        }
        _ => Err(err(path, format!("no message record at byte {offset}"))),
    }
}
