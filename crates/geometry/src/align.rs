//! Least-squares alignment of point sets (Umeyama 1991), as evo and the TUM tools use it.

use crate::{Mat3, Se3, Vec3};

/// A similarity transform `x -> s R x + t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sim3 {
    /// `s`.
    pub scale: f64,
    /// `R` and `t`.
    pub rigid: Se3,
}

impl Sim3 {
    /// The identity.
    pub fn identity() -> Self {
        Self {
            scale: 1.0,
            rigid: Se3::identity(),
        }
    }

    /// Apply to a point.
    pub fn transform_point(&self, p: &Vec3) -> Vec3 {
        self.scale * (self.rigid.rotation * p) + self.rigid.translation.vector
    }

    /// The inverse: `x -> (1/s) R^T (x - t)`.
    pub fn inverse(&self) -> Self {
        let r_inv = self.rigid.rotation.inverse();
        let t = -(r_inv * self.rigid.translation.vector) / self.scale;
        Self {
            scale: 1.0 / self.scale,
            rigid: Se3::from_parts(t.into(), r_inv),
        }
    }

    /// A rigid transform as a similarity of scale 1.
    pub fn from_rigid(rigid: Se3) -> Self {
        Self { scale: 1.0, rigid }
    }

    /// `self ∘ other`: `other` first, then `self`.
    pub fn compose(&self, other: &Sim3) -> Self {
        let t = self.transform_point(&other.rigid.translation.vector);
        Self {
            scale: self.scale * other.scale,
            rigid: Se3::from_parts(t.into(), self.rigid.rotation * other.rigid.rotation),
        }
    }

    /// A world-to-camera similarity as the camera pose it places (the rotation, the
    /// translation divided by the scale: ORB-SLAM's Sim(3) to SE(3) after a loop).
    pub fn to_pose(&self) -> Se3 {
        Se3::from_parts(
            (self.rigid.translation.vector / self.scale).into(),
            self.rigid.rotation,
        )
    }

    /// Apply to a camera pose: rotation composed, position transformed.
    pub fn transform_pose(&self, pose: &Se3) -> Se3 {
        let t = self.transform_point(&pose.translation.vector);
        Se3::from_parts(t.into(), self.rigid.rotation * pose.rotation)
    }
}

/// The similarity (or rigid, when `with_scale` is false) transform minimising
/// `Σ |dst_i - (s R src_i + t)|²`. `None` with fewer than 2 points (3 for a unique rotation is
/// not required: the SVD picks one) or degenerate input (all source points equal).
pub fn umeyama(src: &[Vec3], dst: &[Vec3], with_scale: bool) -> Option<Sim3> {
    let n = src.len();
    if n < 2 || dst.len() != n {
        return None;
    }
    let nf = n as f64;
    let mu_s = src.iter().sum::<Vec3>() / nf;
    let mu_d = dst.iter().sum::<Vec3>() / nf;
    let mut cov = Mat3::zeros();
    let mut var_s = 0.0;
    for (s, d) in src.iter().zip(dst) {
        let ds = s - mu_s;
        cov += (d - mu_d) * ds.transpose();
        var_s += ds.norm_squared();
    }
    cov /= nf;
    var_s /= nf;
    if var_s.is_nan() || var_s <= 1e-300 || !cov.iter().all(|v| v.is_finite()) {
        return None;
    }
    let svd = cov.svd(true, true);
    let u = svd.u?;
    let vt = svd.v_t?;
    let mut sgn = Mat3::identity();
    if u.determinant() * vt.determinant() < 0.0 {
        sgn[(2, 2)] = -1.0;
    }
    let r = u * sgn * vt;
    let scale = if with_scale {
        (svd.singular_values.component_mul(&sgn.diagonal())).sum() / var_s
    } else {
        1.0
    };
    let t = mu_d - scale * r * mu_s;
    let rot = nalgebra::UnitQuaternion::from_rotation_matrix(
        &nalgebra::Rotation3::from_matrix_unchecked(r),
    );
    Some(Sim3 {
        scale,
        rigid: Se3::from_parts(t.into(), rot),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_known_similarity() {
        let truth = Sim3 {
            scale: 1.7,
            rigid: Se3::new(Vec3::new(1.0, -2.0, 3.0), Vec3::new(0.3, -0.2, 0.9)),
        };
        let src: Vec<Vec3> = (0..20)
            .map(|i| {
                let f = i as f64;
                Vec3::new(f.sin(), (0.7 * f).cos(), 0.1 * f)
            })
            .collect();
        let dst: Vec<Vec3> = src.iter().map(|p| truth.transform_point(p)).collect();
        let est = umeyama(&src, &dst, true).unwrap();
        assert!((est.scale - 1.7).abs() < 1e-9);
        for (s, d) in src.iter().zip(&dst) {
            assert!((est.transform_point(s) - d).norm() < 1e-9);
        }
        // Composition and inverse agree with applying the transforms one by one.
        let other = Sim3 {
            scale: 0.6,
            rigid: Se3::new(Vec3::new(-0.5, 0.2, 1.0), Vec3::new(-0.1, 0.4, 0.2)),
        };
        let both = truth.compose(&other);
        for s in &src {
            let by_steps = truth.transform_point(&other.transform_point(s));
            assert!((both.transform_point(s) - by_steps).norm() < 1e-9);
            assert!((both.inverse().transform_point(&by_steps) - s).norm() < 1e-9);
        }
        // A pose of scale 1 is the rigid transform itself.
        let pose = Se3::new(Vec3::new(0.1, 0.2, 0.3), Vec3::new(0.0, 0.5, 0.0));
        assert!(
            (Sim3::from_rigid(pose).to_pose().translation.vector - pose.translation.vector).norm()
                < 1e-12
        );
        let rigid = umeyama(&src, &dst, false).unwrap();
        assert_eq!(rigid.scale, 1.0);
        assert!(umeyama(&src[..1], &dst[..1], true).is_none());
        assert!(umeyama(&[Vec3::zeros(); 3], &dst[..3], true).is_none());
    }
}
