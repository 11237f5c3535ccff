//! A frame's rows as the core receives them: the depth image sampled at the
//! run's stride ([`sampled_rows`]) and cut into `DepthRows` messages
//! ([`row_chunks`]). The one place the host makes a frame's rows, for the
//! wire (the device client's `Session::push_frame`, `bench --db-scaling`'s
//! probe frames, the power-cut tests) and for the online replay, so that the
//! replay and a board see the very same samples.

use crate::sequence::DepthImage;
use placedb::protocol::{DepthRows, HostMessage};

/// The rows a board receives for one frame: sampled rows of sampled columns.
pub fn sampled_rows(img: &DepthImage, stride: u16) -> (usize, Vec<u16>) {
    sampled_rows_of(&img.data, img.width, stride)
}

/// [`sampled_rows`] of a row-major buffer `width` values wide (a frame held
/// in memory, e.g. a camera driver's): its rows `0, stride, 2 stride, ...`,
/// each sampled the same way. A last partial row is ignored.
pub fn sampled_rows_of(data: &[u16], width: u16, stride: u16) -> (usize, Vec<u16>) {
    let s = stride.max(1) as usize;
    let w = width as usize;
    let height = data.len().checked_div(w).unwrap_or(0);
    let sampled = w.div_ceil(s);
    let mut out = Vec::with_capacity(sampled * height.div_ceil(s));
    for row in data.chunks_exact(w.max(1)).take(height).step_by(s) {
        out.extend(row.iter().step_by(s));
    }
    (sampled, out)
}

/// One `DepthRows` payload: `row_count` strided rows from strided row
/// `first_row` on, as the little-endian bytes the message carries.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RowChunk {
    /// First strided row.
    pub first_row: u16,
    /// Strided rows in `data`.
    pub row_count: u16,
    /// The depth values, 2 little-endian bytes each.
    pub data: Vec<u8>,
}

impl RowChunk {
    /// The `DepthRows` message of this chunk in frame `frame`.
    pub fn message(&self, frame: u32) -> HostMessage<'_> {
        HostMessage::DepthRows(DepthRows {
            frame,
            first_row: self.first_row,
            row_count: self.row_count,
            data: &self.data,
        })
    }
}

/// `values`, one frame's sampled rows of `width` values each (as
/// [`sampled_rows`] gives them), in chunks of
/// `rows_per_message` rows (the last one may hold fewer).
pub fn row_chunks(
    width: usize,
    values: &[u16],
    rows_per_message: usize,
) -> impl Iterator<Item = RowChunk> + '_ {
    row_spans(width, values, rows_per_message).map(move |(first_row, chunk)| RowChunk {
        first_row,
        row_count: (chunk.len() / width.max(1)) as u16,
        data: chunk.iter().flat_map(|d| d.to_le_bytes()).collect(),
    })
}

/// The same cut as [`row_chunks`], as the values themselves: each chunk's
/// first strided row and its values (what `push_rows` takes in the replay).
pub fn row_spans(
    width: usize,
    values: &[u16],
    rows_per_chunk: usize,
) -> impl Iterator<Item = (u16, &[u16])> + '_ {
    let per_chunk = rows_per_chunk.max(1);
    values
        .chunks((width * per_chunk).max(1))
        .enumerate()
        .map(move |(k, chunk)| ((k * per_chunk) as u16, chunk))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunks_cover_every_row_once_in_order() {
        // 3 values a row, 5 rows, 2 rows a message: rows 0-1, 2-3, 4.
        let values: Vec<u16> = (0..15).map(|v| 1000 + v).collect();
        let chunks: Vec<RowChunk> = row_chunks(3, &values, 2).collect();
        let heads: Vec<(u16, u16)> = chunks.iter().map(|c| (c.first_row, c.row_count)).collect();
        assert_eq!(heads, vec![(0, 2), (2, 2), (4, 1)]);
        let bytes: Vec<u8> = chunks.iter().flat_map(|c| c.data.clone()).collect();
        let back: Vec<u16> = bytes
            .chunks(2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
            .collect();
        assert_eq!(back, values);
        assert_eq!(
            chunks[2].message(7),
            HostMessage::DepthRows(DepthRows {
                frame: 7,
                first_row: 4,
                row_count: 1,
                data: &[0xf4, 0x03, 0xf5, 0x03, 0xf6, 0x03],
            })
        );
    }
}
