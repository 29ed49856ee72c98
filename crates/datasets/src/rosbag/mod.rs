//! ROS 1 bags (format 2.0, what `rosbag record` writes): read into the same [`Scan`] and
//! [`Location`]s as an MCAP file, so `run --bag rec.bag` and `stillpoint info rec.bag` are the
//! MCAP reader's ([`crate::mcap`]) over another container. Chunks may be uncompressed, bz2 or
//! lz4 (`rosbag record --bz2 / --lz4`); messages are ROS 1 serialised.
//!
//! A bag is a sequence of records, each `header_len: u32, header, data_len: u32, data`, the header
//! a list of `len: u32, name=value` fields with the record's `op` among them. The walk reads
//! them in file order (the index at the end is not needed, so a bag that was never closed and
//! reindexed reads too); a record that runs past the end of the file, or a chunk that does not
//! decompress, is an error naming its byte.

pub mod write;

use crate::error::{DatasetError, io_err, recording_err};
use crate::mcap::file::{ChannelInfo, Location, Scan, record_message};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

/// The first line of a ROS 1 bag.
pub const MAGIC: &[u8; 13] = b"#ROSBAG V2.0\n";

/// Record kinds (the `op` header field).
pub mod op {
    /// A message (`conn`, `time`; data: the serialised message).
    pub const MESSAGE_DATA: u8 = 0x02;
    /// The bag header (`index_pos`, `conn_count`, `chunk_count`), padded to 4096 bytes.
    pub const BAG_HEADER: u8 = 0x03;
    /// A connection's messages in the chunk before it (`ver`, `conn`, `count`).
    pub const INDEX_DATA: u8 = 0x04;
    /// Compressed records (`compression`, `size`).
    pub const CHUNK: u8 = 0x05;
    /// Where a chunk is and what it holds (`ver`, `chunk_pos`, `start_time`, `end_time`, `count`).
    pub const CHUNK_INFO: u8 = 0x06;
    /// A topic (`conn`, `topic`; data: a header with `type`, `md5sum`, `message_definition`).
    pub const CONNECTION: u8 = 0x07;
}

/// Largest record or decompressed chunk read: a corrupt length must be an error, not a request
/// for gigabytes.
const MAX_RECORD: u64 = 1 << 30;

/// A record's header fields.
type Fields<'a> = BTreeMap<&'a str, &'a [u8]>;

/// Split a record header (or a connection header) into its fields.
fn fields(mut b: &[u8]) -> Result<Fields<'_>, String> {
    let mut out = BTreeMap::new();
    while !b.is_empty() {
        if b.len() < 4 {
            return Err("a header field length runs past the header".into());
        }
        let n = u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize;
        if n > b.len() - 4 {
            return Err(format!(
                "a header field of {n} bytes, {} are left",
                b.len() - 4
            ));
        }
        let field = &b[4..4 + n];
        let eq = field
            .iter()
            .position(|&c| c == b'=')
            .ok_or("a header field without '='")?;
        let name =
            std::str::from_utf8(&field[..eq]).map_err(|_| "a header field name is not UTF-8")?;
        out.insert(name, &field[eq + 1..]);
        b = &b[4 + n..];
    }
    Ok(out)
}

fn u32_field(f: &Fields<'_>, name: &str) -> Result<u32, String> {
    let v = f.get(name).ok_or_else(|| format!("no {name:?} field"))?;
    let b: [u8; 4] = (*v)
        .try_into()
        .map_err(|_| format!("field {name:?} has {} bytes, not 4", v.len()))?;
    Ok(u32::from_le_bytes(b))
}

fn u64_field(f: &Fields<'_>, name: &str) -> Result<u64, String> {
    let v = f.get(name).ok_or_else(|| format!("no {name:?} field"))?;
    let b: [u8; 8] = (*v)
        .try_into()
        .map_err(|_| format!("field {name:?} has {} bytes, not 8", v.len()))?;
    Ok(u64::from_le_bytes(b))
}

fn str_field(f: &Fields<'_>, name: &str) -> Result<String, String> {
    f.get(name)
        .map(|v| String::from_utf8_lossy(v).into_owned())
        .ok_or_else(|| format!("no {name:?} field"))
}

fn op_of(f: &Fields<'_>) -> Result<u8, String> {
    match f.get("op") {
        Some([o]) => Ok(*o),
        Some(v) => Err(format!("an op field of {} bytes", v.len())),
        None => Err("a record without op".into()),
    }
}

/// A record in a byte slice (a decompressed chunk): header and data, and the bytes it took.
fn record_at(b: &[u8]) -> Result<(&[u8], &[u8], usize), String> {
    let len_at = |i: usize, what: &str| -> Result<usize, String> {
        b.get(i..i + 4)
            .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]) as usize)
            .ok_or_else(|| format!("the {what} length runs past the chunk"))
    };
    let h = len_at(0, "header")?;
    let d = len_at(4 + h, "data")?;
    let end = 8 + h + d;
    if end > b.len() {
        return Err(format!(
            "a record of {end} bytes, {} are left in the chunk",
            b.len()
        ));
    }
    Ok((&b[4..4 + h], &b[8 + h..end], end))
}

/// A connection record: its id and channel.
fn connection(header: &Fields<'_>, data: &[u8]) -> Result<(u16, ChannelInfo), String> {
    let conn = u32_field(header, "conn")?;
    let id = u16::try_from(conn).map_err(|_| format!("connection id {conn} is too large"))?;
    let topic = str_field(header, "topic")?;
    let info = fields(data).map_err(|e| format!("connection {conn}: {e}"))?;
    let ty = str_field(&info, "type").unwrap_or_default();
    Ok((
        id,
        ChannelInfo {
            topic,
            message_encoding: "ros1".into(),
            schema_name: ty,
            schema_encoding: "ros1msg".into(),
        },
    ))
}

/// `time` (sec, nsec) in nanoseconds.
fn time_ns(header: &Fields<'_>) -> Result<u64, String> {
    let t = u64_field(header, "time")?;
    let (sec, nsec) = (t & 0xffff_ffff, t >> 32);
    Ok(sec * 1_000_000_000 + nsec)
}

/// Decompress a chunk's data.
fn decompress(compression: &str, data: &[u8], size: u64) -> Result<Vec<u8>, String> {
    if size > MAX_RECORD {
        return Err(format!("a chunk claims {size} bytes uncompressed: corrupt"));
    }
    let mut out = Vec::with_capacity(size as usize);
    let limit = size + 1;
    match compression {
        "none" => out.extend_from_slice(data),
        "bz2" => {
            bzip2::read::BzDecoder::new(data)
                .take(limit)
                .read_to_end(&mut out)
                .map_err(|e| format!("bz2: {e}"))?;
        }
        "lz4" => {
            lz4::Decoder::new(data)
                .map_err(|e| format!("lz4: {e}"))?
                .take(limit)
                .read_to_end(&mut out)
                .map_err(|e| format!("lz4: {e}"))?;
        }
        other => {
            return Err(format!(
                "compression {other:?} is not supported (none, bz2, lz4)"
            ));
        }
    }
    if out.len() as u64 != size {
        return Err(format!(
            "{compression} chunk: {} bytes uncompressed, its header says {size}",
            out.len()
        ));
    }
    Ok(out)
}

/// The truncation message, with what saves the rest.
fn truncated(what: String) -> String {
    format!("{what}: the file is truncated (`rosbag reindex` saves what was written)")
}

/// Walk the bag at `path` once; `wanted` picks the channels whose messages are listed. Each
/// message's place is its chunk's byte offset and its ordinal among the chunk's records.
pub fn scan(path: &Path, wanted: &dyn Fn(&ChannelInfo) -> bool) -> Result<Scan, DatasetError> {
    let file = File::open(path).map_err(io_err(path))?;
    let len = file.metadata().map_err(io_err(path))?.len();
    let mut r = BufReader::with_capacity(1 << 20, file);
    let mut magic = [0u8; 13];
    if len < 13 || r.read_exact(&mut magic).is_err() || &magic != MAGIC {
        return Err(recording_err(
            path,
            "byte 0",
            "not a ROS 1 bag of format 2.0 (`#ROSBAG V2.0`)",
        ));
    }
    let mut scan = Scan {
        bytes: len,
        ..Default::default()
    };
    let mut pos = MAGIC.len() as u64;
    while pos < len {
        let at = |m: String| recording_err(path, format!("byte {pos}"), m);
        let (header, data) = read_record(&mut r, len - pos).map_err(at)?;
        let f = fields(&header).map_err(at)?;
        let record_len = 8 + header.len() as u64 + data.len() as u64;
        match op_of(&f).map_err(at)? {
            op::CHUNK => {
                let compression = str_field(&f, "compression").map_err(at)?;
                let size = u32_field(&f, "size").map_err(at)?;
                let bytes = decompress(&compression, &data, u64::from(size))
                    .map_err(|m| at(format!("chunk: {m}")))?;
                walk_chunk(&bytes, &mut scan, wanted, pos).map_err(|(k, m)| {
                    recording_err(path, format!("byte {pos} (chunk, record {k})"), m)
                })?;
                if !scan.compressions.contains(&compression) {
                    scan.compressions.push(compression);
                }
            }
            op::CONNECTION => {
                let (id, c) = connection(&f, &data).map_err(at)?;
                scan.channels.entry(id).or_insert(c);
            }
            op::MESSAGE_DATA => {
                return Err(at(
                    "a message outside a chunk: not what rosbag writes (reindex or re-record it)"
                        .into(),
                ));
            }
            // Bag header, index data, chunk info: the walk does not need them.
            _ => {}
        }
        pos += record_len;
    }
    Ok(scan)
}

/// Read one top-level record, `left` bytes being left in the file.
fn read_record(r: &mut impl Read, left: u64) -> Result<(Vec<u8>, Vec<u8>), String> {
    fn read_len(r: &mut impl Read, what: &str, left: u64) -> Result<u64, String> {
        if left < 4 {
            return Err(truncated(format!(
                "a record's {what} length needs 4 bytes, {left} are left"
            )));
        }
        let mut b = [0u8; 4];
        r.read_exact(&mut b).map_err(|e| e.to_string())?;
        Ok(u64::from(u32::from_le_bytes(b)))
    }
    let h = read_len(r, "header", left)?;
    if h > left - 4 {
        return Err(truncated(format!(
            "a record header of {h} bytes, but the file ends {} bytes later",
            left - 4
        )));
    }
    let mut header = vec![0u8; h as usize];
    r.read_exact(&mut header).map_err(|e| e.to_string())?;
    let left = left - 4 - h;
    let d = read_len(r, "data", left)?;
    if d > left - 4 {
        let what = fields(&header)
            .ok()
            .and_then(|f| op_of(&f).ok())
            .map_or("record".to_string(), op_name);
        return Err(truncated(format!(
            "a {what} of {d} bytes, but the file ends {} bytes later",
            left - 4
        )));
    }
    if d > MAX_RECORD {
        return Err(format!("a record of {d} bytes: corrupt"));
    }
    let mut data = vec![0u8; d as usize];
    r.read_exact(&mut data).map_err(|e| e.to_string())?;
    Ok((header, data))
}

fn op_name(op: u8) -> String {
    match op {
        op::MESSAGE_DATA => "message".into(),
        op::BAG_HEADER => "bag header".into(),
        op::INDEX_DATA => "index".into(),
        op::CHUNK => "chunk".into(),
        op::CHUNK_INFO => "chunk info".into(),
        op::CONNECTION => "connection".into(),
        o => format!("record (op 0x{o:02x})"),
    }
}

/// The records of a decompressed chunk: connections and messages. Errors carry the ordinal.
fn walk_chunk(
    mut b: &[u8],
    scan: &mut Scan,
    wanted: &dyn Fn(&ChannelInfo) -> bool,
    chunk_pos: u64,
) -> Result<(), (u32, String)> {
    let mut ordinal = 0u32;
    while !b.is_empty() {
        let e = |m: String| (ordinal, m);
        let (header, data, used) = record_at(b).map_err(e)?;
        let f = fields(header).map_err(e)?;
        match op_of(&f).map_err(e)? {
            op::CONNECTION => {
                let (id, c) = connection(&f, data).map_err(e)?;
                scan.channels.entry(id).or_insert(c);
            }
            op::MESSAGE_DATA => {
                let conn = u32_field(&f, "conn").map_err(e)?;
                let id = u16::try_from(conn).map_err(|_| e(format!("connection {conn}")))?;
                let t = time_ns(&f).map_err(e)?;
                let at = Location::Chunk {
                    offset: chunk_pos,
                    ordinal,
                };
                record_message(scan, wanted, id, t, data, at);
            }
            _ => {}
        }
        b = &b[used..];
        ordinal += 1;
    }
    Ok(())
}

/// The messages of `channels` in the chunk record at `offset`, by ordinal.
pub fn read_chunk(
    path: &Path,
    offset: u64,
    channels: &[u16],
) -> Result<BTreeMap<u32, Vec<u8>>, DatasetError> {
    let mut f = File::open(path).map_err(io_err(path))?;
    let len = f.metadata().map_err(io_err(path))?.len();
    f.seek(SeekFrom::Start(offset)).map_err(io_err(path))?;
    let at = |m: String| recording_err(path, format!("byte {offset}"), m);
    let (header, data) =
        read_record(&mut BufReader::new(f), len.saturating_sub(offset)).map_err(at)?;
    let fl = fields(&header).map_err(at)?;
    if op_of(&fl).ok() != Some(op::CHUNK) {
        return Err(at(
            "no chunk there any more: the file changed since it was opened".into(),
        ));
    }
    let compression = str_field(&fl, "compression").map_err(at)?;
    let size = u32_field(&fl, "size").map_err(at)?;
    let bytes = decompress(&compression, &data, u64::from(size)).map_err(at)?;
    let mut out = BTreeMap::new();
    let mut b = &bytes[..];
    let mut ordinal = 0u32;
    while !b.is_empty() {
        let (header, data, used) = record_at(b).map_err(at)?;
        let f = fields(header).map_err(at)?;
        if op_of(&f).ok() == Some(op::MESSAGE_DATA)
            && let Ok(conn) = u32_field(&f, "conn")
            && u16::try_from(conn).is_ok_and(|c| channels.contains(&c))
        {
            out.insert(ordinal, data.to_vec());
        }
        b = &b[used..];
        ordinal += 1;
    }
    Ok(out)
}

/// True when `path` starts as a ROS 1 bag does.
pub fn is_bag(path: &Path) -> bool {
    let mut magic = [0u8; 7];
    File::open(path)
        .and_then(|mut f| f.read_exact(&mut magic))
        .is_ok_and(|()| &magic == b"#ROSBAG")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn field(name: &str, v: &[u8]) -> Vec<u8> {
        let mut f = ((name.len() + 1 + v.len()) as u32).to_le_bytes().to_vec();
        f.extend_from_slice(name.as_bytes());
        f.push(b'=');
        f.extend_from_slice(v);
        f
    }

    #[test]
    fn header_fields_split_and_bad_ones_are_named() {
        let mut h = field("op", &[5]);
        h.extend(field("compression", b"bz2"));
        let f = fields(&h).unwrap();
        assert_eq!(op_of(&f), Ok(op::CHUNK));
        assert_eq!(str_field(&f, "compression").unwrap(), "bz2");
        assert!(u32_field(&f, "size").unwrap_err().contains("no \"size\""));
        let mut cut = h.clone();
        cut.truncate(h.len() - 1);
        assert!(
            fields(&cut)
                .unwrap_err()
                .contains("a header field of 15 bytes, 14 are left")
        );
    }

    #[test]
    fn chunks_decompress_and_check_their_size() {
        let text = b"hello bag ".repeat(100);
        let mut bz = Vec::new();
        {
            use std::io::Write;
            let mut e = bzip2::write::BzEncoder::new(&mut bz, bzip2::Compression::best());
            e.write_all(&text).unwrap();
            e.finish().unwrap();
        }
        assert_eq!(decompress("bz2", &bz, text.len() as u64).unwrap(), text);
        let mut l4 = Vec::new();
        {
            use std::io::Write;
            let mut e = lz4::EncoderBuilder::new().build(&mut l4).unwrap();
            e.write_all(&text).unwrap();
            e.finish().1.unwrap();
        }
        assert_eq!(decompress("lz4", &l4, text.len() as u64).unwrap(), text);
        let e = decompress("bz2", &bz, 10).unwrap_err();
        assert!(e.contains("its header says 10"), "{e}");
        assert!(
            decompress("zstd", &bz, 10)
                .unwrap_err()
                .contains("not supported")
        );
        assert!(decompress("bz2", &bz[..20], 1000).is_err());
    }
}
