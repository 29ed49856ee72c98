//! The paper's accuracy table: ATE RMSE / S.D. and translational RPE RMSE / S.D. over 1 s
//! (metres) of each sequence with the dynamic front-end off and on.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

use serde::Serialize;
use stillpoint_run::{Event, RunOptions};

use crate::BenchError;

/// Which sequences, and how the "on" runs detect.
#[derive(Clone, Debug)]
pub struct TumOptions {
    /// Sequence folders.
    pub datasets: Vec<PathBuf>,
    /// Detector of the "on" runs: yolox, gt or none.
    pub detector: String,
    /// Only the first N frames of each sequence.
    pub frames: Option<usize>,
    /// YOLOX ONNX model (else the default search).
    pub model: Option<PathBuf>,
    /// Set to stop the runs early.
    pub stop: Option<&'static AtomicBool>,
}

impl TumOptions {
    /// Every frame of `datasets`, the default model, no stop flag.
    pub fn new(datasets: Vec<PathBuf>, detector: &str) -> Self {
        Self {
            datasets,
            detector: detector.to_string(),
            frames: None,
            model: None,
            stop: None,
        }
    }
}

/// One run of the table.
#[derive(Clone, Debug, Serialize)]
pub struct TumRow {
    /// The sequence's name.
    pub sequence: String,
    /// The front-end was on.
    pub dynamic: bool,
    /// What detected (`off` without the front-end).
    pub detector: String,
    /// Frames with a pose.
    pub tracked: usize,
    /// Frames run.
    pub frames: usize,
    /// ATE RMSE, metres.
    pub ate_rmse: Option<f64>,
    /// ATE standard deviation, metres.
    pub ate_std: Option<f64>,
    /// Translational RPE RMSE over 1 s, metres.
    pub rpe_trans_rmse: Option<f64>,
    /// Translational RPE standard deviation, metres.
    pub rpe_trans_std: Option<f64>,
}

/// Run each sequence with the front-end off, then on (file runs: local mapping inline).
pub fn paper_table(
    o: &TumOptions,
    progress: &mut dyn FnMut(Event),
) -> Result<Vec<TumRow>, BenchError> {
    let mut rows = Vec::new();
    for d in &o.datasets {
        for on in [false, true] {
            let s = stillpoint_eval::run_scored(
                &RunOptions {
                    detector: on.then(|| o.detector.clone()),
                    frames: o.frames,
                    model: o.model.clone(),
                    stop: o.stop,
                    ..RunOptions::new(d.clone())
                },
                progress,
            )?;
            let acc = s.accuracy();
            let rpe = acc.as_ref().and_then(|a| a.1.as_ref());
            rows.push(TumRow {
                sequence: s.run.name.clone(),
                dynamic: on,
                detector: s.run.detector.clone(),
                tracked: s.run.tracked,
                frames: s.run.frames,
                ate_rmse: acc.as_ref().map(|a| a.0.stats.rmse),
                ate_std: acc.as_ref().map(|a| a.0.stats.std),
                rpe_trans_rmse: rpe.map(|r| r.translation.rmse),
                rpe_trans_std: rpe.map(|r| r.translation.std),
            });
        }
    }
    Ok(rows)
}
