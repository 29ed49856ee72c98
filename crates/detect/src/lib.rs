//! stillpoint-detect: object boxes for the dynamic front-end.
//!
//! A [`Detector`] turns one RGB frame into [`Detection`]s (COCO class, score, box in the frame's
//! pixels). Implementations: [`NoDetector`] (no boxes), [`GtDetector`] (ground-truth boxes from
//! `boxes.jsonl`, written by `stillpoint synth`), and YOLOX through ONNX (`yolox`), on ONNX
//! Runtime (feature `ort`, on by default: its library is loaded at run time) or the pure-Rust
//! tract (feature `tract`, off by default: it is most of a cold build's time).
//! [`onnx_proto`] reads a model file's graph without either, for the checks made before loading.
//! [`DetectorThread`] runs any of them on its own thread, frames in and boxes out over channels.
//!
//! ```
//! use stillpoint_detect::{DetectInput, Detector, NoDetector};
//! let rgb = stillpoint_image::Rgb8::new(8, 6, [0, 0, 0]);
//! let mut det = NoDetector;
//! let boxes = det.detect(&DetectInput { index: 0, timestamp: 0.0, rgb: &rgb }).unwrap();
//! assert!(boxes.is_empty());
//! ```

#![deny(missing_docs)]

pub mod backend;
pub mod detector;
pub mod draw;
pub mod error;
pub mod gt;
pub mod model;
pub mod onnx_proto;
pub mod settings;
pub mod thread;
pub mod yolox;

pub use detector::{YoloxDetector, open_detector};
pub use error::DetectError;
pub use gt::{GtDetector, GtDetectorParams, NoDetector};
pub use settings::{Backend, DetectSettings};
pub use thread::{DetectOutput, DetectorThread, JobQueue};

// The detection type and the classes live in `stillpoint-detection` (no inference backend), so
// that the box judgement builds without one; these paths stay for users of this crate.
pub use stillpoint_detection::{BBox, COCO_CLASSES, Detection, classes};
use stillpoint_image::Rgb8;

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
    /// The network's input (height, width), for a detector that has one.
    fn input_size(&self) -> Option<(usize, usize)> {
        None
    }
}

impl<D: Detector + ?Sized> Detector for Box<D> {
    fn detect(&mut self, input: &DetectInput) -> Result<Vec<Detection>, DetectError> {
        (**self).detect(input)
    }
    fn name(&self) -> &str {
        (**self).name()
    }
    fn input_size(&self) -> Option<(usize, usize)> {
        (**self).input_size()
    }
}
