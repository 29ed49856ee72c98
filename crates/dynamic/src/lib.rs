//! stillpoint-dynamic: the paper's contribution (Zhang & Li 2023, sections 2-4), as plain data
//! and pure functions, independent of the SLAM map and of threads.
//!
//! For each new frame, right after ORB extraction and before pose estimation:
//! 1. [`motion_consistency`] (the geometry module): corners of the previous frame tracked into the
//!    current one; each [`TrackedPoint`] is an outlier when it breaks the two-view geometry.
//! 2. [`judge_boxes`] (paper algorithm 1): each detection, with its tracked points, becomes one or
//!    two [`BoxState`]s: NHBC for persons (a seated person is split into a top and a bottom part),
//!    ATA for other classes.
//! 3. [`cull`] (paper algorithm 3): a keypoint is dynamic when inside a dynamic box and inside no
//!    static box.
//!
//! ```
//! use stillpoint_detect::{BBox, Detection};
//! use stillpoint_dynamic::{JudgeParams, TrackedPoint, cull, judge_boxes};
//! let person = Detection { class_id: 0, score: 0.9, bbox: BBox::new(100.0, 40.0, 160.0, 400.0) };
//! let moved = TrackedPoint { prev: [130.0, 100.0], cur: [135.0, 100.0], epipolar_distance: 5.0, outlier: true };
//! let still = TrackedPoint { prev: [400.0, 100.0], cur: [400.0, 100.0], epipolar_distance: 0.0, outlier: false };
//! let states = judge_boxes(&[person], &[moved, still], &JudgeParams::default());
//! assert_eq!(cull(&[[120.0, 300.0], [400.0, 300.0]], &states), vec![true, false]);
//! ```
//!
//! Every parameter lives in [`DynamicSettings`] with the paper's defaults; each module's docs say
//! where we follow the authors' code and where we deliberately differ.

pub mod cull;
pub mod depth;
pub mod judge;
pub mod motion_consistency;
pub mod settings;

pub use cull::{cull, cull_with, near_outliers};
pub use depth::{DepthCullInput, ObjectDepth, cull_frame, cull_with_depth};
pub use judge::{BoxPart, BoxState, Rule, Verdict, judge_boxes, nhbc_parts};
pub use motion_consistency::{
    GeometryTimings, MotionCheck, MotionModel, TrackedPoint, motion_consistency,
};
pub use settings::{CullParams, DepthParams, DynamicSettings, GeometryParams, JudgeParams};

#[cfg(test)]
mod paper_cases;
