//! The SLAM data: frames, keyframes, map points and the map.

pub mod frame;
pub mod map;
pub mod shared;

pub use frame::{Descriptor, Feature, Frame, KeypointGrid};
pub use map::{FreeSpaceCheck, KeyFrame, KfId, Map, MapPoint, MpId};
pub use shared::SharedMap;
