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
    /// moving, so that the map is not initialised on them: points made on a walker then would
    /// stay in the map. Measurements: docs/measurements.md.
    pub people_move_on_first_frame: bool,
    /// Ours: keypoints kept inside a dynamic box only because a static box protects them (paper
    /// algorithm 3) are tracked but create no map points (those kept because depth puts them
    /// behind the object, or their own track shows no motion, do create points): a static box
    /// that overlaps a mover would otherwise let the mover into the map. Measurements:
    /// docs/measurements.md.
    pub no_new_points_in_dynamic_boxes: bool,
    /// Ours: kept keypoints with at least `outlier_guard_min` geometric outliers (motion
    /// consistency) that lie in no dynamic box within this many pixels are tracked but create no
    /// map points: a guard against moving objects the detector misses (0 turns it off). Ours:
    /// 60 px; the geometry finds outliers on only part of a walker, hence the wide radius.
    /// Measurements: docs/measurements.md.
    pub outlier_guard_radius_px: f32,
    /// Outliers needed within `outlier_guard_radius_px` (ours: 1, any outlier). Measurements:
    /// docs/measurements.md.
    pub outlier_guard_min: usize,
    /// The outlier guard on frames without depth too (ours: off for monocular, on for stereo,
    /// whose depth comes after the front-end). Monocular, the two-frame check's outliers cover
    /// the static world of a forward-moving or hand-held camera, so the guard would keep static
    /// keypoints from making points and thin the map. Measurements: docs/measurements.md.
    pub outlier_guard_without_depth: bool,
    /// Ours (RGB-D): culled keypoints whose only dynamic boxes are seated people's parts get a
    /// 3D motion test (`dynamic::seated_motion`): camera motion from the static tracks with the
    /// depth of both frames, each keypoint lifted with its depth, moved back and compared with
    /// its backward LK track; still ones are kept (tracked only unless
    /// `seated_kept_make_points`). Boxes cut by the top or bottom image edge are left to the box
    /// rule, and so are keypoints without smooth depth (silhouettes,
    /// `SeatedMotionParams::keypoint_smooth_depth`). Needs `seated_motion.camera` (set by
    /// `stillpoint run`); without it, or without depth, nothing changes. Why: NHBC culls a
    /// seated person's still torso and legs with the hand that moved. Measurements:
    /// docs/measurements.md.
    pub seated_motion: SeatedMotionParams,
    /// Ours: on the first frame (no motion evidence) seated people's parts are not taken as
    /// moving, so their still torso and legs enter the initial map; from the second frame on
    /// `seated_motion` culls what moves. Boxes cut by the top or bottom image edge still count
    /// as moving. It helps only together with `seated_motion`, which keeps the later frames off
    /// the moving limbs. Measurements: docs/measurements.md.
    pub seated_kept_on_first_frame: bool,
    /// Ours: keypoints that `seated_motion` keeps may create map points (false, the default:
    /// tracked only). Measurements: docs/measurements.md.
    pub seated_kept_make_points: bool,
    /// Ours (feature budget): ORB extraction keeps no corner inside the boxes of objects that
    /// moved in the last frame (`DynamicFrontEnd::orb_exclusion`), so its budget goes to the
    /// static scene.
    pub orb_exclusion: bool,
    /// Ours: drawn without depth (a monocular frame) that mask is the whole box, and a close
    /// walker's box over a plain view left ORB short: when the masked extraction finds fewer
    /// than this share of ORB's budget, the budget it left goes to the masked pixels (every
    /// corner found outside them stays), the culling decides there, and what it keeps there
    /// makes no map points (ours: 0.75; 0 = never). living_close seed 1 read monocular lost
    /// its map for 47 frames at 400-470 keypoints a frame instead of 1,000. Measurements:
    /// docs/monocular.md.
    pub orb_exclusion_min_yield: f32,
    /// Ours: after a frame that followed the evidence's rules without depth
    /// (`front_end.dynamic.keypoint_motion.without_depth`, off by default), that mask is not
    /// the whole box but discs of this radius (pixels) around where the movers' pixels are
    /// expected on the next frame (the moving corners of their boxes carried on by their flow,
    /// and the keypoints culled there), inside the boxes: the room seen inside a walker's box
    /// stays open to ORB and its keypoints to the evidence (16; 0: the whole boxes).
    /// Measurements: docs/monocular.md.
    pub orb_exclusion_radius_px_without_depth: f32,
    /// Ours (monocular): once the map stands, a frame without depth whose culling keeps less
    /// than this share of its keypoints offers the culled ones to the map's existing points:
    /// they may be matched to map points, only as closely as keyframes match each other
    /// (`slam.th_low`), and make none (1: whenever any is culled; 0: never). Without depth the
    /// culling takes whole boxes, and a walker close to the camera takes most of the view's
    /// static keypoints with his box; at 0.6 such a walker offers, a street's cars do not.
    /// Measurements: docs/monocular.md.
    pub offer_culled_to_map_below: f32,
    /// Ours (map hygiene): kept keypoints inside the box of a movable object not proven still
    /// for `ObjectParams::still_frames_to_map` frames create no map points, unless their depth
    /// puts them behind the object.
    pub movable_hygiene: bool,
    /// ... also in a ring of this share of the box's size around it, for keypoints within the
    /// object's depth band (ours: 0.5): YOLOX's box of a person often leaves out an arm or the
    /// knees. Measurements: docs/measurements.md.
    pub movable_hygiene_margin: f32,
    /// Growth of those boxes on each side, as a share of their size (ours: 0.05).
    pub orb_exclusion_margin: f32,
    /// Ours (map hygiene, RGB-D): when objects are judged moving, map points made in the last
    /// this many frames that lie on their surface (in the box, at the depth the sensor reads)
    /// are erased (`DynamicFrontEnd::mover_surface_mask`): a person entering the view is
    /// often missed by the detector for several frames while keyframes make points on them
    /// (0 = off).
    pub erase_recent_mover_points_frames: usize,
    /// The detector on its own thread: frames take the newest boxes it has finished, carried to
    /// them by the corners' flow, and never wait for it (`DynamicFrontEnd::detect_in_background`;
    /// `run --realtime` turns it on). Off: every frame waits for its own boxes (reproducible).
    pub detector_in_background: bool,
    /// With the detector in the background: the least time between two frames handed to it,
    /// seconds of the frames' own clock (0: each frame it is idle for). On two cores a detector
    /// that is never idle takes a whole core from tracking and mapping; the boxes in between
    /// are carried by the corners' flow. Ours: 0.1 (every third frame at 30 Hz). Measurements:
    /// docs/measurements.md.
    pub background_detect_interval_s: f64,
    /// Live, with the detector in the background and a person (any movable class) in its newest
    /// boxes: a frame waits for the detection of the frame the detector holds once that was
    /// handed over more than this long ago (seconds of the
    /// frames' clock), instead of going on with ever older carried boxes: on a starved machine
    /// (one core, 60 Hz) the system then drops frames rather than map the person; and boxes
    /// older than 15 frames are kept while a newer detection is on its way. 0: as before, never
    /// wait and drop them (docs/realtime.md).
    pub background_detect_max_wait_s: f64,
    /// Live, with the detector in the background and no movable object in its newest boxes:
    /// once the frame it holds was handed over more than this long ago (seconds of the frames'
    /// clock), each frame waits for it at most `background_detect_wait_slice_s` before going
    /// on. Someone may have come into view since the newest boxes, and a starved detector
    /// (one core at 60 Hz: tracking never idle, the detector 10 nice steps below) would leave
    /// them unboxed for seconds, long enough to be mapped; the slices give it the core in
    /// pieces, so the system drops frames (fewer frames, a little more motion between them)
    /// instead of stopping for a whole inference, which cost a fast turn its track
    /// (docs/realtime.md). 0: never wait without a mover in view.
    pub background_detect_max_wait_without_mover_s: f64,
    /// The most a frame waits for an overdue detection with no mover in view (seconds of the
    /// wall clock; about one frame at 60 Hz).
    pub background_detect_wait_slice_s: f64,
    /// Nice steps (Linux) the background detector runs below tracking: its boxes may come a
    /// little later, a frame may not. Ours: 5, above local mapping and loop closing
    /// (`slam.background_nice`, 10), so that the time a starved machine's frames leave it goes
    /// to the detector first (at 10, one core at 60 Hz, a person was boxed up to 40 frames
    /// after walking in: docs/realtime.md). Live runs; on a schedule of frames
    /// `background_detect_nice_on_schedule` instead.
    pub background_detect_nice: i32,
    /// As `background_detect_nice`, on a recording's schedule of frames
    /// (`background_detect_every_frames`), where frames wait for the detector's boxes: 0, at
    /// tracking's priority (at 10 a busy machine starved it, and the frames waiting with it:
    /// docs/realtime.md).
    pub background_detect_nice_on_schedule: i32,
    /// Ours, with the detector in the background: while a box touches the image's left or right
    /// edge (someone coming into view, or leaving it), the detector takes each frame it is idle
    /// for, not one every `background_detect_interval_s`: the part still coming in has no box
    /// until a detection sees it.
    pub background_detect_at_side_edge: bool,
    /// On an RGB-D or stereo recording, a detector that infers (YOLOX) runs in the background
    /// on the schedule of frames below, not inline: a file run 2.1x faster at the same
    /// accuracy, and the same trajectory however busy the machine is (docs/realtime.md).
    /// A live run (camera, ROS 2, `--realtime`) hands it frames by
    /// `background_detect_interval_s` instead.
    pub detect_recordings_on_schedule: bool,
    /// On a monocular recording too, but only once its map stands: until then, and while the
    /// map is young, each frame waits for its own boxes (`FrameInput::own_boxes`), since a
    /// monocular start judged on carried boxes started late or not at all (docs/monocular.md).
    /// Off: monocular recordings run the detector inline on every frame.
    pub detect_monocular_recordings_on_schedule: bool,
    /// With the detector in the background on a recording: hand it frame 0 and every this many
    /// frames after it (0: by `background_detect_interval_s` and when it is idle, as live).
    pub background_detect_every_frames: usize,
    /// ... and take its boxes exactly this many frames later (waiting for them if need be),
    /// carried to that frame by the corners' flow; at most `background_detect_every_frames`.
    pub background_detect_lag_frames: usize,
    /// ... the same on a monocular recording, in place of `background_detect_lag_frames`:
    /// without depth, boxes a frame younger held the movers better (the monocular street's
    /// five seeds 6.6 -> 5.6 cm mean Sim(3) ATE, the rooms 3.06 -> 2.95) for a run ~20 %
    /// slower; RGB-D did not gain (docs/monocular.md).
    pub background_detect_lag_frames_monocular: usize,
    /// Ours, on a recording's schedule of frames: the reader hands each scheduled frame to the
    /// detector as it decodes it, up to `read.ahead_frames` before tracking gets there, so the
    /// detector works while the frames before are tracked and mapped; the boxes are taken at
    /// the same frames, so the trajectory is the same. Off on RGB-D and stereo: with boxes
    /// taken two frames later the frames rarely wait, and on two cores the detector and
    /// tracking already fill them (no gain on living_cross, 3 MB more at the peak).
    pub background_detect_ahead: bool,
    /// ... the same on a monocular recording, in place of `background_detect_ahead`: boxes
    /// taken one frame later and a keyframe mapped every second frame leave frames waiting
    /// for them (living_cross monocular with YOLOX on tract: 25.1 -> 22.5 s, docs/realtime.md).
    pub background_detect_ahead_monocular: bool,
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
            orb_exclusion_min_yield: 0.75,
            orb_exclusion_radius_px_without_depth: 16.0,
            offer_culled_to_map_below: 0.6,
            movable_hygiene: true,
            movable_hygiene_margin: 0.5,
            orb_exclusion_margin: 0.05,
            erase_recent_mover_points_frames: 60,
            detector_in_background: false,
            background_detect_interval_s: 0.1,
            background_detect_max_wait_s: 0.5,
            background_detect_max_wait_without_mover_s: 0.2,
            background_detect_wait_slice_s: 0.016,
            background_detect_nice: 5,
            background_detect_nice_on_schedule: 0,
            background_detect_at_side_edge: true,
            detect_recordings_on_schedule: true,
            detect_monocular_recordings_on_schedule: true,
            background_detect_every_frames: 3,
            background_detect_lag_frames: 2,
            background_detect_lag_frames_monocular: 1,
            background_detect_ahead: false,
            background_detect_ahead_monocular: true,
        }
    }
}
