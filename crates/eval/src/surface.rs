//! How far a point cloud lies from a known surface (a synthetic scene's triangles): each point's
//! distance to the nearest triangle, looked up in a uniform grid so that a million points against
//! thousands of triangles takes seconds, not hours.

use std::collections::HashMap;

use serde::Serialize;
use stillpoint_geometry::Vec3;

/// A triangle's corners.
pub type Triangle = [Vec3; 3];

/// The distance from `p` to the triangle `t` (Ericson, Real-Time Collision Detection, 5.1.5:
/// the closest point is found in the Voronoi region of a corner, an edge or the face).
pub fn point_triangle_distance(p: &Vec3, t: &Triangle) -> f64 {
    let [a, b, c] = t;
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return ap.norm();
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
    if d3 >= 0.0 && d4 <= d3 {
        return bp.norm();
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (p - (a + v * ab)).norm();
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
    if d6 >= 0.0 && d5 <= d6 {
        return cp.norm();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (p - (a + w * ac)).norm();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (p - (b + w * (c - b))).norm();
    }
    let denom = va + vb + vc;
    if denom.abs() < f64::MIN_POSITIVE {
        // A degenerate (zero-area) triangle: its nearest edge.
        return [(a, b), (b, c), (c, a)]
            .iter()
            .map(|(u, v)| point_segment_distance(p, u, v))
            .fold(f64::INFINITY, f64::min);
    }
    let (v, w) = (vb / denom, vc / denom);
    (p - (a + ab * v + ac * w)).norm()
}

fn point_segment_distance(p: &Vec3, a: &Vec3, b: &Vec3) -> f64 {
    let ab = b - a;
    let len2 = ab.norm_squared();
    let s = if len2 > 0.0 {
        ((p - a).dot(&ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + s * ab)).norm()
}

/// Triangles filed by grid cell: a triangle is in every cell that lies within `reach` of its
/// bounding box, so one cell's list holds every triangle within `reach` of any point in it.
pub struct SurfaceGrid {
    triangles: Vec<Triangle>,
    cell: f64,
    reach: f64,
    cells: HashMap<[i64; 3], Vec<u32>>,
}

impl SurfaceGrid {
    /// File `triangles` in cells of `cell` metres, for distances up to `reach` metres.
    pub fn new(triangles: Vec<Triangle>, cell: f64, reach: f64) -> Self {
        let cell = cell.max(1e-3);
        let reach = reach.max(0.0);
        let key = |v: f64| (v / cell).floor() as i64;
        let mut cells: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
        for (i, t) in triangles.iter().enumerate() {
            let lo = t[0].inf(&t[1]).inf(&t[2]).add_scalar(-reach);
            let hi = t[0].sup(&t[1]).sup(&t[2]).add_scalar(reach);
            for x in key(lo.x)..=key(hi.x) {
                for y in key(lo.y)..=key(hi.y) {
                    for z in key(lo.z)..=key(hi.z) {
                        cells.entry([x, y, z]).or_default().push(i as u32);
                    }
                }
            }
        }
        Self {
            triangles,
            cell,
            reach,
            cells,
        }
    }

    /// The distance from `p` to the nearest triangle, when one is within the grid's reach.
    pub fn distance(&self, p: &Vec3) -> Option<f64> {
        let key = [p.x, p.y, p.z].map(|v| (v / self.cell).floor() as i64);
        self.cells
            .get(&key)?
            .iter()
            .map(|&i| point_triangle_distance(p, &self.triangles[i as usize]))
            .filter(|&d| d <= self.reach)
            .min_by(f64::total_cmp)
    }
}

/// How far a cloud lies from a surface.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CloudDistance {
    /// Points measured.
    pub points: usize,
    /// Median distance, metres (points beyond the reach count as the reach).
    pub median_m: f64,
    /// 95th percentile, metres (likewise).
    pub p95_m: f64,
    /// Share of points within 1 cm.
    pub within_1cm: f64,
    /// Share of points within 2 cm.
    pub within_2cm: f64,
    /// Share of points within 5 cm.
    pub within_5cm: f64,
    /// Share of points farther than the reach (nothing of the surface near them).
    pub beyond_reach: f64,
    /// The reach, metres.
    pub reach_m: f64,
}

/// Each point's distance to `surface`, summarised. Points farther than the grid's reach count
/// as the reach in the quantiles and in `beyond_reach`.
pub fn cloud_to_surface(points: &[Vec3], surface: &SurfaceGrid) -> CloudDistance {
    let mut d: Vec<f64> = points
        .iter()
        .map(|p| surface.distance(p).unwrap_or(f64::INFINITY))
        .collect();
    let n = d.len().max(1) as f64;
    let share = |limit: f64| d.iter().filter(|&&v| v <= limit).count() as f64 / n;
    let (within_1cm, within_2cm, within_5cm) = (share(0.01), share(0.02), share(0.05));
    let beyond_reach = d.iter().filter(|v| v.is_infinite()).count() as f64 / n;
    for v in d.iter_mut() {
        *v = v.min(surface.reach);
    }
    d.sort_by(f64::total_cmp);
    CloudDistance {
        points: points.len(),
        median_m: crate::quantile(&d, 0.5),
        p95_m: crate::quantile(&d, 0.95),
        within_1cm,
        within_2cm,
        within_5cm,
        beyond_reach,
        reach_m: surface.reach,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64, y: f64, z: f64) -> Vec3 {
        Vec3::new(x, y, z)
    }

    #[test]
    fn the_distance_to_a_triangle_is_to_its_face_edge_or_corner() {
        let t = [v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(0.0, 1.0, 0.0)];
        // Above the face.
        assert!((point_triangle_distance(&v(0.2, 0.2, 0.5), &t) - 0.5).abs() < 1e-12);
        // Beyond corner a, b and c.
        assert!((point_triangle_distance(&v(-3.0, -4.0, 0.0), &t) - 5.0).abs() < 1e-12);
        assert!((point_triangle_distance(&v(2.0, 0.0, 0.0), &t) - 1.0).abs() < 1e-12);
        assert!((point_triangle_distance(&v(0.0, 1.0, 2.0), &t) - 2.0).abs() < 1e-12);
        // Beside edge ab, ac and the hypotenuse bc.
        assert!((point_triangle_distance(&v(0.5, -1.0, 0.0), &t) - 1.0).abs() < 1e-12);
        assert!((point_triangle_distance(&v(-1.0, 0.5, 0.0), &t) - 1.0).abs() < 1e-12);
        let d = point_triangle_distance(&v(1.0, 1.0, 0.0), &t);
        assert!((d - 0.5f64.sqrt()).abs() < 1e-12);
        // A degenerate triangle is its segment.
        let flat = [v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(2.0, 0.0, 0.0)];
        assert!((point_triangle_distance(&v(1.5, 1.0, 0.0), &flat) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_grid_finds_what_brute_force_finds_within_its_reach() {
        // A unit floor of two triangles and a wall beside it.
        let tris = vec![
            [v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(1.0, 1.0, 0.0)],
            [v(0.0, 0.0, 0.0), v(1.0, 1.0, 0.0), v(0.0, 1.0, 0.0)],
            [v(0.0, 1.0, 0.0), v(1.0, 1.0, 0.0), v(1.0, 1.0, 1.0)],
        ];
        let grid = SurfaceGrid::new(tris.clone(), 0.07, 0.1);
        for i in 0..400 {
            // A spread of points around the surfaces, some out of reach.
            let f = i as f64;
            let p = v(
                (f * 0.6180339).fract() * 1.4 - 0.2,
                (f * 0.4142135).fract() * 1.4 - 0.2,
                (f * 0.7320508).fract() * 0.4 - 0.2,
            );
            let truth = tris
                .iter()
                .map(|t| point_triangle_distance(&p, t))
                .fold(f64::INFINITY, f64::min);
            match grid.distance(&p) {
                Some(d) => assert!((d - truth).abs() < 1e-12, "{p:?}: {d} vs {truth}"),
                None => assert!(truth > 0.1, "{p:?}: missed at {truth}"),
            }
        }
    }

    #[test]
    fn a_cloud_on_the_surface_and_a_stray_point_are_summarised() {
        let floor = vec![
            [v(0.0, 0.0, 0.0), v(1.0, 0.0, 0.0), v(1.0, 1.0, 0.0)],
            [v(0.0, 0.0, 0.0), v(1.0, 1.0, 0.0), v(0.0, 1.0, 0.0)],
        ];
        let grid = SurfaceGrid::new(floor, 0.1, 0.2);
        let mut cloud: Vec<Vec3> = (0..18).map(|i| v(0.05 * i as f64, 0.5, 0.005)).collect();
        cloud.push(v(0.5, 0.5, 0.03));
        cloud.push(v(0.5, 0.5, 1.0));
        let d = cloud_to_surface(&cloud, &grid);
        assert_eq!(d.points, 20);
        assert!((d.median_m - 0.005).abs() < 1e-12);
        assert_eq!(d.within_1cm, 0.9);
        assert_eq!(d.within_5cm, 0.95);
        assert_eq!(d.beyond_reach, 0.05);
        // Nearest rank 18 of 0..=19: the 3 cm point; the stray one counts as the reach.
        assert_eq!(d.p95_m, 0.03);
    }
}
