//! What the node publishes, as a sink of the run: each tracked frame's odometry, `/tf` and
//! state, the annotated image; the path and the map's cloud at a fixed period and at the end.

use std::collections::HashMap;
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};

use rustdds::no_key::DataWriter;
use rustdds::{
    DataWriterStatus, DomainParticipant, Publisher, QosPolicies, StatusEvented, TopicKind,
};
use stillpoint_geometry::Se3;
use stillpoint_run::{Ended, RunError, Sink, Tracked};
use stillpoint_slam::TrackingState;
use tracing::warn;

use crate::camera::Arrival;
use crate::msg::{self, RosType, Stamp, Transform};
use crate::tf::TfListener;
use crate::wire::{CdrMessage, RawCdr};
use crate::{Ros2Error, dds_topic_name, qos};

type Writer = DataWriter<CdrMessage, RawCdr>;

/// A publication: its ROS name and writer.
struct Output {
    topic: String,
    writer: Writer,
    failed: bool,
    /// Readers matched now, from the writer's status events.
    readers: i32,
}

impl Output {
    fn new(
        participant: &DomainParticipant,
        publisher: &Publisher,
        topic: &str,
        ty: RosType,
        qos: &QosPolicies,
    ) -> Result<Self, Ros2Error> {
        let dds = participant
            .create_topic(dds_topic_name(topic)?, ty.dds_name(), qos, TopicKind::NoKey)
            .map_err(|e| Ros2Error::Dds(format!("topic {topic}: {e}")))?;
        let writer = publisher
            .create_datawriter_no_key::<CdrMessage, RawCdr>(&dds, Some(qos.clone()))
            .map_err(|e| Ros2Error::Dds(format!("publishing {topic}: {e}")))?;
        Ok(Self {
            topic: topic.to_string(),
            writer,
            failed: false,
            readers: 0,
        })
    }

    /// Whether a reader listens: what is costly to make (the annotated image: a drawing and a
    /// JPEG on the tracking thread) is made only then.
    fn listened(&mut self) -> bool {
        while let Some(status) = self.writer.try_recv_status() {
            if let DataWriterStatus::PublicationMatched { current, .. } = status {
                self.readers = current.count();
            }
        }
        self.readers > 0
    }

    /// Send; a failure is logged once (a slow reliable reader must not stop tracking).
    fn send(&mut self, bytes: Vec<u8>) {
        if let Err(e) = self.writer.write(CdrMessage(bytes), None) {
            if !self.failed {
                warn!(
                    "{}: not sent: {e:?} (later failures are not logged)",
                    self.topic
                );
            }
            self.failed = true;
        }
    }
}

/// The frames the outputs name, from the settings.
#[derive(Clone, Debug)]
pub struct Frames {
    /// The map's frame.
    pub map: String,
    /// The robot's odometry frame: when set, `map` -> `odom` goes on `/tf`; empty: `map` ->
    /// the camera.
    pub odom: String,
    /// The camera's frame; empty: the images' own.
    pub camera: String,
}

/// Latency from an image's arrival to its pose being sent, per frame, milliseconds.
#[derive(Clone, Debug, Default)]
pub struct Latencies {
    /// One per processed frame.
    pub ms: Vec<f64>,
    /// Frames paired from the topics (processed or dropped).
    pub received: usize,
}

/// The node's publications.
pub struct RosOutputs {
    odom: Output,
    tf: Output,
    state: Output,
    path: Output,
    cloud: Output,
    annotated: Option<(Output, u8)>,
    frames: Frames,
    arrivals: Receiver<Arrival>,
    /// The exact stamps of the frames, by their seconds' bits.
    stamps: HashMap<u64, Stamp>,
    path_so_far: Vec<(Stamp, Se3)>,
    cloud_period: Option<Duration>,
    last_cloud: Option<Instant>,
    camera_frame: String,
    listener: TfListener,
    /// What was said once about `/tf`.
    said: Option<String>,
    /// What was measured.
    pub latencies: Latencies,
}

impl RosOutputs {
    /// Create the publications under `prefix`.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        participant: &DomainParticipant,
        prefix: &str,
        frames: Frames,
        cloud_period_s: f64,
        annotated_jpeg_quality: Option<u8>,
        arrivals: Receiver<Arrival>,
    ) -> Result<Self, Ros2Error> {
        let dds = |e: rustdds::dds::CreateError| Ros2Error::Dds(format!("publisher: {e}"));
        let reliable = qos(true, 10, false);
        let latched = qos(true, 1, true);
        let tf_qos = qos(true, 100, false);
        let publisher = participant.create_publisher(&reliable).map_err(dds)?;
        let subscriber = participant.create_subscriber(&tf_qos).map_err(dds)?;
        let listener = TfListener::new(participant, &subscriber)?;
        let at = |name: &str| format!("{}/{name}", prefix.trim_end_matches('/'));
        let out = |topic: &str, ty, qos: &QosPolicies| {
            Output::new(participant, &publisher, topic, ty, qos)
        };
        Ok(Self {
            odom: out(&at("odom"), msg::ODOMETRY, &reliable)?,
            tf: out("/tf", msg::TF_MESSAGE, &tf_qos)?,
            state: out(&at("state"), msg::STRING, &reliable)?,
            path: out(&at("path"), msg::PATH, &latched)?,
            cloud: out(&at("map_cloud"), msg::POINT_CLOUD2, &latched)?,
            annotated: match annotated_jpeg_quality {
                Some(q) => Some((
                    out(
                        &at("image_annotated/compressed"),
                        msg::COMPRESSED_IMAGE,
                        &reliable,
                    )?,
                    q,
                )),
                None => None,
            },
            frames,
            arrivals,
            stamps: HashMap::new(),
            path_so_far: Vec::new(),
            cloud_period: (cloud_period_s > 0.0).then(|| Duration::from_secs_f64(cloud_period_s)),
            last_cloud: None,
            camera_frame: String::new(),
            listener,
            said: None,
            latencies: Latencies::default(),
        })
    }

    /// The arrival of the frame stamped `stamp` (and the camera frame of the images).
    fn arrival(&mut self, stamp: f64) -> Option<Instant> {
        while let Ok(a) = self.arrivals.try_recv() {
            self.latencies.received += 1;
            if self.frames.camera.is_empty() && !a.frame_id.is_empty() {
                self.camera_frame = a.frame_id;
            }
            self.stamps.insert(a.stamp.to_bits(), a.exact);
            if a.stamp == stamp {
                return Some(a.at);
            }
        }
        None
    }

    /// The exact stamp of the frame at `seconds`.
    fn stamp(&self, seconds: f64) -> Stamp {
        self.stamps
            .get(&seconds.to_bits())
            .copied()
            .unwrap_or_else(|| Stamp::from_seconds(seconds))
    }

    fn camera_frame(&self) -> &str {
        if !self.frames.camera.is_empty() {
            &self.frames.camera
        } else if !self.camera_frame.is_empty() {
            &self.camera_frame
        } else {
            "camera"
        }
    }

    fn publish_map(&mut self, stamp: Stamp, map: &stillpoint_slam::data::map::Map) {
        let points = stillpoint_run::record::map_cloud(map, [255, 255, 255]);
        self.cloud
            .send(msg::point_cloud(stamp, &self.frames.map, &points));
        self.path
            .send(msg::path(stamp, &self.frames.map, &self.path_so_far));
    }
}

impl RosOutputs {
    /// What goes on `/tf` for a camera at `pose` in the map (REP 105, one parent per frame):
    /// `map` -> `odom` through the robot's own `odom` -> camera chain, or `map` -> camera when
    /// no other node parents the camera. `None` (said once) when neither can be published.
    fn transform(&mut self, camera: &str, pose: &Se3) -> Option<(String, Se3)> {
        self.listener.update();
        let (child, transform, refusal) = if self.frames.odom.is_empty() {
            match self.listener.tree.parent(camera) {
                Some(p) => (
                    camera,
                    *pose,
                    Some(format!(
                        "{camera} already has a parent on /tf ({p}): map -> {camera} not published (set ros2.odom_frame to publish map -> odom)"
                    )),
                ),
                None => (camera, *pose, None),
            }
        } else {
            let odom = self.frames.odom.as_str();
            match self.listener.tree.lookup(odom, camera) {
                Some(odom_camera) => (odom, pose * odom_camera.inverse(), None),
                None => (
                    odom,
                    *pose,
                    Some(format!(
                        "no {odom} -> {camera} chain on /tf yet: map -> {odom} not published"
                    )),
                ),
            }
        };
        if let Some(why) = refusal {
            if self.said.as_deref() != Some(why.as_str()) {
                warn!("{why}");
                self.said = Some(why);
            }
            return None;
        }
        let child = child.to_string();
        self.listener.own(&self.frames.map, &child);
        Some((child, transform))
    }
}

/// The words `/state` carries.
fn state_word(r: &stillpoint_pipeline::FrameResult) -> &'static str {
    match r.state {
        TrackingState::NotInitialized => "initializing",
        TrackingState::Lost => "lost",
        TrackingState::Ok if r.relocalised => "relocalized",
        TrackingState::Ok => "tracking",
    }
}

impl Sink for RosOutputs {
    fn frame(&mut self, t: &Tracked) -> Result<(), RunError> {
        let arrived = self.arrival(t.frame.timestamp);
        let stamp = self.stamp(t.frame.timestamp);
        let camera = self.camera_frame().to_string();
        if let Some(pose) = t.result.pose_wc {
            self.odom
                .send(msg::odometry(stamp, &self.frames.map, &camera, &pose));
            if let Some((child, transform)) = self.transform(&camera, &pose) {
                let t = Transform {
                    parent: &self.frames.map,
                    child: &child,
                    transform,
                };
                self.tf.send(msg::tf_message(stamp, &[t]));
            }
            self.path_so_far.push((stamp, pose));
        }
        self.state.send(msg::string(state_word(t.result)));
        if let Some(at) = arrived {
            self.latencies.ms.push(at.elapsed().as_secs_f64() * 1e3);
        }
        if let Some((out, quality)) = self.annotated.as_mut()
            && out.listened()
        {
            let img = stillpoint_run::overlay::draw_overlay(t.frame, t.result);
            if let Ok(jpeg) = stillpoint_image::encode_jpeg(&img, *quality) {
                out.send(msg::compressed_image(stamp, &camera, "jpeg", &jpeg));
            }
        }
        if let Some(period) = self.cloud_period
            && self.last_cloud.is_none_or(|l| l.elapsed() >= period)
        {
            self.last_cloud = Some(Instant::now());
            let map = t.system.map();
            if let Ok(map) = map.lock() {
                self.publish_map(stamp, &map);
            }
        }
        Ok(())
    }

    fn finish(&mut self, e: &Ended) -> Result<(), RunError> {
        // The refined trajectory replaces the path as it was tracked.
        let trajectory = &e.finished.trajectory;
        self.path_so_far = trajectory
            .stamps
            .iter()
            .map(|t| self.stamp(*t))
            .zip(trajectory.poses.iter().copied())
            .collect();
        let stamp = self
            .path_so_far
            .last()
            .map_or(Stamp { sec: 0, nanosec: 0 }, |p| p.0);
        let map = e.finished.system.map();
        if let Ok(map) = map.lock() {
            self.publish_map(stamp, &map);
        }
        Ok(())
    }
}
