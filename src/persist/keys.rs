//! Exact voxel keys of a database frame in the log: the key pool's relative
//! 32-bit words (see [`crate::key_pool`]), ascending, as LEB128 varints of the
//! difference to the previous word, in chunks of at most [`KEY_CHUNK_BYTES`]
//! (each chunk starts again from 0, so it decodes alone).
//!
//! Why deltas: a frame's voxels are a surface seen from one camera, sorted by
//! (x, y, z), so consecutive words mostly differ in z by a few voxels (one
//! byte) or step to the next y column (two bytes): about 1.5 bytes a key
//! instead of 4, so the exact keys of hundreds of database frames fit the
//! flash beside their sketches and every label.

/// Most chunks a frame's keys may take; a frame that needs more is stored
/// without its keys (compared by sketch).
pub const MAX_KEY_CHUNKS: usize = 8;

/// Bytes of encoded keys in one chunk (one log record: with its record
/// header it must fit the device's 768-byte record buffer, checked there).
pub const KEY_CHUNK_BYTES: usize = 736;

/// Bytes of the LEB128 encoding of `v`.
fn varint_len(v: u32) -> usize {
    match v {
        0..=0x7F => 1,
        0x80..=0x3FFF => 2,
        0x4000..=0x1F_FFFF => 3,
        0x20_0000..=0xFFF_FFFF => 4,
        _ => 5,
    }
}

/// How ascending `words` split into chunks: the chunks' encoded lengths
/// are reported to `chunk` in order (with the number of words in each);
/// returns the number of chunks and the total bytes.
fn split(words: &[u32], mut chunk: impl FnMut(usize, usize)) -> (usize, usize) {
    let (mut chunks, mut total) = (0, 0);
    let (mut bytes, mut count, mut prev) = (0usize, 0usize, 0u32);
    for &w in words {
        let len = varint_len(w.wrapping_sub(prev));
        if bytes + len > KEY_CHUNK_BYTES {
            chunk(bytes, count);
            chunks += 1;
            total += bytes;
            // A new chunk starts from 0: its first word is absolute.
            (bytes, count) = (varint_len(w), 1);
        } else {
            bytes += len;
            count += 1;
        }
        prev = w;
    }
    if count > 0 {
        chunk(bytes, count);
        chunks += 1;
        total += bytes;
    }
    (chunks, total)
}

/// Chunks and bytes the encoding of ascending `words` takes.
pub fn encoded_size(words: &[u32]) -> (usize, usize) {
    split(words, |_, _| {})
}

/// Bytes and words of chunk `index` of ascending `words`.
pub fn chunk_size(words: &[u32], index: usize) -> Option<(usize, usize)> {
    let mut n = 0;
    let mut found = None;
    split(words, |bytes, count| {
        if n == index {
            found = Some((bytes, count));
        }
        n += 1;
    });
    found
}

/// Encodes the words of chunk `index` of ascending `words` into `out`;
/// returns the bytes written and the number of words, or `None` when there
/// is no such chunk or `out` is too small.
pub fn encode_chunk(words: &[u32], index: usize, out: &mut [u8]) -> Option<(usize, usize)> {
    let mut start = 0;
    let mut found = None;
    let mut n = 0;
    split(words, |bytes, count| {
        if n == index {
            found = Some((start, bytes, count));
        }
        start += count;
        n += 1;
    });
    let (start, bytes, count) = found?;
    let out = out.get_mut(..bytes)?;
    let mut at = 0;
    let mut prev = 0u32;
    for &w in words.get(start..start + count)? {
        let mut v = w.wrapping_sub(prev);
        prev = w;
        loop {
            let byte = (v & 0x7F) as u8;
            v >>= 7;
            let slot = out.get_mut(at)?;
            at += 1;
            if v == 0 {
                *slot = byte;
                break;
            }
            *slot = byte | 0x80;
        }
    }
    Some((at, count))
}

/// The words of one chunk, in order; stops at a truncated or overlong varint.
pub fn decode(bytes: &[u8]) -> impl Iterator<Item = u32> + '_ {
    let mut rest = bytes;
    let mut prev = 0u32;
    core::iter::from_fn(move || {
        let mut v = 0u32;
        for shift in (0..35).step_by(7) {
            let (&b, r) = rest.split_first()?;
            rest = r;
            v |= u32::from(b & 0x7F).checked_shl(shift)?;
            if b & 0x80 == 0 {
                prev = prev.wrapping_add(v);
                return Some(prev);
            }
        }
        rest = &[];
        None
    })
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec::Vec;

    #[test]
    fn chunks_round_trip() {
        let words: Vec<u32> = (0..3000u32).map(|i| i * 37 + (i % 5) * 100_000).collect();
        let mut sorted = words.clone();
        sorted.sort_unstable();
        let (chunks, total) = encoded_size(&sorted);
        assert!(chunks > 1);
        let mut back = Vec::new();
        let mut sum = 0;
        for c in 0..chunks {
            let mut buf = [0u8; KEY_CHUNK_BYTES];
            let (len, count) = encode_chunk(&sorted, c, &mut buf).unwrap();
            sum += len;
            let got: Vec<u32> = decode(&buf[..len]).collect();
            assert_eq!(got.len(), count);
            back.extend(got);
        }
        assert_eq!(back, sorted);
        assert_eq!(sum, total);
        assert!(encode_chunk(&sorted, chunks, &mut [0u8; KEY_CHUNK_BYTES]).is_none());
    }

    #[test]
    fn truncated_input_stops_cleanly() {
        assert_eq!(decode(&[0x80]).count(), 0);
        assert_eq!(decode(&[0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x01]).count(), 0);
        assert_eq!(decode(&[5, 0x81]).collect::<Vec<_>>(), [5]);
    }
}
