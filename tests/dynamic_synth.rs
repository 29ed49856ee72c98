//! Cross-crate scenario for the dynamic front-end: a synthetic walking sequence rendered in
//! process, the geometry module between consecutive frames, NHBC/ATA on the ground-truth boxes,
//! and culling of ORB keypoints, scored against the per-pixel dynamic mask.

use stillpoint_detect::Detection;
use stillpoint_dynamic::{
    CullParams, DynamicSettings, MotionModel, Verdict, cull_frame, cull_with, judge_boxes,
    motion_consistency,
};
use stillpoint_features::{OrbExtractor, OrbParams};
use stillpoint_image::rgb_to_gray;
use stillpoint_synth::{Preset, SynthConfig, generate};

#[test]
fn walking_people_under_a_still_camera_are_found_and_culled() {
    let config = SynthConfig {
        preset: Preset::WalkingStatic,
        frames: 4,
        ..Default::default()
    };
    let frames: Vec<_> = generate(&config).expect("synth").collect();
    let settings = DynamicSettings::default();
    let everything = CullParams {
        static_box_protects: false,
        unknown_box_protects: false,
        ..CullParams::default()
    };
    let mut orb = OrbExtractor::new(OrbParams::default());
    let (mut truly_dynamic, mut found, mut static_kept, mut static_total) = (0, 0, 0, 0);
    // The same for the depth-aware culling (ours, RGB-D).
    let (mut found_depth, mut static_kept_depth) = (0, 0);
    for pair in frames.windows(2) {
        let (prev, cur) = (rgb_to_gray(&pair[0].rgb), rgb_to_gray(&pair[1].rgb));
        let check = motion_consistency(&prev, &cur, &settings.geometry);
        // The synthetic walking_static camera barely moves: the homography judges, not a
        // degenerate F that could align its epipolar lines with the walkers.
        assert_eq!(
            check.model,
            MotionModel::Homography,
            "{:?}",
            check.fallback_reason
        );
        let dets: Vec<Detection> = pair[1]
            .boxes
            .iter()
            .map(|b| Detection {
                class_id: b.class_id,
                score: 1.0,
                bbox: b.bbox,
            })
            .collect();
        let states = judge_boxes(&dets, &check.points, &settings.judge);
        // Every clearly visible walking person is judged dynamic (NHBC: >= 1 outlier inside).
        for (i, b) in pair[1].boxes.iter().enumerate() {
            if b.class_id == 0 && b.moving && b.visible_fraction > 0.5 && b.bbox.area() > 5000.0 {
                let dynamic = states
                    .iter()
                    .any(|s| s.detection == i && s.verdict == Verdict::Dynamic);
                assert!(
                    dynamic,
                    "walking person {} judged static: {states:?}",
                    b.object
                );
            }
        }
        let kps: Vec<[f32; 2]> = orb
            .extract(&cur)
            .keypoints
            .iter()
            .map(|k| [k.x, k.y])
            .collect();
        let removed = cull_with(&kps, &states, &check.points, &everything);
        let mut depth_states = states.clone();
        let removed_depth = cull_frame(
            &kps,
            &mut depth_states,
            &check.points,
            Some(&pair[1].depth),
            &settings,
        );
        let mask = &pair[1].dynamic_mask;
        for ((k, r), rd) in kps.iter().zip(&removed).zip(&removed_depth) {
            let (x, y) = (k[0].round() as usize, k[1].round() as usize);
            if x < mask.width && y < mask.height && mask.get(x, y) > 0 {
                truly_dynamic += 1;
                found += usize::from(*r);
                found_depth += usize::from(*rd);
            } else {
                static_total += 1;
                static_kept += usize::from(!*r);
                static_kept_depth += usize::from(!*rd);
            }
        }
    }
    let recall = found as f64 / truly_dynamic.max(1) as f64;
    assert!(
        truly_dynamic > 100 && recall >= 0.95,
        "recall {recall} of {truly_dynamic}"
    );
    // Box-level culling also removes the background inside the boxes (about half a person's box).
    let kept = static_kept as f64 / static_total.max(1) as f64;
    // Depth-aware culling keeps the background seen past the walkers at nearly the same recall.
    let recall_depth = found_depth as f64 / truly_dynamic.max(1) as f64;
    let kept_depth = static_kept_depth as f64 / static_total.max(1) as f64;
    eprintln!(
        "box level: recall {recall:.3} kept {kept:.3}; depth-aware: recall {recall_depth:.3} kept {kept_depth:.3}"
    );
    assert!(kept > 0.2, "kept {kept} of {static_total} static keypoints");
    assert!(
        recall_depth >= 0.9 && kept_depth > kept + 0.2,
        "depth-aware: recall {recall_depth}, kept {kept_depth} (box level {kept})"
    );
}
