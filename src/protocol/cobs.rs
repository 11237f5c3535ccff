//! The receive path's one pass over a frame: COBS decoded in place, and the
//! CRC-32 of the decoded bytes computed as they move.
//!
//! Every depth sample a device receives goes through here, so the two jobs
//! share one loop instead of a COBS pass, a copy per block and a CRC pass.
//! The CRC is [`super::CRC`]'s (CRC-32/ISO-HDLC) over the whole payload, its
//! own 4 CRC bytes included: that is [`CRC_RESIDUE`] exactly when the CRC
//! bytes are right (appending 4 bytes maps every register value to a distinct
//! one), so the message need not be known before the check.

use core::cell::Cell;

/// CRC-32/ISO-HDLC of any message followed by its own CRC (little-endian).
pub(super) const CRC_RESIDUE: u32 = 0x2144_DF1C;

/// The reflected CRC-32/ISO-HDLC polynomial.
const POLY: u32 = 0xEDB8_8320;

/// Byte-at-a-time table of the polynomial (1 KiB, in flash).
// Evaluated at compile time: a bad index would fail the build, not panic.
#[allow(clippy::indexing_slicing)]
static TABLE: [u32; 256] = {
    let mut table = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut bit = 0;
        while bit < 8 {
            c = if c & 1 != 0 { (c >> 1) ^ POLY } else { c >> 1 };
            bit += 1;
        }
        table[i] = c;
        i += 1;
    }
    table
};

/// The CRC register after one more byte.
#[inline(always)]
fn crc_byte(crc: u32, byte: u8) -> u32 {
    let entry = TABLE.get(usize::from((crc as u8) ^ byte)).copied();
    entry.unwrap_or(0) ^ (crc >> 8)
}

/// Decodes the COBS bytes in `buf` in place; returns the decoded length and
/// the CRC-32/ISO-HDLC of the decoded bytes, or `None` when the bytes are not
/// valid COBS. `buf` holds no 0x00 (`FrameDecoder::push` ends a frame at
/// every 0x00), so only the block codes need checking.
// Out of line: inlined into a board's receive loop it competes for
// registers, and the per-byte loop is what matters.
#[inline(never)]
pub(super) fn decode_in_place(buf: &mut [u8]) -> Option<(usize, u32)> {
    let n = buf.len();
    let mut crc = u32::MAX;
    let mut read = 0usize;
    let mut write = 0usize;
    while read < n {
        let code = usize::from(*buf.get(read)?);
        if code == 0 {
            return None;
        }
        // The block's data is `read + 1..read + code`, moved down to
        // `write` (`write <= read` always holds): within `block`, byte
        // `k + gap` moves to `k`, forwards, so nothing unread is overwritten.
        // Cells give the two overlapping views without index checks.
        let block_end = read.checked_add(code)?;
        let block = Cell::from_mut(buf.get_mut(write..block_end)?).as_slice_of_cells();
        let gap = read + 1 - write;
        for (to, from) in block.iter().zip(block.get(gap..)?) {
            let byte = from.get();
            to.set(byte);
            crc = crc_byte(crc, byte);
        }
        write += code - 1;
        read = block_end;
        if code != 0xFF && read < n {
            *buf.get_mut(write)? = 0;
            crc = crc_byte(crc, 0);
            write += 1;
        }
    }
    Some((write, !crc))
}

#[cfg(test)]
mod tests {
    use super::*;
    use postcard::ser_flavors::{Cobs, Flavor, Slice};

    fn cobs(data: &[u8], out: &mut [u8]) -> usize {
        let mut f = Cobs::try_new(Slice::new(out)).unwrap();
        f.try_extend(data).unwrap();
        let frame = f.finalize().unwrap();
        // Without the trailing delimiter, as the decoder's buffer holds it.
        frame.len() - 1
    }

    #[test]
    fn decodes_and_checksums_like_the_crc_crate() {
        let mut data = [0u8; 700];
        for (i, b) in data.iter_mut().enumerate() {
            // Runs longer than a COBS block, zeros alone and in pairs.
            *b = match i % 300 {
                0 | 7 | 8 => 0,
                k => (k * 37 % 251) as u8 + 1,
            };
        }
        for len in [0, 1, 2, 9, 253, 254, 255, 256, 300, 509, 700] {
            let msg = &data[..len];
            let mut buf = [0u8; 800];
            let n = cobs(msg, &mut buf);
            let (decoded, crc) = decode_in_place(&mut buf[..n]).unwrap();
            assert_eq!(&buf[..decoded], msg, "len {len}");
            assert_eq!(crc, super::super::CRC.checksum(msg), "len {len}");
        }
    }

    #[test]
    fn a_message_and_its_crc_leave_the_residue() {
        let msg = b"placedb depth rows";
        let mut framed = [0u8; 22];
        framed[..18].copy_from_slice(msg);
        framed[18..].copy_from_slice(&super::super::CRC.checksum(msg).to_le_bytes());
        let mut buf = [0u8; 40];
        let n = cobs(&framed, &mut buf);
        assert_eq!(decode_in_place(&mut buf[..n]).unwrap().1, CRC_RESIDUE);
        framed[3] ^= 1;
        let n = cobs(&framed, &mut buf);
        assert_ne!(decode_in_place(&mut buf[..n]).unwrap().1, CRC_RESIDUE);
    }

    #[test]
    fn bad_codes_are_refused() {
        // A code pointing past the end.
        assert_eq!(decode_in_place(&mut [9, 1, 2]), None);
    }
}
