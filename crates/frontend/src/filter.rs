//! The one place where a keypoint filter plugs into the pipeline: after ORB extraction, before
//! tracking (paper figure 2). [`KeypointFilter`] is what the pipeline calls;
//! [`crate::DynamicFrontEnd`] implements it with the detector, `dynamic::motion_consistency`,
//! `judge_boxes` and `cull_frame`; [`KeepAll`] is the baseline.

use stillpoint_image::{DepthMetres, Gray8, Rgb8};

/// What a filter decided for one frame, with the time its stages took.
#[derive(Clone, Debug, Default)]
pub struct FilterOutcome {
    /// `true` = dynamic, remove the keypoint. Same length as the keypoints.
    pub dynamic: Vec<bool>,
    /// Detector time (ms), 0 when none ran.
    pub semantic_ms: f64,
    /// The motion consistency check and the judgement and culling that follow it, the world's
    /// motion and the per-keypoint checks included (ms).
    pub geometry_ms: f64,
    /// Boxes judged dynamic.
    pub dynamic_boxes: usize,
    /// Kept keypoints that must not create map points (inside a dynamic box, kept because a
    /// static box protects them). Same length as the keypoints, or empty for none.
    pub no_new_points: Vec<bool>,
}

/// The images of one frame, as the filter needs them.
pub struct FilterInput<'a> {
    /// Position of the frame in its sequence.
    pub index: usize,
    /// Frame time, seconds.
    pub timestamp: f64,
    /// The gray image (the motion check's).
    pub gray: &'a Gray8,
    /// The colour image, when there is one (the detector's; gray x3 otherwise).
    pub rgb: Option<&'a Rgb8>,
    /// Depth in metres (RGB-D), for depth-aware culling.
    pub depth: Option<&'a DepthMetres>,
}

/// Decides which keypoints lie on moving objects.
pub trait KeypointFilter: Send {
    /// Judge the keypoints (level-0 pixels) of a frame.
    fn judge(&mut self, frame: &FilterInput, keypoints: &[[f32; 2]]) -> FilterOutcome;
    /// Short name for logs.
    fn name(&self) -> &str;
    /// The pose tracking gave frame `index` (camera-to-world; `None` when it was not tracked),
    /// called after each frame: a filter that judges motion against the static world predicts
    /// the next frame's camera motion from these (the map's constant-velocity prior).
    fn observe_pose(&mut self, _index: usize, _pose_wc: Option<&stillpoint_geometry::Se3>) {}
}

/// The baseline: keeps everything (`--no-dynamic`).
pub struct KeepAll;

impl KeypointFilter for KeepAll {
    fn judge(&mut self, _frame: &FilterInput, keypoints: &[[f32; 2]]) -> FilterOutcome {
        FilterOutcome {
            dynamic: vec![false; keypoints.len()],
            ..Default::default()
        }
    }
    fn name(&self) -> &str {
        "none"
    }
}
