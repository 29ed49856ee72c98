//! stillpoint-frontend: the dynamic front-end (paper figure 2) as a
//! [`KeypointFilter`] for the SLAM core.
//!
//! Per frame, [`DynamicFrontEnd`] runs the object detector in a scoped thread while
//! `dynamic::motion_consistency` tracks corners from the previous frame, then judges the boxes
//! (`dynamic::judge_boxes`), carries boxes judged dynamic through detector misses
//! (`dynamic::memory`) and culls keypoints (`dynamic::cull_frame_with_motion`: depth-aware on
//! RGB-D frames, the paper's algorithm 3 otherwise, then per-keypoint motion evidence inside
//! dynamic boxes). Each frame's LK pyramid is built once and serves two frames. Rules of ours on
//! top, each measured (numbers in the field docs of [`FrontEndSettings`]):
//!
//! - first frame: no motion evidence yet, so people (COCO class 0) count as moving;
//! - keypoints kept inside a moving object's box (a static box protects them) are tracked but
//!   create no map points;
//! - optionally (off), mostly still parts of seated people are tracked instead of culled
//!   (synth sitting_xyz with gt boxes 0.64 -> 0.37 cm, as good as without the front-end, but
//!   worse with YOLOX on walking_halfsphere);
//! - seated people (NHBC's split parts, RGB-D): each culled keypoint gets a 3D motion test
//!   (`dynamic::seated_motion`: camera motion from the static tracks with depth, the keypoint
//!   lifted with its depth, moved back, compared with its backward LK track; > 0.5 px = moved);
//!   still ones are tracked but create no map points, and on the first frame seated parts are
//!   not taken as moving. Boxes cut by the top or bottom image edge keep today's rule (NHBC's
//!   height / width test says nothing about a walker whose legs leave the image). Synth
//!   sitting_xyz, gt boxes, ATE 0.64 / 0.45 / 0.53 -> 0.35 / 0.26 / 0.20 cm (seeds 0 / 1 / 2),
//!   walkers and static unchanged (numbers at [`FrontEndSettings::seated_motion`]);
//! - keypoints within 60 px of a geometric outlier that no dynamic box explains are tracked but
//!   create no map points (a guard against moving objects the detector misses; YOLOX on
//!   synthetic walking_xyz 11.4 -> 0.96 cm ATE);
//! - RGB-D: the tracks are judged against the static world, not a two-frame F
//!   (`dynamic::world_motion`): the prior is the motion between the last two poses tracking
//!   gave ([`KeypointFilter::observe_pose`]), refined on corner tracks outside every box that
//!   may move; every rule above then counts those outliers. Boxes are followed over frames
//!   (`dynamic::objects`): people are moving until seen still for 15 frames in a row, and the
//!   keypoints of a movable object, in its box or within half its size around it at its depth,
//!   create no map points until it has been still for 60 frames (background behind it may).
//!   Measured on the synthetic living room with a photographed person (`stillpoint bench
//!   matrix`): see docs/results.md.
//!
//! ```
//! use stillpoint_frontend::{DynamicFrontEnd, FrontEndSettings};
//! use stillpoint_image::Gray8;
//! use stillpoint_frontend::{FilterInput, KeypointFilter};
//!
//! let mut front = DynamicFrontEnd::new(
//!     Box::new(stillpoint_detect::NoDetector),
//!     FrontEndSettings::default(),
//! );
//! let gray = Gray8::new(64, 48, 0);
//! let input = FilterInput { index: 0, timestamp: 0.0, gray: &gray, rgb: None, depth: None };
//! let out = front.judge(&input, &[[10.0, 10.0], [30.0, 20.0]]);
//! assert_eq!(out.dynamic, vec![false, false]);
//! ```

#![deny(missing_docs)]

mod filter;

pub use filter::{FilterInput, FilterOutcome, KeepAll, KeypointFilter};

use std::time::Instant;

use stillpoint_detect::{
    DetectError, DetectInput, Detection, Detector, DetectorThread, NoDetector,
};
use stillpoint_dynamic::{
    BoxPart, BoxState, CulledFrame, DynamicSettings, Evidence, ObjectDecision, ObjectTracker,
    RememberedBox, SeatedMotionParams, TrackedPoint, Verdict, WorldCheck, WorldSource,
    depth::ObjectDepth,
};
use stillpoint_features::LkPyramid;
use stillpoint_geometry::{PinholeCamera, Se3, Vec3};
use stillpoint_image::{DepthMetres, Gray8};

/// COCO's person class: a-priori dynamic when there is no motion evidence yet.
pub const PERSON_CLASS: u16 = 0;

/// Every parameter of the front-end: the paper's (in [`DynamicSettings`]) and ours.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct FrontEndSettings {
    /// Motion consistency, box judgement, culling and box memory (paper section 2 with our
    /// depth-aware culling and box memory; see `stillpoint_dynamic`).
    pub dynamic: DynamicSettings,
    /// Ours: on the first frame (no previous frame, no motion evidence) people are taken as
    /// moving, so that the map is not initialised on them. Measured on synthetic walking_xyz:
    /// without it ~200 of the ~1000 initial map points lay on the walkers and stayed in the map
    /// for the whole sequence.
    pub people_move_on_first_frame: bool,
    /// Ours: keypoints kept inside a dynamic box only because a static box protects them (paper
    /// algorithm 3) are tracked but create no map points (those kept because depth puts them
    /// behind the object, or their own track shows no motion, do create points). Measured on synthetic walking_halfsphere with gt boxes and the paper's culling:
    /// map points on walkers 675 -> 48, ATE 5.3 -> 1.0 cm.
    pub no_new_points_in_dynamic_boxes: bool,
    /// Ours: kept keypoints with at least `outlier_guard_min` geometric outliers (motion
    /// consistency) that lie in no dynamic box within this many pixels are tracked but create no
    /// map points: a guard against moving objects the detector misses (0 turns it off). Measured
    /// (`stillpoint run --sequential`, 300-frame synth, ATE RMSE cm, off -> 60 px): YOLOX
    /// walking_xyz 11.4 -> 0.96, walking_halfsphere 2.16 -> 1.62, sitting_xyz 0.46 -> 0.46; gt
    /// boxes walking_xyz 0.69 -> 0.62, walking_halfsphere 0.83 -> 0.75, sitting_xyz and static
    /// unchanged. 40 px: YOLOX walking_xyz 1.45; 30 px 7.8 (before the dynamic crate's
    /// unknown-objects rule). The geometry finds outliers on only part of a walker (~0.37 of its
    /// keypoints lie within 30 px of one), hence the wide radius. On 10 real TUM fr3
    /// walking_halfsphere frames without a detector it blocks 15-41 % of a keypoint grid.
    pub outlier_guard_radius_px: f32,
    /// Outliers needed within `outlier_guard_radius_px` (1 = any; 2 measured worse: YOLOX
    /// walking_xyz 13.4 cm at 30 px against 7.8 with 1).
    pub outlier_guard_min: usize,
    /// The outlier guard on frames without depth too (ours: off for monocular, on for stereo,
    /// whose depth comes after the front-end). Monocular, the two-frame
    /// check's outliers cover the static world of a forward-moving or hand-held camera; the
    /// guard kept a static highway's keypoints from making points, and the map thinned (KITTI
    /// 01, first 51 frames: 43 keyframes without the front-end, 31 with it).
    pub outlier_guard_without_depth: bool,
    /// Ours (RGB-D): culled keypoints whose only dynamic boxes are seated people's parts get a
    /// 3D motion test (`dynamic::seated_motion`): camera motion from the static tracks with the
    /// depth of both frames, each keypoint lifted with its depth, moved back and compared with
    /// its backward LK track; still ones are kept (tracked only unless
    /// `seated_kept_make_points`). Boxes cut by the top or bottom image edge are left to the box
    /// rule. Needs `seated_motion.camera` (set by `stillpoint run`); without it, or without
    /// depth, nothing changes. Measured (`stillpoint run --sequential`, 300-frame synth, ATE
    /// RMSE cm, before -> with this and `seated_kept_on_first_frame`): sitting_xyz gt 0.64 /
    /// 0.45 / 0.53 -> 0.35 / 0.26 / 0.20 (seeds 0 / 1 / 2; `--detector none` 0.40 / 0.23 /
    /// 0.21), YOLOX 0.45 -> 0.41; walking_xyz gt 0.68 -> 0.71, YOLOX 0.96 -> 0.97;
    /// walking_halfsphere gt 0.58 -> 0.58, YOLOX 1.83 -> 1.77; walking_halfsphere seed 1 gt
    /// 0.71 -> 0.71, YOLOX 1.14 -> 1.12; static 0.42 -> 0.42. Culled keypoints on sitting_xyz gt
    /// 243 -> 185 a frame, moving keypoints kept 8.8 -> 17.4. Without the cut-box rule walkers
    /// suffered (YOLOX walking_xyz 0.96 -> 1.98 at 1.0 px, halfsphere seed 1 gt 0.71 -> 0.88);
    /// keypoints without smooth depth (silhouettes) keep the box decision
    /// (`SeatedMotionParams::keypoint_smooth_depth`). With Kinect-like depth noise
    /// (`synth --noise kinect`, sitting_xyz, seeds 0 / 1 / 2): 0.53 / 0.33 / 0.55 ->
    /// 0.73 / 0.26 / 0.28 (seed 0 worse: the first-frame rule alone gives 0.65 there, the test
    /// alone 0.52; `--detector none` 0.50); walking_xyz Kinect 0.93 -> 0.93, static Kinect
    /// 0.49 -> 0.49. Cost: geometry 6.6 -> 7.6 ms a frame on sitting_xyz. Since the camera
    /// motion is polished on the reprojection error (`dynamic::camera_motion`, session 3):
    /// Kinect sitting_xyz 0.44 / 0.24 / 0.24, gt 0.35 / 0.23 / 0.20, YOLOX walking_xyz 0.97 ->
    /// 0.92, walking_halfsphere 1.77 -> 1.60, the rest within 0.01.
    pub seated_motion: SeatedMotionParams,
    /// Ours: on the first frame (no motion evidence) seated people's parts are not taken as
    /// moving, so their still torso and legs enter the initial map; from the second frame on
    /// `seated_motion` culls what moves. Boxes cut by the top or bottom image edge still count
    /// as moving. Alone it does not help (sitting_xyz gt 0.64 -> 0.59, walking_halfsphere seed
    /// 1 YOLOX 1.14 -> 1.25 before the cut-box rule); with `seated_motion` it is what brings
    /// sitting to the no-front-end level (the sitting map is built almost only on frame 0:
    /// one keyframe), while `seated_motion` keeps the later frames off the moving limbs
    /// (first-frame rule without the test: 0.59).
    pub seated_kept_on_first_frame: bool,
    /// Ours: keypoints that `seated_motion` keeps may create map points (false: tracked only;
    /// measured before the cut-box rule, 1.0 px: same sitting ATE, YOLOX walking_xyz 2.04 with
    /// points against 1.98 without).
    pub seated_kept_make_points: bool,
    /// Ours (feature budget): ORB extraction keeps no corner inside the boxes of objects that
    /// moved in the last frame ([`DynamicFrontEnd::orb_exclusion`]), so its budget goes to the
    /// static scene.
    pub orb_exclusion: bool,
    /// Ours (map hygiene): kept keypoints inside the box of a movable object not proven still
    /// for `ObjectParams::still_frames_to_map` frames create no map points, unless their depth
    /// puts them behind the object.
    pub movable_hygiene: bool,
    /// ... also in a ring of this share of the box's size around it, for keypoints within the
    /// object's depth band (ours: 0.5; YOLOX's box of a person often leaves out an arm or the
    /// knees: on the synthetic living room with a photographed person, 87 map points of a
    /// 300-frame run were made on knees 60-130 px right of a 250 px wide box).
    pub movable_hygiene_margin: f32,
    /// Growth of those boxes on each side, as a share of their size (ours: 0.05).
    pub orb_exclusion_margin: f32,
    /// Ours (map hygiene, RGB-D): when objects are judged moving, map points made in the last
    /// this many frames that lie on their surface (in the box, at the depth the sensor reads)
    /// are erased ([`DynamicFrontEnd::mover_surface_mask`]): a person entering the view is
    /// often missed by the detector for several frames while keyframes make points on them
    /// (0 = off).
    pub erase_recent_mover_points_frames: usize,
    /// The detector on its own thread: frames take the newest boxes it has finished, carried to
    /// them by the corners' flow, and never wait for it ([`DynamicFrontEnd::detect_in_background`];
    /// `run --realtime` turns it on). Off: every frame waits for its own boxes (reproducible).
    pub detector_in_background: bool,
    /// With the detector in the background: the least time between two frames handed to it,
    /// seconds of the frames' own clock (0: each frame it is idle for). On two cores a detector
    /// that is never idle takes a whole core from tracking and mapping; the boxes in between
    /// are carried by the corners' flow. Ours: 0.1 (every third frame at 30 Hz); on walking_xyz
    /// with YOLOX-nano 480x640, 2 cores: 282 -> 290 of 300 frames processed, ATE 0.40 -> 0.38 cm.
    pub background_detect_interval_s: f64,
    /// Nice steps (Linux) the background detector runs below tracking, as local mapping does
    /// (`slam.background_nice`): its boxes may come a little later, a frame may not.
    pub background_detect_nice: i32,
    /// Ours, with the detector in the background: while a box touches the image's left or right
    /// edge (someone coming into view, or leaving it), the detector takes each frame it is idle
    /// for, not one every `background_detect_interval_s`: the part still coming in has no box
    /// until a detection sees it.
    pub background_detect_at_side_edge: bool,
}

impl Default for FrontEndSettings {
    fn default() -> Self {
        Self {
            dynamic: DynamicSettings::default(),
            people_move_on_first_frame: true,
            no_new_points_in_dynamic_boxes: true,
            outlier_guard_radius_px: 60.0,
            outlier_guard_min: 1,
            outlier_guard_without_depth: false,
            seated_motion: SeatedMotionParams::default(),
            seated_kept_on_first_frame: true,
            seated_kept_make_points: false,
            orb_exclusion: true,
            movable_hygiene: true,
            movable_hygiene_margin: 0.5,
            orb_exclusion_margin: 0.05,
            erase_recent_mover_points_frames: 60,
            detector_in_background: false,
            background_detect_interval_s: 0.1,
            background_detect_nice: 10,
            background_detect_at_side_edge: true,
        }
    }
}

/// The detector on its own thread ([`DynamicFrontEnd::detect_in_background`]): each frame hands
/// it the frame when it is idle and takes the newest boxes it has finished, carried from their
/// frame to the current one by the median flow of the corners tracked inside each box, frame by
/// frame; tracking never waits for it (but on the first frame, so that the first map is judged).
struct BackgroundDetector {
    thread: DetectorThread,
    /// A frame is with the detector.
    busy: bool,
    /// The timestamp of the last frame handed to the detector.
    last_sent: Option<f64>,
    /// [`FrontEndSettings::background_detect_interval_s`].
    interval_s: f64,
    /// [`FrontEndSettings::background_detect_at_side_edge`].
    at_side_edge_every_frame: bool,
    /// The newest finished boxes, already carried to frame `at`, and the frame they were
    /// detected on.
    latest: Option<CarriedDetections>,
    /// Corner tracks into each recent frame (frame index, tracks), to carry boxes detected on
    /// an earlier frame.
    tracks: std::collections::VecDeque<(usize, Vec<stillpoint_dynamic::TrackedPoint>)>,
}

/// Boxes detected on frame `detected`, moved to frame `at`.
struct CarriedDetections {
    detected: usize,
    at: usize,
    boxes: Vec<Detection>,
}

/// Whether a box reaches the left or right edge of an image `width` pixels wide (within
/// [`stillpoint_dynamic::AT_BORDER_PX`], as boxes carried in view keep such edges): someone
/// coming into view, or leaving it.
fn at_side_edge(boxes: &[Detection], width: f32) -> bool {
    use stillpoint_dynamic::AT_BORDER_PX;
    boxes
        .iter()
        .any(|d| d.bbox.x1 <= AT_BORDER_PX || d.bbox.x2 >= width - AT_BORDER_PX)
}

/// Frames after which boxes carried from an older detection are dropped.
const MAX_DETECTION_AGE: usize = 15;

impl BackgroundDetector {
    /// Boxes for frame `index` (whose corner tracks are `tracks`): collect what the thread has
    /// finished, carry the newest to this frame, and hand the thread this frame when it is idle.
    fn boxes_for(
        &mut self,
        frame: &FilterInput,
        tracks: &[stillpoint_dynamic::TrackedPoint],
    ) -> Vec<Detection> {
        self.tracks.push_back((frame.index, tracks.to_vec()));
        while self.tracks.len() > MAX_DETECTION_AGE + 1 {
            self.tracks.pop_front();
        }
        while let Some((detected, result)) = self.thread.try_recv() {
            self.busy = false;
            let boxes = result.unwrap_or_else(|e| {
                tracing::warn!("frame {detected}: detector failed: {e}");
                Vec::new()
            });
            self.latest = Some(CarriedDetections {
                detected,
                at: detected,
                boxes,
            });
        }
        if let Some(l) = self.latest.as_mut() {
            let from = l.at;
            let (w, h) = (frame.gray.width as f32, frame.gray.height as f32);
            for (index, pts) in self.tracks.iter().filter(|(i, _)| *i > from) {
                for d in &mut l.boxes {
                    d.bbox = stillpoint_dynamic::moved_by_flow_in_view(&d.bbox, pts, w, h);
                }
                l.at = *index;
            }
        }
        let entering = self
            .latest
            .as_ref()
            .is_some_and(|l| at_side_edge(&l.boxes, frame.gray.width as f32));
        let due = (entering && self.at_side_edge_every_frame)
            || self
                .last_sent
                .is_none_or(|t| frame.timestamp - t >= self.interval_s);
        if !self.busy && due {
            self.send(frame);
        }
        match &self.latest {
            Some(l) if frame.index.saturating_sub(l.detected) <= MAX_DETECTION_AGE => {
                l.boxes.clone()
            }
            _ => Vec::new(),
        }
    }

    fn send(&mut self, frame: &FilterInput) {
        let rgb = match frame.rgb {
            Some(rgb) => rgb.clone(),
            None => stillpoint_image::gray_to_rgb(frame.gray),
        };
        match self.thread.send(frame.index, frame.timestamp, rgb) {
            Ok(()) => {
                self.busy = true;
                self.last_sent = Some(frame.timestamp);
            }
            Err(e) => tracing::warn!("frame {}: {e}", frame.index),
        }
    }

    /// The first frame: wait for its boxes.
    fn boxes_of_first(&mut self, frame: &FilterInput) -> Vec<Detection> {
        self.send(frame);
        let boxes = match self.thread.recv() {
            Ok((_, Ok(b))) => b,
            Ok((_, Err(e))) | Err(e) => {
                tracing::warn!("frame {}: detector failed: {e}", frame.index);
                Vec::new()
            }
        };
        self.busy = false;
        self.latest = Some(CarriedDetections {
            detected: frame.index,
            at: frame.index,
            boxes: boxes.clone(),
        });
        boxes
    }
}

/// The dynamic front-end: detector + motion consistency + box judgement + culling, with the box
/// memory carried from frame to frame. Implements [`KeypointFilter`].
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
}

impl DynamicFrontEnd {
    /// Run the detector on its own thread from now on: every frame gets the newest boxes it
    /// has finished, carried to the frame by the corners' flow (see `BackgroundDetector`), so
    /// tracking never waits for it. Results then depend on timing (not reproducible run to
    /// run); `run --realtime` uses it.
    pub fn detect_in_background(mut self) -> Result<Self, DetectError> {
        let detector = std::mem::replace(&mut self.detector, Box::new(NoDetector));
        let nice = self.settings.background_detect_nice;
        let thread = DetectorThread::spawn(move || {
            stillpoint_detect::lower_this_thread_priority(nice);
            Ok(detector)
        })?;
        self.background = Some(BackgroundDetector {
            thread,
            busy: false,
            last_sent: None,
            interval_s: self.settings.background_detect_interval_s,
            at_side_edge_every_frame: self.settings.background_detect_at_side_edge,
            latest: None,
            tracks: std::collections::VecDeque::new(),
        });
        Ok(self)
    }

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
        }
    }

    /// Give the checks that project through the camera (motion against the static world, seated
    /// people's parts) the camera's intrinsics where the settings left them unset; the pipeline
    /// calls this with its own camera.
    pub fn use_camera(&mut self, camera: PinholeCamera) {
        self.settings.dynamic.world.camera.get_or_insert(camera);
        self.settings.seated_motion.camera.get_or_insert(camera);
    }

    /// Where the next frame's ORB extraction should spend no budget (`[x1, y1, x2, y2]`): the
    /// boxes of objects moving in the last frame, grown by
    /// [`FrontEndSettings::orb_exclusion_margin`] of their size on each side; empty when
    /// [`FrontEndSettings::orb_exclusion`] is off.
    pub fn orb_exclusion(&self) -> Vec<[f32; 4]> {
        if !self.settings.orb_exclusion {
            return Vec::new();
        }
        self.moving_boxes().into_iter().map(|(r, _)| r).collect()
    }

    /// The objects seen in frame `index` (box, class, moving or not): what an overlay of the
    /// frame draws. Empty for a frame the front-end did not judge.
    pub fn objects_in_view(&self, index: usize) -> Vec<&stillpoint_dynamic::TrackedObject> {
        self.objects
            .objects()
            .iter()
            .filter(|o| o.last_seen == index)
            .collect()
    }

    /// The boxes the box memory carried into frame `index` because the detector missed their
    /// objects there (judged moving, as the frame before judged them). Empty for any frame but
    /// the last judged one.
    pub fn carried_in_view(&self, index: usize) -> &[stillpoint_geometry::BBox] {
        if self.last_carried.0 == index {
            &self.last_carried.1
        } else {
            &[]
        }
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

    /// [`DynamicFrontEnd::orb_exclusion`] narrowed to the movers' own pixels when the next
    /// frame's depth is known: inside each box, only pixels within the object's depth band (the
    /// median depth of the box's centre, +- `dynamic.depth` band), so the background seen
    /// around a close person keeps its keypoints. `None` when exclusion is off or nothing
    /// moved; without depth, the whole boxes.
    pub fn orb_exclusion_mask(
        &self,
        depth: Option<&DepthMetres>,
        width: usize,
        height: usize,
    ) -> Option<Gray8> {
        if !self.settings.orb_exclusion {
            return None;
        }
        let rects = self.moving_boxes();
        (!rects.is_empty()).then(|| {
            mover_mask(
                &rects,
                depth,
                &self.settings.dynamic.depth,
                width,
                height,
                false,
            )
        })
    }

    /// After [`KeypointFilter::judge`]: the pixels of the objects judged moving in that frame
    /// (their boxes within each object's depth band), for erasing the map points made on them
    /// ([`FrontEndSettings::erase_recent_mover_points_frames`]). `None` when that is off or
    /// nothing moved.
    pub fn mover_surface_mask(&self, depth: &DepthMetres) -> Option<Gray8> {
        if self.settings.erase_recent_mover_points_frames == 0 {
            return None;
        }
        self.surface_mask(&self.moving_boxes(), depth, false)
    }

    /// The pixels of every object in frame `index` that is moving or of a movable class
    /// (people, animals, vehicles: still or not): in each box, everything up to the far end of
    /// its object's depth band (a close person's head and hands lie outside their torso's
    /// band), the background behind kept. What a static map of the scene should hold none of.
    /// `None` when there is no such object.
    pub fn movable_surface_mask(&self, index: usize, depth: &DepthMetres) -> Option<Gray8> {
        let movable = &self.settings.dynamic.objects.movable_classes;
        let rects: Vec<ObjectRegion> = self
            .objects_in_view(index)
            .into_iter()
            .filter(|o| o.moving || movable.contains(&o.class_id))
            .map(|o| (self.grown(&o.bbox), self.depth_of(o.id)))
            .collect();
        self.surface_mask(&rects, depth, true)
    }

    /// [`mover_mask`] of `rects` on a depth image; `None` when there is no rectangle.
    fn surface_mask(
        &self,
        rects: &[ObjectRegion],
        depth: &DepthMetres,
        up_to_far: bool,
    ) -> Option<Gray8> {
        (!rects.is_empty()).then(|| {
            let d = &self.settings.dynamic.depth;
            mover_mask(rects, Some(depth), d, depth.width, depth.height, up_to_far)
        })
    }

    /// A box grown by [`FrontEndSettings::orb_exclusion_margin`] of its size on each side (a
    /// person's box misses limbs).
    fn grown(&self, b: &stillpoint_geometry::BBox) -> [f32; 4] {
        let m = self.settings.orb_exclusion_margin;
        let (dx, dy) = (m * b.width(), m * b.height());
        [b.x1 - dx, b.y1 - dy, b.x2 + dx, b.y2 + dy]
    }

    /// How the last frame's camera motion was judged against the static world (`None`: not
    /// judged; the paper's two-frame check decided).
    pub fn last_world_source(&self) -> Option<WorldSource> {
        self.last_world
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

    /// Map hygiene against movers no box covers: each kept keypoint that may make a map point
    /// is tracked back into the previous frame and judged against the static world's camera
    /// motion; one that moved, or that cannot be found there
    /// (`WorldMotionParams::new_point_lost_track_moved`), makes none
    /// (`WorldMotionParams::check_new_points`).
    #[allow(clippy::too_many_arguments)]
    fn bar_moving_new_points(
        &self,
        out: &mut FilterOutcome,
        kps: &[[f32; 2]],
        gray: &Gray8,
        depth: &DepthMetres,
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

    /// The settings in use.
    pub fn settings(&self) -> &FrontEndSettings {
        &self.settings
    }

    /// The first frame: no previous frame, so no motion evidence; only the detector speaks.
    fn judge_first(
        &mut self,
        frame: &FilterInput,
        kps: &[[f32; 2]],
        mut out: FilterOutcome,
    ) -> FilterOutcome {
        // A gray camera's first frame goes to the detector as gray x3, as every later frame does
        // (it used to be left unjudged, so a person in the first map was mapped).
        let t0 = Instant::now();
        let dets = match self.background.as_mut() {
            Some(bg) => bg.boxes_of_first(frame),
            None => detect(self.detector.as_mut(), frame),
        };
        out.semantic_ms = t0.elapsed().as_secs_f64() * 1e3;
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
        out.no_new_points =
            self.no_new_points(kps, &out.dynamic, &states, &[], frame.depth.is_some());
        self.add_hygiene(&mut out, kps, &states, &decisions, frame.depth);
        out
    }

    /// Merge [`DynamicFrontEnd::movable_hygiene`] into the outcome's `no_new_points`.
    fn add_hygiene(
        &self,
        out: &mut FilterOutcome,
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
    fn no_new_points(
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

/// A mover's box (`[x1, y1, x2, y2]`) and the depth band the culling found for it, if any.
type ObjectRegion = ([f32; 4], Option<ObjectDepth>);

/// The pixels of movers (255) inside their boxes: with depth, those within each object's depth
/// band (the culling's, else estimated from the box alone by `dynamic::depth::object_depth`)
/// or, `up_to_far`, anything in front of the band's far end too; without depth, or with too
/// few depth samples, the whole box.
fn mover_mask(
    rects: &[ObjectRegion],
    depth: Option<&DepthMetres>,
    d: &stillpoint_dynamic::DepthParams,
    width: usize,
    height: usize,
    up_to_far: bool,
) -> Gray8 {
    let mut mask = Gray8::new(width, height, 0);
    for (r, known) in rects {
        let clamp = |v: f32, hi: usize| (v.max(0.0) as usize).min(hi);
        let (x1, y1) = (clamp(r[0], width), clamp(r[1], height));
        let (x2, y2) = (clamp(r[2], width), clamp(r[3], height));
        let bbox = stillpoint_geometry::BBox::new(r[0], r[1], r[2], r[3]);
        let object = depth.and_then(|z| {
            known.or_else(|| {
                stillpoint_dynamic::depth::object_depth(&bbox, &[], z, None, f32::INFINITY, d)
            })
        });
        for y in y1..y2 {
            for x in x1..x2 {
                let on_mover = match (object, depth) {
                    (Some(o), Some(z)) => z
                        .get_checked(x as isize, y as isize)
                        .is_some_and(|v| o.holds(v) || (up_to_far && v > 0.0 && v <= o.far)),
                    _ => true,
                };
                if on_mover {
                    mask.set(x, y, 255);
                }
            }
        }
    }
    mask
}

/// Run the detector on the frame's colour image, or on its gray image replicated into three
/// channels when the camera is gray (KITTI `image_0/1`, EuRoC); a failure is logged and counts as
/// no detection (the geometry check still runs).
fn detect(detector: &mut dyn Detector, frame: &FilterInput) -> Vec<Detection> {
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

/// What [`DynamicFrontEnd::measure`] found on a frame before its keypoints are known: the
/// boxes, the corners' motion check and the static world's motion.
pub struct Measurement(Measured);

enum Measured {
    /// The first frame: nothing to track from.
    First,
    Next(Box<Motion>),
}

struct Motion {
    prev_depth: Option<DepthMetres>,
    prev_pyramid: LkPyramid,
    pyramid: LkPyramid,
    check: stillpoint_dynamic::MotionCheck,
    dets: Vec<Detection>,
    world: bool,
    semantic_ms: f64,
    geometry_ms: f64,
}

impl DynamicFrontEnd {
    /// The first half of [`KeypointFilter::judge`], which needs no keypoints (so feature
    /// extraction can run beside it): the boxes (the detector beside the motion check, or the
    /// background detector's newest), corners tracked from the previous frame, the epipolar
    /// check and the static world's motion. [`Self::judge_measured`] finishes the frame.
    pub fn measure(&mut self, frame: &FilterInput) -> Measurement {
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
                    (dets, t0.elapsed().as_secs_f64() * 1e3)
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
            let geo_ms = t0.elapsed().as_secs_f64() * 1e3;
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
                (dets, t0.elapsed().as_secs_f64() * 1e3)
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
            geometry_ms: geometry_ms + t0.elapsed().as_secs_f64() * 1e3,
        })))
    }

    /// The second half of [`KeypointFilter::judge`]: the boxes judged with
    /// [`Self::measure`]'s evidence, and the keypoints `kps` (level-0 pixels) of the same frame
    /// culled.
    pub fn judge_measured(
        &mut self,
        frame: &FilterInput,
        measured: Measurement,
        kps: &[[f32; 2]],
    ) -> FilterOutcome {
        let mut out = FilterOutcome {
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
        // made a painting "moving" on frame 1 and culled it for 76 frames).
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
                frame.gray,
                depth,
                &motion,
                (&prev_pyramid, &pyramid),
                &check,
            );
        }
        self.prev_pyramid = Some(pyramid);
        // The whole judgement counts, the new-point check's tracks included.
        out.geometry_ms += t0.elapsed().as_secs_f64() * 1e3;
        out
    }
}

impl KeypointFilter for DynamicFrontEnd {
    fn judge(&mut self, frame: &FilterInput, kps: &[[f32; 2]]) -> FilterOutcome {
        let measured = self.measure(frame);
        self.judge_measured(frame, measured, kps)
    }

    fn name(&self) -> &str {
        "dynamic"
    }

    fn observe_pose(&mut self, index: usize, pose_wc: Option<&Se3>) {
        match pose_wc {
            Some(wc) => {
                self.poses.push((index, wc.inverse()));
                if self.poses.len() > 2 {
                    self.poses.remove(0);
                }
            }
            None => self.poses.clear(),
        }
    }
}

/// The seated-part 3D motion test (`dynamic::seated_motion`) on the culled keypoints whose only
/// dynamic boxes are seated parts; the decision is unchanged without a camera motion estimate.
fn seated_motion(
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
fn on_movable_object(s: &BoxState, at: [f32; 2], depth: Option<f32>, margin: f32) -> bool {
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
fn cut_vertically(s: &BoxState, height: f32, top_fraction: f32) -> bool {
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
    use stillpoint_datasets::annotations::FrameBoxes;
    use stillpoint_detect::{GtDetector, GtDetectorParams, NoDetector};
    use stillpoint_synth::{Preset, SynthConfig, SynthFrame};

    /// Three frames of the synthetic walking_xyz scene, rendered in-process.
    fn walking_frames() -> Vec<SynthFrame> {
        let cfg = SynthConfig {
            preset: Preset::WalkingXyz,
            frames: 3,
            ..Default::default()
        };
        let g = stillpoint_synth::generate(&cfg).expect("generator");
        (0..3).map(|i| g.frame(i)).collect()
    }

    fn grid(w: usize, h: usize, step: usize) -> Vec<[f32; 2]> {
        (step..h - step)
            .step_by(step)
            .flat_map(|y| {
                (step..w - step)
                    .step_by(step)
                    .map(move |x| [x as f32, y as f32])
            })
            .collect()
    }

    fn on(mask: &Gray8, [x, y]: [f32; 2]) -> bool {
        mask.get_checked(x as isize, y as isize)
            .is_some_and(|v| v > 127)
    }

    fn run(
        front: &mut DynamicFrontEnd,
        frames: &[SynthFrame],
        kps: &[[f32; 2]],
    ) -> Vec<FilterOutcome> {
        frames
            .iter()
            .map(|f| {
                let gray = stillpoint_image::rgb_to_gray(&f.rgb);
                let input = FilterInput {
                    index: f.index,
                    timestamp: f.timestamp,
                    gray: &gray,
                    rgb: Some(&f.rgb),
                    depth: Some(&f.depth),
                };
                front.judge(&input, kps)
            })
            .collect()
    }

    /// The generator's boxes as a detector.
    fn gt_detector(frames: &[SynthFrame]) -> GtDetector {
        let boxes: Vec<FrameBoxes> = frames
            .iter()
            .map(|f| FrameBoxes {
                frame: f.index,
                timestamp: f.timestamp,
                boxes: f.boxes.clone(),
            })
            .collect();
        GtDetector::from_frames(boxes, GtDetectorParams::default()).expect("gt boxes")
    }

    /// Share of the keypoints on the person that were neither culled nor barred from the map,
    /// over frames `range` of synth living_close (a textured person walks in and fills 40-60 %
    /// of a plain room's view), at 320x240, with ground-truth boxes and the true poses fed
    /// back as the map's.
    fn mover_keypoints_let_into_the_map(settings: FrontEndSettings) -> (usize, usize) {
        let mut cam = stillpoint_synth::tum_fr3_camera();
        cam.fx /= 2.0;
        cam.fy /= 2.0;
        cam.cx = (cam.cx + 0.5) / 2.0 - 0.5;
        cam.cy = (cam.cy + 0.5) / 2.0 - 0.5;
        cam.width = 320;
        cam.height = 240;
        let cfg = SynthConfig {
            preset: Preset::LivingClose,
            frames: 150,
            camera: cam,
            ..Default::default()
        };
        let g = stillpoint_synth::generate(&cfg).expect("generator");
        let people: Vec<u16> = g
            .objects()
            .iter()
            .filter(|o| o.class_id == Some(PERSON_CLASS))
            .map(|o| o.object as u16 + 1)
            .collect();
        let frames: Vec<SynthFrame> = (100..150).map(|i| g.frame(i)).collect();
        let mut settings = settings;
        settings.dynamic.world.camera = Some(cam);
        settings.seated_motion.camera = Some(cam);
        let background = settings.detector_in_background;
        let mut front = DynamicFrontEnd::new(Box::new(gt_detector(&frames)), settings);
        if background {
            front = front.detect_in_background().expect("detector thread");
        }
        let mut orb = stillpoint_features::OrbExtractor::new(stillpoint_features::OrbParams {
            n_features: 500,
            ..Default::default()
        });
        let (mut on_person, mut let_in) = (0, 0);
        for f in &frames {
            let gray = stillpoint_image::rgb_to_gray(&f.rgb);
            let kps: Vec<[f32; 2]> = orb
                .extract(&gray)
                .keypoints
                .iter()
                .map(|k| [k.x, k.y])
                .collect();
            let input = FilterInput {
                index: f.index,
                timestamp: f.timestamp,
                gray: &gray,
                rgb: Some(&f.rgb),
                depth: Some(&f.depth),
            };
            let out = front.judge(&input, &kps);
            front.observe_pose(f.index, Some(&f.pose_wc));
            for (i, &[x, y]) in kps.iter().enumerate() {
                let id = f.object_ids.get(x as usize, y as usize);
                if people.contains(&id) {
                    on_person += 1;
                    let barred = out.no_new_points.get(i).copied().unwrap_or(false);
                    let_in += (!out.dynamic[i] && !barred) as usize;
                }
            }
        }
        (let_in, on_person)
    }

    #[test]
    fn the_orb_mask_covers_a_mover_but_not_the_background_in_its_box() {
        // A person 1.5 m away fills the middle of a 100 x 100 box; the wall 4 m behind shows
        // around them inside the box.
        let mut depth = DepthMetres::new(200, 200, 4.0);
        for y in 50..150 {
            for x in 75..125 {
                depth.set(x, y, 1.5);
            }
        }
        let params = stillpoint_dynamic::DepthParams::default();
        let rect = ([50.0, 50.0, 150.0, 150.0], None);
        let mask = mover_mask(&[rect], Some(&depth), &params, 200, 200, false);
        assert_eq!(mask.get(100, 100), 255, "the person");
        assert_eq!(mask.get(60, 100), 0, "the wall beside them, inside the box");
        assert_eq!(mask.get(10, 10), 0, "outside the box");
        // Without depth the whole box.
        let whole = mover_mask(&[rect], None, &params, 200, 200, false);
        assert_eq!((whole.get(60, 100), whole.get(10, 10)), (255, 0));
        // A thin person: the box's centre is mostly wall, which the box alone takes for the
        // mover; the band the culling found (with the person's moving tracks) is kept instead.
        let mut thin = DepthMetres::new(200, 200, 4.0);
        for y in 50..150 {
            for x in 95..105 {
                thin.set(x, y, 1.5);
            }
        }
        let blind = mover_mask(&[rect], Some(&thin), &params, 200, 200, false);
        assert_eq!((blind.get(100, 100), blind.get(60, 100)), (0, 255));
        let band = stillpoint_dynamic::depth::object_depth(
            &stillpoint_geometry::BBox::new(95.0, 50.0, 105.0, 150.0),
            &[],
            &thin,
            None,
            f32::INFINITY,
            &params,
        );
        let known = mover_mask(&[(rect.0, band)], Some(&thin), &params, 200, 200, false);
        assert_eq!((known.get(100, 100), known.get(60, 100)), (255, 0));
    }

    /// The detector on its own thread: each frame takes the newest boxes, detected on an
    /// earlier frame and carried by the corners' flow; the person still stays out of the map.
    #[test]
    fn boxes_from_a_background_detector_keep_the_mover_out() {
        let settings = FrontEndSettings {
            detector_in_background: true,
            ..Default::default()
        };
        let (let_in, total) = mover_keypoints_let_into_the_map(settings);
        assert!(total > 3000, "the person holds many keypoints ({total})");
        let share = let_in as f64 / total as f64;
        eprintln!(
            "person keypoints let into the map with the detector in the background: {share:.3}"
        );
        assert!(share < 0.02, "{let_in} of {total}");
    }

    /// In the background the detector is handed a frame at most once per
    /// `background_detect_interval_s` of the frames' own clock, however fast it is.
    #[test]
    fn the_background_detector_takes_one_frame_per_interval() {
        use std::sync::{Arc, Mutex};
        struct Recording(Arc<Mutex<Vec<f64>>>);
        impl Detector for Recording {
            fn detect(&mut self, input: &DetectInput) -> Result<Vec<Detection>, DetectError> {
                self.0.lock().unwrap().push(input.timestamp);
                Ok(Vec::new())
            }
            fn name(&self) -> &str {
                "recording"
            }
        }
        let seen = Arc::new(Mutex::new(Vec::new()));
        let settings = FrontEndSettings {
            detector_in_background: true,
            background_detect_interval_s: 0.1,
            ..Default::default()
        };
        let mut front = DynamicFrontEnd::new(Box::new(Recording(Arc::clone(&seen))), settings)
            .detect_in_background()
            .unwrap();
        let mut gray = Gray8::new(96, 64, 0);
        for y in 0..64 {
            for x in 0..96 {
                gray.set(x, y, if (x / 8 + y / 8) % 2 == 0 { 40 } else { 200 });
            }
        }
        for i in 0..40 {
            let input = FilterInput {
                index: i,
                timestamp: i as f64 / 30.0,
                gray: &gray,
                rgb: None,
                depth: None,
            };
            front.judge(&input, &[]);
        }
        drop(front);
        let seen = seen.lock().unwrap().clone();
        assert!(!seen.is_empty());
        assert!(
            seen.len() <= 14,
            "{} frames detected of 40: {seen:?}",
            seen.len()
        );
        for w in seen.windows(2) {
            assert!(w[1] - w[0] >= 0.1 - 1e-9, "{seen:?}");
        }
    }

    #[test]
    fn boxes_at_the_left_or_right_edge_are_told_apart() {
        let boxed = |x1: f32, x2: f32| {
            vec![Detection {
                bbox: stillpoint_geometry::BBox::new(x1, 100.0, x2, 300.0),
                class_id: PERSON_CLASS,
                score: 0.9,
            }]
        };
        assert!(at_side_edge(&boxed(0.0, 120.0), 640.0));
        assert!(at_side_edge(&boxed(3.5, 120.0), 640.0));
        assert!(at_side_edge(&boxed(500.0, 637.0), 640.0));
        assert!(!at_side_edge(&boxed(5.0, 634.0), 640.0));
        assert!(!at_side_edge(&[], 640.0));
    }

    #[test]
    fn a_dominant_textured_mover_never_reaches_the_map() {
        let (ours, total) = mover_keypoints_let_into_the_map(FrontEndSettings::default());
        let mut paper = FrontEndSettings::default();
        paper.dynamic.world.enabled = false;
        paper.dynamic.objects.enabled = false;
        let (before, total_before) = mover_keypoints_let_into_the_map(paper);
        assert_eq!(total, total_before);
        assert!(total > 3000, "the person holds many keypoints ({total})");
        let share = |n: usize| n as f64 / total as f64;
        eprintln!(
            "person keypoints let into the map: {:.3} with the static world and objects, {:.3} without",
            share(ours),
            share(before)
        );
        assert!(share(ours) < 0.01, "{ours} of {total}");
        assert!(
            share(before) > 5.0 * share(ours).max(0.002),
            "{before} of {total}"
        );
    }

    #[test]
    fn gray_only_frames_still_reach_the_detector() {
        // KITTI image_0/1 and EuRoC are gray: the detector gets the gray image in three channels.
        let frames = walking_frames();
        let kps = grid(frames[0].rgb.width, frames[0].rgb.height, 8);
        let mut front =
            DynamicFrontEnd::new(Box::new(gt_detector(&frames)), FrontEndSettings::default());
        for f in &frames[..2] {
            let gray = stillpoint_image::rgb_to_gray(&f.rgb);
            let input = FilterInput {
                index: f.index,
                timestamp: f.timestamp,
                gray: &gray,
                rgb: None,
                depth: None,
            };
            // The first frame too: people start moving.
            let out = front.judge(&input, &kps);
            assert!(
                out.dynamic_boxes > 0 && out.dynamic.contains(&true),
                "frame {}",
                f.index
            );
        }
    }

    #[test]
    fn culls_walkers_with_gt_boxes_and_nothing_without_a_detector() {
        let frames = walking_frames();
        let (w, h) = (frames[0].rgb.width, frames[0].rgb.height);
        let kps = grid(w, h, 8);
        let mut front =
            DynamicFrontEnd::new(Box::new(gt_detector(&frames)), FrontEndSettings::default());
        let outcomes = run(&mut front, &frames, &kps);
        for (f, out) in frames.iter().zip(&outcomes) {
            assert_eq!(out.dynamic.len(), kps.len());
            let moving: Vec<bool> = kps.iter().map(|&k| on(&f.dynamic_mask, k)).collect();
            let n_moving = moving.iter().filter(|&&m| m).count();
            let caught = moving
                .iter()
                .zip(&out.dynamic)
                .filter(|(m, d)| **m && **d)
                .count();
            let false_pos = moving
                .iter()
                .zip(&out.dynamic)
                .filter(|(m, d)| !**m && **d)
                .count();
            if f.index == 0 {
                // The first frame has no motion evidence: the people rule culls the walkers.
                assert!(out.geometry_ms == 0.0);
            }
            if n_moving > 20 {
                assert!(
                    caught * 10 >= n_moving * 8,
                    "frame {}: {caught} of {n_moving}",
                    f.index
                );
            }
            assert!(
                false_pos * 5 < kps.len(),
                "frame {}: {false_pos} static culled",
                f.index
            );
        }
        // Without boxes only the dynamic crate's unknown-objects rule culls; off, nothing goes.
        let mut settings = FrontEndSettings::default();
        settings.dynamic.cull.unknown_objects = false;
        let mut none = DynamicFrontEnd::new(Box::new(NoDetector), settings);
        for out in run(&mut none, &frames, &kps) {
            assert!(out.dynamic.iter().all(|d| !d));
            assert_eq!(out.dynamic_boxes, 0);
        }
    }

    #[test]
    fn outlier_guard_blocks_new_points_near_missed_movers() {
        let frames = walking_frames();
        let (w, h) = (frames[0].rgb.width, frames[0].rgb.height);
        let kps = grid(w, h, 8);
        let mut settings = FrontEndSettings {
            outlier_guard_radius_px: 30.0,
            ..Default::default()
        };
        // Only the guard: the dynamic crate's unknown-objects rule would cull some of them.
        settings.dynamic.cull.unknown_objects = false;
        // No detector: only the geometry sees the walkers.
        let mut front = DynamicFrontEnd::new(Box::new(NoDetector), settings);
        let outcomes = run(&mut front, &frames, &kps);
        assert!(
            outcomes[0].no_new_points.iter().all(|n| !n),
            "frame 0 has no motion evidence"
        );
        let (mut moving, mut still) = ([0usize; 2], [0usize; 2]);
        for (f, out) in frames.iter().zip(&outcomes).skip(1) {
            assert!(out.dynamic.iter().all(|d| !d), "no box, nothing culled");
            assert_eq!(out.no_new_points.len(), kps.len());
            for (k, &blocked) in kps.iter().zip(&out.no_new_points) {
                let c = if on(&f.dynamic_mask, *k) {
                    &mut moving
                } else {
                    &mut still
                };
                c[0] += 1;
                c[1] += blocked as usize;
            }
        }
        let rate = |c: [usize; 2]| c[1] as f64 / c[0].max(1) as f64;
        // Measured on these frames: ~0.37 of the walkers' keypoints, ~0.11 of the rest.
        assert!(
            rate(moving) > 2.0 * rate(still),
            "moving {:.2} vs static {:.2}",
            rate(moving),
            rate(still)
        );
    }
}

#[cfg(test)]
mod seated_tests {
    use super::*;
    use stillpoint_detect::BBox;
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
