//! The rasteriser: triangles clipped at the near plane, a z-buffer holding the depth along the
//! optical axis, perspective-correct texture coordinates with trilinear filtering, alpha-tested
//! cut-outs, and an id buffer naming the part seen at every pixel.
//!
//! Pixel (u, v) samples the scene at the point (u, v) of the image plane (pixel centres on
//! integer coordinates, as OpenCV and TUM use them), so the depth stored at a pixel is exactly
//! the depth of the surface point that projects there: 1/z is affine in screen space on a plane,
//! and the rasteriser evaluates it in double precision.

use crate::mesh::{Mesh, P3};
use crate::texture::Texture;
use nalgebra::Isometry3;
use stillpoint_geometry::PinholeCamera;

/// Surfaces closer than this to the camera plane are clipped (metres).
pub const NEAR: f64 = 0.05;

/// Colour, depth and part id of one rendered view.
#[derive(Clone, Debug)]
pub struct Target {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Colour, row-major.
    pub rgb: Vec<[u8; 3]>,
    /// Depth along the optical axis in metres; `f32::INFINITY` where nothing was drawn.
    pub depth: Vec<f32>,
    /// 0 where nothing was drawn, else the drawn part's id.
    pub id: Vec<u16>,
}

impl Target {
    /// An empty view: black, infinitely far, no part.
    pub fn new(width: usize, height: usize) -> Target {
        Target {
            width,
            height,
            rgb: vec![[0, 0, 0]; width * height],
            depth: vec![f32::INFINITY; width * height],
            id: vec![0; width * height],
        }
    }
}

/// One rigid part to draw: its mesh, its pose in the camera frame and its pose's rotation in the
/// world (for lighting, so a static surface keeps its brightness when the camera moves).
pub struct DrawItem<'a> {
    /// The part's triangles.
    pub mesh: &'a Mesh,
    /// The part's pose in the camera frame (part to camera).
    pub t_cp: Isometry3<f64>,
    /// The part's rotation in the world (part to world), for the lighting.
    pub r_wp: nalgebra::UnitQuaternion<f64>,
    /// The id written to the id buffer where this part is seen.
    pub id: u16,
}

/// A triangle in screen space, ready to scan.
struct ScreenTri {
    /// Barycentric coordinate i = a[i] * x + b[i] * y + c[i].
    a: [f64; 3],
    b: [f64; 3],
    c: [f64; 3],
    iz: [f64; 3],
    u: [f64; 3],
    v: [f64; 3],
    bbox: [usize; 4],
}

fn setup(
    cam: &PinholeCamera,
    p: [P3; 3],
    uv: [[f64; 2]; 3],
    w: usize,
    h: usize,
) -> Option<ScreenTri> {
    let mut s = [[0.0f64; 2]; 3];
    let mut iz = [0.0f64; 3];
    for i in 0..3 {
        iz[i] = 1.0 / p[i].z;
        s[i] = [
            cam.fx * p[i].x * iz[i] + cam.cx,
            cam.fy * p[i].y * iz[i] + cam.cy,
        ];
    }
    let area =
        (s[1][0] - s[0][0]) * (s[2][1] - s[0][1]) - (s[1][1] - s[0][1]) * (s[2][0] - s[0][0]);
    if !area.is_finite() || area.abs() < 1e-12 {
        return None;
    }
    // Pixel centres inside the screen-space bounding box, clipped to the image.
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for q in &s {
        for d in 0..2 {
            lo[d] = lo[d].min(q[d]);
            hi[d] = hi[d].max(q[d]);
        }
    }
    let (xmin, ymin) = (lo[0].ceil().max(0.0), lo[1].ceil().max(0.0));
    let (xmax, ymax) = (
        hi[0].floor().min(w as f64 - 1.0),
        hi[1].floor().min(h as f64 - 1.0),
    );
    if xmin > xmax || ymin > ymax {
        return None;
    }
    // barycentric of vertex i: edge function of the opposite edge over the area
    let mut a = [0.0; 3];
    let mut b = [0.0; 3];
    let mut c = [0.0; 3];
    for i in 0..3 {
        let (j, k) = ((i + 1) % 3, (i + 2) % 3);
        a[i] = (s[j][1] - s[k][1]) / area;
        b[i] = (s[k][0] - s[j][0]) / area;
        c[i] = (s[j][0] * s[k][1] - s[k][0] * s[j][1]) / area;
    }
    Some(ScreenTri {
        a,
        b,
        c,
        iz,
        u: [uv[0][0], uv[1][0], uv[2][0]],
        v: [uv[0][1], uv[1][1], uv[2][1]],
        bbox: [xmin as usize, ymin as usize, xmax as usize, ymax as usize],
    })
}

/// Clip a triangle (camera frame) against z >= NEAR; returns 0, 1 or 2 triangles.
fn clip_near(p: [P3; 3], uv: [[f64; 2]; 3], out: &mut Vec<([P3; 3], [[f64; 2]; 3])>) {
    out.clear();
    let inside = [p[0].z >= NEAR, p[1].z >= NEAR, p[2].z >= NEAR];
    if inside.iter().all(|&b| b) {
        out.push((p, uv));
        return;
    }
    if !inside.iter().any(|&b| b) {
        return;
    }
    let mut poly: Vec<(P3, [f64; 2])> = Vec::with_capacity(4);
    for i in 0..3 {
        let j = (i + 1) % 3;
        if inside[i] {
            poly.push((p[i], uv[i]));
        }
        if inside[i] != inside[j] {
            let t = (NEAR - p[i].z) / (p[j].z - p[i].z);
            let q = p[i] + (p[j] - p[i]) * t;
            let tuv = [
                uv[i][0] + (uv[j][0] - uv[i][0]) * t,
                uv[i][1] + (uv[j][1] - uv[i][1]) * t,
            ];
            poly.push((P3::new(q.x, q.y, NEAR), tuv));
        }
    }
    for k in 1..poly.len().saturating_sub(1) {
        out.push((
            [poly[0].0, poly[k].0, poly[k + 1].0],
            [poly[0].1, poly[k].1, poly[k + 1].1],
        ));
    }
}

/// Scan a screen triangle, calling `frag(index, x, y, l)` for every pixel inside with its
/// barycentric coordinates `l`.
#[inline]
fn scan(t: &ScreenTri, width: usize, mut frag: impl FnMut(usize, f64, f64, [f64; 3])) {
    for y in t.bbox[1]..=t.bbox[3] {
        let yf = y as f64;
        let row = [
            t.b[0] * yf + t.c[0],
            t.b[1] * yf + t.c[1],
            t.b[2] * yf + t.c[2],
        ];
        // the x range where all three edge functions are >= 0, widened by a pixel so that the
        // exact test below alone decides the border pixels
        let (mut x0, mut x1) = (t.bbox[0] as f64, t.bbox[2] as f64);
        for (&a, &r) in t.a.iter().zip(&row) {
            if a > 0.0 {
                x0 = x0.max((-r / a).floor() - 1.0);
            } else if a < 0.0 {
                x1 = x1.min((-r / a).ceil() + 1.0);
            } else if r < 0.0 {
                x1 = -1.0;
            }
        }
        if x0.is_nan() || x1.is_nan() || x0 > x1 {
            continue;
        }
        for x in x0 as usize..=x1 as usize {
            let xf = x as f64;
            let l = [
                t.a[0] * xf + row[0],
                t.a[1] * xf + row[1],
                t.a[2] * xf + row[2],
            ];
            if l[0] >= 0.0 && l[1] >= 0.0 && l[2] >= 0.0 {
                frag(y * width + x, xf, yf, l);
            }
        }
    }
}

/// Perspective-correct (u, v) at barycentrics `l`, and the texels one pixel spans.
#[inline]
fn texcoord(t: &ScreenTri, l: [f64; 3], tex: &Texture) -> (f32, f32, f32, f64) {
    let wz = l[0] * t.iz[0] + l[1] * t.iz[1] + l[2] * t.iz[2];
    let au = l[0] * t.u[0] * t.iz[0] + l[1] * t.u[1] * t.iz[1] + l[2] * t.u[2] * t.iz[2];
    let av = l[0] * t.v[0] * t.iz[0] + l[1] * t.v[1] * t.iz[1] + l[2] * t.v[2] * t.iz[2];
    let z = 1.0 / wz;
    let (u, v) = (au * z, av * z);
    // derivatives of the affine numerators/denominator along x and y give the footprint
    let d = |g: &[f64; 3]| {
        let dw = g[0] * t.iz[0] + g[1] * t.iz[1] + g[2] * t.iz[2];
        let du = g[0] * t.u[0] * t.iz[0] + g[1] * t.u[1] * t.iz[1] + g[2] * t.u[2] * t.iz[2];
        let dv = g[0] * t.v[0] * t.iz[0] + g[1] * t.v[1] * t.iz[1] + g[2] * t.v[2] * t.iz[2];
        let z1 = 1.0 / (wz + dw);
        ((au + du) * z1 - u, (av + dv) * z1 - v)
    };
    let (tw, th) = tex.size();
    let (dux, dvx) = d(&t.a);
    let (duy, dvy) = d(&t.b);
    let rx = ((dux * tw as f64).powi(2) + (dvx * th as f64).powi(2)).sqrt();
    let ry = ((duy * tw as f64).powi(2) + (dvy * th as f64).powi(2)).sqrt();
    (u as f32, v as f32, rx.max(ry) as f32, z)
}

/// Brightness of a face with world normal `n`: ambient plus two soft lights, two-sided so
/// the winding of a triangle does not matter.
fn shade(n: &P3) -> f32 {
    let l1 = P3::new(0.3, -0.5, 0.81).normalize();
    let l2 = P3::new(-0.6, 0.4, 0.3).normalize();
    (0.55 + 0.35 * n.dot(&l1).abs() + 0.15 * n.dot(&l2).abs()).min(1.0) as f32
}

/// A clipped screen triangle with what shading it needs.
struct Setup {
    tri: ScreenTri,
    tex: u16,
    light: f32,
    id: u16,
}

/// Depth of a fragment as the z-buffer stores it.
#[inline]
fn frag_depth(st: &ScreenTri, l: [f64; 3]) -> f32 {
    let wz = l[0] * st.iz[0] + l[1] * st.iz[1] + l[2] * st.iz[2];
    (1.0 / wz) as f32
}

/// Draw `items` into `target` through `cam` (depth test, alpha test, shading).
///
/// Two passes: the first fills the z-buffer and the id buffer (sampling textures only for the
/// alpha test of cut-outs), the second shades each pixel once, with the triangle that won the
/// depth test, so hidden surfaces cost no texture lookups (most of the time went there).
pub fn draw(target: &mut Target, cam: &PinholeCamera, items: &[DrawItem], textures: &[Texture]) {
    let (w, h) = (target.width, target.height);
    let mut clipped = Vec::with_capacity(2);
    let mut setups: Vec<Setup> = Vec::new();
    for item in items {
        for tri in &item.mesh.tris {
            let pc = tri.p.map(|p| item.t_cp.transform_point(&p.into()).coords);
            let uv = tri.uv.map(|q| [q[0] as f64, q[1] as f64]);
            clip_near(pc, uv, &mut clipped);
            if clipped.is_empty() {
                continue;
            }
            let nl = (tri.p[1] - tri.p[0]).cross(&(tri.p[2] - tri.p[0]));
            let nw = item.r_wp * nl.try_normalize(1e-18).unwrap_or(P3::z());
            let light = shade(&nw);
            for &(p, uv) in clipped.iter() {
                if let Some(st) = setup(cam, p, uv, w, h) {
                    setups.push(Setup {
                        tri: st,
                        tex: tri.tex,
                        light,
                        id: item.id,
                    });
                }
            }
        }
    }
    // pass 1: visibility; the winner of a pixel is the first triangle with the smallest depth
    let mut winner = vec![u32::MAX; w * h];
    for (k, s) in setups.iter().enumerate() {
        let tex = &textures[s.tex as usize];
        let st = &s.tri;
        scan(st, w, |i, _, _, l| {
            let z = frag_depth(st, l);
            if z.partial_cmp(&target.depth[i]) != Some(std::cmp::Ordering::Less) {
                return;
            }
            if tex.has_alpha {
                let (u, v, rho, _) = texcoord(st, l, tex);
                if tex.sample(u, v, rho)[3] < 128.0 {
                    return;
                }
            }
            target.depth[i] = z;
            target.id[i] = s.id;
            winner[i] = k as u32;
        });
    }
    // pass 2: shade each pixel with the triangle that won it
    for (i, &k) in winner.iter().enumerate() {
        let Some(s) = setups.get(k as usize) else {
            continue;
        };
        let st = &s.tri;
        let (xf, yf) = ((i % w) as f64, (i / w) as f64);
        let l = [
            st.a[0] * xf + (st.b[0] * yf + st.c[0]),
            st.a[1] * xf + (st.b[1] * yf + st.c[1]),
            st.a[2] * xf + (st.b[2] * yf + st.c[2]),
        ];
        let tex = &textures[s.tex as usize];
        let (u, v, rho, _) = texcoord(st, l, tex);
        let c = tex.sample(u, v, rho);
        let q = |x: f32| (x * s.light + 0.5).clamp(0.0, 255.0) as u8;
        target.rgb[i] = [q(c[0]), q(c[1]), q(c[2])];
    }
}

/// [`draw`] with `samples` x `samples` colour samples a pixel, averaged (box filter): a camera
/// integrates light over its pixels, so an edge that moves a tenth of a pixel changes the pixels
/// it crosses by a tenth. Point-sampled, edges move in whole-pixel steps and LK on a silhouette or
/// a facet edge misreads a still surface by up to half a pixel. `samples` is made odd so that the
/// middle sample lies on the pixel centre: depth and part id are that sample's (exactly what
/// [`draw`] stores).
pub fn draw_antialiased(
    target: &mut Target,
    cam: &PinholeCamera,
    items: &[DrawItem],
    textures: &[Texture],
    samples: usize,
) {
    let s = samples.max(1) | 1;
    if s == 1 {
        draw(target, cam, items, textures);
        return;
    }
    let (w, h) = (target.width, target.height);
    // sample k of pixel u sits at u + (k - (s-1)/2) / s: hi-res pixel U = u*s + k is at
    // U/s - (s-1)/(2s) in the image, so f' = f*s and c' = c*s + (s-1)/2
    let half = (s - 1) as f64 / 2.0;
    let fine_cam = PinholeCamera::new(
        cam.fx * s as f64,
        cam.fy * s as f64,
        cam.cx * s as f64 + half,
        cam.cy * s as f64 + half,
        (w * s) as u32,
        (h * s) as u32,
    );
    let mut fine = Target::new(w * s, h * s);
    draw(&mut fine, &fine_cam, items, textures);
    let fw = w * s;
    let mid = s / 2;
    for y in 0..h {
        for x in 0..w {
            let mut acc = [0u32; 3];
            for dy in 0..s {
                let row = (y * s + dy) * fw + x * s;
                for c in &fine.rgb[row..row + s] {
                    acc[0] += c[0] as u32;
                    acc[1] += c[1] as u32;
                    acc[2] += c[2] as u32;
                }
            }
            let n = (s * s) as u32;
            let i = y * w + x;
            target.rgb[i] = acc.map(|a| ((a + n / 2) / n) as u8);
            let centre = (y * s + mid) * fw + x * s + mid;
            target.depth[i] = fine.depth[centre];
            target.id[i] = fine.id[centre];
        }
    }
}

/// Count the pixels `items` would cover with nothing in front of them (alpha-tested), using
/// `scratch` (image-sized, all false on entry and on return).
pub fn coverage(
    scratch: &mut [bool],
    width: usize,
    height: usize,
    cam: &PinholeCamera,
    items: &[DrawItem],
    textures: &[Texture],
) -> usize {
    let mut touched = Vec::new();
    let mut clipped = Vec::with_capacity(2);
    for item in items {
        for tri in &item.mesh.tris {
            let pc = tri.p.map(|p| item.t_cp.transform_point(&p.into()).coords);
            let uv = tri.uv.map(|q| [q[0] as f64, q[1] as f64]);
            clip_near(pc, uv, &mut clipped);
            let tex = &textures[tri.tex as usize];
            for &(p, uv) in clipped.iter() {
                let Some(st) = setup(cam, p, uv, width, height) else {
                    continue;
                };
                scan(&st, width, |i, _, _, l| {
                    if scratch[i] {
                        return;
                    }
                    if tex.has_alpha {
                        let (u, v, rho, _) = texcoord(&st, l, tex);
                        if tex.sample(u, v, rho)[3] < 128.0 {
                            return;
                        }
                    }
                    scratch[i] = true;
                    touched.push(i);
                });
            }
        }
    }
    for &i in &touched {
        scratch[i] = false;
    }
    touched.len()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::texture::{Canvas, Texture};

    fn flat_texture() -> Vec<Texture> {
        vec![Canvas::new(4, 4, [0.5, 0.5, 0.5]).into_texture()]
    }

    #[test]
    fn plane_depth_is_exact_at_pixel_centres() {
        let cam = PinholeCamera::new(500.0, 500.0, 319.5, 239.5, 64, 48);
        // a tilted plane z = 2 + 0.3 x, far larger than the view
        let f = |x: f64, y: f64| P3::new(x, y, 2.0 + 0.3 * x);
        let mut mesh = Mesh::default();
        mesh.quad(
            [f(-1.0, -1.0), f(1.0, -1.0), f(1.0, 1.0), f(-1.0, 1.0)],
            0,
            [0.0, 0.0],
            [1.0, 1.0],
        );
        let cam = PinholeCamera {
            cx: 31.5,
            cy: 23.5,
            ..cam
        };
        let mut t = Target::new(64, 48);
        let items = [DrawItem {
            mesh: &mesh,
            t_cp: Isometry3::identity(),
            r_wp: nalgebra::UnitQuaternion::identity(),
            id: 7,
        }];
        draw(&mut t, &cam, &items, &flat_texture());
        for v in 0..48 {
            for u in 0..64 {
                let i = v * 64 + u;
                assert_eq!(t.id[i], 7);
                // ray through (u, v) meets the plane where z = 2 + 0.3 * x, x = (u-cx)/fx * z
                let xn = (u as f64 - cam.cx) / cam.fx;
                let z = 2.0 / (1.0 - 0.3 * xn);
                assert!(
                    (t.depth[i] as f64 - z).abs() < 1e-6,
                    "{} vs {z}",
                    t.depth[i]
                );
            }
        }
    }

    #[test]
    fn near_plane_clipping_keeps_the_visible_part() {
        let cam = PinholeCamera::new(50.0, 50.0, 15.5, 15.5, 32, 32);
        let mut mesh = Mesh::default();
        // floor-like quad y = 0.5 running from behind the camera to z = 5
        mesh.quad(
            [
                P3::new(-3.0, 0.5, -1.0),
                P3::new(3.0, 0.5, -1.0),
                P3::new(3.0, 0.5, 5.0),
                P3::new(-3.0, 0.5, 5.0),
            ],
            0,
            [0.0, 0.0],
            [1.0, 1.0],
        );
        let mut t = Target::new(32, 32);
        let items = [DrawItem {
            mesh: &mesh,
            t_cp: Isometry3::identity(),
            r_wp: nalgebra::UnitQuaternion::identity(),
            id: 1,
        }];
        draw(&mut t, &cam, &items, &flat_texture());
        // rows below the horizon see the floor, at z = 0.5 * fy / (v - cy)
        for v in 17..32 {
            let z = 0.5 * 50.0 / (v as f64 - 15.5);
            let d = t.depth[v * 32 + 16] as f64;
            if z <= 5.0 {
                assert!((d - z).abs() < 1e-5, "row {v}: {d} vs {z}");
            }
        }
        assert!(t.depth[5 * 32 + 16].is_infinite());
        let mut scratch = vec![false; 32 * 32];
        let n = coverage(
            &mut scratch,
            32,
            32,
            &cam,
            &items,
            &flatten(&flat_texture()),
        );
        assert_eq!(n, t.id.iter().filter(|&&i| i == 1).count());
        assert!(scratch.iter().all(|&b| !b));
    }

    #[test]
    fn antialiasing_blends_edge_pixels_and_keeps_depth_and_ids_of_the_centre() {
        let cam = PinholeCamera::new(50.0, 50.0, 15.5, 15.5, 32, 32);
        // A wall at z = 2 whose right edge projects to u = 10.3: pixel 10 (9.5..10.5) is 80 %
        // covered, and two of its three sample columns (9.67, 10.0, 10.33) fall on the wall.
        let x_edge = (10.3 - 15.5) * 2.0 / 50.0;
        let mut mesh = Mesh::default();
        mesh.quad(
            [
                P3::new(-3.0, -3.0, 2.0),
                P3::new(x_edge, -3.0, 2.0),
                P3::new(x_edge, 3.0, 2.0),
                P3::new(-3.0, 3.0, 2.0),
            ],
            0,
            [0.0, 0.0],
            [1.0, 1.0],
        );
        let items = [DrawItem {
            mesh: &mesh,
            t_cp: Isometry3::identity(),
            r_wp: nalgebra::UnitQuaternion::identity(),
            id: 3,
        }];
        let tex = flat_texture();
        let mut point = Target::new(32, 32);
        draw(&mut point, &cam, &items, &tex);
        let mut one = Target::new(32, 32);
        draw_antialiased(&mut one, &cam, &items, &tex, 1);
        assert_eq!((&one.rgb, &one.id), (&point.rgb, &point.id));
        let mut aa = Target::new(32, 32);
        draw_antialiased(&mut aa, &cam, &items, &tex, 3);
        assert_eq!(aa.id, point.id);
        assert!(
            aa.depth
                .iter()
                .zip(&point.depth)
                .all(|(a, b)| a == b || (a.is_infinite() && b.is_infinite()))
        );
        let at = |t: &Target, u: usize| t.rgb[16 * 32 + u][0] as i32;
        let wall = at(&point, 5);
        assert!(wall > 30, "the wall is lit: {wall}");
        assert_eq!(at(&aa, 5), wall);
        assert_eq!((at(&point, 10), at(&point, 11)), (wall, 0));
        assert!(
            (at(&aa, 10) - 2 * wall / 3).abs() <= 1,
            "{} vs 2/3 of {wall}",
            at(&aa, 10)
        );
        assert_eq!(at(&aa, 11), 0);
    }

    fn flatten(t: &[Texture]) -> Vec<Texture> {
        t.to_vec()
    }
}
