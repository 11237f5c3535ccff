//! The one PNG writer: every PNG the tools write (the top view, a dataset's
//! depth and colour images, the TUM sequences `placedb synth` writes) is
//! encoded here, with one set of encoder settings, so that two files of the
//! same pixels are the same bytes whichever command wrote them.

use std::path::Path;

/// A PNG's pixels, in the sample layout the file stores.
#[derive(Debug, Clone, Copy)]
pub enum Samples<'a> {
    /// 8-bit RGB: three bytes a pixel, row after row.
    Rgb8(&'a [u8]),
    /// 16-bit grey (a depth image): one value a pixel, row after row.
    Grey16(&'a [u16]),
}

/// The PNG file of a `width` x `height` image of `samples`.
///
/// Fast compression (the `png` crate's default, which every writer used
/// before there was one): a dataset of thousands of frames is written once,
/// and the top view's flat colours pack well either way.
pub fn encode(
    width: u32,
    height: u32,
    samples: Samples<'_>,
) -> Result<Vec<u8>, png::EncodingError> {
    let (colour, depth, data) = match samples {
        Samples::Rgb8(rgb) => (
            png::ColorType::Rgb,
            png::BitDepth::Eight,
            std::borrow::Cow::Borrowed(rgb),
        ),
        // PNG stores 16-bit samples big-endian.
        Samples::Grey16(values) => (
            png::ColorType::Grayscale,
            png::BitDepth::Sixteen,
            values.iter().flat_map(|v| v.to_be_bytes()).collect(),
        ),
    };
    let mut out = Vec::with_capacity(data.len() / 2 + 1024);
    let mut enc = png::Encoder::new(&mut out, width, height);
    enc.set_color(colour);
    enc.set_depth(depth);
    enc.set_compression(png::Compression::Fast);
    let mut writer = enc.write_header()?;
    writer.write_image_data(&data)?;
    writer.finish()?;
    Ok(out)
}

/// Writes the PNG of [`encode`] to `path`. Encoded in memory and written in
/// one call, so that a failing write (a full disk) is an error, not a file
/// cut short when a buffer drops; an encoding failure (samples that do not
/// fill the size) is an error of kind `Other`.
pub fn write(path: &Path, width: u32, height: u32, samples: Samples<'_>) -> std::io::Result<()> {
    let bytes = encode(width, height, samples).map_err(std::io::Error::other)?;
    std::fs::write(path, bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(bytes: &[u8]) -> (png::OutputInfo, Vec<u8>) {
        let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
            .read_info()
            .unwrap();
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).unwrap();
        buf.truncate(info.buffer_size());
        (info, buf)
    }

    #[test]
    fn samples_read_back_as_written() {
        let rgb: Vec<u8> = (0..2 * 3 * 3).map(|v| v as u8).collect();
        let (info, back) = decode(&encode(3, 2, Samples::Rgb8(&rgb)).unwrap());
        assert_eq!((info.width, info.height), (3, 2));
        assert_eq!(info.color_type, png::ColorType::Rgb);
        assert_eq!(back, rgb);
        let depth = [0u16, 1, 0x1234, u16::MAX];
        let (info, back) = decode(&encode(2, 2, Samples::Grey16(&depth)).unwrap());
        assert_eq!(info.bit_depth, png::BitDepth::Sixteen);
        assert_eq!(back, [0, 0, 0, 1, 0x12, 0x34, 0xFF, 0xFF]);
        // Too few samples for the size is an error, not a short file.
        assert!(encode(3, 3, Samples::Rgb8(&rgb)).is_err());
    }
}
