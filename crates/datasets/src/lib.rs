//! Datasets: readers that turn TUM, Bonn, KITTI, EuRoC and image folders (and stillpoint's own
//! synthetic sequences, which use the TUM layout) into a stream of timestamped frames with
//! calibration, and the settings files (ORB-SLAM `%YAML:1.0`, our TOML) that describe a camera.

pub mod annotations;
pub mod frame;
pub mod settings;

pub use annotations::{FrameBoxes, GtBox};
pub use frame::Frame;
pub use settings::{OrbSettings, Sensor, Settings};
