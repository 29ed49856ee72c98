//! Which kept keypoints may create map points: none on an object not proven still, beside an
//! outlier no box explains, or moving against the static world.

use stillpoint_dynamic::{BoxState, DynamicSettings, ObjectDecision, TrackedPoint};
use stillpoint_features::LkPyramid;
use stillpoint_geometry::{Se3, Vec3};
use stillpoint_image::{DepthMetres, Gray8};

use super::DynamicFrontEnd;
use crate::Judgement;
use crate::seated::{on_movable_object, protected_in_dynamic_box};

impl DynamicFrontEnd {
    /// Map hygiene against movers no box covers: each kept keypoint that may make a map point
    /// is tracked back into the previous frame and judged against the static world's camera
    /// motion; one that moved, or that cannot be found there
    /// (`WorldMotionParams::new_point_lost_track_moved`), makes none
    /// (`WorldMotionParams::check_new_points`).
    pub(super) fn bar_moving_new_points(
        &self,
        out: &mut Judgement,
        kps: &[[f32; 2]],
        (gray, depth): (&Gray8, &DepthMetres),
        motion: &Se3,
        (prev_pyramid, pyramid): (&LkPyramid, &LkPyramid),
        check: &stillpoint_dynamic::MotionCheck,
    ) {
        let p = &self.settings.dynamic.world;
        if !p.check_new_points {
            return;
        }
        let barred = |i: usize| out.no_new_points.get(i).copied().unwrap_or(false);
        let candidates: Vec<bool> = (0..kps.len())
            .map(|i| !out.dynamic[i] && !barred(i))
            .collect();
        if !candidates.contains(&true) {
            return;
        }
        // Only keypoints that can have a residual (a corner with a smooth depth) are tracked.
        let lifted: Vec<Option<Vec3>> = (0..kps.len())
            .map(|i| {
                candidates[i]
                    .then(|| stillpoint_dynamic::lift_keypoint(kps[i], gray, depth, p))
                    .flatten()
            })
            .collect();
        let tracked: Vec<bool> = lifted.iter().map(Option::is_some).collect();
        let km = &self.settings.dynamic.keypoint_motion;
        let motion_of =
            stillpoint_dynamic::keypoint_motion(prev_pyramid, pyramid, kps, &tracked, check, km);
        let depths =
            stillpoint_dynamic::depth::keypoint_depths(depth, kps, &self.settings.dynamic.depth);
        let cur_to_prev = motion.inverse();
        use stillpoint_dynamic::NewPointCheck;
        let mut moving: Vec<usize> = Vec::new();
        let (mut judged, mut lost) = (0, 0);
        for (i, (&m, point)) in motion_of.iter().zip(&lifted).enumerate() {
            let Some(point) = point else {
                continue;
            };
            match stillpoint_dynamic::new_point_check(point, m, &cur_to_prev, p, km.max_fb_error_px)
            {
                NewPointCheck::Still => judged += 1,
                NewPointCheck::Moved => {
                    judged += 1;
                    moving.push(i);
                }
                NewPointCheck::Lost => {
                    lost += 1;
                    if p.new_point_lost_track_moved {
                        moving.push(i);
                    }
                }
            }
        }
        tracing::debug!(
            "new points: {} candidates, {} with a residual, {judged} tracked back, {lost} lost, {} moved",
            candidates.iter().filter(|&&c| c).count(),
            tracked.iter().filter(|&&t| t).count(),
            moving.len()
        );
        if moving.is_empty() {
            return;
        }
        if out.no_new_points.len() != kps.len() {
            out.no_new_points = vec![false; kps.len()];
        }
        let r2 = p.new_point_radius_px * p.new_point_radius_px;
        let mut barred_near = 0;
        for i in (0..kps.len()).filter(|&i| candidates[i]) {
            let d = depths[i];
            let near = moving
                .iter()
                .filter(|&&m| {
                    let (dx, dy) = (kps[m][0] - kps[i][0], kps[m][1] - kps[i][1]);
                    let dm = depths[m];
                    dx * dx + dy * dy <= r2 && d > 0.0 && (d - dm).abs() <= (0.3f32).max(0.15 * dm)
                })
                .count();
            if moving.contains(&i) || near >= 2 {
                out.no_new_points[i] = true;
                barred_near += (!moving.contains(&i)) as usize;
            }
        }
        tracing::debug!(
            "{} kept keypoints moved against the static world, {barred_near} beside them: no new points",
            moving.len()
        );
    }

    /// Map hygiene: kept keypoints inside the box of an object not yet proven still for
    /// `ObjectParams::still_frames_to_map` frames create no map points, unless their depth puts
    /// them clearly behind the object (background seen past a person).
    fn movable_hygiene(
        kps: &[[f32; 2]],
        dynamic: &[bool],
        states: &[BoxState],
        decisions: &[ObjectDecision],
        depth: Option<&DepthMetres>,
        settings: &DynamicSettings,
        margin: f32,
    ) -> Vec<bool> {
        let blocked: Vec<&BoxState> = states
            .iter()
            .zip(decisions)
            .filter(|(_, d)| !d.may_create_points)
            .map(|(s, _)| s)
            .collect();
        if blocked.is_empty() {
            return vec![false; kps.len()];
        }
        let depths =
            depth.map(|d| stillpoint_dynamic::depth::keypoint_depths(d, kps, &settings.depth));
        kps.iter()
            .enumerate()
            .map(|(i, &[x, y])| {
                let d = depths.as_ref().map(|d| d[i]);
                !dynamic[i]
                    && blocked
                        .iter()
                        .any(|s| on_movable_object(s, [x, y], d, margin))
            })
            .collect()
    }

    /// Merge [`DynamicFrontEnd::movable_hygiene`] into the outcome's `no_new_points`.
    pub(super) fn add_hygiene(
        &self,
        out: &mut Judgement,
        kps: &[[f32; 2]],
        states: &[BoxState],
        decisions: &[ObjectDecision],
        depth: Option<&DepthMetres>,
    ) {
        if !self.settings.dynamic.objects.enabled || !self.settings.movable_hygiene {
            return;
        }
        let blocked = Self::movable_hygiene(
            kps,
            &out.dynamic,
            states,
            decisions,
            depth,
            &self.settings.dynamic,
            self.settings.movable_hygiene_margin,
        );
        if !blocked.contains(&true) {
            return;
        }
        if out.no_new_points.len() != kps.len() {
            out.no_new_points = vec![false; kps.len()];
        }
        for (n, b) in out.no_new_points.iter_mut().zip(blocked) {
            *n |= b;
        }
    }

    /// Which kept keypoints must not create map points (empty when no rule is on).
    pub(super) fn no_new_points(
        &self,
        kps: &[[f32; 2]],
        dynamic: &[bool],
        states: &[BoxState],
        tracked: &[TrackedPoint],
        has_depth: bool,
    ) -> Vec<bool> {
        let s = &self.settings;
        let guard = s.outlier_guard_radius_px > 0.0
            && !tracked.is_empty()
            && (has_depth || s.outlier_guard_without_depth);
        if !s.no_new_points_in_dynamic_boxes && !guard {
            return Vec::new();
        }
        let mut out = if s.no_new_points_in_dynamic_boxes {
            protected_in_dynamic_box(kps, dynamic, states)
        } else {
            vec![false; kps.len()]
        };
        if guard {
            // Only outliers that no dynamic box explains: those in a box are the box's business.
            let unexplained: Vec<TrackedPoint> = tracked
                .iter()
                .filter(|t| {
                    let [x, y] = t.cur;
                    t.outlier
                        && !states
                            .iter()
                            .any(|s| s.is_dynamic() && s.bbox.contains_strict(x, y))
                })
                .copied()
                .collect();
            let near = stillpoint_dynamic::near_outliers(
                kps,
                &unexplained,
                s.outlier_guard_radius_px,
                s.outlier_guard_min,
            );
            for ((o, n), d) in out.iter_mut().zip(near).zip(dynamic) {
                *o |= n && !d;
            }
        }
        out
    }
}
