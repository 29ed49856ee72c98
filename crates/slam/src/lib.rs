//! stillpoint-slam: ORB-SLAM3-style RGB-D SLAM in stella_vslam-like modules.
//!
//! - [`data`]: frames, keyframes, map points and the map (covisibility graph, spanning tree);
//! - [`matching`]: descriptor matching by projection and brute force, rotation histogram;
//! - [`optimize`]: pose-only optimisation (Huber, 4 rounds of chi-square rejection), local
//!   bundle adjustment with a Schur complement, and SE3 pose-graph optimisation (the essential
//!   graph of loop closing);
//! - [`solve`]: robust absolute pose (RANSAC) for relocalisation, and the rigid transform
//!   between two keyframes (RANSAC over 3D-3D pairs) for loop closing;
//! - [`module`]: tracking, local mapping (own thread, channels), loop closing (own thread) and
//!   the keypoint-filter hook through which the dynamic front-end removes moving keypoints;
//! - [`place`]: place recognition, a bag of binary words trained online and the keyframe
//!   database;
//! - [`map_file`]: the map saved to and loaded from a versioned, checksummed binary file;
//! - [`System`]: the entry point that ties them together.
//!
//! The crate works on already extracted features ([`Feature`] + [`Descriptor`]), so the ORB
//! extractor and the dynamic front-end stay in their own crates; `stillpoint-pipeline` wires them.
//!
//! ```
//! use stillpoint_slam::{SlamSettings, System};
//! use stillpoint_geometry::PinholeCamera;
//! let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
//! let settings = SlamSettings::rgbd(cam, 40.0, 30.0);
//! let system = System::new(settings);
//! assert_eq!(system.keyframe_count(), 0);
//! ```

#![deny(missing_docs)]

pub mod data;
pub mod io;
pub mod map_file;
pub mod matching;
pub mod module;
pub mod optimize;
pub mod place;
pub mod settings;
pub mod solve;
mod system;

pub use data::frame::{Descriptor, Feature, Frame, KeypointDepth};
pub use module::tracking::{Backfilled, TrackingState};
pub use settings::SlamSettings;
pub use system::{FrameReport, LoadedMapMode, MapHygiene, System, TrackInput};

/// Errors from the SLAM core. Input problems (wrong sizes, NaN) are reported, not panicked on.
#[derive(Debug, thiserror::Error)]
pub enum SlamError {
    /// The input of a frame is unusable (sizes differ, NaN).
    #[error("frame {index}: {msg}")]
    BadInput {
        /// The frame's index.
        index: usize,
        /// What is wrong.
        msg: String,
    },
    /// The local mapping thread died or cannot be started.
    #[error("local mapping thread stopped: {0}")]
    LocalMapping(String),
}

/// FNV-1a, 64 bits: the checksum of map files and the vocabulary fingerprint (computed here:
/// a few lines, no dependency).
pub mod fnv1a64 {
    /// The offset basis: the hash of no bytes.
    pub const START: u64 = 0xcbf2_9ce4_8422_2325;
    const PRIME: u64 = 0x0000_0100_0000_01b3;

    /// The hash `h` continued over `bytes`.
    pub fn update(mut h: u64, bytes: &[u8]) -> u64 {
        for &b in bytes {
            h = (h ^ b as u64).wrapping_mul(PRIME);
        }
        h
    }

    /// The hash of `bytes`.
    ///
    /// ```
    /// assert_eq!(stillpoint_slam::fnv1a64::hash(b"a"), 0xaf63_dc4c_8601_ec8c);
    /// ```
    pub fn hash(bytes: &[u8]) -> u64 {
        update(START, bytes)
    }
}

/// Hamming distance between two 256-bit descriptors (the ORB extractor's).
pub use stillpoint_features::hamming;
