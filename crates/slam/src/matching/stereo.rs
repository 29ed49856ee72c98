//! Stereo matching for rectified pairs (ORB-SLAM's `Frame::ComputeStereoMatches`): each left
//! keypoint is matched by descriptor to the right keypoints on its rows (within a band that grows
//! with the pyramid level) at a disparity in [0, fx]; the match is refined by SAD on an 11x11
//! patch at the keypoint's level over +-5 pixels and a parabola through the best three costs;
//! matches whose SAD exceeds 1.5 x 1.4 x the median are dropped. The result is a depth per left
//! keypoint, which tracking uses as an RGB-D frame's depth.

use stillpoint_image::Gray8;

use crate::{Descriptor, Feature, hamming};
use stillpoint_image::stereo_depth::DenseStereoParams;

/// Stereo matching parameters (ORB-SLAM's values by default).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct StereoParams {
    /// Largest Hamming distance of a descriptor match ((TH_HIGH + TH_LOW) / 2 = 75).
    pub max_hamming: u32,
    /// Half height of the row band at level 0, in pixels, multiplied by the level's scale (2).
    pub row_band_px: f32,
    /// Half side of the SAD patch (5: 11x11).
    pub sad_half_window: usize,
    /// Pixels searched either side of the descriptor match at its level (5).
    pub sad_search: usize,
    /// Drop matches whose SAD exceeds this multiple of the median (1.5 x 1.4).
    pub sad_median_factor: f32,
    /// Dense depth for what reads a depth image: the dynamic front-end, map hygiene and the
    /// dense cloud (tracking keeps the per-keypoint depth above).
    pub dense_depth: DenseStereoParams,
}

impl Default for StereoParams {
    fn default() -> Self {
        Self {
            max_hamming: 75,
            row_band_px: 2.0,
            sad_half_window: 5,
            sad_search: 5,
            sad_median_factor: 1.5 * 1.4,
            dense_depth: DenseStereoParams::default(),
        }
    }
}

/// One image of a rectified pair: its keypoints (level-0 coordinates), descriptors and pyramid
/// levels (level 0 first, each scaled by `scales[l]`).
pub struct StereoView<'a> {
    /// Keypoints in level-0 pixels.
    pub keypoints: &'a [Feature],
    /// Their ORB descriptors.
    pub descriptors: &'a [Descriptor],
    /// The image's pyramid, level 0 first.
    pub levels: Vec<&'a Gray8>,
}

/// Depth (metres along the optical axis) of each left keypoint, 0.0 where it found no reliable
/// right match. `bf` is baseline x fx, `fx` the focal length in pixels, `scales` the pyramid's
/// scale per level (1.0, 1.2, 1.44, ...).
pub fn stereo_depths(
    left: &StereoView,
    right: &StereoView,
    bf: f64,
    fx: f64,
    scales: &[f32],
    p: &StereoParams,
) -> Vec<f32> {
    let n = left.keypoints.len();
    let mut depth = vec![0.0f32; n];
    let (Some(l0), Some(_)) = (left.levels.first(), right.levels.first()) else {
        return depth;
    };
    if !(bf > 0.0 && fx > 0.0) {
        return depth;
    }
    let scale = |o: u8| scales.get(o as usize).copied().unwrap_or(1.0);
    // Right keypoints by row: each registers in the rows its band covers.
    let height = l0.height;
    let mut rows: Vec<Vec<usize>> = vec![Vec::new(); height];
    for (j, k) in right.keypoints.iter().enumerate() {
        let r = p.row_band_px * scale(k.octave);
        let (lo, hi) = ((k.y - r).floor().max(0.0), (k.y + r).ceil());
        for row in rows.iter_mut().take(hi as usize + 1).skip(lo as usize) {
            row.push(j);
        }
    }
    let (min_d, max_d) = (0.0f32, fx as f32);
    let mut found: Vec<(u32, usize)> = Vec::new();
    for (i, kl) in left.keypoints.iter().enumerate() {
        let Some(candidates) = rows.get(kl.y.round().max(0.0) as usize) else {
            continue;
        };
        let (min_u, max_u) = (kl.x - max_d, kl.x - min_d);
        if max_u < 0.0 {
            continue;
        }
        // Best descriptor match among right keypoints one level around the left one's.
        let mut best = (u32::MAX, usize::MAX);
        for &j in candidates {
            let kr = &right.keypoints[j];
            if (kr.octave as i32 - kl.octave as i32).abs() > 1 || kr.x < min_u || kr.x > max_u {
                continue;
            }
            let d = hamming(&left.descriptors[i], &right.descriptors[j]);
            if d < best.0 {
                best = (d, j);
            }
        }
        if best.0 > p.max_hamming {
            continue;
        }
        let kr = &right.keypoints[best.1];
        let Some((u_right, sad)) = refine_by_sad(left, right, kl, kr.x, scale(kl.octave), p) else {
            continue;
        };
        let mut disparity = kl.x - u_right;
        if !(disparity >= min_d && disparity < max_d) {
            continue;
        }
        if disparity <= 0.0 {
            disparity = 0.01;
        }
        depth[i] = (bf / disparity as f64) as f32;
        found.push((sad, i));
    }
    // Drop the worst patch matches (ORB-SLAM: above 1.5 x 1.4 x the median SAD).
    if !found.is_empty() {
        let mut sads: Vec<u32> = found.iter().map(|f| f.0).collect();
        sads.sort_unstable();
        let limit = p.sad_median_factor * sads[sads.len() / 2] as f32;
        for &(sad, i) in &found {
            if sad as f32 > limit {
                depth[i] = 0.0;
            }
        }
    }
    depth
}

/// SAD search at the left keypoint's level around the descriptor match `u_right` (level 0),
/// with a parabola through the best cost and its neighbours. Returns the refined right column
/// (level 0) and the best SAD.
fn refine_by_sad(
    left: &StereoView,
    right: &StereoView,
    kl: &Feature,
    u_right: f32,
    scale: f32,
    p: &StereoParams,
) -> Option<(f32, u32)> {
    let level = kl.octave as usize;
    let (il, ir) = (left.levels.get(level)?, right.levels.get(level)?);
    let w = p.sad_half_window as isize;
    let l = p.sad_search as isize;
    // Level <-> level-0 pixels as the ORB extractor maps them: pixel centres aligned, with the
    // levels' true size ratio (`scale` is the nominal one, off by up to 0.3 %).
    let (ratio_x, ratio_y) = match left.levels.first() {
        Some(full) if il.width > 0 && il.height > 0 => (
            full.width as f32 / il.width as f32,
            full.height as f32 / il.height as f32,
        ),
        _ => (scale, scale),
    };
    let to_level = |u: f32, ratio: f32| ((u + 0.5) / ratio - 0.5).round() as isize;
    let (ul, vl) = (to_level(kl.x, ratio_x), to_level(kl.y, ratio_y));
    let ur0 = to_level(u_right, ratio_x);
    // The patches must stay inside both images over the whole search.
    if vl - w < 0
        || vl + w >= il.height as isize
        || ul - w < 0
        || ul + w >= il.width as isize
        || ur0 - l - w < 0
        || ur0 + l + w >= ir.width as isize
    {
        return None;
    }
    // ORB-SLAM compares patches with their centre intensity removed (robust to gain).
    let centre_l = il.get(ul as usize, vl as usize) as i32;
    let mut costs = Vec::with_capacity(2 * p.sad_search + 1);
    for inc in -l..=l {
        let centre_r = ir.get((ur0 + inc) as usize, vl as usize) as i32;
        let mut sad = 0u32;
        for dy in -w..=w {
            let (row_l, row_r) = (il.row((vl + dy) as usize), ir.row((vl + dy) as usize));
            for dx in -w..=w {
                let a = row_l[(ul + dx) as usize] as i32 - centre_l;
                let b = row_r[(ur0 + inc + dx) as usize] as i32 - centre_r;
                sad += (a - b).unsigned_abs();
            }
        }
        costs.push(sad);
    }
    let (best, &best_sad) = costs.iter().enumerate().min_by_key(|&(_, c)| *c)?;
    if best == 0 || best == costs.len() - 1 {
        return None;
    }
    let (d1, d2, d3) = (
        costs[best - 1] as f32,
        costs[best] as f32,
        costs[best + 1] as f32,
    );
    let denom = 2.0 * (d1 + d3 - 2.0 * d2);
    let delta = if denom.abs() > f32::EPSILON {
        (d1 - d3) / denom
    } else {
        0.0
    };
    if !(-1.0..=1.0).contains(&delta) {
        return None;
    }
    let u = ((ur0 + best as isize - l) as f32 + delta + 0.5) * ratio_x - 0.5;
    Some((u, best_sad))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A textured image and the same scene seen by a camera `shift` pixels to the right at every
    /// pixel (a fronto-parallel plane: constant disparity).
    fn pair(shift: usize) -> (Gray8, Gray8) {
        let (w, h) = (200, 120);
        // Smooth texture: a SAD parabola is exact only where intensity varies smoothly.
        let tex = |x: usize, y: usize| -> u8 {
            let (x, y) = (x as f32, y as f32);
            (128.0 + 60.0 * (0.35 * x + 0.1 * y).sin() + 50.0 * (0.27 * y - 0.05 * x).sin()) as u8
        };
        let mut l = Gray8::new(w, h, 0);
        let mut r = Gray8::new(w, h, 0);
        for y in 0..h {
            for x in 0..w {
                l.set(x, y, tex(x + 100, y));
                r.set(x, y, tex(x + 100 + shift, y));
            }
        }
        (l, r)
    }

    #[test]
    fn a_plane_at_constant_disparity_gets_its_depth() {
        let (l, r) = pair(8);
        // bf 40, disparity 8 px: 5 m.
        let kl: Vec<Feature> = (0..10)
            .map(|i| Feature {
                x: 60.0 + 10.0 * i as f32,
                y: 40.0 + 4.0 * i as f32,
                octave: 0,
                angle: 0.0,
            })
            .collect();
        // The right keypoints 8 px to the left; a descriptor each (equal in both views).
        let kr: Vec<Feature> = kl.iter().map(|k| Feature { x: k.x - 8.0, ..*k }).collect();
        let desc: Vec<Descriptor> = (0..10).map(|i| [i as u8 * 17; 32]).collect();
        let view = |k, img| StereoView {
            keypoints: k,
            descriptors: &desc,
            levels: vec![img],
        };
        let d = stereo_depths(
            &view(&kl, &l),
            &view(&kr, &r),
            40.0,
            500.0,
            &[1.0],
            &StereoParams::default(),
        );
        for z in &d {
            assert!((z - 5.0).abs() < 0.05, "{d:?}");
        }
        // No right keypoints: no depth; a right keypoint on another row is not matched.
        let none = stereo_depths(
            &view(&kl, &l),
            &StereoView {
                keypoints: &[],
                descriptors: &[],
                levels: vec![&r],
            },
            40.0,
            500.0,
            &[1.0],
            &StereoParams::default(),
        );
        assert!(none.iter().all(|&z| z == 0.0));
        let far: Vec<Feature> = kr
            .iter()
            .map(|k| Feature {
                y: k.y + 20.0,
                ..*k
            })
            .collect();
        let off = stereo_depths(
            &view(&kl, &l),
            &view(&far, &r),
            40.0,
            500.0,
            &[1.0],
            &StereoParams::default(),
        );
        assert!(off.iter().all(|&z| z == 0.0), "{off:?}");
    }
}
