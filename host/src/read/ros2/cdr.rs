//! CDR, the ROS 2 message encoding (OMG XCDR version 1, "plain CDR", what
//! rmw implementations write and rosbag2 stores): a 4-byte encapsulation
//! header (`00 01` little-endian, `00 00` big-endian, then 2 option bytes),
//! then the fields in order, each primitive aligned to its own size (8 at
//! most) counted from the end of the header; a string is a `u32` length
//! including its NUL, the bytes and the NUL; a sequence a `u32` count and
//! its elements; a fixed array just its elements.
//!
//! [`Reader`] decodes, refusing (never panicking on) truncated or
//! inconsistent input; [`Writer`] encodes the same way, for tests and tools
//! that write bags.

use std::fmt;

/// Why a message does not decode.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CdrError(pub String);

impl fmt::Display for CdrError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

/// A cursor over one CDR-encoded message, or over its first bytes.
pub struct Reader<'a> {
    body: &'a [u8],
    /// The whole body's length: more than `body`'s when only a head is at
    /// hand ([`Reader::head`]).
    whole: usize,
    pos: usize,
    little: bool,
}

impl<'a> Reader<'a> {
    /// Reads the encapsulation header: plain CDR, either byte order.
    pub fn new(bytes: &'a [u8]) -> Result<Self, CdrError> {
        Self::head(bytes, bytes.len())
    }

    /// [`Reader::new`] over the first bytes of a message of `len` bytes:
    /// every field must lie in them but a trailing `uint8[]`
    /// ([`Reader::bytes`]), which is checked against the whole message and
    /// handed over as far as it is at hand.
    pub fn head(bytes: &'a [u8], len: usize) -> Result<Self, CdrError> {
        let Some((head, body)) = bytes.split_first_chunk::<4>() else {
            return Err(CdrError(format!(
                "{} bytes: too short for the 4-byte CDR encapsulation header",
                bytes.len()
            )));
        };
        let little = match (head[0], head[1]) {
            (0, 0) => false,
            (0, 1) => true,
            (a, b) => {
                return Err(CdrError(format!(
                    "encapsulation {a:02x}{b:02x} is not plain CDR (0000 big-endian, 0001 \
                     little-endian): XCDR2 and parameter lists are not supported"
                )))
            }
        };
        Ok(Reader {
            body,
            whole: len.saturating_sub(4).max(body.len()),
            pos: 0,
            little,
        })
    }

    /// Whether the message is little-endian.
    pub fn little_endian(&self) -> bool {
        self.little
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], CdrError> {
        match self.body.get(self.pos..self.pos.saturating_add(n)) {
            Some(s) => {
                self.pos += n;
                Ok(s)
            }
            None => Err(CdrError(format!(
                "truncated: {what} needs {n} bytes at offset {}, the message has {}",
                self.pos,
                self.body.len()
            ))),
        }
    }

    fn aligned<const N: usize>(&mut self, what: &str) -> Result<[u8; N], CdrError> {
        self.pos = self.pos.next_multiple_of(N);
        let s = self.take(N, what)?;
        let mut b = [0u8; N];
        b.copy_from_slice(s);
        if self.little != cfg!(target_endian = "little") {
            b.reverse();
        }
        Ok(b)
    }

    /// A `uint8` (or `bool`, `char`).
    pub fn u8(&mut self) -> Result<u8, CdrError> {
        Ok(self.take(1, "uint8")?[0])
    }

    /// A `uint32`.
    pub fn u32(&mut self) -> Result<u32, CdrError> {
        self.aligned::<4>("uint32").map(u32::from_ne_bytes)
    }

    /// An `int32`.
    pub fn i32(&mut self) -> Result<i32, CdrError> {
        self.aligned::<4>("int32").map(i32::from_ne_bytes)
    }

    /// A `float64`.
    pub fn f64(&mut self) -> Result<f64, CdrError> {
        self.aligned::<8>("float64").map(f64::from_ne_bytes)
    }

    /// `N` `float64`s (a fixed array).
    pub fn f64s<const N: usize>(&mut self) -> Result<[f64; N], CdrError> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.f64()?;
        }
        Ok(out)
    }

    /// A sequence count, checked against the bytes left (each element at
    /// least `min_size` bytes), so a corrupt count cannot ask for gigabytes.
    pub fn count(&mut self, min_size: usize) -> Result<usize, CdrError> {
        let n = self.u32()? as usize;
        let left = self.whole.saturating_sub(self.pos);
        if n.saturating_mul(min_size.max(1)) > left {
            return Err(CdrError(format!(
                "sequence of {n} elements, only {left} bytes left"
            )));
        }
        Ok(n)
    }

    /// A `string`.
    pub fn string(&mut self) -> Result<String, CdrError> {
        let n = self.count(1)?;
        if n == 0 {
            return Ok(String::new());
        }
        let s = self.take(n, "string")?;
        let (text, nul) = s.split_at(n - 1);
        if nul != [0] {
            return Err(CdrError("string is not NUL-terminated".into()));
        }
        String::from_utf8(text.to_vec()).map_err(|_| CdrError("string is not UTF-8".into()))
    }

    /// A `sequence<uint8>`, borrowed: whole, or as much of it as a head
    /// holds.
    pub fn bytes(&mut self) -> Result<&'a [u8], CdrError> {
        let n = self.count(1)?;
        let at_hand = self.body.get(self.pos..).unwrap_or_default();
        self.pos += n;
        Ok(&at_hand[..n.min(at_hand.len())])
    }

    /// A `sequence<float64>`.
    pub fn f64_seq(&mut self) -> Result<Vec<f64>, CdrError> {
        let n = self.count(8)?;
        (0..n).map(|_| self.f64()).collect()
    }
}

/// Encodes one message as plain CDR (the mirror of [`Reader`]).
pub struct Writer {
    out: Vec<u8>,
    little: bool,
}

impl Writer {
    /// Starts a message: the encapsulation header of the byte order.
    pub fn new(little: bool) -> Self {
        Writer {
            out: vec![0, u8::from(little), 0, 0],
            little,
        }
    }

    fn put<const N: usize>(&mut self, le: [u8; N]) {
        while !(self.out.len() - 4).is_multiple_of(N) {
            self.out.push(0);
        }
        let mut b = le;
        if !self.little {
            b.reverse();
        }
        self.out.extend_from_slice(&b);
    }

    /// A `uint8`.
    pub fn u8(&mut self, v: u8) -> &mut Self {
        self.out.push(v);
        self
    }

    /// A `uint32`.
    pub fn u32(&mut self, v: u32) -> &mut Self {
        self.put(v.to_le_bytes());
        self
    }

    /// An `int32`.
    pub fn i32(&mut self, v: i32) -> &mut Self {
        self.put(v.to_le_bytes());
        self
    }

    /// A `float64`.
    pub fn f64(&mut self, v: f64) -> &mut Self {
        self.put(v.to_le_bytes());
        self
    }

    /// `float64`s without a count (a fixed array).
    pub fn f64s(&mut self, v: &[f64]) -> &mut Self {
        for &x in v {
            self.f64(x);
        }
        self
    }

    /// A `string`.
    pub fn string(&mut self, s: &str) -> &mut Self {
        self.u32(s.len() as u32 + 1);
        self.out.extend_from_slice(s.as_bytes());
        self.out.push(0);
        self
    }

    /// A `sequence<uint8>`.
    pub fn bytes(&mut self, b: &[u8]) -> &mut Self {
        self.u32(b.len() as u32);
        self.out.extend_from_slice(b);
        self
    }

    /// A `sequence<float64>`.
    pub fn f64_seq(&mut self, v: &[f64]) -> &mut Self {
        self.u32(v.len() as u32);
        self.f64s(v)
    }

    /// The encoded message.
    pub fn finish(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_both_byte_orders_with_alignment() {
        for little in [true, false] {
            let bytes = Writer::new(little)
                .u8(7)
                .f64(1.5)
                .string("abc")
                .u32(9)
                .bytes(&[1, 2, 3])
                .f64_seq(&[2.0, -3.0])
                .i32(-4)
                .finish();
            // Body offsets: u8 0, f64 8 (padded), string 16..24, u32 24,
            // bytes 28..35, count 36 (padded), f64s 40..56, i32 56..60.
            assert_eq!(bytes.len(), 4 + 60);
            let mut r = Reader::new(&bytes).unwrap();
            assert_eq!(r.little_endian(), little);
            assert_eq!(r.u8().unwrap(), 7);
            assert_eq!(r.f64().unwrap(), 1.5);
            assert_eq!(r.string().unwrap(), "abc");
            assert_eq!(r.u32().unwrap(), 9);
            assert_eq!(r.bytes().unwrap(), [1, 2, 3]);
            assert_eq!(r.f64_seq().unwrap(), [2.0, -3.0]);
            assert_eq!(r.i32().unwrap(), -4);
            assert!(r.u8().is_err());
        }
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        assert!(Reader::new(&[0, 1]).is_err());
        let e = Reader::new(&[0, 7, 0, 0]).err().unwrap();
        assert!(e.0.contains("XCDR2"), "{e}");
        // A huge sequence count.
        let mut r = Reader::new(&[0, 1, 0, 0, 0xff, 0xff, 0xff, 0x7f, 1]).unwrap();
        assert!(r.bytes().unwrap_err().0.contains("sequence"));
        // A string without its NUL.
        let mut r = Reader::new(&[0, 1, 0, 0, 2, 0, 0, 0, b'a', b'b']).unwrap();
        assert!(r.string().is_err());
        let mut r = Reader::new(&[0, 1, 0, 0, 1, 0]).unwrap();
        assert!(r.u32().is_err());
    }
}
