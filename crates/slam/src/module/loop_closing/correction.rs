//! Stage 3, correction: the current keyframe's covisible group moved onto the loop, points
//! fused, the essential graph optimised (ORB-SLAM's `CorrectLoop`, `SearchAndFuse`,
//! `OptimizeEssentialGraph`).

use std::collections::{BTreeMap, BTreeSet};

use stillpoint_geometry::Se3;
use tracing::debug;

use super::{LoopCloser, LoopEvent, LoopSettings, MapCorrection, Verified};
use crate::data::{KfId, Map, MpId};
use crate::optimize::{PoseGraph, PoseGraphEdge, optimize_pose_graph};
use crate::solve::rigid::apply;

impl LoopCloser {
    /// ORB-SLAM `CorrectLoop` (SE3): returns the poses it moved and the event.
    pub(super) fn correct(
        &mut self,
        m: &mut Map,
        kf: KfId,
        v: &Verified,
    ) -> Option<(MapCorrection, LoopEvent)> {
        let ls = self.s.loop_closing.clone();
        let (cur, lk) = (m.keyframes.get(&kf)?, m.keyframes.get(&v.loop_kf)?);
        if cur.bad || lk.bad {
            return None;
        }
        let epoch = cur.map_epoch;
        m.update_connections(kf, self.s.covisibility_min_shared);
        // Local mapping may have linked the two since detection (threaded): the loop keyframe
        // would then be moved with the group and held fixed at once.
        if m.keyframes[&kf].connections.contains_key(&v.loop_kf) {
            debug!(
                keyframe = kf,
                loop_keyframe = v.loop_kf,
                "loop keyframe now covisible; not corrected"
            );
            return None;
        }
        // A loop into an older map: the current map first moves onto it as a whole.
        let loop_epoch = m.keyframes[&v.loop_kf].map_epoch;
        let merged_map = (loop_epoch != epoch).then_some(loop_epoch);
        let unmerged = match merged_map {
            Some(older) => self.merge_maps(m, kf, v, older)?,
            None => BTreeMap::new(),
        };
        let before: BTreeMap<KfId, Se3> = m
            .keyframes
            .values()
            .filter(|k| k.map_epoch == epoch)
            .map(|k| (k.id, k.pose_cw))
            .collect();
        // The current keyframe's pose from the loop, and its covisible group moved with it.
        let cur_old = before[&kf];
        let cur_new = v.t_cl * m.keyframes[&v.loop_kf].pose_cw;
        let mut group: Vec<KfId> = vec![kf];
        group.extend(
            m.keyframes[&kf]
                .best_covisibles(usize::MAX)
                .into_iter()
                .filter(|c| {
                    m.keyframes
                        .get(c)
                        .is_some_and(|k| !k.bad && k.map_epoch == epoch)
                })
                .take(ls.correction_group_max),
        );
        let mut corrected: BTreeMap<KfId, Se3> = BTreeMap::new();
        for &g in &group {
            let t_gc = before[&g] * cur_old.inverse();
            corrected.insert(g, t_gc * cur_new);
        }
        // Points seen by the group move with the keyframe that moves them first.
        let mut moved_by: BTreeMap<MpId, KfId> = BTreeMap::new();
        for &g in &group {
            let delta = corrected[&g].inverse() * before[&g];
            let mps: Vec<MpId> = m.keyframes[&g]
                .map_points
                .iter()
                .flatten()
                .copied()
                .collect();
            for mp in mps {
                if moved_by.contains_key(&mp) {
                    continue;
                }
                if let Some(p) = m.points.get_mut(&mp) {
                    p.position = apply(&delta, &p.position);
                    moved_by.insert(mp, g);
                }
            }
            if let Some(k) = m.keyframes.get_mut(&g) {
                k.pose_cw = corrected[&g];
            }
        }
        // The verified matches: the loop's points replace the current keyframe's duplicates.
        for (&i, &loop_mp) in &v.matches {
            if !m.points.contains_key(&loop_mp) {
                continue;
            }
            match m.keyframes[&kf].map_points.get(i).copied().flatten() {
                Some(own) if own == loop_mp => {}
                Some(own) if m.points.contains_key(&own) => m.replace_point(own, loop_mp),
                _ => {
                    if !m.points[&loop_mp].observations.contains_key(&kf) {
                        m.add_observation(loop_mp, kf, i);
                    }
                }
            }
        }
        // Fuse the loop group's points into every corrected keyframe.
        let previous: BTreeMap<KfId, BTreeSet<KfId>> = group
            .iter()
            .map(|g| (*g, m.keyframes[g].connections.keys().copied().collect()))
            .collect();
        for &g in &group {
            self.fuse_into(m, g, &v.loop_points, ls.fuse_radius);
        }
        for mp in v.loop_points.iter().chain(moved_by.keys()) {
            m.update_normal_and_depth(*mp, &self.scales);
        }
        // New links: connections that appeared through the fusion, outside the group.
        let group_set: BTreeSet<KfId> = group.iter().copied().collect();
        let mut loop_links: BTreeMap<KfId, BTreeSet<KfId>> = BTreeMap::new();
        for &g in &group {
            m.update_connections(g, self.s.covisibility_min_shared);
            let links: BTreeSet<KfId> = m.keyframes[&g]
                .connections
                .keys()
                .filter(|c| !previous[&g].contains(c) && !group_set.contains(c))
                .copied()
                .collect();
            if !links.is_empty() {
                loop_links.insert(g, links);
            }
        }
        let (graph_keyframes, graph_edges, after) = self.essential_graph(
            m,
            epoch,
            (kf, v.loop_kf),
            (&before, &corrected),
            &loop_links,
            &ls,
        );
        // Keyframes and points follow the optimised poses; a point moves with the keyframe
        // that moved it above, else with its reference keyframe.
        let initial = |k: KfId| {
            corrected
                .get(&k)
                .copied()
                .or_else(|| before.get(&k).copied())
        };
        let point_ids: Vec<MpId> = m.points.keys().copied().collect();
        for mp in point_ids {
            let Some(p) = m.points.get(&mp) else { continue };
            if p.map_epoch != epoch {
                continue;
            }
            let anchor = moved_by.get(&mp).copied().or_else(|| {
                std::iter::once(p.reference_kf)
                    .chain(p.observations.keys().copied())
                    .find(|k| after.contains_key(k))
            });
            let Some(a) = anchor else { continue };
            let (Some(old), Some(new)) = (initial(a), after.get(&a)) else {
                continue;
            };
            let pos = apply(&new.inverse(), &apply(&old, &p.position));
            if let Some(p) = m.points.get_mut(&mp) {
                p.position = pos;
            }
        }
        for (&k, pose) in &after {
            if let Some(x) = m.keyframes.get_mut(&k) {
                x.pose_cw = *pose;
            }
        }
        move_culled_keyframes(m, epoch, &before, &after);
        let ids: Vec<MpId> = m.points.keys().copied().collect();
        for mp in ids {
            m.update_normal_and_depth(mp, &self.scales);
        }
        self.loop_edges.insert((kf, v.loop_kf));
        self.last_loop_kf = Some(kf);
        self.groups.clear();
        self.pending_merge = None;
        let cur_old = unmerged.get(&kf).copied().unwrap_or(cur_old);
        let cur_final = after.get(&kf).copied().unwrap_or(cur_new);
        let moved_m =
            (cur_old.inverse().translation.vector - cur_final.inverse().translation.vector).norm();
        let moved_deg = cur_old.rotation.angle_to(&cur_final.rotation).to_degrees();
        let (c, l) = (&m.keyframes[&kf], &m.keyframes[&v.loop_kf]);
        let event = LoopEvent {
            keyframe: kf,
            frame_index: c.frame_index,
            timestamp: c.timestamp,
            loop_keyframe: v.loop_kf,
            loop_frame_index: l.frame_index,
            loop_timestamp: l.timestamp,
            ransac_inliers: v.ransac_inliers,
            refined_inliers: v.refined_inliers,
            loop_matches: v.matches.len(),
            correction_m: moved_m,
            correction_deg: moved_deg,
            graph_keyframes,
            graph_edges,
            correction_ms: 0.0,
            merged_map,
        };
        // Tracking moves with its keyframes from where they were before the merge.
        let poses = after
            .iter()
            .filter_map(|(k, new)| {
                unmerged
                    .get(k)
                    .or_else(|| before.get(k))
                    .map(|old| (*k, (*old, *new)))
            })
            .collect();
        let rescaled = (v.scale != 1.0).then(|| (v.scale, unmerged.keys().copied().collect()));
        Some((MapCorrection { poses, rescaled }, event))
    }

    /// The loop keyframe `v.loop_kf` is in the older map `older`: every keyframe and point of
    /// the current map moves by the one rigid transform (similarity, for monocular maps) that
    /// puts `kf` where the loop says, and the older map's keyframes and points join the current
    /// map (its first keyframe becomes the gauge). Returns the current map's keyframe poses before the move (`None`
    /// when `kf` is no longer in the current map).
    fn merge_maps(
        &self,
        m: &mut Map,
        kf: KfId,
        v: &Verified,
        older: u32,
    ) -> Option<BTreeMap<KfId, Se3>> {
        let epoch = m.keyframes.get(&kf)?.map_epoch;
        if epoch != m.epoch {
            return None;
        }
        let cur_old = m.keyframes[&kf].pose_cw;
        let cur_new = v.t_cl * m.keyframes[&v.loop_kf].pose_cw;
        // World of the current map -> world of the older one: x' = s R x + t with s the older
        // map's units per the current one's (1 with depth) and R, t from the finder's two poses;
        // a world-to-camera pose becomes R_k R^T, s t_k - R_k R^T t.
        let s = v.scale;
        let r = cur_new.rotation.inverse() * cur_old.rotation;
        let t = cur_new.rotation.inverse()
            * (s * cur_old.translation.vector - cur_new.translation.vector);
        let mut unmerged = BTreeMap::new();
        for k in m.keyframes.values_mut() {
            if k.map_epoch == epoch {
                unmerged.insert(k.id, k.pose_cw);
                let rot = k.pose_cw.rotation * r.inverse();
                let trans = s * k.pose_cw.translation.vector - rot * t;
                k.pose_cw = Se3::from_parts(trans.into(), rot);
            } else if k.map_epoch == older {
                k.map_epoch = epoch;
            }
        }
        for p in m.points.values_mut() {
            if p.map_epoch == epoch {
                p.position = s * (r * p.position) + t;
            } else if p.map_epoch == older {
                p.map_epoch = epoch;
            }
        }
        m.origin_kf = m
            .keyframes
            .values()
            .find(|k| !k.bad && k.map_epoch == epoch && !unmerged.contains_key(&k.id))
            .map(|k| k.id);
        debug!(
            keyframe = kf,
            loop_keyframe = v.loop_kf,
            older_map = older,
            moved_m = t.norm(),
            scale = s,
            "maps merged"
        );
        Some(unmerged)
    }

    /// ORB-SLAM `Fuse(pKF, Scw, vpPoints, th, vpReplacePoint)`: loop points projected into `g`
    /// (already corrected); a keypoint's own point is replaced by the loop's, a free keypoint
    /// gets the observation.
    pub(super) fn fuse_into(&self, m: &mut Map, g: KfId, points: &[MpId], radius: f64) {
        let Some(k) = m.keyframes.get(&g) else { return };
        let pose = k.pose_cw;
        let center = k.camera_center();
        let mut used = BTreeSet::new();
        let skip = |_: MpId, p: &crate::data::MapPoint| p.observations.contains_key(&g);
        let view = super::similarity::Projection {
            keyframe: k,
            pose: &pose,
            center,
        };
        let actions = self.match_by_projection(m, &view, points, skip, &mut used, radius);
        for (i, mp) in actions {
            if !m.points.contains_key(&mp) {
                continue;
            }
            match m.keyframes[&g].map_points[i] {
                Some(own) if own == mp => {}
                Some(own) if m.points.contains_key(&own) => m.replace_point(own, mp),
                _ => {
                    if !m.points[&mp].observations.contains_key(&g) {
                        m.add_observation(mp, g, i);
                    }
                }
            }
        }
    }

    /// ORB-SLAM `OptimizeEssentialGraph` over SE3: the loop keyframe fixed, edges of the new
    /// loop links (from the corrected poses), the spanning tree, earlier loops and strong
    /// covisibility (from the poses before the correction). Returns the keyframe and edge
    /// counts and the optimised pose of every good keyframe.
    pub(super) fn essential_graph(
        &self,
        m: &Map,
        epoch: u32,
        (kf, loop_kf): (KfId, KfId),
        (before, corrected): (&BTreeMap<KfId, Se3>, &BTreeMap<KfId, Se3>),
        loop_links: &BTreeMap<KfId, BTreeSet<KfId>>,
        ls: &LoopSettings,
    ) -> (usize, usize, BTreeMap<KfId, Se3>) {
        let ids: Vec<KfId> = m
            .keyframes
            .values()
            .filter(|k| !k.bad && k.map_epoch == epoch)
            .map(|k| k.id)
            .collect();
        let index: BTreeMap<KfId, usize> = ids.iter().enumerate().map(|(i, k)| (*k, i)).collect();
        let initial = |k: KfId| corrected.get(&k).copied().unwrap_or(before[&k]);
        let mut g = PoseGraph {
            poses: ids.iter().map(|&k| initial(k)).collect(),
            fixed: ids.iter().map(|&k| k == loop_kf).collect(),
            edges: Vec::new(),
        };
        let mut inserted: BTreeSet<(KfId, KfId)> = BTreeSet::new();
        let mut add = |g: &mut PoseGraph, a: KfId, b: KfId, t_ab: Se3| {
            let key = (a.min(b), a.max(b));
            if a == b || !inserted.insert(key) {
                return;
            }
            if let (Some(&i), Some(&j)) = (index.get(&a), index.get(&b)) {
                g.edges.push(PoseGraphEdge {
                    i,
                    j,
                    t_ij: t_ab,
                    weight: 1.0,
                });
            }
        };
        for (&a, links) in loop_links {
            for &b in links {
                let strong = m.keyframes[&a].connections.get(&b).copied().unwrap_or(0)
                    >= ls.essential_min_weight;
                if (a == kf && b == loop_kf) || strong {
                    add(&mut g, a, b, initial(a) * initial(b).inverse());
                }
            }
        }
        // The loop itself, in case fusion did not link the two keyframes strongly.
        add(
            &mut g,
            kf,
            loop_kf,
            initial(kf) * initial(loop_kf).inverse(),
        );
        let rel = |a: KfId, b: KfId| before[&a] * before[&b].inverse();
        for &k in &ids {
            let x = &m.keyframes[&k];
            if let Some(p) = x.parent.filter(|p| index.contains_key(p)) {
                add(&mut g, k, p, rel(k, p));
            }
            for &(a, b) in &self.loop_edges {
                if (a == k || b == k) && index.contains_key(&a) && index.contains_key(&b) {
                    add(&mut g, a, b, rel(a, b));
                }
            }
            let strong = x
                .best_covisibles(ls.essential_max_covisibles)
                .into_iter()
                .filter(|o| {
                    x.connections
                        .get(o)
                        .is_some_and(|&w| w >= ls.essential_min_weight)
                });
            for o in strong {
                if index.contains_key(&o) {
                    add(&mut g, k, o, rel(k, o));
                }
            }
        }
        let report = optimize_pose_graph(&mut g, ls.pose_graph_iterations);
        debug!(
            keyframes = ids.len(),
            edges = g.edges.len(),
            before = report.initial_cost,
            after = report.final_cost,
            iterations = report.iterations,
            "essential graph"
        );
        let after = ids.iter().copied().zip(g.poses.iter().copied()).collect();
        (ids.len(), g.edges.len(), after)
    }
}

/// Culled keyframes stay anchors of the frame trajectory: each moves with its nearest good
/// ancestor in the spanning tree (`before` / `after`: poses of the good ones).
pub(super) fn move_culled_keyframes(
    m: &mut Map,
    epoch: u32,
    before: &BTreeMap<KfId, Se3>,
    after: &BTreeMap<KfId, Se3>,
) {
    let bad: Vec<KfId> = m
        .keyframes
        .values()
        .filter(|k| k.bad && k.map_epoch == epoch)
        .map(|k| k.id)
        .collect();
    for b in bad {
        let mut a = m.keyframes[&b].parent;
        let mut hops = 0;
        while let Some(x) = a {
            if after.contains_key(&x) || hops > m.keyframes.len() {
                break;
            }
            a = m.keyframes.get(&x).and_then(|k| k.parent);
            hops += 1;
        }
        if let Some(x) = a
            && let (Some(old), Some(new)) = (before.get(&x), after.get(&x))
            && let Some(k) = m.keyframes.get_mut(&b)
        {
            k.pose_cw = k.pose_cw * old.inverse() * new;
        }
    }
}
