//! The MCAP files of a rosbag2 recording, read with the `mcap` crate's record
//! parser; zstd and lz4 chunks are decompressed here ([`chunk_data`]).
//!
//! A bag can hold gigabytes of depth, so nothing is kept whole: [`scan`] walks
//! the top-level records once (a few chunks at a time, `read_ahead`) and hands
//! every message to a visitor with its [`Place`] — the top-level record's
//! offset and length and, for a message inside a chunk, its ordinal there —
//! and [`fetch`] reads one message back on demand, a chunk decompressed once
//! for the messages read from it in turn (kept by the reading). This works on
//! indexed and unindexed files alike (a recording cut short has no summary).

use super::bag::{err, BagError, Channel, Location, Message, MessageBytes, Place};
use super::kept_chunks::Chunks;
use super::lz4_frame;
use super::read_ahead::ReadAhead;
use mcap::records::{op, Record};
use std::collections::HashMap;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::ops::Range;
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

/// A chunk record read but not yet walked: its place and its body.
struct Pending {
    offset: u64,
    len: u64,
    body: Vec<u8>,
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
        channels: Channels::default(),
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
    channels: Channels,
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
        let mut magic = [0u8; 8];
        r.read_exact(&mut magic)
            .map_err(|_| err(path, "too short for an MCAP file"))?;
        if magic != mcap::MAGIC {
            return Err(err(path, "not an MCAP file (bad magic)"));
        }
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
            if opcode == op::CHUNK {
                let mut chunk = self.ahead.buffer();
                chunk.resize(len as usize, 0);
                r.read_exact(&mut chunk).map_err(io)?;
                // The chunk's `uncompressed_size`, after its two times.
                let claims = chunk
                    .get(16..24)
                    .and_then(|b| <[u8; 8]>::try_from(b).ok())
                    .map_or(0, u64::from_le_bytes);
                if self.ahead.is_full_for(claims) {
                    self.walk_pending()?;
                }
                let chunk = Pending {
                    offset,
                    len,
                    body: chunk,
                };
                self.ahead.push(chunk, claims);
                continue;
            }
            self.walk_pending()?;
            body.resize(len as usize, 0);
            r.read_exact(&mut body).map_err(io)?;
            let record = mcap::parse_record(opcode, &body)
                .map_err(|e| err(path, format!("record at byte {offset}: {e}")))?;
            let at = Location {
                file: self.index,
                place: Place::Mcap {
                    offset,
                    len,
                    in_chunk: None,
                },
            };
            match record {
                Record::Message { header, data } => {
                    deliver(path, &self.channels, &header, &data, at, self.visit)?
                }
                other => self.channels.note(path, &other)?,
            }
        }
    }

    /// Decompresses the pending chunks in parallel and walks them in order.
    fn walk_pending(&mut self) -> Result<(), BagError> {
        let Walk {
            index,
            path,
            channels,
            ahead,
            visit,
        } = self;
        let (index, path) = (*index, *path);
        ahead.walk(
            |c, out| {
                let bad =
                    |e: mcap::McapError| err(path, format!("record at byte {}: {e}", c.offset));
                let Record::Chunk { header, data } =
                    mcap::parse_record(op::CHUNK, &c.body).map_err(bad)?
                else {
                    return Err(err(path, format!("no chunk record at byte {}", c.offset)));
                };
                let bound = check_chunk(path, c.offset, &header, &data)?;
                // The records end the chunk's body: borrowed from it
                // rather than from the parsed record.
                let data = &c.body[c.body.len() - data.len()..];
                Ok((chunk_data(path, c.offset, &header, data, out)?, bound))
            },
            |c, records, bound| walk_chunk(path, index, channels, &mut **visit, c, bound, records),
            |c| c.body,
        )
    }
}

/// Hands on the messages of chunk `c` of file `index` (`path`; its
/// records decompressed, each at most `bound` bytes) to `visit`, noting
/// its schemas and channels.
fn walk_chunk(
    path: &Path,
    index: usize,
    channels: &mut Channels,
    visit: &mut dyn FnMut(Message<'_>) -> Result<(), BagError>,
    c: &Pending,
    bound: usize,
    records: &[u8],
) -> Result<(), BagError> {
    let mut ordinal = 0u32;
    chunk_records(path, c.offset, records, bound, &mut |inner| {
        if let Record::Message { header, data } = &inner {
            let at = Location {
                file: index,
                place: Place::Mcap {
                    offset: c.offset,
                    len: c.len,
                    in_chunk: Some(ordinal),
                },
            };
            ordinal += 1;
            deliver(path, channels, header, data, at, visit)
        } else {
            channels.note(path, &inner)
        }
    })
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

/// A chunk's records, decompressed and checked against the chunk's CRC
/// (when it has one): `data` itself when it is not compressed, else
/// `out`'s, its room reused without zeroing (the lz4 and zstd libraries
/// decode into it in one call; the `mcap` crate's chunk reader copied the
/// chunk in and out of buffers of its own, and decompressed it again for
/// every message read back).
fn chunk_data<'a>(
    path: &Path,
    offset: u64,
    header: &mcap::records::ChunkHeader,
    data: &'a [u8],
    out: &'a mut Vec<u8>,
) -> Result<&'a [u8], BagError> {
    let at = |e: String| err(path, format!("chunk at byte {offset}: {e}"));
    // Within what its data can hold ([`check_chunk`]), so within memory.
    let size = usize::try_from(header.uncompressed_size).unwrap_or(usize::MAX);
    let claims = |got: usize| {
        at(format!(
            "it claims {size} bytes uncompressed, its data gives {got}"
        ))
    };
    let records: &[u8] = match header.compression.as_str() {
        "" => data,
        "zstd" => {
            out.truncate(size);
            out.resize(size, 0);
            let got = zstd::bulk::decompress_to_buffer(data, out).map_err(|e| {
                at(format!(
                    "its zstd data does not decompress to {size} bytes: {e}"
                ))
            })?;
            if got != size {
                return Err(claims(got));
            }
            out
        }
        "lz4" => {
            // The chunk's CRC, when it has one, checks the same bytes.
            let checksums = match header.uncompressed_crc {
                0 => lz4_frame::Checksums::Verify,
                _ => lz4_frame::Checksums::Skip,
            };
            lz4_frame::decompress_into(data, size, out, checksums)
                .map_err(|e| at(format!("its lz4 data does not decompress: {e}")))?;
            out
        }
        other => {
            return Err(at(format!(
                "compression `{other}` is not supported (zstd, lz4 or none)"
            )))
        }
    };
    if header.uncompressed_crc != 0 && crc32fast::hash(records) != header.uncompressed_crc {
        return Err(at("its data does not match its CRC (damaged)".into()));
    }
    Ok(records)
}

/// Hands the records of a chunk (`records`, decompressed, of the chunk
/// record at `offset`) to `visit`, each a slice of `records`, at most
/// `bound` bytes (a damaged length inside the chunk is refused, not
/// reserved).
fn chunk_records(
    path: &Path,
    offset: u64,
    records: &[u8],
    bound: usize,
    visit: &mut dyn FnMut(Record<'_>) -> Result<(), BagError>,
) -> Result<(), BagError> {
    let mut at = 0;
    while at < records.len() {
        let body = record_at(path, offset, records, at, bound)?;
        let record = mcap::parse_record(records[at], &records[body.clone()])
            .map_err(|e| err(path, format!("chunk at byte {offset}: {e}")))?;
        visit(record)?;
        at = body.end;
    }
    Ok(())
}

/// Where the body of the record at byte `at` of a chunk's `records` lies,
/// checked to end within them and to be at most `bound` bytes.
fn record_at(
    path: &Path,
    offset: u64,
    records: &[u8],
    at: usize,
    bound: usize,
) -> Result<Range<usize>, BagError> {
    let rest = &records[at..];
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
    Ok(at + 9..at + 9 + len)
}

/// Where the data of message `k` (its ordinal among the chunk's messages)
/// lies in a chunk's decompressed `records`.
fn message_in_chunk(
    path: &Path,
    offset: u64,
    records: &[u8],
    k: u32,
) -> Result<Range<usize>, BagError> {
    // A message record's body: channel id (2 bytes), sequence (4), log
    // time (8), publish time (8), then the data.
    const MESSAGE_HEADER: usize = 22;
    let (mut at, mut n) = (0usize, 0u32);
    while at < records.len() {
        let body = record_at(path, offset, records, at, usize::MAX)?;
        if records[at] == op::MESSAGE {
            if n == k {
                if body.len() < MESSAGE_HEADER {
                    break;
                }
                return Ok(body.start + MESSAGE_HEADER..body.end);
            }
            n += 1;
        }
        at = body.end;
    }
    Err(err(
        path,
        format!("chunk at byte {offset} has no message {k}"),
    ))
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
        len: data.len(),
        at,
    })
}

/// Reads back the message whose top-level record's body is `len` bytes at
/// `offset` of file `path` (`in_chunk`: its ordinal in that chunk). A chunk
/// is looked for in `chunks` (under `file`, the file's index in its bag)
/// before it is read, and kept there.
pub fn fetch(
    path: &Path,
    file: usize,
    offset: u64,
    len: u64,
    in_chunk: Option<u32>,
    chunks: &Chunks,
) -> Result<MessageBytes, BagError> {
    if let Some(k) = in_chunk {
        if let Some(chunk) = chunks.get(file, offset) {
            let range = message_in_chunk(path, offset, &chunk, k)?;
            return Ok(MessageBytes::InChunk(chunk, range));
        }
    }
    let io = |e: std::io::Error| err(path, e.to_string());
    let mut file_handle = File::open(path).map_err(io)?;
    file_handle.seek(SeekFrom::Start(offset)).map_err(io)?;
    let mut body = vec![0u8; len as usize];
    file_handle.read_exact(&mut body).map_err(io)?;
    let op = if in_chunk.is_some() {
        op::CHUNK
    } else {
        op::MESSAGE
    };
    let bad = |e: mcap::McapError| err(path, format!("record at byte {offset}: {e}"));
    match (mcap::parse_record(op, &body).map_err(bad)?, in_chunk) {
        (Record::Message { data, .. }, None) => Ok(MessageBytes::Own(data.into_owned())),
        (Record::Chunk { header, data }, Some(k)) => {
            let bound = check_chunk(path, offset, &header, &data)?;
            let mut out = chunks.buffer();
            let records = chunk_data(path, offset, &header, &data, &mut out)?;
            // Every record checked once, before the chunk is kept.
            chunk_records(path, offset, records, bound, &mut |_| Ok(()))?;
            let range = message_in_chunk(path, offset, records, k)?;
            // An uncompressed chunk is the record's data: kept as a copy.
            let kept = if header.compression.is_empty() {
                records.to_vec()
            } else {
                out
            };
            Ok(MessageBytes::InChunk(
                chunks.keep(file, offset, kept),
                range,
            ))
        }
        _ => Err(err(path, format!("no message record at byte {offset}"))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use std::collections::BTreeMap;

    /// `messages` on one channel, written by the `mcap` crate's writer with
    /// `compression`, in chunks of about 200 kB (several messages each).
    fn write(path: &Path, compression: Option<mcap::Compression>, messages: &[Vec<u8>]) {
        let out = std::io::BufWriter::new(File::create(path).unwrap());
        let mut w = mcap::WriteOptions::new()
            .compression(compression)
            .chunk_size(Some(200_000))
            .create(out)
            .unwrap();
        let channel = w.add_channel(0, "/t", "cdr", &BTreeMap::new()).unwrap();
        for (i, m) in messages.iter().enumerate() {
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence: i as u32,
                log_time: i as u64,
                publish_time: i as u64,
            };
            w.write_to_known_channel(&header, m).unwrap();
        }
        w.finish().unwrap();
    }

    /// Messages of every size up to 100 kB, depth-like bytes (smooth with
    /// noise) so that they compress.
    fn messages(rng: &mut SplitMix64) -> Vec<Vec<u8>> {
        (0..40)
            .map(|i| {
                let n = if i % 7 == 0 {
                    rng.below(30)
                } else {
                    rng.below(100_000)
                } as usize;
                let mut v = 0u8;
                (0..n)
                    .map(|_| {
                        v = v.wrapping_add(rng.below(3) as u8);
                        v
                    })
                    .collect()
            })
            .collect()
    }

    /// Every message a walk of `path` hands on, and where.
    fn walk(path: &Path) -> Result<Vec<(Vec<u8>, Place)>, BagError> {
        let mut seen = Vec::new();
        scan(0, path, &mut |m| {
            seen.push((m.data.to_vec(), m.at.place));
            Ok(())
        })?;
        Ok(seen)
    }

    fn read_back(path: &Path, place: Place, chunks: &Chunks) -> Result<Vec<u8>, BagError> {
        let Place::Mcap {
            offset,
            len,
            in_chunk,
        } = place
        else {
            panic!("{place}")
        };
        fetch(path, 0, offset, len, in_chunk, chunks).map(|bytes| bytes.to_vec())
    }

    #[test]
    fn zstd_lz4_and_plain_chunks_walk_and_read_back_every_message() {
        let mut rng = SplitMix64::new(38);
        let messages = messages(&mut rng);
        let dir = std::env::temp_dir().join(format!("placedb-mcap-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for compression in [
            None,
            Some(mcap::Compression::Zstd),
            Some(mcap::Compression::Lz4),
        ] {
            let path = dir.join(format!("{compression:?}.mcap"));
            write(&path, compression, &messages);
            let seen = walk(&path).unwrap();
            let walked: Vec<_> = seen.iter().map(|(data, _)| data.clone()).collect();
            assert!(walked == messages, "{compression:?}: walked");
            let chunked = seen
                .iter()
                .filter(|(_, p)| matches!(p, Place::Mcap { in_chunk: Some(k), .. } if *k > 0))
                .count();
            assert!(chunked > 10, "{compression:?}: several messages a chunk");
            // One reading, in order (a chunk decompressed, then kept), and
            // backwards (each chunk read again once it was dropped).
            let chunks = Chunks::default();
            for (data, place) in seen.iter().chain(seen.iter().rev()) {
                assert!(&read_back(&path, *place, &chunks).unwrap() == data);
            }
            let at = Location {
                file: 0,
                place: seen[5].1,
            };
            assert!(super::super::bag::fetch(&path, at).unwrap() == seen[5].0);
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_damaged_compressed_chunk_is_an_error_naming_it() {
        let mut rng = SplitMix64::new(39);
        let messages = messages(&mut rng);
        let dir = std::env::temp_dir().join(format!("placedb-mcap-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for compression in [mcap::Compression::Zstd, mcap::Compression::Lz4] {
            let path = dir.join(format!("{compression:?}.mcap"));
            write(&path, Some(compression), &messages);
            let seen = walk(&path).unwrap();
            let Place::Mcap { offset, len, .. } = seen[20].1 else {
                panic!()
            };
            // A byte in the middle of the chunk's compressed data.
            let mut bytes = std::fs::read(&path).unwrap();
            bytes[(offset + len / 2) as usize] ^= 0x10;
            std::fs::write(&path, &bytes).unwrap();
            let e = walk(&path).unwrap_err();
            assert!(e.1.contains(&format!("chunk at byte {offset}")), "{}", e.1);
            let e = read_back(&path, seen[20].1, &Chunks::default()).unwrap_err();
            assert!(e.1.contains(&format!("chunk at byte {offset}")), "{}", e.1);
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
