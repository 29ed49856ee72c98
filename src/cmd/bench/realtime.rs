//! `stillpoint bench realtime`: a sequence replayed as a live camera at a given rate on a given
//! number of CPUs, N times (`stillpoint_bench::realtime`), with the goal's figures per run:
//! frames processed, latency p95, ATE, map points on movers. Exits non-zero when a run fails.

use std::path::PathBuf;

use serde_json::json;
use stillpoint_bench::realtime::{RealtimeOptions, RealtimeRow, run_realtime};

#[derive(clap::Args)]
pub struct Args {
    /// Sequence folder (as `run --dataset`).
    #[arg(long)]
    pub dataset: PathBuf,
    /// Dataset kind when it cannot be told from the folder (as `run --kind`).
    #[arg(long)]
    pub kind: Option<String>,
    /// Frames a second the camera delivers (0: the sequence's own timestamps):
    /// `--set realtime.rate_hz=...`.
    #[arg(long, default_value_t = 0.0)]
    pub rate: f64,
    /// CPUs the runs may use (the first ones this process may run on; 0: all).
    #[arg(long, default_value_t = 0)]
    pub cores: usize,
    /// Replays.
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    #[command(flatten)]
    pub detection: super::DetectorArgs,
    #[command(flatten)]
    pub layers: crate::cmd::run::SettingsArgs,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

fn row_json(r: &RealtimeRow) -> serde_json::Value {
    json!({
        "frames": r.frames,
        "frames_processed": r.processed,
        "processed_share": r.processed_share(),
        "latency_ms": {"median": r.latency_ms[0], "p95": r.latency_ms[1], "max": r.latency_ms[2]},
        "processing_ms_mean": r.processing_ms_mean,
        "ate_cm": r.ate_cm,
        "moving_map_points": r.moving_map_points,
    })
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let o = RealtimeOptions {
        dataset: a.dataset.clone(),
        kind: crate::cmd::run::parse_kind(a.kind.as_deref())?,
        detector: a.detection.detector(),
        model: a.detection.model.clone(),
        rate_hz: a.rate,
        cores: a.cores,
        runs: a.runs,
        layers: stillpoint_run::Overrides {
            config: a.layers.config.clone(),
            sets: a.layers.sets.clone(),
            ..Default::default()
        },
        stop: Some(crate::interrupt_flag()),
    };
    let rows = run_realtime(&o, &mut |i, r| {
        tracing::info!(
            "run {}: {} of {} frames, p95 {:.1} ms, ATE {}",
            i + 1,
            r.processed,
            r.frames,
            r.latency_ms[1],
            r.ate_cm.map_or("-".into(), |v| format!("{v:.2} cm"))
        );
    })?;
    let rate = if a.rate > 0.0 {
        format!("{} Hz", a.rate)
    } else {
        "its timestamps".into()
    };
    let cores = if a.cores > 0 {
        a.cores.to_string()
    } else {
        "all".into()
    };
    if a.json {
        let out = json!({
            "dataset": a.dataset,
            "rate_hz": a.rate,
            "cores": a.cores,
            "detector": o.detector,
            "runs": rows.iter().map(row_json).collect::<Vec<_>>(),
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!(
        "{}: {} runs at {rate} on {cores} CPU(s), detector {}",
        a.dataset.display(),
        rows.len(),
        o.detector.as_deref().unwrap_or("off")
    );
    println!(
        "{:>4} {:>10} {:>9} {:>9} {:>9} {:>10} {:>8} {:>7}",
        "run", "processed", "lat p50", "lat p95", "lat max", "ms/frame", "ATE cm", "movers"
    );
    for (i, r) in rows.iter().enumerate() {
        println!(
            "{:>4} {:>4}/{:<5} {:>9.1} {:>9.1} {:>9.1} {:>10.1} {:>8} {:>7}",
            i + 1,
            r.processed,
            r.frames,
            r.latency_ms[0],
            r.latency_ms[1],
            r.latency_ms[2],
            r.processing_ms_mean,
            r.ate_cm.map_or("-".into(), |v| format!("{v:.2}")),
            r.moving_map_points.map_or("-".into(), |v| v.to_string())
        );
    }
    Ok(())
}
