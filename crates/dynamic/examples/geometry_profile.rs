//! Time the motion-consistency check's stages on consecutive frames of a sequence:
//! `cargo run --release -p stillpoint-dynamic --example geometry_profile -- IMG...` (frames in
//! order). Prints the mean corner, LK, check and model milliseconds a pair, and the model stage
//! again with F and the homography timed alone. For profiling, not a benchmark.

use std::time::Instant;

use stillpoint_dynamic::{GeometryParams, motion_consistency_pyramids};
use stillpoint_features::LkPyramid;
use stillpoint_geometry::Vec2;
use stillpoint_geometry::fundamental::fundamental_ransac;
use stillpoint_geometry::homography::{HomographyRansac, homography_ransac};
use stillpoint_image::read_gray;

fn main() {
    let paths: Vec<String> = std::env::args().skip(1).collect();
    let imgs: Vec<_> = paths
        .iter()
        .map(|p| read_gray(std::path::Path::new(p)).expect(p))
        .collect();
    let p = GeometryParams::default();
    let pyramids: Vec<_> = imgs.iter().map(|i| LkPyramid::new(i, &p.lk)).collect();
    let (mut corners, mut lk, mut checks, mut model) = (0.0, 0.0, 0.0, 0.0);
    let (mut f_ms, mut h_ms, mut points) = (0.0, 0.0, 0usize);
    let pairs = imgs.len().saturating_sub(1).max(1) as f64;
    let h_params = HomographyRansac {
        threshold_px: p.outlier_threshold_px,
        confidence: p.ransac.confidence,
        max_iterations: p.ransac.max_iterations,
        seed: p.ransac.seed,
    };
    for i in 1..imgs.len() {
        let check =
            motion_consistency_pyramids(&imgs[i - 1], &imgs[i], &pyramids[i - 1], &pyramids[i], &p);
        corners += check.timings.corners_ms;
        lk += check.timings.lk_ms;
        checks += check.timings.checks_ms;
        model += check.timings.model_ms;
        points += check.points.len();
        let p1: Vec<Vec2> = check
            .points
            .iter()
            .map(|t| Vec2::new(t.prev[0] as f64, t.prev[1] as f64))
            .collect();
        let p2: Vec<Vec2> = check
            .points
            .iter()
            .map(|t| Vec2::new(t.cur[0] as f64, t.cur[1] as f64))
            .collect();
        let t0 = Instant::now();
        let _ = fundamental_ransac(&p1, &p2, &p.ransac);
        f_ms += t0.elapsed().as_secs_f64() * 1e3;
        let t0 = Instant::now();
        let _ = homography_ransac(&p1, &p2, &h_params);
        h_ms += t0.elapsed().as_secs_f64() * 1e3;
    }
    println!(
        "pairs {pairs}, points {:.0} a pair; ms a pair: corners {:.2}, lk {:.2}, checks {:.2}, model {:.2} (F alone {:.2}, H alone {:.2})",
        points as f64 / pairs,
        corners / pairs,
        lk / pairs,
        checks / pairs,
        model / pairs,
        f_ms / pairs,
        h_ms / pairs
    );
}
