//! `stillpoint bench features`: ms per frame of each front-end stage (ORB: pyramid, FAST,
//! distribution, orientation + descriptors; Harris + sub-pixel; LK of the corners into the next
//! image), and the same measured for OpenCV by `bench/opencv_features.py` in the same run, so the
//! ratios compare like with like. Build with `--release`.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, bail};
use serde_json::{Value, json};
use stillpoint_features::{
    CornerParams, LkParams, OrbExtractor, OrbParams, good_features_to_track, track_lk,
};
use stillpoint_image::{Gray8, read_gray};

#[derive(clap::Args)]
pub struct Args {
    /// Images to run on (PNG/JPEG; colour is converted to gray). Image i is tracked into image
    /// i+1. Default: the TUM pair and the first TUM walking frames in ../shared/data.
    pub images: Vec<PathBuf>,
    /// Times each image is processed.
    #[arg(long, default_value_t = 20)]
    pub repeat: usize,
    /// ORB features per image (ORB-SLAM: 1000 TUM, 2000 KITTI).
    #[arg(long, default_value_t = 1000)]
    pub features: usize,
    /// Python interpreter for the OpenCV reference.
    #[arg(long, default_value = "python3")]
    pub python: String,
    /// Threads OpenCV may use (1 = like ours, single-threaded).
    #[arg(long, default_value_t = 1)]
    pub opencv_threads: usize,
    /// Skip the OpenCV reference.
    #[arg(long)]
    pub no_opencv: bool,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

fn shared_dir() -> PathBuf {
    std::env::var_os("STILLPOINT_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("../shared"))
}

fn default_images() -> Vec<PathBuf> {
    let d = shared_dir().join("data");
    let mut v = vec![
        d.join("rgbd_pairs/pair/1.png"),
        d.join("rgbd_pairs/pair/2.png"),
    ];
    let tum = d.join("tum/fr3_walking_halfsphere_first10_rgb/rgb");
    if let Ok(rd) = std::fs::read_dir(&tum) {
        let mut f: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).collect();
        f.sort();
        v.extend(f.into_iter().take(4));
    }
    v
}

fn stats(xs: &mut [f64]) -> Value {
    xs.sort_by(f64::total_cmp);
    if xs.is_empty() {
        return json!({"median": null, "p90": null, "n": 0});
    }
    let p90 = ((xs.len() as f64 * 0.9) as usize).min(xs.len() - 1);
    json!({"median": xs[xs.len() / 2], "p90": xs[p90], "n": xs.len()})
}

/// Find `bench/opencv_features.py` next to the working directory or the executable's repo.
fn script_path() -> Option<PathBuf> {
    let cands = [
        PathBuf::from("bench/opencv_features.py"),
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("bench/opencv_features.py"),
    ];
    cands.into_iter().find(|p| p.is_file())
}

fn run_opencv(args: &Args, images: &[PathBuf]) -> anyhow::Result<Value> {
    let script = script_path().context("bench/opencv_features.py not found")?;
    let out = Command::new(&args.python)
        .arg(&script)
        .arg("speed")
        .args(images)
        .arg("--repeat")
        .arg(args.repeat.to_string())
        .arg("--threads")
        .arg(args.opencv_threads.to_string())
        .output()
        .with_context(|| format!("cannot run {} {}", args.python, script.display()))?;
    if !out.status.success() {
        bail!(
            "{} failed: {}",
            script.display(),
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    serde_json::from_slice(&out.stdout)
        .with_context(|| format!("{}: output is not JSON", script.display()))
}

fn load(paths: &[PathBuf]) -> anyhow::Result<Vec<Gray8>> {
    paths
        .iter()
        .map(|p: &PathBuf| {
            read_gray(Path::new(p)).with_context(|| format!("reading {}", p.display()))
        })
        .collect()
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let images = if args.images.is_empty() {
        default_images()
    } else {
        args.images.clone()
    };
    if images.is_empty() {
        bail!("no images given");
    }
    let imgs = load(&images)?;
    tracing::info!(
        "{} images, {} repeats, {} ORB features",
        imgs.len(),
        args.repeat,
        args.features
    );
    let mut orb = OrbExtractor::new(OrbParams {
        n_features: args.features,
        ..OrbParams::default()
    });
    let cp = CornerParams::default();
    let lp = LkParams::default();
    let names = [
        "pyramid",
        "fast",
        "distribution",
        "describe",
        "orb",
        "harris_subpix",
        "lk",
        "harris_lk",
    ];
    let mut t: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    let (mut nfeat, mut ncorn, mut ntrack) = (0usize, 0usize, 0usize);
    let mut runs = 0usize;
    for _ in 0..args.repeat.max(1) {
        for (i, img) in imgs.iter().enumerate() {
            let next = &imgs[(i + 1) % imgs.len()];
            let next = if (next.width, next.height) == (img.width, img.height) {
                next
            } else {
                img
            };
            let t0 = Instant::now();
            let f = orb.extract(img);
            let orb_ms = t0.elapsed().as_secs_f64() * 1e3;
            let t1 = Instant::now();
            let corners = good_features_to_track(img, &cp);
            let t2 = Instant::now();
            // pyramids of both images + tracking, the work calcOpticalFlowPyrLK does
            let tracked = track_lk(img, next, &corners, &lp);
            let t3 = Instant::now();
            let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
            let st = orb.timings();
            for (k, v) in [
                st.pyramid_ms,
                st.fast_ms,
                st.distribute_ms,
                st.describe_ms,
                orb_ms,
                ms(t1, t2),
                ms(t2, t3),
                ms(t1, t3),
            ]
            .into_iter()
            .enumerate()
            {
                t[k].push(v);
            }
            nfeat += f.keypoints.len();
            ncorn += corners.len();
            ntrack += tracked.iter().flatten().count();
            runs += 1;
        }
    }
    let mut ours = serde_json::Map::new();
    for (n, v) in names.iter().zip(t.iter_mut()) {
        ours.insert(n.to_string(), stats(v));
    }
    ours.insert("features_mean".into(), json!(nfeat as f64 / runs as f64));
    ours.insert("corners_mean".into(), json!(ncorn as f64 / runs as f64));
    ours.insert("tracked_mean".into(), json!(ntrack as f64 / runs as f64));
    let opencv = if args.no_opencv {
        None
    } else {
        match run_opencv(&args, &images) {
            Ok(v) => Some(v),
            Err(e) => {
                tracing::warn!("OpenCV reference skipped: {e:#}");
                None
            }
        }
    };
    // ratio = ours / OpenCV on the median (below 1 = faster than OpenCV)
    let compare = ["orb", "harris_subpix", "lk", "harris_lk"];
    let ratios: serde_json::Map<String, Value> = match &opencv {
        Some(cv) => compare
            .iter()
            .filter_map(|k| {
                let a = ours.get(*k)?.get("median")?.as_f64()?;
                let b = cv.get(*k)?.get("median")?.as_f64()?;
                Some((k.to_string(), json!(a / b)))
            })
            .collect(),
        None => serde_json::Map::new(),
    };
    if args.json {
        let out = json!({
            "images": images,
            "repeat": args.repeat,
            "stillpoint": ours,
            "opencv": opencv,
            "ratio_vs_opencv": ratios,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    let med = |m: &serde_json::Map<String, Value>, k: &str, q: &str| {
        m.get(k)
            .and_then(|v| v.get(q))
            .and_then(Value::as_f64)
            .map(|v| format!("{v:8.3}"))
            .unwrap_or_else(|| format!("{:>8}", "-"))
    };
    let cvm = opencv.as_ref().and_then(Value::as_object);
    println!(
        "{} images x {} repeats; ms per frame (median / p90)",
        imgs.len(),
        args.repeat
    );
    println!(
        "{:<14} {:>8} {:>8}   {:>8} {:>8}   {:>7}",
        "stage", "ours", "p90", "opencv", "p90", "ratio"
    );
    for n in names {
        let (cm, cp90) = match cvm {
            Some(m) => (med(m, n, "median"), med(m, n, "p90")),
            None => (format!("{:>8}", "-"), format!("{:>8}", "-")),
        };
        let r = ratios
            .get(n)
            .and_then(Value::as_f64)
            .map(|r| format!("{r:7.2}"))
            .unwrap_or_else(|| format!("{:>7}", "-"));
        println!(
            "{:<14} {} {}   {} {}   {}",
            n,
            med(&ours, n, "median"),
            med(&ours, n, "p90"),
            cm,
            cp90,
            r
        );
    }
    println!(
        "features/frame {:.0}, corners/frame {:.0}, tracked/frame {:.0}{}",
        nfeat as f64 / runs as f64,
        ncorn as f64 / runs as f64,
        ntrack as f64 / runs as f64,
        match cvm {
            Some(m) => format!(
                "  (OpenCV {}: {:.0} / {:.0} / {:.0}, {} thread(s))",
                m.get("opencv").and_then(Value::as_str).unwrap_or("?"),
                m.get("features_mean")
                    .and_then(Value::as_f64)
                    .unwrap_or(0.0),
                m.get("corners_mean").and_then(Value::as_f64).unwrap_or(0.0),
                m.get("tracked_mean").and_then(Value::as_f64).unwrap_or(0.0),
                m.get("threads").and_then(Value::as_u64).unwrap_or(0),
            ),
            None => String::new(),
        }
    );
    Ok(())
}
