//! `stillpoint bench soak`: one long lapping run (the `loop` preset, rendered in memory), with
//! memory and time per frame sampled along it (`stillpoint_bench::soak`). Exits non-zero when
//! memory at the end is over 20 % above its value at `--baseline` (frame 2,000: the map of the
//! room is whole after the second lap), or the last quarter's time per frame over 20 % above
//! the second quarter's.

use anyhow::bail;
use stillpoint_bench::soak::{SoakOptions, SoakReport, run_soak};

#[derive(clap::Args)]
pub struct Args {
    /// Frames in all (30 a second; a lap every 600).
    #[arg(long, default_value_t = 10_000)]
    pub frames: usize,
    /// Image size, WIDTHxHEIGHT.
    #[arg(long, default_value = "320x240")]
    pub size: String,
    /// No sensor noise (Kinect-like by default).
    #[arg(long)]
    pub no_noise: bool,
    /// A sample every this many frames.
    #[arg(long, default_value_t = 500)]
    pub every: usize,
    /// Local mapping and loop closing on their own threads (sequential by default).
    #[arg(long)]
    pub threaded: bool,
    /// The frame whose memory the end is compared with.
    #[arg(long, default_value_t = 2000)]
    pub baseline: usize,
    #[arg(long)]
    pub json: bool,
}

/// Memory at the end against frame `baseline` (or the first sample), and the mean time per
/// frame of the last quarter of the samples against the second quarter, each as a ratio.
pub fn growth(r: &SoakReport, baseline: usize) -> (Option<f64>, Option<f64>) {
    let first = r.at(baseline).or(r.samples.first());
    let memory = match (
        first.and_then(|s| s.rss_mib),
        r.samples.last().and_then(|s| s.rss_mib),
    ) {
        (Some(a), Some(b)) if a > 0.0 => Some(b / a),
        _ => None,
    };
    let n = r.samples.len();
    let mean = |s: &[stillpoint_bench::soak::SoakSample]| {
        (!s.is_empty()).then(|| s.iter().map(|x| x.ms_per_frame).sum::<f64>() / s.len() as f64)
    };
    let time = match (
        mean(&r.samples[n / 4..n / 2]),
        mean(&r.samples[n * 3 / 4..]),
    ) {
        (Some(a), Some(b)) if a > 0.0 => Some(b / a),
        _ => None,
    };
    (memory, time)
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let Some((w, h)) = a.size.split_once('x') else {
        bail!("--size {:?}: give WIDTHxHEIGHT, e.g. 320x240", a.size);
    };
    let (Ok(w), Ok(h)) = (w.parse(), h.parse()) else {
        bail!("--size {:?}: give WIDTHxHEIGHT, e.g. 320x240", a.size);
    };
    let o = SoakOptions {
        frames: a.frames,
        size: (w, h),
        noise: !a.no_noise,
        every: a.every,
        threaded: a.threaded,
    };
    let report = run_soak(&o, &mut |s| {
        tracing::info!(
            "frame {}: {:.0} MiB, {} keyframes, {} map points, {:.1} ms a frame, {} tracked",
            s.frame,
            s.rss_mib.unwrap_or(f64::NAN),
            s.keyframes,
            s.map_points,
            s.ms_per_frame,
            s.tracked
        )
    })?;
    let (memory, time) = growth(&report, a.baseline);
    let since_1000 = growth(&report, 1000).0;
    if a.json {
        let mut v = serde_json::to_value(&report)?;
        v["memory_end_over_baseline"] = serde_json::json!(memory);
        v["baseline_frame"] = serde_json::json!(a.baseline);
        v["memory_end_over_frame_1000"] = serde_json::json!(since_1000);
        v["time_late_over_early"] = serde_json::json!(time);
        println!("{v}");
    } else {
        println!(
            "{:>7} {:>9} {:>10} {:>11} {:>12} {:>8}",
            "frame", "RSS MiB", "keyframes", "map points", "ms a frame", "tracked"
        );
        for s in &report.samples {
            println!(
                "{:>7} {:>9.0} {:>10} {:>11} {:>12.1} {:>8}",
                s.frame,
                s.rss_mib.unwrap_or(f64::NAN),
                s.keyframes,
                s.map_points,
                s.ms_per_frame,
                s.tracked
            );
        }
        println!(
            "peak {:.0} MiB; memory end / frame {} {:.2} (/ frame 1000 {:.2}); time a frame late / early {:.2}; ATE {:.2} cm",
            report.peak_rss_mib.unwrap_or(f64::NAN),
            a.baseline,
            memory.unwrap_or(f64::NAN),
            since_1000.unwrap_or(f64::NAN),
            time.unwrap_or(f64::NAN),
            report.ate_cm.unwrap_or(f64::NAN)
        );
    }
    if memory.is_some_and(|m| m > 1.2) || time.is_some_and(|t| t > 1.2) {
        bail!(
            "the soak run grew: memory x{:.2} since frame {}, time a frame x{:.2}",
            memory.unwrap_or(f64::NAN),
            a.baseline,
            time.unwrap_or(f64::NAN)
        );
    }
    Ok(())
}
