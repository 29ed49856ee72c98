//! Box memory: temporal propagation of moving-object boxes across missed detections (ours, not
//! in the paper).
//!
//! The paper judges each frame's detections on their own, so a frame in which the detector misses
//! a walker (motion blur, occlusion, an unusual pose) lets all of the walker's keypoints into
//! tracking and the map. Here a box judged dynamic in the previous frame that no current detection
//! of the same class overlaps (IoU < [`BoxMemoryParams::min_iou`]) is carried into the current
//! frame, shifted by the median optical flow of the tracked points that started inside it
//! (unshifted when there are none), for at most [`BoxMemoryParams::max_frames`] frames, and
//! culled as a dynamic box. A mover that was never detected has nothing to carry.
//! Measurements: docs/measurements.md.
//!
//! ```
//! use stillpoint_detection::Detection;
//! use stillpoint_dynamic::{BoxMemoryParams, RememberedBox, TrackedPoint, carry_forward};
//! use stillpoint_geometry::BBox;
//! let walker = RememberedBox { bbox: BBox::new(100.0, 50.0, 150.0, 350.0), class_id: 0, age: 0 };
//! let flow = TrackedPoint { prev: [120.0, 200.0], cur: [126.0, 200.0], epipolar_distance: 6.0, outlier: true };
//! // The detector missed the walker in this frame: the box moves with the flow.
//! let carried = carry_forward(&[walker], &[], &[flow], &BoxMemoryParams::default());
//! assert_eq!(carried[0].bbox, BBox::new(106.0, 50.0, 156.0, 350.0));
//! assert_eq!(carried[0].age, 1);
//! ```

use crate::judge::{BoxPart, BoxState, Rule, Verdict};
use crate::motion_consistency::TrackedPoint;
use crate::settings::BoxMemoryParams;
use stillpoint_detection::Detection;
use stillpoint_geometry::BBox;

/// A box judged dynamic in an earlier frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RememberedBox {
    /// Where the object was last seen (or carried to), pixels.
    pub bbox: BBox,
    /// COCO class of the detection it came from.
    pub class_id: u16,
    /// Frames carried without a matching detection: 0 = judged dynamic in the frame it is from.
    pub age: usize,
}

/// The remembered boxes that no detection of the current frame re-finds, moved into the current
/// frame by the median flow (`prev -> cur`) of the tracked points whose previous position lies
/// strictly inside them, each one frame older. Boxes already `max_frames` old, boxes re-found by a
/// current detection of the same class (IoU >= `min_iou`, or covered by it for at least
/// `min_covered` of their area), and non-finite boxes are dropped.
/// Empty when the memory is disabled.
pub fn carry_forward(
    remembered: &[RememberedBox],
    dets: &[Detection],
    pts: &[TrackedPoint],
    p: &BoxMemoryParams,
) -> Vec<RememberedBox> {
    if !p.enabled {
        return Vec::new();
    }
    remembered
        .iter()
        .filter(|r| r.age < p.max_frames)
        .filter(|r| {
            !dets
                .iter()
                .any(|d| d.class_id == r.class_id && refinds(&d.bbox, &r.bbox, p))
        })
        .filter_map(|r| {
            let bbox = moved_by_flow(&r.bbox, pts);
            let finite = [bbox.x1, bbox.y1, bbox.x2, bbox.y2]
                .iter()
                .all(|v| v.is_finite());
            (finite && bbox.area() > 0.0).then_some(RememberedBox {
                bbox,
                class_id: r.class_id,
                age: r.age + 1,
            })
        })
        .collect()
}

/// Carried boxes as dynamic [`BoxState`]s, to append to the judged ones before culling. Their
/// `detection` index starts at `first_index` (the number of real detections) so that it names no
/// real detection; `tracked` and `outliers` count the points inside, for the log.
pub fn carried_states(
    carried: &[RememberedBox],
    pts: &[TrackedPoint],
    first_index: usize,
) -> Vec<BoxState> {
    carried
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let inside = pts
                .iter()
                .filter(|t| r.bbox.contains_strict(t.cur[0], t.cur[1]));
            let (tracked, outliers) =
                inside.fold((0, 0), |(n, o), t| (n + 1, o + usize::from(t.outlier)));
            BoxState {
                bbox: r.bbox,
                class_id: r.class_id,
                detection: first_index + i,
                part: BoxPart::Whole,
                rule: Rule::Nhbc,
                verdict: Verdict::Dynamic,
                tracked,
                outliers,
                depth: None,
            }
        })
        .collect()
}

/// The memory for the next frame: every state of this frame's detections judged dynamic (age 0;
/// `detection < n_detections`) and the carried boxes (their age kept).
pub fn remember(
    states: &[BoxState],
    n_detections: usize,
    carried: &[RememberedBox],
) -> Vec<RememberedBox> {
    states
        .iter()
        .filter(|s| s.is_dynamic() && s.detection < n_detections)
        .map(|s| RememberedBox {
            bbox: s.bbox,
            class_id: s.class_id,
            age: 0,
        })
        .chain(carried.iter().copied())
        .collect()
}

/// Whether a current detection box is the remembered object again: IoU >= `min_iou`, or it
/// covers at least `min_covered` of the remembered box (a seated person's bottom part against
/// the whole person detected again has IoU 0.23).
fn refinds(det: &BBox, remembered: &BBox, p: &BoxMemoryParams) -> bool {
    let w = (det.x2.min(remembered.x2) - det.x1.max(remembered.x1)).max(0.0);
    let h = (det.y2.min(remembered.y2) - det.y1.max(remembered.y1)).max(0.0);
    let area = remembered.area();
    det.iou(remembered) >= p.min_iou || (area > 0.0 && w * h >= p.min_covered * area)
}

/// `bbox` moved by the median flow (`prev -> cur`) of the points that started strictly inside
/// it; unmoved with none.
pub fn moved_by_flow(bbox: &BBox, pts: &[TrackedPoint]) -> BBox {
    let (dx, dy) = median_flow(bbox, pts);
    BBox::new(bbox.x1 + dx, bbox.y1 + dy, bbox.x2 + dx, bbox.y2 + dy)
}

/// A box edge this close to the view's border (pixels) is at the border: the object may go on
/// past it.
pub const AT_BORDER_PX: f32 = 4.0;

/// [`moved_by_flow`] for a box in a `width` x `height` view: an edge at the view's border
/// (within 4 px) stays there, as the object goes on past it and its hidden part may come in
/// (a person entering from the side is carried as a box that grows with them, not one that
/// slides off the part still entering); the box is kept inside the view.
pub fn moved_by_flow_in_view(bbox: &BBox, pts: &[TrackedPoint], width: f32, height: f32) -> BBox {
    let m = moved_by_flow(bbox, pts);
    let low = |was: f32, now: f32| {
        if was <= AT_BORDER_PX {
            was.min(now)
        } else {
            now
        }
    };
    let high = |was: f32, now: f32, end: f32| {
        if was >= end - AT_BORDER_PX {
            was.max(now)
        } else {
            now
        }
    };
    BBox::new(
        low(bbox.x1, m.x1).clamp(0.0, width),
        low(bbox.y1, m.y1).clamp(0.0, height),
        high(bbox.x2, m.x2, width).clamp(0.0, width),
        high(bbox.y2, m.y2, height).clamp(0.0, height),
    )
}

/// Median (dx, dy) of the flows of the points that started strictly inside `bbox`; (0, 0) with
/// none.
fn median_flow(bbox: &BBox, pts: &[TrackedPoint]) -> (f32, f32) {
    let (mut dx, mut dy): (Vec<f32>, Vec<f32>) = pts
        .iter()
        .filter(|t| bbox.contains_strict(t.prev[0], t.prev[1]))
        .map(|t| (t.cur[0] - t.prev[0], t.cur[1] - t.prev[1]))
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .unzip();
    (median(&mut dx), median(&mut dy))
}

fn median(v: &mut [f32]) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f32::total_cmp);
    let m = v.len() / 2;
    if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PERSON: u16 = 0;
    const CHAIR: u16 = 56;

    fn walker() -> RememberedBox {
        RememberedBox {
            bbox: BBox::new(100.0, 50.0, 150.0, 350.0),
            class_id: PERSON,
            age: 0,
        }
    }

    fn flow(x: f32, y: f32, dx: f32, dy: f32) -> TrackedPoint {
        TrackedPoint {
            prev: [x, y],
            cur: [x + dx, y + dy],
            epipolar_distance: 0.0,
            outlier: false,
        }
    }

    fn det(class_id: u16, bbox: BBox) -> Detection {
        Detection {
            class_id,
            score: 0.9,
            bbox,
        }
    }

    #[test]
    fn missed_walker_is_carried_by_the_median_flow() {
        // Two points move by (4, 2), one bad track by (40, 0): the median ignores it. The
        // background point outside the box does not count.
        let pts = [
            flow(110.0, 100.0, 4.0, 2.0),
            flow(120.0, 200.0, 4.0, 2.0),
            flow(130.0, 300.0, 40.0, 0.0),
            flow(400.0, 200.0, -10.0, 0.0),
        ];
        let carried = carry_forward(&[walker()], &[], &pts, &BoxMemoryParams::default());
        assert_eq!(carried.len(), 1);
        assert_eq!(carried[0].bbox, BBox::new(104.0, 52.0, 154.0, 352.0));
        assert_eq!(carried[0].age, 1);
    }

    #[test]
    fn a_person_entering_from_the_left_is_carried_as_a_growing_box() {
        // The person's points move right by 12 px; the box touches the left border, where the
        // rest of them is still coming in.
        let entering = BBox::new(0.0, 60.0, 200.0, 480.0);
        let pts = [
            flow(50.0, 100.0, 12.0, 0.0),
            flow(120.0, 300.0, 12.0, 0.0),
            flow(180.0, 400.0, 12.0, 0.0),
        ];
        let carried = moved_by_flow_in_view(&entering, &pts, 640.0, 480.0);
        assert_eq!(carried, BBox::new(0.0, 60.0, 212.0, 480.0));
        // Leaving to the left, the box shrinks with them; inside the view, it only moves.
        let leaving: Vec<_> = pts
            .iter()
            .map(|p| flow(p.prev[0], p.prev[1], -12.0, 0.0))
            .collect();
        let carried = moved_by_flow_in_view(&entering, &leaving, 640.0, 480.0);
        assert_eq!(carried, BBox::new(0.0, 60.0, 188.0, 480.0));
        let inside = BBox::new(40.0, 60.0, 200.0, 400.0);
        let carried = moved_by_flow_in_view(&inside, &pts, 640.0, 480.0);
        assert_eq!(carried, BBox::new(52.0, 60.0, 212.0, 400.0));
    }

    #[test]
    fn no_points_inside_carries_the_box_unshifted() {
        let carried = carry_forward(&[walker()], &[], &[], &BoxMemoryParams::default());
        assert_eq!(carried[0].bbox, walker().bbox);
    }

    #[test]
    fn a_redetected_object_is_not_carried() {
        let p = BoxMemoryParams::default();
        let again = det(PERSON, BBox::new(105.0, 50.0, 155.0, 350.0));
        assert!(carry_forward(&[walker()], &[again], &[], &p).is_empty());
        // A detection of another class at the same place does not re-find the person.
        let chair = det(CHAIR, walker().bbox);
        assert_eq!(carry_forward(&[walker()], &[chair], &[], &p).len(), 1);
        // The bottom part of a seated person is re-found by the whole person (IoU 0.23).
        let bottom = RememberedBox {
            bbox: BBox::new(100.0, 100.0, 200.0, 130.0),
            ..walker()
        };
        let whole = det(PERSON, BBox::new(100.0, 0.0, 200.0, 130.0));
        assert!(carry_forward(&[bottom], &[whole], &[], &p).is_empty());
        // Nor does a person elsewhere.
        let other = det(PERSON, BBox::new(400.0, 50.0, 450.0, 350.0));
        assert_eq!(carry_forward(&[walker()], &[other], &[], &p).len(), 1);
    }

    #[test]
    fn memory_expires_after_max_frames() {
        let p = BoxMemoryParams {
            max_frames: 2,
            ..BoxMemoryParams::default()
        };
        let mut memory = vec![walker()];
        let mut lived = 0;
        for _ in 0..5 {
            let carried = carry_forward(&memory, &[], &[], &p);
            memory = remember(&[], 0, &carried);
            lived += usize::from(!memory.is_empty());
        }
        assert_eq!(lived, 2);
    }

    #[test]
    fn disabled_memory_carries_nothing() {
        let p = BoxMemoryParams {
            enabled: false,
            ..BoxMemoryParams::default()
        };
        assert!(carry_forward(&[walker()], &[], &[], &p).is_empty());
    }

    #[test]
    fn non_finite_boxes_are_dropped_without_panic() {
        let nan = RememberedBox {
            bbox: BBox::new(f32::NAN, 0.0, 10.0, 10.0),
            ..walker()
        };
        assert!(carry_forward(&[nan], &[], &[], &BoxMemoryParams::default()).is_empty());
    }

    #[test]
    fn carried_states_are_dynamic_and_culled() {
        let carried = [RememberedBox { age: 1, ..walker() }];
        let inside = flow(120.0, 200.0, 0.0, 0.0);
        let states = carried_states(&carried, &[inside], 3);
        assert_eq!(states[0].verdict, Verdict::Dynamic);
        assert_eq!((states[0].detection, states[0].tracked), (3, 1));
        let culled = crate::cull(&[[120.0, 300.0], [400.0, 300.0]], &states);
        assert_eq!(culled, vec![true, false]);
        // Remembering: fresh dynamic detections at age 0, carried ones keep their age, static
        // and carried states (detection >= n_detections) are not duplicated.
        let judged = crate::judge_boxes(
            &[det(CHAIR, BBox::new(300.0, 300.0, 350.0, 350.0))],
            &[],
            &crate::JudgeParams::default(),
        );
        let all: Vec<BoxState> = judged.iter().chain(&states).copied().collect();
        let next = remember(&all, 1, &carried);
        assert_eq!(next, carried.to_vec());
    }
}
