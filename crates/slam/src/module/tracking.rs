//! Tracking (ORB-SLAM3 `Tracking`): initialisation from depth (RGB-D, stereo) or from two views
//! (monocular), constant-velocity motion model, reference-keyframe fallback, local-map tracking,
//! keyframe decision, relocalisation and a new map when relocalisation keeps failing.

use std::collections::{BTreeMap, BTreeSet, HashSet};

use stillpoint_geometry::Se3;
use tracing::{debug, info, warn};

use crate::SlamSettings;
use crate::data::{Frame, KfId, Map, MpId};
use crate::matching::{
    ProjectedPoint, project_in_frustum, search_by_descriptors, search_by_projection_last,
    search_by_projection_local,
};
use crate::module::initializer::MonoInitializer;
use crate::module::loop_closing::MapCorrection;
use crate::optimize::{PoseObservation, optimize_pose};
use crate::solve::{Correspondence, RansacParams, ransac_pnp, ransac_pose};

/// Where tracking stands after a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TrackingState {
    /// Waiting for a frame with enough keypoints with depth (monocular: for two views that
    /// reconstruct).
    NotInitialized,
    /// Tracking: the frame has a pose in the current map.
    Ok,
    /// The last frame(s) could not be tracked; relocalising.
    Lost,
}

/// Fewest descriptor matches to a keyframe worth a pose optimisation (ORB-SLAM's 15: the
/// reference keyframe, relocalisation, and frames before a monocular map stood).
const MIN_DESCRIPTOR_MATCHES: usize = 15;

/// What happened to one frame.
#[derive(Clone, Debug, Default)]
pub struct TrackOutcome {
    /// Camera-to-world pose when tracked.
    pub pose_wc: Option<Se3>,
    /// Map points matched by the final pose optimisation.
    pub inliers: usize,
    /// Per keypoint handed to tracking: matched to a map point and kept by the pose (an
    /// inlier); empty when the frame was not tracked.
    pub matched: Vec<bool>,
    /// The pose inliers (map point, undistorted pixel, virtual right coordinate, octave), for
    /// optimising the frame's pose again once the map around it is refined.
    pub observations: Vec<FrameObservation>,
    /// The keyframe made from this frame, if one was.
    pub new_keyframe: Option<KfId>,
    /// Monocular initialisation makes the reference frame a keyframe too; local mapping takes it
    /// before `new_keyframe`.
    pub first_keyframe: Option<KfId>,
    /// A map was started with this frame.
    pub initialised: bool,
    /// Relocalised in the same map after being lost (by place recognition, or found again
    /// around the last tracked frame).
    pub relocalised: bool,
    /// The map started is a new one (the old one was lost for good).
    pub new_map: bool,
    /// Monocular: the frames offered before the new map stood, tracked in it once it stood
    /// (`MonoInitSettings::backfill_frames`), oldest first, each with its pose inliers (none
    /// for the map's first view, a keyframe).
    pub backfilled: Vec<PosedLate>,
    /// Monocular, a frame tracked while its map is young: the frame itself, to be matched
    /// again to the final map when it settles (`trajectory_settle_rematch_seconds`).
    pub kept_frame: Option<Box<Frame>>,
}

/// A frame tracked late in a new monocular map, with its pose inliers (none for the map's first
/// view, a keyframe) and the frame itself where it is to be matched again when it settles
/// (`trajectory_settle_rematch_seconds`).
pub type PosedLate = (Backfilled, Vec<FrameObservation>, Option<Box<Frame>>);

/// A frame offered before its monocular map stood, tracked in that map afterwards.
#[derive(Clone, Copy, Debug)]
pub struct Backfilled {
    /// Position of the frame in its sequence.
    pub index: usize,
    /// The frame's time (seconds).
    pub timestamp: f64,
    /// Camera-to-world pose.
    pub pose_wc: Se3,
    /// The keyframe it was tracked against.
    pub reference: KfId,
}

impl Backfilled {
    /// Frame `f`, tracked at `pose_cw` against keyframe `reference`, its pose inliers, and
    /// the frame when it is to be `kept`.
    fn of(f: &Frame, pose_cw: Se3, reference: KfId, kept: bool) -> PosedLate {
        let posed = Self {
            index: f.index,
            timestamp: f.timestamp,
            pose_wc: pose_cw.inverse(),
            reference,
        };
        let frame = kept.then(|| Box::new(f.kept_to_match_later()));
        (posed, observations(f, &matched(f, true)), frame)
    }
}

/// A pose for the frame at `at` before two tracked ones, `near` (the nearer) and `far`, as
/// (world-to-camera, time or index): the motion from `far` to `near` carried on back from
/// `near`, at most one such step.
pub(crate) fn carried_back(near: (Se3, f64), far: (Se3, f64), at: f64) -> Se3 {
    let step = near.0 * far.0.inverse();
    let share = ((near.1 - at) / (far.1 - near.1)).min(1.0);
    Se3::identity().lerp_slerp(&step, share) * near.0
}

/// One pose inlier of a tracked frame.
#[derive(Clone, Copy, Debug)]
pub struct FrameObservation {
    /// The map point matched.
    pub point: MpId,
    /// Undistorted pixel, column.
    pub u: f64,
    /// Undistorted pixel, row.
    pub v: f64,
    /// Virtual right coordinate (negative without depth).
    pub u_right: f32,
    /// Pyramid level of the keypoint.
    pub octave: u8,
}

/// The tracking state machine.
pub struct Tracker {
    /// The settings it runs with.
    pub s: SlamSettings,
    /// Where it stands after the last frame.
    pub state: TrackingState,
    last_frame: Option<Frame>,
    /// While lost: the last frame that was tracked, whose matches are searched for from where
    /// it stood before relocalisation is tried (`slam.recover_lost_frames`).
    last_tracked_frame: Option<Frame>,
    /// The motion model when tracking was lost, and the seconds it was measured over.
    velocity_when_lost: Option<(Se3, f64)>,
    /// T_cw(current) * T_wc(last): the constant-velocity model.
    velocity: Option<Se3>,
    /// Seconds between the two frames `velocity` was measured over: a frame after dropped
    /// ones (a live camera, `run --realtime`) scales the model by its own gap.
    velocity_dt: f64,
    reference_kf: Option<KfId>,
    last_kf_frame: usize,
    last_reloc_frame: Option<usize>,
    /// Last successfully tracked world-to-camera pose (seeds a new map).
    last_good_pose: Option<Se3>,
    lost_frames: usize,
    inv_sigma2: Vec<f64>,
    mono_init: MonoInitializer,
    /// Monocular: relocalisation kept failing and the next initialisation starts a new map.
    new_map_pending: bool,
    /// Localisation only: track against the map without changing it (no keyframes, no
    /// points, no counters, no new map when lost).
    localize: bool,
    /// Keyframes place recognition proposes for the next relocalisation, best first.
    reloc_candidates: Vec<KfId>,
    /// Monocular: the frame the current map was initialised at.
    pub map_started_at: Option<usize>,
    /// Map points the last frame's pose kept (0 when it was not tracked).
    pub last_inliers: usize,
    /// Monocular: frames offered before a map stood that its first two views could not track
    /// (`MonoInitSettings::place_before_map_at_end`), kept to be placed in the map the run
    /// ends with; the newest `MonoInitSettings::backfill_frames` at most.
    unplaced: Vec<Frame>,
}

impl Tracker {
    /// A tracker waiting for its first map.
    pub fn new(s: SlamSettings) -> Self {
        let inv_sigma2 = s.inv_level_sigma2();
        Self {
            s,
            state: TrackingState::NotInitialized,
            last_frame: None,
            last_tracked_frame: None,
            velocity_when_lost: None,
            velocity: None,
            velocity_dt: 0.0,
            reference_kf: None,
            last_kf_frame: 0,
            last_reloc_frame: None,
            last_good_pose: None,
            lost_frames: 0,
            inv_sigma2,
            mono_init: MonoInitializer::default(),
            new_map_pending: false,
            localize: false,
            reloc_candidates: Vec::new(),
            map_started_at: None,
            last_inliers: 0,
            unplaced: Vec::new(),
        }
    }

    /// A tracker for a map loaded from a file: lost (it relocalises first, into that map);
    /// with `localize` it never changes the map.
    pub fn for_loaded_map(s: SlamSettings, localize: bool) -> Self {
        Self {
            state: TrackingState::Lost,
            localize,
            ..Self::new(s)
        }
    }

    /// Keyframes to try first at the next relocalisation (bag-of-words candidates).
    pub fn set_relocalisation_candidates(&mut self, candidates: Vec<KfId>) {
        self.reloc_candidates = candidates;
    }

    /// Track one frame against the map. `mapper_idle` and `mapper_queue` come from local mapping
    /// (keyframe decision).
    pub fn track(
        &mut self,
        frame: Frame,
        map: &mut Map,
        mapper_idle: bool,
        mapper_queue: usize,
    ) -> TrackOutcome {
        let out = self.track_frame(frame, map, mapper_idle, mapper_queue);
        self.last_inliers = if out.pose_wc.is_some() {
            out.inliers
        } else {
            0
        };
        out
    }

    fn track_frame(
        &mut self,
        mut frame: Frame,
        map: &mut Map,
        mapper_idle: bool,
        mapper_queue: usize,
    ) -> TrackOutcome {
        let mut out = TrackOutcome::default();
        let back_in_lost_map = self.state == TrackingState::NotInitialized
            && self.new_map_pending
            && self.relocalise_in_lost_map(&mut frame, map, &mut out);
        let ok = match self.state {
            _ if back_in_lost_map => true,
            TrackingState::NotInitialized => {
                let origin = self.last_good_pose.unwrap_or_else(Se3::identity);
                // Monocular maps start from two keyframes (the reference one comes first).
                let started = if self.s.monocular {
                    self.initialise_monocular(&mut frame, map, origin)
                        .map(|(first, kf, between)| (Some(first), kf, between))
                } else {
                    self.initialise(&mut frame, map, origin)
                        .map(|kf| (None, kf, Vec::new()))
                };
                if let Some((first, kf, between)) = started {
                    out.initialised = true;
                    out.backfilled = between;
                    if first.is_some() {
                        out.new_map = std::mem::take(&mut self.new_map_pending);
                    }
                    out.first_keyframe = first;
                    out.new_keyframe = Some(kf);
                    out.pose_wc = frame.pose_cw.map(|p| p.inverse());
                    out.inliers = frame.map_points.iter().flatten().count();
                    out.matched = matched(&frame, true);
                    out.observations = observations(&frame, &out.matched);
                    self.finish_frame(frame, true);
                    return out;
                }
                false
            }
            TrackingState::Ok => {
                let mut ok = false;
                let mut by_motion = false;
                if self.velocity.is_some() && self.last_frame.is_some() {
                    ok = self.track_motion_model(&mut frame, map);
                    by_motion = ok;
                }
                if !ok {
                    ok = self.track_reference_keyframe(&mut frame, map);
                }
                if !ok && self.velocity.is_none() && self.last_frame.is_some() {
                    // Just relocalised, no velocity yet, and too few descriptor matches to the
                    // reference keyframe (a person filling a monocular view): the last frame's
                    // matches, projected from where it stood (ours).
                    ok = self.track_with_motion(&mut frame, map, Se3::identity());
                    by_motion = ok;
                }
                ok && {
                    let n = self.track_local_map(&mut frame, map);
                    out.inliers = n;
                    debug!(
                        frame = frame.index,
                        by_motion,
                        inliers = n,
                        "tracked against the local map"
                    );
                    self.local_map_ok(&frame, n)
                }
            }
            TrackingState::Lost => {
                self.recover_from_last_tracked(&mut frame, map, &mut out)
                    || self.relocalise_and_track_local_map(&mut frame, map, &mut out)
            }
        };
        if ok {
            self.state = TrackingState::Ok;
            self.lost_frames = 0;
            if let (Some(cur), Some(last)) = (
                frame.pose_cw,
                self.last_frame.as_ref().and_then(|l| l.pose_cw),
            ) {
                let mut v = cur * last.inverse();
                v.rotation.renormalize();
                self.velocity = Some(v);
                self.velocity_dt = frame.timestamp
                    - self
                        .last_frame
                        .as_ref()
                        .map_or(frame.timestamp, |l| l.timestamp);
            }
            if !self.localize
                && self.need_new_keyframe(&frame, map, out.inliers, mapper_idle, mapper_queue)
            {
                out.new_keyframe = self.create_keyframe(&mut frame, map);
            }
            out.pose_wc = frame.pose_cw.map(|p| p.inverse());
        } else if self.state != TrackingState::NotInitialized {
            if self.state == TrackingState::Ok {
                warn!(frame = frame.index, "tracking lost; relocalising");
                self.velocity_when_lost = self.velocity.map(|v| (v, self.velocity_dt));
            }
            self.state = TrackingState::Lost;
            self.velocity = None;
            self.lost_frames += 1;
            if self.localize {
                // The loaded map is all there is: keep relocalising in it.
            } else if self.s.monocular && self.lost_frames > self.s.new_map_after_lost_frames {
                // Relocalisation kept failing: initialise again from two views, into a new map
                // (at its own scale).
                warn!(
                    frame = frame.index,
                    "monocular tracking lost for good: initialising a new map"
                );
                self.state = TrackingState::NotInitialized;
                self.new_map_pending = true;
                self.mono_init.reset();
            } else if self.lost_frames > self.s.new_map_after_lost_frames {
                let origin = self.last_good_pose.unwrap_or_else(Se3::identity);
                frame.map_points.iter_mut().for_each(|m| *m = None);
                if self.can_initialise(&frame) {
                    map.start_new_map();
                    if let Some(kf) = self.initialise(&mut frame, map, origin) {
                        warn!(
                            frame = frame.index,
                            epoch = map.epoch,
                            "relocalisation kept failing: started a new map at the last known pose"
                        );
                        out.new_map = true;
                        out.new_keyframe = Some(kf);
                        out.pose_wc = frame.pose_cw.map(|p| p.inverse());
                        out.matched = matched(&frame, true);
                        out.observations = observations(&frame, &out.matched);
                        self.finish_frame(frame, true);
                        return out;
                    }
                }
            }
        }
        out.matched = matched(&frame, ok);
        out.observations = observations(&frame, &out.matched);
        if ok && self.map_is_young_for_settling(frame.index) {
            out.kept_frame = Some(Box::new(frame.kept_to_match_later()));
        }
        self.finish_frame(frame, ok);
        out
    }

    /// Monocular: frame `index` comes within `trajectory_settle_rematch_seconds` of its map's
    /// start.
    fn map_is_young_for_settling(&self, index: usize) -> bool {
        self.keeps_frames_to_match_again()
            && self.within_seconds_of_map_start(index, self.s.trajectory_settle_rematch_seconds)
    }

    /// Whether frame `index` comes less than `seconds` (at the settings' frame rate) after the
    /// current map started; false without a map.
    pub fn within_seconds_of_map_start(&self, index: usize, seconds: f64) -> bool {
        self.map_started_at
            .is_some_and(|start| (index.saturating_sub(start) as f64) < seconds * self.s.fps)
    }

    /// Monocular with `trajectory_settle_rematch_seconds` on: a young map's frames, and those
    /// tracked before it stood, are kept to be matched again when they settle.
    fn keeps_frames_to_match_again(&self) -> bool {
        self.s.monocular && self.s.trajectory_settle_rematch_seconds * self.s.fps > 0.0
    }

    /// Match `frame` again, at `pose`, to the points of the keyframes that see `around` and
    /// of their best covisible ones (in the current map), in the local-map search's windows:
    /// what a frame tracked in a young map could not see yet. Returns the matches.
    pub fn rematch(
        &self,
        frame: &mut Frame,
        map: &Map,
        pose: &Se3,
        around: &[MpId],
    ) -> Vec<FrameObservation> {
        let local = self.keyframes_seeing(map, around);
        // The current map's: a frame of a map that never merged keeps the points it saw.
        let projected = self.points_in_view(map, &local, pose, &BTreeSet::new());
        frame.ready_to_match(*pose);
        search_by_projection_local(frame, &projected, map, self.s.local_map_search_th, &self.s);
        let all: Vec<bool> = frame.map_points.iter().map(Option::is_some).collect();
        observations(frame, &all)
    }

    /// Whether the next frame relocalises (and so wants place recognition's candidates): lost,
    /// or monocular and initialising a new map after the old one was lost, which the camera may
    /// come back to before the new map has started.
    pub fn is_relocalising(&self) -> bool {
        self.state == TrackingState::Lost
            || (self.state == TrackingState::NotInitialized && self.new_map_pending)
    }

    fn relocalise_and_track_local_map(
        &mut self,
        frame: &mut Frame,
        map: &mut Map,
        out: &mut TrackOutcome,
    ) -> bool {
        if !self.relocalise(frame, map) {
            return false;
        }
        let lost_map = map.epoch;
        let found_in = self
            .reference_kf
            .and_then(|r| map.keyframes.get(&r))
            .map_or(lost_map, |k| k.map_epoch);
        map.reactivate(found_in);
        let n = self.track_local_map(frame, map);
        out.inliers = n;
        let ok = self.local_map_ok(frame, n);
        if ok {
            info!(frame = frame.index, inliers = n, "relocalised");
            if found_in != lost_map {
                info!(
                    frame = frame.index,
                    map = found_in,
                    epoch = map.epoch,
                    "relocalised in an older map: it is the current map again"
                );
            }
            out.relocalised = true;
            self.last_reloc_frame = Some(frame.index);
        } else if found_in != lost_map {
            // The map that was lost stays the current one.
            map.reactivate(lost_map);
        }
        ok
    }

    /// Lost for at most `slam.recover_lost_frames` frames (ours; ORB-SLAM relocalises at once):
    /// the points of the keyframes around the last tracked frame are searched for from where
    /// its motion would put the camera, then from where it stood, in windows
    /// `slam.recover_search_th` times the local map's, and the frame is tracked if the local
    /// map then gives `slam.recover_min_inliers`. Once a person who filled a monocular view
    /// for a few frames has passed, the room is where it was, while place recognition may need
    /// many frames to find a keyframe again.
    fn recover_from_last_tracked(
        &mut self,
        frame: &mut Frame,
        map: &mut Map,
        out: &mut TrackOutcome,
    ) -> bool {
        if self.localize || self.lost_frames >= self.s.recover_lost_frames {
            return false;
        }
        let Some(last) = self.last_tracked_frame.take() else {
            return false;
        };
        // Where the camera would be had it kept the motion it had, then where it was.
        let predicted = self.velocity_when_lost.and_then(|(v, dt)| {
            let v = stillpoint_geometry::motion_over_gap(&v, dt, frame.timestamp - last.timestamp);
            last.pose_cw.map(|p| v * p)
        });
        let found = predicted.into_iter().chain(last.pose_cw).any(|pose| {
            frame.pose_cw = Some(pose);
            frame.map_points.iter_mut().for_each(|m| *m = None);
            let projected = self.local_points_seen_from(&last, map, &pose);
            let n = search_by_projection_local(
                frame,
                &projected,
                map,
                self.s.recover_search_th,
                &self.s,
            );
            debug!(
                frame = frame.index,
                projected = projected.len(),
                matches = n,
                "searched from the last tracked frame"
            );
            n >= self.s.motion_min_matches && {
                self.optimize_frame(frame, map);
                Self::discard_outliers(frame, map) >= 10
            }
        });
        let ok = found && {
            let n = self.track_local_map(frame, map);
            out.inliers = n;
            n >= self.s.recover_min_inliers
        };
        if ok {
            info!(
                frame = frame.index,
                inliers = out.inliers,
                lost_frames = self.lost_frames,
                "found again from the last tracked frame"
            );
            out.relocalised = true;
        } else {
            debug!(
                frame = frame.index,
                found,
                inliers = out.inliers,
                "not found from the last tracked frame"
            );
            frame.pose_cw = None;
            frame.map_points.iter_mut().for_each(|m| *m = None);
            out.inliers = 0;
            self.last_tracked_frame = Some(last);
        }
        ok
    }

    /// The points of the keyframes that share `frame`'s matches and their best covisibles,
    /// in the current map, that project into a camera at `pose`.
    fn local_points_seen_from(&self, frame: &Frame, map: &Map, pose: &Se3) -> Vec<ProjectedPoint> {
        let local = self.keyframes_seeing(map, frame.map_points.iter().flatten());
        self.points_in_view(map, &local, pose, &BTreeSet::new())
    }

    /// The keyframes that see `points`, and their best covisible ones.
    fn keyframes_seeing<'a>(
        &self,
        map: &Map,
        points: impl IntoIterator<Item = &'a MpId>,
    ) -> BTreeSet<KfId> {
        let mut local: BTreeSet<KfId> = BTreeSet::new();
        for mp in points {
            if let Some(p) = map.points.get(mp) {
                local.extend(p.observations.keys().copied());
            }
        }
        let first: Vec<KfId> = local.iter().copied().collect();
        for k in first {
            if let Some(kf) = map.keyframes.get(&k) {
                local.extend(kf.best_covisibles(self.s.local_neighbours));
            }
        }
        local
    }

    /// The points of the `local` keyframes of the current map that project into a camera at
    /// `pose`, each once, but those in `skip`.
    fn points_in_view(
        &self,
        map: &Map,
        local: &BTreeSet<KfId>,
        pose: &Se3,
        skip: &BTreeSet<MpId>,
    ) -> Vec<ProjectedPoint> {
        let center = pose.inverse().translation.vector;
        // Only asked whether a point came before (the order is the keyframes'): a hash set,
        // not a tree, for the ten thousand points of a local map each frame.
        let mut seen: HashSet<MpId> = HashSet::with_capacity(
            local
                .iter()
                .filter_map(|k| map.keyframes.get(k))
                .map(|kf| kf.map_points.len())
                .sum(),
        );
        let mut projected = Vec::new();
        for k in local {
            let Some(kf) = map.keyframes.get(k) else {
                continue;
            };
            if kf.bad || kf.map_epoch != map.epoch {
                continue;
            }
            for mp in kf.map_points.iter().flatten() {
                if skip.contains(mp) || !seen.insert(*mp) {
                    continue;
                }
                if let Some(pp) = project_in_frustum(map, *mp, pose, &center, &self.s) {
                    projected.push(pp);
                }
            }
        }
        projected
    }

    /// Monocular, a new map pending: the lost map is still the current one until the new map
    /// starts, so a frame that relocalises in it goes on there and the new map is dropped.
    fn relocalise_in_lost_map(
        &mut self,
        frame: &mut Frame,
        map: &mut Map,
        out: &mut TrackOutcome,
    ) -> bool {
        if !self.s.relocalise_while_initialising
            || !self.relocalise_and_track_local_map(frame, map, out)
        {
            return false;
        }
        self.new_map_pending = false;
        self.mono_init.reset();
        true
    }

    fn finish_frame(&mut self, mut frame: Frame, ok: bool) {
        if ok {
            self.last_tracked_frame = None;
            self.last_good_pose = frame.pose_cw;
            for (m, o) in frame.map_points.iter_mut().zip(&frame.outliers) {
                if *o {
                    *m = None;
                }
            }
            self.last_frame = Some(frame);
        } else {
            frame.pose_cw = None;
            if let Some(last) = self.last_frame.take() {
                self.last_tracked_frame = Some(last);
            }
        }
    }

    /// Enough keypoints, and enough with depth, to start a map.
    fn can_initialise(&self, frame: &Frame) -> bool {
        frame.len() > self.s.init_min_keypoints
            && frame.with_depth() >= self.s.init_min_with_depth
            && cells_with_depth(frame, &self.s.camera) >= self.s.init_min_cells_with_depth
    }

    /// RGB-D / stereo initialisation: every keypoint with depth becomes a map point of the first
    /// keyframe.
    fn initialise(&mut self, frame: &mut Frame, map: &mut Map, origin_cw: Se3) -> Option<KfId> {
        if !self.can_initialise(frame) {
            debug!(
                frame = frame.index,
                keypoints = frame.len(),
                with_depth = frame.with_depth(),
                "not enough keypoints (with depth) to initialise"
            );
            return None;
        }
        frame.pose_cw = Some(origin_cw);
        let kf = map.add_keyframe(frame)?;
        let scales = self.s.scale_factors();
        for i in 0..frame.len() {
            if !frame.no_new_point[i]
                && let Some(pw) = frame.unproject_world(i, &self.s.camera)
                && let Some(mp) = map.add_point(pw, kf, i)
            {
                map.update_point(mp, &scales);
                frame.map_points[i] = Some(mp);
            }
        }
        info!(
            frame = frame.index,
            points = map.points.len(),
            epoch = map.epoch,
            "map initialised"
        );
        self.start_tracking_from(kf, frame.index);
        Some(kf)
    }

    /// A new map's first keyframe `kf` (frame `frame_index`) is where tracking goes on from.
    fn start_tracking_from(&mut self, kf: KfId, frame_index: usize) {
        self.state = TrackingState::Ok;
        self.reference_kf = Some(kf);
        self.last_kf_frame = frame_index;
        self.velocity = None;
        self.lost_frames = 0;
    }

    /// Monocular initialisation: the frame goes to the two-view initialiser; once it reconstructs,
    /// the reference frame and this one become the first two keyframes of a map (a new one when
    /// the current map has keyframes) at `origin_cw`, and the triangulated points its points.
    /// Returns (reference keyframe, current keyframe, the frames between tracked in the map).
    fn initialise_monocular(
        &mut self,
        frame: &mut Frame,
        map: &mut Map,
        origin_cw: Se3,
    ) -> Option<(KfId, KfId, Vec<PosedLate>)> {
        let mut init = self.mono_init.add_frame(frame, &self.s)?;
        if map.current_keyframes().next().is_some() {
            map.start_new_map();
        }
        let mut reference = init.reference;
        for f in [&mut reference, &mut *frame] {
            f.map_points.iter_mut().for_each(|m| *m = None);
            f.outliers.iter_mut().for_each(|o| *o = false);
        }
        reference.pose_cw = Some(origin_cw);
        frame.pose_cw = Some(init.pose21 * origin_cw);
        let first = map.add_keyframe(&reference)?;
        let kf = map.add_keyframe(frame)?;
        let origin_wc = origin_cw.inverse();
        let scales = self.s.scale_factors();
        for p in &init.points {
            let world = (origin_wc * nalgebra::Point3::from(p.position)).coords;
            if let Some(mp) = map.add_point(world, kf, p.keypoint) {
                map.add_observation(mp, first, p.reference_keypoint);
                map.update_point(mp, &scales);
                frame.map_points[p.keypoint] = Some(mp);
            }
        }
        map.update_connections(first, self.s.covisibility_min_shared);
        map.update_connections(kf, self.s.covisibility_min_shared);
        info!(
            frame = frame.index,
            reference = reference.index,
            model = ?init.model,
            parallax_deg = init.parallax_deg,
            points = init.points.len(),
            epoch = map.epoch,
            "monocular map initialised"
        );
        let second = (init.pose21 * origin_cw, frame.index);
        let between = self.track_between(
            std::mem::take(&mut init.between),
            &reference,
            map,
            [first, kf],
            second,
        );
        let (mut tracked, unplaced) = self.track_before(
            std::mem::take(&mut init.before),
            &between,
            second,
            map,
            [first, kf],
        );
        if self.s.mono_init.place_before_map_at_end {
            self.unplaced
                .extend(unplaced.iter().map(Frame::kept_to_match_later));
            // As many as the initialiser keeps, the newest: a long live run that starts
            // several maps holds no more.
            let over = self
                .unplaced
                .len()
                .saturating_sub(self.s.mono_init.backfill_frames);
            self.unplaced.sort_by_key(|f| f.index);
            self.unplaced.drain(..over);
        }
        tracked.extend(between);
        let between = tracked;
        if let Some((b, ..)) = between.first() {
            info!(
                frames = between.len(),
                first = b.index,
                "frames before the monocular map stood tracked in it"
            );
        }
        self.start_tracking_from(kf, frame.index);
        self.map_started_at = Some(frame.index);
        Some((first, kf, between))
    }

    /// The first view of a new monocular map (its first keyframe) and the frames offered
    /// between its two views, tracked in it: the initial points projected from a pose between
    /// the last frame tracked and the second view's (by frame index) and matched in wide
    /// windows (as after a relocalisation), else matched to the nearer keyframe's points; then
    /// pose optimisation and a second, narrow projection; kept with as many inliers as a
    /// tracked frame.
    fn track_between(
        &self,
        frames: Vec<Frame>,
        first_view: &Frame,
        map: &Map,
        kfs: [KfId; 2],
        second: (Se3, usize),
    ) -> Vec<PosedLate> {
        if self.s.mono_init.backfill_frames == 0 {
            return Vec::new();
        }
        let (cw1, i1) = (
            first_view.pose_cw.unwrap_or_else(Se3::identity),
            first_view.index,
        );
        let (cw2, i2) = second;
        let first = Backfilled {
            index: i1,
            timestamp: first_view.timestamp,
            pose_wc: cw1.inverse(),
            reference: kfs[0],
        };
        let mut out = vec![(first, Vec::new(), None)];
        let kept = self.keeps_frames_to_match_again();
        let points = Self::points_of(map, &kfs);
        let (mut last_cw, mut last_index) = (cw1, i1);
        for mut f in frames {
            if f.index <= last_index || f.index >= i2 {
                continue;
            }
            let t = (f.index - last_index) as f64 / (i2 - last_index) as f64;
            let nearer = if f.index - i1 <= i2 - f.index {
                kfs[0]
            } else {
                kfs[1]
            };
            let inliers = self.track_in_first_views(
                &mut f,
                last_cw.lerp_slerp(&cw2, t),
                &points,
                map,
                nearer,
            );
            if inliers >= self.s.min_tracked_inliers
                && let Some(pose) = f.pose_cw
            {
                out.push(Backfilled::of(&f, pose, nearer, kept));
                (last_cw, last_index) = (pose, f.index);
            }
        }
        out
    }

    /// Monocular: the frames offered before the new map's first view (earlier references that
    /// were dropped for too few matches, and their frames), tracked in it newest first from the
    /// first view back, each from the pose the motion of the two frames after it gives, until
    /// one does not track (the view it came from is not the map's); returned oldest first,
    /// with the frames before that were not tracked. `later` is what `track_between` returned
    /// (the first view first).
    fn track_before(
        &self,
        frames: Vec<Frame>,
        later: &[PosedLate],
        second: (Se3, usize),
        map: &Map,
        kfs: [KfId; 2],
    ) -> (Vec<PosedLate>, Vec<Frame>) {
        let Some((first_view, ..)) = later.first() else {
            return (Vec::new(), Vec::new());
        };
        let kept = self.keeps_frames_to_match_again();
        let points = Self::points_of(map, &kfs);
        // The two tracked frames nearest after the next one to track: (pose, index).
        let mut near = (first_view.pose_wc.inverse(), first_view.index);
        let mut far = later
            .get(1)
            .map_or(second, |(b, ..)| (b.pose_wc.inverse(), b.index));
        let mut out = Vec::new();
        let mut untracked = Vec::new();
        let mut newest_first = frames.into_iter().rev();
        for mut f in newest_first.by_ref() {
            if f.index >= near.1 {
                continue;
            }
            let prior = carried_back(
                (near.0, near.1 as f64),
                (far.0, far.1 as f64),
                f.index as f64,
            );
            let inliers = self.track_in_first_views(&mut f, prior, &points, map, kfs[0]);
            let Some(pose) = f.pose_cw.filter(|_| inliers >= self.s.min_tracked_inliers) else {
                untracked.push(f);
                break;
            };
            out.push(Backfilled::of(&f, pose, kfs[0], kept));
            (far, near) = (near, (pose, f.index));
        }
        untracked.extend(newest_first);
        out.reverse();
        (out, untracked)
    }

    /// Monocular: the frames offered before a map stood that its first two views could not
    /// track, newest first, to be placed in the map the run ends with
    /// ([`Tracker::place_late`]); the tracker keeps none after.
    pub fn take_unplaced(&mut self) -> Vec<Frame> {
        let mut frames = std::mem::take(&mut self.unplaced);
        frames.sort_by_key(|f| std::cmp::Reverse(f.index));
        frames
    }

    /// A frame kept by [`Frame::kept_to_match_later`], tracked at the end of the run from
    /// `prior` in the map as it ended: the points of `reference`'s neighbourhood (the
    /// keyframes that see its points and their best covisible ones) projected in wide windows,
    /// pose optimisation, a narrow projection and pose optimisation again. The pose, when it
    /// keeps as many inliers as a tracked frame.
    pub fn place_late(
        &self,
        frame: &mut Frame,
        prior: Se3,
        reference: KfId,
        map: &Map,
    ) -> Option<Se3> {
        let seen: Vec<MpId> = map
            .keyframes
            .get(&reference)?
            .map_points
            .iter()
            .flatten()
            .copied()
            .collect();
        let points = Self::points_of(map, &Vec::from_iter(self.keyframes_seeing(map, &seen)));
        frame.ready_to_match(prior);
        if self.project_points(frame, &points, map, 5.0) < MIN_DESCRIPTOR_MATCHES {
            return None;
        }
        self.optimize_frame(frame, map);
        Self::discard_outliers(frame, map);
        self.project_points(frame, &points, map, self.s.local_map_search_th);
        let inliers = self.optimize_frame(frame, map);
        debug!(
            frame = frame.index,
            inliers, "frame before its map stood, placed at the end"
        );
        frame
            .pose_cw
            .filter(|_| inliers >= self.s.min_tracked_inliers)
    }

    /// The map points keyframes `kfs` see.
    fn points_of(map: &Map, kfs: &[KfId]) -> BTreeSet<MpId> {
        kfs.iter()
            .filter_map(|k| map.keyframes.get(k))
            .flat_map(|k| k.map_points.iter().flatten().copied())
            .collect()
    }

    /// A frame offered before a new monocular map stood, tracked in its first two views from
    /// `prior`: `points` projected and matched in wide windows (as after a relocalisation),
    /// else matched to keyframe `nearer`'s points; then pose optimisation and a second, narrow
    /// projection. Returns the inliers.
    fn track_in_first_views(
        &self,
        f: &mut Frame,
        prior: Se3,
        points: &BTreeSet<MpId>,
        map: &Map,
        nearer: KfId,
    ) -> usize {
        f.map_points.iter_mut().for_each(|m| *m = None);
        f.outliers.iter_mut().for_each(|o| *o = false);
        f.pose_cw = Some(prior);
        let mut matches = self.project_points(f, points, map, 5.0);
        if matches < self.s.motion_min_matches {
            f.map_points.iter_mut().for_each(|m| *m = None);
            matches = search_by_descriptors(
                f,
                &map.keyframes[&nearer],
                map,
                self.s.ref_kf_ratio,
                self.s.th_low,
            );
        }
        let mut inliers = 0;
        if matches >= MIN_DESCRIPTOR_MATCHES {
            self.optimize_frame(f, map);
            Self::discard_outliers(f, map);
            self.project_points(f, points, map, self.s.local_map_search_th);
            inliers = self.optimize_frame(f, map);
        }
        debug!(
            frame = f.index,
            matches, inliers, "frame before the map stood"
        );
        inliers
    }

    /// Project `points` into `frame` from its pose and match them in windows of `th` (as
    /// tracking the local map does); returns the frame's matches.
    fn project_points(
        &self,
        frame: &mut Frame,
        points: &BTreeSet<MpId>,
        map: &Map,
        th: f64,
    ) -> usize {
        let Some(pose) = frame.pose_cw else {
            return 0;
        };
        let center = pose.inverse().translation.vector;
        let taken: BTreeSet<MpId> = frame.map_points.iter().flatten().copied().collect();
        let projected: Vec<_> = points
            .iter()
            .filter(|mp| !taken.contains(mp))
            .filter_map(|&mp| project_in_frustum(map, mp, &pose, &center, &self.s))
            .collect();
        search_by_projection_local(frame, &projected, map, th, &self.s);
        frame.map_points.iter().flatten().count()
    }

    /// Pose optimisation over the frame's matches; marks outliers, returns the inlier count.
    fn optimize_frame(&self, frame: &mut Frame, map: &Map) -> usize {
        let Some(mut pose) = frame.pose_cw else {
            return 0;
        };
        let mut idx = Vec::new();
        let mut obs = Vec::new();
        for (i, mp) in frame.map_points.iter().enumerate() {
            let Some(p) = mp.and_then(|m| map.points.get(&m)) else {
                continue;
            };
            idx.push(i);
            obs.push(PoseObservation {
                world: p.position,
                u: frame.points[i].x,
                v: frame.points[i].y,
                u_right: (frame.u_right[i] > 0.0).then_some(frame.u_right[i] as f64),
                inv_sigma2: self.inv_sigma2[frame.octaves[i] as usize],
            });
        }
        if obs.len() < 3 {
            return 0;
        }
        let outliers = optimize_pose(&mut pose, &obs, &self.s);
        frame.pose_cw = Some(pose);
        let mut inliers = 0;
        for (k, &i) in idx.iter().enumerate() {
            frame.outliers[i] = outliers[k];
            if !outliers[k] {
                inliers += 1;
            }
        }
        inliers
    }

    /// Drop outlier matches; count matches to points that are in the map.
    fn discard_outliers(frame: &mut Frame, map: &Map) -> usize {
        let mut n = 0;
        for i in 0..frame.len() {
            if frame.outliers[i] {
                frame.map_points[i] = None;
                frame.outliers[i] = false;
            } else if frame.map_points[i].is_some_and(|m| map.points.contains_key(&m)) {
                n += 1;
            }
        }
        n
    }

    fn track_motion_model(&mut self, frame: &mut Frame, map: &Map) -> bool {
        let (Some(last), Some(v)) = (self.last_frame.as_ref(), self.velocity) else {
            return false;
        };
        let v = stillpoint_geometry::motion_over_gap(
            &v,
            self.velocity_dt,
            frame.timestamp - last.timestamp,
        );
        self.track_with_motion(frame, map, v)
    }

    /// The last frame's matches projected into `frame` from `motion` times the last pose, in
    /// windows of the motion model's radius (twice it when too few), then pose optimisation.
    fn track_with_motion(&mut self, frame: &mut Frame, map: &Map, motion: Se3) -> bool {
        let Some(last) = self.last_frame.as_ref() else {
            return false;
        };
        let Some(last_pose) = last.pose_cw else {
            return false;
        };
        frame.pose_cw = Some(motion * last_pose);
        frame.map_points.iter_mut().for_each(|m| *m = None);
        let r = self.s.motion_search_radius;
        let mut n = search_by_projection_last(frame, last, map, r, &self.s);
        if n < self.s.motion_min_matches {
            frame.map_points.iter_mut().for_each(|m| *m = None);
            n = search_by_projection_last(frame, last, map, 2.0 * r, &self.s);
        }
        if n < self.s.motion_min_matches {
            debug!(
                frame = frame.index,
                matches = n,
                "motion model: too few matches"
            );
            return false;
        }
        self.optimize_frame(frame, map);
        Self::discard_outliers(frame, map) >= 10
    }

    fn track_reference_keyframe(&mut self, frame: &mut Frame, map: &Map) -> bool {
        let Some(kf) = self.valid_reference(map) else {
            return false;
        };
        frame.pose_cw = self
            .last_frame
            .as_ref()
            .and_then(|l| l.pose_cw)
            .or(Some(map.keyframes[&kf].pose_cw));
        frame.map_points.iter_mut().for_each(|m| *m = None);
        let n = search_by_descriptors(
            frame,
            &map.keyframes[&kf],
            map,
            self.s.ref_kf_ratio,
            self.s.th_low,
        );
        if n < MIN_DESCRIPTOR_MATCHES {
            debug!(
                frame = frame.index,
                matches = n,
                "reference keyframe: too few matches"
            );
            return false;
        }
        self.optimize_frame(frame, map);
        Self::discard_outliers(frame, map) >= 10
    }

    /// The reference keyframe, or the newest good keyframe of the current map when it was culled.
    fn valid_reference(&mut self, map: &Map) -> Option<KfId> {
        if let Some(k) = self.reference_kf
            && map
                .keyframes
                .get(&k)
                .is_some_and(|k| !k.bad && k.map_epoch == map.epoch)
        {
            return Some(k);
        }
        self.reference_kf = map.current_keyframes().last().map(|k| k.id);
        self.reference_kf
    }

    /// Local keyframes (those seeing the frame's points, their best covisibles, parents and
    /// children) and their points, projected and matched; then pose optimisation.
    fn track_local_map(&mut self, frame: &mut Frame, map: &mut Map) -> usize {
        let mut counts: BTreeMap<KfId, usize> = BTreeMap::new();
        for mp in frame.map_points.iter().flatten() {
            if let Some(p) = map.points.get(mp) {
                for &k in p.observations.keys() {
                    *counts.entry(k).or_default() += 1;
                }
            }
        }
        counts.retain(|k, _| map.keyframes.get(k).is_some_and(|k| !k.bad));
        if let Some((&best, _)) = counts.iter().max_by_key(|(_, c)| **c) {
            self.reference_kf = Some(best);
        }
        let mut local: BTreeSet<KfId> = counts.keys().copied().collect();
        let first: Vec<KfId> = local.iter().copied().collect();
        for k in first {
            if local.len() >= 80 {
                break;
            }
            let Some(kf) = map.keyframes.get(&k) else {
                continue;
            };
            for n in kf.best_covisibles(self.s.local_neighbours) {
                local.insert(n);
            }
            local.extend(kf.children.iter().copied());
            if let Some(p) = kf.parent {
                local.insert(p);
            }
        }
        // Localisation leaves the map's counters (and so its culling) as they were.
        let count = !self.localize;
        let mut in_frame: BTreeSet<MpId> = BTreeSet::new();
        for mp in frame.map_points.iter().flatten() {
            in_frame.insert(*mp);
            if count && let Some(p) = map.points.get_mut(mp) {
                p.visible += 1;
            }
        }
        let Some(pose) = frame.pose_cw else {
            return 0;
        };
        let projected = self.points_in_view(map, &local, &pose, &in_frame);
        for pp in &projected {
            if count && let Some(p) = map.points.get_mut(&pp.id) {
                p.visible += 1;
            }
        }
        let recently_relocalised = self.last_reloc_frame.is_some_and(|r| frame.index < r + 2);
        let th = if recently_relocalised {
            5.0
        } else {
            self.s.local_map_search_th
        };
        search_by_projection_local(frame, &projected, map, th, &self.s);
        self.optimize_frame(frame, map);
        let mut inliers = 0;
        let mut erase = Vec::new();
        for i in 0..frame.len() {
            let Some(mp) = frame.map_points[i] else {
                continue;
            };
            if frame.outliers[i] {
                // The final pose rejects this match: a point that keeps failing (ours) goes.
                if count && let Some(p) = map.points.get_mut(&mp) {
                    p.rejected += 1;
                    let max = self.s.point_max_rejections;
                    if max > 0 && p.rejected >= max && p.rejected >= p.found {
                        erase.push(mp);
                    }
                }
                continue;
            }
            if let Some(p) = map.points.get_mut(&mp) {
                if count {
                    p.found += 1;
                }
                if !p.observations.is_empty() {
                    inliers += 1;
                }
            }
        }
        if !erase.is_empty() {
            debug!(
                frame = frame.index,
                erased = erase.len(),
                "points rejected too often"
            );
            for mp in erase {
                map.erase_point(mp);
            }
        }
        inliers
    }

    fn local_map_ok(&self, frame: &Frame, inliers: usize) -> bool {
        let max_frames = self.s.fps.max(1.0) as usize;
        if self
            .last_reloc_frame
            .is_some_and(|r| frame.index < r + max_frames)
            && inliers < self.s.reloc_min_inliers
        {
            return false;
        }
        inliers >= self.s.min_tracked_inliers
    }

    /// ORB-SLAM3 `NeedNewKeyFrame` (RGB-D: close-points rule included).
    fn need_new_keyframe(
        &mut self,
        frame: &Frame,
        map: &Map,
        inliers: usize,
        mapper_idle: bool,
        mapper_queue: usize,
    ) -> bool {
        let max_frames = self.s.fps.max(1.0) as usize;
        let n_kfs = map.current_keyframes().count();
        if self
            .last_reloc_frame
            .is_some_and(|r| frame.index < r + max_frames)
            && n_kfs > max_frames
        {
            return false;
        }
        let min_obs = if n_kfs <= 2 { 2 } else { 3 };
        let ref_matches = self
            .valid_reference(map)
            .and_then(|k| map.keyframes.get(&k))
            .map_or(0, |kf| {
                kf.map_points
                    .iter()
                    .flatten()
                    .filter(|m| {
                        map.points
                            .get(m)
                            // ORB-SLAM3 counts an observation with depth twice: after a depth
                            // initialisation the first keyframe's points already count 2.
                            .is_some_and(|p| p.weighted_observations(&map.keyframes) >= min_obs)
                    })
                    .count()
            });
        let close = self.s.close_depth() as f32;
        let (mut tracked_close, mut untracked_close) = (0, 0);
        for i in 0..frame.len() {
            let z = frame.depth[i];
            // Keypoints that may not create points (on a possible mover) ask for no keyframe.
            if z > 0.0 && z < close && !frame.no_new_point[i] {
                if frame.map_points[i].is_some() && !frame.outliers[i] {
                    tracked_close += 1;
                } else {
                    untracked_close += 1;
                }
            }
        }
        let gap = self.s.kf_close_min_gap_frames;
        let need_close = tracked_close < self.s.kf_close_tracked_max
            && untracked_close > self.s.kf_close_untracked_min
            && frame.index >= self.last_kf_frame.saturating_add(gap);
        let th_ref = if n_kfs < 2 { 0.4 } else { self.s.kf_ref_ratio };
        let c1a = frame.index >= self.last_kf_frame + max_frames;
        let c1b = mapper_idle;
        let weak = inliers < self.s.kf_weak_tracking_inliers;
        // Monocular: no close points, and ORB-SLAM3 has no c1c (ours, `weak`, stays).
        let c1c = (!self.s.monocular
            && ((inliers as f64) < ref_matches as f64 * 0.25 || need_close))
            || weak;
        let c2 =
            ((inliers as f64) < ref_matches as f64 * th_ref || need_close || weak) && inliers > 15;
        if (c1a || c1b || c1c) && c2 {
            // A busy mapper refuses monocular keyframes (ORB-SLAM3).
            mapper_idle || (!self.s.monocular && mapper_queue < 3)
        } else {
            false
        }
    }

    /// ORB-SLAM3 `CreateNewKeyFrame` for RGB-D: the keyframe, plus map points from depth for the
    /// closest unmatched keypoints (all close ones, at least `kf_new_points_min`).
    fn create_keyframe(&mut self, frame: &mut Frame, map: &mut Map) -> Option<KfId> {
        for i in 0..frame.len() {
            if frame.outliers[i] {
                frame.map_points[i] = None;
                frame.outliers[i] = false;
            }
            if frame.map_points[i].is_some_and(|m| !map.points.contains_key(&m)) {
                frame.map_points[i] = None;
            }
        }
        let kf = map.add_keyframe(frame)?;
        let mut by_depth: Vec<(f32, usize)> = (0..frame.len())
            .filter(|&i| frame.depth[i] > 0.0)
            .map(|i| (frame.depth[i], i))
            .collect();
        by_depth.sort_by(|a, b| a.0.total_cmp(&b.0));
        let close = self.s.close_depth() as f32;
        let scales = self.s.scale_factors();
        let mut n_points = 0;
        for (z, i) in by_depth {
            if frame.map_points[i].is_none()
                && !frame.no_new_point[i]
                && let Some(pw) = frame.unproject_world(i, &self.s.camera)
                && let Some(mp) = map.add_point(pw, kf, i)
            {
                map.update_point(mp, &scales);
                frame.map_points[i] = Some(mp);
            }
            n_points += 1;
            if z > close && n_points > self.s.kf_new_points_min {
                break;
            }
        }
        self.reference_kf = Some(kf);
        self.last_kf_frame = frame.index;
        Some(kf)
    }

    /// Match against candidate keyframes (those place recognition proposed, then the nearest to
    /// the last known pose, or the newest), robust pose by RANSAC (3D-3D with depth, EPnP
    /// monocular), then pose optimisation; needs `reloc_min_inliers`.
    fn relocalise(&mut self, frame: &mut Frame, map: &Map) -> bool {
        if !self.s.monocular && frame.with_depth() < 3 {
            return false;
        }
        let last_center = self.last_good_pose.map(|p| p.inverse().translation.vector);
        let nearest = |current: bool| {
            let mut cands: Vec<(f64, KfId)> = map
                .keyframes
                .values()
                .filter(|k| !k.bad && (k.map_epoch == map.epoch) == current)
                .map(|k| {
                    let d = last_center.map_or(-(k.id as f64), |c| (k.camera_center() - c).norm());
                    (d, k.id)
                })
                .collect();
            cands.sort_by(|a, b| a.0.total_cmp(&b.0));
            cands.truncate(self.s.reloc_candidates);
            cands.into_iter().map(|(_, k)| k)
        };
        // An RGB-D or stereo map starts at the last known pose of the one before, so the older
        // maps' keyframes near it are candidates too; a monocular map's frame is its own.
        let every_map = self.s.relocalise_in_every_map;
        let older = (every_map && !self.s.monocular)
            .then(|| nearest(false))
            .into_iter()
            .flatten();
        // The current map first: an older map is taken up again only where the current one
        // does not hold the place. Within it, with a last known pose, the keyframes nearest it
        // before place recognition's: a camera lost a moment ago is most often still there, and
        // the newest keyframes hold the map as it has drifted to (ORB-SLAM3 asks place
        // recognition alone). Without one (a loaded map) they mean nothing.
        let (proposed, proposed_older): (Vec<KfId>, Vec<KfId>) =
            std::mem::take(&mut self.reloc_candidates)
                .into_iter()
                .partition(|k| {
                    map.keyframes
                        .get(k)
                        .is_some_and(|x| x.map_epoch == map.epoch)
                });
        let (first, second): (Vec<KfId>, Vec<KfId>) = if last_center.is_some() {
            (nearest(true).collect(), proposed)
        } else {
            (proposed, nearest(true).collect())
        };
        let mut tried = BTreeSet::new();
        let order = first
            .into_iter()
            .chain(second)
            .chain(proposed_older)
            .chain(older)
            .filter(|k| tried.insert(*k))
            .collect::<Vec<_>>();
        for kid in order {
            let Some(kf) = map
                .keyframes
                .get(&kid)
                .filter(|k| !k.bad && (every_map || k.map_epoch == map.epoch))
            else {
                continue;
            };
            frame.map_points.iter_mut().for_each(|m| *m = None);
            frame.outliers.iter_mut().for_each(|o| *o = false);
            let n = search_by_descriptors(frame, kf, map, 0.75, self.s.th_low);
            if n < MIN_DESCRIPTOR_MATCHES {
                continue;
            }
            let mut idx = Vec::new();
            let mut corr = Vec::new();
            for i in 0..frame.len() {
                let Some(p) = frame.map_points[i].and_then(|m| map.points.get(&m)) else {
                    continue;
                };
                idx.push(i);
                corr.push(Correspondence {
                    world: p.position,
                    camera: frame.unproject_camera(i, &self.s.camera),
                    u: frame.points[i].x,
                    v: frame.points[i].y,
                    inv_sigma2: self.inv_sigma2[frame.octaves[i] as usize],
                });
            }
            let solved = if self.s.monocular {
                ransac_pnp(&corr, &self.s.camera, &RansacParams::default())
            } else {
                ransac_pose(&corr, &self.s.camera, &RansacParams::default())
            };
            let Some((pose, flags)) = solved else {
                continue;
            };
            if flags.iter().filter(|&&f| f).count() < 10 {
                continue;
            }
            for (k, &i) in idx.iter().enumerate() {
                if !flags[k] {
                    frame.map_points[i] = None;
                }
            }
            frame.pose_cw = Some(pose);
            let inl = self.optimize_frame(frame, map);
            if inl >= self.s.reloc_min_inliers.min(idx.len()) && inl >= 10 {
                Self::discard_outliers(frame, map);
                self.reference_kf = Some(kid);
                return true;
            }
        }
        frame.map_points.iter_mut().for_each(|m| *m = None);
        frame.pose_cw = None;
        false
    }

    /// The keyframe the last frame was tracked against (ORB-SLAM's `mpReferenceKF`).
    pub fn reference_keyframe(&self) -> Option<KfId> {
        self.reference_kf
    }

    /// Loop closing moved keyframes (`poses`: world-to-camera before and after): the last frame
    /// moves with its reference keyframe (else the newest moved one), as ORB-SLAM's
    /// `UpdateLastFrame` re-anchors it, so the motion model predicts in the corrected map.
    /// A monocular keyframe whose scale changed (`c.rescaled`: a merge, a Sim(3) loop) also
    /// scales the last frame's translation from it, and the motion model's.
    pub fn on_map_corrected(&mut self, c: &MapCorrection) {
        let poses = &c.poses;
        let anchor = self
            .reference_kf
            .and_then(|k| poses.get(&k))
            .or_else(|| poses.values().next_back());
        let Some(&(before, after)) = anchor else {
            return;
        };
        let scale = self
            .reference_kf
            .and_then(|r| c.rescaled.get(&r))
            .copied()
            .unwrap_or(1.0);
        let moved = |p: Se3| {
            if scale == 1.0 {
                return p * (before.inverse() * after);
            }
            let mut from_keyframe = p * before.inverse();
            from_keyframe.translation.vector *= scale;
            from_keyframe * after
        };
        for f in [self.last_frame.as_mut(), self.last_tracked_frame.as_mut()]
            .into_iter()
            .flatten()
        {
            if let Some(p) = f.pose_cw {
                f.pose_cw = Some(moved(p));
            }
        }
        if let Some(p) = self.last_good_pose {
            self.last_good_pose = Some(moved(p));
        }
        for v in [
            self.velocity.as_mut(),
            self.velocity_when_lost.as_mut().map(|(v, _)| v),
        ]
        .into_iter()
        .flatten()
        {
            v.translation.vector *= scale;
        }
    }
}

/// Cells of a 4 x 4 grid over the image that hold a keypoint with depth.
fn cells_with_depth(frame: &Frame, camera: &stillpoint_geometry::PinholeCamera) -> usize {
    let (w, h) = (camera.width.max(1) as f64, camera.height.max(1) as f64);
    let mut cells = [false; 16];
    for (p, &z) in frame.points.iter().zip(&frame.depth) {
        if z > 0.0 && p.x.is_finite() && p.y.is_finite() {
            let cx = ((p.x / w * 4.0) as usize).min(3);
            let cy = ((p.y / h * 4.0) as usize).min(3);
            cells[cy * 4 + cx] = true;
        }
    }
    cells.iter().filter(|&&c| c).count()
}

/// The pose inliers of a frame (`matched` from [`matched`]).
fn observations(frame: &Frame, matched: &[bool]) -> Vec<FrameObservation> {
    matched
        .iter()
        .enumerate()
        .filter(|(_, m)| **m)
        .filter_map(|(i, _)| {
            Some(FrameObservation {
                point: frame.map_points[i]?,
                u: frame.points[i].x,
                v: frame.points[i].y,
                u_right: frame.u_right[i],
                octave: frame.octaves[i],
            })
        })
        .collect()
}

/// Per keypoint: matched to a map point and not an outlier of the pose (empty when not tracked).
fn matched(frame: &Frame, ok: bool) -> Vec<bool> {
    if !ok {
        return Vec::new();
    }
    frame
        .map_points
        .iter()
        .enumerate()
        .map(|(i, m)| m.is_some() && !frame.outliers.get(i).copied().unwrap_or(false))
        .collect()
}
