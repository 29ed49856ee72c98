//! Pose-only optimisation (ORB-SLAM `Optimizer::PoseOptimization`): Gauss-Newton on SE3 with a
//! Huber kernel, 4 rounds of 10 iterations; after each round observations above the chi-square
//! threshold are set aside as outliers and the rest re-included; the last two rounds drop the
//! robust kernel.

use nalgebra::{Matrix6, Vector6};
use stillpoint_geometry::{PinholeCamera, Se3, Vec3};

use super::{dpc_dpose, huber_weight, project_stereo, project_with_jacobian, retract};
use crate::SlamSettings;

/// One 3D-2D(+u_r) correspondence.
#[derive(Clone, Copy, Debug)]
pub struct PoseObservation {
    /// The map point in the world.
    pub world: Vec3,
    /// Observed undistorted pixel.
    pub u: f64,
    /// Observed undistorted row (with `u`, the column).
    pub v: f64,
    /// Observed virtual right coordinate; `None` for a monocular observation (no depth).
    pub u_right: Option<f64>,
    /// 1 / sigma² of the keypoint's octave.
    pub inv_sigma2: f64,
}

fn chi2_of(obs: &PoseObservation, pose: &Se3, cam: &PinholeCamera, bf: f64) -> Option<f64> {
    let pc = pose * nalgebra::Point3::from(obs.world);
    let pred = project_stereo(cam, bf, &pc.coords)?;
    let mut e2 = (obs.u - pred.x).powi(2) + (obs.v - pred.y).powi(2);
    if let Some(ur) = obs.u_right {
        e2 += (ur - pred.z).powi(2);
    }
    Some(e2 * obs.inv_sigma2)
}

/// The weighted squared error of observation `o` seen at `pc` (camera frame), predicted at
/// `pred` with the projection's Jacobian `jp`, the transposed Jacobian of its residual by the
/// pose (6x3), and the residual. A monocular observation has two rows: the third row of both
/// is zero, which adds nothing to the normal equations (each of their sums gains a `0.0`), so
/// they are the two-row products' own, without the heap matrices a two-or-three-row view
/// would build per observation and iteration.
#[inline(always)]
fn linearise(
    o: &PoseObservation,
    pc: &Vec3,
    pred: &Vec3,
    jp: &nalgebra::Matrix3<f64>,
) -> (f64, nalgebra::Matrix6x3<f64>, nalgebra::Vector3<f64>) {
    let mut j = jp * dpc_dpose(pc);
    let rows = if o.u_right.is_some() { 3 } else { 2 };
    let e = nalgebra::Vector3::new(
        o.u - pred.x,
        o.v - pred.y,
        o.u_right.map_or(0.0, |ur| ur - pred.z),
    );
    if rows == 2 {
        j.row_mut(2).fill(0.0);
    }
    let chi2 = e.rows(0, rows).norm_squared() * o.inv_sigma2;
    (chi2, j.transpose(), e)
}

/// A Gaussian prior on a pose (ours): where the camera is believed to be, with a standard
/// deviation for its rotation (radians) and its translation (metres), both in the camera frame.
#[derive(Clone, Copy, Debug)]
pub struct PosePrior {
    /// World-to-camera.
    pub pose_cw: Se3,
    /// 1 / sigma² of the rotation, 1/rad².
    pub inv_sigma2_rot: f64,
    /// 1 / sigma² of the translation, 1/m².
    pub inv_sigma2_trans: f64,
}

/// Optimise `pose_cw` in place. Returns the outlier flag of each observation (behind-camera
/// observations count as outliers). With fewer than 3 observations the pose is left alone and
/// every observation is an outlier.
pub fn optimize_pose(pose_cw: &mut Se3, obs: &[PoseObservation], s: &SlamSettings) -> Vec<bool> {
    optimize_pose_with_prior(pose_cw, obs, s, None)
}

/// [`optimize_pose`] with a prior on the pose added to the reprojection terms: where the
/// observations leave a direction of the pose weakly fixed (a sideways shift and a turn that
/// look alike on a wall at one depth) the prior decides it, elsewhere they do.
pub fn optimize_pose_with_prior(
    pose_cw: &mut Se3,
    obs: &[PoseObservation],
    s: &SlamSettings,
    prior: Option<&PosePrior>,
) -> Vec<bool> {
    let mut outlier = vec![false; obs.len()];
    if obs.len() < 3 {
        return vec![true; obs.len()];
    }
    let cam = &s.camera;
    let (d_stereo, d_mono) = (s.chi2_stereo.sqrt(), s.chi2_mono.sqrt());
    for round in 0..s.pose_rounds {
        let robust = round < 2;
        for _ in 0..s.pose_iterations {
            let mut h = Matrix6::<f64>::zeros();
            let mut b = Vector6::<f64>::zeros();
            let mut used = 0;
            for (o, out) in obs.iter().zip(&outlier) {
                if *out {
                    continue;
                }
                let pc = (*pose_cw * nalgebra::Point3::from(o.world)).coords;
                let Some((pred, jp)) = project_with_jacobian(cam, s.bf, &pc) else {
                    continue;
                };
                let (chi2, jt, e) = linearise(o, &pc, &pred, &jp);
                let w = if robust {
                    huber_weight(
                        chi2,
                        if o.u_right.is_some() {
                            d_stereo
                        } else {
                            d_mono
                        },
                    )
                } else {
                    1.0
                } * o.inv_sigma2;
                h += jt * jt.transpose() * w;
                b += jt * e * w;
                used += 1;
            }
            if used < 3 {
                break;
            }
            if let Some(p) = prior {
                // The step that takes the pose onto the prior, in the left update's coordinates
                // (`retract`): the residual is that step minus this iteration's.
                let d = p.pose_cw * pose_cw.inverse();
                let (w, t) = (d.rotation.scaled_axis(), d.translation.vector);
                let to_prior = Vector6::new(w.x, w.y, w.z, t.x, t.y, t.z);
                for k in 0..6 {
                    let w = if k < 3 {
                        p.inv_sigma2_rot
                    } else {
                        p.inv_sigma2_trans
                    };
                    h[(k, k)] += w;
                    b[k] += w * to_prior[k];
                }
            }
            // A touch of damping keeps degenerate configurations finite.
            for k in 0..6 {
                h[(k, k)] += 1e-9;
            }
            let Some(delta) = h.cholesky().map(|c| c.solve(&b)) else {
                break;
            };
            if !delta.iter().all(|x| x.is_finite()) {
                break;
            }
            *pose_cw = retract(pose_cw, &delta);
            if delta.norm() < 1e-10 {
                break;
            }
        }
        // Re-classify every observation, outliers included (they may come back).
        for (o, out) in obs.iter().zip(outlier.iter_mut()) {
            let th = if o.u_right.is_some() {
                s.chi2_stereo
            } else {
                s.chi2_mono
            };
            *out = chi2_of(o, pose_cw, cam, s.bf).is_none_or(|c| c > th);
        }
    }
    outlier
}

#[cfg(test)]
mod tests {
    use super::super::{dpc_dpose, project_with_jacobian};
    use super::*;
    use rand::{Rng, SeedableRng};

    pub(crate) fn synthetic(
        pose: &Se3,
        s: &SlamSettings,
        n: usize,
        noise: f64,
        seed: u64,
    ) -> Vec<PoseObservation> {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
        let twc = pose.inverse();
        let mut out = Vec::new();
        while out.len() < n {
            let pc = Vec3::new(
                rng.random_range(-2.0..2.0),
                rng.random_range(-1.5..1.5),
                rng.random_range(1.0..5.0),
            );
            let Some(px) = s.camera.project_undistorted(&pc) else {
                continue;
            };
            if !s.camera.in_image(&px, 0.0) {
                continue;
            }
            let world = (twc * nalgebra::Point3::from(pc)).coords;
            let mono = out.len() % 4 == 0;
            out.push(PoseObservation {
                world,
                u: px.x + rng.random_range(-noise..noise),
                v: px.y + rng.random_range(-noise..noise),
                u_right: (!mono).then(|| px.x - s.bf / pc.z + rng.random_range(-noise..noise)),
                inv_sigma2: 1.0,
            });
        }
        out
    }

    #[test]
    fn the_normal_equations_are_the_two_or_three_row_products_bit_for_bit() {
        // What a residual of two or three rows gives through nalgebra's views (the release
        // before), against the 6x3 Jacobian with a zero third row, summed the same way.
        let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
        let s = SlamSettings::rgbd(cam, 40.0, 30.0);
        let pose = Se3::new(
            nalgebra::Vector3::new(0.1, -0.2, 0.3),
            nalgebra::Vector3::new(0.05, -0.1, 0.02),
        );
        let obs = synthetic(&pose, &s, 400, 3.0, 7);
        let (mut h_views, mut b_views) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
        let (mut h, mut b) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
        let mut monocular = 0;
        for (i, o) in obs.iter().enumerate() {
            let pc = (pose * nalgebra::Point3::from(o.world)).coords;
            let (pred, jp) = project_with_jacobian(&s.camera, s.bf, &pc).expect("in front");
            let w = 0.3 + i as f64 * 0.01;
            let j = jp * dpc_dpose(&pc);
            let rows = if o.u_right.is_some() { 3 } else { 2 };
            let e = nalgebra::Vector3::new(
                o.u - pred.x,
                o.v - pred.y,
                o.u_right.map_or(0.0, |ur| ur - pred.z),
            );
            let chi2_views = e.rows(0, rows).norm_squared() * o.inv_sigma2;
            let jr = j.rows(0, rows);
            h_views += jr.transpose() * jr * w;
            b_views += jr.transpose() * e.rows(0, rows) * w;
            let (chi2, jt, e) = linearise(o, &pc, &pred, &jp);
            h += jt * jt.transpose() * w;
            b += jt * e * w;
            assert_eq!(chi2.to_bits(), chi2_views.to_bits());
            monocular += usize::from(rows == 2);
        }
        assert!(monocular > 50 && monocular < 350);
        for (x, y) in h
            .iter()
            .zip(h_views.iter())
            .chain(b.iter().zip(b_views.iter()))
        {
            assert_eq!(x.to_bits(), y.to_bits(), "{x} against {y}");
        }
    }

    #[test]
    fn recovers_pose_and_flags_outliers() {
        let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
        let s = SlamSettings::rgbd(cam, 40.0, 30.0);
        let truth = Se3::new(
            nalgebra::Vector3::new(0.1, -0.2, 0.3),
            nalgebra::Vector3::new(0.05, -0.1, 0.02),
        );
        let mut obs = synthetic(&truth, &s, 200, 0.5, 1);
        for o in obs.iter_mut().take(40) {
            o.u += 40.0; // gross outliers, 20 %
        }
        let mut pose = Se3::new(
            nalgebra::Vector3::new(0.12, -0.17, 0.33),
            nalgebra::Vector3::new(0.06, -0.12, 0.03),
        );
        let out = optimize_pose(&mut pose, &obs, &s);
        let err = truth.inverse() * pose;
        assert!(err.translation.vector.norm() < 3e-3, "{err:?}");
        assert!(err.rotation.angle() < 1e-3);
        assert!(out[..40].iter().all(|&o| o));
        assert!(out[40..].iter().filter(|&&o| o).count() < 10);
        // Too few observations: untouched, all outliers.
        let mut p2 = Se3::identity();
        assert_eq!(optimize_pose(&mut p2, &obs[..2], &s), vec![true, true]);
        assert_eq!(p2, Se3::identity());
    }

    #[test]
    fn a_prior_decides_the_direction_the_observations_leave_weak() {
        // Monocular observations of a wall at one depth: a sideways shift and a turn look
        // alike, so pixel noise moves the pose along that direction; a prior at the truth
        // holds it, and a prior of no weight changes nothing.
        let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
        let s = SlamSettings::rgbd(cam, 40.0, 30.0);
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        let (mut err_free, mut err_held) = (0.0, 0.0);
        for _ in 0..20 {
            let obs: Vec<PoseObservation> = (0..80)
                .map(|_| {
                    let pc = Vec3::new(
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-0.8..0.8),
                        3.0,
                    );
                    let px = cam.project_undistorted(&pc).expect("in front");
                    PoseObservation {
                        world: pc,
                        u: px.x + rng.random_range(-1.0..1.0),
                        v: px.y + rng.random_range(-1.0..1.0),
                        u_right: None,
                        inv_sigma2: 1.0,
                    }
                })
                .collect();
            let mut free = Se3::identity();
            optimize_pose(&mut free, &obs, &s);
            let mut unweighted = Se3::identity();
            let nothing = PosePrior {
                pose_cw: Se3::translation(0.5, 0.0, 0.0),
                inv_sigma2_rot: 0.0,
                inv_sigma2_trans: 0.0,
            };
            optimize_pose_with_prior(&mut unweighted, &obs, &s, Some(&nothing));
            assert_eq!(free, unweighted);
            let mut held = Se3::identity();
            let truth = PosePrior {
                pose_cw: Se3::identity(),
                inv_sigma2_rot: 0.0,
                inv_sigma2_trans: 0.003f64.powi(-2),
            };
            optimize_pose_with_prior(&mut held, &obs, &s, Some(&truth));
            err_free += free.translation.vector.norm();
            err_held += held.translation.vector.norm();
        }
        assert!(
            err_free > 0.05,
            "without a prior: {err_free} m over 20 trials"
        );
        assert!(
            err_held < err_free / 4.0,
            "{err_held} m held, {err_free} m free"
        );
    }
}
