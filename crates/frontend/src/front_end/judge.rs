//! A frame's second half: the boxes judged with the measured evidence, objects followed over
//! frames, and the keypoints culled.

use std::time::Instant;

use stillpoint_dynamic::{BoxPart, BoxState, Evidence, Verdict, WorldCheck};

use super::DynamicFrontEnd;
use super::measure::{Measured, Measurement, Motion, detect};
use crate::seated::{cut_vertically, seated_motion};
use crate::{FrameInput, Judgement, PERSON_CLASS};

impl DynamicFrontEnd {
    /// The second half of [`crate::FrontEnd::judge`]: the boxes judged with
    /// [`Self::measure`]'s evidence, and the keypoints `kps` (level-0 pixels) of the same frame
    /// culled.
    pub(super) fn judge_measured(
        &mut self,
        frame: &FrameInput,
        measured: Measurement,
        kps: &[[f32; 2]],
    ) -> Judgement {
        let mut out = Judgement {
            dynamic: vec![false; kps.len()],
            ..Default::default()
        };
        let Motion {
            prev_depth,
            prev_pyramid,
            pyramid,
            check,
            dets,
            world,
            semantic_ms,
            geometry_ms,
        } = match measured.0 {
            Measured::First => return self.judge_first(frame, kps, out),
            Measured::Next(m) => *m,
        };
        let t0 = Instant::now();
        out.semantic_ms = semantic_ms;
        out.geometry_ms = geometry_ms;
        let settings = &self.settings.dynamic;
        let judge = settings.judge.on_frame(frame.depth.is_some());
        let mut states = stillpoint_dynamic::judge_boxes(&dets, &check.points, &judge);
        // Box memory (ours): dynamic boxes of the previous frame that the detector missed now.
        let carried =
            stillpoint_dynamic::carry_forward(&self.memory, &dets, &check.points, &settings.memory);
        if !carried.is_empty() {
            tracing::debug!(
                "frame {}: carried {:?}; detected {:?}",
                frame.index,
                carried
                    .iter()
                    .map(|c| (c.class_id, c.age, c.bbox.x1 as i32, c.bbox.x2 as i32))
                    .collect::<Vec<_>>(),
                dets.iter()
                    .map(|d| (d.class_id, d.bbox.x1 as i32, d.bbox.x2 as i32))
                    .collect::<Vec<_>>()
            );
        }
        self.last_carried = (frame.index, carried.iter().map(|c| c.bbox).collect());
        states.extend(stillpoint_dynamic::carried_states(
            &carried,
            &check.points,
            dets.len(),
        ));
        // Objects over time (ours): each box's verdict is its object's state, with hysteresis.
        // On a depth frame where the static world's motion could not be had, a box judged
        // moving heard only the two-frame check: no evidence either way (in a plain room that
        // check alone can call a painting moving and have it culled for many frames).
        // Measurements: docs/measurements.md.
        let world = if world {
            WorldCheck::Judged
        } else if settings.world.enabled && settings.world.camera.is_some() && frame.depth.is_some()
        {
            WorldCheck::Missing
        } else {
            WorldCheck::NotUsed
        };
        let evidence: Vec<Evidence> = states
            .iter()
            .map(|s| stillpoint_dynamic::evidence_of(s, world, settings.objects.still_min_tracks))
            .collect();
        let decisions = self
            .objects
            .update(frame.index, &mut states, &evidence, &settings.objects);
        self.memory = stillpoint_dynamic::remember(&states, dets.len(), &carried);
        // Each moving box starts from its object's depth band in the last frame (the culling's
        // prior).
        for (s, d) in states.iter_mut().zip(&decisions) {
            s.depth = s.is_dynamic().then(|| self.depth_of(d.id)).flatten();
        }
        out.dynamic_boxes = states
            .iter()
            .filter(|s| s.verdict == Verdict::Dynamic)
            .count();
        // Depth-aware culling when the frame has depth and `settings.depth.enabled` (ours); the
        // paper's algorithm 3 otherwise.
        // The per-keypoint motion evidence inside dynamic boxes (`dynamic::keypoint_motion`,
        // ours) when `settings.keypoint_motion.enabled`.
        let culled = stillpoint_dynamic::cull_frame_with_evidence(
            kps,
            &mut states,
            &check,
            frame.depth,
            Some((&prev_pyramid, &pyramid)),
            settings,
        );
        self.remember_depths(&states, &decisions);
        tracing::debug!(
            "frame {}: box states {:?}",
            frame.index,
            states
                .iter()
                .map(|s| (
                    s.class_id,
                    format!("{:?}", s.verdict),
                    s.bbox.x1 as i32,
                    s.bbox.x2 as i32,
                    s.depth.map(|d| (d.metres, d.near, d.far)),
                    (s.tracked, s.outliers),
                    kps.iter()
                        .zip(&culled.removed)
                        .filter(|(k, r)| **r && s.bbox.contains_strict(k[0], k[1]))
                        .count()
                ))
                .collect::<Vec<_>>()
        );
        let mut seated_kept = Vec::new();
        out.dynamic = match (&prev_depth, frame.depth) {
            (Some(prev_depth), Some(depth)) => {
                let decided = seated_motion(
                    kps,
                    &culled,
                    &states,
                    &check,
                    (prev_depth, depth),
                    (&prev_pyramid, &pyramid),
                    &self.settings,
                );
                if !self.settings.seated_kept_make_points {
                    seated_kept = culled
                        .removed
                        .iter()
                        .zip(&decided)
                        .map(|(&a, &b)| a && !b)
                        .collect();
                }
                decided
            }
            _ => culled.removed,
        };
        // Under F (a driving camera) the evidence keeps nothing: whole boxes.
        self.mover_points = self.expected_mover_points(
            frame.depth.is_some() || !culled.without_depth_rules,
            kps,
            &out.dynamic,
            &states,
            &check.points,
        );
        let track_only = seated_kept;
        out.no_new_points = self.no_new_points(
            kps,
            &out.dynamic,
            &states,
            &check.points,
            frame.depth.is_some(),
        );
        if !track_only.is_empty() {
            if out.no_new_points.is_empty() {
                out.no_new_points = vec![false; kps.len()];
            }
            for (n, t) in out.no_new_points.iter_mut().zip(&track_only) {
                *n |= t;
            }
        }
        self.add_hygiene(&mut out, kps, &states, &decisions, frame.depth);
        if let (Some(motion), Some(depth)) = (self.last_world_motion, frame.depth) {
            self.bar_moving_new_points(
                &mut out,
                kps,
                (frame.gray, depth),
                &motion,
                (&prev_pyramid, &pyramid),
                &check,
            );
        }
        self.prev_pyramid = Some(pyramid);
        // The whole judgement counts, the new-point check's tracks included.
        out.geometry_ms += stillpoint_core::ms_since(t0);
        out
    }

    /// The first frame: no previous frame, so no motion evidence; only the detector speaks.
    fn judge_first(
        &mut self,
        frame: &FrameInput,
        kps: &[[f32; 2]],
        mut out: Judgement,
    ) -> Judgement {
        // A gray camera's first frame goes to the detector as gray x3, as every later frame does
        // (left unjudged, a person in the first frame would go into the map).
        let t0 = Instant::now();
        let dets = match self.background.as_mut() {
            Some(bg) => bg.boxes_of_first(frame),
            None => detect(self.detector.as_mut(), frame),
        };
        out.semantic_ms = stillpoint_core::ms_since(t0);
        let mut states = stillpoint_dynamic::judge_boxes(&dets, &[], &self.settings.dynamic.judge);
        if self.settings.people_move_on_first_frame {
            let first_kept = self.settings.seated_kept_on_first_frame;
            let height = frame.gray.height as f32;
            // A box cut by the top or bottom edge has an unknown height, so NHBC's seated call
            // (height <= 3 x width) says nothing: such a "seated" person may be a walker.
            let top = self.settings.dynamic.judge.seated_top_fraction;
            let cut = |s: &BoxState| cut_vertically(s, height, top);
            for s in states.iter_mut().filter(|s| {
                let seated = s.part != BoxPart::Whole;
                s.class_id == PERSON_CLASS && !(first_kept && seated && !cut(s))
            }) {
                s.verdict = Verdict::Dynamic;
            }
        }
        // Nothing is known of the objects yet: movable ones start moving.
        let evidence: Vec<Evidence> = states
            .iter()
            .map(|s| stillpoint_dynamic::evidence_of(s, WorldCheck::NotUsed, usize::MAX))
            .collect();
        let decisions = self.objects.update(
            frame.index,
            &mut states,
            &evidence,
            &self.settings.dynamic.objects,
        );
        out.dynamic_boxes = states.iter().filter(|s| s.is_dynamic()).count();
        self.memory = stillpoint_dynamic::remember(&states, dets.len(), &[]);
        out.dynamic = stillpoint_dynamic::cull_frame(
            kps,
            &mut states,
            &[],
            frame.depth,
            &self.settings.dynamic,
        );
        self.remember_depths(&states, &decisions);
        // No evidence yet: the next frame's budget mask is the whole boxes.
        self.mover_points = None;
        out.no_new_points =
            self.no_new_points(kps, &out.dynamic, &states, &[], frame.depth.is_some());
        self.add_hygiene(&mut out, kps, &states, &decisions, frame.depth);
        out
    }
}
