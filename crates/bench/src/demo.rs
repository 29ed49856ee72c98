//! The demo: render a synthetic walking sequence into a folder, run SLAM with the dynamic
//! front-end off and on, and compare the ATEs. Needs nothing but the binary (the gt detector
//! reads the boxes the generator wrote).

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use stillpoint_eval::{ScoredRun, run_scored};
use stillpoint_run::{Event, RunOptions};
use stillpoint_synth::{Preset, SynthConfig, WriteOptions};

use crate::BenchError;

/// What the demo renders and runs.
#[derive(Clone, Debug)]
pub struct DemoOptions {
    /// The synthetic scene and camera motion.
    pub preset: Preset,
    /// Frames to render (30 per second).
    pub frames: usize,
    /// Detector of the "on" run: gt (the generator's boxes), yolox or none.
    pub detector: String,
    /// Random seed of the scene.
    pub seed: u64,
    /// Keep the sequence in this folder; `None` renders into a temporary folder, removed after.
    pub keep: Option<PathBuf>,
    /// Set to stop the runs early (their summaries cover the frames taken).
    pub stop: Option<&'static AtomicBool>,
}

/// The two runs and how they compare.
pub struct DemoReport {
    /// The front-end off (the ORB-SLAM3-like baseline).
    pub off: ScoredRun,
    /// The front-end on.
    pub on: ScoredRun,
    /// ATE RMSE of the "off" run, metres.
    pub ate_off: Option<f64>,
    /// ATE RMSE of the "on" run, metres.
    pub ate_on: Option<f64>,
    /// How much lower the ATE is with the front-end, percent of the baseline's.
    pub improvement_percent: Option<f64>,
    /// When a moving object was in view (the generator's boxes), seconds.
    pub moving_intervals: Vec<stillpoint_eval::periods::Interval>,
}

/// Render the sequence, run it twice (a file run: local mapping inline, so deterministic) and
/// compare.
pub fn demo(o: &DemoOptions, progress: &mut dyn FnMut(Event)) -> Result<DemoReport, BenchError> {
    let dir = match &o.keep {
        Some(d) => d.clone(),
        None => std::env::temp_dir().join(format!("stillpoint-demo-{}", std::process::id())),
    };
    let cfg = SynthConfig {
        preset: o.preset,
        frames: o.frames,
        seed: o.seed,
        ..Default::default()
    };
    tracing::info!(
        "rendering {} frames of {} into {}",
        cfg.frames,
        o.preset.name(),
        dir.display()
    );
    stillpoint_synth::write_sequence(&cfg, WriteOptions::default(), &dir).map_err(|source| {
        BenchError::Synth {
            context: format!("writing the synthetic sequence into {}", dir.display()),
            source,
        }
    })?;
    let moving_intervals = stillpoint_eval::periods::dataset_moving_intervals(&dir)?;
    let base = RunOptions {
        stop: o.stop,
        ..RunOptions::new(dir.clone())
    };
    tracing::info!("run 1/2: dynamic front-end off");
    let off = run_scored(&base, progress)?;
    tracing::info!("run 2/2: dynamic front-end on ({})", o.detector);
    let on = run_scored(
        &RunOptions {
            detector: Some(o.detector.clone()),
            ..base
        },
        progress,
    )?;
    if o.keep.is_none() {
        let _ = std::fs::remove_dir_all(&dir);
    }
    let ate = |s: &ScoredRun| s.accuracy().map(|(a, _)| a.stats.rmse);
    let (ate_off, ate_on) = (ate(&off), ate(&on));
    let improvement_percent = match (ate_off, ate_on) {
        (Some(a), Some(b)) if a > 0.0 => Some(100.0 * (a - b) / a),
        _ => None,
    };
    Ok(DemoReport {
        off,
        on,
        ate_off,
        ate_on,
        improvement_percent,
        moving_intervals,
    })
}

/// The demo's plots in `dir` (created): each run's top view against the ground truth
/// (`top_view_off.png`, `top_view_on.png`) and both runs' ATE over time with the periods a
/// moving object was in view shaded (`ate_over_time.png`). Returns the files written; a run
/// without an ATE has no plot.
pub fn write_plots(
    report: &DemoReport,
    title: &str,
    dir: &Path,
) -> Result<Vec<PathBuf>, BenchError> {
    std::fs::create_dir_all(dir).map_err(|source| BenchError::Io {
        context: format!("creating {}", dir.display()),
        source,
    })?;
    let mut written = Vec::new();
    let mut curves = Vec::new();
    for (name, s) in [("off", &report.off), ("on", &report.on)] {
        let (Some(gt), Some((ate, _))) = (&s.ground_truth, s.accuracy()) else {
            continue;
        };
        let path = dir.join(format!("top_view_{name}.png"));
        stillpoint_trajectory::plot_top_view(
            &path,
            &format!("{title}, front-end {name}"),
            &gt.positions(),
            &ate.est_positions,
            &ate.errors,
        )?;
        written.push(path);
        curves.push((
            format!("front-end {name} (RMSE {:.2} cm)", 100.0 * ate.stats.rmse),
            ate.errors_over_time(&s.run.trajectory),
        ));
    }
    if !curves.is_empty() {
        let series: Vec<stillpoint_trajectory::ErrorSeries> = curves
            .iter()
            .map(|(label, points)| stillpoint_trajectory::ErrorSeries { label, points })
            .collect();
        let path = dir.join("ate_over_time.png");
        stillpoint_trajectory::plot_error_over_time(
            &path,
            &format!("{title}: ATE over time"),
            &series,
            &report.moving_intervals,
        )?;
        written.push(path);
    }
    Ok(written)
}
