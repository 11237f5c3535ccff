//! RVL, the depth coding of `compressed_depth_image_transport`'s `rvl`
//! codec (Wilson, "Fast lossless depth image compression", 2017): the
//! image's columns and rows as two little-endian `uint32`, then runs of
//! zeros and of non-zero values, each non-zero value a zigzag delta from
//! the previous one; every count and delta is a variable-length value of
//! 3 bits a nibble, lowest first, the 4th bit set while more follow;
//! nibbles fill 32-bit little-endian words from the top down
//! (`codec.cpp`'s `CompressRVL`/`DecompressRVL`).
//!
//! Depth is smooth, so nearly every delta is one or two nibbles (in
//! 7-Scenes frames about 80 % one, 19 % two): the decoder looks the next
//! three nibbles up in a table of the one or two values they begin with
//! ([`PAIRS`]), one lookup a step where a nibble at a time was a branch
//! and a shift a nibble, about a third of the time (docs/PERFORMANCE.md);
//! other values (counts, longer deltas, the stream's end) it reads with
//! [`Nibbles::value`].

/// Most pixels an RVL image may claim: four times a 4K frame. RVL codes a
/// run of zeros in a few bytes, so without a bound a damaged count could
/// ask for gigabytes.
pub const MOST_PIXELS: usize = 1 << 25;

/// An RVL payload's columns and rows, and the stream after them.
pub fn size(payload: &[u8]) -> Result<(u16, u16, &[u8]), String> {
    let word = |i: usize| {
        payload
            .get(i..i + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .ok_or_else(|| {
                format!(
                    "RVL payload of {} bytes ends inside its size",
                    payload.len()
                )
            })
    };
    let (cols, rows) = (word(0)?, word(4)?);
    let side = |v: u32| u16::try_from(v).ok().filter(|&s| s > 0);
    match (side(cols), side(rows)) {
        (Some(w), Some(h)) if usize::from(w) * usize::from(h) <= MOST_PIXELS => {
            Ok((w, h, &payload[8..]))
        }
        _ => Err(format!(
            "RVL image claims {cols}x{rows} pixels (sides 1..=65535, at most {MOST_PIXELS} pixels)"
        )),
    }
}

/// Decodes `pixels` values of an RVL `stream` (after its size) into `out`,
/// which is resized to `pixels` (its room reused as it is: every value is
/// written, zero runs too).
pub fn decode_into(stream: &[u8], pixels: usize, out: &mut Vec<u16>) -> Result<(), String> {
    out.truncate(pixels);
    out.resize(pixels, 0);
    let mut nibbles = Nibbles {
        // Whole words only: bytes after the last are not read.
        words: &stream[..stream.len() / 4 * 4],
        bits: 0,
        held: 0,
    };
    let short = |done: usize| format!("RVL stream ends after {done} of {pixels} pixels");
    let (mut at, mut previous) = (0usize, 0u16);
    while at < pixels {
        let zeros = nibbles.value().ok_or_else(|| short(at))? as usize;
        if zeros > pixels - at {
            return Err(format!(
                "RVL run of {zeros} zeros after {at} pixels overflows the {pixels}-pixel image"
            ));
        }
        out[at..at + zeros].fill(0);
        at += zeros;
        if at == pixels {
            break;
        }
        let run = nibbles.value().ok_or_else(|| short(at))? as usize;
        if run > pixels - at {
            return Err(format!(
                "RVL run of {run} values after {at} pixels overflows the {pixels}-pixel image"
            ));
        }
        previous = nibbles
            .deltas(previous, &mut out[at..at + run])
            .ok_or_else(|| short(at))?;
        at += run;
    }
    Ok(())
}

/// `previous` plus the zigzag-coded delta, with the codec's arithmetic (an
/// `int` stored as `unsigned short`).
#[inline(always)]
fn add_delta(previous: u16, zigzag: u32) -> u16 {
    let delta = (zigzag >> 1) as i32 ^ -((zigzag & 1) as i32);
    i32::from(previous).wrapping_add(delta) as u16
}

/// The nibbles of an RVL stream, read ahead into a 64-bit buffer with the
/// next nibble in the lowest bits (the stream's words hold theirs from
/// the top down: each word is reversed nibble by nibble as it comes in),
/// so a value's end is the lowest clear stop bit.
#[derive(Clone, Copy)]
struct Nibbles<'a> {
    /// The words not yet taken.
    words: &'a [u8],
    /// Held nibbles, next lowest; zero above them.
    bits: u64,
    /// Bits held (4 a nibble).
    held: u32,
}

/// The stop bits of the buffer's nibbles: clear on a value's last nibble.
const MORE: u64 = 0x8888_8888_8888_8888;

/// Bits of the longest value the fast path takes: four nibbles, 12 bits
/// of value (a delta of up to 2,047 depth units).
const FAST_BITS: u32 = 16;

/// Bits [`Pair::of`] looks at: three nibbles.
const PAIR_BITS: u32 = 12;

/// The values at the start of three nibbles, as [`PAIRS`] holds them: one
/// or two deltas of at most two nibbles each, whole within the three.
#[derive(Clone, Copy)]
struct Pair {
    /// Bits the values take; 0 when the first is longer than two nibbles
    /// or does not end within the three.
    bits: u32,
    /// How many values: 1 or 2.
    values: usize,
    /// The deltas as wrapping `u16` (`second` 0 for one value).
    first: u16,
    second: u16,
}

impl Pair {
    /// The pair at the start of `bits` (next nibble lowest).
    #[inline(always)]
    fn of(bits: u64) -> Pair {
        let [bits, values, first, second] = PAIRS[(bits & ((1 << PAIR_BITS) - 1)) as usize];
        Pair {
            bits: u32::from(bits),
            values: usize::from(values),
            first: i16::from(first as i8) as u16,
            second: i16::from(second as i8) as u16,
        }
    }
}

/// [`Pair`]s of every 12 bits: bits taken, values, and the two deltas as
/// `i8`. One lookup finds a pair of values where computing them costs
/// dozens of instructions in a chain, and a depth image has a value a
/// pixel.
static PAIRS: [[u8; 4]; 1 << PAIR_BITS] = pairs();

const fn pairs() -> [[u8; 4]; 1 << PAIR_BITS] {
    let mut table = [[0u8; 4]; 1 << PAIR_BITS];
    let mut i = 0;
    while i < table.len() {
        // Up to two values of up to two nibbles, from the lowest nibble.
        let (mut at, mut n, mut entry) = (0u32, 0usize, [0u8; 4]);
        while n < 2 {
            let (mut value, mut k, mut ended) = (0u32, 0u32, false);
            while k < 2 && at + k < PAIR_BITS / 4 {
                let nibble = (i as u32 >> (4 * (at + k))) & 0xf;
                value |= (nibble & 7) << (3 * k);
                k += 1;
                if nibble & 8 == 0 {
                    ended = true;
                    break;
                }
            }
            if !ended {
                break;
            }
            let delta = (value >> 1) as i32 ^ -((value & 1) as i32);
            at += k;
            entry[0] = (4 * at) as u8;
            entry[2 + n] = delta as i8 as u8;
            n += 1;
            entry[1] = n as u8;
        }
        table[i] = entry;
        i += 1;
    }
    table
}

impl Nibbles<'_> {
    /// Takes whole words while one fits.
    #[inline(always)]
    fn refill(&mut self) {
        while self.held <= 32 && !self.words.is_empty() {
            self.take_word();
        }
    }

    /// The next value; `None` at the stream's end, or for one longer than
    /// 32 bits (damage; the caller says the stream ended too early).
    #[inline(always)]
    fn value(&mut self) -> Option<u32> {
        if self.held < FAST_BITS {
            self.refill();
        }
        // Bits up to and including the first value's last nibble (65 when
        // no nibble in the buffer stops).
        let end = (!self.bits & MORE).trailing_zeros() + 1;
        if end > FAST_BITS || end > self.held {
            return self.long_value();
        }
        let n = self.bits & ((1 << end) - 1);
        self.bits >>= end;
        self.held -= end;
        // The nibbles' low three bits, packed.
        Some((n & 0o7 | (n >> 1) & 0o70 | (n >> 2) & 0o700 | (n >> 3) & 0o7000) as u32)
    }

    /// Fills `slots` with the values of a run, each the one before plus
    /// its delta (`previous` before the first); returns the last, or
    /// `None` when the stream ends first.
    #[inline(always)]
    fn deltas(&mut self, mut previous: u16, slots: &mut [u16]) -> Option<u16> {
        // A copy the loop keeps in registers: `self` is in memory, and a
        // value stored and loaded back every pixel puts the store's
        // latency into the chain from one value to the next.
        let mut here = *self;
        let mut i = 0;
        while i < slots.len() {
            if here.held < PAIR_BITS {
                here.take_word();
            }
            // One or two short deltas held whole (nearly every delta of a
            // depth image): one lookup. Both slots are written; the next
            // step overwrites the second when the pair had one value.
            let pair = Pair::of(here.bits);
            if pair.bits != 0 && pair.bits <= here.held && i + 1 < slots.len() {
                let first = previous.wrapping_add(pair.first);
                previous = first.wrapping_add(pair.second);
                slots[i] = first;
                slots[i + 1] = previous;
                i += pair.values;
                here.bits >>= pair.bits;
                here.held -= pair.bits;
                continue;
            }
            let mut slow = here;
            let zigzag = slow.value();
            here = slow;
            previous = add_delta(previous, zigzag?);
            slots[i] = previous;
            i += 1;
        }
        *self = here;
        Some(previous)
    }

    /// Takes the next word, if any, above the held bits (at most 32).
    #[inline(always)]
    fn take_word(&mut self) {
        if let Some((b, rest)) = self.words.split_first_chunk::<4>() {
            self.words = rest;
            let word = u32::from_le_bytes(*b).swap_bytes();
            // The byte swap reversed the bytes; swapping each byte's two
            // nibbles completes the word's reversal, first nibble lowest.
            let word = ((word & 0x0f0f_0f0f) << 4) | ((word >> 4) & 0x0f0f_0f0f);
            self.bits |= u64::from(word) << self.held;
            self.held += 32;
        }
    }

    /// [`Self::value`] a nibble at a time: values of more than four
    /// nibbles, and the stream's last nibbles.
    #[cold]
    #[inline(never)]
    fn long_value(&mut self) -> Option<u32> {
        let (mut value, mut shift) = (0u32, 0u32);
        loop {
            if self.held == 0 {
                self.refill();
                if self.held == 0 {
                    return None;
                }
            }
            let nibble = (self.bits & 0xf) as u32;
            self.bits >>= 4;
            self.held -= 4;
            value |= (nibble & 7) << shift;
            if nibble & 8 == 0 {
                return Some(value);
            }
            shift += 3;
            if shift > 30 {
                return None;
            }
        }
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    /// RVL as the codec's `CompressRVL` writes it.
    pub fn encode(values: &[u16]) -> Vec<u8> {
        let mut nibbles: Vec<u32> = Vec::new();
        let vle = |mut v: u32, out: &mut Vec<u32>| loop {
            let nib = v & 7;
            v >>= 3;
            out.push(if v > 0 { nib | 8 } else { nib });
            if v == 0 {
                break;
            }
        };
        let (mut i, mut previous) = (0usize, 0i32);
        while i < values.len() {
            let zeros = values[i..].iter().take_while(|&&v| v == 0).count();
            vle(zeros as u32, &mut nibbles);
            i += zeros;
            let run = values[i..].iter().take_while(|&&v| v != 0).count();
            vle(run as u32, &mut nibbles);
            for &v in &values[i..i + run] {
                let delta = i32::from(v) - previous;
                vle(((delta << 1) ^ (delta >> 31)) as u32, &mut nibbles);
                previous = i32::from(v);
            }
            i += run;
        }
        let mut out = Vec::new();
        for chunk in nibbles.chunks(8) {
            let mut word = 0u32;
            for (k, n) in chunk.iter().enumerate() {
                word |= n << (4 * (7 - k));
            }
            out.extend_from_slice(&word.to_le_bytes());
        }
        out
    }

    /// The decoder a nibble at a time, as `DecompressRVL` reads: what the
    /// batched one must equal, on every stream, damaged ones included.
    fn decode_by_nibbles(stream: &[u8], pixels: usize) -> Result<Vec<u16>, String> {
        let mut words = stream.chunks_exact(4);
        let (mut word, mut left) = (0u32, 0u32);
        let mut value = || {
            let (mut value, mut shift) = (0u32, 0u32);
            loop {
                if left == 0 {
                    let b = words.next()?;
                    word = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
                    left = 8;
                }
                let nibble = word >> 28;
                word <<= 4;
                left -= 1;
                value |= (nibble & 7) << shift;
                if nibble & 8 == 0 {
                    return Some(value);
                }
                shift += 3;
                if shift > 30 {
                    return None;
                }
            }
        };
        let short = |done: usize| format!("RVL stream ends after {done} of {pixels} pixels");
        let mut out = vec![0u16; pixels];
        let (mut at, mut previous) = (0usize, 0u16);
        while at < pixels {
            let zeros = value().ok_or_else(|| short(at))? as usize;
            if zeros > pixels - at {
                return Err(format!(
                    "RVL run of {zeros} zeros after {at} pixels overflows the {pixels}-pixel image"
                ));
            }
            at += zeros;
            if at == pixels {
                break;
            }
            let run = value().ok_or_else(|| short(at))? as usize;
            if run > pixels - at {
                return Err(format!(
                    "RVL run of {run} values after {at} pixels overflows the {pixels}-pixel image"
                ));
            }
            for slot in &mut out[at..at + run] {
                previous = add_delta(previous, value().ok_or_else(|| short(at))?);
                *slot = previous;
            }
            at += run;
        }
        Ok(out)
    }

    fn decode(stream: &[u8], pixels: usize) -> Result<Vec<u16>, String> {
        // Room left from a larger image, none of it zero: reused, not cleared.
        let mut out = vec![7; pixels + 3];
        decode_into(stream, pixels, &mut out).map(|()| out)
    }

    #[test]
    fn reads_the_codecs_worked_example_and_round_trips() {
        // [0, 0, 5, 7, 0]: nibbles 2,2,A,1,4,1,0,0 in one word.
        assert_eq!(encode(&[0, 0, 5, 7, 0]), [0x00, 0x41, 0xa1, 0x22]);
        assert_eq!(
            decode(&[0x00, 0x41, 0xa1, 0x22], 5).unwrap(),
            [0, 0, 5, 7, 0]
        );
        let values: Vec<u16> = (0..3000u32)
            .map(|i| {
                if i % 7 < 2 {
                    0
                } else {
                    (i * 37 % 65535) as u16 + 1
                }
            })
            .chain([65535, 1, 65535, 0])
            .collect();
        assert_eq!(decode(&encode(&values), values.len()).unwrap(), values);
    }

    /// Depth-like rows: smooth runs (one-nibble deltas, batched), steps
    /// (longer deltas), holes (zero runs) in every mix and length.
    fn depth_like(rng: &mut SplitMix64) -> Vec<u16> {
        let n = rng.below(2000) as usize;
        let mut v = 1000u16;
        (0..n)
            .map(|_| match rng.below(100) {
                0..=7 => 0,
                8..=11 => {
                    v = 1 + rng.below(65535) as u16;
                    v
                }
                12..=19 => {
                    v = v.saturating_add(rng.below(40) as u16).max(1);
                    v
                }
                _ => {
                    v = (i32::from(v) + rng.below(7) as i32 - 3).clamp(1, 65535) as u16;
                    v
                }
            })
            .collect()
    }

    #[test]
    fn batches_equal_the_nibble_reader_on_whole_cut_and_damaged_streams() {
        let mut rng = SplitMix64::new(38);
        for case in 0..3000 {
            let values = depth_like(&mut rng);
            let mut stream = encode(&values);
            let pixels = match case % 4 {
                0 => values.len(),
                // More pixels than coded: the stream ends early.
                1 => values.len() + 1 + rng.below(9) as usize,
                _ => values.len(),
            };
            match case % 4 {
                2 if !stream.is_empty() => {
                    let cut = rng.below(stream.len() as u64) as usize;
                    stream.truncate(cut);
                }
                3 => {
                    for _ in 0..=rng.below(4) {
                        if let Some(b) = stream.get_mut(rng.below(1 + values.len() as u64) as usize)
                        {
                            *b ^= 1 << rng.below(8);
                        }
                    }
                }
                _ => {}
            }
            let want = decode_by_nibbles(&stream, pixels);
            assert_eq!(decode(&stream, pixels), want, "case {case}");
            if case % 4 == 0 {
                assert_eq!(want.as_deref(), Ok(&values[..]), "case {case}");
            }
        }
        // Random bytes: mostly damage, long values, the 32-bit limit.
        for case in 0..2000 {
            let stream: Vec<u8> = (0..rng.below(64)).map(|_| rng.below(256) as u8).collect();
            let pixels = 1 + rng.below(300) as usize;
            assert_eq!(
                decode(&stream, pixels),
                decode_by_nibbles(&stream, pixels),
                "random case {case}"
            );
        }
    }
}
