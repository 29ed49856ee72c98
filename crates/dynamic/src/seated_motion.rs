//! Per-keypoint 3D motion test inside seated people's parts (ours, RGB-D only).
//!
//! NHBC splits a seated person into a top and a bottom part, and a part holding one outlier
//! (a hand) is dynamic as a whole: its still torso and legs are culled with it. On synth
//! sitting_xyz that cull made the trajectory worse than no front-end at all. The two-view
//! models of [`crate::keypoint_motion`](mod@crate::keypoint_motion) cannot tell which
//! keypoints moved: the epipolar distance is blind along the epipolar line. With depth it is
//! not: the camera's motion between the two frames comes from the static tracks (inliers of the
//! geometry check outside every dynamic box, lifted with the depth of both frames; 3-point
//! rigid fits, [`umeyama`], in an MSAC RANSAC, polished on the reprojection error), and each
//! culled keypoint of a seated part, lifted with its depth and moved back into the previous
//! frame, must land where backward LK found it.
//! A keypoint whose reprojection residual exceeds [`SeatedMotionParams::dynamic_above_px`]
//! moved in the world; one below it is kept. Keypoints without a reliable track or depth,
//! frames without depth or without a camera estimate keep the box decision. Standing people
//! and other classes (whole boxes) keep the box rule.
//!
//! What bounds its precision: still keypoints whose patch straddles a depth edge (the torso's
//! silhouette against the wall, the chair, the desk) often measure above the threshold, even
//! with the true camera motion. At an edge a pixel's colour mixes two surfaces that move apart
//! by the parallax and get covered or uncovered between frames; a real sensor's depth,
//! misregistered by a pixel or two at edges, makes this worse. Measurements:
//! docs/measurements.md.

use crate::judge::{BoxPart, BoxState, only_in_dynamic_boxes_where};
use crate::keypoint_motion::KeypointMotion;
use crate::motion_consistency::TrackedPoint;
use stillpoint_geometry::{PinholeCamera, Se3, Vec2, Vec3, refine_pose_reprojection, umeyama};
use stillpoint_image::DepthMetres;

/// Parameters of the seated-part 3D motion test (all ours).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct SeatedMotionParams {
    /// Run the test (needs depth on both frames and [`Self::camera`]): it keeps the still
    /// torso and legs of a seated person whose hand moved. Measurements: docs/measurements.md.
    pub enabled: bool,
    /// The camera that took the frames (intrinsics for lifting and projecting).
    #[serde(skip)]
    pub camera: Option<PinholeCamera>,
    /// A keypoint whose reprojection residual exceeds this moved (pixels). Default 0.5 px,
    /// above what still torsos measure. Measurements: docs/measurements.md.
    pub dynamic_above_px: f32,
    /// A static track is an inlier of the camera motion within this reprojection error (px).
    pub inlier_px: f32,
    /// Fewer inliers than this: no camera motion, the box decision stands.
    pub min_inliers: usize,
    /// RANSAC iterations of the 3-point rigid fit.
    pub iterations: usize,
    /// Depth values outside this range (metres) are not used.
    pub depth_range: [f32; 2],
    /// A keypoint needs smooth depth (no depth edge in its 3x3 window) to be tested: keypoints on
    /// a silhouette, whose pixel may take the background's depth, keep the box decision.
    pub keypoint_smooth_depth: bool,
    /// Backward-forward LK error above this makes a track unreliable (pixels).
    pub max_fb_error_px: f32,
}

impl Default for SeatedMotionParams {
    fn default() -> Self {
        Self {
            enabled: true,
            camera: None,
            dynamic_above_px: 0.5,
            inlier_px: 1.0,
            min_inliers: 12,
            iterations: 64,
            depth_range: [0.1, 10.0],
            max_fb_error_px: 0.5,
            keypoint_smooth_depth: true,
        }
    }
}

/// Depth at the pixel nearest `p`, when valid and smooth: every pixel of the 3x3 window within
/// [`DEPTH_EDGE_SHARE`] of the centre (corners sit on depth edges, where rounding the position
/// picks either side).
pub(crate) fn smooth_depth_at(depth: &DepthMetres, p: [f32; 2], range: [f32; 2]) -> Option<f64> {
    let z = depth_at(depth, p, range)? as f32;
    let (x, y) = (p[0].round() as isize, p[1].round() as isize);
    for dy in -1..=1 {
        for dx in -1..=1 {
            let n = depth.get_checked(x + dx, y + dy)?;
            let smooth = (n - z).abs() <= DEPTH_EDGE_SHARE * z; // false for NaN too
            if !smooth {
                return None;
            }
        }
    }
    Some(z as f64)
}

/// Depth at the pixel nearest `p`, when valid.
fn depth_at(depth: &DepthMetres, p: [f32; 2], range: [f32; 2]) -> Option<f64> {
    let z = depth.get_checked(p[0].round() as isize, p[1].round() as isize)?;
    (z.is_finite() && z >= range[0] && z <= range[1]).then_some(z as f64)
}

/// Largest relative depth step inside a 3x3 window that still counts as smooth.
const DEPTH_EDGE_SHARE: f32 = 0.02;

pub(crate) fn lift(cam: &PinholeCamera, p: [f32; 2], z: f64) -> Vec3 {
    cam.unproject(&Vec2::new(p[0] as f64, p[1] as f64), z)
}

pub(crate) fn reprojection(cam: &PinholeCamera, t: &Se3, p: &Vec3, px: [f32; 2]) -> f64 {
    match cam.project(&(t.rotation * p + t.translation.vector)) {
        Some(q) => ((q.x - px[0] as f64).powi(2) + (q.y - px[1] as f64).powi(2)).sqrt(),
        None => f64::INFINITY,
    }
}

/// The camera's motion from the previous frame to the current one (maps previous-camera
/// coordinates to current-camera coordinates), from the static tracks: inliers of the geometry
/// check in no dynamic box with valid depth in both frames. A deterministic 3-point RANSAC on
/// [`umeyama`] scored MSAC-style by reprojection into the current frame (standing still is a
/// hypothesis too), then Gauss-Newton on the reprojection error ([`refine_pose_reprojection`]),
/// robust over all tracks, plain over its inliers: at 30 fps the camera moves a few
/// millimetres, less than the depth errors a 3D-3D fit follows. `None` with too few inliers.
/// Measurements: docs/measurements.md.
pub fn camera_motion(
    tracked: &[TrackedPoint],
    states: &[BoxState],
    prev_depth: &DepthMetres,
    cur_depth: &DepthMetres,
    p: &SeatedMotionParams,
) -> Option<Se3> {
    let cam = p.camera.as_ref()?;
    let mut src = Vec::new();
    let mut dst = Vec::new();
    let mut cur_px = Vec::new();
    for t in tracked.iter().filter(|t| !t.outlier) {
        let [x, y] = t.cur;
        if states
            .iter()
            .any(|s| s.is_dynamic() && s.bbox.contains_strict(x, y))
        {
            continue;
        }
        let (Some(z0), Some(z1)) = (
            smooth_depth_at(prev_depth, t.prev, p.depth_range),
            smooth_depth_at(cur_depth, t.cur, p.depth_range),
        ) else {
            continue;
        };
        src.push(lift(cam, t.prev, z0));
        dst.push(lift(cam, t.cur, z1));
        cur_px.push(t.cur);
    }
    let n = src.len();
    if n < p.min_inliers.max(3) {
        return None;
    }
    let th = p.inlier_px as f64;
    let inliers_of = |t: &Se3| -> Vec<usize> {
        (0..n)
            .filter(|&i| reprojection(cam, t, &src[i], cur_px[i]) <= th)
            .collect()
    };
    // MSAC: a model is scored by its truncated squared residuals, not its inlier count. At
    // 30 fps the camera moves ~1 px between frames, so with an inlier count every model within
    // a pixel of the truth ties, and a wrong one (1 cm off on synth sitting_xyz) often won.
    let cost_of = |t: &Se3| -> f64 {
        (0..n)
            .map(|i| {
                reprojection(cam, t, &src[i], cur_px[i])
                    .powi(2)
                    .min(th * th)
            })
            .sum()
    };
    let best = best_rigid_hypothesis(&src, &dst, p.iterations, cost_of);
    // Polish by the reprojection error (a 3D-3D fit follows the depth errors, which on a
    // slanted surface are centimetres against the camera's few millimetres), first robustly
    // over every track, then on the inliers of that.
    let cur: Vec<Vec2> = cur_px
        .iter()
        .map(|q| Vec2::new(q[0] as f64, q[1] as f64))
        .collect();
    let robust = refine_pose_reprojection(cam, &src, &cur, &best.1, th, 10)?;
    let inliers = inliers_of(&robust);
    if inliers.len() < p.min_inliers {
        return None;
    }
    let s: Vec<Vec3> = inliers.iter().map(|&i| src[i]).collect();
    let c: Vec<Vec2> = inliers.iter().map(|&i| cur[i]).collect();
    let model = refine_pose_reprojection(cam, &s, &c, &robust, f64::INFINITY, 10)?;
    (inliers_of(&model).len() >= p.min_inliers).then_some(model)
}

/// The reprojection residual of one keypoint: lifted with the current depth, moved back by the
/// camera motion `prev_to_cur`, projected into the previous frame and compared with its backward
/// LK track. `None` without depth or a reliable track.
pub fn seated_residual(
    keypoint: [f32; 2],
    motion: &KeypointMotion,
    prev_to_cur: &Se3,
    cur_depth: &DepthMetres,
    p: &SeatedMotionParams,
) -> Option<f32> {
    let cam = p.camera.as_ref()?;
    let reliable = motion.fb_error <= p.max_fb_error_px; // false for NaN too
    if !reliable {
        return None;
    }
    let z = if p.keypoint_smooth_depth {
        smooth_depth_at(cur_depth, keypoint, p.depth_range)?
    } else {
        depth_at(cur_depth, keypoint, p.depth_range)?
    };
    let r = reprojection(
        cam,
        &prev_to_cur.inverse(),
        &lift(cam, keypoint, z),
        motion.prev,
    );
    r.is_finite().then_some(r as f32)
}

/// True for culled keypoints whose dynamic boxes are all seated parts (NHBC split): the
/// candidates of the test.
pub fn seated_candidates(
    keypoints: &[[f32; 2]],
    removed: &[bool],
    states: &[BoxState],
) -> Vec<bool> {
    keypoints
        .iter()
        .zip(removed)
        .map(|(&kp, &r)| r && only_in_dynamic_boxes_where(states, kp, |s| s.part != BoxPart::Whole))
        .collect()
}

/// Keep the candidates whose residual shows no motion; the rest keep `removed`. Returns the
/// new decision and how many keypoints were kept.
pub fn apply_seated_motion(
    keypoints: &[[f32; 2]],
    removed: &[bool],
    candidates: &[bool],
    motion: &[Option<KeypointMotion>],
    prev_to_cur: &Se3,
    cur_depth: &DepthMetres,
    p: &SeatedMotionParams,
) -> (Vec<bool>, usize) {
    let mut kept = 0;
    let out = keypoints
        .iter()
        .enumerate()
        .map(|(i, &kp)| {
            let was = removed.get(i).copied().unwrap_or(false);
            if !(was && candidates.get(i).copied().unwrap_or(false)) {
                return was;
            }
            let Some(m) = motion.get(i).copied().flatten() else {
                return was;
            };
            match seated_residual(kp, &m, prev_to_cur, cur_depth, p) {
                Some(r) if r <= p.dynamic_above_px => {
                    kept += 1;
                    false
                }
                _ => was,
            }
        })
        .collect();
    (out, kept)
}

/// The rigid motion of lowest `cost_of` among the still camera (a static camera has no 3-point
/// fit) and `iterations` 3-point Umeyama fits `src[i] -> dst[i]`, sampled deterministically
/// (xorshift seeded by the point count: the same frames give the same decision).
pub(crate) fn best_rigid_hypothesis(
    src: &[Vec3],
    dst: &[Vec3],
    iterations: usize,
    cost_of: impl Fn(&Se3) -> f64,
) -> (f64, Se3) {
    let n = src.len().min(dst.len());
    let mut best = (cost_of(&Se3::identity()), Se3::identity());
    if n < 3 {
        return best;
    }
    let mut state = 0x9e37_79b9_7f4a_7c15_u64 ^ n as u64;
    let mut next = |m: usize| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state % m as u64) as usize
    };
    for _ in 0..iterations {
        let (a, b, c) = (next(n), next(n), next(n));
        if a == b || b == c || a == c {
            continue;
        }
        let Some(fit) = umeyama(&[src[a], src[b], src[c]], &[dst[a], dst[b], dst[c]], false) else {
            continue;
        };
        let cost = cost_of(&fit.rigid);
        if cost < best.0 {
            best = (cost, fit.rigid);
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::judge::{Rule, Verdict};
    use crate::motion_consistency::MotionModel;
    use stillpoint_geometry::BBox;

    fn cam() -> PinholeCamera {
        PinholeCamera::new(500.0, 500.0, 160.0, 120.0, 320, 240)
    }

    #[test]
    fn camera_motion_from_static_tracks_and_residual_sees_motion_along_any_direction() {
        let c = cam();
        let depth = DepthMetres::new(320, 240, 2.0);
        // The camera moved 2 cm along x: a point at depth 2 m shifts by -5 px.
        let motion = Se3::translation(-0.02, 0.0, 0.0);
        let mut tracked = Vec::new();
        for y in (20..220).step_by(20) {
            for x in (20..300).step_by(20) {
                tracked.push(static_track(&c, &motion, [x as f32, y as f32], 2.0));
            }
        }
        let p = SeatedMotionParams {
            enabled: true,
            camera: Some(c),
            ..Default::default()
        };
        let t = camera_motion(&tracked, &[], &depth, &depth, &p).expect("camera motion");
        assert!((t.translation.vector - motion.translation.vector).norm() < 1e-6);
        // A still keypoint: its backward track is the camera's shift; a hand that moved 2 px
        // along the flow (the epipolar line) is caught.
        let ev = |prev| KeypointMotion {
            prev,
            residual: 0.0,
            fb_error: 0.05,
            model: MotionModel::Fundamental,
        };
        let still = seated_residual([100.0, 100.0], &ev([105.0, 100.0]), &t, &depth, &p).unwrap();
        let moved = seated_residual([100.0, 100.0], &ev([107.0, 100.0]), &t, &depth, &p).unwrap();
        assert!(
            still < 0.01 && (moved - 2.0).abs() < 0.01,
            "{still} {moved}"
        );
        // Only culled keypoints in seated parts are candidates; the moved one stays culled.
        let part = |part| BoxState {
            bbox: BBox::new(50.0, 50.0, 150.0, 150.0),
            class_id: 0,
            detection: 0,
            part,
            rule: Rule::Nhbc,
            verdict: Verdict::Dynamic,
            tracked: 10,
            outliers: 1,
            depth: None,
        };
        let kps = [[100.0, 100.0], [100.0, 100.0], [200.0, 200.0]];
        let cand = seated_candidates(&kps, &[true, true, false], &[part(BoxPart::SeatedTop)]);
        assert_eq!(cand, vec![true, true, false]);
        let whole = seated_candidates(&kps, &[true, true, false], &[part(BoxPart::Whole)]);
        assert_eq!(whole, vec![false; 3]);
        let motion = [Some(ev([105.0, 100.0])), Some(ev([107.0, 100.0])), None];
        let (removed, kept) =
            apply_seated_motion(&kps, &[true, true, false], &cand, &motion, &t, &depth, &p);
        assert_eq!((removed, kept), (vec![false, true, false], 1));
        // No depth (zeros), no camera, too few tracks: no evidence, the box decision stands.
        let empty = DepthMetres::new(320, 240, 0.0);
        assert!(seated_residual([100.0, 100.0], &ev([105.0, 100.0]), &t, &empty, &p).is_none());
        assert!(camera_motion(&tracked, &[], &empty, &depth, &p).is_none());
        assert!(camera_motion(&tracked[..5], &[], &depth, &depth, &p).is_none());
        let no_cam = SeatedMotionParams::default();
        assert!(camera_motion(&tracked, &[], &depth, &depth, &no_cam).is_none());
    }

    #[test]
    fn camera_motion_of_a_few_millimetres_survives_centimetre_depth_errors() {
        // As on synth sitting_xyz: 4 mm between frames, a wall 2-2.4 m away whose depth map is
        // off by up to +-3 cm per pixel (a slanted surface read at rounded pixels, or a Kinect).
        // A 3D-3D fit follows those errors; the reprojection polish does not.
        let c = cam();
        let truth = Se3::translation(-0.0042, -0.0006, -0.0011);
        let true_z = |x: f32, y: f32| 2.0 + 0.4 * (x / 320.0) as f64 + 0.1 * (y / 240.0) as f64;
        let mut depth = DepthMetres::new(320, 240, 0.0);
        for y in 0..240 {
            for x in 0..320 {
                depth.set(x, y, true_z(x as f32, y as f32) as f32);
            }
        }
        let mut prev_depth = depth.clone();
        let mut tracked = Vec::new();
        for (k, y) in (20..220).step_by(25).enumerate() {
            for (j, x) in (20..300).step_by(25).enumerate() {
                let prev = [x as f32, y as f32];
                tracked.push(static_track(&c, &truth, prev, true_z(prev[0], prev[1])));
                // Each 3x3 patch of the previous depth map is off by a different few cm.
                let dz = [0.03, -0.025, 0.015, -0.03, 0.02][(k * 3 + j) % 5];
                for yy in y - 1..=y + 1 {
                    for xx in x - 1..=x + 1 {
                        let z = prev_depth.get(xx, yy);
                        prev_depth.set(xx, yy, z + dz);
                    }
                }
            }
        }
        let p = SeatedMotionParams {
            enabled: true,
            camera: Some(c),
            ..Default::default()
        };
        let t = camera_motion(&tracked, &[], &prev_depth, &depth, &p).expect("camera motion");
        let err = (t.translation.vector - truth.translation.vector).norm();
        assert!(err < 5e-4, "translation off by {err} m");
        // A still point at 1.5 m then measures well under the 0.5 px threshold.
        let kp = [160.0f32, 120.0];
        let seen = c.project(&lift(&c, kp, 1.5)).unwrap();
        let prev = c
            .project(&apply(&truth.inverse(), lift(&c, kp, 1.5)))
            .unwrap();
        assert!((seen.x - kp[0] as f64).abs() < 1e-9);
        let near = DepthMetres::new(320, 240, 1.5);
        let ev = KeypointMotion {
            prev: [prev.x as f32, prev.y as f32],
            residual: 0.0,
            fb_error: 0.05,
            model: MotionModel::Homography,
        };
        let r = seated_residual(kp, &ev, &t, &near, &p).unwrap();
        assert!(r < 0.1, "still point measured {r} px");
    }

    fn apply(t: &Se3, v: Vec3) -> Vec3 {
        t.rotation * v + t.translation.vector
    }

    /// The track of a static point seen at `prev` with depth `z` when the camera moves by
    /// `motion` (previous-camera to current-camera coordinates).
    fn static_track(c: &PinholeCamera, motion: &Se3, prev: [f32; 2], z: f64) -> TrackedPoint {
        let q = c.project(&apply(motion, lift(c, prev, z))).unwrap();
        TrackedPoint {
            prev,
            cur: [q.x as f32, q.y as f32],
            epipolar_distance: 0.0,
            outlier: false,
        }
    }
}
