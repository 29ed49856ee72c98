//! Moving-box judgement, paper algorithm 1: "nine head body checking" (NHBC) for persons and
//! "adaptive threshold adjusting" (ATA) for every other class.
//!
//! Follows the authors' code, with two deliberate differences (both from the paper's own text):
//! - ATA divides by the *successfully* tracked points inside the box; the authors also count
//!   failed LK tracks, which dilutes the ratio.
//! - a box with fewer than [`JudgeParams::min_tracked`] tracked points gets the explicit verdict
//!   [`Verdict::StaticUnknown`] instead of the authors' 0 / 0 = NaN (which compared as static).

use crate::motion_consistency::TrackedPoint;
use crate::settings::JudgeParams;
use serde::Serialize;
use stillpoint_detection::Detection;
use stillpoint_geometry::BBox;

/// What the judgement decided for one box or part box.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Verdict {
    /// Moving: its keypoints are culled unless they are also inside a static box.
    Dynamic,
    /// Not moving, with enough evidence.
    Static,
    /// Too few tracked points inside to tell; treated as static by default
    /// ([`crate::CullParams::unknown_box_protects`]).
    StaticUnknown,
}

/// Which part of a detection a [`BoxState`] covers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum BoxPart {
    /// The whole detection (a standing person, or any other class).
    Whole,
    /// Top 1/1.3 of a seated person (head, torso, arms and hands).
    SeatedTop,
    /// Bottom 0.3/1.3 of a seated person (legs, usually under a desk or on a chair).
    SeatedBottom,
}

/// The rule that judged a box.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Rule {
    /// Nine head body checking: dynamic with at least one outlier inside.
    Nhbc,
    /// Adaptive threshold adjusting: dynamic when outliers / tracked > ε.
    Ata,
}

/// The verdict on one detection or one part of it, and why.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct BoxState {
    /// The box judged (the detection's box, or the part box for a seated person).
    pub bbox: BBox,
    /// COCO class of the detection.
    pub class_id: u16,
    /// Index of the detection in the input slice.
    pub detection: usize,
    /// Whole box, or the upper / lower part of a seated person (NHBC).
    pub part: BoxPart,
    /// Which rule judged it (person outliers, ATA ratio, ...).
    pub rule: Rule,
    /// Moving, static or unknown.
    pub verdict: Verdict,
    /// Successfully tracked points strictly inside `bbox` (current-frame position).
    pub tracked: usize,
    /// Of those, the geometric outliers.
    pub outliers: usize,
    /// The moving object's depth for a dynamic box on an RGB-D frame (ours; filled by
    /// [`crate::depth::estimate_object_depths`], `None` from [`judge_boxes`]).
    pub depth: Option<crate::depth::ObjectDepth>,
}

impl BoxState {
    /// True for [`Verdict::Dynamic`].
    pub fn is_dynamic(&self) -> bool {
        self.verdict == Verdict::Dynamic
    }
}

/// True when `point` lies strictly inside at least one dynamic box and every dynamic box around
/// it satisfies `pred` (the rules that apply only to keypoints of, say, seated parts alone).
pub fn only_in_dynamic_boxes_where(
    states: &[BoxState],
    [x, y]: [f32; 2],
    pred: impl FnMut(&BoxState) -> bool,
) -> bool {
    let mut boxes = states
        .iter()
        .filter(|s| s.is_dynamic() && s.bbox.contains_strict(x, y))
        .peekable();
    boxes.peek().is_some() && boxes.all(pred)
}

/// Judge every detection against the tracked points of the geometry module (their current-frame
/// positions, `TrackedPoint::cur`). A seated person (height / width <= 3) yields two states, top
/// then bottom; every other detection one. Boxes that are empty or not finite contain no point,
/// so they come out [`Verdict::StaticUnknown`] (never a panic, never NaN).
///
/// ```
/// use stillpoint_detection::{BBox, Detection};
/// use stillpoint_dynamic::{JudgeParams, TrackedPoint, Verdict, judge_boxes};
/// let walker = Detection { class_id: 0, score: 0.9, bbox: BBox::new(100.0, 50.0, 150.0, 350.0) };
/// let hand = TrackedPoint { prev: [120.0, 200.0], cur: [124.0, 200.0], epipolar_distance: 4.0, outlier: true };
/// let states = judge_boxes(&[walker], &[hand], &JudgeParams::default());
/// assert_eq!(states.len(), 1); // 300 / 50 > 3: standing, one box
/// assert_eq!(states[0].verdict, Verdict::Dynamic);
/// ```
pub fn judge_boxes(dets: &[Detection], pts: &[TrackedPoint], p: &JudgeParams) -> Vec<BoxState> {
    let mut states = Vec::with_capacity(dets.len() + 2);
    for (index, det) in dets.iter().enumerate() {
        if det.class_id == p.person_class {
            for (part, bbox) in nhbc_parts(&det.bbox, p) {
                let (tracked, outliers) = count_inside(&bbox, pts);
                let subpixel = p.person_subpixel_px.is_some_and(|px| {
                    pts.iter()
                        .filter(|t| bbox.contains_strict(t.cur[0], t.cur[1]))
                        .filter(|t| t.epipolar_distance > px)
                        .count()
                        >= p.person_subpixel_min_points.max(1)
                });
                let verdict = if outliers >= p.person_min_outliers.max(1) || subpixel {
                    Verdict::Dynamic
                } else if tracked < p.min_tracked {
                    Verdict::StaticUnknown
                } else {
                    Verdict::Static
                };
                states.push(BoxState {
                    bbox,
                    class_id: det.class_id,
                    detection: index,
                    part,
                    rule: Rule::Nhbc,
                    verdict,
                    tracked,
                    outliers,
                    depth: None,
                });
            }
        } else {
            let (tracked, outliers) = if p.ata_ignores_person_points {
                let own: Vec<TrackedPoint> = pts
                    .iter()
                    .filter(|t| !in_person_box(dets, t.cur, p.person_class))
                    .copied()
                    .collect();
                count_inside(&det.bbox, &own)
            } else {
                count_inside(&det.bbox, pts)
            };
            states.push(BoxState {
                bbox: det.bbox,
                class_id: det.class_id,
                detection: index,
                part: BoxPart::Whole,
                rule: Rule::Ata,
                verdict: ata_verdict(tracked, outliers, p),
                tracked,
                outliers,
                depth: None,
            });
        }
    }
    states
}

/// NHBC's split: a person box with height / width <= `seated_max_aspect` is a seated person and
/// becomes its top `seated_top_fraction` and the rest; a taller one stays whole.
///
/// ```
/// use stillpoint_dynamic::{BoxPart, JudgeParams, nhbc_parts};
/// use stillpoint_geometry::BBox;
/// let seated = nhbc_parts(&BBox::new(0.0, 0.0, 100.0, 130.0), &JudgeParams::default());
/// assert_eq!(seated[0].0, BoxPart::SeatedTop);
/// assert!((seated[0].1.y2 - 100.0).abs() < 1e-3 && (seated[1].1.y1 - 100.0).abs() < 1e-3);
/// ```
pub fn nhbc_parts(bbox: &BBox, p: &JudgeParams) -> Vec<(BoxPart, BBox)> {
    let (w, h) = (bbox.width(), bbox.height());
    // `w > 0` also rejects NaN; a zero-width box is "infinitely tall", i.e. standing.
    let seated = w > 0.0 && h <= p.seated_max_aspect * w;
    if !seated {
        return vec![(BoxPart::Whole, *bbox)];
    }
    let split = bbox.y1 + h * p.seated_top_fraction;
    vec![
        (
            BoxPart::SeatedTop,
            BBox::new(bbox.x1, bbox.y1, bbox.x2, split),
        ),
        (
            BoxPart::SeatedBottom,
            BBox::new(bbox.x1, split, bbox.x2, bbox.y2),
        ),
    ]
}

/// ATA: dynamic when outliers / tracked > ε; too few tracked points is an explicit unknown.
fn ata_verdict(tracked: usize, outliers: usize, p: &JudgeParams) -> Verdict {
    if tracked == 0 || tracked < p.min_tracked {
        Verdict::StaticUnknown
    } else if outliers as f32 / tracked as f32 > p.ata_ratio {
        Verdict::Dynamic
    } else {
        Verdict::Static
    }
}

fn in_person_box(dets: &[Detection], at: [f32; 2], person_class: u16) -> bool {
    dets.iter()
        .any(|d| d.class_id == person_class && d.bbox.contains_strict(at[0], at[1]))
}

/// (tracked, outliers) strictly inside the box, by current-frame position.
fn count_inside(bbox: &BBox, pts: &[TrackedPoint]) -> (usize, usize) {
    pts.iter()
        .filter(|t| bbox.contains_strict(t.cur[0], t.cur[1]))
        .fold((0, 0), |(n, o), t| (n + 1, o + usize::from(t.outlier)))
}
