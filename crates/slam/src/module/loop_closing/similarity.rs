//! Stage 2, the similarity solve (SE3: RGB-D and stereo know the scale): descriptor matches,
//! rigid RANSAC, guided matching and refinement, the loop group projected (ORB-SLAM's
//! `ComputeSim3`).

use std::collections::{BTreeMap, BTreeSet};

use stillpoint_geometry::{Se3, Vec3};
use tracing::{debug, info};

use super::{LoopCloser, PendingMerge, Verified};
use crate::data::{KeyFrame, KfId, Map, MapPoint, MpId};
use crate::hamming;
use crate::matching::NearestTwo;
use crate::optimize::{PoseObservation, optimize_pose};
use crate::solve::rigid::{
    RigidPair, RigidRansacParams, apply, ransac_rigid, ransac_similarity, refine_rigid,
};

/// A verified transform between two keyframes: the current camera from the loop keyframe's
/// (in the loop map's units), the loop map's units per the current map's unit, the matches,
/// their inlier flags and RANSAC's inlier count.
type Hypothesis = (Se3, f64, Vec<(usize, usize)>, Vec<bool>, usize);

impl LoopCloser {
    /// ORB-SLAM `ComputeSim3` with the scale fixed: the first candidate that passes descriptor
    /// matching, RANSAC, guided matching with refinement and the loop-group projection.
    pub(super) fn verify(&mut self, m: &Map, kf: KfId, candidates: &[KfId]) -> Option<Verified> {
        let cur = m.keyframes.get(&kf)?;
        for &c in candidates {
            self.stats.tried_candidates += 1;
            let Some(l) = m.keyframes.get(&c).filter(|x| !x.bad) else {
                self.stats.rejected_candidates += 1;
                continue;
            };
            match self.verify_one(m, cur, l) {
                Some(v) if l.map_epoch != cur.map_epoch => {
                    // The finder counts as one; its covisible keyframes may add the others.
                    let confirmed = 1 + self.merge_confirmations(m, cur, &v, &mut None);
                    if confirmed > self.s.loop_closing.merge_confirmations {
                        return Some(v);
                    }
                    debug!(
                        keyframe = kf,
                        candidate = c,
                        confirmed,
                        "merge waits: too few keyframes see the place yet"
                    );
                    self.stats.rejected_candidates += 1;
                    if self.pending_merge.is_none() {
                        self.pending_merge = Some(PendingMerge {
                            kf,
                            verified: v,
                            confirmed,
                            misses: 0,
                        });
                    }
                }
                Some(v) if self.plausible(m, cur, l, &v) => return Some(v),
                _ => self.stats.rejected_candidates += 1,
            }
        }
        None
    }

    /// A loop within one map asks the current keyframe to move no further than drift could have
    /// taken it since the loop keyframe ([`LoopSettings::max_correction_share`]).
    fn plausible(&self, m: &Map, cur: &KeyFrame, l: &KeyFrame, v: &Verified) -> bool {
        let ls = &self.s.loop_closing;
        let corrected = v.t_cl * l.pose_cw;
        let centre = |p: &Se3| p.inverse().translation.vector;
        let moved_m = (centre(&cur.pose_cw) - centre(&corrected)).norm();
        let turned_deg = cur
            .pose_cw
            .rotation
            .angle_to(&corrected.rotation)
            .to_degrees();
        // The path of the map's keyframes from the loop keyframe to this one.
        let centres: Vec<_> = m
            .keyframes
            .range(l.id..=cur.id)
            .map(|(_, k)| k)
            .filter(|k| !k.bad && k.map_epoch == cur.map_epoch)
            .map(|k| centre(&k.pose_cw))
            .collect();
        let path_m: f64 = centres.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        let plausible = ls.correction_is_plausible(moved_m, turned_deg, path_m, self.s.monocular);
        if !plausible {
            info!(
                keyframe = cur.id,
                loop_keyframe = l.id,
                moved_m,
                turned_deg,
                path_m,
                "loop rejected: it asks for more correction than drift explains"
            );
        }
        plausible
    }

    /// A place found in an older map, checked in the current keyframe's best covisible ones
    /// (ORB-SLAM3 checks a merge in them before accepting it): moved with it onto the place,
    /// how many see at least `min_loop_matches` of the place's points where they should be.
    fn merge_confirmations(
        &self,
        m: &Map,
        cur: &KeyFrame,
        v: &Verified,
        only: &mut Option<KfId>,
    ) -> usize {
        let ls = &self.s.loop_closing;
        let older = m.keyframes[&v.loop_kf].map_epoch;
        let cur_new = v.t_cl * m.keyframes[&v.loop_kf].pose_cw;
        let (none, taken) = (BTreeSet::new(), BTreeMap::new());
        // The whole older map: a keyframe further on sees past the loop keyframe's group.
        let points: Vec<MpId> = m
            .points
            .iter()
            .filter(|(_, p)| !p.bad && p.map_epoch == older)
            .map(|(id, _)| *id)
            .collect();
        let checked = match only.take() {
            Some(k) => vec![k],
            None => cur.best_covisibles(ls.merge_check_keyframes),
        };
        checked
            .into_iter()
            .filter_map(|g| m.keyframes.get(&g))
            .filter(|g| !g.bad && g.map_epoch == cur.map_epoch)
            .filter(|g| {
                // From the finder in the older map's units (monocular maps differ in scale).
                let mut from_finder = g.pose_cw * cur.pose_cw.inverse();
                from_finder.translation.vector *= v.scale;
                let pose = from_finder * cur_new;
                let seen = self.project_points(
                    m,
                    (g, &pose),
                    &points,
                    (&none, &taken),
                    ls.projection_radius,
                );
                seen.len() >= ls.min_loop_matches
            })
            .count()
    }

    /// A merge waiting for confirmation (`PendingMerge`), checked in the new keyframe `kf`:
    /// the merge to correct once enough keyframes saw the place; dropped after two misses or
    /// when its finder is gone.
    pub(super) fn confirm_pending_merge(&mut self, m: &Map, kf: KfId) -> Option<(KfId, Verified)> {
        let p = self.pending_merge.as_ref()?;
        let finder = m
            .keyframes
            .get(&p.kf)
            .filter(|k| !k.bad && k.map_epoch == m.epoch);
        let (Some(finder), true) = (finder, m.keyframes.contains_key(&p.verified.loop_kf)) else {
            self.pending_merge = None;
            return None;
        };
        if kf == p.kf {
            return None;
        }
        let seen = self.merge_confirmations(m, finder, &p.verified, &mut Some(kf));
        let p = self.pending_merge.as_mut()?;
        p.confirmed += seen;
        p.misses += 1 - seen;
        debug!(
            keyframe = kf,
            finder = p.kf,
            confirmed = p.confirmed,
            misses = p.misses,
            "pending merge checked"
        );
        if p.confirmed > self.s.loop_closing.merge_confirmations {
            let p = self.pending_merge.take()?;
            return Some((p.kf, p.verified));
        }
        if p.misses >= 2 {
            self.pending_merge = None;
        }
        None
    }

    pub(super) fn verify_one(&self, m: &Map, cur: &KeyFrame, l: &KeyFrame) -> Option<Verified> {
        let ls = &self.s.loop_closing;
        let matches = match_by_descriptor(m, cur, l, self.s.th_low, ls.match_ratio);
        if matches.len() < ls.min_descriptor_matches {
            debug!(
                keyframe = cur.id,
                candidate = l.id,
                matches = matches.len(),
                "loop rejected: too few descriptor matches"
            );
            return None;
        }
        let pairs: Vec<RigidPair> = matches
            .iter()
            .map(|&(i, j)| self.pair(m, cur, i, l, j))
            .collect();
        let params = RigidRansacParams {
            iterations: ls.ransac_iterations,
            min_inliers: ls.ransac_min_inliers,
            ..RigidRansacParams::default()
        };
        let found = if self.s.monocular {
            self.similarity(l, &matches, &pairs, &params)
        } else {
            self.rigid(m, (cur, l), &matches, &pairs, &params)
        };
        let Some((t_cl, scale, matched, inliers, ransac_inliers)) = found else {
            debug!(
                keyframe = cur.id,
                candidate = l.id,
                matches = matches.len(),
                "loop rejected: RANSAC"
            );
            return None;
        };
        let refined_inliers = inliers.iter().filter(|&&f| f).count();
        if refined_inliers < ls.min_refined_inliers {
            debug!(
                keyframe = cur.id,
                candidate = l.id,
                refined_inliers,
                "loop rejected: refinement"
            );
            return None;
        }
        let mut out: BTreeMap<usize, MpId> = BTreeMap::new();
        for (&(i, j), ok) in matched.iter().zip(&inliers) {
            if *ok && let Some(mp) = l.map_points[j] {
                out.insert(i, mp);
            }
        }
        // Project the loop group's points into the current keyframe with the corrected pose.
        let mut group = vec![l.id];
        group.extend(l.connections.keys().copied());
        let mut loop_points: Vec<MpId> = Vec::new();
        let mut seen = BTreeSet::new();
        for g in &group {
            if let Some(k) = m.keyframes.get(g).filter(|k| !k.bad) {
                for mp in k.map_points.iter().flatten() {
                    if m.points.get(mp).is_some_and(|p| !p.bad) && seen.insert(*mp) {
                        loop_points.push(*mp);
                    }
                }
            }
        }
        let pose = t_cl * l.pose_cw;
        let already: BTreeSet<MpId> = out.values().copied().collect();
        for (i, mp) in self.project_points(
            m,
            (cur, &pose),
            &loop_points,
            (&already, &out),
            ls.projection_radius,
        ) {
            out.insert(i, mp);
        }
        // Monocular: two maps' points are triangulated with small baselines, so the similarity
        // of their 3D points places the camera loosely; its pose is refined on the older map's
        // points as seen in the image (ORB-SLAM3 optimises the Sim(3) on reprojections), then
        // the scale taken from the refined depths.
        let (t_cl, scale) = if self.s.monocular {
            let (pose, scale) = self.refine_on_older_map(m, cur, &pose, &mut out)?;
            (pose * l.pose_cw.inverse(), scale)
        } else {
            (t_cl, scale)
        };
        if self.s.monocular && ls.min_parallax_deg_monocular > 0.0 {
            let well_placed = out
                .values()
                .filter(|&&mp| {
                    m.point_parallax_deg(mp)
                        .is_some_and(|deg| deg >= ls.min_parallax_deg_monocular)
                })
                .count();
            if well_placed < ls.min_refined_inliers {
                debug!(
                    keyframe = cur.id,
                    candidate = l.id,
                    well_placed,
                    matches = out.len(),
                    "loop rejected: its points were triangulated over too little parallax"
                );
                return None;
            }
        }
        let loop_matches = out.len();
        if loop_matches < ls.min_loop_matches {
            debug!(
                keyframe = cur.id,
                candidate = l.id,
                loop_matches,
                "loop rejected: too few matches with the loop group"
            );
            return None;
        }
        Some(Verified {
            loop_kf: l.id,
            t_cl,
            matches: out,
            loop_points,
            ransac_inliers,
            refined_inliers,
            scale,
        })
    }

    /// Monocular: the current keyframe's pose in the older map (`pose`, refined by motion-only
    /// bundle adjustment on its matches `out` with the older map's points; outliers leave
    /// `out`) and the older map's units per the current map's unit (the median ratio of a
    /// matched point's depth in the two maps). `None` when too few matches are left.
    fn refine_on_older_map(
        &self,
        m: &Map,
        cur: &KeyFrame,
        pose: &Se3,
        out: &mut BTreeMap<usize, MpId>,
    ) -> Option<(Se3, f64)> {
        let matched: Vec<(usize, MpId)> = out
            .iter()
            .filter(|(_, mp)| m.points.get(mp).is_some_and(|p| !p.bad))
            .map(|(&i, &mp)| (i, mp))
            .collect();
        let obs: Vec<PoseObservation> = matched
            .iter()
            .map(|&(i, mp)| PoseObservation {
                world: m.points[&mp].position,
                u: cur.points[i].x,
                v: cur.points[i].y,
                u_right: None,
                inv_sigma2: self.inv_sigma2[cur.octaves[i] as usize],
            })
            .collect();
        let mut refined = *pose;
        let outliers = optimize_pose(&mut refined, &obs, &self.s);
        let mut ratios = Vec::new();
        for (&(i, mp), &bad) in matched.iter().zip(&outliers) {
            if bad {
                out.remove(&i);
                continue;
            }
            let older = apply(&refined, &m.points[&mp].position).z;
            let own = cur.map_points[i]
                .and_then(|own| m.points.get(&own))
                .map(|p| apply(&cur.pose_cw, &p.position).z);
            if let Some(own) = own.filter(|z| *z > 0.0)
                && older > 0.0
            {
                ratios.push(older / own);
            }
        }
        if ratios.len() < self.s.loop_closing.min_refined_inliers {
            debug!(
                keyframe = cur.id,
                ratios = ratios.len(),
                "merge rejected: too few matches to fix the scale"
            );
            return None;
        }
        ratios.sort_by(f64::total_cmp);
        debug!(
            keyframe = cur.id,
            matches = obs.len(),
            outliers = outliers.iter().filter(|&&o| o).count(),
            moved_m =
                (refined.inverse().translation.vector - pose.inverse().translation.vector).norm(),
            scale = ratios[ratios.len() / 2],
            "merge pose refined on the older map"
        );
        Some((refined, ratios[ratios.len() / 2]))
    }

    /// RGB-D and stereo: the rigid transform between the two keyframes, then guided matching
    /// with it and refinement on all pairs.
    fn rigid(
        &self,
        m: &Map,
        (cur, l): (&KeyFrame, &KeyFrame),
        matches: &[(usize, usize)],
        pairs: &[RigidPair],
        params: &RigidRansacParams,
    ) -> Option<Hypothesis> {
        let cam = &self.s.camera;
        let (t_cl, flags) = ransac_rigid(pairs, cam, params)?;
        let ransac_inliers = flags.iter().filter(|&&f| f).count();
        let mut matched: Vec<(usize, usize)> = matches
            .iter()
            .zip(&flags)
            .filter(|(_, f)| **f)
            .map(|(m, _)| *m)
            .collect();
        matched.extend(self.guided_matches(m, cur, l, &t_cl, &matched));
        let pairs: Vec<RigidPair> = matched
            .iter()
            .map(|&(i, j)| self.pair(m, cur, i, l, j))
            .collect();
        let (t_cl, inliers) = refine_rigid(&t_cl, &pairs, cam, 10.0, 5);
        Some((t_cl, 1.0, matched, inliers, ransac_inliers))
    }

    /// Monocular: the similarity between the two keyframes (each map has its own scale), the
    /// current camera placed in the loop keyframe's world in that map's units.
    fn similarity(
        &self,
        l: &KeyFrame,
        matches: &[(usize, usize)],
        pairs: &[RigidPair],
        params: &RigidRansacParams,
    ) -> Option<Hypothesis> {
        let (s_cl, flags) = ransac_similarity(pairs, &self.s.camera, params)?;
        // Its centre from the inverse similarity, its rotation composed.
        let centre_l = s_cl.inverse().transform_point(&Vec3::zeros());
        let centre = apply(&l.pose_cw.inverse(), &centre_l);
        let r_cw = s_cl.rigid.rotation * l.pose_cw.rotation;
        let pose_cw = Se3::from_parts((-(r_cw * centre)).into(), r_cw);
        let inliers = flags.iter().filter(|&&f| f).count();
        Some((
            pose_cw * l.pose_cw.inverse(),
            1.0 / s_cl.scale,
            matches.to_vec(),
            flags,
            inliers,
        ))
    }

    /// Map point of keypoint `i` of `a` and of `j` of `b`, each in its camera's frame.
    pub(super) fn pair(
        &self,
        m: &Map,
        a: &KeyFrame,
        i: usize,
        b: &KeyFrame,
        j: usize,
    ) -> RigidPair {
        let world = |k: &KeyFrame, idx: usize| {
            k.map_points[idx]
                .and_then(|mp| m.points.get(&mp))
                .map_or(Vec3::zeros(), |p| p.position)
        };
        RigidPair {
            p1: apply(&a.pose_cw, &world(a, i)),
            p2: apply(&b.pose_cw, &world(b, j)),
            px1: a.points[i],
            px2: b.points[j],
            inv_sigma2_1: self.inv_sigma2[a.octaves[i] as usize],
            inv_sigma2_2: self.inv_sigma2[b.octaves[j] as usize],
        }
    }

    /// ORB-SLAM `SearchBySim3`: each keyframe's unmatched points projected into the other with
    /// the transform, kept when both directions agree.
    pub(super) fn guided_matches(
        &self,
        m: &Map,
        cur: &KeyFrame,
        l: &KeyFrame,
        t_cl: &Se3,
        matched: &[(usize, usize)],
    ) -> Vec<(usize, usize)> {
        let used_c: BTreeSet<usize> = matched.iter().map(|x| x.0).collect();
        let used_l: BTreeSet<usize> = matched.iter().map(|x| x.1).collect();
        let one_way = |from: &KeyFrame,
                       to: &KeyFrame,
                       t_to_from: &Se3,
                       used_from: &BTreeSet<usize>,
                       used_to: &BTreeSet<usize>| {
            let mut out: BTreeMap<usize, usize> = BTreeMap::new();
            for (i, mp) in from.map_points.iter().enumerate() {
                if used_from.contains(&i) {
                    continue;
                }
                let Some(p) = mp.and_then(|mp| m.points.get(&mp)).filter(|p| !p.bad) else {
                    continue;
                };
                let pc = apply(t_to_from, &apply(&from.pose_cw, &p.position));
                let window = Window {
                    radius: self.s.loop_closing.guided_radius,
                    max_hamming: self.s.th_high,
                };
                if let Some(j) =
                    self.best_in_window(to, &pc, (&p.descriptor, p.max_distance), window, |j| {
                        !used_to.contains(&j)
                    })
                {
                    out.insert(i, j);
                }
            }
            out
        };
        let t_lc = t_cl.inverse();
        let l_to_c = one_way(l, cur, t_cl, &used_l, &used_c);
        let c_to_l = one_way(cur, l, &t_lc, &used_c, &used_l);
        let mut out = Vec::new();
        for (j, i) in l_to_c {
            if c_to_l.get(&i) == Some(&j) && cur.map_points[i].is_some() {
                out.push((i, j));
            }
        }
        out
    }

    /// The keypoint of `k` nearest in descriptor to a point at `pc` (camera frame), searched in
    /// a window of `window.radius` x scale around its projection at the predicted octave (and
    /// the ones beside it), within `window.max_hamming`.
    pub(super) fn best_in_window(
        &self,
        k: &KeyFrame,
        pc: &Vec3,
        (descriptor, max_distance): (&crate::Descriptor, f64),
        window: Window,
        allowed: impl Fn(usize) -> bool,
    ) -> Option<usize> {
        let Window {
            radius,
            max_hamming,
        } = window;
        let cam = &self.s.camera;
        let uv = cam.project_undistorted(pc)?;
        if !cam.in_image(&uv, 0.0) {
            return None;
        }
        let dist = pc.norm();
        let level = {
            let ratio = max_distance / dist.max(1e-9);
            ((ratio.ln() / self.s.scale_factor.ln()).ceil() as i32)
                .clamp(0, self.s.n_levels as i32 - 1)
        };
        let r = radius * self.scales[level as usize];
        let mut best = (u32::MAX, usize::MAX);
        for c in k.features_in_area(uv.x, uv.y, r, level - 1, level + 1) {
            if !allowed(c) {
                continue;
            }
            let d = hamming(descriptor, &k.descriptors[c]);
            if d < best.0 {
                best = (d, c);
            }
        }
        (best.0 <= max_hamming).then_some(best.1)
    }

    /// ORB-SLAM `SearchByProjection(pKF, Scw, vpPoints, vpMatched, th)`: loop-group points not
    /// matched yet, projected with `pose` (world-to-camera of `k`), matched to free keypoints
    /// (TH_LOW) in the scale-invariance range and viewing cone.
    pub(super) fn project_points(
        &self,
        m: &Map,
        (k, pose): (&KeyFrame, &Se3),
        points: &[MpId],
        (already, taken): (&BTreeSet<MpId>, &BTreeMap<usize, MpId>),
        radius: f64,
    ) -> Vec<(usize, MpId)> {
        let view = Projection {
            keyframe: k,
            pose,
            center: pose.inverse().translation.vector,
        };
        let mut used: BTreeSet<usize> = taken.keys().copied().collect();
        let skip = |mp: MpId, _: &MapPoint| already.contains(&mp);
        self.match_by_projection(m, &view, points, skip, &mut used, radius)
    }

    /// Good map points (but those `skip` names) seen from `pose` (world-to-camera of `k`,
    /// camera centre `center`) within their scale range and viewing cone, matched one-to-one
    /// to keypoints of `k` not in `used` (TH_LOW, `radius` x the predicted scale): the
    /// projection search of loop closing's verification and fusion.
    pub(super) fn match_by_projection(
        &self,
        m: &Map,
        view: &Projection,
        points: &[MpId],
        skip: impl Fn(MpId, &MapPoint) -> bool,
        used: &mut BTreeSet<usize>,
        radius: f64,
    ) -> Vec<(usize, MpId)> {
        let mut out = Vec::new();
        for &mp in points {
            let Some(p) = m.points.get(&mp).filter(|p| !p.bad) else {
                continue;
            };
            if skip(mp, p) || !p.in_viewing_range(&view.center) {
                continue;
            }
            let pc = apply(view.pose, &p.position);
            let window = Window {
                radius,
                max_hamming: self.s.th_low,
            };
            if let Some(i) = self.best_in_window(
                view.keyframe,
                &pc,
                (&p.descriptor, p.max_distance),
                window,
                |i| !used.contains(&i),
            ) {
                used.insert(i);
                out.push((i, mp));
            }
        }
        out
    }
}

/// Keypoints of `a` and `b` that both observe good map points, matched by descriptor (TH_LOW,
/// nearest / second ratio, one-to-one, rotation-consistent): ORB-SLAM's `SearchByBoW` between
/// keyframes, by brute force (a keyframe holds a few hundred such keypoints).
fn match_by_descriptor(
    m: &Map,
    a: &KeyFrame,
    b: &KeyFrame,
    th_low: u32,
    ratio: f32,
) -> Vec<(usize, usize)> {
    let good = |k: &KeyFrame| -> Vec<usize> {
        (0..k.map_points.len())
            .filter(|&i| {
                k.map_points[i]
                    .and_then(|mp| m.points.get(&mp))
                    .is_some_and(|p| !p.bad)
            })
            .collect()
    };
    let (ga, gb) = (good(a), good(b));
    let mut best_for_b: BTreeMap<usize, (u32, usize)> = BTreeMap::new();
    for &i in &ga {
        let best = NearestTwo::of(
            gb.iter()
                .map(|&j| (j, hamming(&a.descriptors[i], &b.descriptors[j]))),
        );
        if best.accepted(th_low, ratio) {
            let e = best_for_b
                .entry(best.index)
                .or_insert((u32::MAX, usize::MAX));
            if best.distance < e.0 {
                *e = (best.distance, i);
            }
        }
    }
    let matches: Vec<(usize, usize)> = best_for_b.iter().map(|(&j, &(_, i))| (i, j)).collect();
    let rot: Vec<(usize, f32)> = matches
        .iter()
        .map(|&(i, j)| (i, b.angles[j] - a.angles[i]))
        .collect();
    let drop: BTreeSet<usize> = crate::matching::rotation_outliers(&rot)
        .into_iter()
        .collect();
    matches
        .into_iter()
        .enumerate()
        .filter(|(n, _)| !drop.contains(n))
        .map(|(_, m)| m)
        .collect()
}

/// A keyframe seen from a pose (world-to-camera) with that pose's camera centre: where a
/// projection search looks.
pub(super) struct Projection<'a> {
    pub(super) keyframe: &'a KeyFrame,
    pub(super) pose: &'a Se3,
    pub(super) center: Vec3,
}

/// A search window: `radius` x the predicted scale around a projection, descriptors within
/// `max_hamming`.
#[derive(Clone, Copy)]
pub(super) struct Window {
    pub(super) radius: f64,
    pub(super) max_hamming: u32,
}
