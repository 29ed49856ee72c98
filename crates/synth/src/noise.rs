//! Kinect-like sensor noise: depth noise growing with z², dropouts at depth edges, random holes,
//! a limited range, and image noise.

use rand::Rng;
use rand_pcg::Pcg64Mcg;

/// Noise parameters (defaults after Nguyen, Izadi & Lovell 2012, "Modeling Kinect sensor noise",
/// and Khoshelham & Elberink 2012).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KinectNoise {
    /// Axial noise sigma = a + b (z - c)^2 metres (Nguyen et al.: 0.0012, 0.0019, 0.4).
    pub sigma_a: f32,
    /// `b` of the axial sigma above, metres per square metre.
    pub sigma_b: f32,
    /// `c` of the axial sigma above, metres.
    pub sigma_c: f32,
    /// Valid range in metres (Kinect v1: about 0.4 to 5-6 m).
    pub min_depth: f32,
    /// Farthest valid depth, metres; beyond it depth is 0.
    pub max_depth: f32,
    /// A pixel next to a depth jump larger than this fraction of its depth is dropped with
    /// probability `edge_dropout` (shadowing and mixed pixels at object borders).
    pub edge_jump: f32,
    /// Probability that a pixel at such a jump is dropped.
    pub edge_dropout: f64,
    /// Random elliptical holes per frame (specular or dark surfaces), radius range in pixels.
    pub holes: usize,
    /// Hole radius range (min, max), pixels.
    pub hole_radius: [f32; 2],
    /// Image noise sigma in grey levels per channel.
    pub image_sigma: f32,
}

impl Default for KinectNoise {
    fn default() -> Self {
        Self {
            sigma_a: 0.0012,
            sigma_b: 0.0019,
            sigma_c: 0.4,
            min_depth: 0.4,
            max_depth: 5.5,
            edge_jump: 0.04,
            edge_dropout: 0.7,
            holes: 4,
            hole_radius: [2.0, 12.0],
            image_sigma: 2.0,
        }
    }
}

/// A standard normal sample (Box-Muller).
pub fn gaussian(rng: &mut Pcg64Mcg) -> f32 {
    gaussian_pair(rng)[0]
}

/// Two independent standard normal samples from one Box-Muller draw (cos and sin branch).
pub fn gaussian_pair(rng: &mut Pcg64Mcg) -> [f32; 2] {
    let u1: f64 = rng.random_range(f64::MIN_POSITIVE..1.0);
    let u2: f64 = rng.random();
    let r = (-2.0 * u1.ln()).sqrt();
    let (s, c) = (std::f64::consts::TAU * u2).sin_cos();
    [(r * c) as f32, (r * s) as f32]
}

/// Standard normal samples, using both outputs of each Box-Muller draw.
struct Gaussians {
    spare: Option<f32>,
}

impl Gaussians {
    fn new() -> Self {
        Self { spare: None }
    }

    #[inline]
    fn next(&mut self, rng: &mut Pcg64Mcg) -> f32 {
        if let Some(g) = self.spare.take() {
            return g;
        }
        let [a, b] = gaussian_pair(rng);
        self.spare = Some(b);
        a
    }
}

/// Degrade a depth map (metres, 0 = none) in place.
pub fn apply_depth(
    depth: &mut [f32],
    width: usize,
    height: usize,
    p: &KinectNoise,
    rng: &mut Pcg64Mcg,
) {
    let exact = depth.to_vec();
    let mut normal = Gaussians::new();
    for y in 0..height {
        for x in 0..width {
            let i = y * width + x;
            let z = exact[i];
            if !(z >= p.min_depth && z <= p.max_depth) {
                depth[i] = 0.0;
                continue;
            }
            let mut edge = false;
            for (dx, dy) in [(-1i32, 0i32), (1, 0), (0, -1), (0, 1)] {
                let (nx, ny) = (x as i32 + dx, y as i32 + dy);
                if nx >= 0 && ny >= 0 && (nx as usize) < width && (ny as usize) < height {
                    let zn = exact[ny as usize * width + nx as usize];
                    if zn > 0.0 && (zn - z).abs() > p.edge_jump * z {
                        edge = true;
                    }
                }
            }
            if edge && rng.random_bool(p.edge_dropout) {
                depth[i] = 0.0;
                continue;
            }
            let s = p.sigma_a + p.sigma_b * (z - p.sigma_c).powi(2);
            depth[i] = z + s * normal.next(rng);
        }
    }
    for _ in 0..p.holes {
        let cx = rng.random_range(0.0..width as f32);
        let cy = rng.random_range(0.0..height as f32);
        let rx = rng.random_range(p.hole_radius[0]..p.hole_radius[1]);
        let ry = rng.random_range(p.hole_radius[0]..p.hole_radius[1]);
        let (y0, y1) = (
            (cy - ry).max(0.0) as usize,
            ((cy + ry) as usize).min(height.saturating_sub(1)),
        );
        let (x0, x1) = (
            (cx - rx).max(0.0) as usize,
            ((cx + rx) as usize).min(width.saturating_sub(1)),
        );
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (dx, dy) = ((x as f32 - cx) / rx, (y as f32 - cy) / ry);
                if dx * dx + dy * dy <= 1.0 {
                    depth[y * width + x] = 0.0;
                }
            }
        }
    }
}

/// Add Gaussian noise to every channel.
pub fn apply_image(rgb: &mut [[u8; 3]], sigma: f32, rng: &mut Pcg64Mcg) {
    if sigma <= 0.0 {
        return;
    }
    let mut normal = Gaussians::new();
    for p in rgb.iter_mut() {
        for c in p.iter_mut() {
            *c = (*c as f32 + sigma * normal.next(rng))
                .round()
                .clamp(0.0, 255.0) as u8;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn depth_noise_grows_with_depth_and_drops_edges() {
        let (w, h) = (64, 32);
        let mut d: Vec<f32> = (0..w * h)
            .map(|i| if i % w < 32 { 1.0 } else { 4.0 })
            .collect();
        let p = KinectNoise {
            holes: 0,
            ..Default::default()
        };
        apply_depth(&mut d, w, h, &p, &mut Pcg64Mcg::seed_from_u64(1));
        let err = |range: std::ops::Range<usize>, z: f32| {
            let v: Vec<f32> = (0..h)
                .flat_map(|y| range.clone().map(move |x| y * w + x))
                .map(|i| d[i])
                .filter(|&v| v > 0.0)
                .map(|v| (v - z).powi(2))
                .collect();
            (v.iter().sum::<f32>() / v.len() as f32).sqrt()
        };
        let (near, far) = (err(0..30, 1.0), err(34..64, 4.0));
        assert!(near < 0.004 && far > 0.015 && far < 0.04, "{near} {far}");
        let dropped = (0..h)
            .filter(|y| d[y * w + 31] == 0.0 || d[y * w + 32] == 0.0)
            .count();
        assert!(dropped > h / 2);
    }
}
