//! Culling, paper algorithm 3: a keypoint of the current frame is removed when it lies in some
//! dynamic box and in no static box. Static person parts count as static boxes, so a seated
//! person's legs, and a static chair or keyboard in front of a moving person, keep their points.

use crate::judge::{BoxState, Verdict};
use crate::motion_consistency::TrackedPoint;
use crate::settings::CullParams;

/// The paper's culling, algorithm 3 exactly (no tracked points are passed, so the unknown-object
/// rule of [`CullParams`] never fires): `true` = dynamic, remove the keypoint.
///
/// ```
/// use stillpoint_dynamic::{BoxPart, BoxState, Rule, Verdict, cull};
/// use stillpoint_geometry::BBox;
/// let person = BoxState { bbox: BBox::new(0.0, 0.0, 100.0, 300.0), class_id: 0, detection: 0,
///     part: BoxPart::Whole, rule: Rule::Nhbc, verdict: Verdict::Dynamic, tracked: 9, outliers: 3, depth: None };
/// let chair = BoxState { bbox: BBox::new(50.0, 200.0, 150.0, 320.0), class_id: 56, detection: 1,
///     part: BoxPart::Whole, rule: Rule::Ata, verdict: Verdict::Static, tracked: 10, outliers: 1, depth: None };
/// let removed = cull(&[[20.0, 20.0], [80.0, 250.0], [400.0, 10.0]], &[person, chair]);
/// assert_eq!(removed, vec![true, false, false]); // on the person / on the chair / elsewhere
/// ```
pub fn cull(keypoints: &[[f32; 2]], states: &[BoxState]) -> Vec<bool> {
    cull_with(keypoints, states, &[], &CullParams::default())
}

/// [`cull`] with explicit settings; `tracked` (the geometry module's points) is only read when
/// [`CullParams::unknown_objects`] is on: then keypoints with at least
/// `unknown_min_outliers` outliers that lie in no box within `unknown_radius_px` are culled too,
/// unless a static box holds them.
pub fn cull_with(
    keypoints: &[[f32; 2]],
    states: &[BoxState],
    tracked: &[TrackedPoint],
    p: &CullParams,
) -> Vec<bool> {
    let protects = |s: &BoxState| match s.verdict {
        Verdict::Static => p.static_box_protects,
        Verdict::StaticUnknown => p.unknown_box_protects,
        Verdict::Dynamic => false,
    };
    let boxless_outliers: Vec<[f32; 2]> = if p.unknown_objects {
        tracked
            .iter()
            .filter(|t| t.outlier)
            .filter(|t| {
                !states
                    .iter()
                    .any(|s| s.bbox.contains_strict(t.cur[0], t.cur[1]))
            })
            .map(|t| t.cur)
            .collect()
    } else {
        Vec::new()
    };
    keypoints
        .iter()
        .map(|&[x, y]| {
            let inside = |s: &&BoxState| s.bbox.contains_strict(x, y);
            if states.iter().filter(inside).any(protects) {
                return false;
            }
            states.iter().filter(inside).any(BoxState::is_dynamic)
                || (p.unknown_objects
                    && count_within(&boxless_outliers, [x, y], p.unknown_radius_px)
                        >= p.unknown_min_outliers.max(1))
        })
        .collect()
}

/// The detection-free rule (a baseline for the bench, and the core of the unknown-object option):
/// `true` for each keypoint with at least `min_outliers` geometric outliers within `radius_px`.
pub fn near_outliers(
    keypoints: &[[f32; 2]],
    tracked: &[TrackedPoint],
    radius_px: f32,
    min_outliers: usize,
) -> Vec<bool> {
    let outliers: Vec<[f32; 2]> = tracked
        .iter()
        .filter(|t| t.outlier)
        .map(|t| t.cur)
        .collect();
    keypoints
        .iter()
        .map(|&k| count_within(&outliers, k, radius_px) >= min_outliers.max(1))
        .collect()
}

fn count_within(points: &[[f32; 2]], at: [f32; 2], radius: f32) -> usize {
    let r2 = radius * radius;
    points
        .iter()
        .filter(|q| {
            let (dx, dy) = (q[0] - at[0], q[1] - at[1]);
            dx * dx + dy * dy <= r2
        })
        .count()
}
