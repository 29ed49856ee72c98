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
//! use stillpoint_detection::{BBox, Detection};
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
//! 5. [`cull_frame_with_motion`] adds each keypoint's own motion evidence inside dynamic boxes
//!    ([`keypoint_motion`](mod@keypoint_motion), ours).
//!
//! Two more steps of ours answer the paper's weak point (a two-frame F assumes the movers are a
//! minority; a textured person filling a plain room's view takes the consensus):
//! - before step 2, on RGB-D frames, [`world_motion()`] gives the camera motion of the static
//!   world (the map's constant-velocity prior refined on corner tracks outside every box that
//!   may move) and [`judge_against_world`] replaces each track's outlier flag by its residual
//!   against it: the map wins over the two-frame consensus;
//! - after step 2, [`ObjectTracker`] follows each box over frames and sets its verdict from the
//!   object's state with hysteresis: people (and animals, vehicles) are moving until seen still,
//!   with static-world evidence, for 15 frames in a row; one inconclusive frame changes nothing.
//!
//! A streaming caller builds each frame's LK pyramid once and passes it twice:
//!
//! ```text
//! cur_pyr = LkPyramid::new(&cur_gray, &settings.geometry.lk)
//! check   = motion_consistency_pyramids(&prev_gray, &cur_gray, &prev_pyr, &cur_pyr, &settings.geometry)
//! states  = judge_boxes(&detections, &check.points, &settings.judge)      (+ memory::carried_states)
//! removed = cull_frame_with_motion(&keypoints, &mut states, &check, depth, Some((&prev_pyr, &cur_pyr)), &settings)
//! prev_pyr = cur_pyr
//! ```
//!
//! Every parameter lives in [`DynamicSettings`] (our defaults; [`DynamicSettings::paper`] is
//! the paper as published); each module's docs say where we follow the authors' code and where
//! we deliberately differ.
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
//! - Per-keypoint evidence ([`keypoint_motion`](mod@keypoint_motion)): a keypoint in a walker's
//!   box whose own backward LK track fits the frame's homography within 0.5 px is kept
//!   (background at the walker's depth).
//! - Unknown objects ([`CullParams::unknown_objects`], the paper's option, on): keypoints with 3
//!   outliers in no box within 40 px, at their depth, go (a detector misses walkers).
//! - The object's depth prefers the front: a candidate depth loses the share of the box's centre
//!   in front of it ([`DepthParams::occluder_weight`]); it keeps near the object's band in the
//!   last frame ([`DepthParams::prior_weight`]), and a person is no farther than a box of its
//!   height allows ([`DepthParams::person_max_height_m`]). A keypoint beside a track that moved
//!   with the static world, at its depth, stays ([`DepthParams::static_radius_px`]: the floor at
//!   a walker's feet).
//! - Seated people's parts on RGB-D ([`seated_motion`](mod@seated_motion), used by the
//!   front-end): a culled keypoint whose 3D reprojection residual (camera motion from the static
//!   tracks with the depth of both frames, 3-point rigid RANSAC) is at most 0.5 px is kept:
//!   the still torso and legs.
//! - Box memory ([`memory`]): a box judged dynamic is carried, shifted by the optical flow, into
//!   up to 5 following frames in which the detector misses the object.
//! - Motion against the static world ([`world_motion`](mod@world_motion), RGB-D): the outliers
//!   the box rules count are tracks that break the static world's camera motion, not a
//!   two-frame F; only corner-like tracks speak (in a plain room a quarter of the tracks slide
//!   along edges or follow sensor noise).
//! - Objects over time ([`objects`]): box verdicts with hysteresis; a movable object's keypoints
//!   make map points only after 60 still frames (the front-end applies it); furniture is a mover
//!   only while motion evidence comes frame after frame (a walker in front of a table puts
//!   outliers in its box now and then).
//!
//! How well the decision does against the generator's masks (`stillpoint bench dynamic`), with
//! its commands: `docs/monocular.md` ("What `bench dynamic` measures") and `docs/paper.md`.

#![deny(missing_docs)]

pub mod cull;
pub mod depth;
pub mod judge;
pub mod keypoint_motion;
pub mod memory;
pub mod motion_consistency;
pub mod objects;
pub mod seated_motion;
pub mod settings;
#[cfg(test)]
mod test_texture;
pub mod world_motion;

pub use cull::{cull, cull_with, near_outliers};
pub use depth::{DepthCullInput, ObjectDepth, cull_frame, cull_with_depth};
pub use judge::{
    BoxPart, BoxState, Rule, Verdict, judge_boxes, nhbc_parts, only_in_dynamic_boxes_where,
};
pub use keypoint_motion::{
    CulledFrame, KeypointMotion, apply_keypoint_motion, cull_frame_with_evidence,
    cull_frame_with_motion, in_dynamic_box, keypoint_motion,
};
pub use memory::{
    AT_BORDER_PX, RememberedBox, carried_states, carry_forward, moved_by_flow,
    moved_by_flow_in_view, remember,
};
pub use motion_consistency::{
    GeometryTimings, MotionCheck, MotionModel, TrackedPoint, motion_consistency,
    motion_consistency_pyramids,
};
pub use objects::{
    Evidence, ObjectDecision, ObjectParams, ObjectTracker, TrackedObject, WorldCheck, evidence_of,
};
pub use seated_motion::{
    SeatedMotionParams, apply_seated_motion, camera_motion, seated_candidates, seated_residual,
};
pub use settings::{
    BoxMemoryParams, CullParams, DepthParams, DynamicSettings, EvidenceRules, EvidenceWithoutDepth,
    GeometryParams, JudgeParams, KeypointMotionParams,
};
pub use world_motion::{
    NewPointCheck, WorldMotion, WorldMotionParams, WorldSource, judge_against_world,
    keypoint_world_residual, lift_keypoint, new_point_check, world_motion, world_residuals,
};

#[cfg(test)]
mod paper_cases;
