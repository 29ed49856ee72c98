//! The homography between two views from point correspondences: normalised DLT and RANSAC.
//!
//! A homography relates the views exactly when the camera only rotates (or does not move), or the
//! scene is a plane; then the fundamental matrix is undefined and the motion consistency check
//! (`stillpoint-dynamic`) falls back to the homography's transfer error.
//!
//! ```
//! use stillpoint_geometry::homography::{HomographyRansac, homography_ransac, transfer_error2};
//! use stillpoint_geometry::{Mat3, Vec2};
//! let h = Mat3::new(1.01, 0.02, 3.0, -0.01, 0.99, -2.0, 1e-5, 0.0, 1.0);
//! let p1: Vec<Vec2> = (0..30).map(|i| Vec2::new((i * 37 % 600) as f64, (i * 53 % 440) as f64)).collect();
//! let p2: Vec<Vec2> = p1.iter().map(|p| { let q = h * p.push(1.0); Vec2::new(q.x / q.z, q.y / q.z) }).collect();
//! let (est, inliers) = homography_ransac(&p1, &p2, &HomographyRansac::default()).unwrap();
//! assert!(inliers.iter().all(|&i| i));
//! assert!(transfer_error2(&est, &p1[5], &p2[5]) < 1e-12);
//! ```

use crate::fundamental::{
    RansacRun, apply, normalising_transform, ransac, smallest_null_vector, usable_pairs,
};
use crate::{Mat3, Vec2, Vec3};
use nalgebra::SMatrix;

/// RANSAC settings for [`homography_ransac`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HomographyRansac {
    /// Inlier threshold in pixels on the transfer error `|p2 - H p1|`. Default 1.0 px: the motion
    /// consistency check's outlier threshold, so H inliers are exactly the points it keeps.
    pub threshold_px: f64,
    /// Probability that one sample is outlier-free. Default 0.99, as for the fundamental matrix.
    pub confidence: f64,
    /// Upper bound on the iterations. Default 1000 (OpenCV `findHomography` uses 2000; the
    /// 4-point sample needs far fewer at the same outlier ratio).
    pub max_iterations: usize,
    /// Sampler seed. Default 0.
    pub seed: u64,
}

impl Default for HomographyRansac {
    fn default() -> Self {
        Self {
            threshold_px: 1.0,
            confidence: 0.99,
            max_iterations: 1000,
            seed: 0,
        }
    }
}

/// Normalised direct linear transform over at least 4 pairs: `p2 ~ H p1`, scaled so `H[2,2]` is 1
/// when possible (unit norm otherwise). `None` for fewer than 4 pairs, non-finite input or a
/// degenerate configuration (three of four points collinear, coincident points).
pub fn homography_dlt(p1: &[Vec2], p2: &[Vec2]) -> Option<Mat3> {
    if !usable_pairs(p1, p2, 4) {
        return None;
    }
    let t1 = normalising_transform(p1.iter())?;
    let t2 = normalising_transform(p2.iter())?;
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    for (a, b) in p1.iter().zip(p2) {
        let a = apply(&t1, a);
        let b = apply(&t2, b);
        let r1 = SMatrix::<f64, 9, 1>::from_column_slice(&[
            a.x,
            a.y,
            1.0,
            0.0,
            0.0,
            0.0,
            -b.x * a.x,
            -b.x * a.y,
            -b.x,
        ]);
        let r2 = SMatrix::<f64, 9, 1>::from_column_slice(&[
            0.0,
            0.0,
            0.0,
            a.x,
            a.y,
            1.0,
            -b.y * a.x,
            -b.y * a.y,
            -b.y,
        ]);
        ata += r1 * r1.transpose() + r2 * r2.transpose();
    }
    let h = smallest_null_vector(&ata)?;
    let h = Mat3::from_row_slice(h.as_slice());
    let h = t2.try_inverse()? * h * t1;
    let scale = if h[(2, 2)].abs() > 1e-12 {
        h[(2, 2)]
    } else {
        h.norm()
    };
    let h = h / scale;
    h.iter().all(|x| x.is_finite()).then_some(h)
}

/// Squared transfer error `|p2 - H p1|²`; infinite when `H p1` is at infinity.
pub fn transfer_error2(h: &Mat3, p1: &Vec2, p2: &Vec2) -> f64 {
    let q = h * Vec3::new(p1.x, p1.y, 1.0);
    if q.z.is_nan() || q.z.abs() <= 1e-12 {
        return f64::INFINITY;
    }
    let dx = q.x / q.z - p2.x;
    let dy = q.y / q.z - p2.y;
    dx * dx + dy * dy
}

/// The homography by RANSAC over 4-point samples (adaptive iteration count, refit on inliers, as
/// [`crate::fundamental::fundamental_ransac`]). Returns the matrix and the inlier mask, or `None`
/// with fewer than 4 finite pairs or when every sample was degenerate.
pub fn homography_ransac(
    p1: &[Vec2],
    p2: &[Vec2],
    params: &HomographyRansac,
) -> Option<(Mat3, Vec<bool>)> {
    let run = RansacRun {
        sample_size: 4,
        threshold2: params.threshold_px * params.threshold_px,
        confidence: params.confidence,
        max_iterations: params.max_iterations,
        seed: params.seed,
    };
    ransac(
        p1,
        p2,
        &run,
        homography_dlt,
        |h: &Mat3, p1: &[Vec2], p2: &[Vec2], out: &mut [f64]| {
            for ((a, b), e) in p1.iter().zip(p2).zip(out.iter_mut()) {
                *e = transfer_error2(h, a, b);
            }
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn project(h: &Mat3, p: &Vec2) -> Vec2 {
        let q = h * Vec3::new(p.x, p.y, 1.0);
        Vec2::new(q.x / q.z, q.y / q.z)
    }

    #[test]
    fn dlt_recovers_a_known_homography() {
        let h = Mat3::new(0.98, 0.03, 5.0, -0.02, 1.02, -3.0, 2e-5, -1e-5, 1.0);
        let p1 = [
            Vec2::new(10.0, 20.0),
            Vec2::new(600.0, 30.0),
            Vec2::new(620.0, 450.0),
            Vec2::new(15.0, 400.0),
        ];
        let p2: Vec<Vec2> = p1.iter().map(|p| project(&h, p)).collect();
        let est = homography_dlt(&p1, &p2).unwrap();
        assert!((est - h).norm() < 1e-8);
    }

    #[test]
    fn degenerate_inputs_give_none() {
        let line: Vec<Vec2> = (0..6)
            .map(|i| Vec2::new(i as f64, 2.0 * i as f64))
            .collect();
        assert!(homography_dlt(&line, &line).is_none());
        assert!(homography_dlt(&line[..3], &line[..3]).is_none());
        assert!(homography_ransac(&line[..3], &line[..3], &HomographyRansac::default()).is_none());
    }

    #[test]
    fn ransac_rejects_movers() {
        let h = Mat3::new(1.0, 0.01, 2.0, -0.01, 1.0, 1.0, 0.0, 0.0, 1.0);
        let p1: Vec<Vec2> = (0..100)
            .map(|i| Vec2::new((i * 37 % 620) as f64 + 5.0, (i * 53 % 460) as f64 + 5.0))
            .collect();
        let mut p2: Vec<Vec2> = p1.iter().map(|p| project(&h, p)).collect();
        for p in p2.iter_mut().step_by(4) {
            *p += Vec2::new(4.0, -3.0);
        }
        let (est, mask) = homography_ransac(&p1, &p2, &HomographyRansac::default()).unwrap();
        for (i, m) in mask.iter().enumerate() {
            assert_eq!(*m, i % 4 != 0, "point {i}");
        }
        assert!((est - h).norm() < 1e-6);
    }
}
