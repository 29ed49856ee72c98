//! stillpoint-detect: object boxes for the dynamic front-end.
//!
//! A [`Detector`] turns one RGB frame into [`Detection`]s (COCO class, score, box in the frame's
//! pixels). Implementations: [`NoDetector`] (no boxes), [`GtDetector`] (ground-truth boxes from
//! `boxes.jsonl`, written by `stillpoint synth`), and YOLOX through ONNX (`yolox`), with
//! the pure-Rust `tract` backend by default and ONNX Runtime behind the `ort` feature.
//! [`DetectorThread`] runs any of them on its own thread, frames in and boxes out over channels.
//!
//! ```
//! use stillpoint_detect::{DetectInput, Detector, NoDetector};
//! let rgb = stillpoint_image::Rgb8::new(8, 6, [0, 0, 0]);
//! let mut det = NoDetector;
//! let boxes = det.detect(&DetectInput { index: 0, timestamp: 0.0, rgb: &rgb }).unwrap();
//! assert!(boxes.is_empty());
//! ```

pub mod backend;
pub mod classes;
pub mod detector;
pub mod draw;
pub mod error;
pub mod gt;
pub mod model;
pub mod settings;
pub mod thread;
pub mod yolox;

pub use classes::COCO_CLASSES;
pub use detector::{YoloxDetector, open_detector};
pub use error::DetectError;
pub use gt::{GtDetector, GtDetectorParams, NoDetector};
pub use settings::{Backend, DetectSettings};
pub use thread::{DetectOutput, DetectorThread};

use serde::{Deserialize, Serialize};
pub use stillpoint_geometry::bbox::BBox;
use stillpoint_image::Rgb8;

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
    /// # use stillpoint_detect::{Detection, BBox};
    /// let d = Detection { class_id: 0, score: 0.9, bbox: BBox::default() };
    /// assert_eq!(d.class_name(), "person");
    /// ```
    pub fn class_name(&self) -> &'static str {
        classes::class_name(self.class_id)
    }
}

/// One frame handed to a detector.
#[derive(Clone, Copy, Debug)]
pub struct DetectInput<'a> {
    /// Position of the frame in its sequence.
    pub index: usize,
    /// Frame time in seconds (as the dataset gives it).
    pub timestamp: f64,
    /// The colour image (RGB order).
    pub rgb: &'a Rgb8,
}

/// Anything that turns a frame into boxes. `Send` so it can live on the detector thread.
pub trait Detector: Send {
    /// Boxes of one frame.
    fn detect(&mut self, input: &DetectInput) -> Result<Vec<Detection>, DetectError>;
    /// Short name for logs (`"none"`, `"gt"`, `"yolox-tract"`, ...).
    fn name(&self) -> &str;
}

impl<D: Detector + ?Sized> Detector for Box<D> {
    fn detect(&mut self, input: &DetectInput) -> Result<Vec<Detection>, DetectError> {
        (**self).detect(input)
    }
    fn name(&self) -> &str {
        (**self).name()
    }
}
