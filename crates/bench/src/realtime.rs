//! A sequence replayed as a live camera at a given rate on a given number of CPUs, several
//! times: frames processed, latency, ATE and map points on movers per run. The runs go one
//! after another on a thread kept to the first `cores` CPUs (every thread a run starts inherits
//! that), so "one core" means the detector, tracking and mapping share one.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

use serde::Serialize;
use stillpoint_run::RunOptions;

use crate::BenchError;

/// What is replayed, how fast, on how many CPUs, how often.
#[derive(Clone, Debug)]
pub struct RealtimeOptions {
    /// The sequence (any `run --dataset`).
    pub dataset: PathBuf,
    /// Its kind, when it cannot be told from the folder.
    pub kind: Option<stillpoint_datasets::DatasetKind>,
    /// Detector (`yolox`, `gt`, `none`); `None`: no front-end.
    pub detector: Option<String>,
    /// YOLOX ONNX model (else the default search).
    pub model: Option<PathBuf>,
    /// Frames a second the camera delivers (0: the sequence's timestamps).
    pub rate_hz: f64,
    /// CPUs the runs may use (the first ones this process may run on); 0: all.
    pub cores: usize,
    /// Runs.
    pub runs: usize,
    /// The settings tree's layers (`--config`, `--set`) over the sequence's own.
    pub layers: stillpoint_run::Overrides,
    /// Set to stop early.
    pub stop: Option<&'static AtomicBool>,
}

/// One replay.
#[derive(Clone, Debug, Serialize)]
pub struct RealtimeRow {
    /// Frames in the sequence.
    pub frames: usize,
    /// Frames the system processed (the rest were dropped while it was busy).
    pub processed: usize,
    /// Latency from a frame's arrival to its pose, ms: median, 95th percentile, max.
    pub latency_ms: [f64; 3],
    /// Processing time a frame, mean, ms.
    pub processing_ms_mean: f64,
    /// ATE RMSE, cm (with ground truth).
    pub ate_cm: Option<f64>,
    /// Map points lying on movers (with the generator's masks).
    pub moving_map_points: Option<usize>,
}

impl RealtimeRow {
    /// Share of the sequence's frames processed.
    pub fn processed_share(&self) -> f64 {
        self.processed as f64 / self.frames.max(1) as f64
    }
}

/// Replay `o.dataset` `o.runs` times at `o.rate_hz` on `o.cores` CPUs; `progress` sees each row.
pub fn run_realtime(
    o: &RealtimeOptions,
    progress: &mut (dyn FnMut(usize, &RealtimeRow) + Send),
) -> Result<Vec<RealtimeRow>, BenchError> {
    if o.runs == 0 {
        return Err(BenchError::Invalid("--runs must be at least 1".into()));
    }
    std::thread::scope(|scope| {
        scope
            .spawn(|| {
                if o.cores > 0 {
                    let kept = stillpoint_core::pin_this_thread_to_first_cpus(o.cores)
                        .map_err(|e| BenchError::Invalid(format!("--cores {}: {e}", o.cores)))?;
                    tracing::info!("runs kept to CPU(s) {kept:?}");
                }
                let mut rows = Vec::with_capacity(o.runs);
                for i in 0..o.runs {
                    let row = replay_once(o)?;
                    progress(i, &row);
                    rows.push(row);
                }
                Ok(rows)
            })
            .join()
            .unwrap_or_else(|payload| std::panic::resume_unwind(payload))
    })
}

fn replay_once(o: &RealtimeOptions) -> Result<RealtimeRow, BenchError> {
    let mut sets = o.layers.sets.clone();
    sets.push(format!("realtime.rate_hz={}", o.rate_hz));
    let s = stillpoint_eval::run_scored(
        &RunOptions {
            kind: o.kind,
            detector: o.detector.clone(),
            model: o.model.clone(),
            realtime: true,
            stop: o.stop,
            overrides: stillpoint_run::Overrides {
                sets,
                ..o.layers.clone()
            },
            ..RunOptions::new(o.dataset.clone())
        },
        &mut |_| {},
    )?;
    let replay = s.run.realtime.as_ref().ok_or_else(|| {
        BenchError::Invalid("the run reported no replay (was it a live camera?)".into())
    })?;
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    Ok(RealtimeRow {
        frames: s.run.frames,
        processed: replay.frames_processed,
        latency_ms: replay.latency_quantiles(),
        processing_ms_mean: mean(&replay.processing_ms),
        ate_cm: s.accuracy().map(|a| a.0.stats.rmse * 100.0),
        moving_map_points: s.moving_map_points.map(|m| m.lying),
    })
}
