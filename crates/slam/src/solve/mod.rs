//! Robust absolute pose for relocalisation.
//!
//! RGB-D frames know the depth of their keypoints, so a minimal sample is 3 map point / camera
//! point pairs aligned by Umeyama (rigid), scored by reprojection error of every correspondence
//! (with or without depth). ORB-SLAM uses EPnP here.
//!
//! Monocular frames have no depth: [`ransac_pnp`] samples 4 correspondences for [`epnp`], as
//! ORB-SLAM's `PnPsolver`. [`two_view`]: the relative motion of two views without depth
//! (monocular initialisation).

pub mod epnp;
pub mod two_view;

pub mod rigid;

use stillpoint_geometry::{PinholeCamera, Se3, Vec3, umeyama};

/// A 2D-3D correspondence, with the camera-frame point when the keypoint has depth.
#[derive(Clone, Copy, Debug)]
pub struct Correspondence {
    /// The map point in the world.
    pub world: Vec3,
    /// The same point in the camera's frame, from the keypoint's depth (`None` without).
    pub camera: Option<Vec3>,
    /// Observed undistorted column, pixels.
    pub u: f64,
    /// Observed undistorted row, pixels.
    pub v: f64,
    /// Inverse variance of the keypoint's level.
    pub inv_sigma2: f64,
}

/// RANSAC parameters.
#[derive(Clone, Copy, Debug)]
pub struct RansacParams {
    /// Hypotheses tried (ORB-SLAM's PnP solver: up to 300 per candidate keyframe).
    pub iterations: usize,
    /// Chi-square (2 DoF, 95 %) on the octave-weighted reprojection error (ORB-SLAM: 5.991).
    pub chi2: f64,
    /// Stop early once this many inliers are found.
    pub enough_inliers: usize,
    /// Seed of the hypothesis sampler (runs are reproducible).
    pub seed: u64,
}

impl Default for RansacParams {
    fn default() -> Self {
        Self {
            iterations: 300,
            chi2: 5.991,
            enough_inliers: usize::MAX,
            seed: 0x5eed,
        }
    }
}

/// xorshift64*: a tiny deterministic generator for sampling (every solver here uses it).
pub(crate) struct Rng(pub(crate) u64);
impl Rng {
    pub(crate) fn below(&mut self, n: usize) -> usize {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 33) as usize % n.max(1)
    }
}

fn inliers(pose: &Se3, c: &[Correspondence], cam: &PinholeCamera, chi2: f64) -> Vec<bool> {
    c.iter()
        .map(|k| {
            let pc = pose * nalgebra::Point3::from(k.world);
            cam.project_undistorted(&pc.coords).is_some_and(|px| {
                ((px.x - k.u).powi(2) + (px.y - k.v).powi(2)) * k.inv_sigma2 < chi2
            })
        })
        .collect()
}

/// World-to-camera pose with the most inliers, or `None` with fewer than 3 depth
/// correspondences or no hypothesis with at least 3 inliers.
pub fn ransac_pose(
    c: &[Correspondence],
    cam: &PinholeCamera,
    p: &RansacParams,
) -> Option<(Se3, Vec<bool>)> {
    let with_depth: Vec<usize> = (0..c.len()).filter(|&i| c[i].camera.is_some()).collect();
    if with_depth.len() < 3 {
        return None;
    }
    let mut rng = Rng(p.seed | 1);
    let mut best: Option<(usize, Se3, Vec<bool>)> = None;
    for _ in 0..p.iterations {
        let s: [usize; 3] = std::array::from_fn(|_| with_depth[rng.below(with_depth.len())]);
        if s[0] == s[1] || s[1] == s[2] || s[0] == s[2] {
            continue;
        }
        let src: Vec<Vec3> = s.iter().map(|&i| c[i].world).collect();
        let dst: Vec<Vec3> = s.iter().filter_map(|&i| c[i].camera).collect();
        let Some(t) = umeyama(&src, &dst, false) else {
            continue;
        };
        let flags = inliers(&t.rigid, c, cam, p.chi2);
        let n = flags.iter().filter(|&&f| f).count();
        if n >= 3 && best.as_ref().is_none_or(|b| n > b.0) {
            best = Some((n, t.rigid, flags));
            if n >= p.enough_inliers {
                break;
            }
        }
    }
    let (_, pose, flags) = best?;
    // Refit on all depth inliers.
    let idx: Vec<usize> = (0..c.len())
        .filter(|&i| flags[i] && c[i].camera.is_some())
        .collect();
    let src: Vec<Vec3> = idx.iter().map(|&i| c[i].world).collect();
    let dst: Vec<Vec3> = idx.iter().filter_map(|&i| c[i].camera).collect();
    let refined = umeyama(&src, &dst, false).map_or(pose, |t| t.rigid);
    let f2 = inliers(&refined, c, cam, p.chi2);
    if f2.iter().filter(|&&f| f).count() >= flags.iter().filter(|&&f| f).count() {
        Some((refined, f2))
    } else {
        Some((pose, flags))
    }
}

/// World-to-camera pose from 2D-3D correspondences alone (no depth): RANSAC over 4-point
/// [`epnp::epnp`] samples, the best refit by EPnP on its inliers. `None` with fewer than 4
/// correspondences or no hypothesis with at least 4 inliers.
pub fn ransac_pnp(
    c: &[Correspondence],
    cam: &PinholeCamera,
    p: &RansacParams,
) -> Option<(Se3, Vec<bool>)> {
    if c.len() < 4 {
        return None;
    }
    let norm = |k: &Correspondence| {
        stillpoint_geometry::Vec2::new((k.u - cam.cx) / cam.fx, (k.v - cam.cy) / cam.fy)
    };
    let mut rng = Rng(p.seed | 1);
    let mut best: Option<(usize, Se3, Vec<bool>)> = None;
    for _ in 0..p.iterations {
        let s: [usize; 4] = std::array::from_fn(|_| rng.below(c.len()));
        if (0..4).any(|a| (a + 1..4).any(|b| s[a] == s[b])) {
            continue;
        }
        let world: Vec<Vec3> = s.iter().map(|&i| c[i].world).collect();
        let image: Vec<_> = s.iter().map(|&i| norm(&c[i])).collect();
        let Some(pose) = epnp::epnp(&world, &image) else {
            continue;
        };
        let flags = inliers(&pose, c, cam, p.chi2);
        let n = flags.iter().filter(|&&f| f).count();
        if n >= 4 && best.as_ref().is_none_or(|b| n > b.0) {
            best = Some((n, pose, flags));
            if n >= p.enough_inliers {
                break;
            }
        }
    }
    let (n, pose, flags) = best?;
    let idx: Vec<usize> = (0..c.len()).filter(|&i| flags[i]).collect();
    let world: Vec<Vec3> = idx.iter().map(|&i| c[i].world).collect();
    let image: Vec<_> = idx.iter().map(|&i| norm(&c[i])).collect();
    if let Some(refined) = epnp::epnp(&world, &image) {
        let f2 = inliers(&refined, c, cam, p.chi2);
        if f2.iter().filter(|&&f| f).count() >= n {
            return Some((refined, f2));
        }
    }
    Some((pose, flags))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_pose_among_outliers_and_refuses_too_little_data() {
        let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
        let truth = Se3::new(
            nalgebra::Vector3::new(0.3, -0.1, 0.2),
            nalgebra::Vector3::new(0.1, 0.2, -0.05),
        );
        let mut c = Vec::new();
        for i in 0..100 {
            let pc = Vec3::new(
                ((i * 37) % 100) as f64 / 50.0 - 1.0,
                ((i * 53) % 100) as f64 / 70.0 - 0.7,
                2.0 + (i % 7) as f64 * 0.3,
            );
            let px = cam.project_undistorted(&pc).unwrap();
            let mut world = (truth.inverse() * nalgebra::Point3::from(pc)).coords;
            if i % 3 == 0 {
                world += Vec3::new(0.5, 0.2, -0.3); // wrong match
            }
            c.push(Correspondence {
                world,
                camera: (i % 5 != 0).then_some(pc),
                u: px.x,
                v: px.y,
                inv_sigma2: 1.0,
            });
        }
        let (pose, flags) = ransac_pose(&c, &cam, &RansacParams::default()).unwrap();
        let e = truth.inverse() * pose;
        assert!(e.translation.vector.norm() < 1e-6 && e.rotation.angle() < 1e-6);
        assert!(flags.iter().enumerate().all(|(i, &f)| f == (i % 3 != 0)));
        assert!(ransac_pose(&c[..2], &cam, &RansacParams::default()).is_none());
        // Without depth (monocular): EPnP samples find the same pose.
        let mono: Vec<Correspondence> = c
            .iter()
            .map(|k| Correspondence { camera: None, ..*k })
            .collect();
        let (pose, flags) = ransac_pnp(&mono, &cam, &RansacParams::default()).unwrap();
        let e = truth.inverse() * pose;
        assert!(e.translation.vector.norm() < 1e-6 && e.rotation.angle() < 1e-6);
        assert!(flags.iter().enumerate().all(|(i, &f)| f == (i % 3 != 0)));
        assert!(ransac_pnp(&mono[..3], &cam, &RansacParams::default()).is_none());
    }
}

/// Linear (DLT) triangulation of one point seen at normalised image coordinates `x1` by camera
/// `pose1_cw` and `x2` by `pose2_cw` (world-to-camera poses). `None` for a degenerate system.
pub fn triangulate(
    pose1_cw: &Se3,
    x1: &stillpoint_geometry::Vec2,
    pose2_cw: &Se3,
    x2: &stillpoint_geometry::Vec2,
) -> Option<Vec3> {
    let rows = |t: &Se3, x: &stillpoint_geometry::Vec2| {
        let m = t.to_homogeneous();
        let r = |i: usize| nalgebra::RowVector4::new(m[(i, 0)], m[(i, 1)], m[(i, 2)], m[(i, 3)]);
        (x.x * r(2) - r(0), x.y * r(2) - r(1))
    };
    let (a0, a1) = rows(pose1_cw, x1);
    let (a2, a3) = rows(pose2_cw, x2);
    let a = nalgebra::Matrix4::from_rows(&[a0, a1, a2, a3]);
    let svd = a.svd(false, true);
    let v_t = svd.v_t?;
    // The right singular vector of the smallest singular value.
    let (k, _) = svd
        .singular_values
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let h = v_t.row(k);
    (h[3].abs() > 1e-12).then(|| Vec3::new(h[0] / h[3], h[1] / h[3], h[2] / h[3]))
}

#[cfg(test)]
mod triangulate_tests {
    use super::*;
    use stillpoint_geometry::Vec2;

    #[test]
    fn two_views_recover_the_point() {
        let p = Vec3::new(0.3, -0.2, 4.0);
        let c1 = Se3::identity();
        let c2 = Se3::new(
            nalgebra::Vector3::new(-0.5, 0.0, 0.1),
            nalgebra::Vector3::new(0.0, 0.05, 0.0),
        );
        let norm = |t: &Se3| {
            let q = t * nalgebra::Point3::from(p);
            Vec2::new(q.x / q.z, q.y / q.z)
        };
        let x = triangulate(&c1, &norm(&c1), &c2, &norm(&c2)).expect("a point");
        assert!((x - p).norm() < 1e-9, "{x}");
    }
}
