//! Triangle meshes built from a few primitives (quads, boxes, tapered prisms, ellipsoids), in a
//! part's local frame: x right, y forward, z up, metres.

use nalgebra::Vector3;

/// A point in a part's local frame.
pub type P3 = Vector3<f64>;

/// One textured triangle. `tex` indexes the scene's texture list.
#[derive(Clone, Debug)]
pub struct Tri {
    /// Corners in the part's local frame, metres.
    pub p: [P3; 3],
    /// Texture coordinates of the corners (0..1, rows grow downwards).
    pub uv: [[f32; 2]; 3],
    /// Index of the texture in the scene's list.
    pub tex: u16,
}

/// A list of triangles sharing a rigid frame.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// The triangles, in the part's local frame.
    pub tris: Vec<Tri>,
}

impl Mesh {
    /// Append another mesh.
    pub fn extend(&mut self, other: Mesh) {
        self.tris.extend(other.tris);
    }

    /// A quad `a b c d` (in order around its border) mapped to the texture rectangle `uv0..uv1`
    /// (a gets (u0, v1), b (u1, v1), c (u1, v0), d (u0, v0): texture rows grow downwards).
    pub fn quad(&mut self, q: [P3; 4], tex: u16, uv0: [f32; 2], uv1: [f32; 2]) {
        let uv = [
            [uv0[0], uv1[1]],
            [uv1[0], uv1[1]],
            [uv1[0], uv0[1]],
            [uv0[0], uv0[1]],
        ];
        self.tris.push(Tri {
            p: [q[0], q[1], q[2]],
            uv: [uv[0], uv[1], uv[2]],
            tex,
        });
        self.tris.push(Tri {
            p: [q[0], q[2], q[3]],
            uv: [uv[0], uv[2], uv[3]],
            tex,
        });
    }

    /// An axis-aligned box from `lo` to `hi`. Each face gets its own region of the texture (a
    /// 3x2 atlas) so no two faces show the same pattern.
    pub fn cuboid(lo: P3, hi: P3, tex: u16) -> Mesh {
        let mut m = Mesh::default();
        let (x0, y0, z0, x1, y1, z1) = (lo.x, lo.y, lo.z, hi.x, hi.y, hi.z);
        let v = |x, y, z| P3::new(x, y, z);
        let cell = |i: usize| -> ([f32; 2], [f32; 2]) {
            let (cx, cy) = ((i % 3) as f32, (i / 3) as f32);
            ([cx / 3.0, cy / 2.0], [(cx + 1.0) / 3.0, (cy + 1.0) / 2.0])
        };
        let faces = [
            [v(x0, y0, z0), v(x1, y0, z0), v(x1, y0, z1), v(x0, y0, z1)], // front (-y)
            [v(x1, y1, z0), v(x0, y1, z0), v(x0, y1, z1), v(x1, y1, z1)], // back (+y)
            [v(x0, y1, z0), v(x0, y0, z0), v(x0, y0, z1), v(x0, y1, z1)], // left (-x)
            [v(x1, y0, z0), v(x1, y1, z0), v(x1, y1, z1), v(x1, y0, z1)], // right (+x)
            [v(x0, y0, z1), v(x1, y0, z1), v(x1, y1, z1), v(x0, y1, z1)], // top
            [v(x0, y1, z0), v(x1, y1, z0), v(x1, y0, z0), v(x0, y0, z0)], // bottom
        ];
        for (i, f) in faces.into_iter().enumerate() {
            let (a, b) = cell(i);
            m.quad(f, tex, a, b);
        }
        m
    }

    /// A tapered prism with an elliptical cross-section of `sides` sides, from z = 0 (radii
    /// `r0`) down to z = -`length` (radii `r1`), capped. The texture wraps once around it (u) and
    /// runs along it (v); u = 0.5 faces +y (forward), so faces drawn there look ahead.
    pub fn prism(sides: usize, r0: [f64; 2], r1: [f64; 2], length: f64, tex: u16) -> Mesh {
        let mut m = Mesh::default();
        let sides = sides.max(3);
        let ring = |r: [f64; 2], z: f64, k: usize| {
            // angle 0 at -y (back), so u = 0.5 is +y (front)
            let a = std::f64::consts::TAU * k as f64 / sides as f64;
            P3::new(r[0] * a.sin(), -r[1] * a.cos(), z)
        };
        for k in 0..sides {
            let (u0, u1) = (k as f32 / sides as f32, (k + 1) as f32 / sides as f32);
            let q = [
                ring(r1, -length, k),
                ring(r1, -length, k + 1),
                ring(r0, 0.0, k + 1),
                ring(r0, 0.0, k),
            ];
            m.quad(q, tex, [u0, 0.0], [u1, 1.0]);
        }
        for (r, z) in [(r0, 0.0), (r1, -length)] {
            let c = P3::new(0.0, 0.0, z);
            for k in 0..sides {
                let (a, b) = (ring(r, z, k), ring(r, z, k + 1));
                m.tris.push(Tri {
                    p: [c, a, b],
                    uv: [[0.5, 0.02], [0.45, 0.0], [0.55, 0.0]],
                    tex,
                });
            }
        }
        m
    }

    /// An ellipsoid centred at the origin with semi-axes `r`, as a UV sphere.
    pub fn ellipsoid(r: P3, rings: usize, segments: usize, tex: u16) -> Mesh {
        let mut m = Mesh::default();
        let pt = |i: usize, j: usize| {
            let th = std::f64::consts::PI * i as f64 / rings as f64;
            let ph = std::f64::consts::TAU * j as f64 / segments as f64;
            P3::new(
                r.x * th.sin() * ph.sin(),
                -r.y * th.sin() * ph.cos(),
                r.z * th.cos(),
            )
        };
        for i in 0..rings {
            for j in 0..segments {
                let (u0, u1) = (j as f32 / segments as f32, (j + 1) as f32 / segments as f32);
                let (v0, v1) = (i as f32 / rings as f32, (i + 1) as f32 / rings as f32);
                m.quad(
                    [pt(i + 1, j), pt(i + 1, j + 1), pt(i, j + 1), pt(i, j)],
                    tex,
                    [u0, v0],
                    [u1, v1],
                );
            }
        }
        m
    }

    /// Move every vertex by `t`.
    pub fn translated(mut self, t: P3) -> Mesh {
        for tri in &mut self.tris {
            for p in &mut tri.p {
                *p += t;
            }
        }
        self
    }

    /// Apply a rigid transform to every vertex.
    pub fn transformed(mut self, iso: &nalgebra::Isometry3<f64>) -> Mesh {
        for tri in &mut self.tris {
            for p in &mut tri.p {
                *p = iso.transform_point(&nalgebra::Point3::from(*p)).coords;
            }
        }
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn primitives_have_expected_triangle_counts() {
        assert_eq!(
            Mesh::cuboid(P3::zeros(), P3::new(1.0, 1.0, 1.0), 0)
                .tris
                .len(),
            12
        );
        assert_eq!(
            Mesh::prism(8, [0.1, 0.1], [0.1, 0.1], 1.0, 0).tris.len(),
            32
        );
        let e = Mesh::ellipsoid(P3::new(1.0, 2.0, 3.0), 6, 8, 0);
        assert_eq!(e.tris.len(), 96);
        // every vertex lies on the ellipsoid
        for t in &e.tris {
            for p in &t.p {
                let s = (p.x / 1.0).powi(2) + (p.y / 2.0).powi(2) + (p.z / 3.0).powi(2);
                assert!((s - 1.0).abs() < 1e-9);
            }
        }
    }
}
