//! Four rows' keys in single precision with AVX-512, a tile of four rows by
//! eight samples at a time where it can, with keys exactly those of the
//! fixed-point definition or no answer at all.
//!
//! Per axis a sample's key is `t_int + floor(q)` with
//! `q = raw * (R_v + l S) / 2^40 + t_frac`: the fixed-point sum split at
//! the binary point, `t_frac` in `[0, 1)`, `R_v` row `v`'s ray, `S` the step
//! from sample to sample (the same in every row). Against a reference ray
//! `R_c` with `|R_v - R_c| <= dR` over the four rows, a valid sample of a
//! tile (`raw` in `[rc - dr, rc + dr]`, `l` in `[lc - 3.5, lc + 3.5]`) has
//! `|q - q_c| <= dr |R_c + lc S| + r_hi (dR + 3.5 |S|)` with `q_c` the
//! tile's centre `raw = rc`, `l = lc` and `r_hi` its largest raw. Where
//! `q_c` is farther than that (and the float errors) from an integer on
//! every axis, every valid sample of the tile has the centre's key: one
//! evaluation instead of 32. Neighbouring pixels mostly share a voxel, so
//! most tiles pass; the others are projected sample by sample, sixteen
//! (two rows of a tile) to a vector, and a sample too near an integer for
//! the float error is computed exactly.
//!
//! A failing tile mostly straddles one voxel edge: failing on one axis
//! only, with `spread + 8 E` below a quarter voxel there, its samples have
//! one of two keys, the centre's and the centre's with that axis's floor one
//! step towards the integer in reach (the only integer within the spread of
//! the centre). Where the frame has kept both already (an edge crosses many
//! tiles, and the voxels either side of it are mostly met before), the tile
//! adds nothing and is not projected at all: on 7-Scenes about two thirds
//! of the failing tiles, three quarters of them failing this way.
//!
//! A tile's smallest and largest valid raw cost little: across its rows
//! they are element-wise minima (of `raw - lo` and of `hi - raw`, both
//! above `span` for an invalid sample), and along a row the four quarters
//! of a step are reduced together, a shuffle merging two vectors at each
//! halving.
//!
//! The float error, with `u = 2^-24` (round to nearest), rays bounded by
//! `B` (`|R_v + l S| <= B` and `|R_c + l S| <= B` over the padded rows),
//! `l |S| <= B_S`, raws up to `r_max`: the converted `R`, `S`, `t_frac` are
//! within `u` of theirs relative; a ray `fma(l, S, R)` is within
//! `u (1 + u) (B_S + B) + u B_S` of `R + l S`; and `q = fma(raw, ray, t_frac)`
//! is within `u [(1 + u)^2 r_max (2 B + B_S) + (1 + u) + r_max B + 1]` of
//! the exact value, below `E = 2 u (r_max (3 B + B_S) + 2)` (computed in
//! `f64` and rounded up). `x - round(x)` (`vreduceps`) is exact, so a sample
//! with `|q - round(q)| > E` has the floor of the exact `q`. A tile's
//! spread is computed from the same converted ray with `dR + 3.5 |S|`
//! rounded up and three roundings, its error below `2 E`; a tile passes
//! when its centre is more than `spread + 8 E` from an integer (the margin
//! is far below a tile's spread: it costs no passes).
//!
//! Keys are deduplicated as 32-bit local keys (the three floors as
//! balanced base-1024 digits): a passing tile's key where it differs from
//! the tile before, a failing tile's keys once per two rows, then once per
//! frame as far as a small table of the keys kept so far remembers them.
//! Only those are packed into keys: fewer than two per distinct voxel on
//! recorded 7-Scenes frames (a test checks it), where dropping the
//! neighbours' repeats alone left about a hundred.

use placedb::camera::wide::ChunkRays;
use std::arch::x86_64::*;

/// Rows a tile (and a band) holds.
pub(super) const ROWS: usize = 4;
/// Samples a tile row holds: a 128-bit lane of sixteen-bit raws.
const WIDTH: usize = 8;
/// Lanes of a vector: tiles a step, samples a per-pixel vector.
const LANES: usize = 16;
/// Samples of a row in one step of the tile loop: a tile per lane.
const STEP: usize = WIDTH * LANES;
/// Local keys are three balanced base-1024 digits: floors of at most this
/// magnitude.
const DIGIT_MAX: i64 = 511;
/// A local key no valid sample has: an invalid sample's.
const NOT_A_KEY: i32 = i32::MIN;
/// The table of kept local keys has `2^SEEN_BITS` slots, 16 KiB: room for
/// the distinct voxels of a 640x480 frame down to 5 cm voxels (about 3,400
/// on 7-Scenes; 130 at 0.3 m), within half of a 32 KiB L1 data cache.
const SEEN_BITS: u32 = 12;
const SEEN_SLOTS: usize = 1 << SEEN_BITS;
/// Fibonacci hashing into the table: the top bits of the product mix all
/// digits of a local key.
const SEEN_HASH: u32 = 0x9E37_79B1;
/// A tile whose spread (with its margin) on a failing axis is below this
/// has at most two floors there: its samples lie within less than half a
/// voxel of its centre, so at most one integer is in reach.
const NARROW: f32 = 0.25;
/// Keys are 21 bits an axis.
const AXIS_KEYS: i64 = 1 << 21;
/// `2^-40`: fixed point to voxels (a power of two: multiplying by it is
/// exact).
const UNIT: f32 = 1.0 / (1u64 << 40) as f32;
/// What the rows of a frame share: the step, the translation and the
/// valid raws are the same in every row.
#[derive(Debug, Clone, Copy)]
struct Frame {
    /// The step per raw unit, voxels.
    step: [f32; 3],
    /// Fractional and integer parts of the biased translation, voxels.
    t_frac: [f32; 3],
    t_int: [i64; 3],
    /// Largest valid raw.
    r_max: f64,
    /// The largest `|floor(q)|` every axis's keys have room for, within
    /// the digits.
    room: f64,
}

impl Frame {
    fn new(rays: &ChunkRays) -> Frame {
        let (mut step, mut t_frac, mut t_int) = ([0.0; 3], [0.0; 3], [0; 3]);
        for a in 0..3 {
            step[a] = rays.step[a] as f32 * UNIT;
            t_int[a] = rays.t[a] >> 40;
            t_frac[a] = (rays.t[a] - (t_int[a] << 40)) as f32 * UNIT;
        }
        let room = t_int
            .iter()
            .map(|&t| t.min(AXIS_KEYS - 1 - t))
            .fold(DIGIT_MAX, i64::min);
        Frame {
            step,
            t_frac,
            t_int,
            r_max: (rays.lo + rays.span) as f64,
            room: room as f64,
        }
    }

    /// The packed key of local key `local` (balanced base-1024 digits
    /// `[x, y, z]` of floors that fit them: `local = x 2^20 + y 2^10 + z`).
    fn key(&self, local: i32) -> u64 {
        // Each digit is the low ten bits, sign-extended; taken off, the
        // rest shifts down exactly.
        let low = |v: i32| (v << 22) >> 22;
        let z = low(local);
        let rest = (local - z) >> 10;
        let y = low(rest);
        let x = (rest - y) >> 10;
        let axis = |floor: i32, a: usize| (i64::from(floor) + self.t_int[a]) as u64;
        axis(x, 0) << 42 | axis(y, 1) << 21 | axis(z, 2)
    }
}

/// What a frame's rows share, as compared: what [`Frame`] is made of.
fn shared(rays: &ChunkRays) -> ([i64; 3], [i64; 3], u64, u64) {
    (rays.step, rays.t, rays.lo, rays.span)
}

/// A band's constants as vectors.
#[derive(Clone, Copy)]
struct Band {
    /// The reference ray of the tiles, voxels per raw unit.
    centre_ray: [__m512; 3],
    /// The rows' own rays, rows `2 p` and `2 p + 1` in the low and high
    /// eight lanes of pair `p`.
    pair_rays: [[__m512; 2]; 3],
    step: [__m512; 3],
    t_frac: [__m512; 3],
    /// `dR + 3.5 |S|`, rounded up.
    half_tile: [__m512; 3],
    /// `E` and the tiles' margin `8 E`.
    error: __m512,
    margin: __m512,
    lo: __m512,
    hi: __m512,
}

impl Band {
    /// The constants of the rows `rays` padded to `padded` samples, or
    /// `None` where the float path cannot promise the exact keys: floors
    /// that might not fit the digits or keys the key range (the path has
    /// no range test), or an error so large that most samples would be
    /// near an integer.
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx512cd,popcnt,bmi1")]
    #[inline]
    fn new(frame: &Frame, rays: &[ChunkRays; ROWS], padded: usize) -> Option<Band> {
        let last = padded.saturating_sub(1) as f64;
        let unit = f64::from(UNIT);
        let (mut b, mut b_s) = (0.0f64, 0.0f64);
        let mut centre = [0.0f32; 3];
        let mut d_r = [0.0f64; 3];
        for a in 0..3 {
            let s = rays[0].step[a] as f64 * unit;
            let mut row = [0.0f64; ROWS];
            for (x, r) in row.iter_mut().zip(rays) {
                *x = r.ray[a] as f64 * unit;
            }
            centre[a] = (row.iter().sum::<f64>() / ROWS as f64) as f32;
            for r in row {
                d_r[a] = d_r[a].max((r - f64::from(centre[a])).abs());
                // A ray is linear in the sample: largest at the ends.
                b = b.max(r.abs()).max((r + last * s).abs());
            }
            b_s = b_s.max(last * s.abs());
        }
        // The centre rays are within `dR` of a row's.
        let b = b + d_r.iter().fold(0.0f64, |m, &d| m.max(d));
        // Floors are within `r_max B + 2` of zero, and so are a tile's
        // candidate keys' within `r_max B + 3` (see `Tiles::other`).
        if frame.r_max * b + 3.0 > frame.room {
            return None;
        }
        let u = f64::from(f32::EPSILON) / 2.0;
        let error = 2.0 * u * (frame.r_max * (3.0 * b + b_s) + 2.0);
        if error >= 0.125 {
            return None;
        }
        // Rounded up: the f64 arithmetic here is far more precise (and
        // its absolute error far below `1e-9 B`).
        let up = |x: f64| (x * (1.0 + 1e-6) + 1e-9 * b) as f32;
        let all = |x: f32| _mm512_set1_ps(x);
        let zero = _mm512_setzero_ps();
        let mut band = Band {
            centre_ray: [zero; 3],
            pair_rays: [[zero; 2]; 3],
            step: [zero; 3],
            t_frac: [zero; 3],
            half_tile: [zero; 3],
            error: all(up(error)),
            margin: all(up(8.0 * error)),
            lo: all(rays[0].lo as f32),
            hi: all((rays[0].lo + rays[0].span) as f32),
        };
        for a in 0..3 {
            let row = |r: usize| all(rays[r].ray[a] as f32 * UNIT);
            band.centre_ray[a] = all(centre[a]);
            for p in 0..2 {
                band.pair_rays[a][p] = _mm512_mask_blend_ps(0xff00, row(2 * p), row(2 * p + 1));
            }
            band.step[a] = all(frame.step[a]);
            band.t_frac[a] = all(frame.t_frac[a]);
            band.half_tile[a] = all(up(d_r[a] + 3.5 * f64::from(frame.step[a]).abs()));
        }
        Some(band)
    }
}

/// The tile path's band loop, holding its scratch space.
///
/// One serves one frame: its table of kept keys is the frame's (a key kept
/// for another frame would be missing from this one's).
#[derive(Debug)]
pub(super) struct Bands {
    /// A band's local keys its vectors found new, packed.
    locals: Vec<i32>,
    /// The local keys kept so far, by hash (local keys are the frame's:
    /// its rows share their translation).
    seen: [i32; SEEN_SLOTS],
}

impl Default for Bands {
    fn default() -> Self {
        Bands {
            locals: Vec::new(),
            seen: [NOT_A_KEY; SEEN_SLOTS],
        }
    }
}

impl Bands {
    /// Appends to `keys` the keys of four consecutive rows of samples
    /// (`rows[r]` with rays `rays[r]`, sample `l`'s ray
    /// `rays[r].ray + l * rays[r].step`; rows of one frame and length),
    /// with repeats, in no particular order; returns the valid samples.
    /// `ahead` is what the next band will read, fetched into the cache
    /// meanwhile.
    /// `None`, with nothing appended, where the float path cannot promise
    /// the exact keys (no key of the rows is out of range otherwise): the
    /// caller then runs the exact loop.
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx512cd,popcnt,bmi1")]
    pub(super) fn band(
        &mut self,
        rays: &[ChunkRays; ROWS],
        rows: [&[u16]; ROWS],
        ahead: &[u16],
        keys: &mut Vec<u64>,
    ) -> Option<u32> {
        let samples = rows[0].len();
        if rays.iter().any(|r| shared(r) != shared(&rays[0]))
            || rows.iter().any(|r| r.len() != samples)
        {
            return None;
        }
        // A few conversions a band: cheaper than keeping them per frame.
        let frame = Frame::new(&rays[0]);
        let padded = samples.div_ceil(STEP) * STEP;
        let band = Band::new(&frame, rays, padded)?;
        // Room for a key per sample, and a vector's store past the last.
        let most = ROWS * padded + LANES;
        if self.locals.len() < most {
            self.locals.resize(most, 0);
        }
        let mut records = Records {
            locals: &mut self.locals,
            n: 0,
        };
        let (lo, span) = (rays[0].lo as u16, rays[0].span as u16);
        let mut valid = 0u32;
        let mut before = _mm512_set1_epi32(NOT_A_KEY);
        // The last step's rows padded with zeros, which are never valid.
        let mut tails = [[0u16; STEP]; ROWS];
        for s in 0..padded / STEP {
            let first = STEP * s;
            if first + STEP > samples {
                for (tail, row) in tails.iter_mut().zip(rows) {
                    tail[..samples - first].copy_from_slice(&row[first..]);
                }
            }
            let raw_row = |r: usize| -> &[u16; STEP] {
                match rows[r]
                    .get(first..first + STEP)
                    .map(<&[u16; STEP]>::try_from)
                {
                    Some(Ok(whole)) => whole,
                    _ => &tails[r],
                }
            };
            let raws = [raw_row(0), raw_row(1), raw_row(2), raw_row(3)];
            // The next band's share of the step fetched into the cache (a
            // band is a few rows, which the hardware prefetcher follows
            // less well than one).
            let share = ROWS * STEP * s;
            if share < ahead.len() {
                // Past the end only when `ahead` ends mid-share: a prefetch
                // of any address is harmless.
                let from = ahead.as_ptr().wrapping_add(share);
                for line in 0..ROWS * STEP / 32 {
                    _mm_prefetch::<_MM_HINT_T0>(from.wrapping_add(32 * line).cast());
                }
            }
            let tiles = step_tiles(&band, raws, first, lo, span);
            valid += tiles.valid;
            // The passing tiles' keys, a run of one key once.
            let local =
                _mm512_mask_blend_epi32(tiles.pass, _mm512_set1_epi32(NOT_A_KEY), tiles.local);
            let shifted = _mm512_alignr_epi32::<15>(local, before);
            records.push(
                local,
                _mm512_mask_cmpneq_epi32_mask(tiles.pass, local, shifted),
            );
            before = local;
            // The others sample by sample, two rows to a vector, but for
            // those whose two possible keys the frame has kept already
            // (most: a voxel edge runs across many tiles).
            let kept = both_kept(&self.seen, tiles.local, tiles.other, tiles.two_keys);
            let mut failed = tiles.fail & !kept;
            while failed != 0 {
                let t = failed.trailing_zeros() as usize;
                failed &= failed - 1;
                for pair in 0..ROWS / 2 {
                    if let Some((local, new)) =
                        pixel_locals(&frame, &band, rays, raws, first, t, pair, lo, span)
                    {
                        records.push(local, new);
                    }
                }
            }
        }
        let n = records.n;
        keep_unseen(&frame, &self.locals[..n], &mut self.seen, keys);
        Some(valid)
    }
}

/// The local keys a vector found new, packed into a buffer a vector at a
/// time.
struct Records<'a> {
    locals: &'a mut [i32],
    n: usize,
}

impl Records<'_> {
    /// Appends the lanes of `local` marked in `new`.
    #[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx512cd,popcnt,bmi1")]
    #[inline]
    fn push(&mut self, local: __m512i, new: u16) {
        if let Some(slot) = self.locals.get_mut(self.n..self.n + LANES) {
            let packed = _mm512_maskz_compress_epi32(new, local);
            // SAFETY: writes the 64 bytes of `slot`, sixteen i32.
            unsafe { _mm512_storeu_si512(slot.as_mut_ptr().cast(), packed) };
            self.n += new.count_ones() as usize;
        }
    }
}

/// Appends to `keys` the key of each of `locals` not found in its slot of
/// `seen`, a table of the keys kept before, and records it there. A
/// frame's few voxels recur all along its rows (tiles alternate between
/// the voxels of an edge, failing tiles emit two row pairs): what is left
/// to convert, sort and store is little more than the frame's key set, and
/// the loop mostly reads (the branch to a new key is rarely taken).
fn keep_unseen(frame: &Frame, locals: &[i32], seen: &mut [i32; SEEN_SLOTS], keys: &mut Vec<u64>) {
    for &local in locals {
        let slot = &mut seen[(local as u32).wrapping_mul(SEEN_HASH) as usize >> (32 - SEEN_BITS)];
        if *slot != local {
            *slot = local;
            keys.push(frame.key(local));
        }
    }
}

/// The lanes of `lanes` where both `a` and `b` are in their slots of
/// `seen`, the table of kept keys (a key found there was kept: a key
/// missing from it may have been kept and overwritten).
#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx512cd,popcnt,bmi1")]
#[inline]
fn both_kept(seen: &[i32; SEEN_SLOTS], a: __m512i, b: __m512i, lanes: u16) -> u16 {
    let found = |keys: __m512i| {
        let product = _mm512_mullo_epi32(keys, _mm512_set1_epi32(SEEN_HASH as i32));
        let slots = _mm512_srli_epi32::<{ 32 - SEEN_BITS }>(product);
        // SAFETY: reads the lanes' slots of `seen`, each below
        // `SEEN_SLOTS` (the top `SEEN_BITS` bits of a 32-bit word).
        let held = unsafe {
            _mm512_mask_i32gather_epi32::<4>(
                _mm512_set1_epi32(NOT_A_KEY),
                lanes,
                slots,
                seen.as_ptr().cast(),
            )
        };
        _mm512_mask_cmpeq_epi32_mask(lanes, held, keys)
    };
    found(a) & found(b)
}

/// What the tile test found in one step of [`STEP`] samples a row.
struct Tiles {
    /// Tiles with a valid sample whose samples all have the key of
    /// `local`'s lane.
    pass: u16,
    /// Tiles with a valid sample that did not pass.
    fail: u16,
    local: __m512i,
    /// Failing tiles whose samples all have the key of `local` or of
    /// `other`: those that failed on one axis only, narrowly.
    two_keys: u16,
    /// `local` with the failing axis's floor one step towards the integer
    /// in reach; meaningless outside `two_keys`.
    other: __m512i,
    valid: u32,
}

/// The tile test on the four rows `raws` of [`STEP`] samples, of which the
/// first is sample `first` of its row; `lo` and `span` as in [`ChunkRays`].
#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx512cd,popcnt,bmi1")]
#[inline]
fn step_tiles(band: &Band, raws: [&[u16; STEP]; ROWS], first: usize, lo: u16, span: u16) -> Tiles {
    let (lo16, span16, hi16) = (
        _mm512_set1_epi16(lo as i16),
        _mm512_set1_epi16(span as i16),
        _mm512_set1_epi16(lo.wrapping_add(span) as i16),
    );
    let mut valid = 0u32;
    // Per quarter (32 samples, four tiles: one per 128-bit lane), the
    // smallest `raw - lo` and `hi - raw` over the rows (an invalid sample's
    // are both above `span`), then halved within each tile once, the two
    // side by side: [least `raw - lo` x 4 | least `hi - raw` x 4] a lane.
    let quarter = |k: usize| {
        let (mut below, mut above) = (_mm512_set1_epi16(-1), _mm512_set1_epi16(-1));
        let mut count = 0u32;
        for row in raws {
            // SAFETY: reads the 64 bytes of the row's quarter, 32 u16.
            let raw = unsafe { _mm512_loadu_si512(row[32 * k..][..32].as_ptr().cast()) };
            let offset = _mm512_sub_epi16(raw, lo16);
            count += _mm512_cmple_epu16_mask(offset, span16).count_ones();
            below = _mm512_min_epu16(below, offset);
            above = _mm512_min_epu16(above, _mm512_sub_epi16(hi16, raw));
        }
        let halves = _mm512_min_epu16(
            _mm512_unpacklo_epi64(below, above),
            _mm512_unpackhi_epi64(below, above),
        );
        (halves, count)
    };
    let mut halves = [_mm512_setzero_si512(); 4];
    for (k, h) in halves.iter_mut().enumerate() {
        let (q, count) = quarter(k);
        *h = q;
        valid += count;
    }
    // Quarters two by two: dwords 0 and 2 against 1 and 3 of each lane,
    // [below x 2 | above x 2] per tile of either quarter.
    let merge = |a: __m512i, b: __m512i| {
        let (a, b) = (_mm512_castsi512_ps(a), _mm512_castsi512_ps(b));
        _mm512_min_epu16(
            _mm512_castps_si512(_mm512_shuffle_ps::<0b10_00_10_00>(a, b)),
            _mm512_castps_si512(_mm512_shuffle_ps::<0b11_01_11_01>(a, b)),
        )
    };
    let (e, f) = (merge(halves[0], halves[1]), merge(halves[2], halves[3]));
    // The last halving: each dword's low word against its high word.
    let e = _mm512_min_epu16(e, _mm512_srli_epi32::<16>(e));
    let f = _mm512_min_epu16(f, _mm512_srli_epi32::<16>(f));
    // Lane j of `e` holds tiles j (words 0, 2) and 4 + j (words 4, 6);
    // of `f`, tiles 8 + j and 12 + j: picked into tile order, `raw - lo`
    // first.
    let mut order = [0i16; 32];
    for (t, o) in order[..16].iter_mut().enumerate() {
        *o = ((t & 8) * 4 + (t & 3) * 8 + (t & 4)) as i16;
    }
    for t in 0..16 {
        order[16 + t] = order[t] + 2;
    }
    // SAFETY: reads the 64 bytes of `order`, 32 i16.
    let order = unsafe { _mm512_loadu_si512(order.as_ptr().cast()) };
    let least = _mm512_permutex2var_epi16(e, order, f);
    let below = _mm512_cvtepu16_epi32(_mm512_castsi512_si256(least));
    let above = _mm512_cvtepu16_epi32(_mm512_extracti64x4_epi64::<1>(least));
    let has_valid = _mm512_cmple_epu32_mask(below, _mm512_set1_epi32(i32::from(span)));
    let r_lo = _mm512_add_ps(_mm512_cvtepi32_ps(below), band.lo);
    let r_hi = _mm512_sub_ps(band.hi, _mm512_cvtepi32_ps(above));
    // Exact: integers below 2^17, halved.
    let half = _mm512_set1_ps(0.5);
    let centre = _mm512_mul_ps(_mm512_add_ps(r_lo, r_hi), half);
    let spread_raw = _mm512_mul_ps(_mm512_sub_ps(r_hi, r_lo), half);
    let tile_lane = _mm512_setr_ps(
        3.5, 11.5, 19.5, 27.5, 35.5, 43.5, 51.5, 59.5, 67.5, 75.5, 83.5, 91.5, 99.5, 107.5, 115.5,
        123.5,
    );
    let l = _mm512_add_ps(tile_lane, _mm512_set1_ps(first as f32));
    let mut pass = has_valid;
    let mut floors = [_mm512_setzero_si512(); 3];
    // Per axis, the tiles failing on it; the failing tiles' narrow ones;
    // and the step from a floor to the other floor in reach.
    let mut fails = [0u16; 3];
    let mut narrow = has_valid;
    let mut towards = _mm512_setzero_si512();
    for (a, floor) in floors.iter_mut().enumerate() {
        let ray = _mm512_fmadd_ps(l, band.step[a], band.centre_ray[a]);
        let q = _mm512_fmadd_ps(centre, ray, band.t_frac[a]);
        // 0x08: no fraction bits kept, round to nearest, no exception.
        let near = _mm512_reduce_ps::<0x08>(q);
        // dr |ray| + r_hi (dR + 3.5 |S|), plus the errors: every valid
        // sample's exact `q` is less than `reach` from the centre's.
        let spread = _mm512_fmadd_ps(
            spread_raw,
            _mm512_abs_ps(ray),
            _mm512_mul_ps(r_hi, band.half_tile[a]),
        );
        let reach = _mm512_add_ps(spread, band.margin);
        let clear = _mm512_mask_cmp_ps_mask::<_CMP_GT_OQ>(has_valid, _mm512_abs_ps(near), reach);
        pass &= clear;
        fails[a] = has_valid & !clear;
        narrow &= !fails[a] | _mm512_cmp_ps_mask::<_CMP_LT_OQ>(reach, _mm512_set1_ps(NARROW));
        // The integer in reach is the nearest, `n`: a centre below it has
        // floor `n - 1` and the other floor is one up, else one down.
        let digit = _mm512_set1_epi32(1 << (10 * (2 - a)));
        let below = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(near, _mm512_setzero_ps());
        towards = _mm512_mask_mov_epi32(
            towards,
            fails[a],
            _mm512_mask_sub_epi32(digit, !below, _mm512_setzero_si512(), digit),
        );
        *floor = _mm512_cvt_roundps_epi32::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(q);
    }
    let local = combine(floors);
    let [x, y, z] = fails;
    // Exactly one failing axis.
    let one_axis = (x | y | z) & !(x & y | x & z | y & z);
    Tiles {
        pass,
        fail: has_valid & !pass,
        local,
        two_keys: one_axis & narrow,
        other: _mm512_add_epi32(local, towards),
        valid,
    }
}

/// The local keys of floors `[x, y, z]`, which fit the digits.
#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx512cd,popcnt,bmi1")]
#[inline]
fn combine([x, y, z]: [__m512i; 3]) -> __m512i {
    _mm512_add_epi32(
        _mm512_add_epi32(_mm512_slli_epi32::<20>(x), _mm512_slli_epi32::<10>(y)),
        z,
    )
}

/// Rows `2 pair` and `2 pair + 1` of tile `t` of `raws` sample by sample:
/// their local keys and which are new (valid, and the first lane with that
/// key), or `None` without a valid sample.
#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx512cd,popcnt,bmi1")]
#[inline]
#[allow(clippy::too_many_arguments)]
fn pixel_locals(
    frame: &Frame,
    band: &Band,
    rays: &[ChunkRays; ROWS],
    raws: [&[u16; STEP]; ROWS],
    first: usize,
    t: usize,
    pair: usize,
    lo: u16,
    span: u16,
) -> Option<(__m512i, u16)> {
    let row = |r: usize| {
        let samples = &raws[r][WIDTH * t..][..WIDTH];
        // SAFETY: reads the 16 bytes of `samples`, eight u16.
        unsafe { _mm_loadu_si128(samples.as_ptr().cast()) }
    };
    let raw16 = _mm256_set_m128i(row(2 * pair + 1), row(2 * pair));
    let ok = _mm256_cmple_epu16_mask(
        _mm256_sub_epi16(raw16, _mm256_set1_epi16(lo as i16)),
        _mm256_set1_epi16(span as i16),
    );
    if ok == 0 {
        return None;
    }
    let lane = _mm512_setr_ps(
        0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0,
    );
    // Sample indices are exact in f32 (rows are at most 2^16).
    let l = _mm512_add_ps(lane, _mm512_set1_ps((first + WIDTH * t) as f32));
    let raw = _mm512_cvtepi32_ps(_mm512_cvtepu16_epi32(raw16));
    let mut floors = [_mm512_setzero_si512(); 3];
    let mut closest = _mm512_set1_ps(1.0);
    for (a, floor) in floors.iter_mut().enumerate() {
        let ray = _mm512_fmadd_ps(l, band.step[a], band.pair_rays[a][pair]);
        let q = _mm512_fmadd_ps(raw, ray, band.t_frac[a]);
        // 0x08: as in `step_tiles`; 0b1010: the smaller magnitude.
        closest = _mm512_range_ps::<0b1010>(closest, _mm512_reduce_ps::<0x08>(q));
        *floor = _mm512_cvt_roundps_epi32::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(q);
    }
    let mut local = combine(floors);
    if _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(ok, closest, band.error) != 0 {
        local = exact_locals(frame, rays, raws, first, t, pair, ok);
    }
    let local = _mm512_mask_blend_epi32(ok, _mm512_set1_epi32(NOT_A_KEY), local);
    // A key once: the lanes with no equal valid lane before them (the
    // two rows of a failing tile hold two or three voxels' keys).
    let first = _mm512_cmpeq_epi32_mask(_mm512_conflict_epi32(local), _mm512_setzero_si512());
    Some((local, ok & first))
}

/// The local keys of [`pixel_locals`]'s samples, exactly, for the rare
/// vector with a sample too near an integer for the float path: the
/// fixed-point definition, `(raw * ray + t) >> 40` an axis. Lanes not in
/// `ok` are left zero.
#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx512bw,avx512cd,popcnt,bmi1")]
#[inline(never)]
fn exact_locals(
    frame: &Frame,
    rays: &[ChunkRays; ROWS],
    raws: [&[u16; STEP]; ROWS],
    first: usize,
    t: usize,
    pair: usize,
    ok: u16,
) -> __m512i {
    let mut locals = [0i32; LANES];
    for (j, local) in locals.iter_mut().enumerate() {
        if ok >> j & 1 == 0 {
            continue;
        }
        let (r, sample) = (2 * pair + j / WIDTH, WIDTH * t + j % WIDTH);
        let raw = i64::from(raws[r][sample]);
        let i = (first + sample) as i64;
        let floor = |a: usize| {
            let ray = rays[r].ray[a].wrapping_add(i.wrapping_mul(rays[r].step[a]));
            let p = raw.wrapping_mul(ray).wrapping_add(rays[r].t[a]);
            ((p >> 40) - frame.t_int[a]) as i32
        };
        *local = (floor(0) << 20) + (floor(1) << 10) + floor(2);
    }
    // SAFETY: reads the 64 bytes of `locals`, sixteen i32.
    unsafe { _mm512_loadu_si512(locals.as_ptr().cast()) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use crate::vector_unit::VectorUnit;
    use placedb::{DepthRange, FrameProjector, Intrinsics, Pose, VoxelGrid};

    /// A 640x480 frame of a tilted plane seen from a random pose, raws in
    /// millimetres with a little noise and a few holes: what tiles are for.
    fn smooth_frame(rng: &mut SplitMix64) -> (FrameProjector, Vec<u16>) {
        let k = Intrinsics {
            width: 640,
            height: 480,
            fx: 585.0,
            fy: 585.0,
            cx: 320.0,
            cy: 240.0,
        };
        let grid = VoxelGrid::new([0.1, 0.3][rng.below(2) as usize], [0.0; 3]).unwrap();
        let q = [0.0; 4].map(|_: f32| rng.range(-1.0, 1.0) as f32);
        let n = q.iter().map(|c| c * c).sum::<f32>().sqrt().max(1e-3);
        let t = [0.0; 3].map(|_: f32| rng.range(-5.0, 5.0) as f32);
        let pose = Pose::from_quaternion(t, q.map(|c| c / n)).unwrap();
        let proj = FrameProjector::new(&k, 1000.0, DepthRange::default(), 1, &grid, &pose).unwrap();
        let (base, du, dv) = (
            rng.range(500.0, 4000.0),
            rng.range(-2.0, 2.0),
            rng.range(-2.0, 2.0),
        );
        let data = (0..640 * 480)
            .map(|i| match rng.below(50) {
                0 => 0,
                _ => {
                    let (u, v) = ((i % 640) as f64, (i / 640) as f64);
                    let z = base + du * (u - 320.0) + dv * (v - 240.0) + rng.range(-1.0, 1.0);
                    z.clamp(0.0, 65535.0) as u16
                }
            })
            .collect();
        (proj, data)
    }

    #[test]
    fn most_tiles_of_a_smooth_frame_pass_with_the_keys_of_the_per_pixel_loop() {
        if !VectorUnit::Avx512.runs_here() {
            return;
        }
        let mut rng = SplitMix64::new(7);
        let (mut tiles, mut passed, mut frames_in_bands) = (0u32, 0u32, 0u32);
        for _ in 0..40 {
            let (proj, data) = smooth_frame(&mut rng);
            let mut bands = Bands::default();
            let (mut got, mut want, mut valid) = (Vec::new(), Vec::new(), 0u32);
            let mut all_bands = true;
            for v in (0..480u16).step_by(ROWS) {
                let row = |r: u16| &data[usize::from(v + r) * 640..][..640];
                let rays = [0, 1, 2, 3].map(|r| proj.row_chunk_rays(v + r).unwrap());
                let rows = [row(0), row(1), row(2), row(3)];
                // SAFETY (both calls): the CPU has AVX-512 (checked above).
                let Some(band_valid) = (unsafe { bands.band(&rays, rows, &[], &mut got) }) else {
                    all_bands = false;
                    continue;
                };
                valid += band_valid;
                let frame = Frame::new(&rays[0]);
                let band =
                    unsafe { Band::new(&frame, &rays, 640usize.div_ceil(STEP) * STEP) }.unwrap();
                for first in (0..640).step_by(STEP) {
                    let raws = rows.map(|r| {
                        let mut raws = [0u16; STEP];
                        let part = &r[first..r.len().min(first + STEP)];
                        raws[..part.len()].copy_from_slice(part);
                        raws
                    });
                    let raws = [&raws[0], &raws[1], &raws[2], &raws[3]];
                    // SAFETY: as above.
                    let step = unsafe {
                        step_tiles(&band, raws, first, rays[0].lo as u16, rays[0].span as u16)
                    };
                    tiles += (step.pass | step.fail).count_ones();
                    passed += step.pass.count_ones();
                }
                let mut out_of_range = 0;
                for r in 0..4 {
                    let counted = proj.project_row(v + r, row(r), &mut out_of_range, |key| {
                        want.push(key.to_bits())
                    });
                    valid -= counted;
                }
                assert_eq!((valid, out_of_range), (0, 0));
            }
            frames_in_bands += u32::from(all_bands);
            if !all_bands {
                continue;
            }
            got.sort_unstable();
            got.dedup();
            want.sort_unstable();
            want.dedup();
            assert!(got == want);
        }
        assert!(
            frames_in_bands > 30 && passed > tiles / 2,
            "{frames_in_bands} {passed} {tiles}"
        );
    }

    /// Rows whose fixed-point sums land exactly on voxel edges, and one
    /// raw unit either side, where single precision alone would floor some
    /// of them wrong: the error bounds must send those samples to the exact
    /// arithmetic. The same ray in every sample and row and one raw a tile,
    /// so a tile has no spread at all and only the margin keeps one on an
    /// edge from passing.
    #[test]
    fn samples_on_voxel_edges_get_the_exact_keys() {
        if !VectorUnit::Avx512.runs_here() {
            return;
        }
        let mut rng = SplitMix64::new(11);
        let (mut on_edges, mut keys_seen) = (0usize, 0usize);
        for _ in 0..300 {
            // Up to 2^-8 voxel a raw unit: floors within the digits.
            let ray = [0; 3].map(|_: i64| rng.below(1 << 32) as i64 - (1 << 31));
            let edge_raw = 1 + rng.below(60_000) as i64;
            // t puts `edge_raw * ray + t` on a multiple of 2^40 (a voxel
            // edge), near the middle of the key range.
            let t = ray.map(|r| {
                let to_edge = (-(edge_raw * r)).rem_euclid(1 << 40);
                ((1i64 << 20) + rng.below(1000) as i64 - 500) * (1 << 40) + to_edge
            });
            let rays = ChunkRays {
                ray,
                step: [0; 3],
                t,
                lo: 1,
                span: 65_534,
            };
            // A raw per tile (a tile's rows are alike), so tiles have no
            // spread: centres on the edge, and in half the rows also a raw
            // unit off it (whose keys are the two a wrong floor on the edge
            // would give, so the other half must do without them).
            let off_edge = rng.chance(0.5);
            let row: Vec<u16> = (0..200usize.div_ceil(WIDTH))
                .flat_map(|_| {
                    let raw = match rng.below(4) {
                        0 if off_edge => edge_raw - 1,
                        1 if off_edge => edge_raw + 1,
                        _ => edge_raw,
                    };
                    [raw as u16; WIDTH]
                })
                .take(200)
                .collect();
            let rows = [&row[..], &row[..], &row[..], &row[..]];
            let mut got = Vec::new();
            // SAFETY: the CPU has AVX-512 (checked above).
            let valid = unsafe { Bands::default().band(&[rays; ROWS], rows, &[], &mut got) };
            assert_eq!(valid, Some(4 * 200));
            let mut want: Vec<u64> = row
                .iter()
                .map(|&raw| {
                    let axis = |a: usize| ((i64::from(raw) * ray[a] + t[a]) >> 40) as u64;
                    axis(0) << 42 | axis(1) << 21 | axis(2)
                })
                .collect();
            for keys in [&mut got, &mut want] {
                keys.sort_unstable();
                keys.dedup();
            }
            assert_eq!(got, want, "ray {ray:?} edge raw {edge_raw}");
            on_edges += row.iter().filter(|&&r| i64::from(r) == edge_raw).count();
            keys_seen += want.len();
        }
        assert!(
            on_edges > 30_000 && keys_seen > 450,
            "{on_edges} {keys_seen}"
        );
    }
}
