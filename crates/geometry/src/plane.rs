//! Planes fitted to 3D points by RANSAC: the floor a walker stands on, seen beside him.

use crate::Vec3;
use crate::fundamental::SplitMix64;

/// The plane `normal · x + offset = 0`, `normal` of unit length.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    /// Unit normal.
    pub normal: Vec3,
    /// Signed offset along the normal.
    pub offset: f64,
}

impl Plane {
    /// Distance of `x` from the plane.
    pub fn distance(&self, x: &Vec3) -> f64 {
        (self.normal.dot(x) + self.offset).abs()
    }

    /// The plane through three points; `None` when they are (nearly) on a line.
    pub fn through(a: &Vec3, b: &Vec3, c: &Vec3) -> Option<Self> {
        let n = (b - a).cross(&(c - a));
        let norm = n.norm();
        (norm.is_finite() && norm > 1e-12).then(|| {
            let normal = n / norm;
            Self {
                normal,
                offset: -normal.dot(a),
            }
        })
    }

    /// The least-squares plane of `points` (at least three, not on a line).
    pub fn least_squares(points: &[Vec3]) -> Option<Self> {
        if points.len() < 3 {
            return None;
        }
        let mean = points.iter().sum::<Vec3>() / points.len() as f64;
        let scatter = points
            .iter()
            .map(|p| (p - mean) * (p - mean).transpose())
            .sum::<crate::Mat3>();
        let eigen = scatter.symmetric_eigen();
        let (smallest, _) = eigen
            .eigenvalues
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.total_cmp(b.1))?;
        let normal = eigen.eigenvectors.column(smallest).into_owned();
        let norm = normal.norm();
        (norm.is_finite() && norm > 0.0).then(|| {
            let normal = normal / norm;
            Self {
                normal,
                offset: -normal.dot(&mean),
            }
        })
    }
}

/// The plane most of `points` lie on: `iterations` planes through three points drawn with
/// `seed` (the same points and seed give the same plane), the one with the most points within
/// `tolerance(point)` of it, refitted by least squares to those points. With the number of
/// them; `None` for fewer than three points or no plane.
///
/// ```
/// use stillpoint_geometry::{Vec3, plane::ransac_plane};
/// // A floor 1.5 m below the camera (y down), and a box standing on it.
/// let mut points: Vec<Vec3> = (0..100)
///     .map(|i| Vec3::new((i % 10) as f64 * 0.2 - 1.0, 1.5, 2.0 + (i / 10) as f64 * 0.2))
///     .collect();
/// points.extend((0..20).map(|i| Vec3::new(0.1, 1.0 + i as f64 * 0.02, 3.0)));
/// let (floor, inliers) = ransac_plane(&points, &|_| 0.01, 64, 7).unwrap();
/// assert_eq!(inliers, 100);
/// assert!(floor.distance(&Vec3::new(5.0, 1.5, 9.0)) < 1e-9);
/// ```
pub fn ransac_plane(
    points: &[Vec3],
    tolerance: &dyn Fn(&Vec3) -> f64,
    iterations: usize,
    seed: u64,
) -> Option<(Plane, usize)> {
    if points.len() < 3 {
        return None;
    }
    let mut rng = SplitMix64(seed);
    let inliers = |plane: &Plane| {
        points
            .iter()
            .filter(|p| plane.distance(p) <= tolerance(p))
            .count()
    };
    let mut best: Option<(Plane, usize)> = None;
    let mut draw = [0usize; 3];
    for _ in 0..iterations {
        crate::fundamental::draw_distinct(&mut rng, points.len(), &mut draw);
        let Some(plane) = Plane::through(&points[draw[0]], &points[draw[1]], &points[draw[2]])
        else {
            continue;
        };
        let n = inliers(&plane);
        if best.is_none_or(|(_, b)| n > b) {
            best = Some((plane, n));
        }
    }
    let (plane, _) = best?;
    let on: Vec<Vec3> = points
        .iter()
        .filter(|p| plane.distance(p) <= tolerance(p))
        .copied()
        .collect();
    // The refit stands only if it loses none of the points it was fitted to.
    let refit = Plane::least_squares(&on).map(|r| (r, inliers(&r)));
    Some(
        refit
            .filter(|&(_, n)| n >= on.len())
            .unwrap_or((plane, on.len())),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plane_of_most_points_is_found_among_others_and_noise() {
        let mut rng = SplitMix64(3);
        let mut uniform = || (rng.next() >> 11) as f64 / (1u64 << 53) as f64;
        // A tilted floor with 1 cm noise, a wall-like clutter of 40 % as many points.
        let (normal, offset) = (Vec3::new(0.0, -0.96, -0.28).normalize(), 1.4);
        let mut points = Vec::new();
        for _ in 0..200 {
            let (x, z) = (uniform() * 2.0 - 1.0, 1.0 + uniform() * 3.0);
            // Solve normal · (x, y, z) + offset = 0 for y, then add noise along the normal.
            let y = -(normal.x * x + normal.z * z + offset) / normal.y;
            points.push(Vec3::new(x, y, z) + normal * (uniform() - 0.5) * 0.02);
        }
        for _ in 0..80 {
            points.push(Vec3::new(
                uniform() * 2.0 - 1.0,
                uniform() - 0.5,
                2.5 + uniform() * 0.3,
            ));
        }
        let (plane, inliers) = ransac_plane(&points, &|_| 0.02, 64, 11).expect("a plane");
        assert!(inliers >= 200, "{inliers}");
        assert!(
            plane.normal.dot(&normal).abs() > 0.999,
            "{:?}",
            plane.normal
        );
        let on = Vec3::new(
            0.3,
            -(normal.x * 0.3 + normal.z * 2.0 + offset) / normal.y,
            2.0,
        );
        assert!(plane.distance(&on) < 0.005);
        // The same points and seed, the same plane; too few points, none.
        assert_eq!(ransac_plane(&points, &|_| 0.02, 64, 11).unwrap().0, plane);
        assert!(ransac_plane(&points[..2], &|_| 0.02, 64, 11).is_none());
    }
}
