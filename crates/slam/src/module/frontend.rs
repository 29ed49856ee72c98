//! The one place where the dynamic front-end plugs in: after ORB extraction, before anything
//! else (paper figure 2). The slam crate does not know how keypoints are judged; the
//! `stillpoint-frontend` crate implements [`KeypointFilter`] with `dynamic::motion_consistency` +
//! the detector + `judge_boxes` + `cull_frame`.

use stillpoint_image::{DepthMetres, Gray8, Rgb8};

use crate::{Descriptor, Feature};

/// What a filter decided for one frame, with the time its stages took.
#[derive(Clone, Debug, Default)]
pub struct FilterOutcome {
    /// `true` = dynamic, remove the keypoint. Same length as the keypoints.
    pub dynamic: Vec<bool>,
    /// Detector time (ms), 0 when none ran.
    pub semantic_ms: f64,
    /// Motion consistency check time (ms).
    pub geometry_ms: f64,
    /// Boxes judged dynamic.
    pub dynamic_boxes: usize,
    /// Kept keypoints that must not create map points (inside a dynamic box, kept because a
    /// static box protects them). Same length as the keypoints, or empty for none.
    pub no_new_points: Vec<bool>,
}

/// The images of one frame, as the filter needs them.
pub struct FilterInput<'a> {
    pub index: usize,
    pub timestamp: f64,
    pub gray: &'a Gray8,
    pub rgb: Option<&'a Rgb8>,
    /// Depth in metres (RGB-D), for depth-aware culling.
    pub depth: Option<&'a DepthMetres>,
}

/// Decides which keypoints lie on moving objects.
pub trait KeypointFilter: Send {
    /// Judge the keypoints (level-0 pixels) of a frame.
    fn judge(&mut self, frame: &FilterInput, keypoints: &[[f32; 2]]) -> FilterOutcome;
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

/// Remove the keypoints flagged dynamic; returns how many were removed. A mask of the wrong
/// length is ignored (nothing removed) rather than trusted.
pub fn remove_dynamic(
    features: &mut Vec<Feature>,
    descriptors: &mut Vec<Descriptor>,
    dynamic: &[bool],
) -> usize {
    if dynamic.len() != features.len() || descriptors.len() != features.len() {
        return 0;
    }
    let before = features.len();
    let mut k = 0;
    features.retain(|_| {
        k += 1;
        !dynamic[k - 1]
    });
    let mut k = 0;
    descriptors.retain(|_| {
        k += 1;
        !dynamic[k - 1]
    });
    before - features.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn removes_flagged_keypoints_and_ignores_bad_masks() {
        let f = |x| Feature {
            x,
            y: 0.0,
            octave: 0,
            angle: 0.0,
        };
        let mut feats = vec![f(1.0), f(2.0), f(3.0)];
        let mut descs = vec![[1u8; 32], [2u8; 32], [3u8; 32]];
        assert_eq!(remove_dynamic(&mut feats, &mut descs, &[false, true]), 0);
        assert_eq!(
            remove_dynamic(&mut feats, &mut descs, &[false, true, false]),
            1
        );
        assert_eq!(feats, vec![f(1.0), f(3.0)]);
        assert_eq!(descs, vec![[1u8; 32], [3u8; 32]]);
    }
}
