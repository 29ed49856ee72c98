//! The one place where a front-end plugs into the pipeline (paper figure 2): [`FrontEnd`], data
//! in and data out, called twice a frame. The pipeline calls [`FrontEnd::measure`] while ORB
//! extracts the frame's features and [`FrontEnd::judge`] with the keypoints ORB found, before
//! tracking; everything the rest of the system needs from the front-end (what ORB skips on the
//! next frame, which map points leave, the objects an overlay draws) comes back in
//! [`Judgement`].

use stillpoint_dynamic::TrackedObject;
use stillpoint_geometry::{BBox, PinholeCamera, Se3};
use stillpoint_image::{DepthMetres, Gray8, Rgb8};

use crate::Regions;

/// Decides which keypoints lie on moving objects.
pub trait FrontEnd: Send {
    /// Once, before the first frame: the camera the pipeline runs with.
    fn start(&mut self, _camera: PinholeCamera) {}
    /// A frame's first call, on the pipeline's thread while ORB extracts its features (on other
    /// threads): the work that needs no keypoints.
    fn measure(&mut self, _frame: &FrameInput) {}
    /// A frame's second call, with the keypoints (level-0 pixels) ORB found on it: the
    /// judgement. Works without [`FrontEnd::measure`] too.
    fn judge(&mut self, frame: &FrameInput, keypoints: &[[f32; 2]]) -> Judgement;
    /// A handle that hands a recording's frames to the detector as soon as they are decoded,
    /// ahead of these calls (`None`: the front-end has no use for them).
    fn detection_prefetch(&self) -> Option<crate::DetectionPrefetch> {
        None
    }
}

/// One frame as the front-end gets it: its images and what tracking made of the frame before.
/// Both calls of a frame get the same input.
pub struct FrameInput<'a> {
    /// Position of the frame in its sequence.
    pub index: usize,
    /// Frame time, seconds.
    pub timestamp: f64,
    /// The gray image (the motion check's).
    pub gray: &'a Gray8,
    /// The colour image, when there is one (the detector's; gray x3 otherwise).
    pub rgb: Option<&'a Rgb8>,
    /// Depth in metres (RGB-D), for depth-aware culling.
    pub depth: Option<&'a DepthMetres>,
    /// The frame fed before this one and the pose tracking gave it; `None` on the first frame.
    pub previous: Option<PreviousPose>,
    /// The frame needs boxes detected on itself, not carried from an earlier frame: a
    /// monocular map is starting (`slam::System::wants_initial_features`). A detector working
    /// in the background on a schedule of frames detects this one and the frame waits for it.
    pub own_boxes: bool,
}

/// The pose tracking gave a frame: a front-end that judges motion against the static world
/// predicts the next frame's camera motion from these (the map's constant-velocity prior).
#[derive(Clone, Copy, Debug)]
pub struct PreviousPose {
    /// The frame's position in its sequence.
    pub index: usize,
    /// Camera-to-world; `None` when the frame was not tracked.
    pub pose_wc: Option<Se3>,
}

/// What a front-end decided for one frame, with the time its stages took.
#[derive(Clone, Debug, Default)]
pub struct Judgement {
    /// `true` = dynamic, remove the keypoint. Same length as the keypoints.
    pub dynamic: Vec<bool>,
    /// Kept keypoints that must not create map points (on an object not proven still). Same
    /// length as the keypoints, or empty for none.
    pub no_new_points: Vec<bool>,
    /// Boxes judged dynamic.
    pub dynamic_boxes: usize,
    /// Detector time (ms), 0 when none ran.
    pub semantic_ms: f64,
    /// The motion consistency check and the judgement and culling that follow it, the world's
    /// motion and the per-keypoint checks included (ms).
    pub geometry_ms: f64,
    /// Where the next frame's ORB extraction should keep no corner (the feature budget goes to
    /// the static scene); drawn on that frame's depth. Empty: everywhere.
    pub skip_next: Regions,
    /// Map hygiene: the map points made since a frame on these movers' pixels leave the map.
    pub erase_recent: Option<EraseRecent>,
    /// The frame's objects, for overlays, recordings and static dense maps.
    pub objects: SceneObjects,
    /// The culled keypoints may still be matched to the map's existing points, closely, and
    /// make none (`front_end.offer_culled_to_map_below`; frames without depth only).
    pub offer_culled_to_map: bool,
}

/// Map points to erase once the frame has its pose (RGB-D): those made since frame `since` that
/// lie on `movers` (drawn on the frame's depth).
#[derive(Clone, Debug, Default)]
pub struct EraseRecent {
    /// The oldest frame whose points go.
    pub since: usize,
    /// The pixels of the objects judged moving.
    pub movers: Regions,
}

/// The objects a front-end saw in a frame.
#[derive(Clone, Debug, Default)]
pub struct SceneObjects {
    /// Every object seen in the frame (box, class, moving or not).
    pub tracked: Vec<TrackedObject>,
    /// Boxes the box memory carried into the frame because the detector missed their objects
    /// there (judged moving, as the frame before judged them).
    pub carried: Vec<BBox>,
    /// The pixels of every object moving or of a movable class (people, animals, vehicles:
    /// still or not), up to the far end of each one's depth band: what a static map of the
    /// scene should hold none of.
    pub movable: Regions,
}
