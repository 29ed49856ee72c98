//! One timestamped frame of a sequence.

use stillpoint_image::{DepthMetres, Gray8, Rgb8};

/// A frame as the SLAM front-end receives it. `gray` is always there; the rest depends on the
/// sensor (RGB-D: `rgb` + `depth`; stereo: `right`; mono: `gray` alone, `rgb` if colour).
#[derive(Clone, Debug)]
pub struct Frame {
    /// Position in the sequence, from 0.
    pub index: usize,
    /// Seconds, as the dataset gives them (TUM: Unix time; KITTI: from 0).
    pub timestamp: f64,
    /// Left / only image, 8-bit gray.
    pub gray: Gray8,
    /// Colour image when the dataset has one (the detector wants it).
    pub rgb: Option<Rgb8>,
    /// Depth in metres registered to `gray` (0 = no measurement).
    pub depth: Option<DepthMetres>,
    /// Right image of a rectified stereo pair.
    pub right: Option<Gray8>,
}
