//! Per-frame detector latency (letterbox + inference + decode/NMS) for each backend, thread
//! count and model; median of N runs after warm-up, with the on-CPU time per frame.

use std::path::PathBuf;
use std::time::Instant;

use stillpoint_detect::{Backend, DetectInput, DetectSettings, Detector, YoloxDetector, backend};

use crate::BenchError;

/// What is timed.
#[derive(Clone, Debug)]
pub struct DetectorOptions {
    /// Models to time.
    pub models: Vec<PathBuf>,
    /// The image to run on.
    pub image: PathBuf,
    /// Timed runs per configuration (the median is reported).
    pub runs: usize,
    /// Untimed runs first (caches, thread pools, lazy allocations).
    pub warmup: usize,
    /// Thread counts to time.
    pub threads: Vec<usize>,
    /// Backends to time; empty: those available (`backend::available`).
    pub backends: Vec<Backend>,
}

/// One configuration timed.
#[derive(Clone, Debug)]
pub struct DetectorRow {
    /// The model's file name.
    pub model: String,
    /// Its input size, `HxW`.
    pub input: String,
    /// The backend's name.
    pub backend: &'static str,
    /// Intra-op threads.
    pub threads: usize,
    /// Median latency, ms.
    pub median_ms: f64,
    /// Fastest run, ms.
    pub min_ms: f64,
    /// Boxes found on the image.
    pub boxes: usize,
    /// On-CPU time of all threads per frame, ms (NaN where it cannot be read).
    pub cpu_ms_per_frame: f64,
}

/// The measurement.
#[derive(Clone, Debug)]
pub struct DetectorReport {
    /// The image's size (width, height).
    pub image_size: [usize; 2],
    /// One row per model x backend x threads, the reference (the ratios' denominator) first.
    pub rows: Vec<DetectorRow>,
}

/// On-CPU time of all this process's threads, in ns (Linux `/proc/self/task/*/schedstat`), so
/// the report also shows compute per frame, which a busy machine does not inflate like wall time.
fn process_cpu_ns() -> Option<u64> {
    let mut total = 0u64;
    for task in std::fs::read_dir("/proc/self/task").ok()? {
        let stat = std::fs::read_to_string(task.ok()?.path().join("schedstat")).ok()?;
        total += stat.split_whitespace().next()?.parse::<u64>().ok()?;
    }
    Some(total)
}

/// Time every model x backend x thread count.
pub fn measure(o: &DetectorOptions) -> Result<DetectorReport, BenchError> {
    if o.runs == 0 || o.threads.contains(&0) {
        return Err(BenchError::Invalid(
            "--runs and --threads must be at least 1".into(),
        ));
    }
    let rgb = stillpoint_image::read_rgb(&o.image).map_err(|source| BenchError::Image {
        context: "bench image (set --image)".into(),
        source,
    })?;
    let backends = if o.backends.is_empty() {
        let b = backend::available(None);
        if !b.contains(&Backend::Ort) {
            tracing::warn!(
                "ONNX Runtime not found (scripts/setup-onnxruntime.sh, ORT_DYLIB_PATH): not timed"
            );
        }
        if b.is_empty() {
            return Err(BenchError::Invalid(
                "no inference backend: build with --features tract, or run \
                 scripts/setup-onnxruntime.sh and set ORT_DYLIB_PATH"
                    .into(),
            ));
        }
        b
    } else {
        o.backends.clone()
    };
    let mut rows = Vec::new();
    for model in &o.models {
        for &be in &backends {
            for &threads in &o.threads {
                let settings = DetectSettings {
                    backend: be,
                    threads,
                    ..Default::default()
                };
                let mut det =
                    YoloxDetector::load(model, &settings).map_err(|source| BenchError::Detect {
                        context: format!("loading {} with {}", model.display(), be.as_str()),
                        source,
                    })?;
                let input = DetectInput {
                    index: 0,
                    timestamp: 0.0,
                    rgb: &rgb,
                };
                let failed = |source| BenchError::Detect {
                    context: format!("{} with {}", model.display(), be.as_str()),
                    source,
                };
                let mut boxes = 0;
                for _ in 0..o.warmup {
                    boxes = det.detect(&input).map_err(failed)?.len();
                }
                let cpu_before = process_cpu_ns();
                let times: Vec<f64> = (0..o.runs)
                    .map(|_| {
                        let t = Instant::now();
                        det.detect(&input).map(|d| {
                            boxes = d.len();
                            stillpoint_core::ms_since(t)
                        })
                    })
                    .collect::<Result<_, _>>()
                    .map_err(failed)?;
                let cpu_ms = match (cpu_before, process_cpu_ns()) {
                    (Some(a), Some(b)) => b.saturating_sub(a) as f64 / 1e6 / o.runs as f64,
                    _ => f64::NAN,
                };
                let min = times.iter().copied().fold(f64::INFINITY, f64::min);
                let med = stillpoint_eval::stats::median(&times);
                let (h, w) = det.input_size();
                tracing::info!("{} {h}x{w} {threads} thread(s): {med:.1} ms", be.as_str());
                rows.push(DetectorRow {
                    model: model
                        .file_name()
                        .unwrap_or_default()
                        .to_string_lossy()
                        .to_string(),
                    input: format!("{h}x{w}"),
                    backend: be.as_str(),
                    threads,
                    median_ms: med,
                    min_ms: min,
                    boxes,
                    cpu_ms_per_frame: cpu_ms,
                });
            }
        }
    }
    Ok(DetectorReport {
        image_size: [rgb.width, rgb.height],
        rows,
    })
}
