//! The JPEG image of a frame for the COLMAP and VPR-evaluation exports:
//! its colour file as it is when that is a JPEG, other colour re-encoded,
//! and a rendering of its depth where the sequence has no colour.

use crate::error::OutputError;
use crate::picture::Image;
use crate::sequence::Sequence;

/// JPEG quality of re-encoded colour and of depth renderings.
pub const QUALITY: u8 = 95;
/// Depth drawn black, metres: a rendering is white at the camera,
/// darker with distance (missing depth is black).
pub const RENDER_FAR: f64 = 8.0;

/// The bytes of frame `i`'s JPEG. Its size must be the depth images'
/// (the exports' camera is the sequence's intrinsics).
pub fn frame_jpeg(seq: &Sequence, i: usize) -> Result<Vec<u8>, OutputError> {
    let frame = seq.frames.get(i).ok_or_else(|| {
        OutputError::Mismatch(format!(
            "frame {i} is not in the sequence of {} frames",
            seq.frames.len()
        ))
    })?;
    let (w, h) = seq.size;
    let check = |what: String, size: (u32, u32)| {
        if size == (u32::from(w), u32::from(h)) {
            Ok(())
        } else {
            Err(OutputError::Mismatch(format!(
                "frame {}: {what} is {}x{}, the depth images (whose intrinsics the export's camera has) are {}x{}",
                frame.index, size.0, size.1, seq.size.0, seq.size.1
            )))
        }
    };
    if let Some(path) = &frame.color_path {
        let bytes = std::fs::read(path).map_err(|source| OutputError::Write {
            path: path.clone(),
            source,
        })?;
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        let shown = path.display().to_string();
        if ext == "jpg" || ext == "jpeg" {
            let size = jpeg_size(&bytes).ok_or_else(|| {
                OutputError::Mismatch(format!("{shown}: not a readable JPEG file"))
            })?;
            check(
                format!("colour image {shown}"),
                (u32::from(size.0), u32::from(size.1)),
            )?;
            return Ok(bytes);
        }
        let img = decode_png_rgb(&bytes).map_err(|e| {
            OutputError::Mismatch(format!("{shown}: cannot read the colour image: {e}"))
        })?;
        check(format!("colour image {shown}"), (img.width, img.height))?;
        return encode(&img.rgb, w, h, jpeg_encoder::ColorType::Rgb);
    }
    if let Some(img) = seq.source.color(i)? {
        check("its colour image".into(), (img.width, img.height))?;
        return encode(&img.rgb, w, h, jpeg_encoder::ColorType::Rgb);
    }
    let depth = seq.depth(i)?;
    let grey: Vec<u8> = depth
        .data
        .iter()
        .map(|&v| {
            let m = f64::from(v) / seq.depth_scale;
            if v == 0 || !m.is_finite() {
                0
            } else {
                (255.0 * (1.0 - m / RENDER_FAR).clamp(0.0, 1.0)).round() as u8
            }
        })
        .collect();
    encode(
        &grey,
        depth.width,
        depth.height,
        jpeg_encoder::ColorType::Luma,
    )
}

fn encode(
    data: &[u8],
    w: u16,
    h: u16,
    colour: jpeg_encoder::ColorType,
) -> Result<Vec<u8>, OutputError> {
    let mut out = Vec::new();
    jpeg_encoder::Encoder::new(&mut out, QUALITY)
        .encode(data, w, h, colour)
        .map_err(|e| OutputError::Mismatch(format!("JPEG encoding failed: {e}")))?;
    Ok(out)
}

/// Width and height from a JPEG's frame header (SOFn); `None` when the
/// bytes are no JPEG.
pub fn jpeg_size(bytes: &[u8]) -> Option<(u16, u16)> {
    if bytes.get(..2)? != [0xFF, 0xD8] {
        return None;
    }
    let mut at = 2;
    loop {
        // Fill bytes 0xFF may precede a marker.
        while *bytes.get(at)? == 0xFF && *bytes.get(at + 1)? == 0xFF {
            at += 1;
        }
        if *bytes.get(at)? != 0xFF {
            return None;
        }
        let marker = *bytes.get(at + 1)?;
        let len = usize::from(u16::from_be_bytes([
            *bytes.get(at + 2)?,
            *bytes.get(at + 3)?,
        ]));
        let is_sof = (0xC0..=0xCF).contains(&marker) && ![0xC4, 0xC8, 0xCC].contains(&marker);
        if is_sof {
            let h = u16::from_be_bytes([*bytes.get(at + 5)?, *bytes.get(at + 6)?]);
            let w = u16::from_be_bytes([*bytes.get(at + 7)?, *bytes.get(at + 8)?]);
            return Some((w, h));
        }
        at += 2 + len;
    }
}

/// An 8-bit RGB image from a PNG file's bytes (grey, palette, alpha and
/// 16-bit samples converted).
fn decode_png_rgb(bytes: &[u8]) -> Result<Image, String> {
    let mut dec = png::Decoder::new(std::io::Cursor::new(bytes));
    dec.set_transformations(png::Transformations::normalize_to_color8());
    let mut reader = dec.read_info().map_err(|e| e.to_string())?;
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
    buf.truncate(info.buffer_size());
    let channels = match info.color_type {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Indexed => return Err("palette left unexpanded".into()),
    };
    let rgb = buf
        .chunks_exact(channels)
        .flat_map(|p| match channels {
            1 | 2 => [p[0]; 3],
            _ => [p[0], p[1], p[2]],
        })
        .collect();
    Ok(Image {
        width: info.width,
        height: info.height,
        rgb,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encoded_jpeg_reads_back_its_size() {
        let grey = vec![128u8; 40 * 30];
        let bytes = encode(&grey, 40, 30, jpeg_encoder::ColorType::Luma).unwrap();
        assert_eq!(jpeg_size(&bytes), Some((40, 30)));
        assert_eq!(jpeg_size(b"\x89PNG"), None);
        assert_eq!(jpeg_size(&bytes[..10]), None);
    }
}
