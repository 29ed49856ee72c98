//! Every parameter of the dynamic front-end, with the paper's (or the authors' code's) defaults.

use stillpoint_features::{CornerParams, LkParams};
use stillpoint_geometry::fundamental::FundamentalRansac;

/// All settings of this crate: the geometry module, the box judgement and the culling.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct DynamicSettings {
    /// The motion check: corners, LK, the fundamental matrix (paper section 3.2).
    pub geometry: GeometryParams,
    /// Moving boxes (paper algorithms 1-2: NHBC, ATA).
    pub judge: JudgeParams,
    /// Culling (paper algorithm 3, with our rules beside it).
    pub cull: CullParams,
    /// Depth-aware culling for RGB-D frames (ours; see [`crate::depth`]).
    pub depth: DepthParams,
    /// Temporal propagation of moving-object boxes across missed detections (ours; see
    /// [`crate::memory`]).
    pub memory: BoxMemoryParams,
    /// Per-keypoint motion evidence inside dynamic boxes (ours; see
    /// [`crate::keypoint_motion`](mod@crate::keypoint_motion)).
    pub keypoint_motion: KeypointMotionParams,
    /// Motion judged against the static world instead of a two-frame consensus, RGB-D (ours;
    /// see [`crate::world_motion`](mod@crate::world_motion)).
    pub world: crate::world_motion::WorldMotionParams,
    /// Objects tracked across frames, with hysteresis on their state (ours; see
    /// [`crate::objects`]).
    pub objects: crate::objects::ObjectParams,
}

impl DynamicSettings {
    /// The paper as published wherever we added a rule of ours: no sub-pixel NHBC rule, no
    /// depth-aware culling, no unknown-object rule, no box memory, no per-keypoint evidence
    /// (the geometry module keeps its guards: F refit, homography / flow fallbacks).
    /// [`crate::cull_frame`] with these is the paper's algorithm 3.
    pub fn paper() -> Self {
        let mut s = Self::default();
        s.judge.person_subpixel_px = None;
        s.judge.ata_ignores_person_points_without_depth = false;
        s.cull.unknown_objects = false;
        s.depth.enabled = false;
        s.memory.enabled = false;
        s.keypoint_motion.enabled = false;
        s.world.enabled = false;
        s.objects.enabled = false;
        s
    }
}

/// The motion consistency check (paper section 2, module 2; DS-SLAM's `ProcessMovingObject`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct GeometryParams {
    /// Harris corners on the previous frame: 1000, quality 0.01, min distance 8, block 3, k 0.04,
    /// sub-pixel window 10x10, 20 iterations, eps 0.03 (paper; `features` defaults).
    pub corners: CornerParams,
    /// Pyramidal LK: window 22x22, 5 levels, 20 iterations, eps 0.01 (paper; `features` defaults).
    pub lk: LkParams,
    /// Drop a pair when either point is closer than this to the image border, in pixels
    /// (authors' `limit_edge_corner = 5`).
    pub border_px: f32,
    /// Half side of the patches compared between the two frames: 1 → 3x3 (authors' code).
    pub patch_half: usize,
    /// Drop a pair whose patches differ by more than this sum of absolute differences (authors'
    /// `limit_of_check = 2120`; the maximum for 3x3 is 2295, so this is only a sanity check).
    pub max_patch_sad: u32,
    /// RANSAC for F: 0.1 px, confidence 0.99 (authors' `findFundamentalMat(.., 0.1, 0.99)`);
    /// deterministic seed. Unlike the authors' OpenCV call, F is refit on the inliers.
    pub ransac: FundamentalRansac,
    /// A tracked point is an outlier when its residual under the chosen motion model (distance to
    /// its epipolar line for F) exceeds this, in pixels (authors' `limit_dis_epi = 1`).
    pub outlier_threshold_px: f64,
    /// Fewest surviving pairs to estimate F at all (ours; the authors call OpenCV with whatever
    /// is left, which fails below 8 and leaves F empty, unguarded). Below it a homography or the
    /// flow is used.
    pub min_points_fundamental: usize,
    /// Use a homography instead of F when it explains (residual <= `outlier_threshold_px`) at
    /// least this fraction of the points F explains (ours). Then the views have no measurable
    /// parallax (static or purely rotating camera, distant or planar scene), F is not determined
    /// by the static points, and RANSAC would happily pick an F whose epipolar lines run along a
    /// moving person's motion, hiding it. Two views alone cannot tell an object moving rigidly
    /// over a static background from a near static object seen with parallax; this ratio is the
    /// prior that decides: points F explains beyond the homography count as parallax once they
    /// are more than 1 - ratio of F's inliers (default 0.8: a mover covering up to ~20 % of the
    /// tracked points is still caught by a static camera; a synthetic static camera with an 8 %
    /// mover gives 0.91, a translating one with a 24 % near box 0.63 — see the tests).
    /// Values above 1 disable the fallback whenever F exists.
    pub homography_support_ratio: f64,
    /// The camera counts as still, and the homography is used whatever F explains, when the
    /// points that moved less than this many pixels number at least 90 % of the homography's
    /// inliers (ours; default 1.0 px, the outlier threshold: parallax cannot exceed the flow of
    /// the nearest static point). This catches a static camera watching large movers, which the
    /// ratio above cannot.
    pub still_camera_flow_px: f64,
    /// Fewest pairs for the last fallback, the flow relative to the median flow (ours).
    pub min_points_flow: usize,
}

impl Default for GeometryParams {
    fn default() -> Self {
        Self {
            corners: CornerParams::default(),
            lk: LkParams::default(),
            border_px: 5.0,
            patch_half: 1,
            max_patch_sad: 2120,
            ransac: FundamentalRansac {
                threshold_px: 0.1,
                confidence: 0.99,
                max_iterations: 1000,
                seed: 0,
            },
            outlier_threshold_px: 1.0,
            min_points_fundamental: 15,
            homography_support_ratio: 0.8,
            still_camera_flow_px: 1.0,
            min_points_flow: 3,
        }
    }
}

/// The moving-box judgement (paper algorithm 1: NHBC for persons, ATA for everything else).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct JudgeParams {
    /// COCO class judged by NHBC (0, person).
    pub person_class: u16,
    /// A person box with height / width at most this is a seated person and is split (paper: 3,
    /// "nine head body": a standing adult is about 7-9 heads tall and 2-3 heads wide).
    pub seated_max_aspect: f32,
    /// Share of a seated person's height that is the top part (paper: 1 / 1.3 ≈ 0.77; the bottom
    /// part is the remaining 0.3 / 1.3).
    pub seated_top_fraction: f32,
    /// A person box or part is dynamic with at least this many outliers strictly inside (paper: 1).
    pub person_min_outliers: usize,
    /// Sub-pixel motion of persons (ours; `None` = the paper): a person box or part is also
    /// dynamic when at least [`Self::person_subpixel_min_points`] of its tracked points have a
    /// residual above this many pixels (below the 1 px outlier threshold): a seated person's hand
    /// at 2-3 m often moves less than a pixel between frames. Default 0.5 px; a false alarm only
    /// costs keypoints on a person. Measurements: docs/measurements.md.
    pub person_subpixel_px: Option<f32>,
    /// See [`Self::person_subpixel_px`] (ours: 3, so that a single noisy track does not count).
    pub person_subpixel_min_points: usize,
    /// ATA: a non-person box is dynamic when outliers / tracked points inside exceed this
    /// (paper's ε = 0.4).
    pub ata_ratio: f32,
    /// A box with fewer successfully tracked points inside than this (and not dynamic by NHBC)
    /// is [`crate::Verdict::StaticUnknown`] (ours: the authors divide by zero and get NaN, which
    /// compares as static). 1 keeps the paper's behaviour for every non-empty box.
    pub min_tracked: usize,
    /// ATA ignores tracked points that lie inside a person box, on every frame (ours, off by
    /// default = paper): those belong to the person NHBC judges, and a walker passing in front
    /// of a table would otherwise make the table "dynamic" by its outliers.
    pub ata_ignores_person_points: bool,
    /// ... and on frames without depth (ours: on), where a box judged dynamic is culled whole:
    /// counted, children jumping on a bed made the bed's box "dynamic" by their outliers, and
    /// the whole bed went, with most of the image (a monocular map that never started). With
    /// depth the culling keeps to the object's depth band, and counting them measured better.
    /// Measurements: docs/measurements.md.
    pub ata_ignores_person_points_without_depth: bool,
}

impl JudgeParams {
    /// The judgement for one frame: [`Self::ata_ignores_person_points_without_depth`] resolved
    /// into [`Self::ata_ignores_person_points`], which [`crate::judge_boxes`] reads.
    pub fn on_frame(&self, has_depth: bool) -> Self {
        Self {
            ata_ignores_person_points: self.ata_ignores_person_points
                || (self.ata_ignores_person_points_without_depth && !has_depth),
            ..self.clone()
        }
    }
}

impl Default for JudgeParams {
    fn default() -> Self {
        Self {
            person_class: 0,
            seated_max_aspect: 3.0,
            seated_top_fraction: 1.0 / 1.3,
            person_min_outliers: 1,
            person_subpixel_px: Some(0.5),
            person_subpixel_min_points: 3,
            ata_ratio: 0.4,
            min_tracked: 1,
            ata_ignores_person_points: false,
            ata_ignores_person_points_without_depth: true,
        }
    }
}

/// Culling (paper algorithm 3) and the optional culling near unexplained outliers.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct CullParams {
    /// Whether a [`crate::Verdict::Static`] box protects the keypoints inside it (paper
    /// algorithm 3: yes). Off only to measure what the protection costs in recall.
    pub static_box_protects: bool,
    /// Whether a [`crate::Verdict::StaticUnknown`] box protects the keypoints inside it like a
    /// static one (paper: yes, NaN → static). Default true.
    pub unknown_box_protects: bool,
    /// Also cull keypoints near geometric outliers that lie in no box: the paper's "unknown
    /// dynamic objects" (ours: on; the paper describes it without an algorithm). On RGB-D frames
    /// only outliers at the keypoint's depth (their band, [`DepthParams::band_min_m`]) count.
    /// It catches movers the detector misses. Measurements: docs/measurements.md.
    pub unknown_objects: bool,
    /// Radius around such outliers in pixels (ours: 40). Measurements: docs/measurements.md.
    pub unknown_radius_px: f32,
    /// Fewest box-less outliers within the radius of a keypoint to cull it (ours: 3; ignores
    /// isolated bad tracks).
    pub unknown_min_outliers: usize,
    /// The unknown-object rule on frames without depth too (ours: off for monocular, on for
    /// stereo, whose depth comes after the front-end). Without a depth band to gate them, the
    /// two-frame check's outliers of a forward-moving or hand-held monocular camera lie all over
    /// the static world (the epipole in the image, rolling shutter), and the rule would cull
    /// static keypoints. Measurements: docs/measurements.md.
    pub unknown_objects_without_depth: bool,
}

impl Default for CullParams {
    fn default() -> Self {
        Self {
            static_box_protects: true,
            unknown_box_protects: true,
            unknown_objects: true,
            unknown_radius_px: 40.0,
            unknown_min_outliers: 3,
            unknown_objects_without_depth: false,
        }
    }
}

/// Depth-aware culling for RGB-D frames (ours, not in the paper; see [`crate::depth`] for the
/// rules). Measurements: docs/measurements.md.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct DepthParams {
    /// Use the depth when the frame has one (default true). False gives the paper's
    /// algorithm 3 unchanged on RGB-D frames too.
    pub enabled: bool,
    /// Half width of the depth band around a moving object's depth, at least this many metres
    /// (ours: 0.4 m, about a person's half depth extent with swinging arms and a stride, and
    /// several times the Kinect's depth noise at 4 m). Measurements: docs/measurements.md.
    pub band_min_m: f32,
    /// ... and at least this share of the object's depth (ours: 10 %, for far objects, where the
    /// Kinect's noise grows with the square of the depth). Measurements: docs/measurements.md.
    pub band_relative: f32,
    /// Share of a box's width, centred, sampled for the object's depth (ours: 0.5: a person is
    /// mostly in the middle of the box, the background at its sides).
    pub central_width: f32,
    /// Share of a box's height, centred, sampled for the object's depth (ours: 0.8).
    pub central_height: f32,
    /// Step of the depth samples in the central region, pixels (ours: 4).
    pub sample_step_px: usize,
    /// Fewest valid depth samples in the central region to estimate the object's depth; below
    /// it the box is culled by the paper's rule (ours: 20).
    pub min_samples: usize,
    /// Weight of the outliers' depths against the central samples when choosing the object's
    /// depth: score = central share in band + weight x n / (n + `outlier_half_count`) x outlier
    /// share in band, n the outliers with depth (ours: 1.5; the geometric outliers are the
    /// motion evidence, the central region the prior; several outliers on a thin person beat a
    /// mostly-background centre, a single bad track on the background does not beat a centre
    /// mostly on the person).
    pub outlier_weight: f32,
    /// Number of outliers at which their evidence counts half its weight (ours: 3).
    pub outlier_half_count: f32,
    /// Penalty on a candidate depth per share of the central samples nearer than its band
    /// (ours: 1.0, one share in front cancels one share in the band; 0 = the rule off): the
    /// mover is in front of what it hides, so a depth with much of the box's centre in front of
    /// it is likely background seen past the object. Measurements: docs/measurements.md.
    pub occluder_weight: f32,
    /// The tallest a person is, metres (ours: 2.0; 0 = no bound): a person's box `h` pixels
    /// tall lies within `fy x this / h`, so the wall behind a walker in a stride, most of his
    /// box's centre, is never taken for him.
    pub person_max_height_m: f32,
    /// Bonus for a candidate depth within the band the object had in the last frame (ours:
    /// 0.5; [`BoxState::depth`](crate::BoxState::depth) going into the culling): a walker's
    /// depth changes by centimetres a frame, while a box's centre can turn from the person to
    /// the wall behind him from one frame to the next (a close person at the image edge).
    pub prior_weight: f32,
    /// Also cull keypoints near a geometric outlier of a dynamic box and at that outlier's depth
    /// (its band), within this share of the square root of the box's area (ours: 0.25; a hand
    /// reaching in front of the body, an arm of a seated person). 0 turns the local rule off.
    pub local_radius_fraction: f32,
    /// Keep a keypoint in a mover's band when a tracked point that moved with the static world
    /// lies within this many pixels at its depth (± [`DepthParams::static_depth_m`]) and no
    /// moving one does (ours: 12; 0 = off): the floor at a walker's feet and the desk beside
    /// his hip share his depth, not his motion.
    pub static_radius_px: f32,
    /// Depth difference within which such a static neighbour counts (ours: 0.1 m).
    pub static_depth_m: f32,
    /// Depths at or below this, or not finite, are missing (Kinect: no reading is 0).
    pub min_valid_m: f32,
    /// A keypoint's depth is the nearest valid depth within this many pixels of it (ours: 1, a
    /// 3x3 window): a keypoint on a silhouette describes a patch that is partly the mover.
    pub keypoint_window_px: usize,
    /// Keep what lies on the plane a mover stands on (ours, on; [`crate::depth::support_plane`]):
    /// the floor at a walker's feet is in his depth band but does not move. Measurements:
    /// docs/measurements.md.
    pub support_plane: bool,
    /// The plane is fitted in the rows from this share of a whole box's height above its
    /// bottom (ours: 0.35, a walker's legs; a seated-split box's bottom part, all of it) ...
    pub support_height_fraction: f32,
    /// ... to this share below it (ours: 0.1) ...
    pub support_below_fraction: f32,
    /// ... across this share of the box's width on each side of it (ours: 0.5).
    pub support_side_fraction: f32,
    /// Fewest depth samples there to fit a plane (ours: 30).
    pub support_min_samples: usize,
    /// Planes drawn (ours: 64).
    pub support_iterations: usize,
    /// A point is on the plane within this many metres (ours: 0.03, Kinect noise at 2-3 m) ...
    pub support_tolerance_m: f32,
    /// ... or this share of its depth, if more (ours: 0.015).
    pub support_tolerance_relative: f32,
    /// The plane must hold at least this share of the samples (ours: 0.4) ...
    pub support_min_share: f32,
    /// ... face the camera no more than this: the cosine between its normal and the ray to the
    /// box's bottom (ours: 0.8; a floor 2-3 m away seen from 0.8-1.5 m up is 0.3-0.6, a
    /// cabinet's front facing the camera near 1) ...
    pub support_max_facing: f32,
    /// ... and hold at most this share of the object's moving points at its depth (ours:
    /// 0.25) ...
    pub support_max_object_share: f32,
    /// ... or this many of them if more (ours: 3, a walker's feet stand on it): a plane
    /// through the object is not what it stands on.
    pub support_feet_points: usize,
}

impl Default for DepthParams {
    fn default() -> Self {
        Self {
            enabled: true,
            band_min_m: 0.4,
            band_relative: 0.1,
            central_width: 0.5,
            central_height: 0.8,
            sample_step_px: 4,
            min_samples: 20,
            outlier_weight: 1.5,
            outlier_half_count: 3.0,
            occluder_weight: 1.0,
            person_max_height_m: 2.0,
            prior_weight: 0.5,
            local_radius_fraction: 0.25,
            static_radius_px: 12.0,
            static_depth_m: 0.1,
            min_valid_m: 0.05,
            keypoint_window_px: 1,
            support_plane: true,
            support_height_fraction: 0.35,
            support_below_fraction: 0.1,
            support_side_fraction: 0.5,
            support_min_samples: 30,
            support_iterations: 64,
            support_tolerance_m: 0.03,
            support_tolerance_relative: 0.015,
            support_min_share: 0.4,
            support_max_facing: 0.8,
            support_max_object_share: 0.25,
            support_feet_points: 3,
        }
    }
}

/// Box memory: carry a box judged dynamic into the next frames when the detector misses it
/// (ours, not in the paper; see [`crate::memory`]). Measurements: docs/measurements.md.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct BoxMemoryParams {
    /// On by default; off = the paper (a missed detection lets the mover's keypoints through).
    pub enabled: bool,
    /// Most consecutive frames a box is carried without a matching detection. 5 frames at
    /// 30 Hz: long enough for a detector's dropouts (blur, occlusion), short enough that a
    /// box that left the scene does not blank the background for long.
    pub max_frames: usize,
    /// A current detection of the same class with IoU >= this with the remembered box is the
    /// same object re-detected, and the memory is dropped (the detection is judged instead).
    pub min_iou: f32,
    /// ... or when such a detection covers at least this share of the remembered box (so the
    /// part boxes of a seated person, and boxes that shrank, are re-found by the whole person).
    pub min_covered: f32,
}

impl Default for BoxMemoryParams {
    fn default() -> Self {
        Self {
            enabled: true,
            max_frames: 5,
            min_iou: 0.3,
            min_covered: 0.5,
        }
    }
}

/// Per-keypoint motion evidence inside dynamic boxes (ours, not in the paper; see
/// [`crate::keypoint_motion`](mod@crate::keypoint_motion) for the rules). Measurements:
/// docs/measurements.md.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct KeypointMotionParams {
    /// Apply the evidence after the box culling in [`crate::cull_frame_with_motion`] (ours, on):
    /// it keeps background seen inside a mover's box. Measurements: docs/measurements.md.
    pub enabled: bool,
    /// LK for the backward and forward tracks: the geometry module's pyramids with a 7x7 window
    /// (ours; the paper's 22x22 window straddles the silhouette of a person for keypoints just
    /// outside it). Measurements: docs/measurements.md.
    pub lk: LkParams,
    /// Drop a track whose previous position is closer than this to the border, pixels (the
    /// geometry module's 5 px).
    pub border_px: f32,
    /// A track counts only when tracking it forward again lands within this many pixels of the
    /// keypoint (ours: 0.5). Measurements: docs/measurements.md.
    pub max_fb_error_px: f32,
    /// A culled keypoint whose residual is at most this is kept (ours: 0.5 px, half the
    /// outlier threshold). Measurements: docs/measurements.md.
    pub keep_below_px: f32,
    /// A kept keypoint inside a dynamic box whose residual exceeds this is culled (ours; off
    /// with infinity: at 1 px it culled background next to the silhouette, whose LK window
    /// holds part of the mover). Measurements: docs/measurements.md.
    pub cull_above_px: f32,
    /// Let a small residual keep keypoints in whole boxes (standing people, other classes):
    /// a walker's parts move by pixels, so a keypoint that fits the background model is
    /// background seen inside the box.
    pub keep_in_whole_boxes: bool,
    /// The rules on a frame without depth (monocular), where the evidence is all there is to
    /// tell a mover from the background in its box (ours; the fields above are the rules with
    /// depth). Measurements: docs/monocular.md.
    pub without_depth: EvidenceWithoutDepth,
}

/// How the per-keypoint evidence decides on a frame without depth ([`KeypointMotionParams`]).
/// On the walking presets read monocular (`bench dynamic --no-depth --dump-keypoints`, the
/// keypoints of moving boxes) a walker's keypoints moved 5-26 px under the frame's homography
/// and the background seen inside the box 0.1-1 px, seated-split boxes included; the looser
/// bounds here keep that background and cull the mover's keypoints a static box (a table the
/// walker passes) would protect. Measurements: docs/monocular.md.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct EvidenceWithoutDepth {
    /// Use these rules on frames without depth (off: such frames follow the rules with depth,
    /// and ORB's budget mask is their whole boxes). On, the walking presets read monocular
    /// (`bench dynamic --no-depth`) cull with twice the precision, but the monocular matrix's
    /// trajectories did not gain (YOLOX rooms 2.60 -> 2.77 cm mean). Measurements:
    /// docs/monocular.md.
    pub enabled: bool,
    /// A culled keypoint whose residual is at most this is kept, pixels (1.0: the geometry
    /// module's outlier threshold).
    pub keep_below_px: f32,
    /// ... when its track came back within this many pixels (2.0: the residual already says
    /// the track fits the static world's motion).
    pub keep_max_fb_error_px: f32,
    /// Keep in a seated person's parts too (on): without depth NHBC calls most walkers close
    /// to the camera seated, and their boxes hold most of the background that is culled.
    pub keep_in_seated_parts: bool,
    /// A kept keypoint inside a dynamic box (a static box protects it, the paper's rule) whose
    /// residual exceeds this is culled, pixels (2.0).
    pub cull_above_px: f32,
    /// ... when its track came back within this many pixels (1.0).
    pub cull_max_fb_error_px: f32,
    /// A static box (a table a walker passes) protects the keypoints of a dynamic box it
    /// overlaps (the paper's rule; off): without depth the evidence above decides there, and
    /// a keypoint without evidence is culled with the mover.
    pub static_boxes_protect: bool,
    /// A culled keypoint whose track is lost or unreliable is kept when its 7x7 patch matches
    /// the previous frame's where the static world's motion (a homography, the flow) puts it
    /// with at least this normalised cross-correlation (0.9; above 1: never).
    pub patch_ncc_min: f32,
}

impl Default for EvidenceWithoutDepth {
    fn default() -> Self {
        Self {
            enabled: false,
            keep_below_px: 1.0,
            keep_max_fb_error_px: 2.0,
            keep_in_seated_parts: true,
            cull_above_px: 2.0,
            cull_max_fb_error_px: 1.0,
            static_boxes_protect: false,
            patch_ncc_min: 0.9,
        }
    }
}

/// The rules the evidence follows on one frame ([`KeypointMotionParams::rules`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EvidenceRules {
    /// Keep a culled keypoint whose residual is at most this, pixels...
    pub keep_below_px: f32,
    /// ... and whose track came back within this many pixels...
    pub keep_max_fb_error_px: f32,
    /// ... in a whole box (standing people, other classes)...
    pub keep_in_whole_boxes: bool,
    /// ... or in a seated person's part.
    pub keep_in_seated_parts: bool,
    /// Cull a kept keypoint inside a dynamic box whose residual exceeds this, pixels...
    pub cull_above_px: f32,
    /// ... and whose track came back within this many pixels.
    pub cull_max_fb_error_px: f32,
    /// Keep a culled keypoint without a reliable track whose patch is found where the static
    /// world's motion puts it, at least this correlated (above 1: never).
    pub patch_ncc_min: f32,
}

impl EvidenceRules {
    /// Whether a rule could keep a culled keypoint under `model` (the epipolar distance is blind
    /// along the epipolar line, so F keeps nothing).
    pub fn may_keep(&self, model: crate::MotionModel) -> bool {
        (self.keep_in_whole_boxes || self.keep_in_seated_parts)
            && model != crate::MotionModel::Fundamental
    }

    /// Whether a rule could cull a kept keypoint.
    pub fn may_cull(&self) -> bool {
        self.cull_above_px.is_finite()
    }
}

impl KeypointMotionParams {
    /// The rules for a frame: those without depth when `without_depth` and they are
    /// [`EvidenceWithoutDepth::enabled`], else those with depth.
    pub fn rules(&self, without_depth: bool) -> EvidenceRules {
        let w = &self.without_depth;
        if !(without_depth && w.enabled) {
            EvidenceRules {
                keep_below_px: self.keep_below_px,
                keep_max_fb_error_px: self.max_fb_error_px,
                keep_in_whole_boxes: self.keep_in_whole_boxes,
                keep_in_seated_parts: false,
                cull_above_px: self.cull_above_px,
                cull_max_fb_error_px: self.max_fb_error_px,
                patch_ncc_min: f32::INFINITY,
            }
        } else {
            EvidenceRules {
                keep_below_px: w.keep_below_px,
                keep_max_fb_error_px: w.keep_max_fb_error_px,
                keep_in_whole_boxes: self.keep_in_whole_boxes,
                keep_in_seated_parts: w.keep_in_seated_parts,
                cull_above_px: w.cull_above_px,
                cull_max_fb_error_px: w.cull_max_fb_error_px,
                patch_ncc_min: w.patch_ncc_min,
            }
        }
    }
}

impl Default for KeypointMotionParams {
    fn default() -> Self {
        Self {
            enabled: true,
            lk: LkParams {
                window: 7,
                ..LkParams::default()
            },
            border_px: 5.0,
            max_fb_error_px: 0.5,
            keep_below_px: 0.5,
            cull_above_px: f32::INFINITY,
            keep_in_whole_boxes: true,
            without_depth: EvidenceWithoutDepth::default(),
        }
    }
}
