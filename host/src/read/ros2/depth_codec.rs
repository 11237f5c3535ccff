//! Depth recorded through `image_transport`: a `sensor_msgs/CompressedImage`
//! whose `format` string says how its `data` is coded.
//!
//! - `compressed_depth_image_transport` (`"16UC1; compressedDepth"` on ROS 2
//!   Humble, `"...; compressedDepth png"` or `"...; compressedDepth rvl"`
//!   since): a 12-byte `ConfigHeader` (`int32` format, two `float32` depth
//!   parameters, little-endian as the robot's CPU wrote them), then a 16-bit
//!   greyscale PNG or an RVL stream (`uint32` columns and rows, then
//!   nibble-coded zero runs and zigzag deltas in little-endian 32-bit words,
//!   first nibble in the top bits). A `16UC1` image is the depth itself; a
//!   `32FC1` one is inverse depth quantised to 16 bits, metres =
//!   `A / (q - B)` with the header's parameters `A`, `B`, and `q = 0` for
//!   no depth (`compressed_depth_image_transport/src/codec.cpp`).
//! - `compressed_image_transport` with PNG (`"16UC1; png compressed "`), or a
//!   bare `"png"`: a 16-bit greyscale PNG of the depth.
//!
//! Every length and count in the payload is checked before it is used: a
//! damaged message is an error in words, never a panic or a huge allocation.

use super::{metres_to_units, rvl};
use crate::error::ReadError;
use std::path::Path;

/// How a depth CompressedImage's data is coded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DepthCodec {
    /// `compressed_depth_image_transport`: a ConfigHeader, then a PNG (or
    /// RVL) of depth (`16UC1`) or quantised inverse depth (`32FC1`).
    CompressedDepth { inverse: bool, rvl: bool },
    /// A 16-bit greyscale PNG of the depth, nothing before it.
    Png,
}

/// Bytes of the `ConfigHeader` before a compressedDepth image.
const CONFIG_HEADER: usize = 12;

/// The codec of a CompressedImage `format`, or why it is not depth.
pub fn codec(format: &str) -> Result<DepthCodec, String> {
    let (encoding, rest) = match format.split_once(';') {
        Some((e, r)) => (e.trim(), r.trim()),
        None => ("", format.trim()),
    };
    if let Some(tail) = rest.strip_prefix("compressedDepth") {
        let inverse = match encoding {
            "16UC1" | "mono16" => false,
            "32FC1" => true,
            other => {
                return Err(format!(
                    "compressedDepth of `{other}` images: only 16UC1 and 32FC1 are depth"
                ))
            }
        };
        let rvl = match tail.trim() {
            "" | "png" => false,
            "rvl" => true,
            other => return Err(format!("compressedDepth codec `{other}` is not png or rvl")),
        };
        return Ok(DepthCodec::CompressedDepth { inverse, rvl });
    }
    let is_png = rest == "png" || rest.starts_with("png ");
    match (encoding, is_png) {
        ("" | "16UC1" | "mono16", true) => Ok(DepthCodec::Png),
        (_, true) => Err(format!(
            "a PNG of `{encoding}` images, which are not depth (16UC1)"
        )),
        _ => Err(format!(
            "format `{format}` is not a depth coding (compressedDepth or a 16-bit PNG)"
        )),
    }
}

/// Whether a CompressedImage `format` names depth (for topic detection):
/// compressedDepth, or a PNG of a `16UC1` image.
pub fn is_depth_format(format: &str) -> bool {
    let (encoding, _) = format.split_once(';').unwrap_or(("", ""));
    codec(format).is_ok() && ["16UC1", "mono16", "32FC1"].contains(&encoding.trim())
}

/// The reason of a PNG decoder error (the decoder names a file; here the
/// caller names the topic and time).
fn png_reason(e: ReadError) -> String {
    match e {
        ReadError::Png { reason, .. } => format!("its PNG: {reason}"),
        other => other.to_string(),
    }
}

/// The image bytes after a compressedDepth payload's ConfigHeader, and the
/// header's two depth parameters.
fn split_header(data: &[u8]) -> Result<(&[u8], [f32; 2]), String> {
    if data.len() <= CONFIG_HEADER {
        return Err(format!(
            "compressedDepth payload of {} bytes has no image after its {CONFIG_HEADER}-byte \
             header",
            data.len()
        ));
    }
    let f = |i: usize| f32::from_le_bytes([data[i], data[i + 1], data[i + 2], data[i + 3]]);
    Ok((&data[CONFIG_HEADER..], [f(4), f(8)]))
}

/// Width and height of the image in `data`, reading only its header.
pub fn size(codec: DepthCodec, data: &[u8]) -> Result<(u16, u16), String> {
    let image = match codec {
        DepthCodec::CompressedDepth { rvl: true, .. } => {
            return rvl::size(split_header(data)?.0).map(|(w, h, _)| (w, h))
        }
        DepthCodec::CompressedDepth { .. } => split_header(data)?.0,
        DepthCodec::Png => data,
    };
    crate::read::png::depth_png_bytes_size(image).map_err(png_reason)
}

/// Decodes `data` to depth units at `depth_scale` per metre (`16UC1` data
/// as stored; inverse depth converted as a `32FC1` Image is) into
/// `values`, a row after another; returns its width and height.
pub fn decode_into(
    codec: DepthCodec,
    data: &[u8],
    depth_scale: f64,
    values: &mut Vec<u16>,
) -> Result<(u16, u16), String> {
    let (image, params, inverse, is_rvl) = match codec {
        DepthCodec::CompressedDepth { inverse, rvl } => {
            let (image, params) = split_header(data)?;
            (image, params, inverse, rvl)
        }
        DepthCodec::Png => (data, [0.0; 2], false, false),
    };
    let (width, height) = if is_rvl {
        let (w, h, stream) = rvl::size(image)?;
        rvl::decode_into(stream, usize::from(w) * usize::from(h), values)?;
        (w, h)
    } else {
        crate::read::png::decode_bytes(Path::new(""), image, false, values).map_err(png_reason)?
    };
    if inverse {
        let [a, b] = params;
        for v in values.iter_mut() {
            *v = match *v {
                0 => 0,
                q => metres_to_units(a / (f32::from(q) - b), depth_scale),
            };
        }
    }
    Ok((width, height))
}

/// [`decode_into`] a new buffer: width, height and values.
pub fn decode(
    codec: DepthCodec,
    data: &[u8],
    depth_scale: f64,
) -> Result<(u16, u16, Vec<u16>), String> {
    let mut values = Vec::new();
    let (w, h) = decode_into(codec, data, depth_scale, &mut values)?;
    Ok((w, h, values))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn damaged_payloads_are_errors_in_words() {
        let header = |data: &[u8]| [&[0u8; 12][..], data].concat();
        let rvl = DepthCodec::CompressedDepth {
            inverse: false,
            rvl: true,
        };
        assert!(decode(rvl, &[0; 7], 1000.0)
            .unwrap_err()
            .contains("7 bytes"));
        let mut huge = header(&[0xff, 0xff, 0, 0, 0xff, 0xff, 0, 0]);
        huge.extend_from_slice(&[0; 4]);
        assert!(decode(rvl, &huge, 1000.0)
            .unwrap_err()
            .contains("65535x65535"));
        // 2x2 image: a run of 9 zeros overflows it.
        let mut over = header(&[2, 0, 0, 0, 2, 0, 0, 0]);
        over.extend_from_slice(&0x9100_0000u32.to_le_bytes());
        assert!(decode(rvl, &over, 1000.0)
            .unwrap_err()
            .contains("overflows"));
        let mut cut = header(&[2, 0, 0, 0, 2, 0, 0, 0]);
        cut.extend_from_slice(&rvl::tests::encode(&[0, 5])[..]);
        assert!(decode(rvl, &cut, 1000.0)
            .unwrap_err()
            .contains("ends after 2 of 4"));
        let png = DepthCodec::CompressedDepth {
            inverse: false,
            rvl: false,
        };
        assert!(decode(png, &header(b"not a png"), 1000.0)
            .unwrap_err()
            .contains("PNG"));
    }

    #[test]
    fn format_strings_as_the_transports_write_them() {
        let cd = |inverse, rvl| Ok(DepthCodec::CompressedDepth { inverse, rvl });
        assert_eq!(codec("16UC1; compressedDepth"), cd(false, false));
        assert_eq!(codec("16UC1; compressedDepth png"), cd(false, false));
        assert_eq!(codec("16UC1; compressedDepth rvl"), cd(false, true));
        assert_eq!(codec("32FC1; compressedDepth"), cd(true, false));
        assert_eq!(codec("16UC1; png compressed "), Ok(DepthCodec::Png));
        assert_eq!(codec("png"), Ok(DepthCodec::Png));
        assert!(codec("rgb8; jpeg compressed bgr8").is_err());
        assert!(codec("bgr8; png compressed bgr8")
            .unwrap_err()
            .contains("bgr8"));
        assert!(codec("16UC1; compressedDepth zstd")
            .unwrap_err()
            .contains("zstd"));
        assert!(is_depth_format("16UC1; png compressed "));
        assert!(!is_depth_format("png"));
        assert!(!is_depth_format("rgb8; jpeg compressed bgr8"));
    }
}
