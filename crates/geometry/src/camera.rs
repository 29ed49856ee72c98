//! Pinhole camera with radial-tangential (OpenCV "plumb bob") distortion.

use crate::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

/// Radial-tangential distortion coefficients k1 k2 p1 p2 k3, OpenCV's order.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RadTan {
    /// Radial, r^2.
    pub k1: f64,
    /// Radial, r^4.
    pub k2: f64,
    /// Tangential, first.
    pub p1: f64,
    /// Tangential, second.
    pub p2: f64,
    /// Radial, r^6.
    pub k3: f64,
}

impl RadTan {
    /// True when every coefficient is zero (undistortion is the identity).
    pub fn is_zero(&self) -> bool {
        [self.k1, self.k2, self.p1, self.p2, self.k3]
            .iter()
            .all(|&c| c == 0.0)
    }

    /// Distort normalised coordinates (x, y) = (X/Z, Y/Z).
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        (xd, yd)
    }

    /// Undistort normalised coordinates by fixed-point iteration (as OpenCV's
    /// `undistortPoints`, which ORB-SLAM uses), 20 iterations.
    pub fn undistort(&self, xd: f64, yd: f64) -> (f64, f64) {
        if self.is_zero() {
            return (xd, yd);
        }
        let (mut x, mut y) = (xd, yd);
        for _ in 0..20 {
            let r2 = x * x + y * y;
            let icdist = 1.0 / (1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3)));
            let dx = 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
            let dy = self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
            x = (xd - dx) * icdist;
            y = (yd - dy) * icdist;
        }
        (x, y)
    }
}

/// A pinhole camera: focal lengths and principal point in pixels, image size, distortion.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PinholeCamera {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point, x.
    pub cx: f64,
    /// Principal point, y.
    pub cy: f64,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Lens distortion (zero for rectified or synthetic images).
    #[serde(default)]
    pub distortion: RadTan,
}

impl PinholeCamera {
    /// A camera without distortion.
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64, width: u32, height: u32) -> Self {
        Self {
            fx,
            fy,
            cx,
            cy,
            width,
            height,
            distortion: RadTan::default(),
        }
    }

    /// The intrinsic matrix K.
    pub fn k(&self) -> crate::Mat3 {
        crate::Mat3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// Project a point in camera coordinates to a (distorted) pixel. `None` behind the camera.
    pub fn project(&self, p: &Vec3) -> Option<Vec2> {
        if p.z.is_nan() || p.z <= 1e-9 {
            return None;
        }
        let (x, y) = self.distortion.distort(p.x / p.z, p.y / p.z);
        Some(Vec2::new(self.fx * x + self.cx, self.fy * y + self.cy))
    }

    /// Project ignoring distortion (for undistorted keypoints).
    pub fn project_undistorted(&self, p: &Vec3) -> Option<Vec2> {
        if p.z.is_nan() || p.z <= 1e-9 {
            return None;
        }
        Some(Vec2::new(
            self.fx * p.x / p.z + self.cx,
            self.fy * p.y / p.z + self.cy,
        ))
    }

    /// Undistort a pixel: the pixel an ideal (distortion-free) camera with the same K would see.
    pub fn undistort_pixel(&self, px: &Vec2) -> Vec2 {
        let (x, y) = self
            .distortion
            .undistort((px.x - self.cx) / self.fx, (px.y - self.cy) / self.fy);
        Vec2::new(self.fx * x + self.cx, self.fy * y + self.cy)
    }

    /// Back-project an undistorted pixel at depth `z` (along the optical axis) to camera coordinates.
    pub fn unproject(&self, px: &Vec2, z: f64) -> Vec3 {
        Vec3::new(
            (px.x - self.cx) / self.fx * z,
            (px.y - self.cy) / self.fy * z,
            z,
        )
    }

    /// True when the pixel lies inside the image (with a margin of `border` pixels).
    pub fn in_image(&self, px: &Vec2, border: f64) -> bool {
        px.x >= border
            && px.y >= border
            && px.x < self.width as f64 - border
            && px.y < self.height as f64 - border
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn cam() -> PinholeCamera {
        let mut c = PinholeCamera::new(517.3, 516.5, 318.6, 255.3, 640, 480);
        c.distortion = RadTan {
            k1: 0.2624,
            k2: -0.9531,
            p1: -0.0054,
            p2: 0.0026,
            k3: 1.1633,
        };
        c
    }

    proptest! {
        #[test]
        fn undistort_inverts_distort(u in 20.0f64..620.0, v in 20.0f64..460.0) {
            let c = cam();
            let ideal = Vec2::new(u, v);
            let p = c.unproject(&ideal, 2.0);
            let distorted = c.project(&p).unwrap();
            let back = c.undistort_pixel(&distorted);
            prop_assert!((back - ideal).norm() < 1e-3, "{back:?} vs {ideal:?}");
        }
    }

    #[test]
    fn project_unproject_roundtrip_and_behind_camera() {
        let c = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
        let p = Vec3::new(0.3, -0.2, 2.5);
        let px = c.project(&p).unwrap();
        assert!((c.unproject(&px, 2.5) - p).norm() < 1e-12);
        assert!(c.project(&Vec3::new(0.0, 0.0, -1.0)).is_none());
        assert!(c.project(&Vec3::new(0.0, 0.0, f64::NAN)).is_none());
    }
}
