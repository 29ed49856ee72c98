//! Time the ORB extractor alone on the bench images, stage by stage: `cargo run --release -p
//! stillpoint-features --example orb_profile -- IMG...` (`REPS` rounds, default 50; medians per
//! image size). For profiling (`perf record`), not a benchmark: `stillpoint bench features`
//! compares with OpenCV.

use std::time::Instant;

use stillpoint_features::{OrbExtractor, OrbParams};
use stillpoint_image::read_gray;

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let paths: Vec<String> = std::env::args().skip(1).collect();
    let imgs: Vec<_> = paths
        .iter()
        .map(|p| read_gray(std::path::Path::new(p)).expect(p))
        .collect();
    let reps: usize = std::env::var("REPS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(50);
    let mut orb = OrbExtractor::new(OrbParams::default());
    for (path, img) in paths.iter().zip(&imgs) {
        let mut t = vec![Vec::new(); 5];
        for _ in 0..reps {
            let t0 = Instant::now();
            let f = orb.extract(img);
            let total = t0.elapsed().as_secs_f64() * 1e3;
            std::hint::black_box(&f);
            let s = orb.timings();
            for (k, v) in [
                total,
                s.pyramid_ms,
                s.fast_ms,
                s.distribute_ms,
                s.describe_ms,
            ]
            .into_iter()
            .enumerate()
            {
                t[k].push(v);
            }
        }
        // the fastest round too: on a shared machine it moves less than the median
        let min = t[0].iter().copied().fold(f64::INFINITY, f64::min);
        let m: Vec<f64> = t.iter_mut().map(|v| median(v)).collect();
        println!(
            "{path} {}x{}: total {:.3} ms, fastest {min:.3} (pyramid {:.3}, fast {:.3}, distribute {:.3}, describe {:.3})",
            img.width, img.height, m[0], m[1], m[2], m[3], m[4]
        );
    }
}
