//! YOLOX pre- and post-processing as pure functions over plain buffers, shared by every
//! inference backend: top-left letterbox into a BGR CHW float tensor, grid + stride decoding,
//! score = objectness x class, class-wise NMS, boxes back in the original image.
//!
//! Follows the YOLOX authors' `yolox/data/data_augment.py::preproc` and
//! `yolox/utils/demo_utils.py` (`demo_postprocess`, `multiclass_nms_class_aware`, `nms`).
//!
//! ```
//! use stillpoint_detect::yolox::{expected_rows, letterbox};
//! let rgb = stillpoint_image::Rgb8::new(64, 32, [10, 20, 30]);
//! let lb = letterbox(&rgb, 64, 64, 114.0);
//! assert_eq!(lb.ratio, 1.0);
//! assert_eq!(lb.tensor.len(), 3 * 64 * 64);
//! assert_eq!(lb.tensor[0], 30.0); // channel 0 is blue
//! assert_eq!(lb.tensor[64 * 63], 114.0); // padding below the image
//! assert_eq!(expected_rows(64, 64), 64 + 16 + 4);
//! ```

use crate::{BBox, DetectError, Detection};
use stillpoint_image::Rgb8;

/// YOLOX's three output strides (P3, P4, P5 of its PAFPN head).
pub const STRIDES: [usize; 3] = [8, 16, 32];

/// A letterboxed network input: `[1, 3, height, width]` BGR floats 0..255, and the scale that
/// maps the original image into it (network pixel = original pixel x ratio).
#[derive(Clone, Debug, PartialEq)]
pub struct Letterboxed {
    /// The network input, `[1, 3, height, width]`.
    pub tensor: Vec<f32>,
    /// Network pixels per original pixel.
    pub ratio: f32,
}

/// Resize `rgb` keeping its aspect ratio so it fits `height` x `width`, place it at the top-left,
/// pad the rest with `pad`, and lay it out as planar BGR floats (no mean, no std), as YOLOX's
/// `preproc` does. Resizing is bilinear with OpenCV's pixel-centre convention (`INTER_LINEAR`)
/// and rounds back to 8 bits, as `cv2.resize(...).astype(np.uint8)` does.
pub fn letterbox(rgb: &Rgb8, height: usize, width: usize, pad: f32) -> Letterboxed {
    let mut tensor = vec![pad; 3 * height * width];
    if rgb.is_empty() || height == 0 || width == 0 {
        return Letterboxed { tensor, ratio: 1.0 };
    }
    let ratio = (height as f32 / rgb.height as f32).min(width as f32 / rgb.width as f32);
    // YOLOX: int(img.shape[1] * r), truncation.
    let new_w = ((rgb.width as f32 * ratio) as usize).clamp(1, width);
    let new_h = ((rgb.height as f32 * ratio) as usize).clamp(1, height);
    let plane = height * width;
    let put = |tensor: &mut [f32], x: usize, y: usize, p: [u8; 3]| {
        let at = y * width + x;
        tensor[at] = p[2] as f32;
        tensor[plane + at] = p[1] as f32;
        tensor[2 * plane + at] = p[0] as f32;
    };
    if new_w == rgb.width && new_h == rgb.height {
        for y in 0..new_h {
            for (x, &p) in rgb.row(y).iter().enumerate() {
                put(&mut tensor, x, y, p);
            }
        }
        return Letterboxed { tensor, ratio };
    }
    // Source coordinate and weight per destination column / row (OpenCV INTER_LINEAR).
    let taps = |dst: usize, src: usize| -> Vec<(usize, usize, f32)> {
        let scale = src as f32 / dst as f32;
        (0..dst)
            .map(|d| {
                let f = (d as f32 + 0.5) * scale - 0.5;
                let i = f.floor();
                let w = f - i;
                let i = i as isize;
                if i < 0 {
                    (0, 0, 0.0)
                } else if i as usize >= src - 1 {
                    (src - 1, src - 1, 0.0)
                } else {
                    (i as usize, i as usize + 1, w)
                }
            })
            .collect()
    };
    let xs = taps(new_w, rgb.width);
    let ys = taps(new_h, rgb.height);
    for (y, &(y0, y1, wy)) in ys.iter().enumerate() {
        let (r0, r1) = (rgb.row(y0), rgb.row(y1));
        for (x, &(x0, x1, wx)) in xs.iter().enumerate() {
            let mut p = [0u8; 3];
            for (c, out) in p.iter_mut().enumerate() {
                let top = r0[x0][c] as f32 * (1.0 - wx) + r0[x1][c] as f32 * wx;
                let bottom = r1[x0][c] as f32 * (1.0 - wx) + r1[x1][c] as f32 * wx;
                *out = (top * (1.0 - wy) + bottom * wy).round().clamp(0.0, 255.0) as u8;
            }
            put(&mut tensor, x, y, p);
        }
    }
    Letterboxed { tensor, ratio }
}

/// Number of output rows (anchors) a YOLOX head gives for an input of `height` x `width`.
pub fn expected_rows(height: usize, width: usize) -> usize {
    STRIDES.iter().map(|s| (height / s) * (width / s)).sum()
}

/// Check a raw output shape against the input size: `[1, rows, 5 + classes]` (or without the
/// batch axis). Returns (rows, values per row).
pub fn check_output_shape(
    shape: &[usize],
    height: usize,
    width: usize,
) -> Result<(usize, usize), String> {
    let rows = expected_rows(height, width);
    let (n, k) = match shape {
        [1, n, k] | [n, k] => (*n, *k),
        _ => {
            return Err(format!(
                "output shape {shape:?}, expected [1, {rows}, 5 + classes] for a {height}x{width} input"
            ));
        }
    };
    if n != rows || k < 6 {
        return Err(format!(
            "output shape {shape:?}, expected [1, {rows}, 5 + classes] for a {height}x{width} input \
             (strides 8/16/32; is this a YOLOX model with decoding left out of the graph?)"
        ));
    }
    Ok((n, k))
}

/// Thresholds of the post-processing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PostParams {
    /// Minimum score (objectness x class), YOLOX demo 0.3.
    pub conf_threshold: f32,
    /// Class-wise NMS IoU threshold, YOLOX demo 0.45.
    pub nms_threshold: f32,
}

impl Default for PostParams {
    fn default() -> Self {
        Self {
            conf_threshold: 0.3,
            nms_threshold: 0.45,
        }
    }
}

/// Turn a raw YOLOX output into detections in the original image.
///
/// `output` holds `rows x (5 + classes)` floats: cx, cy, w, h relative to the anchor's grid cell
/// (log-space w/h), objectness and class probabilities (already sigmoid). `input` is the network
/// input (height, width), `ratio` the letterbox scale and `image` the original (width, height).
/// Boxes are clipped to the image; boxes that end up empty (found in the padding) are dropped.
/// The result is sorted by descending score.
pub fn decode(
    output: &[f32],
    shape: &[usize],
    input: (usize, usize),
    ratio: f32,
    image: (usize, usize),
    params: &PostParams,
) -> Result<Vec<Detection>, DetectError> {
    let (rows, k) = check_output_shape(shape, input.0, input.1).map_err(DetectError::BadInput)?;
    if output.len() != rows * k {
        return Err(DetectError::BadInput(format!(
            "output holds {} values, shape {shape:?} needs {}",
            output.len(),
            rows * k
        )));
    }
    if !(ratio.is_finite() && ratio > 0.0) {
        return Err(DetectError::BadInput(format!(
            "letterbox ratio {ratio} is not positive"
        )));
    }
    let classes = k - 5;
    let mut candidates: Vec<Detection> = Vec::new();
    let mut row = 0;
    for stride in STRIDES {
        let (gh, gw) = (input.0 / stride, input.1 / stride);
        let s = stride as f32;
        for gy in 0..gh {
            for gx in 0..gw {
                let v = &output[row * k..(row + 1) * k];
                row += 1;
                let objectness = v[4];
                // Class probabilities are at most 1, so a low objectness rules the row out
                // (NaN too: the comparison is false).
                if objectness.partial_cmp(&params.conf_threshold)
                    != Some(std::cmp::Ordering::Greater)
                {
                    continue;
                }
                let cx = (v[0] + gx as f32) * s;
                let cy = (v[1] + gy as f32) * s;
                let w = v[2].exp() * s;
                let h = v[3].exp() * s;
                if !(cx.is_finite() && cy.is_finite() && w.is_finite() && h.is_finite()) {
                    continue;
                }
                let bbox = BBox::new(
                    (cx - 0.5 * w) / ratio,
                    (cy - 0.5 * h) / ratio,
                    (cx + 0.5 * w) / ratio,
                    (cy + 0.5 * h) / ratio,
                );
                for c in 0..classes {
                    let score = objectness * v[5 + c];
                    if score > params.conf_threshold {
                        candidates.push(Detection {
                            class_id: c.min(u16::MAX as usize) as u16,
                            score,
                            bbox,
                        });
                    }
                }
            }
        }
    }
    // NMS is quadratic in the candidates: a model whose every row is confident (6300 rows x 80
    // classes) took ~8 s a frame. Keep the best MAX_NMS_CANDIDATES, as detectors' `nms_pre` does.
    if candidates.len() > MAX_NMS_CANDIDATES {
        candidates.select_nth_unstable_by(MAX_NMS_CANDIDATES, |a, b| b.score.total_cmp(&a.score));
        candidates.truncate(MAX_NMS_CANDIDATES);
    }
    let kept = nms_class_aware(candidates, params.nms_threshold);
    let (iw, ih) = (image.0 as f32, image.1 as f32);
    let mut out: Vec<Detection> = kept
        .into_iter()
        .filter_map(|mut d| {
            d.bbox = BBox::new(
                d.bbox.x1.clamp(0.0, iw),
                d.bbox.y1.clamp(0.0, ih),
                d.bbox.x2.clamp(0.0, iw),
                d.bbox.y2.clamp(0.0, ih),
            );
            (d.bbox.area() > 0.0).then_some(d)
        })
        .collect();
    out.sort_by(|a, b| b.score.total_cmp(&a.score));
    Ok(out)
}

/// Boxes kept for non-maximum suppression, best scores first (a real frame has a few dozen).
pub const MAX_NMS_CANDIDATES: usize = 1000;

/// IoU as YOLOX's `demo_utils.nms` computes it: integer-pixel areas `(x2 - x1 + 1) * (y2 - y1 + 1)`.
/// Kept (rather than `BBox::iou`) so suppression decisions match the reference pipeline.
fn iou_plus_one(a: &BBox, b: &BBox) -> f32 {
    let area = |r: &BBox| (r.x2 - r.x1 + 1.0).max(0.0) * (r.y2 - r.y1 + 1.0).max(0.0);
    let w = (a.x2.min(b.x2) - a.x1.max(b.x1) + 1.0).max(0.0);
    let h = (a.y2.min(b.y2) - a.y1.max(b.y1) + 1.0).max(0.0);
    let inter = w * h;
    let union = area(a) + area(b) - inter;
    if union > 0.0 { inter / union } else { 0.0 }
}

/// Greedy non-maximum suppression within each class: the best box of a class removes the boxes
/// of the same class that overlap it by more than `iou_threshold`. Order of the result: by class,
/// then by descending score.
///
/// ```
/// use stillpoint_detect::{yolox::nms_class_aware, BBox, Detection};
/// let d = |c, s, x| Detection { class_id: c, score: s, bbox: BBox::new(x, 0.0, x + 10.0, 10.0) };
/// let kept = nms_class_aware(vec![d(0, 0.9, 0.0), d(0, 0.8, 1.0), d(1, 0.7, 1.0)], 0.45);
/// assert_eq!(kept.len(), 2); // the second person box is suppressed, the other class is not
/// ```
pub fn nms_class_aware(mut dets: Vec<Detection>, iou_threshold: f32) -> Vec<Detection> {
    dets.sort_by(|a, b| {
        a.class_id
            .cmp(&b.class_id)
            .then(b.score.total_cmp(&a.score))
    });
    let mut kept: Vec<Detection> = Vec::with_capacity(dets.len());
    let mut class_start = 0;
    for d in dets {
        if kept
            .get(class_start)
            .is_some_and(|k| k.class_id != d.class_id)
        {
            class_start = kept.len();
        }
        if kept[class_start..]
            .iter()
            .all(|k| iou_plus_one(&k.bbox, &d.bbox) <= iou_threshold)
        {
            kept.push(d);
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A raw output for a `height` x `width` input with one planted anchor.
    fn planted(
        height: usize,
        width: usize,
        classes: usize,
        row: usize,
        values: &[f32],
    ) -> Vec<f32> {
        let k = 5 + classes;
        let mut out = vec![0.0; expected_rows(height, width) * k];
        out[row * k..row * k + values.len()].copy_from_slice(values);
        out
    }

    #[test]
    fn decode_uses_grid_stride_and_exp() {
        // 64x64 input: stride 8 gives an 8x8 grid (rows 0..64), stride 16 a 4x4 grid (64..80).
        // Row 64 + 1*4 + 2 is the stride-16 cell (gx 2, gy 1).
        let row = 64 + 4 + 2;
        let mut v = vec![0.5, 0.25, (2.0f32).ln(), 0.0, 0.9];
        v.extend([0.0, 0.8]); // class 1 at 0.8 -> score 0.72
        let out = planted(64, 64, 2, row, &v);
        let dets = decode(
            &out,
            &[1, 84, 7],
            (64, 64),
            0.5,
            (128, 128),
            &PostParams::default(),
        )
        .unwrap();
        assert_eq!(dets.len(), 1);
        let d = dets[0];
        assert_eq!(d.class_id, 1);
        assert!((d.score - 0.72).abs() < 1e-6);
        // cx = (0.5 + 2) * 16 = 40, cy = (0.25 + 1) * 16 = 20, w = 2 * 16 = 32, h = 16;
        // then divided by the ratio 0.5.
        let want = BBox::new(48.0, 24.0, 112.0, 56.0);
        for (a, b) in [
            (d.bbox.x1, want.x1),
            (d.bbox.y1, want.y1),
            (d.bbox.x2, want.x2),
            (d.bbox.y2, want.y2),
        ] {
            assert!((a - b).abs() < 1e-4, "{:?} vs {want:?}", d.bbox);
        }
    }

    #[test]
    fn decode_clips_thresholds_and_keeps_both_classes() {
        // Cell (0, 0) at stride 8, a box hanging off the top-left corner, two classes above 0.3.
        let v = [0.0, 0.0, (4.0f32).ln(), (4.0f32).ln(), 1.0, 0.5, 0.29, 0.6];
        let out = planted(64, 64, 3, 0, &v);
        let dets = decode(
            &out,
            &[1, 84, 8],
            (64, 64),
            1.0,
            (64, 64),
            &PostParams::default(),
        )
        .unwrap();
        let classes: Vec<u16> = dets.iter().map(|d| d.class_id).collect();
        assert_eq!(classes, vec![2, 0]); // sorted by score; class 1 (0.29) below the threshold
        assert_eq!(dets[0].bbox, BBox::new(0.0, 0.0, 16.0, 16.0));
    }

    #[test]
    fn boxes_in_the_padding_are_dropped() {
        // Image 64 wide, 16 high in a 64x64 input: a box at the bottom lies in the padding.
        let row = 7 * 8 + 3; // stride 8, gy 7
        let v = [0.5, 0.5, 0.0, 0.0, 0.9, 0.9];
        let out = planted(64, 64, 1, row, &v);
        let dets = decode(
            &out,
            &[1, 84, 6],
            (64, 64),
            1.0,
            (64, 16),
            &PostParams::default(),
        )
        .unwrap();
        assert!(dets.is_empty(), "{dets:?}");
    }

    #[test]
    fn wrong_shapes_are_errors() {
        assert!(check_output_shape(&[1, 6300, 85], 480, 640).is_ok());
        assert!(check_output_shape(&[6300, 85], 480, 640).is_ok());
        let e = check_output_shape(&[1, 1680, 85], 480, 640).unwrap_err();
        assert!(e.contains("6300"), "{e}");
        assert!(check_output_shape(&[1, 6300, 5], 480, 640).is_err());
        assert!(check_output_shape(&[1, 3, 480, 640], 480, 640).is_err());
        let short = vec![0.0; 10];
        let err = decode(
            &short,
            &[1, 84, 85],
            (64, 64),
            1.0,
            (64, 64),
            &PostParams::default(),
        );
        assert!(matches!(err, Err(DetectError::BadInput(_))));
        let out = planted(64, 64, 1, 0, &[]);
        let bad_ratio = decode(
            &out,
            &[1, 84, 6],
            (64, 64),
            f32::NAN,
            (64, 64),
            &PostParams::default(),
        );
        assert!(bad_ratio.is_err());
    }

    #[test]
    fn nan_outputs_are_skipped_not_panicked_on() {
        let v = [f32::NAN, 0.0, 0.0, 0.0, 0.9, 0.9];
        let out = planted(64, 64, 1, 0, &v);
        let dets = decode(
            &out,
            &[1, 84, 6],
            (64, 64),
            1.0,
            (64, 64),
            &PostParams::default(),
        );
        assert!(dets.unwrap().is_empty());
    }

    #[test]
    fn a_model_confident_everywhere_is_capped_before_nms() {
        // Every row of a 480x640 head confident for every class: 6300 x 80 candidates.
        let (h, w, k) = (480usize, 640usize, 85usize);
        let rows = (h / 8) * (w / 8) + (h / 16) * (w / 16) + (h / 32) * (w / 32);
        let mut out = vec![0.9f32; rows * k];
        for r in 0..rows {
            out[r * k..r * k + 4].copy_from_slice(&[0.5, 0.5, 0.0, 0.0]);
        }
        let params = PostParams {
            conf_threshold: 0.3,
            nms_threshold: 0.45,
        };
        let dets = decode(&out, &[1, rows, k], (h, w), 1.0, (w, h), &params).unwrap();
        assert!(!dets.is_empty() && dets.len() <= MAX_NMS_CANDIDATES);
    }

    #[test]
    fn nms_suppresses_within_a_class_only() {
        let d = |c, s, x: f32| Detection {
            class_id: c,
            score: s,
            bbox: BBox::new(x, 0.0, x + 100.0, 100.0),
        };
        let kept = nms_class_aware(
            vec![
                d(0, 0.5, 30.0),
                d(0, 0.9, 0.0),
                d(0, 0.8, 10.0),
                d(3, 0.7, 10.0),
            ],
            0.45,
        );
        let got: Vec<(u16, f32)> = kept.iter().map(|k| (k.class_id, k.score)).collect();
        // 0.8 overlaps 0.9 by 91/110 > 0.45: gone; 0.5 overlaps 0.9 by 71/131 > 0.45: gone.
        assert_eq!(got, vec![(0, 0.9), (3, 0.7)]);
    }

    #[test]
    fn letterbox_scales_and_pads_at_the_top_left() {
        // A 4x2 image into an 8x8 input: ratio 2, image occupies rows 0..4, columns 0..8.
        let mut rgb = Rgb8::new(4, 2, [0, 0, 0]);
        rgb.set(3, 1, [200, 100, 50]);
        let lb = letterbox(&rgb, 8, 8, 114.0);
        assert_eq!(lb.ratio, 2.0);
        let at = |c: usize, x: usize, y: usize| lb.tensor[c * 64 + y * 8 + x];
        assert_eq!(at(0, 7, 3), 50.0); // bottom-right corner of the image, blue first
        assert_eq!(at(2, 7, 3), 200.0);
        assert_eq!(at(0, 0, 0), 0.0);
        assert_eq!(at(1, 0, 4), 114.0); // padding
        // Bilinear: the pixel between the dark and the bright one is in between.
        assert!(at(2, 5, 3) > 0.0 && at(2, 5, 3) < 200.0);
        // An empty image is all padding, not a panic.
        let empty = letterbox(&Rgb8::new(0, 0, [0; 3]), 8, 8, 114.0);
        assert!(empty.tensor.iter().all(|&v| v == 114.0));
    }
}
