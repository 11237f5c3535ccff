//! The readers' decoders on bytes in memory, for the fuzz targets
//! (`fuzz/src/readers.rs`, replayed by `tests/fuzz_corpus.rs`): the same
//! code the file readers run, without the file.

use super::png;
use super::unfilter;
use crate::error::ReadError;
use crate::sequence::DepthImage;
use crate::vector_unit::VectorUnit;
use std::path::Path;

/// Decodes `bytes` as a 16-bit greyscale depth PNG, as [`super::decode_depth_png`]
/// decodes a file (`name` stands for the file in errors); with
/// `invalid_65535`, 65535 becomes 0 (7-Scenes).
pub fn decode_depth_png(
    name: &Path,
    bytes: &[u8],
    invalid_65535: bool,
) -> Result<DepthImage, ReadError> {
    let mut data = Vec::new();
    let (width, height) = png::decode_bytes(name, bytes, invalid_65535, &mut data)?;
    Ok(DepthImage {
        width,
        height,
        data,
    })
}

/// Undoes the PNG filters of `scanlines` in place (rows of `1 + row_bytes`
/// bytes, `row_bytes` even) on `unit`'s wavefront; the first unknown filter
/// type, if any, is returned with the rows before it unfiltered.
pub fn unfilter(unit: VectorUnit, scanlines: &mut [u8], row_bytes: usize) -> Result<(), u8> {
    unfilter::unfilter_scanlines(unit, scanlines, row_bytes)
}
