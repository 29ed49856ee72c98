//! Per-keypoint motion evidence inside dynamic boxes (ours, not in the paper).
//!
//! The paper culls by boxes: every keypoint inside a dynamic box goes (and our depth-aware
//! culling every keypoint at the mover's depth). A seated person moves a hand or the head while
//! the torso stays; a walker's planted foot stands still. Here each ORB keypoint inside a
//! dynamic box gets its own evidence: it is tracked backward with LK into the previous frame
//! (on the pyramids the geometry module already built, see
//! [`crate::motion_consistency_pyramids`]), tracked forward again to check the track
//! (forward-backward error), and its residual under the frame's two-view model
//! ([`crate::MotionCheck::model`]: epipolar distance for F, transfer error for a homography,
//! distance from the median flow) says whether it moved in the world.
//!
//! [`apply_keypoint_motion`] then changes the box decision only where the evidence is clear:
//! - a culled keypoint whose reliable track (forward-backward error at most
//!   [`KeypointMotionParams::max_fb_error_px`]) fits the model within
//!   [`KeypointMotionParams::keep_below_px`] is kept: background seen inside a walker's box
//!   at the walker's depth (a wall right behind him, the floor at his feet);
//! - keypoints that cannot be tracked keep the box decision.
//!
//! What is left off with depth, and why (see [`KeypointMotionParams`]): the epipolar distance
//! is blind to motion along the epipolar line, so only a homography's transfer error (a still
//! or rotating camera, which sees every motion) may keep a keypoint; a seated person's moving
//! hand often moves less than half a pixel, so a seated person's parts keep the box decision
//! ([`crate::seated_motion`] tests them); culling kept keypoints that break the model (a 1 px
//! rule) culls the background next to the silhouette, whose LK window holds part of the mover.
//! Most remaining false positives on walkers are keypoints whose FAST circle straddles the
//! silhouette: occlusion corners that do move with the person, which no motion evidence can
//! (or should) keep. Measurements: docs/measurements.md.
//!
//! Without depth (monocular) the evidence is all there is to tell a mover from the room in its
//! box; looser rules for such frames are measured and left off by default
//! ([`crate::EvidenceWithoutDepth`]): a culled keypoint is kept
//! within 1 px in seated parts too, a kept one (a static box protected it) is culled above
//! 2 px, and a culled keypoint whose track is lost or unreliable (LK's coarse levels hold the
//! mover next to a silhouette) is kept when its patch is found where the static world's
//! motion puts it ([`EvidenceRules::patch_ncc_min`]). Measurements: docs/monocular.md.

use crate::depth::cull_frame_protecting;
use crate::judge::{BoxPart, BoxState};
use crate::motion_consistency::{MotionCheck, MotionModel};
use crate::settings::{DynamicSettings, EvidenceRules, KeypointMotionParams};
use serde::Serialize;
use stillpoint_features::{LkParams, LkPyramid, track_lk_pyramids};
use stillpoint_geometry::homography::transfer_error2;
use stillpoint_geometry::{Mat3, Vec2, epipolar_distance};
use stillpoint_image::DepthMetres;

/// The motion evidence of one keypoint.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct KeypointMotion {
    /// Where the keypoint was in the previous frame (backward LK), pixels.
    pub prev: [f32; 2],
    /// Residual of the pair (prev, keypoint) under the frame's motion model, pixels.
    pub residual: f32,
    /// Distance between the keypoint and its backward track tracked forward again, pixels.
    pub fb_error: f32,
    /// The model the residual is measured against.
    pub model: MotionModel,
}

/// Track the keypoints flagged in `candidates` (all when `candidates` is shorter) backward
/// from `cur_pyr` into `prev_pyr`, forward again, and measure each pair against `check`'s
/// model. `None` where a track failed, left the image, or the frame has no model. Both
/// pyramids must have gradients ([`LkPyramid::new`]) and the sizes of the frames `check` judged.
///
/// ```
/// use stillpoint_dynamic::{GeometryParams, KeypointMotionParams, keypoint_motion,
///     motion_consistency_pyramids};
/// use stillpoint_features::LkPyramid;
/// use stillpoint_image::Gray8;
/// let mut img = Gray8::new(160, 120, 0);
/// for y in 0..120 { for x in 0..160 {
///     img.set(x, y, ((x / 8 * 37 + y / 8 * 91) % 200 + 20) as u8);
/// }}
/// let p = GeometryParams::default();
/// let pyr = LkPyramid::new(&img, &p.lk);
/// let check = motion_consistency_pyramids(&img, &img, &pyr, &pyr, &p);
/// let ev = keypoint_motion(&pyr, &pyr, &[[40.0, 40.0]], &[], &check, &KeypointMotionParams::default());
/// assert!(ev[0].is_some_and(|m| m.residual < 0.1)); // nothing moved
/// ```
pub fn keypoint_motion(
    prev_pyr: &LkPyramid,
    cur_pyr: &LkPyramid,
    keypoints: &[[f32; 2]],
    candidates: &[bool],
    check: &MotionCheck,
    p: &KeypointMotionParams,
) -> Vec<Option<KeypointMotion>> {
    let mut out = vec![None; keypoints.len()];
    let Some(residual) = Residual::of(check) else {
        return out;
    };
    let idx: Vec<usize> = (0..keypoints.len())
        .filter(|&i| candidates.get(i).copied().unwrap_or(true))
        .filter(|&i| keypoints[i][0].is_finite() && keypoints[i][1].is_finite())
        .collect();
    if idx.is_empty() {
        return out;
    }
    let lk: &LkParams = &p.lk;
    let pts: Vec<[f32; 2]> = idx.iter().map(|&i| keypoints[i]).collect();
    let back = track_lk_pyramids(cur_pyr, prev_pyr, &pts, lk);
    let ok: Vec<usize> = (0..pts.len()).filter(|&k| back[k].is_some()).collect();
    let back_pts: Vec<[f32; 2]> = ok.iter().filter_map(|&k| back[k]).collect();
    let again = track_lk_pyramids(prev_pyr, cur_pyr, &back_pts, lk);
    let (w, h) = prev_pyr.size();
    for (j, &k) in ok.iter().enumerate() {
        let (Some(b), Some(f)) = (back[k], again[j]) else {
            continue;
        };
        let border = p.border_px;
        if b[0] < border
            || b[1] < border
            || b[0] > w as f32 - 1.0 - border
            || b[1] > h as f32 - 1.0 - border
        {
            continue;
        }
        let kp = pts[k];
        let fb = ((f[0] - kp[0]).powi(2) + (f[1] - kp[1]).powi(2)).sqrt();
        let r = residual.measure(b, kp);
        if !(r.is_finite() && fb.is_finite()) {
            continue;
        }
        out[idx[k]] = Some(KeypointMotion {
            prev: b,
            residual: r,
            fb_error: fb,
            model: check.model,
        });
    }
    out
}

/// The frame's motion model, ready to measure a pair (previous, current) in pixels.
#[derive(Clone, Copy, Debug)]
enum Residual {
    Fundamental(Mat3),
    Homography(Mat3),
    /// The median flow.
    Flow([f32; 2]),
}

impl Residual {
    fn of(check: &MotionCheck) -> Option<Self> {
        match (check.model, check.matrix) {
            (MotionModel::Fundamental, Some(f)) => Some(Self::Fundamental(f)),
            (MotionModel::Homography, Some(h)) => Some(Self::Homography(h)),
            (MotionModel::Flow, _) if !check.points.is_empty() => {
                let median = |mut c: Vec<f32>| {
                    c.sort_by(f32::total_cmp);
                    c[c.len() / 2]
                };
                Some(Self::Flow([
                    median(check.points.iter().map(|t| t.cur[0] - t.prev[0]).collect()),
                    median(check.points.iter().map(|t| t.cur[1] - t.prev[1]).collect()),
                ]))
            }
            _ => None,
        }
    }

    /// The motion back from the current frame to the previous one, as a map of points:
    /// `None` under F (a pixel maps to a line, not a point) or where the homography does not
    /// invert. Built once a frame, not once a keypoint.
    fn backward(&self) -> Option<Self> {
        match self {
            Self::Fundamental(_) => None,
            Self::Homography(h) => h.try_inverse().map(Self::Homography),
            Self::Flow([mx, my]) => Some(Self::Flow([-mx, -my])),
        }
    }

    /// Where this motion (a homography or the flow) takes pixel `a`; `None` under F or at
    /// infinity.
    fn map_point(&self, a: [f32; 2]) -> Option<[f32; 2]> {
        match self {
            Self::Fundamental(_) => None,
            Self::Homography(h) => {
                let q = h * stillpoint_geometry::Vec3::new(a[0] as f64, a[1] as f64, 1.0);
                (q.z.abs() > 1e-12).then(|| [(q.x / q.z) as f32, (q.y / q.z) as f32])
            }
            Self::Flow([mx, my]) => Some([a[0] + mx, a[1] + my]),
        }
    }

    fn measure(&self, a: [f32; 2], b: [f32; 2]) -> f32 {
        let v = |p: [f32; 2]| Vec2::new(p[0] as f64, p[1] as f64);
        match self {
            Self::Fundamental(f) => epipolar_distance(f, &v(a), &v(b)) as f32,
            Self::Homography(h) => transfer_error2(h, &v(a), &v(b)).sqrt() as f32,
            Self::Flow([mx, my]) => {
                ((b[0] - a[0] - mx).powi(2) + (b[1] - a[1] - my).powi(2)).sqrt()
            }
        }
    }
}

/// True for each keypoint strictly inside some dynamic box: the candidates for
/// [`keypoint_motion`].
pub fn in_dynamic_box(keypoints: &[[f32; 2]], states: &[BoxState]) -> Vec<bool> {
    keypoints
        .iter()
        .map(|&[x, y]| {
            states
                .iter()
                .any(|s| s.is_dynamic() && s.bbox.contains_strict(x, y))
        })
        .collect()
}

/// Change the culling decision `removed` where a keypoint's own evidence is clear under `rules`
/// ([`KeypointMotionParams::rules`]: the frame's, with depth or without); keypoints in no
/// dynamic box, or without evidence, keep their decision.
///
/// ```
/// use stillpoint_dynamic::{BoxPart, BoxState, KeypointMotion, KeypointMotionParams, MotionModel,
///     Rule, Verdict, apply_keypoint_motion};
/// use stillpoint_geometry::BBox;
/// let walker = BoxState { bbox: BBox::new(0.0, 0.0, 100.0, 300.0), class_id: 0, detection: 0,
///     part: BoxPart::Whole, rule: Rule::Nhbc, verdict: Verdict::Dynamic, tracked: 9,
///     outliers: 4, depth: None };
/// let ev = |residual| Some(KeypointMotion { prev: [0.0; 2], residual, fb_error: 0.05,
///     model: MotionModel::Homography });
/// let kps = [[50.0, 50.0], [5.0, 280.0]];
/// let rules = KeypointMotionParams::default().rules(false);
/// let removed = apply_keypoint_motion(&kps, &[true, true], &[walker],
///     &[ev(4.0), ev(0.1)], &rules);
/// assert_eq!(removed, vec![true, false]); // the walker culled, the floor behind him kept
/// ```
pub fn apply_keypoint_motion(
    keypoints: &[[f32; 2]],
    removed: &[bool],
    states: &[BoxState],
    motion: &[Option<KeypointMotion>],
    rules: &EvidenceRules,
) -> Vec<bool> {
    keypoints
        .iter()
        .enumerate()
        .map(|(i, &[x, y])| {
            let was = removed.get(i).copied().unwrap_or(false);
            let Some(m) = motion.get(i).copied().flatten() else {
                return was;
            };
            let mut dynamic = states
                .iter()
                .filter(|s| s.is_dynamic() && s.bbox.contains_strict(x, y))
                .peekable();
            if dynamic.peek().is_none() {
                return was;
            }
            if was {
                // A seated person's hand often moves less than half a pixel between frames
                // (with depth, `seated_motion` tests those parts), and the epipolar test is
                // blind along the epipolar line: neither keeps a keypoint.
                let keep_allowed = rules.may_keep(m.model)
                    && dynamic.all(|s| match s.part {
                        BoxPart::Whole => rules.keep_in_whole_boxes,
                        _ => rules.keep_in_seated_parts,
                    });
                let fits =
                    m.fb_error <= rules.keep_max_fb_error_px && m.residual <= rules.keep_below_px;
                !(keep_allowed && fits)
            } else {
                m.fb_error <= rules.cull_max_fb_error_px && m.residual > rules.cull_above_px
            }
        })
        .collect()
}

/// The whole culling step with the per-keypoint evidence: [`crate::cull_frame`] (depth-aware on RGB-D
/// frames, the paper's algorithm 3 otherwise), then, when
/// [`KeypointMotionParams::enabled`] and the frames' LK pyramids (previous, current; both from
/// [`LkPyramid::new`], as given to [`crate::motion_consistency_pyramids`]) are at hand,
/// [`keypoint_motion`] on the keypoints inside dynamic boxes and [`apply_keypoint_motion`].
/// Without pyramids this is [`crate::cull_frame`] exactly. `true` = dynamic, remove.
pub fn cull_frame_with_motion(
    keypoints: &[[f32; 2]],
    states: &mut [BoxState],
    check: &MotionCheck,
    depth: Option<&DepthMetres>,
    pyramids: Option<(&LkPyramid, &LkPyramid)>,
    s: &DynamicSettings,
) -> Vec<bool> {
    cull_frame_with_evidence(keypoints, states, check, depth, pyramids, s).removed
}

/// What [`cull_frame_with_evidence`] decided and measured.
#[derive(Clone, Debug, Default)]
pub struct CulledFrame {
    /// `true` = dynamic, remove (as [`cull_frame_with_motion`] returns it).
    pub removed: Vec<bool>,
    /// The keypoints [`keypoint_motion`] was asked to track (empty when it did not run).
    pub tracked: Vec<bool>,
    /// Its evidence, per keypoint (empty when it did not run).
    pub motion: Vec<Option<KeypointMotion>>,
    /// The frame followed the rules without depth ([`crate::EvidenceWithoutDepth`]): no depth,
    /// and a model that sees motion in every direction (a homography or the flow).
    pub without_depth_rules: bool,
}

/// [`cull_frame_with_motion`], also handing back the per-keypoint evidence it measured, so that
/// a later test on the same frames (the front-end's seated-part test) tracks no keypoint twice.
pub fn cull_frame_with_evidence(
    keypoints: &[[f32; 2]],
    states: &mut [BoxState],
    check: &MotionCheck,
    depth: Option<&DepthMetres>,
    pyramids: Option<(&LkPyramid, &LkPyramid)>,
    s: &DynamicSettings,
) -> CulledFrame {
    let km = &s.keypoint_motion;
    let pyramids = pyramids.filter(|_| km.enabled);
    // Without depth the looser rules, and the evidence instead of static boxes' protection,
    // only where the model sees motion in every direction: under F the residual is blind
    // along the epipolar line (a driving camera's frames), and the paper's rules stay.
    let loose = depth.is_none()
        && pyramids.is_some()
        && km.without_depth.enabled
        && check.model != MotionModel::Fundamental
        && check.model != MotionModel::None;
    let protect = s.cull.static_box_protects && (!loose || km.without_depth.static_boxes_protect);
    let removed = cull_frame_protecting(keypoints, states, &check.points, depth, s, protect);
    let Some((prev_pyr, cur_pyr)) = pyramids else {
        return CulledFrame {
            removed,
            without_depth_rules: loose,
            ..CulledFrame::default()
        };
    };
    // Track only the keypoints a rule could change: culled ones, when the model may keep them;
    // kept ones, when the cull rule is on.
    let rules = km.rules(loose);
    let may_keep = rules.may_keep(check.model);
    let may_cull = rules.may_cull();
    let candidates: Vec<bool> = in_dynamic_box(keypoints, states)
        .iter()
        .zip(&removed)
        .map(|(&inside, &r)| inside && if r { may_keep } else { may_cull })
        .collect();
    if !candidates.contains(&true) {
        return CulledFrame {
            removed,
            without_depth_rules: loose,
            ..CulledFrame::default()
        };
    }
    let mut motion = keypoint_motion(
        prev_pyr,
        cur_pyr,
        keypoints,
        &candidates,
        check,
        &s.keypoint_motion,
    );
    if loose && may_keep {
        let unsure: Vec<bool> = (0..keypoints.len())
            .map(|i| {
                candidates[i]
                    && removed[i]
                    && motion[i].is_none_or(|m| m.fb_error > rules.keep_max_fb_error_px)
            })
            .collect();
        found_where_predicted(
            prev_pyr,
            cur_pyr,
            keypoints,
            &unsure,
            check,
            &rules,
            &mut motion,
        );
    }
    let after = apply_keypoint_motion(keypoints, &removed, states, &motion, &rules);
    CulledFrame {
        removed: after,
        tracked: candidates,
        motion,
        without_depth_rules: loose,
    }
}

/// The fallback where a culled keypoint's track gives no reliable evidence (`unsure`: lost, or
/// its forward-backward error over `rules.keep_max_fb_error_px`): its patch compared with the
/// previous frame's where the static world's motion puts it ([`EvidenceRules::patch_ncc_min`];
/// a homography or the flow: under F the place is a line). Found there, the keypoint's evidence
/// becomes a fit: residual 0 at that place. Near a silhouette LK's coarser levels hold the mover
/// and lose the track of the background beside it; a 7x7 patch at the predicted place does not.
fn found_where_predicted(
    prev_pyr: &LkPyramid,
    cur_pyr: &LkPyramid,
    keypoints: &[[f32; 2]],
    unsure: &[bool],
    check: &MotionCheck,
    rules: &EvidenceRules,
    motion: &mut [Option<KeypointMotion>],
) {
    // NaN or above 1: off.
    if rules.patch_ncc_min.is_nan() || rules.patch_ncc_min > 1.0 || !unsure.contains(&true) {
        return;
    }
    let Some(back) = Residual::of(check).and_then(|r| r.backward()) else {
        return;
    };
    for (i, kp) in keypoints.iter().enumerate() {
        if !unsure.get(i).copied().unwrap_or(false) {
            continue;
        }
        let Some(prev) = back.map_point(*kp) else {
            continue;
        };
        let ncc = cur_pyr.patch_ncc(*kp, prev_pyr, prev, PATCH_HALF_PX);
        if ncc.is_some_and(|c| c >= rules.patch_ncc_min) {
            motion[i] = Some(KeypointMotion {
                prev,
                residual: 0.0,
                fb_error: 0.0,
                model: check.model,
            });
        }
    }
}

/// Half side of [`found_where_predicted`]'s patches: 7x7, LK's window.
const PATCH_HALF_PX: usize = 3;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::judge::{Rule, Verdict};
    use crate::motion_consistency::motion_consistency_pyramids;
    use crate::settings::GeometryParams;
    use stillpoint_geometry::BBox;
    use stillpoint_image::Gray8;

    /// A smooth random texture (blurred 6 px blocks), `seed` picks the pattern.
    fn texture(seed: u32, x: isize, y: isize) -> u8 {
        crate::test_texture::blocky(seed, 6, x, y)
    }

    /// A still background with a "hand" rectangle shifted by `shift` (content and rect).
    fn frame(hand: [isize; 4], shift: [isize; 2]) -> Gray8 {
        let mut img = Gray8::new(320, 240, 0);
        for y in 0..240isize {
            for x in 0..320isize {
                let (u, v) = (x - shift[0], y - shift[1]);
                let on_hand = u >= hand[0] && u < hand[2] && v >= hand[1] && v < hand[3];
                let value = if on_hand {
                    texture(2, u, v)
                } else {
                    texture(1, x, y)
                };
                img.set(x as usize, y as usize, value);
            }
        }
        img
    }

    fn person(part: BoxPart, bbox: BBox) -> BoxState {
        BoxState {
            bbox,
            class_id: 0,
            detection: 0,
            part,
            rule: Rule::Nhbc,
            verdict: Verdict::Dynamic,
            tracked: 20,
            outliers: 5,
            depth: None,
        }
    }

    #[test]
    fn still_background_in_a_moving_box_is_kept_the_mover_is_not() {
        let hand = [140, 90, 200, 150];
        let (prev, cur) = (frame(hand, [0, 0]), frame(hand, [3, 2]));
        let g = GeometryParams::default();
        let km = KeypointMotionParams::default();
        let (pp, cp) = (LkPyramid::new(&prev, &g.lk), LkPyramid::new(&cur, &g.lk));
        let check = motion_consistency_pyramids(&prev, &cur, &pp, &cp, &g);
        assert_eq!(check.model, MotionModel::Homography);
        // Keypoints: on the hand (moved 3, 2), on the background inside the box, and one on a
        // flat black image region... none here: every point is textured.
        let kps = [
            [170.0, 120.0],
            [160.0, 110.0],
            [110.0, 60.0],
            [230.0, 180.0],
        ];
        let ev = keypoint_motion(&pp, &cp, &kps, &[], &check, &km);
        let r: Vec<f32> = ev.iter().map(|m| m.expect("tracked").residual).collect();
        assert!(r[0] > 2.0 && r[1] > 2.0, "hand residuals {r:?}");
        assert!(r[2] < 0.3 && r[3] < 0.3, "background residuals {r:?}");
        // A standing person's box around everything: the background goes back, the hand stays
        // culled. The same box as a seated part keeps the box decision (by default).
        let whole = person(BoxPart::Whole, BBox::new(100.0, 40.0, 260.0, 200.0));
        let removed = apply_keypoint_motion(&kps, &[true; 4], &[whole], &ev, &km.rules(false));
        assert_eq!(removed, vec![true, true, false, false]);
        let top = person(BoxPart::SeatedTop, whole.bbox);
        let removed = apply_keypoint_motion(&kps, &[true; 4], &[top], &ev, &km.rules(false));
        assert_eq!(removed, vec![true; 4]);
        // Without depth, with its rules on, the evidence is all there is: a seated part keeps
        // its background too.
        let mut loose = km.clone();
        loose.without_depth.enabled = true;
        let removed = apply_keypoint_motion(&kps, &[true; 4], &[top], &ev, &loose.rules(true));
        assert_eq!(removed, vec![true, true, false, false]);
        // The whole step: only the keypoints inside the dynamic box are looked at.
        let mut states = [whole];
        let s = DynamicSettings::default();
        let removed = cull_frame_with_motion(&kps, &mut states, &check, None, Some((&pp, &cp)), &s);
        assert_eq!(removed, vec![true, true, false, false]);
        // Without pyramids, or switched off: the box decision.
        let removed = cull_frame_with_motion(&kps, &mut states, &check, None, None, &s);
        assert_eq!(removed, vec![true; 4]);
        let mut off = s.clone();
        off.keypoint_motion.enabled = false;
        let removed =
            cull_frame_with_motion(&kps, &mut states, &check, None, Some((&pp, &cp)), &off);
        assert_eq!(removed, vec![true; 4]);
    }

    #[test]
    fn epipolar_fit_keeps_nothing_by_default_and_unreliable_tracks_keep_the_box_decision() {
        let bbox = BBox::new(0.0, 0.0, 100.0, 100.0);
        let ev = |residual, fb_error, model| {
            Some(KeypointMotion {
                prev: [0.0; 2],
                residual,
                fb_error,
                model,
            })
        };
        let kps = [
            [10.0, 10.0],
            [20.0, 20.0],
            [30.0, 30.0],
            [40.0, 40.0],
            [500.0, 5.0],
        ];
        let motion = [
            ev(0.1, 0.05, MotionModel::Fundamental), // blind along the epipolar line
            ev(0.1, 2.0, MotionModel::Homography),   // forward-backward failed
            None,                                    // not tracked
            ev(0.1, 0.05, MotionModel::Flow),
            ev(0.1, 0.05, MotionModel::Homography), // in no dynamic box
        ];
        let km = KeypointMotionParams::default();
        let states = [person(BoxPart::Whole, bbox)];
        let removed = apply_keypoint_motion(&kps, &[true; 5], &states, &motion, &km.rules(false));
        assert_eq!(removed, vec![true, true, true, false, true]);
        // The optional cull rule: a kept keypoint in a dynamic box that broke the model.
        let cull = KeypointMotionParams {
            cull_above_px: 1.0,
            ..km.clone()
        };
        let moved = [ev(3.0, 0.05, MotionModel::Fundamental)];
        let removed =
            apply_keypoint_motion(&kps[..1], &[false], &states, &moved, &cull.rules(false));
        assert_eq!(removed, vec![true]);
        // Without depth a kept keypoint in a dynamic box (a static box protected it) that
        // clearly moved is culled; with an unreliable track it keeps its decision. A residual
        // of 0.8 px keeps a culled keypoint there (0.5 px with depth).
        let mut on = km.clone();
        on.without_depth.enabled = true;
        let without = on.rules(true);
        let kept = [
            ev(3.0, 0.05, MotionModel::Homography),
            ev(3.0, 1.5, MotionModel::Homography),
            ev(0.8, 1.5, MotionModel::Homography),
        ];
        let removed =
            apply_keypoint_motion(&kps[..3], &[false, false, true], &states, &kept, &without);
        assert_eq!(removed, vec![true, false, false]);
        let removed = apply_keypoint_motion(
            &kps[..3],
            &[false, false, true],
            &states,
            &kept,
            &km.rules(false),
        );
        assert_eq!(removed, vec![false, false, true]);
        assert_eq!(km.rules(true), km.rules(false), "off by default");
        // Short or empty slices never panic.
        assert_eq!(
            apply_keypoint_motion(&kps, &[], &states, &[], &km.rules(false)),
            vec![false; 5]
        );
    }

    #[test]
    fn a_keypoint_without_a_track_is_found_where_the_static_world_puts_it_or_not() {
        let hand = [140, 90, 200, 150];
        let (prev, cur) = (frame(hand, [0, 0]), frame(hand, [3, 2]));
        let g = GeometryParams::default();
        let (pp, cp) = (LkPyramid::new(&prev, &g.lk), LkPyramid::new(&cur, &g.lk));
        let check = motion_consistency_pyramids(&prev, &cur, &pp, &cp, &g);
        assert_eq!(check.model, MotionModel::Homography);
        // The background (still) and the hand (moved 3, 2), both without a track.
        let kps = [[110.0, 60.0], [170.0, 120.0], [230.0, 180.0]];
        let mut on = KeypointMotionParams::default();
        on.without_depth.enabled = true;
        let rules = on.rules(true);
        let mut motion = vec![None; 3];
        let unsure = [true, true, false];
        found_where_predicted(&pp, &cp, &kps, &unsure, &check, &rules, &mut motion);
        assert!(motion[0].is_some_and(|m| m.residual == 0.0), "{motion:?}");
        assert_eq!(motion[1], None, "the hand's patch is elsewhere");
        assert_eq!(motion[2], None, "not asked");
        // With the rules with depth (the default) nothing is looked for.
        let mut motion = vec![None; 3];
        let off = KeypointMotionParams::default().rules(true);
        found_where_predicted(&pp, &cp, &kps, &unsure, &check, &off, &mut motion);
        assert_eq!(motion, vec![None; 3]);
    }

    #[test]
    fn mismatched_pyramids_or_no_model_give_no_evidence() {
        let img = frame([140, 90, 200, 150], [0, 0]);
        let small = Gray8::new(64, 48, 9);
        let g = GeometryParams::default();
        let km = KeypointMotionParams::default();
        let (a, b) = (LkPyramid::new(&img, &g.lk), LkPyramid::new(&small, &g.lk));
        let check = motion_consistency_pyramids(&img, &img, &a, &b, &g);
        assert_eq!(check.model, MotionModel::None);
        let kps = [[100.0, 100.0], [f32::NAN, 3.0]];
        assert_eq!(
            keypoint_motion(&a, &b, &kps, &[], &check, &km),
            vec![None, None]
        );
        let good = motion_consistency_pyramids(&img, &img, &a, &a, &g);
        assert_eq!(
            keypoint_motion(&a, &b, &kps, &[], &good, &km),
            vec![None, None]
        );
        let ev = keypoint_motion(&a, &a, &kps, &[true, true], &good, &km);
        assert!(ev[0].is_some() && ev[1].is_none());
        assert_eq!(
            keypoint_motion(&a, &a, &kps, &[false, false], &good, &km),
            vec![None, None]
        );
    }
}
