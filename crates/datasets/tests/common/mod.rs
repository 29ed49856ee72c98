//! The small recording both reader tests write: a 32x24 colour pattern with depth, its camera
//! and topics.

use stillpoint_datasets::Frame;
use stillpoint_datasets::mcap::McapTopics;
use stillpoint_geometry::PinholeCamera;
use stillpoint_image::{DepthMetres, ImageBuf, Rgb8, rgb_to_gray};

pub const W: usize = 32;
pub const H: usize = 24;

/// Colour on `rgb`, depth on /camera/depth/image_raw, the camera info beside the colour.
pub fn topics_named(rgb: &str) -> McapTopics {
    McapTopics {
        rgb: rgb.into(),
        depth: Some("/camera/depth/image_raw".into()),
        right: None,
        camera_info: None,
    }
}

/// The camera, with a little distortion.
pub fn camera() -> PinholeCamera {
    let mut c = PinholeCamera::new(30.5, 31.0, 15.5, 11.25, W as u32, H as u32);
    c.distortion.k1 = 0.01;
    c
}

/// Frame i: a colour pattern and depth in whole millimetres, at 30 Hz from a Unix time.
pub fn frame(i: usize) -> Frame {
    let rgb: Rgb8 = ImageBuf::from_vec(
        W,
        H,
        (0..W * H)
            .map(|p| [(p + i) as u8, (p * 3) as u8, (i * 7) as u8])
            .collect(),
    )
    .unwrap();
    let depth: DepthMetres = ImageBuf::from_vec(
        W,
        H,
        (0..W * H)
            .map(|p| {
                if p % 11 == 0 {
                    0.0
                } else {
                    (500 + p + i) as f32 / 1000.0
                }
            })
            .collect(),
    )
    .unwrap();
    Frame {
        index: i,
        timestamp: 1_700_000_000.0 + i as f64 / 30.0,
        gray: rgb_to_gray(&rgb),
        rgb: Some(rgb),
        depth: Some(depth),
        right: None,
    }
}
