//! Stage 4, global bundle adjustment after a correction (ORB-SLAM's
//! `RunGlobalBundleAdjustment`).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Mutex;

use stillpoint_geometry::Se3;
use tracing::debug;

use super::{LoopCloser, MapCorrection};
use crate::data::{KfId, MpId, SharedMap};
use crate::solve::rigid::apply;

use super::correction::move_culled_keyframes;

impl LoopCloser {
    /// ORB-SLAM `RunGlobalBundleAdjustment`: every keyframe and point of the current map, the
    /// origin fixed, robust LM; solved with the map unlocked (local mapping stays stopped, as
    /// the caller holds its lock), then written back. Keyframes tracking created meanwhile
    /// move with the newest optimised one, points of theirs with their reference keyframe.
    pub(super) fn global_bundle_adjustment(
        &self,
        map: &SharedMap,
        publish: Option<&Mutex<Vec<MapCorrection>>>,
    ) -> Option<MapCorrection> {
        let (mut problem, kf_ids, pt_ids) = {
            let m = map.lock().ok()?;
            let kfs: Vec<KfId> = m.current_keyframes().map(|k| k.id).collect();
            if kfs.len() > self.s.loop_closing.global_ba_max_keyframes || kfs.len() < 2 {
                debug!(keyframes = kfs.len(), "global BA skipped");
                return None;
            }
            let index: BTreeMap<KfId, usize> =
                kfs.iter().enumerate().map(|(i, k)| (*k, i)).collect();
            let origin = m
                .origin_kf
                .filter(|o| index.contains_key(o))
                .unwrap_or(kfs[0]);
            let mut problem = crate::optimize::BaProblem {
                poses: kfs.iter().map(|k| m.keyframes[k].pose_cw).collect(),
                fixed: kfs.iter().map(|k| *k == origin).collect(),
                points: Vec::new(),
                observations: Vec::new(),
            };
            let mut pt_ids = Vec::new();
            for (id, p) in &m.points {
                if p.bad || p.map_epoch != m.epoch {
                    continue;
                }
                let obs: Vec<(usize, usize)> = p
                    .observations
                    .iter()
                    .filter_map(|(k, i)| index.get(k).map(|c| (*c, *i)))
                    .collect();
                if obs.is_empty() {
                    continue;
                }
                let pi = pt_ids.len();
                pt_ids.push(*id);
                problem.points.push(p.position);
                for (c, i) in obs {
                    let k = &m.keyframes[&kfs[c]];
                    let (Some(px), Some(&o), Some(&ur)) =
                        (k.points.get(i), k.octaves.get(i), k.u_right.get(i))
                    else {
                        continue;
                    };
                    problem.observations.push(crate::optimize::BaObservation {
                        camera: c,
                        point: pi,
                        u: px.x,
                        v: px.y,
                        u_right: (ur > 0.0).then_some(ur as f64),
                        inv_sigma2: self.inv_sigma2[o as usize],
                    });
                }
            }
            (problem, kfs, pt_ids)
        };
        let before = problem.poses.clone();
        let report = crate::optimize::global_bundle_adjustment(
            &mut problem,
            &self.s,
            self.s.loop_closing.global_ba_iterations,
            self.s.loop_closing.global_ba_trials_after_failure,
        );
        debug!(
            steps = report.steps,
            rejected = report.rejected,
            cost_before = report.cost_before,
            cost_after = report.cost_after,
            "global BA solved"
        );
        let mut m = map.lock().ok()?;
        let mut poses = BTreeMap::new();
        for (c, k) in kf_ids.iter().enumerate() {
            if let Some(x) = m.keyframes.get_mut(k) {
                poses.insert(*k, (before[c], problem.poses[c]));
                x.pose_cw = problem.poses[c];
            }
        }
        let newest = kf_ids.last().and_then(|k| poses.get(k)).copied();
        let late: Vec<KfId> = m
            .keyframes
            .keys()
            .copied()
            .filter(|k| !poses.contains_key(k) && kf_ids.last().is_some_and(|n| k > n))
            .filter(|k| m.keyframes[k].map_epoch == m.epoch && !m.keyframes[k].bad)
            .collect();
        let mut late_delta: BTreeMap<KfId, Se3> = BTreeMap::new();
        if let Some((old, new)) = newest {
            for k in late {
                if let Some(x) = m.keyframes.get_mut(&k) {
                    let moved = x.pose_cw * old.inverse() * new;
                    poses.insert(k, (x.pose_cw, moved));
                    late_delta.insert(k, old.inverse() * new);
                    x.pose_cw = moved;
                }
            }
        }
        let (good_before, good_after): (BTreeMap<KfId, Se3>, BTreeMap<KfId, Se3>) =
            poses.iter().map(|(k, (b, a))| ((*k, *b), (*k, *a))).unzip();
        let epoch = m.epoch;
        move_culled_keyframes(&mut m, epoch, &good_before, &good_after);
        let in_problem: BTreeSet<MpId> = pt_ids.iter().copied().collect();
        for (i, id) in pt_ids.iter().enumerate() {
            if let Some(p) = m.points.get_mut(id) {
                p.position = problem.points[i];
            }
        }
        if !late_delta.is_empty() {
            let ids: Vec<MpId> = m
                .points
                .keys()
                .filter(|k| !in_problem.contains(k))
                .copied()
                .collect();
            for id in ids {
                let Some(p) = m.points.get_mut(&id) else {
                    continue;
                };
                if let Some(d) = late_delta.get(&p.reference_kf) {
                    // T_new⁻¹ T_old = (T_old d)⁻¹ T_old = d⁻¹.
                    p.position = apply(&d.inverse(), &p.position);
                }
            }
        }
        let ids: Vec<MpId> = m.points.keys().copied().collect();
        for id in ids {
            m.update_normal_and_depth(id, &self.scales);
        }
        let correction = MapCorrection {
            poses,
            rescaled: BTreeMap::new(),
        };
        if let Some(p) = publish
            && let Ok(mut q) = p.lock()
        {
            q.push(correction.clone());
        }
        debug!(keyframes = kf_ids.len(), points = pt_ids.len(), "global BA");
        Some(correction)
    }
}
