//! stillpoint-pipeline: the whole system on images.
//!
//! [`Pipeline`] takes a dataset's frames ([`stillpoint_core::Frame`]: gray, colour, depth or
//! a right image) and does everything between pixels and poses: ORB extraction (a bigger
//! extractor while a monocular map initialises, the right image in parallel for stereo), the
//! dynamic front-end when one is given (boxes, motion against the static world, culling, which
//! kept keypoints may not create map points), stereo depth per keypoint, tracking, local mapping
//! and loop closing. [`Pipeline::track`] returns what happened to one frame
//! ([`FrameResult`]); [`Pipeline::finish`] stops the threads and returns the trajectory (rebuilt
//! through the keyframes after a loop closed), the keyframe trajectory and the map.
//!
//! ```no_run
//! use stillpoint_pipeline::{Pipeline, PipelineSettings};
//! let seq = stillpoint_datasets::open("rgbd_dataset_freiburg3_walking_xyz".as_ref(), None, None)?;
//! let mut slam = Pipeline::new(PipelineSettings::from_dataset(seq.settings()), None, None);
//! for i in 0..seq.len() {
//!     let result = slam.track(&seq.frame(i)?)?;
//!     println!("{} {:?}", result.timestamp, result.pose_wc);
//! }
//! let run = slam.finish()?;
//! println!("{} poses, {} map points", run.trajectory.len(), run.map_points);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![deny(missing_docs)]

pub mod dense;
pub mod settings;

pub use settings::{Layered, SettingsError, Source};

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

use stillpoint_core::ms_since;

use stillpoint_core::{Frame, Sensor};
use stillpoint_features::{OrbExtractor, OrbParams};
use stillpoint_frontend::{EraseRecent, FrameInput, FrontEnd, PreviousPose, Regions, SceneObjects};
use stillpoint_geometry::Se3;
use stillpoint_image::stereo_depth::DenseStereo;
use stillpoint_image::{DepthMetres, Gray8};
use stillpoint_slam::data::Map;
use stillpoint_slam::map_file::{MapFile, MapFileError};
use stillpoint_slam::matching::stereo::{StereoParams, StereoView, stereo_depths};
use stillpoint_slam::module::loop_closing::LoopStats;
use stillpoint_slam::place::Vocabulary;
use stillpoint_slam::{
    Backfilled, Descriptor, Feature, KeypointDepth, LoadedMapMode, MapHygiene, SlamError,
    SlamSettings, System, TrackInput, TrackingState,
};
use stillpoint_trajectory::{Trajectory, TrajectoryError};

/// Why the pipeline stopped.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// Tracking refused a frame (bad input) or local mapping stopped.
    #[error("frame {index}: {source}")]
    Slam {
        /// The frame's index.
        index: usize,
        /// What the SLAM said.
        source: SlamError,
    },
    /// Stopping local mapping and loop closing failed.
    #[error("stopping: {0}")]
    Shutdown(SlamError),
    /// The poses do not make a trajectory (never expected: stamps are kept increasing).
    #[error("{0}")]
    Trajectory(#[from] TrajectoryError),
}

/// Frames offered ahead of [`Pipeline::track`] ([`Pipeline::frame_prefetch`]), from any thread.
#[derive(Clone, Debug)]
pub struct FramePrefetch(stillpoint_frontend::DetectionPrefetch);

impl FramePrefetch {
    /// `frame`, decoded and not tracked yet.
    pub fn offer(&self, frame: &Frame) {
        self.0.offer(
            frame.index,
            frame.timestamp,
            &frame.gray,
            frame.rgb.as_ref(),
        );
    }
}

/// Everything the pipeline needs besides a front-end and a vocabulary.
#[derive(Clone, Debug)]
pub struct PipelineSettings {
    /// Tracking, mapping and loop closing.
    pub slam: SlamSettings,
    /// The ORB extractor (the right image of a stereo pair uses the same).
    pub orb: OrbParams,
    /// Stereo matching along the rows (stereo pairs only).
    pub stereo: StereoParams,
}

impl PipelineSettings {
    /// Settings from a dataset's settings: monocular for a monocular sequence, else RGB-D (also
    /// for stereo, whose depth comes per keypoint; `bf` defaults to ORB-SLAM's TUM 40).
    pub fn from_dataset(s: &stillpoint_core::Settings) -> Self {
        let mut slam = if s.sensor == Sensor::Mono {
            SlamSettings::monocular(s.camera, s.fps)
        } else {
            SlamSettings::rgbd(s.camera, s.bf.unwrap_or(40.0), s.fps)
        };
        slam.th_depth = s.th_depth;
        slam.scale_factor = s.orb.scale_factor as f64;
        slam.n_levels = s.orb.n_levels.max(1);
        let orb = s.orb.clone();
        Self {
            slam,
            orb,
            stereo: StereoParams::default(),
        }
    }
}

/// Milliseconds spent on one frame, per stage.
#[derive(Clone, Copy, Debug, Default)]
pub struct FrameTimings {
    /// The detector (0 without a front-end).
    pub semantic_ms: f64,
    /// The front-end's motion check, judgement and culling (0 without a front-end).
    pub geometry_ms: f64,
    /// ORB extraction, and stereo matching for a pair.
    pub orb_ms: f64,
    /// Tracking (frame building included).
    pub tracking_ms: f64,
    /// Of `tracking_ms`, waiting for the map while local mapping or loop closing held it.
    pub map_wait_ms: f64,
}

impl FrameResult {
    /// The depth image of `frame` (the one this result is of): its own (RGB-D), or the one
    /// matched from its stereo pair.
    pub fn depth<'a>(&'a self, frame: &'a Frame) -> Option<&'a DepthMetres> {
        frame.depth.as_ref().or(self.stereo_depth.as_deref())
    }

    /// The poses this frame gave, in time order: the earlier frames a new monocular map took
    /// in ([`Self::backfilled`]), then this frame's own when tracked; (index, time, pose).
    pub fn poses_in_time_order(&self) -> impl Iterator<Item = (usize, f64, Se3)> + '_ {
        let late = self
            .backfilled
            .iter()
            .map(|b| (b.index, b.timestamp, b.pose_wc));
        late.chain(self.pose_wc.map(|p| (self.index, self.timestamp, p)))
    }
}

/// What happened to one frame.
#[derive(Clone, Debug)]
pub struct FrameResult {
    /// Position of the frame in its sequence.
    pub index: usize,
    /// The frame's time (seconds).
    pub timestamp: f64,
    /// Camera-to-world pose when tracked (TUM convention).
    pub pose_wc: Option<Se3>,
    /// Tracking's state after the frame.
    pub state: TrackingState,
    /// Every keypoint ORB found (level-0 pixels), culled ones included.
    pub keypoints: Vec<[f32; 2]>,
    /// Per keypoint: the pyramid level ORB found it on.
    pub octaves: Vec<u8>,
    /// The pixels where ORB kept no corner (the feature budget: last frame's movers); `None`
    /// when it kept them everywhere, the mask having given way too
    /// (`front_end.orb_exclusion_min_yield`). Part of the front-end's decision, with
    /// [`Self::dynamic`].
    pub excluded: Option<Arc<Gray8>>,
    /// Per keypoint: `true` = judged on a moving object: removed before tracking, or, where
    /// the frame offered its culled keypoints to the map (`front_end.offer_culled_to_map_below`,
    /// monocular), only matched closely to existing map points.
    pub dynamic: Vec<bool>,
    /// Per keypoint: kept for tracking but barred from creating map points (on an object not
    /// proven still); empty when none is.
    pub no_new_points: Vec<bool>,
    /// Boxes the front-end judged moving.
    pub dynamic_boxes: usize,
    /// The objects the front-end saw in the frame (for overlays, recordings and static dense
    /// maps); empty without a front-end.
    pub objects: SceneObjects,
    /// Map points matched by tracking (pose inliers).
    pub inliers: usize,
    /// Per keypoint: matched to a map point and kept by the pose (culled keypoints only where
    /// the frame offered them to the map); empty when the frame was not tracked.
    pub matched: Vec<bool>,
    /// The frame became a keyframe.
    pub new_keyframe: bool,
    /// Tracking was lost and came back in the same map.
    pub relocalised: bool,
    /// A new map was started.
    pub new_map: bool,
    /// Monocular, on the frame that started a map: earlier frames of this run (between the
    /// map's two first views) that got their poses now, oldest first. A run's trajectory and
    /// its count of tracked frames take them in.
    pub backfilled: Vec<Backfilled>,
    /// Stereo: the depth matched densely from the pair (every frame with a front-end, else
    /// keyframes only; `stereo.dense_depth`), 0 where no match was trusted.
    pub stereo_depth: Option<Arc<DepthMetres>>,
    /// Time per stage.
    pub timings: FrameTimings,
}

impl FrameResult {
    /// Keypoints removed as dynamic.
    pub fn culled(&self) -> usize {
        self.dynamic.iter().filter(|&&d| d).count()
    }

    /// Culled keypoints matched to map points and kept by the pose (only where the frame
    /// offered its culled keypoints to the map).
    pub fn culled_matched(&self) -> usize {
        self.dynamic
            .iter()
            .zip(&self.matched)
            .filter(|&(&d, &m)| d && m)
            .count()
    }
}

/// What a finished run leaves.
pub struct Finished {
    /// One pose per tracked frame, stamps increasing, each following its reference keyframe as
    /// bundle adjustment and loop closing left it (ORB-SLAM saves its trajectory this way); it
    /// differs from the poses [`Pipeline::track`] returned as the map was refined.
    pub trajectory: Trajectory,
    /// Frames of maps that never merged with the main one (the map holding the most frames),
    /// each map's in a frame of reference of its own: (map number, its trajectory).
    pub other_maps: Vec<(u32, Trajectory)>,
    /// The maps made and merged.
    pub maps: MapsReport,
    /// A loop closed during the run.
    pub loop_closed: bool,
    /// The keyframes' poses, in time order.
    pub keyframe_trajectory: Trajectory,
    /// Keyframes in the map.
    pub keyframes: usize,
    /// Map points in the map.
    pub map_points: usize,
    /// Local mapping's time per keyframe (ms).
    pub mapping_ms: Vec<f64>,
    /// Loop closing's statistics (`None` when it is off).
    pub loops: Option<LoopStats>,
    /// Frames given a pose only at the end ([`System::frames_placed_at_end`]): in the
    /// trajectory, in no frame's report.
    pub placed_at_end: usize,
    /// The stopped system: its map, for saving ([`System::map_file`]) or inspection.
    pub system: System,
}

/// The maps of a run: tracking lost for good starts a new one, a place of an older map seen
/// again merges the two (`slam.loop_closing.merge_maps`).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct MapsReport {
    /// Maps made: the first and each new one.
    pub made: usize,
    /// Merges of an older map into the current one.
    pub merged: usize,
    /// The map the trajectory is in: the one holding the most frames.
    pub main: u32,
    /// (map number, frames) of every map holding frames at the end, in map order.
    pub frames: Vec<(u32, usize)>,
}

/// The whole system: frames in, poses and a map out.
pub struct Pipeline {
    system: System,
    orb: OrbExtractor,
    /// Monocular initialisation matches level-0 keypoints only: more features until the map
    /// exists (ORB-SLAM3's initialisation extractor).
    orb_init: Option<OrbExtractor>,
    /// Stereo: the right image gets its own extractor (its pyramid is kept for matching).
    orb_right: OrbExtractor,
    front_end: Option<Box<dyn FrontEnd>>,
    /// What the front-end's last judgement said the next frame's ORB should skip.
    skip_next: Regions,
    /// The last frame fed and its pose, for the front-end's next frame.
    previous: Option<PreviousPose>,
    stereo: StereoParams,
    /// The dense stereo matcher's buffers (stereo with a front-end only).
    dense_stereo: DenseStereo,
    bf: f64,
    fx: f64,
    stamps: Vec<f64>,
    poses: Vec<Se3>,
    /// New maps started so far.
    new_maps: usize,
}

impl Pipeline {
    /// A pipeline; `front_end` `None` runs the baseline (no dynamic front-end), `vocabulary`
    /// `None` trains loop closing's vocabulary online. The front-end gets the camera of
    /// `settings` where its own settings left it unset.
    pub fn new(
        settings: PipelineSettings,
        front_end: Option<Box<dyn FrontEnd>>,
        vocabulary: Option<Vocabulary>,
    ) -> Self {
        let system = System::with_vocabulary(settings.slam.clone(), vocabulary);
        Self::with_system(settings, front_end, system)
    }

    /// A pipeline that starts in a map read from a file ([`stillpoint_slam::map_file::load`]):
    /// it relocalises in it, then maps on in it ([`LoadedMapMode::Extend`]) or only tracks
    /// against it ([`LoadedMapMode::Localize`]: the map is left as it was, the moving-object
    /// hygiene included). Fails when the map was made with another camera, sensor or ORB
    /// pyramid, or with another vocabulary than `vocabulary`; `None` uses the map's.
    ///
    /// ```no_run
    /// use stillpoint_pipeline::{Pipeline, PipelineSettings};
    /// use stillpoint_slam::LoadedMapMode;
    /// let seq = stillpoint_datasets::open("office_again".as_ref(), None, None)?;
    /// let map = stillpoint_slam::map_file::load("office.map".as_ref())?;
    /// let settings = PipelineSettings::from_dataset(seq.settings());
    /// let mut slam = Pipeline::with_map(settings, None, None, map, LoadedMapMode::Localize)?;
    /// for i in 0..seq.len() {
    ///     let r = slam.track(&seq.frame(i)?)?;
    ///     println!("{} {:?} relocalised: {}", r.timestamp, r.pose_wc, r.relocalised);
    /// }
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn with_map(
        settings: PipelineSettings,
        front_end: Option<Box<dyn FrontEnd>>,
        vocabulary: Option<Vocabulary>,
        map: MapFile,
        mode: LoadedMapMode,
    ) -> Result<Self, MapFileError> {
        let mut map = map;
        if let Some(v) = vocabulary {
            map.check_vocabulary(&v)?;
            map.vocabulary = Some(v);
        }
        let system = System::with_map(settings.slam.clone(), map, mode)?;
        Ok(Self::with_system(settings, front_end, system))
    }

    fn with_system(
        settings: PipelineSettings,
        mut front_end: Option<Box<dyn FrontEnd>>,
        system: System,
    ) -> Self {
        let slam = settings.slam;
        if let Some(f) = front_end.as_mut() {
            f.start(slam.camera);
        }
        let orb_init = slam.monocular.then(|| {
            OrbExtractor::new(OrbParams {
                n_features: settings.orb.n_features * slam.mono_init.feature_factor.max(1),
                ..settings.orb.clone()
            })
        });
        Self {
            orb: OrbExtractor::new(settings.orb.clone()),
            orb_init,
            orb_right: OrbExtractor::new(settings.orb),
            front_end,
            skip_next: Regions::default(),
            previous: None,
            stereo: settings.stereo,
            dense_stereo: DenseStereo::default(),
            bf: slam.bf,
            fx: slam.camera.fx,
            system,
            stamps: Vec::new(),
            poses: Vec::new(),
            new_maps: 0,
        }
    }

    /// The SLAM system (map, keyframe count, state) while the pipeline runs.
    pub fn system(&self) -> &System {
        &self.system
    }

    /// A handle for a recording's reader: each frame it decodes, offered before the frame's
    /// turn, lets the detector start on it while the frames before are tracked (the same
    /// boxes at the same frames: the run's result does not change). `None` without a detector
    /// on a schedule of frames.
    pub fn frame_prefetch(&self) -> Option<FramePrefetch> {
        self.front_end
            .as_ref()?
            .detection_prefetch()
            .map(FramePrefetch)
    }

    /// Track one frame: features, the front-end's judgement, depth, pose.
    pub fn track(&mut self, frame: &Frame) -> Result<FrameResult, PipelineError> {
        let mut timings = FrameTimings::default();
        let (w, h) = (frame.gray.width, frame.gray.height);
        // A stereo pair's dense depth, for the front-end (tracking matches keypoints itself).
        let t_dense = Instant::now();
        let mut stereo_depth_image = if self.front_end.is_some() {
            self.dense_stereo_depth(frame)
        } else {
            None
        };
        let depth_image = frame.depth.as_ref().or(stereo_depth_image.as_deref());
        let dense_stereo_ms = if stereo_depth_image.is_some() {
            ms_since(t_dense)
        } else {
            0.0
        };
        let t0 = Instant::now();
        let mut excluded = self.skip_next.mask(depth_image, w, h).map(Arc::new);
        self.orb.set_exclusion_mask(excluded.clone());
        // A monocular map starting: more corners, and the detector's boxes of this very frame.
        let map_starting = self.system.wants_initial_features(frame.index);
        let left_orb = match self.orb_init.as_mut() {
            Some(o) if map_starting => {
                // The map's first frames take every corner (the mask is not the init's).
                excluded = None;
                o
            }
            _ => &mut self.orb,
        };
        let orb_right = &mut self.orb_right;
        let input = FrameInput {
            index: frame.index,
            timestamp: frame.timestamp,
            gray: &frame.gray,
            rgb: frame.rgb.as_ref(),
            depth: depth_image,
            previous: self.previous.take(),
            own_boxes: map_starting,
        };
        let front_end = &mut self.front_end;
        // Left and right images in parallel, as ORB-SLAM does, and beside them the front-end's
        // motion check, which needs no keypoints (on two cores ORB's time leaves the frame's).
        // The check stays on this thread: its corner and LK buffers are kept per thread, and a
        // thread spawned a frame would allocate and zero them afresh every frame.
        let (feats, right_feats, measured, orb_ms) = std::thread::scope(|sc| {
            let right = frame
                .right
                .as_ref()
                .map(|r| sc.spawn(|| orb_right.extract(r)));
            // Without a right image, the left's levels are split over two threads; the check
            // shares the cores with them.
            let threads = if frame.right.is_some() { 1 } else { 2 };
            let left = sc.spawn(move || {
                let left = left_orb.extract_on(&frame.gray, threads);
                (left, ms_since(t0))
            });
            let measured = front_end.as_mut().is_some_and(|f| {
                std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| f.measure(&input)))
                    .map_err(|_| tracing::warn!("frame {}: the motion check panicked", input.index))
                    .is_ok()
            });
            let right = right.and_then(|h| h.join().ok());
            let (left, orb_ms) = match left.join() {
                Ok(left) => left,
                Err(payload) => std::panic::resume_unwind(payload),
            };
            (left, right, measured, orb_ms)
        });
        // Whole boxes (no depth) over a plain view can leave ORB far short of its budget, and
        // tracking with it: below the front-end's share, the budget left unspent goes to the
        // masked pixels (every corner found outside them stays), and the culling decides there.
        let (budget, found) = (self.orb.params().n_features, feats.keypoints.len());
        // (A share set above 1 asks no more than the whole budget.)
        let short = found < budget && (found as f32) < self.skip_next.min_yield() * budget as f32;
        let mut given_way = None;
        let (feats, orb_ms) = match excluded.take() {
            Some(mask) if depth_image.is_none() && short => {
                let t1 = Instant::now();
                // The corners FAST found under the mask, kept by the extraction just made.
                let more = self.orb.extract_masked(&frame.gray, budget - found);
                let mut feats = feats;
                feats.keypoints.extend(more.keypoints);
                feats.descriptors.extend(more.descriptors);
                given_way = Some(mask);
                (feats, orb_ms + ms_since(t1))
            }
            mask => {
                excluded = mask;
                (feats, orb_ms)
            }
        };
        timings.orb_ms = orb_ms;
        let mut features: Vec<Feature> = feats.keypoints.iter().map(Feature::from).collect();
        let keypoints: Vec<[f32; 2]> = features.iter().map(|k| [k.x, k.y]).collect();
        let octaves: Vec<u8> = features.iter().map(|k| k.octave).collect();
        let mut descriptors = feats.descriptors;
        let (mut dynamic, mut no_new_points, mut dynamic_boxes) = (Vec::new(), Vec::new(), 0);
        // What tracking does not see (the culled keypoints, unless offered to the map), and
        // the keypoints it may match only closely.
        let (mut removed, mut close_match_only) = (Vec::new(), Vec::new());
        let (mut objects, mut erase_recent) = (SceneObjects::default(), None);
        if let (Some(f), true) = (self.front_end.as_mut(), measured) {
            let judged = f.judge(&input, &keypoints);
            timings.semantic_ms = judged.semantic_ms;
            timings.geometry_ms = judged.geometry_ms + dense_stereo_ms;
            dynamic_boxes = judged.dynamic_boxes;
            // Monocular, once the map stands: the culled keypoints stay, to be matched to the
            // map's points only (closely) and to make none.
            let offered = judged.offer_culled_to_map
                && frame.right.is_none()
                && self.system.state() != TrackingState::NotInitialized;
            let mut no_new = judged.no_new_points;
            if offered {
                if no_new.len() != judged.dynamic.len() {
                    no_new = vec![false; judged.dynamic.len()];
                }
                for (n, d) in no_new.iter_mut().zip(&judged.dynamic) {
                    *n |= *d;
                }
                close_match_only = judged.dynamic.clone();
            } else {
                remove_dynamic(&mut features, &mut descriptors, &judged.dynamic);
                removed = judged.dynamic.clone();
            }
            if no_new.len() == judged.dynamic.len() {
                no_new_points = no_new;
            }
            dynamic = judged.dynamic;
            self.skip_next = judged.skip_next;
            erase_recent = judged.erase_recent;
            objects = judged.objects;
        }
        if dynamic.len() != keypoints.len() {
            dynamic = vec![false; keypoints.len()];
        }
        if removed.len() != keypoints.len() {
            removed = vec![false; keypoints.len()];
        }
        // Where the mask gave way (the movers' boxes and their margins) keypoints are tracked
        // only: a limb outside its box was kept off by the mask alone, and no culling sees it.
        if let Some(mask) = &given_way {
            if no_new_points.len() != keypoints.len() {
                no_new_points = vec![false; keypoints.len()];
            }
            for (barred, k) in no_new_points.iter_mut().zip(&keypoints) {
                *barred |= mask.get(k[0] as usize, k[1] as usize) > 0;
            }
        }
        // The kept keypoints' flags, in the order tracking sees them.
        let kept_no_new_points: Vec<bool> = if no_new_points.is_empty() {
            Vec::new()
        } else {
            no_new_points
                .iter()
                .zip(&removed)
                .filter(|(_, d)| !**d)
                .map(|(n, _)| *n)
                .collect()
        };
        // Stereo: depth for the kept left keypoints by matching them along the rows.
        let stereo_depth = match (&frame.right, &right_feats) {
            (Some(right), Some(rf)) => {
                let t1 = Instant::now();
                let right_keypoints: Vec<Feature> =
                    rf.keypoints.iter().map(Feature::from).collect();
                let d = stereo_depths(
                    &StereoView {
                        keypoints: &features,
                        descriptors: &descriptors,
                        levels: self.orb.pyramid(&frame.gray),
                    },
                    &StereoView {
                        keypoints: &right_keypoints,
                        descriptors: &rf.descriptors,
                        levels: self.orb_right.pyramid(right),
                    },
                    self.bf,
                    self.fx,
                    self.orb.scale_factors(),
                    &self.stereo,
                );
                timings.orb_ms += ms_since(t1);
                Some(d)
            }
            _ => None,
        };
        let depth = match &stereo_depth {
            Some(d) => KeypointDepth::PerKeypoint(d),
            None => frame.depth.as_ref().into(),
        };
        let hygiene = self.recent_points_on_movers_eraser(frame.index, depth_image, erase_recent);
        let report = self
            .system
            .track(TrackInput {
                depth,
                no_new_points: &kept_no_new_points,
                close_match_only: &close_match_only,
                hygiene,
                ..TrackInput::new(frame.index, frame.timestamp, &features, &descriptors)
            })
            .map_err(|source| PipelineError::Slam {
                index: frame.index,
                source,
            })?;
        timings.tracking_ms = report.tracking_ms;
        timings.map_wait_ms = report.map_wait_ms;
        if stereo_depth_image.is_none() && report.new_keyframe {
            // Without a front-end only keyframes need it (the dense cloud fuses keyframes).
            stereo_depth_image = self.dense_stereo_depth(frame);
        }
        self.previous = Some(PreviousPose {
            index: frame.index,
            pose_wc: report.pose_wc,
        });
        // Tracking saw the keypoints not removed: spread its flags back over all of them.
        let matched = if report.matched.is_empty() {
            Vec::new()
        } else {
            let mut kept = report.matched.iter();
            removed
                .iter()
                .map(|&d| !d && kept.next().copied().unwrap_or(false))
                .collect()
        };
        let result = FrameResult {
            index: frame.index,
            timestamp: frame.timestamp,
            pose_wc: report.pose_wc,
            state: report.state,
            keypoints,
            octaves,
            excluded,
            dynamic,
            no_new_points,
            dynamic_boxes,
            objects,
            inliers: report.inliers,
            matched,
            new_keyframe: report.new_keyframe,
            relocalised: report.relocalised,
            new_map: report.new_map,
            backfilled: report.backfilled,
            stereo_depth: stereo_depth_image,
            timings,
        };
        self.new_maps += result.new_map as usize;
        for (_, t, p) in result.poses_in_time_order() {
            if self.stamps.last().is_none_or(|&l| t > l) {
                self.stamps.push(t);
                self.poses.push(p);
            }
        }
        Ok(result)
    }

    /// A stereo pair's dense depth, when the pair has no depth image of its own.
    fn dense_stereo_depth(&mut self, frame: &Frame) -> Option<Arc<DepthMetres>> {
        let params = &self.stereo.dense_depth;
        match (&frame.right, &frame.depth) {
            (Some(right), None) if params.enabled => Some(Arc::new(self.dense_stereo.depth(
                &frame.gray,
                right,
                self.bf as f32,
                params,
            ))),
            _ => None,
        }
    }

    /// Map hygiene after tracking (RGB-D; the points the depth image sees through leave in
    /// `slam::System` itself): points made in the last frames on the surface of objects judged
    /// moving in this one leave the map
    /// (`FrontEndSettings::erase_recent_mover_points_frames`). The eraser the system runs once
    /// the frame has its pose, `None` when there is nothing to erase.
    fn recent_points_on_movers_eraser<'a>(
        &self,
        index: usize,
        depth: Option<&'a DepthMetres>,
        erase: Option<EraseRecent>,
    ) -> Option<MapHygiene<'a>> {
        let (Some(erase), Some(depth), false) = (erase, depth, self.system.localizing()) else {
            return None;
        };
        let mask = erase.movers.mask(Some(depth), depth.width, depth.height)?;
        let since = erase.since;
        let cam = self.system.settings.camera;
        Some(Box::new(move |m: &mut Map, pose_wc: &Se3| {
            let erased =
                m.erase_recent_points_on_movers(&pose_wc.inverse(), &cam, &mask, depth, since);
            if erased > 0 {
                tracing::debug!(frame = index, erased, "map points on movers erased");
            }
        }))
    }

    /// Stop local mapping and loop closing (waiting for their queues) and return the
    /// trajectory, the keyframes and the map.
    pub fn finish(mut self) -> Result<Finished, PipelineError> {
        self.system.shutdown().map_err(PipelineError::Shutdown)?;
        let loops = self.system.loop_stats();
        let loop_closed = loops.as_ref().is_some_and(|l| !l.loops.is_empty());
        // Every frame follows its reference keyframe as local BA and loop closing left it
        // (ORB-SLAM's SaveTrajectoryTUM): on the living-room presets 1.67 -> 1.54 cm mean ATE
        // against the poses tracking returned.
        let mut rebuilt = self.system.rebuilt_trajectory();
        rebuilt.dedup_by(|b, a| b.0 <= a.0);
        let by_map = split_by_map(&rebuilt);
        let main = main_map(&by_map);
        let merged = loops.as_ref().map_or(0, |l| {
            l.loops.iter().filter(|e| e.merged_map.is_some()).count()
        });
        let maps = MapsReport {
            made: 1 + self.new_maps,
            merged,
            main,
            frames: by_map.iter().map(|(k, (s, _))| (*k, s.len())).collect(),
        };
        let placed_at_end = self.system.frames_placed_at_end();
        let (trajectory, other_maps) = if rebuilt.len() < self.stamps.len() + placed_at_end {
            // A frame whose keyframe is gone: keep what tracking returned rather than lose it.
            tracing::warn!(
                rebuilt = rebuilt.len(),
                tracked = self.stamps.len(),
                "frames without a keyframe; the trajectory keeps the tracked poses"
            );
            (Trajectory::from_parts(self.stamps, self.poses)?, Vec::new())
        } else {
            let mut other_maps = Vec::new();
            let mut trajectory = Trajectory::from_parts(Vec::new(), Vec::new())?;
            for (map, (stamps, poses)) in by_map {
                let t = Trajectory::from_parts(stamps, poses)?;
                if map == main {
                    trajectory = t;
                } else {
                    other_maps.push((map, t));
                }
            }
            if !other_maps.is_empty() {
                tracing::warn!(
                    main_map = main,
                    other_maps = other_maps.len(),
                    frames = other_maps.iter().map(|(_, t)| t.len()).sum::<usize>(),
                    "frames of maps that never merged with the main one are left out of its trajectory"
                );
            }
            (trajectory, other_maps)
        };
        let mut kf = self.system.keyframe_trajectory();
        // The keyframes of the trajectory's map only, in its frame of reference.
        kf.retain(|k| other_maps.is_empty() || k.2 == main);
        kf.sort_by(|a, b| a.0.total_cmp(&b.0));
        kf.dedup_by(|a, b| a.0 == b.0);
        let keyframe_trajectory = Trajectory::from_parts(
            kf.iter().map(|k| k.0).collect(),
            kf.iter().map(|k| k.1).collect(),
        )?;
        Ok(Finished {
            trajectory,
            other_maps,
            maps,
            loop_closed,
            keyframe_trajectory,
            keyframes: self.system.keyframe_count(),
            map_points: self.system.map_point_count(),
            mapping_ms: self.system.mapping_times_ms(),
            loops,
            placed_at_end,
            system: self.system,
        })
    }
}

/// (stamps, camera-to-world poses) of each map's frames, in time order.
fn split_by_map(rebuilt: &[(f64, Se3, u32)]) -> BTreeMap<u32, (Vec<f64>, Vec<Se3>)> {
    let mut by_map: BTreeMap<u32, (Vec<f64>, Vec<Se3>)> = BTreeMap::new();
    for (t, p, map) in rebuilt {
        let e = by_map.entry(*map).or_default();
        e.0.push(*t);
        e.1.push(*p);
    }
    by_map
}

/// The map the trajectory is in: the one holding the most frames (the first of a tie).
fn main_map(by_map: &BTreeMap<u32, (Vec<f64>, Vec<Se3>)>) -> u32 {
    by_map
        .iter()
        .max_by_key(|(map, (stamps, _))| (stamps.len(), std::cmp::Reverse(**map)))
        .map_or(0, |(map, _)| *map)
}

/// Remove the keypoints flagged dynamic; returns how many were removed. A mask of the wrong
/// length is ignored (nothing removed) rather than trusted.
fn remove_dynamic(
    features: &mut Vec<Feature>,
    descriptors: &mut Vec<Descriptor>,
    dynamic: &[bool],
) -> usize {
    if dynamic.len() != features.len() || descriptors.len() != features.len() {
        return 0;
    }
    let before = features.len();
    let mut k = 0;
    features.retain(|_| {
        k += 1;
        !dynamic[k - 1]
    });
    let mut k = 0;
    descriptors.retain(|_| {
        k += 1;
        !dynamic[k - 1]
    });
    before - features.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_trajectory_is_the_map_holding_the_most_frames() {
        let at = |t: f64, map: u32| (t, Se3::identity(), map);
        let rebuilt = [
            at(0.0, 0),
            at(0.1, 0),
            at(0.5, 1),
            at(0.6, 1),
            at(0.7, 1),
            at(0.9, 2),
        ];
        let by_map = split_by_map(&rebuilt);
        assert_eq!(by_map[&1].0, vec![0.5, 0.6, 0.7]);
        assert_eq!(main_map(&by_map), 1);
        let tie = split_by_map(&rebuilt[..4]);
        assert_eq!(main_map(&tie), 0, "a tie goes to the first map");
        assert_eq!(main_map(&BTreeMap::new()), 0);
    }

    #[test]
    fn removes_flagged_keypoints_and_ignores_bad_masks() {
        let f = |x| Feature {
            x,
            y: 0.0,
            octave: 0,
            angle: 0.0,
        };
        let mut feats = vec![f(1.0), f(2.0), f(3.0)];
        let mut descs = vec![[1u8; 32], [2u8; 32], [3u8; 32]];
        assert_eq!(remove_dynamic(&mut feats, &mut descs, &[false, true]), 0);
        assert_eq!(
            remove_dynamic(&mut feats, &mut descs, &[false, true, false]),
            1
        );
        assert_eq!(feats, vec![f(1.0), f(3.0)]);
        assert_eq!(descs, vec![[1u8; 32], [3u8; 32]]);
    }
}
