//! Pictures: the one raster type ([`Image`], 8-bit RGB, with the few
//! drawing primitives the top view and its annotation use) and the one PNG
//! writer ([`png`]) of every picture and dataset file the tools write (the
//! top view, a dataset's depth and colour images, the TUM sequences
//! `placedb synth` writes).
//!
//! It sits below every module that draws or writes an image and imports
//! none of them, so a picture's bytes are made in one place.

pub mod png;

use std::path::Path;

/// An 8-bit RGB raster, row-major, three bytes per pixel: a picture the
/// tools draw, and a frame's colour image as a reader decodes it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height * 3` bytes, row after row.
    pub rgb: Vec<u8>,
}

impl Image {
    /// A `width` x `height` image filled with `color`.
    pub fn filled(width: u32, height: u32, color: [u8; 3]) -> Image {
        let n = width as usize * height as usize;
        Image {
            width,
            height,
            // `repeat` copies in doubling blocks, where a byte-by-byte
            // cycle took a millisecond for a 900-pixel square.
            rgb: color.repeat(n),
        }
    }

    /// Colour of pixel `(x, y)`; `None` outside the image.
    pub fn pixel(&self, x: i64, y: i64) -> Option<[u8; 3]> {
        let i = self.index(x, y)?;
        Some([self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]])
    }

    /// Sets pixel `(x, y)`; pixels outside the image are ignored.
    pub fn set(&mut self, x: i64, y: i64, color: [u8; 3]) {
        if let Some(i) = self.index(x, y) {
            self.rgb[i..i + 3].copy_from_slice(&color);
        }
    }

    fn index(&self, x: i64, y: i64) -> Option<usize> {
        let inside = (0..self.width as i64).contains(&x) && (0..self.height as i64).contains(&y);
        inside.then(|| 3 * (y as usize * self.width as usize + x as usize))
    }

    /// A straight 1-pixel line from `a` to `b` (Bresenham), clipped to the image.
    pub fn line(&mut self, a: (i64, i64), b: (i64, i64), color: [u8; 3]) {
        let (mut x, mut y) = a;
        let dx = (b.0 - x).abs();
        let dy = -(b.1 - y).abs();
        let sx = if x < b.0 { 1 } else { -1 };
        let sy = if y < b.1 { 1 } else { -1 };
        let mut err = dx + dy;
        loop {
            self.set(x, y, color);
            if (x, y) == b {
                break;
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }

    /// A filled disc of radius `r` centred on `c`, clipped to the image.
    pub fn disc(&mut self, c: (i64, i64), r: i64, color: [u8; 3]) {
        for dy in -r..=r {
            for dx in -r..=r {
                if dx * dx + dy * dy <= r * r {
                    self.set(c.0 + dx, c.1 + dy, color);
                }
            }
        }
    }

    /// Writes the image as an 8-bit RGB PNG ([`png::write`]).
    pub fn write_png(&self, path: &Path) -> std::io::Result<()> {
        png::write(path, self.width, self.height, png::Samples::Rgb8(&self.rgb))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drawing_is_clipped_to_the_image() {
        let mut img = Image::filled(5, 4, [255; 3]);
        img.line((-3, 1), (9, 1), [1, 2, 3]);
        img.disc((4, 3), 2, [9; 3]);
        assert_eq!(img.pixel(0, 1), Some([1, 2, 3]));
        assert_eq!(img.pixel(4, 3), Some([9; 3]));
        assert_eq!(img.pixel(0, 0), Some([255; 3]));
        assert_eq!(img.pixel(5, 0), None);
        assert_eq!(img.rgb.len(), 5 * 4 * 3);
    }
}
