//! Epipolar geometry between two views.

use crate::{Mat3, Se3, Vec2, Vec3, skew};

/// Distance in pixels of `p2` from the epipolar line `F p1` in the second image:
/// `|p2ᵀ F p1| / sqrt(a² + b²)` with `(a, b, c) = F p1` (the motion consistency check of DS-SLAM).
/// Returns `f64::INFINITY` for a degenerate line (a = b = 0).
pub fn epipolar_distance(f: &Mat3, p1: &Vec2, p2: &Vec2) -> f64 {
    let l = f * Vec3::new(p1.x, p1.y, 1.0);
    let norm = (l.x * l.x + l.y * l.y).sqrt();
    if norm.is_nan() || norm <= 1e-300 {
        return f64::INFINITY;
    }
    (p2.x * l.x + p2.y * l.y + l.z).abs() / norm
}

/// The fundamental matrix mapping pixels of view 1 to epipolar lines in view 2, from the two
/// camera-to-world poses and intrinsics: `F = K2⁻ᵀ [t]x R K1⁻¹` with `(R, t) = T_2w T_w1`.
/// Returns `None` when a K is not invertible.
pub fn fundamental_from_poses(k1: &Mat3, t_w1: &Se3, k2: &Mat3, t_w2: &Se3) -> Option<Mat3> {
    let t21 = t_w2.inverse() * t_w1;
    let r = t21.rotation.to_rotation_matrix().into_inner();
    let t: Vec3 = t21.translation.vector;
    let e = skew(&t) * r;
    let k1i = k1.try_inverse()?;
    let k2i = k2.try_inverse()?;
    Some(k2i.transpose() * e * k1i)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::PinholeCamera;

    #[test]
    fn static_points_lie_on_their_epipolar_lines() {
        let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
        let t_w1 = Se3::identity();
        let t_w2 = Se3::new(Vec3::new(0.1, 0.02, -0.05), Vec3::new(0.01, 0.05, -0.02));
        let f = fundamental_from_poses(&cam.k(), &t_w1, &cam.k(), &t_w2).unwrap();
        for p in [Vec3::new(0.3, 0.1, 2.0), Vec3::new(-0.5, 0.4, 3.5)] {
            let a = cam
                .project(&(t_w1.inverse() * nalgebra::Point3::from(p)).coords)
                .unwrap();
            let b = cam
                .project(&(t_w2.inverse() * nalgebra::Point3::from(p)).coords)
                .unwrap();
            assert!(epipolar_distance(&f, &a, &b) < 1e-9);
            // a point moved by 5 px perpendicular-ish is off the line
            assert!(epipolar_distance(&f, &a, &(b + Vec2::new(0.0, 5.0))) > 1.0);
        }
        assert!(epipolar_distance(&Mat3::zeros(), &Vec2::zeros(), &Vec2::zeros()).is_infinite());
    }
}
