//! `stillpoint bench tum`: the paper's accuracy table (ATE RMSE / S.D., translational RPE RMSE /
//! S.D. over 1 s, metres) for each sequence with the dynamic front-end on and off
//! (`stillpoint_bench::tum`).

use std::path::PathBuf;

use stillpoint_bench::tum::{TumOptions, paper_table};

use crate::cmd::run::ProgressBar;

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
    let mut bar = ProgressBar::default();
    let rows = paper_table(
        &TumOptions {
            datasets: args.dataset.clone(),
            detector: args.detector.clone(),
            frames: args.frames,
            model: args.model.clone(),
            stop: Some(crate::interrupt_flag()),
        },
        &mut |e| bar.show(e),
    )?;
    if args.json {
        println!("{}", serde_json::to_value(&rows)?);
        return Ok(());
    }
    let f = |v: Option<f64>| v.map_or("n/a".into(), |x| format!("{x:.4}"));
    println!(
        "{:<28} {:<8} {:>10} {:>10} {:>10} {:>10} {:>9}",
        "sequence", "dynamic", "ATE RMSE", "ATE S.D.", "RPE RMSE", "RPE S.D.", "tracked"
    );
    // The tracked column prints unpadded, as it always has (the padding was once asked of JSON
    // values, whose Display ignores it).
    for r in &rows {
        println!(
            "{:<28} {:<8} {:>10} {:>10} {:>10} {:>10} {}/{}",
            r.sequence,
            if r.dynamic {
                r.detector.as_str()
            } else {
                "off"
            },
            f(r.ate_rmse),
            f(r.ate_std),
            f(r.rpe_trans_rmse),
            f(r.rpe_trans_std),
            r.tracked,
            r.frames,
        );
    }
    Ok(())
}
