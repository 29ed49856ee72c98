//! The ROS 2 messages the node publishes, written with the project's CDR writer (the one that
//! writes `run --bag` test recordings), and the names DDS knows them by. The camera messages it
//! reads are decoded by the recording reader's own code ([`stillpoint_datasets::mcap::ros`]).

use stillpoint_datasets::mcap::cdr::{CdrWriter, seconds_to_stamp};
use stillpoint_geometry::{Se3, se3_to_tum};

/// A ROS 2 message type: its package, its name, and the DDS type name rmw gives it
/// (`sensor_msgs::msg::dds_::Image_`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RosType {
    /// `sensor_msgs`.
    pub package: &'static str,
    /// `Image`.
    pub name: &'static str,
}

impl RosType {
    /// The DDS type name.
    pub fn dds_name(&self) -> String {
        format!("{}::msg::dds_::{}_", self.package, self.name)
    }
}

/// `sensor_msgs/Image`.
pub const IMAGE: RosType = RosType {
    package: "sensor_msgs",
    name: "Image",
};
/// `sensor_msgs/CompressedImage`.
pub const COMPRESSED_IMAGE: RosType = RosType {
    package: "sensor_msgs",
    name: "CompressedImage",
};
/// `sensor_msgs/CameraInfo`.
pub const CAMERA_INFO: RosType = RosType {
    package: "sensor_msgs",
    name: "CameraInfo",
};
/// `nav_msgs/Odometry`.
pub const ODOMETRY: RosType = RosType {
    package: "nav_msgs",
    name: "Odometry",
};
/// `nav_msgs/Path`.
pub const PATH: RosType = RosType {
    package: "nav_msgs",
    name: "Path",
};
/// `tf2_msgs/TFMessage`.
pub const TF_MESSAGE: RosType = RosType {
    package: "tf2_msgs",
    name: "TFMessage",
};
/// `sensor_msgs/PointCloud2`.
pub const POINT_CLOUD2: RosType = RosType {
    package: "sensor_msgs",
    name: "PointCloud2",
};
/// `std_msgs/String`.
pub const STRING: RosType = RosType {
    package: "std_msgs",
    name: "String",
};

/// A ROS time as a header carries it. Outputs repeat their frame's stamp exactly (an f64 of
/// seconds is 60 ns coarse at today's Unix times, and ROS tools match stamps exactly).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Stamp {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds, below 10^9.
    pub nanosec: u32,
}

impl Stamp {
    /// The nearest stamp to `seconds`.
    pub fn from_seconds(seconds: f64) -> Self {
        let (sec, nanosec) = seconds_to_stamp(seconds);
        Self { sec, nanosec }
    }
}

/// A `std_msgs/Header`.
fn header(w: &mut CdrWriter, stamp: Stamp, frame_id: &str) {
    w.i32(stamp.sec).u32(stamp.nanosec).string(frame_id);
}

/// A `geometry_msgs/Pose` (position, then orientation x, y, z, w) of a rigid transform.
fn pose(w: &mut CdrWriter, p: &Se3) {
    let (t, q) = se3_to_tum(p);
    for v in t.into_iter().chain(q) {
        w.f64(v);
    }
}

/// A `double[36]` covariance.
fn covariance(w: &mut CdrWriter, diagonal: f64) {
    for i in 0..36 {
        w.f64(if i % 7 == 0 { diagonal } else { 0.0 });
    }
}

/// `nav_msgs/Odometry`: the camera's pose in `frame_id`, no twist. Unknown covariances are
/// left at zero, as most odometry sources publish them (ROS has no "unknown" value but -1 on
/// the first element, which tools read as "ignore").
pub fn odometry(stamp: Stamp, frame_id: &str, child_frame_id: &str, pose_wc: &Se3) -> Vec<u8> {
    let mut w = CdrWriter::new();
    header(&mut w, stamp, frame_id);
    w.string(child_frame_id);
    pose(&mut w, pose_wc);
    covariance(&mut w, 0.0);
    for _ in 0..6 {
        w.f64(0.0);
    }
    covariance(&mut w, 0.0);
    w.finish()
}

/// One `geometry_msgs/TransformStamped`: `child` in `parent`.
#[derive(Clone, Debug)]
pub struct Transform<'a> {
    /// The parent frame.
    pub parent: &'a str,
    /// The child frame.
    pub child: &'a str,
    /// Child to parent.
    pub transform: Se3,
}

/// `tf2_msgs/TFMessage` of transforms at one stamp.
pub fn tf_message(stamp: Stamp, transforms: &[Transform]) -> Vec<u8> {
    let mut w = CdrWriter::new();
    w.u32(transforms.len() as u32);
    for t in transforms {
        header(&mut w, stamp, t.parent);
        w.string(t.child);
        pose(&mut w, &t.transform);
    }
    w.finish()
}

/// `nav_msgs/Path` of stamped poses in `frame_id`.
pub fn path(stamp: Stamp, frame_id: &str, poses: &[(Stamp, Se3)]) -> Vec<u8> {
    let mut w = CdrWriter::new();
    header(&mut w, stamp, frame_id);
    w.u32(poses.len() as u32);
    for (t, p) in poses {
        header(&mut w, *t, frame_id);
        pose(&mut w, p);
    }
    w.finish()
}

/// `sensor_msgs/PointCloud2` of x, y, z (float32) and rgb (a float32 holding 0x00RRGGBB, as
/// PCL and RViz read it), unordered (height 1).
pub fn point_cloud(stamp: Stamp, frame_id: &str, points: &[([f32; 3], [u8; 3])]) -> Vec<u8> {
    const FLOAT32: u8 = 7;
    let mut w = CdrWriter::new();
    header(&mut w, stamp, frame_id);
    w.u32(1).u32(points.len() as u32).u32(4);
    for (i, name) in ["x", "y", "z", "rgb"].iter().enumerate() {
        w.string(name).u32(4 * i as u32).u8(FLOAT32).u32(1);
    }
    let mut data = Vec::with_capacity(points.len() * 16);
    for (p, c) in points {
        for v in p {
            data.extend_from_slice(&v.to_le_bytes());
        }
        let rgb = u32::from(c[0]) << 16 | u32::from(c[1]) << 8 | u32::from(c[2]);
        data.extend_from_slice(&rgb.to_le_bytes());
    }
    w.u8(0)
        .u32(16)
        .u32(16 * points.len() as u32)
        .bytes(&data)
        .u8(1);
    w.finish()
}

/// `sensor_msgs/CompressedImage` (`format` `jpeg`).
pub fn compressed_image(stamp: Stamp, frame_id: &str, format: &str, data: &[u8]) -> Vec<u8> {
    let mut w = CdrWriter::new();
    header(&mut w, stamp, frame_id);
    w.string(format).bytes(data);
    w.finish()
}

/// `std_msgs/String`.
pub fn string(s: &str) -> Vec<u8> {
    let mut w = CdrWriter::new();
    w.string(s);
    w.finish()
}

/// The transforms of a `tf2_msgs/TFMessage`: (parent, child, child to parent), read by the
/// recording reader's CDR code.
pub fn decode_tf(bytes: &[u8]) -> Result<Vec<(String, String, Se3)>, String> {
    use stillpoint_datasets::mcap::cdr::{MessageReader, Wire};
    let e = |e: stillpoint_datasets::mcap::cdr::DecodeError| e.to_string();
    let mut r = MessageReader::new(bytes, Wire::Cdr).map_err(e)?;
    let n = r.u32("transforms").map_err(e)?;
    // Each transform is at least 60 bytes: a count beyond the message is a bad sample.
    if n as usize > bytes.len() / 60 {
        return Err(format!("{n} transforms in {} bytes", bytes.len()));
    }
    let mut out = Vec::with_capacity(n as usize);
    for _ in 0..n {
        let (_, parent) = r.header().map_err(e)?;
        let child = r.string("child_frame_id").map_err(e)?;
        let mut v = [0.0; 7];
        for x in &mut v {
            *x = r.f64("transform").map_err(e)?;
        }
        let pose = stillpoint_geometry::se3_from_tum([v[0], v[1], v[2]], [v[3], v[4], v[5], v[6]])
            .ok_or_else(|| {
                format!("{parent} -> {child}: a rotation that is not a unit quaternion")
            })?;
        out.push((parent, child, pose));
    }
    Ok(out)
}
