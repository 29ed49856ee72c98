//! Descriptor matching: Hamming distance, brute force with ratio test and mutual check, search by
//! projection on a keypoint grid, and ORB-SLAM's rotation-consistency histogram.

use crate::{Descriptor, KeyPoint, OrbFeatures};

/// Hamming distance of two 256-bit descriptors (popcount of XOR over four u64).
///
/// ```
/// let a = [0u8; 32];
/// let mut b = [0u8; 32];
/// b[0] = 0b1011;
/// b[31] = 0x80;
/// assert_eq!(stillpoint_features::hamming(&a, &b), 4);
/// ```
#[inline]
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    let mut d = 0;
    for (x, y) in a.chunks_exact(8).zip(b.chunks_exact(8)) {
        let x = u64::from_le_bytes([x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7]]);
        let y = u64::from_le_bytes([y[0], y[1], y[2], y[3], y[4], y[5], y[6], y[7]]);
        d += (x ^ y).count_ones();
    }
    d
}

/// A descriptor match: `query` indexes the first set, `train` the second.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Match {
    /// Index in the first set.
    pub query: usize,
    /// Index in the second set.
    pub train: usize,
    /// Hamming distance of the two descriptors.
    pub distance: u32,
}

/// Brute-force matching settings.
#[derive(Clone, Debug, PartialEq)]
pub struct MatchParams {
    /// Largest accepted distance (ORB-SLAM `TH_HIGH` = 100 of 256 bits).
    pub max_distance: u32,
    /// Best must be below `ratio` x second best (Lowe's test; ORB-SLAM uses 0.6-0.9 by search,
    /// 0.8 is its local-map value).
    pub ratio: f32,
    /// Keep only pairs that are each other's best match (OpenCV's `crossCheck`).
    pub mutual: bool,
    /// Drop matches outside the three dominant bins of the keypoint-angle change
    /// ([`RotationHistogram`]; ORB-SLAM3's `mbCheckOrientation`, true in every ORB-SLAM3
    /// matcher). Needs the keypoints, so only [`match_keypoints`] applies it;
    /// [`match_brute_force`] sees descriptors only. Most of the matches it drops are RANSAC
    /// outliers. Measurements: docs/measurements.md.
    pub check_orientation: bool,
}

impl Default for MatchParams {
    fn default() -> Self {
        Self {
            max_distance: 100,
            ratio: 0.8,
            mutual: true,
            check_orientation: true,
        }
    }
}

/// Best and second-best distance with the best index.
#[inline]
fn best_two(d: &Descriptor, set: &[Descriptor]) -> (usize, u32, u32) {
    let (mut bi, mut b1, mut b2) = (usize::MAX, u32::MAX, u32::MAX);
    for (i, t) in set.iter().enumerate() {
        let h = hamming(d, t);
        if h < b1 {
            b2 = b1;
            b1 = h;
            bi = i;
        } else if h < b2 {
            b2 = h;
        }
    }
    (bi, b1, b2)
}

/// Match every `query` descriptor to its nearest `train` descriptor, keeping matches that pass
/// the distance threshold, the ratio test and (optionally) the mutual check.
pub fn match_brute_force(
    query: &[Descriptor],
    train: &[Descriptor],
    p: &MatchParams,
) -> Vec<Match> {
    let reverse: Vec<usize> = if p.mutual {
        train.iter().map(|t| best_two(t, query).0).collect()
    } else {
        Vec::new()
    };
    let mut out = Vec::new();
    for (qi, q) in query.iter().enumerate() {
        let (ti, d1, d2) = best_two(q, train);
        if ti == usize::MAX || d1 > p.max_distance {
            continue;
        }
        if d2 != u32::MAX && d1 as f32 >= p.ratio * d2 as f32 {
            continue;
        }
        if p.mutual && reverse[ti] != qi {
            continue;
        }
        out.push(Match {
            query: qi,
            train: ti,
            distance: d1,
        });
    }
    out
}

/// Match two sets of ORB features: [`match_brute_force`] on the descriptors, then (with
/// `p.check_orientation`) ORB-SLAM's rotation-consistency check on the keypoint angles. This is
/// the pipeline the inlier-ratio claim against OpenCV uses (see the crate docs).
///
/// ```
/// use stillpoint_features::{MatchParams, OrbExtractor, OrbParams, match_keypoints};
/// use stillpoint_image::Gray8;
/// let mut img = Gray8::new(160, 120, 0);
/// for y in 0..120 { for x in 0..160 {
///     img.set(x, y, (((x / 7) * 37 + (y / 5) * 91 + (x * y) % 13) % 256) as u8);
/// }}
/// let mut orb = OrbExtractor::new(OrbParams { n_features: 200, ..OrbParams::default() });
/// let f = orb.extract(&img);
/// let m = match_keypoints(&f, &f, &MatchParams::default());
/// assert!(m.iter().all(|m| m.query == m.train && m.distance == 0));
/// ```
pub fn match_keypoints(a: &OrbFeatures, b: &OrbFeatures, p: &MatchParams) -> Vec<Match> {
    let mut matches = match_brute_force(&a.descriptors, &b.descriptors, p);
    if p.check_orientation {
        let mut hist = RotationHistogram::default();
        for (i, m) in matches.iter().enumerate() {
            if let (Some(ka), Some(kb)) = (a.keypoints.get(m.query), b.keypoints.get(m.train)) {
                hist.add(ka.angle, kb.angle, i);
            }
        }
        let mut keep = vec![true; matches.len()];
        for i in hist.inconsistent() {
            keep[i] = false;
        }
        let mut k = keep.iter();
        matches.retain(|_| k.next().copied().unwrap_or(true));
    }
    matches
}

/// Keypoint indices bucketed on a grid over the image (ORB-SLAM's 64 x 48 frame grid), for
/// finding the keypoints near a predicted position.
#[derive(Clone, Debug)]
pub struct KeypointGrid {
    cols: usize,
    rows: usize,
    inv_cell_w: f32,
    inv_cell_h: f32,
    cells: Vec<Vec<u32>>,
    pts: Vec<(f32, f32, u8)>,
}

impl KeypointGrid {
    /// ORB-SLAM `FRAME_GRID_COLS`.
    pub const COLS: usize = 64;
    /// ORB-SLAM `FRAME_GRID_ROWS`.
    pub const ROWS: usize = 48;

    /// Bucket `keypoints` of an image of `width` x `height` pixels. Keypoints outside the image
    /// (or NaN) are left out.
    pub fn new(keypoints: &[KeyPoint], width: usize, height: usize) -> Self {
        let (cols, rows) = (Self::COLS, Self::ROWS);
        let inv_cell_w = cols as f32 / width.max(1) as f32;
        let inv_cell_h = rows as f32 / height.max(1) as f32;
        let mut cells = vec![Vec::new(); cols * rows];
        for (i, k) in keypoints.iter().enumerate() {
            let (cx, cy) = (k.x * inv_cell_w, k.y * inv_cell_h);
            if cx >= 0.0 && cy >= 0.0 && (cx as usize) < cols && (cy as usize) < rows {
                cells[cy as usize * cols + cx as usize].push(i as u32);
            }
        }
        let pts = keypoints.iter().map(|k| (k.x, k.y, k.octave)).collect();
        Self {
            cols,
            rows,
            inv_cell_w,
            inv_cell_h,
            cells,
            pts,
        }
    }

    /// Indices of keypoints with |dx| < radius and |dy| < radius of (x, y) and octave in
    /// `[min_octave, max_octave]`; a negative bound means no bound (ORB-SLAM
    /// `Frame::GetFeaturesInArea`).
    pub fn candidates(
        &self,
        x: f32,
        y: f32,
        radius: f32,
        min_octave: i32,
        max_octave: i32,
    ) -> Vec<usize> {
        let mut out = Vec::new();
        if !(x.is_finite() && y.is_finite() && radius.is_finite() && radius > 0.0) {
            return out;
        }
        let c0 = ((x - radius) * self.inv_cell_w).floor().max(0.0) as usize;
        let c1 = ((x + radius) * self.inv_cell_w).floor();
        let r0 = ((y - radius) * self.inv_cell_h).floor().max(0.0) as usize;
        let r1 = ((y + radius) * self.inv_cell_h).floor();
        if c1 < 0.0 || r1 < 0.0 || c0 >= self.cols || r0 >= self.rows {
            return out;
        }
        let c1 = (c1 as usize).min(self.cols - 1);
        let r1 = (r1 as usize).min(self.rows - 1);
        for r in r0..=r1 {
            for c in c0..=c1 {
                for &i in &self.cells[r * self.cols + c] {
                    let (kx, ky, o) = self.pts[i as usize];
                    let o = o as i32;
                    if (min_octave >= 0 && o < min_octave) || (max_octave >= 0 && o > max_octave) {
                        continue;
                    }
                    if (kx - x).abs() < radius && (ky - y).abs() < radius {
                        out.push(i as usize);
                    }
                }
            }
        }
        out
    }
}

/// A point to look for in a frame: predicted pixel, predicted octave, its descriptor and
/// (for the rotation check) the angle of the keypoint it came from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Projected {
    /// Predicted column, level-0 pixels.
    pub x: f32,
    /// Predicted row, level-0 pixels.
    pub y: f32,
    /// Predicted pyramid level.
    pub octave: u8,
    /// The descriptor to match.
    pub descriptor: Descriptor,
    /// Angle of the keypoint it came from, degrees (`None`: no rotation check).
    pub angle: Option<f32>,
}

/// Search-by-projection settings.
#[derive(Clone, Debug, PartialEq)]
pub struct ProjectionParams {
    /// Window half-size in level-0 pixels, multiplied by the scale of the predicted octave
    /// (ORB-SLAM motion model: 7 RGB-D/stereo, 15 monocular).
    pub radius: f32,
    /// Search octaves predicted ± this (ORB-SLAM motion model: 1).
    pub octave_margin: u8,
    /// Largest accepted distance (ORB-SLAM `TH_HIGH` 100).
    pub max_distance: u32,
    /// Ratio test between best and second best at the same octave (ORB-SLAM local map: 0.8;
    /// 1.0 switches it off, as in the motion-model search).
    pub ratio: f32,
    /// Rotation-histogram consistency (ORB-SLAM `mbCheckOrientation`, on by default).
    pub check_orientation: bool,
}

impl Default for ProjectionParams {
    fn default() -> Self {
        Self {
            radius: 7.0,
            octave_margin: 1,
            max_distance: 100,
            ratio: 1.0,
            check_orientation: true,
        }
    }
}

/// Match each projected point to the best keypoint of a frame within its window. Each frame
/// keypoint is given to at most one point (the closest in descriptor distance). Returns one
/// entry per point: `Some(Match { query: point index, train: keypoint index, distance })`.
pub fn search_by_projection(
    points: &[Projected],
    keypoints: &[KeyPoint],
    descriptors: &[Descriptor],
    grid: &KeypointGrid,
    scale_factors: &[f32],
    p: &ProjectionParams,
) -> Vec<Option<Match>> {
    let mut out: Vec<Option<Match>> = vec![None; points.len()];
    let mut owner: Vec<Option<usize>> = vec![None; keypoints.len()];
    for (pi, pt) in points.iter().enumerate() {
        let scale = scale_factors
            .get(pt.octave as usize)
            .copied()
            .unwrap_or(1.0);
        let lo = pt.octave.saturating_sub(p.octave_margin) as i32;
        let hi = pt.octave as i32 + p.octave_margin as i32;
        let cands = grid.candidates(pt.x, pt.y, p.radius * scale, lo, hi);
        let (mut best, mut b1, mut b2, mut best_oct) = (usize::MAX, u32::MAX, u32::MAX, 0u8);
        for k in cands {
            let Some(d) = descriptors.get(k) else {
                continue;
            };
            let h = hamming(&pt.descriptor, d);
            if h < b1 {
                b2 = if keypoints[k].octave == best_oct || best == usize::MAX {
                    b1
                } else {
                    b2
                };
                b1 = h;
                best = k;
                best_oct = keypoints[k].octave;
            } else if h < b2 && keypoints[k].octave == best_oct {
                b2 = h;
            }
        }
        if best == usize::MAX || b1 > p.max_distance {
            continue;
        }
        if p.ratio < 1.0 && b2 != u32::MAX && b1 as f32 > p.ratio * b2 as f32 {
            continue;
        }
        if let Some(prev) = owner[best] {
            match out[prev] {
                Some(m) if m.distance <= b1 => continue,
                _ => out[prev] = None,
            }
        }
        owner[best] = Some(pi);
        out[pi] = Some(Match {
            query: pi,
            train: best,
            distance: b1,
        });
    }
    if p.check_orientation {
        let mut hist = RotationHistogram::default();
        for m in out.iter().flatten() {
            if let Some(a) = points[m.query].angle {
                hist.add(a, keypoints[m.train].angle, m.query);
            }
        }
        for i in hist.inconsistent() {
            out[i] = None;
        }
    }
    out
}

/// ORB-SLAM's rotation-consistency check: histogram of the angle change of each match; matches
/// outside the three biggest bins are rejected (the 2nd and 3rd bins count only if they hold at
/// least 10 % of the biggest). Bins are 360/`n` degrees wide (ORB-SLAM's code multiplies by
/// 1/30 instead of 30/360, i.e. uses 12 bins of 30 degrees; here the 30 bins are really 30).
#[derive(Clone, Debug)]
pub struct RotationHistogram {
    bins: Vec<Vec<usize>>,
}

impl Default for RotationHistogram {
    /// ORB-SLAM `HISTO_LENGTH` = 30 bins.
    fn default() -> Self {
        Self::new(30)
    }
}

impl RotationHistogram {
    /// A histogram with `n_bins` bins (at least 1).
    pub fn new(n_bins: usize) -> Self {
        Self {
            bins: vec![Vec::new(); n_bins.max(1)],
        }
    }

    /// Record match `id` whose keypoint angle went from `angle_from` to `angle_to` (degrees).
    /// Non-finite angles are ignored (such a match is neither consistent nor inconsistent).
    pub fn add(&mut self, angle_from: f32, angle_to: f32, id: usize) {
        let rot = (angle_from - angle_to).rem_euclid(360.0);
        if !rot.is_finite() {
            return;
        }
        let n = self.bins.len();
        let bin = (rot * n as f32 / 360.0).round() as usize % n;
        self.bins[bin].push(id);
    }

    fn top_bins(&self) -> Vec<usize> {
        let mut order: Vec<usize> = (0..self.bins.len()).collect();
        order.sort_by_key(|&b| std::cmp::Reverse(self.bins[b].len()));
        let max = self.bins[order[0]].len();
        let mut keep = vec![order[0]];
        for &b in order.iter().skip(1).take(2) {
            let n = self.bins[b].len();
            if n == 0 || (n as f32) < 0.1 * max as f32 {
                break;
            }
            keep.push(b);
        }
        keep
    }

    /// Ids in the three dominant bins.
    pub fn consistent(&self) -> Vec<usize> {
        let top = self.top_bins();
        top.iter()
            .flat_map(|&b| self.bins[b].iter().copied())
            .collect()
    }

    /// Ids outside the three dominant bins (ORB-SLAM removes these matches).
    pub fn inconsistent(&self) -> Vec<usize> {
        let top = self.top_bins();
        (0..self.bins.len())
            .filter(|b| !top.contains(b))
            .flat_map(|b| self.bins[b].iter().copied())
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn desc(seed: u32) -> Descriptor {
        let mut rng = crate::test_rng::Lcg(seed.wrapping_mul(2654435761).wrapping_add(1));
        std::array::from_fn(|_| rng.byte())
    }

    fn flip_bits(d: &Descriptor, n: usize) -> Descriptor {
        let mut o = *d;
        for i in 0..n {
            o[(i * 7) % 32] ^= 1 << (i % 8);
        }
        o
    }

    fn kp(x: f32, y: f32, octave: u8, angle: f32) -> KeyPoint {
        KeyPoint {
            x,
            y,
            octave,
            angle,
            response: 1.0,
            size: 31.0,
        }
    }

    #[test]
    fn match_keypoints_drops_matches_whose_rotation_disagrees() {
        let n = 40;
        let descriptors: Vec<Descriptor> = (0..n).map(|i| desc(i as u32)).collect();
        let a = OrbFeatures {
            keypoints: (0..n).map(|i| kp(i as f32, 0.0, 0, 10.0)).collect(),
            descriptors: descriptors.clone(),
        };
        // the image turned by 5 degrees, except three keypoints whose angle jumped by 90
        let b = OrbFeatures {
            keypoints: (0..n)
                .map(|i| kp(i as f32, 0.0, 0, if i % 13 == 1 { 100.0 } else { 15.0 }))
                .collect(),
            descriptors: descriptors.iter().map(|d| flip_bits(d, 5)).collect(),
        };
        let on = match_keypoints(&a, &b, &MatchParams::default());
        assert_eq!(on.len(), n - 3);
        assert!(on.iter().all(|m| m.query == m.train && m.query % 13 != 1));
        let off = MatchParams {
            check_orientation: false,
            ..MatchParams::default()
        };
        assert_eq!(match_keypoints(&a, &b, &off).len(), n);
        let empty = OrbFeatures {
            keypoints: vec![],
            descriptors: vec![],
        };
        assert!(match_keypoints(&empty, &b, &MatchParams::default()).is_empty());
    }

    #[test]
    fn brute_force_finds_noisy_copies_and_rejects_ambiguous() {
        let train: Vec<Descriptor> = (0..200).map(desc).collect();
        let mut query: Vec<Descriptor> = (0..50).map(|i| flip_bits(&train[i * 3], 10)).collect();
        // an ambiguous query: halfway between two train descriptors
        let mut amb = train[1];
        for i in 0..32 {
            if i % 2 == 0 {
                amb[i] = train[2][i];
            }
        }
        query.push(amb);
        let m = match_brute_force(&query, &train, &MatchParams::default());
        assert_eq!(m.len(), 50);
        assert!(m.iter().all(|m| m.train == m.query * 3 && m.distance <= 10));
        assert!(match_brute_force(&[], &train, &MatchParams::default()).is_empty());
        assert!(match_brute_force(&query, &[], &MatchParams::default()).is_empty());
    }

    #[test]
    fn grid_returns_exactly_the_points_in_the_window() {
        let kps: Vec<KeyPoint> = (0..500)
            .map(|i| {
                kp(
                    (i * 37 % 640) as f32 + 0.5,
                    (i * 53 % 480) as f32,
                    (i % 8) as u8,
                    0.0,
                )
            })
            .collect();
        let grid = KeypointGrid::new(&kps, 640, 480);
        for &(x, y, r, lo, hi) in &[
            (100.0, 100.0, 30.0, -1, -1),
            (0.0, 0.0, 50.0, 2, 4),
            (639.0, 479.0, 80.0, -1, 3),
        ] {
            let mut got = grid.candidates(x, y, r, lo, hi);
            got.sort();
            let want: Vec<usize> = (0..kps.len())
                .filter(|&i| {
                    let k = &kps[i];
                    (k.x - x).abs() < r
                        && (k.y - y).abs() < r
                        && (lo < 0 || k.octave as i32 >= lo)
                        && (hi < 0 || k.octave as i32 <= hi)
                })
                .collect();
            assert_eq!(got, want);
        }
        assert!(grid.candidates(f32::NAN, 1.0, 5.0, -1, -1).is_empty());
        assert!(grid.candidates(-500.0, -500.0, 5.0, -1, -1).is_empty());
    }

    #[test]
    fn projection_search_with_rotation_check() {
        let descs: Vec<Descriptor> = (0..100).map(desc).collect();
        let kps: Vec<KeyPoint> = (0..100)
            .map(|i| {
                kp(
                    (i % 10) as f32 * 60.0 + 20.0,
                    (i / 10) as f32 * 45.0 + 20.0,
                    0,
                    10.0,
                )
            })
            .collect();
        let grid = KeypointGrid::new(&kps, 640, 480);
        let scales = [1.0, 1.2];
        let mut points: Vec<Projected> = (0..100)
            .map(|i| Projected {
                x: kps[i].x + 2.0,
                y: kps[i].y - 1.5,
                octave: 0,
                descriptor: flip_bits(&descs[i], 20),
                angle: Some(15.0),
            })
            .collect();
        // one point whose rotation disagrees with all others
        points[5].angle = Some(200.0);
        let m = search_by_projection(
            &points,
            &kps,
            &descs,
            &grid,
            &scales,
            &ProjectionParams::default(),
        );
        for (i, r) in m.iter().enumerate() {
            if i == 5 {
                assert!(r.is_none());
            } else {
                assert_eq!(r.map(|m| m.train), Some(i));
            }
        }
    }

    #[test]
    fn rotation_histogram_keeps_the_dominant_rotations() {
        let mut h = RotationHistogram::default();
        for i in 0..50 {
            h.add(100.0, 90.0 + (i % 3) as f32, i); // about +10 degrees
        }
        h.add(0.0, 180.0, 100);
        h.add(f32::NAN, 0.0, 101);
        let bad = h.inconsistent();
        assert_eq!(bad, vec![100]);
        assert_eq!(h.consistent().len(), 50);
    }
}
