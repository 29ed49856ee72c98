//! `stillpoint bench features`: ms per frame of each front-end stage against OpenCV's, measured
//! in the same run with rounds alternating (`stillpoint_bench::features`). Build with
//! `--release`.

use std::path::PathBuf;

use serde_json::{Value, json};
use stillpoint_bench::features::{FeatureOptions, StageTimes, measure};

use super::shared_dir;

#[derive(clap::Args)]
pub struct Args {
    /// Images to run on (PNG/JPEG; colour is converted to gray). Image i is tracked into image
    /// i+1. Default: the TUM pair and the first TUM walking frames in ../shared/data.
    pub images: Vec<PathBuf>,
    /// Rounds (every image once per round, ours and OpenCV's alternating).
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

fn times_json(t: &StageTimes) -> Value {
    json!({"median": t.median, "p90": t.p90, "n": t.n})
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let images = if args.images.is_empty() {
        default_images()
    } else {
        args.images.clone()
    };
    let r = measure(&FeatureOptions {
        images,
        repeat: args.repeat,
        features: args.features,
        python: (!args.no_opencv).then(|| args.python.clone()),
        opencv_threads: args.opencv_threads,
    })?;
    let mut ours = serde_json::Map::new();
    for (n, t) in &r.ours {
        ours.insert(n.to_string(), times_json(t));
    }
    ours.insert("features_mean".into(), json!(r.counts.features));
    ours.insert("corners_mean".into(), json!(r.counts.corners));
    ours.insert("tracked_mean".into(), json!(r.counts.tracked));
    let opencv = r.opencv.as_ref().map(|cv| {
        let mut m = serde_json::Map::new();
        for (k, t) in &cv.stages {
            m.insert(k.to_string(), times_json(t));
        }
        m.insert("features_mean".into(), json!(cv.counts.features));
        m.insert("corners_mean".into(), json!(cv.counts.corners));
        m.insert("tracked_mean".into(), json!(cv.counts.tracked));
        m.insert("opencv".into(), cv.version.clone());
        m.insert("threads".into(), cv.threads.clone());
        Value::Object(m)
    });
    let ratios: serde_json::Map<String, Value> = r
        .ratios
        .iter()
        .map(|(k, v)| (k.to_string(), json!(v)))
        .collect();
    let by_size: Vec<Value> = r
        .orb_by_size
        .iter()
        .map(|g| {
            json!({
                "width": g.size.0,
                "height": g.size.1,
                "images": g.images,
                "ours_ms": g.ours_ms,
                "opencv_orb_ms": g.opencv_ms[0],
                "opencv_orb_default_ms": g.opencv_ms[1],
                "ratio_vs_orb": g.ratios[0],
                "ratio_vs_orb_default": g.ratios[1],
            })
        })
        .collect();
    let [load_before, load_after] = r.load_average;
    if args.json {
        let out = json!({
            "images": r.images,
            "repeat": r.repeat,
            "stillpoint": ours,
            "opencv": opencv,
            "ratio_vs_opencv": ratios,
            "orb_by_size": by_size,
            "load_average_1min": [load_before, load_after],
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
        "{} images x {} rounds, ours and OpenCV alternating; ms per frame (median / p90); ratio = median of per-round ratios",
        r.images.len(),
        args.repeat
    );
    println!(
        "{:<14} {:>8} {:>8}   {:>8} {:>8}   {:>7}",
        "stage", "ours", "p90", "opencv", "p90", "ratio"
    );
    // every stage of ours; OpenCV's second ORB (its default border) right under ours
    let rows = stillpoint_bench::features::STAGES.iter().flat_map(|n| {
        let extra = (*n == "orb").then_some(("orb_default", "orb"));
        std::iter::once((*n, *n)).chain(extra)
    });
    for (name, ours_name) in rows {
        let (cm, cp90) = match cvm {
            Some(m) => (med(m, name, "median"), med(m, name, "p90")),
            None => (format!("{:>8}", "-"), format!("{:>8}", "-")),
        };
        let r = ratios
            .get(name)
            .and_then(Value::as_f64)
            .map(|r| format!("{r:7.2}"))
            .unwrap_or_else(|| format!("{:>7}", "-"));
        println!(
            "{:<14} {} {}   {} {}   {}",
            name,
            med(&ours, ours_name, "median"),
            med(&ours, ours_name, "p90"),
            cm,
            cp90,
            r
        );
    }
    let num = |v: Option<f64>, p: usize| v.map_or_else(|| "-".to_string(), |v| format!("{v:.p$}"));
    println!("ORB by image size: ours ms, OpenCV orb / orb_default ms, ratios");
    for g in &r.orb_by_size {
        println!(
            "  {}x{} ({} images): {} ms vs {} / {} ms, ratio {} / {}",
            g.size.0,
            g.size.1,
            g.images,
            num(g.ours_ms, 3),
            num(g.opencv_ms[0], 3),
            num(g.opencv_ms[1], 3),
            num(g.ratios[0], 2),
            num(g.ratios[1], 2)
        );
    }
    let fmt_load = |l: Option<f64>| l.map_or_else(|| "?".to_string(), |l| format!("{l:.2}"));
    println!(
        "load average (1 min) before / after: {} / {}",
        fmt_load(load_before),
        fmt_load(load_after)
    );
    println!(
        "features/frame {:.0}, corners/frame {:.0}, tracked/frame {:.0}{}",
        r.counts.features,
        r.counts.corners,
        r.counts.tracked,
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
