//! [`System`]: tracking plus local mapping and loop closing (threaded or inline) over a shared
//! map.

use std::collections::{BTreeSet, VecDeque};
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::Instant;
use tracing::debug;

use stillpoint_geometry::{Se3, Vec3};
use stillpoint_image::DepthMetres;

use crate::data::{FreeSpaceCheck, KfId, Map, MpId, SharedMap};
use crate::map_file::{MapFile, MapSensor};
use crate::module::local_mapping::{LocalMapper, MapperHooks, MapperThread};
use crate::module::loop_closing::{LoopCloser, LoopStats, LoopThread, MapCorrection};
use crate::module::tracking::{FrameObservation, Tracker, carried_back};
use crate::optimize::{PoseObservation, PosePrior, optimize_pose_with_prior};
use crate::place::{KeyFrameDatabase, Vocabulary};
use crate::{Descriptor, Feature, Frame, KeypointDepth, SlamError, SlamSettings, TrackingState};

/// The caller's map hygiene after a frame's tracking, `hygiene(map, pose_wc)`.
pub type MapHygiene<'a> = Box<dyn FnOnce(&mut Map, &Se3) + 'a>;

/// One frame as tracking takes it ([`System::track`]).
pub struct TrackInput<'a> {
    /// Position of the frame in its sequence.
    pub index: usize,
    /// The frame's time, seconds.
    pub timestamp: f64,
    /// The keypoints the front-end kept.
    pub features: &'a [Feature],
    /// Their descriptors, in the same order.
    pub descriptors: &'a [Descriptor],
    /// Their depth: a depth image (RGB-D), one per keypoint (stereo, from
    /// [`crate::matching::stereo::stereo_depths`]) or none (monocular).
    pub depth: KeypointDepth<'a>,
    /// Keypoints that may be tracked but must not create map points (same length as
    /// `features`, or empty): the front-end's keypoints on objects not proven still.
    pub no_new_points: &'a [bool],
    /// Keypoints that may be matched to map points only as closely as keyframes match (same
    /// length as `features`, or empty).
    pub close_match_only: &'a [bool],
    /// The caller's own map hygiene once the frame has a pose, `hygiene(map, pose_wc)`.
    pub hygiene: Option<MapHygiene<'a>>,
}

impl<'a> TrackInput<'a> {
    /// A frame of `features` with no depth, no flags and no hygiene.
    pub fn new(
        index: usize,
        timestamp: f64,
        features: &'a [Feature],
        descriptors: &'a [Descriptor],
    ) -> Self {
        Self {
            index,
            timestamp,
            features,
            descriptors,
            depth: KeypointDepth::None,
            no_new_points: &[],
            close_match_only: &[],
            hygiene: None,
        }
    }

    /// The same with its depth.
    pub fn with_depth(self, depth: impl Into<KeypointDepth<'a>>) -> Self {
        Self {
            depth: depth.into(),
            ..self
        }
    }
}

/// What the system did with one frame.
#[derive(Clone, Debug)]
pub struct FrameReport {
    /// Position of the frame in its sequence.
    pub index: usize,
    /// Time of the frame, seconds.
    pub timestamp: f64,
    /// Tracking's state after it.
    pub state: TrackingState,
    /// Camera-to-world pose when tracked (TUM convention).
    pub pose_wc: Option<Se3>,
    /// Keypoints handed to tracking.
    pub keypoints: usize,
    /// Map points matched by the final pose optimisation.
    pub inliers: usize,
    /// Per keypoint handed to tracking: a pose inlier matched to a map point (empty when the
    /// frame was not tracked).
    pub matched: Vec<bool>,
    /// The frame became a keyframe.
    pub new_keyframe: bool,
    /// Relocalised in the same map after being lost.
    pub relocalised: bool,
    /// A new map was started.
    pub new_map: bool,
    /// Tracking time (ms), frame building included.
    pub tracking_ms: f64,
    /// Of `tracking_ms`, the time spent waiting for the map while local mapping or loop
    /// closing held it (ms).
    pub map_wait_ms: f64,
    /// Monocular, on the frame that started a map: the earlier frames offered before it stood
    /// (its first view, the frames between its two views and those of references dropped
    /// before), tracked in it (oldest first); their poses settle later as tracked frames' do.
    pub backfilled: Vec<crate::Backfilled>,
}

enum Mapping {
    Inline(Box<LocalMapper>),
    Thread(MapperThread),
}

enum Looping {
    Off,
    Inline(Box<LoopCloser>),
    Thread(Box<LoopThread>),
}

/// The SLAM system: RGB-D, stereo (depth per keypoint) or monocular input (see
/// [`SlamSettings::monocular`]).
pub struct System {
    /// The settings it runs with (read-only once tracking started).
    pub settings: SlamSettings,
    map: Arc<SharedMap>,
    tracker: Tracker,
    mapping: Mapping,
    mapping_ms: Arc<Mutex<Vec<f64>>>,
    looping: Looping,
    /// Per tracked frame: timestamp, reference keyframe, pose relative to it (T_c_ref); the
    /// trajectory rebuilt through the keyframes after loop corrections.
    anchors: Vec<(f64, KfId, Se3)>,
    /// Tracked frames waiting for local mapping to refine the keyframes around them before
    /// their pose is optimised again (`SlamSettings::trajectory_settle_keyframes`).
    unsettled: VecDeque<Unsettled>,
    /// Keyframes handed to local mapping so far.
    keyframes_inserted: usize,
    /// A map was loaded: bags of words of its keyframes (and of the new ones), for
    /// relocalising by place recognition.
    reloc_db: Option<KeyFrameDatabase>,
    /// The loop closer's keyframe database (`slam.relocalise_with_loop_database`): place
    /// recognition for relocalising in a fresh run, every map's keyframes.
    loop_db: Option<Arc<Mutex<KeyFrameDatabase>>>,
    /// Localisation only: the loaded map is never changed.
    localize: bool,
    /// Loop edges of a loaded map (the loop closer holds them too when it runs).
    loaded_loop_edges: std::collections::BTreeSet<(KfId, KfId)>,
    /// Monocular: frames placed at the end of the run that no map's first views could track
    /// (`MonoInitSettings::place_before_map_at_end`).
    placed_at_end: usize,
}

/// What to do with a map loaded from a file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoadedMapMode {
    /// Relocalise in it, then go on mapping in it: new keyframes and points are added, local
    /// mapping and loop closing run as usual.
    Extend,
    /// Relocalise in it and track against it without changing it: no keyframes, no points, no
    /// bundle adjustment, no loop closing, no counters.
    Localize,
}

/// A tracked frame whose anchor is not final yet.
struct Unsettled {
    /// Its entry in `System::anchors`.
    anchor: usize,
    /// World-to-camera as tracking left it.
    pose_cw: Se3,
    observations: Vec<FrameObservation>,
    /// `System::keyframes_inserted` when it was tracked.
    keyframes_at: usize,
    /// `Map::fusions` when it was tracked: its points' later fusions are numbered from here.
    fusions_at: u64,
    /// The frame, to be matched again to the map it settles on (a young monocular map's).
    frame: Option<Box<Frame>>,
}

impl System {
    /// A system; local mapping gets its own thread when `settings.local_mapping_thread` (falls
    /// back to inline if the thread cannot be spawned).
    pub fn new(settings: SlamSettings) -> Self {
        Self::with_vocabulary(settings, None)
    }

    /// [`System::new`] with a place-recognition vocabulary given by the user (else loop closing
    /// trains its own from the keyframes).
    pub fn with_vocabulary(settings: SlamSettings, vocabulary: Option<Vocabulary>) -> Self {
        Self::build(settings, vocabulary, None)
    }

    /// A system that starts in a map loaded from a file ([`crate::map_file`]): tracking starts
    /// lost and relocalises in it by place recognition (the map's vocabulary, or one trained
    /// from its keyframes when it has none) and RANSAC; then `mode` says whether it maps on or
    /// only localises. Fails when the map was made with another camera, sensor or ORB pyramid,
    /// or holds no keyframe to relocalise in.
    pub fn with_map(
        settings: SlamSettings,
        file: MapFile,
        mode: LoadedMapMode,
    ) -> Result<Self, crate::map_file::MapFileError> {
        file.check_settings(&settings)?;
        if file.map.current_keyframes().next().is_none() {
            return Err(crate::map_file::MapFileError::Invalid(
                "the map holds no keyframe to relocalise in".into(),
            ));
        }
        Ok(Self::build(settings, None, Some((file, mode))))
    }

    fn build(
        mut settings: SlamSettings,
        vocabulary: Option<Vocabulary>,
        loaded: Option<(MapFile, LoadedMapMode)>,
    ) -> Self {
        let localize = loaded
            .as_ref()
            .is_some_and(|(_, m)| *m == LoadedMapMode::Localize);
        if localize {
            // Loop closing would move the map's keyframes.
            settings.loop_closing.enabled = false;
        }
        let (map, vocabulary, loaded_loop_edges) = match loaded {
            Some((mut f, _)) => {
                f.map.session_first_kf = f.map.next_kf;
                (f.map, f.vocabulary.or(vocabulary), f.loop_edges)
            }
            None => (Map::new(), vocabulary, Default::default()),
        };
        let is_loaded = !map.keyframes.is_empty();
        let reloc_db =
            is_loaded.then(|| relocalisation_database(&map, vocabulary.clone(), &settings));
        let map = Arc::new(SharedMap::new(map));
        let mapping_ms = Arc::new(Mutex::new(Vec::new()));
        let mapper = LocalMapper::new(settings.clone());
        // A monocular run closes loops within its map in Sim(3) when `monocular_loops` is on,
        // and merges maps (with the scale between them) when `merge_maps` is.
        let ls = &settings.loop_closing;
        let looping_on = ls.enabled && (!settings.monocular || ls.merge_maps || ls.monocular_loops);
        if ls.enabled && settings.monocular && !ls.monocular_loops {
            tracing::info!(
                "monocular: loop closing merges maps only (slam.loop_closing.monocular_loops is off)"
            );
        }
        let closer = looping_on.then(|| {
            let mut c = match vocabulary {
                Some(v) => LoopCloser::with_vocabulary(settings.clone(), v),
                None => LoopCloser::new(settings.clone()),
            };
            if is_loaded && let Ok(m) = map.lock() {
                c.resume(&m, &loaded_loop_edges);
            }
            c
        });
        let loop_db = closer
            .as_ref()
            .filter(|_| settings.relocalise_with_loop_database)
            .map(|c| c.database());
        let mut looping = Looping::Off;
        let mapping = if settings.local_mapping_thread {
            // Local mapping hands each keyframe to the loop-closing thread when both run.
            let busy = Arc::new(Mutex::new(()));
            let (to_loop, from_mapping) = std::sync::mpsc::channel();
            let mut closer = closer;
            if let Some(c) = closer.take() {
                match LoopThread::spawn(c, map.clone(), from_mapping, busy.clone()) {
                    Ok(t) => looping = Looping::Thread(Box::new(t)),
                    Err(e) => tracing::warn!(
                        "cannot start the loop-closing thread ({e}); no loop closing"
                    ),
                }
            }
            let hooks = MapperHooks {
                processed: matches!(looping, Looping::Thread(_)).then_some(to_loop),
                busy,
            };
            match MapperThread::spawn_with_hooks(
                LocalMapper::new(settings.clone()),
                map.clone(),
                mapping_ms.clone(),
                hooks,
            ) {
                Ok(t) => Mapping::Thread(t),
                Err(e) => {
                    tracing::warn!("cannot start the local mapping thread ({e}); mapping inline");
                    Mapping::Inline(Box::new(mapper))
                }
            }
        } else {
            if let Some(c) = closer {
                looping = Looping::Inline(Box::new(c));
            }
            Mapping::Inline(Box::new(mapper))
        };
        let tracker = if is_loaded {
            Tracker::for_loaded_map(settings.clone(), localize)
        } else {
            Tracker::new(settings.clone())
        };
        Self {
            tracker,
            settings,
            map,
            mapping,
            mapping_ms,
            looping,
            anchors: Vec::new(),
            placed_at_end: 0,
            unsettled: VecDeque::new(),
            keyframes_inserted: 0,
            reloc_db,
            loop_db,
            localize,
            loaded_loop_edges,
        }
    }

    /// Localising in a loaded map without changing it.
    pub fn localizing(&self) -> bool {
        self.localize
    }

    /// The map as a [`MapFile`] to save: a copy of the map, the place-recognition vocabulary
    /// (the loop closer's, else the one relocalisation uses) and the loop edges. Call it after
    /// [`System::shutdown`]: a loop-closing thread hands its vocabulary back only then.
    pub fn map_file(&self) -> MapFile {
        let map = self.map.lock().map(|m| m.clone()).unwrap_or_default();
        let closer = match &self.looping {
            Looping::Off => None,
            Looping::Inline(l) => Some(l.as_ref()),
            Looping::Thread(t) => t.closer(),
        };
        let vocabulary = closer
            .and_then(|c| c.vocabulary())
            .or_else(|| self.reloc_db.as_ref().and_then(|d| d.vocabulary()).cloned());
        let mut loop_edges = self.loaded_loop_edges.clone();
        if let Some(c) = closer {
            loop_edges.extend(c.loop_edges().iter().copied());
        }
        MapFile {
            sensor: MapSensor::of(&self.settings),
            map,
            vocabulary,
            loop_edges,
        }
    }

    /// Whether frame `index` should be extracted with `settings.mono_init.feature_factor` times
    /// the usual features: monocular, and not initialised yet or within
    /// `settings.mono_init.young_map_seconds` of the map's start. Initialisation matches level-0
    /// keypoints only; and the young map's points were made from those many keypoints, so with
    /// the usual count a frame finds a fraction of them (ORB-SLAM3 keeps `mpIniORBextractor` for
    /// `mMaxFrames`, a second, after initialising).
    pub fn wants_initial_features(&self, index: usize) -> bool {
        if !self.settings.monocular {
            return false;
        }
        if self.tracker.state == TrackingState::NotInitialized {
            return true;
        }
        self.tracker.map_started_at.is_some_and(|start| {
            crate::module::initializer::map_is_young(
                index.saturating_sub(start),
                self.tracker.last_inliers,
                self.settings.fps,
                &self.settings.mono_init,
            )
        })
    }

    /// Whether frame `index`'s keyframe is mapped before the next frame is tracked although
    /// local mapping has its own thread: monocular, within
    /// `settings.mono_init.map_keyframes_at_once_seconds` of the map's start.
    fn maps_keyframes_at_once(&self, index: usize) -> bool {
        self.settings.monocular
            && self.tracker.within_seconds_of_map_start(
                index,
                self.settings.mono_init.map_keyframes_at_once_seconds,
            )
    }

    /// Track one frame: its (already filtered) features, their depth, and then the caller's
    /// map hygiene ([`TrackInput::hygiene`]). With local mapping in its own thread the hygiene
    /// runs before this frame's keyframe is handed over, as do the system's own hygiene and
    /// settling: the mapper's first steps on a keyframe hold the map for several milliseconds at
    /// a lower priority, and a lock taken after them made the frame wait for them (12-17 ms on
    /// a keyframe). Inline, the keyframe is mapped first.
    pub fn track(&mut self, input: TrackInput) -> Result<FrameReport, SlamError> {
        let TrackInput {
            index,
            timestamp,
            features,
            descriptors,
            depth,
            no_new_points,
            close_match_only,
            hygiene,
        } = input;
        let t0 = Instant::now();
        if !timestamp.is_finite() {
            return Err(SlamError::BadInput {
                index,
                msg: "timestamp is not finite".into(),
            });
        }
        let mut frame = Frame::new_with_mask(
            index,
            timestamp,
            features,
            descriptors,
            depth,
            &self.settings,
            no_new_points,
        )?;
        if close_match_only.len() == frame.len() {
            frame.close_match_only = close_match_only.to_vec();
        }
        let keypoints = frame.len();
        let (idle, queued) = match &self.mapping {
            Mapping::Inline(_) => (true, 0),
            Mapping::Thread(t) => (
                t.idle.load(Ordering::SeqCst),
                t.queued.load(Ordering::SeqCst),
            ),
        };
        let waiting = Instant::now();
        let map_wait_ms;
        let mut backfilled = Vec::new();
        let outcome = {
            let mut map = self
                .map
                .lock()
                .map_err(|_| SlamError::LocalMapping("map lock poisoned".into()))?;
            map_wait_ms = stillpoint_core::ms_since(waiting);
            // Corrections the loop-closing thread made since the last frame.
            if let Looping::Thread(t) = &self.looping {
                let pending =
                    std::mem::take(&mut *t.corrections.lock().unwrap_or_else(|e| e.into_inner()));
                for c in pending {
                    self.tracker.on_map_corrected(&c);
                    rescale_anchors(&mut self.anchors, &c);
                }
            }
            // A loaded map's database, else the loop closer's (without waiting for it: a
            // frame that finds it busy goes without place recognition).
            let relocalising = self.tracker.is_relocalising();
            let loop_db = (relocalising && self.reloc_db.is_none())
                .then(|| self.loop_db.as_ref()?.try_lock().ok())
                .flatten();
            if relocalising
                && let Some(db) = self.reloc_db.as_ref().or(loop_db.as_deref())
                && let Some(v) = db.vocabulary()
            {
                let bow = v.transform(&frame.descriptors);
                let epoch = map.epoch;
                let every_map = self.settings.relocalise_in_every_map;
                let candidates = db.relocalisation_candidates(
                    &bow,
                    |k| {
                        map.keyframes
                            .get(&k)
                            .is_some_and(|x| !x.bad && (every_map || x.map_epoch == epoch))
                    },
                    |k| {
                        map.keyframes
                            .get(&k)
                            .map_or(Vec::new(), |x| x.best_covisibles(10))
                    },
                );
                debug!(
                    frame = index,
                    candidates = candidates.len(),
                    "relocalisation candidates"
                );
                self.tracker
                    .set_relocalisation_candidates(candidates.into_iter().map(|c| c.0).collect());
            }
            drop(loop_db);
            let mut outcome = self.tracker.track(frame, &mut map, idle, queued);
            if let Some(db) = self.reloc_db.as_mut() {
                for kf in [outcome.first_keyframe, outcome.new_keyframe]
                    .into_iter()
                    .flatten()
                {
                    if let Some(k) = map.keyframes.get(&kf) {
                        db.add(kf, &k.descriptors);
                    }
                }
            }
            // Frames tracked late come before this one: the anchors stay in time order.
            // They settle as tracked frames do, counted from the map's first two keyframes.
            let keyframes_at = self.keyframes_inserted
                + [outcome.first_keyframe, outcome.new_keyframe]
                    .iter()
                    .flatten()
                    .count();
            for (b, observations, frame) in std::mem::take(&mut outcome.backfilled) {
                if let Some(k) = map.keyframes.get(&b.reference) {
                    let pose_cw = b.pose_wc.inverse();
                    if self.settings.trajectory_settle_keyframes > 0 && !observations.is_empty() {
                        self.unsettled.push_back(Unsettled {
                            anchor: self.anchors.len(),
                            pose_cw,
                            observations,
                            keyframes_at,
                            fusions_at: map.fusions(),
                            frame,
                        });
                    }
                    self.anchors
                        .push((b.timestamp, b.reference, pose_cw * k.pose_cw.inverse()));
                    backfilled.push(b);
                }
            }
            if let Some(wc) = outcome.pose_wc
                && let Some(r) = self.tracker.reference_keyframe()
                && let Some(k) = map.keyframes.get(&r)
            {
                let pose_cw = wc.inverse();
                if self.settings.trajectory_settle_keyframes > 0 {
                    self.unsettled.push_back(Unsettled {
                        anchor: self.anchors.len(),
                        pose_cw,
                        observations: std::mem::take(&mut outcome.observations),
                        keyframes_at: self.keyframes_inserted,
                        fusions_at: map.fusions(),
                        frame: outcome.kept_frame.take(),
                    });
                }
                self.anchors
                    .push((timestamp, r, pose_cw * k.pose_cw.inverse()));
            }
            let first_needed = self
                .unsettled
                .front()
                .map_or_else(|| map.fusions(), |u| u.fusions_at);
            map.forget_fusions_before(first_needed);
            outcome
        };
        let tracking_ms = stillpoint_core::ms_since(t0);
        let new_keyframes = [outcome.first_keyframe, outcome.new_keyframe];
        let mapping_inline = matches!(self.mapping, Mapping::Inline(_));
        if mapping_inline {
            for kf in new_keyframes.into_iter().flatten() {
                self.insert_keyframe(kf)?;
            }
        }
        if let (KeypointDepth::Map(image), Some(pose_wc), false) =
            (depth, outcome.pose_wc, self.localize)
        {
            self.erase_points_seen_through(index, &pose_wc.inverse(), image);
        }
        // Lost: the frames still waiting settle on the map as it is now; a new map's keyframes
        // would otherwise count as the refinement they wait for, and local mapping drops the
        // lost map's recent points meanwhile.
        self.settle(self.tracker.state == TrackingState::Lost);
        if let (Some(hygiene), Some(pose_wc)) = (hygiene, &outcome.pose_wc)
            && let Ok(mut map) = self.map.lock()
        {
            hygiene(&mut map, pose_wc);
        }
        if !mapping_inline {
            let mut inserted = false;
            for kf in new_keyframes.into_iter().flatten() {
                self.insert_keyframe(kf)?;
                inserted = true;
            }
            if inserted
                && self.maps_keyframes_at_once(index)
                && let Mapping::Thread(t) = &self.mapping
                && !t.wait_for_queue()
            {
                return Err(SlamError::LocalMapping("the thread is gone".into()));
            }
        }
        Ok(FrameReport {
            index,
            timestamp,
            state: self.tracker.state,
            pose_wc: outcome.pose_wc,
            keypoints,
            inliers: outcome.inliers,
            matched: outcome.matched,
            new_keyframe: outcome.new_keyframe.is_some(),
            relocalised: outcome.relocalised,
            new_map: outcome.new_map,
            tracking_ms,
            map_wait_ms,
            backfilled,
        })
    }

    /// RGB-D map hygiene after each tracked frame: map points the depth image sees through
    /// leave the map (`Map::erase_points_seen_through`, `SlamSettings::erase_seen_through_after`).
    fn erase_points_seen_through(&self, index: usize, pose_cw: &Se3, depth: &DepthMetres) {
        let s = &self.settings;
        let check = FreeSpaceCheck {
            bf: s.bf,
            gap_px: s.seen_through_gap_px,
            erase_after: s.erase_seen_through_after,
        };
        let erased = self.map.lock().map_or(0, |mut m| {
            m.erase_points_seen_through(pose_cw, &s.camera, depth, &check)
        });
        if erased > 0 {
            debug!(frame = index, erased, "map points seen through erased");
        }
    }

    fn insert_keyframe(&mut self, kf: KfId) -> Result<(), SlamError> {
        self.keyframes_inserted += 1;
        match &mut self.mapping {
            Mapping::Inline(m) => {
                let t0 = Instant::now();
                m.process(&self.map, kf);
                if let Ok(mut t) = self.mapping_ms.lock() {
                    t.push(stillpoint_core::ms_since(t0));
                }
                if let Looping::Inline(l) = &mut self.looping
                    && let Some(c) = l.process(&self.map, kf, None, None)
                {
                    self.tracker.on_map_corrected(&c);
                    rescale_anchors(&mut self.anchors, &c);
                }
                Ok(())
            }
            Mapping::Thread(t) => {
                if t.send(kf) {
                    Ok(())
                } else {
                    Err(SlamError::LocalMapping("the thread is gone".into()))
                }
            }
        }
    }

    /// Wait for local mapping to finish its queue.
    pub fn shutdown(&mut self) -> Result<(), SlamError> {
        if let Mapping::Thread(t) = &mut self.mapping {
            t.finish()?;
        }
        // Local mapping has stopped, so the loop-closing thread's channel is closed.
        if let Looping::Thread(t) = &mut self.looping {
            t.finish()?;
        }
        self.settle(true);
        self.placed_at_end = self.place_frames_before_maps();
        Ok(())
    }

    /// Frames tracked only at the end of the run: those before a monocular map stood that its
    /// first views could not track (`MonoInitSettings::place_before_map_at_end`).
    pub fn frames_placed_at_end(&self) -> usize {
        self.placed_at_end
    }

    /// Monocular, at the end: the frames before a map stood that its first views could not
    /// track, placed in the map as it ended, newest first, each from the motion of the two
    /// frames after it, until one fails; anchored to the reference keyframe of the frame
    /// after it. Returns how many were placed.
    fn place_frames_before_maps(&mut self) -> usize {
        let frames = self.tracker.take_unplaced();
        if frames.is_empty() {
            return 0;
        }
        let map = self.map.clone();
        let Ok(map) = map.lock() else {
            return 0;
        };
        // (time, world-to-camera, reference keyframe, map) of every frame with a pose, in
        // time order
        let mut posed: Vec<(f64, Se3, KfId, u32)> = (0..self.anchors.len())
            .filter_map(|i| self.anchor_pose_cw(&map, i))
            .collect();
        // Frames that failed: nothing before one is placed from the frames after it.
        let mut failed: Vec<f64> = Vec::new();
        let mut placed = 0;
        for mut f in frames {
            let next = posed.partition_point(|p| p.0 <= f.timestamp);
            let Some(&(t_near, near, r, epoch)) = posed.get(next) else {
                continue;
            };
            if failed.iter().any(|&b| f.timestamp < b && b < t_near) {
                failed.push(f.timestamp);
                continue;
            }
            let prior = match posed.get(next + 1) {
                Some(&(t_far, far, _, far_epoch)) if far_epoch == epoch => {
                    carried_back((near, t_near), (far, t_far), f.timestamp)
                }
                _ => near,
            };
            let (Some(pose), Some(ref_cw)) = (
                self.tracker.place_late(&mut f, prior, r, &map),
                map.keyframe_pose_cw(r),
            ) else {
                failed.push(f.timestamp);
                continue;
            };
            posed.insert(next, (f.timestamp, pose, r, epoch));
            let at = self.anchors.partition_point(|a| a.0 <= f.timestamp);
            self.anchors
                .insert(at, (f.timestamp, r, pose * ref_cw.inverse()));
            placed += 1;
        }
        if placed > 0 {
            tracing::info!(
                frames = placed,
                "frames before a monocular map stood placed at the end"
            );
        }
        placed
    }

    /// Tracked frames whose pose waits to be settled on a refined map
    /// (`SlamSettings::trajectory_settle_at_end`); at most `trajectory_settle_max_pending`.
    pub fn frames_waiting_to_settle(&self) -> usize {
        self.unsettled.len()
    }

    /// Anchor `i`'s time, camera-to-world pose (through its keyframe as the map has it now) and
    /// map.
    fn anchor_pose_wc(&self, map: &Map, i: usize) -> Option<(f64, Se3, u32)> {
        let (t, pose_cw, _, epoch) = self.anchor_pose_cw(map, i)?;
        Some((t, pose_cw.inverse(), epoch))
    }

    /// Anchor `i`'s time, world-to-camera pose (through its keyframe as the map has it now),
    /// that keyframe and its map.
    fn anchor_pose_cw(&self, map: &Map, i: usize) -> Option<(f64, Se3, KfId, u32)> {
        let (t, r, t_cr) = *self.anchors.get(i)?;
        let pose_cw = t_cr * map.keyframe_pose_cw(r)?;
        Some((t, pose_cw, r, map.keyframes.get(&r)?.map_epoch))
    }

    /// Where anchor `a`'s neighbours in time put it: the mean of the positions interpolated at
    /// its timestamp between the k-th frame before and the k-th after, k = 1 to
    /// `trajectory_smooth_neighbours`, as a prior for settling it (now at `pose_cw`), its
    /// standard deviation `trajectory_smooth_sigma_depth` of the median depth of `obs` (ours).
    /// `None` when smoothing is off or no pair of neighbours is near enough in time on the same
    /// map.
    fn smoothing_prior(
        &self,
        map: &Map,
        a: usize,
        pose_cw: &Se3,
        obs: &[PoseObservation],
    ) -> Option<PosePrior> {
        let s = &self.settings;
        if s.trajectory_smooth_sigma_depth <= 0.0 || s.trajectory_smooth_neighbours == 0 {
            return None;
        }
        let (t, _, epoch) = self.anchor_pose_wc(map, a)?;
        let near = |i: usize| {
            self.anchor_pose_wc(map, i)
                .filter(|(ti, _, e)| *e == epoch && (ti - t).abs() <= s.trajectory_smooth_max_gap_s)
        };
        let mut sum = Vec3::zeros();
        let mut n = 0.0;
        for k in 1..=s.trajectory_smooth_neighbours {
            let (Some((t0, before, _)), Some((t1, after, _))) =
                (a.checked_sub(k).and_then(near), near(a + k))
            else {
                break;
            };
            if !(t0 < t && t < t1) {
                break;
            }
            let share = (t - t0) / (t1 - t0);
            sum += before
                .translation
                .vector
                .lerp(&after.translation.vector, share);
            n += 1.0;
        }
        let depths: Vec<f64> = obs
            .iter()
            .map(|o| (pose_cw * nalgebra::Point3::from(o.world)).z)
            .filter(|z| *z > 0.0)
            .collect();
        if n == 0.0 || depths.is_empty() {
            return None;
        }
        // The frame's own rotation, the neighbours' position: only the position is held.
        let mut prior_wc = pose_cw.inverse();
        prior_wc.translation.vector = sum / n;
        let sigma = s.trajectory_smooth_sigma_depth * stillpoint_core::stats::median(&depths);
        Some(PosePrior {
            pose_cw: prior_wc.inverse(),
            inv_sigma2_rot: 0.0,
            inv_sigma2_trans: sigma.powi(-2),
        })
    }

    /// Optimise again the poses of the tracked frames that are due against the map as it is
    /// now, and anchor each to its reference keyframe from there: all of them at the end
    /// (`all`), the oldest past `trajectory_settle_max_pending`, and, with
    /// `trajectory_settle_at_end` off, those `trajectory_settle_keyframes` keyframes old once
    /// mapping is idle.
    fn settle(&mut self, all: bool) {
        let s = &self.settings;
        let mapping_idle = match &self.mapping {
            Mapping::Inline(_) => true,
            Mapping::Thread(t) => {
                t.idle.load(Ordering::SeqCst) && t.queued.load(Ordering::SeqCst) == 0
            }
        };
        // Past `trajectory_settle_max_pending` frames the oldest settle on the map as it is:
        // waiting for the end (or for keyframes, where none comes) the queue would grow with
        // every frame.
        let (keyframes_inserted, max_pending) =
            (self.keyframes_inserted, s.trajectory_settle_max_pending);
        // Bounded per frame only where a frame waits for it: mapping in its own thread.
        let max_now = match (&self.mapping, s.trajectory_settle_max_per_frame) {
            (Mapping::Thread(_), n) if !all && n > 0 => n,
            _ => usize::MAX,
        };
        let due = |u: &Unsettled, pending: usize| {
            all || pending > max_pending
                || (!s.trajectory_settle_at_end
                    && mapping_idle
                    && u.keyframes_at + s.trajectory_settle_keyframes <= keyframes_inserted)
        };
        if !self
            .unsettled
            .front()
            .is_some_and(|u| due(u, self.unsettled.len()))
        {
            return;
        }
        let Ok(map) = self.map.lock() else {
            return;
        };
        let inv_sigma2 = s.inv_level_sigma2();
        let mut settled = 0;
        while settled < max_now
            && self
                .unsettled
                .front()
                .is_some_and(|u| due(u, self.unsettled.len()))
        {
            settled += 1;
            let Some(mut u) = self.unsettled.pop_front() else {
                break;
            };
            let (_, r, t_cr) = self.anchors[u.anchor];
            let Some(ref_cw) = map.keyframe_pose_cw(r) else {
                continue;
            };
            let obs = pose_observations(&map, &u.observations, &inv_sigma2);
            if obs.len() < s.trajectory_settle_min_inliers {
                continue;
            }
            // From the pose tracking found and from the one its keyframe carries it to now
            // (they differ after a loop correction, or when the keyframe moved): the start with
            // more inliers wins.
            let anchored = t_cr * ref_cw;
            let prior = self.smoothing_prior(&map, u.anchor, &anchored, &obs);
            let best = [u.pose_cw, anchored]
                .into_iter()
                .map(|mut pose| {
                    let outliers = optimize_pose_with_prior(&mut pose, &obs, s, prior.as_ref());
                    (outliers.iter().filter(|&&o| !o).count(), pose)
                })
                .max_by_key(|(inliers, _)| *inliers);
            // A frame of a young map: matched again to the map's points around it now, kept
            // where that finds more inliers.
            let best = match (best, u.frame.as_deref_mut()) {
                (Some((inliers, pose)), Some(frame)) => {
                    let around: Vec<MpId> = u
                        .observations
                        .iter()
                        .filter_map(|o| map.point_or_its_replacement(o.point).map(|(id, _)| id))
                        .collect();
                    let fresh = self.tracker.rematch(frame, &map, &pose, &around);
                    let obs = pose_observations(&map, &fresh, &inv_sigma2);
                    let prior = self.smoothing_prior(&map, u.anchor, &pose, &obs);
                    let mut again = pose;
                    let outliers = optimize_pose_with_prior(&mut again, &obs, s, prior.as_ref());
                    let more = outliers.iter().filter(|&&o| !o).count();
                    debug!(
                        anchor = u.anchor,
                        before = inliers,
                        after = more,
                        "settling a young map's frame matched again"
                    );
                    Some(if more >= inliers {
                        (more, again)
                    } else {
                        (inliers, pose)
                    })
                }
                (best, _) => best,
            };
            if let Some((inliers, pose)) = best
                && inliers >= s.trajectory_settle_min_inliers
            {
                self.anchors[u.anchor].2 = pose * ref_cw.inverse();
            }
        }
    }

    /// Loop-closing statistics (`None` when it is off, or its thread still runs).
    pub fn loop_stats(&self) -> Option<LoopStats> {
        match &self.looping {
            Looping::Off => None,
            Looping::Inline(l) => Some(l.stats().clone()),
            Looping::Thread(t) => t.stats().cloned(),
        }
    }

    /// (timestamp, camera-to-world) of every tracked frame, rebuilt from its pose relative to
    /// its reference keyframe and that keyframe's pose now (ORB-SLAM's `SaveTrajectoryTUM`):
    /// after loop corrections, the frames tracked before the loop follow their keyframes.
    /// Each comes with the number of the map it is in (its reference keyframe's, after merges).
    pub fn rebuilt_trajectory(&self) -> Vec<(f64, Se3, u32)> {
        let Ok(m) = self.map.lock() else {
            return Vec::new();
        };
        (0..self.anchors.len())
            .filter_map(|i| self.anchor_pose_wc(&m, i))
            .collect()
    }

    /// Tracking's state after the last frame.
    pub fn state(&self) -> TrackingState {
        self.tracker.state
    }

    /// Good keyframes, all maps.
    pub fn keyframe_count(&self) -> usize {
        self.map
            .lock()
            .map(|m| m.keyframes.values().filter(|k| !k.bad).count())
            .unwrap_or(0)
    }

    /// Map points in the map (all maps).
    pub fn map_point_count(&self) -> usize {
        self.map.lock().map(|m| m.points.len()).unwrap_or(0)
    }

    /// (timestamp, camera-to-world, map) of every good keyframe this run made, in order (a
    /// loaded map's keyframes carry another run's timestamps).
    pub fn keyframe_trajectory(&self) -> Vec<(f64, Se3, u32)> {
        self.map
            .lock()
            .map(|m| {
                m.keyframes
                    .values()
                    .filter(|k| !k.bad && k.id >= m.session_first_kf)
                    .map(|k| (k.timestamp, k.pose_cw.inverse(), k.map_epoch))
                    .collect()
            })
            .unwrap_or_default()
    }

    /// Local mapping time per keyframe (ms).
    pub fn mapping_times_ms(&self) -> Vec<f64> {
        self.mapping_ms
            .lock()
            .map(|t| t.clone())
            .unwrap_or_default()
    }

    /// Shared map (read it under the lock).
    pub fn map(&self) -> Arc<SharedMap> {
        self.map.clone()
    }
}

/// Monocular keyframes whose scale changed (a merge, a Sim(3) loop): the frames anchored to
/// them keep their relative rotation, their relative translation scales with it.
fn rescale_anchors(anchors: &mut [(f64, KfId, Se3)], c: &MapCorrection) {
    for (_, r, t_cr) in anchors.iter_mut() {
        if let Some(scale) = c.rescaled.get(r) {
            t_cr.translation.vector *= *scale;
        }
    }
}

/// The keyframe database relocalisation queries in a loaded map: the map's vocabulary, or one
/// trained from its keyframes (deterministic), with every good keyframe's bag of words.
fn relocalisation_database(
    map: &Map,
    vocabulary: Option<Vocabulary>,
    s: &SlamSettings,
) -> KeyFrameDatabase {
    let docs: Vec<(KfId, &[Descriptor])> = map
        .keyframes
        .values()
        .filter(|k| !k.bad)
        .map(|k| (k.id, k.descriptors.as_slice()))
        .collect();
    match vocabulary {
        Some(v) => {
            let mut db = KeyFrameDatabase::with_vocabulary(v);
            for (k, d) in docs {
                db.add(k, d);
            }
            db
        }
        None => {
            let mut db = KeyFrameDatabase::new();
            db.train(&docs, &s.loop_closing.database);
            db
        }
    }
}

/// A frame's observations as pose-optimisation terms on the map's points now, each point once:
/// a point fused into another since counts as the one that replaced it, a bad one not at all.
fn pose_observations(
    map: &Map,
    observations: &[FrameObservation],
    inv_sigma2: &[f64],
) -> Vec<PoseObservation> {
    let mut seen = BTreeSet::new();
    observations
        .iter()
        .filter_map(|o| {
            let (id, p) = map.point_or_its_replacement(o.point)?;
            if p.bad || !seen.insert(id) {
                return None;
            }
            Some(PoseObservation {
                world: p.position,
                u: o.u,
                v: o.v,
                u_right: (o.u_right > 0.0).then_some(o.u_right as f64),
                inv_sigma2: inv_sigma2.get(o.octave as usize).copied().unwrap_or(1.0),
            })
        })
        .collect()
}
