//! The front-end's settings: the paper's (in [`DynamicSettings`]) and ours.

use stillpoint_dynamic::{DynamicSettings, SeatedMotionParams};

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
