//! `stillpoint bench detect`: per-frame detector latency (letterbox + inference + decode/NMS) for
//! each backend, 1 and 2 intra-op threads, and each model size; median of N runs after warm-up
//! (`stillpoint_bench::detector`). Speed is also given as a ratio to the reference measured in
//! the same run (the first row: first backend, first thread count, first model).

use anyhow::Result;
use serde_json::json;
use std::path::PathBuf;
use stillpoint_bench::detector::{DetectorOptions, measure};
use stillpoint_detect::Backend;

use super::shared_dir;

#[derive(clap::Args)]
pub struct Args {
    /// Models to time (default: ../shared/models/yolox_nano_480x640.onnx and _256x320.onnx).
    #[arg(long, num_args = 1..)]
    models: Vec<PathBuf>,
    /// Image to run on (default: ../shared/data/detector_images/tum_fr3_two_people.png).
    #[arg(long)]
    image: Option<PathBuf>,
    /// Timed runs per configuration (the median is reported).
    #[arg(long, default_value_t = 20)]
    runs: usize,
    /// Untimed runs first (caches, thread pools, lazy allocations).
    #[arg(long, default_value_t = 2)]
    warmup: usize,
    /// Thread counts to time.
    #[arg(long, num_args = 1.., default_values_t = [1usize, 2])]
    threads: Vec<usize>,
    /// Backends to time (default: those available: tract in a build with it, ort when its
    /// library is found).
    #[arg(long, num_args = 1..)]
    backends: Vec<Backend>,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
}

pub fn run(args: Args) -> Result<()> {
    let models = if args.models.is_empty() {
        ["yolox_nano_480x640.onnx", "yolox_nano_256x320.onnx"]
            .iter()
            .map(|m| shared_dir().join("models").join(m))
            .collect()
    } else {
        args.models.clone()
    };
    let image = args
        .image
        .clone()
        .unwrap_or_else(|| shared_dir().join("data/detector_images/tum_fr3_two_people.png"));
    let report = measure(&DetectorOptions {
        models,
        image: image.clone(),
        runs: args.runs,
        warmup: args.warmup,
        threads: args.threads.clone(),
        backends: args.backends.clone(),
    })?;
    let rows = &report.rows;
    let [width, height] = report.image_size;
    let reference = rows.first().map(|r| r.median_ms).unwrap_or(f64::NAN);
    if args.json {
        let out: Vec<_> = rows
            .iter()
            .map(|r| {
                json!({
                    "model": r.model, "input": r.input, "backend": r.backend, "threads": r.threads,
                    "median_ms": r.median_ms, "min_ms": r.min_ms, "boxes": r.boxes,
                    "cpu_ms_per_frame": r.cpu_ms_per_frame,
                    "speedup_vs_reference": reference / r.median_ms,
                })
            })
            .collect();
        let doc = json!({
            "image": image,
            "image_size": [width, height],
            "runs": args.runs,
            "reference": rows.first().map(|r| format!("{} {} {} thread(s)", r.backend, r.input, r.threads)),
            "results": out,
        });
        println!("{}", serde_json::to_string_pretty(&doc)?);
    } else {
        println!(
            "# {} ({}x{}), median of {} runs; speed-up vs the first row",
            image.display(),
            width,
            height,
            args.runs
        );
        println!(
            "{:<8} {:<8} {:>7} {:>10} {:>10} {:>9} {:>13} {:>6}",
            "backend",
            "input",
            "threads",
            "median ms",
            "min ms",
            "speed-up",
            "cpu ms/frame",
            "boxes"
        );
        for r in rows {
            println!(
                "{:<8} {:<8} {:>7} {:>10.1} {:>10.1} {:>8.2}x {:>13.1} {:>6}",
                r.backend,
                r.input,
                r.threads,
                r.median_ms,
                r.min_ms,
                reference / r.median_ms,
                r.cpu_ms_per_frame,
                r.boxes
            );
        }
    }
    Ok(())
}
