//! Descriptor matching: by projection (motion model, local map), by brute force with a ratio test
//! (reference keyframe, relocalisation), in a window for monocular initialisation ([`area`]), along
//! epipolar lines for triangulation ([`epipolar`]), and the rotation-consistency histogram.

pub mod area;
pub mod epipolar;
pub mod stereo;

use stillpoint_geometry::{PinholeCamera, Se3, Vec3};

use crate::data::{Frame, KeyFrame, Map, MpId};
use crate::{Descriptor, SlamSettings, hamming};

/// Bins of the rotation histogram (ORB-SLAM `HISTO_LENGTH`).
const HISTO_LENGTH: usize = 30;

/// The nearest of some candidates by descriptor distance, and the second-nearest distance
/// (ORB-SLAM's bestDist / bestDist2 loops); `u32::MAX` where there is none.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NearestTwo {
    /// Distance of the nearest.
    pub distance: u32,
    /// Index of the nearest among the candidates.
    pub index: usize,
    /// Distance of the second nearest.
    pub second: u32,
}

impl NearestTwo {
    /// Over (candidate index, Hamming distance) pairs; on ties the first candidate stays.
    pub fn of(candidates: impl IntoIterator<Item = (usize, u32)>) -> Self {
        let mut n = NearestTwo {
            distance: u32::MAX,
            index: usize::MAX,
            second: u32::MAX,
        };
        for (i, d) in candidates {
            if d < n.distance {
                n.second = n.distance;
                n.distance = d;
                n.index = i;
            } else if d < n.second {
                n.second = d;
            }
        }
        n
    }

    /// ORB-SLAM's acceptance: within `th_low` and clearly nearer than the second
    /// (`distance < ratio x second`).
    pub fn accepted(&self, th_low: u32, ratio: f32) -> bool {
        self.distance <= th_low && (self.distance as f32) < ratio * self.second as f32
    }
}

/// Keep only matches whose orientation change falls in the three most populated bins of a
/// 30-bin histogram (ORB-SLAM's `ComputeThreeMaxima`). `matches` holds (frame keypoint,
/// rotation change in degrees); returns the indices into `matches` to discard.
pub fn rotation_outliers(matches: &[(usize, f32)]) -> Vec<usize> {
    let mut hist: Vec<Vec<usize>> = vec![Vec::new(); HISTO_LENGTH];
    let factor = HISTO_LENGTH as f32 / 360.0;
    for (m, &(_, rot)) in matches.iter().enumerate() {
        let mut r = rot % 360.0;
        if r < 0.0 {
            r += 360.0;
        }
        let bin = ((r * factor).round() as usize) % HISTO_LENGTH;
        hist[bin].push(m);
    }
    let mut counts: Vec<(usize, usize)> =
        hist.iter().enumerate().map(|(i, h)| (h.len(), i)).collect();
    counts.sort_by(|a, b| b.cmp(a));
    let (m1, m2, m3) = (counts[0].0, counts[1].0, counts[2].0);
    // ORB-SLAM drops the 2nd / 3rd bins when they are much smaller than the first.
    let keep2 = m2 as f32 >= 0.1 * m1 as f32;
    let keep3 = keep2 && m3 as f32 >= 0.1 * m1 as f32;
    let mut keep = vec![counts[0].1];
    if keep2 {
        keep.push(counts[1].1);
    }
    if keep3 {
        keep.push(counts[2].1);
    }
    let mut out = Vec::new();
    for (bin, h) in hist.iter().enumerate() {
        if !keep.contains(&bin) {
            out.extend_from_slice(h);
        }
    }
    out
}

/// Project the map points matched in `last` into `cur` (whose `pose_cw` holds the prediction)
/// and match within `radius` x octave scale (ORB-SLAM `SearchByProjection(CurrentFrame,
/// LastFrame)`). Returns the number of new matches.
pub fn search_by_projection_last(
    cur: &mut Frame,
    last: &Frame,
    map: &Map,
    radius: f64,
    s: &SlamSettings,
) -> usize {
    let Some(pose) = cur.pose_cw else {
        return 0;
    };
    let scales = s.scale_factors();
    let cam = &s.camera;
    let mut rot = Vec::new();
    let mut nmatches = 0;
    for (i, mp) in last.map_points.iter().enumerate() {
        let Some(mp) = mp else { continue };
        if last.outliers[i] {
            continue;
        }
        let Some(p) = map.points.get(mp) else {
            continue;
        };
        let pc = pose * nalgebra::Point3::from(p.position);
        let Some(uv) = cam.project_undistorted(&pc.coords) else {
            continue;
        };
        if !cam.in_image(&uv, 0.0) {
            continue;
        }
        let o = last.octaves[i] as i32;
        let r = radius * scales[o as usize];
        let cands = cur.features_in_area(uv.x, uv.y, r, o - 1, o + 1);
        let ur_pred = uv.x - s.bf / pc.z;
        let mut best = (u32::MAX, usize::MAX);
        for c in cands {
            if cur.map_points[c].is_some() {
                continue;
            }
            if cur.u_right[c] > 0.0 && ((ur_pred - cur.u_right[c] as f64).abs() > r) {
                continue;
            }
            let d = hamming(&p.descriptor, &cur.descriptors[c]);
            if d > s.th_low && cur.close_match_only.get(c).copied().unwrap_or(false) {
                continue;
            }
            if d < best.0 {
                best = (d, c);
            }
        }
        if best.0 <= s.th_high {
            cur.map_points[best.1] = Some(*mp);
            cur.outliers[best.1] = false;
            rot.push((best.1, last.angles[i] - cur.angles[best.1]));
            nmatches += 1;
        }
    }
    for m in rotation_outliers(&rot) {
        cur.map_points[rot[m].0] = None;
        nmatches -= 1;
    }
    nmatches
}

/// A local map point prepared for projection into the current frame.
pub struct ProjectedPoint {
    /// The map point.
    pub id: MpId,
    /// Its projection's column, undistorted pixels.
    pub u: f64,
    /// Its projection's row.
    pub v: f64,
    /// Its virtual right coordinate (u - bf / z).
    pub u_right: f64,
    /// The pyramid level it should be seen at from this distance.
    pub level: i32,
    /// Cosine of the angle between the viewing ray and the point's mean viewing direction.
    pub view_cos: f64,
}

/// Frustum test (ORB-SLAM `Frame::isInFrustum`): in front, in the image, within the scale-
/// invariance distances and seen within 60 degrees of its mean viewing direction.
pub fn project_in_frustum(
    map: &Map,
    mp: MpId,
    pose_cw: &Se3,
    center: &Vec3,
    s: &SlamSettings,
) -> Option<ProjectedPoint> {
    let p = map.points.get(&mp)?;
    if p.bad {
        return None;
    }
    let cam: &PinholeCamera = &s.camera;
    let pc = pose_cw * nalgebra::Point3::from(p.position);
    let uv = cam.project_undistorted(&pc.coords)?;
    if !cam.in_image(&uv, 0.0) {
        return None;
    }
    if !p.in_viewing_range(center) {
        return None;
    }
    let po = p.position - center;
    let dist = po.norm();
    let view_cos = po.dot(&p.normal) / dist.max(1e-12);
    let level = p.predict_scale(dist, s.scale_factor.ln(), s.n_levels);
    Some(ProjectedPoint {
        id: mp,
        u: uv.x,
        v: uv.y,
        u_right: uv.x - s.bf / pc.z,
        level,
        view_cos,
    })
}

/// Match projected local-map points into `cur` (ORB-SLAM `SearchByProjection(F, vpMapPoints,
/// th)`): window th x (2.5 or 4 by viewing angle) x scale, octave in [level-1, level], ratio test.
pub fn search_by_projection_local(
    cur: &mut Frame,
    projected: &[ProjectedPoint],
    map: &Map,
    th: f64,
    s: &SlamSettings,
) -> usize {
    let scales = s.scale_factors();
    let mut n = 0;
    for pp in projected {
        let Some(p) = map.points.get(&pp.id) else {
            continue;
        };
        let r_view = if pp.view_cos > 0.998 { 2.5 } else { 4.0 };
        let r = th * r_view * scales[pp.level as usize];
        let cands = cur.features_in_area(pp.u, pp.v, r, pp.level - 1, pp.level);
        let (mut best, mut second) = ((u32::MAX, usize::MAX), u32::MAX);
        let mut best_level = -1;
        let mut second_level = -1;
        for c in cands {
            if let Some(existing) = cur.map_points[c]
                && map
                    .points
                    .get(&existing)
                    .is_some_and(|q| !q.observations.is_empty())
            {
                continue;
            }
            if cur.u_right[c] > 0.0 && (pp.u_right - cur.u_right[c] as f64).abs() > r {
                continue;
            }
            let d = hamming(&p.descriptor, &cur.descriptors[c]);
            if d > s.th_low && cur.close_match_only.get(c).copied().unwrap_or(false) {
                continue;
            }
            if d < best.0 {
                second = best.0;
                second_level = best_level;
                best = (d, c);
                best_level = cur.octaves[c] as i32;
            } else if d < second {
                second = d;
                second_level = cur.octaves[c] as i32;
            }
        }
        if best.0 <= s.th_high {
            if best_level == second_level && best.0 as f32 > s.local_map_ratio * second as f32 {
                continue;
            }
            cur.map_points[best.1] = Some(pp.id);
            cur.outliers[best.1] = false;
            n += 1;
        }
    }
    n
}

/// Brute-force match the keyframe's map points against the frame's keypoints, TH_LOW and the
/// nearest/second `ratio`, with rotation consistency. Writes matches into `cur.map_points`
/// (replacing nothing already there); returns how many. Stands in for ORB-SLAM's BoW search.
pub fn search_by_descriptors(
    cur: &mut Frame,
    kf: &KeyFrame,
    map: &Map,
    ratio: f32,
    th_low: u32,
) -> usize {
    let mut rot = Vec::new();
    let mut taken: Vec<Option<(u32, usize)>> = vec![None; cur.len()];
    for (i, mp) in kf.map_points.iter().enumerate() {
        let Some(mp) = mp else { continue };
        if map.points.get(mp).is_none_or(|p| p.bad) {
            continue;
        }
        let d_kf: &Descriptor = &kf.descriptors[i];
        let best = NearestTwo::of(
            cur.descriptors
                .iter()
                .enumerate()
                .filter(|(c, _)| cur.map_points[*c].is_none())
                .map(|(c, dc)| (c, hamming(d_kf, dc))),
        );
        if best.accepted(th_low, ratio) {
            let c = best.index;
            if taken[c].is_none_or(|(d, _)| best.distance < d) {
                taken[c] = Some((best.distance, i));
            }
        }
    }
    for (c, t) in taken.iter().enumerate() {
        if let Some((_, i)) = t {
            cur.map_points[c] = kf.map_points[*i];
            cur.outliers[c] = false;
            rot.push((c, kf.angles[*i] - cur.angles[c]));
        }
    }
    let mut n = rot.len();
    for m in rotation_outliers(&rot) {
        cur.map_points[rot[m].0] = None;
        n -= 1;
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_two_keeps_the_first_of_ties_and_tracks_the_second() {
        let n = NearestTwo::of([(4, 30), (7, 20), (9, 20), (2, 50)]);
        assert_eq!((n.distance, n.index, n.second), (20, 7, 20));
        assert!(!n.accepted(50, 0.9), "a tie is not clearly nearer");
        let n = NearestTwo::of([(1, 40), (3, 10)]);
        assert_eq!((n.distance, n.index, n.second), (10, 3, 40));
        assert!(n.accepted(50, 0.9) && !n.accepted(9, 0.9));
        let none = NearestTwo::of([]);
        assert_eq!(none.index, usize::MAX);
        assert!(!none.accepted(u32::MAX, 1.0));
    }

    /// A map point 2 m ahead of a frame at the origin (seen by keypoint 0 of its first
    /// keyframe, descriptor all zeros) and a frame whose one keypoint lies where it projects,
    /// its descriptor `bits` bits away from the point's.
    fn point_and_frame(bits: usize) -> (Map, Frame, Frame, SlamSettings) {
        use crate::Feature;
        let cam = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
        let s = SlamSettings::monocular(cam, 30.0);
        let at_centre = [Feature {
            x: 320.0,
            y: 240.0,
            octave: 0,
            angle: 0.0,
        }];
        let mut seen = Frame::new(0, 0.0, &at_centre, &[[0u8; 32]], None, &s).unwrap();
        seen.pose_cw = Some(Se3::identity());
        let mut map = Map::new();
        let kf = map.add_keyframe(&seen).unwrap();
        let mp = map.add_point(Vec3::new(0.0, 0.0, 2.0), kf, 0).unwrap();
        map.update_point(mp, &s.scale_factors());
        seen.map_points[0] = Some(mp);
        let mut descriptor = [0u8; 32];
        for b in 0..bits {
            descriptor[b / 8] |= 1 << (b % 8);
        }
        let mut cur = Frame::new(1, 0.1, &at_centre, &[descriptor], None, &s).unwrap();
        cur.pose_cw = Some(Se3::identity());
        (map, seen, cur, s)
    }

    #[test]
    fn a_close_match_only_keypoint_matches_only_within_th_low() {
        for (bits, close_only, matched) in [(70, false, true), (70, true, false), (30, true, true)]
        {
            let (map, last, mut cur, s) = point_and_frame(bits);
            assert!(s.th_low < 70 && 70 <= s.th_high && 30 <= s.th_low);
            if close_only {
                cur.close_match_only = vec![true];
            }
            let mut local = cur.clone();
            let by_motion = search_by_projection_last(&mut cur, &last, &map, 15.0, &s);
            assert_eq!(
                by_motion == 1,
                matched,
                "last frame, {bits} bits, {close_only}"
            );
            let centre = Vec3::zeros();
            let pose = Se3::identity();
            let projected: Vec<_> = map
                .points
                .keys()
                .filter_map(|&mp| project_in_frustum(&map, mp, &pose, &centre, &s))
                .collect();
            let n = search_by_projection_local(&mut local, &projected, &map, 1.0, &s);
            assert_eq!(n == 1, matched, "local map, {bits} bits, {close_only}");
        }
    }

    #[test]
    fn rotation_histogram_drops_inconsistent_matches() {
        let mut m: Vec<(usize, f32)> = (0..50).map(|i| (i, 10.0 + (i % 3) as f32)).collect();
        m.push((50, 180.0));
        m.push((51, -90.0));
        let mut out = rotation_outliers(&m);
        out.sort_unstable();
        assert_eq!(out, vec![50, 51]);
    }
}
