//! stillpoint-dynamic: the paper's contribution (Zhang & Li 2023, sections 2-4), as plain data
//! and pure functions, independent of the SLAM map and of threads.
//!
//! For each new frame, right after ORB extraction and before pose estimation:
//! 1. [`motion_consistency()`] (the geometry module): corners of the previous frame tracked into the
//!    current one; each [`TrackedPoint`] is an outlier when it breaks the two-view geometry.
//! 2. [`judge_boxes`] (paper algorithm 1): each detection, with its tracked points, becomes one or
//!    two [`BoxState`]s: NHBC for persons (a seated person is split into a top and a bottom part),
//!    ATA for other classes.
//! 3. [`cull()`] (paper algorithm 3): a keypoint is dynamic when inside a dynamic box and inside no
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
//! 4. On RGB-D frames, [`cull_frame`] replaces step 3 by the depth-aware culling of [`depth`]
//!    (ours; [`DepthParams::enabled`], on by default, off = the paper's algorithm 3 unchanged).
//!
//! Every parameter lives in [`DynamicSettings`]; each module's docs say where we follow the
//! authors' code and where we deliberately differ.
//!
//! # Where we differ from the paper, and why
//! - Geometry ([`motion_consistency()`]): F refit on its inliers; a homography (or the flow) when F
//!   is undetermined (too few points, still camera, no parallax), said in [`MotionCheck::model`].
//!   The still-camera test counts the points that did not move against the homography's inliers.
//! - ATA divides by successful tracks; an empty box is [`Verdict::StaticUnknown`], not NaN.
//! - NHBC also calls a person dynamic with 3 tracked points above 0.5 px
//!   ([`JudgeParams::person_subpixel_px`]): a seated person's hand often moves less than a pixel.
//! - Culling on RGB-D is depth-aware ([`depth`]): inside a dynamic box only keypoints at the moving
//!   object's depth (± max(0.4 m, 10 %)) go; background seen past the person stays, and a static
//!   box protects only keypoints that are not at the mover's depth. Box-level culling caps
//!   precision at the share of the box the object fills (about half for a person), and the
//!   paper's static-box protection (tables, chairs, screens overlapping a walker) costs recall.
//! - Box memory ([`memory`]): a box judged dynamic is carried, shifted by the optical flow, into
//!   up to 5 following frames in which the detector misses the object.
//!
//! Measured with `stillpoint bench dynamic --dataset D` on `stillpoint synth --preset P --frames 20
//! --masks` (ground-truth boxes, precision / recall of the dynamic-keypoint decision against the
//! moving-pixel masks; paper = algorithm 1 + 3 as published, ours = the defaults):
//!
//! | sequence           | paper       | ours        | ours, Kinect noise | person boxes |
//! |--------------------|-------------|-------------|--------------------|--------------|
//! | walking_xyz        | 0.484/0.852 | 0.808/0.972 | 0.838/0.976        | 0.503/1.000  |
//! | walking_static     | 0.407/0.931 | 0.761/0.996 | 0.801/0.989        | 0.426/1.000  |
//! | walking_rpy        | 0.491/0.766 | 0.784/0.986 | 0.847/0.983        | 0.448/1.000  |
//! | walking_halfsphere | 0.474/0.755 | 0.785/0.961 | 0.854/0.955        | 0.489/1.000  |
//! | sitting_xyz        | 0.180/0.614 | 0.261/0.955 | 0.263/0.963        | 0.203/1.000  |
//! | sitting_static     | 0.196/0.679 | 0.292/0.980 | 0.298/0.978        | 0.209/1.000  |
//!
//! Almost all of the remaining false positives on walkers are keypoints on the silhouette (a
//! keypoint's depth is the nearest within 3x3 on purpose: its patch is partly the mover): counted
//! with a 1 px tolerance (`--gt-radius 1`) ours reaches 0.95-0.97 precision at 0.96-0.99 recall.
//! On seated people the masks mark only the moving limbs (7 % of the image against 24 % for the
//! people): culling the whole person at its depth caps precision near 0.3; culling only around the
//! outliers ([`DepthParams::seated_parts_local`], `--seated-local`) raises it to 0.36-0.50 but
//! drops recall to 0.39-0.45 (and walking_xyz's to 0.89: walkers cut by the image border look
//! seated to NHBC), so it is off.

pub mod cull;
pub mod depth;
pub mod judge;
pub mod keypoint_motion;
pub mod memory;
pub mod motion_consistency;
pub mod settings;

pub use cull::{cull, cull_with, near_outliers};
pub use depth::{DepthCullInput, ObjectDepth, cull_frame, cull_with_depth};
pub use judge::{BoxPart, BoxState, Rule, Verdict, judge_boxes, nhbc_parts};
pub use keypoint_motion::{
    KeypointMotion, apply_keypoint_motion, cull_frame_with_motion, in_dynamic_box, keypoint_motion,
};
pub use memory::{RememberedBox, carried_states, carry_forward, remember};
pub use motion_consistency::{
    GeometryTimings, MotionCheck, MotionModel, TrackedPoint, motion_consistency,
    motion_consistency_pyramids,
};
pub use settings::{
    BoxMemoryParams, CullParams, DepthParams, DynamicSettings, GeometryParams, JudgeParams,
    KeypointMotionParams,
};

#[cfg(test)]
mod paper_cases;
