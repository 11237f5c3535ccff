//! 16-bit greyscale depth PNG decoding, and the on-demand [`DepthSource`] of
//! the file-based readers.
//!
//! Decoding is the floor under every host tool's time (1,000 frames of
//! 7-Scenes are 88 MB of PNG), so the one image kind a depth file can be,
//! 16-bit greyscale, has its own decoder here: the chunks are walked and
//! CRC-checked in one read of the file, the image data is inflated by
//! libdeflate in one call into a per-thread buffer, and each scanline is
//! unfiltered in place and written out in native byte order (folding in the
//! optional "65535 means no measurement" mapping) while it is in cache.
//! Interlaced files, which no depth camera writes, go through the `png` crate.

use super::unfilter;
use crate::error::ReadError;
use crate::sequence::{DepthImage, DepthSource};
use crate::vector_unit::VectorUnit;
use std::cell::RefCell;
use std::path::{Path, PathBuf};

fn png_error(path: &Path, reason: impl Into<String>) -> ReadError {
    ReadError::Png {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

fn read_file(path: &Path) -> Result<Vec<u8>, ReadError> {
    std::fs::read(path).map_err(|source| ReadError::Io {
        path: path.to_path_buf(),
        source,
    })
}

const SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a];
/// Signature plus the IHDR chunk (length, type, 13 bytes, CRC).
const HEADER_LEN: usize = 8 + 8 + 13 + 4;

/// What IHDR says, once it is known to describe a depth image.
#[derive(Debug, Clone, Copy)]
struct Header {
    width: u16,
    height: u16,
    interlaced: bool,
}

fn colour_name(colour_type: u8) -> &'static str {
    match colour_type {
        0 => "Grayscale",
        2 => "Rgb",
        3 => "Indexed",
        4 => "GrayscaleAlpha",
        6 => "Rgba",
        _ => "unknown colour type",
    }
}

/// Parses the signature and IHDR (the first [`HEADER_LEN`] bytes) and checks
/// that they describe a 16-bit greyscale image whose sides fit `u16`.
fn parse_header(path: &Path, bytes: &[u8]) -> Result<Header, ReadError> {
    let head = bytes
        .get(..HEADER_LEN)
        .ok_or_else(|| png_error(path, "file ends inside the PNG header"))?;
    if head[..8] != SIGNATURE {
        return Err(png_error(path, "not a PNG file (bad signature)"));
    }
    if head[8..16] != [0, 0, 0, 13, b'I', b'H', b'D', b'R'] {
        return Err(png_error(path, "the first chunk is not a 13-byte IHDR"));
    }
    let ihdr = &head[16..29];
    if crc32fast::hash(&head[12..29]).to_be_bytes() != head[29..33] {
        return Err(png_error(path, "CRC error in chunk IHDR"));
    }
    let be32 = |b: &[u8]| u32::from_be_bytes([b[0], b[1], b[2], b[3]]);
    let (width, height) = (be32(&ihdr[0..4]), be32(&ihdr[4..8]));
    let (bit_depth, colour_type) = (ihdr[8], ihdr[9]);
    let (compression, filter, interlace) = (ihdr[10], ihdr[11], ihdr[12]);
    if colour_type != 0 || bit_depth != 16 {
        return Err(png_error(
            path,
            format!(
                "image is {bit_depth}-bit {}, a depth image must be 16-bit Grayscale",
                colour_name(colour_type)
            ),
        ));
    }
    if compression != 0 || filter != 0 || interlace > 1 {
        return Err(png_error(
            path,
            format!("unknown compression {compression}, filter {filter} or interlace {interlace} method"),
        ));
    }
    let side = |v: u32| u16::try_from(v).ok().filter(|&s| s > 0);
    match (side(width), side(height)) {
        (Some(width), Some(height)) => Ok(Header {
            width,
            height,
            interlaced: interlace == 1,
        }),
        _ => Err(png_error(
            path,
            format!("image is {width}x{height}, sides must be 1..=65535"),
        )),
    }
}

/// Width and height of a depth PNG, reading only its header (and checking
/// that it is 16-bit greyscale).
pub(crate) fn depth_png_size(path: &Path) -> Result<(u16, u16), ReadError> {
    use std::io::Read;
    let file = std::fs::File::open(path).map_err(|source| ReadError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut head = Vec::with_capacity(HEADER_LEN);
    file.take(HEADER_LEN as u64)
        .read_to_end(&mut head)
        .map_err(|source| ReadError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    let h = parse_header(path, &head)?;
    Ok((h.width, h.height))
}

/// Width and height of a depth PNG held in memory, reading only its header
/// (and checking that it is 16-bit greyscale).
pub(crate) fn depth_png_bytes_size(bytes: &[u8]) -> Result<(u16, u16), ReadError> {
    let h = parse_header(Path::new(""), bytes)?;
    Ok((h.width, h.height))
}

/// Per-thread buffers, reused from frame to frame: a 640x480 image inflates
/// to 615 KB, and a fresh allocation that size is a fresh mapping whose
/// pages all fault in again.
struct Scratch {
    /// The concatenated IDAT payloads (the zlib stream).
    zlib: Vec<u8>,
    /// The inflated scanlines, each a filter byte and `2 * width` bytes.
    scanlines: Vec<u8>,
    inflater: libdeflater::Decompressor,
}

thread_local! {
    static SCRATCH: RefCell<Scratch> = RefCell::new(Scratch {
        zlib: Vec::new(),
        scanlines: Vec::new(),
        inflater: libdeflater::Decompressor::new(),
    });
}

/// Decodes a 16-bit greyscale depth PNG; with `invalid_65535`, the value 65535
/// ("no measurement" in 7-Scenes) becomes 0.
pub(crate) fn decode(path: &Path, invalid_65535: bool) -> Result<DepthImage, ReadError> {
    let mut image = DepthImage::default();
    decode_into(path, invalid_65535, &mut image)?;
    Ok(image)
}

/// [`decode`] into an existing image, reusing its buffer. On error the image
/// is left empty (0x0), never half-written.
pub(crate) fn decode_into(
    path: &Path,
    invalid_65535: bool,
    image: &mut DepthImage,
) -> Result<(), ReadError> {
    match decode_pixels(path, invalid_65535, &mut image.data) {
        Ok((width, height)) => {
            (image.width, image.height) = (width, height);
            Ok(())
        }
        Err(e) => {
            *image = DepthImage::default();
            Err(e)
        }
    }
}

/// Decodes the file's pixels into `data` (resized, not cleared first: a
/// buffer of the right size is overwritten without being zeroed) and
/// returns the image's width and height.
fn decode_pixels(
    path: &Path,
    invalid_65535: bool,
    data: &mut Vec<u16>,
) -> Result<(u16, u16), ReadError> {
    let bytes = read_file(path)?;
    decode_bytes(path, &bytes, invalid_65535, data)
}

/// [`decode_pixels`] of a file's bytes already read (`path` names it in
/// errors).
pub(crate) fn decode_bytes(
    path: &Path,
    bytes: &[u8],
    invalid_65535: bool,
    data: &mut Vec<u16>,
) -> Result<(u16, u16), ReadError> {
    let header = parse_header(path, bytes)?;
    let (width, height) = (header.width, header.height);
    if header.interlaced {
        *data = decode_with_png_crate(path, bytes, width, height)?;
        if invalid_65535 {
            blank_invalid(data);
        }
        return Ok((width, height));
    }
    SCRATCH.with(|scratch| {
        let scratch = &mut *scratch.borrow_mut();
        collect_image_data(path, bytes, &mut scratch.zlib)?;
        let row_bytes = 2 * width as usize;
        let total = (row_bytes + 1) * height as usize;
        // A header can claim 65535x65535 (8.6 GB) in a file of a few bytes:
        // no deflate stream inflates more than MAX_INFLATE_RATIO times its
        // size, so the image data must be large enough before the buffer
        // for its scanlines is made.
        if total / MAX_INFLATE_RATIO > scratch.zlib.len() {
            return Err(png_error(
                path,
                format!(
                    "{} bytes of image data cannot hold the {total} bytes of a \
                     {width}x{height} 16-bit image (the file is cut short or its header is wrong)",
                    scratch.zlib.len()
                ),
            ));
        }
        scratch.scanlines.resize(total, 0);
        let n = inflate(&scratch.zlib, &mut scratch.scanlines, &mut scratch.inflater)
            .map_err(|e| {
                let reason = match e {
                    Inflate::TooLong => format!(
                        "image data inflates to more than the {total} bytes of a {width}x{height} 16-bit image"
                    ),
                    Inflate::Invalid => "image data is not a valid zlib stream".into(),
                };
                png_error(path, reason)
            })?;
        if n != total {
            return Err(png_error(
                path,
                format!("image data inflates to {n} bytes, a {width}x{height} 16-bit image has {total}"),
            ));
        }
        data.resize(width as usize * height as usize, 0);
        unfilter_rows(
            path,
            &mut scratch.scanlines[..total],
            row_bytes,
            invalid_65535,
            data,
        )
    })?;
    Ok((width, height))
}

/// 65535, "no measurement" in 7-Scenes, becomes 0.
fn blank_invalid(values: &mut [u16]) {
    for v in values {
        if *v == u16::MAX {
            *v = 0;
        }
    }
}

/// Walks the chunks after IHDR up to IEND, checking every CRC, and gathers
/// the IDAT payloads into `zlib`. A file cut anywhere before IEND's end is
/// refused.
fn collect_image_data(path: &Path, bytes: &[u8], zlib: &mut Vec<u8>) -> Result<(), ReadError> {
    zlib.clear();
    let mut rest = bytes.get(HEADER_LEN..).unwrap_or_default();
    loop {
        let (len, kind) = match rest {
            [a, b, c, d, k0, k1, k2, k3, ..] => (
                u32::from_be_bytes([*a, *b, *c, *d]) as usize,
                [*k0, *k1, *k2, *k3],
            ),
            _ => return Err(png_error(path, "file ends before the IEND chunk")),
        };
        let name = String::from_utf8_lossy(&kind).into_owned();
        let Some(chunk) = rest.get(4..8 + len + 4) else {
            return Err(png_error(path, format!("file ends inside chunk {name}")));
        };
        let (typed, crc) = chunk.split_at(4 + len);
        if crc32fast::hash(typed).to_be_bytes() != crc {
            return Err(png_error(path, format!("CRC error in chunk {name}")));
        }
        let data = &typed[4..];
        match &kind {
            b"IDAT" => zlib.extend_from_slice(data),
            b"IEND" => break,
            // Ancillary chunks (lower-case first letter) carry nothing a
            // depth image needs; an unknown critical one cannot be ignored.
            _ if kind[0].is_ascii_lowercase() => {}
            _ => return Err(png_error(path, format!("unexpected critical chunk {name}"))),
        }
        rest = &rest[8 + len + 4..];
    }
    if zlib.is_empty() {
        return Err(png_error(path, "no IDAT chunk"));
    }
    Ok(())
}

/// The largest ratio of inflated to deflated size: a deflate block codes a
/// run of 258 bytes in at least 2 bits, 1032 bytes a byte (RFC 1951).
const MAX_INFLATE_RATIO: usize = 1032;

/// Why image data did not inflate.
enum Inflate {
    /// More bytes than the image has.
    TooLong,
    /// Not a complete, valid zlib stream (checksum included).
    Invalid,
}

/// Inflates a whole zlib stream into `out`, returning the bytes written.
///
/// Two inflaters, chosen by the compressor's own level hint (the FLEVEL
/// bits of the zlib header), for speed only: both check the stream and its
/// checksum and give the same bytes. libdeflate is about twice as fast on
/// ordinary streams (7-Scenes depth: level 9); fdeflate is three times as
/// fast on the streams the `png` crate's fast encoder writes, as
/// `placedb synth` does (level 0), where libdeflate slows to ~175 MB/s.
fn inflate(
    zlib: &[u8],
    out: &mut [u8],
    libdeflate: &mut libdeflater::Decompressor,
) -> Result<usize, Inflate> {
    let fastest = zlib.get(1).is_some_and(|flags| flags >> 6 == 0);
    if !fastest {
        return libdeflate.zlib_decompress(zlib, out).map_err(|e| match e {
            libdeflater::DecompressionError::InsufficientSpace => Inflate::TooLong,
            libdeflater::DecompressionError::BadData => Inflate::Invalid,
        });
    }
    let mut fdeflate = fdeflate::Decompressor::new();
    let (_, written) = fdeflate
        .read(zlib, out, 0, true)
        .map_err(|_| Inflate::Invalid)?;
    if fdeflate.is_done() {
        Ok(written)
    } else if written == out.len() {
        Err(Inflate::TooLong)
    } else {
        Err(Inflate::Invalid) // the stream ends early
    }
}

/// Unfilters the scanlines in place and writes the rows to `out` in native
/// byte order, 65535 as 0 with `invalid_65535`.
fn unfilter_rows(
    path: &Path,
    scanlines: &mut [u8],
    row_bytes: usize,
    invalid_65535: bool,
    out: &mut [u16],
) -> Result<(), ReadError> {
    unfilter::unfilter_scanlines(VectorUnit::best(), scanlines, row_bytes)
        .map_err(|f| png_error(path, format!("unknown scanline filter {f}")))?;
    write_native(scanlines, row_bytes, invalid_65535, out);
    Ok(())
}

/// Writes unfiltered scanlines to `out` in native byte order, 65535 as 0
/// with `invalid_65535`.
fn write_native(scanlines: &[u8], row_bytes: usize, invalid_65535: bool, out: &mut [u16]) {
    let rows = scanlines
        .chunks_exact(row_bytes + 1)
        .zip(out.chunks_exact_mut(row_bytes / 2));
    for (line, out_row) in rows {
        let bytes = &line[1..];
        #[cfg(target_arch = "x86_64")]
        let done = sse2::write_native_row(bytes, invalid_65535, out_row);
        #[cfg(not(target_arch = "x86_64"))]
        let done = 0;
        for (v, px) in out_row[done..]
            .iter_mut()
            .zip(bytes[2 * done..].chunks_exact(2))
        {
            *v = u16::from_be_bytes([px[0], px[1]]);
        }
        if invalid_65535 {
            blank_invalid(&mut out_row[done..]);
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod sse2 {
    //! [`super::write_native`] eight pixels at a time in SSE2 (part of
    //! every x86-64 CPU): a byte swap as two shifts, 65535 blanked with a
    //! compare. Wider vectors gain nothing here: the pass is bound by
    //! memory, not by its few instructions.
    use std::arch::x86_64::*;

    /// Writes the pixels of whole 16-byte blocks of `bytes` (big-endian
    /// pixels) to `out` and returns how many.
    pub(super) fn write_native_row(bytes: &[u8], invalid_65535: bool, out: &mut [u16]) -> usize {
        // SAFETY: the function only needs SSE2, which every x86-64 CPU has.
        unsafe { write_blocks(bytes, invalid_65535, out) }
    }

    #[target_feature(enable = "sse2")]
    fn write_blocks(bytes: &[u8], invalid_65535: bool, out: &mut [u16]) -> usize {
        let invalid = _mm_set1_epi16(if invalid_65535 { -1 } else { 0 });
        let mut done = 0;
        for (block, pixels) in bytes.chunks_exact(16).zip(out.chunks_exact_mut(8)) {
            // SAFETY: `block` is 16 bytes, the load's width.
            let v = unsafe { _mm_loadu_si128(block.as_ptr().cast()) };
            let native = _mm_or_si128(_mm_slli_epi16::<8>(v), _mm_srli_epi16::<8>(v));
            // All ones where the value is 65535 and that means nothing.
            let blank = _mm_and_si128(_mm_cmpeq_epi16(v, _mm_set1_epi16(-1)), invalid);
            // SAFETY: `pixels` is eight u16, the store's 16 bytes.
            unsafe {
                _mm_storeu_si128(pixels.as_mut_ptr().cast(), _mm_andnot_si128(blank, native))
            };
            done += 8;
        }
        done
    }
}

/// The `png` crate's decoder: for interlaced files, and the tests' reference.
fn decode_with_png_crate(
    path: &Path,
    bytes: &[u8],
    width: u16,
    height: u16,
) -> Result<Vec<u16>, ReadError> {
    let err = |e: png::DecodingError| png_error(path, e.to_string());
    let mut decoder = png::Decoder::new(bytes);
    decoder.set_transformations(png::Transformations::IDENTITY);
    let mut reader = decoder.read_info().map_err(err)?;
    let mut raw = vec![0u8; reader.output_buffer_size()];
    reader.next_frame(&mut raw).map_err(err)?;
    reader.finish().map_err(err)?;
    let n = width as usize * height as usize;
    if raw.len() != 2 * n {
        return Err(png_error(
            path,
            format!(
                "decoder gave {} bytes for a {width}x{height} 16-bit image",
                raw.len()
            ),
        ));
    }
    Ok(raw
        .chunks_exact(2)
        .map(|px| u16::from_be_bytes([px[0], px[1]]))
        .collect())
}

/// Depth images of a file-based sequence, decoded on demand (thread-safe, no
/// shared state).
#[derive(Debug, Clone)]
pub(crate) struct PngDepthSource {
    /// Depth PNG of each frame, in sequence order.
    pub(crate) paths: Vec<PathBuf>,
    /// Whether 65535 means "no measurement" (mapped to 0).
    pub(crate) invalid_65535: bool,
}

impl DepthSource for PngDepthSource {
    fn depth(&self, i: usize) -> Result<DepthImage, ReadError> {
        match self.paths.get(i) {
            Some(path) => decode(path, self.invalid_65535),
            None => Err(self.no_frame(i)),
        }
    }

    fn depth_into(&self, i: usize, image: &mut DepthImage) -> Result<(), ReadError> {
        match self.paths.get(i) {
            Some(path) => decode_into(path, self.invalid_65535, image),
            None => Err(self.no_frame(i)),
        }
    }

    fn depth_file(&self, i: usize) -> Option<&Path> {
        self.paths.get(i).map(PathBuf::as_path)
    }
}

impl PngDepthSource {
    fn no_frame(&self, i: usize) -> ReadError {
        ReadError::Layout {
            path: PathBuf::new(),
            reason: format!(
                "frame {i} requested, the sequence has {} frames",
                self.paths.len()
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_png(
        path: &Path,
        w: u32,
        h: u32,
        color: png::ColorType,
        depth: png::BitDepth,
        data: &[u8],
    ) {
        let file = std::fs::File::create(path).unwrap();
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w, h);
        enc.set_color(color);
        enc.set_depth(depth);
        enc.write_header().unwrap().write_image_data(data).unwrap();
    }

    fn temp(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("placedb-read-png-{}-{name}", std::process::id()))
    }

    /// A PNG file from raw chunk payloads (CRCs computed here), so tests can
    /// build what no encoder writes.
    fn png_file(chunks: &[(&[u8; 4], Vec<u8>)]) -> Vec<u8> {
        let mut out = SIGNATURE.to_vec();
        for (kind, data) in chunks {
            out.extend_from_slice(&(data.len() as u32).to_be_bytes());
            let start = out.len();
            out.extend_from_slice(*kind);
            out.extend_from_slice(data);
            let crc = crc32fast::hash(&out[start..]);
            out.extend_from_slice(&crc.to_be_bytes());
        }
        out
    }

    fn ihdr(w: u32, h: u32, interlace: u8) -> Vec<u8> {
        let mut d = w.to_be_bytes().to_vec();
        d.extend_from_slice(&h.to_be_bytes());
        d.extend_from_slice(&[16, 0, 0, 0, interlace]);
        d
    }

    // Which inflater the tests of damaged files reach: level 1 streams say
    // "fastest" in their header (fdeflate), level 6 ones do not (libdeflate).
    thread_local! {
        static LEVEL: std::cell::Cell<i32> = const { std::cell::Cell::new(6) };
    }

    fn zlib(raw: &[u8]) -> Vec<u8> {
        let level = LEVEL.with(|l| l.get());
        let mut c = libdeflater::Compressor::new(libdeflater::CompressionLvl::new(level).unwrap());
        let mut out = vec![0; c.zlib_compress_bound(raw.len())];
        let n = c.zlib_compress(raw, &mut out).unwrap();
        out.truncate(n);
        out
    }

    /// Deterministic depth-like values: smooth runs, jumps and holes, so
    /// every filter meets carries, ties and wrap-around.
    fn test_depths(n: usize, seed: u64) -> Vec<u16> {
        let mut rng = crate::rng::SplitMix64::new(seed);
        let mut v = 1500u16;
        (0..n)
            .map(|_| {
                let r = (rng.next_u64() >> 32) as u32;
                v = match r % 16 {
                    0 => 0,
                    1 => u16::MAX,
                    2 => r as u16,
                    _ => v.wrapping_add((r % 64) as u16).wrapping_sub(31),
                };
                v
            })
            .collect()
    }

    #[test]
    fn every_filter_decodes_as_the_png_crate_does() {
        use png::FilterType::*;
        let (w, h) = (37u32, 23u32);
        let values = test_depths((w * h) as usize, 7);
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
        let filters = [NoFilter, Sub, Up, Avg, Paeth].into_iter().enumerate();
        let compressions = [png::Compression::Default, png::Compression::Fast];
        for ((i, filter), compression) in filters.flat_map(|f| compressions.map(|c| (f, c))) {
            for adaptive in [false, true] {
                let path = temp(&format!("filter-{i}-{adaptive}-{compression:?}.png"));
                let file = std::fs::File::create(&path).unwrap();
                let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w, h);
                enc.set_color(png::ColorType::Grayscale);
                enc.set_depth(png::BitDepth::Sixteen);
                enc.set_compression(compression);
                enc.set_filter(filter);
                if adaptive {
                    enc.set_adaptive_filter(png::AdaptiveFilterType::Adaptive);
                }
                enc.write_header()
                    .unwrap()
                    .write_image_data(&bytes)
                    .unwrap();
                let img = decode(&path, false).unwrap();
                assert_eq!((img.width, img.height), (w as u16, h as u16));
                assert_eq!(
                    img.data, values,
                    "{filter:?} adaptive={adaptive} {compression:?}"
                );
                // Both inflaters are reached: the fast encoder's streams say
                // "fastest" in their zlib header.
                let file = std::fs::read(&path).unwrap();
                let idat = file.windows(4).position(|w| w == b"IDAT").unwrap();
                let fastest = file[idat + 5] >> 6 == 0;
                assert_eq!(fastest, matches!(compression, png::Compression::Fast));
                std::fs::remove_file(&path).ok();
            }
        }
    }

    #[test]
    fn native_order_and_blanking_match_the_pixel_at_a_time_form() {
        for width in 1..=41usize {
            let height = 3;
            let mut values = test_depths(width * height, width as u64);
            // A 65535 in every image, so that the blanking is met whatever
            // the draws give.
            values[width * height / 2] = u16::MAX;
            let mut scanlines = Vec::new();
            for row in values.chunks_exact(width) {
                scanlines.push(4); // the filter byte, ignored here
                scanlines.extend(row.iter().flat_map(|v| v.to_be_bytes()));
            }
            for invalid_65535 in [false, true] {
                let mut out = vec![1u16; width * height];
                write_native(&scanlines, 2 * width, invalid_65535, &mut out);
                let want: Vec<u16> = values
                    .iter()
                    .map(|&v| if invalid_65535 && v == u16::MAX { 0 } else { v })
                    .collect();
                assert_eq!(out, want, "width {width} invalid_65535 {invalid_65535}");
            }
        }
    }

    #[test]
    fn recorded_frames_decode_as_the_png_crate_does() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/7scenes-1000");
        for i in [0, 1, 499, 999] {
            let path = dir.join(format!("frame-{i:06}.depth.png"));
            let bytes = std::fs::read(&path).unwrap();
            let expected = decode_with_png_crate(&path, &bytes, 640, 480).unwrap();
            assert_eq!(decode(&path, false).unwrap().data, expected, "{path:?}");
        }
    }

    #[test]
    fn interlaced_files_decode_through_the_png_crate() {
        // Adam7: pass p takes pixels (x0 + k dx, y0 + j dy), every pass
        // scanline unfiltered.
        const PASSES: [(u32, u32, u32, u32); 7] = [
            (0, 0, 8, 8),
            (4, 0, 8, 8),
            (0, 4, 4, 8),
            (2, 0, 4, 4),
            (0, 2, 2, 4),
            (1, 0, 2, 2),
            (0, 1, 1, 2),
        ];
        let (w, h) = (13u32, 9u32);
        let values = test_depths((w * h) as usize, 3);
        let mut raw = Vec::new();
        for (x0, y0, dx, dy) in PASSES {
            for y in (y0..h).step_by(dy as usize) {
                if x0 >= w {
                    continue;
                }
                raw.push(0);
                for x in (x0..w).step_by(dx as usize) {
                    raw.extend_from_slice(&values[(y * w + x) as usize].to_be_bytes());
                }
            }
        }
        let path = temp("adam7.png");
        let file = png_file(&[
            (b"IHDR", ihdr(w, h, 1)),
            (b"IDAT", zlib(&raw)),
            (b"IEND", vec![]),
        ]);
        std::fs::write(&path, file).unwrap();
        let img = decode(&path, true).unwrap();
        let mapped: Vec<u16> = values
            .iter()
            .map(|&v| if v == u16::MAX { 0 } else { v })
            .collect();
        assert_eq!(img.data, mapped);
        std::fs::remove_file(&path).ok();
    }

    #[test]
    fn damaged_files_are_refused_by_name_by_either_inflater() {
        for (level, fastest) in [(1, true), (6, false)] {
            LEVEL.with(|l| l.set(level));
            assert_eq!(zlib(&[0; 9])[1] >> 6 == 0, fastest, "level {level}");
            damaged_files_are_refused_by_name();
        }
    }

    fn damaged_files_are_refused_by_name() {
        let (w, h) = (4u32, 3u32);
        let scanlines = |filter: u8| -> Vec<u8> {
            (0..h)
                .flat_map(|_| std::iter::once(filter).chain([0u8; 8]))
                .collect()
        };
        let good = png_file(&[
            (b"IHDR", ihdr(w, h, 0)),
            (b"IDAT", zlib(&scanlines(0))),
            (b"IEND", vec![]),
        ]);
        let mut bad_crc = good.clone();
        let last = bad_crc.len() - 13; // inside IDAT's CRC
        bad_crc[last] ^= 1;
        let cases: Vec<(&str, Vec<u8>, &str)> = vec![
            ("crc", bad_crc, "CRC error in chunk IDAT"),
            (
                "critical",
                png_file(&[
                    (b"IHDR", ihdr(w, h, 0)),
                    (b"ABCD", vec![1]),
                    (b"IDAT", zlib(&scanlines(0))),
                    (b"IEND", vec![]),
                ]),
                "unexpected critical chunk ABCD",
            ),
            (
                "short",
                png_file(&[
                    (b"IHDR", ihdr(w, h, 0)),
                    (b"IDAT", zlib(&scanlines(0)[..20])),
                    (b"IEND", vec![]),
                ]),
                "inflates to 20 bytes",
            ),
            (
                "long",
                png_file(&[
                    (b"IHDR", ihdr(w, h, 0)),
                    (b"IDAT", zlib(&[0; 40])),
                    (b"IEND", vec![]),
                ]),
                "inflates to more than the 27 bytes",
            ),
            (
                "filter",
                png_file(&[
                    (b"IHDR", ihdr(w, h, 0)),
                    (b"IDAT", zlib(&scanlines(5))),
                    (b"IEND", vec![]),
                ]),
                "unknown scanline filter 5",
            ),
            (
                "no-idat",
                png_file(&[(b"IHDR", ihdr(w, h, 0)), (b"IEND", vec![])]),
                "no IDAT chunk",
            ),
            (
                "garbage-stream",
                png_file(&[
                    (b"IHDR", ihdr(w, h, 0)),
                    (b"IDAT", vec![1, 2, 3, 4]),
                    (b"IEND", vec![]),
                ]),
                "not a valid zlib stream",
            ),
        ];
        let path = temp("damaged.png");
        let good_path = temp("damaged-good.png");
        std::fs::write(&good_path, &good).unwrap();
        let ancillary = png_file(&[
            (b"IHDR", ihdr(w, h, 0)),
            (b"tEXt", b"a\0b".to_vec()),
            (b"IDAT", zlib(&scanlines(0))),
            (b"IEND", vec![]),
        ]);
        std::fs::write(&path, &ancillary).unwrap();
        assert_eq!(decode(&path, false).unwrap().data, vec![0; 12]);
        for (name, bytes, reason) in cases {
            std::fs::write(&path, &bytes).unwrap();
            let e = decode(&path, false).unwrap_err();
            assert!(e.to_string().contains(reason), "{name}: {e}");
            assert!(e.to_string().contains("damaged.png"), "{name}: {e}");
            // A reused image is left empty, not half-written.
            let mut reused = decode(&good_path, false).unwrap();
            assert!(decode_into(&path, false, &mut reused).is_err(), "{name}");
            assert_eq!(reused, DepthImage::default(), "{name}");
            // Every cut of a good file is refused, wherever it falls.
        }
        for cut in 0..good.len() {
            std::fs::write(&path, &good[..cut]).unwrap();
            let e = decode(&path, false).unwrap_err();
            assert!(matches!(e, ReadError::Png { .. }), "cut at {cut}: {e}");
        }
        std::fs::remove_file(&path).ok();
        std::fs::remove_file(&good_path).ok();
    }

    #[test]
    fn round_trip_and_65535_mapping() {
        let path = temp("rt.png");
        let values: [u16; 6] = [0, 1, 258, 1000, 65534, 65535];
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
        write_png(
            &path,
            3,
            2,
            png::ColorType::Grayscale,
            png::BitDepth::Sixteen,
            &bytes,
        );
        assert_eq!(depth_png_size(&path).unwrap(), (3, 2));
        let img = decode(&path, false).unwrap();
        assert_eq!((img.width, img.height), (3, 2));
        assert_eq!(img.data, values);
        let img = decode(&path, true).unwrap();
        assert_eq!(img.data, [0, 1, 258, 1000, 65534, 0]);
        let src = PngDepthSource {
            paths: vec![path.clone()],
            invalid_65535: true,
        };
        assert_eq!(src.depth(0).unwrap().data[5], 0);
        assert!(matches!(src.depth(1), Err(ReadError::Layout { .. })));
        std::fs::remove_file(&path).ok();
    }

    /// Not a check: the cost of the decoder's steps after inflating, on
    /// recorded frames, as wall time a frame (compare medians of
    /// interleaved runs: the machine's speed drifts). `PLACEDB_BENCH`
    /// picks the work: `copy` (refilling the scanlines, which every mode
    /// also does: subtract it), unfiltering with a [`VectorUnit`]
    /// (`baseline`, `avx2`, `avx512`), or `convert` (byte swap and 65535
    /// blanking); `PLACEDB_BENCH_REPS` the passes over 20 frames.
    /// `PLACEDB_BENCH=avx2 cargo test --release -p placedb-host --lib decode_step_cost -- --ignored --nocapture`
    #[test]
    #[ignore]
    fn decode_step_cost() {
        let mode = std::env::var("PLACEDB_BENCH").unwrap_or_else(|_| "baseline".into());
        let reps: usize = std::env::var("PLACEDB_BENCH_REPS")
            .ok()
            .and_then(|r| r.parse().ok())
            .unwrap_or(50);
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/7scenes-1000");
        let mut inflater = libdeflater::Decompressor::new();
        let frames: Vec<Vec<u8>> = (0..1000)
            .step_by(50)
            .map(|i| {
                let path = dir.join(format!("frame-{i:06}.depth.png"));
                let bytes = std::fs::read(&path).unwrap();
                let mut zlib = Vec::new();
                collect_image_data(&path, &bytes, &mut zlib).unwrap();
                let mut scanlines = vec![0; 480 * 1281];
                let n = inflate(&zlib, &mut scanlines, &mut inflater).ok().unwrap();
                assert_eq!(n, scanlines.len());
                scanlines
            })
            .collect();
        let unit = match mode.as_str() {
            "avx2" => VectorUnit::Avx2,
            "avx512" => VectorUnit::Avx512,
            _ => VectorUnit::Baseline,
        };
        assert!(VectorUnit::available().contains(&unit), "{unit:?}");
        let (mut work, mut out) = (vec![0u8; 480 * 1281], vec![0u16; 640 * 480]);
        let start = std::time::Instant::now();
        for _ in 0..reps {
            for frame in &frames {
                work.copy_from_slice(frame);
                match mode.as_str() {
                    "copy" => {}
                    "baseline" | "avx2" | "avx512" => {
                        unfilter::unfilter_scanlines(unit, &mut work, 1280).unwrap()
                    }
                    "convert" => write_native(&work, 1280, true, &mut out),
                    _ => panic!("unknown PLACEDB_BENCH {mode}"),
                }
                std::hint::black_box((&mut work, &mut out));
            }
        }
        let per_frame = start.elapsed().as_secs_f64() * 1e6 / (reps * frames.len()) as f64;
        println!("{mode}: {per_frame:.1} us a frame");
    }

    #[test]
    fn refuses_colour_and_8_bit_in_header_check() {
        let path = temp("rgb16.png");
        write_png(
            &path,
            1,
            1,
            png::ColorType::Rgb,
            png::BitDepth::Sixteen,
            &[0; 6],
        );
        let e = depth_png_size(&path).unwrap_err();
        assert!(matches!(e, ReadError::Png { .. }), "{e}");
        assert!(e.to_string().contains("rgb16.png"), "{e}");
        let e = decode(&path, false).unwrap_err();
        assert!(matches!(e, ReadError::Png { .. }), "{e}");
        std::fs::remove_file(&path).ok();
    }
}
