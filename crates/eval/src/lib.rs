//! stillpoint-eval: how good a run was, measured against the truth a dataset carries.
//!
//! - [`mod@stats`]: mean, median and p90 of per-frame numbers (timings, keypoints culled), nearest
//!   rank quantiles;
//! - [`mod@accuracy`]: a run's ATE and RPE against the sequence's ground truth (SE(3)-aligned, or
//!   Sim(3) for monocular), the ground truth read in the sequence's own format, and how far apart
//!   two instants truly were (for judging loop closures);
//! - [`movers`]: the generator's per-pixel masks of moving objects (`stillpoint synth --masks`),
//!   keypoints kept on them and map points observed on them;
//! - [`periods`]: when a moving object was in view (from a sequence's boxes or a text file),
//!   for shading plots of the error over time;
//! - [`surface`]: a point cloud's distance to a known surface (a synthetic scene's triangles);
//! - [`keypoints`]: confusion counts, precision and recall of a per-keypoint dynamic decision
//!   against those masks (strict, occlusion-aware and straddle-free ground truths);
//! - [`scoring`]: a run of `stillpoint-run` with a sink that scores it against all of the
//!   above ([`run_scored`]), so that the run itself scores nothing.
//!
//! The experiments that put runs in tables are `stillpoint-bench`'s.
//!
//! ```
//! use stillpoint_eval::stats::{quantile, stats};
//! let (mean, median, p90) = stats(&[4.0, 1.0, 3.0, 2.0, 10.0]);
//! assert_eq!((mean, median, p90), (4.0, 3.0, 10.0));
//! assert_eq!(quantile(&[1.0, 2.0, 3.0], 0.5), 2.0);
//! ```

#![deny(missing_docs)]

pub mod accuracy;
pub mod keypoints;
pub mod movers;
pub mod periods;
pub mod scoring;
/// Summary statistics of per-frame numbers (one definition for the workspace, in
/// `stillpoint-core`).
pub use stillpoint_core::stats;
pub mod surface;

pub use accuracy::{EvalError, accuracy, alignment, read_ground_truth};
pub use keypoints::Counts;
pub use scoring::{ScoredRun, run_scored};
pub use stats::{mean, median, quantile, stats};
