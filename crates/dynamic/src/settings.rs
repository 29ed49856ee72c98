//! Every parameter of the dynamic front-end, with the paper's (or the authors' code's) defaults.

use stillpoint_features::{CornerParams, LkParams};
use stillpoint_geometry::fundamental::FundamentalRansac;

/// All settings of this crate: the geometry module, the box judgement and the culling.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DynamicSettings {
    pub geometry: GeometryParams,
    pub judge: JudgeParams,
    pub cull: CullParams,
}

/// The motion consistency check (paper section 2, module 2; DS-SLAM's `ProcessMovingObject`).
#[derive(Clone, Debug, PartialEq)]
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
    /// The camera counts as still, and the homography is used whatever F explains, when 90 % of
    /// the homography's inliers moved less than this many pixels (ours; default 1.0 px, the
    /// outlier threshold: parallax cannot exceed the flow of the nearest static point). This
    /// catches a static camera watching a large rigid mover, which the ratio above cannot.
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
#[derive(Clone, Debug, PartialEq)]
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
    /// ATA: a non-person box is dynamic when outliers / tracked points inside exceed this
    /// (paper's ε = 0.4).
    pub ata_ratio: f32,
    /// A box with fewer successfully tracked points inside than this (and not dynamic by NHBC)
    /// is [`crate::Verdict::StaticUnknown`] (ours: the authors divide by zero and get NaN, which
    /// compares as static). 1 keeps the paper's behaviour for every non-empty box.
    pub min_tracked: usize,
    /// ATA ignores tracked points that lie inside a person box (ours, off by default = paper):
    /// those belong to the person NHBC judges, and a walker passing in front of a table would
    /// otherwise make the table "dynamic" by its outliers.
    pub ata_ignores_person_points: bool,
}

impl Default for JudgeParams {
    fn default() -> Self {
        Self {
            person_class: 0,
            seated_max_aspect: 3.0,
            seated_top_fraction: 1.0 / 1.3,
            person_min_outliers: 1,
            ata_ratio: 0.4,
            min_tracked: 1,
            ata_ignores_person_points: false,
        }
    }
}

/// Culling (paper algorithm 3) and the optional culling near unexplained outliers.
#[derive(Clone, Debug, PartialEq)]
pub struct CullParams {
    /// Whether a [`crate::Verdict::Static`] box protects the keypoints inside it (paper
    /// algorithm 3: yes). Off only to measure what the protection costs in recall.
    pub static_box_protects: bool,
    /// Whether a [`crate::Verdict::StaticUnknown`] box protects the keypoints inside it like a
    /// static one (paper: yes, NaN → static). Default true.
    pub unknown_box_protects: bool,
    /// Also cull keypoints near geometric outliers that lie in no box: the paper's "unknown
    /// dynamic objects" (ours, off by default; see the bench for whether it pays).
    pub unknown_objects: bool,
    /// Radius around such outliers in pixels (ours).
    pub unknown_radius_px: f32,
    /// Fewest box-less outliers within the radius of a keypoint to cull it; 2 ignores isolated
    /// bad tracks (ours).
    pub unknown_min_outliers: usize,
}

impl Default for CullParams {
    fn default() -> Self {
        Self {
            static_box_protects: true,
            unknown_box_protects: true,
            unknown_objects: false,
            unknown_radius_px: 20.0,
            unknown_min_outliers: 2,
        }
    }
}
