//! Detectors that need no model: [`NoDetector`] (no boxes) and [`GtDetector`] (ground-truth
//! boxes from `boxes.jsonl`, so SLAM can run with perfect detections).

use crate::{DetectError, DetectInput, Detection, Detector};
use std::path::Path;
use stillpoint_detection::annotations::{FrameBoxes, read_boxes};

/// Returns no boxes: the dynamic front-end then relies on geometry alone.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoDetector;

impl Detector for NoDetector {
    fn detect(&mut self, _input: &DetectInput) -> Result<Vec<Detection>, DetectError> {
        Ok(Vec::new())
    }
    fn name(&self) -> &str {
        "none"
    }
}

/// How [`GtDetector`] picks and filters boxes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GtDetectorParams {
    /// Keep only boxes whose visible fraction is above this (0 keeps every box; a real detector
    /// misses heavily occluded objects, so e.g. 0.3 mimics one). stillpoint's own choice.
    pub min_visible_fraction: f32,
    /// When the frame with the input's index is missing or its timestamp differs by more than
    /// this many seconds, take the frame nearest in time instead, if it is within this distance;
    /// otherwise return no boxes. 0.02 s is below half a frame at 30 Hz (TUM association uses
    /// the same order of magnitude).
    pub max_time_difference: f64,
}

impl Default for GtDetectorParams {
    fn default() -> Self {
        Self {
            min_visible_fraction: 0.0,
            max_time_difference: 0.02,
        }
    }
}

/// Ground-truth boxes, score 1.0, read once from `boxes.jsonl`.
///
/// ```
/// use stillpoint_detect::{DetectInput, Detector, GtDetector, GtDetectorParams};
/// use stillpoint_detection::annotations::{FrameBoxes, GtBox};
/// use stillpoint_geometry::BBox;
/// let frames = vec![FrameBoxes { frame: 0, timestamp: 1.0, boxes: vec![GtBox {
///     object: 1, class_id: 0, bbox: BBox::new(1.0, 2.0, 3.0, 4.0), moving: true, visible_fraction: 1.0 }] }];
/// let mut det = GtDetector::from_frames(frames, GtDetectorParams::default()).unwrap();
/// let rgb = stillpoint_image::Rgb8::new(8, 8, [0; 3]);
/// let boxes = det.detect(&DetectInput { index: 0, timestamp: 1.0, rgb: &rgb }).unwrap();
/// assert_eq!(boxes[0].score, 1.0);
/// ```
#[derive(Clone, Debug)]
pub struct GtDetector {
    /// Frames sorted by timestamp.
    frames: Vec<FrameBoxes>,
    params: GtDetectorParams,
}

impl GtDetector {
    /// Read `boxes.jsonl` (see `stillpoint_detection::annotations`).
    pub fn open(path: &Path, params: GtDetectorParams) -> Result<Self, DetectError> {
        let frames = read_boxes(path)?;
        Self::from_frames(frames, params).map_err(|e| match e {
            DetectError::BadInput(msg) => {
                DetectError::BadInput(format!("{}: {msg}", path.display()))
            }
            other => other,
        })
    }

    /// Build from frames already in memory. Non-finite timestamps are an error; frames out of
    /// time order are sorted (and logged).
    pub fn from_frames(
        mut frames: Vec<FrameBoxes>,
        params: GtDetectorParams,
    ) -> Result<Self, DetectError> {
        if let Some(f) = frames.iter().find(|f| !f.timestamp.is_finite()) {
            return Err(DetectError::BadInput(format!(
                "frame {}: timestamp is not finite",
                f.frame
            )));
        }
        if !(params.min_visible_fraction.is_finite() && params.max_time_difference >= 0.0) {
            return Err(DetectError::BadInput(format!(
                "gt detector: bad parameters {params:?}"
            )));
        }
        if frames.windows(2).any(|w| w[1].timestamp < w[0].timestamp) {
            tracing::warn!("boxes.jsonl: frames are not in time order; sorting them");
            frames.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
        }
        Ok(Self { frames, params })
    }

    /// The frame for an input: same index with a matching time, else nearest in time.
    fn lookup(&self, index: usize, timestamp: f64) -> Option<&FrameBoxes> {
        let tol = self.params.max_time_difference;
        let close =
            |f: &FrameBoxes| !timestamp.is_finite() || (f.timestamp - timestamp).abs() <= tol;
        if let Some(f) = self.frames.iter().find(|f| f.frame == index)
            && close(f)
        {
            return Some(f);
        }
        if !timestamp.is_finite() {
            return None;
        }
        let i = self.frames.partition_point(|f| f.timestamp < timestamp);
        let before = i.checked_sub(1).map(|j| &self.frames[j]);
        let after = self.frames.get(i);
        let best = match (before, after) {
            (Some(a), Some(b)) => {
                if timestamp - a.timestamp <= b.timestamp - timestamp {
                    a
                } else {
                    b
                }
            }
            (Some(a), None) => a,
            (None, Some(b)) => b,
            (None, None) => return None,
        };
        close(best).then_some(best)
    }
}

impl Detector for GtDetector {
    fn detect(&mut self, input: &DetectInput) -> Result<Vec<Detection>, DetectError> {
        let Some(frame) = self.lookup(input.index, input.timestamp) else {
            tracing::debug!(
                "gt detector: no boxes for frame {} at {:.6}",
                input.index,
                input.timestamp
            );
            return Ok(Vec::new());
        };
        Ok(frame
            .boxes
            .iter()
            .filter(|b| {
                self.params.min_visible_fraction <= 0.0
                    || b.visible_fraction > self.params.min_visible_fraction
            })
            .map(|b| Detection {
                class_id: b.class_id,
                score: 1.0,
                bbox: b.bbox,
            })
            .collect())
    }
    fn name(&self) -> &str {
        "gt"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stillpoint_detection::annotations::{GtBox, write_frame_boxes};
    use stillpoint_geometry::BBox;
    use stillpoint_image::Rgb8;

    fn frame(index: usize, t: f64, vis: &[f32]) -> FrameBoxes {
        FrameBoxes {
            frame: index,
            timestamp: t,
            boxes: vis
                .iter()
                .enumerate()
                .map(|(k, &v)| GtBox {
                    object: k as u32,
                    class_id: k as u16,
                    bbox: BBox::new(index as f32, 0.0, 10.0 + k as f32, 10.0),
                    moving: k == 0,
                    visible_fraction: v,
                })
                .collect(),
        }
    }

    fn run(det: &mut GtDetector, index: usize, t: f64) -> Vec<Detection> {
        let rgb = Rgb8::new(4, 4, [0; 3]);
        det.detect(&DetectInput {
            index,
            timestamp: t,
            rgb: &rgb,
        })
        .unwrap()
    }

    #[test]
    fn reads_file_and_matches_by_index_then_time() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("boxes.jsonl");
        let mut buf = Vec::new();
        for f in [
            frame(0, 1.0, &[1.0]),
            frame(1, 1.1, &[1.0, 0.2]),
            frame(2, 1.2, &[]),
        ] {
            write_frame_boxes(&mut buf, &f).unwrap();
        }
        std::fs::write(&path, &buf).unwrap();
        let mut det = GtDetector::open(&path, GtDetectorParams::default()).unwrap();
        let b = run(&mut det, 1, 1.1);
        assert_eq!(b.len(), 2);
        assert_eq!(b[1].class_id, 1);
        assert_eq!(b[0].bbox.x1, 1.0);
        assert!(b.iter().all(|d| d.score == 1.0));
        // Index 7 does not exist: nearest timestamp (frame 1 at 1.1) wins.
        assert_eq!(run(&mut det, 7, 1.105)[0].bbox.x1, 1.0);
        // Index exists but its time is far off: nearest in time.
        assert!(run(&mut det, 0, 1.199).is_empty()); // frame 2 at 1.2 has no boxes
        // Nothing within the tolerance: no boxes.
        assert!(run(&mut det, 9, 5.0).is_empty());
        assert_eq!(det.name(), "gt");
    }

    #[test]
    fn visibility_filter_drops_occluded_boxes() {
        let params = GtDetectorParams {
            min_visible_fraction: 0.5,
            ..Default::default()
        };
        let mut det =
            GtDetector::from_frames(vec![frame(0, 0.0, &[0.9, 0.2, 0.5])], params).unwrap();
        let ids: Vec<u16> = run(&mut det, 0, 0.0).iter().map(|d| d.class_id).collect();
        assert_eq!(ids, vec![0]);
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        let dir = tempfile::tempdir().unwrap();
        let missing = GtDetector::open(&dir.path().join("nope.jsonl"), Default::default());
        assert!(missing.unwrap_err().to_string().contains("nope.jsonl"));
        let nan = GtDetector::from_frames(vec![frame(3, f64::NAN, &[])], Default::default());
        assert!(nan.unwrap_err().to_string().contains("frame 3"));
        // Unsorted input is sorted, not rejected.
        let mut det = GtDetector::from_frames(
            vec![frame(1, 2.0, &[1.0]), frame(0, 1.0, &[1.0, 1.0])],
            Default::default(),
        )
        .unwrap();
        assert_eq!(run(&mut det, 5, 1.0).len(), 2);
    }

    #[test]
    fn no_detector_returns_nothing() {
        let rgb = Rgb8::new(2, 2, [1; 3]);
        let input = DetectInput {
            index: 0,
            timestamp: 0.0,
            rgb: &rgb,
        };
        assert!(NoDetector.detect(&input).unwrap().is_empty());
        assert_eq!(NoDetector.name(), "none");
    }
}
