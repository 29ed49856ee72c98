//! Monocular initialisation (ORB-SLAM `Tracking::MonocularInitialization`): a reference frame is
//! kept until a later frame, matched to it in windows around the keypoints' last positions, gives
//! a two-view reconstruction; then the initial map is the two frames and the triangulated points,
//! refined by bundle adjustment and scaled to a median scene depth of 1.

use std::collections::VecDeque;

use stillpoint_geometry::{Se3, Vec2, Vec3};
use tracing::debug;

use crate::SlamSettings;
use crate::data::Frame;
use crate::matching::area::search_for_initialisation;
use crate::optimize::{BaObservation, BaProblem, local_bundle_adjustment};
use crate::settings::MonoInitSettings;
use crate::solve::two_view::{TwoViewModel, TwoViewParams, reconstruct};

/// A point of the initial map and the keypoints that see it.
#[derive(Clone, Copy, Debug)]
pub struct InitialPoint {
    /// Its keypoint in the reference frame.
    pub reference_keypoint: usize,
    /// Its keypoint in the current frame.
    pub keypoint: usize,
    /// In the reference camera's frame.
    pub position: Vec3,
}

/// An accepted initialisation: the reference frame, the second camera relative to it, and the
/// points, scaled to a median depth of 1 in the reference camera.
#[derive(Clone, Debug)]
pub struct Initialisation {
    /// The first of the two views (it becomes the first keyframe).
    pub reference: Frame,
    /// Current camera from the reference camera.
    pub pose21: Se3,
    /// The triangulated points.
    pub points: Vec<InitialPoint>,
    /// Whether the homography or the fundamental matrix gave the motion.
    pub model: TwoViewModel,
    /// Parallax of the points, degrees (ORB-SLAM's measure: the 51st largest).
    pub parallax_deg: f64,
    /// The frames offered between the two views, oldest first (at most
    /// `MonoInitSettings::backfill_frames` of them, the newest): once the map stands they can
    /// be tracked in it.
    pub between: Vec<Frame>,
    /// The frames offered before the reference frame since the initialiser last started over
    /// (earlier references dropped for too few matches, and the frames matched to them), oldest
    /// first; with `between`, at most `backfill_frames` frames.
    pub before: Vec<Frame>,
}

/// The monocular initialiser's state: the reference frame and where its keypoints were last
/// matched.
#[derive(Default)]
pub struct MonoInitializer {
    reference: Option<Frame>,
    prev_matched: Vec<Vec2>,
    /// Where its keypoints were last matched by the coarser levels' search.
    prev_matched_coarse: Vec<Vec2>,
    /// Frames offered since the reference that did not start the map.
    between: VecDeque<Frame>,
    /// Frames offered before the reference: earlier references dropped because the view moved
    /// on, and their frames (a plain room may drop two before one starts the map).
    before: VecDeque<Frame>,
    /// The last frame offered had too few matches to the reference, which was kept for the
    /// next ([`MonoInitSettings::keep_reference_over_sudden_fall`]).
    last_short: bool,
    /// The last frame's matches to the reference.
    last_matches: usize,
}

impl MonoInitializer {
    /// Start over: the next frame with enough keypoints becomes the reference, and no frame
    /// offered so far is kept.
    pub fn reset(&mut self) {
        self.reference = None;
        self.prev_matched.clear();
        self.prev_matched_coarse.clear();
        self.between.clear();
        self.before.clear();
        self.last_short = false;
    }

    /// Drop the reference frame (the next frame with enough keypoints becomes it) but keep it,
    /// its frames and `frame`, when given, as frames before the next reference (the newest
    /// `keep` in all).
    fn drop_reference(&mut self, frame: Option<&Frame>, keep: usize) {
        self.before.extend(self.reference.take());
        self.before.extend(self.between.drain(..));
        self.before.extend(frame.cloned());
        while self.before.len() > keep {
            self.before.pop_front();
        }
        self.prev_matched.clear();
        self.prev_matched_coarse.clear();
        self.last_short = false;
    }

    /// `frame` becomes the reference.
    fn start_reference(&mut self, frame: &Frame) {
        self.last_matches = 0;
        self.prev_matched = frame.points.clone();
        self.prev_matched_coarse = frame.points.clone();
        self.reference = Some(frame.clone());
        debug!(
            frame = frame.index,
            keypoints = frame.len(),
            "initialisation reference"
        );
    }

    /// Keep `frame` for tracking once the map stands (the newest `keep` only).
    fn remember(&mut self, frame: &Frame, keep: usize) {
        if keep == 0 {
            return;
        }
        if self.between.len() >= keep {
            self.between.pop_front();
        }
        self.between.push_back(frame.clone());
        while self.before.len() + self.between.len() > keep {
            self.before.pop_front();
        }
    }

    /// Index of the reference frame, when there is one.
    pub fn reference_index(&self) -> Option<usize> {
        self.reference.as_ref().map(|f| f.index)
    }

    /// Offer a frame. The first with more than `min_keypoints` keypoints becomes the reference;
    /// later ones are matched to it, and the reference is dropped when a frame has too few
    /// matches (the camera moved too far: the frames so far are kept, to be tracked once a map
    /// stands) or too few keypoints (the view changed: all is forgotten). Returns the
    /// initialisation once the two views reconstruct and survive bundle adjustment.
    pub fn add_frame(&mut self, frame: &Frame, s: &SlamSettings) -> Option<Initialisation> {
        let p = &s.mono_init;
        let Some(reference) = &self.reference else {
            if frame.len() <= p.min_keypoints {
                self.reset();
            } else {
                self.start_reference(frame);
            }
            return None;
        };
        if frame.len() <= p.min_keypoints {
            debug!(
                frame = frame.index,
                keypoints = frame.len(),
                "too few keypoints: reference dropped"
            );
            self.reset();
            return None;
        }
        // (reference keypoint, frame keypoint) pairs of the levels up to `max_octave`.
        let search = |prev_matched: &mut Vec<Vec2>, max_octave: i32| -> Vec<(usize, usize)> {
            search_for_initialisation(
                reference,
                frame,
                prev_matched,
                p.window_px,
                p.ratio,
                s.th_low,
                max_octave,
            )
            .into_iter()
            .enumerate()
            .filter_map(|(i, m)| m.map(|j| (i, j)))
            .collect()
        };
        let finest = search(&mut self.prev_matched, p.max_octave);
        // ORB-SLAM's rule on the finest levels' matches: fewer, and the view has changed too
        // much for this reference. A reference kept on the coarser levels' count was held for
        // 150 frames without a reconstruction where a fresh one would have started the map.
        if finest.len() < p.min_matches {
            let sudden = (finest.len() as f64)
                < p.keep_reference_over_sudden_fall * self.last_matches as f64;
            if sudden && !self.last_short {
                debug!(
                    frame = frame.index,
                    reference = reference.index,
                    matches = finest.len(),
                    "too few matches: reference kept for the next frame"
                );
                self.remember(frame, p.backfill_frames);
                self.last_short = true;
                return None;
            }
            debug!(
                frame = frame.index,
                reference = reference.index,
                matches = finest.len(),
                "too few matches: reference dropped"
            );
            if self.last_short {
                // As if the first short frame had dropped it (ORB-SLAM's rule): the frame after
                // it, this one, is the next reference.
                self.drop_reference(None, p.frames_kept_before());
                self.start_reference(frame);
            } else {
                self.drop_reference(Some(frame), p.frames_kept_before());
            }
            return None;
        }
        self.last_short = false;
        self.last_matches = finest.len();
        // The coarser levels' own search, with its own last positions (kept on every frame),
        // so that the finest levels' matches stay exactly ORB-SLAM's; tried once the reference
        // has been held long enough.
        let coarse = (p.fallback_max_octave > p.max_octave)
            .then(|| search(&mut self.prev_matched_coarse, p.fallback_max_octave))
            .filter(|_| frame.index.saturating_sub(reference.index) >= p.fallback_after_frames);
        let params = TwoViewParams {
            sigma: 1.0,
            iterations: p.ransac_iterations,
            min_parallax_deg: p.min_parallax_deg,
            min_triangulated: p.min_triangulated,
            min_triangulated_share: p.min_triangulated_share,
            refit_rounds: p.refit_rounds,
            fundamental_when_ambiguous: p.fundamental_when_ambiguous,
            homography_ratio: p.homography_ratio,
            seed: 0,
        };
        let try_pairs = |pairs: &[(usize, usize)]| {
            let p1: Vec<Vec2> = pairs.iter().map(|&(i, _)| reference.points[i]).collect();
            let p2: Vec<Vec2> = pairs.iter().map(|&(_, j)| frame.points[j]).collect();
            reconstruct(&s.camera, &p1, &p2, &params)
        };
        // The finest levels first (ORB-SLAM's views); where they give no reconstruction the
        // coarser levels' matches get a second try.
        let mut attempts = std::iter::once(finest).chain(coarse);
        let (pairs, two_view) = loop {
            let Some(pairs) = attempts.next() else {
                self.remember(frame, p.backfill_frames);
                return None;
            };
            match try_pairs(&pairs) {
                Ok(t) => break (pairs, t),
                Err(why) => debug!(
                    frame = frame.index,
                    reference = reference.index,
                    matches = pairs.len(),
                    "no reconstruction: {why}"
                ),
            }
        };
        // Keypoints the front-end keeps but forbids new points on found none here either.
        let points: Vec<InitialPoint> = pairs
            .iter()
            .zip(&two_view.points)
            .filter_map(|(&(i, j), x)| {
                Some(InitialPoint {
                    reference_keypoint: i,
                    keypoint: j,
                    position: (*x)?,
                })
            })
            .filter(|p| {
                !reference.no_new_point[p.reference_keypoint] && !frame.no_new_point[p.keypoint]
            })
            .collect();
        let reference = reference.clone();
        let refined = refine_and_scale(&reference, frame, two_view.pose21, points, s);
        let Some((pose21, points)) = refined else {
            debug!(
                frame = frame.index,
                reference = reference.index,
                "initial map rejected after bundle adjustment"
            );
            if p.reset_on_rejection {
                self.drop_reference(Some(frame), p.frames_kept_before());
            } else {
                self.remember(frame, p.backfill_frames);
            }
            return None;
        };
        let between = std::mem::take(&mut self.between).into();
        let before = std::mem::take(&mut self.before).into();
        self.reset();
        Some(Initialisation {
            reference,
            pose21,
            points,
            model: two_view.model,
            parallax_deg: two_view.parallax_deg,
            between,
            before,
        })
    }
}

/// Whether a frame `since_start` frames after its monocular map started wants the wider feature
/// extraction of initialisation: for `young_map_seconds`, and then while the last frame tracked
/// fewer than `thin_map_inliers` points, up to `thin_map_seconds`. A map started from little
/// parallax (a slow camera) stays thin until the camera has moved on.
pub fn map_is_young(
    since_start: usize,
    last_inliers: usize,
    fps: f64,
    p: &MonoInitSettings,
) -> bool {
    let frames = |seconds: f64| (fps * seconds).round().max(0.0) as usize;
    since_start < frames(p.young_map_seconds)
        || (since_start < frames(p.thin_map_seconds) && last_inliers < p.thin_map_inliers)
}

/// Bundle adjustment of the two views (the reference fixed; ORB-SLAM's global BA over the initial
/// map), observations beyond the chi-square test drop their point; then the scale that makes the
/// median depth in the reference camera 1. `None` when fewer than `min_points_after_ba` points
/// remain or the median depth is not positive.
fn refine_and_scale(
    reference: &Frame,
    frame: &Frame,
    pose21: Se3,
    points: Vec<InitialPoint>,
    s: &SlamSettings,
) -> Option<(Se3, Vec<InitialPoint>)> {
    let inv_sigma2 = s.inv_level_sigma2();
    let mut problem = BaProblem {
        poses: vec![Se3::identity(), pose21],
        fixed: vec![true, false],
        points: points.iter().map(|p| p.position).collect(),
        observations: Vec::with_capacity(2 * points.len()),
    };
    for (k, p) in points.iter().enumerate() {
        for (camera, f, idx) in [(0, reference, p.reference_keypoint), (1, frame, p.keypoint)] {
            problem.observations.push(BaObservation {
                camera,
                point: k,
                u: f.points[idx].x,
                v: f.points[idx].y,
                u_right: None,
                inv_sigma2: inv_sigma2[f.octaves[idx] as usize],
            });
        }
    }
    let outliers = local_bundle_adjustment(&mut problem, s);
    let mut bad = vec![false; points.len()];
    for (o, out) in problem.observations.iter().zip(&outliers) {
        bad[o.point] |= *out;
    }
    let kept: Vec<InitialPoint> = points
        .iter()
        .enumerate()
        .filter(|(k, _)| !bad[*k])
        .map(|(k, p)| InitialPoint {
            position: problem.points[k],
            ..*p
        })
        .collect();
    let mut depths: Vec<f64> = kept.iter().map(|p| p.position.z).collect();
    if kept.is_empty() || kept.len() < s.mono_init.min_points_after_ba {
        debug!(
            points = kept.len(),
            "too few points after bundle adjustment"
        );
        return None;
    }
    depths.sort_by(f64::total_cmp);
    let median = depths[(depths.len() - 1) / 2];
    if !(median.is_finite() && median > 0.0) {
        return None;
    }
    let scale = 1.0 / median;
    let mut pose = problem.poses[1];
    pose.translation.vector *= scale;
    let kept = kept
        .into_iter()
        .map(|p| InitialPoint {
            position: p.position * scale,
            ..p
        })
        .collect();
    Some((pose, kept))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Descriptor, Feature};
    use nalgebra::Point3;
    use rand::{Rng, SeedableRng};
    use stillpoint_geometry::PinholeCamera;

    /// The frame a camera at `pose_cw` sees of `points` (level-0 keypoints, their descriptors).
    fn view(
        index: usize,
        pose_cw: &Se3,
        points: &[Vec3],
        descriptors: &[Descriptor],
        s: &SlamSettings,
    ) -> Frame {
        view_in_levels(index, pose_cw, points, descriptors, s, 1)
    }

    /// As [`view`], the `k`-th point's keypoint on pyramid level `k % levels`.
    fn view_in_levels(
        index: usize,
        pose_cw: &Se3,
        points: &[Vec3],
        descriptors: &[Descriptor],
        s: &SlamSettings,
        levels: usize,
    ) -> Frame {
        let (mut feats, mut descs) = (Vec::new(), Vec::new());
        for (k, (p, d)) in points.iter().zip(descriptors).enumerate() {
            let Some(uv) = s
                .camera
                .project(&(pose_cw * Point3::from(*p)).coords)
                .filter(|uv| s.camera.in_image(uv, 1.0))
            else {
                continue;
            };
            feats.push(Feature {
                x: uv.x as f32,
                y: uv.y as f32,
                octave: (k % levels) as u8,
                angle: 0.0,
            });
            descs.push(*d);
        }
        Frame::new(index, index as f64, &feats, &descs, None, s).unwrap()
    }

    /// 400 random points 3-8 m ahead of the camera and a random descriptor for each.
    fn scene(seed: u64) -> (Vec<Vec3>, Vec<Descriptor>) {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
        let points: Vec<Vec3> = (0..400)
            .map(|_| {
                let z = rng.random_range(3.0..8.0);
                Vec3::new(
                    rng.random_range(-0.6..0.6) * z,
                    rng.random_range(-0.45..0.45) * z,
                    z,
                )
            })
            .collect();
        let descriptors: Vec<Descriptor> = (0..points.len())
            .map(|_| std::array::from_fn(|_| rng.random()))
            .collect();
        (points, descriptors)
    }

    #[test]
    fn two_views_of_a_scene_make_an_initial_map_at_median_depth_one() {
        let cam = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
        let s = SlamSettings::monocular(cam, 30.0);
        let (points, descriptors) = scene(11);
        let truth21 = Se3::new(Vec3::new(-0.35, 0.02, -0.05), Vec3::new(0.0, 0.04, 0.01));
        let mut init = MonoInitializer::default();
        // Too few keypoints: no reference.
        let sparse = view(0, &Se3::identity(), &points[..50], &descriptors[..50], &s);
        assert!(init.add_frame(&sparse, &s).is_none());
        assert_eq!(init.reference_index(), None);
        let first = view(1, &Se3::identity(), &points, &descriptors, &s);
        assert!(init.add_frame(&first, &s).is_none());
        assert_eq!(init.reference_index(), Some(1));
        let second = view(2, &truth21, &points, &descriptors, &s);
        let got = init.add_frame(&second, &s).expect("initialised");
        assert_eq!(init.reference_index(), None);
        assert!(got.points.len() > 300, "{} points", got.points.len());
        let dir = got.pose21.translation.vector.normalize();
        let angle = dir
            .dot(&truth21.translation.vector.normalize())
            .clamp(-1.0, 1.0)
            .acos();
        assert!(angle.to_degrees() < 1.0, "translation off by {angle} rad");
        let mut depths: Vec<f64> = got.points.iter().map(|p| p.position.z).collect();
        depths.sort_by(f64::total_cmp);
        assert!((depths[(depths.len() - 1) / 2] - 1.0).abs() < 1e-9);
        // Each point is the true one at the map's scale.
        let scale = got.pose21.translation.vector.norm() / truth21.translation.vector.norm();
        for p in &got.points {
            let kp = first.points[p.reference_keypoint];
            let truth = points
                .iter()
                .find(|x| cam.project(x).is_some_and(|uv| (uv - kp).norm() < 1e-3))
                .expect("a scene point");
            assert!((p.position - truth * scale).norm() < 1e-3 * scale * truth.z);
        }
    }

    #[test]
    fn keypoints_of_coarser_levels_start_a_map_the_finest_level_alone_cannot() {
        // A quarter of the keypoints on each of levels 0-3, as a pyramid gives them: level 0
        // alone has 100 at most, too few matches (ORB-SLAM matches only level 0).
        let cam = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
        let (points, descriptors) = scene(12);
        let truth21 = Se3::new(Vec3::new(-0.35, 0.02, -0.05), Vec3::new(0.0, 0.04, 0.01));
        let start = |max_octave: i32| {
            let mut s = SlamSettings::monocular(cam, 30.0);
            s.mono_init.max_octave = max_octave;
            let mut init = MonoInitializer::default();
            let first = view_in_levels(0, &Se3::identity(), &points, &descriptors, &s, 4);
            assert!(init.add_frame(&first, &s).is_none());
            let second = view_in_levels(1, &truth21, &points, &descriptors, &s, 4);
            init.add_frame(&second, &s)
        };
        assert!(start(0).is_none());
        let got = start(2).expect("initialised from levels 0-2");
        assert!(got.points.len() > 200, "{} points", got.points.len());
    }

    #[test]
    fn the_coarser_levels_get_a_second_try_where_the_finest_give_no_map() {
        // A third of the keypoints on each of levels 0-2. The views need 150 triangulated
        // points: level 0's ~130 matches keep the reference but cannot give them.
        let cam = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
        let (points, descriptors) = scene(13);
        let truth21 = Se3::new(Vec3::new(-0.35, 0.02, -0.05), Vec3::new(0.0, 0.04, 0.01));
        // The same second view offered 5 and 10 frames after the reference.
        let start = |fallback_max_octave: i32| {
            let mut s = SlamSettings::monocular(cam, 30.0);
            s.mono_init.min_triangulated = 150;
            s.mono_init.fallback_max_octave = fallback_max_octave;
            s.mono_init.fallback_after_frames = 10;
            let mut init = MonoInitializer::default();
            let first = view_in_levels(0, &Se3::identity(), &points, &descriptors, &s, 3);
            assert!(init.add_frame(&first, &s).is_none());
            [5, 10].map(|index| {
                let second = view_in_levels(index, &truth21, &points, &descriptors, &s, 3);
                (init.add_frame(&second, &s), init.reference_index())
            })
        };
        let [(early, _), (late, reference)] = start(0);
        assert!(early.is_none() && late.is_none());
        assert_eq!(
            reference,
            Some(0),
            "the finest level's matches keep the reference"
        );
        let [(early, reference), (late, _)] = start(2);
        assert!(early.is_none(), "the coarser levels wait 10 frames");
        assert_eq!(reference, Some(0));
        let got = late.expect("initialised from levels 0-2");
        assert!(got.points.len() >= 150, "{} points", got.points.len());
        let dir = got.pose21.translation.vector.normalize();
        assert!((dir - truth21.translation.vector.normalize()).norm() < 1e-2);
    }

    #[test]
    fn one_frame_short_of_matches_keeps_the_reference() {
        let cam = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
        let (b, b_desc) = scene(16);
        let (a, a_desc) = scene(17);
        let truth21 = Se3::new(Vec3::new(-0.35, 0.02, -0.05), Vec3::new(0.0, 0.04, 0.01));
        // Frame 1 sees the reference's view again; frame 2 only 60 of its points, the rest
        // hidden at once (a walker's box culled, other keypoints around it); frame 3 sees them
        // all again, from a view with parallax.
        let mut hidden: Vec<Vec3> = b[..60].to_vec();
        hidden.extend_from_slice(&a[..100]);
        let mut hidden_desc: Vec<Descriptor> = b_desc[..60].to_vec();
        hidden_desc.extend_from_slice(&a_desc[..100]);
        let start = |keep_reference_over_sudden_fall: f64| {
            let mut s = SlamSettings::monocular(cam, 30.0);
            s.mono_init.keep_reference_over_sudden_fall = keep_reference_over_sudden_fall;
            let mut init = MonoInitializer::default();
            let frames = [
                view(0, &Se3::identity(), &b, &b_desc, &s),
                view(1, &Se3::identity(), &b, &b_desc, &s),
                view(2, &Se3::identity(), &hidden, &hidden_desc, &s),
                view(3, &truth21, &b, &b_desc, &s),
            ];
            let got = frames.iter().find_map(|f| init.add_frame(f, &s));
            (got, init.reference_index())
        };
        let (got, _) = start(0.8);
        let got = got.expect("initialised over the short frame");
        assert_eq!(got.reference.index, 0);
        assert_eq!(
            got.between.iter().map(|f| f.index).collect::<Vec<_>>(),
            [1, 2]
        );
        // ORB-SLAM's rule: the short frame drops the reference, and frame 3 becomes the next.
        let (got, reference) = start(0.0);
        assert!(got.is_none());
        assert_eq!(reference, Some(3));
        // A view that stays short drops it on its second frame, which becomes the reference
        // as under ORB-SLAM's rule, the first short frame one of the frames before; a fall
        // a few matches at a time drops it at once.
        let s = SlamSettings::monocular(cam, 30.0);
        let mut init = MonoInitializer::default();
        init.add_frame(&view(0, &Se3::identity(), &b, &b_desc, &s), &s);
        init.add_frame(&view(1, &Se3::identity(), &b, &b_desc, &s), &s);
        for i in 2..=3 {
            init.add_frame(&view(i, &Se3::identity(), &hidden, &hidden_desc, &s), &s);
            assert_eq!(init.reference_index(), Some(if i == 2 { 0 } else { 3 }));
        }
        let kept: Vec<usize> = init.before.iter().map(|f| f.index).collect();
        assert_eq!(kept, [0, 1, 2]);
        let mut init = MonoInitializer::default();
        init.add_frame(&view(0, &Se3::identity(), &b, &b_desc, &s), &s);
        init.add_frame(
            &view(1, &Se3::identity(), &b[..105], &b_desc[..105], &s),
            &s,
        );
        let mut fewer: Vec<Vec3> = b[..90].to_vec();
        fewer.extend_from_slice(&a[..100]);
        let mut fewer_desc: Vec<Descriptor> = b_desc[..90].to_vec();
        fewer_desc.extend_from_slice(&a_desc[..100]);
        init.add_frame(&view(2, &Se3::identity(), &fewer, &fewer_desc, &s), &s);
        assert_eq!(init.reference_index(), None);
    }

    #[test]
    fn a_reference_dropped_for_too_few_matches_is_kept_as_a_frame_before() {
        let cam = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
        let s = SlamSettings::monocular(cam, 30.0);
        let (a, a_desc) = scene(14);
        let (b, b_desc) = scene(15);
        let truth21 = Se3::new(Vec3::new(-0.35, 0.02, -0.05), Vec3::new(0.0, 0.04, 0.01));
        // Frame 0 sees scene a, 1 scene b (no match: 0 is dropped), 2 and 3 start the map in b.
        // `sparse_at`: a frame with too few keypoints offered before frame 2.
        let before = |sparse_at: Option<usize>| {
            let mut init = MonoInitializer::default();
            let mut frames = vec![
                view(0, &Se3::identity(), &a, &a_desc, &s),
                view(1, &Se3::identity(), &b, &b_desc, &s),
                view(2, &Se3::identity(), &b, &b_desc, &s),
                view(3, &truth21, &b, &b_desc, &s),
            ];
            if let Some(i) = sparse_at {
                frames.insert(i, view(9, &Se3::identity(), &b[..50], &b_desc[..50], &s));
            }
            let mut got = frames.iter().filter_map(|f| init.add_frame(f, &s));
            let got = got.next().expect("initialised");
            assert_eq!((got.reference.index, got.between.len()), (2, 0));
            got.before.iter().map(|f| f.index).collect::<Vec<_>>()
        };
        assert_eq!(before(None), [0, 1]);
        // A frame with too few keypoints (a covered lens) parts the views: all is forgotten.
        assert!(before(Some(2)).is_empty());
    }

    #[test]
    fn a_young_map_is_one_second_old_or_thin_for_up_to_five() {
        let p = MonoInitSettings {
            thin_map_seconds: 5.0,
            ..Default::default()
        };
        // 30 fps: the first 30 frames whatever tracking finds; then only while it finds fewer
        // than 100 points, until frame 150.
        assert!(map_is_young(29, 500, 30.0, &p));
        assert!(!map_is_young(30, 100, 30.0, &p));
        assert!(map_is_young(30, 99, 30.0, &p));
        assert!(map_is_young(149, 0, 30.0, &p));
        assert!(!map_is_young(150, 0, 30.0, &p));
        let orb_slam = MonoInitSettings {
            thin_map_seconds: 0.0,
            ..p
        };
        assert!(!map_is_young(30, 0, 30.0, &orb_slam));
    }
}
