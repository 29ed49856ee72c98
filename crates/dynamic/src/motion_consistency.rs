//! The geometry module: motion consistency check between the previous and the current grayscale
//! frame (paper section 2, module 2; DS-SLAM's `ProcessMovingObject`, which the authors reuse).
//!
//! Steps, as the authors' code:
//! 1. Harris corners on the previous frame, refined to sub-pixel;
//! 2. pyramidal LK into the current frame, failed tracks dropped;
//! 3. pairs with a point within 5 px of the border, or whose 3x3 patches differ by a sum of
//!    absolute differences above 2120, dropped;
//! 4. F by RANSAC (0.1 px, 0.99);
//! 5. outlier when the distance of the current point to the epipolar line of the previous one
//!    exceeds 1 px.
//!
//! Where we differ, and why:
//! - F is refit on the RANSAC inliers (the authors keep OpenCV's best minimal-sample model);
//! - too few pairs, or no F (degenerate samples), never yields an empty or garbage F: the check
//!   falls back to a homography, then to the flow, and says so in [`MotionCheck::model`];
//! - when a homography explains the points as well as F does (static or purely rotating camera,
//!   no measurable parallax), F is not determined by the static scene and RANSAC may align its
//!   epipolar lines with a moving person; then the homography's transfer error is used instead
//!   ([`GeometryParams::homography_support_ratio`]).

use crate::settings::GeometryParams;
use serde::Serialize;
use stillpoint_features::{LkPyramid, good_features_to_track, track_lk, track_lk_pyramids};
use stillpoint_geometry::fundamental::fundamental_ransac;
use stillpoint_geometry::homography::{HomographyRansac, homography_ransac, transfer_error2};
use stillpoint_geometry::{Mat3, Vec2, epipolar_distance};
use stillpoint_image::Gray8;

/// One corner tracked from the previous into the current frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct TrackedPoint {
    /// Position in the previous frame (pixels).
    pub prev: [f32; 2],
    /// Position in the current frame (pixels).
    pub cur: [f32; 2],
    /// Residual under [`MotionCheck::model`] in pixels: distance to the epipolar line (F), transfer
    /// error (homography), or distance of the flow from the median flow (flow).
    pub epipolar_distance: f32,
    /// Residual above [`GeometryParams::outlier_threshold_px`]: the point moved in the world.
    pub outlier: bool,
}

/// Which motion model judged the points.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum MotionModel {
    /// Epipolar distance to the fundamental matrix (the paper's check).
    Fundamental,
    /// Transfer error of a homography (no parallax, or too few points for F).
    Homography,
    /// Distance of each flow vector from the median flow (too few points for a homography).
    Flow,
    /// Nothing could be estimated; no point is an outlier.
    None,
}

/// Time spent per stage, milliseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct GeometryTimings {
    /// Harris corners on the previous frame.
    pub corners_ms: f64,
    /// Pyramidal Lucas-Kanade.
    pub lk_ms: f64,
    /// Border and patch checks.
    pub checks_ms: f64,
    /// Fitting the motion model and the epipolar test.
    pub model_ms: f64,
}

impl GeometryTimings {
    /// Sum of the stages.
    pub fn total_ms(&self) -> f64 {
        self.corners_ms + self.lk_ms + self.checks_ms + self.model_ms
    }
}

/// The result of [`motion_consistency`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MotionCheck {
    /// Pairs that survived tracking, border and patch checks, each judged.
    pub points: Vec<TrackedPoint>,
    /// The model the points were judged against (F, H, flow, none).
    pub model: MotionModel,
    /// Corners found on the previous frame.
    pub corners: usize,
    /// Corners LK lost.
    pub lk_failed: usize,
    /// Pairs dropped by the border check.
    pub border_rejected: usize,
    /// Pairs dropped by the patch check.
    pub patch_rejected: usize,
    /// Why a fallback model (or none) was used; `None` for the paper's F.
    pub fallback_reason: Option<&'static str>,
    /// The model matrix (F or H; `None` for flow or none).
    #[serde(skip)]
    pub matrix: Option<Mat3>,
    /// Time per stage.
    pub timings: GeometryTimings,
}

impl MotionCheck {
    fn empty(reason: &'static str) -> Self {
        Self {
            points: Vec::new(),
            model: MotionModel::None,
            corners: 0,
            lk_failed: 0,
            border_rejected: 0,
            patch_rejected: 0,
            fallback_reason: Some(reason),
            matrix: None,
            timings: GeometryTimings::default(),
        }
    }

    /// Number of outliers.
    pub fn outliers(&self) -> usize {
        self.points.iter().filter(|t| t.outlier).count()
    }
}

/// Run the motion consistency check from `prev` to `cur` (same size, grayscale). Never panics:
/// empty or differently sized images give [`MotionModel::None`] with no points.
///
/// ```
/// use stillpoint_dynamic::{GeometryParams, MotionModel, motion_consistency};
/// use stillpoint_image::Gray8;
/// let mut img = Gray8::new(160, 120, 0);
/// for y in 0..120 { for x in 0..160 {
///     img.set(x, y, ((x / 8 * 37 + y / 8 * 91) % 200 + 20) as u8);
/// }}
/// let check = motion_consistency(&img, &img, &GeometryParams::default());
/// assert_eq!(check.model, MotionModel::Homography); // a static camera: F is undefined
/// assert_eq!(check.outliers(), 0);
/// ```
pub fn motion_consistency(prev: &Gray8, cur: &Gray8, p: &GeometryParams) -> MotionCheck {
    if let Some(reason) = bad_pair(prev, cur) {
        return MotionCheck::empty(reason);
    }
    let clock = std::time::Instant::now();
    let corners = good_features_to_track(prev, &p.corners);
    let t_corners = clock.elapsed();
    let tracks = track_lk(prev, cur, &corners, &p.lk);
    judge_tracks(prev, cur, &corners, &tracks, p, clock, t_corners)
}

/// [`motion_consistency`] on LK pyramids the caller already built, so that a streaming caller
/// builds each frame's pyramid once ([`LkPyramid::new`], with gradients) and keeps the current
/// one as the next frame's previous one; the same pyramids serve
/// [`crate::keypoint_motion()`]. Same result as [`motion_consistency`]. Pyramids that do not
/// match the images (other size, built empty) give [`MotionModel::None`], never a panic.
///
/// ```
/// use stillpoint_dynamic::{GeometryParams, motion_consistency, motion_consistency_pyramids};
/// use stillpoint_features::LkPyramid;
/// use stillpoint_image::Gray8;
/// let mut img = Gray8::new(160, 120, 0);
/// for y in 0..120 { for x in 0..160 {
///     img.set(x, y, ((x / 8 * 37 + y / 8 * 91) % 200 + 20) as u8);
/// }}
/// let p = GeometryParams::default();
/// let pyr = LkPyramid::new(&img, &p.lk); // keep it: next frame's previous pyramid
/// let check = motion_consistency_pyramids(&img, &img, &pyr, &pyr, &p);
/// assert_eq!(check.points, motion_consistency(&img, &img, &p).points);
/// ```
pub fn motion_consistency_pyramids(
    prev: &Gray8,
    cur: &Gray8,
    prev_pyr: &LkPyramid,
    cur_pyr: &LkPyramid,
    p: &GeometryParams,
) -> MotionCheck {
    if let Some(reason) = bad_pair(prev, cur) {
        return MotionCheck::empty(reason);
    }
    let size = (prev.width, prev.height);
    if prev_pyr.size() != size || cur_pyr.size() != size {
        return MotionCheck::empty("LK pyramids do not match the frames");
    }
    let clock = std::time::Instant::now();
    let corners = good_features_to_track(prev, &p.corners);
    let t_corners = clock.elapsed();
    let tracks = track_lk_pyramids(prev_pyr, cur_pyr, &corners, &p.lk);
    judge_tracks(prev, cur, &corners, &tracks, p, clock, t_corners)
}

fn bad_pair(prev: &Gray8, cur: &Gray8) -> Option<&'static str> {
    if prev.is_empty() || cur.is_empty() {
        return Some("empty image");
    }
    if prev.width != cur.width || prev.height != cur.height {
        return Some("previous and current frames differ in size");
    }
    None
}

/// Steps 3-5: border and patch checks, the model, the residuals.
fn judge_tracks(
    prev: &Gray8,
    cur: &Gray8,
    corners: &[[f32; 2]],
    tracks: &[Option<[f32; 2]>],
    p: &GeometryParams,
    clock: std::time::Instant,
    t_corners: std::time::Duration,
) -> MotionCheck {
    let t_lk = clock.elapsed();

    let mut check = MotionCheck::empty("");
    check.corners = corners.len();
    let (mut p1, mut p2) = (
        Vec::with_capacity(corners.len()),
        Vec::with_capacity(corners.len()),
    );
    for (c, t) in corners.iter().zip(tracks) {
        let Some(t) = t else {
            check.lk_failed += 1;
            continue;
        };
        if !inside_border(prev, *c, p.border_px) || !inside_border(cur, *t, p.border_px) {
            check.border_rejected += 1;
            continue;
        }
        if patch_sad(prev, *c, cur, *t, p.patch_half) > p.max_patch_sad {
            check.patch_rejected += 1;
            continue;
        }
        p1.push(Vec2::new(c[0] as f64, c[1] as f64));
        p2.push(Vec2::new(t[0] as f64, t[1] as f64));
    }
    let t_checks = clock.elapsed();

    let (model, residuals, matrix, reason) = choose_model(&p1, &p2, p);
    check.model = model;
    check.matrix = matrix;
    check.fallback_reason = reason;
    check.points = p1
        .iter()
        .zip(&p2)
        .zip(&residuals)
        .map(|((a, b), &r)| TrackedPoint {
            prev: [a.x as f32, a.y as f32],
            cur: [b.x as f32, b.y as f32],
            epipolar_distance: r as f32,
            outlier: model != MotionModel::None && r > p.outlier_threshold_px,
        })
        .collect();
    let t_model = clock.elapsed();
    let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3;
    check.timings = GeometryTimings {
        corners_ms: ms(t_corners),
        lk_ms: ms(t_lk - t_corners),
        checks_ms: ms(t_checks - t_lk),
        model_ms: ms(t_model - t_checks),
    };
    check
}

type ModelChoice = (MotionModel, Vec<f64>, Option<Mat3>, Option<&'static str>);

/// Pick the motion model for the surviving pairs and return each pair's residual (pixels).
pub fn choose_model(p1: &[Vec2], p2: &[Vec2], p: &GeometryParams) -> ModelChoice {
    let n = p1.len();
    let threshold = p.outlier_threshold_px;
    let h_params = HomographyRansac {
        threshold_px: threshold,
        confidence: p.ransac.confidence,
        max_iterations: p.ransac.max_iterations,
        seed: p.ransac.seed,
    };
    let homography = (n >= 4)
        .then(|| homography_ransac(p1, p2, &h_params))
        .flatten();
    let h_residuals = |h: &Mat3| -> Vec<f64> {
        p1.iter()
            .zip(p2)
            .map(|(a, b)| transfer_error2(h, a, b).sqrt())
            .collect()
    };
    let fundamental = (n >= p.min_points_fundamental.max(8))
        .then(|| fundamental_ransac(p1, p2, &p.ransac))
        .flatten();
    match (fundamental, homography) {
        (Some((f, _)), h) => {
            let f_res: Vec<f64> = p1
                .iter()
                .zip(p2)
                .map(|(a, b)| epipolar_distance(&f, a, b))
                .collect();
            if let Some((h, h_inliers)) = h {
                let h_res = h_residuals(&h);
                if still_camera(p1, p2, &h_inliers, p.still_camera_flow_px) {
                    return (
                        MotionModel::Homography,
                        h_res,
                        Some(h),
                        Some("still camera: the static points barely move"),
                    );
                }
                let f_static = f_res.iter().filter(|&&r| r <= threshold).count();
                let h_static = h_res.iter().filter(|&&r| r <= threshold).count();
                if h_static as f64 >= p.homography_support_ratio * f_static as f64 {
                    return (
                        MotionModel::Homography,
                        h_res,
                        Some(h),
                        Some("no parallax: a homography explains the static points"),
                    );
                }
            }
            (MotionModel::Fundamental, f_res, Some(f), None)
        }
        (None, Some((h, _))) => {
            let reason = if n < p.min_points_fundamental.max(8) {
                "too few tracked points for F"
            } else {
                "F degenerate (no parallax)"
            };
            (
                MotionModel::Homography,
                h_residuals(&h),
                Some(h),
                Some(reason),
            )
        }
        (None, None) if n >= p.min_points_flow.max(1) => (
            MotionModel::Flow,
            flow_residuals(p1, p2),
            None,
            Some("too few tracked points for a homography"),
        ),
        (None, None) => (
            MotionModel::None,
            vec![0.0; n],
            None,
            Some("too few tracked points"),
        ),
    }
}

/// True when "nothing moved" (flow below `max_flow_px`) explains at least 90 % as many points
/// as the homography does: the camera (nearly) stood still, so parallax, which is at most the
/// translational flow of the nearest point, is below the outlier threshold too, and F is
/// undetermined. (Counting all points rather than the 90th percentile of the homography's
/// inliers: with walkers covering a quarter of the image, RANSAC's homography takes in a few
/// slow walker points and its 90th percentile crept to 1.03 px on a camera moving 0.2 mm.)
fn still_camera(p1: &[Vec2], p2: &[Vec2], inliers: &[bool], max_flow_px: f64) -> bool {
    let h_count = inliers.iter().filter(|&&i| i).count();
    if h_count == 0 {
        return false;
    }
    let still = p1
        .iter()
        .zip(p2)
        .filter(|(a, b)| (*b - *a).norm() < max_flow_px)
        .count();
    still as f64 >= 0.9 * h_count as f64
}

/// Distance of each flow vector from the component-wise median flow.
fn flow_residuals(p1: &[Vec2], p2: &[Vec2]) -> Vec<f64> {
    let flows: Vec<Vec2> = p1.iter().zip(p2).map(|(a, b)| b - a).collect();
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let m = Vec2::new(
        median(flows.iter().map(|f| f.x).collect()),
        median(flows.iter().map(|f| f.y).collect()),
    );
    flows.iter().map(|f| (f - m).norm()).collect()
}

/// The authors' border check: at least `border` px from every edge.
fn inside_border(img: &Gray8, p: [f32; 2], border: f32) -> bool {
    p[0] >= border
        && p[1] >= border
        && p[0] <= img.width as f32 - 1.0 - border
        && p[1] <= img.height as f32 - 1.0 - border
}

/// Sum of absolute differences of the (2 half + 1)² patches around the two points, at their
/// integer (truncated, as the authors' `int` casts) positions. Out-of-image pixels count as the
/// maximal difference, so the check fails safe.
fn patch_sad(a: &Gray8, pa: [f32; 2], b: &Gray8, pb: [f32; 2], half: usize) -> u32 {
    let h = half as isize;
    let (ax, ay) = (pa[0] as isize, pa[1] as isize);
    let (bx, by) = (pb[0] as isize, pb[1] as isize);
    let mut sad = 0u32;
    for dy in -h..=h {
        for dx in -h..=h {
            sad += match (
                a.get_checked(ax + dx, ay + dy),
                b.get_checked(bx + dx, by + dy),
            ) {
                (Some(u), Some(v)) => u.abs_diff(v) as u32,
                _ => 255,
            };
        }
    }
    sad
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A blocky random texture (7 px blocks), `seed` picks the pattern.
    fn texture(seed: u32) -> impl Fn(isize, isize) -> u8 {
        move |x: isize, y: isize| crate::test_texture::blocky(seed, 7, x, y)
    }

    /// A frame with layers drawn back to front: each layer is (texture seed, rect in the frame
    /// or the whole frame, shift applied to its content and rect).
    type Layer = (u32, Option<[isize; 4]>, [isize; 2]);

    fn render(w: usize, h: usize, layers: &[Layer]) -> Gray8 {
        let mut img = Gray8::new(w, h, 0);
        for &(seed, rect, [sx, sy]) in layers {
            let tex = texture(seed);
            for y in 0..h as isize {
                for x in 0..w as isize {
                    let (u, v) = (x - sx, y - sy);
                    let inside =
                        rect.is_none_or(|[x1, y1, x2, y2]| u >= x1 && u < x2 && v >= y1 && v < y2);
                    if inside {
                        img.set(x as usize, y as usize, tex(u, v));
                    }
                }
            }
        }
        img
    }

    fn in_rect(p: [f32; 2], [x1, y1, x2, y2]: [isize; 4], margin: f32) -> bool {
        p[0] > x1 as f32 + margin
            && p[0] < x2 as f32 - margin
            && p[1] > y1 as f32 + margin
            && p[1] < y2 as f32 - margin
    }

    /// Every track well inside `mover` is an outlier (at least 20 of them) and none of the
    /// tracks well outside it that `still` keeps (at least 100).
    fn assert_only_the_mover_is_flagged(
        check: &MotionCheck,
        mover: [isize; 4],
        still: impl Fn([f32; 2]) -> bool,
    ) {
        let (mut moving, mut moving_out, mut kept, mut kept_out) = (0, 0, 0, 0);
        for t in &check.points {
            if in_rect(t.prev, mover, 6.0) {
                moving += 1;
                moving_out += usize::from(t.outlier);
            } else if !in_rect(t.prev, mover, -14.0) && still(t.prev) {
                kept += 1;
                kept_out += usize::from(t.outlier);
            }
        }
        assert!(
            moving >= 20 && moving_out == moving,
            "{moving_out}/{moving} movers flagged"
        );
        assert!(
            kept >= 100 && kept_out == 0,
            "{kept_out}/{kept} static flagged"
        );
    }

    #[test]
    fn static_camera_gives_no_spurious_outliers() {
        let img = render(320, 240, &[(1, None, [0, 0])]);
        let check = motion_consistency(&img, &img, &GeometryParams::default());
        assert!(check.points.len() > 200, "{} points", check.points.len());
        assert_eq!(check.model, MotionModel::Homography);
        assert_eq!(check.outliers(), 0);
    }

    #[test]
    fn static_camera_flags_a_moving_object() {
        let mover = [120, 80, 200, 160];
        let prev = render(320, 240, &[(1, None, [0, 0]), (2, Some(mover), [0, 0])]);
        let cur = render(320, 240, &[(1, None, [0, 0]), (2, Some(mover), [4, -3])]);
        let check = motion_consistency(&prev, &cur, &GeometryParams::default());
        assert_eq!(check.model, MotionModel::Homography);
        assert_only_the_mover_is_flagged(&check, mover, |_| true);
    }

    #[test]
    fn translating_camera_with_parallax_uses_f_and_flags_the_mover() {
        // Camera moves right: far wall shifts 2 px, a near box 6 px (parallax along the
        // horizontal epipolar lines); a mover slides down 4 px, across its epipolar line.
        let near = [20, 30, 130, 200];
        let mover = [190, 60, 280, 150];
        let layers = |k: isize| {
            vec![
                (1, None, [2 * k, 0]),
                (3, Some(near), [6 * k, 0]),
                (2, Some(mover), [2 * k, 4 * k]),
            ]
        };
        let prev = render(320, 240, &layers(0));
        let cur = render(320, 240, &layers(1));
        let check = motion_consistency(&prev, &cur, &GeometryParams::default());
        assert_eq!(
            check.model,
            MotionModel::Fundamental,
            "{:?}",
            check.fallback_reason
        );
        // Tracks on the near box's border straddle two depths: neither side is judged.
        let boundary = |p| in_rect(p, near, -14.0) && !in_rect(p, near, 14.0);
        assert_only_the_mover_is_flagged(&check, mover, |p| !boundary(p));
    }

    #[test]
    fn prebuilt_pyramids_give_the_same_check() {
        let mover = [120, 80, 200, 160];
        let prev = render(320, 240, &[(1, None, [0, 0]), (2, Some(mover), [0, 0])]);
        let cur = render(320, 240, &[(1, None, [1, 0]), (2, Some(mover), [4, -3])]);
        let p = GeometryParams::default();
        let (a, b) = (LkPyramid::new(&prev, &p.lk), LkPyramid::new(&cur, &p.lk));
        let streamed = motion_consistency_pyramids(&prev, &cur, &a, &b, &p);
        let once = motion_consistency(&prev, &cur, &p);
        assert!(once.outliers() > 10);
        assert_eq!((streamed.points, streamed.model), (once.points, once.model));
        // Pyramids of other frames' size: no model, no panic.
        let other = LkPyramid::new(&Gray8::new(64, 48, 7), &p.lk);
        let bad = motion_consistency_pyramids(&prev, &cur, &a, &other, &p);
        assert_eq!((bad.model, bad.points.len()), (MotionModel::None, 0));
    }

    #[test]
    fn bad_input_is_no_model_not_a_panic() {
        let a = Gray8::new(64, 48, 0);
        let b = Gray8::new(32, 48, 0);
        assert_eq!(
            motion_consistency(&a, &b, &GeometryParams::default()).model,
            MotionModel::None
        );
        let empty = Gray8::new(0, 0, 0);
        assert_eq!(
            motion_consistency(&empty, &empty, &GeometryParams::default()).model,
            MotionModel::None
        );
        // A flat image has no corners: nothing to judge, nothing flagged.
        let check = motion_consistency(&a, &a, &GeometryParams::default());
        assert_eq!((check.model, check.outliers()), (MotionModel::None, 0));
    }

    #[test]
    fn too_few_points_fall_back_to_the_flow() {
        let p1: Vec<Vec2> = [[10.0, 10.0], [50.0, 12.0], [30.0, 40.0]]
            .iter()
            .map(|&[x, y]| Vec2::new(x, y))
            .collect();
        let mut p2: Vec<Vec2> = p1.iter().map(|p| p + Vec2::new(1.0, 0.0)).collect();
        p2[2].y += 5.0;
        let (model, residuals, _, _) = choose_model(&p1, &p2, &GeometryParams::default());
        assert_eq!(model, MotionModel::Flow);
        assert!(residuals[0] < 1e-9 && residuals[1] < 1e-9 && (residuals[2] - 5.0).abs() < 1e-9);
    }

    #[test]
    fn patch_and_border_checks() {
        let img = render(64, 48, &[(1, None, [0, 0])]);
        assert_eq!(patch_sad(&img, [20.3, 20.7], &img, [20.9, 20.1], 1), 0);
        let dark = Gray8::new(64, 48, 0);
        assert!(patch_sad(&img, [20.0, 20.0], &dark, [20.0, 20.0], 1) > 0);
        assert_eq!(patch_sad(&img, [0.0, 0.0], &img, [0.0, 0.0], 1), 5 * 255);
        assert!(inside_border(&img, [5.0, 5.0], 5.0));
        assert!(!inside_border(&img, [4.9, 20.0], 5.0));
        assert!(!inside_border(&img, [20.0, 42.5], 5.0));
    }
}
