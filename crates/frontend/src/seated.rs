//! Seated people (NHBC's split parts) and movable objects: which culled keypoints a 3D motion
//! test keeps, and which kept keypoints may lie on an object not proven still.

use stillpoint_dynamic::{BoxPart, BoxState, CulledFrame};
use stillpoint_features::LkPyramid;
use stillpoint_image::DepthMetres;

use crate::FrontEndSettings;

/// The seated-part 3D motion test (`dynamic::seated_motion`) on the culled keypoints whose only
/// dynamic boxes are seated parts; the decision is unchanged without a camera motion estimate.
pub(crate) fn seated_motion(
    kps: &[[f32; 2]],
    culled: &CulledFrame,
    states: &[BoxState],
    check: &stillpoint_dynamic::MotionCheck,
    (prev_depth, depth): (&DepthMetres, &DepthMetres),
    (prev_pyramid, pyramid): (&LkPyramid, &LkPyramid),
    settings: &FrontEndSettings,
) -> Vec<bool> {
    let removed = &culled.removed[..];
    let p = &settings.seated_motion;
    let height = pyramid.size().1 as f32;
    let top = settings.dynamic.judge.seated_top_fraction;
    let mut candidates = stillpoint_dynamic::seated_candidates(kps, removed, states);
    // NHBC's seated call on a box cut by the top or bottom edge is unreliable (a walker whose
    // legs leave the image): those keep today's rule.
    for (c, &[x, y]) in candidates.iter_mut().zip(kps) {
        *c &= !states.iter().any(|s| {
            s.is_dynamic() && s.bbox.contains_strict(x, y) && cut_vertically(s, height, top)
        });
    }
    if !candidates.contains(&true) {
        return removed.to_vec();
    }
    let Some(prev_to_cur) =
        stillpoint_dynamic::camera_motion(&check.points, states, prev_depth, depth, p)
    else {
        return removed.to_vec();
    };
    // The culling step tracked some of these already (same frames, same parameters, and each
    // keypoint is tracked on its own): track only the rest.
    let was_tracked = |i: usize| culled.tracked.get(i).copied().unwrap_or(false);
    let untracked: Vec<bool> = (0..kps.len())
        .map(|i| candidates[i] && !was_tracked(i))
        .collect();
    let mut motion = if untracked.contains(&true) {
        stillpoint_dynamic::keypoint_motion(
            prev_pyramid,
            pyramid,
            kps,
            &untracked,
            check,
            &settings.dynamic.keypoint_motion,
        )
    } else {
        vec![None; kps.len()]
    };
    for (i, m) in motion.iter_mut().enumerate() {
        if was_tracked(i) {
            *m = culled.motion.get(i).copied().flatten();
        }
    }
    let (out, kept) = stillpoint_dynamic::apply_seated_motion(
        kps,
        removed,
        &candidates,
        &motion,
        &prev_to_cur,
        depth,
        p,
    );
    if tracing::enabled!(tracing::Level::DEBUG) {
        let mut res: Vec<f32> = Vec::new();
        let (mut no_track, mut bad_fb) = (0, 0);
        for (i, c) in candidates.iter().enumerate() {
            if !c {
                continue;
            }
            match motion[i] {
                None => no_track += 1,
                Some(m) if m.fb_error > p.max_fb_error_px => bad_fb += 1,
                Some(m) => {
                    if let Some(r) =
                        stillpoint_dynamic::seated_residual(kps[i], &m, &prev_to_cur, depth, p)
                    {
                        res.push(r);
                    }
                }
            }
        }
        res.sort_by(f32::total_cmp);
        let q = |f: f32| {
            res.get((res.len() as f32 * f) as usize)
                .copied()
                .unwrap_or(-1.0)
        };
        tracing::debug!(
            "seated motion: {kept} of {} candidates kept; no track {no_track}, fb {bad_fb}, residuals {}, p25 {:.2} p50 {:.2} p75 {:.2} t {:?}",
            candidates.iter().filter(|&&c| c).count(),
            res.len(),
            q(0.25),
            q(0.5),
            q(0.75),
            prev_to_cur.translation.vector.as_slice()
        );
    }
    out
}

/// Whether a keypoint at `at` with depth `depth` (0 or `None`: unknown) may lie on the object of
/// box `s`: inside the box unless its depth puts it behind the object's depth band, or in a ring
/// `margin` x the box's size around it within the object's depth band (a detector's box often
/// misses an arm or the legs; what lies beside the person at another depth is something else).
pub(crate) fn on_movable_object(
    s: &BoxState,
    at: [f32; 2],
    depth: Option<f32>,
    margin: f32,
) -> bool {
    let [x, y] = at;
    let known = depth.filter(|&d| d > 0.0);
    if s.bbox.contains_strict(x, y) {
        return !matches!((known, s.depth), (Some(d), Some(o)) if d > o.far);
    }
    let (dx, dy) = (margin * s.bbox.width(), margin * s.bbox.height());
    let in_ring =
        x > s.bbox.x1 - dx && x < s.bbox.x2 + dx && y > s.bbox.y1 - dy && y < s.bbox.y2 + dy;
    in_ring && matches!((known, s.depth), (Some(d), Some(o)) if o.holds(d))
}

/// A box this close to the top or bottom edge of the image is cut by it (pixels).
const TRUNCATED_MARGIN_PX: f32 = 2.0;

/// The person's whole box (both parts of a seated one, NHBC's split at `top_fraction`) reaches
/// the top or bottom edge of an image `height` pixels high.
pub(crate) fn cut_vertically(s: &BoxState, height: f32, top_fraction: f32) -> bool {
    let (y1, y2) = (s.bbox.y1, s.bbox.y2);
    let (y1, y2) = match s.part {
        BoxPart::Whole => (y1, y2),
        BoxPart::SeatedTop => (y1, y1 + (y2 - y1) / top_fraction.max(1e-3)),
        BoxPart::SeatedBottom => (y2 - (y2 - y1) / (1.0 - top_fraction).max(1e-3), y2),
    };
    y1 <= TRUNCATED_MARGIN_PX || y2 >= height - 1.0 - TRUNCATED_MARGIN_PX
}

/// Kept keypoints inside a dynamic box and inside a box that protects them (static or unknown
/// verdict; paper algorithm 3 keeps them): tracked, but they create no map points.
pub fn protected_in_dynamic_box(
    kps: &[[f32; 2]],
    dynamic: &[bool],
    states: &[BoxState],
) -> Vec<bool> {
    kps.iter()
        .zip(dynamic)
        .map(|(&[x, y], &d)| {
            let inside = |s: &&BoxState| s.bbox.contains_strict(x, y);
            !d && states.iter().filter(inside).any(|s| s.is_dynamic())
                && states.iter().filter(inside).any(|s| !s.is_dynamic())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::PERSON_CLASS;
    use stillpoint_detect::BBox;
    use stillpoint_dynamic::Verdict;
    use stillpoint_dynamic::{Rule, nhbc_parts};

    fn state(part: BoxPart, bbox: BBox) -> BoxState {
        BoxState {
            bbox,
            class_id: PERSON_CLASS,
            detection: 0,
            part,
            rule: Rule::Nhbc,
            verdict: Verdict::Dynamic,
            tracked: 10,
            outliers: 1,
            depth: None,
        }
    }

    #[test]
    fn a_seated_part_is_cut_when_its_whole_box_reaches_the_top_or_bottom_edge() {
        let judge = stillpoint_dynamic::JudgeParams::default();
        let top = judge.seated_top_fraction;
        // A walker whose legs leave a 480-pixel-high image: both parts count as cut.
        let walker = BBox::new(446.0, 12.0, 639.5, 479.5);
        for (part, bbox) in nhbc_parts(&walker, &judge) {
            assert!(part != BoxPart::Whole);
            assert!(cut_vertically(&state(part, bbox), 480.0, top), "{part:?}");
        }
        // A seated person inside the image, touching only the left edge: neither part is cut.
        let seated = BBox::new(0.0, 112.0, 206.0, 454.0);
        for (part, bbox) in nhbc_parts(&seated, &judge) {
            assert!(!cut_vertically(&state(part, bbox), 480.0, top), "{part:?}");
        }
        assert!(cut_vertically(
            &state(BoxPart::Whole, BBox::new(10.0, 0.0, 20.0, 100.0)),
            480.0,
            top
        ));
    }
}
