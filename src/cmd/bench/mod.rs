//! `stillpoint bench`: one module per benchmark. Speed is reported as ratios against a reference
//! measured in the same run; accuracy as the metric itself.

pub mod detect;
pub mod dynamic;
pub mod features;
pub mod matrix;
pub mod realtime;
pub mod recording;
pub mod soak;
pub mod tum;

#[derive(clap::Subcommand)]
pub enum BenchCommand {
    /// Feature front-end speed (ORB, Harris, LK) per stage.
    Features(features::Args),
    /// Detector latency per backend, thread count and input size.
    Detect(detect::Args),
    /// Precision/recall of the dynamic-keypoint decision against ground-truth masks.
    Dynamic(dynamic::Args),
    /// SLAM accuracy table (ATE, RPE) with the dynamic front-end on and off.
    Tum(tum::Args),
    /// ATE and map points on movers over synthetic presets x seeds x {off, gt, yolox}.
    Matrix(matrix::Args),
    /// One long lapping run: memory and time per frame along it (flat, or it fails).
    Soak(soak::Args),
    /// A sequence replayed as a live camera at a given rate on a given number of CPUs, N
    /// times: frames processed, latency, ATE, map points on movers per run.
    Realtime(realtime::Args),
    /// A recording run as users run it, per detector backend, idle and with a busy thread
    /// beside it, N rounds: frames a second, times real time, peak memory, ATE, and the same
    /// trajectory every run.
    Recording(recording::Args),
}

/// The detector flags of the benchmarks that run whole sequences (`realtime`, `recording`), as
/// `run` spells them.
#[derive(clap::Args)]
pub struct DetectorArgs {
    /// Object detector: yolox, gt or none.
    #[arg(long, default_value = "yolox")]
    pub detector: String,
    /// Turn the dynamic front-end off.
    #[arg(long)]
    pub no_dynamic: bool,
    /// YOLOX ONNX model (else the default search).
    #[arg(long)]
    pub model: Option<std::path::PathBuf>,
}

impl DetectorArgs {
    /// The detector to run, `None` with the front-end off.
    pub fn detector(&self) -> Option<String> {
        (!self.no_dynamic).then(|| self.detector.clone())
    }
}

/// The shared data folder: `$STILLPOINT_SHARED`, else `../shared` (the benches' default inputs).
fn shared_dir() -> std::path::PathBuf {
    std::env::var_os("STILLPOINT_SHARED")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| std::path::PathBuf::from("../shared"))
}

pub fn run(cmd: BenchCommand) -> anyhow::Result<()> {
    match cmd {
        BenchCommand::Features(a) => features::run(a),
        BenchCommand::Detect(a) => detect::run(a),
        BenchCommand::Dynamic(a) => dynamic::run(a),
        BenchCommand::Tum(a) => tum::run(a),
        BenchCommand::Matrix(a) => matrix::run(a),
        BenchCommand::Soak(a) => soak::run(a),
        BenchCommand::Realtime(a) => realtime::run(a),
        BenchCommand::Recording(a) => recording::run(a),
    }
}
