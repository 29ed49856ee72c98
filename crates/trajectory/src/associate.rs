//! Timestamp association, exactly as evo 1.38 (`evo.core.sync.associate_trajectories`, nearest
//! time): start from the trajectory with fewer poses; for each of its stamps take the nearest stamp
//! of the other within `max_diff` (ties go to the earlier stamp). It is not one-to-one: a pose of
//! the longer trajectory may be used twice, as in evo.

use crate::{Trajectory, TrajectoryError};

/// How poses of two trajectories are paired.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Matching {
    /// Nearest timestamp within `max_diff` seconds (evo's default 0.01), after adding `offset`
    /// seconds to the estimate's stamps (evo's `--t_offset`, default 0).
    Nearest {
        /// Largest stamp difference paired, seconds.
        max_diff: f64,
        /// Added to the estimate's stamps, seconds.
        offset: f64,
    },
    /// Pose i with pose i (KITTI files, which carry no stamps); lengths must be equal.
    ByIndex,
}

impl Default for Matching {
    /// evo's defaults: nearest stamp within 0.01 s, no offset.
    fn default() -> Self {
        Matching::Nearest {
            max_diff: 0.01,
            offset: 0.0,
        }
    }
}

impl Matching {
    /// How files of these formats are paired: by index when either is KITTI (its files carry
    /// no stamps, as `evo_ape kitti` pairs them), else by nearest stamp within `max_diff` after
    /// adding `offset` to the estimate's stamps.
    pub fn for_formats(
        gt: crate::TrajectoryFormat,
        est: crate::TrajectoryFormat,
        max_diff: f64,
        offset: f64,
    ) -> Self {
        use crate::TrajectoryFormat::Kitti;
        if gt == Kitti || est == Kitti {
            Matching::ByIndex
        } else {
            Matching::Nearest { max_diff, offset }
        }
    }
}

/// For each stamp of `short`, the index in `long` (sorted) of the nearest stamp within `max_diff`,
/// as evo's binary-search `matching_time_indices`.
fn matching_time_indices(short: &[f64], long: &[f64], max_diff: f64) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let (Some(&first), Some(&last)) = (long.first(), long.last()) else {
        return out;
    };
    for (i, &s) in short.iter().enumerate() {
        if s < first - max_diff || s > last + max_diff {
            continue;
        }
        // numpy searchsorted(side="right"): first index with long[k] > s.
        let mut k = long.partition_point(|&x| x <= s);
        if k >= long.len() {
            k = long.len() - 1;
        }
        let diff_ub = long[k] - s;
        let diff_lb = if k > 0 {
            s - long[k - 1]
        } else {
            f64::INFINITY
        };
        if diff_ub <= max_diff && diff_ub < diff_lb {
            out.push((i, k));
        } else if diff_lb <= max_diff && diff_lb <= diff_ub {
            out.push((i, k - 1));
        }
    }
    out
}

/// Index pairs `(gt index, est index)` of associated poses, in the order evo produces them.
/// An error when nothing matches.
pub fn associate(
    gt: &Trajectory,
    est: &Trajectory,
    matching: Matching,
) -> Result<Vec<(usize, usize)>, TrajectoryError> {
    match matching {
        Matching::ByIndex => {
            if gt.len() != est.len() {
                return Err(TrajectoryError::Invalid(format!(
                    "matching by index needs equal lengths, got {} ground-truth and {} estimated poses",
                    gt.len(),
                    est.len()
                )));
            }
            Ok((0..gt.len()).map(|i| (i, i)).collect())
        }
        Matching::Nearest { max_diff, offset } => {
            if max_diff.is_nan() || max_diff < 0.0 || !offset.is_finite() {
                return Err(TrajectoryError::Invalid(format!(
                    "max_diff must be >= 0 and offset finite (got {max_diff}, {offset})"
                )));
            }
            let est_longer = est.len() > gt.len();
            let pairs = if est_longer {
                let long: Vec<f64> = est.stamps.iter().map(|t| t + offset).collect();
                matching_time_indices(&gt.stamps, &long, max_diff)
            } else {
                let long: Vec<f64> = gt.stamps.iter().map(|t| t - offset).collect();
                matching_time_indices(&est.stamps, &long, max_diff)
                    .into_iter()
                    .map(|(e, g)| (g, e))
                    .collect()
            };
            if pairs.is_empty() {
                return Err(TrajectoryError::Invalid(format!(
                    "found no matching timestamps between ground truth and estimate with max. time \
                     diff {max_diff} s and offset {offset} s"
                )));
            }
            Ok(pairs)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kitti_files_pair_by_index() {
        use crate::TrajectoryFormat::{Euroc, Kitti, Tum};
        assert_eq!(
            Matching::for_formats(Kitti, Tum, 0.01, 0.0),
            Matching::ByIndex
        );
        assert_eq!(
            Matching::for_formats(Tum, Kitti, 0.01, 0.0),
            Matching::ByIndex
        );
        assert_eq!(
            Matching::for_formats(Euroc, Tum, 0.02, 0.5),
            Matching::Nearest {
                max_diff: 0.02,
                offset: 0.5
            }
        );
    }
    use stillpoint_geometry::Se3;

    fn traj(stamps: &[f64]) -> Trajectory {
        Trajectory::from_parts(stamps.to_vec(), vec![Se3::identity(); stamps.len()]).unwrap()
    }

    #[test]
    fn nearest_within_max_diff_ties_go_to_the_earlier_stamp() {
        let gt = traj(&[0.0, 0.1, 0.2, 0.3, 0.4]);
        let est = traj(&[0.005, 0.15, 0.301]);
        // 0.15 is 0.05 from both neighbours: too far with max_diff 0.01.
        let pairs = associate(&gt, &est, Matching::default()).unwrap();
        assert_eq!(pairs, vec![(0, 0), (3, 2)]);
        let wide = Matching::Nearest {
            max_diff: 0.06,
            offset: 0.0,
        };
        let pairs = associate(&gt, &est, wide).unwrap();
        assert_eq!(pairs, vec![(0, 0), (1, 1), (3, 2)]);
    }

    #[test]
    fn offset_shifts_the_estimate_and_no_match_is_an_error() {
        let gt = traj(&[10.0, 11.0, 12.0]);
        let est = traj(&[0.0, 1.0]);
        assert!(associate(&gt, &est, Matching::default()).is_err());
        let shifted = Matching::Nearest {
            max_diff: 0.01,
            offset: 10.0,
        };
        assert_eq!(associate(&gt, &est, shifted).unwrap(), vec![(0, 0), (1, 1)]);
        assert!(associate(&gt, &est, Matching::ByIndex).is_err());
    }
}
