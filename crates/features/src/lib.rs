//! stillpoint-features: the two front-ends that run on every frame.
//!
//! * ORB features for SLAM, extracted the way ORB-SLAM3 does it ([`OrbExtractor`]): 8-level
//!   pyramid at 1.2, features per level as a geometric series, FAST on ~35 px cells at threshold
//!   20 falling back to 7, quadtree distribution, intensity-centroid orientation and 256-bit
//!   steered BRIEF on a Gaussian-blurred level. Matching: [`hamming`], [`match_brute_force`]
//!   (ratio test + mutual check), [`KeypointGrid`] for search by projection, and
//!   [`RotationHistogram`] for ORB-SLAM's rotation consistency.
//! * Corners and flow for the motion-consistency check: [`good_features_to_track`] (Harris or
//!   Shi-Tomasi + sub-pixel refinement, like OpenCV's `goodFeaturesToTrack` + `cornerSubPix`) and
//!   pyramidal Lucas-Kanade [`track_lk`] (like OpenCV's `calcOpticalFlowPyrLK`).
//!
//! Every function takes a [`Gray8`]; colour and 16-bit images are converted with [`to_gray8`]
//! / [`gray_from_u16`]. Blank or tiny images give empty results, never a panic.
//!
//! ```
//! use stillpoint_features::{OrbExtractor, OrbParams, hamming};
//! use stillpoint_image::Gray8;
//! // a textured synthetic image
//! let mut img = Gray8::new(160, 120, 0);
//! for y in 0..120 { for x in 0..160 {
//!     img.set(x, y, (((x / 7) * 37 + (y / 5) * 91 + (x * y) % 13) % 256) as u8);
//! }}
//! let mut orb = OrbExtractor::new(OrbParams { n_features: 200, ..OrbParams::default() });
//! let f = orb.extract(&img);
//! assert_eq!(f.keypoints.len(), f.descriptors.len());
//! assert!(!f.keypoints.is_empty());
//! assert_eq!(hamming(&f.descriptors[0], &f.descriptors[0]), 0);
//! ```

mod corners;
mod fast;
mod imgops;
mod lk;
mod matcher;
mod orb;
mod pattern;

pub use corners::{CornerParams, corner_sub_pix, good_features_to_track};
pub use lk::{LkParams, LkPyramid, forward_backward_errors, track_lk, track_lk_pyramids};
pub use matcher::{
    KeypointGrid, Match, MatchParams, Projected, ProjectionParams, RotationHistogram, hamming,
    match_brute_force, match_keypoints, search_by_projection,
};
pub use orb::{KeyPoint, OrbExtractor, OrbFeatures, OrbParams, OrbScore, OrbTimings};
pub use stillpoint_image::{Gray8, rgb_to_gray};

/// A 256-bit binary descriptor (ORB).
pub type Descriptor = [u8; 32];

/// Errors of this crate (the feature functions themselves never fail: bad input gives empty
/// output; these are for the helpers that validate input).
#[derive(Debug, thiserror::Error)]
pub enum FeaturesError {
    #[error("{file}:{line}: {what}")]
    BadInput {
        file: &'static str,
        line: u32,
        what: String,
    },
}

/// Convert a 16-bit image to 8 bits by its own range (min → 0, max → 255), so depth-like or
/// 12-bit camera data keeps its contrast; a constant image becomes 0.
///
/// ```
/// use stillpoint_image::ImageBuf;
/// let img = ImageBuf::from_vec(3, 1, vec![1000u16, 2000, 3000]).unwrap();
/// assert_eq!(stillpoint_features::gray_from_u16(&img).data, vec![0, 128, 255]);
/// ```
pub fn gray_from_u16(img: &stillpoint_image::ImageBuf<u16>) -> Gray8 {
    let lo = img.data.iter().copied().min().unwrap_or(0) as f32;
    let hi = img.data.iter().copied().max().unwrap_or(0) as f32;
    let scale = if hi > lo { 255.0 / (hi - lo) } else { 0.0 };
    Gray8 {
        width: img.width,
        height: img.height,
        data: img
            .data
            .iter()
            .map(|&v| ((v as f32 - lo) * scale).round() as u8)
            .collect(),
    }
}

/// Colour to gray with OpenCV's luma weights (re-exported from `stillpoint_image`).
pub fn to_gray8(rgb: &stillpoint_image::Rgb8) -> Gray8 {
    rgb_to_gray(rgb)
}

/// Check that an image's buffer matches its size (a `Gray8` built by hand may not).
pub(crate) fn valid(img: &Gray8) -> bool {
    !img.is_empty() && img.data.len() == img.width * img.height
}
