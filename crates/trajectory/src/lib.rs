//! Trajectories: TUM / KITTI / EuRoC IO, a line-by-line TUM writer, timestamp association, and
//! the evaluation metrics (ATE, RPE, the KITTI odometry metric) computed exactly as evo 1.38
//! computes them, plus a top-view plot.
//!
//! ```
//! use stillpoint_geometry::{Se3, Vec3};
//! use stillpoint_trajectory::{Trajectory, ate, AteOptions};
//! let gt = Trajectory::from_parts(
//!     (0..10).map(|i| i as f64).collect(),
//!     (0..10).map(|i| Se3::translation(i as f64, (i * i) as f64 * 0.1, 0.0)).collect(),
//! ).unwrap();
//! let result = ate(&gt, &gt, &AteOptions::default()).unwrap();
//! assert_eq!(result.stats.count, 10);
//! assert!(result.stats.rmse < 1e-9);
//! ```

#![deny(missing_docs)]

pub mod associate;
pub mod error;
pub mod io;
pub mod kitti;
pub mod metrics;
pub mod plot;

pub use associate::{Matching, associate};
pub use error::TrajectoryError;
pub use io::{
    TrajectoryFormat, TumWriter, parse, parse_euroc, parse_kitti, parse_tum, read_euroc,
    read_kitti, read_trajectory, read_trajectory_lenient, read_tum, write_kitti, write_tum,
};
pub use kitti::{KittiOptions, KittiResult, kitti_odometry};
pub use metrics::{
    Alignment, AteOptions, AteResult, DeltaUnit, ErrorStats, RpeOptions, RpeResult, SCALE_PIECES,
    ScaleAlongPath, ate, rpe, scale_along_path,
};
pub use plot::{ErrorSeries, plot_error_over_time, plot_top_view};

use stillpoint_geometry::{Se3, Vec3};

/// Timestamped camera poses (camera-to-world), stamps strictly increasing.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trajectory {
    /// Seconds (KITTI files without times: the pose index).
    pub stamps: Vec<f64>,
    /// `T_wc` for each stamp.
    pub poses: Vec<Se3>,
}

impl Trajectory {
    /// Build from stamps and poses; they must have equal length and the stamps must be finite and
    /// strictly increasing.
    pub fn from_parts(stamps: Vec<f64>, poses: Vec<Se3>) -> Result<Self, TrajectoryError> {
        if stamps.len() != poses.len() {
            return Err(TrajectoryError::Invalid(format!(
                "{} stamps but {} poses",
                stamps.len(),
                poses.len()
            )));
        }
        if let Some(i) = stamps.iter().position(|t| !t.is_finite()) {
            return Err(TrajectoryError::Invalid(format!("stamp {i} is not finite")));
        }
        if let Some(i) = stamps.windows(2).position(|w| w[1] <= w[0]) {
            return Err(TrajectoryError::Invalid(format!(
                "stamps {} and {} ({} then {}) are not strictly increasing",
                i,
                i + 1,
                stamps[i],
                stamps[i + 1]
            )));
        }
        Ok(Self { stamps, poses })
    }

    /// Number of poses.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True when there is no pose.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Camera positions (the translations of the poses).
    pub fn positions(&self) -> Vec<Vec3> {
        self.poses.iter().map(|p| p.translation.vector).collect()
    }

    /// Length of the path through the positions up to each pose, in metres (0 at the first).
    pub fn distances_along(&self) -> Vec<f64> {
        distances_along(&self.positions())
    }

    /// Length of the path through the positions, in metres.
    pub fn path_length(&self) -> f64 {
        self.distances_along().last().copied().unwrap_or(0.0)
    }

    /// The poses at the given indices, in that order.
    pub fn select(&self, ids: &[usize]) -> Self {
        Self {
            stamps: ids.iter().map(|&i| self.stamps[i]).collect(),
            poses: ids.iter().map(|&i| self.poses[i]).collect(),
        }
    }
}

/// Length of the path through `points` up to each of them (0 at the first).
pub(crate) fn distances_along(points: &[Vec3]) -> Vec<f64> {
    let mut along = Vec::with_capacity(points.len());
    let mut total = 0.0;
    for (k, p) in points.iter().enumerate() {
        if k > 0 {
            total += (p - points[k - 1]).norm();
        }
        along.push(total);
    }
    along
}
