//! The fundamental matrix from point correspondences: Hartley's normalised 8-point algorithm with
//! rank-2 enforcement, and RANSAC around it with an adaptive iteration count.
//!
//! Convention (as [`crate::epipolar_distance`] and [`crate::fundamental_from_poses`]):
//! `p2ᵀ F p1 = 0`, so `F p1` is the epipolar line of `p1` in the second image.
//!
//! ```
//! use stillpoint_geometry::fundamental::{FundamentalRansac, fundamental_ransac};
//! use stillpoint_geometry::{PinholeCamera, Se3, Vec2, Vec3, epipolar_distance};
//! let cam = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
//! let t_w2 = Se3::new(Vec3::new(0.2, 0.0, 0.05), Vec3::new(0.0, 0.05, 0.0));
//! let (mut p1, mut p2) = (Vec::new(), Vec::new());
//! for i in 0..40 {
//!     let x = Vec3::new((i % 7) as f64 * 0.3 - 1.0, (i % 5) as f64 * 0.25 - 0.5, 3.0 + (i % 3) as f64);
//!     p1.push(cam.project(&x).unwrap());
//!     p2.push(cam.project(&(t_w2.inverse() * nalgebra::Point3::from(x)).coords).unwrap());
//! }
//! let (f, inliers) = fundamental_ransac(&p1, &p2, &FundamentalRansac::default()).unwrap();
//! assert!(inliers.iter().all(|&i| i));
//! assert!(epipolar_distance(&f, &p1[0], &p2[0]) < 1e-6);
//! ```

use crate::{Mat3, Vec2};
use nalgebra::{SMatrix, SymmetricEigen};

/// RANSAC settings for [`fundamental_ransac`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct FundamentalRansac {
    /// Inlier threshold in pixels on the symmetric epipolar distance (the larger of the distances
    /// of p2 to `F p1` and of p1 to `Fᵀ p2`, as OpenCV's `findFundamentalMat` scores it).
    /// Default 0.1 px: DS-SLAM's and the paper's authors' `findFundamentalMat(..., 0.1, 0.99)`.
    pub threshold_px: f64,
    /// Probability that at least one sample is outlier-free; drives the adaptive iteration count.
    /// Default 0.99 (DS-SLAM, the paper's authors).
    pub confidence: f64,
    /// Upper bound on the iterations. Default 1000, OpenCV's `findFundamentalMat` default.
    pub max_iterations: usize,
    /// Seed of the sampler; the same input and seed give the same result. Default 0.
    pub seed: u64,
}

impl Default for FundamentalRansac {
    fn default() -> Self {
        Self {
            threshold_px: 0.1,
            confidence: 0.99,
            max_iterations: 1000,
            seed: 0,
        }
    }
}

/// Hartley's normalised 8-point algorithm (least squares over all given pairs, at least 8) with
/// rank 2 enforced by zeroing the smallest singular value. The result has unit Frobenius norm.
///
/// Returns `None` for fewer than 8 pairs, mismatched lengths, non-finite input, coincident points,
/// or a degenerate configuration whose solution is not unique (for example a static camera,
/// `p2 = p1`, or a purely rotating one, `p2 = H p1`: then every `F = [e]x H` fits).
pub fn fundamental_8point(p1: &[Vec2], p2: &[Vec2]) -> Option<Mat3> {
    if !usable_pairs(p1, p2, 8) {
        return None;
    }
    let t1 = normalising_transform(p1.iter())?;
    let t2 = normalising_transform(p2.iter())?;
    // Row of p2ᵀ F p1 = 0 in the unknowns F00 F01 F02 F10 .. F22 (row-major).
    let row = |a: &Vec2, b: &Vec2| {
        let a = apply(&t1, a);
        let b = apply(&t2, b);
        [
            b.x * a.x,
            b.x * a.y,
            b.x,
            b.y * a.x,
            b.y * a.y,
            b.y,
            a.x,
            a.y,
            1.0,
        ]
    };
    let f_normalised = if p1.len() == 8 {
        // RANSAC's minimal samples: eight equations have one null vector, found exactly by
        // elimination at a fraction of the eigen-solve's cost.
        let mut rows = [[0.0; 9]; 8];
        for ((r, a), b) in rows.iter_mut().zip(p1).zip(p2) {
            *r = row(a, b);
        }
        null_vector_8x9(rows)?
    } else {
        let mut ata = SMatrix::<f64, 9, 9>::zeros();
        for (a, b) in p1.iter().zip(p2) {
            let r = SMatrix::<f64, 9, 1>::from_column_slice(&row(a, b));
            ata += r * r.transpose();
        }
        smallest_null_vector(&ata)?
    };
    let f = Mat3::from_row_slice(f_normalised.as_slice());
    let f = enforce_rank2(&f)?;
    let f = t2.transpose() * f * t1;
    let norm = f.norm();
    if !(norm.is_finite() && norm > 0.0) {
        return None;
    }
    Some(f / norm)
}

/// The fundamental matrix by RANSAC over minimal 8-point samples, with the iteration count adapted
/// to the best inlier ratio so far (OpenCV's `RANSACUpdateNumIters`), then refit by
/// [`fundamental_8point`] on the inliers until the inlier set stops growing (at most 3 times).
/// OpenCV 4 stops at the best minimal sample; the paper's authors' code inherited that, and a
/// model from 8 points at a 0.1 px threshold is noisy away from those points.
///
/// Returns the matrix and the inlier mask, or `None` with fewer than 8 finite pairs, mismatched
/// lengths, or when every sample was degenerate (see [`fundamental_8point`]).
pub fn fundamental_ransac(
    p1: &[Vec2],
    p2: &[Vec2],
    params: &FundamentalRansac,
) -> Option<(Mat3, Vec<bool>)> {
    if p1.len() != p2.len() {
        return None;
    }
    let threshold2 = params.threshold_px * params.threshold_px;
    let fit = |s1: &[Vec2], s2: &[Vec2]| fundamental_8point(s1, s2);
    let run = RansacRun {
        sample_size: 8,
        threshold2,
        confidence: params.confidence,
        max_iterations: params.max_iterations,
        seed: params.seed,
    };
    ransac(p1, p2, &run, fit, symmetric_epipolar_errors2)
}

/// [`symmetric_epipolar_error2`] of every pair into `out` (same length), bit for bit; compiled
/// for AVX2 where the CPU has it, since RANSAC scores every pair against every sample's F.
pub fn symmetric_epipolar_errors2(f: &Mat3, p1: &[Vec2], p2: &[Vec2], out: &mut [f64]) {
    #[inline(always)]
    fn inner(f: &Mat3, p1: &[Vec2], p2: &[Vec2], out: &mut [f64]) {
        let f = row_major(f);
        for ((a, b), e) in p1.iter().zip(p2).zip(out.iter_mut()) {
            *e = epipolar_error2(&f, a, b);
        }
    }
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2")]
        unsafe fn avx2(f: &Mat3, p1: &[Vec2], p2: &[Vec2], out: &mut [f64]) {
            inner(f, p1, p2, out)
        }
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, the one feature `avx2` is compiled for.
            return unsafe { avx2(f, p1, p2, out) };
        }
    }
    inner(f, p1, p2, out)
}

/// The squared symmetric epipolar distance: `max(d(p2, F p1)², d(p1, Fᵀ p2)²)` (OpenCV's score).
/// Infinite for a degenerate line.
pub fn symmetric_epipolar_error2(f: &Mat3, p1: &Vec2, p2: &Vec2) -> f64 {
    epipolar_error2(&row_major(f), p1, p2)
}

fn row_major(f: &Mat3) -> [f64; 9] {
    std::array::from_fn(|k| f[(k / 3, k % 3)])
}

/// [`symmetric_epipolar_error2`] with `F` row-major, branch-free so a loop over pairs vectorises.
#[inline(always)]
fn epipolar_error2(f: &[f64; 9], a: &Vec2, b: &Vec2) -> f64 {
    // l2 = F p1 and l1 = Fᵀ p2, each row summed left to right.
    let (l2x, l2y, l2z) = (
        f[0] * a.x + f[1] * a.y + f[2],
        f[3] * a.x + f[4] * a.y + f[5],
        f[6] * a.x + f[7] * a.y + f[8],
    );
    let (l1x, l1y, l1z) = (
        f[0] * b.x + f[3] * b.y + f[6],
        f[1] * b.x + f[4] * b.y + f[7],
        f[2] * b.x + f[5] * b.y + f[8],
    );
    let n2 = l2x * l2x + l2y * l2y;
    let n1 = l1x * l1x + l1y * l1y;
    let d2 = b.x * l2x + b.y * l2y + l2z;
    let d1 = a.x * l1x + a.y * l1y + l1z;
    let v = (d2 * d2 / n2).max(d1 * d1 / n1);
    if n1 > 1e-300 && n2 > 1e-300 {
        v
    } else {
        f64::INFINITY
    }
}

/// One RANSAC search: minimal samples of `sample_size` pairs, inliers within `threshold2`
/// (squared error), iterations adapted to `confidence` up to `max_iterations`, samples drawn
/// from `seed`.
pub(crate) struct RansacRun {
    pub(crate) sample_size: usize,
    pub(crate) threshold2: f64,
    pub(crate) confidence: f64,
    pub(crate) max_iterations: usize,
    pub(crate) seed: u64,
}

/// The generic RANSAC loop shared by the fundamental matrix and the homography: minimal samples of
/// `sample_size` finite pairs, score = inlier count (ties broken by the smaller summed error),
/// adaptive iteration count, refit on inliers.
pub(crate) fn ransac<F, E>(
    p1: &[Vec2],
    p2: &[Vec2],
    run: &RansacRun,
    fit: F,
    error: E,
) -> Option<(Mat3, Vec<bool>)>
where
    F: Fn(&[Vec2], &[Vec2]) -> Option<Mat3>,
    E: Fn(&Mat3, &[Vec2], &[Vec2], &mut [f64]),
{
    let &RansacRun {
        sample_size,
        threshold2,
        confidence,
        max_iterations,
        seed,
    } = run;
    if p1.len() != p2.len() || !(threshold2.is_finite() && threshold2 >= 0.0) {
        return None;
    }
    let finite: Vec<usize> = (0..p1.len())
        .filter(|&i| {
            let (a, b) = (&p1[i], &p2[i]);
            a.x.is_finite() && a.y.is_finite() && b.x.is_finite() && b.y.is_finite()
        })
        .collect();
    if finite.len() < sample_size {
        return None;
    }
    // The finite pairs, contiguous, and a buffer for their errors under each model.
    let q1: Vec<Vec2> = finite.iter().map(|&i| p1[i]).collect();
    let q2: Vec<Vec2> = finite.iter().map(|&i| p2[i]).collect();
    let mut errors = vec![0.0; finite.len()];
    let score = |m: &Mat3, errors: &mut [f64]| -> (usize, f64) {
        error(m, &q1, &q2, errors);
        let (mut count, mut sum) = (0, 0.0);
        for &e in errors.iter().filter(|&&e| e <= threshold2) {
            count += 1;
            sum += e;
        }
        (count, sum)
    };
    let better = |a: (usize, f64), b: (usize, f64)| a.0 > b.0 || (a.0 == b.0 && a.1 < b.1);

    let mut rng = SplitMix64(seed);
    let mut best: Option<(Mat3, (usize, f64))> = None;
    let mut needed = max_iterations.max(1);
    let mut iteration = 0;
    let mut sample = vec![0usize; sample_size];
    let (mut s1, mut s2) = (
        vec![Vec2::zeros(); sample_size],
        vec![Vec2::zeros(); sample_size],
    );
    while iteration < needed {
        iteration += 1;
        draw_distinct(&mut rng, finite.len(), &mut sample);
        for (k, &j) in sample.iter().enumerate() {
            s1[k] = q1[j];
            s2[k] = q2[j];
        }
        let Some(m) = fit(&s1, &s2) else { continue };
        let s = score(&m, &mut errors);
        if best.as_ref().is_none_or(|(_, b)| better(s, *b)) {
            best = Some((m, s));
            let outlier_ratio = 1.0 - s.0 as f64 / finite.len() as f64;
            needed = needed.min(adaptive_iterations(
                confidence,
                outlier_ratio,
                sample_size,
                max_iterations,
            ));
        }
    }
    let (mut model, mut best_score) = best?;
    // Refit on the inliers while that gains inliers.
    for _ in 0..3 {
        error(&model, &q1, &q2, &mut errors);
        let inliers = || (0..errors.len()).filter(|&k| errors[k] <= threshold2);
        let r1: Vec<Vec2> = inliers().map(|k| q1[k]).collect();
        let r2: Vec<Vec2> = inliers().map(|k| q2[k]).collect();
        let Some(refit) = fit(&r1, &r2) else { break };
        let s = score(&refit, &mut errors);
        if better(s, best_score) {
            model = refit;
            best_score = s;
        } else {
            break;
        }
    }
    error(&model, &q1, &q2, &mut errors);
    let mut mask = vec![false; p1.len()];
    for (&i, &e) in finite.iter().zip(&errors) {
        mask[i] = e <= threshold2;
    }
    Some((model, mask))
}

/// Iterations needed so that, with probability `confidence`, one sample of `sample_size` is free
/// of outliers (OpenCV's `RANSACUpdateNumIters`), capped at `max_iterations`.
pub(crate) fn adaptive_iterations(
    confidence: f64,
    outlier_ratio: f64,
    sample_size: usize,
    max_iterations: usize,
) -> usize {
    let confidence = confidence.clamp(0.0, 1.0 - f64::EPSILON);
    let outlier_ratio = outlier_ratio.clamp(0.0, 1.0);
    let num = (1.0 - confidence).max(f64::MIN_POSITIVE).ln();
    let denom = (1.0 - (1.0 - outlier_ratio).powi(sample_size as i32)).ln();
    if denom.is_nan() || denom >= 0.0 || -num >= max_iterations as f64 * -denom {
        return max_iterations.max(1);
    }
    ((num / denom).round() as usize).clamp(1, max_iterations.max(1))
}

/// Hartley's normalisation: translate the centroid to the origin and scale the mean distance to
/// √2. `None` when all points coincide.
pub(crate) fn normalising_transform<'a>(
    pts: impl Iterator<Item = &'a Vec2> + Clone,
) -> Option<Mat3> {
    let n = pts.clone().count() as f64;
    if n == 0.0 {
        return None;
    }
    let centroid = pts.clone().fold(Vec2::zeros(), |acc, p| acc + p) / n;
    let mean_distance = pts.map(|p| (p - centroid).norm()).sum::<f64>() / n;
    if !(mean_distance.is_finite() && mean_distance > 1e-12) {
        return None;
    }
    let s = std::f64::consts::SQRT_2 / mean_distance;
    Some(Mat3::new(
        s,
        0.0,
        -s * centroid.x,
        0.0,
        s,
        -s * centroid.y,
        0.0,
        0.0,
        1.0,
    ))
}

/// `T p` for a pixel, in inhomogeneous coordinates (T is affine).
#[inline]
/// At least `min` pairs, equal lengths, every coordinate finite: what the minimal solvers need
/// before they normalise.
pub(crate) fn usable_pairs(p1: &[Vec2], p2: &[Vec2], min: usize) -> bool {
    p1.len() >= min
        && p1.len() == p2.len()
        && p1
            .iter()
            .chain(p2)
            .all(|p| p.x.is_finite() && p.y.is_finite())
}

pub(crate) fn apply(t: &Mat3, p: &Vec2) -> Vec2 {
    Vec2::new(
        t[(0, 0)] * p.x + t[(0, 1)] * p.y + t[(0, 2)],
        t[(1, 0)] * p.x + t[(1, 1)] * p.y + t[(1, 2)],
    )
}

/// The unit eigenvector of the smallest eigenvalue of the 9x9 normal matrix `AᵀA`, or `None` when
/// the null space is not one-dimensional (the second smallest eigenvalue is also ~0 relative to
/// the largest), i.e. the configuration is degenerate.
pub(crate) fn smallest_null_vector(ata: &SMatrix<f64, 9, 9>) -> Option<SMatrix<f64, 9, 1>> {
    let eig = SymmetricEigen::new(*ata);
    let mut order: Vec<usize> = (0..9).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let largest = eig.eigenvalues[order[8]];
    let second = eig.eigenvalues[order[1]];
    if !(largest.is_finite() && largest > 0.0) || second <= 1e-10 * largest {
        return None;
    }
    let v = eig.eigenvectors.column(order[0]).into_owned();
    v.iter().all(|x| x.is_finite()).then_some(v)
}

/// The unit null vector of eight equations in nine unknowns, by Gaussian elimination with full
/// pivoting, or `None` when the rows are (nearly) rank-deficient: the last pivot at most 1e-5 of
/// the first, the counterpart of [`smallest_null_vector`]'s test on `AᵀA`'s eigenvalues (which
/// are the squared singular values).
fn null_vector_8x9(mut a: [[f64; 9]; 8]) -> Option<SMatrix<f64, 9, 1>> {
    // column[k]: which unknown the k-th column of `a` holds after column swaps.
    let mut column: [usize; 9] = std::array::from_fn(|k| k);
    let mut first_pivot = 0.0;
    for k in 0..8 {
        let (mut pr, mut pc, mut best) = (k, k, -1.0);
        for (i, r) in a.iter().enumerate().skip(k) {
            for (j, v) in r.iter().enumerate().skip(k) {
                if v.abs() > best {
                    (pr, pc, best) = (i, j, v.abs());
                }
            }
        }
        if k == 0 {
            if !(best.is_finite() && best > 0.0) {
                return None;
            }
            first_pivot = best;
        } else if best <= 1e-5 * first_pivot {
            return None;
        }
        a.swap(k, pr);
        if pc != k {
            for r in a.iter_mut() {
                r.swap(k, pc);
            }
            column.swap(k, pc);
        }
        let pivot_row = a[k];
        for r in a.iter_mut().skip(k + 1) {
            let factor = r[k] / pivot_row[k];
            for j in k + 1..9 {
                r[j] -= factor * pivot_row[j];
            }
        }
    }
    // The free unknown is the last column's; back-substitute the others.
    let mut x = [0.0; 9];
    x[8] = 1.0;
    for k in (0..8).rev() {
        let sum: f64 = (k + 1..9).map(|j| a[k][j] * x[j]).sum();
        x[k] = -sum / a[k][k];
    }
    let mut v = SMatrix::<f64, 9, 1>::zeros();
    for (k, &unknown) in column.iter().enumerate() {
        v[unknown] = x[k];
    }
    let norm = v.norm();
    (norm.is_finite() && norm > 0.0).then(|| v / norm)
}

/// Closest rank-2 matrix in the Frobenius norm.
fn enforce_rank2(f: &Mat3) -> Option<Mat3> {
    let svd = f.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut s = svd.singular_values;
    // nalgebra sorts singular values in decreasing order.
    s[2] = 0.0;
    Some(u * Mat3::from_diagonal(&s) * v_t)
}

/// Fill `out` with distinct indices in `0..n` (n >= out.len()).
pub(crate) fn draw_distinct(rng: &mut SplitMix64, n: usize, out: &mut [usize]) {
    let mut k = 0;
    while k < out.len() {
        let candidate = (rng.next() % n as u64) as usize;
        if !out[..k].contains(&candidate) {
            out[k] = candidate;
            k += 1;
        }
    }
}

/// SplitMix64 (Steele et al. 2014): a tiny deterministic generator, so RANSAC results do not
/// depend on a random crate's version.
pub(crate) struct SplitMix64(pub(crate) u64);

impl SplitMix64 {
    pub(crate) fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{PinholeCamera, Se3, Vec3, epipolar_distance, fundamental_from_poses};

    fn camera() -> PinholeCamera {
        PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480)
    }

    /// Points at 2-6 m in front of camera 1 seen from both poses, with their true F.
    fn two_views(n: usize, t_w2: Se3, seed: u64) -> (Vec<Vec2>, Vec<Vec2>, Mat3) {
        let cam = camera();
        let mut rng = SplitMix64(seed);
        let mut uniform = || (rng.next() >> 11) as f64 / (1u64 << 53) as f64;
        let (mut p1, mut p2) = (Vec::new(), Vec::new());
        while p1.len() < n {
            let z = 2.0 + 4.0 * uniform();
            let x = Vec3::new((uniform() - 0.5) * z, (uniform() - 0.5) * 0.75 * z, z);
            let a = cam.project(&x);
            let b = cam.project(&(t_w2.inverse() * nalgebra::Point3::from(x)).coords);
            if let (Some(a), Some(b)) = (a, b) {
                p1.push(a);
                p2.push(b);
            }
        }
        let f = fundamental_from_poses(&cam.k(), &Se3::identity(), &cam.k(), &t_w2).unwrap();
        (p1, p2, f / f.norm())
    }

    fn moving_pose() -> Se3 {
        Se3::new(Vec3::new(0.15, -0.03, 0.08), Vec3::new(0.02, -0.04, 0.01))
    }

    #[test]
    fn eight_point_recovers_the_true_f_up_to_scale() {
        let (p1, p2, f_true) = two_views(8, moving_pose(), 1);
        let f = fundamental_8point(&p1, &p2).unwrap();
        let same = (f - f_true).norm().min((f + f_true).norm());
        assert!(same < 1e-6, "difference {same}");
        assert!(f.determinant().abs() < 1e-12);
        for (a, b) in p1.iter().zip(&p2) {
            assert!(epipolar_distance(&f, a, b) < 1e-6);
        }
    }

    #[test]
    fn too_few_mismatched_or_coincident_points_give_none() {
        let (p1, p2, _) = two_views(8, moving_pose(), 2);
        assert!(fundamental_8point(&p1[..7], &p2[..7]).is_none());
        assert!(fundamental_8point(&p1, &p2[..7]).is_none());
        assert!(fundamental_8point(&[Vec2::new(3.0, 4.0); 9], &[Vec2::new(1.0, 2.0); 9]).is_none());
        let mut bad = p1.clone();
        bad[3].x = f64::NAN;
        assert!(fundamental_8point(&bad, &p2).is_none());
        assert!(fundamental_ransac(&p1[..7], &p2[..7], &FundamentalRansac::default()).is_none());
    }

    #[test]
    fn static_and_purely_rotating_cameras_are_degenerate() {
        let (p1, _, _) = two_views(50, moving_pose(), 3);
        // Static camera: p2 = p1, every skew-symmetric F fits.
        assert!(fundamental_8point(&p1, &p1).is_none());
        assert!(fundamental_ransac(&p1, &p1, &FundamentalRansac::default()).is_none());
        // Pure rotation: p2 = K R K⁻¹ p1.
        let rotation = Se3::new(Vec3::zeros(), Vec3::new(0.03, -0.05, 0.02));
        let (r1, r2, _) = two_views(50, rotation, 4);
        assert!(fundamental_8point(&r1, &r2).is_none());
        // The same with exactly eight pairs (RANSAC's samples, solved by elimination).
        assert!(fundamental_8point(&p1[..8], &p1[..8]).is_none());
        assert!(fundamental_8point(&r1[..8], &r2[..8]).is_none());
    }

    #[test]
    fn eight_pairs_by_elimination_match_the_least_squares_solution() {
        // Each pair twice: 16 pairs take the eigen-solve, with the same normalisation and the
        // same exact solution as the eight by elimination.
        let (p1, mut p2, _) = two_views(8, moving_pose(), 11);
        p2[2].x += 0.7; // off the true F, so the solution is the sample's own
        let d1: Vec<Vec2> = p1.iter().chain(&p1).copied().collect();
        let d2: Vec<Vec2> = p2.iter().chain(&p2).copied().collect();
        let minimal = fundamental_8point(&p1, &p2).unwrap();
        let least_squares = fundamental_8point(&d1, &d2).unwrap();
        let diff = (minimal - least_squares)
            .norm()
            .min((minimal + least_squares).norm());
        assert!(diff < 1e-9, "difference {diff}");
    }

    #[test]
    fn batch_errors_are_bit_for_bit_the_single_errors() {
        let (p1, mut p2, f) = two_views(37, moving_pose(), 12);
        for (i, p) in p2.iter_mut().enumerate() {
            p.y += (i % 5) as f64 * 0.3;
        }
        // A point whose epipolar line has no direction: infinite error.
        let f_degenerate = Mat3::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0);
        for f in [f, f * 3.0, f_degenerate] {
            let mut batch = vec![0.0; p1.len()];
            symmetric_epipolar_errors2(&f, &p1, &p2, &mut batch);
            for ((a, b), e) in p1.iter().zip(&p2).zip(&batch) {
                assert_eq!(symmetric_epipolar_error2(&f, a, b).to_bits(), e.to_bits());
            }
        }
    }

    #[test]
    fn ransac_separates_movers_and_is_deterministic() {
        let (p1, mut p2, f_true) = two_views(200, moving_pose(), 5);
        let mut rng = SplitMix64(99);
        let mut noise = || ((rng.next() >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.06;
        // Sub-pixel noise on every point, and 30 % of the points moved 3-9 px off their
        // epipolar line (movers; a motion along the line is invisible to any F).
        let mut truly_outlier = vec![false; p2.len()];
        for (i, p) in p2.iter_mut().enumerate() {
            *p += Vec2::new(noise(), noise());
            if i % 10 < 3 {
                let line = f_true * Vec3::new(p1[i].x, p1[i].y, 1.0);
                let normal = Vec2::new(line.x, line.y).normalize();
                *p += normal * (3.0 + (i % 7) as f64);
                truly_outlier[i] = true;
            }
        }
        let params = FundamentalRansac::default();
        let (f, mask) = fundamental_ransac(&p1, &p2, &params).unwrap();
        for (i, (a, b)) in p1.iter().zip(&p2).enumerate() {
            let d = epipolar_distance(&f, a, b);
            if truly_outlier[i] {
                assert!(d > 1.0, "mover {i} at {d} px");
                assert!(!mask[i]);
            } else {
                assert!(d < 0.2, "static point {i} at {d} px");
            }
        }
        let inliers = mask.iter().filter(|&&m| m).count();
        assert!(inliers >= 100, "only {inliers} inliers");
        assert!((f - f_true).norm().min((f + f_true).norm()) < 0.05);
        assert_eq!(fundamental_ransac(&p1, &p2, &params), Some((f, mask)));
    }

    #[test]
    fn adaptive_iterations_match_opencv_formula() {
        // 50 % outliers, 8 points, 0.99 → log(0.01) / log(1 - 0.5^8) ≈ 1177, capped at 1000.
        assert_eq!(adaptive_iterations(0.99, 0.5, 8, 1000), 1000);
        assert_eq!(adaptive_iterations(0.99, 0.5, 8, 5000), 1177);
        assert_eq!(adaptive_iterations(0.99, 0.0, 8, 1000), 1);
        assert_eq!(adaptive_iterations(0.99, 1.0, 8, 1000), 1000);
    }
}
