//! The chunks of a bag a reading decompressed last (a ROS 1 bag's lz4 or
//! bz2 chunks, an MCAP file's zstd or lz4 ones), kept by the reading so that
//! frames read in order decompress each chunk once, not once a message.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, PoisonError};

/// The chunks a reading of a bag decompressed last, so that its frames,
/// read in order, decompress a chunk once rather than once a message (a
/// chunk holds several). Each reading owns its own, dropped with it: a file
/// rewritten in place is read afresh by the next reading (a cache shared
/// by every reading, by path and offset, served the chunk of the file as
/// it was).
#[derive(Default)]
pub struct Chunks(Mutex<Kept>);

/// What [`Chunks`] holds: the chunks, the last used first, and a buffer
/// of one dropped, to decompress the next into.
#[derive(Default)]
struct Kept {
    chunks: VecDeque<Chunk>,
    spare: Option<Vec<u8>>,
}

/// A chunk's data decompressed: of file `file` of the bag, at byte `offset`.
struct Chunk {
    file: usize,
    offset: u64,
    data: Arc<Vec<u8>>,
}

/// How many chunks [`Chunks`] keeps: every thread reading frames (each
/// reads a run of frames in order) keeps its own.
const CHUNKS_KEPT: usize = 8;

/// How many bytes of chunks [`Chunks`] keeps at most, besides the last.
const CHUNK_BYTES_KEPT: usize = 64 << 20;

impl Chunks {
    fn kept(&self) -> std::sync::MutexGuard<'_, Kept> {
        // A thread that panicked holding it left a whole list behind.
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The chunk at byte `offset` of file `file`, if kept.
    pub fn get(&self, file: usize, offset: u64) -> Option<Arc<Vec<u8>>> {
        let mut kept = self.kept();
        let chunks = &mut kept.chunks;
        let at = chunks
            .iter()
            .position(|c| c.file == file && c.offset == offset)?;
        let chunk = chunks.remove(at)?;
        let data = Arc::clone(&chunk.data);
        chunks.push_front(chunk);
        Some(data)
    }

    /// A buffer to decompress a chunk into (one dropped, or a new one).
    pub fn buffer(&self) -> Vec<u8> {
        self.kept().spare.take().unwrap_or_default()
    }

    /// Keeps a chunk just decompressed, dropping the longest unused, and
    /// hands it back shared, to lend its messages from.
    pub fn keep(&self, file: usize, offset: u64, data: Vec<u8>) -> Arc<Vec<u8>> {
        let data = Arc::new(data);
        let mut kept = self.kept();
        let Kept { chunks, spare } = &mut *kept;
        if chunks.iter().any(|c| c.file == file && c.offset == offset) {
            return data;
        }
        chunks.push_front(Chunk {
            file,
            offset,
            data: Arc::clone(&data),
        });
        let mut bytes: usize = chunks.iter().map(|c| c.data.len()).sum();
        while chunks.len() > CHUNKS_KEPT || (chunks.len() > 1 && bytes > CHUNK_BYTES_KEPT) {
            if let Some(old) = chunks.pop_back() {
                bytes -= old.data.len();
                // Its room, unless a thread still reads it.
                if let Ok(buffer) = Arc::try_unwrap(old.data) {
                    *spare = Some(buffer);
                }
            }
        }
        data
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kept_chunks_are_bounded_in_number() {
        let chunks = Chunks::default();
        for offset in 0..20u64 {
            chunks.keep(0, offset, vec![0; 10]);
        }
        assert_eq!(chunks.kept().chunks.len(), CHUNKS_KEPT);
        assert!(chunks.get(0, 19).is_some() && chunks.get(0, 0).is_none());
        chunks.keep(0, 100, vec![0; CHUNK_BYTES_KEPT]);
        assert_eq!(
            chunks.kept().chunks.len(),
            1,
            "the last is kept, whatever its size"
        );
    }
}
