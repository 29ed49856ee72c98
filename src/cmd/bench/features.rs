//! `stillpoint bench features`: ms per frame of each front-end stage (ORB: pyramid, FAST,
//! distribution, orientation + descriptors; Harris + sub-pixel; LK of the corners into the next
//! image), and the same measured for OpenCV by `bench/opencv_features.py` in the same run, so the
//! ratios compare like with like: our rounds and OpenCV's alternate (the script runs as a child
//! serving one round per request), and each ratio is the median of per-round ratios. Build with
//! `--release`.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
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

/// The OpenCV reference as a child process that runs one round (every image once) per request,
/// so our rounds and OpenCV's alternate and load changes on the machine hit both sides alike.
struct OpenCvServer {
    child: std::process::Child,
    stdin: std::process::ChildStdin,
    stdout: std::io::BufReader<std::process::ChildStdout>,
    /// The header line: OpenCV version and threads.
    header: Value,
}

impl OpenCvServer {
    fn start(args: &Args, images: &[PathBuf]) -> anyhow::Result<Self> {
        let script = script_path().context("bench/opencv_features.py not found")?;
        let mut child = Command::new(&args.python)
            .arg(&script)
            .arg("serve")
            .args(images)
            .arg("--threads")
            .arg(args.opencv_threads.to_string())
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .with_context(|| format!("cannot run {} {}", args.python, script.display()))?;
        let stdin = child.stdin.take().context("no stdin")?;
        let stdout = BufReader::new(child.stdout.take().context("no stdout")?);
        let mut s = Self {
            child,
            stdin,
            stdout,
            header: Value::Null,
        };
        s.header = s
            .read_line()
            .with_context(|| format!("{}: no header (is OpenCV installed?)", script.display()))?;
        Ok(s)
    }

    fn read_line(&mut self) -> anyhow::Result<Value> {
        let mut line = String::new();
        if self.stdout.read_line(&mut line)? == 0 {
            bail!("the OpenCV reference exited");
        }
        serde_json::from_str(&line).context("OpenCV reference output is not JSON")
    }

    /// One round: per-frame ms of each stage, and the counts.
    fn round(&mut self) -> anyhow::Result<Value> {
        writeln!(self.stdin, "round")?;
        self.stdin.flush()?;
        self.read_line()
    }
}

impl Drop for OpenCvServer {
    fn drop(&mut self) {
        // closing stdin ends the script's loop
        let _ = writeln!(self.stdin, "quit");
        let _ = self.stdin.flush();
        let _ = self.child.wait();
    }
}

/// The 1-minute load average (Linux `/proc/loadavg`), printed with the results: absolute ms on a
/// shared machine mean little without it (the ratios are measured interleaved).
fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

fn median(xs: &[f64]) -> Option<f64> {
    let mut v = xs.to_vec();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied()
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
    let load_before = load_average();
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
    let mut cv = if args.no_opencv {
        None
    } else {
        match OpenCvServer::start(&args, &images) {
            Ok(s) => Some(s),
            Err(e) => {
                tracing::warn!("OpenCV reference skipped: {e:#}");
                None
            }
        }
    };
    let compare = ["orb", "harris_subpix", "lk", "harris_lk"];
    let mut cv_t: Vec<Vec<f64>> = vec![Vec::new(); compare.len()];
    let mut cv_counts = [0f64; 3];
    // per round: median of ours / median of OpenCV's, for each compared stage
    let mut round_ratios: Vec<Vec<f64>> = vec![Vec::new(); compare.len()];
    for round in 0..args.repeat.max(1) {
        // alternate who goes first, so neither side always runs on a cache warmed by the other
        let cv_first = round % 2 == 1;
        let mut cv_round = None;
        if cv_first && let Some(s) = cv.as_mut() {
            cv_round = Some(s.round()?);
        }
        let mut ours_round: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
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
                ours_round[k].push(v);
            }
            nfeat += f.keypoints.len();
            ncorn += corners.len();
            ntrack += tracked.iter().flatten().count();
            runs += 1;
        }
        if !cv_first && let Some(s) = cv.as_mut() {
            cv_round = Some(s.round()?);
        }
        if let Some(r) = &cv_round {
            for (c, k) in compare.iter().enumerate() {
                let v: Vec<f64> = r["times"][*k]
                    .as_array()
                    .map(|a| a.iter().filter_map(Value::as_f64).collect())
                    .unwrap_or_default();
                let ours_k = names.iter().position(|n| n == k).unwrap_or(0);
                if let (Some(a), Some(b)) = (median(&ours_round[ours_k]), median(&v))
                    && b > 0.0
                {
                    round_ratios[c].push(a / b);
                }
                cv_t[c].extend(v);
            }
            for (n, k) in ["features", "corners", "tracked"].iter().enumerate() {
                if let Some(a) = r["counts"][*k].as_array() {
                    cv_counts[n] += a.iter().filter_map(Value::as_f64).sum::<f64>();
                }
            }
        }
        for (all, r) in t.iter_mut().zip(ours_round) {
            all.extend(r);
        }
    }
    let mut ours = serde_json::Map::new();
    for (n, v) in names.iter().zip(t.iter_mut()) {
        ours.insert(n.to_string(), stats(v));
    }
    ours.insert("features_mean".into(), json!(nfeat as f64 / runs as f64));
    ours.insert("corners_mean".into(), json!(ncorn as f64 / runs as f64));
    ours.insert("tracked_mean".into(), json!(ntrack as f64 / runs as f64));
    let opencv = cv.as_ref().map(|s| {
        let mut m = serde_json::Map::new();
        for (k, v) in compare.iter().zip(cv_t.iter_mut()) {
            m.insert(k.to_string(), stats(v));
        }
        for (n, k) in ["features", "corners", "tracked"].iter().enumerate() {
            m.insert(format!("{k}_mean"), json!(cv_counts[n] / runs as f64));
        }
        m.insert("opencv".into(), s.header["opencv"].clone());
        m.insert("threads".into(), s.header["threads"].clone());
        Value::Object(m)
    });
    drop(cv);
    let load_after = load_average();
    // ratio = ours / OpenCV (below 1 = faster than OpenCV): the median over rounds of the
    // ratio of the two sides' medians within the round, so slow patches of load cancel out
    let ratios: serde_json::Map<String, Value> = compare
        .iter()
        .zip(&round_ratios)
        .filter_map(|(k, r)| Some((k.to_string(), json!(median(r)?))))
        .collect();
    if args.json {
        let out = json!({
            "images": images,
            "repeat": args.repeat,
            "stillpoint": ours,
            "opencv": opencv,
            "ratio_vs_opencv": ratios,
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
    let fmt_load = |l: Option<f64>| l.map_or_else(|| "?".to_string(), |l| format!("{l:.2}"));
    println!(
        "load average (1 min) before / after: {} / {}",
        fmt_load(load_before),
        fmt_load(load_after)
    );
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
