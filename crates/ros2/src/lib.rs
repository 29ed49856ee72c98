//! stillpoint as a ROS 2 node, with no ROS install: camera topics in over DDS, poses and the
//! map out. The node is a run like any other ([`stillpoint_run::run_source`]): its source is
//! the camera's topics ([`camera`]: images paired by stamp, as a live camera's frames), and
//! its outputs one more sink ([`outputs`]: odometry, `/tf`, path, map cloud, annotated image,
//! state). DDS is RustDDS, under ros2-client's context and node, so `ros2 node list` shows
//! the node, and real ROS 2 nodes (rmw_fastrtps, rmw_cyclonedds) talk to it. Messages are
//! read and written by the project's CDR code ([`wire`], [`msg`]).

pub mod camera;
pub mod msg;
pub mod outputs;
pub mod tf;
pub mod wire;

use std::time::Duration;

use ros2_client::{Context, NodeName};
use rustdds::policy::{Durability, History, Reliability};
use rustdds::{DomainParticipantBuilder, QosPolicies, QosPolicyBuilder};
use stillpoint_datasets::live::{Buffering, LiveSequence};
use stillpoint_datasets::mcap::ros::{CameraInfoMsg, MessageType};
use stillpoint_datasets::{Sensor, Settings};
use stillpoint_geometry::PinholeCamera;
use stillpoint_run::{Ros2Settings, RunOptions, RunSummary};

use crate::camera::{RosCamera, Subscription, wait_for_info};
use crate::outputs::{Frames, Latencies, RosOutputs};

/// Why the node could not run.
#[derive(Debug, thiserror::Error)]
pub enum Ros2Error {
    /// A setting or the environment is wrong (one line; exit status 1).
    #[error("{0}")]
    Config(String),
    /// DDS refused something.
    #[error("DDS: {0}")]
    Dds(String),
    /// The run failed.
    #[error(transparent)]
    Run(#[from] stillpoint_run::RunError),
    /// The settings file.
    #[error(transparent)]
    Dataset(#[from] stillpoint_datasets::DatasetError),
}

/// How the node runs.
#[derive(Clone, Debug)]
pub struct NodeOptions {
    /// The run: detector, outputs, maps, settings (`dataset` only names the node's source in
    /// messages; `settings`, when given, is the camera file used instead of `CameraInfo`).
    pub run: RunOptions,
    /// Lock-step: every frame tracked in order, reliable subscriptions, local mapping and
    /// the detector inline (a peer that sends the next frame once this one's state came back
    /// gets `run --sequential`'s trajectory). Off: live, the newest frame tracked and older
    /// ones dropped, the detector in the background.
    pub lock_step: bool,
}

/// What a node run did.
pub struct NodeSummary {
    /// The run's summary (trajectory, frames tracked, timings).
    pub run: RunSummary,
    /// Frames paired from the topics, latency from arrival to pose sent.
    pub latencies: Latencies,
}

/// The DDS name of a ROS 2 topic (`/camera/image` -> `rt/camera/image`), as rmw names it.
pub fn dds_topic_name(topic: &str) -> Result<String, Ros2Error> {
    let name = topic.trim_start_matches('/');
    let ok = !name.is_empty()
        && !name.ends_with('/')
        && !name.contains("//")
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '/')
        && name
            .split('/')
            .all(|part| !part.starts_with(|c: char| c.is_ascii_digit()));
    if !ok {
        return Err(Ros2Error::Config(format!(
            "{topic:?} is not a ROS 2 topic name (letters, digits and _ between slashes, no part starting with a digit)"
        )));
    }
    Ok(format!("rt/{name}"))
}

/// The topic `leaf` beside `topic` (`/cam/color/image_raw` -> `/cam/color/camera_info`).
fn beside(topic: &str, leaf: &str) -> String {
    let topic = topic.trim_end_matches("/compressed");
    match topic.rsplit_once('/') {
        Some((dir, _)) => format!("{dir}/{leaf}"),
        None => leaf.to_string(),
    }
}

/// `ROS_DOMAIN_ID`, 0 when unset.
fn domain_id() -> Result<u16, Ros2Error> {
    match std::env::var("ROS_DOMAIN_ID") {
        Err(_) => Ok(0),
        Ok(v) if v.trim().is_empty() => Ok(0),
        Ok(v) => v
            .trim()
            .parse::<u16>()
            .ok()
            .filter(|d| *d <= 232)
            .ok_or_else(|| {
                Ros2Error::Config(format!("ROS_DOMAIN_ID={v:?}: not a domain (0 to 232)"))
            }),
    }
}

fn sensor_of(r: &Ros2Settings) -> Result<Sensor, Ros2Error> {
    match r.sensor.as_str() {
        "rgbd" => Ok(Sensor::Rgbd),
        "stereo" => Ok(Sensor::Stereo),
        "mono" | "monocular" => Ok(Sensor::Mono),
        o => Err(Ros2Error::Config(format!(
            "ros2.sensor = {o:?}: rgbd, stereo or mono"
        ))),
    }
}

/// A quality of service: reliable or best effort (ROS's sensor-data profile), keep last
/// `depth`, transient local (`latched`: late joiners get the last samples) or volatile.
pub(crate) fn qos(reliable: bool, depth: i32, latched: bool) -> QosPolicies {
    QosPolicyBuilder::new()
        .reliability(if reliable {
            Reliability::Reliable {
                max_blocking_time: rustdds::Duration::from_millis(100),
            }
        } else {
            Reliability::BestEffort
        })
        .history(History::KeepLast { depth })
        .durability(if latched {
            Durability::TransientLocal
        } else {
            Durability::Volatile
        })
        .build()
}

/// The run's settings tree as the overrides make it, for its `[ros2]` table (the camera is
/// not known yet).
fn ros2_settings(o: &RunOptions) -> Result<Ros2Settings, Ros2Error> {
    let placeholder =
        Settings::with_camera(Sensor::Rgbd, PinholeCamera::new(1.0, 1.0, 0.5, 0.5, 1, 1));
    let layers = stillpoint_run::settings_layers(&placeholder, None, false, &o.overrides)?;
    Ok(layers.tree.ros2)
}

/// The camera's settings from its `CameraInfo` (and, for a stereo pair, the right one's
/// projection for the baseline).
fn camera_settings(
    sensor: Sensor,
    left: &CameraInfoMsg,
    right: Option<&CameraInfoMsg>,
) -> Result<Settings, Ros2Error> {
    let rectified = sensor == Sensor::Stereo;
    let camera = left
        .camera(rectified)
        .map_err(|e| Ros2Error::Config(format!("CameraInfo: {e}")))?;
    let mut s = Settings::with_camera(sensor, camera);
    if let Some(r) = right {
        let bf = -(r.p[3] - left.p[3]);
        if !(bf.is_finite() && bf > 0.0) {
            return Err(Ros2Error::Config(format!(
                "the right CameraInfo's P[3] is {} (left {}): no baseline (a rectified right camera's P[3] is -fx * baseline); give --settings FILE with Camera.bf",
                r.p[3], left.p[3]
            )));
        }
        s.bf = Some(bf);
    }
    Ok(s)
}

/// Run the node until the topics end (never, live) or `o.run.stop` is set.
pub fn run_node(o: &NodeOptions) -> Result<NodeSummary, Ros2Error> {
    let r = ros2_settings(&o.run)?;
    let sensor = sensor_of(&r)?;
    // Every name checked before DDS starts: a wrong one is one line, not a half-built node.
    let domain = domain_id()?;
    for t in [&r.image_topic, &r.depth_topic, &r.right_topic]
        .into_iter()
        .chain([&r.camera_info_topic, &r.right_camera_info_topic])
        .filter(|t| !t.is_empty())
    {
        dds_topic_name(t)?;
    }
    dds_topic_name(&format!("{}/odom", r.output_prefix.trim_end_matches('/')))?;
    let second_topic = match sensor {
        Sensor::Rgbd => Some(&r.depth_topic),
        Sensor::Stereo => Some(&r.right_topic),
        Sensor::Mono => None,
    };
    if second_topic.is_some_and(|t| t.is_empty()) {
        return Err(Ros2Error::Config(format!(
            "ros2.sensor = {:?} needs its second image topic (--depth-topic or --right-topic)",
            r.sensor
        )));
    }
    let participant = DomainParticipantBuilder::new(domain)
        .socket_receive_buffer_size(r.socket_buffer_mib << 20)
        .build()
        .map_err(|e| Ros2Error::Dds(format!("joining the domain: {e}")))?;
    let context = Context::from_domain_participant(participant.clone())
        .map_err(|e| Ros2Error::Dds(format!("{e:?}")))?;
    let _node = context
        .new_node(
            NodeName::new("/", "stillpoint").map_err(|e| Ros2Error::Config(format!("{e:?}")))?,
            ros2_client::NodeOptions::new()
                .enable_rosout(false)
                .start_parameter_services(false),
        )
        .map_err(|e| Ros2Error::Dds(format!("creating the node: {e:?}")))?;
    let images_qos = qos(r.reliable || o.lock_step, r.queue_depth.max(1), false);
    let subscriber = participant
        .create_subscriber(&images_qos)
        .map_err(|e| Ros2Error::Dds(format!("subscriber: {e}")))?;
    let image = Subscription::image(&participant, &subscriber, &r.image_topic, &images_qos)?;
    let second = match second_topic {
        Some(t) => Some((
            Subscription::image(&participant, &subscriber, t, &images_qos)?,
            sensor,
        )),
        None => None,
    };
    let warn_every = Duration::from_secs_f64(r.silence_warning_s.max(0.5));
    let ds = match &o.run.settings {
        Some(path) => {
            let mut s = stillpoint_datasets::read_settings(path)?;
            s.sensor = sensor;
            s
        }
        None => {
            let info_topic = if r.camera_info_topic.is_empty() {
                beside(&r.image_topic, "camera_info")
            } else {
                r.camera_info_topic.clone()
            };
            let info_qos = qos(true, 1, true);
            let mut info = Subscription::new(
                &participant,
                &subscriber,
                &info_topic,
                MessageType::CameraInfo,
                &info_qos,
            )?;
            let Some(left) = wait_for_info(&mut info, warn_every, o.run.stop)? else {
                return Err(Ros2Error::Config(format!(
                    "stopped before a CameraInfo came on {info_topic}"
                )));
            };
            let right = if sensor == Sensor::Stereo {
                let topic = if r.right_camera_info_topic.is_empty() {
                    beside(&r.right_topic, "camera_info")
                } else {
                    r.right_camera_info_topic.clone()
                };
                let mut sub = Subscription::new(
                    &participant,
                    &subscriber,
                    &topic,
                    MessageType::CameraInfo,
                    &info_qos,
                )?;
                match wait_for_info(&mut sub, warn_every, o.run.stop)? {
                    Some(m) => Some(m),
                    None => {
                        return Err(Ros2Error::Config(format!(
                            "stopped before a CameraInfo came on {topic}"
                        )));
                    }
                }
            } else {
                None
            };
            camera_settings(sensor, &left, right.as_ref())?
        }
    };
    let (arrivals_tx, arrivals) = std::sync::mpsc::channel();
    let source = RosCamera::new(
        image,
        second,
        ds.clone(),
        r.pair_tolerance_s,
        warn_every,
        o.run.stop,
        arrivals_tx,
    );
    let buffering = if o.lock_step {
        Buffering::All
    } else {
        Buffering::Newest
    };
    let seq = LiveSequence::start(Box::new(source), ds, buffering)?;
    let mut outputs = RosOutputs::new(
        &participant,
        &r.output_prefix,
        Frames {
            map: r.map_frame.clone(),
            odom: r.odom_frame.clone(),
            camera: r.camera_frame.clone(),
        },
        r.cloud_period_s,
        r.annotated_image.then_some(r.jpeg_quality),
        arrivals,
    )?;
    let mut run = o.run.clone();
    run.realtime = false;
    run.settings = None;
    // Lock-step is a recording's run (mapping inline); live is a camera's (the detector in
    // the background, mapping on its thread). A user's --set still wins.
    let mode: &[&str] = if o.lock_step {
        &["slam.local_mapping_thread=false"]
    } else {
        &["front_end.detector_in_background=true"]
    };
    let mut sets: Vec<String> = mode.iter().map(|s| s.to_string()).collect();
    sets.append(&mut run.overrides.sets);
    run.overrides.sets = sets;
    let summary =
        stillpoint_run::run_source(&run, Box::new(seq), None, &mut [&mut outputs], &mut |_| {})?;
    Ok(NodeSummary {
        run: summary,
        latencies: std::mem::take(&mut outputs.latencies),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topics_are_named_as_rmw_names_them() {
        assert_eq!(
            dds_topic_name("/camera/image_raw").unwrap(),
            "rt/camera/image_raw"
        );
        assert_eq!(dds_topic_name("tf").unwrap(), "rt/tf");
        for bad in ["", "/", "/a//b", "/a/", "/camera/2d", "/a b", "/ä"] {
            let e = dds_topic_name(bad).unwrap_err().to_string();
            assert!(e.contains("not a ROS 2 topic name"), "{bad:?}: {e}");
        }
    }

    #[test]
    fn camera_info_is_looked_for_beside_the_image() {
        assert_eq!(
            beside("/camera/camera/color/image_raw", "camera_info"),
            "/camera/camera/color/camera_info"
        );
        assert_eq!(
            beside("/cam/image_raw/compressed", "camera_info"),
            "/cam/camera_info"
        );
    }

    #[test]
    fn a_stereo_camera_needs_a_baseline_in_the_right_projection() {
        let info = |p3: f64| CameraInfoMsg {
            stamp: 0.0,
            height: 480,
            width: 640,
            distortion_model: "plumb_bob".into(),
            d: vec![0.0; 5],
            k: [500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0],
            p: [
                500.0, 0.0, 320.0, p3, 0.0, 500.0, 240.0, 0.0, 0.0, 0.0, 1.0, 0.0,
            ],
        };
        let s = camera_settings(Sensor::Stereo, &info(0.0), Some(&info(-50.0))).unwrap();
        assert_eq!(s.bf, Some(50.0));
        let e = camera_settings(Sensor::Stereo, &info(0.0), Some(&info(0.0))).unwrap_err();
        assert!(e.to_string().contains("no baseline"), "{e}");
    }
}
