//! ROS recordings in MCAP (what `ros2 bag record` writes by default since Iron) and ROS 1 bags
//! (walked by [`crate::rosbag`] into the same listing): a colour topic and an optional depth
//! topic (RGB-D) or right image topic (a rectified stereo pair) as a [`Sequence`], the camera
//! from a settings file or the recording's `CameraInfo` (for a pair, the baseline from the right
//! camera's projection matrix, `P[3] = -fx * baseline` as `stereo_image_proc` publishes it).
//!
//! Messages are ROS 2 CDR (or ROS 1, as `mcap convert` leaves a `.bag`): `sensor_msgs/Image`
//! (`rgb8`, `bgr8`, `rgba8`, `bgra8`, `mono8`; depth `16UC1` in millimetres, `32FC1` in metres,
//! REP 118), `sensor_msgs/CompressedImage` (PNG / JPEG; 16-bit PNG depth, also after
//! `compressed_depth_image_transport`'s header) and `sensor_msgs/CameraInfo`. Colour and depth
//! (or left and right) pair by `header.stamp` as TUM's `associate.py` pairs them (nearest within
//! 0.02 s).
//!
//! Opening reads the file once (decompressing its chunks) to list where each message is;
//! [`Sequence::frame`] then reads and decodes one frame's messages.

pub mod cdr;
pub mod file;
pub mod info;
pub mod ros;
pub mod write;

use crate::error::{DatasetError, layout_err, recording_err};
use crate::lists::associate_nearest;
use crate::sequence::Sequence;
use crate::tum::TUM_ASSOCIATION_MAX_DIFF;
use crate::{Frame, Sensor, Settings};
use cdr::Wire;
use file::{MessageRef, MessageSource, Scan};
use ros::{CameraInfoMsg, ImageMsg, MessageType};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use stillpoint_image::rgb_to_gray;

pub use info::{RecordingInfo, TopicInfo, inspect};
pub use write::{DepthEncoding, RecordingWriter};

/// The topics a sequence is read from.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct McapTopics {
    /// Colour (or mono) images, `sensor_msgs/Image` or `CompressedImage`.
    pub rgb: String,
    /// Depth images registered to the colour ones; none: monocular (or stereo with `right`).
    pub depth: Option<String>,
    /// The right images of a rectified stereo pair whose left images are `rgb` (not with
    /// `depth`); its `CameraInfo` is `camera_info` beside it.
    pub right: Option<String>,
    /// `sensor_msgs/CameraInfo` of the colour camera; by default `camera_info` beside the
    /// colour topic (`/camera/color/image_raw` -> `/camera/color/camera_info`).
    pub camera_info: Option<String>,
}

impl McapTopics {
    /// The camera info topic: the one given, or `camera_info` in the colour topic's namespace.
    pub fn camera_info_topic(&self) -> String {
        self.camera_info
            .clone()
            .unwrap_or_else(|| info_beside(&self.rgb))
    }

    /// The right camera's info topic: `camera_info` in the right topic's namespace
    /// (`/stereo/right/image_rect` -> `/stereo/right/camera_info`).
    pub fn right_camera_info_topic(&self) -> Option<String> {
        self.right.as_deref().map(info_beside)
    }
}

/// `camera_info` in `topic`'s namespace.
fn info_beside(topic: &str) -> String {
    match topic.rsplit_once('/') {
        Some((ns, _)) => format!("{ns}/camera_info"),
        None => "camera_info".into(),
    }
}

/// Open a recording as a sequence; `settings` (ORB-SLAM YAML or our TOML) gives the camera,
/// else the recording's `CameraInfo` does. Like [`crate::open`], images of another size than
/// the camera are an error now rather than a skipped frame each.
pub fn open(
    path: &Path,
    topics: &McapTopics,
    settings: Option<&Path>,
) -> Result<Box<dyn Sequence>, DatasetError> {
    let settings = settings.map(crate::read_settings).transpose()?;
    let seq = McapSequence::open(path, topics, settings)?;
    if let Err(e @ DatasetError::SizeMismatch { .. }) = seq.frame(0) {
        return Err(e);
    }
    Ok(Box::new(seq))
}

/// A topic of the recording and how its messages read.
#[derive(Clone, Debug)]
struct Topic {
    name: String,
    ty: MessageType,
    wire: Wire,
    /// Its messages, by stamp.
    messages: Vec<MessageRef>,
}

/// A colour topic of an MCAP recording, with a depth or a right image topic.
pub struct McapSequence {
    path: PathBuf,
    settings: Settings,
    source: MessageSource,
    rgb: Topic,
    depth: Option<Topic>,
    right: Option<Topic>,
    /// Per frame: stamp, index of its colour message, of its depth (or right) message.
    frames: Vec<(f64, usize, Option<usize>)>,
}

impl McapSequence {
    /// Open `path` (an `.mcap`, or a `ros2 bag` folder holding one). Settings: `settings` if
    /// given, else the camera of the first `CameraInfo` ([`McapTopics::camera_info_topic`])
    /// with ORB-SLAM's TUM defaults and the frame rate of the colour stamps. The depth factor
    /// is the depth encoding's (REP 118), whatever the settings say. With a right topic the
    /// pair is taken as rectified: the camera is the left `CameraInfo`'s `P` and `bf` is
    /// `-(P_right[3] - P_left[3])`.
    pub fn open(
        path: &Path,
        topics: &McapTopics,
        settings: Option<Settings>,
    ) -> Result<Self, DatasetError> {
        let path = recording_file(path)?;
        if let (Some(d), Some(r)) = (&topics.depth, &topics.right) {
            return Err(recording_err(
                &path,
                format!("topics {d} and {r}"),
                "give a depth topic or a right image topic, not both",
            ));
        }
        let info_topic = topics.camera_info_topic();
        let right_info_topic = topics.right_camera_info_topic();
        let mut wanted = vec![topics.rgb.clone(), info_topic.clone()];
        wanted.extend(topics.depth.clone());
        wanted.extend(topics.right.clone());
        wanted.extend(right_info_topic.clone());
        let mut scan = file::scan(&path, &|c| wanted.contains(&c.topic))?;
        let by_channel = messages_by_channel(&mut scan);
        let rgb = image_topic(&path, &scan, &by_channel, &topics.rgb, "--rgb-topic")?;
        let depth = topics
            .depth
            .as_deref()
            .map(|t| image_topic(&path, &scan, &by_channel, t, "--depth-topic"))
            .transpose()?;
        let right = topics
            .right
            .as_deref()
            .map(|t| image_topic(&path, &scan, &by_channel, t, "--right-topic"))
            .transpose()?;
        let mut settings = match (settings, &right_info_topic) {
            (Some(s), _) => s,
            (None, None) => {
                settings_from_camera_info(&path, &scan, &by_channel, &info_topic, &rgb, false)?
            }
            (None, Some(right_info)) => {
                let mut s =
                    settings_from_camera_info(&path, &scan, &by_channel, &info_topic, &rgb, true)?;
                s.bf = Some(stereo_bf(
                    &path,
                    &scan,
                    &by_channel,
                    &info_topic,
                    right_info,
                    &s,
                )?);
                s
            }
        };
        settings.sensor = match (&depth, &right) {
            _ if settings.sensor == Sensor::Mono => Sensor::Mono,
            (Some(_), _) => Sensor::Rgbd,
            (_, Some(r)) => {
                if settings.bf.is_none_or(|bf| !(bf.is_finite() && bf > 0.0)) {
                    return Err(recording_err(
                        &path,
                        format!("--right-topic {}", r.name),
                        "the settings give no stereo baseline (Camera.bf, or bf in TOML)",
                    ));
                }
                Sensor::Stereo
            }
            (None, None) => Sensor::Mono,
        };
        let channels: Vec<u16> = [&rgb]
            .into_iter()
            .chain(depth.as_ref())
            .chain(right.as_ref())
            .flat_map(|t| t.messages.iter().map(|m| m.channel))
            .collect::<std::collections::BTreeSet<_>>()
            .into_iter()
            .collect();
        let mut seq = Self {
            source: MessageSource::new(&path, channels),
            frames: pair_frames(&path, &rgb, depth.as_ref().or(right.as_ref()))?,
            path,
            settings,
            rgb,
            depth,
            right,
        };
        seq.check_first_messages()?;
        Ok(seq)
    }

    /// Decode the first colour and depth (or right) messages: an encoding we cannot read is an
    /// error now, and the depth encoding sets the depth factor.
    fn check_first_messages(&mut self) -> Result<(), DatasetError> {
        let (_, rgb_i, depth_i) = self.frames[0];
        let bytes = self.read(&self.rgb, rgb_i)?;
        let msg = self.decode(&self.rgb, rgb_i, &bytes)?;
        msg.to_rgb()
            .map_err(|e| self.message_err(&self.rgb, rgb_i, e))?;
        if let (Some(right), Some(j)) = (&self.right, depth_i) {
            let bytes = self.read(right, j)?;
            let msg = self.decode(right, j, &bytes)?;
            msg.to_rgb().map_err(|e| self.message_err(right, j, e))?;
            return Ok(());
        }
        let (Some(depth), Some(j)) = (&self.depth, depth_i) else {
            return Ok(());
        };
        let bytes = self.read(depth, j)?;
        let msg = self.decode(depth, j, &bytes)?;
        let (_, factor) = msg.to_depth().map_err(|e| self.message_err(depth, j, e))?;
        if self.settings.depth_factor != factor {
            tracing::info!(
                "{}: depth factor {factor} for {} depth (REP 118), not the settings' {}",
                self.path.display(),
                msg.encoding,
                self.settings.depth_factor
            );
            self.settings.depth_factor = factor;
        }
        Ok(())
    }

    fn read(&self, topic: &Topic, i: usize) -> Result<Vec<u8>, DatasetError> {
        let m = &topic.messages[i];
        self.source.read(m.at).map_err(|e| match e {
            DatasetError::Recording { path, at, msg } => DatasetError::Recording {
                path,
                at: format!("{} message {i}, {at}", topic.name),
                msg,
            },
            e => e,
        })
    }

    fn decode<'b>(
        &self,
        topic: &Topic,
        i: usize,
        bytes: &'b [u8],
    ) -> Result<ImageMsg<'b>, DatasetError> {
        ImageMsg::decode(bytes, topic.wire, topic.ty)
            .map_err(|e| self.message_err(topic, i, e.to_string()))
    }

    fn message_err(&self, topic: &Topic, i: usize, msg: String) -> DatasetError {
        recording_err(&self.path, message_at(topic, i), msg)
    }

    /// What a size error names: the file and the message.
    fn message_name(&self, topic: &Topic, i: usize) -> String {
        format!("{}: {} message {i}", self.path.display(), topic.name)
    }
}

/// "topic message i (byte b)".
fn message_at(topic: &Topic, i: usize) -> String {
    format!(
        "{} message {i} (byte {})",
        topic.name,
        topic.messages[i].at.byte()
    )
}

impl Sequence for McapSequence {
    fn settings(&self) -> &Settings {
        &self.settings
    }
    fn len(&self) -> usize {
        self.frames.len()
    }
    fn frame(&self, i: usize) -> Result<Frame, DatasetError> {
        crate::sequence::check_index(i, self.frames.len())?;
        let (stamp, rgb_i, pair_i) = self.frames[i];
        let depth_i = pair_i.filter(|_| self.depth.is_some());
        let bytes = self.read(&self.rgb, rgb_i)?;
        let rgb = self
            .decode(&self.rgb, rgb_i, &bytes)?
            .to_rgb()
            .map_err(|e| self.message_err(&self.rgb, rgb_i, e))?;
        self.check_size(&self.rgb, rgb_i, rgb.width, rgb.height)?;
        let depth = match (&self.depth, depth_i) {
            (Some(topic), Some(j)) => {
                let bytes = self.read(topic, j)?;
                let (d, _) = self
                    .decode(topic, j, &bytes)?
                    .to_depth()
                    .map_err(|e| self.message_err(topic, j, e))?;
                if (d.width, d.height) != (rgb.width, rgb.height) {
                    return Err(self.message_err(
                        topic,
                        j,
                        format!(
                            "depth is {}x{} but colour is {}x{}: give depth registered to the colour image (e.g. /camera/aligned_depth_to_color/image_raw)",
                            d.width, d.height, rgb.width, rgb.height
                        ),
                    ));
                }
                Some(d)
            }
            _ => None,
        };
        let right = match (&self.right, pair_i) {
            (Some(topic), Some(j)) if self.settings.sensor == Sensor::Stereo => {
                let bytes = self.read(topic, j)?;
                let r = self
                    .decode(topic, j, &bytes)?
                    .to_rgb()
                    .map_err(|e| self.message_err(topic, j, e))?;
                self.check_size(topic, j, r.width, r.height)?;
                Some(rgb_to_gray(&r))
            }
            _ => None,
        };
        Ok(Frame {
            index: i,
            timestamp: stamp,
            gray: rgb_to_gray(&rgb),
            rgb: Some(rgb),
            depth,
            right,
        })
    }
    fn ground_truth(&self) -> Option<PathBuf> {
        None
    }
    fn boxes(&self) -> Option<PathBuf> {
        None
    }
    fn name(&self) -> String {
        self.path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| self.path.display().to_string())
    }
    fn timestamp(&self, i: usize) -> Option<f64> {
        self.frames.get(i).map(|f| f.0)
    }
}

impl McapSequence {
    fn check_size(&self, topic: &Topic, i: usize, w: usize, h: usize) -> Result<(), DatasetError> {
        let c = &self.settings.camera;
        if (w, h) == (c.width as usize, c.height as usize) {
            return Ok(());
        }
        Err(DatasetError::SizeMismatch {
            path: self.message_name(topic, i),
            width: w,
            height: h,
            expected_width: c.width,
            expected_height: c.height,
        })
    }
}

/// The `.mcap` to read: `path`, or the one `.mcap` in a `ros2 bag` folder.
fn recording_file(path: &Path) -> Result<PathBuf, DatasetError> {
    if !path.is_dir() {
        return Ok(path.to_path_buf());
    }
    let mut found: Vec<PathBuf> = std::fs::read_dir(path)
        .map_err(crate::error::io_err(path))?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "mcap" || e == "db3"))
        .collect();
    found.sort();
    match found.as_slice() {
        [one] if one.extension().is_some_and(|e| e == "mcap") => Ok(one.clone()),
        [] => Err(layout_err(path, "no .mcap file in this folder")),
        [one] => Err(layout_err(
            one,
            "a SQLite (.db3) recording; convert it: `ros2 bag convert` to the mcap storage",
        )),
        many => Err(layout_err(
            path,
            format!(
                "{} recording files ({}): give one of them",
                many.len(),
                many.iter()
                    .filter_map(|p| p.file_name())
                    .map(|n| n.to_string_lossy())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )),
    }
}

/// The listed messages of each channel, by stamp (a stable sort: equal stamps keep file order).
fn messages_by_channel(scan: &mut Scan) -> BTreeMap<u16, Vec<MessageRef>> {
    let mut out: BTreeMap<u16, Vec<MessageRef>> = BTreeMap::new();
    for m in std::mem::take(&mut scan.messages) {
        out.entry(m.channel).or_default().push(m);
    }
    for v in out.values_mut() {
        v.sort_by(|a, b| a.stamp.total_cmp(&b.stamp));
    }
    out
}

/// The messages of `topic` (all its channels), with their type and wire format.
fn topic_messages(
    path: &Path,
    scan: &Scan,
    by_channel: &BTreeMap<u16, Vec<MessageRef>>,
    topic: &str,
    flag: &str,
) -> Result<(MessageType, Wire, Vec<MessageRef>), DatasetError> {
    let ids = scan.channels_of(topic);
    let Some(first) = ids.first().map(|id| &scan.channels[id]) else {
        return Err(recording_err(
            path,
            format!("{flag} {topic}"),
            format!("no such topic; {}", scan.topic_list()),
        ));
    };
    let at = format!("topic {topic}");
    let Some(wire) = first.wire() else {
        return Err(recording_err(
            path,
            at,
            format!(
                "message encoding {:?} is not supported (cdr for ROS 2, ros1)",
                first.message_encoding
            ),
        ));
    };
    let Some(ty) = first.message_type() else {
        return Err(recording_err(
            path,
            at,
            format!(
                "type {:?} is not a camera message (sensor_msgs Image, CompressedImage, CameraInfo)",
                first.schema_name
            ),
        ));
    };
    let mut messages: Vec<MessageRef> = ids
        .iter()
        .flat_map(|id| by_channel.get(id).into_iter().flatten().copied())
        .collect();
    messages.sort_by(|a, b| a.stamp.total_cmp(&b.stamp));
    if messages.is_empty() {
        return Err(recording_err(path, at, "no messages"));
    }
    Ok((ty, wire, messages))
}

/// An image topic.
fn image_topic(
    path: &Path,
    scan: &Scan,
    by_channel: &BTreeMap<u16, Vec<MessageRef>>,
    topic: &str,
    flag: &str,
) -> Result<Topic, DatasetError> {
    let (ty, wire, messages) = topic_messages(path, scan, by_channel, topic, flag)?;
    if !ty.is_image() {
        return Err(recording_err(
            path,
            format!("topic {topic}"),
            format!("{ty:?} messages, not images ({flag})"),
        ));
    }
    Ok(Topic {
        name: topic.to_string(),
        ty,
        wire,
        messages,
    })
}

/// Settings from the first `CameraInfo` on `info_topic`: its camera with ORB-SLAM's TUM
/// defaults, and the colour stamps' frame rate.
fn settings_from_camera_info(
    path: &Path,
    scan: &Scan,
    by_channel: &BTreeMap<u16, Vec<MessageRef>>,
    info_topic: &str,
    rgb: &Topic,
    stereo: bool,
) -> Result<Settings, DatasetError> {
    let (info, at) = first_camera_info(path, scan, by_channel, info_topic)?;
    // An `image_rect*` topic is already undistorted: its camera is P's, as image_geometry has it;
    // so are both images of a stereo pair (matched along rows).
    let rectified = stereo
        || rgb
            .name
            .rsplit('/')
            .next()
            .is_some_and(|n| n.contains("rect"));
    let camera = info
        .camera(rectified)
        .map_err(|e| recording_err(path, at, format!("{e}; pass --settings")))?;
    let sensor = if stereo { Sensor::Stereo } else { Sensor::Rgbd };
    let mut settings = Settings::with_camera(sensor, camera);
    if let Some(fps) = frame_rate(&rgb.messages) {
        settings.fps = fps;
    }
    tracing::info!(
        "{}: camera from {info_topic}: fx {:.2} fy {:.2} cx {:.2} cy {:.2} {}x{}{}, {} fps",
        path.display(),
        camera.fx,
        camera.fy,
        camera.cx,
        camera.cy,
        camera.width,
        camera.height,
        if rectified {
            " (rectified: P, no distortion)"
        } else {
            ""
        },
        settings.fps
    );
    Ok(settings)
}

/// The first `CameraInfo` on `info_topic`, and where it is ("topic message 0 (byte b)"). An
/// error says to pass `--settings`.
fn first_camera_info(
    path: &Path,
    scan: &Scan,
    by_channel: &BTreeMap<u16, Vec<MessageRef>>,
    info_topic: &str,
) -> Result<(CameraInfoMsg, String), DatasetError> {
    let no_camera = |why: String| {
        recording_err(
            path,
            format!("topic {info_topic}"),
            format!("{why}; pass --settings (a camera file) or --camera-info-topic"),
        )
    };
    let (ty, wire, messages) = topic_messages(path, scan, by_channel, info_topic, "camera info")
        .map_err(|e| match e {
            DatasetError::Recording { msg, .. } => no_camera(msg),
            e => e,
        })?;
    if ty != MessageType::CameraInfo {
        return Err(no_camera(format!("{ty:?} messages, not CameraInfo")));
    }
    let source = MessageSource::new(path, vec![messages[0].channel]);
    let bytes = source.read(messages[0].at)?;
    let at = format!("{info_topic} message 0 (byte {})", messages[0].at.byte());
    let info = CameraInfoMsg::decode(&bytes, wire)
        .map_err(|e| recording_err(path, at.clone(), e.to_string()))?;
    Ok((info, at))
}

/// A rectified pair's `bf` (pixel-metres) from the right camera's projection matrix:
/// `P_right[3] = -fx * baseline` (relative to the left's `P[3]`, 0 as `stereo_image_proc` has
/// it). The right camera must have the left's size and focal length.
fn stereo_bf(
    path: &Path,
    scan: &Scan,
    by_channel: &BTreeMap<u16, Vec<MessageRef>>,
    left_info_topic: &str,
    right_info_topic: &str,
    left: &Settings,
) -> Result<f64, DatasetError> {
    let no_baseline = |at: String, why: String| {
        recording_err(
            path,
            at,
            format!("{why}; pass --settings (a stereo camera file with Camera.bf)"),
        )
    };
    let (l, _) = first_camera_info(path, scan, by_channel, left_info_topic)?;
    let (r, at) =
        first_camera_info(path, scan, by_channel, right_info_topic).map_err(|e| match e {
            DatasetError::Recording { at, msg, .. } => no_baseline(
                at,
                msg.replace(
                    "; pass --settings (a camera file) or --camera-info-topic",
                    "",
                ),
            ),
            e => e,
        })?;
    let c = &left.camera;
    if (r.width, r.height) != (c.width, c.height) || (r.p[0] - c.fx).abs() > 1e-6 * c.fx {
        return Err(no_baseline(
            at,
            format!(
                "the right camera (P fx {}, {}x{}) is not the left one's rectified twin (fx {}, {}x{})",
                r.p[0], r.width, r.height, c.fx, c.width, c.height
            ),
        ));
    }
    let bf = -(r.p[3] - l.p[3]);
    if !(bf.is_finite() && bf > 0.0) {
        return Err(no_baseline(
            at,
            format!(
                "P[3] is {} (left {}): no baseline (a rectified right camera's P[3] is -fx * baseline)",
                r.p[3], l.p[3]
            ),
        ));
    }
    tracing::info!(
        "{}: stereo baseline {:.4} m (bf {bf:.3}) from {right_info_topic}",
        path.display(),
        bf / c.fx
    );
    Ok(bf)
}

/// Frames per second from the median interval of the stamps, rounded (`None` with fewer than
/// two frames or equal stamps).
fn frame_rate(messages: &[MessageRef]) -> Option<f64> {
    let mut dt: Vec<f64> = messages
        .windows(2)
        .map(|w| w[1].stamp - w[0].stamp)
        .filter(|d| *d > 0.0)
        .collect();
    if dt.is_empty() {
        return None;
    }
    dt.sort_by(f64::total_cmp);
    let fps = (1.0 / dt[dt.len() / 2]).round();
    (fps >= 1.0).then_some(fps)
}

/// Frames: every colour message, or with depth (or right images) the colour messages paired
/// with a depth (right) one (TUM's rule: nearest within 0.02 s, one-to-one).
fn pair_frames(
    path: &Path,
    rgb: &Topic,
    depth: Option<&Topic>,
) -> Result<Vec<(f64, usize, Option<usize>)>, DatasetError> {
    let stamps = |t: &Topic| t.messages.iter().map(|m| m.stamp).collect::<Vec<f64>>();
    let Some(depth) = depth else {
        return Ok(stamps(rgb)
            .into_iter()
            .enumerate()
            .map(|(i, t)| (t, i, None))
            .collect());
    };
    let (a, b) = (stamps(rgb), stamps(depth));
    let pairs = associate_nearest(&a, &b, TUM_ASSOCIATION_MAX_DIFF);
    if pairs.is_empty() {
        return Err(recording_err(
            path,
            format!("topics {} and {}", rgb.name, depth.name),
            format!(
                "no message of {} has one of {} within {TUM_ASSOCIATION_MAX_DIFF} s (stamps {:.3}..{:.3} and {:.3}..{:.3})",
                rgb.name,
                depth.name,
                a[0],
                a[a.len() - 1],
                b[0],
                b[b.len() - 1]
            ),
        ));
    }
    if pairs.len() < a.len() {
        tracing::info!(
            "{}: {} of {} messages of {} have one of {} within {TUM_ASSOCIATION_MAX_DIFF} s",
            path.display(),
            pairs.len(),
            a.len(),
            rgb.name,
            depth.name
        );
    }
    Ok(pairs.into_iter().map(|(i, j)| (a[i], i, Some(j))).collect())
}
