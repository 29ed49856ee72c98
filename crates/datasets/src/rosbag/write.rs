//! Frames written as a ROS 1 bag (format 2.0, one chunk per frame, then the index as `rosbag`
//! writes it): what `run --bag rec.bag` reads, for tests and for trying ROS 1 tools on a
//! dataset. Colour as `sensor_msgs/Image` `rgb8` (or `mono8`), depth as `16UC1` / `32FC1`, and
//! the camera's `sensor_msgs/CameraInfo` with each frame.

use super::{MAGIC, op};
use crate::Frame;
use crate::error::{DatasetError, io_err, recording_err};
use crate::mcap::cdr::seconds_to_stamp;
use crate::mcap::{DepthEncoding, McapTopics};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use stillpoint_geometry::PinholeCamera;

/// How chunks are stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BagCompression {
    /// As they are (`rosbag record`'s default).
    None,
    /// bz2 (`rosbag record --bz2`).
    Bz2,
    /// lz4 frames (`rosbag record --lz4`).
    Lz4,
}

impl BagCompression {
    fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Bz2 => "bz2",
            Self::Lz4 => "lz4",
        }
    }
}

/// A bag record: header fields, then data.
fn record(fields: &[(&str, &[u8])], data: &[u8]) -> Vec<u8> {
    let mut header = Vec::new();
    for (name, value) in fields {
        header.extend_from_slice(&((name.len() + 1 + value.len()) as u32).to_le_bytes());
        header.extend_from_slice(name.as_bytes());
        header.push(b'=');
        header.extend_from_slice(value);
    }
    let mut out = (header.len() as u32).to_le_bytes().to_vec();
    out.extend_from_slice(&header);
    out.extend_from_slice(&(data.len() as u32).to_le_bytes());
    out.extend_from_slice(data);
    out
}

/// ROS 1 `time`: sec then nsec, little-endian.
fn ros_time(stamp: f64) -> [u8; 8] {
    let (sec, nsec) = seconds_to_stamp(stamp);
    let mut b = [0u8; 8];
    b[..4].copy_from_slice(&(sec as u32).to_le_bytes());
    b[4..].copy_from_slice(&nsec.to_le_bytes());
    b
}

/// A ROS 1 message, field by field (little-endian, no alignment, strings without NUL).
#[derive(Default)]
struct Ros1Writer(Vec<u8>);

impl Ros1Writer {
    fn u8(&mut self, v: u8) -> &mut Self {
        self.0.push(v);
        self
    }
    fn u32(&mut self, v: u32) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
    fn f64(&mut self, v: f64) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
    fn bytes(&mut self, b: &[u8]) -> &mut Self {
        self.u32(b.len() as u32);
        self.0.extend_from_slice(b);
        self
    }
    fn string(&mut self, s: &str) -> &mut Self {
        self.bytes(s.as_bytes())
    }
    /// `std_msgs/Header`: seq, stamp, frame_id.
    fn header(&mut self, seq: u32, stamp: f64, frame_id: &str) -> &mut Self {
        self.u32(seq);
        self.0.extend_from_slice(&ros_time(stamp));
        self.string(frame_id)
    }
}

const IMAGE_MD5: &str = "060021388200f6f0f447d0fcd9c64743";
const CAMERA_INFO_MD5: &str = "c9a58c1b0b154e0e6da7578cb991d214";
const HEADER_DEF: &str = "MSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n";
const IMAGE_DEF: &str = "Header header\nuint32 height\nuint32 width\nstring encoding\n\
                         uint8 is_bigendian\nuint32 step\nuint8[] data\n";
const CAMERA_INFO_DEF: &str = "Header header\nuint32 height\nuint32 width\n\
                               string distortion_model\nfloat64[] D\nfloat64[9] K\n\
                               float64[9] R\nfloat64[12] P\nuint32 binning_x\nuint32 binning_y\n\
                               RegionOfInterest roi\n";
const ROI_DEF: &str = "MSG: sensor_msgs/RegionOfInterest\nuint32 x_offset\nuint32 y_offset\n\
                       uint32 height\nuint32 width\nbool do_rectify\n";
const SEPARATOR: &str =
    "================================================================================\n";

/// A topic being written: its id, name, and connection header.
struct Connection {
    id: u32,
    topic: String,
    /// The connection record's data (type, md5sum, definition).
    header: Vec<u8>,
}

fn connection(id: u32, topic: &str, ty: &str, md5: &str, definition: &str) -> Connection {
    let mut header = Vec::new();
    for (k, v) in [
        ("topic", topic),
        ("type", ty),
        ("md5sum", md5),
        ("message_definition", definition),
        ("callerid", "/stillpoint"),
        ("latching", "0"),
    ] {
        header.extend_from_slice(&((k.len() + 1 + v.len()) as u32).to_le_bytes());
        header.extend_from_slice(k.as_bytes());
        header.push(b'=');
        header.extend_from_slice(v.as_bytes());
    }
    Connection {
        id,
        topic: topic.to_string(),
        header,
    }
}

impl Connection {
    fn record(&self) -> Vec<u8> {
        record(
            &[
                ("op", &[op::CONNECTION]),
                ("conn", &self.id.to_le_bytes()),
                ("topic", self.topic.as_bytes()),
            ],
            &self.header,
        )
    }
}

/// Where each chunk is and what it holds, for the index at the end.
struct ChunkInfo {
    pos: u64,
    start: f64,
    end: f64,
    /// Messages per connection.
    counts: BTreeMap<u32, u32>,
}

/// Writes frames into a ROS 1 bag: colour, depth or right images (when the topics have them)
/// and camera info.
pub struct BagWriter {
    path: PathBuf,
    out: BufWriter<File>,
    compression: BagCompression,
    rgb: Connection,
    depth: Option<(Connection, DepthEncoding)>,
    info: Connection,
    /// The right image and camera info connections.
    right: Option<(Connection, Connection)>,
    camera: PinholeCamera,
    /// Stereo baseline times fx: the right camera info's `P[3]` is `-bf`.
    bf: f64,
    chunks: Vec<ChunkInfo>,
    /// Connections already written in a chunk.
    announced: Vec<u32>,
    seq: u32,
}

/// A record of a given total size: the bag header is padded to 4096 bytes with spaces.
const BAG_HEADER_LEN: usize = 4096;

fn bag_header(index_pos: u64, conns: u32, chunks: u32) -> Vec<u8> {
    let fields: [(&str, &[u8]); 4] = [
        ("op", &[op::BAG_HEADER]),
        ("index_pos", &index_pos.to_le_bytes()),
        ("conn_count", &conns.to_le_bytes()),
        ("chunk_count", &chunks.to_le_bytes()),
    ];
    let bare = record(&fields, &[]).len();
    record(&fields, &vec![b' '; BAG_HEADER_LEN - bare])
}

impl BagWriter {
    /// Create `path`: colour on `topics.rgb`, depth on `topics.depth` (as `depth`), camera info
    /// on [`McapTopics::camera_info_topic`]; right images (`mono8`) on `topics.right` with
    /// their camera info beside them (the baseline from [`Self::with_stereo_bf`]).
    pub fn create(
        path: &Path,
        topics: &McapTopics,
        depth: DepthEncoding,
        camera: &PinholeCamera,
        compression: BagCompression,
    ) -> Result<Self, DatasetError> {
        let file = File::create(path).map_err(io_err(path))?;
        let mut out = BufWriter::new(file);
        out.write_all(MAGIC).map_err(io_err(path))?;
        out.write_all(&bag_header(0, 0, 0)).map_err(io_err(path))?;
        let image_def = format!("{IMAGE_DEF}{SEPARATOR}{HEADER_DEF}");
        let info_def = format!("{CAMERA_INFO_DEF}{SEPARATOR}{HEADER_DEF}{SEPARATOR}{ROI_DEF}");
        let image = |id, t: &str| connection(id, t, "sensor_msgs/Image", IMAGE_MD5, &image_def);
        let rgb = image(0, &topics.rgb);
        let depth = topics.depth.as_deref().map(|t| (image(1, t), depth));
        let info_conn =
            |id, t: &str| connection(id, t, "sensor_msgs/CameraInfo", CAMERA_INFO_MD5, &info_def);
        let info = info_conn(2, &topics.camera_info_topic());
        let right = match (&topics.right, topics.right_camera_info_topic()) {
            (Some(t), Some(i)) => Some((image(3, t), info_conn(4, &i))),
            _ => None,
        };
        Ok(Self {
            path: path.to_path_buf(),
            out,
            compression,
            rgb,
            depth,
            info,
            right,
            camera: *camera,
            bf: 0.0,
            chunks: Vec::new(),
            announced: Vec::new(),
            seq: 0,
        })
    }

    /// The stereo pair's baseline times fx (pixel-metres), written as the right camera info's
    /// `P[3] = -bf`.
    pub fn with_stereo_bf(mut self, bf: f64) -> Self {
        self.bf = bf;
        self
    }

    fn io(&self) -> impl FnOnce(std::io::Error) -> DatasetError + '_ {
        io_err(&self.path)
    }

    /// Write one frame as one chunk: its messages, then the chunk's index records.
    pub fn write_frame(&mut self, frame: &Frame) -> Result<(), DatasetError> {
        let t = frame.timestamp;
        let seq = self.seq;
        self.seq += 1;
        let mut messages: Vec<(u32, Vec<u8>)> = Vec::new();
        let mut m = Ros1Writer::default();
        m.header(seq, t, "camera");
        match &frame.rgb {
            Some(rgb) => {
                let px: Vec<u8> = rgb.data.iter().flatten().copied().collect();
                m.u32(rgb.height as u32)
                    .u32(rgb.width as u32)
                    .string("rgb8");
                m.u8(0).u32(rgb.width as u32 * 3).bytes(&px);
            }
            None => {
                let g = &frame.gray;
                m.u32(g.height as u32).u32(g.width as u32).string("mono8");
                m.u8(0).u32(g.width as u32).bytes(&g.data);
            }
        }
        messages.push((self.rgb.id, m.0));
        if let (Some((c, encoding)), Some(d)) = (&self.depth, &frame.depth) {
            let mut m = Ros1Writer::default();
            m.header(seq, t, "camera")
                .u32(d.height as u32)
                .u32(d.width as u32);
            match encoding {
                DepthEncoding::Millimetres16 => {
                    let px: Vec<u8> = d
                        .data
                        .iter()
                        .flat_map(|&v| millimetres(v).to_le_bytes())
                        .collect();
                    m.string("16UC1").u8(0).u32(d.width as u32 * 2).bytes(&px);
                }
                DepthEncoding::Metres32 => {
                    let px: Vec<u8> = d.data.iter().flat_map(|v| v.to_le_bytes()).collect();
                    m.string("32FC1").u8(0).u32(d.width as u32 * 4).bytes(&px);
                }
            }
            messages.push((c.id, m.0));
        }
        if let (Some((image, info)), Some(r)) = (&self.right, &frame.right) {
            let mut m = Ros1Writer::default();
            m.header(seq, t, "camera_right")
                .u32(r.height as u32)
                .u32(r.width as u32)
                .string("mono8");
            m.u8(0).u32(r.width as u32).bytes(&r.data);
            messages.push((image.id, m.0));
            messages.push((info.id, camera_info(seq, t, &self.camera, -self.bf)));
        }
        messages.push((self.info.id, camera_info(seq, t, &self.camera, 0.0)));

        // The chunk: connections met for the first time, then the messages.
        let mut body = Vec::new();
        let mut index: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
        let mut counts = BTreeMap::new();
        for (conn, data) in &messages {
            if !self.announced.contains(conn) {
                self.announced.push(*conn);
                body.extend(self.connection(*conn).record());
            }
            index.entry(*conn).or_default().push(body.len() as u32);
            *counts.entry(*conn).or_insert(0) += 1;
            body.extend(record(
                &[
                    ("op", &[op::MESSAGE_DATA]),
                    ("conn", &conn.to_le_bytes()),
                    ("time", &ros_time(t)),
                ],
                data,
            ));
        }
        let packed = compress(self.compression, &body).map_err(self.io())?;
        let pos = self.out.stream_position().map_err(self.io())?;
        let chunk = record(
            &[
                ("op", &[op::CHUNK]),
                ("compression", self.compression.name().as_bytes()),
                ("size", &(body.len() as u32).to_le_bytes()),
            ],
            &packed,
        );
        self.out.write_all(&chunk).map_err(io_err(&self.path))?;
        for (conn, offsets) in &index {
            let mut data = Vec::new();
            for o in offsets {
                data.extend_from_slice(&ros_time(t));
                data.extend_from_slice(&o.to_le_bytes());
            }
            let r = record(
                &[
                    ("op", &[op::INDEX_DATA]),
                    ("ver", &1u32.to_le_bytes()),
                    ("conn", &conn.to_le_bytes()),
                    ("count", &(offsets.len() as u32).to_le_bytes()),
                ],
                &data,
            );
            self.out.write_all(&r).map_err(io_err(&self.path))?;
        }
        self.chunks.push(ChunkInfo {
            pos,
            start: t,
            end: t,
            counts,
        });
        Ok(())
    }

    fn connection(&self, id: u32) -> &Connection {
        let depth = self.depth.iter().map(|(c, _)| c);
        let right = self.right.iter().flat_map(|(i, c)| [i, c]);
        [&self.rgb, &self.info]
            .into_iter()
            .chain(depth)
            .chain(right)
            .find(|c| c.id == id)
            .unwrap_or(&self.info)
    }

    /// Write the index (connections, chunk infos) and the bag header that points to it.
    pub fn finish(mut self) -> Result<(), DatasetError> {
        let index_pos = self.out.stream_position().map_err(self.io())?;
        let conns: Vec<u32> = self.announced.clone();
        for c in &conns {
            let r = self.connection(*c).record();
            self.out.write_all(&r).map_err(io_err(&self.path))?;
        }
        for ch in &self.chunks {
            let mut data = Vec::new();
            for (conn, n) in &ch.counts {
                data.extend_from_slice(&conn.to_le_bytes());
                data.extend_from_slice(&n.to_le_bytes());
            }
            let r = record(
                &[
                    ("op", &[op::CHUNK_INFO]),
                    ("ver", &1u32.to_le_bytes()),
                    ("chunk_pos", &ch.pos.to_le_bytes()),
                    ("start_time", &ros_time(ch.start)),
                    ("end_time", &ros_time(ch.end)),
                    ("count", &(ch.counts.len() as u32).to_le_bytes()),
                ],
                &data,
            );
            self.out.write_all(&r).map_err(io_err(&self.path))?;
        }
        let header = bag_header(index_pos, conns.len() as u32, self.chunks.len() as u32);
        self.out
            .seek(SeekFrom::Start(MAGIC.len() as u64))
            .map_err(io_err(&self.path))?;
        self.out.write_all(&header).map_err(io_err(&self.path))?;
        self.out.flush().map_err(io_err(&self.path))?;
        if self.chunks.is_empty() {
            return Err(recording_err(&self.path, "writing", "no frame was written"));
        }
        Ok(())
    }
}

fn compress(c: BagCompression, body: &[u8]) -> std::io::Result<Vec<u8>> {
    match c {
        BagCompression::None => Ok(body.to_vec()),
        BagCompression::Bz2 => {
            let mut e = bzip2::write::BzEncoder::new(Vec::new(), bzip2::Compression::fast());
            e.write_all(body)?;
            e.finish()
        }
        BagCompression::Lz4 => {
            let mut e = lz4::EncoderBuilder::new().build(Vec::new())?;
            e.write_all(body)?;
            let (out, r) = e.finish();
            r.map(|()| out)
        }
    }
}

/// Metres as `16UC1` millimetres; no measurement (0, non-finite) and beyond 65.535 m are 0.
fn millimetres(m: f32) -> u16 {
    let v = (m * 1000.0).round();
    if v.is_finite() && v > 0.0 && v <= f32::from(u16::MAX) {
        v as u16
    } else {
        0
    }
}

/// A ROS 1 `sensor_msgs/CameraInfo` of `c` (plumb_bob), `P[3]` = `tx` (`-fx * baseline` for a
/// right camera).
fn camera_info(seq: u32, stamp: f64, c: &PinholeCamera, tx: f64) -> Vec<u8> {
    let d = &c.distortion;
    let k = [c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0];
    let r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let p = [
        c.fx, 0.0, c.cx, tx, 0.0, c.fy, c.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
    ];
    let mut m = Ros1Writer::default();
    m.header(seq, stamp, "camera").u32(c.height).u32(c.width);
    m.string("plumb_bob").u32(5);
    for v in [d.k1, d.k2, d.p1, d.p2, d.k3]
        .iter()
        .chain(&k)
        .chain(&r)
        .chain(&p)
    {
        m.f64(*v);
    }
    // binning x, y; roi x, y, height, width, do_rectify.
    m.u32(0).u32(0).u32(0).u32(0).u32(0).u32(0).u8(0);
    m.0
}
