//! Datasets: readers that turn TUM, Bonn, KITTI, EuRoC and image folders (and stillpoint's own
//! synthetic sequences, which use the TUM layout), ROS recordings (MCAP: [`mcap`]; ROS 1 bags:
//! [`rosbag`], read through the same code), video files ([`video`]) and live cameras
//! ([`camera`], [`live`]) into a stream of timestamped frames with calibration, and the settings
//! files (ORB-SLAM `%YAML:1.0`, our TOML) that describe a camera.
//!
//! Frames are read lazily: [`open`] reads file lists only, [`Sequence::frame`] loads one frame.
//! Each kind of input has one opener returning a `Box<dyn Sequence>`: [`open`] (folders),
//! [`open_recording`] (`.mcap`, `.bag`), [`open_video`], [`open_camera`].

#![deny(missing_docs)]

/// `boxes.jsonl`: the per-frame object boxes that come with a sequence
/// (`stillpoint_detection::annotations`).
pub use stillpoint_detection::annotations;
pub mod camera;
pub mod depth_check;
pub mod error;
pub mod euroc;
pub mod folder;
pub mod kitti;
pub mod lists;
pub mod live;
pub mod mcap;
pub mod rosbag;
pub mod sequence;
pub mod settings_file;
pub mod tum;
pub mod video;

pub use annotations::{FrameBoxes, GtBox};
pub use camera::open as open_camera;
pub use depth_check::depth_scale_warning;
pub use error::DatasetError;
pub use lists::{associate_nearest, read_associations, read_stamped_list, read_times};
pub use mcap::open as open_recording;
pub use sequence::{DatasetKind, GroundTruthFormat, Sequence, detect_kind, open};
pub use settings_file::{
    parse_orbslam_yaml, parse_settings_toml, read_orbslam_yaml, read_settings,
    read_settings_for_images, read_settings_toml, write_settings_toml,
};
pub use stillpoint_core::{Frame, OrbParams, Sensor, Settings};
/// The ORB extractor's settings as a dataset's settings carry them (`Settings::orb`).
pub use video::open as open_video;
