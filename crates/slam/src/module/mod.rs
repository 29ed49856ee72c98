//! The running parts: tracking (per frame), monocular initialisation, local mapping (per
//! keyframe, own thread), loop closing (per keyframe after local mapping, own thread) and the
//! hook through which the dynamic front-end removes keypoints before tracking sees them.

pub mod initializer;
pub mod local_mapping;
pub mod loop_closing;
pub mod tracking;
