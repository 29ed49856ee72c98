//! The front-end's plug-in point from outside the frontend crate: a front-end of this test's
//! own, which culls the keypoints of the image's left half and asks ORB to skip a box, sees
//! two calls a frame and nothing else, and the pipeline does what its judgement says.

use std::sync::{Arc, Mutex};

use stillpoint_frontend::{FrameInput, FrontEnd, Judgement, Regions};
use stillpoint_geometry::PinholeCamera;
use stillpoint_pipeline::{Pipeline, PipelineSettings};
use stillpoint_synth::{Preset, SynthConfig, WriteOptions, write_sequence};

/// Where ORB is asked to keep no corner, `[x1, y1, x2, y2]`.
const SKIP: [f32; 4] = [400.0, 100.0, 560.0, 300.0];

#[derive(Default)]
struct Calls {
    started: Vec<PinholeCamera>,
    /// Per frame index: (measure calls, judge calls).
    per_frame: Vec<(usize, usize)>,
    /// Per frame: the index of the previous frame its input named.
    previous: Vec<Option<usize>>,
}

struct LeftHalfFrontEnd {
    calls: Arc<Mutex<Calls>>,
}

impl LeftHalfFrontEnd {
    fn count(&self, index: usize, measure: bool) {
        let mut calls = self.calls.lock().unwrap();
        if calls.per_frame.len() <= index {
            calls.per_frame.resize(index + 1, (0, 0));
        }
        let c = &mut calls.per_frame[index];
        if measure { c.0 += 1 } else { c.1 += 1 }
    }
}

impl FrontEnd for LeftHalfFrontEnd {
    fn start(&mut self, camera: PinholeCamera) {
        self.calls.lock().unwrap().started.push(camera);
    }

    fn measure(&mut self, frame: &FrameInput) {
        self.count(frame.index, true);
        let previous = frame.previous.map(|p| p.index);
        self.calls.lock().unwrap().previous.push(previous);
    }

    fn judge(&mut self, frame: &FrameInput, keypoints: &[[f32; 2]]) -> Judgement {
        self.count(frame.index, false);
        let half = frame.gray.width as f32 / 2.0;
        Judgement {
            dynamic: keypoints.iter().map(|k| k[0] < half).collect(),
            skip_next: Regions::new(vec![(SKIP, None)], &Default::default(), false),
            ..Default::default()
        }
    }
}

/// The static synthetic sequence of `frames` frames written into `dir` and opened; without
/// `depth` its depth.txt is removed, so that the folder reads monocular.
fn static_sequence(
    dir: &std::path::Path,
    frames: usize,
    depth: bool,
) -> Box<dyn stillpoint_datasets::Sequence> {
    let config = SynthConfig {
        preset: Preset::Static,
        frames,
        ..SynthConfig::default()
    };
    write_sequence(&config, WriteOptions::default(), dir).unwrap();
    if !depth {
        std::fs::remove_file(dir.join("depth.txt")).unwrap();
    }
    stillpoint_datasets::open(dir, None, None).unwrap()
}

#[test]
fn a_front_end_is_called_twice_a_frame_and_its_judgement_is_kept() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = static_sequence(tmp.path(), 6, true);
    let mut settings = PipelineSettings::from_dataset(seq.settings());
    settings.slam.local_mapping_thread = false;
    let calls = Arc::new(Mutex::new(Calls::default()));
    let front_end = LeftHalfFrontEnd {
        calls: calls.clone(),
    };
    let width = seq.frame(0).unwrap().gray.width;
    let mut slam = Pipeline::new(settings, Some(Box::new(front_end)), None);
    for i in 0..seq.len() {
        let frame = seq.frame(i).unwrap();
        let r = slam.track(&frame).unwrap();
        let half = frame.gray.width as f32 / 2.0;
        let left: Vec<bool> = r.keypoints.iter().map(|k| k[0] < half).collect();
        assert_eq!(
            r.dynamic, left,
            "frame {i}: the judgement is the pipeline's"
        );
        assert!(
            r.culled() > 0 && r.culled() < r.keypoints.len(),
            "frame {i}"
        );
        // From the second frame on, ORB skips the box the last judgement named (the pixels in
        // it at the depth of its centre: the region has no depth band of its own).
        match (i, &r.excluded) {
            (0, None) => {}
            (0, Some(_)) => panic!("the first frame has no judgement before it"),
            (_, None) => panic!("frame {i}: no mask from the last judgement"),
            (_, Some(mask)) => {
                let (mut inside, mut outside) = (0, 0);
                for y in 0..mask.height {
                    for x in 0..mask.width {
                        if mask.get(x, y) > 0 {
                            let (x, y) = (x as f32, y as f32);
                            let in_box =
                                (SKIP[0]..SKIP[2]).contains(&x) && (SKIP[1]..SKIP[3]).contains(&y);
                            if in_box { inside += 1 } else { outside += 1 }
                        }
                    }
                }
                assert!(
                    inside > 0 && outside == 0,
                    "frame {i}: {inside} in, {outside} out"
                );
                let on_mask = r
                    .keypoints
                    .iter()
                    .filter(|k| mask.get(k[0] as usize, k[1] as usize) > 0)
                    .count();
                assert_eq!(
                    on_mask, 0,
                    "frame {i}: ORB kept corners where it was told not to"
                );
            }
        }
        assert!(r.pose_wc.is_some(), "frame {i} tracked on the right half");
    }
    let calls = calls.lock().unwrap();
    assert_eq!(calls.started.len(), 1, "started once");
    assert_eq!(calls.started[0].width as usize, width);
    assert_eq!(
        calls.per_frame,
        vec![(1, 1); seq.len()],
        "one measure and one judge a frame"
    );
    let expected: Vec<Option<usize>> = (0..seq.len()).map(|i| i.checked_sub(1)).collect();
    assert_eq!(calls.previous, expected, "each frame names the one before");
}

/// How much of the image's width, from the left, `WideSkipFrontEnd` asks ORB to skip.
const SKIPPED_SHARE: f32 = 0.9;

/// Culls nothing and asks ORB to skip the image's left nine tenths, giving way below
/// `min_yield` of ORB's budget.
struct WideSkipFrontEnd {
    min_yield: f32,
}

impl FrontEnd for WideSkipFrontEnd {
    fn start(&mut self, _camera: PinholeCamera) {}

    fn measure(&mut self, _frame: &FrameInput) {}

    fn judge(&mut self, frame: &FrameInput, keypoints: &[[f32; 2]]) -> Judgement {
        let (w, h) = (frame.gray.width as f32, frame.gray.height as f32);
        let region = ([0.0, 0.0, SKIPPED_SHARE * w, h], None);
        Judgement {
            dynamic: vec![false; keypoints.len()],
            skip_next: Regions::new(vec![region], &Default::default(), false)
                .with_min_yield(self.min_yield),
            ..Default::default()
        }
    }
}

/// A monocular run of a static sequence behind `WideSkipFrontEnd`: per frame once its map
/// stands, (the mask in force, keypoints found in the skipped part, of those free to make map
/// points).
fn wide_skip_run(
    seq: &dyn stillpoint_datasets::Sequence,
    min_yield: f32,
) -> Vec<(bool, usize, usize)> {
    let mut settings = PipelineSettings::from_dataset(seq.settings());
    assert!(settings.slam.monocular);
    settings.slam.local_mapping_thread = false;
    // The mask applies from the map's first frame on (a young map takes every corner).
    settings.slam.mono_init.young_map_seconds = 0.0;
    let front_end = WideSkipFrontEnd { min_yield };
    let mut slam = Pipeline::new(settings, Some(Box::new(front_end)), None);
    let mut out = Vec::new();
    for i in 0..seq.len() {
        let frame = seq.frame(i).unwrap();
        let r = slam.track(&frame).unwrap();
        if r.pose_wc.is_none() {
            continue;
        }
        let skip = SKIPPED_SHARE * frame.gray.width as f32;
        let inside: Vec<usize> = (0..r.keypoints.len())
            .filter(|&i| r.keypoints[i][0] < skip - 1.0)
            .collect();
        let barred = |i: usize| r.no_new_points.get(i).copied().unwrap_or(false);
        let may_map = inside.iter().filter(|&&i| !barred(i)).count();
        out.push((r.excluded.is_some(), inside.len(), may_map));
    }
    out
}

#[test]
fn a_budget_mask_without_depth_that_leaves_orb_short_gives_way() {
    let tmp = tempfile::tempdir().unwrap();
    // Monocular: the mask is the whole region.
    let seq = static_sequence(tmp.path(), 40, false);

    // Never giving way: the map's frames find nothing in the skipped nine tenths.
    let kept = wide_skip_run(seq.as_ref(), 0.0);
    let masked: Vec<_> = kept.iter().filter(|(mask, _, _)| *mask).collect();
    assert!(masked.len() >= 5, "{kept:?}");
    assert!(
        masked.iter().all(|&&(_, inside, _)| inside == 0),
        "{kept:?}"
    );

    // The tenth left cannot take 75 % of the budget: on every such frame the rest goes to the
    // skipped part, whose keypoints are tracked but make no map points (the first frame of the
    // map, extracted whole while the map started, excepted).
    let given_way = wide_skip_run(seq.as_ref(), 0.75);
    assert!(given_way.len() >= 5, "{given_way:?}");
    assert!(
        given_way
            .iter()
            .all(|&(mask, inside, _)| !mask && inside > 0),
        "{given_way:?}"
    );
    assert!(
        given_way[1..].iter().all(|&(_, _, may_map)| may_map == 0),
        "{given_way:?}"
    );
}
