//! Stage 3, correction: the current keyframe's covisible group moved onto the loop, points
//! fused, the essential graph optimised (ORB-SLAM's `CorrectLoop`, `SearchAndFuse`,
//! `OptimizeEssentialGraph`).

use std::collections::{BTreeMap, BTreeSet};

use stillpoint_geometry::{Se3, Sim3};
use tracing::debug;

use super::{LoopCloser, LoopEvent, LoopSettings, MapCorrection, Verified};
use crate::data::{KfId, Map, MpId};
use crate::optimize::{
    Graph, GraphEdge, PoseGraphReport, optimize_pose_graph, optimize_sim3_graph,
};
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
        // Monocular: a similarity per keyframe (ORB-SLAM's Sim(3) correction), so the scale the
        // map lost between the loop keyframe and this one comes back; the loop's scale is the
        // loop keyframe's units per this keyframe's (1 after a merge: the map took it whole).
        let similar_loop = self.s.monocular.then(|| {
            let scale = if merged_map.is_some() { 1.0 } else { v.scale };
            Sim3 {
                scale: 1.0 / scale,
                rigid: Se3::from_parts(
                    (cur_new.translation.vector / scale).into(),
                    cur_new.rotation,
                ),
            }
        });
        let mut corrected: BTreeMap<KfId, Se3> = BTreeMap::new();
        let mut similar: BTreeMap<KfId, Sim3> = BTreeMap::new();
        for &g in &group {
            let t_gc = before[&g] * cur_old.inverse();
            match similar_loop {
                Some(s_cw) => {
                    let s_gw = Sim3::from_rigid(t_gc).compose(&s_cw);
                    corrected.insert(g, s_gw.to_pose());
                    similar.insert(g, s_gw);
                }
                None => {
                    corrected.insert(g, t_gc * cur_new);
                }
            }
        }
        // Points seen by the group move with the keyframe that moves them first.
        let mut moved_by: BTreeMap<MpId, KfId> = BTreeMap::new();
        for &g in &group {
            // World of the keyframe before -> corrected world (a similarity's inverse once
            // per keyframe, not per point).
            let moved = match similar.get(&g) {
                Some(s_gw) => Moved::Similar(s_gw.inverse()),
                None => Moved::Rigid(corrected[&g].inverse() * before[&g]),
            };
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
                    p.position = match &moved {
                        Moved::Similar(s_wg) => {
                            s_wg.transform_point(&apply(&before[&g], &p.position))
                        }
                        Moved::Rigid(delta) => apply(delta, &p.position),
                    };
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
        let edges = self.essential_edges(m, epoch, (kf, v.loop_kf), &loop_links, &ls);
        let graph_keyframes = edges.keyframes.len();
        let graph_edges = edges.pairs.len();
        // Each keyframe's similarity after the graph (scale 1 for RGB-D and stereo), and the
        // one it started from, by which a point anchored to it moved.
        let (initial_of, after_of): (BTreeMap<KfId, Sim3>, BTreeMap<KfId, Sim3>) =
            if self.s.monocular {
                let initial: BTreeMap<KfId, Sim3> = edges
                    .keyframes
                    .iter()
                    .map(|&k| {
                        let s = similar
                            .get(&k)
                            .copied()
                            .unwrap_or_else(|| Sim3::from_rigid(before[&k]));
                        (k, s)
                    })
                    .collect();
                let after = sim3_essential_graph(&edges, &initial, &before, &ls);
                (initial, after)
            } else {
                (BTreeMap::new(), BTreeMap::new())
            };
        let after: BTreeMap<KfId, Se3> = if self.s.monocular {
            after_of.iter().map(|(k, s)| (*k, s.to_pose())).collect()
        } else {
            se3_essential_graph(&edges, (&before, &corrected), &ls)
        };
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
            let pos = match (initial_of.get(&a), after_of.get(&a)) {
                (Some(old), Some(new)) => new
                    .inverse()
                    .transform_point(&old.transform_point(&p.position)),
                _ => {
                    let (Some(old), Some(new)) = (initial(a), after.get(&a)) else {
                        continue;
                    };
                    apply(&new.inverse(), &apply(&old, &p.position))
                }
            };
            if let Some(p) = m.points.get_mut(&mp) {
                p.position = pos;
            }
        }
        for (&k, pose) in &after {
            if let Some(x) = m.keyframes.get_mut(&k) {
                x.pose_cw = *pose;
            }
        }
        if self.s.monocular {
            let before_of: BTreeMap<KfId, Sim3> = before
                .iter()
                .map(|(k, p)| (*k, Sim3::from_rigid(*p)))
                .collect();
            move_culled_keyframes_sim3(m, epoch, &before_of, &after_of);
        } else {
            move_culled_keyframes(m, epoch, &before, &after);
        }
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
            correction_scale: v.scale,
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
        // A frame anchored to a keyframe sees the world nearer or farther by the keyframe's
        // scale change: the merge's (older map's units per the merged map's), then the
        // similarity's (its camera coordinates shrink by 1 / scale).
        let mut rescaled: BTreeMap<KfId, f64> = BTreeMap::new();
        if v.scale != 1.0 && merged_map.is_some() {
            rescaled.extend(unmerged.keys().map(|k| (*k, v.scale)));
        }
        for (k, s) in &after_of {
            if s.scale != 1.0 {
                *rescaled.entry(*k).or_insert(1.0) /= s.scale;
            }
        }
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
            }
        }
        for p in m.points.values_mut() {
            if p.map_epoch == epoch {
                p.position = s * (r * p.position) + t;
            }
        }
        m.relabel_map(older, epoch);
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

    /// ORB-SLAM `OptimizeEssentialGraph`'s edges: the loop keyframe fixed, edges of the new
    /// loop links (measured on the corrected poses), the spanning tree, earlier loops and strong
    /// covisibility (measured on the poses before the correction), over every good keyframe.
    pub(super) fn essential_edges(
        &self,
        m: &Map,
        epoch: u32,
        (kf, loop_kf): (KfId, KfId),
        loop_links: &BTreeMap<KfId, BTreeSet<KfId>>,
        ls: &LoopSettings,
    ) -> EssentialEdges {
        let keyframes: Vec<KfId> = m
            .keyframes
            .values()
            .filter(|k| !k.bad && k.map_epoch == epoch)
            .map(|k| k.id)
            .collect();
        let index: BTreeMap<KfId, usize> =
            keyframes.iter().enumerate().map(|(i, k)| (*k, i)).collect();
        let mut edges = EssentialEdges {
            keyframes,
            fixed: loop_kf,
            pairs: Vec::new(),
        };
        let mut inserted: BTreeSet<(KfId, KfId)> = BTreeSet::new();
        let mut add = |e: &mut EssentialEdges, a: KfId, b: KfId, corrected: bool| {
            let key = (a.min(b), a.max(b));
            if a == b || !inserted.insert(key) {
                return;
            }
            if let (Some(&i), Some(&j)) = (index.get(&a), index.get(&b)) {
                e.pairs.push(EssentialEdge {
                    i,
                    j,
                    ids: (a, b),
                    corrected,
                });
            }
        };
        for (&a, links) in loop_links {
            for &b in links {
                let strong = m.keyframes[&a].connections.get(&b).copied().unwrap_or(0)
                    >= ls.essential_min_weight;
                if (a == kf && b == loop_kf) || strong {
                    add(&mut edges, a, b, true);
                }
            }
        }
        // The loop itself, in case fusion did not link the two keyframes strongly.
        add(&mut edges, kf, loop_kf, true);
        for k in edges.keyframes.clone() {
            let x = &m.keyframes[&k];
            if let Some(p) = x.parent.filter(|p| index.contains_key(p)) {
                add(&mut edges, k, p, false);
            }
            for &(a, b) in &self.loop_edges {
                if (a == k || b == k) && index.contains_key(&a) && index.contains_key(&b) {
                    add(&mut edges, a, b, false);
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
                    add(&mut edges, k, o, false);
                }
            }
        }
        edges
    }
}

/// How the points a corrected keyframe moves go: camera-to-world of its similarity, or the
/// rigid move from its old pose to its new one.
enum Moved {
    Similar(Sim3),
    Rigid(Se3),
}

/// The essential graph's keyframes and edges, before any pose is attached.
pub(super) struct EssentialEdges {
    /// Every good keyframe of the map, in id order (the graph's vertices).
    keyframes: Vec<KfId>,
    /// The loop keyframe, held fixed.
    fixed: KfId,
    pairs: Vec<EssentialEdge>,
}

/// One edge: vertex indices, keyframe ids, and whether it is measured on the corrected poses.
struct EssentialEdge {
    i: usize,
    j: usize,
    ids: (KfId, KfId),
    corrected: bool,
}

impl EssentialEdges {
    /// The graph with each keyframe's starting transform and each edge's measurement, both
    /// from keyframe ids (`measured(a, b, corrected)`: b seen from a).
    fn graph<V>(
        &self,
        initial: impl Fn(KfId) -> V,
        measured: impl Fn(KfId, KfId, bool) -> V,
    ) -> Graph<V> {
        Graph {
            poses: self.keyframes.iter().map(|&k| initial(k)).collect(),
            fixed: self.keyframes.iter().map(|&k| k == self.fixed).collect(),
            edges: self
                .pairs
                .iter()
                .map(|e| GraphEdge {
                    i: e.i,
                    j: e.j,
                    t_ij: measured(e.ids.0, e.ids.1, e.corrected),
                    weight: 1.0,
                })
                .collect(),
        }
    }
}

/// The essential graph over SE3 (RGB-D, stereo): the optimised pose of every good keyframe.
fn se3_essential_graph(
    edges: &EssentialEdges,
    (before, corrected): (&BTreeMap<KfId, Se3>, &BTreeMap<KfId, Se3>),
    ls: &LoopSettings,
) -> BTreeMap<KfId, Se3> {
    let initial = |k: KfId| corrected.get(&k).copied().unwrap_or(before[&k]);
    let mut g = edges.graph(initial, |a, b, from_corrected| {
        if from_corrected {
            initial(a) * initial(b).inverse()
        } else {
            before[&a] * before[&b].inverse()
        }
    });
    let report = optimize_pose_graph(&mut g, ls.pose_graph_iterations);
    log_graph("essential graph", &g, &report);
    edges.keyframes.iter().copied().zip(g.poses).collect()
}

/// The essential graph over Sim(3) (monocular): the optimised similarity of every good
/// keyframe, from `initial` (the corrected group's similarities, the others' poses).
fn sim3_essential_graph(
    edges: &EssentialEdges,
    initial: &BTreeMap<KfId, Sim3>,
    before: &BTreeMap<KfId, Se3>,
    ls: &LoopSettings,
) -> BTreeMap<KfId, Sim3> {
    let mut g = edges.graph(
        |k| initial[&k],
        |a, b, from_corrected| {
            if from_corrected {
                initial[&a].compose(&initial[&b].inverse())
            } else {
                Sim3::from_rigid(before[&a] * before[&b].inverse())
            }
        },
    );
    let report = optimize_sim3_graph(&mut g, ls.pose_graph_iterations);
    log_graph("essential graph (Sim3)", &g, &report);
    edges.keyframes.iter().copied().zip(g.poses).collect()
}

fn log_graph<V>(what: &str, g: &Graph<V>, report: &PoseGraphReport) {
    debug!(
        keyframes = g.poses.len(),
        edges = g.edges.len(),
        before = report.initial_cost,
        after = report.final_cost,
        iterations = report.iterations,
        "{what}"
    );
}

/// Culled keyframes stay anchors of the frame trajectory: each moves with its nearest good
/// ancestor in the spanning tree (`before` / `after`: poses of the good ones).
pub(super) fn move_culled_keyframes(
    m: &mut Map,
    epoch: u32,
    before: &BTreeMap<KfId, Se3>,
    after: &BTreeMap<KfId, Se3>,
) {
    move_culled_keyframes_by(m, epoch, before, after, |pose, old, new| {
        *pose * old.inverse() * new
    });
}

/// [`move_culled_keyframes`] for a monocular map corrected in Sim(3): each culled keyframe
/// keeps its pose relative to its ancestor's similarity (`before` / `after`: the good ones').
fn move_culled_keyframes_sim3(
    m: &mut Map,
    epoch: u32,
    before: &BTreeMap<KfId, Sim3>,
    after: &BTreeMap<KfId, Sim3>,
) {
    move_culled_keyframes_by(m, epoch, before, after, |pose, old, new| {
        Sim3::from_rigid(*pose)
            .compose(&old.inverse())
            .compose(new)
            .to_pose()
    });
}

/// Each culled keyframe of map `epoch` gets `moved(its pose, ancestor before, ancestor after)`.
fn move_culled_keyframes_by<V>(
    m: &mut Map,
    epoch: u32,
    before: &BTreeMap<KfId, V>,
    after: &BTreeMap<KfId, V>,
    moved: impl Fn(&Se3, &V, &V) -> Se3,
) {
    let bad: Vec<KfId> = m
        .keyframes
        .values()
        .filter(|k| k.bad && k.map_epoch == epoch)
        .map(|k| k.id)
        .collect();
    for b in bad {
        if let Some(x) = good_ancestor(m, b, after)
            && let (Some(old), Some(new)) = (before.get(&x), after.get(&x))
            && let Some(k) = m.keyframes.get_mut(&b)
        {
            k.pose_cw = moved(&k.pose_cw, old, new);
        }
    }
}

/// The nearest ancestor of `b` in the spanning tree that is a key of `good`.
fn good_ancestor<V>(m: &Map, b: KfId, good: &BTreeMap<KfId, V>) -> Option<KfId> {
    let mut a = m.keyframes[&b].parent;
    let mut hops = 0;
    while let Some(x) = a {
        if good.contains_key(&x) || hops > m.keyframes.len() {
            break;
        }
        a = m.keyframes.get(&x).and_then(|k| k.parent);
        hops += 1;
    }
    a
}
