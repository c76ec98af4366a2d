//! Little-endian byte reading and writing with bounds checks (SPEC §1). A reader never panics
//! on short input and knows where it is in the file, so every error it reports has a place.

use crate::error::{DecodeError, Place};

/// A cursor over untrusted bytes; every read is bounds-checked and reports what was being read
/// and where (section and file offset).
#[derive(Debug, Clone)]
pub struct ByteReader<'a> {
    data: &'a [u8],
    pos: usize,
    at: Place,
}

impl<'a> ByteReader<'a> {
    /// A reader over bytes that start the file.
    pub fn new(data: &'a [u8]) -> Self {
        ByteReader { data, pos: 0, at: Place::default() }
    }

    /// A reader over bytes that lie at `at` in the file.
    pub(crate) fn at(data: &'a [u8], at: Place) -> Self {
        ByteReader { data, pos: 0, at }
    }

    /// Bytes read so far.
    pub fn position(&self) -> usize {
        self.pos
    }

    /// Bytes left.
    pub fn remaining(&self) -> usize {
        self.data.len() - self.pos
    }

    /// Where the next byte lies in the file.
    pub(crate) fn place(&self) -> Place {
        self.at.plus(self.pos)
    }

    /// A corrupt-data error at the current position.
    pub fn corrupt(&self, what: &'static str) -> DecodeError {
        self.place().corrupt(what)
    }

    /// The next `n` bytes.
    pub fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], DecodeError> {
        if n > self.remaining() {
            return Err(self.place().truncated(what));
        }
        let s = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    /// A `u8`.
    pub fn u8(&mut self, what: &'static str) -> Result<u8, DecodeError> {
        Ok(self.take(1, what)?[0])
    }

    /// A little-endian `u16`.
    pub fn u16(&mut self, what: &'static str) -> Result<u16, DecodeError> {
        let b = self.take(2, what)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }

    /// A little-endian `u32`.
    pub fn u32(&mut self, what: &'static str) -> Result<u32, DecodeError> {
        let b = self.take(4, what)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    /// A little-endian `f32` that must be finite.
    pub fn f32(&mut self, what: &'static str) -> Result<f32, DecodeError> {
        let at = self.place();
        let v = f32::from_bits(self.u32(what)?);
        if v.is_finite() {
            Ok(v)
        } else {
            Err(at.corrupt(what))
        }
    }

    /// Unsigned LEB128, at most 5 bytes, value must fit in u32.
    pub fn varint(&mut self, what: &'static str) -> Result<u32, DecodeError> {
        let at = self.place();
        let mut v: u64 = 0;
        for i in 0..5 {
            let b = self.u8(what)?;
            v |= u64::from(b & 0x7f) << (7 * i);
            if b & 0x80 == 0 {
                return u32::try_from(v).map_err(|_| at.corrupt(what));
            }
        }
        Err(at.corrupt(what))
    }

    /// Zigzag-mapped signed varint.
    pub fn svarint(&mut self, what: &'static str) -> Result<i32, DecodeError> {
        Ok(unzigzag(self.varint(what)?))
    }
}

/// Appends little-endian fields; the writer side of [`ByteReader`].
#[derive(Debug, Clone, Default)]
pub struct ByteWriter {
    /// The bytes written so far.
    pub buf: Vec<u8>,
}

impl ByteWriter {
    /// An empty writer.
    pub fn new() -> Self {
        Self::default()
    }
    /// A `u8`.
    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }
    /// A little-endian `u16`.
    pub fn u16(&mut self, v: u16) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// A little-endian `u32`.
    pub fn u32(&mut self, v: u32) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// A little-endian `f32`.
    pub fn f32(&mut self, v: f32) {
        self.u32(v.to_bits());
    }
    /// Raw bytes.
    pub fn bytes(&mut self, b: &[u8]) {
        self.buf.extend_from_slice(b);
    }
    /// Unsigned LEB128.
    pub fn varint(&mut self, mut v: u32) {
        loop {
            let b = (v & 0x7f) as u8;
            v >>= 7;
            if v == 0 {
                self.buf.push(b);
                return;
            }
            self.buf.push(b | 0x80);
        }
    }
    /// Zigzag-mapped signed varint.
    pub fn svarint(&mut self, v: i32) {
        self.varint(zigzag(v));
    }
}

/// Zigzag map: 0, −1, 1, −2, … → 0, 1, 2, 3, …
pub fn zigzag(v: i32) -> u32 {
    ((v << 1) ^ (v >> 31)) as u32
}

/// Inverse of [`zigzag`].
pub fn unzigzag(v: u32) -> i32 {
    ((v >> 1) as i32) ^ -((v & 1) as i32)
}
