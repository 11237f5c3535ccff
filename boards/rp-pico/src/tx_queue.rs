//! The reply bytes waiting for the host: a fixed ring that takes frames a
//! slice at a time and gives them back a USB packet at a time.
//!
//! A `heapless::Deque` moves one byte per call each way; the link copies
//! every reply byte in and out of this queue, so both sides copy slices.

/// A byte ring of `N` bytes.
pub struct TxQueue<const N: usize> {
    buf: [u8; N],
    /// Index of the oldest byte.
    head: usize,
    len: usize,
}

impl<const N: usize> TxQueue<N> {
    pub const fn new() -> Self {
        TxQueue {
            buf: [0; N],
            head: 0,
            len: 0,
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn free(&self) -> usize {
        N - self.len
    }

    /// Appends as much of `bytes` as fits; returns how much that was.
    pub fn push(&mut self, bytes: &[u8]) -> usize {
        let n = bytes.len().min(self.free());
        let tail = (self.head + self.len) % N.max(1);
        // At most two runs: up to the end of the ring, then from its start.
        let first = n.min(N - tail);
        let (a, b) = bytes.split_at(first);
        if let Some(dest) = self.buf.get_mut(tail..tail + first) {
            dest.copy_from_slice(a);
        }
        if let Some(dest) = self.buf.get_mut(..n - first) {
            dest.copy_from_slice(b.get(..n - first).unwrap_or_default());
        }
        self.len += n;
        n
    }

    /// The oldest `min(max, len)` bytes: contiguous when they do not wrap
    /// around the end of the ring, else copied into `scratch`.
    pub fn front<'s>(&'s self, max: usize, scratch: &'s mut [u8]) -> &'s [u8] {
        let n = max.min(self.len).min(scratch.len());
        let first = n.min(N - self.head);
        let head = self
            .buf
            .get(self.head..self.head + first)
            .unwrap_or_default();
        if first == n {
            return head;
        }
        let wrapped = self.buf.get(..n - first).unwrap_or_default();
        let (a, b) = scratch.split_at_mut(first);
        a.copy_from_slice(head);
        if let Some(dest) = b.get_mut(..wrapped.len()) {
            dest.copy_from_slice(wrapped);
        }
        scratch.get(..n).unwrap_or_default()
    }

    /// Drops the oldest `n` bytes (all of them if fewer are queued).
    pub fn pop(&mut self, n: usize) {
        let n = n.min(self.len);
        self.head = (self.head + n) % N.max(1);
        self.len -= n;
    }
}
