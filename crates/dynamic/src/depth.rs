//! Depth-aware culling for RGB-D frames (ours; the paper culls whole boxes).
//!
//! The paper's algorithm 3 removes every keypoint inside a dynamic box that is inside no static
//! box. A person's box is about half background, so that caps precision near 0.5, and a static
//! table, chair or screen box overlapping a walker protects the walker's own keypoints, which
//! costs recall. With a depth map both can be told apart: a person is compact in depth.
//!
//! Rules ([`cull_with_depth`]), for a keypoint inside at least one dynamic box:
//! - each dynamic box carries its moving object's depth ([`ObjectDepth`], from
//!   [`object_depth`]): the depth with the best score "share of the box's central depth samples
//!   within the band + w x (the box's geometric outliers within the band) / (outliers + k)"
//!   ([`DepthParams::outlier_weight`], [`DepthParams::outlier_half_count`]: many outliers
//!   outweigh the centre, a single one does not), minus the share of the central samples in
//!   front of the band ([`DepthParams::occluder_weight`]: the mover is in front of what it
//!   hides), plus a bonus within the band the object had in the last frame
//!   ([`DepthParams::prior_weight`]), refined to the median of the central samples in that
//!   band; a person no farther than a box of its height allows
//!   ([`DepthParams::person_max_height_m`]);
//! - the band is that depth ± max([`DepthParams::band_min_m`],
//!   [`DepthParams::band_relative`] x depth);
//! - a keypoint with a valid depth is culled when its depth lies in the band of a dynamic box
//!   holding it, whatever static boxes also hold it (a chair or table at another depth keeps
//!   its points, the person's points in the chair's box go), and kept when it lies outside every
//!   such band (background seen past the person, a desk in front of it);
//! - local rule: a keypoint within [`DepthParams::local_radius_fraction`] x sqrt(box area) of a
//!   geometric outlier of the box and in that outlier's band is culled too (a hand reaching in
//!   front of the body); outliers behind the object's band are background at its silhouette and
//!   do not count;
//! - static-neighbour rule: a keypoint with a tracked point that moved with the static world
//!   within [`DepthParams::static_radius_px`] at its depth, and no moving one, is kept (the
//!   floor at a walker's feet, the desk at his hip);
//! - support-plane rule: a keypoint on the plane the object stands on ([`support_plane`], fitted
//!   by RANSAC to the depth beside the bottom of its box, given a camera) is kept, whatever
//!   its band (the floor at a walker's feet, lying in his band, was most of what the culling
//!   took of the static world);
//! - a keypoint without depth, or in a dynamic box whose depth could not be estimated (too few
//!   valid samples), is judged by the paper's rule (culled unless a static box holds it).
//!
//! Keypoints in no dynamic box are kept, exactly as the paper (or handled by the unknown-object
//! option of [`crate::cull_with`]). Measurements: docs/measurements.md.

use crate::cull::cull_with;
use crate::judge::{BoxPart, BoxState, Verdict};
use crate::motion_consistency::TrackedPoint;
use crate::settings::{CullParams, DepthParams, DynamicSettings};
use serde::Serialize;
use stillpoint_geometry::plane::{Plane, ransac_plane};
use stillpoint_geometry::{BBox, PinholeCamera, Vec2, Vec3};
use stillpoint_image::DepthMetres;

/// COCO's person class.
const PERSON: u16 = 0;

/// The estimated depth of the moving object in a dynamic box, and the evidence for it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ObjectDepth {
    /// The object's depth, metres.
    pub metres: f32,
    /// Nearest depth still counted as the object.
    pub near: f32,
    /// Farthest depth still counted as the object.
    pub far: f32,
    /// Valid depth samples in the box's central region.
    pub samples: usize,
    /// Share of those samples inside the band.
    pub central_share: f32,
    /// Geometric outliers inside the box with a valid depth.
    pub outliers_with_depth: usize,
    /// Of those, the ones inside the band.
    pub outliers_in_band: usize,
    /// The plane the object stands on, seen beside the bottom of its box (the floor at a
    /// walker's feet): it shares his depth, not his motion. `None` where none was found.
    pub support: Option<SupportPlane>,
}

impl ObjectDepth {
    /// True when `depth` lies in the object's band.
    pub fn holds(&self, depth: f32) -> bool {
        depth >= self.near && depth <= self.far
    }

    /// True when pixel (`x`, `y`) at `depth` lies on the plane the object stands on.
    pub fn on_support(&self, x: f32, y: f32, depth: f32) -> bool {
        self.support.is_some_and(|s| s.holds(x, y, depth))
    }
}

/// The plane a mover stands on (the floor at a walker's feet, the road under a car), in pixel
/// form: a pixel (`u`, `v`) at depth `z` lies `|z (a u + b v + c) + d|` metres from it (the
/// camera's intrinsics folded in). It holds pixels at or below `from_row`, the top of the
/// strip it was fitted beside, within `max(tolerance_m, tolerance_relative z)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SupportPlane {
    /// Coefficient of `u`.
    pub a: f32,
    /// Coefficient of `v`.
    pub b: f32,
    /// Constant inside the bracket.
    pub c: f32,
    /// The plane's offset, metres.
    pub d: f32,
    /// The first image row it holds pixels on.
    pub from_row: f32,
    /// Distance within which a pixel is on it, metres ...
    pub tolerance_m: f32,
    /// ... or this share of the pixel's depth, if more.
    pub tolerance_relative: f32,
}

impl SupportPlane {
    /// The plane `plane` (camera coordinates) seen through `camera`.
    pub fn new(plane: &Plane, camera: &PinholeCamera, from_row: f32, p: &DepthParams) -> Self {
        let n = plane.normal;
        let (a, b) = (n.x / camera.fx, n.y / camera.fy);
        Self {
            a: a as f32,
            b: b as f32,
            c: (n.z - a * camera.cx - b * camera.cy) as f32,
            d: plane.offset as f32,
            from_row,
            tolerance_m: p.support_tolerance_m,
            tolerance_relative: p.support_tolerance_relative,
        }
    }

    /// Distance of pixel (`u`, `v`) at depth `z` from the plane, metres.
    pub fn distance(&self, u: f32, v: f32, z: f32) -> f32 {
        (z * (self.a * u + self.b * v + self.c) + self.d).abs()
    }

    /// True when pixel (`u`, `v`) at depth `z` is on the plane, at or below its first row.
    pub fn holds(&self, u: f32, v: f32, z: f32) -> bool {
        v >= self.from_row
            && z > 0.0
            && self.distance(u, v, z) <= self.tolerance_m.max(self.tolerance_relative * z)
    }
}

/// The plane most of the depth beside the bottom of `bbox` lies on: samples (every
/// [`DepthParams::sample_step_px`]) in the rows from `legs` x its height above its bottom to
/// [`DepthParams::support_below_fraction`] below it, across
/// [`DepthParams::support_side_fraction`] of its width on each side, outside the box and the
/// boxes of `movers`, fitted by RANSAC ([`ransac_plane`]). `None` with fewer than
/// [`DepthParams::support_min_samples`] samples, when the plane holds less than
/// [`DepthParams::support_min_share`] of them, when it faces the camera (the cosine between
/// its normal and the ray to the box's bottom above [`DepthParams::support_max_facing`]), or
/// when it holds more of `object_points` (the object's moving points, pixels and depth) than
/// [`DepthParams::support_max_object_share`] of them and [`DepthParams::support_feet_points`]:
/// a plane through the object is not what it stands on.
pub fn support_plane(
    bbox: &BBox,
    legs: f32,
    movers: &[BBox],
    object_points: &[DepthPoint],
    depth: &DepthMetres,
    camera: &PinholeCamera,
    p: &DepthParams,
) -> Option<SupportPlane> {
    if !p.support_plane || depth.is_empty() {
        return None;
    }
    let (w, h) = (bbox.width(), bbox.height());
    let (cols, rows) = (depth.width as f32 - 1.0, depth.height as f32 - 1.0);
    let from_row = (bbox.y2 - legs * h).max(0.0);
    let y_range = (from_row, (bbox.y2 + p.support_below_fraction * h).min(rows));
    let x_range = (
        (bbox.x1 - p.support_side_fraction * w).max(0.0),
        (bbox.x2 + p.support_side_fraction * w).min(cols),
    );
    if !(w > 0.0 && h > 0.0 && y_range.0 <= y_range.1 && x_range.0 <= x_range.1) {
        return None;
    }
    let step = p.sample_step_px.max(1);
    let pixel = |u: f32, v: f32| Vec2::new(u as f64, v as f64);
    let mut samples = Vec::new();
    for y in (y_range.0.ceil() as usize..=y_range.1 as usize).step_by(step) {
        for x in (x_range.0.ceil() as usize..=x_range.1 as usize).step_by(step) {
            let (u, v) = (x as f32, y as f32);
            let inside = |b: &BBox| u >= b.x1 && u <= b.x2 && v >= b.y1 && v <= b.y2;
            let z = depth.get(x, y);
            if valid(z, p) && !inside(bbox) && !movers.iter().any(inside) {
                samples.push(camera.unproject(&pixel(u, v), z as f64));
            }
        }
    }
    if samples.len() < p.support_min_samples.max(3) {
        return None;
    }
    let tolerance =
        |x: &Vec3| (p.support_tolerance_m as f64).max(p.support_tolerance_relative as f64 * x.z);
    let (plane, inliers) = ransac_plane(&samples, &tolerance, p.support_iterations, 0x5eed)?;
    if (inliers as f32) < p.support_min_share * samples.len() as f32 {
        return None;
    }
    // A floor is seen at a grazing angle; a plane facing the camera at the object's depth
    // (a cabinet's front beside a walker) would cut through him.
    let bottom = pixel((bbox.x1 + bbox.x2) / 2.0, bbox.y2.min(rows));
    let ray = camera.unproject(&bottom, 1.0).normalize();
    if plane.normal.dot(&ray).abs() > p.support_max_facing as f64 {
        return None;
    }
    let support = SupportPlane::new(&plane, camera, from_row, p);
    let on_plane = object_points
        .iter()
        .filter(|&&(at, z)| support.holds(at[0], at[1], z))
        .count();
    let allowed =
        (p.support_max_object_share * object_points.len() as f32).max(p.support_feet_points as f32);
    (on_plane as f32 <= allowed).then_some(support)
}

/// The band [near, far] around `depth`.
pub fn depth_band(depth: f32, p: &DepthParams) -> (f32, f32) {
    let half = p.band_min_m.max(p.band_relative * depth);
    (depth - half, depth + half)
}

fn valid(d: f32, p: &DepthParams) -> bool {
    d.is_finite() && d > p.min_valid_m
}

/// The nearest valid depth within `window` pixels of `at` (a (2 window + 1)² square), or 0.0 when
/// none is valid or `at` is outside the image. Nearest, because a keypoint on a silhouette
/// describes a patch that is partly the foreground object.
///
/// ```
/// use stillpoint_dynamic::depth::depth_near;
/// use stillpoint_image::DepthMetres;
/// let mut d = DepthMetres::new(4, 4, 3.0);
/// d.set(2, 1, 1.5);
/// d.set(1, 1, 0.0); // no reading
/// assert_eq!(depth_near(&d, [1.2, 1.4], 0, 0.05), 0.0);
/// assert_eq!(depth_near(&d, [1.2, 1.4], 1, 0.05), 1.5);
/// ```
pub fn depth_near(depth: &DepthMetres, at: [f32; 2], window: usize, min_valid_m: f32) -> f32 {
    if !(at[0].is_finite() && at[1].is_finite()) {
        return 0.0;
    }
    let (x, y) = (at[0].round() as isize, at[1].round() as isize);
    let w = window as isize;
    let mut best = f32::INFINITY;
    for dy in -w..=w {
        for dx in -w..=w {
            if let Some(d) = depth.get_checked(x + dx, y + dy)
                && d.is_finite()
                && d > min_valid_m
            {
                best = best.min(d);
            }
        }
    }
    if best.is_finite() { best } else { 0.0 }
}

/// Depth of each keypoint by [`depth_near`] with [`DepthParams::keypoint_window_px`]; 0.0 when
/// missing.
pub fn keypoint_depths(depth: &DepthMetres, keypoints: &[[f32; 2]], p: &DepthParams) -> Vec<f32> {
    keypoints
        .iter()
        .map(|&k| depth_near(depth, k, p.keypoint_window_px, p.min_valid_m))
        .collect()
}

/// Estimate the depth of the moving object in `bbox` (see the module docs); `None` when the
/// box's central region has fewer than [`DepthParams::min_samples`] valid depths.
pub fn object_depth(
    bbox: &BBox,
    tracked: &[TrackedPoint],
    depth: &DepthMetres,
    prior: Option<&ObjectDepth>,
    farthest: f32,
    p: &DepthParams,
) -> Option<ObjectDepth> {
    let central = central_samples(bbox, depth, p);
    if central.len() < p.min_samples.max(1) {
        return None;
    }
    let mut outliers: Vec<f32> = tracked
        .iter()
        .filter(|t| t.outlier && bbox.contains_strict(t.cur[0], t.cur[1]))
        .map(|t| depth_near(depth, t.cur, p.keypoint_window_px, p.min_valid_m))
        .filter(|&d| valid(d, p))
        .collect();
    outliers.sort_by(f32::total_cmp);
    let in_band = |sorted: &[f32], d: f32| {
        let (near, far) = depth_band(d, p);
        sorted.partition_point(|&v| v <= far) - sorted.partition_point(|&v| v < near)
    };
    let score = |d: f32| {
        let c = in_band(&central, d) as f32 / central.len() as f32;
        let o = if outliers.is_empty() {
            0.0
        } else {
            in_band(&outliers, d) as f32 / (outliers.len() as f32 + p.outlier_half_count.max(0.0))
        };
        // The mover is in front of what it hides: a depth with much of the centre in front of
        // it is more likely background seen past the object.
        let (near, _) = depth_band(d, p);
        let in_front = central.partition_point(|&v| v < near) as f32 / central.len() as f32;
        let known = prior.is_some_and(|o| o.holds(d)) as u8 as f32;
        c + p.outlier_weight * o - p.occluder_weight * in_front + p.prior_weight * known
    };
    // Candidates: the central samples (thinned to at most ~256), the outliers' depths and the
    // prior, no farther than `farthest` while any is.
    let step = (central.len() / 256).max(1);
    let candidates = || {
        central
            .iter()
            .step_by(step)
            .chain(&outliers)
            .chain(prior.map(|o| &o.metres))
            .copied()
    };
    let within = candidates().any(|d| d <= farthest);
    let best = candidates()
        .filter(|&d| !within || d <= farthest)
        .map(|d| (score(d), d))
        .fold(None::<(f32, f32)>, |acc, (s, d)| match acc {
            // Ties go to the nearer depth: the mover is in front of what it hides.
            Some((bs, bd)) if bs > s || (bs == s && bd <= d) => Some((bs, bd)),
            _ => Some((s, d)),
        })?
        .1;
    // Refine to the median of the central samples in the band (stable against the candidate's
    // own noise).
    let (near, far) = depth_band(best, p);
    let lo = central.partition_point(|&v| v < near);
    let hi = central.partition_point(|&v| v <= far);
    let metres = if hi > lo {
        central[(lo + hi) / 2]
    } else {
        best
    };
    let (near, far) = depth_band(metres, p);
    let central_in = in_band(&central, metres);
    Some(ObjectDepth {
        metres,
        near,
        far,
        samples: central.len(),
        central_share: central_in as f32 / central.len() as f32,
        outliers_with_depth: outliers.len(),
        outliers_in_band: in_band(&outliers, metres),
        support: None,
    })
}

/// Valid depths on a grid over the box's central region, sorted.
fn central_samples(bbox: &BBox, depth: &DepthMetres, p: &DepthParams) -> Vec<f32> {
    let (w, h) = (bbox.width(), bbox.height());
    let overlaps = bbox.x2 > 0.0
        && bbox.y2 > 0.0
        && bbox.x1 < depth.width as f32
        && bbox.y1 < depth.height as f32;
    if !(w > 0.0 && h > 0.0 && overlaps) || depth.is_empty() {
        return Vec::new();
    }
    let cx = (bbox.x1 + bbox.x2) / 2.0;
    let cy = (bbox.y1 + bbox.y2) / 2.0;
    let (hw, hh) = (
        w * p.central_width.clamp(0.0, 1.0) / 2.0,
        h * p.central_height.clamp(0.0, 1.0) / 2.0,
    );
    let clamp_x = |v: f32| v.clamp(0.0, depth.width as f32 - 1.0).round() as usize;
    let clamp_y = |v: f32| v.clamp(0.0, depth.height as f32 - 1.0).round() as usize;
    let (x1, x2, y1, y2) = (
        clamp_x(cx - hw),
        clamp_x(cx + hw),
        clamp_y(cy - hh),
        clamp_y(cy + hh),
    );
    let step = p.sample_step_px.max(1);
    let mut samples = Vec::new();
    for y in (y1..=y2).step_by(step) {
        for x in (x1..=x2).step_by(step) {
            let d = depth.get(x, y);
            if valid(d, p) {
                samples.push(d);
            }
        }
    }
    samples.sort_by(f32::total_cmp);
    samples
}

/// Fill [`BoxState::depth`] of every dynamic box with [`object_depth`], the depth it holds
/// going in (its object's in the last frame, if any) the prior, a person no farther than
/// [`person_farthest`]; static boxes are left without one (their keypoints are never culled
/// for their own sake).
pub fn estimate_object_depths(
    states: &mut [BoxState],
    tracked: &[TrackedPoint],
    depth: &DepthMetres,
    camera: Option<&PinholeCamera>,
    p: &DepthParams,
) {
    for s in states.iter_mut() {
        s.depth = if s.verdict == Verdict::Dynamic {
            let farthest = person_farthest(s, camera, p);
            object_depth(&s.bbox, tracked, depth, s.depth.as_ref(), farthest, p)
        } else {
            None
        };
    }
    let Some(camera) = camera.filter(|_| p.support_plane) else {
        return;
    };
    let movers: Vec<BBox> = states
        .iter()
        .filter(|s| s.is_dynamic())
        .map(|s| s.bbox)
        .collect();
    for s in states.iter_mut() {
        // Only a box whose bottom is the object's stands on anything.
        let Some(o) = s.depth.as_mut().filter(|_| s.part != BoxPart::SeatedTop) else {
            continue;
        };
        let moving: Vec<DepthPoint> = tracked
            .iter()
            .filter(|t| t.outlier && s.bbox.contains_strict(t.cur[0], t.cur[1]))
            .map(|t| {
                (
                    t.cur,
                    depth_near(depth, t.cur, p.keypoint_window_px, p.min_valid_m),
                )
            })
            .filter(|&(_, z)| o.holds(z))
            .collect();
        // A seated person's bottom part is their legs: all of it is near the floor.
        let legs = if s.part == BoxPart::SeatedBottom {
            1.0
        } else {
            p.support_height_fraction
        };
        o.support = support_plane(&s.bbox, legs, &movers, &moving, depth, camera, p);
    }
}

/// The farthest a person can be whose box (or NHBC part) is as tall as `state`'s: no one is
/// taller than [`DepthParams::person_max_height_m`], so a box `h` pixels tall lies within
/// `fy x H / h` (a box cut by the image's edge is taller still). Infinite for other classes,
/// without a camera or with the bound off.
pub fn person_farthest(state: &BoxState, camera: Option<&PinholeCamera>, p: &DepthParams) -> f32 {
    match camera {
        Some(c) if state.class_id == PERSON && p.person_max_height_m > 0.0 => {
            let h = state.bbox.height();
            if h > 1.0 {
                (c.fy as f32 * p.person_max_height_m / h).max(p.min_valid_m)
            } else {
                f32::INFINITY
            }
        }
        _ => f32::INFINITY,
    }
}

/// A point (pixels) and its depth (metres).
type DepthPoint = ([f32; 2], f32);

/// Everything [`cull_with_depth`] reads for one frame. Depths are metres; 0, negative or not
/// finite means missing, and a slice shorter than its points counts the rest as missing.
#[derive(Clone, Copy, Debug)]
pub struct DepthCullInput<'a> {
    /// Keypoints of the current frame (level-0 pixels).
    pub keypoints: &'a [[f32; 2]],
    /// Depth of each keypoint ([`keypoint_depths`]).
    pub keypoint_depths: &'a [f32],
    /// The judged boxes; dynamic ones with [`BoxState::depth`] from [`estimate_object_depths`]
    /// (those without fall back to the paper's rule).
    pub states: &'a [BoxState],
    /// The geometry module's points (for the local rule and the unknown-object option).
    pub tracked: &'a [TrackedPoint],
    /// Depth of each tracked point at its current position.
    pub tracked_depths: &'a [f32],
}

/// Depth-aware culling (rules in the module docs): `true` = dynamic, remove.
///
/// ```
/// use stillpoint_dynamic::depth::{DepthCullInput, ObjectDepth, cull_with_depth};
/// use stillpoint_dynamic::{BoxPart, BoxState, CullParams, DepthParams, Rule, Verdict};
/// use stillpoint_geometry::BBox;
/// let person_depth = ObjectDepth { metres: 2.0, near: 1.6, far: 2.4, samples: 100,
///     central_share: 0.8, outliers_with_depth: 5, outliers_in_band: 5, support: None };
/// let person = BoxState { bbox: BBox::new(0.0, 0.0, 100.0, 300.0), class_id: 0, detection: 0,
///     part: BoxPart::Whole, rule: Rule::Nhbc, verdict: Verdict::Dynamic, tracked: 9, outliers: 5,
///     depth: Some(person_depth) };
/// let input = DepthCullInput { keypoints: &[[50.0, 50.0], [10.0, 10.0], [20.0, 20.0]],
///     keypoint_depths: &[2.1, 4.0, 0.0], states: &[person], tracked: &[], tracked_depths: &[] };
/// let removed = cull_with_depth(&input, &CullParams::default(), &DepthParams::default());
/// assert_eq!(removed, vec![true, false, true]); // on the person / wall behind / no depth
/// ```
pub fn cull_with_depth(input: &DepthCullInput, cull: &CullParams, p: &DepthParams) -> Vec<bool> {
    let DepthCullInput {
        keypoints,
        keypoint_depths,
        states,
        tracked,
        tracked_depths,
    } = *input;
    let paper = cull_with(keypoints, states, tracked, cull);
    let protects = |s: &BoxState| match s.verdict {
        Verdict::Static => cull.static_box_protects,
        Verdict::StaticUnknown => cull.unknown_box_protects,
        Verdict::Dynamic => false,
    };
    // Per state: the outliers inside it with a valid depth, and the local radius.
    let local: Vec<(Vec<DepthPoint>, f32)> = states
        .iter()
        .map(|s| {
            if !s.is_dynamic() || p.local_radius_fraction <= 0.0 {
                return (Vec::new(), 0.0);
            }
            let pts = tracked
                .iter()
                .enumerate()
                .filter(|(_, t)| t.outlier && s.bbox.contains_strict(t.cur[0], t.cur[1]))
                .filter_map(|(j, t)| {
                    // Outliers behind the object are background near its silhouette (covered
                    // or uncovered as it moves): not evidence of a part of the object.
                    let d = tracked_depths.get(j).copied().unwrap_or(0.0);
                    let far = s.depth.map_or(f32::INFINITY, |o| o.far);
                    (valid(d, p) && d <= far).then_some((t.cur, d))
                })
                .collect();
            let radius = p.local_radius_fraction * (s.bbox.area().max(0.0)).sqrt();
            (pts, radius)
        })
        .collect();
    let neighbours = StaticNeighbours::new(tracked, tracked_depths, states, p);
    // Unknown-object option: the outliers in no box, with their depths.
    let boxless: Vec<DepthPoint> = if cull.unknown_objects {
        tracked
            .iter()
            .enumerate()
            .filter(|(_, t)| {
                t.outlier
                    && !states
                        .iter()
                        .any(|s| s.bbox.contains_strict(t.cur[0], t.cur[1]))
            })
            .map(|(j, t)| (t.cur, tracked_depths.get(j).copied().unwrap_or(0.0)))
            .collect()
    } else {
        Vec::new()
    };
    keypoints
        .iter()
        .enumerate()
        .map(|(i, &[x, y])| {
            let inside = |s: &BoxState| s.bbox.contains_strict(x, y);
            let mut dynamic = states
                .iter()
                .zip(&local)
                .filter(|(s, _)| inside(s) && s.is_dynamic())
                .peekable();
            if dynamic.peek().is_none() {
                // In no dynamic box: the paper's decision (kept, or the unknown-object option,
                // counting only outliers at the keypoint's depth when both have one).
                let d = keypoint_depths.get(i).copied().unwrap_or(0.0);
                if !cull.unknown_objects || !valid(d, p) || !paper[i] {
                    return paper[i];
                }
                let r2 = cull.unknown_radius_px * cull.unknown_radius_px;
                let near = boxless
                    .iter()
                    .filter(|&&(at, od)| {
                        let (dx, dy) = (at[0] - x, at[1] - y);
                        let same_depth = !valid(od, p) || {
                            let (near, far) = depth_band(od, p);
                            d >= near && d <= far
                        };
                        dx * dx + dy * dy <= r2 && same_depth
                    })
                    .count();
                return near >= cull.unknown_min_outliers.max(1);
            }
            let d = keypoint_depths.get(i).copied().unwrap_or(0.0);
            let protected = || states.iter().filter(|s| inside(s)).any(protects);
            if valid(d, p) && neighbours.keep([x, y], d, p) {
                return false;
            }
            dynamic.any(|(s, (outliers, radius))| match s.depth {
                Some(o) if valid(d, p) => {
                    let near_outlier = || {
                        outliers.iter().any(|&(at, od)| {
                            let (near, far) = depth_band(od, p);
                            let (dx, dy) = (at[0] - x, at[1] - y);
                            d >= near && d <= far && dx * dx + dy * dy <= radius * radius
                        })
                    };
                    !o.on_support(x, y, d) && (o.holds(d) || near_outlier())
                }
                _ => !protected(),
            })
        })
        .collect()
}

/// The tracked points inside a frame's dynamic boxes with their depths: where a mover's band
/// holds static world ([`DepthParams::static_radius_px`]).
#[derive(Clone, Debug, Default)]
struct StaticNeighbours {
    points: Vec<(TrackedPoint, f32)>,
}

impl StaticNeighbours {
    /// The points of `tracked` (depths `tracked_depths`, missing when short) inside a dynamic
    /// box of `states`; none when the rule is off.
    fn new(
        tracked: &[TrackedPoint],
        tracked_depths: &[f32],
        states: &[BoxState],
        p: &DepthParams,
    ) -> Self {
        if p.static_radius_px <= 0.0 {
            return Self::default();
        }
        let points = tracked
            .iter()
            .zip(tracked_depths.iter().chain(std::iter::repeat(&0.0)))
            .filter(|(t, _)| {
                states
                    .iter()
                    .any(|s| s.is_dynamic() && s.bbox.contains_strict(t.cur[0], t.cur[1]))
            })
            .map(|(t, &d)| (*t, d))
            .collect();
        Self { points }
    }

    /// A point that moved with the static world lies within [`DepthParams::static_radius_px`]
    /// of `at` at depth `d` (± [`DepthParams::static_depth_m`]), and no moving one does.
    fn keep(&self, at: [f32; 2], d: f32, p: &DepthParams) -> bool {
        let r2 = p.static_radius_px * p.static_radius_px;
        let mut still = false;
        for (t, td) in &self.points {
            let (dx, dy) = (t.cur[0] - at[0], t.cur[1] - at[1]);
            if dx * dx + dy * dy > r2 {
                continue;
            }
            if t.outlier {
                return false;
            }
            still |= valid(*td, p) && (td - d).abs() <= p.static_depth_m;
        }
        still
    }
}

/// The whole culling step for one frame: depth-aware when `depth` is given and
/// [`DepthParams::enabled`], the paper's algorithm 3 otherwise. Fills [`BoxState::depth`] of the
/// dynamic boxes as a side result (why a keypoint was kept or culled).
pub fn cull_frame(
    keypoints: &[[f32; 2]],
    states: &mut [BoxState],
    tracked: &[TrackedPoint],
    depth: Option<&DepthMetres>,
    s: &DynamicSettings,
) -> Vec<bool> {
    cull_frame_protecting(
        keypoints,
        states,
        tracked,
        depth,
        s,
        s.cull.static_box_protects,
    )
}

/// [`cull_frame`], with static boxes protecting the keypoints of dynamic ones they overlap on a
/// frame without depth only when `static_boxes_protect` (the per-keypoint evidence may decide
/// there instead: [`crate::EvidenceWithoutDepth::static_boxes_protect`]).
pub(crate) fn cull_frame_protecting(
    keypoints: &[[f32; 2]],
    states: &mut [BoxState],
    tracked: &[TrackedPoint],
    depth: Option<&DepthMetres>,
    s: &DynamicSettings,
    static_boxes_protect: bool,
) -> Vec<bool> {
    match depth {
        Some(depth) if s.depth.enabled && !depth.is_empty() => {
            estimate_object_depths(states, tracked, depth, s.world.camera.as_ref(), &s.depth);
            let depths = keypoint_depths(depth, keypoints, &s.depth);
            let cur: Vec<[f32; 2]> = tracked.iter().map(|t| t.cur).collect();
            let tracked_depths = keypoint_depths(depth, &cur, &s.depth);
            let input = DepthCullInput {
                keypoints,
                keypoint_depths: &depths,
                states,
                tracked,
                tracked_depths: &tracked_depths,
            };
            cull_with_depth(&input, &s.cull, &s.depth)
        }
        Some(_) => cull_with(keypoints, states, tracked, &s.cull),
        None => {
            let cull = CullParams {
                unknown_objects: s.cull.unknown_objects && s.cull.unknown_objects_without_depth,
                static_box_protects: static_boxes_protect,
                ..s.cull.clone()
            };
            cull_with(keypoints, states, tracked, &cull)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::judge::{BoxPart, judge_boxes};
    use crate::paper_cases::{det, pt};
    use crate::settings::JudgeParams;

    const PERSON: u16 = 0;
    const CHAIR: u16 = 56;

    /// A depth map at `background` metres with rectangles [x1, y1, x2, y2] painted at a depth,
    /// back to front.
    fn depth_map(background: f32, rects: &[([usize; 4], f32)]) -> DepthMetres {
        let mut d = DepthMetres::new(640, 480, background);
        for &([x1, y1, x2, y2], z) in rects {
            for y in y1..y2 {
                for x in x1..x2 {
                    d.set(x, y, z);
                }
            }
        }
        d
    }

    fn settings() -> DynamicSettings {
        DynamicSettings::default()
    }

    #[test]
    fn person_in_front_of_a_wall_keeps_the_wall_points_in_its_box() {
        // Box 120 x 400 (standing); the body is the middle 80 px at 2 m, the wall at 4 m.
        let person = det(PERSON, 240.0, 40.0, 360.0, 440.0);
        let depth = depth_map(4.0, &[([260, 60, 340, 440], 2.0)]);
        let tracked = [pt(300.0, 200.0, true), pt(320.0, 300.0, true)];
        let mut states = judge_boxes(&[person], &tracked, &JudgeParams::default());
        let keypoints = [
            [300.0, 100.0], // chest: culled
            [270.0, 400.0], // leg: culled
            [245.0, 100.0], // wall seen beside the body, inside the box: kept
            [355.0, 420.0], // wall, inside the box: kept
            [500.0, 100.0], // wall outside the box: kept
        ];
        let removed = cull_frame(&keypoints, &mut states, &tracked, Some(&depth), &settings());
        assert_eq!(removed, vec![true, true, false, false, false]);
        let o = states[0].depth.expect("object depth");
        assert!((o.metres - 2.0).abs() < 1e-6 && o.holds(2.35) && !o.holds(2.5));
        assert_eq!((o.outliers_with_depth, o.outliers_in_band), (2, 2));
        // The paper's rule culls the whole box.
        let paper = cull_with(&keypoints, &states, &tracked, &CullParams::default());
        assert_eq!(paper, vec![true, true, true, true, false]);
    }

    #[test]
    fn the_floor_at_a_walkers_feet_is_kept_beside_static_tracks() {
        // A walker at 2 m before a wall at 4 m; the floor in his box's lower part at 2.1 m.
        let person = det(PERSON, 240.0, 40.0, 360.0, 440.0);
        let depth = depth_map(
            4.0,
            &[([240, 380, 360, 440], 2.1), ([260, 60, 340, 380], 2.0)],
        );
        let tracked = [
            pt(300.0, 200.0, true),
            pt(320.0, 300.0, true),
            pt(250.0, 420.0, false), // floor, moved with the static world
            pt(300.0, 104.0, false), // a still track on the chest...
            pt(305.0, 96.0, true),   // ... beside a moving one
        ];
        let mut states = judge_boxes(&[person], &tracked, &JudgeParams::default());
        let keypoints = [
            [255.0, 425.0], // floor beside the static track: kept
            [340.0, 425.0], // floor with no track near: in the band, culled
            [300.0, 100.0], // chest beside a moving track: culled
            [300.0, 250.0], // chest: culled
        ];
        let removed = cull_frame(&keypoints, &mut states, &tracked, Some(&depth), &settings());
        assert_eq!(removed, vec![false, true, true, true]);
        let mut off = settings();
        off.depth.static_radius_px = 0.0;
        let removed = cull_frame(&keypoints, &mut states, &tracked, Some(&depth), &off);
        assert_eq!(removed, vec![true, true, true, true]);
    }

    /// A wall at 5 m, level floor 0.8 m below the camera, and a walker 1.8 m tall at 2.5 m
    /// standing on it (columns 290..350, rows 32..420) seen through `camera`; with `cabinets`,
    /// fronts at his depth fill the rows of his legs beside him.
    fn walker_on_a_floor(camera: &PinholeCamera, cabinets: bool) -> DepthMetres {
        let mut depth = DepthMetres::new(640, 480, 5.0);
        for y in 0..480 {
            for x in 0..640 {
                let below = y as f32 - camera.cy as f32;
                let floor = if below > 0.0 {
                    0.8 * camera.fy as f32 / below
                } else {
                    5.0
                };
                let walker = (290..350).contains(&x) && (32..420).contains(&y);
                let cabinet = cabinets && (250..470).contains(&y);
                depth.set(
                    x,
                    y,
                    if walker || cabinet {
                        2.5
                    } else {
                        floor.min(5.0)
                    },
                );
            }
        }
        depth
    }

    #[test]
    fn the_floor_a_walker_stands_on_is_kept_and_he_is_not() {
        let camera = PinholeCamera::new(535.4, 539.2, 320.1, 247.6, 640, 480);
        let depth = walker_on_a_floor(&camera, false);
        let person = det(PERSON, 280.0, 30.0, 360.0, 421.0);
        let tracked = [
            pt(320.0, 150.0, true),
            pt(300.0, 300.0, true),
            pt(330.0, 400.0, true),
        ];
        let mut s = settings();
        s.world.camera = Some(camera);
        let keypoints = [
            [284.0, 410.0], // floor in his box beside his feet, in his band (2.66 m): kept
            [300.0, 400.0], // his shin, 9 cm above the floor: culled
            [320.0, 200.0], // his chest: culled
        ];
        let mut states = judge_boxes(&[person], &tracked, &s.judge);
        let removed = cull_frame(&keypoints, &mut states, &tracked, Some(&depth), &s);
        assert_eq!(removed, vec![false, true, true]);
        let support = states[0].depth.and_then(|o| o.support).expect("the floor");
        assert!(support.distance(284.0, 410.0, depth.get(284, 410)) < 0.005);
        // Without the plane the floor there goes with him.
        s.depth.support_plane = false;
        let mut states = judge_boxes(&[person], &tracked, &s.judge);
        let removed = cull_frame(&keypoints, &mut states, &tracked, Some(&depth), &s);
        assert_eq!(removed, vec![true, true, true]);
    }

    #[test]
    fn a_plane_through_the_walker_is_not_what_he_stands_on() {
        // Cabinet fronts beside him at his depth are the largest plane there, but they hold
        // his moving points too.
        let camera = PinholeCamera::new(535.4, 539.2, 320.1, 247.6, 640, 480);
        let depth = walker_on_a_floor(&camera, true);
        let person = det(PERSON, 280.0, 30.0, 360.0, 421.0);
        let tracked = [
            pt(320.0, 300.0, true),
            pt(300.0, 350.0, true),
            pt(330.0, 400.0, true),
            pt(310.0, 320.0, true),
            pt(315.0, 380.0, true),
        ];
        let mut s = settings();
        s.world.camera = Some(camera);
        let knee = |s: &DynamicSettings| {
            let mut states = judge_boxes(&[person], &tracked, &s.judge);
            let removed = cull_frame(&[[310.0, 380.0]], &mut states, &tracked, Some(&depth), s);
            (
                removed[0],
                states[0].depth.expect("his depth").support.is_some(),
            )
        };
        // It faces the camera, and it holds all five of his moving points.
        assert_eq!(knee(&s), (true, false), "his knee culled, no plane");
        s.depth.support_max_facing = 1.0;
        assert_eq!(knee(&s), (true, false));
        s.depth.support_max_facing = 0.8;
        s.depth.support_max_object_share = 1.0;
        assert_eq!(knee(&s), (true, false));
        // Taken whatever it holds of him and however it faces the camera, it keeps his knee.
        s.depth.support_max_facing = 1.0;
        assert_eq!(knee(&s), (false, true));
    }

    #[test]
    fn chair_in_front_of_a_walker_keeps_its_points_the_walker_loses_his() {
        // Walker at 3 m, body 260..340; a chair at 2 m in front of his legs; wall at 5 m.
        // The chair's box is wider than its silhouette, as detector boxes are.
        let walker = det(PERSON, 230.0, 40.0, 360.0, 460.0);
        let chair = det(CHAIR, 180.0, 300.0, 330.0, 470.0);
        let depth = depth_map(
            5.0,
            &[([260, 50, 340, 460], 3.0), ([180, 320, 300, 470], 2.0)],
        );
        let mut tracked: Vec<TrackedPoint> = (0..12)
            .map(|i| pt(190.0 + 12.0 * i as f32, 380.0, false))
            .filter(|t| t.cur[0] < 330.0)
            .collect();
        tracked.extend([pt(300.0, 100.0, true), pt(290.0, 200.0, true)]);
        let mut states = judge_boxes(&[walker, chair], &tracked, &JudgeParams::default());
        assert_eq!(states[0].verdict, Verdict::Dynamic);
        assert_eq!(states[1].verdict, Verdict::Static);
        let keypoints = [
            [300.0, 150.0], // walker's torso: culled
            [250.0, 400.0], // chair, in both boxes: kept (at 2 m, not the walker's 3 m)
            [320.0, 330.0], // walker's leg beside the chair, in the chair's box: culled
            [355.0, 200.0], // wall inside the walker's box: kept
        ];
        let removed = cull_frame(&keypoints, &mut states, &tracked, Some(&depth), &settings());
        assert_eq!(removed, vec![true, false, true, false]);
        // The paper: the chair box protects the leg too, and the wall is culled.
        let paper = cull_with(&keypoints, &states, &tracked, &CullParams::default());
        assert_eq!(paper, vec![true, false, false, true]);
    }

    #[test]
    fn missing_depth_falls_back_to_the_paper() {
        let walker = det(PERSON, 200.0, 40.0, 300.0, 440.0);
        let chair = det(CHAIR, 200.0, 300.0, 300.0, 440.0);
        let mut depth = depth_map(4.0, &[([220, 40, 280, 440], 2.0)]);
        for y in 90..110 {
            for x in 240..260 {
                depth.set(x, y, 0.0); // a hole in the Kinect's reading
            }
        }
        for y in 348..353 {
            for x in 248..253 {
                depth.set(x, y, f32::NAN);
            }
        }
        let tracked = [pt(250.0, 200.0, true)];
        let mut states = judge_boxes(&[walker, chair], &tracked, &JudgeParams::default());
        let keypoints = [[250.0, 100.0], [250.0, 350.0], [210.0, 100.0]];
        let removed = cull_frame(&keypoints, &mut states, &tracked, Some(&depth), &settings());
        // hole on the body: culled; NaN inside the static chair box: protected; wall: kept
        assert_eq!(removed, vec![true, false, false]);

        // No valid depth at all in the box: no estimate, the paper's rule for every keypoint.
        let blank = DepthMetres::new(640, 480, 0.0);
        let removed = cull_frame(&keypoints, &mut states, &tracked, Some(&blank), &settings());
        assert!(states[0].depth.is_none());
        assert_eq!(
            removed,
            cull_with(&keypoints, &states, &tracked, &CullParams::default())
        );
        // Depth switched off: the paper exactly, even with a good depth map.
        let mut off = settings();
        off.depth.enabled = false;
        let removed = cull_frame(&keypoints, &mut states, &tracked, Some(&depth), &off);
        assert_eq!(removed, vec![true, false, true]);
        // A depth slice shorter than the keypoints counts the rest as missing.
        let input = DepthCullInput {
            keypoints: &keypoints,
            keypoint_depths: &[],
            states: &states,
            tracked: &tracked,
            tracked_depths: &[],
        };
        let short = cull_with_depth(&input, &CullParams::default(), &off.depth);
        assert_eq!(short, vec![true, false, true]);
    }

    #[test]
    fn the_outliers_pick_the_object_when_the_centre_is_mostly_background() {
        // A thin person (40 px at 2 m) in a wide box: the central samples are mostly wall at 4 m,
        // but the outliers sit on the person.
        let bbox = BBox::new(100.0, 40.0, 400.0, 440.0);
        let depth = depth_map(4.0, &[([230, 40, 270, 440], 2.0)]);
        let tracked: Vec<TrackedPoint> = (0..5)
            .map(|i| pt(250.0, 100.0 + 50.0 * i as f32, true))
            .chain([pt(150.0, 200.0, false), pt(380.0, 100.0, true)]) // one bad track on the wall
            .collect();
        let o = object_depth(
            &bbox,
            &tracked,
            &depth,
            None,
            f32::INFINITY,
            &DepthParams::default(),
        )
        .expect("depth");
        assert!(o.central_share < 0.5, "{o:?}");
        assert_eq!(o.metres, 2.0);
        assert_eq!((o.outliers_with_depth, o.outliers_in_band), (6, 5));
        // Without outliers the centre's mode wins: the wall...
        let p = DepthParams::default();
        let none = object_depth(&bbox, &[], &depth, None, f32::INFINITY, &p).expect("depth");
        assert_eq!(none.metres, 4.0);
        // ... unless the last frame's band held the person (a walker's depth changes by
        // centimetres a frame), or the person's box is too tall for anyone at the wall's depth.
        let last = object_depth(&bbox, &tracked, &depth, None, f32::INFINITY, &p).expect("depth");
        let prior =
            object_depth(&bbox, &[], &depth, Some(&last), f32::INFINITY, &p).expect("depth");
        assert_eq!(prior.metres, 2.0);
        let bounded = object_depth(&bbox, &[], &depth, None, 3.0, &p).expect("depth");
        assert_eq!(bounded.metres, 2.0);
        // A person's box 400 px tall at fy 500 is within 2.5 m; a chair's is not bounded.
        let camera = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
        let walker = BoxState {
            bbox,
            class_id: PERSON,
            detection: 0,
            part: BoxPart::Whole,
            rule: crate::judge::Rule::Nhbc,
            verdict: Verdict::Dynamic,
            tracked: 0,
            outliers: 0,
            depth: None,
        };
        assert_eq!(person_farthest(&walker, Some(&camera), &p), 2.5);
        let chair = BoxState {
            class_id: CHAIR,
            ..walker
        };
        assert_eq!(person_farthest(&chair, Some(&camera), &p), f32::INFINITY);
        assert_eq!(person_farthest(&walker, None, &p), f32::INFINITY);
        // Degenerate boxes give no estimate, never a panic.
        for b in [
            BBox::new(f32::NAN, 0.0, 10.0, 10.0),
            BBox::new(50.0, 50.0, 10.0, 10.0),
            BBox::new(-500.0, -500.0, -400.0, -400.0),
        ] {
            assert!(
                object_depth(
                    &b,
                    &tracked,
                    &depth,
                    None,
                    f32::INFINITY,
                    &DepthParams::default()
                )
                .is_none()
            );
        }
    }

    #[test]
    fn unknown_objects_count_only_outliers_at_the_keypoints_depth() {
        // A walker the detector missed (no box) at 2 m before a wall at 4 m; a static chair box.
        let depth = depth_map(4.0, &[([300, 100, 360, 400], 2.0)]);
        let chair = det(CHAIR, 50.0, 300.0, 150.0, 440.0);
        let tracked: Vec<TrackedPoint> = [
            [320.0, 200.0],
            [340.0, 210.0],
            [330.0, 230.0],
            [310.0, 250.0],
        ]
        .iter()
        .map(|&[x, y]| pt(x, y, true))
        .chain((0..10).map(|i| pt(60.0 + 8.0 * i as f32, 350.0, false)))
        .collect();
        let mut states = judge_boxes(&[chair], &tracked, &JudgeParams::default());
        let keypoints = [
            [335.0, 215.0], // on the walker: culled
            [296.0, 220.0], // wall beside him, within the radius: kept (another depth)
            [500.0, 100.0], // far from every outlier: kept
        ];
        let s = settings(); // unknown objects on by default
        let removed = cull_frame(&keypoints, &mut states, &tracked, Some(&depth), &s);
        assert_eq!(removed, vec![true, false, false]);
        // Without depth the rule is off by default (monocular: box-less outliers lie all over
        // the static world); asked for, the wall point goes too (the paper's image-only rule).
        let removed = cull_frame(&keypoints, &mut states, &tracked, None, &s);
        assert_eq!(removed, vec![false; 3]);
        let mut image_only = settings();
        image_only.cull.unknown_objects_without_depth = true;
        let removed = cull_frame(&keypoints, &mut states, &tracked, None, &image_only);
        assert_eq!(removed, vec![true, true, false]);
        // Off (the paper): nothing outside a box is culled.
        let mut off = settings();
        off.cull.unknown_objects = false;
        let removed = cull_frame(&keypoints, &mut states, &tracked, Some(&depth), &off);
        assert_eq!(removed, vec![false; 3]);
    }

    #[test]
    fn background_outliers_beside_a_seated_person_do_not_pull_the_depth_behind_him() {
        // A seated person at 1.4 m fills two thirds of the box's centre; the room behind at
        // 2.3 m. Three outliers on the room beside him (noise, occlusion), one on his hand.
        let bbox = BBox::new(0.0, 76.0, 240.0, 310.0);
        let depth = depth_map(2.3, &[([40, 76, 140, 310], 1.4)]);
        let tracked = [
            pt(20.0, 100.0, true),
            pt(25.0, 200.0, true),
            pt(215.0, 150.0, true),
            pt(120.0, 200.0, true),
        ];
        let p = DepthParams::default();
        let o = object_depth(&bbox, &tracked, &depth, None, f32::INFINITY, &p).expect("depth");
        assert_eq!(o.metres, 1.4, "{o:?}");
        // Without the occluder rule the three background outliers win.
        let off = DepthParams {
            occluder_weight: 0.0,
            ..p
        };
        let o = object_depth(&bbox, &tracked, &depth, None, f32::INFINITY, &off).expect("depth");
        assert_eq!(o.metres, 2.3, "{o:?}");
    }

    #[test]
    fn band_grows_with_depth() {
        let p = DepthParams::default();
        assert_eq!(depth_band(1.0, &p), (0.6, 1.4));
        let (near, far) = depth_band(4.0, &p);
        let (n2, f2) = depth_band(8.0, &p);
        assert!((near - 3.6).abs() < 1e-5 && (far - 4.4).abs() < 1e-5);
        assert!((n2 - 7.2).abs() < 1e-5 && (f2 - 8.8).abs() < 1e-5);
    }
}
