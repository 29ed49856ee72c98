//! One pass over an MCAP file that finds every channel and where each wanted message lies, and
//! the reading of one message back from where it lies.
//!
//! The pass walks the top-level records itself (so an error can name its byte offset) and uses
//! the `mcap` crate to parse records and to decompress chunks (zstd, lz4). It does not need the
//! summary section: a file whose summary is missing or wrong reads the same. A message is found
//! again by its record's offset, or by its chunk's offset and its place in the chunk; the last
//! two chunks read are kept decompressed, as a frame's colour and depth lie in one or two.

use super::cdr::{MessageReader, Wire, stamp_seconds};
use super::ros::MessageType;
use crate::error::{DatasetError, io_err, recording_err};
use ::mcap::records::{MessageHeader, Record, op};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// MCAP's magic, at both ends of a file.
const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";
/// Opcode and length before every record.
const RECORD_HEADER: u64 = 9;
/// channel id, sequence, log time, publish time.
const MESSAGE_HEADER: u64 = 22;
/// Message bytes read during the pass: CDR's header and a `std_msgs/Header` stamp (ROS 1: seq
/// and stamp).
const STAMP_PREFIX: u64 = 16;

/// A channel (topic) and its schema.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ChannelInfo {
    /// The topic, `/camera/color/image_raw`.
    pub topic: String,
    /// How its messages are serialised (`cdr`, `ros1`, `protobuf`, ...).
    pub message_encoding: String,
    /// The message type, `sensor_msgs/msg/Image` (empty without a schema).
    pub schema_name: String,
    /// The schema's language (`ros2msg`, `ros1msg`, ...).
    pub schema_encoding: String,
}

impl ChannelInfo {
    /// The camera message type, when it is one.
    pub fn message_type(&self) -> Option<MessageType> {
        MessageType::from_schema_name(&self.schema_name)
    }

    /// The wire format, when we read it.
    pub fn wire(&self) -> Option<Wire> {
        Wire::from_message_encoding(&self.message_encoding)
    }
}

/// Where a message's bytes are.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Location {
    /// A message record outside chunks: its data's offset and length.
    Direct {
        /// Byte offset of the message data.
        offset: u64,
        /// Bytes.
        len: u64,
    },
    /// A message record inside a chunk.
    Chunk {
        /// Byte offset of the chunk record.
        offset: u64,
        /// The message's place among the chunk's records.
        ordinal: u32,
    },
}

impl Location {
    /// The byte offset of the record holding the message (the chunk's for a chunked one).
    pub fn byte(&self) -> u64 {
        match *self {
            Self::Direct { offset, .. } => offset - MESSAGE_HEADER - RECORD_HEADER,
            Self::Chunk { offset, .. } => offset,
        }
    }
}

/// A message found by the pass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MessageRef {
    /// Its channel.
    pub channel: u16,
    /// `header.stamp` for the camera messages, else the log time, seconds.
    pub stamp: f64,
    /// Where it is.
    pub at: Location,
}

/// What one channel holds.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ChannelStats {
    /// Messages.
    pub count: u64,
    /// The first message.
    pub first: Option<MessageRef>,
    /// Smallest and largest stamp.
    pub stamps: Option<(f64, f64)>,
}

/// The pass's findings.
#[derive(Debug, Default)]
pub struct Scan {
    /// Every channel by id.
    pub channels: BTreeMap<u16, ChannelInfo>,
    /// Per channel: count, first message, stamp range.
    pub stats: BTreeMap<u16, ChannelStats>,
    /// The messages of the wanted channels, in file order.
    pub messages: Vec<MessageRef>,
    /// Chunk compressions met (`zstd`, `lz4`, `` for none).
    pub compressions: Vec<String>,
    /// The file's size, bytes.
    pub bytes: u64,
}

impl Scan {
    /// The channel ids of `topic`.
    pub fn channels_of(&self, topic: &str) -> Vec<u16> {
        self.channels
            .iter()
            .filter(|(_, c)| c.topic == topic)
            .map(|(&id, _)| id)
            .collect()
    }

    /// "topic (type)" for every topic, for an error about a missing one.
    pub fn topic_list(&self) -> String {
        let mut seen: Vec<String> = self
            .channels
            .values()
            .map(|c| format!("{} ({})", c.topic, c.schema_name))
            .collect();
        seen.sort();
        seen.dedup();
        if seen.is_empty() {
            "the file has no topics".into()
        } else {
            format!("topics in the file: {}", seen.join(", "))
        }
    }
}

/// Walk `path` once; `wanted` picks the channels whose messages are listed. A ROS 1 bag is
/// walked by [`crate::rosbag::scan`] into the same findings.
pub fn scan(path: &Path, wanted: &dyn Fn(&ChannelInfo) -> bool) -> Result<Scan, DatasetError> {
    if crate::rosbag::is_bag(path) {
        return crate::rosbag::scan(path, wanted);
    }
    let file = File::open(path).map_err(io_err(path))?;
    let len = file.metadata().map_err(io_err(path))?.len();
    let mut r = BufReader::with_capacity(1 << 20, file);
    check_magic(&mut r, path, len)?;
    let mut walker = Walker {
        path,
        wanted,
        scan: Scan {
            bytes: len,
            ..Default::default()
        },
        schemas: BTreeMap::new(),
    };
    let mut pos = MAGIC.len() as u64;
    loop {
        let at = |m: String| recording_err(path, format!("byte {pos}"), m);
        if pos == len {
            return Err(at(truncated("the file ends without a footer")));
        }
        if len - pos < RECORD_HEADER {
            return Err(at(truncated(&format!(
                "a record header needs 9 bytes, {} are left",
                len - pos
            ))));
        }
        let mut head = [0u8; RECORD_HEADER as usize];
        r.read_exact(&mut head).map_err(io_err(path))?;
        let opcode = head[0];
        let body = u64::from_le_bytes(head[1..].try_into().unwrap_or_default());
        if body > len - pos - RECORD_HEADER {
            return Err(at(truncated(&format!(
                "a {} record of {body} bytes, but the file ends {} bytes later",
                record_name(opcode),
                len - pos - RECORD_HEADER
            ))));
        }
        match opcode {
            op::MESSAGE => walker.direct_message(&mut r, pos, body)?,
            op::CHUNK => walker.chunk(&mut r, pos, body)?,
            op::SCHEMA | op::CHANNEL => {
                let bytes = read_body(&mut r, path, body)?;
                let record = ::mcap::parse_record(opcode, &bytes)
                    .map_err(|e| at(format!("bad record: {e}")))?;
                walker.metadata(record);
            }
            op::FOOTER => return Ok(walker.scan),
            _ => skip(&mut r, path, body)?,
        }
        pos += RECORD_HEADER + body;
    }
}

/// The record type of an opcode, for errors.
fn record_name(opcode: u8) -> String {
    let name = match opcode {
        op::HEADER => "header",
        op::FOOTER => "footer",
        op::SCHEMA => "schema",
        op::CHANNEL => "channel",
        op::MESSAGE => "message",
        op::CHUNK => "chunk",
        op::MESSAGE_INDEX => "message index",
        op::CHUNK_INDEX => "chunk index",
        op::ATTACHMENT => "attachment",
        op::STATISTICS => "statistics",
        op::METADATA => "metadata",
        op::DATA_END => "data end",
        _ => return format!("opcode 0x{opcode:02x}"),
    };
    name.to_string()
}

fn truncated(what: &str) -> String {
    format!("{what}: the file is truncated (`mcap recover` saves what was written)")
}

fn check_magic(r: &mut impl Read, path: &Path, len: u64) -> Result<(), DatasetError> {
    let mut magic = [0u8; 8];
    if len < 8 || r.read_exact(&mut magic).is_err() {
        return Err(recording_err(
            path,
            "byte 0",
            format!("{len} bytes: not an MCAP file"),
        ));
    }
    if &magic != MAGIC {
        return Err(recording_err(
            path,
            "byte 0",
            format!("not an MCAP file (starts with {magic:02x?})"),
        ));
    }
    Ok(())
}

fn read_body(r: &mut impl Read, path: &Path, n: u64) -> Result<Vec<u8>, DatasetError> {
    // `n` is within the file (checked by the caller).
    let mut buf = vec![0u8; n as usize];
    r.read_exact(&mut buf).map_err(io_err(path))?;
    Ok(buf)
}

fn skip(r: &mut BufReader<File>, path: &Path, n: u64) -> Result<(), DatasetError> {
    r.seek_relative(n as i64).map_err(io_err(path))
}

struct Walker<'a> {
    path: &'a Path,
    wanted: &'a dyn Fn(&ChannelInfo) -> bool,
    scan: Scan,
    /// Schema id -> (name, encoding).
    schemas: BTreeMap<u16, (String, String)>,
}

impl Walker<'_> {
    /// A schema or channel record (data section, chunk or summary: the same ids).
    fn metadata(&mut self, record: Record<'_>) {
        match record {
            Record::Schema { header, .. } => {
                self.schemas
                    .insert(header.id, (header.name, header.encoding));
            }
            Record::Channel(c) => {
                let (schema_name, schema_encoding) =
                    self.schemas.get(&c.schema_id).cloned().unwrap_or_default();
                self.scan.channels.insert(
                    c.id,
                    ChannelInfo {
                        topic: c.topic,
                        message_encoding: c.message_encoding,
                        schema_name,
                        schema_encoding,
                    },
                );
            }
            _ => {}
        }
    }

    /// A message record outside chunks: its header and the first bytes of its data are read.
    fn direct_message(
        &mut self,
        r: &mut BufReader<File>,
        pos: u64,
        body: u64,
    ) -> Result<(), DatasetError> {
        if body < MESSAGE_HEADER {
            return Err(recording_err(
                self.path,
                format!("byte {pos}"),
                format!("a message record of {body} bytes, shorter than its header"),
            ));
        }
        let head = body.min(MESSAGE_HEADER + STAMP_PREFIX);
        let bytes = read_body(r, self.path, head)?;
        let header = message_header(&bytes);
        let at = Location::Direct {
            offset: pos + RECORD_HEADER + MESSAGE_HEADER,
            len: body - MESSAGE_HEADER,
        };
        self.message(&header, &bytes[MESSAGE_HEADER as usize..], at);
        skip(r, self.path, body - head)
    }

    /// A chunk: decompressed, its records walked.
    fn chunk(&mut self, r: &mut BufReader<File>, pos: u64, body: u64) -> Result<(), DatasetError> {
        let bytes = read_body(r, self.path, body)?;
        let path = self.path;
        let compression =
            for_each_chunk_record(&bytes, path, pos, |ordinal, record| match record {
                Record::Message { header, data } => {
                    let at = Location::Chunk {
                        offset: pos,
                        ordinal,
                    };
                    self.message(&header, &data, at);
                }
                other => self.metadata(other),
            })?;
        let compression = if compression.is_empty() {
            "none".to_string()
        } else {
            compression
        };
        if !self.scan.compressions.contains(&compression) {
            self.scan.compressions.push(compression);
        }
        Ok(())
    }

    fn message(&mut self, header: &MessageHeader, data: &[u8], at: Location) {
        record_message(
            &mut self.scan,
            self.wanted,
            header.channel_id,
            header.log_time,
            data,
            at,
        );
    }
}

/// Count a message of `channel` (logged at `log_time` ns) in the channel's stats, and list it
/// when `wanted` picks the channel. Its stamp is `header.stamp` for the camera messages.
pub(crate) fn record_message(
    scan: &mut Scan,
    wanted: &dyn Fn(&ChannelInfo) -> bool,
    channel_id: u16,
    log_time: u64,
    data: &[u8],
    at: Location,
) {
    let channel = scan.channels.get(&channel_id);
    let stamp = channel
        .and_then(|c| Some((c.message_type()?, c.wire()?)))
        .and_then(|(_, wire)| MessageReader::new(data, wire).ok()?.stamp().ok())
        .unwrap_or_else(|| log_time_seconds(log_time));
    let m = MessageRef {
        channel: channel_id,
        stamp,
        at,
    };
    let listed = channel.is_some_and(wanted);
    let s = scan.stats.entry(channel_id).or_default();
    s.count += 1;
    s.first.get_or_insert(m);
    s.stamps = Some(match s.stamps {
        Some((a, b)) => (a.min(stamp), b.max(stamp)),
        None => (stamp, stamp),
    });
    if listed {
        scan.messages.push(m);
    }
}

/// A log time (nanoseconds) in seconds.
fn log_time_seconds(ns: u64) -> f64 {
    stamp_seconds((ns / 1_000_000_000) as i64, (ns % 1_000_000_000) as u32)
}

/// The 22-byte header of a message record (`bytes` holds at least that).
fn message_header(b: &[u8]) -> MessageHeader {
    let u64_at = |i: usize| u64::from_le_bytes(b[i..i + 8].try_into().unwrap_or_default());
    MessageHeader {
        channel_id: u16::from_le_bytes([b[0], b[1]]),
        sequence: u32::from_le_bytes(b[2..6].try_into().unwrap_or_default()),
        log_time: u64_at(6),
        publish_time: u64_at(14),
    }
}

/// Walk the records of the chunk record whose body is `body` (at byte `pos`), decompressed:
/// `each` gets each record's place in the chunk and the record. Returns the compression.
///
/// The `mcap` crate's sans-io reader decompresses, with a record length limit: it reserves
/// what a length claims, and a corrupt one must be an error, not an abort.
fn for_each_chunk_record(
    body: &[u8],
    path: &Path,
    pos: u64,
    mut each: impl FnMut(u32, Record<'_>),
) -> Result<String, DatasetError> {
    let at = |ordinal: u32, e: ::mcap::McapError| {
        recording_err(
            path,
            format!("byte {pos} (chunk, record {ordinal})"),
            e.to_string(),
        )
    };
    let header = match ::mcap::parse_record(op::CHUNK, body).map_err(|e| at(0, e))? {
        Record::Chunk { header, .. } => header,
        _ => return Err(recording_err(path, format!("byte {pos}"), "bad chunk")),
    };
    check_chunk_size(&header).map_err(|m| recording_err(path, format!("byte {pos}"), m))?;
    let limit = header.uncompressed_size.max(body.len() as u64) as usize;
    let mut reader = ::mcap::sans_io::LinearReader::new_with_options(
        ::mcap::sans_io::LinearReaderOptions::default()
            .with_skip_start_magic(true)
            .with_skip_end_magic(true)
            .with_validate_chunk_crcs(true)
            .with_record_length_limit(limit),
    );
    let mut record_header = [0u8; RECORD_HEADER as usize];
    record_header[0] = op::CHUNK;
    record_header[1..].copy_from_slice(&(body.len() as u64).to_le_bytes());
    // The chunk record as it is in the file: its header, then its body.
    let mut input: [&[u8]; 2] = [&record_header, body];
    let mut ordinal = 0u32;
    while let Some(event) = reader.next_event() {
        match event.map_err(|e| at(ordinal, e))? {
            ::mcap::sans_io::LinearReadEvent::ReadRequest(need) => {
                let src = input.iter_mut().find(|s| !s.is_empty());
                let n = src.as_ref().map_or(0, |s| s.len().min(need));
                if let Some(src) = src {
                    reader.insert(n).copy_from_slice(&src[..n]);
                    *src = &src[n..];
                }
                reader.notify_read(n);
            }
            ::mcap::sans_io::LinearReadEvent::Record { opcode, data } => {
                let record = ::mcap::parse_record(opcode, data).map_err(|e| at(ordinal, e))?;
                each(ordinal, record);
                ordinal += 1;
            }
        }
    }
    Ok(header.compression)
}

/// Largest chunk we decompress: a decompressor reserves what a chunk's header claims, so a
/// corrupt size would abort the process. Writers make chunks of a few MB (one large image each at most).
const MAX_CHUNK: u64 = 1 << 30;

fn check_chunk_size(h: &::mcap::records::ChunkHeader) -> Result<(), String> {
    let (size, packed) = (h.uncompressed_size, h.compressed_size);
    if size > MAX_CHUNK || (h.compression.is_empty() && size != packed) {
        return Err(format!(
            "a chunk of {packed} bytes ({:?}) claims {size} bytes uncompressed: corrupt",
            h.compression
        ));
    }
    Ok(())
}

/// A chunk's messages (of the channels read) by their place in the chunk.
type ChunkMessages = BTreeMap<u32, Vec<u8>>;

/// Chunks kept decompressed: a frame's colour and depth may lie in two chunks, read in turn.
const CACHED_CHUNKS: usize = 2;

/// Reads messages back by [`Location`], keeping the last chunks read.
pub struct MessageSource {
    path: PathBuf,
    /// Channels whose messages the chunk cache keeps.
    channels: Vec<u16>,
    /// A ROS 1 bag ([`crate::rosbag`]), not MCAP.
    bag: bool,
    /// The last chunks read, newest last: offset, and messages of `channels` by ordinal.
    chunks: Mutex<Vec<(u64, ChunkMessages)>>,
}

impl MessageSource {
    /// Messages of `path`; a chunk read keeps those of `channels`.
    pub fn new(path: &Path, channels: Vec<u16>) -> Self {
        Self {
            path: path.to_path_buf(),
            channels,
            bag: crate::rosbag::is_bag(path),
            chunks: Mutex::new(Vec::new()),
        }
    }

    /// The data of the message at `at`.
    pub fn read(&self, at: Location) -> Result<Vec<u8>, DatasetError> {
        match at {
            Location::Direct { offset, len } => {
                let mut f = File::open(&self.path).map_err(io_err(&self.path))?;
                f.seek(SeekFrom::Start(offset))
                    .map_err(io_err(&self.path))?;
                let mut buf = vec![0u8; len as usize];
                f.read_exact(&mut buf).map_err(io_err(&self.path))?;
                Ok(buf)
            }
            Location::Chunk { offset, ordinal } => {
                let mut cache = self.chunks.lock().unwrap_or_else(|e| e.into_inner());
                if !cache.iter().any(|(o, _)| *o == offset) {
                    let messages = self.read_chunk(offset)?;
                    if cache.len() == CACHED_CHUNKS {
                        cache.remove(0);
                    }
                    cache.push((offset, messages));
                }
                let found = cache
                    .iter()
                    .find(|(o, _)| *o == offset)
                    .and_then(|(_, messages)| messages.get(&ordinal).cloned());
                found.ok_or_else(|| {
                    recording_err(
                        &self.path,
                        format!("byte {offset} (chunk, record {ordinal})"),
                        "no such message in the chunk: the file changed since it was opened",
                    )
                })
            }
        }
    }

    /// The messages of our channels in the chunk record at `offset`.
    fn read_chunk(&self, offset: u64) -> Result<ChunkMessages, DatasetError> {
        let path = &self.path;
        if self.bag {
            return crate::rosbag::read_chunk(path, offset, &self.channels);
        }
        let mut f = File::open(path).map_err(io_err(path))?;
        f.seek(SeekFrom::Start(offset)).map_err(io_err(path))?;
        let mut head = [0u8; RECORD_HEADER as usize];
        f.read_exact(&mut head).map_err(io_err(path))?;
        let body = u64::from_le_bytes(head[1..].try_into().unwrap_or_default());
        let len = f.metadata().map_err(io_err(path))?.len();
        if head[0] != op::CHUNK || body > len.saturating_sub(offset + RECORD_HEADER) {
            return Err(recording_err(
                path,
                format!("byte {offset}"),
                "no chunk there any more: the file changed since it was opened",
            ));
        }
        let bytes = read_body(&mut f, path, body)?;
        let mut out = BTreeMap::new();
        for_each_chunk_record(&bytes, path, offset, |ordinal, record| {
            if let Record::Message { header, data } = record
                && self.channels.contains(&header.channel_id)
            {
                out.insert(ordinal, data.into_owned());
            }
        })?;
        Ok(out)
    }
}
