//! A frame's first half, which needs no keypoints: the boxes, the corners' motion check and
//! the static world's motion.

use std::time::Instant;

use stillpoint_detect::{DetectInput, Detection, Detector};
use stillpoint_features::LkPyramid;
use stillpoint_image::{DepthMetres, Gray8};

use super::DynamicFrontEnd;
use crate::FrameInput;

/// What `measure_frame` found on a frame before its keypoints are known: the
/// boxes, the corners' motion check and the static world's motion.
pub(crate) struct Measurement(pub(super) Measured);

pub(super) enum Measured {
    /// The first frame: nothing to track from.
    First,
    Next(Box<Motion>),
}

pub(super) struct Motion {
    pub(super) prev_depth: Option<DepthMetres>,
    pub(super) prev_pyramid: LkPyramid,
    pub(super) pyramid: LkPyramid,
    pub(super) check: stillpoint_dynamic::MotionCheck,
    pub(super) dets: Vec<Detection>,
    pub(super) world: bool,
    pub(super) semantic_ms: f64,
    pub(super) geometry_ms: f64,
}

impl DynamicFrontEnd {
    /// The first half of [`crate::FrontEnd::judge`], which needs no keypoints (so feature
    /// extraction can run beside it): the boxes (the detector beside the motion check, or the
    /// background detector's newest), corners tracked from the previous frame, the epipolar
    /// check and the static world's motion. `judge_measured` finishes the frame.
    pub(super) fn measure_frame(&mut self, frame: &FrameInput) -> Measurement {
        let prev = self.prev_gray.replace(frame.gray.clone());
        let prev_depth =
            if self.settings.seated_motion.enabled || self.settings.dynamic.world.enabled {
                std::mem::replace(&mut self.prev_depth, frame.depth.cloned())
            } else {
                None
            };
        let prev_pyramid = self.prev_pyramid.take();
        let (Some(prev), Some(prev_pyramid)) = (prev, prev_pyramid) else {
            self.prev_pyramid = Some(LkPyramid::new(
                frame.gray,
                &self.settings.dynamic.geometry.lk,
            ));
            return Measurement(Measured::First);
        };
        if let Some(bg) = self.background.as_mut() {
            if frame.own_boxes {
                bg.detect_own(frame);
            }
            bg.send_if_due(frame);
        }
        let detector = &mut self.detector;
        let geometry = &self.settings.dynamic.geometry;
        let background = self.background.is_some();
        // The detector works on the frame while motion consistency runs (paper figure 2); in
        // the background it works on its own frame and this one takes its newest boxes.
        let ((dets, semantic_ms), (check, pyramid, geometry_ms)) = std::thread::scope(|s| {
            let det = (!background).then(|| {
                s.spawn(|| {
                    let t0 = Instant::now();
                    let dets = detect(detector.as_mut(), frame);
                    (dets, stillpoint_core::ms_since(t0))
                })
            });
            let t0 = Instant::now();
            let pyramid = LkPyramid::new(frame.gray, &geometry.lk);
            let check = stillpoint_dynamic::motion_consistency_pyramids(
                &prev,
                frame.gray,
                &prev_pyramid,
                &pyramid,
                geometry,
            );
            let geo_ms = stillpoint_core::ms_since(t0);
            let dets = det.map_or((Vec::new(), 0.0), |d| {
                d.join().unwrap_or_else(|_| {
                    tracing::warn!("frame {}: the detector thread panicked", frame.index);
                    (Vec::new(), 0.0)
                })
            });
            (dets, (check, pyramid, geo_ms))
        });
        let (dets, semantic_ms) = match self.background.as_mut() {
            Some(bg) => {
                let t0 = Instant::now();
                let dets = bg.boxes_for(frame, &check.points);
                (dets, stillpoint_core::ms_since(t0))
            }
            None => (dets, semantic_ms),
        };
        let mut check = check;
        let t0 = Instant::now();
        let world = self.judge_against_world(
            frame.index,
            &mut check,
            &dets,
            &prev,
            prev_depth.as_ref().filter(|_| frame.depth.is_some()),
        );
        Measurement(Measured::Next(Box::new(Motion {
            prev_depth,
            prev_pyramid,
            pyramid,
            check,
            dets,
            world,
            semantic_ms,
            geometry_ms: geometry_ms + stillpoint_core::ms_since(t0),
        })))
    }

    /// Judge the tracks against the static world (RGB-D with a camera): tracks in boxes of
    /// movable classes, of objects seen moving, or of remembered dynamic boxes take no part in
    /// the camera motion; then every track's outlier flag is its residual against that motion.
    /// Returns whether the check was replaced.
    fn judge_against_world(
        &mut self,
        index: usize,
        check: &mut stillpoint_dynamic::MotionCheck,
        dets: &[Detection],
        prev_gray: &Gray8,
        prev_depth: Option<&DepthMetres>,
    ) -> bool {
        self.last_world = None;
        self.last_world_motion = None;
        let p = &self.settings.dynamic.world;
        let Some(prev_depth) = prev_depth.filter(|_| p.enabled && p.camera.is_some()) else {
            return false;
        };
        let movable = &self.settings.dynamic.objects.movable_classes;
        let excluded: Vec<bool> = check
            .points
            .iter()
            .map(|t| {
                let [x, y] = t.cur;
                let [px, py] = t.prev;
                dets.iter()
                    .any(|d| movable.contains(&d.class_id) && d.bbox.contains_strict(x, y))
                    || self
                        .objects
                        .objects()
                        .iter()
                        .any(|o| o.moving && o.bbox.contains_strict(px, py))
                    || self.memory.iter().any(|m| m.bbox.contains_strict(px, py))
            })
            .collect();
        let prior = self.predicted_motion(index);
        let Some(world) = stillpoint_dynamic::world_motion(
            &check.points,
            &excluded,
            prev_gray,
            prev_depth,
            prior.as_ref(),
            p,
        ) else {
            return false;
        };
        let residuals = stillpoint_dynamic::world_residuals(
            &check.points,
            prev_gray,
            prev_depth,
            &world.prev_to_cur,
            p,
        );
        let before = check.outliers();
        if tracing::enabled!(tracing::Level::TRACE) {
            let mut r: Vec<f32> = residuals
                .iter()
                .zip(&excluded)
                .filter(|(_, e)| !**e)
                .filter_map(|(r, _)| *r)
                .collect();
            r.sort_by(f32::total_cmp);
            let q = |f: f32| {
                r.get((r.len() as f32 * f) as usize)
                    .copied()
                    .unwrap_or(-1.0)
            };
            tracing::trace!(
                frame = index,
                "static-side residuals p25 {:.2} p50 {:.2} p75 {:.2} p90 {:.2} max {:.2}",
                q(0.25),
                q(0.5),
                q(0.75),
                q(0.9),
                r.last().copied().unwrap_or(-1.0)
            );
        }
        let after =
            stillpoint_dynamic::judge_against_world(check, &residuals, &world.prev_to_cur, p);
        tracing::debug!(
            frame = index,
            source = ?world.source,
            inliers = world.inliers,
            candidates = world.candidates,
            excluded = excluded.iter().filter(|&&e| e).count(),
            tracks = check.points.len(),
            two_frame_outliers = before,
            world_outliers = after,
            "judged against the static world"
        );
        self.last_world = Some(world.source);
        self.last_world_motion = Some(world.prev_to_cur);
        true
    }
}

/// Run the detector on the frame's colour image, or on its gray image replicated into three
/// channels when the camera is gray (KITTI `image_0/1`, EuRoC); a failure is logged and counts as
/// no detection (the geometry check still runs).
pub(super) fn detect(detector: &mut dyn Detector, frame: &FrameInput) -> Vec<Detection> {
    let replicated;
    let rgb = match frame.rgb {
        Some(rgb) => rgb,
        None => {
            replicated = stillpoint_image::gray_to_rgb(frame.gray);
            &replicated
        }
    };
    detector
        .detect(&DetectInput {
            index: frame.index,
            timestamp: frame.timestamp,
            rgb,
        })
        .unwrap_or_else(|e| {
            tracing::warn!("frame {}: detector failed: {e}", frame.index);
            Vec::new()
        })
}
