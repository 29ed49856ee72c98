//! Time the corner and LK stages on the bench images: `cargo run --release -p stillpoint-features
//! --example lk_profile -- IMG...` (pyramid of the image tracked from, pyramid of the image
//! tracked into, tracking; the per-thread buffers of `track_lk` and reused pyramids), and corners with and
//! without sub-pixel refinement. For profiling, not a benchmark.

use std::time::Instant;

use stillpoint_features::{
    CornerParams, LkParams, LkPyramid, good_features_to_track, track_lk, track_lk_pyramids,
};
use stillpoint_image::read_gray;

fn main() {
    let paths: Vec<String> = std::env::args().skip(1).collect();
    let imgs: Vec<_> = paths
        .iter()
        .map(|p| read_gray(std::path::Path::new(p)).expect(p))
        .collect();
    let reps: usize = std::env::var("REPS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20);
    let lp = LkParams::default();
    let corners: Vec<_> = imgs
        .iter()
        .map(|i| good_features_to_track(i, &CornerParams::default()))
        .collect();
    let no_subpix = CornerParams {
        subpix_half_window: 0,
        ..CornerParams::default()
    };
    let (mut t_corners, mut t_nosub) = (vec![], vec![]);
    let (mut t_full, mut t_pa, mut t_pb, mut t_track) = (vec![], vec![], vec![], vec![]);
    let (mut pa, mut pb) = (LkPyramid::default(), LkPyramid::default());
    for _ in 0..reps {
        for (i, img) in imgs.iter().enumerate() {
            let next = &imgs[(i + 1) % imgs.len()];
            let c0 = Instant::now();
            let _ = good_features_to_track(img, &CornerParams::default());
            let c1 = Instant::now();
            let _ = good_features_to_track(img, &no_subpix);
            let c2 = Instant::now();
            t_corners.push((c1 - c0).as_secs_f64() * 1e3);
            t_nosub.push((c2 - c1).as_secs_f64() * 1e3);
            let t0 = Instant::now();
            let r = track_lk(img, next, &corners[i], &lp);
            let t1 = Instant::now();
            pa.rebuild(img, &lp);
            let t2 = Instant::now();
            pb.rebuild(next, &lp);
            let t3 = Instant::now();
            let r2 = track_lk_pyramids(&pa, &pb, &corners[i], &lp);
            let t4 = Instant::now();
            assert_eq!(r, r2);
            let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
            t_full.push(ms(t0, t1));
            t_pa.push(ms(t1, t2));
            t_pb.push(ms(t2, t3));
            t_track.push(ms(t3, t4));
        }
    }
    for (name, v) in [
        ("corners + subpix", &mut t_corners),
        ("corners, no subpix", &mut t_nosub),
        ("track_lk (cached)", &mut t_full),
        ("pyramid+grads (reused)", &mut t_pa),
        ("pyramid (reused)", &mut t_pb),
        ("tracking only", &mut t_track),
    ] {
        v.sort_by(f64::total_cmp);
        println!("{name:<24} median {:.3} ms", v[v.len() / 2]);
    }
    let n: usize = corners.iter().map(Vec::len).sum();
    println!("corners/frame {}", n / imgs.len());
}
