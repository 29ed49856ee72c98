//! Optimisers: pose-only (tracking) and local bundle adjustment (local mapping), both on the
//! stereo/RGB-D residual (u, v, u_r) or the monocular (u, v), weighted by the keypoint octave.

pub mod local_ba;
pub mod pose;
pub mod pose_graph;

pub use local_ba::{
    BaObservation, BaProblem, LmReport, global_bundle_adjustment, local_bundle_adjustment,
};
pub use pose::{PoseObservation, PosePrior, optimize_pose, optimize_pose_with_prior};
pub use pose_graph::{
    Graph, GraphEdge, PoseGraph, PoseGraphEdge, PoseGraphReport, Sim3Edge, Sim3Graph,
    optimize_pose_graph, optimize_sim3_graph,
};

use nalgebra::{Matrix3, Vector3};
use stillpoint_geometry::{PinholeCamera, Vec3};
pub use stillpoint_geometry::{dpc_dpose, retract};

/// Residual (observed - predicted) and Jacobians of the prediction w.r.t. the camera camera-frame
/// point for one observation. Returns (error, d pred / d Pc (3x3; the u_r row unused in mono)).
fn project_with_jacobian(
    cam: &PinholeCamera,
    bf: f64,
    pc: &Vec3,
) -> Option<(Vector3<f64>, Matrix3<f64>)> {
    let pred = project_stereo(cam, bf, pc)?;
    let iz = 1.0 / pc.z;
    let iz2 = iz * iz;
    let j = Matrix3::new(
        cam.fx * iz,
        0.0,
        -cam.fx * pc.x * iz2,
        0.0,
        cam.fy * iz,
        -cam.fy * pc.y * iz2,
        cam.fx * iz,
        0.0,
        -cam.fx * pc.x * iz2 + bf * iz2,
    );
    Some((pred, j))
}

/// The prediction alone (u, v, u_r) of [`project_with_jacobian`], with the same arithmetic, for
/// the cost of a step, which needs no Jacobian.
fn project_stereo(cam: &PinholeCamera, bf: f64, pc: &Vec3) -> Option<Vector3<f64>> {
    if pc.z.is_nan() || pc.z <= 1e-6 {
        return None;
    }
    let iz = 1.0 / pc.z;
    let u = cam.fx * pc.x * iz + cam.cx;
    let v = cam.fy * pc.y * iz + cam.cy;
    let ur = u - bf * iz;
    Some(Vector3::new(u, v, ur))
}

/// Huber weight for a squared error `chi2` with threshold `delta` (on the square root).
fn huber_weight(chi2: f64, delta: f64) -> f64 {
    let e = chi2.sqrt();
    if e <= delta { 1.0 } else { delta / e }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stillpoint_geometry::Se3;

    #[test]
    fn jacobians_match_finite_differences() {
        let cam = PinholeCamera::new(525.0, 520.0, 319.5, 239.5, 640, 480);
        let bf = 40.0;
        let pose = Se3::new(Vector3::new(0.6, 0.05, 0.2), Vector3::new(0.02, 0.4, 0.01));
        let pw = Vec3::new(1.5, -0.3, 3.0);
        let pc = (pose * nalgebra::Point3::from(pw)).coords;
        let (pred, jp) = project_with_jacobian(&cam, bf, &pc).unwrap();
        let j = jp * dpc_dpose(&pc);
        for k in 0..6 {
            let mut d = nalgebra::Vector6::zeros();
            d[k] = 1e-6;
            let pc2 = (retract(&pose, &d) * nalgebra::Point3::from(pw)).coords;
            let (pred2, _) = project_with_jacobian(&cam, bf, &pc2).unwrap();
            let fd = (pred2 - pred) / 1e-6;
            assert!(
                (fd - j.column(k)).norm() < 1e-3 * (1.0 + fd.norm()),
                "column {k}: {fd} vs {}",
                j.column(k)
            );
        }
    }
}
