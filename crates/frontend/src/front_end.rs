//! [`DynamicFrontEnd`]: the detector, the motion check, the boxes' judgement and culling, and
//! objects followed over frames, behind the [`FrontEnd`] trait.

mod judge;
mod measure;
mod new_points;

use stillpoint_detect::{DetectError, Detector, NoDetector};
use stillpoint_dynamic::{
    BoxState, ObjectDecision, ObjectTracker, RememberedBox, WorldSource, depth::ObjectDepth,
};
use stillpoint_features::LkPyramid;
use stillpoint_geometry::{PinholeCamera, Se3};
use stillpoint_image::{DepthMetres, Gray8};

use crate::background::BackgroundDetector;
use crate::regions::ObjectRegion;
use crate::{
    EraseRecent, FrameInput, FrontEnd, FrontEndSettings, Judgement, PreviousPose, Regions,
    SceneObjects,
};
use measure::Measurement;

/// The dynamic front-end: detector + motion consistency + box judgement + culling, with the box
/// memory carried from frame to frame. Implements [`FrontEnd`].
pub struct DynamicFrontEnd {
    detector: Box<dyn Detector>,
    /// Set by [`DynamicFrontEnd::detect_in_background`]: the detector runs there instead.
    background: Option<BackgroundDetector>,
    settings: FrontEndSettings,
    prev_gray: Option<Gray8>,
    /// The previous frame's LK pyramid: each frame's pyramid is built once and serves the
    /// motion check and the per-keypoint evidence of two frames.
    prev_pyramid: Option<LkPyramid>,
    /// Boxes judged dynamic in the previous frame, or carried into it (`dynamic::memory`).
    memory: Vec<RememberedBox>,
    /// The previous frame's depth, for the static-world and seated-part 3D motion tests.
    prev_depth: Option<DepthMetres>,
    /// Objects followed across frames, with hysteresis on their state.
    objects: ObjectTracker,
    /// The last two poses tracking gave (frame index, world-to-camera), newest last: the map's
    /// constant-velocity prior for the static-world motion test.
    poses: Vec<(usize, Se3)>,
    /// What the last frame's static-world test did, for the logs and benches.
    last_world: Option<WorldSource>,
    /// ... and the camera motion it found (previous to current camera).
    last_world_motion: Option<Se3>,
    /// The frame last judged and the boxes the memory carried into it (the detector missed
    /// them there), for the overlays and recordings that tell them apart.
    last_carried: (usize, Vec<stillpoint_geometry::BBox>),
    /// The depth band the culling found for each object judged moving in the last frame (by
    /// object id): the masks of its pixels reuse it. Estimated again from the box alone, a thin
    /// walker's band fell on the wall behind him (most of his box's centre).
    object_depths: Vec<(u32, ObjectDepth)>,
    /// What [`FrontEnd::measure`] found on a frame (its index), for [`FrontEnd::judge`].
    pending: Option<(usize, Measurement)>,
    /// A frame without depth: where its movers' pixels are expected on the next frame (ORB's
    /// budget mask is drawn around them: `FrontEndSettings::orb_exclusion_radius_px_without_depth`).
    /// `None`: a frame with depth, or the whole boxes.
    mover_points: Option<Vec<[f32; 2]>>,
}

impl DynamicFrontEnd {
    /// A front-end over `detector` (any [`Detector`]: YOLOX, ground truth, none).
    pub fn new(detector: Box<dyn Detector>, settings: FrontEndSettings) -> Self {
        Self {
            detector,
            background: None,
            settings,
            prev_gray: None,
            prev_pyramid: None,
            memory: Vec::new(),
            prev_depth: None,
            objects: ObjectTracker::default(),
            poses: Vec::new(),
            last_world: None,
            last_world_motion: None,
            last_carried: (usize::MAX, Vec::new()),
            object_depths: Vec::new(),
            pending: None,
            mover_points: None,
        }
    }

    /// Run the detector on its own thread from now on: every frame gets the newest boxes it
    /// has finished, carried to the frame by the corners' flow (see `BackgroundDetector`), so
    /// tracking never waits for it. Results then depend on timing (not reproducible run to
    /// run); `run --realtime` uses it.
    pub fn detect_in_background(mut self) -> Result<Self, DetectError> {
        let detector = std::mem::replace(&mut self.detector, Box::new(NoDetector));
        self.background = Some(BackgroundDetector::spawn(detector, &self.settings)?);
        Ok(self)
    }

    /// The settings in use.
    pub fn settings(&self) -> &FrontEndSettings {
        &self.settings
    }

    /// How the last frame's camera motion was judged against the static world (`None`: not
    /// judged; the paper's two-frame check decided).
    pub fn last_world_source(&self) -> Option<WorldSource> {
        self.last_world
    }

    /// What the judgement of frame `index` leaves for the rest of the system: what ORB skips on
    /// the next frame, the movers whose recent map points leave, the objects in view.
    fn outputs(&self, index: usize, out: &mut Judgement) {
        let depth = &self.settings.dynamic.depth;
        let moving = self.moving_boxes();
        if self.settings.orb_exclusion {
            let mut skip = Regions::new(moving.clone(), depth, false)
                .with_min_yield(self.settings.orb_exclusion_min_yield);
            if let Some(points) = &self.mover_points {
                let radius = self.settings.orb_exclusion_radius_px_without_depth;
                skip = skip.with_discs(points.clone(), radius);
            }
            out.skip_next = skip;
        }
        let erase = self.settings.erase_recent_mover_points_frames;
        if erase > 0 && !moving.is_empty() {
            out.erase_recent = Some(EraseRecent {
                since: index.saturating_sub(erase),
                movers: Regions::new(moving, depth, false),
            });
        }
        let movable = &self.settings.dynamic.objects.movable_classes;
        let tracked: Vec<_> = self
            .objects
            .objects()
            .iter()
            .filter(|o| o.last_seen == index)
            .cloned()
            .collect();
        let movable = tracked
            .iter()
            .filter(|o| o.moving || movable.contains(&o.class_id))
            .map(|o| (self.grown(&o.bbox), self.depth_of(o.id)))
            .collect();
        out.objects = SceneObjects {
            tracked,
            carried: if self.last_carried.0 == index {
                self.last_carried.1.clone()
            } else {
                Vec::new()
            },
            movable: Regions::new(movable, depth, true),
        };
    }

    /// The boxes of the objects judged moving in the last judged frame, grown by
    /// [`FrontEndSettings::orb_exclusion_margin`] of their size on each side, with the depth
    /// band the culling found for each.
    fn moving_boxes(&self) -> Vec<ObjectRegion> {
        let last = self.objects.objects().iter().map(|o| o.last_seen).max();
        self.objects
            .objects()
            .iter()
            .filter(|o| o.moving && Some(o.last_seen) == last)
            .map(|o| (self.grown(&o.bbox), self.depth_of(o.id)))
            .collect()
    }

    /// Where the movers' pixels are expected on the next frame, for a budget mask drawn as
    /// discs: each moving corner of a dynamic box carried on by its flow, and each keypoint
    /// culled in one. `None` for `whole_boxes` (a frame with depth, or one that did not follow
    /// the evidence's rules without depth) or with the discs' radius 0.
    fn expected_mover_points(
        &self,
        whole_boxes: bool,
        kps: &[[f32; 2]],
        culled: &[bool],
        states: &[BoxState],
        tracked: &[stillpoint_dynamic::TrackedPoint],
    ) -> Option<Vec<[f32; 2]>> {
        if whole_boxes || self.settings.orb_exclusion_radius_px_without_depth <= 0.0 {
            return None;
        }
        let in_mover = |[x, y]: [f32; 2]| {
            states
                .iter()
                .any(|s| s.is_dynamic() && s.bbox.contains_strict(x, y))
        };
        let moving = tracked
            .iter()
            .filter(|t| t.outlier && in_mover(t.cur))
            .map(|t| [2.0 * t.cur[0] - t.prev[0], 2.0 * t.cur[1] - t.prev[1]]);
        let culled = kps
            .iter()
            .zip(culled)
            .filter(|&(&k, &c)| c && in_mover(k))
            .map(|(&k, _)| k);
        Some(moving.chain(culled).collect())
    }

    /// The depth band the culling found for object `id` in the last judged frame.
    fn depth_of(&self, id: u32) -> Option<ObjectDepth> {
        self.object_depths
            .iter()
            .find(|(o, _)| *o == id)
            .map(|&(_, depth)| depth)
    }

    /// Remember the depth band of each object of the judged boxes `states` (`decisions` in
    /// the same order).
    fn remember_depths(&mut self, states: &[BoxState], decisions: &[ObjectDecision]) {
        self.object_depths = states
            .iter()
            .zip(decisions)
            .filter_map(|(s, d)| s.depth.map(|depth| (d.id, depth)))
            .collect();
    }

    /// A box grown by [`FrontEndSettings::orb_exclusion_margin`] of its size on each side (a
    /// person's box misses limbs).
    fn grown(&self, b: &stillpoint_geometry::BBox) -> [f32; 4] {
        let m = self.settings.orb_exclusion_margin;
        let (dx, dy) = (m * b.width(), m * b.height());
        [b.x1 - dx, b.y1 - dy, b.x2 + dx, b.y2 + dy]
    }

    /// The map's prediction of the camera motion into frame `index` (previous- to
    /// current-camera coordinates): the motion between the last two frames tracking gave,
    /// scaled to this frame's gap when frames were dropped in between (a live camera, `run
    /// --realtime`); none over gaps of more than 3 frames.
    fn predicted_motion(&self, index: usize) -> Option<Se3> {
        const MAX_GAP: usize = 3;
        match self.poses.as_slice() {
            [(i0, cw0), (i1, cw1)]
                if i0 < i1 && *i1 < index && i1 - i0 <= MAX_GAP && index - i1 <= MAX_GAP =>
            {
                let mut v = cw1 * cw0.inverse();
                v.rotation.renormalize();
                Some(stillpoint_geometry::motion_over_gap(
                    &v,
                    (i1 - i0) as f64,
                    (index - i1) as f64,
                ))
            }
            _ => None,
        }
    }

    /// A frame's first half: the last frame's pose kept, then the measurement.
    fn pose_and_measure(&mut self, frame: &FrameInput) -> Measurement {
        if let Some(previous) = frame.previous {
            self.observe_pose(previous);
        }
        self.measure_frame(frame)
    }

    /// Keep the pose tracking gave a frame, for [`Self::predicted_motion`].
    fn observe_pose(&mut self, previous: PreviousPose) {
        match previous.pose_wc {
            Some(wc) => {
                self.poses.push((previous.index, wc.inverse()));
                if self.poses.len() > 2 {
                    self.poses.remove(0);
                }
            }
            None => self.poses.clear(),
        }
    }
}

impl FrontEnd for DynamicFrontEnd {
    /// Give the checks that project through the camera (motion against the static world,
    /// seated people's parts) the camera's intrinsics where the settings left them unset.
    fn start(&mut self, camera: PinholeCamera) {
        self.settings.dynamic.world.camera.get_or_insert(camera);
        self.settings.seated_motion.camera.get_or_insert(camera);
    }

    fn measure(&mut self, frame: &FrameInput) {
        let measured = self.pose_and_measure(frame);
        self.pending = Some((frame.index, measured));
    }

    fn judge(&mut self, frame: &FrameInput, keypoints: &[[f32; 2]]) -> Judgement {
        let measured = match self.pending.take() {
            Some((index, measured)) if index == frame.index => measured,
            // Judged without `measure`: the first half now.
            _ => self.pose_and_measure(frame),
        };
        let mut out = self.judge_measured(frame, measured, keypoints);
        self.outputs(frame.index, &mut out);
        let below = self.settings.offer_culled_to_map_below;
        if frame.depth.is_none() && below > 0.0 {
            let kept = out.dynamic.iter().filter(|d| !**d).count();
            out.offer_culled_to_map =
                kept < out.dynamic.len() && (kept as f32) < below * out.dynamic.len() as f32;
        }
        out
    }

    /// On a schedule of frames (a recording), the background detector's prefetch.
    fn detection_prefetch(&self) -> Option<crate::DetectionPrefetch> {
        self.background.as_ref()?.prefetch()
    }
}
