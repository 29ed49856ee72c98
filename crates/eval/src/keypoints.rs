//! The dynamic-keypoint decision against the generator's masks: confusion counts, precision
//! and recall, and three ground truths for an ORB keypoint.
//!
//! - strict: the keypoint's pixel (rounded, optionally widened by a radius) is moving;
//! - occlusion ([`support_truth`]): any of the 17 pixels of its FAST test (centre and 16-pixel
//!   circle of radius 3, scaled to its pyramid level) is moving: a corner formed by a moving
//!   silhouette moves with it;
//! - clear ([`clear_truth`]): keypoints whose FAST test straddles a moving silhouette (some of
//!   the 17 pixels moving, some not) are not scored, the others by their (unanimous) pixels.

use std::path::{Path, PathBuf};

use serde::Serialize;
use stillpoint_datasets::{DatasetError, read_stamped_list};
use stillpoint_features::{FAST_CIRCLE, KeyPoint};
use stillpoint_image::Gray8;

/// Confusion counts of one method (`true` = dynamic).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Counts {
    /// Predicted dynamic, truly dynamic.
    pub tp: usize,
    /// Predicted dynamic, truly static.
    pub fp: usize,
    /// Predicted static, truly dynamic.
    pub fn_: usize,
    /// Predicted static, truly static.
    pub tn: usize,
}

impl Counts {
    /// Count each (prediction, truth) pair.
    pub fn add(&mut self, predicted: &[bool], truth: &[bool]) {
        for (&p, &t) in predicted.iter().zip(truth) {
            match (p, t) {
                (true, true) => self.tp += 1,
                (true, false) => self.fp += 1,
                (false, true) => self.fn_ += 1,
                (false, false) => self.tn += 1,
            }
        }
    }

    /// Count only the pairs whose truth is known (`Some`), as the clear ground truth needs.
    pub fn add_known(&mut self, predicted: &[bool], truth: &[Option<bool>]) {
        let (p, t): (Vec<bool>, Vec<bool>) = predicted
            .iter()
            .zip(truth)
            .filter_map(|(&p, t)| t.map(|t| (p, t)))
            .unzip();
        self.add(&p, &t);
    }

    /// Precision; `None` when nothing was predicted dynamic.
    pub fn precision(&self) -> Option<f64> {
        let d = self.tp + self.fp;
        (d > 0).then(|| self.tp as f64 / d as f64)
    }

    /// Recall; `None` when nothing is truly dynamic.
    pub fn recall(&self) -> Option<f64> {
        let d = self.tp + self.fn_;
        (d > 0).then(|| self.tp as f64 / d as f64)
    }
}

/// Why the masks of a sequence cannot be listed.
#[derive(Debug, thiserror::Error)]
pub enum MaskListError {
    /// `rgb.txt` is unreadable.
    #[error(transparent)]
    List(#[from] DatasetError),
    /// A line of `rgb.txt` names no file.
    #[error("{}: no file name in {}", list.display(), entry.display())]
    NoFileName {
        /// `rgb.txt`.
        list: PathBuf,
        /// The entry.
        entry: PathBuf,
    },
    /// Fewer than two frames: nothing can move between them.
    #[error("{}: need at least 2 frames, found {found}", list.display())]
    TooShort {
        /// `rgb.txt`.
        list: PathBuf,
        /// Frames listed.
        found: usize,
    },
}

/// The ground-truth mask of each frame of a synthetic sequence (`mask/` beside `rgb/`, same
/// names): (timestamp, mask path), in the order of `rgb.txt`.
pub fn mask_frames(dir: &Path) -> Result<Vec<(f64, PathBuf)>, MaskListError> {
    let list = dir.join("rgb.txt");
    let frames = read_stamped_list(&list, dir)?
        .into_iter()
        .map(|(t, rgb)| {
            let name = rgb.file_name().ok_or_else(|| MaskListError::NoFileName {
                list: list.clone(),
                entry: rgb.clone(),
            })?;
            Ok((t, dir.join("mask").join(name)))
        })
        .collect::<Result<Vec<_>, MaskListError>>()?;
    if frames.len() < 2 {
        return Err(MaskListError::TooShort {
            list,
            found: frames.len(),
        });
    }
    Ok(frames)
}

/// Strict ground truth: a moving mask pixel (non-zero) within `radius` pixels (a square) of
/// the keypoint's rounded position.
pub fn strict_truth(mask: &Gray8, keypoints: &[[f32; 2]], radius: usize) -> Vec<bool> {
    let r = radius as isize;
    keypoints
        .iter()
        .map(|&[x, y]| {
            let (x, y) = (x.round() as isize, y.round() as isize);
            (-r..=r).any(|dy| {
                (-r..=r).any(|dx| mask.get_checked(x + dx, y + dy).is_some_and(|m| m > 0))
            })
        })
        .collect()
}

/// Per keypoint: how many of the 17 pixels of its FAST test (centre and 16-pixel circle of
/// radius 3, scaled by its level's factor in `scales`) are moving.
pub fn fast_test_moving(mask: &Gray8, keypoints: &[KeyPoint], scales: &[f32]) -> Vec<usize> {
    keypoints
        .iter()
        .map(|k| {
            let scale = scales.get(k.octave as usize).copied().unwrap_or(1.0);
            std::iter::once((0, 0))
                .chain(FAST_CIRCLE)
                .filter(|&(dx, dy)| {
                    let x = (k.x + dx as f32 * scale).round() as isize;
                    let y = (k.y + dy as f32 * scale).round() as isize;
                    mask.get_checked(x, y).is_some_and(|m| m > 0)
                })
                .count()
        })
        .collect()
}

/// Occlusion ground truth from [`fast_test_moving`]: dynamic when any pixel of the test moves.
pub fn support_truth(fast_moving: &[usize]) -> Vec<bool> {
    fast_moving.iter().map(|&m| m > 0).collect()
}

/// Clear ground truth from [`fast_test_moving`]: static when none of the 17 pixels moves,
/// dynamic when all do, not scored (`None`) when the test straddles a silhouette.
pub fn clear_truth(fast_moving: &[usize]) -> Vec<Option<bool>> {
    fast_moving
        .iter()
        .map(|&m| match m {
            0 => Some(false),
            17 => Some(true),
            _ => None,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 40x40, moving in the square x, y in 10..20.
    fn mask() -> Gray8 {
        let mut m = Gray8::new(40, 40, 0);
        for y in 10..20 {
            for x in 10..20 {
                m.set(x, y, 255);
            }
        }
        m
    }

    fn kp(x: f32, y: f32, octave: u8) -> KeyPoint {
        KeyPoint {
            x,
            y,
            octave,
            angle: 0.0,
            response: 0.0,
            size: 31.0,
        }
    }

    #[test]
    fn precision_and_recall_follow_the_counts() {
        let mut c = Counts::default();
        c.add(
            &[true, true, false, false, true],
            &[true, false, true, false, true],
        );
        assert_eq!(
            c,
            Counts {
                tp: 2,
                fp: 1,
                fn_: 1,
                tn: 1
            }
        );
        assert_eq!(c.precision(), Some(2.0 / 3.0));
        assert_eq!(c.recall(), Some(2.0 / 3.0));
        let none = Counts::default();
        assert_eq!((none.precision(), none.recall()), (None, None));
    }

    #[test]
    fn unknown_truths_are_not_counted() {
        let mut c = Counts::default();
        c.add_known(&[true, true, false], &[Some(true), None, Some(false)]);
        assert_eq!(
            c,
            Counts {
                tp: 1,
                fp: 0,
                fn_: 0,
                tn: 1
            }
        );
    }

    #[test]
    fn strict_truth_widens_with_the_radius() {
        let m = mask();
        let kps = [[15.0, 15.0], [8.6, 15.0], [5.0, 5.0]];
        assert_eq!(strict_truth(&m, &kps, 0), vec![true, false, false]);
        assert_eq!(strict_truth(&m, &kps, 1), vec![true, true, false]);
    }

    #[test]
    fn the_fast_test_sees_a_silhouette_at_its_level() {
        let m = mask();
        let kps = [
            kp(15.0, 15.0, 0), // all 17 pixels inside
            kp(30.0, 30.0, 0), // none
            kp(21.0, 15.0, 0), // centre outside, part of the circle inside
            kp(24.0, 15.0, 1), // level 1 (x2): the circle reaches 6 px, into the square
        ];
        let moving = fast_test_moving(&m, &kps, &[1.0, 2.0]);
        assert_eq!(moving[0], 17);
        assert_eq!(moving[1], 0);
        assert!(moving[2] > 0 && moving[2] < 17);
        assert!(moving[3] > 0 && moving[3] < 17);
        assert_eq!(support_truth(&moving), vec![true, false, true, true]);
        assert_eq!(
            clear_truth(&moving),
            vec![Some(true), Some(false), None, None]
        );
    }
}
