//! The KITTI odometry metric (`evaluate_odometry.cpp` of the KITTI devkit): for every 10th frame
//! and every segment length 100, 200, ..., 800 m of ground-truth path, the relative pose error
//! over the segment divided by its length; averaged over all segments. Translation in percent,
//! rotation in degrees per metre.

use crate::metrics::ErrorStats;
use crate::{Trajectory, TrajectoryError};
use serde::Serialize;

/// Parameters of the KITTI metric, the devkit's values by default.
#[derive(Clone, Debug, PartialEq)]
pub struct KittiOptions {
    /// Segment lengths in metres (devkit: 100..=800 step 100).
    pub lengths: Vec<f64>,
    /// First frames of segments are taken every `step` frames (devkit: 10).
    pub step: usize,
}

impl Default for KittiOptions {
    fn default() -> Self {
        Self {
            lengths: (1..=8).map(|k| 100.0 * k as f64).collect(),
            step: 10,
        }
    }
}

/// Errors of one segment length.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct KittiLengthError {
    /// Segment length, metres (100, 200, ... 800).
    pub length_m: f64,
    /// Segments of this length evaluated.
    pub segments: usize,
    /// Mean translational error, percent of the segment length.
    pub translation_pct: f64,
    /// Mean rotational error, degrees per metre.
    pub rotation_deg_per_m: f64,
}

/// The KITTI metric over all segments, and per length.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct KittiResult {
    /// Number of segments evaluated.
    pub segments: usize,
    /// Mean translational error, percent (the devkit's `t_err * 100`).
    pub translation_pct: f64,
    /// Mean rotational error, degrees per metre (the devkit's `r_err` converted from rad/m).
    pub rotation_deg_per_m: f64,
    /// Statistics of the per-segment translational errors, percent.
    pub translation_pct_stats: ErrorStats,
    /// The same per segment length.
    pub per_length: Vec<KittiLengthError>,
}

/// KITTI odometry metric of `est` against `gt`, paired by index (equal lengths).
pub fn kitti_odometry(
    gt: &Trajectory,
    est: &Trajectory,
    opts: &KittiOptions,
) -> Result<KittiResult, TrajectoryError> {
    if gt.len() != est.len() {
        return Err(TrajectoryError::Invalid(format!(
            "the KITTI metric pairs poses by index: {} ground-truth vs {} estimated poses",
            gt.len(),
            est.len()
        )));
    }
    if opts.step == 0 {
        return Err(TrajectoryError::Invalid("KITTI step must be >= 1".into()));
    }
    // Accumulated ground-truth path length at each frame.
    let dist = gt.distances_along();
    let mut t_errs = Vec::new();
    let mut per_length: Vec<(usize, f64, f64)> = vec![(0, 0.0, 0.0); opts.lengths.len()];
    for first in (0..gt.len()).step_by(opts.step) {
        for (li, &len) in opts.lengths.iter().enumerate() {
            let Some(last) = (first..gt.len()).find(|&i| dist[i] > dist[first] + len) else {
                continue;
            };
            let delta_gt = gt.poses[first].inverse() * gt.poses[last];
            let delta_est = est.poses[first].inverse() * est.poses[last];
            let err = delta_est.inverse() * delta_gt;
            // Devkit: acos of 0.5 (trace - 1), clamped.
            let r = err.rotation.to_rotation_matrix();
            let d = 0.5 * (r.matrix().trace() - 1.0);
            let r_err = d.clamp(-1.0, 1.0).acos() / len;
            let t_err = err.translation.vector.norm() / len;
            t_errs.push((t_err, r_err));
            let e = &mut per_length[li];
            e.0 += 1;
            e.1 += t_err;
            e.2 += r_err;
        }
    }
    if t_errs.is_empty() {
        return Err(TrajectoryError::Invalid(format!(
            "ground-truth path of {:.1} m is shorter than the shortest KITTI segment ({} m)",
            dist.last().copied().unwrap_or(0.0),
            opts.lengths.iter().copied().fold(f64::INFINITY, f64::min)
        )));
    }
    let n = t_errs.len() as f64;
    let t_pct: Vec<f64> = t_errs.iter().map(|e| 100.0 * e.0).collect();
    Ok(KittiResult {
        segments: t_errs.len(),
        translation_pct: t_pct.iter().sum::<f64>() / n,
        rotation_deg_per_m: t_errs.iter().map(|e| e.1).sum::<f64>().to_degrees() / n,
        translation_pct_stats: ErrorStats::from_errors(&t_pct),
        per_length: opts
            .lengths
            .iter()
            .zip(&per_length)
            .filter(|(_, e)| e.0 > 0)
            .map(|(&length_m, e)| KittiLengthError {
                length_m,
                segments: e.0,
                translation_pct: 100.0 * e.1 / e.0 as f64,
                rotation_deg_per_m: e.2.to_degrees() / e.0 as f64,
            })
            .collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use stillpoint_geometry::Se3;

    #[test]
    fn a_one_percent_longer_straight_line_gives_one_percent() {
        let n = 1000;
        let stamps: Vec<f64> = (0..n).map(|i| i as f64 * 0.1).collect();
        let gt: Vec<Se3> = (0..n)
            .map(|i| Se3::translation(0.0, 0.0, i as f64))
            .collect();
        let est: Vec<Se3> = (0..n)
            .map(|i| Se3::translation(0.0, 0.0, 1.01 * i as f64))
            .collect();
        let gt = Trajectory::from_parts(stamps.clone(), gt).unwrap();
        let est = Trajectory::from_parts(stamps, est).unwrap();
        let r = kitti_odometry(&gt, &est, &KittiOptions::default()).unwrap();
        // The devkit divides by the nominal length; segments end at the first frame beyond it
        // (1 m further here), so the error is 1% of (len + 1) / len.
        assert!(
            r.translation_pct > 1.0 && r.translation_pct < 1.011,
            "{r:?}"
        );
        assert!(r.rotation_deg_per_m.abs() < 1e-12);
        assert_eq!(r.per_length.len(), 8);
        let short = gt.select(&(0..50).collect::<Vec<_>>());
        assert!(kitti_odometry(&short, &short, &KittiOptions::default()).is_err());
    }
}
