//! `stillpoint eval`: trajectory metrics (ATE, RPE, KITTI odometry metric), equal to evo 1.38.

use anyhow::{Context, Result};
use serde_json::json;
use std::path::{Path, PathBuf};
use stillpoint_trajectory::{
    Alignment, AteOptions, DeltaUnit, ErrorSeries, ErrorStats, KittiOptions, Matching, RpeOptions,
    Trajectory, TrajectoryFormat, ate, kitti_odometry, plot_error_over_time, plot_top_view,
    read_trajectory_lenient, rpe, scale_along_path,
};

#[derive(clap::Subcommand)]
pub enum EvalCommand {
    /// Absolute trajectory error, translation part (as `evo_ape`).
    Ate(AteArgs),
    /// Relative pose error, translation and rotation parts (as `evo_rpe`, consecutive pairs).
    Rpe(RpeArgs),
    /// KITTI odometry metric: segments of 100..800 m every 10 frames; translation %, rotation deg/m.
    Kitti(KittiArgs),
}

#[derive(clap::Args)]
pub struct Inputs {
    /// Ground-truth trajectory.
    #[arg(long)]
    gt: PathBuf,
    /// Estimated trajectory.
    #[arg(long)]
    est: PathBuf,
    /// Format of the estimate (tum, kitti, euroc); the ground truth's too unless --gt-format.
    #[arg(long, default_value = "tum")]
    format: TrajectoryFormat,
    /// Format of the ground truth when it differs (e.g. euroc csv ground truth, tum estimate).
    #[arg(long)]
    gt_format: Option<TrajectoryFormat>,
    /// Umeyama alignment of the estimate: none, se3 (evo -a), sim3 (evo -as).
    #[arg(long, default_value = "none")]
    align: Alignment,
    /// Largest time difference for associating stamps, seconds (evo's default).
    #[arg(long, default_value_t = 0.01)]
    max_diff: f64,
    /// Seconds added to the estimate's stamps before association (evo --t_offset).
    #[arg(long, default_value_t = 0.0)]
    offset: f64,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
pub struct AteArgs {
    #[command(flatten)]
    inputs: Inputs,
    /// Write a top-view plot (estimate coloured by error) to this .png or .svg file.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Write the error of each pose over time (after alignment) to this .png or .svg file.
    #[arg(long)]
    time_plot: Option<PathBuf>,
    /// Shade the periods a moving object was in view in --time-plot: a file of `start end`
    /// lines (seconds, on the estimate's clock; `#` comments).
    #[arg(long, requires = "time_plot", conflicts_with = "dataset")]
    moving: Option<PathBuf>,
    /// Shade the periods a moving object was in view in --time-plot, from this sequence's
    /// per-frame boxes (boxes.jsonl, as `stillpoint synth` writes them).
    #[arg(long, requires = "time_plot")]
    dataset: Option<PathBuf>,
    /// Cut the ground-truth path into this many pieces of equal length and report the aligned
    /// estimate's scale on each, and its drift from end to end (monocular scale drift; 0: none).
    #[arg(long, default_value_t = stillpoint_trajectory::SCALE_PIECES)]
    scale_pieces: usize,
}

#[derive(clap::Args)]
pub struct RpeArgs {
    #[command(flatten)]
    inputs: Inputs,
    /// Distance between the poses of a pair, in --delta-unit.
    #[arg(long, default_value_t = 1.0)]
    delta: f64,
    /// Unit of --delta: f (frames), s (seconds), m (metres of path).
    #[arg(long, default_value = "f")]
    delta_unit: DeltaUnit,
}

#[derive(clap::Args)]
pub struct KittiArgs {
    /// Ground-truth poses (KITTI format unless --format says otherwise).
    #[arg(long)]
    gt: PathBuf,
    /// Estimated poses, one per ground-truth pose.
    #[arg(long)]
    est: PathBuf,
    /// Format of both files.
    #[arg(long, default_value = "kitti")]
    format: TrajectoryFormat,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
}

pub fn run(cmd: EvalCommand) -> Result<()> {
    match cmd {
        EvalCommand::Ate(a) => run_ate(a),
        EvalCommand::Rpe(a) => run_rpe(a),
        EvalCommand::Kitti(a) => run_kitti(a),
    }
}

/// Read a trajectory; equal stamps are kept (as evo does) and logged.
fn load(path: &Path, format: TrajectoryFormat) -> Result<Trajectory> {
    let (traj, dups) = read_trajectory_lenient(path, format)
        .with_context(|| format!("reading trajectory {}", path.display()))?;
    if !dups.is_empty() {
        tracing::warn!(
            "{}: {} pose(s) repeat the previous timestamp (first on line {}); kept, as evo does",
            path.display(),
            dups.len(),
            dups[0]
        );
    }
    tracing::info!("{}: {} poses", path.display(), traj.len());
    Ok(traj)
}

fn load_pair(i: &Inputs) -> Result<(Trajectory, Trajectory, Matching)> {
    let gt_format = i.gt_format.unwrap_or(i.format);
    let gt = load(&i.gt, gt_format)?;
    let est = load(&i.est, i.format)?;
    let matching = Matching::for_formats(gt_format, i.format, i.max_diff, i.offset);
    Ok((gt, est, matching))
}

fn stats_json(s: &ErrorStats) -> serde_json::Value {
    json!({"count": s.count, "rmse": s.rmse, "mean": s.mean, "median": s.median, "std": s.std,
           "min": s.min, "max": s.max, "sse": s.sse})
}

/// evo's table layout.
fn print_table(title: &str, s: &ErrorStats) {
    println!("{title}\n");
    for (k, v) in [
        ("max", s.max),
        ("mean", s.mean),
        ("median", s.median),
        ("min", s.min),
        ("rmse", s.rmse),
        ("sse", s.sse),
        ("std", s.std),
    ] {
        println!("{k:>10}\t{v:.6}");
    }
    println!("{:>10}\t{}\n", "count", s.count);
}

fn align_title(a: Alignment) -> &'static str {
    match a {
        Alignment::None => "(not aligned)",
        Alignment::Se3 => "(with SE(3) Umeyama alignment)",
        Alignment::Sim3 => "(with Sim(3) Umeyama alignment)",
    }
}

fn run_ate(a: AteArgs) -> Result<()> {
    let i = &a.inputs;
    let (gt, est, matching) = load_pair(i)?;
    let r = ate(
        &gt,
        &est,
        &AteOptions {
            align: i.align,
            matching,
        },
    )
    .with_context(|| format!("ATE of {} against {}", i.est.display(), i.gt.display()))?;
    if let Some(plot) = &a.plot {
        let title = label_of(&i.est);
        plot_top_view(plot, &title, &gt.positions(), &r.est_positions, &r.errors)
            .context("writing the ATE plot")?;
        tracing::info!("plot written to {}", plot.display());
    }
    if let Some(plot) = &a.time_plot {
        let shaded = match (&a.moving, &a.dataset) {
            (Some(file), _) => stillpoint_eval::periods::read_intervals(file)?,
            (None, Some(dir)) => stillpoint_eval::periods::dataset_moving_intervals(dir)?,
            (None, None) => Vec::new(),
        };
        let points = r.errors_over_time(&est);
        let label = format!("{} {}", label_of(&i.est), align_title(i.align));
        let series = [ErrorSeries {
            label: &label,
            points: &points,
        }];
        plot_error_over_time(plot, "ATE over time", &series, &shaded)
            .context("writing the ATE-over-time plot")?;
        tracing::info!(
            "plot written to {} ({} moving periods shaded)",
            plot.display(),
            shaded.len()
        );
    }
    let along = scale_along_path(&r, a.scale_pieces);
    if i.json {
        let mut v = stats_json(&r.stats);
        v["metric"] = json!("ate");
        v["align"] = json!(i.align);
        v["scale"] = json!(r.alignment.scale);
        v["scale_along_path"] = json!(along);
        println!("{v}");
    } else {
        print_table(
            &format!("APE w.r.t. translation part (m)\n{}", align_title(i.align)),
            &r.stats,
        );
        if let Some(s) = &along {
            let ratios: Vec<String> = s.ratios.iter().map(|q| format!("{q:.3}")).collect();
            println!(
                "scale along the path ({} pieces): {}\nscale drift, end to end: {:+.1} %",
                s.ratios.len(),
                ratios.join(" "),
                100.0 * s.drift
            );
        }
    }
    Ok(())
}

/// A file's name, for titles and legends.
fn label_of(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

fn run_rpe(a: RpeArgs) -> Result<()> {
    let i = &a.inputs;
    let (gt, est, matching) = load_pair(i)?;
    let opts = RpeOptions {
        align: i.align,
        matching,
        delta: a.delta,
        delta_unit: a.delta_unit,
    };
    let r = rpe(&gt, &est, &opts)
        .with_context(|| format!("RPE of {} against {}", i.est.display(), i.gt.display()))?;
    if i.json {
        let v = json!({
            "metric": "rpe", "align": i.align, "delta": a.delta, "delta_unit": a.delta_unit,
            "translation": stats_json(&r.translation),
            "rotation_deg": stats_json(&r.rotation_deg),
        });
        println!("{v}");
    } else {
        let unit = match a.delta_unit {
            DeltaUnit::Frames => "frames",
            DeltaUnit::Seconds => "s",
            DeltaUnit::Metres => "m",
        };
        let head = format!(
            "for delta = {} ({unit}) using consecutive pairs\n{}",
            a.delta,
            align_title(i.align)
        );
        print_table(
            &format!("RPE w.r.t. translation part (m)\n{head}"),
            &r.translation,
        );
        print_table(
            &format!("RPE w.r.t. rotation angle in degrees (deg)\n{head}"),
            &r.rotation_deg,
        );
    }
    Ok(())
}

fn run_kitti(a: KittiArgs) -> Result<()> {
    let gt = load(&a.gt, a.format)?;
    let est = load(&a.est, a.format)?;
    let r = kitti_odometry(&gt, &est, &KittiOptions::default()).with_context(|| {
        format!(
            "KITTI metric of {} against {}",
            a.est.display(),
            a.gt.display()
        )
    })?;
    if a.json {
        println!(
            "{}",
            serde_json::to_string(&r).context("serialising the KITTI result")?
        );
    } else {
        println!("KITTI odometry metric ({} segments)\n", r.segments);
        println!("{:>12}\t{:.4}", "t_err [%]", r.translation_pct);
        println!("{:>12}\t{:.6}", "r_err [deg/m]", r.rotation_deg_per_m);
        println!(
            "{:>12}\t{:.4}\n",
            "r_err [deg/100m]",
            100.0 * r.rotation_deg_per_m
        );
        println!(
            "{:>8}  {:>8}  {:>10}  {:>12}",
            "length", "segments", "t_err [%]", "r_err [deg/m]"
        );
        for l in &r.per_length {
            println!(
                "{:>8.0}  {:>8}  {:>10.4}  {:>12.6}",
                l.length_m, l.segments, l.translation_pct, l.rotation_deg_per_m
            );
        }
    }
    Ok(())
}
