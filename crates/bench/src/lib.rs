//! stillpoint-bench: the experiments behind stillpoint's tables, as functions that return plain
//! reports (the `stillpoint demo` and `stillpoint bench ...` commands print them).
//!
//! - [`demo`]: a synthetic walking sequence run with the dynamic front-end off and on;
//! - [`matrix`]: synthetic presets x seeds x front-end modes, ATE and map points on movers;
//! - [`tum`]: the paper's accuracy table (ATE, RPE over 1 s) with the front-end on and off;
//! - [`keypoints`]: precision and recall of the dynamic-keypoint decision (the paper, variants,
//!   ours, two baselines) against the generator's masks;
//! - [`features`]: the feature front-end's speed against OpenCV, measured in the same run;
//! - [`detector`]: detector latency per backend, thread count and model;
//! - [`soak`]: one long lapping run, memory and time per frame along it;
//! - [`recording`]: a recording run as users run it, per backend, idle and loaded: frames a
//!   second, peak memory, ATE, the same trajectory every run.
//!
//! Runs go through `stillpoint-run`, measurements through `stillpoint-eval`.
//!
//! ```no_run
//! use stillpoint_bench::tum::{TumOptions, paper_table};
//! let rows = paper_table(
//!     &TumOptions::new(vec!["rgbd_dataset_freiburg3_walking_xyz".into()], "yolox"),
//!     &mut |_| {},
//! )?;
//! for r in &rows {
//!     println!("{} {} ATE {:?}", r.sequence, r.dynamic, r.ate_rmse);
//! }
//! # Ok::<(), stillpoint_bench::BenchError>(())
//! ```

#![deny(missing_docs)]

pub mod demo;
pub mod detector;
pub mod features;
pub mod keypoints;
pub mod matrix;
pub mod realtime;
pub mod recording;
pub mod soak;
pub mod tum;

use stillpoint_datasets::DatasetError;
use stillpoint_detect::DetectError;
use stillpoint_eval::keypoints::MaskListError;
use stillpoint_image::ImageError;
use stillpoint_run::RunError;
use stillpoint_synth::SynthError;

/// Why an experiment stopped. Each names what it was doing; the cause is its source.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// A run failed.
    #[error(transparent)]
    Run(#[from] RunError),
    /// The options ask for something impossible.
    #[error("{0}")]
    Invalid(String),
    /// A file or folder cannot be read, created or written.
    #[error("{context}")]
    Io {
        /// What was being done.
        context: String,
        /// Why it failed.
        source: std::io::Error,
    },
    /// A synthetic sequence cannot be generated or written.
    #[error("{context}")]
    Synth {
        /// What was being written.
        context: String,
        /// What the generator said.
        source: SynthError,
    },
    /// A sequence or one of its frames cannot be read.
    #[error("{context}")]
    Dataset {
        /// What was being read.
        context: String,
        /// What the reader said.
        source: DatasetError,
    },
    /// The masks of a synthetic sequence cannot be listed.
    #[error(transparent)]
    Masks(#[from] MaskListError),
    /// An image cannot be read or written.
    #[error("{context}")]
    Image {
        /// Which image.
        context: String,
        /// What the codec said.
        source: ImageError,
    },
    /// A detector cannot be opened or failed on a frame.
    #[error("{context}")]
    Detect {
        /// What was being done.
        context: String,
        /// What the detector said.
        source: DetectError,
    },
    /// The OpenCV reference (a Python child process) misbehaved.
    #[error("{context}")]
    Reference {
        /// What went wrong.
        context: String,
        /// The underlying error, when there is one.
        source: Option<Box<dyn std::error::Error + Send + Sync>>,
    },
    /// The pipeline stopped on a frame of an in-memory run.
    #[error(transparent)]
    Pipeline(#[from] stillpoint_pipeline::PipelineError),
    /// Poses that do not make a trajectory, or a plot that cannot be written.
    #[error(transparent)]
    Trajectory(#[from] stillpoint_trajectory::TrajectoryError),
    /// The periods a moving object was in view cannot be had.
    #[error(transparent)]
    Periods(#[from] stillpoint_eval::periods::PeriodsError),
}

pub use stillpoint_run::error_chain;

fn io_error(context: String) -> impl FnOnce(std::io::Error) -> BenchError {
    move |source| BenchError::Io { context, source }
}
