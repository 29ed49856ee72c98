//! Stereo rectification maps, as OpenCV's `initUndistortRectifyMap` computes them: for every
//! pixel of a rectified image, the raw (distorted) pixel it samples, from the raw camera (K, D),
//! the rectifying rotation R and the rectified projection P. ORB-SLAM's stereo settings carry
//! exactly these (`LEFT.K`, `LEFT.D`, `LEFT.R`, `LEFT.P`, `RIGHT.*`) for cameras whose images
//! are not rectified (EuRoC); after rectification epipolar lines are image rows, which is what
//! stereo matching searches along.

use crate::{Mat3, PinholeCamera, Vec2, Vec3};
use serde::{Deserialize, Serialize};

/// One camera of a stereo pair to rectify.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RectifyingView {
    /// The camera as recorded: intrinsics and distortion of the raw images.
    pub raw: PinholeCamera,
    /// Rotation from the raw camera's frame into the rectified frame (row-major).
    pub r: [[f64; 3]; 3],
    /// Projection matrix of the rectified camera (row-major 3x4); the right camera's fourth
    /// column is (-fx * baseline, 0, 0).
    pub p: [[f64; 4]; 3],
}

impl RectifyingView {
    fn rotation(&self) -> Mat3 {
        Mat3::from_fn(|i, j| self.r[i][j])
    }

    fn new_k(&self) -> Mat3 {
        Mat3::from_fn(|i, j| self.p[i][j])
    }

    /// The raw pixel that the rectified pixel (u, v) samples (`initUndistortRectifyMap`):
    /// the ray through (u, v) of the rectified camera, rotated back into the raw camera and
    /// distorted. `None` for a ray that points behind the raw camera or a singular setup.
    pub fn raw_pixel(&self, u: f64, v: f64) -> Option<Vec2> {
        self.raw_pixel_by(&self.pixel_to_raw_ray()?, u, v)
    }

    /// (P R)^-1: a rectified pixel to a ray in the raw camera's frame.
    fn pixel_to_raw_ray(&self) -> Option<Mat3> {
        (self.new_k() * self.rotation()).try_inverse()
    }

    fn raw_pixel_by(&self, to_ray: &Mat3, u: f64, v: f64) -> Option<Vec2> {
        let ray = to_ray * Vec3::new(u, v, 1.0);
        if ray.z.is_nan() || ray.z <= 1e-12 {
            return None;
        }
        let (xd, yd) = self.raw.distortion.distort(ray.x / ray.z, ray.y / ray.z);
        Some(Vec2::new(
            self.raw.fx * xd + self.raw.cx,
            self.raw.fy * yd + self.raw.cy,
        ))
    }

    /// The rectified pixel of a raw pixel: undistorted, rotated into the rectified frame and
    /// projected with P (the inverse of [`Self::raw_pixel`]).
    pub fn rectified_pixel(&self, raw: &Vec2) -> Option<Vec2> {
        let c = &self.raw;
        let (x, y) = c
            .distortion
            .undistort((raw.x - c.cx) / c.fx, (raw.y - c.cy) / c.fy);
        let q = self.new_k() * self.rotation() * Vec3::new(x, y, 1.0);
        (q.z > 1e-12).then(|| Vec2::new(q.x / q.z, q.y / q.z))
    }

    /// The rectified camera: P's intrinsics, no distortion, the raw image's size.
    pub fn rectified_camera(&self) -> PinholeCamera {
        let p = &self.p;
        PinholeCamera::new(
            p[0][0],
            p[1][1],
            p[0][2],
            p[1][2],
            self.raw.width,
            self.raw.height,
        )
    }

    /// For every pixel of the rectified image (the raw size, row-major), the raw pixel it
    /// samples; (-1, -1) where no raw pixel does.
    pub fn map(&self) -> Vec<[f32; 2]> {
        let (w, h) = (self.raw.width as usize, self.raw.height as usize);
        let Some(to_ray) = self.pixel_to_raw_ray() else {
            return vec![[-1.0, -1.0]; w * h];
        };
        let mut out = Vec::with_capacity(w * h);
        for v in 0..h {
            for u in 0..w {
                out.push(
                    self.raw_pixel_by(&to_ray, u as f64, v as f64)
                        .map_or([-1.0, -1.0], |q| [q.x as f32, q.y as f32]),
                );
            }
        }
        out
    }
}

/// A stereo pair to rectify (ORB-SLAM's `LEFT.*` and `RIGHT.*`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StereoRectification {
    /// The left camera.
    pub left: RectifyingView,
    /// The right camera.
    pub right: RectifyingView,
}

impl StereoRectification {
    /// Baseline times fx of the rectified pair (ORB-SLAM's `Camera.bf`): minus the fourth
    /// entry of the right projection's first row.
    pub fn bf(&self) -> f64 {
        -self.right.p[0][3]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::RadTan;

    /// ORB-SLAM2's EuRoC stereo settings (`LEFT.*`, `RIGHT.*`).
    fn euroc() -> StereoRectification {
        let raw = |k: [f64; 4], d: [f64; 4]| PinholeCamera {
            distortion: RadTan {
                k1: d[0],
                k2: d[1],
                p1: d[2],
                p2: d[3],
                k3: 0.0,
            },
            ..PinholeCamera::new(k[0], k[1], k[2], k[3], 752, 480)
        };
        let (f, cx, cy) = (435.2046959714599, 367.4517211914062, 252.2008514404297);
        StereoRectification {
            left: RectifyingView {
                raw: raw(
                    [458.654, 457.296, 367.215, 248.375],
                    [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05],
                ),
                r: [
                    [
                        0.999966347530033,
                        -0.001422739138722922,
                        0.008079580483432283,
                    ],
                    [
                        0.001365741834644127,
                        0.9999741760894847,
                        0.007055629199258132,
                    ],
                    [
                        -0.008089410156878961,
                        -0.007044357138835809,
                        0.9999424675829176,
                    ],
                ],
                p: [[f, 0.0, cx, 0.0], [0.0, f, cy, 0.0], [0.0, 0.0, 1.0, 0.0]],
            },
            right: RectifyingView {
                raw: raw(
                    [457.587, 456.134, 379.999, 255.238],
                    [-0.28368365, 0.07451284, -0.00010473, -3.555907e-05],
                ),
                r: [
                    [
                        0.9999633526194376,
                        -0.003625811871560086,
                        0.007755443660172947,
                    ],
                    [
                        0.003680398547259526,
                        0.9999684752771629,
                        -0.007035845251224894,
                    ],
                    [
                        -0.007729688520722713,
                        0.007064130529506649,
                        0.999945173484644,
                    ],
                ],
                p: [
                    [f, 0.0, cx, -47.90639384423901],
                    [0.0, f, cy, 0.0],
                    [0.0, 0.0, 1.0, 0.0],
                ],
            },
        }
    }

    /// A point in the rectified left frame seen by the raw cameras: the raw frames are the
    /// rectified ones rotated back (R^T), the right one shifted by the baseline.
    fn raw_views(s: &StereoRectification, x: Vec3) -> (Vec2, Vec2) {
        let b = s.bf() / s.left.p[0][0];
        let left = s.left.rotation().transpose() * x;
        let right = s.right.rotation().transpose() * (x - Vec3::new(b, 0.0, 0.0));
        (
            s.left.raw.project(&left).unwrap(),
            s.right.raw.project(&right).unwrap(),
        )
    }

    #[test]
    fn rectified_views_of_a_point_share_a_row_and_show_its_disparity() {
        let s = euroc();
        let cam = s.left.rectified_camera();
        assert!((s.bf() - 47.90639384423901).abs() < 1e-12);
        for (k, &(x, y, z)) in [
            (0.3, -0.2, 2.0),
            (-0.8, 0.5, 3.5),
            (0.05, 0.02, 0.9),
            (1.5, 0.9, 6.0),
        ]
        .iter()
        .enumerate()
        {
            let p = Vec3::new(x, y, z);
            let (raw_l, raw_r) = raw_views(&s, p);
            let l = s.left.rectified_pixel(&raw_l).unwrap();
            let r = s.right.rectified_pixel(&raw_r).unwrap();
            let expect = cam.project_undistorted(&p).unwrap();
            assert!((l - expect).norm() < 1e-6, "point {k}: {l:?} vs {expect:?}");
            assert!(
                (l.y - r.y).abs() < 1e-6,
                "point {k}: rows {} vs {}",
                l.y,
                r.y
            );
            assert!(
                (l.x - r.x - s.bf() / z).abs() < 1e-6,
                "point {k}: disparity"
            );
            // The map goes the other way: rectified pixel -> the raw pixel it samples.
            assert!((s.left.raw_pixel(l.x, l.y).unwrap() - raw_l).norm() < 1e-6);
            assert!((s.right.raw_pixel(r.x, r.y).unwrap() - raw_r).norm() < 1e-6);
        }
    }

    #[test]
    fn the_map_samples_inside_the_raw_image_away_from_its_corners() {
        let s = euroc();
        let map = s.left.map();
        assert_eq!(map.len(), 752 * 480);
        let at = |u: usize, v: usize| map[v * 752 + u];
        // The rectified principal point's ray is R's third row in the raw frame, (-0.0081,
        // -0.0070, 1): 3.7 px left of and 3.2 px above the raw principal point (367.2, 248.4).
        let c = at(367, 252);
        assert!(
            (c[0] - 363.5).abs() < 0.6 && (c[1] - 245.2).abs() < 0.6,
            "{c:?}"
        );
        let inside = map
            .iter()
            .filter(|q| q[0] >= 0.0 && q[1] >= 0.0 && q[0] <= 751.0 && q[1] <= 479.0)
            .count();
        assert!(inside * 100 > map.len() * 95, "{inside} of {}", map.len());
        // Identity rectification of an undistorted camera maps every pixel to itself.
        let id = RectifyingView {
            raw: PinholeCamera::new(400.0, 400.0, 15.5, 11.5, 32, 24),
            r: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            p: [
                [400.0, 0.0, 15.5, 0.0],
                [0.0, 400.0, 11.5, 0.0],
                [0.0, 0.0, 1.0, 0.0],
            ],
        };
        for (i, q) in id.map().iter().enumerate() {
            let (u, v) = ((i % 32) as f32, (i / 32) as f32);
            assert!((q[0] - u).abs() < 1e-4 && (q[1] - v).abs() < 1e-4);
        }
    }
}
