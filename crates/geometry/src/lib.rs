//! Geometry shared by every stillpoint crate: cameras, rigid and similarity transforms, epipolar
//! geometry and trajectory alignment.
//!
//! Conventions (as TUM and ORB-SLAM use them): poses are `Se3` camera-to-world (`T_wc`) unless a
//! name says otherwise; pixel (u, v) has u to the right and v down; camera z looks forward.

#![deny(missing_docs)]

pub mod align;
pub mod bbox;
pub mod camera;
pub mod epipolar;
pub mod fundamental;
pub mod homography;
pub mod plane;
pub mod pose;
pub mod rectify;

pub use align::{Sim3, umeyama};
pub use bbox::BBox;
pub use camera::{PinholeCamera, RadTan};
pub use epipolar::{epipolar_distance, fundamental_from_poses};
pub use pose::{dpc_dpose, motion_over_gap, refine_pose_reprojection, retract};
pub use rectify::{RectifyingView, StereoRectification};

/// A rigid transform (rotation + translation), double precision.
pub type Se3 = nalgebra::Isometry3<f64>;
/// A 3D point or vector, double precision.
pub type Vec3 = nalgebra::Vector3<f64>;
/// A pixel position or 2D vector.
pub type Vec2 = nalgebra::Vector2<f64>;
/// A 3x3 matrix (rotations, intrinsics, fundamental matrices).
pub type Mat3 = nalgebra::Matrix3<f64>;

/// Build an [`Se3`] from a translation and a unit quaternion given as (qx, qy, qz, qw), the TUM
/// order. The quaternion is normalised; a zero quaternion gives `None`.
pub fn se3_from_tum(t: [f64; 3], q: [f64; 4]) -> Option<Se3> {
    let quat = nalgebra::Quaternion::new(q[3], q[0], q[1], q[2]);
    let n = quat.norm();
    if !(n.is_finite() && n > 1e-12) {
        return None;
    }
    Some(Se3::from_parts(
        nalgebra::Translation3::new(t[0], t[1], t[2]),
        nalgebra::UnitQuaternion::from_quaternion(quat),
    ))
}

/// The (t, q) of an [`Se3`] in TUM order: tx ty tz, qx qy qz qw.
pub fn se3_to_tum(p: &Se3) -> ([f64; 3], [f64; 4]) {
    let t = p.translation.vector;
    let q = p.rotation.quaternion();
    ([t.x, t.y, t.z], [q.i, q.j, q.k, q.w])
}

/// Build an [`Se3`] from a row-major 3x4 matrix `[R | t]` (KITTI). The rotation is projected onto
/// SO(3), so slightly non-orthogonal input is accepted.
pub fn se3_from_3x4(m: &[f64; 12]) -> Se3 {
    let r = Mat3::new(m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]);
    let rot = nalgebra::Rotation3::from_matrix(&r);
    Se3::from_parts(
        nalgebra::Translation3::new(m[3], m[7], m[11]),
        nalgebra::UnitQuaternion::from_rotation_matrix(&rot),
    )
}

/// A row-major 3x4 matrix `[R | t]` of an [`Se3`] (KITTI).
pub fn se3_to_3x4(p: &Se3) -> [f64; 12] {
    let r = p.rotation.to_rotation_matrix();
    let r = r.matrix();
    let t = p.translation.vector;
    [
        r[(0, 0)],
        r[(0, 1)],
        r[(0, 2)],
        t.x,
        r[(1, 0)],
        r[(1, 1)],
        r[(1, 2)],
        t.y,
        r[(2, 0)],
        r[(2, 1)],
        r[(2, 2)],
        t.z,
    ]
}

/// The skew-symmetric matrix `[v]x` with `[v]x w = v x w`.
pub fn skew(v: &Vec3) -> Mat3 {
    Mat3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tum_and_kitti_roundtrip() {
        let p = se3_from_tum([1.0, -2.0, 0.5], [0.1, 0.2, 0.3, 0.9]).unwrap();
        let (t, q) = se3_to_tum(&p);
        let p2 = se3_from_tum(t, q).unwrap();
        assert!((p.inverse() * p2).translation.vector.norm() < 1e-12);
        let m = se3_to_3x4(&p);
        let p3 = se3_from_3x4(&m);
        assert!((p.inverse() * p3).rotation.angle() < 1e-12);
        assert!(se3_from_tum([0.0; 3], [0.0; 4]).is_none());
    }
}
