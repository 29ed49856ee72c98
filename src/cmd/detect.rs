//! `stillpoint detect`: run YOLOX on images, print the boxes, optionally draw them.

use anyhow::{Context, Result};
use serde_json::json;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;
use stillpoint_detect::{
    Backend, DetectInput, DetectSettings, Detection, Detector, YoloxDetector, draw, model,
    settings::load_toml,
};

#[derive(clap::Args)]
pub struct Args {
    /// Images to run the detector on (PNG or JPEG).
    #[arg(required = true)]
    images: Vec<PathBuf>,
    /// YOLOX ONNX model. Default: the settings' `model`, then $STILLPOINT_MODEL, then
    /// models/yolox_nano.onnx beside the binary, then ../shared/models/yolox_nano_480x640.onnx.
    #[arg(long)]
    model: Option<PathBuf>,
    /// TOML settings file whose `[detect]` table sets model, backend, threads, thresholds.
    #[arg(long)]
    settings: Option<PathBuf>,
    /// Inference backend: ort (ONNX Runtime; scripts/setup-onnxruntime.sh) or tract (pure Rust; a
    /// build with `--features tract`, whose default it is).
    #[arg(long)]
    backend: Option<Backend>,
    /// Intra-op threads of the backend.
    #[arg(long)]
    threads: Option<usize>,
    /// Score threshold (objectness x class).
    #[arg(long)]
    conf: Option<f32>,
    /// Class-wise NMS IoU threshold.
    #[arg(long)]
    nms: Option<f32>,
    /// Print one JSON array instead of text.
    #[arg(long)]
    json: bool,
    /// Draw the boxes into this PNG (with several images: one file per image, named
    /// `<stem>_<image stem>.png`).
    #[arg(long)]
    draw: Option<PathBuf>,
}

/// Settings from the file (if any) with the command line on top.
fn merged_settings(args: &Args) -> Result<DetectSettings> {
    let mut s = match &args.settings {
        Some(path) => load_toml(path)?,
        None => DetectSettings::default(),
    };
    if args.model.is_some() {
        s.model = args.model.clone();
    }
    if let Some(b) = args.backend {
        s.backend = b;
    }
    if let Some(t) = args.threads {
        s.threads = t;
    }
    if let Some(c) = args.conf {
        s.conf_threshold = c;
    }
    if let Some(n) = args.nms {
        s.nms_threshold = n;
    }
    s.validate()?;
    Ok(s)
}

fn draw_path(draw: &Path, image: &Path, several: bool) -> PathBuf {
    if !several {
        return draw.to_path_buf();
    }
    let stem = draw.file_stem().unwrap_or_default().to_string_lossy();
    let image_stem = image.file_stem().unwrap_or_default().to_string_lossy();
    draw.with_file_name(format!("{stem}_{image_stem}.png"))
}

fn detection_json(d: &Detection) -> serde_json::Value {
    json!({
        "class_id": d.class_id,
        "class_name": d.class_name(),
        "score": d.score,
        "bbox": [d.bbox.x1, d.bbox.y1, d.bbox.x2, d.bbox.y2],
    })
}

pub fn run(args: Args) -> Result<()> {
    let settings = merged_settings(&args)?;
    let model_path = model::resolve_model(settings.model.as_deref())?;
    let started = Instant::now();
    let mut detector = YoloxDetector::load(&model_path, &settings)
        .with_context(|| format!("loading the {} backend", settings.backend.as_str()))?;
    let (h, w) = detector.input_size();
    tracing::info!(
        "{} loaded {} ({h}x{w} input, {} thread(s)) in {:.0} ms",
        detector.name(),
        model_path.display(),
        settings.threads,
        started.elapsed().as_secs_f64() * 1e3
    );
    let several = args.images.len() > 1;
    let mut stdout = std::io::stdout().lock();
    let mut report = Vec::new();
    for (index, path) in args.images.iter().enumerate() {
        let mut rgb = stillpoint_image::read_rgb(path)?;
        let t0 = Instant::now();
        let dets = detector
            .detect(&DetectInput {
                index,
                timestamp: 0.0,
                rgb: &rgb,
            })
            .with_context(|| format!("{}: detection failed", path.display()))?;
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        tracing::info!("{}: {} boxes in {ms:.1} ms", path.display(), dets.len());
        if args.json {
            report.push(json!({
                "image": path,
                "width": rgb.width,
                "height": rgb.height,
                "model": model_path,
                "backend": settings.backend.as_str(),
                "milliseconds": ms,
                "detections": dets.iter().map(detection_json).collect::<Vec<_>>(),
            }));
        } else {
            writeln!(stdout, "# {} ({} boxes)", path.display(), dets.len())?;
            for d in &dets {
                writeln!(
                    stdout,
                    "{:<14} {:.3} {:7.1} {:7.1} {:7.1} {:7.1}",
                    d.class_name(),
                    d.score,
                    d.bbox.x1,
                    d.bbox.y1,
                    d.bbox.x2,
                    d.bbox.y2
                )?;
            }
        }
        if let Some(draw) = &args.draw {
            let out = draw_path(draw, path, several);
            draw::draw_detections(&mut rgb, &dets);
            stillpoint_image::write_rgb(&out, &rgb)?;
            tracing::info!("drew {} boxes into {}", dets.len(), out.display());
        }
    }
    if args.json {
        writeln!(stdout, "{}", serde_json::to_string_pretty(&report)?)?;
    }
    Ok(())
}
