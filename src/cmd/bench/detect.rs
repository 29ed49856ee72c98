//! `stillpoint bench detect`: per-frame detector latency (letterbox + inference + decode/NMS) for
//! each backend, 1 and 2 intra-op threads, and each model size; median of N runs after warm-up.
//! Speed is also given as a ratio to the reference measured in the same run (tract, 1 thread,
//! first model).

use anyhow::{Context, Result, bail};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;
use stillpoint_detect::{Backend, DetectInput, DetectSettings, Detector, YoloxDetector, backend};

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
    /// Backends to time (default: tract, and ort when its library is found).
    #[arg(long, num_args = 1..)]
    backends: Vec<Backend>,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
}

fn shared() -> PathBuf {
    std::env::var_os("STILLPOINT_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("../shared"))
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

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

pub fn run(args: Args) -> Result<()> {
    if args.runs == 0 || args.threads.contains(&0) {
        bail!("--runs and --threads must be at least 1");
    }
    let models = if args.models.is_empty() {
        ["yolox_nano_480x640.onnx", "yolox_nano_256x320.onnx"]
            .iter()
            .map(|m| shared().join("models").join(m))
            .collect()
    } else {
        args.models.clone()
    };
    let image = args
        .image
        .clone()
        .unwrap_or_else(|| shared().join("data/detector_images/tum_fr3_two_people.png"));
    let rgb = stillpoint_image::read_rgb(&image).context("bench image (set --image)")?;
    let backends = if args.backends.is_empty() {
        let mut b = vec![Backend::Tract];
        if backend::ort_dylib_available(None) {
            b.push(Backend::Ort);
        } else {
            tracing::warn!(
                "ONNX Runtime not found (scripts/setup-onnxruntime.sh, ORT_DYLIB_PATH): timing tract only"
            );
        }
        b
    } else {
        args.backends.clone()
    };
    let mut rows = Vec::new();
    for model in &models {
        for &be in &backends {
            for &threads in &args.threads {
                let settings = DetectSettings {
                    backend: be,
                    threads,
                    ..Default::default()
                };
                let mut det = YoloxDetector::load(model, &settings)
                    .with_context(|| format!("loading {} with {}", model.display(), be.as_str()))?;
                let input = DetectInput {
                    index: 0,
                    timestamp: 0.0,
                    rgb: &rgb,
                };
                let mut boxes = 0;
                for _ in 0..args.warmup {
                    boxes = det.detect(&input)?.len();
                }
                let cpu_before = process_cpu_ns();
                let mut times: Vec<f64> = (0..args.runs)
                    .map(|_| {
                        let t = Instant::now();
                        det.detect(&input).map(|d| {
                            boxes = d.len();
                            t.elapsed().as_secs_f64() * 1e3
                        })
                    })
                    .collect::<Result<_, _>>()?;
                let cpu_ms = match (cpu_before, process_cpu_ns()) {
                    (Some(a), Some(b)) => b.saturating_sub(a) as f64 / 1e6 / args.runs as f64,
                    _ => f64::NAN,
                };
                let min = times.iter().copied().fold(f64::INFINITY, f64::min);
                let med = median(&mut times);
                let (h, w) = det.input_size();
                tracing::info!("{} {h}x{w} {threads} thread(s): {med:.1} ms", be.as_str());
                rows.push((
                    model
                        .file_name()
                        .unwrap_or_default()
                        .to_string_lossy()
                        .to_string(),
                    format!("{h}x{w}"),
                    be.as_str(),
                    threads,
                    med,
                    min,
                    boxes,
                    cpu_ms,
                ));
            }
        }
    }
    let reference = rows.first().map(|r| r.4).unwrap_or(f64::NAN);
    if args.json {
        let out: Vec<_> = rows
            .iter()
            .map(|(model, size, be, threads, med, min, boxes, cpu)| {
                json!({
                    "model": model, "input": size, "backend": be, "threads": threads,
                    "median_ms": med, "min_ms": min, "boxes": boxes,
                    "cpu_ms_per_frame": cpu,
                    "speedup_vs_reference": reference / med,
                })
            })
            .collect();
        let doc = json!({
            "image": image,
            "image_size": [rgb.width, rgb.height],
            "runs": args.runs,
            "reference": rows.first().map(|r| format!("{} {} {} thread(s)", r.2, r.1, r.3)),
            "results": out,
        });
        println!("{}", serde_json::to_string_pretty(&doc)?);
    } else {
        println!(
            "# {} ({}x{}), median of {} runs; speed-up vs the first row",
            image.display(),
            rgb.width,
            rgb.height,
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
        for (_, size, be, threads, med, min, boxes, cpu) in &rows {
            println!(
                "{be:<8} {size:<8} {threads:>7} {med:>10.1} {min:>10.1} {:>8.2}x {cpu:>13.1} {boxes:>6}",
                reference / med
            );
        }
    }
    Ok(())
}
