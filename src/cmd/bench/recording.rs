//! `stillpoint bench recording`: a recording run as a user runs it (`stillpoint run`, a process
//! each), on each backend, idle and with a busy thread beside it, N rounds
//! (`stillpoint_bench::recording`): frames a second, times real time, peak memory, ATE, and
//! whether every run of a backend wrote the same trajectory. Exits non-zero when a run fails or
//! a backend's trajectories differ.

use std::path::PathBuf;

use serde_json::json;
use stillpoint_bench::recording::{RecordingOptions, RecordingRow, run_recording};

#[derive(clap::Args)]
pub struct Args {
    /// Sequence folder (as `run --dataset`).
    #[arg(long)]
    pub dataset: PathBuf,
    /// Dataset kind when it cannot be told from the folder (as `run --kind`).
    #[arg(long)]
    pub kind: Option<String>,
    /// Detector backends side by side, comma-separated (`detect.backend`: tract, ort); default:
    /// the settings' own.
    #[arg(long, value_delimiter = ',')]
    pub backends: Vec<String>,
    /// Rounds; each runs every backend once idle (and once loaded with `--busy`).
    #[arg(long, default_value_t = 2)]
    pub rounds: usize,
    /// Also run each backend with a thread of this process busy beside it.
    #[arg(long)]
    pub busy: bool,
    #[command(flatten)]
    pub detection: super::DetectorArgs,
    /// Folder for the runs' trajectories (default: one under the temporary folder, removed
    /// after).
    #[arg(long)]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub layers: crate::cmd::run::SettingsArgs,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

fn row_json(r: &RecordingRow) -> serde_json::Value {
    json!({
        "backend": r.backend,
        "busy": r.busy,
        "frames": r.frames,
        "tracked": r.tracked,
        "wall_s": r.wall_s,
        "frames_per_second": r.frames_per_second,
        "footage_fps": r.footage_fps,
        "times_real_time": r.times_real_time(),
        "peak_memory_mib": r.peak_memory_mib,
        "ate_cm": r.ate_cm,
        "same_trajectory": r.same_trajectory,
        "same_as_first_backend": r.same_as_first_backend,
    })
}

pub fn run(a: Args) -> anyhow::Result<()> {
    // Without --out, a folder of this process's own under the temporary folder, removed after.
    let temp = a.out.is_none().then(|| {
        std::env::temp_dir().join(format!("stillpoint-bench-recording-{}", std::process::id()))
    });
    let out_dir = a.out.clone().or_else(|| temp.clone()).unwrap_or_default();
    let o = RecordingOptions {
        program: std::env::current_exe()?,
        dataset: a.dataset.clone(),
        kind: a.kind.clone(),
        detector: a.detection.detector(),
        model: a.detection.model.clone(),
        backends: a.backends.clone(),
        rounds: a.rounds,
        busy: a.busy,
        config: a.layers.config.clone(),
        sets: a.layers.sets.clone(),
        out_dir,
    };
    let rows = run_recording(&o, &mut |r| {
        tracing::info!(
            "{} {}: {:.1} frames a second, peak {}",
            r.backend,
            if r.busy { "busy" } else { "idle" },
            r.frames_per_second,
            r.peak_memory_mib
                .map_or("-".into(), |m| format!("{m:.0} MiB"))
        );
    });
    if let Some(t) = &temp {
        let _ = std::fs::remove_dir_all(t);
    }
    let rows = rows?;
    let differ: Vec<&str> = rows
        .iter()
        .filter(|r| !r.same_trajectory)
        .map(|r| r.backend.as_str())
        .collect();
    if a.json {
        let out = json!({
            "dataset": a.dataset,
            "detector": o.detector,
            "runs": rows.iter().map(row_json).collect::<Vec<_>>(),
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        print_table(&a, &rows);
    }
    if !differ.is_empty() {
        anyhow::bail!(
            "a file run must give the same trajectory every run; backend(s) {} did not",
            differ.join(", ")
        );
    }
    Ok(())
}

fn print_table(a: &Args, rows: &[RecordingRow]) {
    let f = |v: Option<f64>, d: usize| v.map_or("-".into(), |v| format!("{v:.d$}"));
    println!(
        "{}: {} runs, detector {}",
        a.dataset.display(),
        rows.len(),
        a.detection.detector().unwrap_or_else(|| "off".into())
    );
    println!(
        "{:<8} {:<5} {:>8} {:>8} {:>8} {:>9} {:>8} {:>8} {:>5}",
        "backend", "load", "tracked", "wall s", "frames/s", "x real", "peak MiB", "ATE cm", "same"
    );
    for r in rows {
        println!(
            "{:<8} {:<5} {:>8} {:>8.2} {:>8.1} {:>9} {:>8} {:>8} {:>5}",
            r.backend,
            if r.busy { "busy" } else { "idle" },
            format!("{}/{}", r.tracked, r.frames),
            r.wall_s,
            r.frames_per_second,
            f(r.times_real_time(), 2),
            f(r.peak_memory_mib, 1),
            f(r.ate_cm, 3),
            if r.same_trajectory { "yes" } else { "NO" }
        );
    }
    let backends: std::collections::BTreeSet<&str> =
        rows.iter().map(|r| r.backend.as_str()).collect();
    if rows.len() > 1 && rows.iter().all(|r| r.same_as_first_backend) {
        println!("every run wrote the same trajectory, byte for byte");
    } else if backends.len() > 1 && rows.iter().all(|r| r.same_trajectory) {
        println!("each backend wrote the same trajectory every run (the backends' differ)");
    }
}
