//! `stillpoint bench dynamic`: precision and recall of the dynamic-keypoint decision against the
//! ground-truth masks of a synthetic sequence (`stillpoint synth --masks`), for the paper and
//! variants of it, ours, and two baselines; the measurement is `stillpoint_bench::keypoints`
//! (its docs list the methods and the three ground truths), this module maps the flags onto its
//! settings and prints the report.

use anyhow::bail;
use std::path::PathBuf;
use stillpoint_bench::keypoints::{KeypointOptions, KeypointReport, evaluate};
use stillpoint_dynamic::DynamicSettings;

#[derive(clap::Args)]
pub struct Args {
    /// A synthetic sequence written with `stillpoint synth --masks` (rgb.txt, rgb/, mask/,
    /// boxes.jsonl).
    #[arg(long)]
    dataset: PathBuf,
    /// Boxes from: gt (boxes.jsonl), yolox (the ONNX model), none.
    #[arg(long, default_value = "gt")]
    detector: String,
    /// YOLOX ONNX model for `--detector yolox` (else $STILLPOINT_MODEL, models/ beside the
    /// binary, ../shared/models), as `stillpoint run --model`.
    #[arg(long)]
    model: Option<PathBuf>,
    /// Radius in pixels of the detection-free baseline's dilation around outliers.
    #[arg(long, default_value_t = 20.0)]
    radius: f32,
    /// Count a keypoint as truly dynamic when a moving mask pixel lies within this many pixels
    /// (0: the keypoint's own pixel only). A keypoint on a silhouette edge describes a patch
    /// that is partly the mover.
    #[arg(long, default_value_t = 0)]
    gt_radius: usize,
    /// Depth-aware culling: half width of the band around the object's depth, at least (m).
    #[arg(long)]
    depth_band_m: Option<f32>,
    /// Depth-aware culling: half width of the band, at least this share of the depth.
    #[arg(long)]
    depth_band_rel: Option<f32>,
    /// Depth-aware culling: penalty per share of the box's centre in front of a candidate
    /// object depth.
    #[arg(long)]
    occluder_weight: Option<f32>,
    /// Depth-aware culling: a keypoint's depth is the nearest within this many pixels.
    #[arg(long)]
    depth_window: Option<usize>,
    /// Depth-aware culling: radius of the local rule around outliers, as a share of the square
    /// root of the box's area (0: off).
    #[arg(long)]
    local_radius: Option<f32>,
    /// Depth-aware culling: cull a seated person's dynamic part only around its outliers, not
    /// whole at its depth.
    #[arg(long)]
    seated_local: bool,
    /// Outlier threshold of the geometry module in pixels (paper: 1.0).
    #[arg(long)]
    outlier_px: Option<f64>,
    /// NHBC (ours_depth): a person box or part is also dynamic with 3 tracked points above this
    /// residual in pixels (default 0.5; 0 turns it off, as the paper).
    #[arg(long)]
    person_subpixel: Option<f32>,
    /// Per-keypoint motion (ours_kp): a culled keypoint whose residual is at most this is kept.
    #[arg(long)]
    kp_keep_px: Option<f32>,
    /// Per-keypoint motion (ours_kp): a kept keypoint in a dynamic box whose residual exceeds
    /// this is culled.
    #[arg(long)]
    kp_cull_px: Option<f32>,
    /// Per-keypoint motion (ours_kp): largest forward-backward error of a usable track.
    #[arg(long)]
    kp_fb_px: Option<f32>,
    /// Per-keypoint motion (ours_kp): LK window in pixels (default: the geometry module's 22).
    #[arg(long)]
    kp_window: Option<usize>,
    /// Per-keypoint motion (ours_kp): where a small residual may keep a keypoint: whole (boxes
    /// of standing people and other classes), seated (a seated person's parts), both, none.
    #[arg(long)]
    kp_keep_in: Option<String>,
    /// Per-keypoint motion (ours_kp): a small epipolar distance may keep a keypoint too (by
    /// default only a homography's transfer error does).
    #[arg(long)]
    kp_keep_fundamental: bool,
    /// Write one CSV line per keypoint inside a dynamic box (frame, x, y, octave, truth,
    /// support truth, depth-aware decision, residual, forward-backward error, model, seated) to
    /// this file, for studying the per-keypoint evidence.
    #[arg(long)]
    dump_keypoints: Option<PathBuf>,
    /// Unknown-object option: radius around box-less outliers, pixels (default 20).
    #[arg(long)]
    unknown_radius: Option<f32>,
    /// Unknown-object option: fewest box-less outliers within the radius (default 2).
    #[arg(long)]
    unknown_min: Option<usize>,
    /// `ours` without the unknown-object rule.
    #[arg(long)]
    no_unknown_objects: bool,
    /// `ours` without the per-keypoint motion evidence.
    #[arg(long)]
    no_keypoint_motion: bool,
    /// `ours` without the front-end's seated-part 3D motion test (`dynamic::seated_motion`).
    #[arg(long)]
    no_seated_motion: bool,
    /// Ignore the sequence's depth (ours_depth then culls by the paper's rule).
    #[arg(long)]
    no_depth: bool,
    /// Use at most this many frames (0: all).
    #[arg(long, default_value_t = 0)]
    max_frames: usize,
    /// Print the dynamic boxes of each frame with their estimated object depth.
    #[arg(long)]
    boxes: bool,
    /// Print one line per frame as well.
    #[arg(long)]
    per_frame: bool,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
}

/// The bench's dynamic settings: the defaults with the flags laid over them.
fn dynamic_settings(args: &Args) -> anyhow::Result<DynamicSettings> {
    let mut settings = DynamicSettings::default();
    if let Some(v) = args.depth_band_m {
        settings.depth.band_min_m = v;
    }
    if let Some(v) = args.depth_band_rel {
        settings.depth.band_relative = v;
    }
    if let Some(v) = args.outlier_px {
        settings.geometry.outlier_threshold_px = v;
    }
    if let Some(v) = args.person_subpixel {
        settings.judge.person_subpixel_px = (v > 0.0).then_some(v);
    }
    if let Some(v) = args.local_radius {
        settings.depth.local_radius_fraction = v;
    }
    settings.depth.seated_parts_local = args.seated_local;
    if let Some(v) = args.occluder_weight {
        settings.depth.occluder_weight = v;
    }
    if let Some(v) = args.depth_window {
        settings.depth.keypoint_window_px = v;
    }
    if let Some(v) = args.unknown_radius {
        settings.cull.unknown_radius_px = v;
    }
    if let Some(v) = args.unknown_min {
        settings.cull.unknown_min_outliers = v;
    }
    settings.cull.unknown_objects &= !args.no_unknown_objects;
    settings.keypoint_motion.enabled &= !args.no_keypoint_motion;
    if let Some(v) = args.kp_keep_px {
        settings.keypoint_motion.keep_below_px = v;
    }
    if let Some(v) = args.kp_cull_px {
        settings.keypoint_motion.cull_above_px = v;
    }
    if let Some(v) = args.kp_fb_px {
        settings.keypoint_motion.max_fb_error_px = v;
    }
    if let Some(v) = args.kp_window {
        settings.keypoint_motion.lk.window = v;
    }
    if let Some(v) = &args.kp_keep_in {
        let (whole, seated) = match v.as_str() {
            "whole" => (true, false),
            "seated" => (false, true),
            "both" => (true, true),
            "none" => (false, false),
            other => bail!("--kp-keep-in {other:?}: expected whole, seated, both or none"),
        };
        settings.keypoint_motion.keep_in_whole_boxes = whole;
        settings.keypoint_motion.keep_in_seated_parts = seated;
    }
    settings.keypoint_motion.keep_with_fundamental |= args.kp_keep_fundamental;
    Ok(settings)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let report = evaluate(&KeypointOptions {
        dataset: args.dataset.clone(),
        detector: args.detector.clone(),
        model: args.model.clone(),
        radius: args.radius,
        gt_radius: args.gt_radius,
        settings: dynamic_settings(&args)?,
        seated_motion: !args.no_seated_motion,
        use_depth: !args.no_depth,
        max_frames: args.max_frames,
        dump_keypoints: args.dump_keypoints.clone(),
    })?;
    if !args.json {
        print_frames(&args, &report);
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    println!(
        "{}: {} frames judged ({} with depth), detector {}; {} keypoints, {} straddle a moving silhouette",
        report.dataset,
        report.frames,
        report.depth_frames,
        report.detector,
        report.keypoints,
        report.straddling
    );
    println!(
        "strict: the keypoint's pixel is moving; occl: any pixel of its FAST test (centre and \
         16-pixel circle at its level) is; clear: keypoints whose FAST test straddles a moving \
         silhouette are not scored"
    );
    println!(
        "{:<20} {:>9} {:>9} {:>7} {:>7} {:>7}   {:>9} {:>9}   {:>9} {:>9}",
        "method", "precision", "recall", "tp", "fp", "fn", "P occl", "R occl", "P clear", "R clear"
    );
    for m in &report.methods {
        println!(
            "{:<20} {:>9} {:>9} {:>7} {:>7} {:>7}   {:>9} {:>9}   {:>9} {:>9}",
            m.method,
            fmt_opt(m.precision),
            fmt_opt(m.recall),
            m.counts.tp,
            m.counts.fp,
            m.counts.fn_,
            fmt_opt(m.support_precision),
            fmt_opt(m.support_recall),
            fmt_opt(m.clear_precision),
            fmt_opt(m.clear_recall)
        );
    }
    println!("motion models: {:?}", report.models);
    let s = report.geometry_stage_ms_mean;
    println!(
        "geometry module: mean {:.2} ms, median {:.2} ms per frame (corners {:.2}, LK {:.2}, checks {:.2}, model {:.2}); {:.2}x ORB extraction ({:.2} ms)",
        report.geometry_ms_mean,
        report.geometry_ms_median,
        s[0],
        s[1],
        s[2],
        s[3],
        report.geometry_over_orb,
        report.orb_ms_mean
    );
    println!(
        "our culling step (depth, unknown objects, per-keypoint evidence): mean {:.2} ms per frame ({:.2}x ORB extraction)",
        report.culling_ms_mean,
        report.culling_ms_mean / report.orb_ms_mean.max(1e-9)
    );
    Ok(())
}

fn fmt_opt(v: Option<f64>) -> String {
    v.map_or("-".to_string(), |v| format!("{v:.3}"))
}

/// `--boxes` and `--per-frame`: the dynamic boxes of each frame, then its line.
fn print_frames(args: &Args, report: &KeypointReport) {
    for f in &report.per_frame {
        if args.boxes {
            for b in &f.dynamic_boxes {
                println!(
                    "frame {:4} class {:3} {:?} {:?} box [{:.0} {:.0} {:.0} {:.0}] tracked {} outliers {} depth {}",
                    f.frame,
                    b.class_id,
                    b.part,
                    b.rule,
                    b.bbox.x1,
                    b.bbox.y1,
                    b.bbox.x2,
                    b.bbox.y2,
                    b.tracked,
                    b.outliers,
                    b.depth.map_or("-".to_string(), |o| format!(
                        "{:.2} m [{:.2}, {:.2}] central {:.2} outliers {}/{}",
                        o.metres,
                        o.near,
                        o.far,
                        o.central_share,
                        o.outliers_in_band,
                        o.outliers_with_depth
                    ))
                );
            }
        }
        if args.per_frame {
            let pr: Vec<String> = f
                .counts
                .iter()
                .map(|c| format!("{}/{}", fmt_opt(c.precision()), fmt_opt(c.recall())))
                .collect();
            println!(
                "frame {:4}  kps {:4}  dyn {:4}  {:?} tracked {:4} outliers {:3}  P/R {}",
                f.frame,
                f.keypoints,
                f.truly_dynamic,
                f.model,
                f.tracked,
                f.outliers,
                pr.join("  ")
            );
        }
    }
}
