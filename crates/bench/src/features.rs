//! The feature front-end's speed: ms per frame of each stage (ORB: pyramid, FAST, distribution,
//! orientation + descriptors; Harris + sub-pixel; LK of the corners into the next image), and
//! the same measured for OpenCV by `bench/opencv_features.py` in the same run, so the ratios
//! compare like with like: our rounds and OpenCV's alternate (the script runs as a child
//! serving one round per request), and each ratio is the median of per-round ratios. Build with
//! `--release`.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Instant;

use serde_json::Value;
use stillpoint_features::{
    CornerParams, LkParams, OrbExtractor, OrbParams, good_features_to_track, track_lk,
};
use stillpoint_image::{Gray8, read_gray};

use crate::BenchError;

/// Our stages, in report order.
pub const STAGES: [&str; 8] = [
    "pyramid",
    "fast",
    "distribution",
    "describe",
    "orb",
    "harris_subpix",
    "lk",
    "harris_lk",
];

/// The stages OpenCV's script measures, each with the stage of ours it is compared with:
/// `orb` is OpenCV's ORB with ORB-SLAM's border (edgeThreshold 19), `orb_default` with OpenCV's
/// own defaults but the feature count (edgeThreshold 31, fewer pixels scanned); ours is the
/// ORB-SLAM extractor with its own parameters against both.
pub const COMPARED: [(&str, &str); 5] = [
    ("orb", "orb"),
    ("orb_default", "orb"),
    ("harris_subpix", "harris_subpix"),
    ("lk", "lk"),
    ("harris_lk", "harris_lk"),
];

/// What is timed, and how the reference runs.
#[derive(Clone, Debug)]
pub struct FeatureOptions {
    /// Images (PNG/JPEG; colour is converted to gray). Image i is tracked into image i+1.
    pub images: Vec<PathBuf>,
    /// Rounds (every image once per round, ours and OpenCV's alternating).
    pub repeat: usize,
    /// ORB features per image.
    pub features: usize,
    /// Python interpreter for the OpenCV reference; `None` skips it.
    pub python: Option<String>,
    /// Threads OpenCV may use.
    pub opencv_threads: usize,
}

/// Per-frame times of one stage.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    /// Median, ms (`None` when nothing was timed).
    pub median: Option<f64>,
    /// 90th percentile (rank `floor(0.9 n)`), ms.
    pub p90: Option<f64>,
    /// Frames timed.
    pub n: usize,
}

impl StageTimes {
    /// Median and p90 of `xs` (sorted in place).
    pub fn of(xs: &mut [f64]) -> Self {
        xs.sort_by(f64::total_cmp);
        if xs.is_empty() {
            return Self::default();
        }
        let p90 = ((xs.len() as f64 * 0.9) as usize).min(xs.len() - 1);
        Self {
            median: Some(xs[xs.len() / 2]),
            p90: Some(xs[p90]),
            n: xs.len(),
        }
    }
}

/// Keypoints, corners and tracked corners per frame (means).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Counts {
    /// ORB keypoints.
    pub features: f64,
    /// Harris corners.
    pub corners: f64,
    /// Corners LK tracked into the next image.
    pub tracked: f64,
}

/// OpenCV's side.
#[derive(Clone, Debug)]
pub struct OpenCvReport {
    /// Per [`COMPARED`] stage.
    pub stages: Vec<(&'static str, StageTimes)>,
    /// Its counts per frame.
    pub counts: Counts,
    /// The version the script reported.
    pub version: Value,
    /// The threads it used, as it reported them.
    pub threads: Value,
}

/// The measurement.
#[derive(Clone, Debug)]
pub struct FeatureReport {
    /// The images timed.
    pub images: Vec<PathBuf>,
    /// Rounds.
    pub repeat: usize,
    /// Our stages ([`STAGES`] order).
    pub ours: Vec<(&'static str, StageTimes)>,
    /// Our counts per frame.
    pub counts: Counts,
    /// OpenCV's, when its reference ran.
    pub opencv: Option<OpenCvReport>,
    /// Ours / OpenCV's per [`COMPARED`] stage (below 1 = faster): the median over rounds of the
    /// ratio of the two sides' medians within the round.
    pub ratios: Vec<(&'static str, f64)>,
    /// The ORB ratios per image size, measured the same way over that size's images.
    pub orb_by_size: Vec<SizeRatios>,
    /// The 1-minute load average before and after (absolute ms on a shared machine mean little
    /// without it).
    pub load_average: [Option<f64>; 2],
}

/// ORB on the images of one size: our median and OpenCV's, and the ratios.
#[derive(Clone, Debug, PartialEq)]
pub struct SizeRatios {
    /// Width and height.
    pub size: (usize, usize),
    /// Images of this size.
    pub images: usize,
    /// Our ORB, median ms per frame.
    pub ours_ms: Option<f64>,
    /// OpenCV's `orb` and `orb_default`, median ms per frame.
    pub opencv_ms: [Option<f64>; 2],
    /// Ours / `orb` and ours / `orb_default` (median over rounds).
    pub ratios: [Option<f64>; 2],
}

/// The script beside the working directory, or in this repository.
fn script_path() -> Option<PathBuf> {
    let cands = [
        PathBuf::from("bench/opencv_features.py"),
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../bench/opencv_features.py"),
    ];
    cands.into_iter().find(|p| p.is_file())
}

fn reference_error(context: impl Into<String>) -> BenchError {
    BenchError::Reference {
        context: context.into(),
        source: None,
    }
}

fn reference_cause(
    context: String,
) -> impl FnOnce(Box<dyn std::error::Error + Send + Sync>) -> BenchError {
    move |source| BenchError::Reference {
        context,
        source: Some(source),
    }
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
    fn start(python: &str, threads: usize, images: &[PathBuf]) -> Result<Self, BenchError> {
        let script =
            script_path().ok_or_else(|| reference_error("bench/opencv_features.py not found"))?;
        let mut child = Command::new(python)
            .arg(&script)
            .arg("serve")
            .args(images)
            .arg("--threads")
            .arg(threads.to_string())
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .map_err(crate::io_error(format!(
                "cannot run {python} {}",
                script.display()
            )))?;
        let stdin = child
            .stdin
            .take()
            .ok_or_else(|| reference_error("no stdin"))?;
        let stdout = BufReader::new(
            child
                .stdout
                .take()
                .ok_or_else(|| reference_error("no stdout"))?,
        );
        let mut s = Self {
            child,
            stdin,
            stdout,
            header: Value::Null,
        };
        s.header = s.read_line().map_err(|e| BenchError::Reference {
            context: format!("{}: no header (is OpenCV installed?)", script.display()),
            source: Some(Box::new(e)),
        })?;
        Ok(s)
    }

    fn read_line(&mut self) -> Result<Value, BenchError> {
        let mut line = String::new();
        let read = self
            .stdout
            .read_line(&mut line)
            .map_err(crate::io_error("reading the OpenCV reference".into()))?;
        if read == 0 {
            return Err(reference_error("the OpenCV reference exited"));
        }
        serde_json::from_str(&line)
            .map_err(|e| reference_cause("OpenCV reference output is not JSON".into())(Box::new(e)))
    }

    /// One round: per-frame ms of each stage, and the counts.
    fn round(&mut self) -> Result<Value, BenchError> {
        writeln!(self.stdin, "round")
            .and_then(|()| self.stdin.flush())
            .map_err(crate::io_error(
                "asking the OpenCV reference for a round".into(),
            ))?;
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

/// The 1-minute load average (Linux `/proc/loadavg`).
fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// [`stillpoint_core::stats::median`]; `None` when empty.
fn median(xs: &[f64]) -> Option<f64> {
    (!xs.is_empty()).then(|| stillpoint_core::stats::median(xs))
}

/// Time our stages and OpenCV's, alternating rounds.
pub fn measure(o: &FeatureOptions) -> Result<FeatureReport, BenchError> {
    if o.images.is_empty() {
        return Err(BenchError::Invalid("no images given".into()));
    }
    let imgs: Vec<Gray8> = o
        .images
        .iter()
        .map(|p| {
            read_gray(p).map_err(|source| BenchError::Image {
                context: format!("reading {}", p.display()),
                source,
            })
        })
        .collect::<Result<_, _>>()?;
    let load_before = load_average();
    tracing::info!(
        "{} images, {} repeats, {} ORB features",
        imgs.len(),
        o.repeat,
        o.features
    );
    let mut orb = OrbExtractor::new(OrbParams {
        n_features: o.features,
        ..OrbParams::default()
    });
    let cp = CornerParams::default();
    let lp = LkParams::default();
    let mut t: Vec<Vec<f64>> = vec![Vec::new(); STAGES.len()];
    let (mut nfeat, mut ncorn, mut ntrack) = (0usize, 0usize, 0usize);
    let mut runs = 0usize;
    let mut cv = match &o.python {
        None => None,
        Some(python) => match OpenCvServer::start(python, o.opencv_threads, &o.images) {
            Ok(s) => Some(s),
            Err(e) => {
                tracing::warn!("OpenCV reference skipped: {}", crate::error_chain(&e));
                None
            }
        },
    };
    // image indices grouped by size, in order of first appearance
    let mut sizes: Vec<((usize, usize), Vec<usize>)> = Vec::new();
    for (i, img) in imgs.iter().enumerate() {
        let size = (img.width, img.height);
        match sizes.iter_mut().find(|(s, _)| *s == size) {
            Some((_, v)) => v.push(i),
            None => sizes.push((size, vec![i])),
        }
    }
    // per size: ours, OpenCV's two ORBs (all frames) and the two per-round ratios
    let mut size_ours: Vec<Vec<f64>> = vec![Vec::new(); sizes.len()];
    let mut size_cv: Vec<[Vec<f64>; 2]> = vec![Default::default(); sizes.len()];
    let mut size_ratios: Vec<[Vec<f64>; 2]> = vec![Default::default(); sizes.len()];
    let mut cv_t: Vec<Vec<f64>> = vec![Vec::new(); COMPARED.len()];
    let mut cv_counts = [0f64; 3];
    // per round: median of ours / median of OpenCV's, for each compared stage
    let mut round_ratios: Vec<Vec<f64>> = vec![Vec::new(); COMPARED.len()];
    for round in 0..o.repeat.max(1) {
        // alternate who goes first, so neither side always runs on a cache warmed by the other
        let cv_first = round % 2 == 1;
        let mut cv_round = None;
        if cv_first && let Some(s) = cv.as_mut() {
            cv_round = Some(s.round()?);
        }
        let mut ours_round: Vec<Vec<f64>> = vec![Vec::new(); STAGES.len()];
        for (i, img) in imgs.iter().enumerate() {
            let next = &imgs[(i + 1) % imgs.len()];
            let next = if (next.width, next.height) == (img.width, img.height) {
                next
            } else {
                img
            };
            let t0 = Instant::now();
            let f = orb.extract(img);
            let orb_ms = stillpoint_core::ms_since(t0);
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
            let orb_k = STAGES.iter().position(|n| *n == "orb").unwrap_or(0);
            for (c, (k, ours_name)) in COMPARED.iter().enumerate() {
                let v: Vec<f64> = r["times"][*k]
                    .as_array()
                    .map(|a| a.iter().filter_map(Value::as_f64).collect())
                    .unwrap_or_default();
                let ours_k = STAGES.iter().position(|n| n == ours_name).unwrap_or(0);
                if let (Some(a), Some(b)) = (median(&ours_round[ours_k]), median(&v))
                    && b > 0.0
                {
                    round_ratios[c].push(a / b);
                }
                if let Some(which) = ["orb", "orb_default"].iter().position(|n| n == k)
                    && v.len() == imgs.len()
                {
                    for (g, (_, members)) in sizes.iter().enumerate() {
                        let theirs: Vec<f64> = members.iter().map(|&i| v[i]).collect();
                        let ours: Vec<f64> =
                            members.iter().map(|&i| ours_round[orb_k][i]).collect();
                        if let (Some(a), Some(b)) = (median(&ours), median(&theirs))
                            && b > 0.0
                        {
                            size_ratios[g][which].push(a / b);
                        }
                        size_cv[g][which].extend(theirs);
                    }
                }
                cv_t[c].extend(v);
            }
            for (n, k) in ["features", "corners", "tracked"].iter().enumerate() {
                if let Some(a) = r["counts"][*k].as_array() {
                    cv_counts[n] += a.iter().filter_map(Value::as_f64).sum::<f64>();
                }
            }
        }
        if let Some(orb_k) = STAGES.iter().position(|n| *n == "orb") {
            for (g, (_, members)) in sizes.iter().enumerate() {
                size_ours[g].extend(members.iter().map(|&i| ours_round[orb_k][i]));
            }
        }
        for (all, r) in t.iter_mut().zip(ours_round) {
            all.extend(r);
        }
    }
    let per_frame = |total: f64| total / runs as f64;
    let ours = STAGES
        .iter()
        .zip(t.iter_mut())
        .map(|(n, v)| (*n, StageTimes::of(v)))
        .collect();
    let opencv = cv.as_ref().map(|s| OpenCvReport {
        stages: COMPARED
            .iter()
            .zip(cv_t.iter_mut())
            .map(|((k, _), v)| (*k, StageTimes::of(v)))
            .collect(),
        counts: Counts {
            features: per_frame(cv_counts[0]),
            corners: per_frame(cv_counts[1]),
            tracked: per_frame(cv_counts[2]),
        },
        version: s.header["opencv"].clone(),
        threads: s.header["threads"].clone(),
    });
    drop(cv);
    let load_after = load_average();
    let ratios = COMPARED
        .iter()
        .zip(&round_ratios)
        .filter_map(|((k, _), r)| Some((*k, median(r)?)))
        .collect();
    let orb_by_size = sizes
        .iter()
        .enumerate()
        .map(|(g, (size, members))| SizeRatios {
            size: *size,
            images: members.len(),
            ours_ms: median(&size_ours[g]),
            opencv_ms: [median(&size_cv[g][0]), median(&size_cv[g][1])],
            ratios: [median(&size_ratios[g][0]), median(&size_ratios[g][1])],
        })
        .collect();
    Ok(FeatureReport {
        images: o.images.clone(),
        repeat: o.repeat,
        ours,
        counts: Counts {
            features: per_frame(nfeat as f64),
            corners: per_frame(ncorn as f64),
            tracked: per_frame(ntrack as f64),
        },
        opencv,
        ratios,
        orb_by_size,
        load_average: [load_before, load_after],
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stage_times_rank_by_floor() {
        let mut v: Vec<f64> = (0..20).rev().map(f64::from).collect();
        let s = StageTimes::of(&mut v);
        assert_eq!((s.median, s.p90, s.n), (Some(10.0), Some(18.0), 20));
        assert_eq!(StageTimes::of(&mut []), StageTimes::default());
    }
}
