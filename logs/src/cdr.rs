//! The two wire formats of ROS messages, read and written field by field.
//!
//! - **CDR** (ROS 2, OMG DDS XCDR1 "plain CDR"): a 4-byte encapsulation header (`00 01` =
//!   little endian, `00 00` = big endian, then two option bytes), then the fields in
//!   declaration order, each primitive aligned to its own size *relative to the byte after the
//!   header*. Strings are a `u32` length that counts a terminating NUL, the bytes, the NUL;
//!   sequences are a `u32` element count followed by the elements.
//! - **ROS 1**: little endian, no header, no alignment; strings carry no NUL; `std_msgs/Header`
//!   starts with a `u32 seq`; `time` is two `u32`s.
//!
//! Bounded allocation: a length or count is checked against the bytes that remain before
//! anything is allocated, so a corrupt `0xffffffff` costs an error, not 4 GiB.

use super::error::DecodeError;

type Result<T> = std::result::Result<T, DecodeError>;

/// The byte layout of one payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WireFormat {
    /// ROS 2 CDR with its encapsulation header (endianness read from the header).
    Cdr,
    /// ROS 1 serialization.
    Ros1,
}

/// Reads fields from one message payload.
#[derive(Debug, Clone)]
pub struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
    /// Where alignment is counted from (just after the CDR encapsulation header).
    origin: usize,
    big_endian: bool,
    /// ROS 1: no alignment, strings without NUL, Header with seq, time as two u32.
    ros1: bool,
}

macro_rules! read_primitive {
    ($name:ident, $t:ty) => {
        #[inline]
        pub fn $name(&mut self) -> Result<$t> {
            const N: usize = std::mem::size_of::<$t>();
            self.align(N)?;
            let bytes: [u8; N] = self.take_array(stringify!($t))?;
            Ok(if self.big_endian {
                <$t>::from_be_bytes(bytes)
            } else {
                <$t>::from_le_bytes(bytes)
            })
        }
    };
}

impl<'a> Reader<'a> {
    /// A reader over `payload` in the given wire format (CDR reads the encapsulation header).
    pub fn new(payload: &'a [u8], format: WireFormat) -> Result<Self> {
        match format {
            WireFormat::Cdr => Self::cdr(payload),
            WireFormat::Ros1 => Ok(Self::ros1(payload)),
        }
    }

    /// A CDR payload: checks the encapsulation header (plain CDR, either endianness).
    pub fn cdr(payload: &'a [u8]) -> Result<Self> {
        let Some(header) = payload.get(..4) else {
            return Err(DecodeError::Truncated {
                what: "CDR encapsulation header",
                at: 0,
                len: payload.len(),
            });
        };
        let big_endian = match (header[0], header[1]) {
            (0, 0) => true,
            (0, 1) => false,
            (a, b) => {
                return Err(DecodeError::Invalid(format!(
                    "CDR encapsulation {a:02x} {b:02x} is not plain CDR (00 00 or 00 01); \
                     parameter lists and XCDR2 are not supported"
                )));
            }
        };
        Ok(Reader {
            buf: payload,
            pos: 4,
            origin: 4,
            big_endian,
            ros1: false,
        })
    }

    /// A ROS 1 payload.
    pub fn ros1(payload: &'a [u8]) -> Self {
        Reader {
            buf: payload,
            pos: 0,
            origin: 0,
            big_endian: false,
            ros1: true,
        }
    }

    pub fn is_ros1(&self) -> bool {
        self.ros1
    }

    /// Bytes not read yet.
    pub fn remaining(&self) -> usize {
        self.buf.len() - self.pos
    }

    /// The current byte offset in the payload.
    pub fn position(&self) -> usize {
        self.pos
    }

    #[inline]
    fn align(&mut self, n: usize) -> Result<()> {
        if self.ros1 || n <= 1 {
            return Ok(());
        }
        let pad = (n - (self.pos - self.origin) % n) % n;
        if pad > self.remaining() {
            return Err(self.truncated("alignment padding"));
        }
        self.pos += pad;
        Ok(())
    }

    fn truncated(&self, what: &'static str) -> DecodeError {
        DecodeError::Truncated {
            what,
            at: self.pos,
            len: self.buf.len(),
        }
    }

    #[inline]
    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8]> {
        if n > self.remaining() {
            return Err(self.truncated(what));
        }
        let bytes = &self.buf[self.pos..self.pos + n];
        self.pos += n;
        Ok(bytes)
    }

    #[inline]
    fn take_array<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N]> {
        let bytes = self.take(N, what)?;
        let mut out = [0u8; N];
        out.copy_from_slice(bytes);
        Ok(out)
    }

    read_primitive!(u8, u8);
    read_primitive!(i8, i8);
    read_primitive!(u16, u16);
    read_primitive!(i16, i16);
    read_primitive!(u32, u32);
    read_primitive!(i32, i32);
    read_primitive!(u64, u64);
    read_primitive!(i64, i64);
    read_primitive!(f32, f32);
    read_primitive!(f64, f64);

    pub fn bool(&mut self) -> Result<bool> {
        Ok(self.u8()? != 0)
    }

    /// A sequence's element count, checked against the bytes left: every element takes at
    /// least `min_element_bytes`, so a count that cannot fit is an error before any
    /// allocation.
    pub fn sequence_len(&mut self, min_element_bytes: usize, what: &'static str) -> Result<usize> {
        let at = self.pos;
        let count = self.u32()?;
        let needed = u64::from(count).saturating_mul(min_element_bytes.max(1) as u64);
        if needed > self.remaining() as u64 {
            return Err(DecodeError::LengthTooLarge {
                what,
                count: u64::from(count),
                at,
                remaining: self.remaining(),
            });
        }
        Ok(count as usize)
    }

    /// A string: CDR counts (and requires) a terminating NUL, ROS 1 does not have one.
    pub fn string(&mut self) -> Result<String> {
        let at = self.pos;
        let len = self.u32()? as usize;
        if len > self.remaining() {
            return Err(DecodeError::LengthTooLarge {
                what: "string",
                count: len as u64,
                at,
                remaining: self.remaining(),
            });
        }
        let bytes = self.take(len, "string")?;
        let text = if self.ros1 || len == 0 {
            bytes
        } else {
            match bytes.split_last() {
                Some((0, text)) => text,
                _ => {
                    return Err(DecodeError::Invalid(format!(
                        "string at byte {at} does not end with NUL"
                    )));
                }
            }
        };
        String::from_utf8(text.to_vec())
            .map_err(|_| DecodeError::Invalid(format!("string at byte {at} is not UTF-8")))
    }

    /// A `uint8[]` / `char[]` field as bytes (one copy, no per-element work).
    pub fn byte_sequence(&mut self) -> Result<Vec<u8>> {
        let len = self.sequence_len(1, "byte sequence")?;
        Ok(self.take(len, "byte sequence")?.to_vec())
    }
}

/// Writes a little-endian CDR payload (what ROS 2 publishes on x86 and ARM).
#[derive(Debug, Clone)]
pub struct Writer {
    buf: Vec<u8>,
}

impl Default for Writer {
    fn default() -> Self {
        Self::new()
    }
}

macro_rules! write_primitive {
    ($name:ident, $t:ty) => {
        #[inline]
        pub fn $name(&mut self, v: $t) {
            self.align(std::mem::size_of::<$t>());
            self.buf.extend_from_slice(&v.to_le_bytes());
        }
    };
}

impl Writer {
    /// An empty payload: the encapsulation header `00 01 00 00` (CDR, little endian).
    pub fn new() -> Self {
        let mut buf = Vec::with_capacity(256);
        buf.extend_from_slice(&[0, 1, 0, 0]);
        Writer { buf }
    }

    fn align(&mut self, n: usize) {
        let pad = (n - (self.buf.len() - 4) % n) % n;
        self.buf.resize(self.buf.len() + pad, 0);
    }

    write_primitive!(u8, u8);
    write_primitive!(i8, i8);
    write_primitive!(u16, u16);
    write_primitive!(i16, i16);
    write_primitive!(u32, u32);
    write_primitive!(i32, i32);
    write_primitive!(u64, u64);
    write_primitive!(i64, i64);
    write_primitive!(f32, f32);
    write_primitive!(f64, f64);

    pub fn bool(&mut self, v: bool) {
        self.u8(u8::from(v));
    }

    /// A sequence's element count. Counts above `u32::MAX` cannot be written in CDR; callers
    /// hold in-memory messages, which never come near that.
    pub fn sequence_len(&mut self, len: usize) {
        self.u32(u32::try_from(len).unwrap_or(u32::MAX));
    }

    pub fn string(&mut self, s: &str) {
        self.sequence_len(s.len() + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }

    pub fn byte_sequence(&mut self, bytes: &[u8]) {
        self.sequence_len(bytes.len());
        self.buf.extend_from_slice(bytes);
    }

    /// The finished payload.
    pub fn finish(self) -> Vec<u8> {
        self.buf
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn alignment_counts_from_after_the_encapsulation_header() -> Result<()> {
        // u8 at 0, then f64 aligned to 8 relative to byte 4 of the payload.
        let mut w = Writer::new();
        w.u8(7);
        w.f64(1.5);
        let bytes = w.finish();
        assert_eq!(bytes.len(), 4 + 8 + 8);
        assert_eq!(&bytes[..4], &[0, 1, 0, 0]);
        let mut r = Reader::cdr(&bytes)?;
        assert_eq!(r.u8()?, 7);
        assert_eq!(r.f64()?, 1.5);
        assert_eq!(r.remaining(), 0);
        Ok(())
    }

    #[test]
    fn big_endian_payloads_are_read() -> Result<()> {
        let mut bytes = vec![0, 0, 0, 0];
        bytes.extend_from_slice(&5u32.to_be_bytes());
        bytes.extend_from_slice(b"abcd\0");
        bytes.extend_from_slice(&[0; 7]); // 9 bytes after the header: pad to 16
        bytes.extend_from_slice(&2.25f64.to_be_bytes());
        let mut r = Reader::cdr(&bytes)?;
        assert_eq!(r.string()?, "abcd");
        assert_eq!(r.f64()?, 2.25);
        Ok(())
    }

    #[test]
    fn huge_counts_fail_before_allocating() -> Result<()> {
        let mut w = Writer::new();
        w.u32(u32::MAX);
        let bytes = w.finish();
        let mut r = Reader::cdr(&bytes)?;
        assert!(matches!(
            r.sequence_len(8, "doubles"),
            Err(DecodeError::LengthTooLarge { .. })
        ));
        let mut r = Reader::cdr(&bytes)?;
        assert!(matches!(
            r.string(),
            Err(DecodeError::LengthTooLarge { .. })
        ));
        Ok(())
    }

    #[test]
    fn bad_headers_and_strings_are_errors() -> Result<()> {
        assert!(Reader::cdr(&[0, 1]).is_err());
        assert!(Reader::cdr(&[0, 3, 0, 0]).is_err());
        let mut bytes = vec![0, 1, 0, 0];
        bytes.extend_from_slice(&3u32.to_le_bytes());
        bytes.extend_from_slice(b"abc"); // no NUL
        assert!(Reader::cdr(&bytes)?.string().is_err());
        Ok(())
    }

    #[test]
    fn ros1_has_no_alignment_and_no_nul() -> Result<()> {
        let mut bytes = vec![9u8];
        bytes.extend_from_slice(&3u32.to_le_bytes());
        bytes.extend_from_slice(b"abc");
        bytes.extend_from_slice(&1.0f64.to_le_bytes());
        let mut r = Reader::ros1(&bytes);
        assert_eq!(r.u8()?, 9);
        assert_eq!(r.string()?, "abc");
        assert_eq!(r.f64()?, 1.0);
        Ok(())
    }
}
