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
//! # Measured against OpenCV 4.6
//!
//! Speed (`stillpoint bench features --repeat 20`, 6 TUM 640x480 images, 1 thread each, our
//! rounds and OpenCV's alternating, ratio = median of per-round ratios ours / OpenCV, three
//! runs at load 4.2-4.4 on 2 cores): ORB 0.93-0.95 (5.3 vs 5.7 ms), Harris + sub-pixel
//! 0.30-0.31 (3.0 vs 9.8-11 ms, ~294 corners), LK 0.38-0.41 (2.3-2.5 vs 5.6-8.9 ms, both
//! pyramids built per call), Harris + LK 0.31-0.35. What makes it: [`track_lk`] and
//! [`good_features_to_track`] keep their per-pixel buffers per thread (fresh pages of ~8 MB
//! per call cost more than the arithmetic), and the inner loops of LK, sub-pixel refinement and
//! the FAST segment test run in AVX2 registers, each with a portable path that gives the same
//! bits (tested).
//!
//! Inlier ratio of a fundamental-matrix RANSAC (1 px, 0.99) on the ORB matches of the real
//! pairs in `../shared/data`, mean over 20 RANSAC draws on both sides
//! (`tests/real_data.rs`). The claim uses each system's own pipeline: ours = ORB-SLAM3 ORB +
//! [`match_keypoints`] (ratio 0.8, mutual, ORB-SLAM's rotation check) + our RANSAC (refit on
//! the inliers); OpenCV = `ORB_create` + `BFMatcher` ratio 0.8 + cross check +
//! `findFundamentalMat`. Ours / OpenCV: TUM desk 0.621 / 0.617, bow loop 1-2 0.578 / 0.435,
//! KITTI stereo 0.823 / 0.757, KITTI seq 1-2 0.698 / 0.674, EuRoC 0.626 / 0.534, TUM walking
//! 0.714 / 0.699. With the same matcher (rotation check on both) and the same RANSAC (ours)
//! OpenCV's ORB is ahead on TUM desk (0.660) and the bow pair (0.600), level on TUM walking
//! (0.714): ORB-SLAM's quadtree keeps weaker corners, placed less precisely at a 1 px
//! threshold. Without the rotation check ours is below OpenCV on TUM desk (0.592) and bow 1-2
//! (0.296); one RANSAC draw per side (the old comparison) also put KITTI seq 1-2 below (0.637
//! vs 0.720, whose 20-draw means are 0.699 vs 0.674).
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

#![deny(missing_docs)]

mod corners;
mod fast;
mod imgops;
mod lk;
mod matcher;
mod orb;
mod pattern;
#[cfg(test)]
mod test_rng;

pub use corners::{CornerParams, corner_sub_pix, good_features_to_track};
pub use fast::FAST_CIRCLE;
pub use lk::{LkParams, LkPyramid, forward_backward_errors, track_lk, track_lk_pyramids};
pub use matcher::{
    KeypointGrid, Match, MatchParams, Projected, ProjectionParams, RotationHistogram, hamming,
    match_brute_force, match_keypoints, search_by_projection,
};
pub use orb::{KeyPoint, OrbExtractor, OrbFeatures, OrbParams, OrbScore, OrbTimings, noise_sigma};
pub use stillpoint_image::{Gray8, rgb_to_gray};

/// A 256-bit binary descriptor (ORB).
pub type Descriptor = [u8; 32];

/// Errors of this crate (the feature functions themselves never fail: bad input gives empty
/// output; these are for the helpers that validate input).
#[derive(Debug, thiserror::Error)]
pub enum FeaturesError {
    /// An input a helper cannot use.
    #[error("{file}:{line}: {what}")]
    BadInput {
        /// Source file of the check.
        file: &'static str,
        /// Its line.
        line: u32,
        /// What was wrong.
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
