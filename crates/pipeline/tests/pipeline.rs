//! The pipeline on a synthetic walking sequence written in-process: with the dynamic front-end
//! and ground-truth boxes it tracks every frame accurately and reports per-keypoint labels; the
//! baseline on the same frames is pulled by the walkers.

use stillpoint_detect::{GtDetectorParams, open_detector};
use stillpoint_frontend::{DynamicFrontEnd, FrontEnd, FrontEndSettings};
use stillpoint_pipeline::{Pipeline, PipelineSettings};
use stillpoint_synth::{Preset, SynthConfig, WriteOptions, write_sequence};
use stillpoint_trajectory::{Alignment, AteOptions, Trajectory, ate, read_tum};

/// The dynamic front-end on the sequence's own boxes (`boxes.jsonl`).
fn gt_front_end(seq: &dyn stillpoint_datasets::Sequence, s: FrontEndSettings) -> Box<dyn FrontEnd> {
    let boxes = seq.boxes();
    let detector = open_detector(
        "gt",
        &Default::default(),
        boxes.as_deref(),
        GtDetectorParams::default(),
    )
    .unwrap();
    Box::new(DynamicFrontEnd::new(detector, s))
}

fn run(dir: &std::path::Path, with_front_end: bool) -> (f64, usize, usize) {
    let seq = stillpoint_datasets::open(dir, None, None).unwrap();
    let mut settings = PipelineSettings::from_dataset(seq.settings());
    settings.slam.local_mapping_thread = false;
    let front_end = with_front_end.then(|| gt_front_end(seq.as_ref(), FrontEndSettings::default()));
    let mut slam = Pipeline::new(settings, front_end, None);
    let mut culled = 0;
    for i in 0..seq.len() {
        let r = slam.track(&seq.frame(i).unwrap()).unwrap();
        assert_eq!(r.keypoints.len(), r.dynamic.len());
        assert!(r.no_new_points.is_empty() || r.no_new_points.len() == r.keypoints.len());
        culled += r.culled();
    }
    let fin = slam.finish().unwrap();
    let gt: Trajectory = read_tum(&seq.ground_truth().unwrap()).unwrap();
    let opts = AteOptions {
        align: Alignment::Se3,
        ..AteOptions::default()
    };
    let a = ate(&gt, &fin.trajectory, &opts).unwrap();
    assert!(fin.keyframes > 0 && !fin.keyframe_trajectory.is_empty());
    (a.stats.rmse, fin.trajectory.len(), culled)
}

#[test]
fn the_front_end_keeps_walkers_out_and_the_baseline_is_pulled() {
    let tmp = tempfile::tempdir().unwrap();
    let config = SynthConfig {
        preset: Preset::WalkingXyz,
        frames: 90,
        ..SynthConfig::default()
    };
    write_sequence(&config, WriteOptions::default(), tmp.path()).unwrap();
    // Side by side: two runs for the machine's two cores.
    let ((on, tracked, culled), (off, _, none_culled)) = std::thread::scope(|s| {
        let on = s.spawn(|| run(tmp.path(), true));
        let off = run(tmp.path(), false);
        (on.join().unwrap(), off)
    });
    eprintln!(
        "ATE front-end on {:.2} cm, off {:.2} cm",
        on * 100.0,
        off * 100.0
    );
    assert_eq!(tracked, 90);
    // ORB's budget keeps most of the walkers' corners from being extracted at all; what it
    // leaves on them is culled.
    assert!(culled > 90 * 30, "{culled} keypoints culled");
    assert_eq!(none_culled, 0);
    assert!(on < 0.02, "ATE {on}");
    // The walkers pull tracking; settling each frame on the final map puts most of that right
    // in the written trajectory, so the gap left is small but there.
    assert!(off > on, "off {off} on {on}");
}

/// With true poses, the dense cloud of a walking sequence lies on the scene's static surfaces and
/// nothing of it on the walkers: what a run's cloud loses against this is its poses' error.
#[test]
fn with_true_poses_the_dense_cloud_lies_on_the_static_scene() {
    use stillpoint_eval::surface::{SurfaceGrid, cloud_to_surface};
    use stillpoint_pipeline::dense::{DenseFusion, DenseSettings};
    let cfg = SynthConfig {
        preset: Preset::WalkingXyz,
        frames: 40,
        ..SynthConfig::default()
    };
    let g = stillpoint_synth::Generator::new(&cfg).unwrap();
    let mut fusion = DenseFusion::new(DenseSettings::default(), cfg.camera);
    let mut poses = Vec::new();
    for i in (0..cfg.frames).step_by(8) {
        let f = g.frame(i);
        fusion.add_keyframe(
            f.timestamp,
            &f.depth,
            Some(&f.rgb),
            Some(&f.dynamic_mask),
            Some(&f.dynamic_mask),
        );
        poses.push((f.timestamp, f.pose_wc));
    }
    let cloud = fusion.fuse(|t| poses.iter().find(|p| p.0 == t).map(|p| p.1));
    assert!(cloud.len() > 10_000, "{}", cloud.len());
    assert!(cloud.iter().all(|p| !p.on_mover));
    let surface = SurfaceGrid::new(g.static_triangles(), 0.1, 0.1);
    let points: Vec<_> = cloud.iter().map(|p| p.position).collect();
    let d = cloud_to_surface(&points, &surface);
    // Voxel means of samples on a plane lie on it; at corners and edges a voxel straddles two.
    assert!(d.median_m < 1e-3 && d.within_1cm > 0.99, "{d:?}");
}

/// Monocular (the walking sequence with its depth withheld), gt boxes: culled keypoints matched
/// to map points and kept by the pose, and of those on a walker (the generator's masks), over
/// the run; `offer_below` is `front_end.offer_culled_to_map_below`.
fn monocular_culled_matches(dir: &std::path::Path, offer_below: f32) -> (usize, usize, usize) {
    let seq = stillpoint_datasets::open(dir, None, None).unwrap();
    let mut settings = PipelineSettings::from_dataset(seq.settings());
    settings.slam.local_mapping_thread = false;
    let front_end = FrontEndSettings {
        offer_culled_to_map_below: offer_below,
        ..FrontEndSettings::default()
    };
    let mut slam = Pipeline::new(settings, Some(gt_front_end(seq.as_ref(), front_end)), None);
    let (mut matched, mut on_walkers, mut tracked) = (0, 0, 0);
    for i in 0..seq.len() {
        let frame = seq.frame(i).unwrap();
        let r = slam.track(&frame).unwrap();
        tracked += usize::from(r.pose_wc.is_some());
        if r.culled_matched() == 0 {
            continue;
        }
        matched += r.culled_matched();
        let mask = stillpoint_image::read_gray(
            &dir.join("mask").join(format!("{:.6}.png", frame.timestamp)),
        )
        .unwrap();
        on_walkers += r
            .keypoints
            .iter()
            .zip(r.dynamic.iter().zip(&r.matched))
            .filter(|(k, (d, m))| **d && **m && mask.get(k[0] as usize, k[1] as usize) > 0)
            .count();
    }
    (matched, on_walkers, tracked)
}

#[test]
fn monocular_culled_keypoints_match_the_static_map_only() {
    let tmp = tempfile::tempdir().unwrap();
    let config = SynthConfig {
        preset: Preset::WalkingXyz,
        frames: 60,
        ..SynthConfig::default()
    };
    let options = WriteOptions {
        masks: true,
        ..WriteOptions::default()
    };
    write_sequence(&config, options, tmp.path()).unwrap();
    std::fs::remove_file(tmp.path().join("depth.txt")).unwrap();
    let ((offered, on_walkers, tracked), (never, _, _)) = std::thread::scope(|s| {
        let offered = s.spawn(|| monocular_culled_matches(tmp.path(), 1.0));
        let never = monocular_culled_matches(tmp.path(), 0.0);
        (offered.join().unwrap(), never)
    });
    eprintln!("culled keypoints matched: {offered}, on walkers {on_walkers}; tracked {tracked}");
    assert!(tracked >= 50, "{tracked} frames tracked");
    assert!(
        offered > 100,
        "{offered} culled keypoints matched to the map"
    );
    assert!(
        on_walkers * 20 <= offered,
        "{on_walkers} of {offered} on the walkers"
    );
    assert_eq!(never, 0, "offer_culled_to_map_below = 0 offers none");
}
