//! `stillpoint bench tum`: the paper's accuracy table (ATE RMSE / S.D., translational RPE RMSE /
//! S.D. over 1 s, metres) for each sequence with the dynamic front-end on and off.

use std::path::PathBuf;

use crate::cmd::run::{RunOptions, accuracy, run_sequence};

#[derive(clap::Args)]
pub struct Args {
    /// Sequence folders.
    #[arg(long, num_args = 1.., required = true)]
    pub dataset: Vec<PathBuf>,
    /// Detector of the "on" runs: yolox, gt or none.
    #[arg(long, default_value = "yolox")]
    pub detector: String,
    /// Only the first N frames of each sequence.
    #[arg(long)]
    pub frames: Option<usize>,
    #[arg(long)]
    pub json: bool,
    /// YOLOX ONNX model (else the default search).
    #[arg(long)]
    pub model: Option<std::path::PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mut rows = Vec::new();
    for d in &args.dataset {
        for on in [false, true] {
            let s = run_sequence(&RunOptions {
                realtime: false,
                dataset: d.clone(),
                kind: None,
                settings: None,
                out: None,
                detector: on.then(|| args.detector.clone()),
                sequential: true,
                frames: args.frames,
                progress: true,
                paper_cull: false,
                model: args.model.clone(),
                overrides: Default::default(),
            })?;
            let acc = accuracy(&s);
            rows.push(serde_json::json!({
                "sequence": s.name,
                "dynamic": on,
                "detector": s.detector,
                "tracked": s.tracked,
                "frames": s.frames,
                "ate_rmse": acc.as_ref().map(|a| a.0.stats.rmse),
                "ate_std": acc.as_ref().map(|a| a.0.stats.std),
                "rpe_trans_rmse": acc.as_ref().and_then(|a| a.1.as_ref()).map(|r| r.translation.rmse),
                "rpe_trans_std": acc.as_ref().and_then(|a| a.1.as_ref()).map(|r| r.translation.std),
            }));
        }
    }
    if args.json {
        println!("{}", serde_json::Value::Array(rows));
        return Ok(());
    }
    let f = |v: &serde_json::Value| v.as_f64().map_or("n/a".into(), |x| format!("{x:.4}"));
    println!(
        "{:<28} {:<8} {:>10} {:>10} {:>10} {:>10} {:>9}",
        "sequence", "dynamic", "ATE RMSE", "ATE S.D.", "RPE RMSE", "RPE S.D.", "tracked"
    );
    for r in &rows {
        println!(
            "{:<28} {:<8} {:>10} {:>10} {:>10} {:>10} {:>4}/{:<4}",
            r["sequence"].as_str().unwrap_or(""),
            if r["dynamic"].as_bool() == Some(true) {
                r["detector"].as_str().unwrap_or("")
            } else {
                "off"
            },
            f(&r["ate_rmse"]),
            f(&r["ate_std"]),
            f(&r["rpe_trans_rmse"]),
            f(&r["rpe_trans_std"]),
            r["tracked"],
            r["frames"],
        );
    }
    Ok(())
}
