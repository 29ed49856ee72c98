//! The front-end on synthetic frames rendered in-process.

use super::*;
use stillpoint_datasets::annotations::FrameBoxes;
use stillpoint_detect::{
    DetectError, DetectInput, Detection, Detector, GtDetector, GtDetectorParams, NoDetector,
};
use stillpoint_image::Gray8;
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

/// A synthetic frame (colour and depth) as the front-end takes it, `gray` its gray image.
fn input_of<'a>(
    f: &'a SynthFrame,
    gray: &'a Gray8,
    previous: Option<PreviousPose>,
) -> FrameInput<'a> {
    FrameInput {
        index: f.index,
        timestamp: f.timestamp,
        gray,
        rgb: Some(&f.rgb),
        depth: Some(&f.depth),
        previous,
        own_boxes: false,
    }
}

fn run(front: &mut DynamicFrontEnd, frames: &[SynthFrame], kps: &[[f32; 2]]) -> Vec<Judgement> {
    frames
        .iter()
        .map(|f| {
            let gray = stillpoint_image::rgb_to_gray(&f.rgb);
            front.judge(&input_of(f, &gray, None), kps)
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
    let mut previous = None;
    for f in &frames {
        let gray = stillpoint_image::rgb_to_gray(&f.rgb);
        let kps: Vec<[f32; 2]> = orb
            .extract(&gray)
            .keypoints
            .iter()
            .map(|k| [k.x, k.y])
            .collect();
        let input = input_of(f, &gray, previous);
        front.measure(&input);
        let out = front.judge(&input, &kps);
        previous = Some(PreviousPose {
            index: f.index,
            pose_wc: Some(f.pose_wc),
        });
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
    eprintln!("person keypoints let into the map with the detector in the background: {share:.3}");
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
        // By the clock, as a live run hands it frames.
        background_detect_every_frames: 0,
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
        let input = FrameInput {
            index: i,
            timestamp: i as f64 / 30.0,
            gray: &gray,
            rgb: None,
            depth: None,
            previous: None,
            own_boxes: false,
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

/// A detector that finds one chair (judged, never culled on its own) far from the image's side
/// edges, its left edge at 20 + its mark: the function of the frame and of the number of
/// detections before it. The marks are kept, in order.
struct MarkedChair(
    std::sync::Arc<std::sync::Mutex<Vec<usize>>>,
    fn(&DetectInput, usize) -> usize,
);

impl Detector for MarkedChair {
    fn detect(&mut self, input: &DetectInput) -> Result<Vec<Detection>, DetectError> {
        let mut marks = self.0.lock().unwrap();
        let mark = (self.1)(input, marks.len());
        marks.push(mark);
        Ok(vec![Detection {
            bbox: stillpoint_geometry::BBox::new(20.0 + mark as f32, 10.0, 80.0, 50.0),
            class_id: 56,
            score: 0.9,
        }])
    }
    fn name(&self) -> &str {
        "marked chair"
    }
}

/// A front-end whose detector works in the background on a recording's schedule of frames:
/// every third frame, its boxes taken two frames later.
fn on_a_schedule(detector: impl Detector + 'static) -> DynamicFrontEnd {
    let settings = FrontEndSettings {
        detector_in_background: true,
        background_detect_every_frames: 3,
        background_detect_lag_frames: 2,
        background_detect_ahead: true,
        ..Default::default()
    };
    DynamicFrontEnd::new(Box::new(detector), settings)
        .detect_in_background()
        .unwrap()
}

/// Frame `index` of a 30 Hz sequence of `gray` images, without colour, depth or pose.
fn plain_frame(index: usize, gray: &Gray8, own_boxes: bool) -> FrameInput<'_> {
    FrameInput {
        index,
        timestamp: index as f64 / 30.0,
        gray,
        rgb: None,
        depth: None,
        previous: None,
        own_boxes,
    }
}

/// On a schedule of frames the background detector takes exactly every n-th frame, and the boxes
/// of frame k reach frame k + lag, whatever the detector's speed: a recording's run is the same
/// on a busy machine.
#[test]
fn the_background_detector_on_a_schedule_takes_every_nth_frame() {
    use std::sync::{Arc, Mutex};
    let seen = Arc::new(Mutex::new(Vec::new()));
    // The n-th detection (1-based) is marked n.
    let mut front = on_a_schedule(MarkedChair(Arc::clone(&seen), |_, before| before + 1));
    let gray = Gray8::new(96, 64, 0);
    let mut objects = Vec::new();
    // The last frame takes the boxes of frame 39, the last one handed over.
    for i in 0..42 {
        let judged = front.judge(&plain_frame(i, &gray, false), &[]);
        objects.push(judged.objects.tracked.first().map(|o| o.bbox.x1));
    }
    drop(front);
    // Frame 0 and every third frame after it.
    assert_eq!(seen.lock().unwrap().len(), 14);
    // Detection n (1-based) of frame 3(n-1) is in use from frame 3(n-1) + 2 on (the first at once).
    for (i, x1) in objects.iter().enumerate() {
        let n = if i < 5 { 1 } else { (i - 2) / 3 + 1 };
        assert_eq!(*x1, Some(20.0 + n as f32), "frame {i}: {objects:?}");
    }
}

/// On a schedule of frames, a frame that needs its own boxes (a monocular map starting) is
/// detected and waits for them, whatever was with the detector; once no frame asks, the
/// schedule goes on from there.
#[test]
fn a_frame_that_needs_its_own_boxes_waits_for_them_on_a_schedule() {
    use std::sync::{Arc, Mutex};
    let seen = Arc::new(Mutex::new(Vec::new()));
    // A detection is marked with the frame it was made on.
    let mut front = on_a_schedule(MarkedChair(Arc::clone(&seen), |input, _| input.index));
    let gray = Gray8::new(96, 64, 0);
    let own = 10..17;
    let mut detected_on = Vec::new();
    for i in 0..30 {
        let judged = front.judge(&plain_frame(i, &gray, own.contains(&i)), &[]);
        let x1 = judged.objects.tracked.first().map(|o| o.bbox.x1);
        detected_on.push(x1.map(|x| (x - 20.0).round() as usize));
    }
    drop(front);
    for (i, d) in detected_on.iter().enumerate() {
        let d = d.unwrap_or_else(|| panic!("frame {i} has no box: {detected_on:?}"));
        if own.contains(&i) {
            assert_eq!(d, i, "frame {i}: {detected_on:?}");
        } else {
            // Carried from a detection at most `every + lag - 1` frames old, never a later one.
            assert!(d <= i && i - d <= 4, "frame {i}: {detected_on:?}");
        }
    }
    // The schedule before and after, each frame asking for its own in between; frame 9's
    // detection was taken when frame 10 asked.
    let seen = seen.lock().unwrap().clone();
    let expected: Vec<usize> = [0, 3, 6, 9]
        .into_iter()
        .chain(own.clone())
        .chain((18..30).step_by(3))
        .collect();
    assert_eq!(seen, expected);
}

/// A recording's reader offers each frame to the detector as it decodes it, ahead of the
/// front-end: every frame gets the boxes it gets without the offers, frames that ask for their
/// own included, however far ahead the offers come.
#[test]
fn frames_offered_ahead_get_the_boxes_they_get_without() {
    use std::sync::{Arc, Mutex};
    let run = |ahead: Option<usize>| {
        let seen = Arc::new(Mutex::new(Vec::new()));
        let mut front = on_a_schedule(MarkedChair(Arc::clone(&seen), |input, _| input.index));
        let prefetch = front.detection_prefetch();
        assert!(prefetch.is_some());
        let gray = Gray8::new(96, 64, 0);
        let own = 10..17;
        let mut boxes = Vec::new();
        for i in 0..40 {
            if let (Some(p), Some(ahead)) = (&prefetch, ahead) {
                for j in i..=i + ahead {
                    p.offer(j, j as f64 / 30.0, &gray, None);
                }
            }
            let judged = front.judge(&plain_frame(i, &gray, own.contains(&i)), &[]);
            boxes.push(judged.objects.tracked.first().map(|o| o.bbox.x1));
        }
        drop(front);
        let seen = seen.lock().unwrap().clone();
        (boxes, seen)
    };
    let (without, seen_without) = run(None);
    assert!(without.iter().all(Option::is_some), "{without:?}");
    for ahead in [0, 1, 2, 5] {
        let (with, seen_with) = run(Some(ahead));
        assert_eq!(with, without, "offered {ahead} ahead");
        // Each frame detected once; the scheduled ones the front-end skipped (12, 15: frames
        // asking for their own held the detector) are detected too, ahead.
        let mut once = seen_with.clone();
        once.sort_unstable();
        once.dedup();
        assert_eq!(
            once.len(),
            seen_with.len(),
            "offered {ahead} ahead: {seen_with:?}"
        );
        // (What was handed over for frames after the last one taken may be skipped when the
        // front-end is dropped.)
        let taken = |f: &&usize| **f + 2 < 40;
        assert!(
            seen_without
                .iter()
                .filter(taken)
                .all(|f| seen_with.contains(f)),
            "offered {ahead} ahead: {seen_with:?} against {seen_without:?}"
        );
    }
}

/// Ages (in frames) of the boxes each of 30 live frames at 60 Hz gets from a background
/// detector that finishes the detection of frame k only once the caller has started frame
/// k + 4, finding one box of `class_id` a frame.
fn box_ages_with_a_detector_behind(class_id: u16, settings: FrontEndSettings) -> Vec<f32> {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};
    struct Behind(Arc<AtomicUsize>, u16);
    impl Detector for Behind {
        fn detect(&mut self, input: &DetectInput) -> Result<Vec<Detection>, DetectError> {
            let frame = (input.timestamp * 60.0).round() as usize;
            while frame > 0 && self.0.load(Ordering::SeqCst) < frame + 4 {
                std::thread::yield_now();
            }
            // and then takes a while: a frame that does not wait for it goes on without it
            // (the ages asserted hold only because the frames wait)
            for _ in 0..20_000 {
                std::thread::yield_now();
            }
            Ok(vec![Detection {
                bbox: stillpoint_geometry::BBox::new(20.0 + frame as f32, 10.0, 60.0, 50.0),
                class_id: self.1,
                score: 0.9,
            }])
        }
        fn name(&self) -> &str {
            "behind"
        }
    }
    let started = Arc::new(AtomicUsize::new(0));
    let mut front =
        DynamicFrontEnd::new(Box::new(Behind(Arc::clone(&started), class_id)), settings)
            .detect_in_background()
            .unwrap();
    let gray = Gray8::new(96, 64, 0);
    let mut ages = Vec::new();
    for i in 0..30 {
        started.store(i, Ordering::SeqCst);
        let input = FrameInput {
            index: i,
            timestamp: i as f64 / 60.0,
            gray: &gray,
            rgb: None,
            depth: None,
            previous: None,
            own_boxes: false,
        };
        let judged = front.judge(&input, &[]);
        let detected = judged
            .objects
            .tracked
            .first()
            .map(|o| o.bbox.x1 - 20.0)
            .unwrap_or_else(|| panic!("frame {i}: no boxes"));
        ages.push(i as f32 - detected);
    }
    started.store(usize::MAX / 2, Ordering::SeqCst);
    drop(front);
    ages
}

/// Frame 1 is handed over and waited for at frame 5 (held 4 frames), frame 5 at frame 9, ...:
/// those frames get boxes 4 frames old, the frames between carry them (never older than 7);
/// without the wait they would age until the detection happened to be collected.
fn assert_waited_for_at_4_frames(ages: &[f32]) {
    for (i, &age) in ages.iter().enumerate() {
        assert!(age <= 7.0, "frame {i}: boxes {age} frames old: {ages:?}");
        if i >= 5 && (i - 5) % 4 == 0 {
            assert_eq!(age, 4.0, "frame {i}: {ages:?}");
        }
    }
}

/// Live, with a person in view, a detector that falls behind is waited for once the frame it
/// holds was handed over more than `background_detect_max_wait_s` ago: no frame goes on with
/// older boxes (a starved machine drops frames instead of mapping the person).
#[test]
fn a_live_detector_that_falls_behind_is_waited_for() {
    let settings = FrontEndSettings {
        detector_in_background: true,
        background_detect_every_frames: 0,
        background_detect_interval_s: 0.0,
        // 60 Hz: a detection held 4 frames (0.067 s) is waited for, 3 (0.05 s) is not
        background_detect_max_wait_s: 0.06,
        background_detect_max_wait_without_mover_s: 0.0,
        ..Default::default()
    };
    assert_waited_for_at_4_frames(&box_ages_with_a_detector_behind(
        crate::PERSON_CLASS,
        settings,
    ));
}

/// Live, with no mover in the newest boxes, a detector that falls behind gets a slice of each
/// frame once the frame it holds was handed over more than
/// `background_detect_max_wait_without_mover_s` ago (someone may have come into view): with a
/// slice longer than the detection, the frames get the same boxes as with a mover in view.
#[test]
fn a_live_detector_that_falls_behind_with_no_mover_in_view_gets_its_slices() {
    const CHAIR: u16 = 56;
    let settings = FrontEndSettings {
        detector_in_background: true,
        background_detect_every_frames: 0,
        background_detect_interval_s: 0.0,
        background_detect_max_wait_s: 0.0,
        background_detect_max_wait_without_mover_s: 0.06,
        // far longer than the detection takes once frame k + 4 started: no timing in the test
        background_detect_wait_slice_s: 60.0,
        ..Default::default()
    };
    assert!(!settings.dynamic.objects.movable_classes.contains(&CHAIR));
    assert_waited_for_at_4_frames(&box_ages_with_a_detector_behind(CHAIR, settings));
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
        let input = FrameInput {
            index: f.index,
            timestamp: f.timestamp,
            gray: &gray,
            rgb: None,
            depth: None,
            previous: None,
            own_boxes: false,
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
