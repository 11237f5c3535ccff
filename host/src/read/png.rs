//! 16-bit greyscale depth PNG decoding, and the on-demand [`DepthSource`] of
//! the file-based readers.
//!
//! Decoding is the hot path of every host tool (called from many threads, once
//! per frame and pass), so it reads the file in one go, lets `png` inflate
//! straight into the final `Vec<u16>` (viewed as bytes) with no
//! transformation, then converts PNG's big-endian samples to native order in
//! place, folding in the optional "65535 means no measurement" mapping.

use crate::error::ReadError;
use crate::sequence::{DepthImage, DepthSource};
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

/// Checks that the header describes a 16-bit greyscale image whose sides fit
/// `u16`, and returns its size.
fn check_header(path: &Path, info: &png::Info) -> Result<(u16, u16), ReadError> {
    if info.color_type != png::ColorType::Grayscale || info.bit_depth != png::BitDepth::Sixteen {
        return Err(png_error(
            path,
            format!(
                "image is {}-bit {:?}, a depth image must be 16-bit Grayscale",
                info.bit_depth as u8, info.color_type
            ),
        ));
    }
    let side = |v: u32| u16::try_from(v).ok().filter(|&s| s > 0);
    match (side(info.width), side(info.height)) {
        (Some(w), Some(h)) => Ok((w, h)),
        _ => Err(png_error(
            path,
            format!(
                "image is {}x{}, sides must be 1..=65535",
                info.width, info.height
            ),
        )),
    }
}

/// Width and height of a depth PNG, reading only its header (and checking
/// that it is 16-bit greyscale).
pub(crate) fn depth_png_size(path: &Path) -> Result<(u16, u16), ReadError> {
    let file = std::fs::File::open(path).map_err(|source| ReadError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut decoder = png::Decoder::new(std::io::BufReader::with_capacity(256, file));
    let info = decoder
        .read_header_info()
        .map_err(|e| png_error(path, e.to_string()))?;
    check_header(path, info)
}

/// Decodes a 16-bit greyscale depth PNG; with `invalid_65535`, the value 65535
/// ("no measurement" in 7-Scenes) becomes 0.
pub(crate) fn decode(path: &Path, invalid_65535: bool) -> Result<DepthImage, ReadError> {
    let bytes = read_file(path)?;
    let err = |e: png::DecodingError| png_error(path, e.to_string());
    let mut decoder = png::Decoder::new(bytes.as_slice());
    decoder.set_transformations(png::Transformations::IDENTITY);
    let mut reader = decoder.read_info().map_err(err)?;
    let (width, height) = check_header(path, reader.info())?;
    let n = width as usize * height as usize;
    if reader.output_buffer_size() != 2 * n {
        return Err(png_error(
            path,
            format!(
                "decoder wants {} bytes for a {width}x{height} 16-bit image",
                reader.output_buffer_size()
            ),
        ));
    }
    let mut data = vec![0u16; n];
    {
        // SAFETY: `data` owns `n` initialised `u16`s, i.e. `2 * n` bytes; `u8`
        // has alignment 1 and every byte pattern is a valid `u16`, and `data`
        // is not otherwise accessed while `raw` lives.
        let raw: &mut [u8] =
            unsafe { std::slice::from_raw_parts_mut(data.as_mut_ptr().cast::<u8>(), 2 * n) };
        reader.next_frame(raw).map_err(err)?;
    }
    // Reads up to IEND: a file cut after its image data is refused too.
    reader.finish().map_err(err)?;
    if invalid_65535 {
        for v in &mut data {
            let x = u16::from_be(*v);
            *v = if x == u16::MAX { 0 } else { x };
        }
    } else {
        for v in &mut data {
            *v = u16::from_be(*v);
        }
    }
    Ok(DepthImage {
        width,
        height,
        data,
    })
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
            None => Err(ReadError::Layout {
                path: PathBuf::new(),
                reason: format!(
                    "frame {i} requested, the sequence has {} frames",
                    self.paths.len()
                ),
            }),
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
