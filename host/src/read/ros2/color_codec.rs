//! Colour recorded through `image_transport`: a `sensor_msgs/CompressedImage`
//! holding a JPEG or a PNG, as `compressed_image_transport` writes it
//! (`"bgr8; jpeg compressed bgr8"`, `"rgb8; png compressed bgr8"`, or a bare
//! `"jpeg"`). The image inside is a plain JPEG or PNG whatever the encoding
//! before the `;` (the transport converts to BGR for OpenCV, which writes
//! the file's standard channel order), so it decodes to RGB as any file
//! does. Robots record colour this way to save bandwidth, so a bag's colour
//! topic is usually one of these.

use crate::picture::Image;

/// How a colour CompressedImage's data is coded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColorCodec {
    Jpeg,
    Png,
}

/// The raw encodings whose compressed images are colour (or grey).
const COLOUR_ENCODINGS: [&str; 6] = ["rgb8", "bgr8", "rgba8", "bgra8", "mono8", ""];

/// Most pixels a colour image may have: as many as a depth image may
/// (a damaged header must not ask for gigabytes).
const MOST_PIXELS: usize = 1 << 25;

/// The codec of a colour CompressedImage `format`, `None` when it is not
/// colour (a depth coding, another codec).
pub fn codec(format: &str) -> Option<ColorCodec> {
    let (encoding, rest) = match format.split_once(';') {
        Some((e, r)) => (e.trim(), r.trim()),
        None => ("", format.trim()),
    };
    if !COLOUR_ENCODINGS.contains(&encoding) {
        return None;
    }
    let first = rest.split_whitespace().next()?;
    match first {
        "jpeg" | "jpg" => Some(ColorCodec::Jpeg),
        "png" => Some(ColorCodec::Png),
        _ => None,
    }
}

/// Decodes `data` to RGB.
pub fn decode(codec: ColorCodec, data: &[u8]) -> Result<Image, String> {
    match codec {
        ColorCodec::Jpeg => jpeg(data),
        ColorCodec::Png => png(data),
    }
}

fn jpeg(data: &[u8]) -> Result<Image, String> {
    use zune_jpeg::zune_core::colorspace::ColorSpace;
    use zune_jpeg::zune_core::options::DecoderOptions;
    let options = DecoderOptions::default()
        .jpeg_set_out_colorspace(ColorSpace::RGB)
        .set_max_width(1 << 15)
        .set_max_height(1 << 15);
    let mut decoder = zune_jpeg::JpegDecoder::new_with_options(data, options);
    decoder
        .decode_headers()
        .map_err(|e| format!("its JPEG does not decode: {e}"))?;
    let (w, h) = decoder.dimensions().ok_or("its JPEG has no size")?;
    if w == 0 || h == 0 || w.saturating_mul(h) > MOST_PIXELS {
        return Err(format!("its JPEG claims {w}x{h} pixels"));
    }
    let rgb = decoder
        .decode()
        .map_err(|e| format!("its JPEG does not decode: {e}"))?;
    if rgb.len() != 3 * w * h {
        return Err(format!(
            "its JPEG decoded to {} bytes for {w}x{h} pixels",
            rgb.len()
        ));
    }
    Ok(Image {
        width: w as u32,
        height: h as u32,
        rgb,
    })
}

fn png(data: &[u8]) -> Result<Image, String> {
    let mut decoder = png::Decoder::new(std::io::Cursor::new(data));
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder
        .read_info()
        .map_err(|e| format!("its PNG does not decode: {e}"))?;
    let (w, h) = (reader.info().width as usize, reader.info().height as usize);
    if w == 0 || h == 0 || w.saturating_mul(h) > MOST_PIXELS {
        return Err(format!("its PNG claims {w}x{h} pixels"));
    }
    let mut buf = vec![0u8; reader.output_buffer_size()];
    let frame = reader
        .next_frame(&mut buf)
        .map_err(|e| format!("its PNG does not decode: {e}"))?;
    let bytes = &buf[..frame.buffer_size()];
    let per = match frame.color_type {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Indexed => return Err("its PNG is still indexed after expansion".into()),
    };
    let rgb = bytes
        .chunks_exact(per)
        .flat_map(|p| match per {
            1 | 2 => [p[0], p[0], p[0]],
            _ => [p[0], p[1], p[2]],
        })
        .collect();
    Ok(Image {
        width: w as u32,
        height: h as u32,
        rgb,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_as_compressed_image_transport_writes_them() {
        assert_eq!(codec("bgr8; jpeg compressed bgr8"), Some(ColorCodec::Jpeg));
        assert_eq!(codec("rgb8; jpeg compressed bgr8"), Some(ColorCodec::Jpeg));
        assert_eq!(codec("rgb8; png compressed bgr8"), Some(ColorCodec::Png));
        assert_eq!(codec("jpeg"), Some(ColorCodec::Jpeg));
        assert_eq!(codec("16UC1; png compressed "), None);
        assert_eq!(codec("16UC1; compressedDepth png"), None);
        assert_eq!(codec("rgb8; tiff"), None);
    }

    #[test]
    fn a_jpeg_of_the_sample_decodes_and_damage_is_an_error() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../shared/data/7scenes-1000/frame-000000.color.jpg");
        let bytes = std::fs::read(path).unwrap();
        let img = decode(ColorCodec::Jpeg, &bytes).unwrap();
        assert_eq!(
            (img.width, img.height, img.rgb.len()),
            (640, 480, 640 * 480 * 3)
        );
        assert!(decode(ColorCodec::Jpeg, &bytes[..40]).is_err());
        assert!(decode(ColorCodec::Png, &bytes).is_err());
    }
}
