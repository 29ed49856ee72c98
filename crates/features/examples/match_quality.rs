//! The inlier-ratio comparison with OpenCV, both ways round. `cargo run --release -p
//! stillpoint-features --example match_quality -- [--opencv DUMP.json] PREV CUR [PREV CUR ...]`
//! prints, per pair, our ORB matches with ratio 0.8 + mutual ("bf") and with ORB-SLAM's rotation
//! check added ("bf+rot", [`match_keypoints`] with its defaults), and the fundamental-RANSAC
//! (1 px, 0.99) inlier ratio: seed 0 and the mean over seeds 0..20. With `--opencv` (the file
//! written by `bench/opencv_features.py quality ... --dump DUMP.json`) it also scores OpenCV's
//! matches with our RANSAC, so extractor and RANSAC can be told apart. Analysis, not a test.

use stillpoint_features::{MatchParams, OrbExtractor, OrbParams, match_keypoints};
use stillpoint_geometry::Vec2;
use stillpoint_geometry::fundamental::{FundamentalRansac, fundamental_ransac};
use stillpoint_image::read_gray;

const SEEDS: u64 = 20;

/// (inliers with seed 0, mean inlier ratio over SEEDS seeds)
fn score(p1: &[Vec2], p2: &[Vec2]) -> (usize, f64) {
    let counts: Vec<usize> = (0..SEEDS)
        .map(|seed| {
            let params = FundamentalRansac {
                threshold_px: 1.0,
                confidence: 0.99,
                seed,
                ..FundamentalRansac::default()
            };
            fundamental_ransac(p1, p2, &params)
                .map(|(_, mask)| mask.iter().filter(|&&b| b).count())
                .unwrap_or(0)
        })
        .collect();
    let n = p1.len().max(1) as f64;
    let mean = counts.iter().map(|&c| c as f64 / n).sum::<f64>() / SEEDS as f64;
    (counts[0], mean)
}

fn short(path: &str) -> &str {
    path.rsplit("data/").next().unwrap_or(path)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut opencv: Vec<serde_like::Entry> = Vec::new();
    if args.first().map(String::as_str) == Some("--opencv") && args.len() >= 2 {
        let text = std::fs::read_to_string(&args[1])?;
        opencv = serde_like::parse(&text);
        args.drain(..2);
    }
    let mut orb = OrbExtractor::new(OrbParams::default());
    println!(
        "pair | matcher | ours: matches, inliers seed 0, ratio seed 0, mean ratio over {SEEDS} seeds"
    );
    for pair in args.chunks_exact(2) {
        let a = read_gray(std::path::Path::new(&pair[0]))?;
        let b = read_gray(std::path::Path::new(&pair[1]))?;
        let (fa, fb) = (orb.extract(&a), orb.extract(&b));
        for (name, check_orientation) in [("bf", false), ("bf+rot", true)] {
            let p = MatchParams {
                check_orientation,
                ..MatchParams::default()
            };
            let m = match_keypoints(&fa, &fb, &p);
            let point = |k: &stillpoint_features::KeyPoint| Vec2::new(k.x as f64, k.y as f64);
            let p1: Vec<Vec2> = m.iter().map(|m| point(&fa.keypoints[m.query])).collect();
            let p2: Vec<Vec2> = m.iter().map(|m| point(&fb.keypoints[m.train])).collect();
            let (inl, mean) = score(&p1, &p2);
            let mut line = format!(
                "{:<38} {:<7} ours {:4} {:4} {:.3} mean {:.3}",
                short(&pair[0]),
                name,
                m.len(),
                inl,
                inl as f64 / m.len().max(1) as f64,
                mean
            );
            if let Some(e) = opencv
                .iter()
                .find(|e| e.prev == pair[0] && e.variant == name)
            {
                let q1: Vec<Vec2> = e.pts.iter().map(|p| Vec2::new(p[0], p[1])).collect();
                let q2: Vec<Vec2> = e.pts.iter().map(|p| Vec2::new(p[2], p[3])).collect();
                let (ci, cm) = score(&q1, &q2);
                line += &format!(
                    " | OpenCV's matches, our RANSAC {:4} {:4} {:.3} mean {:.3}",
                    q1.len(),
                    ci,
                    ci as f64 / q1.len().max(1) as f64,
                    cm
                );
            }
            println!("{line}");
        }
    }
    Ok(())
}

/// Just enough of a reader for the dump's fixed shape (`[{"prev": .., "variant": .., "pts":
/// [[x1, y1, x2, y2], ..]}, ..]`), to keep the crate free of a JSON dependency.
mod serde_like {
    pub struct Entry {
        pub prev: String,
        pub variant: String,
        pub pts: Vec<[f64; 4]>,
    }

    fn string_after(s: &str, key: &str) -> Option<String> {
        let i = s.find(key)? + key.len();
        let rest = &s[i..];
        let start = rest.find('"')? + 1;
        let end = start + rest[start..].find('"')?;
        Some(rest[start..end].to_string())
    }

    pub fn parse(text: &str) -> Vec<Entry> {
        text.split("{\"prev\"")
            .skip(1)
            .filter_map(|chunk| {
                let chunk = format!("\"prev\"{chunk}");
                let prev = string_after(&chunk, "\"prev\":")?;
                let variant = string_after(&chunk, "\"variant\":")?;
                let pts_start = chunk.find("\"pts\":")? + 6;
                let nums: Vec<f64> = chunk[pts_start..]
                    .split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == 'e'))
                    .filter_map(|t| t.parse().ok())
                    .collect();
                let pts = nums
                    .chunks_exact(4)
                    .map(|c| [c[0], c[1], c[2], c[3]])
                    .collect();
                Some(Entry { prev, variant, pts })
            })
            .collect()
    }
}
