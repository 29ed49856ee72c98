//! stillpoint: visual SLAM that stays accurate when the world moves. This crate is the one
//! dependency an embedding program needs: open a source, build the pipeline with its dynamic
//! front-end and detector, feed it frames, and take the trajectory and map back.
//!
//! ```no_run
//! use stillpoint::{DetectSettings, DynamicFrontEnd, FrontEndSettings, Pipeline, PipelineSettings};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let seq = stillpoint::open("rgbd_dataset_freiburg3_walking_xyz".as_ref(), None, None)?;
//! let yolox = stillpoint::open_detector("yolox", &DetectSettings::default(), None, Default::default())?;
//! let front_end = DynamicFrontEnd::new(yolox, FrontEndSettings::default());
//! let mut slam = Pipeline::new(PipelineSettings::from_dataset(seq.settings()), Some(Box::new(front_end)), None);
//! for i in 0..seq.len() {
//!     let frame = slam.track(&seq.frame(i)?)?; // pose, state, keypoints culled or kept
//! }
//! let run = slam.finish()?; // trajectory, keyframes, the map
//! # Ok(())
//! # }
//! ```
//!
//! The crates behind it, one idea each, are re-exported whole for what this page leaves out.

pub use stillpoint_datasets::{
    DatasetKind, Frame, Sensor, Sequence, Settings as SensorSettings, open,
};
pub use stillpoint_detect::{
    COCO_CLASSES, DetectSettings, Detection, Detector, GtDetectorParams, open_detector,
};
pub use stillpoint_frontend::{DynamicFrontEnd, FrontEnd, FrontEndSettings, Judgement};
pub use stillpoint_pipeline::{Finished, FrameResult, Pipeline, PipelineError, PipelineSettings};
pub use stillpoint_slam::TrackingState;
pub use stillpoint_trajectory::{Trajectory, write_tum};

/// Sources: dataset folders, recordings, video, cameras.
pub use stillpoint_datasets as datasets;
/// Object detectors (YOLOX on ONNX Runtime or tract, ground-truth boxes).
pub use stillpoint_detect as detect;
/// The paper's dynamic-point rules (algorithms 1-3) and ours, as pure functions.
pub use stillpoint_dynamic as dynamic;
/// The dynamic front-end: detector, motion check, judgement and culling over time.
pub use stillpoint_frontend as frontend;
/// Geometry: camera models, poses, two-view models.
pub use stillpoint_geometry as geometry;
/// Images and depth maps.
pub use stillpoint_image as image;
/// Frames in, poses out: features, front-end and SLAM in one pipeline.
pub use stillpoint_pipeline as pipeline;
/// The ROS 2 node (feature `ros2`).
#[cfg(feature = "ros2")]
pub use stillpoint_ros2 as ros2;
/// A whole run: the settings tree (file, then `key=value` overrides), the detector and
/// front-end opened from it, the outputs (feature `run`).
#[cfg(feature = "run")]
pub use stillpoint_run as run;
/// Tracking, local mapping, loop closing, maps.
pub use stillpoint_slam as slam;
/// Synthetic sequences with exact ground truth (feature `synth`).
#[cfg(feature = "synth")]
pub use stillpoint_synth as synth;
/// Trajectories: reading, writing, alignment, ATE, RPE.
pub use stillpoint_trajectory as trajectory;
