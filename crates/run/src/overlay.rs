//! Per-frame pictures of what the front-end did, in the style of the paper's figures 4 and 6:
//! keypoints kept for tracking green (matched to the map) or yellow (kept, unmatched), culled
//! red, and each object in view boxed red when judged moving, green when static.

use std::path::Path;

use stillpoint_datasets::Frame;
use stillpoint_detect::draw::{draw_box, draw_dot};
use stillpoint_image::Rgb8;
use stillpoint_pipeline::FrameResult;

/// Colour of a kept keypoint matched to a map point.
pub const MATCHED: [u8; 3] = [0, 220, 0];
/// Colour of a kept keypoint tracking did not match.
pub const KEPT: [u8; 3] = [230, 200, 0];
/// Colour of a culled keypoint, and of a moving object's box.
pub const CULLED: [u8; 3] = [255, 0, 0];
/// Colour of a static object's box.
pub const STATIC: [u8; 3] = [0, 160, 255];

/// The frame's colour image (or its gray one) with its keypoints and objects drawn on it.
pub fn draw_overlay(frame: &Frame, result: &FrameResult) -> Rgb8 {
    let mut img = match &frame.rgb {
        Some(rgb) => rgb.clone(),
        None => {
            let g = &frame.gray;
            let data = g.data.iter().map(|&v| [v, v, v]).collect();
            Rgb8::from_vec(g.width, g.height, data).unwrap_or_else(|_| Rgb8::new(1, 1, [0; 3]))
        }
    };
    for o in &result.objects.tracked {
        let (colour, state) = if o.moving {
            (CULLED, "moving")
        } else {
            (STATIC, "static")
        };
        let label = format!(
            "{} {state}",
            stillpoint_detect::classes::class_name(o.class_id)
        );
        draw_box(&mut img, &o.bbox, colour, &label);
    }
    for (i, k) in result.keypoints.iter().enumerate() {
        let colour = if result.dynamic.get(i).copied().unwrap_or(false) {
            CULLED
        } else if result.matched.get(i).copied().unwrap_or(false) {
            MATCHED
        } else {
            KEPT
        };
        draw_dot(&mut img, k[0], k[1], 1, colour);
    }
    img
}

/// The overlay's file for frame `index` in `dir`.
pub fn overlay_path(dir: &Path, index: usize) -> std::path::PathBuf {
    dir.join(format!("{index:06}.png"))
}
