//! The pipeline on a synthetic walking sequence written in-process: with the dynamic front-end
//! and ground-truth boxes it tracks every frame accurately and reports per-keypoint labels; the
//! baseline on the same frames is pulled by the walkers.

use stillpoint_detect::{GtDetectorParams, open_detector};
use stillpoint_frontend::{DynamicFrontEnd, FrontEndSettings};
use stillpoint_pipeline::{Pipeline, PipelineSettings};
use stillpoint_synth::{Preset, SynthConfig, WriteOptions, write_sequence};
use stillpoint_trajectory::{Alignment, AteOptions, Trajectory, ate, read_tum};

fn run(dir: &std::path::Path, with_front_end: bool) -> (f64, usize, usize) {
    let seq = stillpoint_datasets::open(dir, None, None).unwrap();
    let mut settings = PipelineSettings::from_dataset(seq.settings());
    settings.slam.local_mapping_thread = false;
    let front_end = with_front_end.then(|| {
        let boxes = seq.boxes();
        let detector = open_detector(
            "gt",
            &Default::default(),
            boxes.as_deref(),
            GtDetectorParams::default(),
        )
        .unwrap();
        DynamicFrontEnd::new(detector, FrontEndSettings::default())
    });
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
    let (on, tracked, culled) = run(tmp.path(), true);
    let (off, _, none_culled) = run(tmp.path(), false);
    eprintln!(
        "ATE front-end on {:.2} cm, off {:.2} cm",
        on * 100.0,
        off * 100.0
    );
    assert_eq!(tracked, 90);
    assert!(culled > 90 * 50, "{culled} keypoints culled");
    assert_eq!(none_culled, 0);
    assert!(on < 0.02, "ATE {on}");
    assert!(off > 2.0 * on, "off {off} on {on}");
}
