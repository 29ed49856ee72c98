//! Map points and keypoints on moving objects, judged by the generator's per-pixel masks
//! (`mask/<timestamp>.png` of a `stillpoint synth --masks` sequence: 255 where something moves).

use std::collections::BTreeSet;
use std::path::Path;

use stillpoint_image::Gray8;
use stillpoint_slam::data::map::Map;

/// The generator's mask of the frame at `timestamp` (255 = moving), when the sequence has one.
pub fn moving_mask(dataset: &Path, timestamp: f64) -> Option<Gray8> {
    let p = dataset.join("mask").join(format!("{timestamp:.6}.png"));
    stillpoint_image::read_gray(&p).ok()
}

/// The pixel nearest to (x, y) is moving (over 127); outside the image it is not.
pub fn on_mask(mask: &Gray8, x: f64, y: f64) -> bool {
    mask.get_checked(x.round() as isize, y.round() as isize)
        .is_some_and(|v| v > 127)
}

/// Keypoints handed to tracking (not `dynamic`) that lie on a moving object.
pub fn moving_keypoints_kept(mask: &Gray8, keypoints: &[[f32; 2]], dynamic: &[bool]) -> usize {
    on_mask_where(mask, keypoints, dynamic, false)
}

/// The share of the keypoints off every moving object that the front-end culled (`dynamic`):
/// static world lost to the culling. `None` when no keypoint lies off the movers.
pub fn static_keypoints_culled_share(
    mask: &Gray8,
    keypoints: &[[f32; 2]],
    dynamic: &[bool],
) -> Option<f64> {
    let (mut off_movers, mut culled) = (0usize, 0usize);
    for (k, &d) in keypoints.iter().zip(dynamic) {
        if !on_mask(mask, k[0] as f64, k[1] as f64) {
            off_movers += 1;
            culled += usize::from(d);
        }
    }
    (off_movers > 0).then(|| culled as f64 / off_movers as f64)
}

/// Keypoints tracking `matched` to the map (pose inliers) that lie on a moving object.
pub fn moving_keypoints_matched(mask: &Gray8, keypoints: &[[f32; 2]], matched: &[bool]) -> usize {
    on_mask_where(mask, keypoints, matched, true)
}

/// Keypoints whose flag is `wanted` that lie on a moving object.
fn on_mask_where(mask: &Gray8, keypoints: &[[f32; 2]], flags: &[bool], wanted: bool) -> usize {
    keypoints
        .iter()
        .zip(flags)
        .filter(|&(k, &f)| f == wanted && on_mask(mask, k[0] as f64, k[1] as f64))
        .count()
}

/// Good map points on moving objects, as the keyframes' masks tell.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MoversInMap {
    /// Points that lie on a mover: made there (their first keyframe saw them on the mask) or
    /// seen there by more than half of the keyframes with a mask that observe them. Their
    /// position came from, or agrees with, the moving surface.
    pub lying: usize,
    /// Points with at least one keyframe observation on a mover (also a static point matched
    /// once to a keypoint beside a foot, or at the mask's edge).
    pub seen: usize,
}

/// Good map points on the moving masks of good keyframes (`mask_at(timestamp)`; keyframes
/// without a mask are skipped): those lying on movers and those seen there at least once.
pub fn moving_map_points(map: &Map, mut mask_at: impl FnMut(f64) -> Option<Gray8>) -> MoversInMap {
    let mut moving = BTreeSet::new();
    let mut created = BTreeSet::new();
    // Per point: (observations on a mask, observations by keyframes with a mask).
    let mut votes: std::collections::BTreeMap<_, (usize, usize)> = Default::default();
    for kf in map.keyframes.values().filter(|k| !k.bad) {
        let Some(mask) = mask_at(kf.timestamp) else {
            continue;
        };
        let before = created.len();
        for (i, mp) in kf.map_points.iter().enumerate() {
            let Some(mp) = mp else { continue };
            if map.points.get(mp).is_none_or(|p| p.bad) {
                continue;
            }
            let on = on_mask(&mask, kf.points[i].x, kf.points[i].y);
            let v = votes.entry(*mp).or_insert((0, 0));
            v.0 += usize::from(on);
            v.1 += 1;
            if on && let Some(p) = map.points.get(mp) {
                moving.insert(*mp);
                if p.first_kf == kf.id {
                    created.insert(*mp);
                    tracing::trace!(
                        "keyframe {} point {mp} created on a mover at ({:.0}, {:.0}) depth {:.2}",
                        kf.id,
                        kf.points[i].x,
                        kf.points[i].y,
                        kf.depth.get(i).copied().unwrap_or(0.0)
                    );
                }
            }
        }
        if created.len() > before {
            tracing::debug!(
                "keyframe {} (frame at {:.3}): {} map points created on movers",
                kf.id,
                kf.timestamp,
                created.len() - before
            );
        }
    }
    let lying = votes
        .iter()
        .filter(|&(mp, &(on, all))| created.contains(mp) || 2 * on > all)
        .count();
    tracing::info!(
        "map points on moving objects: {lying} lying there ({} created there), {} seen there once or more",
        created.len(),
        moving.len(),
    );
    MoversInMap {
        lying,
        seen: moving.len(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 8x6, moving in the 3x2 block at x 4..7, y 2..4.
    fn mask() -> Gray8 {
        let mut data = vec![0u8; 8 * 6];
        for y in 2..4 {
            for x in 4..7 {
                data[y * 8 + x] = 255;
            }
        }
        Gray8::from_vec(8, 6, data).unwrap()
    }

    #[test]
    fn points_round_to_the_nearest_pixel() {
        let m = mask();
        assert!(on_mask(&m, 4.0, 2.0));
        assert!(on_mask(&m, 3.6, 2.4));
        assert!(!on_mask(&m, 3.4, 2.0));
        assert!(!on_mask(&m, 6.0, 4.0));
        assert!(!on_mask(&m, -10.0, 2.0));
        assert!(!on_mask(&m, 100.0, 100.0));
    }

    #[test]
    fn the_static_share_culled_counts_only_keypoints_off_the_movers() {
        let m = mask();
        // Two on the mover (one culled), four off it (one culled).
        let kps = [
            [4.0, 2.0],
            [5.0, 3.0],
            [0.0, 0.0],
            [1.0, 1.0],
            [2.0, 5.0],
            [7.0, 0.0],
        ];
        let dynamic = [true, false, true, false, false, false];
        assert_eq!(
            static_keypoints_culled_share(&m, &kps, &dynamic),
            Some(0.25)
        );
        assert_eq!(
            static_keypoints_culled_share(&m, &kps[..2], &dynamic[..2]),
            None
        );
    }

    #[test]
    fn only_kept_keypoints_on_movers_count() {
        let m = mask();
        let kps = [[4.0, 2.0], [5.0, 3.0], [0.0, 0.0], [6.0, 2.0]];
        assert_eq!(moving_keypoints_kept(&m, &kps, &[false; 4]), 3);
        assert_eq!(
            moving_keypoints_kept(&m, &kps, &[true, false, false, false]),
            2
        );
    }

    #[test]
    fn an_empty_map_has_no_points_on_movers() {
        assert_eq!(
            moving_map_points(&Map::new(), |_| Some(mask())),
            MoversInMap::default()
        );
    }

    #[test]
    fn map_points_count_once_when_a_good_keyframe_saw_them_on_a_mover() {
        use stillpoint_geometry::{PinholeCamera, Se3, Vec3};
        use stillpoint_slam::{Feature, Frame, SlamSettings};
        let cam = PinholeCamera::new(500.0, 500.0, 4.0, 3.0, 8, 6);
        let s = SlamSettings::rgbd(cam, 40.0, 30.0);
        // keypoints 0 and 1 on the moving block, 2 and 3 beside it
        let feats: Vec<Feature> = [(4.0, 2.0), (6.0, 3.0), (1.0, 1.0), (7.0, 5.0)]
            .iter()
            .map(|&(x, y)| Feature {
                x,
                y,
                octave: 0,
                angle: 0.0,
            })
            .collect();
        let mut f = Frame::new(0, 0.0, &feats, &[[7u8; 32]; 4], None, &s).unwrap();
        f.pose_cw = Some(Se3::identity());
        let mut map = Map::new();
        let k0 = map.add_keyframe(&f).unwrap();
        let k1 = map.add_keyframe(&f).unwrap();
        for i in 0..4 {
            let mp = map.add_point(Vec3::new(0.0, 0.0, 3.0), k0, i).unwrap();
            map.add_observation(mp, k1, i);
        }
        let both = |n| MoversInMap { lying: n, seen: n };
        assert_eq!(moving_map_points(&map, |_| Some(mask())), both(2));
        // keyframes without a mask say nothing
        assert_eq!(moving_map_points(&map, |_| None), both(0));
        // a bad point does not count
        let first = *map.points.keys().next().unwrap();
        map.points.get_mut(&first).unwrap().bad = true;
        assert_eq!(moving_map_points(&map, |_| Some(mask())), both(1));
        // a static point seen on the mask by one keyframe of three (a keypoint beside a foot
        // matched to it) is seen there, but does not lie there
        let k2 = map.add_keyframe(&f).unwrap();
        let static_point = map.add_point(Vec3::new(0.0, 0.0, 3.0), k0, 2).unwrap();
        map.add_observation(static_point, k1, 2);
        map.add_observation(static_point, k2, 0);
        let m = moving_map_points(&map, |_| Some(mask()));
        assert_eq!((m.lying, m.seen), (1, 2));
    }
}
