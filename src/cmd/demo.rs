//! `stillpoint demo`: render a synthetic walking sequence into a temporary folder, run SLAM with
//! the dynamic front-end off and on, and print both ATEs, the improvement and the timings. Needs
//! nothing but the binary (the gt detector reads the boxes the generator wrote).

use anyhow::Context;
use stillpoint_bench::demo::{DemoOptions, demo, write_plots};
use stillpoint_eval::stats;
use stillpoint_synth::Preset;

use super::run::{ProgressBar, print_culled_row, summary_json};

#[derive(clap::Args)]
pub struct Args {
    /// Frames to render (30 per second). 300 (10 s, as the benchmarks) takes about a minute on
    /// 2 cores, rendering and both runs included.
    #[arg(long, default_value_t = 300)]
    pub frames: usize,
    /// Synthetic preset (walking_xyz, walking_halfsphere, sitting_xyz, static, ...).
    #[arg(long, default_value = "walking_xyz")]
    pub preset: String,
    /// Detector for the "on" run: gt (the generator's boxes), yolox or none.
    #[arg(long, default_value = "gt")]
    pub detector: String,
    /// Random seed of the scene.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Keep the generated sequence in this folder instead of a temporary one.
    #[arg(long)]
    pub keep: Option<std::path::PathBuf>,
    /// Write the plots here: top views of both runs against the ground truth, and both runs'
    /// ATE over time with the periods a walker was in view shaded (default: a
    /// `stillpoint-demo-plots-PID` folder in the temporary directory; its name is printed).
    #[arg(long)]
    pub plots: Option<std::path::PathBuf>,
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let preset = Preset::from_name(&args.preset)
        .with_context(|| format!("unknown preset {:?}", args.preset))?;
    let mut bar = ProgressBar::default();
    let report = demo(
        &DemoOptions {
            preset,
            frames: args.frames,
            detector: args.detector.clone(),
            seed: args.seed,
            keep: args.keep.clone(),
            stop: Some(crate::interrupt_flag()),
        },
        &mut |e| bar.show(e),
    )?;
    let plots_dir = args.plots.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!("stillpoint-demo-plots-{}", std::process::id()))
    });
    let plots = write_plots(&report, preset.name(), &plots_dir)?;
    tracing::info!("plots written to {}", plots_dir.display());
    let (off, on) = (&report.off, &report.on);
    let (a_off, a_on, improvement) = (report.ate_off, report.ate_on, report.improvement_percent);
    if args.json {
        println!(
            "{}",
            serde_json::json!({
                "preset": preset.name(),
                "frames": args.frames,
                "off": summary_json(off),
                "on": summary_json(on),
                "ate_rmse_off": a_off,
                "ate_rmse_on": a_on,
                "improvement_percent": improvement,
                "moving_periods": report.moving_intervals,
                "plots": plots,
            })
        );
        return Ok(());
    }
    let fmt = |a: Option<f64>| a.map_or("n/a".to_string(), |a| format!("{:.2} cm", a * 100.0));
    println!(
        "{} ({} frames, seed {}, detector {})",
        preset.name(),
        args.frames,
        args.seed,
        args.detector
    );
    println!(
        "{:<24} {:>12} {:>14} {:>10} {:>11}",
        "dynamic front-end", "ATE RMSE", "tracked", "keyframes", "map points"
    );
    for (name, s, a) in [("off (baseline)", &off.run, a_off), ("on", &on.run, a_on)] {
        println!(
            "{:<24} {:>12} {:>14} {:>10} {:>11}",
            name,
            fmt(a),
            format!("{} / {}", s.tracked, s.frames),
            s.keyframes,
            s.map_points
        );
    }
    match improvement {
        Some(i) => println!("improvement: {i:.1} % lower ATE with the front-end"),
        None => println!("improvement: n/a (no ATE for one of the runs)"),
    }
    println!();
    println!(
        "{:<30} {:>9} {:>9} {:>9} {:>12}",
        "stage (ms)", "mean", "median", "p90", "off: mean"
    );
    for (k, v) in &on.run.timings {
        let off_times = off.run.timings.iter().find(|(name, _)| name == k);
        // Stages that ran in neither run (no loop closed: no correction) have no row.
        if v.is_empty() && off_times.is_none_or(|(_, b)| b.is_empty()) {
            continue;
        }
        let (m, med, p90) = stats(v);
        let base = off_times
            .filter(|(_, b)| !b.is_empty())
            .map_or("-".to_string(), |(_, b)| format!("{:.2}", stats(b).0));
        println!("{k:<30} {m:>9.2} {med:>9.2} {p90:>9.2} {base:>12}");
    }
    print_culled_row(&on.run);
    println!();
    println!("plots in {}:", plots_dir.display());
    for p in &plots {
        println!("  {}", p.display());
    }
    Ok(())
}
