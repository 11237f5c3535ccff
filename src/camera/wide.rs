//! The host's row projection: the same keys as
//! [`FrameProjector::project_row`], computed a chunk of samples at a time.
//!
//! A chunk kernel projects [`CHUNK`] samples branch-free into a key buffer
//! (every sample gets its key or [`NO_KEY`]) and marks the keys that differ
//! from the previous sample's; the row loop then copies only those. A row
//! is a few runs of one voxel each, so the copy touches few keys. The
//! kernel is a parameter so that a host can pass one written for its
//! vector unit; [`portable_chunk`] is written for LLVM to vectorize. Only
//! where 64-bit multiplies are native: a Cortex-M keeps the
//! one-pixel-at-a-time loop, which suits its few registers better.

use super::{FrameProjector, MAX_SHIFT};

/// Samples a kernel projects at once: one `u64` mask of new keys.
pub const CHUNK: usize = 64;

/// A sample without a key in a chunk's buffer (invalid depth or out of
/// range): packed keys use 63 bits, so no key equals it.
pub const NO_KEY: u64 = u64::MAX;

/// One row's projection as a chunk kernel computes it (the fixed-point
/// arithmetic of `fast_loop`, widened to 64-bit lanes). A sample `raw` is
/// valid when `raw - lo <= span` (unsigned; `lo > 0`, so raw 0, which pads
/// a short chunk, is never valid). Per axis, its point is
/// `p = raw * ray + t` as a wrapping `i64` seen as `u64`, with `ray` the
/// chunk's ray plus `i * step` for sample `i`; the key is in range when
/// `px | py | pz < 2^61` and is then
/// `(px >> 40) << 42 | (py >> 40) << 21 | pz >> 40`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChunkRays {
    /// Fixed-point ray of the chunk's first sample, per axis.
    pub ray: [i64; 3],
    /// Its step from one sample to the next.
    pub step: [i64; 3],
    /// Camera centre, biased so that keys are non-negative.
    pub t: [i64; 3],
    /// Smallest valid raw depth.
    pub lo: u64,
    /// Valid raw depths past `lo`.
    pub span: u64,
}

/// What a kernel found in a chunk besides its keys.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChunkCounts {
    /// Bit `i` set when sample `i` has a key that differs from the key (or
    /// [`NO_KEY`]) of the sample before it.
    pub new: u64,
    /// Samples with a valid depth.
    pub valid: u32,
    /// Valid samples whose key is out of range.
    pub outside: u32,
}

/// Projects `raws` with `rays` into `keys` (key or [`NO_KEY`] per sample);
/// `previous` is the key of the sample before the chunk. Written for LLVM
/// to vectorize: no branch, 64-bit lanes throughout.
#[inline(always)]
pub fn portable_chunk(
    raws: &[u16; CHUNK],
    rays: ChunkRays,
    previous: u64,
    keys: &mut [u64; CHUNK],
) -> ChunkCounts {
    let ChunkRays {
        ray: [mut x, mut y, mut z],
        step: [sx, sy, sz],
        t: [tx, ty, tz],
        lo,
        span,
    } = rays;
    // Counters as wide as the lanes, so that counting converts nothing.
    let (mut valid, mut outside) = (0u64, 0u64);
    for (&raw, key) in raws.iter().zip(keys.iter_mut()) {
        let raw = u64::from(raw);
        let ok = raw.wrapping_sub(lo) <= span;
        let p = |ray: i64, t: i64| (raw as i64).wrapping_mul(ray).wrapping_add(t) as u64;
        let (px, py, pz) = (p(x, tx), p(y, ty), p(z, tz));
        let inside = (px | py | pz) < 1 << 61;
        let packed = (px >> 40) << 42 | (py >> 40) << 21 | (pz >> 40);
        *key = if ok & inside { packed } else { NO_KEY };
        valid += u64::from(ok);
        outside += u64::from(ok & !inside);
        (x, y, z) = (x.wrapping_add(sx), y.wrapping_add(sy), z.wrapping_add(sz));
    }
    let mut new = 0u64;
    let mut before = previous;
    for (i, &k) in keys.iter().enumerate() {
        new |= u64::from(k != before && k != NO_KEY) << i;
        before = k;
    }
    // At most `CHUNK` each.
    ChunkCounts {
        new,
        valid: valid as u32,
        outside: outside as u32,
    }
}

impl FrameProjector {
    /// The keys of [`Self::project_row`] with [`portable_chunk`]; see
    /// [`Self::project_row_with`].
    #[inline(always)]
    pub fn project_row_into(
        &self,
        v: u16,
        row: &[u16],
        out_of_range: &mut u32,
        keys: &mut [u64],
    ) -> (u32, usize) {
        self.project_row_with(v, row, out_of_range, keys, &mut portable_chunk)
    }

    /// The keys of [`Self::project_row`], computed by `kernel` a chunk at a
    /// time and written to `keys` instead of emitted, leaving out a key
    /// equal to the previous sample's (so consecutive repeats are dropped
    /// unless an invalid pixel separates them). Returns the valid pixels
    /// and how many keys were written; `out_of_range` counts as in
    /// `project_row`. At most `keys.len()` keys are written, and at most
    /// [`Self::samples_per_row`] are needed. `kernel` must compute what
    /// [`portable_chunk`] does; at extreme scales (fewer fixed-point bits)
    /// the general loop runs instead.
    #[inline(always)]
    pub fn project_row_with(
        &self,
        v: u16,
        row: &[u16],
        out_of_range: &mut u32,
        keys: &mut [u64],
        kernel: &mut impl FnMut(&[u16; CHUNK], ChunkRays, u64, &mut [u64; CHUNK]) -> ChunkCounts,
    ) -> (u32, usize) {
        let mut written = 0usize;
        if self.shift != MAX_SHIFT {
            let mut last = NO_KEY;
            let valid = self.project_row(v, row, out_of_range, |key| {
                let bits = key.to_bits();
                if bits != last {
                    if let Some(slot) = keys.get_mut(written) {
                        *slot = bits;
                        written += 1;
                    }
                }
                last = bits;
            });
            return (valid, written);
        }
        let Some(mut rays) = self.row_chunk_rays(v) else {
            return (0, 0);
        };
        let chunk_step = rays.step.map(|s| s.wrapping_mul(CHUNK as i64));
        // The samples are pixels 0, stride, ..: cut the row after the last.
        let stride = usize::from(self.stride);
        let samples = usize::from(self.samples_per_row());
        let row = row.get(..(samples - 1) * stride + 1).unwrap_or(row);
        let (mut valid, mut outside) = (0u32, 0u32);
        let mut previous = NO_KEY;
        let mut chunk_keys = [NO_KEY; CHUNK];
        for piece in row.chunks(CHUNK * stride) {
            // A whole chunk of consecutive samples is read in place; others
            // are gathered, with zeros (never valid) past the row's end.
            let mut gathered = [0u16; CHUNK];
            let raws = match <&[u16; CHUNK]>::try_from(piece) {
                Ok(whole) if stride == 1 => whole,
                _ => {
                    for (r, s) in gathered.iter_mut().zip(piece.iter().step_by(stride)) {
                        *r = *s;
                    }
                    &gathered
                }
            };
            let counts = kernel(raws, rays, previous, &mut chunk_keys);
            valid += counts.valid;
            outside += counts.outside;
            written = copy_new(&chunk_keys, counts.new, keys, written);
            previous = chunk_keys[CHUNK - 1];
            for (r, s) in rays.ray.iter_mut().zip(&chunk_step) {
                *r = r.wrapping_add(*s);
            }
        }
        *out_of_range = out_of_range.saturating_add(outside);
        (valid, written)
    }
}

impl FrameProjector {
    /// The [`ChunkRays`] of the first sample of row `v`, for a host that
    /// runs a row loop of its own (sample `i`'s ray is `ray + i * step`).
    /// `None` where [`Self::project_row_with`] projects nothing (a row the
    /// stride skips or below the image, an empty depth range), and where the
    /// projector uses fewer fixed-point bits (extreme scales), which only
    /// [`Self::project_row_with`] handles.
    pub fn row_chunk_rays(&self, v: u16) -> Option<ChunkRays> {
        let span = self.raw_max.checked_sub(self.raw_min)?;
        if self.shift != MAX_SHIFT || !self.projects_row(v) {
            return None;
        }
        let (ray, step) = self.row_rays(v);
        Some(ChunkRays {
            ray,
            step,
            t: self.biased_translation(),
            lo: u64::from(self.raw_min),
            span: u64::from(span),
        })
    }
}

/// Copies the keys of `chunk` marked in `new` to `out` from index `n`;
/// returns the new end (at most `out.len()`).
#[inline(always)]
fn copy_new(chunk: &[u64; CHUNK], mut new: u64, out: &mut [u64], mut n: usize) -> usize {
    // A chunk usually holds a few new keys: that many steps without a
    // branch (a step past the last key writes a key that the next one
    // overwrites, or none when `out` is full), then a loop for the rest.
    for _ in 0..4 {
        let i = new.trailing_zeros() as usize % CHUNK;
        if let (Some(slot), Some(&k)) = (out.get_mut(n), chunk.get(i)) {
            *slot = k;
            n += usize::from(new != 0);
        }
        new &= new.wrapping_sub(1);
    }
    while new != 0 {
        let i = new.trailing_zeros() as usize;
        if let (Some(slot), Some(&k)) = (out.get_mut(n), chunk.get(i)) {
            *slot = k;
            n += 1;
        }
        new &= new - 1;
    }
    n
}
