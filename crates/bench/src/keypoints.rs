//! Precision and recall of the dynamic-keypoint decision against the ground-truth masks of a
//! synthetic sequence (`stillpoint synth --masks`), for the paper (geometry + NHBC/ATA +
//! algorithm 3) and variants of it, our depth-aware culling for RGB-D (`ours_depth`, when the
//! sequence has depth), with the per-keypoint motion evidence (`ours_depth+kp`), what `stillpoint
//! run` decides (`ours`: a run of the sequence with the same settings tree, in run's default
//! mode, scored on that run's own keypoints; keypoints it keeps as track-only count as not
//! culled, and what an extraction without the feature budget finds where the run kept no
//! corner counts as culled), a person-box-only baseline (Crowd-SLAM: cull everything in person boxes) and a
//! detection-free baseline (epipolar outliers only, dilated to a radius). Also times the
//! geometry module per frame, as a ratio to ORB extraction of the same frames.
//!
//! Ground truth, three ways (all reported; [`stillpoint_eval::keypoints`]): strict, occlusion
//! (`support_*`) and clear. Frame 0 has no previous frame and is skipped by every method.

use std::io::Write;
use std::path::{Path, PathBuf};

use serde::Serialize;
use stillpoint_detect::{DetectInput, DetectSettings, GtDetectorParams, open_detector};
use stillpoint_dynamic::{
    BoxState, CullParams, DynamicSettings, MotionModel, apply_keypoint_motion, cull_frame,
    cull_frame_with_motion, cull_with, in_dynamic_box, judge_boxes, keypoint_motion,
    motion_consistency_pyramids, near_outliers,
};
use stillpoint_eval::keypoints::{
    Counts, clear_truth, fast_test_moving, mask_frames, strict_truth, support_truth,
};
use stillpoint_eval::{mean, median};
use stillpoint_features::{KeyPoint, LkPyramid, OrbExtractor, OrbParams};
use stillpoint_image::{Gray8, read_gray};
use stillpoint_run::{Event, Overrides, RunOptions, settings_layers};

use crate::BenchError;

/// The rows of the report: the paper (algorithms 1 and 3 as published) and variants of it, our
/// depth-aware culling alone and with the per-keypoint evidence, what `run` decides (`ours`),
/// and the two baselines.
pub const METHODS: [&str; 9] = [
    "paper",
    "paper+unknown",
    "paper_no_protect",
    "paper_ata_own_points",
    "ours_depth",
    "ours_depth+kp",
    "ours",
    "person_boxes",
    "outliers_only",
];

/// What is measured, on which sequence.
#[derive(Clone, Debug)]
pub struct KeypointOptions {
    /// A synthetic sequence written with masks (rgb.txt, rgb/, mask/, boxes.jsonl).
    pub dataset: PathBuf,
    /// Boxes from: gt (boxes.jsonl), yolox (the ONNX model), none.
    pub detector: String,
    /// YOLOX ONNX model for the yolox detector (else the default search).
    pub model: Option<PathBuf>,
    /// Radius in pixels of the detection-free baseline's dilation around outliers.
    pub radius: f32,
    /// A keypoint is truly dynamic (strict truth) with a moving mask pixel this close.
    pub gt_radius: usize,
    /// The settings tree's layers over the sequence's own settings (`--config`, `--set`), as
    /// `run` takes them: `ours` is a run with them, and every other row takes its dynamic
    /// settings (`front_end.dynamic`) from the same tree; the paper's rows with the paper's
    /// judgement (no sub-pixel person rule) and culling (no unknown objects).
    pub overrides: Overrides,
    /// Use the sequence's depth (else ours_depth culls by the paper's rule, and `ours` runs the
    /// sequence monocular, from a temporary folder of links without the depth).
    pub use_depth: bool,
    /// Use at most this many frames (0: all).
    pub max_frames: usize,
    /// Write one CSV line per keypoint inside a dynamic box (frame, x, y, octave, truth,
    /// support truth, depth-aware decision, residual, forward-backward error, model, seated).
    pub dump_keypoints: Option<PathBuf>,
}

/// One frame judged.
#[derive(Serialize)]
pub struct FrameReport {
    /// The frame's index.
    pub frame: usize,
    /// ORB keypoints judged.
    pub keypoints: usize,
    /// Of those, truly dynamic (strict).
    pub truly_dynamic: usize,
    /// The motion model the geometry module fitted.
    pub model: MotionModel,
    /// Corners the geometry module tracked from.
    pub corners: usize,
    /// Corners LK lost.
    pub lk_failed: usize,
    /// Tracks rejected at the border.
    pub border_rejected: usize,
    /// Tracks rejected by the patch check.
    pub patch_rejected: usize,
    /// Tracks kept.
    pub tracked: usize,
    /// Of those, geometric outliers.
    pub outliers: usize,
    /// The geometry module's time, ms.
    pub geometry_ms: f64,
    /// Strict counts per method ([`METHODS`] order).
    pub counts: Vec<Counts>,
    /// The dynamic boxes of ours_depth, with their object depth (not in the JSON).
    #[serde(skip)]
    pub dynamic_boxes: Vec<BoxState>,
}

/// One method over the sequence.
#[derive(Serialize)]
pub struct MethodReport {
    /// The method ([`METHODS`]).
    pub method: &'static str,
    /// Against the strict ground truth.
    pub counts: Counts,
    /// Strict precision.
    pub precision: Option<f64>,
    /// Strict recall.
    pub recall: Option<f64>,
    /// The same against the occlusion ground truth.
    pub support_counts: Counts,
    /// Occlusion precision.
    pub support_precision: Option<f64>,
    /// Occlusion recall.
    pub support_recall: Option<f64>,
    /// The same on the keypoints whose FAST circle does not straddle a moving silhouette.
    pub clear_counts: Counts,
    /// Clear precision.
    pub clear_precision: Option<f64>,
    /// Clear recall.
    pub clear_recall: Option<f64>,
}

/// The whole measurement.
#[derive(Serialize)]
pub struct KeypointReport {
    /// The sequence folder.
    pub dataset: String,
    /// The detector's name.
    pub detector: String,
    /// Frames judged.
    pub frames: usize,
    /// Frames that had a depth map (ours_depth is ours on the others).
    pub depth_frames: usize,
    /// Keypoints judged.
    pub keypoints: usize,
    /// Of those, the ones whose FAST circle straddles a moving silhouette (not scored by the
    /// clear metric).
    pub straddling: usize,
    /// Per method ([`METHODS`] order).
    pub methods: Vec<MethodReport>,
    /// Frames per motion model.
    pub models: Vec<(MotionModel, usize)>,
    /// The geometry module's mean time per frame, ms.
    pub geometry_ms_mean: f64,
    /// Its median, ms.
    pub geometry_ms_median: f64,
    /// Its stages' mean times (corners, LK, checks, model), ms.
    pub geometry_stage_ms_mean: [f64; 4],
    /// ORB extraction's mean time per frame, ms.
    pub orb_ms_mean: f64,
    /// Geometry over ORB.
    pub geometry_over_orb: f64,
    /// Our culling step ([`cull_frame_with_motion`]: depth-aware culling, unknown objects,
    /// per-keypoint evidence), mean milliseconds per frame.
    pub culling_ms_mean: f64,
    /// Keypoints `ours` culled over every frame of its run (frame 0 included): `run --json`'s
    /// `culled` on the same frames.
    pub ours_culled: usize,
    /// Frames `ours`'s run tracked.
    pub ours_tracked: usize,
    /// Keypoints an extraction without the feature budget finds on the pixels where `ours`'s
    /// run kept no corner (`front_end.orb_exclusion`): scored in `ours` as culled.
    pub ours_excluded: usize,
    /// The median share of the static keypoints (centre off the generator's mask) that `ours`'s
    /// run culled per frame: `run --json`'s `static_keypoints_culled_share`.
    pub ours_static_culled_median: Option<f64>,
    /// Per frame.
    pub per_frame: Vec<FrameReport>,
}

fn detect_err(context: String) -> impl FnOnce(stillpoint_detect::DetectError) -> BenchError {
    move |source| BenchError::Detect { context, source }
}

/// Judge every frame by every method and count against the masks.
pub fn evaluate(o: &KeypointOptions) -> Result<KeypointReport, BenchError> {
    let frames = mask_frames(&o.dataset)?;
    let n = if o.max_frames > 0 {
        o.max_frames.min(frames.len())
    } else {
        frames.len()
    };
    let boxes = o.dataset.join("boxes.jsonl");
    let detect_settings = DetectSettings {
        model: o.model.clone(),
        ..DetectSettings::default()
    };
    let mut detector = open_detector(
        &o.detector,
        &detect_settings,
        boxes.exists().then_some(boxes.as_path()),
        GtDetectorParams::default(),
    )
    .map_err(detect_err(format!("detector {:?}", o.detector)))?;
    // Frames, depth (with the sequence's depth factor) and their association as `run` reads them.
    let sequence = stillpoint_datasets::open(&o.dataset, None, None).map_err(|source| {
        BenchError::Dataset {
            context: format!("{}", o.dataset.display()),
            source,
        }
    })?;
    // One settings tree for every row: the one `run` builds for this sequence.
    let settings = settings_layers(sequence.settings(), None, false, &o.overrides)?
        .tree
        .front_end
        .dynamic;
    // The paper's judgement for every method but ours_depth.
    let paper_judge = stillpoint_dynamic::JudgeParams {
        person_subpixel_px: None,
        ..settings.judge.clone()
    };
    let mut depth_frames = 0usize;
    // The paper has no unknown-object rule; ours_depth and ours_depth+kp measure without it.
    let paper_cull = CullParams {
        unknown_objects: false,
        ..settings.cull.clone()
    };
    let no_protect = CullParams {
        static_box_protects: false,
        unknown_box_protects: false,
        ..paper_cull.clone()
    };
    let unknown = CullParams {
        unknown_objects: true,
        ..settings.cull.clone()
    };
    let depth_only = DynamicSettings {
        cull: paper_cull.clone(),
        ..settings.clone()
    };
    let ours = run_decisions(o, n)?;
    let mut orb = OrbExtractor::new(OrbParams::default());
    let scales = orb.scale_factors().to_vec();

    let mut totals = [Counts::default(); METHODS.len()];
    let mut support_totals = [Counts::default(); METHODS.len()];
    let mut clear_totals = [Counts::default(); METHODS.len()];
    let mut straddling = 0usize;
    let mut last_pyr = LkPyramid::default();
    let mut dump = match &o.dump_keypoints {
        Some(path) => Some(std::io::BufWriter::new(
            std::fs::File::create(path).map_err(crate::io_error(format!(
                "{}: cannot create",
                path.display()
            )))?,
        )),
        None => None,
    };
    let dump_error = || {
        crate::io_error(format!(
            "writing {}",
            o.dump_keypoints.clone().unwrap_or_default().display()
        ))
    };
    if let Some(w) = dump.as_mut() {
        writeln!(
            w,
            "frame,x,y,octave,truth,support,removed,residual,fb,model,seated"
        )
        .map_err(dump_error())?;
    }
    let mut per_frame = Vec::new();
    let (mut geometry_ms, mut orb_ms) = (Vec::new(), Vec::new());
    let mut ours_ms = Vec::new();
    let mut stages = [0.0f64; 4];
    let mut models: Vec<(MotionModel, usize)> = Vec::new();
    let mut prev: Option<Gray8> = None;
    let mut ours_excluded = 0usize;
    for (index, (t, mask_path)) in frames.iter().take(n).enumerate() {
        let frame = sequence
            .frame(index)
            .map_err(|source| BenchError::Dataset {
                context: format!("frame {index}"),
                source,
            })?;
        let gray = frame.gray;
        let rgb = frame
            .rgb
            .ok_or_else(|| BenchError::Invalid(format!("frame {index}: no colour image")))?;
        let depth = if o.use_depth { frame.depth } else { None };
        // Each frame's pyramid is built once and serves as the next frame's previous one.
        let prev_pyr =
            std::mem::replace(&mut last_pyr, LkPyramid::new(&gray, &settings.geometry.lk));
        let cur_pyr = &last_pyr;
        let Some(prev_gray) = prev.replace(gray.clone()) else {
            continue;
        };
        let mask = read_gray(mask_path).map_err(|source| BenchError::Image {
            context: format!("frame {index}: ground-truth mask (synth --masks)"),
            source,
        })?;
        if (mask.width, mask.height) != (gray.width, gray.height) {
            return Err(BenchError::Invalid(format!(
                "{}: mask size differs from the image",
                mask_path.display()
            )));
        }
        let clock = std::time::Instant::now();
        let features = orb.extract(&gray);
        orb_ms.push(stillpoint_core::ms_since(clock));
        let kps: Vec<[f32; 2]> = features.keypoints.iter().map(|k| [k.x, k.y]).collect();
        let truth = strict_truth(&mask, &kps, o.gt_radius);
        // The FAST test of each keypoint: how many of its 17 pixels are moving.
        let fast_moving = fast_test_moving(&mask, &features.keypoints, &scales);
        // Occlusion ground truth: a corner whose FAST circle touches the mover is formed by it.
        let support = support_truth(&fast_moving);
        // Clear ground truth: corners whose circle straddles a moving silhouette are not scored.
        let clear = clear_truth(&fast_moving);
        straddling += clear.iter().filter(|c| c.is_none()).count();

        let check =
            motion_consistency_pyramids(&prev_gray, &gray, &prev_pyr, cur_pyr, &settings.geometry);
        geometry_ms.push(check.timings.total_ms());
        let tm = check.timings;
        for (s, v) in stages
            .iter_mut()
            .zip([tm.corners_ms, tm.lk_ms, tm.checks_ms, tm.model_ms])
        {
            *s += v;
        }
        match models.iter_mut().find(|(m, _)| *m == check.model) {
            Some((_, c)) => *c += 1,
            None => models.push((check.model, 1)),
        }
        let dets = detector
            .detect(&DetectInput {
                index,
                timestamp: *t,
                rgb: &rgb,
            })
            .map_err(detect_err(format!("frame {index}: detector")))?;
        let states = judge_boxes(&dets, &check.points, &paper_judge);
        depth_frames += usize::from(depth.is_some());
        // Our judgement, once: culling fills in each state's depth, so `ours` gets a fresh copy.
        let our_judgement = judge_boxes(&dets, &check.points, &settings.judge);
        let mut depth_states = our_judgement.clone();
        let person = settings.judge.person_class;
        let own_judge = stillpoint_dynamic::JudgeParams {
            ata_ignores_person_points: true,
            ..paper_judge.clone()
        };
        let own_states = judge_boxes(&dets, &check.points, &own_judge);
        let depth_removed = cull_frame(
            &kps,
            &mut depth_states,
            &check.points,
            depth.as_ref(),
            &depth_only,
        );
        let candidates = in_dynamic_box(&kps, &depth_states);
        let motion = keypoint_motion(
            &prev_pyr,
            cur_pyr,
            &kps,
            &candidates,
            &check,
            &settings.keypoint_motion,
        );
        let kp_removed = apply_keypoint_motion(
            &kps,
            &depth_removed,
            &depth_states,
            &motion,
            &settings.keypoint_motion.rules(depth.is_none()),
        );
        if let Some(w) = dump.as_mut() {
            for (i, k) in features.keypoints.iter().enumerate() {
                if !candidates[i] {
                    continue;
                }
                let seated = depth_states.iter().any(|s| {
                    s.is_dynamic()
                        && s.part != stillpoint_dynamic::BoxPart::Whole
                        && s.bbox.contains_strict(k.x, k.y)
                });
                let (r, fb) = motion[i].map_or((f32::NAN, f32::NAN), |m| (m.residual, m.fb_error));
                writeln!(
                    w,
                    "{index},{:.2},{:.2},{},{},{},{},{r:.4},{fb:.4},{:?},{}",
                    k.x,
                    k.y,
                    k.octave,
                    u8::from(truth[i]),
                    u8::from(support[i]),
                    u8::from(depth_removed[i]),
                    check.model,
                    u8::from(seated)
                )
                .map_err(dump_error())?;
            }
        }
        let mut our_states = our_judgement;
        let ours_clock = std::time::Instant::now();
        // Timed alone: the culling step that `ours` runs before the seated-part test.
        cull_frame_with_motion(
            &kps,
            &mut our_states,
            &check,
            depth.as_ref(),
            Some((&prev_pyr, cur_pyr)),
            &settings,
        );
        ours_ms.push(stillpoint_core::ms_since(ours_clock));
        let predictions = [
            cull_with(&kps, &states, &check.points, &paper_cull),
            cull_with(&kps, &states, &check.points, &unknown),
            cull_with(&kps, &states, &check.points, &no_protect),
            cull_with(&kps, &own_states, &check.points, &paper_cull),
            depth_removed,
            kp_removed,
            Vec::new(),
            kps.iter()
                .map(|&[x, y]| {
                    dets.iter()
                        .any(|d| d.class_id == person && d.bbox.contains_strict(x, y))
                })
                .collect(),
            near_outliers(&kps, &check.points, o.radius, 1),
        ];
        let mut counts = [Counts::default(); METHODS.len()];
        for (m, ((c, total), p)) in counts
            .iter_mut()
            .zip(&mut totals)
            .zip(&predictions)
            .enumerate()
        {
            if m != OURS {
                c.add(p, &truth);
                total.add(p, &truth);
                support_totals[m].add(p, &support);
                clear_totals[m].add_known(p, &clear);
            }
        }
        // `ours` on its run's own keypoints, against the same mask.
        if let Some(d) = ours.frames.get(&index) {
            let run_truth = strict_truth(&mask, &d.keypoints, o.gt_radius);
            let run_fast = fast_test_moving(&mask, &d.keypoints_with_octaves(), &scales);
            counts[OURS].add(&d.dynamic, &run_truth);
            totals[OURS].add(&d.dynamic, &run_truth);
            support_totals[OURS].add(&d.dynamic, &support_truth(&run_fast));
            clear_totals[OURS].add_known(&d.dynamic, &clear_truth(&run_fast));
            // The feature budget decided too: what an extraction without it finds on the
            // excluded pixels counts as culled, scored against the same truth.
            if let Some(excluded) = d.excluded.as_deref() {
                let inside: Vec<usize> = (0..kps.len())
                    .filter(|&i| excluded_at(excluded, kps[i]))
                    .collect();
                let pick = |v: &[bool]| inside.iter().map(|&i| v[i]).collect::<Vec<bool>>();
                let culled = vec![true; inside.len()];
                counts[OURS].add(&culled, &pick(&truth));
                totals[OURS].add(&culled, &pick(&truth));
                support_totals[OURS].add(&culled, &pick(&support));
                let clear_inside: Vec<Option<bool>> = inside.iter().map(|&i| clear[i]).collect();
                clear_totals[OURS].add_known(&culled, &clear_inside);
                ours_excluded += inside.len();
            }
        }
        let report = FrameReport {
            frame: index,
            keypoints: kps.len(),
            truly_dynamic: truth.iter().filter(|&&d| d).count(),
            model: check.model,
            corners: check.corners,
            lk_failed: check.lk_failed,
            border_rejected: check.border_rejected,
            patch_rejected: check.patch_rejected,
            tracked: check.points.len(),
            outliers: check.outliers(),
            geometry_ms: check.timings.total_ms(),
            counts: counts.to_vec(),
            dynamic_boxes: depth_states
                .into_iter()
                .filter(|b| b.is_dynamic())
                .collect(),
        };
        tracing::debug!(frame = index, ms = report.geometry_ms, "geometry");
        per_frame.push(report);
    }
    if let Some(w) = dump.as_mut() {
        w.flush().map_err(dump_error())?;
    }
    let judged = per_frame.len().max(1) as f64;
    Ok(KeypointReport {
        dataset: o.dataset.display().to_string(),
        detector: detector.name().to_string(),
        frames: per_frame.len(),
        depth_frames,
        keypoints: per_frame.iter().map(|f| f.keypoints).sum(),
        straddling,
        methods: METHODS
            .iter()
            .zip(totals.iter().zip(support_totals.iter().zip(&clear_totals)))
            .map(|(&method, (c, (sc, cc)))| MethodReport {
                method,
                counts: *c,
                precision: c.precision(),
                recall: c.recall(),
                support_counts: *sc,
                support_precision: sc.precision(),
                support_recall: sc.recall(),
                clear_counts: *cc,
                clear_precision: cc.precision(),
                clear_recall: cc.recall(),
            })
            .collect(),
        models,
        geometry_ms_mean: mean(&geometry_ms),
        geometry_ms_median: median(&geometry_ms),
        geometry_stage_ms_mean: stages.map(|s| s / judged),
        orb_ms_mean: mean(&orb_ms),
        geometry_over_orb: mean(&geometry_ms) / mean(&orb_ms).max(1e-9),
        culling_ms_mean: mean(&ours_ms),
        ours_culled: ours.culled,
        ours_tracked: ours.tracked,
        ours_static_culled_median: ours.static_culled_median,
        ours_excluded,
        per_frame,
    })
}

/// The keypoint at `k` lies on a pixel where the feature budget kept no corner (looked up as
/// the extractor does).
fn excluded_at(excluded: &Gray8, k: [f32; 2]) -> bool {
    excluded
        .get_checked(k[0] as isize, k[1] as isize)
        .is_some_and(|m| m != 0)
}

/// Where `ours` sits in [`METHODS`].
const OURS: usize = 6;

/// One frame of `ours`'s run: its keypoints and which it culled.
struct RunFrame {
    keypoints: Vec<[f32; 2]>,
    octaves: Vec<u8>,
    dynamic: Vec<bool>,
    excluded: Option<std::sync::Arc<Gray8>>,
}

impl RunFrame {
    fn keypoints_with_octaves(&self) -> Vec<KeyPoint> {
        self.keypoints
            .iter()
            .zip(&self.octaves)
            .map(|(&[x, y], &octave)| KeyPoint {
                x,
                y,
                octave,
                angle: 0.0,
                response: 0.0,
                size: 0.0,
            })
            .collect()
    }
}

/// What `run` decided on each frame.
struct RunDecisions {
    frames: std::collections::BTreeMap<usize, RunFrame>,
    culled: usize,
    tracked: usize,
    static_culled_median: Option<f64>,
}

/// `stillpoint run` on the first `n` frames with the bench's detector and settings layers, in
/// run's default mode: what it culled on each frame. Without depth, the sequence is run
/// monocular from a folder of links that leaves the depth out, made in the temporary folder
/// (the dataset's own folder may be read-only) and removed after.
fn run_decisions(o: &KeypointOptions, n: usize) -> Result<RunDecisions, BenchError> {
    let mono = (!o.use_depth).then(|| {
        std::env::temp_dir()
            .join(format!("stillpoint-bench-{}", std::process::id()))
            .join(o.dataset.file_name().unwrap_or_default())
    });
    if let Some(mono) = &mono {
        crate::matrix::link_without_depth(&o.dataset, mono)?;
    }
    let options = RunOptions {
        detector: Some(o.detector.clone()),
        model: o.model.clone(),
        frames: Some(n),
        overrides: o.overrides.clone(),
        ..RunOptions::new(mono.clone().unwrap_or_else(|| o.dataset.clone()))
    };
    let mut frames = std::collections::BTreeMap::new();
    let summary = stillpoint_eval::run_scored(&options, &mut |e| {
        if let Event::Tracked { result, .. } = e {
            frames.insert(
                result.index,
                RunFrame {
                    keypoints: result.keypoints.clone(),
                    octaves: result.octaves.clone(),
                    dynamic: result.dynamic.clone(),
                    excluded: result.excluded.clone(),
                },
            );
        }
    });
    // Links only: removing them leaves the sequence as it was.
    if let Some(parent) = mono.as_deref().and_then(Path::parent) {
        let _ = std::fs::remove_dir_all(parent);
    }
    let summary = summary?;
    Ok(RunDecisions {
        frames,
        culled: summary.run.culled_per_frame.iter().sum(),
        tracked: summary.run.tracked,
        static_culled_median: summary.static_culled_stats().map(|(_, median, _)| median),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use stillpoint_synth::{Preset, SynthConfig, WriteOptions};

    /// `ours` is `run`'s decision: with depth and without, the keypoints it scores culled are
    /// the ones a run of the same frames culls, and a `--set` reaches it as it reaches `run`.
    #[test]
    fn ours_is_what_run_culls_on_the_same_frames() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("walking_xyz");
        let cfg = SynthConfig {
            preset: Preset::WalkingXyz,
            frames: 12,
            ..SynthConfig::default()
        };
        let opts = WriteOptions {
            stereo: false,
            masks: true,
        };
        stillpoint_synth::write_sequence(&cfg, opts, &dir).unwrap();
        for (use_depth, sets) in [
            (true, vec![]),
            (false, vec![]),
            (true, vec!["front_end.orb_exclusion=false".to_string()]),
        ] {
            let budget = sets.is_empty();
            let overrides = Overrides {
                sets,
                ..Overrides::default()
            };
            let options = KeypointOptions {
                dataset: dir.clone(),
                detector: "gt".into(),
                model: None,
                radius: 20.0,
                gt_radius: 0,
                overrides: overrides.clone(),
                use_depth,
                max_frames: 0,
                dump_keypoints: None,
            };
            let report = evaluate(&options).unwrap();
            let run_dir = if use_depth {
                dir.clone()
            } else {
                // The bench left nothing beside the sequence.
                assert!(!dir.with_file_name("walking_xyz_mono").exists());
                crate::matrix::without_depth(&dir).unwrap()
            };
            let run = stillpoint_eval::run_scored(
                &RunOptions {
                    detector: Some("gt".into()),
                    overrides,
                    ..RunOptions::new(run_dir)
                },
                &mut |_| {},
            )
            .unwrap();
            let culled: usize = run.run.culled_per_frame.iter().sum();
            assert!(culled > 0, "depth {use_depth}: nothing culled");
            assert_eq!(report.ours_culled, culled, "depth {use_depth}");
            assert_eq!(report.ours_tracked, run.run.tracked, "depth {use_depth}");
            assert_eq!(
                report.ours_static_culled_median,
                run.static_culled_stats().map(|(_, median, _)| median),
                "depth {use_depth}"
            );
            // Frame 0 is not scored; every other frame's culled keypoints are, and what the
            // feature budget kept out counts as culled (monocular takes every corner in the
            // map's first second, all of these 12 frames).
            assert_eq!(
                report.ours_excluded > 0,
                budget && use_depth,
                "depth {use_depth}"
            );
            let ours = &report.methods[OURS];
            assert_eq!(ours.method, "ours");
            assert_eq!(
                ours.counts.tp + ours.counts.fp,
                culled - run.run.culled_per_frame[0] + report.ours_excluded,
                "depth {use_depth}"
            );
        }
    }
}
