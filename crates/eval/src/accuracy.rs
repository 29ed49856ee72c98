//! A run's trajectory against the sequence's ground truth: ATE and RPE as the paper reports
//! them, the ground truth read in the sequence's own format, and the true distance between two
//! instants (which tells a true loop closure from a false one).

use std::path::{Path, PathBuf};

use stillpoint_datasets::{GroundTruthFormat, Sensor, Sequence};
use stillpoint_geometry::Se3;
use stillpoint_trajectory::{
    Alignment, AteOptions, AteResult, DeltaUnit, RpeOptions, RpeResult, Trajectory,
    TrajectoryError, TrajectoryFormat, read_trajectory,
};

/// Why a ground truth could not be read.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// The file is unreadable or malformed.
    #[error("{}", path.display())]
    Read {
        /// The ground-truth file.
        path: PathBuf,
        /// What the reader said.
        source: TrajectoryError,
    },
    /// KITTI poses carry no stamps and there are more poses than frames to take them from.
    #[error("{}: {poses} poses but {frames} frames", path.display())]
    Stamps {
        /// The ground-truth file.
        path: PathBuf,
        /// Poses in the file.
        poses: usize,
        /// Frames in the sequence.
        frames: usize,
    },
    /// The stamped poses do not make a trajectory.
    #[error(transparent)]
    Trajectory(#[from] TrajectoryError),
}

/// How a run's trajectory is aligned to the ground truth: SE(3), as the paper, or Sim(3) for a
/// monocular run, whose scale is arbitrary (evo `-as`).
pub fn alignment(sensor: Sensor) -> Alignment {
    if sensor == Sensor::Mono {
        Alignment::Sim3
    } else {
        Alignment::Se3
    }
}

/// ATE ([`alignment`]: SE(3), or Sim(3) for monocular) and translational RPE over 1 s (not
/// aligned, or Sim(3) for monocular) of `est` against `gt`. `None` when no ATE can be computed
/// (no pose associates); the RPE alone may be missing. Failures are logged as warnings.
pub fn accuracy(
    gt: &Trajectory,
    est: &Trajectory,
    sensor: Sensor,
) -> Option<(AteResult, Option<RpeResult>)> {
    let ate = stillpoint_trajectory::ate(
        gt,
        est,
        &AteOptions {
            align: alignment(sensor),
            ..Default::default()
        },
    )
    .map_err(|e| tracing::warn!("ATE: {e}"))
    .ok()?;
    let rpe = stillpoint_trajectory::rpe(
        gt,
        est,
        &RpeOptions {
            align: if sensor == Sensor::Mono {
                Alignment::Sim3
            } else {
                Alignment::None
            },
            delta: 1.0,
            delta_unit: DeltaUnit::Seconds,
            ..Default::default()
        },
    )
    .map_err(|e| tracing::warn!("RPE: {e}"))
    .ok();
    Some((ate, rpe))
}

/// Read a sequence's ground truth in its format. KITTI poses carry no stamps (line i is frame i):
/// they take the sequence's frame stamps (`times.txt`), so they associate with the estimate.
pub fn read_ground_truth(seq: &dyn Sequence, path: &Path) -> Result<Trajectory, EvalError> {
    let format = match seq.ground_truth_format() {
        GroundTruthFormat::Tum => TrajectoryFormat::Tum,
        GroundTruthFormat::KittiPoses => TrajectoryFormat::Kitti,
        GroundTruthFormat::EurocCsv => TrajectoryFormat::Euroc,
    };
    let t = read_trajectory(path, format).map_err(|source| EvalError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    if format != TrajectoryFormat::Kitti {
        return Ok(t);
    }
    let stamps: Option<Vec<f64>> = (0..t.len()).map(|i| seq.timestamp(i)).collect();
    let stamps = stamps.ok_or_else(|| EvalError::Stamps {
        path: path.to_path_buf(),
        poses: t.len(),
        frames: seq.len(),
    })?;
    Ok(Trajectory::from_parts(stamps, t.poses)?)
}

/// The ground-truth pose nearest to `t` (within 0.02 s, the TUM tools' association window).
pub fn gt_pose_at(gt: &Trajectory, t: f64) -> Option<Se3> {
    let i = gt
        .stamps
        .iter()
        .enumerate()
        .min_by(|a, b| (a.1 - t).abs().total_cmp(&(b.1 - t).abs()))?
        .0;
    ((gt.stamps[i] - t).abs() <= 0.02).then(|| gt.poses[i])
}

/// How far apart the camera truly was at times `a` and `b`: (metres, degrees), when the ground
/// truth has both instants. A loop closed between two keyframes that are far apart is false.
pub fn true_separation(gt: &Trajectory, a: f64, b: f64) -> Option<(f64, f64)> {
    let (a, b) = (gt_pose_at(gt, a)?, gt_pose_at(gt, b)?);
    Some((
        (a.translation.vector - b.translation.vector).norm(),
        a.rotation.angle_to(&b.rotation).to_degrees(),
    ))
}

/// Ground-truth frames before the estimate's first pose: how late tracking started.
pub fn frames_before_first_pose(gt: &Trajectory, est: &Trajectory) -> Option<usize> {
    let t0 = *est.stamps.first()?;
    Some(gt.stamps.iter().filter(|&&t| t < t0 - 1e-6).count())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(n: usize, offset: f64) -> Trajectory {
        Trajectory::from_parts(
            (0..n).map(|i| i as f64 * 0.1).collect(),
            (0..n)
                .map(|i| Se3::translation(i as f64 * 0.05 + offset, (i * i) as f64 * 0.01, 0.0))
                .collect(),
        )
        .unwrap()
    }

    #[test]
    fn monocular_runs_are_aligned_with_scale() {
        assert_eq!(alignment(Sensor::Mono), Alignment::Sim3);
        assert_eq!(alignment(Sensor::Rgbd), Alignment::Se3);
        assert_eq!(alignment(Sensor::Stereo), Alignment::Se3);
    }

    #[test]
    fn a_shifted_copy_has_no_error_after_alignment() {
        let gt = line(30, 0.0);
        let est = line(30, 1.0);
        let (ate, rpe) = accuracy(&gt, &est, Sensor::Rgbd).unwrap();
        assert_eq!(ate.stats.count, 30);
        assert!(ate.stats.rmse < 1e-9, "{}", ate.stats.rmse);
        assert!(rpe.unwrap().translation.rmse < 1e-9);
    }

    #[test]
    fn no_common_stamps_give_no_accuracy() {
        let gt = line(10, 0.0);
        let late = Trajectory::from_parts(
            (0..10).map(|i| 100.0 + i as f64).collect(),
            vec![Se3::identity(); 10],
        )
        .unwrap();
        assert!(accuracy(&gt, &late, Sensor::Rgbd).is_none());
    }

    #[test]
    fn ground_truth_poses_are_found_within_the_association_window() {
        let gt = line(10, 0.0);
        assert!(gt_pose_at(&gt, 0.31).is_some());
        assert!(gt_pose_at(&gt, 0.35).is_none());
        let (metres, degrees) = true_separation(&gt, 0.0, 0.2).unwrap();
        assert!((metres - (0.1f64.powi(2) + 0.04f64.powi(2)).sqrt()).abs() < 1e-12);
        assert_eq!(degrees, 0.0);
        assert!(true_separation(&gt, 0.0, 5.0).is_none());
    }

    #[test]
    fn late_starts_are_counted_in_ground_truth_frames() {
        let gt = line(10, 0.0);
        let est = Trajectory::from_parts(vec![0.3, 0.4], vec![Se3::identity(); 2]).unwrap();
        assert_eq!(frames_before_first_pose(&gt, &est), Some(3));
        assert_eq!(frames_before_first_pose(&gt, &Trajectory::default()), None);
    }
}
