//! What the projected-scene tests share: the scene (3D points with descriptors) and its
//! observation by a camera (keypoints with +-0.3 px noise, depth, descriptors with 3 bits flipped).

use rand::{Rng, SeedableRng};
use stillpoint_geometry::{PinholeCamera, Se3, Vec3, umeyama};
use stillpoint_image::DepthMetres;
use stillpoint_slam::{Descriptor, Feature};

/// Points and their descriptors.
pub struct Scene {
    pub points: Vec<Vec3>,
    pub descriptors: Vec<Descriptor>,
}

/// `n` points drawn by `point` from a generator seeded with `seed`, each with a random
/// descriptor drawn after it.
pub fn scene_of(seed: u64, n: usize, mut point: impl FnMut(&mut rand_pcg::Pcg64) -> Vec3) -> Scene {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let (mut points, mut descriptors) = (Vec::new(), Vec::new());
    for _ in 0..n {
        points.push(point(&mut rng));
        let mut d = [0u8; 32];
        rng.fill(&mut d[..]);
        descriptors.push(d);
    }
    Scene {
        points,
        descriptors,
    }
}

/// Points on the four walls of a 5 x 5 m room (y is down, the camera height is 0).
#[allow(dead_code)] // not every test binary that includes this module uses it
pub fn room(seed: u64, n: usize) -> Scene {
    scene_of(seed, n, |rng| {
        let along = rng.random_range(-2.5..2.5);
        let y = rng.random_range(-1.2..1.2);
        match rng.random_range(0..4) {
            0 => Vec3::new(along, y, 2.5),
            1 => Vec3::new(along, y, -2.5),
            2 => Vec3::new(2.5, y, along),
            _ => Vec3::new(-2.5, y, along),
        }
    })
}

/// The scene's points seen from `pose_wc`: features, descriptors and a sparse depth image.
#[allow(dead_code)] // not every test file uses it
pub fn observe(
    sc: &Scene,
    pose_wc: &Se3,
    cam: &PinholeCamera,
    rng: &mut impl Rng,
) -> (Vec<Feature>, Vec<Descriptor>, DepthMetres) {
    observe_with_noise(sc, pose_wc, cam, rng, 0.3)
}

/// As [`observe`], keypoints off by up to `noise_px` in each direction.
#[allow(dead_code)] // not every test file uses it
pub fn observe_with_noise(
    sc: &Scene,
    pose_wc: &Se3,
    cam: &PinholeCamera,
    rng: &mut impl Rng,
    noise_px: f64,
) -> (Vec<Feature>, Vec<Descriptor>, DepthMetres) {
    let mut depth = DepthMetres::new(cam.width as usize, cam.height as usize, 0.0);
    let (mut f, mut d) = (Vec::new(), Vec::new());
    let pose_cw = pose_wc.inverse();
    for (p, desc) in sc.points.iter().zip(&sc.descriptors) {
        let pc = (pose_cw * nalgebra::Point3::from(*p)).coords;
        let Some(px) = cam.project(&pc) else { continue };
        if !cam.in_image(&px, 2.0) {
            continue;
        }
        let x = px.x + rng.random_range(-noise_px..noise_px);
        let y = px.y + rng.random_range(-noise_px..noise_px);
        let (xi, yi) = (x.round() as usize, y.round() as usize);
        if xi >= depth.width || yi >= depth.height {
            continue;
        }
        depth.set(xi, yi, pc.z as f32);
        let mut desc = *desc;
        for _ in 0..3 {
            let b = rng.random_range(0..256);
            desc[b / 8] ^= 1 << (b % 8);
        }
        f.push(Feature {
            x: x as f32,
            y: y as f32,
            octave: 0,
            angle: 0.0,
        });
        d.push(desc);
    }
    (f, d, depth)
}

/// ATE RMSE of positions `est` against `truth` after the best rigid alignment (with a scale,
/// Sim(3), when `with_scale`: a monocular map has its own).
#[allow(dead_code)] // not every test file uses it
pub fn ate_rmse(est: &[Vec3], truth: &[Vec3], with_scale: bool) -> f64 {
    let align = umeyama(est, truth, with_scale).expect("alignment");
    let sse: f64 = est
        .iter()
        .zip(truth)
        .map(|(e, g)| (align.transform_point(e) - g).norm_squared())
        .sum();
    (sse / est.len() as f64).sqrt()
}
