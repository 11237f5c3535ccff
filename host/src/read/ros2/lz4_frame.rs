//! LZ4 frames (a ROS 1 bag's `lz4` chunks, as `roslz4` and `lz4.frame`
//! write them) decompressed by the lz4 library's frame decoder in one
//! call over the whole chunk, straight into the caller's buffer.
//!
//! Why not the lz4 crate's `Decoder` (a `Read`): it feeds the library 32
//! KiB of input at a time, so the library copies every block bigger than
//! that into a buffer of its own before decoding it, and a buffer handed
//! to `Read::read_to_end` is zeroed first; for a bag of depth images the
//! copies cost a third as much as decompressing. Given whole blocks and
//! room for the whole output, the library decodes in place: no copy.
//!
//! The library checks every frame field, the blocks' bounds and, where the
//! frame carries them and the caller has no check of its own, its
//! checksums.

use lz4::liblz4::{
    LZ4FDecompressOptions, LZ4FDecompressionContext, LZ4F_createDecompressionContext,
    LZ4F_decompress, LZ4F_freeDecompressionContext, LZ4F_getErrorName, LZ4F_isError, LZ4F_VERSION,
};
use std::ffi::CStr;

/// A decompression context of the library, freed when dropped.
struct Context(LZ4FDecompressionContext);

impl Drop for Context {
    fn drop(&mut self) {
        // SAFETY: the context was created by the library (`new`) and is
        // freed once, here.
        unsafe { LZ4F_freeDecompressionContext(LZ4FDecompressionContext(self.0 .0)) };
    }
}

impl Context {
    fn new() -> Result<Context, String> {
        let mut ctx = LZ4FDecompressionContext(std::ptr::null_mut());
        // SAFETY: the library writes a new context's pointer into `ctx`.
        checked(unsafe { LZ4F_createDecompressionContext(&mut ctx, LZ4F_VERSION) })?;
        Ok(Context(ctx))
    }
}

/// The library's result code as a result: its error named in words.
fn checked(code: usize) -> Result<usize, String> {
    // SAFETY: both functions take any code; the name is a static string.
    unsafe {
        if LZ4F_isError(code) == 0 {
            return Ok(code);
        }
        let name = CStr::from_ptr(LZ4F_getErrorName(code));
        Err(name
            .to_string_lossy()
            .trim_start_matches("ERROR_")
            .replace('_', " "))
    }
}

/// Whether the frames' own checksums (xxHash-32 of each block and of the
/// content, where a frame has them) are verified.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Checksums {
    Verify,
    /// The output is checked another way (an MCAP chunk's CRC: verifying
    /// both cost a third of reading an lz4 MCAP bag), or these very bytes
    /// were verified already (a ROS 1 chunk read back after the walk: in a
    /// bag rosbag wrote, whose lz4 frames all carry a content checksum,
    /// verifying it twice was 30 % of the read).
    Skip,
}

/// The first bytes of an LZ4 frame.
const MAGIC: [u8; 4] = [0x04, 0x22, 0x4d, 0x18];

/// Whether the LZ4 frame `data` begins with has checksums to verify (its
/// flags' content or block checksum bit): a frame without any decodes the
/// same under [`Checksums::Skip`].
pub fn has_checksums(data: &[u8]) -> bool {
    const BLOCK_CHECKSUM: u8 = 1 << 4;
    const CONTENT_CHECKSUM: u8 = 1 << 2;
    data.starts_with(&MAGIC)
        && data
            .get(4)
            .is_some_and(|flags| flags & (BLOCK_CHECKSUM | CONTENT_CHECKSUM) != 0)
}

/// Decompresses the LZ4 frames of `data` (one, or several one after the
/// other) into `out`: exactly `size` bytes, else an error in words.
/// `out`'s room is reused without being zeroed where it is already there
/// (every byte is written before it is read).
pub fn decompress_into(
    data: &[u8],
    size: usize,
    out: &mut Vec<u8>,
    checksums: Checksums,
) -> Result<(), String> {
    out.truncate(size);
    out.resize(size, 0);
    let ctx = Context::new()?;
    // The library's options: `stableDst` (0: none promised), then
    // `skipChecksums` (lz4frame.h, the bundled lz4 1.10), then two fields
    // that must be zero.
    let skip = u32::from(checksums == Checksums::Skip);
    let options = LZ4FDecompressOptions {
        stable_dst: 0,
        reserved: [skip, 0, 0],
    };
    let (mut read, mut written) = (0usize, 0usize);
    loop {
        let (src, dst) = (&data[read..], &mut out[written..]);
        let (mut src_len, mut dst_len) = (src.len(), dst.len());
        // SAFETY: `src` and `dst` are live slices of the lengths passed;
        // the library reads at most `src_len` bytes, writes at most
        // `dst_len`, and says how many it did in both.
        let next = checked(unsafe {
            LZ4F_decompress(
                ctx.0,
                dst.as_mut_ptr(),
                &mut dst_len,
                src.as_ptr(),
                &mut src_len,
                &options,
            )
        })?;
        read += src_len.min(src.len());
        written += dst_len.min(dst.len());
        if next == 0 && read == data.len() {
            break;
        }
        if src_len == 0 && dst_len == 0 {
            // The library stops only for want of room or of input.
            return Err(if read < data.len() {
                "it holds more bytes than the chunk claims".into()
            } else {
                format!("it ends inside a frame, after {written} of {size} bytes")
            });
        }
    }
    if written != size {
        return Err(format!("it holds {written} bytes, not {size}"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use std::io::{Read, Write};

    /// `data` as the lz4 library's frame encoder writes it.
    fn encode(data: &[u8], linked: bool, checksums: bool, block: lz4::BlockSize) -> Vec<u8> {
        let mut encoder = lz4::EncoderBuilder::new()
            .block_size(block)
            .block_mode(if linked {
                lz4::BlockMode::Linked
            } else {
                lz4::BlockMode::Independent
            })
            .block_checksum(if checksums {
                lz4::liblz4::BlockChecksum::BlockChecksumEnabled
            } else {
                lz4::liblz4::BlockChecksum::NoBlockChecksum
            })
            .checksum(if checksums {
                lz4::ContentChecksum::ChecksumEnabled
            } else {
                lz4::ContentChecksum::NoChecksum
            })
            .build(Vec::new())
            .unwrap();
        encoder.write_all(data).unwrap();
        let (frame, result) = encoder.finish();
        result.unwrap();
        frame
    }

    /// Depth-image-like bytes: smooth 16-bit values with holes, jumps and
    /// noise, so blocks hold both matches and literals.
    fn depth_bytes(rng: &mut SplitMix64, n: usize) -> Vec<u8> {
        let mut v = 1000u16;
        (0..n / 2)
            .flat_map(|_| {
                v = match rng.below(50) {
                    0 => 0,
                    1 => rng.below(65536) as u16,
                    _ => v.wrapping_add(rng.below(5) as u16).wrapping_sub(2),
                };
                v.to_le_bytes()
            })
            .collect()
    }

    #[test]
    fn every_block_mode_and_size_decompresses_whole() {
        let mut rng = SplitMix64::new(4);
        for n in [0usize, 2, 100, 70_000, 300_000, 1_300_000] {
            let data = depth_bytes(&mut rng, n);
            for linked in [true, false] {
                for checksums in [true, false] {
                    for block in [lz4::BlockSize::Max64KB, lz4::BlockSize::Max4MB] {
                        let frame = encode(&data, linked, checksums, block);
                        assert_eq!(has_checksums(&frame), checksums);
                        let mut out = vec![9; 3];
                        decompress_into(&frame, data.len(), &mut out, Checksums::Verify).unwrap();
                        assert!(out == data, "{n} bytes, linked {linked}");
                        // Two frames one after the other, into room left
                        // from a longer chunk.
                        let two = [&frame[..], &frame].concat();
                        out.resize(5 * data.len() + 7, 3);
                        decompress_into(&two, 2 * data.len(), &mut out, Checksums::Verify).unwrap();
                        assert!(out == [&data[..], &data].concat(), "{n} bytes twice");
                    }
                }
            }
        }
    }

    #[test]
    fn damage_is_an_error_in_words_or_the_same_bytes_the_stream_decoder_gives() {
        let mut rng = SplitMix64::new(5);
        let data = depth_bytes(&mut rng, 200_000);
        let frames = [
            encode(&data, true, true, lz4::BlockSize::Max64KB),
            encode(&data, false, false, lz4::BlockSize::Max64KB),
        ];
        for case in 0..600 {
            let mut frame = frames[case % 2].clone();
            if case % 3 == 0 {
                frame.truncate(rng.below(frame.len() as u64) as usize);
            } else {
                for _ in 0..=rng.below(3) {
                    let at = rng.below(frame.len() as u64) as usize;
                    frame[at] ^= 1 << rng.below(8);
                }
            }
            let mut out = Vec::new();
            let ours = decompress_into(&frame, data.len(), &mut out, Checksums::Verify);
            // Skipped, the checksums make no other difference.
            let mut unchecked = Vec::new();
            if decompress_into(&frame, data.len(), &mut unchecked, Checksums::Skip).is_ok()
                && ours.is_ok()
            {
                assert!(unchecked == out, "case {case}: skipping the checksums");
            }
            if let Err(e) = &ours {
                assert!(!e.is_empty() && !e.contains("ERROR"), "case {case}: {e}");
            }
            // Checksummed frames decompress to the chunk or not at all.
            if case % 2 == 0 {
                assert!(ours.is_err() || out == data, "case {case}: checksummed");
            }
            // Where the stream decoder gives the claimed bytes, so does
            // this one.
            let mut want = Vec::new();
            let stream = lz4::Decoder::new(&frame[..]).and_then(|mut d| d.read_to_end(&mut want));
            if stream.is_ok() && want.len() == data.len() && ours.is_ok() {
                assert!(out == want, "case {case}");
            }
        }
        let mut out = Vec::new();
        let whole = &frames[0];
        assert!(
            decompress_into(whole, data.len() - 1, &mut out, Checksums::Verify)
                .unwrap_err()
                .contains("more bytes than the chunk claims")
        );
        assert!(
            decompress_into(whole, data.len() + 1, &mut out, Checksums::Verify)
                .unwrap_err()
                .contains(&format!(
                    "holds {} bytes, not {}",
                    data.len(),
                    data.len() + 1
                ))
        );
        assert!(decompress_into(b"BZh91AY&SY", 5, &mut out, Checksums::Verify).is_err());
        assert!(decompress_into(&[], 0, &mut out, Checksums::Verify).is_err());
        // A damaged content checksum: refused when verified; skipped (the
        // caller checks the bytes itself), the data comes out whole.
        let mut bad_sum = whole.clone();
        *bad_sum.last_mut().unwrap() ^= 1;
        assert!(
            decompress_into(&bad_sum, data.len(), &mut out, Checksums::Verify)
                .unwrap_err()
                .contains("hecksum")
        );
        decompress_into(&bad_sum, data.len(), &mut out, Checksums::Skip).unwrap();
        assert!(out == data);
        let cut = &whole[..whole.len() / 2];
        assert!(
            decompress_into(cut, data.len(), &mut out, Checksums::Verify)
                .unwrap_err()
                .contains("ends inside a frame")
        );
    }
}
