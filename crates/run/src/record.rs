//! `run --record FILE`: the run as an MCAP file that Foxglove opens, each message JSON with
//! Foxglove's own JSON schema embedded (message encoding `json`, schema encoding `jsonschema`).
//!
//! | topic                 | schema                      | when                                  |
//! |-----------------------|-----------------------------|---------------------------------------|
//! | `/camera/image`       | `foxglove.CompressedImage`  | each frame (JPEG or PNG, `[record]`)  |
//! | `/camera/calibration` | `foxglove.CameraCalibration`| each frame                            |
//! | `/camera/annotations` | `foxglove.ImageAnnotations` | each frame: keypoints and boxes       |
//! | `/tf`                 | `foxglove.FrameTransform`   | each tracked frame: `world` → `camera`|
//! | `/points/moving`      | `foxglove.PointCloud`       | each tracked frame: culled keypoints with depth, in `world`, red |
//! | `/map/points`         | `foxglove.PointCloud`       | after new keyframes, and at the end: the map, grey |
//! | `/map/keyframes`      | `foxglove.PosesInFrame`     | with the map points                   |
//! | `/camera/path`        | `foxglove.PosesInFrame`     | with the map points: tracking's poses so far; at the end the final trajectory |
//!
//! Keypoints are drawn as the overlay draws them ([`crate::overlay`]): matched green, kept
//! yellow, culled red; boxes red when moving, blue when static, orange when the box memory
//! carried them into a frame whose detections missed them. Log times are the frames' stamps.
//! Each frame's messages end a chunk, so a run killed midway leaves a file readable up to its
//! last frame (unindexed: Foxglove streams it, `mcap recover` rebuilds the index); a run that
//! stops or fails writes the summary and footer.

use std::collections::BTreeMap;
use std::io::{BufWriter, Seek, Write};
use std::path::{Path, PathBuf};

use crate::settings::{RecordImage, RecordSettings};
use serde_json::{Value, json};
use stillpoint_datasets::Frame;
use stillpoint_dynamic::TrackedObject;
use stillpoint_geometry::{BBox, PinholeCamera, Se3, Vec3};
use stillpoint_pipeline::FrameResult;

use crate::RunError;
use crate::overlay::{CULLED, KEPT, MATCHED, STATIC};

/// Colour of a box the memory carried into a frame (the detector missed it there).
pub const CARRIED: [u8; 3] = [255, 150, 0];
/// Colour of the map's points.
pub const MAP_POINT: [u8; 3] = [170, 170, 170];

/// The frame of the map (SLAM's world: the first camera's frame, z forward, y down).
pub const WORLD_FRAME: &str = "world";
/// The camera's optical frame (z forward, x right, y down, as Foxglove's images expect).
pub const CAMERA_FRAME: &str = "camera";

/// Topics and their schemas, as the file holds them.
pub const TOPICS: [(&str, &str); 8] = [
    ("/camera/image", "foxglove.CompressedImage"),
    ("/camera/calibration", "foxglove.CameraCalibration"),
    ("/camera/annotations", "foxglove.ImageAnnotations"),
    ("/tf", "foxglove.FrameTransform"),
    ("/points/moving", "foxglove.PointCloud"),
    ("/map/points", "foxglove.PointCloud"),
    ("/map/keyframes", "foxglove.PosesInFrame"),
    ("/camera/path", "foxglove.PosesInFrame"),
];

/// Foxglove's JSON schemas (from the foxglove-sdk repository, unchanged), by name.
pub const SCHEMAS: [(&str, &str); 6] = [
    (
        "foxglove.CompressedImage",
        include_str!("../schemas/foxglove/CompressedImage.json"),
    ),
    (
        "foxglove.CameraCalibration",
        include_str!("../schemas/foxglove/CameraCalibration.json"),
    ),
    (
        "foxglove.ImageAnnotations",
        include_str!("../schemas/foxglove/ImageAnnotations.json"),
    ),
    (
        "foxglove.FrameTransform",
        include_str!("../schemas/foxglove/FrameTransform.json"),
    ),
    (
        "foxglove.PointCloud",
        include_str!("../schemas/foxglove/PointCloud.json"),
    ),
    (
        "foxglove.PosesInFrame",
        include_str!("../schemas/foxglove/PosesInFrame.json"),
    ),
];

/// What one frame brings to the recording.
pub struct FrameRecord<'a> {
    /// The frame as read.
    pub frame: &'a Frame,
    /// What the pipeline made of it.
    pub result: &'a FrameResult,
    /// The camera (intrinsics for the calibration and for lifting culled keypoints).
    pub camera: &'a PinholeCamera,
}

/// What a recording holds when finished.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RecordReport {
    /// Messages per topic.
    pub messages: BTreeMap<String, usize>,
    /// Size of the file, bytes.
    pub bytes: u64,
}

/// An MCAP file being written as the run goes.
pub struct Recorder {
    path: PathBuf,
    writer: mcap::Writer<BufWriter<std::fs::File>>,
    /// Channel id and messages so far, by topic.
    channels: BTreeMap<&'static str, (u16, u32)>,
    settings: RecordSettings,
    /// Tracking's poses so far (stamp, camera-to-world).
    path_so_far: Vec<(f64, Se3)>,
    keyframes_seen: usize,
    last_stamp: f64,
}

impl Recorder {
    /// Create `path` (replacing it) with its schemas and channels.
    pub fn create(path: &Path, settings: &RecordSettings) -> Result<Self, RunError> {
        let file = std::fs::File::create(path).map_err(|source| RunError::Io {
            context: format!("creating {}", path.display()),
            source,
        })?;
        let mcap_err = |e: mcap::McapError| record_error(path, e);
        let mut writer = mcap::WriteOptions::new()
            .profile("")
            .library(concat!("stillpoint ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(file))
            .map_err(mcap_err)?;
        let mut schema_ids = BTreeMap::new();
        for (name, text) in SCHEMAS {
            let id = writer
                .add_schema(name, "jsonschema", text.as_bytes())
                .map_err(mcap_err)?;
            schema_ids.insert(name, id);
        }
        let mut channels = BTreeMap::new();
        for (topic, schema) in TOPICS {
            let id = writer
                .add_channel(schema_ids[schema], topic, "json", &BTreeMap::new())
                .map_err(mcap_err)?;
            channels.insert(topic, (id, 0));
        }
        Ok(Self {
            path: path.to_path_buf(),
            writer,
            channels,
            settings: settings.clone(),
            path_so_far: Vec::new(),
            keyframes_seen: 0,
            last_stamp: 0.0,
        })
    }

    /// One frame's messages: image, calibration, annotations, and when tracked its pose and
    /// its culled keypoints lifted into the world. Ends a chunk, so what is written so far is
    /// readable if the run dies.
    pub fn frame(&mut self, f: &FrameRecord) -> Result<(), RunError> {
        let stamp = f.frame.timestamp;
        self.last_stamp = stamp;
        if let Some(img) = self.image_message(f.frame)? {
            self.write("/camera/image", stamp, &img)?;
        }
        let (w, h) = (f.frame.gray.width, f.frame.gray.height);
        self.write(
            "/camera/calibration",
            stamp,
            &calibration_json(stamp, f.camera, w, h),
        )?;
        self.write(
            "/camera/annotations",
            stamp,
            &annotations_json(stamp, f.result),
        )?;
        if let Some(pose) = f.result.pose_wc {
            self.path_so_far.push((stamp, pose));
            self.write("/tf", stamp, &frame_transform_json(stamp, &pose))?;
            let lifted = f
                .result
                .depth(f.frame)
                .map(|d| lift_culled(f.result, d, f.camera, &pose))
                .unwrap_or_default();
            let points: Vec<([f32; 3], [u8; 3])> =
                lifted.into_iter().map(|p| (p, CULLED)).collect();
            self.write(
                "/points/moving",
                stamp,
                &point_cloud_json(stamp, WORLD_FRAME, &points),
            )?;
        }
        self.writer.flush().map_err(|e| record_error(&self.path, e))
    }

    /// After a frame that made a keyframe: the map's points, its keyframes and the path so far,
    /// every `[record] map_every_keyframes` keyframes.
    pub fn keyframe(&mut self, map: &stillpoint_slam::data::map::Map) -> Result<(), RunError> {
        self.keyframes_seen += 1;
        let every = self.settings.map_every_keyframes;
        if every == 0 || !self.keyframes_seen.is_multiple_of(every) {
            return Ok(());
        }
        self.write_map(map)?;
        let poses: Vec<Se3> = self.path_so_far.iter().map(|(_, p)| *p).collect();
        self.write(
            "/camera/path",
            self.last_stamp,
            &poses_json(self.last_stamp, &poses),
        )
    }

    fn write_map(&mut self, map: &stillpoint_slam::data::map::Map) -> Result<(), RunError> {
        let stamp = self.last_stamp;
        let points = map_cloud(map, MAP_POINT);
        self.write(
            "/map/points",
            stamp,
            &point_cloud_json(stamp, WORLD_FRAME, &points),
        )?;
        let keyframes: Vec<Se3> = map
            .keyframes
            .values()
            .filter(|k| !k.bad)
            .map(|k| k.pose_cw.inverse())
            .collect();
        self.write("/map/keyframes", stamp, &poses_json(stamp, &keyframes))
    }

    /// The end: the final map and trajectory (frames following their refined keyframes), then
    /// the summary and footer.
    pub fn finish(
        mut self,
        map: Option<&stillpoint_slam::data::map::Map>,
        trajectory: &stillpoint_trajectory::Trajectory,
    ) -> Result<RecordReport, RunError> {
        if let Some(map) = map {
            self.write_map(map)?;
        }
        let stamp = self.last_stamp;
        self.write("/camera/path", stamp, &poses_json(stamp, &trajectory.poses))?;
        self.writer
            .finish()
            .map_err(|e| record_error(&self.path, e))?;
        let messages = self
            .channels
            .iter()
            .map(|(t, (_, n))| (t.to_string(), *n as usize))
            .collect();
        // Dropping the writer flushes the file.
        let Self { path, writer, .. } = self;
        let mut file = writer.into_inner();
        let bytes = file
            .flush()
            .and_then(|_| file.stream_position())
            .map_err(|source| RunError::Io {
                context: format!("writing {}", path.display()),
                source,
            })?;
        Ok(RecordReport { messages, bytes })
    }

    fn image_message(&self, frame: &Frame) -> Result<Option<Value>, RunError> {
        let rgb;
        let img = match &frame.rgb {
            Some(rgb) => rgb,
            None => {
                rgb = stillpoint_image::gray_to_rgb(&frame.gray);
                &rgb
            }
        };
        let (format, data) = match self.settings.image {
            RecordImage::None => return Ok(None),
            RecordImage::Jpeg => (
                "jpeg",
                stillpoint_image::encode_jpeg(img, self.settings.jpeg_quality),
            ),
            RecordImage::Png => ("png", stillpoint_image::encode_png(img)),
        };
        let data = data.map_err(|e| RunError::Io {
            context: format!("recording frame {} in {}", frame.index, self.path.display()),
            source: std::io::Error::other(e.to_string()),
        })?;
        Ok(Some(json!({
            "timestamp": time_json(frame.timestamp),
            "frame_id": CAMERA_FRAME,
            "data": base64(&data),
            "format": format,
        })))
    }

    fn write(&mut self, topic: &'static str, stamp: f64, message: &Value) -> Result<(), RunError> {
        let Some((channel_id, sequence)) = self.channels.get_mut(topic) else {
            return Err(RunError::Refused(format!(
                "{}: no channel for {topic}",
                self.path.display()
            )));
        };
        let ns = stamp_ns(stamp);
        let header = mcap::records::MessageHeader {
            channel_id: *channel_id,
            sequence: *sequence,
            log_time: ns,
            publish_time: ns,
        };
        *sequence += 1;
        let bytes = serde_json::to_vec(message).map_err(|e| RunError::Io {
            context: format!("recording {topic} in {}", self.path.display()),
            source: std::io::Error::other(e),
        })?;
        self.writer
            .write_to_known_channel(&header, &bytes)
            .map_err(|e| record_error(&self.path, e))
    }
}

fn record_error(path: &Path, e: mcap::McapError) -> RunError {
    RunError::Io {
        context: format!("writing {}", path.display()),
        source: std::io::Error::other(e),
    }
}

/// The map's good points as a cloud of one colour (the recording's and the ROS 2 node's).
pub fn map_cloud(
    map: &stillpoint_slam::data::map::Map,
    colour: [u8; 3],
) -> Vec<([f32; 3], [u8; 3])> {
    map.points
        .values()
        .filter(|p| !p.bad)
        .map(|p| {
            let x = p.position;
            ([x.x as f32, x.y as f32, x.z as f32], colour)
        })
        .collect()
}

/// Seconds as MCAP nanoseconds, rounded to the microsecond: a Unix time in an f64 holds no
/// finer digits, and the datasets' text files give six decimals (negative stamps, which no
/// dataset has, become 0).
pub fn stamp_ns(t: f64) -> u64 {
    (t.max(0.0) * 1e6).round() as u64 * 1000
}

/// Seconds as Foxglove's `{sec, nsec}`.
pub fn time_json(t: f64) -> Value {
    let ns = stamp_ns(t);
    json!({"sec": ns / 1_000_000_000, "nsec": ns % 1_000_000_000})
}

fn colour_json(c: [u8; 3], alpha: f64) -> Value {
    let f = |v: u8| f64::from(v) / 255.0;
    json!({"r": f(c[0]), "g": f(c[1]), "b": f(c[2]), "a": alpha})
}

fn position_json(p: &Se3) -> Value {
    let t = p.translation.vector;
    json!({"x": t.x, "y": t.y, "z": t.z})
}

fn orientation_json(p: &Se3) -> Value {
    let q = p.rotation.quaternion();
    json!({"x": q.i, "y": q.j, "z": q.k, "w": q.w})
}

/// `foxglove.FrameTransform`: the camera (`camera`) in the map (`world`), from a camera-to-world
/// pose.
pub fn frame_transform_json(stamp: f64, pose_wc: &Se3) -> Value {
    json!({
        "timestamp": time_json(stamp),
        "parent_frame_id": WORLD_FRAME,
        "child_frame_id": CAMERA_FRAME,
        "translation": position_json(pose_wc),
        "rotation": orientation_json(pose_wc),
    })
}

/// `foxglove.PosesInFrame` in `world` from camera-to-world poses.
pub fn poses_json(stamp: f64, poses: &[Se3]) -> Value {
    let poses: Vec<Value> = poses
        .iter()
        .map(|p| json!({"position": position_json(p), "orientation": orientation_json(p)}))
        .collect();
    json!({"timestamp": time_json(stamp), "frame_id": WORLD_FRAME, "poses": poses})
}

/// `foxglove.CameraCalibration` of a pinhole camera with radial-tangential distortion
/// (`plumb_bob`) for `width` x `height` images.
pub fn calibration_json(stamp: f64, c: &PinholeCamera, width: usize, height: usize) -> Value {
    let d = &c.distortion;
    json!({
        "timestamp": time_json(stamp),
        "frame_id": CAMERA_FRAME,
        "width": width,
        "height": height,
        "distortion_model": "plumb_bob",
        "D": [d.k1, d.k2, d.p1, d.p2, d.k3],
        "K": [c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0],
        "R": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        "P": [c.fx, 0.0, c.cx, 0.0, 0.0, c.fy, c.cy, 0.0, 0.0, 0.0, 1.0, 0.0],
    })
}

/// `foxglove.PointCloud` of coloured points: x, y, z as float32 and red, green, blue, alpha as
/// uint8, 16 bytes a point, identity pose in `frame_id`.
pub fn point_cloud_json(stamp: f64, frame_id: &str, points: &[([f32; 3], [u8; 3])]) -> Value {
    const FLOAT32: u8 = 7;
    const UINT8: u8 = 1;
    let mut data = Vec::with_capacity(points.len() * 16);
    for (p, c) in points {
        for v in p {
            data.extend_from_slice(&v.to_le_bytes());
        }
        data.extend_from_slice(&[c[0], c[1], c[2], 255]);
    }
    let field =
        |name: &str, offset: u32, ty: u8| json!({"name": name, "offset": offset, "type": ty});
    json!({
        "timestamp": time_json(stamp),
        "frame_id": frame_id,
        "pose": {
            "position": {"x": 0.0, "y": 0.0, "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
        },
        "point_stride": 16,
        "fields": [
            field("x", 0, FLOAT32), field("y", 4, FLOAT32), field("z", 8, FLOAT32),
            field("red", 12, UINT8), field("green", 13, UINT8), field("blue", 14, UINT8),
            field("alpha", 15, UINT8),
        ],
        "data": base64(&data),
    })
}

/// The culled keypoints of a tracked frame with a depth measurement, in the world (metres).
pub fn lift_culled(
    r: &FrameResult,
    depth: &stillpoint_image::DepthMetres,
    camera: &PinholeCamera,
    pose_wc: &Se3,
) -> Vec<[f32; 3]> {
    r.keypoints
        .iter()
        .zip(&r.dynamic)
        .filter(|(_, d)| **d)
        .filter_map(|(k, _)| {
            let (u, v) = (k[0].round(), k[1].round());
            if u < 0.0 || v < 0.0 || u as usize >= depth.width || v as usize >= depth.height {
                return None;
            }
            let z = f64::from(depth.get(u as usize, v as usize));
            if !(z.is_finite() && z > 0.0) {
                return None;
            }
            let x = (f64::from(k[0]) - camera.cx) / camera.fx * z;
            let y = (f64::from(k[1]) - camera.cy) / camera.fy * z;
            let w = pose_wc.rotation * Vec3::new(x, y, z) + pose_wc.translation.vector;
            Some([w.x as f32, w.y as f32, w.z as f32])
        })
        .collect()
}

/// `foxglove.PointsAnnotation` type values.
const POINTS: u8 = 1;
const LINE_LOOP: u8 = 2;

/// `foxglove.ImageAnnotations` of a frame: keypoints matched green, kept yellow, culled red
/// (one points annotation each), and each object's box (a line loop) with its class and state
/// as text: moving red, static blue, carried by the memory orange.
pub fn annotations_json(stamp: f64, r: &FrameResult) -> Value {
    let (objects, carried) = (&r.objects.tracked, &r.objects.carried[..]);
    let time = time_json(stamp);
    let mut groups: [(Vec<Value>, [u8; 3]); 3] = [
        (Vec::new(), MATCHED),
        (Vec::new(), KEPT),
        (Vec::new(), CULLED),
    ];
    for (i, k) in r.keypoints.iter().enumerate() {
        let g = if r.dynamic.get(i).copied().unwrap_or(false) {
            2
        } else if r.matched.get(i).copied().unwrap_or(false) {
            0
        } else {
            1
        };
        groups[g].0.push(json!({"x": k[0], "y": k[1]}));
    }
    let mut points: Vec<Value> = groups
        .into_iter()
        .map(|(pts, c)| {
            json!({
                "timestamp": time, "type": POINTS, "points": pts,
                "outline_color": colour_json(c, 1.0), "outline_colors": [],
                "fill_color": colour_json(c, 1.0), "thickness": 3.0,
            })
        })
        .collect();
    let mut texts = Vec::new();
    for o in objects {
        let (colour, state) = box_state(o, carried);
        let b = &o.bbox;
        let corners = [(b.x1, b.y1), (b.x2, b.y1), (b.x2, b.y2), (b.x1, b.y2)]
            .map(|(x, y)| json!({"x": x, "y": y}));
        points.push(json!({
            "timestamp": time, "type": LINE_LOOP, "points": corners,
            "outline_color": colour_json(colour, 1.0), "outline_colors": [],
            "fill_color": colour_json(colour, 0.0), "thickness": 2.0,
        }));
        texts.push(json!({
            "timestamp": time,
            "position": {"x": b.x1, "y": (b.y1 - 2.0).max(0.0)},
            "text": format!("{} {state}", stillpoint_detect::classes::class_name(o.class_id)),
            "font_size": 12.0,
            "text_color": colour_json([255, 255, 255], 1.0),
            "background_color": colour_json(colour, 0.7),
        }));
    }
    json!({"timestamp": time, "circles": [], "points": points, "texts": texts})
}

/// An object's box colour and state word: carried (its box is one the memory carried into the
/// frame), else moving or static.
pub fn box_state(o: &TrackedObject, carried: &[BBox]) -> ([u8; 3], &'static str) {
    if carried.contains(&o.bbox) {
        (CARRIED, "carried")
    } else if o.moving {
        (CULLED, "moving")
    } else {
        (STATIC, "static")
    }
}

/// Standard base64 with padding (RFC 4648), as JSON-encoded Foxglove messages carry bytes.
fn base64(bytes: &[u8]) -> String {
    use base64::Engine as _;
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stamps_split_into_seconds_and_nanoseconds() {
        assert_eq!(time_json(1.5), json!({"sec": 1, "nsec": 500_000_000}));
        assert_eq!(stamp_ns(-1.0), 0);
        assert_eq!(stamp_ns(1305031102.175304), 1_305_031_102_175_304_000);
    }

    #[test]
    fn every_topic_has_an_embedded_schema_titled_with_its_name() {
        for (_, schema) in TOPICS {
            let (_, text) = SCHEMAS.iter().find(|(n, _)| *n == schema).unwrap();
            let v: Value = serde_json::from_str(text).unwrap();
            assert_eq!(v["title"], schema);
        }
    }

    #[test]
    fn culled_keypoints_with_depth_are_lifted_through_the_pose() {
        let camera = PinholeCamera::new(100.0, 100.0, 2.0, 2.0, 5, 5);
        let mut depth = stillpoint_image::DepthMetres::new(5, 5, 0.0);
        depth.set(3, 2, 2.0);
        depth.set(1, 1, 4.0);
        let r = FrameResult {
            keypoints: vec![[3.0, 2.0], [1.0, 1.0], [0.0, 0.0]],
            dynamic: vec![true, false, true],
            ..test_result()
        };
        let pose = Se3::translation(1.0, 0.0, 0.0);
        // Keypoint 1 is kept, keypoint 2 has no depth.
        assert_eq!(
            lift_culled(&r, &depth, &camera, &pose),
            vec![[1.02, 0.0, 2.0]]
        );
    }

    #[test]
    fn a_run_that_dies_leaves_its_frames_readable() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.mcap");
        let mut rec = Recorder::create(&path, &RecordSettings::default()).unwrap();
        let camera = PinholeCamera::new(50.0, 50.0, 8.0, 6.0, 16, 12);
        for i in 0..3 {
            let frame = Frame {
                index: i,
                timestamp: 10.0 + i as f64 / 30.0,
                gray: stillpoint_image::Gray8::new(16, 12, 100),
                rgb: None,
                depth: None,
                right: None,
            };
            let result = FrameResult {
                index: i,
                pose_wc: Some(Se3::identity()),
                keypoints: vec![[3.0, 4.0]],
                dynamic: vec![false],
                ..test_result()
            };
            rec.frame(&FrameRecord {
                frame: &frame,
                result: &result,
                camera: &camera,
            })
            .unwrap();
        }
        // No summary, no footer: as if the process were killed.
        std::mem::forget(rec);
        let bytes = std::fs::read(&path).unwrap();
        let read: Vec<_> = mcap::MessageStream::new(&bytes)
            .unwrap()
            .map_while(Result::ok)
            .map(|m| (m.channel.topic.clone(), m.log_time))
            .collect();
        // Image, calibration, annotations, pose and (empty) moving points per frame.
        assert_eq!(read.len(), 15, "{read:?}");
        assert_eq!(read[14], ("/points/moving".to_string(), 10_066_667_000));
    }

    fn test_result() -> FrameResult {
        FrameResult {
            index: 0,
            timestamp: 0.0,
            pose_wc: None,
            state: stillpoint_slam::TrackingState::Ok,
            keypoints: vec![],
            octaves: vec![],
            excluded: None,
            dynamic: vec![],
            no_new_points: vec![],
            dynamic_boxes: 0,
            objects: Default::default(),
            inliers: 0,
            matched: vec![],
            new_keyframe: false,
            relocalised: false,
            new_map: false,
            backfilled: vec![],
            stereo_depth: None,
            timings: Default::default(),
        }
    }
}
