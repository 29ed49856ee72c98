//! The wire formats of ROS messages, as far as the camera messages need them: ROS 2's CDR
//! (XCDR1, and XCDR2 for plain final types) and ROS 1's serialisation, read and (CDR) written.
//!
//! CDR: a 4-byte encapsulation header (`00 01 00 00` = little-endian XCDR1), then the fields, each
//! aligned to its size counted from the end of the header (8-byte values to 4 in XCDR2);
//! strings are a u32 length that includes the NUL, then the bytes and the NUL; sequences a u32
//! count then the elements. ROS 1: little-endian, no alignment, strings without a NUL.

use std::fmt;

/// How a message's bytes are laid out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wire {
    /// ROS 2: CDR with its encapsulation header (MCAP message encoding `cdr`).
    Cdr,
    /// ROS 1 (MCAP message encoding `ros1`).
    Ros1,
}

impl Wire {
    /// The wire of an MCAP channel's message encoding, `None` for one we do not read.
    pub fn from_message_encoding(encoding: &str) -> Option<Self> {
        match encoding {
            "cdr" => Some(Self::Cdr),
            "ros1" => Some(Self::Ros1),
            _ => None,
        }
    }
}

/// A message that ends early or holds a value that cannot be.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DecodeError {
    /// Byte of the message (from its first byte, header included) where decoding failed.
    pub offset: usize,
    /// What was expected there.
    pub msg: String,
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "byte {} of the message: {}", self.offset, self.msg)
    }
}

impl std::error::Error for DecodeError {}

/// Reads the fields of one serialised message in order.
pub struct MessageReader<'a> {
    data: &'a [u8],
    pos: usize,
    /// Where alignment is counted from: the end of CDR's encapsulation header.
    origin: usize,
    little: bool,
    /// Largest alignment: 8 in XCDR1, 4 in XCDR2, 1 (none) in ROS 1.
    max_align: usize,
    /// ROS 1 headers start with a sequence number; CDR strings count their NUL.
    wire: Wire,
}

impl<'a> MessageReader<'a> {
    /// A reader over `data` serialised as `wire`; for CDR the encapsulation header is checked.
    pub fn new(data: &'a [u8], wire: Wire) -> Result<Self, DecodeError> {
        match wire {
            Wire::Ros1 => Ok(Self {
                data,
                pos: 0,
                origin: 0,
                little: true,
                max_align: 1,
                wire,
            }),
            Wire::Cdr => {
                let Some(&[hi, lo, _, _]) = data.first_chunk::<4>() else {
                    return Err(DecodeError {
                        offset: 0,
                        msg: format!(
                            "{} bytes, shorter than CDR's 4-byte encapsulation header",
                            data.len()
                        ),
                    });
                };
                // Representation ids of the DDS-XTypes spec, table 60: 0/1 XCDR1 plain, 6/7
                // XCDR2 plain (odd = little-endian); the parameter-list forms are not for ROS
                // message types.
                let (little, max_align) = match (hi, lo) {
                    (0, 0) => (false, 8),
                    (0, 1) => (true, 8),
                    (0, 6) => (false, 4),
                    (0, 7) => (true, 4),
                    _ => {
                        return Err(DecodeError {
                            offset: 0,
                            msg: format!(
                                "CDR encapsulation {hi:02x} {lo:02x} is not plain CDR (00 00, 00 01, 00 06 or 00 07)"
                            ),
                        });
                    }
                };
                Ok(Self {
                    data,
                    pos: 4,
                    origin: 4,
                    little,
                    max_align,
                    wire,
                })
            }
        }
    }

    fn err(&self, msg: impl Into<String>) -> DecodeError {
        DecodeError {
            offset: self.pos,
            msg: msg.into(),
        }
    }

    fn align(&mut self, size: usize) {
        let a = size.min(self.max_align);
        if a > 1 {
            let rel = self.pos - self.origin;
            self.pos += (a - rel % a) % a;
        }
    }

    /// The next `n` bytes, unaligned.
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], DecodeError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.data.len());
        match end {
            Some(end) => {
                let s = &self.data[self.pos..end];
                self.pos = end;
                Ok(s)
            }
            None => Err(self.err(format!(
                "{what}: {n} bytes wanted, the message ends after {}",
                self.data.len().saturating_sub(self.pos)
            ))),
        }
    }

    fn fixed<const N: usize>(&mut self, what: &str) -> Result<[u8; N], DecodeError> {
        self.align(N);
        let b = self.take(N, what)?;
        let mut out = [0u8; N];
        out.copy_from_slice(b);
        if !self.little {
            out.reverse();
        }
        // Now little-endian whatever the message's order.
        Ok(out)
    }

    /// A `uint8` / `bool`.
    pub fn u8(&mut self, what: &str) -> Result<u8, DecodeError> {
        Ok(self.take(1, what)?[0])
    }

    /// A `uint32`.
    pub fn u32(&mut self, what: &str) -> Result<u32, DecodeError> {
        Ok(u32::from_le_bytes(self.fixed(what)?))
    }

    /// An `int32`.
    pub fn i32(&mut self, what: &str) -> Result<i32, DecodeError> {
        Ok(i32::from_le_bytes(self.fixed(what)?))
    }

    /// A `float32`.
    pub fn f32(&mut self, what: &str) -> Result<f32, DecodeError> {
        Ok(f32::from_le_bytes(self.fixed(what)?))
    }

    /// A `float64`.
    pub fn f64(&mut self, what: &str) -> Result<f64, DecodeError> {
        Ok(f64::from_le_bytes(self.fixed(what)?))
    }

    /// A sequence length, checked against what is left (each element at least `elem` bytes), so
    /// a corrupt length cannot ask for gigabytes.
    fn length(&mut self, elem: usize, what: &str) -> Result<usize, DecodeError> {
        let n = self.u32(what)? as usize;
        let left = self.data.len() - self.pos;
        if n.saturating_mul(elem) > left + elem {
            return Err(self.err(format!("{what}: length {n} but only {left} bytes are left")));
        }
        Ok(n)
    }

    /// A `string` (UTF-8; invalid bytes are replaced).
    pub fn string(&mut self, what: &str) -> Result<String, DecodeError> {
        let n = self.length(1, what)?;
        let bytes = self.take(n, what)?;
        // CDR counts the terminating NUL; ROS 1 has none.
        let bytes = match self.wire {
            Wire::Cdr => bytes.strip_suffix(&[0]).unwrap_or(bytes),
            Wire::Ros1 => bytes,
        };
        Ok(String::from_utf8_lossy(bytes).into_owned())
    }

    /// A `uint8[]`, borrowed.
    pub fn bytes(&mut self, what: &str) -> Result<&'a [u8], DecodeError> {
        let n = self.length(1, what)?;
        self.take(n, what)
    }

    /// A `float64[]`.
    pub fn f64_seq(&mut self, what: &str) -> Result<Vec<f64>, DecodeError> {
        let n = self.length(8, what)?;
        (0..n).map(|_| self.f64(what)).collect()
    }

    /// A `float64[N]`.
    pub fn f64_array<const N: usize>(&mut self, what: &str) -> Result<[f64; N], DecodeError> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.f64(what)?;
        }
        Ok(out)
    }

    /// A `std_msgs/Header`'s stamp (seconds) and frame id.
    pub fn header(&mut self) -> Result<(f64, String), DecodeError> {
        let stamp = self.stamp()?;
        let frame_id = self.string("header.frame_id")?;
        Ok((stamp, frame_id))
    }

    /// The stamp of a `std_msgs/Header`, in seconds (the frame id is left unread).
    pub fn stamp(&mut self) -> Result<f64, DecodeError> {
        let (sec, nanosec) = match self.wire {
            Wire::Cdr => (
                i64::from(self.i32("header.stamp.sec")?),
                self.u32("header.stamp.nanosec")?,
            ),
            Wire::Ros1 => {
                self.u32("header.seq")?;
                (
                    i64::from(self.u32("header.stamp.secs")?),
                    self.u32("header.stamp.nsecs")?,
                )
            }
        };
        if nanosec >= 1_000_000_000 {
            return Err(self.err(format!("header.stamp: {nanosec} nanoseconds")));
        }
        Ok(stamp_seconds(sec, nanosec))
    }
}

/// `sec.nanosec` as the f64 nearest to that decimal: the same f64 a TUM list holding the same
/// digits gives (summing `sec + nanosec * 1e-9` can be one ulp off it).
pub fn stamp_seconds(sec: i64, nanosec: u32) -> f64 {
    if sec < 0 {
        // -1 s + 0.25 s is -0.75 s, which the decimal "-1.25" is not.
        return (i128::from(sec) * 1_000_000_000 + i128::from(nanosec)) as f64 * 1e-9;
    }
    format!("{sec}.{nanosec:09}")
        .parse()
        .unwrap_or(sec as f64 + f64::from(nanosec) * 1e-9)
}

/// `seconds` as a ROS time (sec, nanosec), to the nearest nanosecond; [`stamp_seconds`] gives
/// the same f64 back for any stamp above 2^23 s (Unix times), where an f64 step exceeds 1 ns.
pub fn seconds_to_stamp(seconds: f64) -> (i32, u32) {
    let sec = seconds.floor();
    let mut nanosec = ((seconds - sec) * 1e9).round() as u32;
    let mut sec = sec as i32;
    if nanosec >= 1_000_000_000 {
        sec += 1;
        nanosec -= 1_000_000_000;
    }
    (sec, nanosec)
}

/// Writes a little-endian XCDR1 message, as ROS 2 publishes them.
pub struct CdrWriter {
    buf: Vec<u8>,
}

impl Default for CdrWriter {
    fn default() -> Self {
        Self::new()
    }
}

impl CdrWriter {
    /// An empty message: the encapsulation header alone.
    pub fn new() -> Self {
        Self {
            buf: vec![0, 1, 0, 0],
        }
    }

    fn align(&mut self, size: usize) {
        while !(self.buf.len() - 4).is_multiple_of(size) {
            self.buf.push(0);
        }
    }

    /// A `uint8`.
    pub fn u8(&mut self, v: u8) -> &mut Self {
        self.buf.push(v);
        self
    }

    /// A `uint32`.
    pub fn u32(&mut self, v: u32) -> &mut Self {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }

    /// An `int32`.
    pub fn i32(&mut self, v: i32) -> &mut Self {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }

    /// A `float64`.
    pub fn f64(&mut self, v: f64) -> &mut Self {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }

    /// A `string` (length with its NUL, the bytes, the NUL).
    pub fn string(&mut self, s: &str) -> &mut Self {
        self.u32(s.len() as u32 + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
        self
    }

    /// A `uint8[]`.
    pub fn bytes(&mut self, b: &[u8]) -> &mut Self {
        self.u32(b.len() as u32);
        self.buf.extend_from_slice(b);
        self
    }

    /// A `float64[]`.
    pub fn f64_seq(&mut self, v: &[f64]) -> &mut Self {
        self.u32(v.len() as u32);
        v.iter().for_each(|&x| {
            self.f64(x);
        });
        self
    }

    /// A `std_msgs/Header`.
    pub fn header(&mut self, stamp: f64, frame_id: &str) -> &mut Self {
        let (sec, nanosec) = seconds_to_stamp(stamp);
        self.i32(sec).u32(nanosec).string(frame_id)
    }

    /// The message's bytes.
    pub fn finish(self) -> Vec<u8> {
        self.buf
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cdr_fields_are_aligned_from_after_the_encapsulation_header() {
        // header stamp 7.5 s, frame "cam" (len 4 with NUL), then u8, then f64 aligned to 8.
        let mut w = CdrWriter::new();
        w.header(7.5, "cam").u8(9).f64(1.25).f64_seq(&[2.0, -3.0]);
        w.string("rgb8").bytes(&[1, 2, 3]);
        let m = w.finish();
        // 4 header + sec 4 + nsec 4 + len 4 + "cam\0" 4 = 20; u8 at 20 (rel 16); f64 at rel 24.
        assert_eq!(&m[..4], &[0, 1, 0, 0]);
        assert_eq!(&m[16..20], b"cam\0");
        assert_eq!(m[20], 9);
        assert_eq!(&m[28..36], &1.25f64.to_le_bytes());
        let mut r = MessageReader::new(&m, Wire::Cdr).unwrap();
        assert_eq!(r.header().unwrap(), (7.5, "cam".to_string()));
        assert_eq!(r.u8("u8").unwrap(), 9);
        assert_eq!(r.f64("f64").unwrap(), 1.25);
        assert_eq!(r.f64_seq("seq").unwrap(), vec![2.0, -3.0]);
        assert_eq!(r.string("enc").unwrap(), "rgb8");
        assert_eq!(r.bytes("data").unwrap(), &[1, 2, 3]);
        // Past the end: an error with the (aligned) offset, no panic.
        let e = r.u32("more").unwrap_err();
        assert_eq!((e.offset, m.len()), (80, 79));
    }

    #[test]
    fn big_endian_and_xcdr2_and_ros1_are_read() {
        // Big-endian XCDR1: sec 1, nanosec 5e8, frame "", then f64 2.0 at rel 16.
        let mut m = vec![0, 0, 0, 0];
        m.extend_from_slice(&1i32.to_be_bytes());
        m.extend_from_slice(&500_000_000u32.to_be_bytes());
        m.extend_from_slice(&1u32.to_be_bytes());
        m.extend_from_slice(&[0, 0, 0, 0]); // NUL + padding to rel 16
        m.extend_from_slice(&2.0f64.to_be_bytes());
        let mut r = MessageReader::new(&m, Wire::Cdr).unwrap();
        assert_eq!(r.header().unwrap(), (1.5, String::new()));
        assert_eq!(r.f64("x").unwrap(), 2.0);
        // XCDR2 little-endian: f64 aligned to 4 only.
        let mut m = vec![0, 7, 0, 0];
        m.extend_from_slice(&3u32.to_le_bytes());
        m.extend_from_slice(&4.5f64.to_le_bytes());
        let mut r = MessageReader::new(&m, Wire::Cdr).unwrap();
        assert_eq!(r.u32("a").unwrap(), 3);
        assert_eq!(r.f64("b").unwrap(), 4.5);
        // ROS 1: seq, secs, nsecs, frame id without NUL, no alignment.
        let mut m = Vec::new();
        for v in [42u32, 3, 250_000_000, 2] {
            m.extend_from_slice(&v.to_le_bytes());
        }
        m.extend_from_slice(b"ab");
        m.push(1);
        m.extend_from_slice(&0.5f64.to_le_bytes());
        let mut r = MessageReader::new(&m, Wire::Ros1).unwrap();
        assert_eq!(r.header().unwrap(), (3.25, "ab".to_string()));
        assert_eq!(r.u8("b").unwrap(), 1);
        assert_eq!(r.f64("f").unwrap(), 0.5);
    }

    #[test]
    fn bad_messages_are_errors_not_panics() {
        assert!(MessageReader::new(&[0, 1], Wire::Cdr).is_err());
        let e = MessageReader::new(&[0, 3, 0, 0], Wire::Cdr).err().unwrap();
        assert!(e.msg.contains("not plain CDR"), "{e}");
        // A sequence claiming 2^32-1 bytes.
        let mut m = vec![0, 1, 0, 0];
        m.extend_from_slice(&u32::MAX.to_le_bytes());
        let mut r = MessageReader::new(&m, Wire::Cdr).unwrap();
        let e = r.bytes("data").unwrap_err();
        assert!(e.msg.contains("length 4294967295"), "{e}");
        assert_eq!(e.to_string(), format!("byte 8 of the message: {}", e.msg));
    }

    #[test]
    fn stamps_round_trip_to_the_same_f64() {
        for t in [1_341_846_313.533_333, 1_700_000_000.999_999_9, 0.25, 12.0] {
            let (s, n) = seconds_to_stamp(t);
            assert_eq!(stamp_seconds(i64::from(s), n), t, "{t}");
        }
        // The decimal a TUM list would hold.
        assert_eq!(
            stamp_seconds(1_341_846_313, 533_333_000),
            "1341846313.533333".parse::<f64>().unwrap()
        );
        assert_eq!(stamp_seconds(-1, 250_000_000), -0.75);
    }
}
