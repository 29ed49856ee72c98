//! `stillpoint bench dynamic`: precision and recall of the dynamic-keypoint decision against the
//! ground-truth masks of a synthetic sequence (`stillpoint synth --masks`), for the paper and
//! variants of it, ours, and two baselines; the measurement is `stillpoint_bench::keypoints`
//! (its docs list the methods and the three ground truths), this module maps the flags onto its
//! settings and prints the report.

use std::path::PathBuf;
use stillpoint_bench::keypoints::{KeypointOptions, KeypointReport, evaluate};

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
    /// The settings tree's layers over the sequence's own, as `run` takes them: `ours` is a run
    /// with them and every other row takes its dynamic settings from the same tree.
    #[command(flatten)]
    layers: crate::cmd::run::SettingsArgs,
    /// Write one CSV line per keypoint inside a dynamic box (frame, x, y, octave, truth,
    /// support truth, depth-aware decision, residual, forward-backward error, model, seated) to
    /// this file, for studying the per-keypoint evidence.
    #[arg(long)]
    dump_keypoints: Option<PathBuf>,
    /// Ignore the sequence's depth (ours_depth then culls by the paper's rule, and `ours` runs
    /// the sequence monocular, from a temporary folder of links to it).
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

pub fn run(args: Args) -> anyhow::Result<()> {
    let report = evaluate(&KeypointOptions {
        dataset: args.dataset.clone(),
        detector: args.detector.clone(),
        model: args.model.clone(),
        radius: args.radius,
        gt_radius: args.gt_radius,
        overrides: stillpoint_run::Overrides {
            config: args.layers.config.clone(),
            sets: args.layers.sets.clone(),
            ..Default::default()
        },
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
    println!(
        "ours: `stillpoint run` on these frames, scored on its own keypoints: {} culled, {} more where the feature budget kept no corner, {} frames tracked, a median {} of the static keypoints culled per frame",
        report.ours_culled,
        report.ours_excluded,
        report.ours_tracked,
        report
            .ours_static_culled_median
            .map_or("-".to_string(), |s| format!("{:.1} %", 100.0 * s)),
    );
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
