//! Absolute trajectory error (evo_ape, translation part) and relative pose error (evo_rpe,
//! translation and rotation parts), with evo 1.38's conventions:
//! - association by nearest stamp ([`crate::associate`](mod@crate::associate)), then Umeyama alignment of the estimate's
//!   positions onto the ground truth's (`-a` SE(3), `-as` Sim(3));
//! - ATE error i = |p_gt,i - p_est,i|;
//! - RPE pair (i, j): E = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j), Q ground truth, P estimate; pairs are
//!   consecutive (evo's `--all_pairs` off), chosen on the estimate's poses;
//! - statistics as numpy: population std, median averaging the middle two.

use crate::{Matching, Trajectory, TrajectoryError, associate};
use serde::Serialize;
use stillpoint_geometry::{Se3, Sim3, Vec3, umeyama};

/// count, rmse, mean, median, std, min, max, sse of a list of errors (evo's statistics).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct ErrorStats {
    /// Errors counted.
    pub count: usize,
    /// Root mean square.
    pub rmse: f64,
    /// Mean.
    pub mean: f64,
    /// Median.
    pub median: f64,
    /// Population standard deviation (numpy's `std`, ddof 0).
    pub std: f64,
    /// Smallest.
    pub min: f64,
    /// Largest.
    pub max: f64,
    /// Sum of squared errors.
    pub sse: f64,
}

impl ErrorStats {
    /// Statistics of `errors`; all zero when empty.
    pub fn from_errors(errors: &[f64]) -> Self {
        let n = errors.len();
        if n == 0 {
            return Self::default();
        }
        let nf = n as f64;
        let sse: f64 = errors.iter().map(|e| e * e).sum();
        let mean = errors.iter().sum::<f64>() / nf;
        let var = errors.iter().map(|e| (e - mean) * (e - mean)).sum::<f64>() / nf;
        let mut sorted = errors.to_vec();
        sorted.sort_by(f64::total_cmp);
        let median = if n % 2 == 1 {
            sorted[n / 2]
        } else {
            0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
        };
        Self {
            count: n,
            rmse: (sse / nf).sqrt(),
            mean,
            median,
            std: var.sqrt(),
            min: sorted[0],
            max: sorted[n - 1],
            sse,
        }
    }
}

/// Alignment of the estimate onto the ground truth before measuring.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Alignment {
    /// Compare as is (evo without `-a`).
    #[default]
    None,
    /// Rigid Umeyama (evo `-a`).
    Se3,
    /// Similarity Umeyama, scale corrected (evo `-as`); needed for monocular estimates.
    Sim3,
}

impl std::str::FromStr for Alignment {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "none" => Ok(Self::None),
            "se3" => Ok(Self::Se3),
            "sim3" => Ok(Self::Sim3),
            other => Err(format!("unknown alignment {other:?} (none, se3, sim3)")),
        }
    }
}

/// Options of [`ate`]. Defaults: evo_ape's (`max_diff` 0.01 s, no offset, no alignment).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AteOptions {
    /// Alignment of the estimate before comparing.
    pub align: Alignment,
    /// How poses are paired.
    pub matching: Matching,
}

/// The ATE and what it was computed from (for plots and reports).
#[derive(Clone, Debug)]
pub struct AteResult {
    /// Statistics of the translational error, metres.
    pub stats: ErrorStats,
    /// Error of each associated pair, metres, in pair order.
    pub errors: Vec<f64>,
    /// `(gt index, est index)` of each associated pair.
    pub pairs: Vec<(usize, usize)>,
    /// The transform applied to the estimate (identity without alignment).
    pub alignment: Sim3,
    /// Ground-truth positions of the pairs.
    pub gt_positions: Vec<Vec3>,
    /// Aligned estimated positions of the pairs.
    pub est_positions: Vec<Vec3>,
}

impl AteResult {
    /// (stamp of the estimate's pose, its error) of each pair: the error over time. `est` is
    /// the trajectory the result was computed for.
    pub fn errors_over_time(&self, est: &Trajectory) -> Vec<(f64, f64)> {
        self.pairs
            .iter()
            .zip(&self.errors)
            .filter_map(|(&(_, e), &err)| Some((*est.stamps.get(e)?, err)))
            .collect()
    }
}

/// The estimate's scale along the path ([`scale_along_path`]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ScaleAlongPath {
    /// Per piece of the ground-truth path (equal lengths, in order): the scale that best maps
    /// the truth's positions there onto the aligned estimate's, about their means. 1 is the
    /// scale of the whole run's alignment.
    pub ratios: Vec<f64>,
    /// The least-squares line through `ratios` (over the path's fraction at each piece's
    /// middle), its value at the path's end minus at its start: the share by which the scale
    /// grew (negative: shrank) from one end to the other.
    pub drift: f64,
}

/// Pieces the path is cut into for [`scale_along_path`] by default (`eval ate`, `run --json`):
/// a tenth of a 60 m drive is 6 m, long against a monocular run's centimetres of error.
pub const SCALE_PIECES: usize = 10;

/// A piece of the path counts in [`scale_along_path`] when the RMS spread of its true positions
/// is at least this many times the run's ATE.
const MIN_EXTENT_PER_ERROR: f64 = 10.0;

/// How the scale of an aligned estimate (a monocular run's, [`Alignment::Sim3`]) changes along
/// the path: `pieces` pieces of equal ground-truth path length, each with the scale of its own
/// positions against the truth's. Jitter does not lengthen a piece (a path length of a noisy
/// estimate would). Only pieces whose true positions spread at least 10 times the run's ATE
/// count (a drive's pieces, not a hand-held camera's few centimetres); `None` with fewer than
/// two such pieces of at least 3 pairs.
///
/// ```
/// use stillpoint_geometry::{Se3, Vec3};
/// use stillpoint_trajectory::{Alignment, AteOptions, Trajectory, ate, scale_along_path};
/// // A straight drive whose estimate covers each metre 5 % shorter by the end.
/// let n = 200;
/// let stamps: Vec<f64> = (0..n).map(|i| i as f64).collect();
/// let at = |x: f64| Se3::new(Vec3::new(x, 0.0, 0.0), Vec3::zeros());
/// let gt = Trajectory::from_parts(stamps.clone(), (0..n).map(|i| at(i as f64)).collect()).unwrap();
/// let mut x = 0.0;
/// let est: Vec<Se3> = (0..n).map(|i| { let p = at(x); x += 1.0 - 0.05 * i as f64 / n as f64; p }).collect();
/// let est = Trajectory::from_parts(stamps, est).unwrap();
/// let r = ate(&gt, &est, &AteOptions { align: Alignment::Sim3, ..Default::default() }).unwrap();
/// let s = scale_along_path(&r, 10).unwrap();
/// assert!((s.drift + 0.05).abs() < 0.01, "{}", s.drift);
/// ```
pub fn scale_along_path(r: &AteResult, pieces: usize) -> Option<ScaleAlongPath> {
    let (g, e) = (&r.gt_positions, &r.est_positions);
    if pieces < 2 || g.len() < 2 {
        return None;
    }
    let along = crate::distances_along(g);
    let total = along[along.len() - 1];
    if total <= 0.0 {
        return None;
    }
    // Each pair in the piece its distance along the true path falls in (the end in the last).
    let mut members: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for (k, &d) in along.iter().enumerate() {
        let piece = ((d / total * pieces as f64) as usize).min(pieces - 1);
        members.entry(piece).or_default().push(k);
    }
    let mut points: Vec<(f64, f64)> = Vec::new();
    for (piece, idx) in members {
        if idx.len() < 3 {
            continue;
        }
        let mean = |v: &[Vec3]| idx.iter().map(|&k| v[k]).sum::<Vec3>() / idx.len() as f64;
        let (gm, em) = (mean(g), mean(e));
        let (mut cross, mut spread) = (0.0, 0.0);
        for &k in &idx {
            cross += (e[k] - em).dot(&(g[k] - gm));
            spread += (g[k] - gm).norm_squared();
        }
        // A piece whose extent is not well above the run's error tells no scale (a hand-held
        // camera's 10 cm with 2 cm of error).
        if spread > 0.0 && (spread / idx.len() as f64).sqrt() >= MIN_EXTENT_PER_ERROR * r.stats.rmse
        {
            points.push(((piece as f64 + 0.5) / pieces as f64, cross / spread));
        }
    }
    if points.len() < 2 {
        return None;
    }
    let n = points.len() as f64;
    let (mx, my) = (
        points.iter().map(|p| p.0).sum::<f64>() / n,
        points.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxy: f64 = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = points.iter().map(|p| (p.0 - mx).powi(2)).sum();
    Some(ScaleAlongPath {
        ratios: points.iter().map(|p| p.1).collect(),
        drift: if sxx > 0.0 { sxy / sxx } else { 0.0 },
    })
}

/// Associated pairs, the matched ground truth, the matched and aligned estimate, the alignment.
type Aligned = (Vec<(usize, usize)>, Trajectory, Trajectory, Sim3);

/// Associate, align (positions only) and return the matched, aligned trajectories.
fn associate_and_align(
    gt: &Trajectory,
    est: &Trajectory,
    align: Alignment,
    matching: Matching,
) -> Result<Aligned, TrajectoryError> {
    if gt.is_empty() || est.is_empty() {
        return Err(TrajectoryError::Invalid(
            "both trajectories need at least one pose".into(),
        ));
    }
    let pairs = associate(gt, est, matching)?;
    let gt_ids: Vec<usize> = pairs.iter().map(|p| p.0).collect();
    let est_ids: Vec<usize> = pairs.iter().map(|p| p.1).collect();
    let gt_m = gt.select(&gt_ids);
    let mut est_m = est.select(&est_ids);
    let transform = match align {
        Alignment::None => Sim3::identity(),
        Alignment::Se3 | Alignment::Sim3 => umeyama(
            &est_m.positions(),
            &gt_m.positions(),
            align == Alignment::Sim3,
        )
        .ok_or_else(|| {
            TrajectoryError::Invalid(format!(
                "Umeyama alignment failed on {} associated poses (need at least 2 distinct positions)",
                pairs.len()
            ))
        })?,
    };
    if align != Alignment::None {
        for p in &mut est_m.poses {
            *p = transform.transform_pose(p);
        }
    }
    Ok((pairs, gt_m, est_m, transform))
}

/// Absolute trajectory error, translation part (`evo_ape tum GT EST [-a|-as]`).
pub fn ate(
    gt: &Trajectory,
    est: &Trajectory,
    opts: &AteOptions,
) -> Result<AteResult, TrajectoryError> {
    let (pairs, gt_m, est_m, alignment) = associate_and_align(gt, est, opts.align, opts.matching)?;
    let gt_positions = gt_m.positions();
    let est_positions = est_m.positions();
    let errors: Vec<f64> = gt_positions
        .iter()
        .zip(&est_positions)
        .map(|(g, e)| (e - g).norm())
        .collect();
    Ok(AteResult {
        stats: ErrorStats::from_errors(&errors),
        errors,
        pairs,
        alignment,
        gt_positions,
        est_positions,
    })
}

/// What the RPE's `delta` counts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DeltaUnit {
    /// Poses (evo `f`).
    #[default]
    Frames,
    /// Seconds between stamps (stillpoint's addition; evo 1.38 has no time unit).
    Seconds,
    /// Metres of travelled path (evo `m`).
    Metres,
}

impl std::str::FromStr for DeltaUnit {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "f" | "frames" => Ok(Self::Frames),
            "s" | "seconds" => Ok(Self::Seconds),
            "m" | "metres" | "meters" => Ok(Self::Metres),
            other => Err(format!("unknown delta unit {other:?} (f, s, m)")),
        }
    }
}

/// Options of [`rpe`]. Defaults: evo_rpe's (delta 1 frame, consecutive pairs, no alignment).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RpeOptions {
    /// Alignment of the estimate before comparing.
    pub align: Alignment,
    /// How poses are paired.
    pub matching: Matching,
    /// Pair distance, in `delta_unit`.
    pub delta: f64,
    /// What `delta` counts (frames, metres, ...).
    pub delta_unit: DeltaUnit,
}

impl Default for RpeOptions {
    fn default() -> Self {
        Self {
            align: Alignment::None,
            matching: Matching::default(),
            delta: 1.0,
            delta_unit: DeltaUnit::Frames,
        }
    }
}

/// RPE translation (metres) and rotation (degrees) parts over the same pairs.
#[derive(Clone, Debug)]
pub struct RpeResult {
    /// Translational error of the relative poses, metres.
    pub translation: ErrorStats,
    /// Rotational error of the relative poses, degrees.
    pub rotation_deg: ErrorStats,
    /// `(i, j)` indices into the associated trajectories.
    pub pairs: Vec<(usize, usize)>,
    /// Per pair, metres.
    pub translation_errors: Vec<f64>,
    /// Per pair, degrees.
    pub rotation_errors_deg: Vec<f64>,
}

/// Consecutive pairs: start at 0, close a pair once the accumulated measure reaches `delta`
/// (evo's `filter_pairs_by_path` without `all_pairs`).
fn consecutive_pairs(steps: impl Iterator<Item = f64>, delta: f64) -> Vec<(usize, usize)> {
    let mut ids = vec![0usize];
    let mut acc = 0.0;
    for (k, step) in steps.enumerate() {
        acc += step;
        if acc >= delta {
            ids.push(k + 1);
            acc = 0.0;
        }
    }
    ids.windows(2).map(|w| (w[0], w[1])).collect()
}

/// Rotation angle of a unit quaternion in radians, well conditioned near zero (as scipy's
/// `as_rotvec`, which evo uses, rather than `acos`).
fn rotation_angle(q: &nalgebra::UnitQuaternion<f64>) -> f64 {
    2.0 * q.imag().norm().atan2(q.scalar().abs())
}

/// Relative pose error (`evo_rpe tum GT EST --delta N --delta_unit f|m [-a|-as]`, translation
/// part and `-r angle_deg`).
pub fn rpe(
    gt: &Trajectory,
    est: &Trajectory,
    opts: &RpeOptions,
) -> Result<RpeResult, TrajectoryError> {
    if !opts.delta.is_finite() || opts.delta <= 0.0 {
        return Err(TrajectoryError::Invalid(format!(
            "RPE delta must be a positive number, got {}",
            opts.delta
        )));
    }
    let (_, gt_m, est_m, _) = associate_and_align(gt, est, opts.align, opts.matching)?;
    let n = est_m.len();
    let pairs: Vec<(usize, usize)> = match opts.delta_unit {
        DeltaUnit::Frames => {
            let step = opts.delta as usize;
            if step == 0 || step as f64 != opts.delta {
                return Err(TrajectoryError::Invalid(format!(
                    "a delta in frames must be a whole number >= 1, got {}",
                    opts.delta
                )));
            }
            let ids: Vec<usize> = (0..n).step_by(step).collect();
            ids.windows(2).map(|w| (w[0], w[1])).collect()
        }
        DeltaUnit::Metres => consecutive_pairs(
            est_m
                .poses
                .windows(2)
                .map(|w| (w[1].translation.vector - w[0].translation.vector).norm()),
            opts.delta,
        ),
        DeltaUnit::Seconds => {
            consecutive_pairs(est_m.stamps.windows(2).map(|w| w[1] - w[0]), opts.delta)
        }
    };
    if pairs.is_empty() {
        return Err(TrajectoryError::Invalid(format!(
            "delta {} ({:?}) gives no pair among {n} associated poses; try a smaller delta",
            opts.delta, opts.delta_unit
        )));
    }
    let mut translation_errors = Vec::with_capacity(pairs.len());
    let mut rotation_errors_deg = Vec::with_capacity(pairs.len());
    for &(i, j) in &pairs {
        let q_rel: Se3 = gt_m.poses[i].inverse() * gt_m.poses[j];
        let p_rel: Se3 = est_m.poses[i].inverse() * est_m.poses[j];
        let e = q_rel.inverse() * p_rel;
        translation_errors.push(e.translation.vector.norm());
        rotation_errors_deg.push(rotation_angle(&e.rotation).to_degrees());
    }
    Ok(RpeResult {
        translation: ErrorStats::from_errors(&translation_errors),
        rotation_deg: ErrorStats::from_errors(&rotation_errors_deg),
        pairs,
        translation_errors,
        rotation_errors_deg,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn helix(n: usize) -> Trajectory {
        let stamps = (0..n).map(|i| i as f64 * 0.1).collect();
        let poses = (0..n)
            .map(|i| {
                let a = i as f64 * 0.2;
                Se3::new(
                    Vec3::new(a.cos(), a.sin(), 0.05 * a),
                    Vec3::new(0.0, 0.0, a),
                )
            })
            .collect();
        Trajectory::from_parts(stamps, poses).unwrap()
    }

    #[test]
    fn jitter_does_not_read_as_a_change_of_scale() {
        // The helix at half scale, each position 2 cm off at random: every piece's scale is
        // the run's, whatever the jitter adds to the estimate's path length.
        let gt = helix(300);
        // A hash-like pseudo-random offset per pose, within ±2 cm on each axis.
        let noise = |x: f64| ((x * 12.9898).sin() * 43758.5453).fract() * 0.02;
        let mut est = gt.clone();
        for (i, p) in est.poses.iter_mut().enumerate() {
            let i = i as f64;
            let jitter = Vec3::new(noise(i + 0.1), noise(i + 0.2), noise(i + 0.3));
            *p = Se3::from_parts((p.translation.vector * 0.5 + jitter).into(), p.rotation);
        }
        let opts = AteOptions {
            align: Alignment::Sim3,
            ..Default::default()
        };
        let r = ate(&gt, &est, &opts).unwrap();
        let s = scale_along_path(&r, 10).unwrap();
        assert_eq!(s.ratios.len(), 10);
        assert!(s.ratios.iter().all(|q| (q - 1.0).abs() < 0.03), "{s:?}");
        assert!(s.drift.abs() < 0.01, "{s:?}");
        // Too short a run to cut in pieces.
        let two = ate(&helix(2), &helix(2), &opts).unwrap();
        assert_eq!(scale_along_path(&two, 10), None);
    }

    #[test]
    fn stats_follow_numpy() {
        let s = ErrorStats::from_errors(&[1.0, 2.0, 3.0, 4.0]);
        assert_eq!(s.count, 4);
        assert_eq!(s.median, 2.5);
        assert_eq!(s.mean, 2.5);
        assert!((s.std - 1.118033988749895).abs() < 1e-15);
        assert_eq!(s.sse, 30.0);
        assert!((s.rmse - 7.5f64.sqrt()).abs() < 1e-15);
        assert_eq!((s.min, s.max), (1.0, 4.0));
        assert_eq!(ErrorStats::from_errors(&[]).count, 0);
    }

    #[test]
    fn alignment_removes_a_similarity_and_rpe_sees_only_relative_motion() {
        let gt = helix(50);
        let sim = Sim3 {
            scale: 0.5,
            rigid: Se3::new(Vec3::new(3.0, -1.0, 2.0), Vec3::new(0.1, 0.4, -0.3)),
        };
        let mut est = gt.clone();
        for p in &mut est.poses {
            *p = sim.transform_pose(p);
        }
        let none = ate(&gt, &est, &AteOptions::default()).unwrap();
        assert!(none.stats.rmse > 1.0);
        let se3 = ate(
            &gt,
            &est,
            &AteOptions {
                align: Alignment::Se3,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(se3.stats.rmse > 1e-3 && se3.stats.rmse < none.stats.rmse);
        let sim3 = ate(
            &gt,
            &est,
            &AteOptions {
                align: Alignment::Sim3,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(sim3.stats.rmse < 1e-9, "{:?}", sim3.stats);
        assert!((sim3.alignment.scale - 2.0).abs() < 1e-9);

        let rigid_only = {
            let mut e = gt.clone();
            for p in &mut e.poses {
                *p = sim.rigid * *p;
            }
            e
        };
        let r = rpe(&gt, &rigid_only, &RpeOptions::default()).unwrap();
        assert_eq!(r.translation.count, 49);
        assert!(r.translation.max < 1e-9 && r.rotation_deg.max < 1e-6);
        let r10 = rpe(
            &gt,
            &gt,
            &RpeOptions {
                delta: 10.0,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(r10.pairs, vec![(0, 10), (10, 20), (20, 30), (30, 40)]);
        let rs = rpe(
            &gt,
            &gt,
            &RpeOptions {
                delta: 1.0,
                delta_unit: DeltaUnit::Seconds,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(
            rs.pairs.iter().all(|&(i, j)| j - i == 10 || j - i == 11),
            "{:?}",
            rs.pairs
        );
        let rm = rpe(
            &gt,
            &gt,
            &RpeOptions {
                delta: 1.0,
                delta_unit: DeltaUnit::Metres,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(!rm.pairs.is_empty());
        assert!(
            rpe(
                &gt,
                &gt,
                &RpeOptions {
                    delta: 1000.0,
                    ..Default::default()
                }
            )
            .is_err()
        );
        assert!(
            rpe(
                &gt,
                &gt,
                &RpeOptions {
                    delta: 1.5,
                    ..Default::default()
                }
            )
            .is_err()
        );
    }

    #[test]
    fn rpe_measures_a_known_drift() {
        let gt = helix(20);
        let mut est = gt.clone();
        // Every step of the estimate is 1 cm longer along x of the previous camera.
        for i in 1..est.len() {
            let step = gt.poses[i - 1].inverse() * gt.poses[i];
            est.poses[i] = est.poses[i - 1] * Se3::translation(0.01, 0.0, 0.0) * step;
        }
        let r = rpe(&gt, &est, &RpeOptions::default()).unwrap();
        assert!(
            (r.translation.mean - 0.01).abs() < 1e-9,
            "{:?}",
            r.translation
        );
        assert!(r.rotation_deg.max < 1e-9);
    }
}
