//! Loop closing (ORB-SLAM2/3 `LoopClosing` for RGB-D and stereo, where the scale is known and a
//! loop is an SE3): per keyframe from local mapping, bag-of-words candidates, covisibility
//! consistency, geometric verification, then the correction: the keyframe's covisible group is
//! moved onto the loop, duplicated points are fused, and the essential graph is optimised.
//!
//! [`LoopCloser::process`] does one keyframe (inline under `--sequential`); [`LoopThread`] runs
//! it in its own thread fed by local mapping through a channel. While it corrects the map it
//! holds the lock local mapping holds per keyframe, so local mapping stops between keyframes
//! (no busy-wait), and the map lock, so tracking waits for the correction as in ORB-SLAM.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::mpsc::Receiver;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use stillpoint_geometry::{Se3, Vec3};
use tracing::{debug, info};

use crate::data::{KeyFrame, KfId, Map, MapPoint, MpId};
use crate::matching::NearestTwo;
use crate::optimize::{PoseGraph, PoseGraphEdge, optimize_pose_graph};
use crate::place::{DatabaseParams, KeyFrameDatabase, Vocabulary};
use crate::solve::rigid::{RigidPair, RigidRansacParams, apply, ransac_rigid, refine_rigid};
use crate::{SlamSettings, hamming};

/// Loop-closing parameters, ORB-SLAM's values unless said otherwise.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct LoopSettings {
    /// Run loop closing at all (`stillpoint run --no-loop-closing` turns it off).
    pub enabled: bool,
    /// Vocabulary and its online training.
    pub database: DatabaseParams,
    /// No loop is searched while the map holds fewer keyframes (ORB-SLAM: 10).
    pub min_keyframes: usize,
    /// ... nor within this many keyframes after the last loop (ORB-SLAM: 10).
    pub keyframes_after_loop: usize,
    /// A candidate's covisibility group must stay consistent for this many keyframes after
    /// the one that first found it (ORB-SLAM2's `mnCovisibilityConsistencyTh` = 3: the group
    /// is seen in four consecutive keyframes).
    pub consistency: usize,
    /// Descriptor matches between the keyframe and a candidate needed to try RANSAC (ORB-SLAM
    /// `SearchByBoW` >= 20).
    pub min_descriptor_matches: usize,
    /// Nearest / second Hamming ratio of those matches (ORB-SLAM: 0.75).
    pub match_ratio: f32,
    /// RANSAC iterations and inliers needed (ORB-SLAM `Sim3Solver`: 300, 20).
    pub ransac_iterations: usize,
    pub ransac_min_inliers: usize,
    /// Inliers needed after guided matching and refinement (ORB-SLAM `OptimizeSim3`: 20).
    pub min_refined_inliers: usize,
    /// Matches with the loop keyframe's covisible group, after projecting its points, needed
    /// to accept the loop (ORB-SLAM: 40).
    pub min_loop_matches: usize,
    /// Search radii in pixels at octave 0: guided matching between the two keyframes
    /// (`SearchBySim3`: 7.5), projection of the loop group's points (`SearchByProjection`:
    /// 10), fusion into the corrected keyframes (`Fuse`: 4).
    pub guided_radius: f64,
    pub projection_radius: f64,
    pub fuse_radius: f64,
    /// The keyframes moved with the current one onto the loop: its best covisible ones, at most
    /// this many (ours; ORB-SLAM takes them all, which on a map whose keyframes all see the same
    /// points, front-end off on walking_static, is the whole map: 225 keyframes, 2.7 s of
    /// fusion). The others follow through the essential graph.
    pub correction_group_max: usize,
    /// Covisibility edges of the essential graph need this many shared points (ORB-SLAM: 100).
    pub essential_min_weight: usize,
    /// ... and each keyframe adds at most its this many strongest (ours; ORB-SLAM takes them
    /// all). A map whose keyframes all see the same points (front-end off on a walking
    /// sequence: 227 keyframes) otherwise gives a dense graph of 22 885 edges.
    pub essential_max_covisibles: usize,
    /// Levenberg-Marquardt iterations of the essential graph (ORB-SLAM: 20).
    pub pose_graph_iterations: usize,
    /// Bundle adjustment of the whole map after a correction (ORB-SLAM runs one in a thread of
    /// its own; here it runs in loop closing's thread with local mapping stopped).
    pub global_ba: bool,
    /// Robust Levenberg-Marquardt iterations of it (ORB-SLAM: 10).
    pub global_ba_iterations: usize,
    /// Global BA solves the reduced camera system densely: maps with more keyframes skip it.
    pub global_ba_max_keyframes: usize,
}

impl Default for LoopSettings {
    fn default() -> Self {
        Self {
            enabled: true,
            database: DatabaseParams::default(),
            min_keyframes: 10,
            keyframes_after_loop: 10,
            consistency: 3,
            min_descriptor_matches: 20,
            match_ratio: 0.75,
            ransac_iterations: 300,
            ransac_min_inliers: 20,
            min_refined_inliers: 20,
            min_loop_matches: 40,
            guided_radius: 7.5,
            projection_radius: 10.0,
            fuse_radius: 4.0,
            correction_group_max: 30,
            essential_min_weight: 100,
            essential_max_covisibles: 10,
            pose_graph_iterations: 20,
            global_ba: true,
            global_ba_iterations: 10,
            global_ba_max_keyframes: 200,
        }
    }
}

/// One closed loop.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct LoopEvent {
    pub keyframe: KfId,
    pub frame_index: usize,
    pub timestamp: f64,
    pub loop_keyframe: KfId,
    pub loop_frame_index: usize,
    pub loop_timestamp: f64,
    /// RANSAC inliers, inliers after refinement, matches with the loop group.
    pub ransac_inliers: usize,
    pub refined_inliers: usize,
    pub loop_matches: usize,
    /// How far the keyframe moved (m, degrees): the drift the loop removed there.
    pub correction_m: f64,
    pub correction_deg: f64,
    /// Keyframes in the essential graph and its edges.
    pub graph_keyframes: usize,
    pub graph_edges: usize,
    pub correction_ms: f64,
}

/// What loop closing did over a run.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct LoopStats {
    /// Per keyframe: bag of words, detection and verification (ms; vocabulary training and
    /// corrections not included).
    pub detection_ms: Vec<f64>,
    /// Per vocabulary training (ms).
    pub training_ms: Vec<f64>,
    /// Per correction (ms).
    pub correction_ms: Vec<f64>,
    /// Per global bundle adjustment after a correction (ms).
    pub global_ba_ms: Vec<f64>,
    /// Candidates that passed the consistency test and were tried by verification, and how
    /// many of them it rejected.
    pub tried_candidates: usize,
    pub rejected_candidates: usize,
    pub vocabulary_words: usize,
    pub loops: Vec<LoopEvent>,
}

/// The keyframe poses a correction moved (world-to-camera, before and after): tracking moves
/// its last frame with its reference keyframe.
#[derive(Clone, Debug, Default)]
pub struct MapCorrection {
    pub poses: BTreeMap<KfId, (Se3, Se3)>,
}

/// A verified loop, ready to be corrected.
struct Verified {
    loop_kf: KfId,
    /// Camera of the loop keyframe to camera of the current one.
    t_cl: Se3,
    /// Keypoint of the current keyframe -> loop-side map point.
    matches: BTreeMap<usize, MpId>,
    /// Map points of the loop keyframe's covisible group.
    loop_points: Vec<MpId>,
    ransac_inliers: usize,
    refined_inliers: usize,
}

/// Loop-closing state: the keyframe database, the consistent groups, the loop edges.
pub struct LoopCloser {
    s: SlamSettings,
    db: KeyFrameDatabase,
    /// Covisibility groups of the last keyframe's candidates and how many consecutive
    /// keyframes each has been consistent for.
    groups: Vec<(BTreeSet<KfId>, usize)>,
    last_loop_kf: Option<KfId>,
    loop_edges: BTreeSet<(KfId, KfId)>,
    scales: Vec<f64>,
    inv_sigma2: Vec<f64>,
    stats: LoopStats,
}

impl LoopCloser {
    pub fn new(s: SlamSettings) -> Self {
        Self {
            scales: s.scale_factors(),
            inv_sigma2: s.inv_level_sigma2(),
            s,
            db: KeyFrameDatabase::new(),
            groups: Vec::new(),
            last_loop_kf: None,
            loop_edges: BTreeSet::new(),
            stats: LoopStats::default(),
        }
    }

    /// With a vocabulary given by the user (a DBoW2 file): no online training.
    pub fn with_vocabulary(s: SlamSettings, v: Vocabulary) -> Self {
        let mut c = Self::new(s);
        c.db = KeyFrameDatabase::with_vocabulary(v);
        c
    }

    pub fn stats(&self) -> &LoopStats {
        &self.stats
    }

    /// Loop edges (current keyframe, loop keyframe) closed so far.
    pub fn loop_edges(&self) -> &BTreeSet<(KfId, KfId)> {
        &self.loop_edges
    }

    /// Handle one keyframe that local mapping finished. `mapping_busy` is the lock local
    /// mapping holds per keyframe (`None` inline). `publish` receives the correction while the
    /// map is still locked, so tracking sees it before its next frame. Returns the correction
    /// when a loop was closed.
    pub fn process(
        &mut self,
        map: &Mutex<Map>,
        kf: KfId,
        mapping_busy: Option<&Mutex<()>>,
        publish: Option<&Mutex<Vec<MapCorrection>>>,
    ) -> Option<MapCorrection> {
        let p = self.s.loop_closing.database.clone();
        // Train the vocabulary outside the map lock (it takes a while); copy the descriptors.
        let training: Option<Vec<(KfId, Vec<crate::Descriptor>)>> = {
            let m = map.lock().ok()?;
            let n = m.current_keyframes().count();
            // Only keyframes local mapping has finished (ids up to this one): newer ones have
            // no covisibility yet, so they would not be excluded as neighbours of `kf`.
            self.db.needs_training(n, &p).then(|| {
                m.current_keyframes()
                    .filter(|k| k.id <= kf)
                    .map(|k| (k.id, k.descriptors.clone()))
                    .collect()
            })
        };
        if let Some(docs) = training {
            let t0 = Instant::now();
            let refs: Vec<(KfId, &[crate::Descriptor])> =
                docs.iter().map(|(k, d)| (*k, d.as_slice())).collect();
            self.db.train(&refs, &p);
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            self.stats.training_ms.push(ms);
            self.stats.vocabulary_words = self.db.vocabulary().map_or(0, |v| v.words());
            info!(
                keyframes = docs.len(),
                words = self.stats.vocabulary_words,
                ms,
                "loop closing: vocabulary trained"
            );
        }
        let t0 = Instant::now();
        let verified = {
            let m = map.lock().ok()?;
            let Some(k) = m.keyframes.get(&kf).filter(|k| !k.bad) else {
                self.groups.clear();
                return None;
            };
            self.db.add(kf, &k.descriptors);
            self.detect(&m, kf)
                .and_then(|candidates| self.verify(&m, kf, &candidates))
        };
        self.stats
            .detection_ms
            .push(t0.elapsed().as_secs_f64() * 1e3);
        let v = verified?;
        // Stop local mapping (it finishes its keyframe first), then take the map.
        let busy = mapping_busy.map(|b| b.lock().unwrap_or_else(|e| e.into_inner()));
        let mut m = map.lock().ok()?;
        let t1 = Instant::now();
        let outcome = self.correct(&mut m, kf, &v);
        let ms = t1.elapsed().as_secs_f64() * 1e3;
        let (mut correction, mut event) = outcome?;
        if let Some(p) = publish
            && let Ok(mut q) = p.lock()
        {
            q.push(correction.clone());
        }
        drop(m);
        if self.s.loop_closing.global_ba {
            let t2 = Instant::now();
            if let Some(c) = self.global_bundle_adjustment(map, publish) {
                // One correction from before the loop to after the BA, for an inline caller.
                for (k, (before, after)) in c.poses {
                    correction.poses.entry(k).or_insert((before, after)).1 = after;
                }
                self.stats
                    .global_ba_ms
                    .push(t2.elapsed().as_secs_f64() * 1e3);
            }
        }
        drop(busy);
        event.correction_ms = ms;
        info!(
            keyframe = kf,
            frame = event.frame_index,
            loop_keyframe = v.loop_kf,
            loop_frame = event.loop_frame_index,
            matches = event.loop_matches,
            moved_m = event.correction_m,
            ms,
            "loop closed"
        );
        self.stats.correction_ms.push(ms);
        self.stats.loops.push(event);
        Some(correction)
    }

    /// ORB-SLAM `DetectLoop`: the candidates whose covisibility group has been consistent for
    /// `consistency` keyframes; `None` when there are none.
    fn detect(&mut self, m: &Map, kf: KfId) -> Option<Vec<KfId>> {
        let ls = &self.s.loop_closing;
        let k = m.keyframes.get(&kf)?;
        let n = m.current_keyframes().count();
        if n < ls.min_keyframes
            || self
                .last_loop_kf
                .is_some_and(|l| kf < l + ls.keyframes_after_loop as KfId)
        {
            // No consistency carried across keyframes that were not checked.
            self.groups.clear();
            return None;
        }
        // The lowest score among the covisible keyframes sets the bar.
        let connected: BTreeSet<KfId> = k.connections.keys().copied().collect();
        // (Only neighbours already in the database: a missing one would score 0 and lower
        // the bar to nothing.)
        let min_score = connected
            .iter()
            .filter(|&&c| self.db.bow(c).is_some())
            .map(|&c| self.db.score(kf, c))
            .fold(1.0f32, f32::min);
        let mut excluded = connected.clone();
        excluded.insert(kf);
        let epoch = k.map_epoch;
        let candidates = self.db.loop_candidates(
            kf,
            &excluded,
            min_score,
            |c| {
                c < kf
                    && m.keyframes
                        .get(&c)
                        .is_some_and(|x| !x.bad && x.map_epoch == epoch)
            },
            |c| {
                m.keyframes
                    .get(&c)
                    .map_or(Vec::new(), |x| x.best_covisibles(10))
            },
        );
        if candidates.is_empty() {
            self.groups.clear();
            return None;
        }
        // Covisibility consistency: a candidate's group (it and its covisible keyframes) must
        // share a keyframe with a group of the previous keyframe's candidates.
        let mut current: Vec<(BTreeSet<KfId>, usize)> = Vec::new();
        let mut enough = Vec::new();
        let mut extended = vec![false; self.groups.len()];
        for &(c, _) in &candidates {
            let mut group: BTreeSet<KfId> = m
                .keyframes
                .get(&c)
                .map(|x| x.connections.keys().copied().collect())
                .unwrap_or_default();
            group.insert(c);
            let mut consistent_for_some = false;
            let mut enough_added = false;
            for (g, (prev, n_prev)) in self.groups.iter().enumerate() {
                if group.is_disjoint(prev) {
                    continue;
                }
                consistent_for_some = true;
                let n_cur = n_prev + 1;
                if !extended[g] {
                    current.push((group.clone(), n_cur));
                    extended[g] = true;
                }
                if n_cur >= ls.consistency && !enough_added {
                    enough.push(c);
                    enough_added = true;
                }
            }
            if !consistent_for_some {
                current.push((group, 0));
            }
        }
        debug!(
            keyframe = kf,
            candidates = candidates.len(),
            consistent = enough.len(),
            min_score,
            "loop candidates"
        );
        self.groups = current;
        (!enough.is_empty()).then_some(enough)
    }

    /// ORB-SLAM `ComputeSim3` with the scale fixed: the first candidate that passes descriptor
    /// matching, RANSAC, guided matching with refinement and the loop-group projection.
    fn verify(&mut self, m: &Map, kf: KfId, candidates: &[KfId]) -> Option<Verified> {
        let cur = m.keyframes.get(&kf)?;
        for &c in candidates {
            self.stats.tried_candidates += 1;
            let Some(l) = m.keyframes.get(&c).filter(|x| !x.bad) else {
                self.stats.rejected_candidates += 1;
                continue;
            };
            match self.verify_one(m, cur, l) {
                Some(v) => return Some(v),
                None => self.stats.rejected_candidates += 1,
            }
        }
        None
    }

    fn verify_one(&self, m: &Map, cur: &KeyFrame, l: &KeyFrame) -> Option<Verified> {
        let ls = &self.s.loop_closing;
        let cam = &self.s.camera;
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
        let Some((t_cl, flags)) = ransac_rigid(&pairs, cam, &params) else {
            debug!(
                keyframe = cur.id,
                candidate = l.id,
                matches = matches.len(),
                "loop rejected: RANSAC"
            );
            return None;
        };
        let ransac_inliers = flags.iter().filter(|&&f| f).count();
        // Guided matching with the transform, then refinement on all pairs.
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
            cur,
            &pose,
            &loop_points,
            &already,
            &out,
            ls.projection_radius,
        ) {
            out.insert(i, mp);
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
        })
    }

    /// Map point of keypoint `i` of `a` and of `j` of `b`, each in its camera's frame.
    fn pair(&self, m: &Map, a: &KeyFrame, i: usize, b: &KeyFrame, j: usize) -> RigidPair {
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
    fn guided_matches(
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
                if let Some(j) = self.best_in_window(
                    to,
                    &pc,
                    &p.descriptor,
                    p.max_distance,
                    self.s.loop_closing.guided_radius,
                    self.s.th_high,
                    |j| !used_to.contains(&j),
                ) {
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
    /// a window of `radius` x scale around its projection at the predicted octave (and the ones
    /// beside it), within `max_hamming`.
    #[allow(clippy::too_many_arguments)]
    fn best_in_window(
        &self,
        k: &KeyFrame,
        pc: &Vec3,
        descriptor: &crate::Descriptor,
        max_distance: f64,
        radius: f64,
        max_hamming: u32,
        allowed: impl Fn(usize) -> bool,
    ) -> Option<usize> {
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
    #[allow(clippy::too_many_arguments)]
    fn project_points(
        &self,
        m: &Map,
        k: &KeyFrame,
        pose: &Se3,
        points: &[MpId],
        already: &BTreeSet<MpId>,
        taken: &BTreeMap<usize, MpId>,
        radius: f64,
    ) -> Vec<(usize, MpId)> {
        let center = pose.inverse().translation.vector;
        let mut used: BTreeSet<usize> = taken.keys().copied().collect();
        let mut out = Vec::new();
        for &mp in points {
            if already.contains(&mp) {
                continue;
            }
            let Some(p) = m.points.get(&mp).filter(|p| !p.bad) else {
                continue;
            };
            if !in_viewing_range(p, &center) {
                continue;
            }
            let pc = apply(pose, &p.position);
            if let Some(i) = self.best_in_window(
                k,
                &pc,
                &p.descriptor,
                p.max_distance,
                radius,
                self.s.th_low,
                |i| !used.contains(&i),
            ) {
                used.insert(i);
                out.push((i, mp));
            }
        }
        out
    }

    /// ORB-SLAM `CorrectLoop` (SE3): returns the poses it moved and the event.
    fn correct(
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
            update_normal_and_depth(m, *mp, &self.scales);
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
            kf,
            v.loop_kf,
            &before,
            &corrected,
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
            update_normal_and_depth(m, mp, &self.scales);
        }
        self.loop_edges.insert((kf, v.loop_kf));
        self.last_loop_kf = Some(kf);
        self.groups.clear();
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
        };
        let poses = after
            .iter()
            .filter_map(|(k, new)| before.get(k).map(|old| (*k, (*old, *new))))
            .collect();
        Some((MapCorrection { poses }, event))
    }

    /// ORB-SLAM `RunGlobalBundleAdjustment`: every keyframe and point of the current map, the
    /// origin fixed, robust LM; solved with the map unlocked (local mapping stays stopped, as
    /// the caller holds its lock), then written back. Keyframes tracking created meanwhile
    /// move with the newest optimised one, points of theirs with their reference keyframe.
    fn global_bundle_adjustment(
        &self,
        map: &Mutex<Map>,
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
        let mut s = self.s.clone();
        s.ba_iterations = [self.s.loop_closing.global_ba_iterations, 0];
        crate::optimize::local_bundle_adjustment(&mut problem, &s);
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
            update_normal_and_depth(&mut m, id, &self.scales);
        }
        let correction = MapCorrection { poses };
        if let Some(p) = publish
            && let Ok(mut q) = p.lock()
        {
            q.push(correction.clone());
        }
        debug!(keyframes = kf_ids.len(), points = pt_ids.len(), "global BA");
        Some(correction)
    }

    /// ORB-SLAM `Fuse(pKF, Scw, vpPoints, th, vpReplacePoint)`: loop points projected into `g`
    /// (already corrected); a keypoint's own point is replaced by the loop's, a free keypoint
    /// gets the observation.
    fn fuse_into(&self, m: &mut Map, g: KfId, points: &[MpId], radius: f64) {
        let Some(k) = m.keyframes.get(&g) else { return };
        let pose = k.pose_cw;
        let center = k.camera_center();
        let mut actions: Vec<(usize, MpId)> = Vec::new();
        let mut used = BTreeSet::new();
        for &mp in points {
            let Some(p) = m.points.get(&mp).filter(|p| !p.bad) else {
                continue;
            };
            if p.observations.contains_key(&g) {
                continue;
            }
            if !in_viewing_range(p, &center) {
                continue;
            }
            let pc = apply(&pose, &p.position);
            if let Some(i) = self.best_in_window(
                k,
                &pc,
                &p.descriptor,
                p.max_distance,
                radius,
                self.s.th_low,
                |i| !used.contains(&i),
            ) {
                used.insert(i);
                actions.push((i, mp));
            }
        }
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
    #[allow(clippy::too_many_arguments)]
    fn essential_graph(
        &self,
        m: &Map,
        epoch: u32,
        kf: KfId,
        loop_kf: KfId,
        before: &BTreeMap<KfId, Se3>,
        corrected: &BTreeMap<KfId, Se3>,
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
fn move_culled_keyframes(
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

/// A point's mean viewing direction and scale-invariance distances after its keyframes or its
/// position moved (ORB-SLAM `UpdateNormalAndDepth`); the representative descriptor, which
/// `Map::update_point` also recomputes at a cost quadratic in the observations, stays.
fn update_normal_and_depth(m: &mut Map, mp: MpId, scales: &[f64]) {
    let Some(p) = m.points.get(&mp) else { return };
    let mut normal = Vec3::zeros();
    for k in p.observations.keys() {
        if let Some(k) = m.keyframes.get(k) {
            let d = p.position - k.camera_center();
            if d.norm() > 1e-12 {
                normal += d.normalize();
            }
        }
    }
    let reference = m.keyframes.get(&p.reference_kf).and_then(|k| {
        let idx = *p.observations.get(&k.id)?;
        Some((k.camera_center(), *k.octaves.get(idx)?))
    });
    let Some(p) = m.points.get_mut(&mp) else {
        return;
    };
    if normal.norm() > 1e-12 {
        p.normal = normal.normalize();
    }
    if let Some((center, octave)) = reference
        && let (Some(level_scale), Some(top)) = (scales.get(octave as usize), scales.last())
    {
        p.max_distance = (p.position - center).norm() * level_scale;
        p.min_distance = p.max_distance / top;
    }
}

/// A point moved by a pose (nalgebra's `Isometry * Vector` would only rotate it).
/// Whether a camera at `center` sees `p` within its scale range (x0.8 .. x1.2) and viewing cone
/// (60 degrees from its normal), as ORB-SLAM's loop-closing projections ask.
fn in_viewing_range(p: &MapPoint, center: &Vec3) -> bool {
    let po = p.position - center;
    let dist = po.norm();
    dist >= 0.8 * p.min_distance && dist <= 1.2 * p.max_distance && po.dot(&p.normal) >= 0.5 * dist
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

/// Loop closing in its own thread: keyframes arrive from local mapping's thread through a
/// channel; the thread ends when that channel closes.
pub struct LoopThread {
    handle: Option<std::thread::JoinHandle<LoopCloser>>,
    /// Corrections not yet applied to tracking (filled under the map lock).
    pub corrections: Arc<Mutex<Vec<MapCorrection>>>,
    closer: Option<LoopCloser>,
}

impl LoopThread {
    pub fn spawn(
        closer: LoopCloser,
        map: Arc<Mutex<Map>>,
        keyframes: Receiver<KfId>,
        mapping_busy: Arc<Mutex<()>>,
    ) -> std::io::Result<Self> {
        let corrections = Arc::new(Mutex::new(Vec::new()));
        let pending = corrections.clone();
        let handle = std::thread::Builder::new()
            .name("loop-closing".into())
            .spawn(move || {
                let mut closer = closer;
                while let Ok(kf) = keyframes.recv() {
                    closer.process(&map, kf, Some(&mapping_busy), Some(&pending));
                }
                closer
            })?;
        Ok(Self {
            handle: Some(handle),
            corrections,
            closer: None,
        })
    }

    /// Wait for the queued keyframes (local mapping must have stopped, closing the channel).
    pub fn finish(&mut self) -> Result<(), crate::SlamError> {
        if let Some(h) = self.handle.take() {
            let c = h.join().map_err(|_| {
                crate::SlamError::LocalMapping("the loop-closing thread panicked".into())
            })?;
            self.closer = Some(c);
        }
        Ok(())
    }

    /// The closer's statistics once [`LoopThread::finish`] returned.
    pub fn stats(&self) -> Option<&LoopStats> {
        self.closer.as_ref().map(|c| c.stats())
    }
}
