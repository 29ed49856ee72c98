//! Keyframes, map points and the map with its covisibility graph and spanning tree.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use stillpoint_geometry::{PinholeCamera, Se3, Vec2, Vec3};
use stillpoint_image::{DepthMetres, Gray8};

use super::frame::{Descriptor, Frame, KeypointGrid};
use crate::hamming;

/// Keyframe id, unique over the run (all maps).
pub type KfId = u64;
/// Map point id, unique over the run (all maps).
pub type MpId = u64;

/// A keyframe: a frame kept in the map, with its observations.
#[derive(Clone, Debug)]
pub struct KeyFrame {
    /// Its id.
    pub id: KfId,
    /// Map this keyframe belongs to (a new map starts when tracking is lost for good).
    pub map_epoch: u32,
    /// Index of the frame it was made from.
    pub frame_index: usize,
    /// Time of that frame, seconds.
    pub timestamp: f64,
    /// World-to-camera pose (refined by bundle adjustment and loop closing).
    pub pose_cw: Se3,
    /// Undistorted keypoint positions, pixels.
    pub points: Vec<Vec2>,
    /// Pyramid level of each keypoint.
    pub octaves: Vec<u8>,
    /// Orientation of each keypoint, degrees.
    pub angles: Vec<f32>,
    /// ORB descriptor of each keypoint.
    pub descriptors: Vec<Descriptor>,
    /// Depth of each keypoint, metres (0 = none).
    pub depth: Vec<f32>,
    /// Virtual right coordinate of each keypoint (negative = no depth).
    pub u_right: Vec<f32>,
    /// Map point observed by each keypoint.
    pub map_points: Vec<Option<MpId>>,
    /// Keypoints the front-end allows to be tracked but not to found a map point.
    pub no_new_point: Vec<bool>,
    /// Keypoints by image cell, for searches in a window.
    pub grid: KeypointGrid,
    /// Covisibility: keyframe -> shared map points (only edges with >= the minimum weight, or
    /// the single best when none reaches it, as ORB-SLAM).
    pub connections: BTreeMap<KfId, usize>,
    /// Spanning tree.
    pub parent: Option<KfId>,
    /// Spanning-tree children.
    pub children: BTreeSet<KfId>,
    /// Culled: kept only so that frames anchored to it can follow its parent, which is then
    /// the good covisible keyframe nearest it in time.
    pub bad: bool,
    /// Set when culled: this keyframe's pose relative to its parent then (ORB-SLAM's `mTcp`),
    /// so that frames anchored to it follow the parent as bundle adjustment moves it.
    pub pose_to_parent: Option<Se3>,
}

impl KeyFrame {
    /// A keyframe made from a tracked frame; `None` when the frame has no pose.
    pub fn from_frame(id: KfId, map_epoch: u32, f: &Frame) -> Option<Self> {
        Some(Self {
            id,
            map_epoch,
            frame_index: f.index,
            timestamp: f.timestamp,
            pose_cw: f.pose_cw?,
            points: f.points.clone(),
            octaves: f.octaves.clone(),
            angles: f.angles.clone(),
            descriptors: f.descriptors.clone(),
            depth: f.depth.clone(),
            u_right: f.u_right.clone(),
            map_points: f.map_points.clone(),
            no_new_point: f.no_new_point.clone(),
            grid: f.grid.clone(),
            connections: BTreeMap::new(),
            parent: None,
            children: BTreeSet::new(),
            pose_to_parent: None,
            bad: false,
        })
    }

    /// Camera centre in the world.
    pub fn camera_center(&self) -> Vec3 {
        self.pose_cw.inverse().translation.vector
    }

    /// Keypoint `i` back-projected into the world with its depth; `None` without depth.
    pub fn unproject_world(&self, i: usize, cam: &PinholeCamera) -> Option<Vec3> {
        let z = *self.depth.get(i)?;
        (z > 0.0).then(|| {
            let pc = cam.unproject(&self.points[i], z as f64);
            (self.pose_cw.inverse() * nalgebra::Point3::from(pc)).coords
        })
    }

    /// Median depth of the keyframe's map points in its camera (ORB-SLAM
    /// `ComputeSceneMedianDepth(2)`); `None` without points (the median may be negative when most points are behind it).
    pub fn scene_median_depth(&self, points: &BTreeMap<MpId, MapPoint>) -> Option<f64> {
        let mut z: Vec<f64> = self
            .map_points
            .iter()
            .flatten()
            .filter_map(|mp| points.get(mp))
            .map(|p| (self.pose_cw * nalgebra::Point3::from(p.position)).z)
            .filter(|z| z.is_finite())
            .collect();
        if z.is_empty() {
            return None;
        }
        z.sort_by(f64::total_cmp);
        Some(z[(z.len() - 1) / 2])
    }

    /// Best covisible keyframes, highest weight first.
    pub fn best_covisibles(&self, n: usize) -> Vec<KfId> {
        let mut v: Vec<(usize, KfId)> = self.connections.iter().map(|(&k, &w)| (w, k)).collect();
        v.sort_by(|a, b| b.cmp(a));
        v.into_iter().take(n).map(|(_, k)| k).collect()
    }

    /// Keypoints inside a window, as [`Frame::features_in_area`].
    pub fn features_in_area(&self, x: f64, y: f64, r: f64, min_o: i32, max_o: i32) -> Vec<usize> {
        self.grid
            .candidates((&self.points, &self.octaves), x, y, r, (min_o, max_o))
    }
}

/// A 3D landmark.
#[derive(Clone, Debug)]
pub struct MapPoint {
    /// Its id.
    pub id: MpId,
    /// Map it belongs to.
    pub map_epoch: u32,
    /// Position in the world, metres.
    pub position: Vec3,
    /// Representative descriptor: the observation descriptor with the least median distance to
    /// the others (ORB-SLAM's `ComputeDistinctiveDescriptors`).
    pub descriptor: Descriptor,
    /// Fingerprint of the observations' descriptors `descriptor` was last chosen from (0 =
    /// never): [`Map::update_point`] chooses again only when they changed.
    pub descriptor_of: u64,
    /// Mean viewing direction (unit).
    pub normal: Vec3,
    /// Scale-invariance distances: the point can be matched between these camera distances.
    pub min_distance: f64,
    /// Farthest camera distance at which it can be matched (see `min_distance`).
    pub max_distance: f64,
    /// keyframe -> keypoint index.
    pub observations: BTreeMap<KfId, usize>,
    /// Keyframe whose observation sets its scale and normal (ORB-SLAM's `mpRefKF`).
    pub reference_kf: KfId,
    /// Keyframe that created it.
    pub first_kf: KfId,
    /// Frames in whose frustum the point fell / frames in which it was matched.
    pub visible: u32,
    /// Frames in which it was matched (see `visible`).
    pub found: u32,
    /// Frames in which the matched point failed the chi-square test of local-map tracking.
    pub rejected: u32,
    /// Frames whose depth image showed a surface well behind the point along its ray: the
    /// point is no longer there (it was on something that moved).
    pub seen_through: u32,
    /// Erased: kept by id only until no structure refers to it.
    pub bad: bool,
}

impl MapPoint {
    /// The octave at which the point should appear from camera distance `dist`.
    pub fn predict_scale(&self, dist: f64, log_scale: f64, n_levels: usize) -> i32 {
        let ratio = self.max_distance / dist.max(1e-9);
        let l = (ratio.ln() / log_scale).ceil() as i32;
        l.clamp(0, n_levels as i32 - 1)
    }

    /// Observations weighted as ORB-SLAM counts them: 2 for a keypoint with depth (stereo), 1
    /// otherwise. Needs the keyframes to look up the depth.
    pub fn weighted_observations(&self, keyframes: &BTreeMap<KfId, KeyFrame>) -> usize {
        self.observations
            .iter()
            .map(|(k, &i)| {
                let depth = keyframes
                    .get(k)
                    .and_then(|kf| kf.u_right.get(i))
                    .is_some_and(|&u| u >= 0.0);
                if depth { 2 } else { 1 }
            })
            .sum()
    }

    /// Whether a camera at `center` sees the point within its scale range (x0.8 .. x1.2 of
    /// its distances) and viewing cone (60 degrees from its normal), as ORB-SLAM's
    /// projection searches ask (`isInFrustum`, `SearchByProjection`, `Fuse`).
    pub fn in_viewing_range(&self, center: &Vec3) -> bool {
        let po = self.position - center;
        let dist = po.norm();
        dist >= 0.8 * self.min_distance
            && dist <= 1.2 * self.max_distance
            && po.dot(&self.normal) >= 0.5 * dist
    }

    /// Share of the frames that saw it in their frustum that also matched it (`found / visible`).
    pub fn found_ratio(&self) -> f64 {
        self.found as f64 / self.visible.max(1) as f64
    }
}

/// What [`Map::erase_points_seen_through`] needs to know.
#[derive(Clone, Copy, Debug)]
pub struct FreeSpaceCheck {
    /// Baseline x focal length (ORB-SLAM's virtual stereo for RGB-D): depth gaps are judged in
    /// disparity pixels, the unit in which bundle adjustment weighs depth.
    pub bf: f64,
    /// A surface farther than the point by more than this many disparity pixels (and 10 cm)
    /// sees through it; within it, the point is seen where it is.
    pub gap_px: f64,
    /// Frames seen through, with none seeing it in between, before a point is erased (0 = off).
    pub erase_after: u32,
}

/// The map: keyframes and points by id (ordered maps, so iteration is deterministic).
#[derive(Clone, Debug, Default)]
pub struct Map {
    /// Keyframes by id, culled ones included (`bad`).
    pub keyframes: BTreeMap<KfId, KeyFrame>,
    /// Map points by id.
    pub points: BTreeMap<MpId, MapPoint>,
    pub(crate) next_kf: KfId,
    pub(crate) next_mp: MpId,
    /// Keyframes with a smaller id came from a map file: their frame indices and timestamps
    /// are another run's (0 when nothing was loaded).
    pub session_first_kf: KfId,
    /// Current map; older maps stay for the keyframe trajectory but are not tracked against.
    pub epoch: u32,
    /// First keyframe of the current map (fixed in bundle adjustment: the gauge).
    pub origin_kf: Option<KfId>,
    /// Points fused into another (dropped -> kept), so that a frame waiting to settle still
    /// finds the points it saw (ORB-SLAM's `mpReplaced`); the oldest are forgotten once no
    /// waiting frame can have seen them.
    fused_into: BTreeMap<MpId, MpId>,
    /// The dropped points of `fused_into`, oldest first; fusion number `fusions_forgotten + i`
    /// is at `i`.
    fusion_order: VecDeque<MpId>,
    fusions_forgotten: u64,
}

impl Map {
    /// An empty map.
    pub fn new() -> Self {
        Self::default()
    }

    /// Reserve the next keyframe id.
    pub fn next_kf_id(&mut self) -> KfId {
        let id = self.next_kf;
        self.next_kf += 1;
        id
    }

    /// Insert a keyframe built from a tracked frame; returns its id.
    pub fn add_keyframe(&mut self, f: &Frame) -> Option<KfId> {
        let id = self.next_kf;
        let kf = KeyFrame::from_frame(id, self.epoch, f)?;
        self.next_kf += 1;
        if self.origin_kf.is_none() {
            self.origin_kf = Some(id);
        }
        self.keyframes.insert(id, kf);
        Some(id)
    }

    /// Create a map point at `position` observed by keypoint `idx` of keyframe `kf`, in the
    /// keyframe's map (a keyframe the mapping thread still held when tracking moved to another
    /// map keeps its points in its own).
    pub fn add_point(&mut self, position: Vec3, kf: KfId, idx: usize) -> Option<MpId> {
        let k = self.keyframes.get_mut(&kf)?;
        let descriptor = *k.descriptors.get(idx)?;
        let map_epoch = k.map_epoch;
        let id = self.next_mp;
        self.next_mp += 1;
        k.map_points[idx] = Some(id);
        let mut observations = BTreeMap::new();
        observations.insert(kf, idx);
        self.points.insert(
            id,
            MapPoint {
                id,
                map_epoch,
                position,
                descriptor,
                descriptor_of: 0,
                normal: Vec3::z(),
                min_distance: 0.0,
                max_distance: 0.0,
                observations,
                reference_kf: kf,
                first_kf: kf,
                visible: 1,
                found: 1,
                rejected: 0,
                seen_through: 0,
                bad: false,
            },
        );
        Some(id)
    }

    /// Record that keypoint `idx` of `kf` observes `mp`.
    pub fn add_observation(&mut self, mp: MpId, kf: KfId, idx: usize) {
        let (Some(p), Some(k)) = (self.points.get_mut(&mp), self.keyframes.get_mut(&kf)) else {
            return;
        };
        if p.bad || idx >= k.map_points.len() {
            return;
        }
        p.observations.insert(kf, idx);
        k.map_points[idx] = Some(mp);
    }

    /// Remove a point and every reference to it.
    pub fn erase_point(&mut self, mp: MpId) {
        if let Some(p) = self.points.remove(&mp) {
            for (kf, idx) in p.observations {
                if let Some(k) = self.keyframes.get_mut(&kf)
                    && k.map_points.get(idx) == Some(&Some(mp))
                {
                    k.map_points[idx] = None;
                }
            }
        }
    }

    /// Remove the observation of `mp` by `kf`; a point left with < 2 observations is erased (as
    /// ORB-SLAM does).
    pub fn erase_observation(&mut self, mp: MpId, kf: KfId) {
        let mut erase = false;
        if let Some(p) = self.points.get_mut(&mp)
            && let Some(idx) = p.observations.remove(&kf)
        {
            if let Some(k) = self.keyframes.get_mut(&kf)
                && k.map_points.get(idx) == Some(&Some(mp))
            {
                k.map_points[idx] = None;
            }
            if p.reference_kf == kf {
                p.reference_kf = p.observations.keys().next().copied().unwrap_or(kf);
            }
            erase = p.observations.len() < 2;
        }
        if erase {
            self.erase_point(mp);
        }
    }

    /// Make `keep` absorb `drop` (duplicate landmarks found by fusion).
    pub fn replace_point(&mut self, drop: MpId, keep: MpId) {
        if drop == keep {
            return;
        }
        let Some(old) = self.points.remove(&drop) else {
            return;
        };
        self.fused_into.insert(drop, keep);
        self.fusion_order.push_back(drop);
        let (found, visible) = (old.found, old.visible);
        for (kf, idx) in old.observations {
            let Some(k) = self.keyframes.get_mut(&kf) else {
                continue;
            };
            let already = self
                .points
                .get(&keep)
                .is_some_and(|p| p.observations.contains_key(&kf));
            if already {
                if k.map_points.get(idx) == Some(&Some(drop)) {
                    k.map_points[idx] = None;
                }
            } else {
                k.map_points[idx] = Some(keep);
                if let Some(p) = self.points.get_mut(&keep) {
                    p.observations.insert(kf, idx);
                }
            }
        }
        if let Some(p) = self.points.get_mut(&keep) {
            p.found += found;
            p.visible += visible;
        }
        self.update_point(keep, &[]);
    }

    /// Fusions so far: a frame tracked now can only need the ones numbered from here on.
    pub fn fusions(&self) -> u64 {
        self.fusions_forgotten + self.fusion_order.len() as u64
    }

    /// Forget the fusions numbered below `first_needed`.
    pub fn forget_fusions_before(&mut self, first_needed: u64) {
        while self.fusions_forgotten < first_needed
            && let Some(drop) = self.fusion_order.pop_front()
        {
            self.fused_into.remove(&drop);
            self.fusions_forgotten += 1;
        }
    }

    /// A point by id, or the point it was fused into (if that fusion is not forgotten).
    pub fn point_or_its_replacement(&self, mut id: MpId) -> Option<(MpId, &MapPoint)> {
        // A fused point is gone from `points` for good, so chains end; the bound is a guard.
        for _ in 0..16 {
            if let Some(p) = self.points.get(&id) {
                return Some((id, p));
            }
            id = *self.fused_into.get(&id)?;
        }
        None
    }

    /// Recompute a point's normal, scale-invariance distances and representative descriptor.
    /// `scale_factors` empty keeps the previous distances' level ratio (used after fusion).
    pub fn update_point(&mut self, mp: MpId, scale_factors: &[f64]) {
        let Some(p) = self.points.get(&mp) else {
            return;
        };
        let descs: Vec<Descriptor> = p
            .observations
            .iter()
            .filter_map(|(kf, &idx)| self.keyframes.get(kf)?.descriptors.get(idx).copied())
            .collect();
        // Local mapping updates every point of the window after each bundle adjustment, most of
        // them with the same observations as last time; choosing again is quadratic in them.
        let fingerprint = descriptors_fingerprint(&descs);
        if fingerprint != p.descriptor_of {
            let descriptor = best_descriptor(&descs).unwrap_or(p.descriptor);
            if let Some(p) = self.points.get_mut(&mp) {
                p.descriptor = descriptor;
                p.descriptor_of = fingerprint;
            }
        }
        self.update_normal_and_depth(mp, scale_factors);
    }

    /// A point's mean viewing direction and scale-invariance distances after its keyframes or
    /// its position moved (ORB-SLAM `UpdateNormalAndDepth`), without the representative
    /// descriptor ([`Map::update_point`] adds it, at a cost quadratic in the observations).
    pub fn update_normal_and_depth(&mut self, mp: MpId, scale_factors: &[f64]) {
        let Some(p) = self.points.get(&mp) else {
            return;
        };
        let mut normal = Vec3::zeros();
        for kf in p.observations.keys() {
            if let Some(k) = self.keyframes.get(kf) {
                let d = p.position - k.camera_center();
                if d.norm() > 1e-12 {
                    normal += d.normalize();
                }
            }
        }
        let reference = self.keyframes.get(&p.reference_kf).and_then(|k| {
            let idx = *p.observations.get(&k.id)?;
            Some((k.camera_center(), *k.octaves.get(idx)?))
        });
        let Some(p) = self.points.get_mut(&mp) else {
            return;
        };
        if normal.norm() > 1e-12 {
            p.normal = normal.normalize();
        }
        if let Some((center, octave)) = reference
            && let (Some(level_scale), Some(top)) = (
                scale_factors.get((octave as usize).min(scale_factors.len().saturating_sub(1))),
                scale_factors.last(),
            )
        {
            p.max_distance = (p.position - center).norm() * level_scale;
            p.min_distance = p.max_distance / top;
        }
    }

    /// Recompute the covisibility edges of `kf` (and the reverse edges), and attach it to the
    /// spanning tree on first connection (parent = strongest covisible keyframe).
    pub fn update_connections(&mut self, kf: KfId, min_shared: usize) {
        let Some(k) = self.keyframes.get(&kf) else {
            return;
        };
        // Counted by sorting the ids of the keyframes that see each point: culling a keyframe
        // recounts every neighbour's edges, and a map entry per observation cost more than
        // reading the points.
        let mut seen_with: Vec<KfId> = Vec::with_capacity(8 * k.map_points.len());
        for mp in k.map_points.iter().flatten() {
            if let Some(p) = self.points.get(mp) {
                if p.bad {
                    continue;
                }
                seen_with.extend(p.observations.keys().filter(|&&other| other != kf));
            }
        }
        seen_with.sort_unstable();
        let counts: Vec<(KfId, usize)> = seen_with
            .chunk_by(|a, b| a == b)
            .map(|run| (run[0], run.len()))
            .filter(|(o, _)| self.keyframes.get(o).is_some_and(|k| !k.bad))
            .collect();
        // In id order, the last of equal weights, as a map's `max_by_key` gave.
        let best = counts.iter().max_by_key(|(_, w)| *w).copied();
        let mut edges: BTreeMap<KfId, usize> = counts
            .iter()
            .filter(|(_, w)| *w >= min_shared)
            .copied()
            .collect();
        if edges.is_empty()
            && let Some((b, w)) = best
        {
            edges.insert(b, w);
        }
        // Old edges that vanished must also vanish on the other side.
        let old: Vec<KfId> = self.keyframes[&kf].connections.keys().copied().collect();
        for o in old {
            if !edges.contains_key(&o)
                && let Some(ok) = self.keyframes.get_mut(&o)
            {
                ok.connections.remove(&kf);
            }
        }
        for (&o, &w) in &edges {
            if let Some(ok) = self.keyframes.get_mut(&o) {
                ok.connections.insert(kf, w);
            }
        }
        let first_connection = {
            let k = &self.keyframes[&kf];
            k.parent.is_none() && Some(kf) != self.origin_kf
        };
        if let Some(k) = self.keyframes.get_mut(&kf) {
            k.connections = edges;
        }
        if first_connection && let Some((b, _)) = best {
            if let Some(k) = self.keyframes.get_mut(&kf) {
                k.parent = Some(b);
            }
            if let Some(pk) = self.keyframes.get_mut(&b) {
                pk.children.insert(kf);
            }
        }
    }

    /// Mark a keyframe bad: drop its observations and edges, hand its children to its parent;
    /// from then on it follows the good covisible keyframe nearest it in time.
    pub fn set_bad_keyframe(&mut self, kf: KfId, min_shared: usize) {
        if Some(kf) == self.origin_kf {
            return;
        }
        let Some(k) = self.keyframes.get(&kf) else {
            return;
        };
        let mps: Vec<MpId> = k.map_points.iter().flatten().copied().collect();
        let conns: Vec<KfId> = k.connections.keys().copied().collect();
        let parent = k.parent;
        let children: Vec<KfId> = k.children.iter().copied().collect();
        let covisibles = k.best_covisibles(usize::MAX);
        let t_kf = k.timestamp;
        for mp in mps {
            self.erase_observation(mp, kf);
        }
        for c in &conns {
            if let Some(ck) = self.keyframes.get_mut(c) {
                ck.connections.remove(&kf);
            }
        }
        // Frames anchored to it follow, from now on, the good covisible keyframe nearest it in
        // time: its spanning-tree parent can be a keyframe of seconds before (the one that
        // shared most points when it was made), and the map between them bends as bundle
        // adjustment goes on. Covisibles strongest first, so that of two as near in time (one
        // before, one after) the one sharing more points wins.
        let follow = covisibles
            .iter()
            .filter_map(|o| self.keyframes.get(o).filter(|k| !k.bad))
            .min_by(|a, b| {
                (a.timestamp - t_kf)
                    .abs()
                    .total_cmp(&(b.timestamp - t_kf).abs())
            })
            .map(|k| k.id)
            .or(parent);
        let pose_to_parent = follow
            .and_then(|p| self.keyframes.get(&p))
            .map(|pk| self.keyframes[&kf].pose_cw * pk.pose_cw.inverse());
        if let Some(k) = self.keyframes.get_mut(&kf) {
            k.bad = true;
            k.parent = follow;
            k.pose_to_parent = pose_to_parent;
            k.connections.clear();
            k.children.clear();
            k.map_points.iter_mut().for_each(|m| *m = None);
        }
        if let Some(p) = parent
            && let Some(pk) = self.keyframes.get_mut(&p)
        {
            pk.children.remove(&kf);
        }
        // Children re-attach to their strongest good covisible keyframe, else the parent.
        for c in children {
            let new_parent = self
                .keyframes
                .get(&c)
                .and_then(|ck| {
                    ck.best_covisibles(usize::MAX)
                        .into_iter()
                        .find(|o| *o != kf && self.keyframes.get(o).is_some_and(|k| !k.bad))
                })
                .or(parent);
            if let Some(ck) = self.keyframes.get_mut(&c) {
                ck.parent = new_parent;
            }
            if let Some(np) = new_parent
                && let Some(pk) = self.keyframes.get_mut(&np)
            {
                pk.children.insert(c);
            }
        }
        for c in conns {
            self.update_connections(c, min_shared);
        }
    }

    /// Erase the points of the current map that lie on a moving object's surface in a frame:
    /// seen from `pose_cw` they fall on a non-zero pixel of `mover_mask` at the depth the
    /// sensor reads there (within 10 cm or 5 %; points behind the object stay), and their first
    /// keyframe is from frame `since_frame` or later. Points made while a mover was not yet
    /// detected (entering the view, missed by the detector) leave the map once it is. Returns
    /// how many were erased.
    pub fn erase_recent_points_on_movers(
        &mut self,
        pose_cw: &Se3,
        cam: &PinholeCamera,
        mover_mask: &Gray8,
        depth: &DepthMetres,
        since_frame: usize,
    ) -> usize {
        let on_mover: Vec<MpId> = self
            .points
            .values()
            .filter(|p| p.map_epoch == self.epoch && !p.bad)
            .filter(|p| {
                // A loaded map's keyframes count frames of another run: never recent.
                p.first_kf >= self.session_first_kf
                    && self
                        .keyframes
                        .get(&p.first_kf)
                        .is_some_and(|k| k.frame_index >= since_frame)
            })
            .filter(|p| {
                let pc = pose_cw * nalgebra::Point3::from(p.position);
                let Some(px) = cam.project(&pc.coords) else {
                    return false;
                };
                let (x, y) = (px.x.round() as isize, px.y.round() as isize);
                let masked = mover_mask.get_checked(x, y).is_some_and(|m| m > 0);
                let seen = depth
                    .get_checked(x, y)
                    .filter(|d| d.is_finite() && *d > 0.0);
                masked && seen.is_some_and(|d| (pc.z - d as f64).abs() <= (0.05 * pc.z).max(0.10))
            })
            .map(|p| p.id)
            .collect();
        for &mp in &on_mover {
            self.erase_point(mp);
        }
        on_mover.len()
    }

    /// Free-space check of the current map against a depth image seen from `pose_cw`: a point
    /// whose projection shows, everywhere in the 5 x 5 pixels around it, a surface farther
    /// than the point by more than 10 cm and by more than `gap_px` of virtual disparity
    /// (`bf / z`, the unit in which bundle adjustment weighs depth: with bf = 40 a point at
    /// 3.3 m may settle 0.27 m off per pixel) is seen through: it stood on something that has
    /// moved away. Points seen through in `erase_after` frames, with no frame in between that saw
    /// them where they are, are erased; returns how many. (The window keeps points on
    /// silhouettes, whose pixel may read the background.) When over 30 % of the points checked
    /// are seen through, the pose is taken as wrong and nothing changes.
    pub fn erase_points_seen_through(
        &mut self,
        pose_cw: &Se3,
        cam: &PinholeCamera,
        depth: &DepthMetres,
        check: &FreeSpaceCheck,
    ) -> usize {
        let FreeSpaceCheck {
            bf,
            gap_px: max_gap,
            erase_after,
        } = *check;
        if erase_after == 0 {
            return 0;
        }
        let epoch = self.epoch;
        // Per point: Some(true) seen through, Some(false) seen where it is, None no evidence
        // (off the image, no reading, or something in front of it).
        let verdicts: Vec<(MpId, Option<bool>)> = self
            .points
            .values()
            .filter(|p| p.map_epoch == epoch && !p.bad)
            .map(|p| {
                let pc = pose_cw * nalgebra::Point3::from(p.position);
                let Some(px) = cam.project(&pc.coords) else {
                    return (p.id, None);
                };
                let (x, y) = (px.x.round() as isize, px.y.round() as isize);
                // Most of a map is out of view: no evidence, and no pixel to read.
                let (w, h) = (depth.width as isize, depth.height as isize);
                if x < 2 || y < 2 || x + 2 >= w || y + 2 >= h || pc.z <= 0.0 {
                    return (p.id, None);
                }
                let mut nearest = f32::INFINITY;
                for v in y - 2..=y + 2 {
                    for u in x - 2..=x + 2 {
                        let d = depth.get(u as usize, v as usize);
                        if !(d.is_finite() && d > 0.0) {
                            // No reading: no evidence.
                            return (p.id, None);
                        }
                        nearest = nearest.min(d);
                    }
                }
                let behind = nearest as f64;
                let gap_px = bf / pc.z - bf / behind;
                if behind > pc.z + 0.10 && gap_px > max_gap {
                    (p.id, Some(true))
                } else if gap_px.abs() <= max_gap {
                    (p.id, Some(false))
                } else {
                    (p.id, None)
                }
            })
            .collect();
        let seen = verdicts.iter().filter(|v| v.1 == Some(true)).count();
        let checked = verdicts.iter().filter(|v| v.1.is_some()).count();
        if seen > 10 && seen * 10 > checked * 3 {
            // A third of the map seen through at once says the pose is off, not the world.
            tracing::debug!(seen, checked, "free-space check skipped: pose suspect");
            return 0;
        }
        let mut erase = Vec::new();
        for (id, verdict) in verdicts {
            let Some(p) = self.points.get_mut(&id) else {
                continue;
            };
            match verdict {
                Some(true) => {
                    p.seen_through += 1;
                    if p.seen_through >= erase_after {
                        erase.push(id);
                    }
                }
                Some(false) => p.seen_through = 0,
                None => {}
            }
        }
        for &mp in &erase {
            self.erase_point(mp);
        }
        erase.len()
    }

    /// World-to-camera pose of a keyframe as the map holds it now: a culled keyframe's is its
    /// pose relative to its parent times the parent's (through culled ancestors too).
    pub fn keyframe_pose_cw(&self, kf: KfId) -> Option<Se3> {
        let mut rel = Se3::identity();
        let mut id = kf;
        for _ in 0..=self.keyframes.len() {
            let k = self.keyframes.get(&id)?;
            match (k.bad, k.pose_to_parent, k.parent) {
                (true, Some(t_cp), Some(p)) => {
                    rel *= t_cp;
                    id = p;
                }
                _ => return Some(rel * k.pose_cw),
            }
        }
        None
    }

    /// The widest angle (degrees) between the rays from two of the keyframes that observe map
    /// point `mp` to it: its triangulation's parallax, which bounds how well its depth is known.
    pub fn point_parallax_deg(&self, mp: MpId) -> Option<f64> {
        let p = self.points.get(&mp)?;
        let rays: Vec<Vec3> = p
            .observations
            .keys()
            .filter_map(|k| self.keyframes.get(k))
            .filter_map(|k| (p.position - k.camera_center()).try_normalize(1e-12))
            .collect();
        let widest = rays
            .iter()
            .enumerate()
            .flat_map(|(i, a)| rays[i + 1..].iter().map(move |b| a.angle(b)))
            .fold(0.0, f64::max);
        Some(widest.to_degrees())
    }

    /// Good keyframes of the current map.
    pub fn current_keyframes(&self) -> impl Iterator<Item = &KeyFrame> {
        self.keyframes
            .values()
            .filter(move |k| !k.bad && k.map_epoch == self.epoch)
    }

    /// Start a new map: later keyframes and points get the next epoch.
    pub fn start_new_map(&mut self) {
        self.epoch += 1;
        self.origin_kf = None;
    }

    /// Make the older map `epoch` the current one again (tracking relocalised in it): its
    /// keyframes and points take the next epoch, so the map left behind becomes an older map,
    /// one loop closing may merge later, and the current map stays the newest epoch.
    pub fn reactivate(&mut self, epoch: u32) {
        if epoch == self.epoch {
            return;
        }
        self.epoch += 1;
        self.relabel_map(epoch, self.epoch);
        let origin = self.current_keyframes().map(|k| k.id).next();
        self.origin_kf = origin;
    }

    /// The keyframes and points of map `from` become map `to`'s (a merge, a map made current
    /// again).
    pub fn relabel_map(&mut self, from: u32, to: u32) {
        for k in self.keyframes.values_mut() {
            if k.map_epoch == from {
                k.map_epoch = to;
            }
        }
        for p in self.points.values_mut() {
            if p.map_epoch == from {
                p.map_epoch = to;
            }
        }
    }
}

/// A 64-bit fingerprint of a sequence of descriptors (never 0): equal sequences give equal
/// fingerprints; different ones collide with odds of about 2^-64.
fn descriptors_fingerprint(descs: &[Descriptor]) -> u64 {
    // FNV-1a over 64-bit words, then a final mix (splitmix64's): `crate::fnv1a64` goes byte by
    // byte, 8x the dependent multiplies, and this runs for every point after every local BA.
    let mut h: u64 = 0xcbf2_9ce4_8422_2325 ^ descs.len() as u64;
    for d in descs {
        for w in d.chunks_exact(8) {
            let w = u64::from_le_bytes(w.try_into().expect("8 bytes"));
            h = (h ^ w).wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    h ^= h >> 30;
    h = h.wrapping_mul(0xbf58_476d_1ce4_e5b9);
    h ^= h >> 27;
    h = h.wrapping_mul(0x94d0_49bb_1331_11eb);
    h ^= h >> 31;
    h.max(1)
}

/// The descriptor with the least median Hamming distance to the others.
pub fn best_descriptor(descs: &[Descriptor]) -> Option<Descriptor> {
    if descs.len() <= 2 {
        return descs.first().copied();
    }
    let n = descs.len();
    // Each distance once (the matrix is symmetric), and each row's median by selection, not a
    // sort: a point seen by 50 keyframes made this a tenth of local mapping.
    let mut dist = vec![0u32; n * n];
    for i in 0..n {
        for j in i + 1..n {
            let d = hamming(&descs[i], &descs[j]);
            dist[i * n + j] = d;
            dist[j * n + i] = d;
        }
    }
    let mut best = (u32::MAX, 0);
    for (i, row) in dist.chunks_exact_mut(n).enumerate() {
        let median = *row.select_nth_unstable((n - 1) / 2).1;
        if median < best.0 {
            best = (median, i);
        }
    }
    Some(descs[best.1])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Feature, SlamSettings};

    /// A frame at the origin with 20 keypoints along a row.
    fn row_frame() -> Frame {
        let cam = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
        let s = SlamSettings::rgbd(cam, 40.0, 30.0);
        let feats: Vec<Feature> = (0..20)
            .map(|i| Feature {
                x: 10.0 + 20.0 * i as f32,
                y: 100.0,
                octave: 0,
                angle: 0.0,
            })
            .collect();
        let descs = vec![[7u8; 32]; 20];
        let mut f = Frame::new(0, 0.0, &feats, &descs, None, &s).unwrap();
        f.pose_cw = Some(Se3::identity());
        f
    }

    #[test]
    fn a_points_parallax_is_the_widest_angle_between_its_observing_keyframes() {
        let f = row_frame();
        let mut map = Map::new();
        let k0 = map.add_keyframe(&f).unwrap();
        let k1 = map.add_keyframe(&f).unwrap();
        let k2 = map.add_keyframe(&f).unwrap();
        // Cameras at x = 0, 1 and -1 m; the point 1 m in front of the first: 45 degrees from
        // each side camera, 90 between those two.
        for (k, x) in [(k1, 1.0), (k2, -1.0)] {
            let pose_wc = Se3::from_parts(Vec3::new(x, 0.0, 0.0).into(), Default::default());
            map.keyframes.get_mut(&k).unwrap().pose_cw = pose_wc.inverse();
        }
        let mp = map.add_point(Vec3::new(0.0, 0.0, 1.0), k0, 0).unwrap();
        assert_eq!(map.point_parallax_deg(mp), Some(0.0), "one observation");
        map.add_observation(mp, k1, 0);
        assert!((map.point_parallax_deg(mp).unwrap() - 45.0).abs() < 1e-9);
        map.add_observation(mp, k2, 0);
        assert!((map.point_parallax_deg(mp).unwrap() - 90.0).abs() < 1e-9);
        assert_eq!(map.point_parallax_deg(mp + 1), None);
    }

    #[test]
    fn a_fused_point_is_found_as_the_one_it_went_into_until_that_fusion_is_forgotten() {
        let f = row_frame();
        let mut map = Map::new();
        let k = map.add_keyframe(&f).unwrap();
        let [a, b, c] =
            [0, 1, 2].map(|i| map.add_point(Vec3::new(i as f64, 0.0, 3.0), k, i).unwrap());
        let before = map.fusions();
        map.replace_point(a, b);
        map.replace_point(b, c);
        assert_eq!(map.fusions(), before + 2);
        // a went into b, and b into c: both are found as c.
        for id in [a, b, c] {
            let (found, p) = map.point_or_its_replacement(id).unwrap();
            assert_eq!(found, c);
            assert_eq!(p.position, Vec3::new(2.0, 0.0, 3.0));
        }
        assert!(map.point_or_its_replacement(c + 1).is_none());
        // A frame tracked after the first fusion can only have seen b or c.
        map.forget_fusions_before(before + 1);
        assert!(map.point_or_its_replacement(a).is_none());
        assert_eq!(map.point_or_its_replacement(b).map(|(id, _)| id), Some(c));
        map.forget_fusions_before(map.fusions());
        assert!(map.point_or_its_replacement(b).is_none());
        assert_eq!(map.fusions(), before + 2, "forgetting keeps the count");
    }

    #[test]
    fn edges_count_shared_good_points_with_good_keyframes_and_ties_go_to_the_larger_id() {
        let f = row_frame();
        let mut map = Map::new();
        let _origin = map.add_keyframe(&f).unwrap();
        let others: Vec<KfId> = (0..4).map(|_| map.add_keyframe(&f).unwrap()).collect();
        let subject = map.add_keyframe(&f).unwrap();
        // Points the subject shares: 5 with others[0], 5 with others[1], 2 with others[2], 5
        // with others[3] (made bad below), and one bad point with others[2].
        let shares = [(0, 5), (1, 5), (2, 2), (3, 5), (2, 1)];
        let mut idx = 0;
        let mut next_of = [0usize; 4];
        for (n, &(o, count)) in shares.iter().enumerate() {
            for _ in 0..count {
                let mp = map
                    .add_point(Vec3::new(idx as f64, 0.0, 3.0), subject, idx)
                    .unwrap();
                map.add_observation(mp, others[o], next_of[o]);
                next_of[o] += 1;
                idx += 1;
                if n == 4 {
                    map.points.get_mut(&mp).unwrap().bad = true;
                }
            }
        }
        map.keyframes.get_mut(&others[3]).unwrap().bad = true;
        map.update_connections(subject, 3);
        let edges = |m: &Map, k: KfId| m.keyframes[&k].connections.clone();
        assert_eq!(
            edges(&map, subject),
            BTreeMap::from([(others[0], 5), (others[1], 5)])
        );
        assert_eq!(edges(&map, others[0]).get(&subject), Some(&5));
        assert_eq!(edges(&map, others[2]).get(&subject), None);
        // Of the two strongest (5 each), the later keyframe becomes the parent.
        assert_eq!(map.keyframes[&subject].parent, Some(others[1]));
        // None reaches 6: the strongest alone stays an edge, and the old edge's other side
        // loses it.
        map.update_connections(subject, 6);
        assert_eq!(edges(&map, subject), BTreeMap::from([(others[1], 5)]));
        assert_eq!(edges(&map, others[0]).get(&subject), None);
    }

    #[test]
    fn covisibility_spanning_tree_and_bad_keyframes() {
        let f = row_frame();
        let mut map = Map::new();
        let k0 = map.add_keyframe(&f).unwrap();
        let k1 = map.add_keyframe(&f).unwrap();
        let k2 = map.add_keyframe(&f).unwrap();
        for i in 0..20 {
            let mp = map.add_point(Vec3::new(i as f64, 0.0, 3.0), k0, i).unwrap();
            map.add_observation(mp, k1, i);
            if i < 16 {
                map.add_observation(mp, k2, i);
            }
        }
        map.update_connections(k1, 15);
        map.update_connections(k2, 15);
        assert_eq!(map.keyframes[&k1].connections.get(&k0), Some(&20));
        assert_eq!(map.keyframes[&k2].connections.get(&k1), Some(&16));
        assert_eq!(map.keyframes[&k1].parent, Some(k0));
        assert_eq!(map.keyframes[&k2].parent, Some(k1));
        map.set_bad_keyframe(k1, 15);
        assert!(map.keyframes[&k1].bad);
        assert!(!map.keyframes[&k0].connections.contains_key(&k1));
        // Points seen by k0 and k2 survive, those only by k0 now (4 of them) are erased.
        assert_eq!(map.points.len(), 16);
        assert_eq!(map.keyframes[&k2].parent, Some(k0));
    }

    /// A map with one keyframe at the origin (frame `index`) and points at `positions`.
    fn map_with_points(index: usize, positions: &[Vec3]) -> (Map, Vec<MpId>, PinholeCamera) {
        let cam = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
        let s = SlamSettings::rgbd(cam, 40.0, 30.0);
        let feats: Vec<Feature> = positions
            .iter()
            .map(|p| Feature::at(cam.project(p).unwrap()))
            .collect();
        let descs = vec![[7u8; 32]; feats.len()];
        let mut f = Frame::new(index, 0.0, &feats, &descs, None, &s).unwrap();
        f.pose_cw = Some(Se3::identity());
        let mut map = Map::new();
        let kf = map.add_keyframe(&f).unwrap();
        let ids = positions
            .iter()
            .enumerate()
            .map(|(i, p)| map.add_point(*p, kf, i).unwrap())
            .collect();
        (map, ids, cam)
    }

    /// Depth image of a wall at `z` with a `(x, y, half, z)` square patch at another depth.
    fn wall(z: f32, patch: (usize, usize, usize, f32)) -> DepthMetres {
        let mut d = DepthMetres::new(640, 480, z);
        let (x, y, half, pz) = patch;
        for v in y - half..=y + half {
            for u in x - half..=x + half {
                d.set(u, v, pz);
            }
        }
        d
    }

    const CHECK: FreeSpaceCheck = FreeSpaceCheck {
        bf: 40.0,
        gap_px: 1.0,
        erase_after: 2,
    };

    #[test]
    fn points_seen_through_twice_leave_the_map() {
        // On a person at 2 m (projects to (320, 240)); on the wall at 3.5 m; on the person's
        // silhouette (its 5 x 5 window still reads 2 m).
        let (mut map, ids, cam) = map_with_points(
            0,
            &[
                Vec3::new(0.0, 0.0, 2.0),
                Vec3::new(0.7, 0.0, 3.5),
                Vec3::new(0.08, 0.0, 2.0),
            ],
        );
        // The person walked away: the sensor sees the wall through the first point; the third
        // point's pixel (340, 240) is at the edge of what remains of them.
        let mut depth = wall(3.5, (320, 240, 3, 3.5));
        for v in 230..=250 {
            for u in 336..=338 {
                depth.set(u, v, 2.0);
            }
        }
        let pose = Se3::identity();
        assert_eq!(
            map.erase_points_seen_through(&pose, &cam, &depth, &CHECK),
            0
        );
        assert_eq!(map.points[&ids[0]].seen_through, 1);
        assert_eq!(
            map.erase_points_seen_through(&pose, &cam, &depth, &CHECK),
            1
        );
        assert!(!map.points.contains_key(&ids[0]));
        assert!(map.points.contains_key(&ids[1]) && map.points.contains_key(&ids[2]));
        // Everything seen through at once: the pose is wrong, not the world.
        let many: Vec<Vec3> = (0..20)
            .map(|i| Vec3::new(0.05 * i as f64 - 0.5, 0.0, 2.0))
            .collect();
        let (mut map, _, cam) = map_with_points(0, &many);
        let far_wall = DepthMetres::new(640, 480, 3.5);
        for _ in 0..3 {
            assert_eq!(
                map.erase_points_seen_through(&pose, &cam, &far_wall, &CHECK),
                0
            );
        }
        assert_eq!(map.points.len(), 20);
        // A hole in the depth image is no evidence.
        let (mut map, ids, cam) = map_with_points(0, &[Vec3::new(0.0, 0.0, 2.0)]);
        let holed = wall(3.5, (320, 240, 1, 0.0));
        for _ in 0..3 {
            map.erase_points_seen_through(&pose, &cam, &holed, &CHECK);
        }
        assert!(map.points.contains_key(&ids[0]));
    }

    #[test]
    fn recent_points_on_a_mover_surface_leave_the_map() {
        let positions = [Vec3::new(0.0, 0.0, 2.0), Vec3::new(0.0, 0.4, 3.5)];
        // The person (2 m) stands over (320, 240); the mask holds their pixels (box and depth
        // band, as the front-end makes it); the wall point below them is not on them.
        let depth = wall(3.5, (320, 240, 40, 2.0));
        let mut mask = Gray8::new(640, 480, 0);
        for v in 200..=280 {
            for u in 280..=360 {
                mask.set(u, v, 255);
            }
        }
        let pose = Se3::identity();
        let (mut map, ids, cam) = map_with_points(50, &positions);
        assert_eq!(
            map.erase_recent_points_on_movers(&pose, &cam, &mask, &depth, 40),
            1
        );
        assert!(!map.points.contains_key(&ids[0]) && map.points.contains_key(&ids[1]));
        // Made before the window: kept.
        let (mut map, _, cam) = map_with_points(10, &positions);
        assert_eq!(
            map.erase_recent_points_on_movers(&pose, &cam, &mask, &depth, 40),
            0
        );
    }

    /// A culled keyframe moves with its parent afterwards (frames anchored to it follow).
    #[test]
    fn culled_keyframe_pose_follows_its_parent() {
        let mut f = row_frame();
        let mut map = Map::new();
        let k0 = map.add_keyframe(&f).unwrap();
        let step = Se3::new(Vec3::new(0.1, 0.0, 0.0), Vec3::new(0.0, 0.05, 0.0));
        f.pose_cw = Some(step);
        let k1 = map.add_keyframe(&f).unwrap();
        for i in 0..20 {
            let mp = map.add_point(Vec3::new(i as f64, 0.0, 3.0), k0, i).unwrap();
            map.add_observation(mp, k1, i);
        }
        map.update_connections(k1, 15);
        assert_eq!(map.keyframes[&k1].parent, Some(k0));
        map.set_bad_keyframe(k1, 15);
        // Bundle adjustment moves the parent after the cull.
        let moved = Se3::new(Vec3::new(0.0, 0.2, 0.0), Vec3::new(0.02, 0.0, 0.0));
        map.keyframes.get_mut(&k0).unwrap().pose_cw = moved;
        let pose = map.keyframe_pose_cw(k1).unwrap();
        let expected = step * moved;
        assert!((pose.translation.vector - expected.translation.vector).norm() < 1e-12);
        assert!(pose.rotation.angle_to(&expected.rotation) < 1e-12);
        assert_eq!(map.keyframe_pose_cw(k0), Some(moved));
    }

    /// A culled keyframe follows its covisible keyframe nearest in time, not an older parent
    /// that shared more points with it: the frames anchored to it move with the map around it.
    #[test]
    fn culled_keyframe_follows_its_nearest_covisible_in_time() {
        let mut f = row_frame();
        let mut map = Map::new();
        let mut ids = Vec::new();
        for (i, t) in [0.0, 1.0, 1.1].into_iter().enumerate() {
            f.timestamp = t;
            f.pose_cw = Some(Se3::new(Vec3::new(0.1 * i as f64, 0.0, 0.0), Vec3::zeros()));
            ids.push(map.add_keyframe(&f).unwrap());
        }
        let (old, subject, next) = (ids[0], ids[1], ids[2]);
        // The subject shares all 20 points with the old keyframe, 16 with the next.
        for i in 0..20 {
            let mp = map
                .add_point(Vec3::new(i as f64, 0.0, 3.0), old, i)
                .unwrap();
            map.add_observation(mp, subject, i);
            if i < 16 {
                map.add_observation(mp, next, i);
            }
        }
        map.update_connections(subject, 15);
        map.update_connections(next, 15);
        assert_eq!(map.keyframes[&subject].parent, Some(old));
        map.set_bad_keyframe(subject, 15);
        assert_eq!(map.keyframes[&subject].parent, Some(next));
        // Bundle adjustment moves the next keyframe, not the old one: the culled one goes along.
        let moved = Se3::new(Vec3::new(0.0, 0.3, 0.0), Vec3::new(0.0, 0.0, 0.01));
        let before = map.keyframe_pose_cw(subject).unwrap();
        let next_before = map.keyframes[&next].pose_cw;
        map.keyframes.get_mut(&next).unwrap().pose_cw = moved * next_before;
        let after = map.keyframe_pose_cw(subject).unwrap();
        let expected = before * next_before.inverse() * moved * next_before;
        assert!((after.translation.vector - expected.translation.vector).norm() < 1e-12);
        assert!(after.rotation.angle_to(&expected.rotation) < 1e-12);
    }

    #[test]
    fn best_descriptor_is_the_first_with_the_least_sorted_median_distance() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        for n in 0..40 {
            // Few distinct bits, so that medians tie and the first of them must win.
            let descs: Vec<Descriptor> = (0..n)
                .map(|_| {
                    let mut d = [0u8; 32];
                    d[0] = rng.random_range(0..8);
                    d[5] = rng.random_range(0..4);
                    d
                })
                .collect();
            let reference = (descs.len() > 2).then(|| {
                let median = |i: usize| {
                    let mut d: Vec<u32> = descs.iter().map(|b| hamming(&descs[i], b)).collect();
                    d.sort_unstable();
                    d[(n - 1) / 2]
                };
                let best = (0..n).min_by_key(|&i| (median(i), i)).unwrap();
                descs[best]
            });
            let expected = reference.or_else(|| descs.first().copied());
            assert_eq!(best_descriptor(&descs), expected, "{n} descriptors");
        }
    }
}
