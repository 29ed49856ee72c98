//! Frames written as a ROS 2 recording (MCAP, CDR, the schemas named as ROS 2 names them):
//! what `run --bag` reads, for tests and for trying ROS tools on a dataset.

use super::McapTopics;
use super::cdr::CdrWriter;
use crate::Frame;
use crate::error::{DatasetError, io_err, recording_err};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::Path;
use stillpoint_geometry::PinholeCamera;

/// How depth images are written (REP 118).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DepthEncoding {
    /// `16UC1`, millimetres (what RealSense and Kinect drivers publish).
    Millimetres16,
    /// `32FC1`, metres.
    Metres32,
}

const TIME: &str = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n";
const HEADER: &str = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n";
const SEPARATOR: &str =
    "================================================================================\n";
const IMAGE: &str = "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n\
                     uint8 is_bigendian\nuint32 step\nuint8[] data\n";
const CAMERA_INFO: &str = "std_msgs/Header header\nuint32 height\nuint32 width\n\
                           string distortion_model\nfloat64[] d\nfloat64[9] k\nfloat64[9] r\n\
                           float64[12] p\nuint32 binning_x\nuint32 binning_y\n\
                           RegionOfInterest roi\n";
const ROI: &str = "MSG: sensor_msgs/RegionOfInterest\nuint32 x_offset\nuint32 y_offset\n\
                   uint32 height\nuint32 width\nbool do_rectify\n";

/// A `ros2msg` schema: the message's definition, then its dependencies', as ROS 2 writes it.
fn definition(main: &str, deps: &[&str]) -> Vec<u8> {
    let mut s = main.to_string();
    for d in deps {
        s += SEPARATOR;
        s += d;
    }
    s.into_bytes()
}

/// Writes frames: colour as `rgb8` (or `mono8` without colour), depth, the right image of a
/// stereo pair as `mono8`, and the cameras' `CameraInfo` with each frame, as a camera driver
/// publishes them.
pub struct RecordingWriter<W: Write + Seek> {
    out: ::mcap::Writer<W>,
    name: String,
    rgb: u16,
    depth: Option<(u16, DepthEncoding)>,
    info: u16,
    /// The right image and camera info channels.
    right: Option<(u16, u16)>,
    camera: PinholeCamera,
    /// Stereo baseline times fx: the right camera info's `P[3]` is `-bf`.
    bf: f64,
    sequence: u32,
}

impl RecordingWriter<BufWriter<File>> {
    /// Create `path` with the `mcap` crate's default options (zstd-compressed chunks).
    pub fn create(
        path: &Path,
        topics: &McapTopics,
        depth: DepthEncoding,
        camera: &PinholeCamera,
    ) -> Result<Self, DatasetError> {
        let file = File::create(path).map_err(io_err(path))?;
        Self::new(
            BufWriter::new(file),
            ::mcap::WriteOptions::new(),
            &path.display().to_string(),
            topics,
            depth,
            camera,
        )
    }
}

impl<W: Write + Seek> RecordingWriter<W> {
    /// Write to `w` with `options`; `name` names it in errors. The camera info goes to
    /// [`McapTopics::camera_info_topic`], depth (when a topic is given) as `depth`, right
    /// images (when a topic is given) with their camera info beside them
    /// ([`McapTopics::right_camera_info_topic`]; the baseline from [`Self::with_stereo_bf`]).
    pub fn new(
        w: W,
        options: ::mcap::WriteOptions,
        name: &str,
        topics: &McapTopics,
        depth: DepthEncoding,
        camera: &PinholeCamera,
    ) -> Result<Self, DatasetError> {
        let err = |e: ::mcap::McapError| write_err(name, e);
        let mut out = options.create(w).map_err(err)?;
        let image = out
            .add_schema(
                "sensor_msgs/msg/Image",
                "ros2msg",
                &definition(IMAGE, &[HEADER, TIME]),
            )
            .map_err(err)?;
        let info = out
            .add_schema(
                "sensor_msgs/msg/CameraInfo",
                "ros2msg",
                &definition(CAMERA_INFO, &[HEADER, TIME, ROI]),
            )
            .map_err(err)?;
        let none = BTreeMap::new();
        let rgb = out
            .add_channel(image, &topics.rgb, "cdr", &none)
            .map_err(err)?;
        let depth = match &topics.depth {
            Some(t) => Some((out.add_channel(image, t, "cdr", &none).map_err(err)?, depth)),
            None => None,
        };
        let right = match (&topics.right, topics.right_camera_info_topic()) {
            (Some(t), Some(i)) => Some((
                out.add_channel(image, t, "cdr", &none).map_err(err)?,
                out.add_channel(info, &i, "cdr", &none).map_err(err)?,
            )),
            _ => None,
        };
        let info = out
            .add_channel(info, &topics.camera_info_topic(), "cdr", &none)
            .map_err(err)?;
        Ok(Self {
            out,
            name: name.to_string(),
            rgb,
            depth,
            info,
            right,
            camera: *camera,
            bf: 0.0,
            sequence: 0,
        })
    }

    /// The stereo pair's baseline times fx (pixel-metres), written as the right camera info's
    /// `P[3] = -bf`.
    pub fn with_stereo_bf(mut self, bf: f64) -> Self {
        self.bf = bf;
        self
    }

    /// Write one frame: colour, depth (when the frame and the writer have it), camera info.
    pub fn write_frame(&mut self, frame: &Frame) -> Result<(), DatasetError> {
        let t = frame.timestamp;
        let image = match &frame.rgb {
            Some(rgb) => {
                let px: Vec<u8> = rgb.data.iter().flatten().copied().collect();
                image_message(t, rgb.width, rgb.height, "rgb8", 3, &px)
            }
            None => {
                let g = &frame.gray;
                image_message(t, g.width, g.height, "mono8", 1, &g.data)
            }
        };
        self.put(self.rgb, t, &image)?;
        if let (Some((channel, encoding)), Some(d)) = (self.depth, &frame.depth) {
            let msg = match encoding {
                DepthEncoding::Millimetres16 => {
                    let px: Vec<u8> = d
                        .data
                        .iter()
                        .flat_map(|&m| millimetres(m).to_le_bytes())
                        .collect();
                    image_message(t, d.width, d.height, "16UC1", 2, &px)
                }
                DepthEncoding::Metres32 => {
                    let px: Vec<u8> = d.data.iter().flat_map(|m| m.to_le_bytes()).collect();
                    image_message(t, d.width, d.height, "32FC1", 4, &px)
                }
            };
            self.put(channel, t, &msg)?;
        }
        if let (Some((image, info)), Some(r)) = (self.right, &frame.right) {
            let msg = image_message(t, r.width, r.height, "mono8", 1, &r.data);
            self.put(image, t, &msg)?;
            let msg = camera_info_message(t, &self.camera, -self.bf);
            self.put(info, t, &msg)?;
        }
        let info = camera_info_message(t, &self.camera, 0.0);
        self.put(self.info, t, &info)
    }

    fn put(&mut self, channel_id: u16, stamp: f64, data: &[u8]) -> Result<(), DatasetError> {
        // Log time = the stamp, as a recording of a live camera has it within milliseconds.
        let ns = (stamp.max(0.0) * 1e9).round() as u64;
        self.sequence += 1;
        let header = ::mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: ns,
            publish_time: ns,
        };
        self.out
            .write_to_known_channel(&header, data)
            .map_err(|e| write_err(&self.name, e))
    }

    /// Write the summary and the footer.
    pub fn finish(mut self) -> Result<(), DatasetError> {
        self.out.finish().map_err(|e| write_err(&self.name, e))?;
        Ok(())
    }
}

fn write_err(name: &str, e: ::mcap::McapError) -> DatasetError {
    recording_err(Path::new(name), "writing", e.to_string())
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

/// A `sensor_msgs/msg/Image` with rows of `width * bpp` bytes.
fn image_message(
    stamp: f64,
    width: usize,
    height: usize,
    encoding: &str,
    bpp: usize,
    data: &[u8],
) -> Vec<u8> {
    let mut m = CdrWriter::new();
    m.header(stamp, "camera")
        .u32(height as u32)
        .u32(width as u32);
    m.string(encoding)
        .u8(0)
        .u32((width * bpp) as u32)
        .bytes(data);
    m.finish()
}

/// A `sensor_msgs/msg/CameraInfo` of `c` (plumb_bob), `P[3]` = `tx` (`-fx * baseline` for a
/// right camera).
fn camera_info_message(stamp: f64, c: &PinholeCamera, tx: f64) -> Vec<u8> {
    let d = &c.distortion;
    let k = [c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0];
    let r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let p = [
        c.fx, 0.0, c.cx, tx, 0.0, c.fy, c.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
    ];
    let mut m = CdrWriter::new();
    m.header(stamp, "camera").u32(c.height).u32(c.width);
    m.string("plumb_bob")
        .f64_seq(&[d.k1, d.k2, d.p1, d.p2, d.k3]);
    k.iter().chain(&r).chain(&p).for_each(|&v| {
        m.f64(v);
    });
    // binning x, y; roi x, y, height, width, do_rectify.
    m.u32(0).u32(0).u32(0).u32(0).u32(0).u32(0).u8(0);
    m.finish()
}
