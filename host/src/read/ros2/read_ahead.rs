//! Chunk records read ahead, decompressed a few at a time in parallel and
//! then walked in file order: how the walks of a ROS 1 bag and of an MCAP
//! file keep both cores busy on compressed chunks, while what their
//! visitor sees, and the first error, are as if the chunks were read one
//! by one.

use rayon::prelude::*;

/// Most chunk records read ahead, and most bytes they may claim
/// uncompressed together (a chunk claiming more is decompressed alone).
const MOST_CHUNKS: usize = 8;
const MOST_BYTES: u64 = 64 << 20;

/// Chunk records read and not yet walked, in file order (`C`: what a
/// storage keeps of one, its place and its bytes).
pub struct ReadAhead<C> {
    pending: Vec<C>,
    /// The bytes the pending chunks claim uncompressed.
    claimed: u64,
    /// Buffers to decompress the pending chunks into, reused.
    outs: Vec<Vec<u8>>,
    /// Buffers of chunks walked, to read the next ones into.
    spare: Vec<Vec<u8>>,
}

impl<C> Default for ReadAhead<C> {
    fn default() -> Self {
        ReadAhead {
            pending: Vec::new(),
            claimed: 0,
            outs: Vec::new(),
            spare: Vec::new(),
        }
    }
}

impl<C: Sync> ReadAhead<C> {
    /// Whether the pending chunks are to be walked before one claiming
    /// `claims` bytes uncompressed joins them.
    pub fn is_full_for(&self, claims: u64) -> bool {
        !self.pending.is_empty()
            && (self.pending.len() == MOST_CHUNKS
                || self.claimed.saturating_add(claims) > MOST_BYTES)
    }

    /// A buffer to read the next chunk record into (one of a chunk walked,
    /// or a new one).
    pub fn buffer(&mut self) -> Vec<u8> {
        self.spare.pop().unwrap_or_default()
    }

    /// Adds a chunk record read (claiming `claims` bytes uncompressed).
    pub fn push(&mut self, chunk: C, claims: u64) {
        self.claimed = self.claimed.saturating_add(claims);
        self.pending.push(chunk);
    }

    /// Decompresses the pending chunks in parallel, each by `decompress`
    /// into a buffer of its own (its records, and what else the walk
    /// needs), and hands each to `walk` in file order, stopping at the
    /// first error. `bytes` gives a chunk's buffer back for the next
    /// records to be read into.
    pub fn walk<T: Send, E: Send>(
        &mut self,
        decompress: impl for<'a> Fn(&'a C, &'a mut Vec<u8>) -> Result<(&'a [u8], T), E> + Sync,
        mut walk: impl FnMut(&C, &[u8], T) -> Result<(), E>,
        bytes: impl Fn(C) -> Vec<u8>,
    ) -> Result<(), E> {
        let pending = std::mem::take(&mut self.pending);
        self.claimed = 0;
        let mut outs = std::mem::take(&mut self.outs);
        outs.resize_with(outs.len().max(pending.len()), Vec::new);
        let chunks: Vec<Result<(&[u8], T), E>> = pending
            .par_iter()
            .zip(outs.par_iter_mut())
            .map(|(c, out)| decompress(c, out))
            .collect();
        let mut walked = Ok(());
        for (c, chunk) in pending.iter().zip(chunks) {
            walked = chunk.and_then(|(records, extra)| walk(c, records, extra));
            if walked.is_err() {
                break;
            }
        }
        self.spare
            .extend(pending.into_iter().map(bytes).take(MOST_CHUNKS));
        self.outs = outs;
        walked
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunks_are_walked_in_order_and_the_first_error_wins() {
        let mut ahead = ReadAhead::default();
        for i in 0..6u8 {
            assert!(!ahead.is_full_for(1));
            ahead.push([i; 3], 1);
        }
        // Chunk 2 fails to decompress, chunk 4 too; chunk 1's walk fails.
        fn decompress<'a>(c: &'a [u8; 3], out: &'a mut Vec<u8>) -> Result<(&'a [u8], u8), String> {
            match c[0] {
                2 | 4 => Err(format!("decompress {}", c[0])),
                n => {
                    out.clear();
                    out.extend(c.iter().map(|b| b + 10));
                    Ok((&out[..], n))
                }
            }
        }
        let mut seen = Vec::new();
        let first = ahead.walk(
            decompress,
            |c, records, n| {
                seen.push((c[0], records.to_vec(), n));
                if c[0] == 1 {
                    Err("walk 1".to_string())
                } else {
                    Ok(())
                }
            },
            |c| c.to_vec(),
        );
        assert_eq!(first, Err("walk 1".to_string()));
        assert_eq!(seen, [(0, vec![10; 3], 0), (1, vec![11; 3], 1)]);
        // Walked (or dropped) once: nothing pending, buffers kept.
        assert!(ahead
            .walk(decompress, |_, _, _| Ok(()), |c| c.to_vec())
            .is_ok());
        assert!(!ahead.buffer().is_empty());
        // Bounded in number and in bytes claimed.
        for _ in 0..MOST_CHUNKS {
            ahead.push([0; 3], 1);
        }
        assert!(ahead.is_full_for(1));
        let mut big = ReadAhead::default();
        big.push([0u8; 3], MOST_BYTES);
        assert!(big.is_full_for(1) && !ReadAhead::<[u8; 3]>::default().is_full_for(u64::MAX));
    }
}
