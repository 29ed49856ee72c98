//! stillpoint-detection: what a detector says about a frame, and nothing that runs one.
//!
//! [`Detection`] (COCO class, score, box) is the language between the detectors
//! (`stillpoint-detect`: YOLOX through tract or ONNX Runtime, ground-truth boxes) and the crates
//! that judge boxes (`stillpoint-dynamic`), so the paper's rules build without an inference
//! backend.
//!
//! ```
//! use stillpoint_detection::{BBox, Detection};
//! let d = Detection { class_id: 62, score: 0.8, bbox: BBox::new(10.0, 20.0, 110.0, 90.0) };
//! assert_eq!(d.class_name(), "tvmonitor");
//! ```

#![deny(missing_docs)]

pub mod annotations;
pub mod classes;

pub use classes::COCO_CLASSES;
use serde::{Deserialize, Serialize};
pub use stillpoint_geometry::bbox::BBox;

/// One detected object.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Detection {
    /// COCO class index (0 person, 62 tv, ...; see [`COCO_CLASSES`]).
    pub class_id: u16,
    /// Confidence in 0..1 (YOLOX: objectness x class probability; ground truth: 1).
    pub score: f32,
    /// Box in the input frame's pixels, clipped to the frame.
    pub bbox: BBox,
}

impl Detection {
    /// The COCO name of the class, or `"unknown"` for ids beyond the 80 COCO classes (a user's
    /// model may have more).
    ///
    /// ```
    /// # use stillpoint_detection::{Detection, BBox};
    /// let d = Detection { class_id: 0, score: 0.9, bbox: BBox::default() };
    /// assert_eq!(d.class_name(), "person");
    /// ```
    pub fn class_name(&self) -> &'static str {
        classes::class_name(self.class_id)
    }
}
