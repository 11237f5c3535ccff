//! Framing: postcard + CRC-32 + COBS on the way out, a resynchronising
//! accumulator on the way in.
//!
//! Encoding uses postcard's `Cobs` over `Slice` flavours under a CRC of our
//! own ([`Framer`]: postcard's `CrcModifier`, the same bytes, but a slice's
//! digest taken in one call), so a frame is built in one pass straight into
//! the caller's buffer. Decoding does not use postcard's `CobsAccumulator`: it
//! cannot tell a bad CRC from bad COBS from a bad message, and after an
//! overflow it restarts in the middle of the oversized frame instead of at its
//! end. [`FrameDecoder`] keeps the COBS bytes of one frame, decodes them in
//! place when the delimiter arrives (computing the CRC in the same pass,
//! [`super::cobs`]), checks the CRC, then lets postcard deserialize straight
//! from its buffer, so borrowed payloads ([`super::DepthRows::data`]) point
//! into the decoder: no copy.

use super::messages::{DeviceMessage, ErrorKind, ExportRecord, HostFrame, ProtocolError};
use crc::{Crc, Digest, CRC_32_ISO_HDLC};
use postcard::ser_flavors::{Cobs, Flavor, Slice};
use serde::{Deserialize, Serialize};

/// Largest frame, trailing 0x00 included, that a receiver must accept: the
/// device's receive buffer ([`FrameDecoder<MAX_FRAME_LEN>`]). Holds one
/// [`super::HostMessage::DepthRows`] of up to [`super::MAX_ROW_VALUES`] (1007)
/// depth values, e.g. 8 or 12 strided rows of 80 values (640 px at stride 8).
pub const MAX_FRAME_LEN: usize = 2048;

/// The frame CRC: CRC-32/ISO-HDLC (zlib, Ethernet), appended little-endian.
pub static CRC: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);

/// Bytes of CRC after the postcard message.
const CRC_LEN: usize = 4;

/// Worst-case length of the frame (COBS overhead and delimiter included) of a
/// postcard message of `message_len` bytes.
pub const fn max_frame_len(message_len: usize) -> usize {
    let payload = message_len.saturating_add(CRC_LEN);
    // COBS adds one code byte per started run of 254 bytes (plus a final one when
    // the payload ends a full run); then the 0x00 delimiter.
    payload.saturating_add(payload / 254).saturating_add(2)
}

/// Longest postcard message whose worst-case frame fits `frame_len` bytes.
pub(crate) const fn max_message_len(frame_len: usize) -> usize {
    let mut len = frame_len;
    while len > 0 && max_frame_len(len) > frame_len {
        len -= 1;
    }
    if max_frame_len(len) > frame_len {
        0
    } else {
        len
    }
}

/// `ceil(len / stride)`: pixels per strided row or column (0 for stride 0).
pub const fn strided_len(len: u16, stride: u16) -> u16 {
    if stride == 0 {
        0
    } else {
        len.div_ceil(stride)
    }
}

/// Encodes `msg` as one complete frame (postcard, CRC-32, COBS, trailing 0x00)
/// into `buf` and returns the frame. `msg` is a [`HostFrame`] or a
/// [`DeviceMessage`]. A buffer too small gives [`ErrorKind::Oversized`];
/// [`max_frame_len`] of the postcard size is always enough.
pub fn encode<'b, T>(msg: &T, buf: &'b mut [u8]) -> Result<&'b [u8], ProtocolError>
where
    T: Serialize + ?Sized,
{
    let cobs = Cobs::try_new(Slice::new(buf)).map_err(ser_error)?;
    let flavor = Framer {
        crc: CRC.digest(),
        cobs,
    };
    let frame: &'b mut [u8] = postcard::serialize_with_flavor(msg, flavor).map_err(ser_error)?;
    Ok(frame)
}

/// postcard's CRC-over-COBS (`CrcModifier<Cobs<Slice>>`: the CRC-32 of the
/// message appended little-endian, all of it COBS-encoded), with two
/// differences that leave the bytes alone. A slice (a [`super::DepthRows`]'s
/// depth bytes) goes to the digest in one call: `CrcModifier` has
/// no `try_extend` and took every depth byte through a one-byte digest
/// update, the host's largest encoding cost. And the steps are out-of-line
/// calls: otherwise inlined into every field of every message, they
/// multiply the firmware's code size for no measurable speed gain.
struct Framer<'b> {
    crc: Digest<'static, u32>,
    cobs: Cobs<Slice<'b>>,
}

impl<'b> Flavor for Framer<'b> {
    type Output = &'b mut [u8];

    #[inline(never)]
    fn try_push(&mut self, data: u8) -> postcard::Result<()> {
        self.crc.update(&[data]);
        self.cobs.try_push(data)
    }

    #[inline(never)]
    fn try_extend(&mut self, data: &[u8]) -> postcard::Result<()> {
        self.crc.update(data);
        self.cobs.try_extend(data)
    }

    fn finalize(mut self) -> postcard::Result<Self::Output> {
        for byte in self.crc.finalize().to_le_bytes() {
            self.cobs.try_push(byte)?;
        }
        self.cobs.finalize()
    }
}

fn ser_error(e: postcard::Error) -> ProtocolError {
    match e {
        postcard::Error::SerializeBufferFull => ProtocolError::new(ErrorKind::Oversized),
        _ => ProtocolError::new(ErrorKind::Internal),
    }
}

/// What a [`FrameDecoder`] needs to know about the message type of a direction.
pub trait WireMessage {
    /// Whether the encoding starts with a `u32` sequence number (host frames),
    /// which the decoder reports with errors of damaged frames.
    const SEQ_PREFIX: bool;
    /// Number of variants of the message enum, to tell an unknown message from a
    /// malformed one.
    const VARIANTS: u32;
}

impl WireMessage for HostFrame<'_> {
    const SEQ_PREFIX: bool = true;
    const VARIANTS: u32 = 11;
}

impl WireMessage for DeviceMessage<'_> {
    const SEQ_PREFIX: bool = false;
    const VARIANTS: u32 = 9;
}

/// Result of [`FrameDecoder::push`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Push<'i> {
    /// Every input byte was consumed; no frame is complete yet.
    NeedMore,
    /// A frame is complete: call [`FrameDecoder::decode`] before pushing again.
    Ready {
        /// Input after the frame's delimiter, not consumed yet.
        remaining: &'i [u8],
    },
    /// A frame was lost (too long); the decoder resynchronises on the next 0x00.
    Error {
        /// What happened.
        error: ProtocolError,
        /// Input not consumed yet.
        remaining: &'i [u8],
    },
}

/// Result of [`FrameDecoder::push_held`]: [`Push`] for bytes received in
/// place, which the decoder holds (so there is no remaining input to give
/// back: what follows the frame stays held, [`FrameDecoder::holds_input`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Held {
    /// Every held byte was consumed; no frame is complete yet.
    NeedMore,
    /// A frame is complete: call [`FrameDecoder::decode`] before going on.
    Ready,
    /// A frame was lost (too long); the decoder resynchronises on the next 0x00.
    Error(ProtocolError),
}

/// Result of [`FrameDecoder::feed`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Feed<'i, M> {
    /// Every input byte was consumed; no frame is complete yet.
    NeedMore,
    /// A frame ended: its message or why it could not be read.
    Frame {
        /// The decoded message (borrowing the decoder) or the error.
        result: Result<M, ProtocolError>,
        /// Input after the frame, not consumed yet: feed it next.
        remaining: &'i [u8],
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Accumulating the COBS bytes of a frame.
    Collecting,
    /// A complete frame is in the buffer.
    Ready,
    /// Dropping the rest of an oversized frame until the next 0x00.
    Discarding,
}

/// Accumulates a byte stream into frames of at most `N` bytes (delimiter
/// included) and decodes them in place.
///
/// Feed it arbitrary chunks; each [`Feed::Frame`] is one frame's message or
/// error, and the chunk's unconsumed rest to feed next:
///
/// ```
/// use placedb::protocol::{encode, Feed, FrameDecoder, HostFrame, HostMessage, MAX_FRAME_LEN};
/// let mut tx = [0u8; 64];
/// let frame = encode(&HostFrame { seq: 7, msg: HostMessage::StatusRequest }, &mut tx).unwrap();
/// let mut decoder = FrameDecoder::<MAX_FRAME_LEN>::new();
/// let mut rest: &[u8] = frame;
/// while let Feed::Frame { result, remaining } = decoder.feed::<HostFrame>(rest) {
///     assert_eq!(result.unwrap().seq, 7);
///     rest = remaining;
/// }
/// ```
///
/// Errors: a frame longer than `N` gives [`ErrorKind::Oversized`] as soon as it
/// overflows, and the rest of it up to the next 0x00 is dropped silently; bad
/// COBS gives [`ErrorKind::BadFraming`], a frame shorter than its CRC
/// [`ErrorKind::Truncated`], a CRC mismatch [`ErrorKind::BadCrc`], a message
/// postcard cannot read [`ErrorKind::Decode`] or [`ErrorKind::UnknownMessage`].
/// After any error the next frame decodes normally. Empty frames are skipped.
///
/// Input can also be received in place, with no copy: [`Self::spare`] lends
/// the free room after the bytes held (a USB packet is read straight into
/// it), [`Self::commit`] says how many bytes came, and [`Self::push_held`]
/// consumes them as [`Self::push`] does its input; the bytes after a
/// frame's delimiter stay held for the next call.
#[derive(Debug, Clone)]
pub struct FrameDecoder<const N: usize> {
    buf: [u8; N],
    /// Where the frame starts in `buf` (0..=3 for pushed input): chosen at
    /// its first byte so that `buf[start..]` and the input are equally
    /// aligned to 4 bytes. The copies into `buf` are then word copies: on
    /// the Cortex-M0+ a `memcpy` between differently aligned buffers moves
    /// a byte at a time, and the receive path copies every byte of every
    /// frame.
    start: usize,
    len: usize,
    /// Bytes received in place and not consumed yet: `buf[held_at..][..held]`
    /// (right after the frame's bytes while collecting, after its
    /// delimiter once it is complete).
    held_at: usize,
    held: usize,
    state: State,
}

impl<const N: usize> Default for FrameDecoder<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> FrameDecoder<N> {
    /// COBS bytes a frame may have besides its delimiter.
    const CAPACITY: usize = N.saturating_sub(1);

    /// An empty decoder.
    pub const fn new() -> Self {
        FrameDecoder {
            buf: [0; N],
            start: 0,
            len: 0,
            held_at: 0,
            held: 0,
            state: State::Collecting,
        }
    }

    /// Forgets any partial frame and held input; the next byte starts a new
    /// frame.
    pub fn clear(&mut self) {
        self.start = 0;
        self.len = 0;
        self.held_at = 0;
        self.held = 0;
        self.state = State::Collecting;
    }

    /// After a complete frame (decoded or not): the next frame starts at the
    /// held bytes after it.
    fn settle(&mut self) {
        if self.state == State::Ready {
            self.state = State::Collecting;
            self.start = self.held_at;
            self.len = 0;
        }
    }

    /// Bytes of the frame being received, or of the complete frame awaiting
    /// [`Self::decode`] (COBS bytes, delimiter not counted).
    pub fn frame_len(&self) -> usize {
        self.len
    }

    /// Whether part of a frame has been received (and not completed), or
    /// input is held that [`Self::push_held`] has not consumed yet.
    pub fn is_mid_frame(&self) -> bool {
        self.held > 0
            || self.state == State::Discarding
            || (self.state == State::Collecting && self.len > 0)
    }

    /// Whether bytes received in place wait for [`Self::push_held`].
    pub fn holds_input(&self) -> bool {
        self.held > 0
    }

    /// The free room after the frame and the bytes held, to receive input
    /// into in place; say how much came with [`Self::commit`]. A frame left
    /// undecoded is dropped. The open frame (and what is held) moves to
    /// the buffer's start when that gives the room `want` bytes it lacks,
    /// or when it is shorter than `want` (a frame just begun: few bytes to
    /// move): it is placed so that the room starts word-aligned, for word
    /// copies into it (as [`Self::push`] aligns to its input). The room is
    /// shorter than `want` only when the frame so far leaves no more.
    pub fn spare(&mut self, want: usize) -> &mut [u8] {
        self.settle();
        // What must stay: the frame so far and the held bytes after it
        // (only the held bytes while discarding the rest of a frame).
        let (from, kept) = if self.state == State::Discarding {
            (self.held_at, self.held)
        } else {
            (self.start, self.len.saturating_add(self.held))
        };
        let end = from.saturating_add(kept);
        // Reading an address is safe; only its low bits are used.
        let base = self.buf.as_ptr() as usize;
        let to = 0usize.wrapping_sub(base.wrapping_add(kept)) & 3;
        let lacks_room = N.saturating_sub(end) < want && to < from;
        let short = kept < want && to != from;
        if (lacks_room || short) && to.saturating_add(kept) <= N {
            self.move_kept(from, to, kept);
        }
        let end = self.held_at.saturating_add(self.held);
        self.buf.get_mut(end..).unwrap_or_default()
    }

    /// Moves the `kept` bytes at `from` (frame and held bytes, contiguous)
    /// to `to`. A loop, not `copy_within`: no panicking path.
    fn move_kept(&mut self, from: usize, to: usize, kept: usize) {
        let byte = |buf: &[u8; N], i: usize| buf.get(i).copied().unwrap_or(0);
        if to < from {
            for i in 0..kept {
                let b = byte(&self.buf, from + i);
                if let Some(dest) = self.buf.get_mut(to + i) {
                    *dest = b;
                }
            }
        } else {
            for i in (0..kept).rev() {
                let b = byte(&self.buf, from + i);
                if let Some(dest) = self.buf.get_mut(to + i) {
                    *dest = b;
                }
            }
        }
        if self.state != State::Discarding {
            self.start = to;
        }
        self.held_at = to.saturating_add(kept - self.held.min(kept));
    }

    /// Holds the first `n` bytes of the room the last [`Self::spare`]
    /// lent (as many as fit) as received input, for [`Self::push_held`].
    pub fn commit(&mut self, n: usize) {
        let end = self.held_at.saturating_add(self.held);
        self.held = self.held.saturating_add(n.min(N.saturating_sub(end)));
    }

    /// [`Self::push`] for the input held ([`Self::commit`]): consumes it up
    /// to the end of the next complete frame; the bytes after the frame
    /// stay held. A frame left undecoded by the previous call is dropped.
    pub fn push_held(&mut self) -> Held {
        self.settle();
        loop {
            if self.held == 0 {
                return Held::NeedMore;
            }
            let from = self.held_at;
            let region = self
                .buf
                .get(from..from.saturating_add(self.held))
                .unwrap_or_default();
            let zero = region.iter().position(|&b| b == 0);
            let (body, ended) = match zero {
                Some(z) => (z, true),
                None => (region.len(), false),
            };
            let used = body.saturating_add(usize::from(ended));
            self.held = self.held.saturating_sub(used);
            self.held_at = from.saturating_add(used);
            if self.state == State::Discarding {
                if ended {
                    self.state = State::Collecting;
                    self.start = self.held_at;
                    self.len = 0;
                    continue;
                }
                return Held::NeedMore;
            }
            let len = self.len.saturating_add(body);
            if len > Self::CAPACITY {
                self.len = 0;
                if ended {
                    self.start = self.held_at;
                } else {
                    self.state = State::Discarding;
                }
                return Held::Error(ProtocolError::new(ErrorKind::Oversized));
            }
            self.len = len;
            if !ended {
                return Held::NeedMore;
            }
            if len == 0 {
                // Empty frame (a lone delimiter): resynchronisation, no message.
                self.start = self.held_at;
                continue;
            }
            self.state = State::Ready;
            return Held::Ready;
        }
    }

    /// Consumes input up to the end of the next complete frame. A frame left
    /// undecoded by the previous call is dropped. Input held
    /// ([`Self::commit`]) comes first: a frame that ends in it is
    /// returned with all of `input` remaining.
    pub fn push<'i>(&mut self, input: &'i [u8]) -> Push<'i> {
        match self.push_held() {
            Held::NeedMore => {}
            Held::Ready => return Push::Ready { remaining: input },
            Held::Error(error) => {
                return Push::Error {
                    error,
                    remaining: input,
                }
            }
        }
        let mut input = input;
        loop {
            if input.is_empty() {
                return Push::NeedMore;
            }
            let zero = input.iter().position(|&b| b == 0);
            let (body, rest, ended) = match zero {
                Some(z) => (
                    input.get(..z).unwrap_or_default(),
                    input.get(z + 1..).unwrap_or_default(),
                    true,
                ),
                None => (input, &[][..], false),
            };
            if self.state == State::Discarding {
                if ended {
                    self.clear();
                    input = rest;
                    continue;
                }
                return Push::NeedMore;
            }
            if self.len == 0 {
                // Reading an address is safe; only its low bits are used.
                let gap = (body.as_ptr() as usize).wrapping_sub(self.buf.as_ptr() as usize);
                self.start = gap & 3;
            }
            let end = self.len.saturating_add(body.len());
            if end > Self::CAPACITY {
                self.len = 0;
                self.start = 0;
                self.held_at = 0;
                self.state = if ended {
                    State::Collecting
                } else {
                    State::Discarding
                };
                return Push::Error {
                    error: ProtocolError::new(ErrorKind::Oversized),
                    remaining: rest,
                };
            }
            if self.start + end > Self::CAPACITY {
                // The aligned start leaves no room for a frame this long:
                // it moves to the buffer's start (once per such frame),
                // so the capacity is CAPACITY whatever the alignment.
                // (A loop, not `copy_within`: no panicking path, and rare.)
                for i in 0..self.len {
                    let byte = self.buf.get(self.start + i).copied().unwrap_or(0);
                    if let Some(to) = self.buf.get_mut(i) {
                        *to = byte;
                    }
                }
                self.start = 0;
            }
            let dest = match self.buf.get_mut(self.start + self.len..self.start + end) {
                Some(dest) => dest,
                None => {
                    self.len = 0;
                    self.start = 0;
                    self.held_at = 0;
                    self.state = State::Discarding;
                    return Push::Error {
                        error: ProtocolError::new(ErrorKind::Internal),
                        remaining: rest,
                    };
                }
            };
            dest.copy_from_slice(body);
            self.len = end;
            // Nothing is held: the room for input in place starts after
            // the frame (after its delimiter once it is complete).
            self.held_at = self.start + end + usize::from(ended);
            if !ended {
                return Push::NeedMore;
            }
            if self.len == 0 {
                // Empty frame (a lone delimiter): resynchronisation, no
                // message. Nothing is held and no frame is open: room for
                // input in place starts where the next frame will.
                self.held_at = self.start;
                input = rest;
                continue;
            }
            self.state = State::Ready;
            return Push::Ready { remaining: rest };
        }
    }

    /// Decodes the frame completed by the last [`Self::push`] or
    /// [`Self::push_held`]: COBS in place, CRC
    /// check, then postcard. The message may borrow the decoder's buffer. Without
    /// a complete frame, returns [`ErrorKind::Internal`].
    pub fn decode<'d, M>(&'d mut self) -> Result<M, ProtocolError>
    where
        M: Deserialize<'d> + WireMessage,
    {
        if self.state != State::Ready {
            return Err(ProtocolError::new(ErrorKind::Internal));
        }
        let (start, n) = (self.start, self.len);
        // The next frame starts at the bytes held after this one.
        self.settle();
        let body = self
            .buf
            .get_mut(start..start + n)
            .ok_or(ProtocolError::new(ErrorKind::Internal))?;
        let (decoded, crc) =
            super::cobs::decode_in_place(body).ok_or(ProtocolError::new(ErrorKind::BadFraming))?;
        let body: &'d [u8] = body;
        let payload = body
            .get(..decoded)
            .ok_or(ProtocolError::new(ErrorKind::Internal))?;
        decode_payload(payload, crc)
    }

    /// [`Self::push`] then, when a frame is complete, [`Self::decode`].
    pub fn feed<'d, 'i, M>(&'d mut self, input: &'i [u8]) -> Feed<'i, M>
    where
        M: Deserialize<'d> + WireMessage,
    {
        match self.push(input) {
            Push::NeedMore => Feed::NeedMore,
            Push::Error { error, remaining } => Feed::Frame {
                result: Err(error),
                remaining,
            },
            Push::Ready { remaining } => Feed::Frame {
                result: self.decode(),
                remaining,
            },
        }
    }
}

/// Checks the CRC of a decoded frame (`crc`: the CRC of the whole payload,
/// its CRC bytes included) and deserializes its message.
fn decode_payload<'d, M>(payload: &'d [u8], crc: u32) -> Result<M, ProtocolError>
where
    M: Deserialize<'d> + WireMessage,
{
    let split = payload
        .len()
        .checked_sub(CRC_LEN)
        .ok_or(ProtocolError::new(ErrorKind::Truncated))?;
    let (message, crc_bytes) = payload.split_at_checked(split).unwrap_or_default();
    let (seq, after_seq) = if M::SEQ_PREFIX {
        match postcard::take_from_bytes::<u32>(message) {
            Ok((seq, rest)) => (Some(seq), rest),
            Err(_) => (None, message),
        }
    } else {
        (None, message)
    };
    let error = |kind| ProtocolError { kind, seq };
    if crc_bytes.len() != CRC_LEN {
        return Err(error(ErrorKind::Internal));
    }
    if crc != super::cobs::CRC_RESIDUE {
        return Err(error(ErrorKind::BadCrc));
    }
    if M::SEQ_PREFIX && seq.is_none() {
        return Err(error(ErrorKind::Decode));
    }
    match postcard::take_from_bytes::<u32>(after_seq) {
        Ok((tag, _)) if tag >= M::VARIANTS => return Err(error(ErrorKind::UnknownMessage)),
        Ok(_) => {}
        Err(_) => return Err(error(ErrorKind::Decode)),
    }
    match postcard::take_from_bytes::<M>(message) {
        Ok((msg, [])) => Ok(msg),
        Ok(_) | Err(_) => Err(error(ErrorKind::Decode)),
    }
}

/// A postcard flavour that only feeds a CRC digest.
struct DigestFlavor<'a> {
    digest: &'a mut Digest<'static, u32>,
}

impl Flavor for DigestFlavor<'_> {
    type Output = ();

    fn try_extend(&mut self, data: &[u8]) -> postcard::Result<()> {
        self.digest.update(data);
        Ok(())
    }

    fn try_push(&mut self, data: u8) -> postcard::Result<()> {
        self.digest.update(&[data]);
        Ok(())
    }

    fn finalize(self) -> postcard::Result<()> {
        Ok(())
    }
}

/// Running checksum of an export: CRC-32/ISO-HDLC over the concatenated postcard
/// encodings of the [`ExportRecord`]s sent (the struct alone, without the
/// [`DeviceMessage`] tag, CRC or COBS), in order. Both sides compute it the
/// same way; [`DeviceMessage::ExportEnd::crc32`] carries the device's value.
#[derive(Clone)]
pub struct ExportCrc {
    digest: Digest<'static, u32>,
    count: u32,
}

impl core::fmt::Debug for ExportCrc {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ExportCrc")
            .field("count", &self.count)
            .finish_non_exhaustive()
    }
}

impl Default for ExportCrc {
    fn default() -> Self {
        Self::new()
    }
}

impl ExportCrc {
    /// A checksum over no records.
    pub fn new() -> Self {
        ExportCrc {
            digest: CRC.digest(),
            count: 0,
        }
    }

    /// Adds one record.
    pub fn add(&mut self, record: &ExportRecord) {
        let flavor = DigestFlavor {
            digest: &mut self.digest,
        };
        // Serializing a plain struct into a flavour that cannot fail cannot fail.
        let _ = postcard::serialize_with_flavor::<ExportRecord, _, ()>(record, flavor);
        self.count = self.count.wrapping_add(1);
    }

    /// Records added so far.
    pub fn count(&self) -> u32 {
        self.count
    }

    /// The checksum of the records added so far.
    pub fn value(&self) -> u32 {
        self.digest.clone().finalize()
    }
}

/// [`ExportCrc`] of a sequence of records.
pub fn export_crc<'r>(records: impl IntoIterator<Item = &'r ExportRecord>) -> u32 {
    let mut crc = ExportCrc::new();
    for record in records {
        crc.add(record);
    }
    crc.value()
}

/// Packs `row_count` strided rows, from strided row `first_row` on, of a
/// full-resolution row-major depth image `depth` (`width` columns) sampled at
/// `stride`, as the little-endian bytes of [`super::DepthRows::data`], into
/// `out`. Errors: [`ErrorKind::RowOutOfRange`] when a row is beyond the image,
/// [`ErrorKind::Oversized`] when `out` is too small, [`ErrorKind::BadConfig`]
/// for a zero width or stride.
pub fn pack_rows<'o>(
    depth: &[u16],
    width: u16,
    stride: u16,
    first_row: u16,
    row_count: u16,
    out: &'o mut [u8],
) -> Result<&'o [u8], ErrorKind> {
    if width == 0 || stride == 0 {
        return Err(ErrorKind::BadConfig);
    }
    let w = usize::from(width);
    let s = usize::from(stride);
    let mut written = 0usize;
    for r in 0..usize::from(row_count) {
        let start = (usize::from(first_row) + r)
            .checked_mul(s)
            .and_then(|v| v.checked_mul(w))
            .ok_or(ErrorKind::RowOutOfRange)?;
        let row = start
            .checked_add(w)
            .and_then(|end| depth.get(start..end))
            .ok_or(ErrorKind::RowOutOfRange)?;
        for &value in row.iter().step_by(s) {
            let dest = out
                .get_mut(written..written.saturating_add(2))
                .ok_or(ErrorKind::Oversized)?;
            dest.copy_from_slice(&value.to_le_bytes());
            written += 2;
        }
    }
    out.get(..written).ok_or(ErrorKind::Internal)
}
