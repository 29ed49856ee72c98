//! Small pose solvers on SE3: the left-multiplicative update and its point Jacobian (shared with
//! the SLAM optimisers), and a robust Gauss-Newton refinement of a relative pose from 3D points
//! and the pixels where they were seen.

use nalgebra::{Matrix2x3, Matrix3, Matrix3x6, Matrix6, Vector3, Vector6};

use crate::{PinholeCamera, Se3, Vec2, Vec3, skew};

/// Left-multiplicative update exp(δ) T with δ = (ω, υ): rotation by the axis-angle ω, then
/// translation υ (a retraction whose derivative at 0 is the SE3 one).
pub fn retract(t: &Se3, delta: &Vector6<f64>) -> Se3 {
    let d = Se3::new(
        Vector3::new(delta[3], delta[4], delta[5]),
        Vector3::new(delta[0], delta[1], delta[2]),
    );
    let mut out = d * t;
    out.rotation.renormalize();
    out
}

/// The constant-velocity motion `v`, measured between frames `measured_s` seconds apart,
/// carried to a frame `gap_s` seconds after the last: `v` itself when the two gaps agree within
/// 25 % (a camera's jitter), else `v` repeated `gap_s / measured_s` times (at most 4), so that
/// a frame after a dropped one is predicted twice as far. The rotation is scaled on its axis
/// and the translation linearly: exact for a pure translation, and off by far less than the
/// search radius for the few degrees a camera turns between frames.
///
/// ```
/// use stillpoint_geometry::{Se3, motion_over_gap};
/// let v = Se3::translation(0.01, 0.0, 0.0);
/// let two = motion_over_gap(&v, 1.0 / 30.0, 2.0 / 30.0);
/// assert!((two.translation.vector.x - 0.02).abs() < 1e-12);
/// assert_eq!(motion_over_gap(&v, 1.0 / 30.0, 1.05 / 30.0), v);
/// ```
pub fn motion_over_gap(v: &Se3, measured_s: f64, gap_s: f64) -> Se3 {
    let ratio = gap_s / measured_s;
    if !ratio.is_finite() || ratio <= 0.0 || (ratio - 1.0).abs() <= 0.25 {
        return *v;
    }
    let ratio = ratio.min(4.0);
    Se3::from_parts(
        (v.translation.vector * ratio).into(),
        nalgebra::UnitQuaternion::from_scaled_axis(v.rotation.scaled_axis() * ratio),
    )
}

/// d Pc / d δ for a left perturbation of the pose that maps a point to Pc: `[-[Pc]x | I]`.
pub fn dpc_dpose(pc: &Vec3) -> Matrix3x6<f64> {
    let mut m = Matrix3x6::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-skew(pc)));
    m.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&Matrix3::identity());
    m
}

/// Refine `init` (mapping the points' frame into the camera's) by Gauss-Newton on the
/// reprojection error of `points` against `pixels`, with a Huber kernel of `huber_px` pixels.
/// Why not a 3D-3D fit: depth errors (centimetres on a slanted surface or a Kinect) dwarf the
/// few millimetres a camera moves between two frames, while the reprojection error of a point
/// barely depends on its depth when the camera moves little. `None` with fewer than 3 usable
/// points or a singular system.
pub fn refine_pose_reprojection(
    cam: &PinholeCamera,
    points: &[Vec3],
    pixels: &[Vec2],
    init: &Se3,
    huber_px: f64,
    iterations: usize,
) -> Option<Se3> {
    let mut pose = *init;
    for _ in 0..iterations {
        let mut h = Matrix6::<f64>::zeros();
        let mut b = Vector6::<f64>::zeros();
        let mut used = 0;
        for (p, px) in points.iter().zip(pixels) {
            let pc = pose * nalgebra::Point3::from(*p);
            let Some(pred) = cam.project(&pc.coords) else {
                continue;
            };
            let e = px - pred;
            let norm = e.norm();
            let w = if norm <= huber_px {
                1.0
            } else {
                huber_px / norm
            };
            let iz = 1.0 / pc.z;
            let jp = Matrix2x3::new(
                cam.fx * iz,
                0.0,
                -cam.fx * pc.x * iz * iz,
                0.0,
                cam.fy * iz,
                -cam.fy * pc.y * iz * iz,
            );
            let j = jp * dpc_dpose(&pc.coords);
            h += j.transpose() * j * w;
            b += j.transpose() * e * w;
            used += 1;
        }
        if used < 3 {
            return None;
        }
        let delta = h.cholesky()?.solve(&b);
        if !delta.iter().all(|x| x.is_finite()) {
            return None;
        }
        pose = retract(&pose, &delta);
        if delta.norm() < 1e-10 {
            break;
        }
    }
    Some(pose)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_turn_over_a_dropped_frame_is_predicted_twice_as_far() {
        let axis = Vector3::new(0.0, 1.0, 0.0);
        let v = Se3::new(Vector3::new(0.0, 0.0, 0.01), axis * 2f64.to_radians());
        let dt = 1.0 / 30.0;
        let two = motion_over_gap(&v, dt, 2.0 * dt);
        assert!((two.rotation.angle() - 4f64.to_radians()).abs() < 1e-12);
        assert!((two.translation.vector.z - 0.02).abs() < 1e-12);
        // The frame after the gap: the motion was measured over two frames, the next is one.
        let one = motion_over_gap(&two, 2.0 * dt, dt);
        assert!((one.rotation.angle() - 2f64.to_radians()).abs() < 1e-12);
        // A stalled camera is not extrapolated without bound.
        let stalled = motion_over_gap(&v, dt, 30.0 * dt);
        assert!((stalled.rotation.angle() - 8f64.to_radians()).abs() < 1e-12);
        assert_eq!(motion_over_gap(&v, dt, 0.0), v);
    }

    #[test]
    fn refinement_recovers_a_small_motion_despite_centimetre_depth_errors() {
        let cam = PinholeCamera::new(535.0, 539.0, 320.0, 240.0, 640, 480);
        let truth = Se3::new(
            Vector3::new(-0.004, 0.001, -0.001),
            Vector3::new(0.001, -0.002, 0.0),
        );
        let mut points = Vec::new();
        let mut pixels = Vec::new();
        for i in 0..60 {
            let (x, y) = ((i % 10) as f64 * 60.0 + 30.0, (i / 10) as f64 * 70.0 + 40.0);
            let z = 2.0 + 0.3 * ((i * 7) % 5) as f64;
            let p = cam.unproject(&Vec2::new(x, y), z);
            pixels.push(
                cam.project(&(truth * nalgebra::Point3::from(p)).coords)
                    .unwrap(),
            );
            // The lifted point carries a depth error of up to 4 cm, alternating in sign.
            let dz = if i % 2 == 0 { 0.04 } else { -0.03 };
            points.push(cam.unproject(&Vec2::new(x, y), z + dz));
        }
        // One gross outlier, which the Huber kernel must not follow.
        pixels[5] += Vec2::new(15.0, -9.0);
        let fit = refine_pose_reprojection(&cam, &points, &pixels, &Se3::identity(), 0.5, 20)
            .expect("a pose");
        let dt = (fit.translation.vector - truth.translation.vector).norm();
        let dr = (fit.rotation * truth.rotation.inverse()).angle();
        assert!(dt < 5e-4 && dr < 2e-4, "dt {dt} dr {dr}");
        // Too few points: no pose.
        assert!(
            refine_pose_reprojection(&cam, &points[..2], &pixels[..2], &Se3::identity(), 0.5, 5)
                .is_none()
        );
    }
}
