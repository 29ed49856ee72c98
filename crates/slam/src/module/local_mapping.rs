//! Local mapping (ORB-SLAM3 `LocalMapping`): per new keyframe, associate its points, cull recent
//! points, fuse duplicates with neighbours, local bundle adjustment, cull redundant keyframes.
//!
//! [`LocalMapper::process`] does one keyframe; [`MapperThread`] runs it in its own thread fed by
//! a channel. The map ([`SharedMap`], served in turn) is taken for one short piece of work at a
//! time (a neighbour's triangulation, a batch of points, a step), so that tracking, which needs
//! it every frame, waits a few milliseconds at most: whole steps under one lock (13 ms mean, 30
//! max, longer when the niced mapper was preempted) held it back 20-40 ms. Bundle adjustment
//! works on a copy so tracking is not blocked while it solves.

use std::collections::BTreeSet;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use stillpoint_geometry::Vec3;
use tracing::debug;

use crate::SlamSettings;
use crate::data::{KfId, Map, MpId, SharedMap};
use crate::hamming;
use crate::matching::epipolar::EpipolarGrid;
use crate::optimize::{BaObservation, BaProblem, local_bundle_adjustment};

/// Points handled under one taking of the map lock (new points, updates, fusion candidates):
/// ~1 ms of work.
const POINTS_PER_LOCK: usize = 200;

/// A free keypoint of a neighbour keyframe, as the epipolar search reads it.
#[derive(Clone, Copy)]
struct NearLine {
    /// Its index in the keyframe.
    j: usize,
    x: f64,
    y: f64,
    /// Squared distance from a line it may be matched within, in pixels.
    band: f64,
    /// `band` with a margin, for the test without the division.
    loose: f64,
}

/// Cell side of the grid that finds a neighbour's keypoints near an epipolar line, in pixels.
const EPIPOLAR_CELL_PX: f64 = 32.0;

/// Run `f` on `items`, `POINTS_PER_LOCK` at a time, each batch under its own lock; false when
/// the lock is poisoned.
fn in_batches<T>(map: &SharedMap, items: &[T], mut f: impl FnMut(&mut Map, &T)) -> bool {
    for batch in items.chunks(POINTS_PER_LOCK) {
        let Ok(mut m) = map.lock() else { return false };
        for item in batch {
            f(&mut m, item);
        }
    }
    true
}

/// Local mapping state: the recently created points awaiting culling.
pub struct LocalMapper {
    /// The settings it runs with.
    pub s: SlamSettings,
    recent_points: Vec<MpId>,
    scales: Vec<f64>,
    inv_sigma2: Vec<f64>,
}

impl LocalMapper {
    /// A mapper with no recent points.
    pub fn new(s: SlamSettings) -> Self {
        Self {
            scales: s.scale_factors(),
            inv_sigma2: s.inv_level_sigma2(),
            s,
            recent_points: Vec::new(),
        }
    }

    /// Process one keyframe. The map lock is taken per short piece of work; the BA solve runs
    /// unlocked. Alone on the map (inline), the pieces do exactly what one locked pass would.
    pub fn process(&mut self, map: &SharedMap, kf: KfId) {
        if map
            .lock()
            .map_or(true, |m| m.keyframes.get(&kf).is_none_or(|k| k.bad))
        {
            return;
        }
        let t0 = Instant::now();
        self.process_new_keyframe(map, kf);
        let t1 = Instant::now();
        if self.s.triangulate_new_points {
            self.create_new_points(map, kf);
        }
        let t2 = Instant::now();
        self.fuse_with_neighbours(map, kf);
        debug!(
            associate_ms = (t1 - t0).as_secs_f64() * 1e3,
            triangulate_ms = (t2 - t1).as_secs_f64() * 1e3,
            fuse_ms = stillpoint_core::ms_since(t2),
            "local mapping: before BA"
        );
        self.local_ba(map, kf);
        if let Ok(mut m) = map.lock() {
            self.cull_keyframes(&mut m, kf);
        }
    }

    /// The keyframe's points observe it (those it created are recent), its connections are
    /// updated, then recent points are culled.
    fn process_new_keyframe(&mut self, map: &SharedMap, kf: KfId) {
        let mps: Vec<(usize, MpId)> = {
            let Ok(m) = map.lock() else { return };
            let Some(k) = m.keyframes.get(&kf) else {
                return;
            };
            k.map_points
                .iter()
                .enumerate()
                .filter_map(|(i, p)| p.map(|p| (i, p)))
                .collect()
        };
        let recent = &mut self.recent_points;
        let scales = &self.scales;
        let done = in_batches(map, &mps, |m, &(i, mp)| {
            let Some(p) = m.points.get(&mp) else {
                if let Some(k) = m.keyframes.get_mut(&kf) {
                    k.map_points[i] = None;
                }
                return;
            };
            if p.observations.contains_key(&kf) {
                if p.first_kf == kf {
                    recent.push(mp);
                }
            } else {
                m.add_observation(mp, kf, i);
                m.update_point(mp, scales);
            }
        });
        if !done {
            return;
        }
        if let Ok(mut m) = map.lock() {
            m.update_connections(kf, self.s.covisibility_min_shared);
            self.cull_points(&mut m, kf);
        }
    }

    /// ORB-SLAM3 `MapPointCulling`.
    fn cull_points(&mut self, m: &mut Map, current: KfId) {
        let min_obs = self.s.point_min_observations;
        let ratio = self.s.point_found_ratio;
        let mut keep = Vec::with_capacity(self.recent_points.len());
        for &mp in &self.recent_points {
            let Some(p) = m.points.get(&mp) else { continue };
            let age = current.saturating_sub(p.first_kf);
            if p.found_ratio() < ratio
                || (age >= 2 && p.weighted_observations(&m.keyframes) <= min_obs)
            {
                m.erase_point(mp);
            } else if age < 3 {
                keep.push(mp);
            }
        }
        self.recent_points = keep;
    }

    /// ORB-SLAM3 `CreateNewMapPoints`: keypoints of the new keyframe and of its best covisible
    /// keyframes that observe no map point are matched by descriptor (Hamming <= `th_low`, near
    /// the epipolar line, rotation-consistent) and triangulated, or lifted with the depth of the
    /// view whose depth gives more parallax; kept when in front of both cameras, within the
    /// chi-square of both observations and at consistent scales. This is how keypoints without
    /// depth (beyond the sensor, or on a depth hole) enter the map, and, monocular, every point
    /// after initialisation. Monocular also skips neighbours too close for their scene depth
    /// (baseline < 1 % of their median depth) and keypoints near the epipole, as ORB-SLAM3, and
    /// asks the parallax also at the depth of the keyframe's points round the keypoint.
    /// Keypoints the front-end flagged `no_new_point` never found a point here either.
    fn create_new_points(&mut self, map: &SharedMap, kf: KfId) {
        let (free1, neighbours, prior) = {
            let Ok(m) = map.lock() else { return };
            let Some(k1) = m.keyframes.get(&kf) else {
                return;
            };
            let free1: Vec<usize> = (0..k1.points.len())
                .filter(|&i| free_keypoint(k1, i))
                .collect();
            let prior = (self.s.monocular && self.s.new_point_parallax_from_neighbours)
                .then(|| {
                    DepthPrior::of(
                        k1,
                        &m.points,
                        &self.s.camera,
                        self.s.new_point_prior_depth_quantile,
                    )
                })
                .flatten();
            (free1, k1.best_covisibles(self.s.mapping_neighbours), prior)
        };
        let prior = prior.as_ref();
        let threads = if self.s.local_mapping_thread {
            1
        } else {
            self.s
                .triangulation_threads
                .clamp(1, neighbours.len().max(1))
        };
        let mut created = Vec::new();
        if threads == 1 {
            // The lock per neighbour: tracking, on its own thread, gets the map in between.
            for kf2 in neighbours {
                let Ok(m) = map.lock() else { return };
                self.triangulate_with_neighbour(&m, kf, kf2, &free1, prior, &mut created);
            }
        } else {
            // Inline, nothing else uses the map: each thread takes a run of the neighbours,
            // and their points join in the neighbours' order, as one thread would make them.
            let Ok(m) = map.lock() else { return };
            let m: &Map = &m;
            let share = neighbours.len().div_ceil(threads);
            let this = &*self;
            let free1 = &free1;
            let work = move |run: &[KfId]| {
                let mut out = Vec::new();
                for &kf2 in run {
                    this.triangulate_with_neighbour(m, kf, kf2, free1, prior, &mut out);
                }
                out
            };
            let mut runs = neighbours.chunks(share);
            let first = runs.next().unwrap_or_default();
            std::thread::scope(|sc| {
                let others: Vec<_> = runs.map(|run| sc.spawn(move || work(run))).collect();
                created = work(first);
                for h in others {
                    // A worker's panic is the mapper's, as with one thread.
                    created.extend(h.join().unwrap_or_else(|p| std::panic::resume_unwind(p)));
                }
            });
        }
        let recent = &mut self.recent_points;
        let scales = &self.scales;
        in_batches(map, &created, |m, &(x, i, kf2, j)| {
            let (Some(k1), Some(k2)) = (m.keyframes.get(&kf), m.keyframes.get(&kf2)) else {
                return;
            };
            // An earlier neighbour may have taken either keypoint.
            if k1.map_points[i].is_some() || k2.map_points[j].is_some() {
                return;
            }
            if let Some(mp) = m.add_point(x, kf, i) {
                m.add_observation(mp, kf2, j);
                m.update_point(mp, scales);
                recent.push(mp);
            }
        });
    }

    /// [`LocalMapper::create_new_points`] with one neighbour `kf2`: the free keypoints `free1`
    /// of `kf` matched along their epipolar lines and triangulated, pushed to `created` as
    /// (point, keypoint in `kf`, `kf2`, keypoint in `kf2`).
    fn triangulate_with_neighbour(
        &self,
        m: &Map,
        kf: KfId,
        kf2: KfId,
        free1: &[usize],
        prior: Option<&DepthPrior>,
        created: &mut Vec<(Vec3, usize, KfId, usize)>,
    ) {
        let (Some(k1), Some(k2)) = (m.keyframes.get(&kf), m.keyframes.get(&kf2)) else {
            return;
        };
        if k2.bad || k2.map_epoch != k1.map_epoch {
            return;
        }
        let s = &self.s;
        let cam = &s.camera;
        let baseline = s.bf / cam.fx;
        let ratio_factor = 1.5 * s.scale_factor;
        let center1 = k1.camera_center();
        let center2 = k2.camera_center();
        if s.monocular {
            let depth2 = k2.scene_median_depth(&m.points).unwrap_or(0.0);
            if !(depth2 > 0.0 && (center2 - center1).norm() / depth2 >= 0.01) {
                return;
            }
        } else if (center2 - center1).norm() < baseline {
            return;
        }
        let pose2 = k2.pose_cw;
        // Fundamental matrix of the pair, for the epipolar check (pixels of 1 -> line in 2).
        let t12 = k1.pose_cw * pose2.inverse();
        let (r21, t21) = {
            let t21 = t12.inverse();
            (
                t21.rotation.to_rotation_matrix().into_inner(),
                t21.translation.vector,
            )
        };
        let kinv = cam
            .k()
            .try_inverse()
            .unwrap_or_else(stillpoint_geometry::Mat3::identity);
        let f21 = kinv.transpose() * stillpoint_geometry::skew(&t21) * r21 * kinv;
        // Monocular: where the first camera's centre appears in the second image; matches
        // near it have no parallax whatever their depth.
        let epipole2 = {
            let c = (pose2 * nalgebra::Point3::from(center1)).coords;
            (s.monocular && c.z.abs() > 1e-12).then(|| {
                stillpoint_geometry::Vec2::new(
                    cam.fx * c.x / c.z + cam.cx,
                    cam.fy * c.y / c.z + cam.cy,
                )
            })
        };
        // The free keypoints of the neighbour in a grid, so that the epipolar test, which
        // rejects all but a few, looks only at those in the cells the line crosses before any
        // descriptor is compared (a monocular keyframe has ~all its keypoints free, and 30
        // neighbours: every pair tested took over a third of a monocular run). Each carries
        // its band (3.84 sigma^2, chi-square 95 % at one degree of freedom) and the band with
        // a margin for a first test without the division: the pair of tests as before the
        // grid, so that the same pairs pass to the last bit.
        let candidates: Vec<NearLine> = (0..k2.points.len())
            .filter(|&j| free_keypoint(k2, j))
            .map(|j| {
                let band = 3.84 * (1.0 / self.inv_sigma2[k2.octaves[j] as usize]);
                NearLine {
                    j,
                    x: k2.points[j].x,
                    y: k2.points[j].y,
                    band,
                    loose: band * (1.0 + 1e-9),
                }
            })
            .collect();
        let widest = candidates.iter().fold(0.0f64, |w, c| w.max(c.band)).sqrt();
        let grid = EpipolarGrid::new(&candidates, |c| (c.x, c.y), EPIPOLAR_CELL_PX, widest);
        let mut matches: Vec<(usize, usize, f32)> = Vec::new();
        for &i in free1 {
            let p1 = k1.points[i];
            let line = f21 * nalgebra::Vector3::new(p1.x, p1.y, 1.0);
            let norm2 = line.x * line.x + line.y * line.y;
            if norm2 <= 0.0 {
                continue;
            }
            // The closest descriptor near the line, the first in the neighbour's keypoint order
            // among equals (the grid visits in no order, so ties go to the smaller index).
            let mut best = (u32::MAX, usize::MAX);
            grid.near_line(line.x, line.y, line.z, |c| {
                let dist = line.x * c.x + line.y * c.y + line.z;
                if !(dist * dist < c.loose * norm2 && dist * dist / norm2 < c.band) {
                    return;
                }
                let j = c.j;
                if let Some(ep) = epipole2
                    && k1.depth[i] <= 0.0
                    && k2.depth[j] <= 0.0
                    && (ep - k2.points[j]).norm_squared()
                        < 100.0 * self.scales[k2.octaves[j] as usize]
                {
                    return;
                }
                let d = hamming(&k1.descriptors[i], &k2.descriptors[j]);
                if d <= s.th_low && (d, j) < best {
                    best = (d, j);
                }
            });
            if best.1 != usize::MAX {
                matches.push((i, best.1, k2.angles[best.1] - k1.angles[i]));
            }
        }
        let rot: Vec<(usize, f32)> = matches.iter().map(|m| (m.0, m.2)).collect();
        let drop: BTreeSet<usize> = crate::matching::rotation_outliers(&rot)
            .into_iter()
            .collect();
        let mut used2 = BTreeSet::new();
        for (n, &(i, j, _)) in matches.iter().enumerate() {
            if drop.contains(&n) || !used2.insert(j) {
                continue;
            }
            if let Some(x) = self.triangulate_pair(k1, i, k2, j, ratio_factor, prior) {
                created.push((x, i, kf2, j));
            }
        }
    }

    /// The 3D point of keypoint `i` of `k1` matched to `j` of `k2`, with ORB-SLAM3's checks;
    /// `None` when it fails one.
    fn triangulate_pair(
        &self,
        k1: &crate::data::KeyFrame,
        i: usize,
        k2: &crate::data::KeyFrame,
        j: usize,
        ratio_factor: f64,
        prior: Option<&DepthPrior>,
    ) -> Option<Vec3> {
        let s = &self.s;
        let cam = &s.camera;
        let norm = |p: &stillpoint_geometry::Vec2| {
            stillpoint_geometry::Vec2::new((p.x - cam.cx) / cam.fx, (p.y - cam.cy) / cam.fy)
        };
        let (x1, x2) = (norm(&k1.points[i]), norm(&k2.points[j]));
        let ray = |k: &crate::data::KeyFrame, x: &stillpoint_geometry::Vec2| {
            k.pose_cw.inverse().rotation * Vec3::new(x.x, x.y, 1.0)
        };
        let (ray1, ray2) = (ray(k1, &x1), ray(k2, &x2));
        let cos_rays = ray1.dot(&ray2) / (ray1.norm() * ray2.norm());
        let baseline = s.bf / cam.fx;
        let stereo_cos = |z: f32| {
            if z > 0.0 {
                (2.0 * (baseline / 2.0).atan2(z as f64)).cos()
            } else {
                2.0
            }
        };
        let (c1, c2) = (stereo_cos(k1.depth[i]), stereo_cos(k2.depth[j]));
        let cos_stereo = c1.min(c2);
        // Without depth: enough parallax on the rays themselves (ORB-SLAM3) and, monocular, at
        // the depth the keyframe's points round the keypoint have, which its noise cannot move.
        let parallax = || match prior {
            Some(prior) => {
                let z = prior.at(k1.points[i].x, k1.points[i].y);
                let at = k1.pose_cw.inverse() * nalgebra::Point3::new(x1.x * z, x1.y * z, z);
                let (r1, r2) = (
                    at.coords - k1.camera_center(),
                    at.coords - k2.camera_center(),
                );
                let cos_prior = r1.dot(&r2) / (r1.norm() * r2.norm());
                cos_prior < s.new_point_max_cos_parallax
                    && cos_rays < s.new_point_max_cos_parallax_measured
            }
            None => cos_rays < s.new_point_max_cos_parallax,
        };
        let x = if cos_rays < cos_stereo
            && cos_rays > 0.0
            && (k1.depth[i] > 0.0 || k2.depth[j] > 0.0 || parallax())
        {
            crate::solve::triangulate(&k1.pose_cw, &x1, &k2.pose_cw, &x2)?
        } else if k1.depth[i] > 0.0 && c1 < c2 {
            k1.unproject_world(i, cam)?
        } else if k2.depth[j] > 0.0 && c2 < c1 {
            k2.unproject_world(j, cam)?
        } else {
            return None;
        };
        // In front of both cameras, within the chi-square of both observations.
        for (k, idx) in [(k1, i), (k2, j)] {
            let pc = (k.pose_cw * nalgebra::Point3::from(x)).coords;
            if pc.z <= 0.0 {
                return None;
            }
            let uv = cam.project_undistorted(&pc)?;
            let kp = k.points[idx];
            let inv = self.inv_sigma2[k.octaves[idx] as usize];
            let mut e2 = (uv.x - kp.x).powi(2) + (uv.y - kp.y).powi(2);
            let th = if k.u_right[idx] > 0.0 {
                e2 += (uv.x - s.bf / pc.z - k.u_right[idx] as f64).powi(2);
                7.8
            } else {
                5.991
            };
            if e2 * inv > th {
                return None;
            }
        }
        // Scale consistency: distances to the two cameras agree with the keypoints' octaves.
        let (d1, d2) = (
            (x - k1.camera_center()).norm(),
            (x - k2.camera_center()).norm(),
        );
        if d1 <= 0.0 || d2 <= 0.0 {
            return None;
        }
        let ratio_dist = d2 / d1;
        let ratio_octave =
            self.scales[k1.octaves[i] as usize] / self.scales[k2.octaves[j] as usize];
        if ratio_dist * ratio_factor < ratio_octave || ratio_dist > ratio_octave * ratio_factor {
            return None;
        }
        Some(x)
    }

    /// ORB-SLAM3 `SearchInNeighbors`: fuse the keyframe's points into its neighbours and theirs
    /// into it, merging duplicates.
    fn fuse_with_neighbours(&mut self, map: &SharedMap, kf: KfId) {
        let (targets, own) = {
            let Ok(m) = map.lock() else { return };
            let Some(k) = m.keyframes.get(&kf) else {
                return;
            };
            let mut targets: BTreeSet<KfId> = BTreeSet::new();
            for k in k.best_covisibles(self.s.mapping_neighbours) {
                targets.insert(k);
                if let Some(kk) = m.keyframes.get(&k) {
                    for k2 in kk.best_covisibles(5) {
                        targets.insert(k2);
                    }
                }
            }
            targets.remove(&kf);
            targets.retain(|t| {
                m.keyframes
                    .get(t)
                    .is_some_and(|k| !k.bad && k.map_epoch == m.epoch)
            });
            (targets, matched_points(&m, kf))
        };
        for &t in &targets {
            if !self.fuse(map, t, &own) {
                return;
            }
        }
        let theirs: Vec<MpId> = {
            let Ok(m) = map.lock() else { return };
            let mut theirs = BTreeSet::new();
            for t in &targets {
                if let Some(k) = m.keyframes.get(t) {
                    theirs.extend(k.map_points.iter().flatten().copied());
                }
            }
            theirs.into_iter().collect()
        };
        if !self.fuse(map, kf, &theirs) {
            return;
        }
        let own = match map.lock() {
            Ok(m) => matched_points(&m, kf),
            Err(_) => return,
        };
        let scales = &self.scales;
        if in_batches(map, &own, |m, &mp| m.update_point(mp, scales))
            && let Ok(mut m) = map.lock()
        {
            m.update_connections(kf, self.s.covisibility_min_shared);
        }
    }

    /// ORB-SLAM `ORBmatcher::Fuse(pKF, vpMapPoints, th=3)`: `points` projected into `target`
    /// and merged with, or added to, the keypoint they match. The matches are all found (a
    /// batch of points per lock) before any is applied, as ORB-SLAM does; false when the lock
    /// is poisoned.
    fn fuse(&self, map: &SharedMap, target: KfId, points: &[MpId]) -> bool {
        let mut found = Vec::new();
        for batch in points.chunks(POINTS_PER_LOCK) {
            let Ok(m) = map.lock() else { return false };
            found.extend(self.fusion_matches(&m, target, batch));
        }
        let Ok(mut m) = map.lock() else { return false };
        apply_fusion(&mut m, target, found);
        true
    }

    /// Of `points`, those that project onto a keypoint of `target` with a close descriptor:
    /// (point, keypoint, the keypoint's point then).
    fn fusion_matches(&self, m: &Map, target: KfId, points: &[MpId]) -> Vec<FusionMatch> {
        let s = &self.s;
        let Some(k) = m.keyframes.get(&target) else {
            return Vec::new();
        };
        let pose = k.pose_cw;
        let center = k.camera_center();
        let mut actions: Vec<(MpId, usize, Option<MpId>)> = Vec::new();
        for &mp in points {
            let Some(p) = m.points.get(&mp) else { continue };
            let k = &m.keyframes[&target];
            if p.bad || p.observations.contains_key(&target) {
                continue;
            }
            let pc = (pose * nalgebra::Point3::from(p.position)).coords;
            let Some(uv) = s.camera.project_undistorted(&pc) else {
                continue;
            };
            if !s.camera.in_image(&uv, 0.0) {
                continue;
            }
            if !p.in_viewing_range(&center) {
                continue;
            }
            let dist = (p.position - center).norm();
            let level = p.predict_scale(dist, s.scale_factor.ln(), s.n_levels);
            let r = 3.0 * self.scales[level as usize];
            let ur = uv.x - s.bf / pc.z;
            let mut best = (u32::MAX, usize::MAX);
            for c in k.features_in_area(uv.x, uv.y, r, level - 1, level) {
                let kp = k.points[c];
                let inv = self.inv_sigma2[k.octaves[c] as usize];
                let mut e2 = (uv.x - kp.x).powi(2) + (uv.y - kp.y).powi(2);
                let chi_th = if k.u_right[c] > 0.0 {
                    e2 += (ur - k.u_right[c] as f64).powi(2);
                    7.8
                } else {
                    5.99
                };
                if e2 * inv > chi_th {
                    continue;
                }
                let d = hamming(&p.descriptor, &k.descriptors[c]);
                if d < best.0 {
                    best = (d, c);
                }
            }
            if best.0 <= s.th_low {
                actions.push((mp, best.1, k.map_points[best.1]));
            }
        }
        actions
    }

    /// Local BA over the keyframe and its covisible keyframes; keyframes that see those points
    /// but are not covisible are fixed, as is the map's first keyframe.
    fn local_ba(&mut self, map: &SharedMap, kf: KfId) {
        let (mut problem, kf_ids, pt_ids) = {
            let Ok(m) = map.lock() else { return };
            let Some(k) = m.keyframes.get(&kf) else {
                return;
            };
            // The keyframe and its best covisible ones, at most `local_ba_max_keyframes`; the
            // rest that see the points are fixed. ORB-SLAM takes every covisible keyframe, which
            // on a failing map (a keyframe every frame) makes each BA grow with the map.
            let mut local: Vec<KfId> = vec![kf];
            local.extend(
                k.best_covisibles(k.connections.len())
                    .into_iter()
                    .filter(|o| {
                        m.keyframes
                            .get(o)
                            .is_some_and(|x| !x.bad && x.map_epoch == m.epoch)
                    })
                    .take(self.s.local_ba_max_keyframes.saturating_sub(1)),
            );
            let local_set: BTreeSet<KfId> = local.iter().copied().collect();
            let mut pts: BTreeSet<MpId> = BTreeSet::new();
            for l in &local {
                pts.extend(
                    m.keyframes[l]
                        .map_points
                        .iter()
                        .flatten()
                        .filter(|p| m.points.contains_key(p)),
                );
            }
            let mut fixed: BTreeSet<KfId> = BTreeSet::new();
            for p in &pts {
                for o in m.points[p].observations.keys() {
                    if !local_set.contains(o) && m.keyframes.get(o).is_some_and(|x| !x.bad) {
                        fixed.insert(*o);
                    }
                }
            }
            let mut kf_ids: Vec<KfId> = local.clone();
            kf_ids.extend(fixed.iter().copied());
            let mut is_fixed: Vec<bool> = kf_ids
                .iter()
                .map(|id| fixed.contains(id) || Some(*id) == m.origin_kf)
                .collect();
            if !is_fixed.iter().any(|&f| f) {
                // No gauge anchor: fix the oldest local keyframe.
                let oldest = (0..kf_ids.len()).min_by_key(|&i| kf_ids[i]).unwrap_or(0);
                is_fixed[oldest] = true;
            }
            let kf_index: std::collections::BTreeMap<KfId, usize> =
                kf_ids.iter().enumerate().map(|(i, k)| (*k, i)).collect();
            let pt_ids: Vec<MpId> = pts.into_iter().collect();
            let mut problem = BaProblem {
                poses: kf_ids.iter().map(|k| m.keyframes[k].pose_cw).collect(),
                fixed: is_fixed,
                points: pt_ids.iter().map(|p| m.points[p].position).collect(),
                observations: Vec::new(),
            };
            for (pi, p) in pt_ids.iter().enumerate() {
                for (ok, &idx) in &m.points[p].observations {
                    let Some(&ci) = kf_index.get(ok) else {
                        continue;
                    };
                    let k = &m.keyframes[ok];
                    let Some(px) = k.points.get(idx) else {
                        continue;
                    };
                    problem.observations.push(BaObservation {
                        camera: ci,
                        point: pi,
                        u: px.x,
                        v: px.y,
                        u_right: (k.u_right[idx] > 0.0).then_some(k.u_right[idx] as f64),
                        inv_sigma2: self.inv_sigma2[k.octaves[idx] as usize],
                    });
                }
            }
            (problem, kf_ids, pt_ids)
        };
        let t0 = Instant::now();
        let outliers = local_bundle_adjustment(&mut problem, &self.s);
        debug!(
            keyframes = kf_ids.len(),
            points = pt_ids.len(),
            ms = stillpoint_core::ms_since(t0),
            "local BA"
        );
        let Ok(mut m) = map.lock() else { return };
        for (i, id) in kf_ids.iter().enumerate() {
            if !problem.fixed[i]
                && let Some(k) = m.keyframes.get_mut(id)
                && !k.bad
            {
                k.pose_cw = problem.poses[i];
            }
        }
        for (i, id) in pt_ids.iter().enumerate() {
            if let Some(p) = m.points.get_mut(id) {
                p.position = problem.points[i];
            }
        }
        for (o, out) in problem.observations.iter().zip(outliers) {
            if out {
                m.erase_observation(pt_ids[o.point], kf_ids[o.camera]);
            }
        }
        drop(m);
        let scales = &self.scales;
        in_batches(map, &pt_ids, |m, id| m.update_point(*id, scales));
    }

    /// ORB-SLAM3 `KeyFrameCulling`: drop covisible keyframes whose close points (monocular: all
    /// points) are 90 % seen by at least 3 other keyframes at the same or finer scale.
    fn cull_keyframes(&mut self, m: &mut Map, kf: KfId) {
        let Some(k) = m.keyframes.get(&kf) else {
            return;
        };
        let close = self.s.close_depth() as f32;
        let th_obs = 3;
        let max_gap_s = if self.s.monocular {
            self.s.kf_cull_max_gap_s_monocular
        } else {
            self.s.kf_cull_max_gap_s
        };
        let candidates: Vec<KfId> = k.connections.keys().copied().collect();
        for c in candidates {
            if Some(c) == m.origin_kf {
                continue;
            }
            let Some(ck) = m.keyframes.get(&c) else {
                continue;
            };
            if ck.bad {
                continue;
            }
            let (mut n_mps, mut redundant) = (0usize, 0usize);
            for (i, mp) in ck.map_points.iter().enumerate() {
                let Some(p) = mp.and_then(|mp| m.points.get(&mp)) else {
                    continue;
                };
                let z = ck.depth[i];
                let counted = self.s.monocular || (z > 0.0 && z < close);
                if !counted {
                    continue;
                }
                n_mps += 1;
                if p.observations.len() > th_obs {
                    let level = ck.octaves[i] as i32;
                    let n_obs = p
                        .observations
                        .iter()
                        .filter(|(o, _)| **o != c)
                        .filter(|(o, idx)| {
                            m.keyframes
                                .get(o)
                                .is_some_and(|ok| (ok.octaves[**idx] as i32) <= level + 1)
                        })
                        .count();
                    if n_obs >= th_obs {
                        redundant += 1;
                    }
                }
            }
            if n_mps > 0
                && redundant as f64 > self.s.kf_redundancy * n_mps as f64
                && !leaves_gap(m, c, max_gap_s)
            {
                debug!(keyframe = c, "redundant keyframe culled");
                m.set_bad_keyframe(c, self.s.covisibility_min_shared);
            }
        }
    }
}

/// Whether culling keyframe `c` would leave more than `max_gap_s` seconds between the good
/// keyframes of its map just before and just after it in time (`max_gap_s` 0: never).
fn leaves_gap(m: &Map, c: KfId, max_gap_s: f64) -> bool {
    let Some(ck) = m.keyframes.get(&c).filter(|_| max_gap_s > 0.0) else {
        return false;
    };
    let (mut before, mut after) = (f64::NEG_INFINITY, f64::INFINITY);
    for k in m.keyframes.values() {
        if k.bad || k.id == c || k.map_epoch != ck.map_epoch {
            continue;
        }
        if k.timestamp < ck.timestamp {
            before = before.max(k.timestamp);
        } else {
            after = after.min(k.timestamp);
        }
    }
    before.is_finite() && after.is_finite() && after - before > max_gap_s
}

/// A point of [`LocalMapper::fusion_matches`]: (point, keypoint of the target, the
/// keypoint's own point when it had one).
type FusionMatch = (MpId, usize, Option<MpId>);

/// Apply the matches of [`LocalMapper::fusion_matches`] to `target`: a matched keypoint's
/// point and the match merge into whichever has more observations; a free keypoint observes
/// the match. Points and keypoints taken since the matches were found are checked again.
fn apply_fusion(m: &mut Map, target: KfId, actions: Vec<FusionMatch>) {
    for (mp, idx, existing) in actions {
        if !m.points.contains_key(&mp) {
            continue;
        }
        match existing.filter(|e| m.points.contains_key(e)) {
            Some(e) if e == mp => {}
            Some(e) => {
                let (ne, nm) = (
                    m.points[&e].observations.len(),
                    m.points[&mp].observations.len(),
                );
                if ne > nm {
                    m.replace_point(mp, e)
                } else {
                    m.replace_point(e, mp)
                }
            }
            None => {
                if m.keyframes[&target].map_points[idx].is_none()
                    && !m.points[&mp].observations.contains_key(&target)
                {
                    m.add_observation(mp, target, idx);
                }
            }
        }
    }
}

/// A keypoint with no map point that the front-end left free to make one.
fn free_keypoint(k: &crate::data::KeyFrame, i: usize) -> bool {
    k.map_points[i].is_none() && !k.no_new_point.get(i).copied().unwrap_or(false)
}

/// The map points `kf` sees, in keypoint order (read again after fusion, which replaces some).
fn matched_points(m: &Map, kf: KfId) -> Vec<MpId> {
    m.keyframes[&kf]
        .map_points
        .iter()
        .flatten()
        .copied()
        .collect()
}

/// Messages to the local-mapping thread.
enum Msg {
    KeyFrame(KfId),
    /// Answered once every keyframe sent before it is processed.
    Flush(Sender<()>),
    Stop,
}

/// Local mapping in its own thread; keyframes arrive through a channel.
pub struct MapperThread {
    tx: Sender<Msg>,
    handle: Option<std::thread::JoinHandle<()>>,
    /// No keyframe is waiting or being processed.
    pub idle: Arc<AtomicBool>,
    /// Keyframes sent and not yet processed.
    pub queued: Arc<AtomicUsize>,
    /// Time per processed keyframe, ms.
    pub times_ms: Arc<Mutex<Vec<f64>>>,
}

/// How local mapping works with loop closing: where each processed keyframe goes next, and
/// the lock local mapping holds while it processes a keyframe (loop correction takes it to
/// stop local mapping between keyframes).
#[derive(Default)]
pub struct MapperHooks {
    /// Where each processed keyframe is sent next (loop closing), if anywhere.
    pub processed: Option<Sender<KfId>>,
    /// Held while a keyframe is processed.
    pub busy: Arc<Mutex<()>>,
}

impl MapperThread {
    /// Start the thread on `map`; each keyframe's time goes to `times_ms`.
    pub fn spawn(
        mapper: LocalMapper,
        map: Arc<SharedMap>,
        times_ms: Arc<Mutex<Vec<f64>>>,
    ) -> std::io::Result<Self> {
        Self::spawn_with_hooks(mapper, map, times_ms, MapperHooks::default())
    }

    /// [`MapperThread::spawn`] feeding loop closing.
    pub fn spawn_with_hooks(
        mapper: LocalMapper,
        map: Arc<SharedMap>,
        times_ms: Arc<Mutex<Vec<f64>>>,
        hooks: MapperHooks,
    ) -> std::io::Result<Self> {
        let (tx, rx): (Sender<Msg>, Receiver<Msg>) = channel();
        let idle = Arc::new(AtomicBool::new(true));
        let queued = Arc::new(AtomicUsize::new(0));
        let (idle2, queued2, times2) = (idle.clone(), queued.clone(), times_ms.clone());
        let handle = std::thread::Builder::new()
            .name("local-mapping".into())
            .spawn(move || {
                stillpoint_core::lower_this_thread_priority(mapper.s.background_nice);
                let mut mapper = mapper;
                loop {
                    let kf = match rx.recv() {
                        Ok(Msg::KeyFrame(kf)) => kf,
                        Ok(Msg::Flush(done)) => {
                            let _ = done.send(());
                            continue;
                        }
                        Ok(Msg::Stop) | Err(_) => break,
                    };
                    idle2.store(false, Ordering::SeqCst);
                    let busy = hooks.busy.lock().unwrap_or_else(|e| e.into_inner());
                    let t0 = Instant::now();
                    mapper.process(&map, kf);
                    if let Ok(mut t) = times2.lock() {
                        t.push(stillpoint_core::ms_since(t0));
                    }
                    drop(busy);
                    if let Some(next) = &hooks.processed {
                        let _ = next.send(kf);
                    }
                    queued2.fetch_sub(1, Ordering::SeqCst);
                    idle2.store(queued2.load(Ordering::SeqCst) == 0, Ordering::SeqCst);
                }
            })?;
        Ok(Self {
            tx,
            handle: Some(handle),
            idle,
            queued,
            times_ms,
        })
    }

    /// Queue keyframe `kf`; false when the thread has stopped.
    pub fn send(&self, kf: KfId) -> bool {
        self.queued.fetch_add(1, Ordering::SeqCst);
        self.idle.store(false, Ordering::SeqCst);
        self.tx.send(Msg::KeyFrame(kf)).is_ok()
    }

    /// Wait until every keyframe sent so far is processed; false when the thread has stopped.
    pub fn wait_for_queue(&self) -> bool {
        let (done, processed) = channel();
        self.tx.send(Msg::Flush(done)).is_ok() && processed.recv().is_ok()
    }

    /// Finish the queued keyframes and stop the thread.
    pub fn finish(&mut self) -> Result<(), crate::SlamError> {
        let _ = self.tx.send(Msg::Stop);
        if let Some(h) = self.handle.take() {
            h.join()
                .map_err(|_| crate::SlamError::LocalMapping("the thread panicked".into()))?;
        }
        Ok(())
    }
}

impl Drop for MapperThread {
    fn drop(&mut self) {
        let _ = self.finish();
    }
}

/// The depth a monocular keyframe's map points have round each part of its image: a quantile
/// (`SlamSettings::new_point_prior_depth_quantile`, the median) per cell of an 8x6 grid, the
/// keyframe's where a cell holds fewer than 5 points (a cell left to the rays alone was
/// measured worse: docs/monocular.md).
pub(crate) struct DepthPrior {
    cells: Vec<f64>,
    cell_w: f64,
    cell_h: f64,
}

impl DepthPrior {
    const COLS: usize = 8;
    const ROWS: usize = 6;

    /// `None` while the keyframe sees no point in front of it. Each cell's depth is the
    /// `quantile` (0 nearest, 0.5 the median) of its points' depths.
    fn of(
        k: &crate::data::KeyFrame,
        points: &std::collections::BTreeMap<crate::data::MpId, crate::data::MapPoint>,
        cam: &stillpoint_geometry::PinholeCamera,
        quantile: f64,
    ) -> Option<Self> {
        let cell_w = (cam.width.max(1) as f64) / Self::COLS as f64;
        let cell_h = (cam.height.max(1) as f64) / Self::ROWS as f64;
        let mut per_cell: Vec<Vec<f64>> = vec![Vec::new(); Self::COLS * Self::ROWS];
        let mut all = Vec::new();
        for (i, mp) in k.map_points.iter().enumerate() {
            let Some(p) = mp.and_then(|mp| points.get(&mp)) else {
                continue;
            };
            let z = (k.pose_cw * nalgebra::Point3::from(p.position)).z;
            if !(z.is_finite() && z > 0.0) {
                continue;
            }
            let kp = k.points[i];
            per_cell[Self::cell(kp.x, kp.y, cell_w, cell_h)].push(z);
            all.push(z);
        }
        let quantile = quantile.clamp(0.0, 1.0);
        let pick = |v: &mut Vec<f64>| {
            v.sort_by(f64::total_cmp);
            // At 0.5 the lower middle of an even count, as the median always was.
            let at = if quantile == 0.5 {
                (v.len() - 1) / 2
            } else {
                ((v.len() - 1) as f64 * quantile).round() as usize
            };
            v[at]
        };
        if all.is_empty() {
            return None;
        }
        let whole = pick(&mut all);
        let cells = per_cell
            .iter_mut()
            .map(|v| if v.len() >= 5 { pick(v) } else { whole })
            .collect();
        Some(Self {
            cells,
            cell_w,
            cell_h,
        })
    }

    fn cell(x: f64, y: f64, cell_w: f64, cell_h: f64) -> usize {
        let col = ((x / cell_w).floor().max(0.0) as usize).min(Self::COLS - 1);
        let row = ((y / cell_h).floor().max(0.0) as usize).min(Self::ROWS - 1);
        row * Self::COLS + col
    }

    /// The depth at pixel `(x, y)`.
    fn at(&self, x: f64, y: f64) -> f64 {
        self.cells[Self::cell(x, y, self.cell_w, self.cell_h)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Descriptor, Feature, Frame, KeypointDepth};
    use stillpoint_geometry::{PinholeCamera, Se3};

    /// `n` descriptors of random bits (a small generator started at `seed`).
    fn random_descriptors(n: usize, mut seed: u64) -> Vec<Descriptor> {
        (0..n)
            .map(|_| {
                std::array::from_fn(|_| {
                    seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
                    (seed >> 56) as u8
                })
            })
            .collect()
    }

    #[test]
    fn keypoints_without_depth_are_triangulated_unless_flagged() {
        let cam = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
        let s = SlamSettings::rgbd(cam, 40.0, 30.0);
        // 20 anchor points (already mapped, they make the two keyframes covisible) and 40 far
        // points without depth; keypoints 20..30 of the new keyframe are flagged no-new-point.
        let points: Vec<Vec3> = (0..60)
            .map(|i| {
                let (x, y) = ((i % 10) as f64 - 4.5, (i / 10) as f64 - 2.5);
                Vec3::new(x * 0.6, y * 0.5, 6.0 + (i % 7) as f64 * 0.5)
            })
            .collect();
        let descriptors = random_descriptors(60, 0x2545_f491_4f6c_dd1d);
        let view = |pose: Se3, flags: &[bool]| {
            let feats: Vec<Feature> = points
                .iter()
                .map(|p| {
                    Feature::at(
                        cam.project_undistorted(&(pose * nalgebra::Point3::from(*p)).coords)
                            .unwrap(),
                    )
                })
                .collect();
            let mut f =
                Frame::new_with_mask(0, 0.0, &feats, &descriptors, None, &s, flags).unwrap();
            f.pose_cw = Some(pose);
            f
        };
        let flags: Vec<bool> = (0..60).map(|i| (20..30).contains(&i)).collect();
        let old = view(Se3::identity(), &[]);
        let new = view(Se3::translation(-0.4, 0.0, 0.0), &flags);
        let mut map = Map::new();
        let k1 = map.add_keyframe(&old).unwrap();
        let k2 = map.add_keyframe(&new).unwrap();
        for (i, p) in points.iter().enumerate().take(20) {
            let mp = map.add_point(*p, k1, i).unwrap();
            map.add_observation(mp, k2, i);
        }
        map.update_connections(k2, 15);
        let mut mapper = LocalMapper::new(s);
        let shared = SharedMap::new(map);
        mapper.create_new_points(&shared, k2);
        let map = shared.lock().unwrap();
        let k = &map.keyframes[&k2];
        for (i, p) in points.iter().enumerate().skip(20) {
            let made = k.map_points[i].map(|mp| map.points[&mp].position);
            if flags[i] {
                assert!(made.is_none(), "flagged keypoint {i} founded a point");
            } else {
                let x = made.unwrap_or_else(|| panic!("keypoint {i} not triangulated"));
                assert!((x - p).norm() < 0.01, "{i}: {x} vs {p}");
            }
        }
        assert_eq!(mapper.recent_points.len(), 30);
    }

    /// A map of one monocular keyframe at the origin that sees a point at each of `pixels`, at
    /// the depth `depth(index, pixel)` gives (camera 500 px, 640x480).
    fn keyframe_seeing(
        pixels: &[(f64, f64)],
        depth: impl Fn(usize, (f64, f64)) -> f64,
    ) -> (Map, KfId, PinholeCamera, SlamSettings) {
        let cam = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
        let s = SlamSettings::monocular(cam, 30.0);
        let feats: Vec<Feature> = pixels
            .iter()
            .map(|&(u, v)| Feature::at(stillpoint_geometry::Vec2::new(u, v)))
            .collect();
        let descriptors = random_descriptors(pixels.len(), 7);
        let mut f = Frame::new_with_mask(0, 0.0, &feats, &descriptors, None, &s, &[]).unwrap();
        f.pose_cw = Some(Se3::identity());
        let mut map = Map::new();
        let kf = map.add_keyframe(&f).unwrap();
        for (i, &(u, v)) in pixels.iter().enumerate() {
            let z = depth(i, (u, v));
            let x = Vec3::new((u - 320.0) / 500.0 * z, (v - 240.0) / 500.0 * z, z);
            map.add_point(x, kf, i).unwrap();
        }
        (map, kf, cam, s)
    }

    /// The depth prior of a keyframe that sees a near wall on its left and a far one on its
    /// right: each cell has its own side's depth, and a cell without points (the bottom row)
    /// the keyframe's median.
    #[test]
    fn the_depth_prior_is_the_depth_of_the_points_round_a_pixel() {
        let pixels: Vec<(f64, f64)> = (0..20)
            .flat_map(|r| (0..32).map(move |c| (10.0 + 20.0 * c as f64, 10.0 + 20.0 * r as f64)))
            .collect();
        let (map, kf, cam, _) =
            keyframe_seeing(&pixels, |_, (u, _)| if u < 240.0 { 2.0 } else { 10.0 });
        let prior = DepthPrior::of(&map.keyframes[&kf], &map.points, &cam, 0.5).unwrap();
        for (u, v, z) in [
            (100.0, 100.0, 2.0),
            (500.0, 100.0, 10.0),
            (100.0, 450.0, 10.0),
        ] {
            assert!(
                (prior.at(u, v) - z).abs() < 1e-9,
                "({u}, {v}): {}",
                prior.at(u, v)
            );
        }
    }

    /// A cell whose points lie at two depths, three near and five far: the median is the far
    /// depth, the lower quartile the near one, so a map whose points in a part of the view are
    /// partly too far still lets new, nearer points be made there.
    #[test]
    fn the_depth_prior_takes_its_quantile_of_a_cell() {
        // Eight keypoints in the top-left cell (80x80 pixels).
        let pixels: Vec<(f64, f64)> = (0..8).map(|i| (10.0 + 8.0 * i as f64, 20.0)).collect();
        let (map, kf, cam, s) = keyframe_seeing(&pixels, |i, _| if i < 3 { 2.0 } else { 10.0 });
        let k = &map.keyframes[&kf];
        let median = DepthPrior::of(k, &map.points, &cam, 0.5).unwrap();
        let quartile = DepthPrior::of(k, &map.points, &cam, 0.25).unwrap();
        assert_eq!(median.at(40.0, 20.0), 10.0);
        assert_eq!(quartile.at(40.0, 20.0), 2.0);
        assert_eq!(s.new_point_prior_depth_quantile, 0.5);
    }

    /// A monocular keyframe with four neighbours that all see the same free points: the first
    /// neighbour to triangulate a keypoint takes it, so the order counts. Split over threads,
    /// the map is the one a single thread makes, to the bit.
    #[test]
    fn triangulation_over_threads_makes_the_single_threads_map() {
        let cam = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
        let points: Vec<Vec3> = (0..140)
            .map(|i| {
                let (x, y) = ((i % 14) as f64 - 6.5, (i / 14) as f64 - 4.5);
                Vec3::new(x * 0.45, y * 0.4, 4.0 + (i % 9) as f64 * 0.5)
            })
            .collect();
        let descriptors = random_descriptors(points.len(), 0x9e37_79b9_7f4a_7c15);
        let poses = [
            Se3::identity(),
            Se3::translation(-0.3, 0.0, 0.0),
            Se3::translation(0.3, 0.05, 0.0),
            Se3::translation(0.0, 0.3, 0.05),
            Se3::translation(-0.2, -0.2, 0.1),
        ];
        let map_with = |threads: usize| {
            let mut s = SlamSettings::monocular(cam, 30.0);
            s.triangulation_threads = threads;
            let mut map = Map::new();
            let kfs: Vec<KfId> = poses
                .iter()
                .enumerate()
                .map(|(n, pose)| {
                    let feats: Vec<Feature> = points
                        .iter()
                        .map(|p| {
                            let pc = (pose * nalgebra::Point3::from(*p)).coords;
                            Feature::at(cam.project_undistorted(&pc).unwrap())
                        })
                        .collect();
                    let mut f =
                        Frame::new_with_mask(n, n as f64, &feats, &descriptors, None, &s, &[])
                            .unwrap();
                    f.pose_cw = Some(*pose);
                    map.add_keyframe(&f).unwrap()
                })
                .collect();
            // The first 40 points are mapped and seen by every keyframe: they connect them.
            for (i, p) in points.iter().enumerate().take(40) {
                let mp = map.add_point(*p, kfs[0], i).unwrap();
                for &k in &kfs[1..] {
                    map.add_observation(mp, k, i);
                }
            }
            for &k in &kfs {
                map.update_connections(k, 15);
            }
            let shared = SharedMap::new(map);
            LocalMapper::new(s).create_new_points(&shared, kfs[0]);
            let map = shared.lock().unwrap();
            kfs.iter()
                .flat_map(|k| map.keyframes[k].map_points.clone())
                .map(|mp| {
                    mp.map(|mp| {
                        let p = &map.points[&mp];
                        let at = p.position.map(f64::to_bits);
                        (mp, at, p.observations.clone())
                    })
                })
                .collect::<Vec<_>>()
        };
        let one = map_with(1);
        let made = one.iter().flatten().count();
        assert!(made > 40 * 5 + 100, "few points triangulated: {made}");
        for threads in [2, 3, 4] {
            assert_eq!(map_with(threads), one, "{threads} threads");
        }
    }

    /// Six keyframes 0.1 s apart that all see the same points: each is redundant with the
    /// others, and culling them one after the other leaves the origin and the two newest.
    /// With `kf_cull_max_gap_s` (stereo / RGB-D) or `kf_cull_max_gap_s_monocular` no two good
    /// keyframes end up further apart than that.
    #[test]
    fn keyframe_culling_leaves_no_gap_longer_than_the_limit() {
        let cam = PinholeCamera::new(500.0, 500.0, 320.0, 240.0, 640, 480);
        let points: Vec<Vec3> = (0..40)
            .map(|i| Vec3::new((i % 8) as f64 * 0.2 - 0.7, (i / 8) as f64 * 0.2 - 0.4, 2.0))
            .collect();
        let depths = vec![2.0f32; points.len()];
        let survivors = |monocular: bool, max_gap_s: f64| {
            let mut s = if monocular {
                SlamSettings::monocular(cam, 30.0)
            } else {
                SlamSettings::rgbd(cam, 40.0, 30.0)
            };
            s.kf_cull_max_gap_s = if monocular { 0.0 } else { max_gap_s };
            s.kf_cull_max_gap_s_monocular = if monocular { max_gap_s } else { 0.0 };
            let feats: Vec<Feature> = points
                .iter()
                .map(|p| Feature::at(cam.project_undistorted(p).unwrap()))
                .collect();
            let descriptors = vec![[0u8; 32]; points.len()];
            let depth = if monocular {
                KeypointDepth::None
            } else {
                KeypointDepth::PerKeypoint(&depths)
            };
            let mut map = Map::new();
            let kfs: Vec<KfId> = (0..6)
                .map(|i| {
                    let t = i as f64 * 0.1;
                    let mut f =
                        Frame::new_with_mask(i, t, &feats, &descriptors, depth, &s, &[]).unwrap();
                    f.pose_cw = Some(Se3::identity());
                    map.add_keyframe(&f).unwrap()
                })
                .collect();
            for (i, p) in points.iter().enumerate() {
                let mp = map.add_point(*p, kfs[0], i).unwrap();
                for k in &kfs[1..] {
                    map.add_observation(mp, *k, i);
                }
            }
            for k in &kfs {
                map.update_connections(*k, 15);
            }
            LocalMapper::new(s).cull_keyframes(&mut map, kfs[5]);
            map.keyframes
                .values()
                .filter(|k| !k.bad)
                .map(|k| k.timestamp)
                .collect::<Vec<f64>>()
        };
        let longest_gap = |t: &[f64]| t.windows(2).map(|w| w[1] - w[0]).fold(0.0, f64::max);
        for monocular in [true, false] {
            let unlimited = survivors(monocular, 0.0);
            assert_eq!(unlimited.len(), 3, "{unlimited:?}");
            assert!(
                (longest_gap(&unlimited) - 0.4).abs() < 1e-9,
                "{unlimited:?}"
            );
            let limited = survivors(monocular, 0.25);
            assert!(longest_gap(&limited) <= 0.25, "{limited:?}");
            assert!(limited.len() < 6, "nothing culled: {limited:?}");
        }
    }
}
