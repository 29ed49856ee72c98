//! The rigid transform between two keyframes from their matched map points (ORB-SLAM's
//! `Sim3Solver` with the scale fixed, as for RGB-D and stereo): RANSAC over 3-point Umeyama
//! fits, scored by the reprojection error in both images, refined on the inliers.

use super::Rng;
use stillpoint_geometry::{PinholeCamera, Se3, Sim3, Vec2, Vec3, umeyama};

/// A matched pair: a map point in camera 1's frame and one in camera 2's, with the keypoints
/// that observe them.
#[derive(Clone, Copy, Debug)]
pub struct RigidPair {
    /// The map point in camera 1's frame.
    pub p1: Vec3,
    /// The matched map point in camera 2's frame.
    pub p2: Vec3,
    /// Its keypoint in image 1, undistorted pixels.
    pub px1: Vec2,
    /// Its keypoint in image 2.
    pub px2: Vec2,
    /// Inverse keypoint variance (octave scale squared) in image 1 and 2.
    pub inv_sigma2_1: f64,
    /// Inverse keypoint variance in image 2 (see `inv_sigma2_1`).
    pub inv_sigma2_2: f64,
}

/// RANSAC parameters (ORB-SLAM `Sim3Solver::SetRansacParameters(0.99, 20, 300)`).
#[derive(Clone, Copy, Debug)]
pub struct RigidRansacParams {
    /// Hypotheses tried at most.
    pub iterations: usize,
    /// A hypothesis needs this many inliers.
    pub min_inliers: usize,
    /// Chi-square on the octave-weighted reprojection error in each image (ORB-SLAM: 9.21,
    /// 2 DoF at 99 %).
    pub chi2: f64,
    /// Stop once a hypothesis is this likely to be the best (RANSAC's confidence).
    pub probability: f64,
    /// Seed of the sampler (runs are reproducible).
    pub seed: u64,
}

impl Default for RigidRansacParams {
    fn default() -> Self {
        Self {
            iterations: 300,
            min_inliers: 20,
            chi2: 9.21,
            probability: 0.99,
            seed: 0x51_3a,
        }
    }
}

/// T12 (camera 2 to camera 1) of the pair set's inliers under `chi2`.
pub fn rigid_inliers(t12: &Se3, pairs: &[RigidPair], cam: &PinholeCamera, chi2: f64) -> Vec<bool> {
    let t21 = t12.inverse();
    inliers_both_ways(pairs, cam, chi2, |p| apply(t12, p), |p| apply(&t21, p))
}

/// Per pair: camera 2's point seen in image 1 (`to1`) and camera 1's in image 2 (`to2`), each
/// within `chi2` of its keypoint.
fn inliers_both_ways(
    pairs: &[RigidPair],
    cam: &PinholeCamera,
    chi2: f64,
    to1: impl Fn(&Vec3) -> Vec3,
    to2: impl Fn(&Vec3) -> Vec3,
) -> Vec<bool> {
    let seen = |q: Vec3, px: &Vec2, inv: f64| {
        cam.project_undistorted(&q)
            .is_some_and(|uv| (uv - px).norm_squared() * inv < chi2)
    };
    pairs
        .iter()
        .map(|p| {
            seen(to1(&p.p2), &p.px1, p.inv_sigma2_1) && seen(to2(&p.p1), &p.px2, p.inv_sigma2_2)
        })
        .collect()
}

/// A point moved by a pose (nalgebra's `Isometry * Vector` would only rotate it).
pub fn apply(t: &Se3, p: &Vec3) -> Vec3 {
    t.transform_point(&nalgebra::Point3::from(*p)).coords
}

fn fit(pairs: &[RigidPair], idx: impl Iterator<Item = usize> + Clone) -> Option<Se3> {
    fit_similarity(pairs, idx, false).map(|s| s.rigid)
}

fn fit_similarity(
    pairs: &[RigidPair],
    idx: impl Iterator<Item = usize> + Clone,
    with_scale: bool,
) -> Option<Sim3> {
    let src: Vec<Vec3> = idx.clone().map(|i| pairs[i].p2).collect();
    let dst: Vec<Vec3> = idx.map(|i| pairs[i].p1).collect();
    umeyama(&src, &dst, with_scale)
}

/// T12 with the most inliers, refitted on them, with the inlier flags; `None` when no
/// hypothesis reaches `min_inliers`.
pub fn ransac_rigid(
    pairs: &[RigidPair],
    cam: &PinholeCamera,
    p: &RigidRansacParams,
) -> Option<(Se3, Vec<bool>)> {
    ransac(
        pairs,
        p,
        |idx| fit(pairs, idx.iter().copied()),
        |t| rigid_inliers(t, pairs, cam, p.chi2),
    )
}

/// S12 (camera 2 to camera 1, with the scale: monocular maps each have their own) of the pair
/// set's inliers under `chi2`: ORB-SLAM's `Sim3Solver`, scored in both images.
pub fn similarity_inliers(
    s12: &Sim3,
    pairs: &[RigidPair],
    cam: &PinholeCamera,
    chi2: f64,
) -> Vec<bool> {
    let s21 = s12.inverse();
    inliers_both_ways(
        pairs,
        cam,
        chi2,
        |p| s12.transform_point(p),
        |p| s21.transform_point(p),
    )
}

/// As [`ransac_rigid`] with the scale free: S12 (`p1 = s R p2 + t`) with the most inliers,
/// refitted on them.
pub fn ransac_similarity(
    pairs: &[RigidPair],
    cam: &PinholeCamera,
    p: &RigidRansacParams,
) -> Option<(Sim3, Vec<bool>)> {
    ransac(
        pairs,
        p,
        |idx| fit_similarity(pairs, idx.iter().copied(), true),
        |s| similarity_inliers(s, pairs, cam, p.chi2),
    )
}

/// RANSAC over 3-pair samples: the hypothesis `fit` gives with the most `inliers`, refitted on
/// them when that loses none.
fn ransac<T>(
    pairs: &[RigidPair],
    p: &RigidRansacParams,
    fit: impl Fn(&[usize]) -> Option<T>,
    inliers: impl Fn(&T) -> Vec<bool>,
) -> Option<(T, Vec<bool>)> {
    let n = pairs.len();
    if n < 3 || n < p.min_inliers {
        return None;
    }
    let mut rng = Rng(p.seed | 1);
    let mut best: Option<(usize, T, Vec<bool>)> = None;
    let mut max_iterations = p.iterations;
    let mut it = 0;
    while it < max_iterations {
        it += 1;
        let s: [usize; 3] = std::array::from_fn(|_| rng.below(n));
        if s[0] == s[1] || s[1] == s[2] || s[0] == s[2] {
            continue;
        }
        // Nearly collinear samples give a rotation about their line at random.
        let (a, b, c) = (pairs[s[0]].p2, pairs[s[1]].p2, pairs[s[2]].p2);
        if (b - a).cross(&(c - a)).norm() < 1e-6 {
            continue;
        }
        let Some(t) = fit(&s) else {
            continue;
        };
        let flags = inliers(&t);
        let k = flags.iter().filter(|&&f| f).count();
        if best.as_ref().is_none_or(|b| k > b.0) {
            // Iterations needed for `probability` with this inlier ratio (ORB-SLAM's formula).
            let ratio = k as f64 / n as f64;
            let need = ((1.0 - p.probability).ln() / (1.0 - ratio.powi(3)).ln()).ceil();
            if need.is_finite() && need >= 0.0 {
                max_iterations = max_iterations.min((need as usize).max(1));
            }
            best = Some((k, t, flags));
        }
    }
    let (k, t, flags) = best?;
    if k < p.min_inliers {
        return None;
    }
    // Refit on the inliers; keep the refit when it does not lose inliers.
    let inl: Vec<usize> = (0..n).filter(|&i| flags[i]).collect();
    let refined = fit(&inl)?;
    let f2 = inliers(&refined);
    if f2.iter().filter(|&&f| f).count() >= k {
        Some((refined, f2))
    } else {
        Some((t, flags))
    }
}

/// Refine T12 by Gauss-Newton on the reprojection errors in both images (ORB-SLAM
/// `OptimizeSim3` with the scale fixed): `iterations` with a Huber kernel at sqrt(`chi2`), the
/// pairs above `chi2` in either image dropped, then `iterations` more on the rest. Returns the
/// refined transform and the inlier flags.
pub fn refine_rigid(
    t12: &Se3,
    pairs: &[RigidPair],
    cam: &PinholeCamera,
    chi2: f64,
    iterations: usize,
) -> (Se3, Vec<bool>) {
    let mut t = *t12;
    let mut active = vec![true; pairs.len()];
    for round in 0..2 {
        for _ in 0..iterations {
            let Some(next) = gauss_newton_step(&t, pairs, &active, cam, chi2) else {
                break;
            };
            let moved = (next.inverse() * t).translation.vector.norm()
                + (next.inverse() * t).rotation.angle();
            t = next;
            if moved < 1e-10 {
                break;
            }
        }
        active = rigid_inliers(&t, pairs, cam, chi2);
        if round == 0 && active.iter().all(|&a| a) {
            break;
        }
    }
    (t, active)
}

fn gauss_newton_step(
    t12: &Se3,
    pairs: &[RigidPair],
    active: &[bool],
    cam: &PinholeCamera,
    chi2: f64,
) -> Option<Se3> {
    use nalgebra::{Matrix2x3, Matrix6, Vector6};
    use stillpoint_geometry::dpc_dpose;
    let t21 = t12.inverse();
    let r21 = *t21.rotation.to_rotation_matrix().matrix();
    let delta_huber = chi2.sqrt();
    let (mut h, mut b) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
    let mut used = 0;
    let jac = |q: &Vec3| {
        let iz = 1.0 / q.z;
        Matrix2x3::new(
            cam.fx * iz,
            0.0,
            -cam.fx * q.x * iz * iz,
            0.0,
            cam.fy * iz,
            -cam.fy * q.y * iz * iz,
        )
    };
    for (p, _) in pairs.iter().zip(active).filter(|(_, a)| **a) {
        let q1 = apply(t12, &p.p2);
        let q2 = apply(&t21, &p.p1);
        let (Some(uv1), Some(uv2)) = (cam.project_undistorted(&q1), cam.project_undistorted(&q2))
        else {
            continue;
        };
        // Prediction Jacobians w.r.t. a left perturbation of T12 (T21 moves by its inverse).
        let j1 = jac(&q1) * dpc_dpose(&q1);
        let j2 = -(jac(&q2) * r21 * dpc_dpose(&p.p1));
        for (e, j, inv) in [
            (p.px1 - uv1, j1, p.inv_sigma2_1),
            (p.px2 - uv2, j2, p.inv_sigma2_2),
        ] {
            let e2 = e.norm_squared() * inv;
            let w = inv
                * if e2.sqrt() <= delta_huber {
                    1.0
                } else {
                    delta_huber / e2.sqrt()
                };
            h += j.transpose() * j * w;
            b += j.transpose() * e * w;
        }
        used += 1;
    }
    if used < 3 {
        return None;
    }
    let d = h.cholesky()?.solve(&b);
    d.iter()
        .all(|x| x.is_finite())
        .then(|| crate::optimize::retract(t12, &d))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pairs(truth: &Se3, cam: &PinholeCamera, n: usize, outliers: usize) -> Vec<RigidPair> {
        (0..n)
            .map(|i| {
                let p2 = Vec3::new(
                    ((i * 37) % 100) as f64 / 40.0 - 1.2,
                    ((i * 53) % 100) as f64 / 60.0 - 0.8,
                    2.0 + (i % 9) as f64 * 0.4,
                );
                let mut p1 = apply(truth, &p2);
                let px1 = cam.project_undistorted(&p1).unwrap();
                let px2 = cam.project_undistorted(&p2).unwrap();
                if i < outliers {
                    p1 += Vec3::new(0.4, -0.3, 0.5); // a wrong match
                }
                RigidPair {
                    p1,
                    p2,
                    px1,
                    px2,
                    inv_sigma2_1: 1.0,
                    inv_sigma2_2: 1.0,
                }
            })
            .collect()
    }

    #[test]
    fn exact_and_outlier_laden_correspondences() {
        let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
        let truth = Se3::new(Vec3::new(0.1, -0.05, 0.2), Vec3::new(0.02, 0.15, -0.03));
        let exact = pairs(&truth, &cam, 60, 0);
        let (t, flags) = ransac_rigid(&exact, &cam, &RigidRansacParams::default()).unwrap();
        assert!((t.inverse() * truth).translation.vector.norm() < 1e-9);
        assert!(flags.iter().all(|&f| f));
        // 40 % wrong matches: the pose is still exact and exactly the wrong ones are out.
        let noisy = pairs(&truth, &cam, 60, 24);
        let (t, flags) = ransac_rigid(&noisy, &cam, &RigidRansacParams::default()).unwrap();
        let e = t.inverse() * truth;
        assert!(e.translation.vector.norm() < 1e-9 && e.rotation.angle() < 1e-9);
        assert!(flags.iter().enumerate().all(|(i, &f)| f == (i >= 24)));
        // Too few inliers for the threshold: no transform.
        let mostly_wrong = pairs(&truth, &cam, 30, 15);
        assert!(ransac_rigid(&mostly_wrong, &cam, &RigidRansacParams::default()).is_none());
        assert!(ransac_rigid(&exact[..2], &cam, &RigidRansacParams::default()).is_none());
    }

    #[test]
    fn a_similarity_finds_the_scale_between_two_monocular_maps() {
        let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
        let rigid = Se3::new(Vec3::new(0.1, -0.05, 0.2), Vec3::new(0.02, 0.15, -0.03));
        // Camera 2's map is 2.5 times camera 1's: p1 = s R p2 + t with s = 0.4.
        let truth = Sim3 { scale: 0.4, rigid };
        let mut ps = pairs(&rigid, &cam, 60, 20);
        for p in &mut ps {
            p.p2 *= 2.5;
        }
        let (s12, flags) = ransac_similarity(&ps, &cam, &RigidRansacParams::default()).unwrap();
        assert!((s12.scale - truth.scale).abs() < 1e-9, "{}", s12.scale);
        let e = s12.rigid.inverse() * truth.rigid;
        assert!(e.translation.vector.norm() < 1e-9 && e.rotation.angle() < 1e-9);
        assert!(flags.iter().enumerate().all(|(i, &f)| f == (i >= 20)));
        let back = s12.inverse();
        let x = Vec3::new(0.3, -0.2, 2.0);
        assert!((back.transform_point(&s12.transform_point(&x)) - x).norm() < 1e-12);
        // The scale fixed, those pairs agree with no rigid transform.
        assert!(ransac_rigid(&ps, &cam, &RigidRansacParams::default()).is_none());
    }

    #[test]
    fn refinement_recovers_the_transform_from_a_rough_guess_and_drops_wrong_pairs() {
        let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
        let truth = Se3::new(Vec3::new(0.1, -0.05, 0.2), Vec3::new(0.02, 0.15, -0.03));
        let ps = pairs(&truth, &cam, 60, 6);
        let rough = Se3::new(Vec3::new(0.0, 0.0, 0.01), Vec3::new(0.0, 0.01, 0.0)) * truth;
        let (t, flags) = refine_rigid(&rough, &ps, &cam, 10.0, 10);
        let e = t.inverse() * truth;
        assert!(
            e.translation.vector.norm() < 1e-6 && e.rotation.angle() < 1e-6,
            "{e}"
        );
        assert!(flags.iter().enumerate().all(|(i, &f)| f == (i >= 6)));
    }
}
