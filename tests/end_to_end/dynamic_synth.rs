//! Cross-crate scenario for the dynamic front-end: a synthetic walking sequence rendered in
//! process, the geometry module between consecutive frames, NHBC/ATA on the ground-truth boxes,
//! and culling of ORB keypoints, scored against the per-pixel dynamic mask.

use stillpoint_detect::Detection;
use stillpoint_dynamic::{
    CullParams, DynamicSettings, MotionModel, Verdict, cull_frame, cull_frame_with_motion,
    cull_with, judge_boxes, motion_consistency_pyramids,
};
use stillpoint_features::{LkPyramid, OrbExtractor, OrbParams};
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
    // ... and with each keypoint's own motion evidence (ours, the default front-end step).
    let (mut found_kp, mut static_kept_kp) = (0, 0);
    for pair in frames.windows(2) {
        let (prev, cur) = (rgb_to_gray(&pair[0].rgb), rgb_to_gray(&pair[1].rgb));
        // Each pyramid is built once; a streaming caller keeps the current one for the next frame.
        let prev_pyr = LkPyramid::new(&prev, &settings.geometry.lk);
        let cur_pyr = LkPyramid::new(&cur, &settings.geometry.lk);
        let check =
            motion_consistency_pyramids(&prev, &cur, &prev_pyr, &cur_pyr, &settings.geometry);
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
        let mut kp_states = states.clone();
        let removed_kp = cull_frame_with_motion(
            &kps,
            &mut kp_states,
            &check,
            Some(&pair[1].depth),
            Some((&prev_pyr, &cur_pyr)),
            &settings,
        );
        // The evidence only ever keeps keypoints the boxes would cull.
        assert!(removed_kp.iter().zip(&removed_depth).all(|(k, d)| !k || *d));
        let mask = &pair[1].dynamic_mask;
        for (((k, r), rd), rk) in kps
            .iter()
            .zip(&removed)
            .zip(&removed_depth)
            .zip(&removed_kp)
        {
            let (x, y) = (k[0].round() as usize, k[1].round() as usize);
            if x < mask.width && y < mask.height && mask.get(x, y) > 0 {
                truly_dynamic += 1;
                found += usize::from(*r);
                found_depth += usize::from(*rd);
                found_kp += usize::from(*rk);
            } else {
                static_total += 1;
                static_kept += usize::from(!*r);
                static_kept_depth += usize::from(!*rd);
                static_kept_kp += usize::from(!*rk);
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
    let recall_kp = found_kp as f64 / truly_dynamic.max(1) as f64;
    let kept_kp = static_kept_kp as f64 / static_total.max(1) as f64;
    eprintln!(
        "box level: recall {recall:.3} kept {kept:.3}; depth-aware: recall {recall_depth:.3} kept {kept_depth:.3}; with keypoint evidence: recall {recall_kp:.3} kept {kept_kp:.3}"
    );
    assert!(
        recall_kp >= 0.9 && kept_kp >= kept_depth,
        "keypoint evidence: recall {recall_kp}, kept {kept_kp} (depth-aware {kept_depth})"
    );
    assert!(kept > 0.2, "kept {kept} of {static_total} static keypoints");
    assert!(
        recall_depth >= 0.9 && kept_depth > kept + 0.2,
        "depth-aware: recall {recall_depth}, kept {kept_depth} (box level {kept})"
    );
}
