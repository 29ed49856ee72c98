//! Matching in a window around where a keypoint was last seen, for monocular initialisation
//! (ORB-SLAM `ORBmatcher::SearchForInitialization`, stella_vslam `match::area`).

use stillpoint_geometry::Vec2;

use super::{NearestTwo, rotation_outliers};
use crate::data::Frame;
use crate::hamming;

/// Match the level-0 keypoints of `reference` to those of `cur` found within a square window of
/// half-size `window` around `prev_matched[i]` (where keypoint i was last matched; its own
/// position at first): Hamming <= `th_low`, nearest < `ratio` x second, one keypoint of `cur` per
/// match (the closer descriptor wins), rotation-consistent. `prev_matched` is updated to the new
/// positions. Returns, per reference keypoint, the matched keypoint of `cur`.
pub fn search_for_initialisation(
    reference: &Frame,
    cur: &Frame,
    prev_matched: &mut [Vec2],
    window: f64,
    ratio: f32,
    th_low: u32,
    max_octave: i32,
) -> Vec<Option<usize>> {
    let mut matches12: Vec<Option<usize>> = vec![None; reference.len()];
    let mut matches21: Vec<Option<usize>> = vec![None; cur.len()];
    let mut distance21 = vec![u32::MAX; cur.len()];
    for i1 in 0..reference.len().min(prev_matched.len()) {
        let octave = reference.octaves[i1] as i32;
        if octave > max_octave {
            continue;
        }
        let at = prev_matched[i1];
        // A keypoint of `cur` already matched at least as closely is no candidate.
        let best = NearestTwo::of(
            cur.features_in_area(at.x, at.y, window, octave, octave)
                .into_iter()
                .map(|i2| {
                    (
                        i2,
                        hamming(&reference.descriptors[i1], &cur.descriptors[i2]),
                    )
                })
                .filter(|&(i2, d)| distance21[i2] > d),
        );
        if best.accepted(th_low, ratio) {
            let i2 = best.index;
            if let Some(old) = matches21[i2] {
                matches12[old] = None;
            }
            matches12[i1] = Some(i2);
            matches21[i2] = Some(i1);
            distance21[i2] = best.distance;
        }
    }
    let rot: Vec<(usize, f32)> = matches12
        .iter()
        .enumerate()
        .filter_map(|(i1, m)| m.map(|i2| (i1, reference.angles[i1] - cur.angles[i2])))
        .collect();
    for k in rotation_outliers(&rot) {
        matches12[rot[k].0] = None;
    }
    for (i1, m) in matches12.iter().enumerate() {
        if let Some(i2) = m {
            prev_matched[i1] = cur.points[*i2];
        }
    }
    matches12
}
