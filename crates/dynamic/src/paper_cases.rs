//! The paper's own cases for algorithms 1 and 3, as unit tests.

use crate::*;
use stillpoint_detection::{BBox, Detection};

const PERSON: u16 = 0;
const CHAIR: u16 = 56;
const KEYBOARD: u16 = 66;
const BOOK: u16 = 73;

/// A detection of `class_id` with score 0.9 (also the depth tests' helper).
pub(crate) fn det(class_id: u16, x1: f32, y1: f32, x2: f32, y2: f32) -> Detection {
    Detection {
        class_id,
        score: 0.9,
        bbox: BBox::new(x1, y1, x2, y2),
    }
}

/// A point that stayed on its epipolar line (`outlier` false) or left it by 3 px.
pub(crate) fn pt(x: f32, y: f32, outlier: bool) -> TrackedPoint {
    let d = if outlier { 3.0 } else { 0.2 };
    TrackedPoint {
        prev: [x, y],
        cur: [x, y],
        epipolar_distance: d,
        outlier,
    }
}

/// A grid of tracked points over a box, all static.
fn static_grid(x1: f32, y1: f32, x2: f32, y2: f32, n: usize) -> Vec<TrackedPoint> {
    let mut v = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let fx = (i as f32 + 0.5) / n as f32;
            let fy = (j as f32 + 0.5) / n as f32;
            v.push(pt(x1 + fx * (x2 - x1), y1 + fy * (y2 - y1), false));
        }
    }
    v
}

#[test]
fn seated_person_moving_a_hand() {
    // A seated person 200 wide x 260 tall (ratio 1.3 <= 3): split at 260 / 1.3 = 200 px.
    // The hand (on the desk, in the top part) moved; legs, keyboard and chair did not.
    let person = det(PERSON, 100.0, 100.0, 300.0, 360.0);
    let keyboard = det(KEYBOARD, 150.0, 270.0, 260.0, 295.0); // in front, inside the top part
    let chair = det(CHAIR, 80.0, 250.0, 320.0, 420.0);
    let mut pts = static_grid(100.0, 100.0, 300.0, 360.0, 8);
    pts.extend(static_grid(150.0, 270.0, 260.0, 295.0, 3));
    pts.push(pt(270.0, 280.0, true)); // the hand, right of the keyboard
    let states = judge_boxes(&[person, keyboard, chair], &pts, &JudgeParams::default());
    assert_eq!(states.len(), 4);
    let (top, bottom) = (&states[0], &states[1]);
    assert_eq!(
        (top.part, top.rule, top.verdict),
        (BoxPart::SeatedTop, Rule::Nhbc, Verdict::Dynamic)
    );
    assert_eq!(
        (bottom.part, bottom.verdict),
        (BoxPart::SeatedBottom, Verdict::Static)
    );
    assert!((top.bbox.y2 - 300.0).abs() < 1e-3 && (bottom.bbox.y1 - 300.0).abs() < 1e-3);
    assert_eq!(top.outliers, 1);
    assert_eq!(states[2].verdict, Verdict::Static, "keyboard");
    assert_eq!(
        states[3].verdict,
        Verdict::Static,
        "chair: 1 outlier of many tracked"
    );
    let keypoints = [
        [200.0, 150.0], // face: top part only → culled
        [270.0, 282.0], // hand: top part, inside the (static) chair box → kept (algorithm 3)
        [200.0, 280.0], // keyboard in front of the person → kept
        [200.0, 340.0], // legs: bottom part (static) → kept
        [500.0, 200.0], // background → kept
    ];
    assert_eq!(
        cull(&keypoints, &states),
        vec![true, false, false, false, false]
    );
}

#[test]
fn standing_walker_is_dynamic_as_a_whole() {
    // 60 x 300: ratio 5 > 3, one box; a single outlier (a swinging leg) makes all of it dynamic.
    let walker = det(PERSON, 300.0, 100.0, 360.0, 400.0);
    let mut pts = static_grid(300.0, 100.0, 360.0, 400.0, 5);
    pts.push(pt(320.0, 380.0, true));
    let states = judge_boxes(&[walker], &pts, &JudgeParams::default());
    assert_eq!(states.len(), 1);
    assert_eq!(
        (states[0].part, states[0].verdict),
        (BoxPart::Whole, Verdict::Dynamic)
    );
    assert_eq!((states[0].tracked, states[0].outliers), (26, 1));
    let removed = cull(
        &[
            [310.0, 110.0],
            [330.0, 250.0],
            [350.0, 395.0],
            [361.0, 250.0],
        ],
        &states,
    );
    assert_eq!(removed, vec![true, true, true, false]);
    // A point exactly on the edge is outside, as the authors test it.
    assert_eq!(cull(&[[300.0, 250.0]], &states), vec![false]);
}

#[test]
fn static_chair_inside_a_moving_person_keeps_its_points() {
    let walker = det(PERSON, 100.0, 50.0, 180.0, 400.0);
    let chair = det(CHAIR, 120.0, 250.0, 200.0, 390.0);
    let mut pts = static_grid(120.0, 250.0, 200.0, 390.0, 4);
    pts.extend([pt(140.0, 100.0, true), pt(150.0, 150.0, true)]);
    let states = judge_boxes(&[walker, chair], &pts, &JudgeParams::default());
    assert_eq!(states[0].verdict, Verdict::Dynamic);
    assert_eq!(states[1].verdict, Verdict::Static);
    assert_eq!(
        cull(&[[140.0, 100.0], [150.0, 300.0]], &states),
        vec![true, false]
    );
}

#[test]
fn moved_book_two_of_three_vs_one_of_ten() {
    let book = det(BOOK, 10.0, 10.0, 60.0, 40.0);
    let moved = [
        pt(20.0, 20.0, true),
        pt(30.0, 25.0, true),
        pt(40.0, 30.0, false),
    ];
    let states = judge_boxes(&[book], &moved, &JudgeParams::default());
    assert_eq!(
        (states[0].rule, states[0].verdict),
        (Rule::Ata, Verdict::Dynamic)
    );
    assert_eq!((states[0].tracked, states[0].outliers), (3, 2)); // 0.67 > 0.4
    let mut still: Vec<TrackedPoint> = (0..9)
        .map(|i| pt(12.0 + 5.0 * i as f32, 20.0, false))
        .collect();
    still.push(pt(30.0, 30.0, true));
    let states = judge_boxes(&[book], &still, &JudgeParams::default());
    assert_eq!(states[0].verdict, Verdict::Static); // 0.1 <= 0.4
    assert_eq!(cull(&[[30.0, 20.0]], &states), vec![false]);
}

#[test]
fn box_with_no_tracked_points_is_static_unknown() {
    let tv = det(62, 10.0, 10.0, 60.0, 40.0);
    let far_away = [pt(300.0, 300.0, true)];
    let params = JudgeParams::default();
    for pts in [&far_away[..], &[]] {
        let states = judge_boxes(&[tv], pts, &params);
        assert_eq!(
            (states[0].verdict, states[0].tracked, states[0].outliers),
            (Verdict::StaticUnknown, 0, 0)
        );
    }
    // A person with no tracked point is unknown too (no outlier, no evidence either way).
    let states = judge_boxes(&[det(PERSON, 0.0, 0.0, 50.0, 200.0)], &[], &params);
    assert_eq!(states[0].verdict, Verdict::StaticUnknown);
    // min_tracked raises the bar: 2 of 2 outliers is not enough evidence with min_tracked 3.
    let strict = JudgeParams {
        min_tracked: 3,
        ..params.clone()
    };
    let two = [pt(20.0, 20.0, true), pt(30.0, 20.0, true)];
    assert_eq!(
        judge_boxes(&[tv], &two, &strict)[0].verdict,
        Verdict::StaticUnknown
    );
    assert_eq!(
        judge_boxes(&[tv], &two, &params)[0].verdict,
        Verdict::Dynamic
    );
}

#[test]
fn unknown_box_inside_a_dynamic_one_protects_only_when_asked() {
    let walker = det(PERSON, 0.0, 0.0, 60.0, 300.0);
    let bag = det(24, 10.0, 100.0, 50.0, 140.0);
    let states = judge_boxes(
        &[walker, bag],
        &[pt(30.0, 50.0, true)],
        &JudgeParams::default(),
    );
    assert_eq!(states[1].verdict, Verdict::StaticUnknown);
    let kp = [[30.0, 120.0]];
    assert_eq!(cull(&kp, &states), vec![false]);
    let no_protect = CullParams {
        unknown_box_protects: false,
        ..CullParams::default()
    };
    assert_eq!(cull_with(&kp, &states, &[], &no_protect), vec![true]);
}

#[test]
fn degenerate_boxes_never_panic_or_nan() {
    let nan = det(BOOK, f32::NAN, 0.0, 10.0, 10.0);
    let zero_width = det(PERSON, 10.0, 10.0, 10.0, 100.0);
    let inverted = det(CHAIR, 50.0, 50.0, 10.0, 10.0);
    let pts = [pt(10.0, 50.0, true), pt(30.0, 30.0, true)];
    let states = judge_boxes(&[nan, zero_width, inverted], &pts, &JudgeParams::default());
    assert_eq!(states.len(), 3);
    assert!(states.iter().all(|s| s.verdict == Verdict::StaticUnknown));
    assert_eq!(
        cull(&[[10.0, 50.0], [30.0, 30.0]], &states),
        vec![false, false]
    );
}

#[test]
fn unknown_dynamic_objects_option() {
    // Outliers on something no detector knows (a balloon) cull nearby keypoints when asked.
    let chair = det(CHAIR, 200.0, 200.0, 300.0, 300.0);
    let pts = [
        pt(50.0, 50.0, true),
        pt(58.0, 52.0, true),
        pt(48.0, 64.0, true),
        pt(400.0, 400.0, true), // isolated: a single bad track
        pt(250.0, 250.0, true), // inside a box: ATA's business, not this option's
        pt(255.0, 250.0, false),
        pt(245.0, 250.0, false),
    ];
    let states = judge_boxes(&[chair], &pts, &JudgeParams::default());
    let kp = [[54.0, 60.0], [400.0, 405.0], [250.0, 255.0], [120.0, 120.0]];
    assert_eq!(cull(&kp, &states), vec![false; 4]);
    let on = CullParams {
        unknown_objects: true,
        ..CullParams::default()
    };
    assert_eq!(
        cull_with(&kp, &states, &pts, &on),
        vec![true, false, false, false]
    );
    assert_eq!(
        near_outliers(&kp, &pts, 20.0, 1),
        vec![true, true, true, false]
    );
}

#[test]
fn ata_on_own_points_keeps_a_table_behind_a_walker_static() {
    let table = det(60, 0.0, 200.0, 400.0, 300.0);
    let walker = det(PERSON, 150.0, 50.0, 210.0, 380.0);
    let mut pts = static_grid(0.0, 200.0, 100.0, 300.0, 2); // 4 table points left of the walker
    pts.extend((0..6).map(|i| pt(160.0 + 8.0 * i as f32, 250.0, true))); // the walker's legs
    let paper = judge_boxes(&[table, walker], &pts, &JudgeParams::default());
    assert_eq!((paper[0].verdict, paper[0].outliers), (Verdict::Dynamic, 6)); // 6 / 10 > 0.4
    let own = JudgeParams {
        ata_ignores_person_points: true,
        ..JudgeParams::default()
    };
    let states = judge_boxes(&[table, walker], &pts, &own);
    assert_eq!((states[0].verdict, states[0].tracked), (Verdict::Static, 4));
    assert_eq!(states[1].verdict, Verdict::Dynamic);
}

#[test]
fn subpixel_hand_motion_makes_a_seated_top_part_dynamic_ours() {
    // Seated person; the hand moved 0.6-0.8 px off its epipolar line (below the paper's 1 px).
    let person = det(PERSON, 100.0, 100.0, 300.0, 360.0);
    let mut pts = static_grid(100.0, 100.0, 300.0, 360.0, 6);
    for (i, r) in [0.6, 0.7, 0.8].into_iter().enumerate() {
        let mut t = pt(250.0 + 5.0 * i as f32, 250.0, false);
        t.epipolar_distance = r;
        pts.push(t);
    }
    let paper = JudgeParams {
        person_subpixel_px: None,
        ..JudgeParams::default()
    };
    assert_eq!(
        judge_boxes(&[person], &pts, &paper)[0].verdict,
        Verdict::Static
    );
    let states = judge_boxes(&[person], &pts, &JudgeParams::default());
    assert_eq!(
        (states[0].part, states[0].verdict, states[1].verdict),
        (BoxPart::SeatedTop, Verdict::Dynamic, Verdict::Static)
    );
    // Two such points are not enough (a noisy track or two), nor is noise below 0.5 px.
    pts.pop();
    assert_eq!(
        judge_boxes(&[person], &pts, &JudgeParams::default())[0].verdict,
        Verdict::Static
    );
    let quiet: Vec<TrackedPoint> = static_grid(100.0, 100.0, 300.0, 360.0, 6)
        .into_iter()
        .map(|mut t| {
            t.epipolar_distance = 0.45;
            t
        })
        .collect();
    assert_eq!(
        judge_boxes(&[person], &quiet, &JudgeParams::default())[0].verdict,
        Verdict::Static
    );
}

#[test]
fn paper_settings_cull_as_algorithm_3() {
    // Our defaults add the unknown-object rule (and, on RGB-D, depth); `paper()` takes them off.
    let chair = det(CHAIR, 200.0, 200.0, 300.0, 300.0);
    let walker = det(PERSON, 400.0, 40.0, 460.0, 400.0);
    let pts = [
        pt(50.0, 50.0, true),
        pt(58.0, 52.0, true),
        pt(48.0, 64.0, true),
        pt(430.0, 200.0, true),
        pt(250.0, 250.0, false),
    ];
    let kp = [[54.0, 60.0], [430.0, 100.0], [250.0, 255.0], [120.0, 120.0]];
    let paper = crate::DynamicSettings::paper();
    let mut states = judge_boxes(&[chair, walker], &pts, &paper.judge);
    let removed = crate::cull_frame(&kp, &mut states, &pts, None, &paper);
    assert_eq!(removed, cull(&kp, &states));
    assert_eq!(removed, vec![false, true, false, false]);
    // Our defaults: the unknown-object rule needs depth (or, for stereo, asking).
    let mut ours = crate::DynamicSettings::default();
    let removed = crate::cull_frame(&kp, &mut states, &pts, None, &ours);
    assert_eq!(removed, vec![false, true, false, false]);
    ours.cull.unknown_objects_without_depth = true;
    let removed = crate::cull_frame(&kp, &mut states, &pts, None, &ours);
    assert_eq!(removed, vec![true, true, false, false]);
}
