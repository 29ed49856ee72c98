//! What the projected-scene tests share: the scene (3D points with descriptors) and its
//! observation by a camera (keypoints with +-0.3 px noise, depth, descriptors with 3 bits flipped).

use rand::Rng;
use stillpoint_geometry::{PinholeCamera, Se3, Vec3};
use stillpoint_image::DepthMetres;
use stillpoint_slam::{Descriptor, Feature};

/// Points and their descriptors.
pub struct Scene {
    pub points: Vec<Vec3>,
    pub descriptors: Vec<Descriptor>,
}

/// The scene's points seen from `pose_wc`: features, descriptors and a sparse depth image.
pub fn observe(
    sc: &Scene,
    pose_wc: &Se3,
    cam: &PinholeCamera,
    rng: &mut impl Rng,
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
        let x = px.x + rng.random_range(-0.3..0.3);
        let y = px.y + rng.random_range(-0.3..0.3);
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
