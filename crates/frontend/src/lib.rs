//! stillpoint-frontend: the dynamic front-end (paper figure 2) behind the [`FrontEnd`] trait,
//! the pipeline's plug-in point between ORB extraction and tracking.
//!
//! Per frame, [`DynamicFrontEnd`] runs the object detector beside the motion check
//! (`dynamic::motion_consistency`, corners tracked from the previous frame), judges the boxes
//! (`dynamic::judge_boxes`), follows objects over frames (`dynamic::objects`), carries boxes
//! judged dynamic through detector misses (`dynamic::memory`) and culls keypoints
//! (`dynamic::cull_frame_with_evidence`: depth-aware on RGB-D frames, the paper's algorithm 3
//! otherwise, then per-keypoint motion evidence inside dynamic boxes). On RGB-D frames the
//! tracks are judged against the static world (`dynamic::world_motion`, the map's
//! constant-velocity prior from the poses tracking gave) instead of a two-frame F. Kept
//! keypoints on objects not proven still, or beside outliers no box explains, are tracked but
//! create no map points. The rules of ours on top of the paper are switches in
//! [`FrontEndSettings`]; what each one is for and its measurements are in docs/results.md and
//! docs/paper.md.
//!
//! ```
//! use stillpoint_frontend::{DynamicFrontEnd, FrameInput, FrontEnd, FrontEndSettings};
//! use stillpoint_image::Gray8;
//!
//! let mut front = DynamicFrontEnd::new(
//!     Box::new(stillpoint_detect::NoDetector),
//!     FrontEndSettings::default(),
//! );
//! let gray = Gray8::new(64, 48, 0);
//! let input = FrameInput {
//!     index: 0,
//!     timestamp: 0.0,
//!     gray: &gray,
//!     rgb: None,
//!     depth: None,
//!     previous: None,
//!     own_boxes: false,
//! };
//! front.measure(&input);
//! let out = front.judge(&input, &[[10.0, 10.0], [30.0, 20.0]]);
//! assert_eq!(out.dynamic, vec![false, false]);
//! ```

#![deny(missing_docs)]

mod background;
mod front_end;
mod interface;
mod regions;
mod seated;
mod settings;
#[cfg(test)]
mod tests;

pub use background::DetectionPrefetch;
pub use front_end::DynamicFrontEnd;
pub use interface::{EraseRecent, FrameInput, FrontEnd, Judgement, PreviousPose, SceneObjects};
pub use regions::{ObjectRegion, Regions};
pub use seated::protected_in_dynamic_box;
pub use settings::FrontEndSettings;

/// COCO's person class: a-priori dynamic when there is no motion evidence yet.
pub const PERSON_CLASS: u16 = 0;
