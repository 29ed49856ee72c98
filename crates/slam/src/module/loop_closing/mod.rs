//! Loop closing (ORB-SLAM2/3 `LoopClosing`: an SE3 for RGB-D and stereo, where the scale is
//! known, a Sim(3) for monocular maps): per keyframe from local mapping, bag-of-words candidates, covisibility
//! consistency, geometric verification, then the correction: the keyframe's covisible group is
//! moved onto the loop, duplicated points are fused, and the essential graph is optimised.
//!
//! One file per stage: `detection` (candidates, consistency), `similarity` (matches, rigid
//! RANSAC, guided refinement, the loop group's projection), `correction` (moving the group,
//! fusing, the essential graph) and `global_ba`; this file holds the settings, the state and
//! the thread.
//!
//! [`LoopCloser::process`] does one keyframe (inline under `--sequential`); [`LoopThread`] runs
//! it in its own thread fed by local mapping through a channel. While it corrects the map it
//! holds the lock local mapping holds per keyframe, so local mapping stops between keyframes
//! (no busy-wait), and the map lock, so tracking waits for the correction as in ORB-SLAM.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::mpsc::Receiver;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use stillpoint_geometry::Se3;
use tracing::info;

use crate::SlamSettings;
use crate::data::{KfId, Map, MpId, SharedMap};
use crate::place::{DatabaseParams, KeyFrameDatabase, Vocabulary};

mod correction;
mod detection;
mod global_ba;
mod similarity;

/// Loop-closing parameters, ORB-SLAM's values unless said otherwise.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct LoopSettings {
    /// Run loop closing at all (`stillpoint run --no-loop-closing` turns it off).
    pub enabled: bool,
    /// Look for the current map's places in the older maps too (made when tracking was lost
    /// for good) and merge the two when one is found (ORB-SLAM3's atlas): the current map moves
    /// onto the older one as a whole, then the loop is corrected as any other.
    pub merge_maps: bool,
    /// Monocular runs close loops within a map too, correcting in Sim(3) (ORB-SLAM's
    /// monocular loop closing: each keyframe's pose and scale). Off: a monocular run only
    /// merges maps.
    pub monocular_loops: bool,
    /// A place found in an older map merges once this many more keyframes see it where the
    /// finder puts it: its best covisible ones, then the next new keyframes (ORB-SLAM3: three
    /// keyframes in all). Two new keyframes that do not see it drop it.
    pub merge_confirmations: usize,
    /// The finder's best covisible keyframes checked, at most this many.
    pub merge_check_keyframes: usize,
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
    /// Inliers a RANSAC hypothesis needs.
    pub ransac_min_inliers: usize,
    /// Inliers needed after guided matching and refinement (ORB-SLAM `OptimizeSim3`: 20).
    pub min_refined_inliers: usize,
    /// Matches with the loop keyframe's covisible group, after projecting its points, needed
    /// to accept the loop (ORB-SLAM: 40).
    pub min_loop_matches: usize,
    /// Ours, monocular: of the matches a loop or merge is placed on, this many
    /// ([`Self::min_refined_inliers`]) must be points triangulated over at least this much
    /// parallax (degrees; 0: no test). A monocular point seen only from keyframes a few
    /// centimetres apart has its depth set by their small relative pose, and a cluster of such
    /// points all err alike: a lap's first keyframes, 8 cm apart, put the loop 9 degrees and
    /// 18 cm from a camera that had drifted half a degree. The next keyframe along the revisit
    /// sees better-placed points.
    pub min_parallax_deg_monocular: f64,
    /// Ours, for a loop within one map: the correction it asks of the current keyframe may move
    /// it by at most this share of the path the keyframes travelled since the loop keyframe
    /// (plus `max_correction_floor_m`). A place that verifies yet asks to undo the whole path
    /// (the estimate went straight on, the loop says the camera never left) is a look-alike
    /// further along it: a street's repeated facades asked for 30-40 m over 30-40 m travelled.
    /// Drift itself stays below: in a room where a person corrupted the map (front-end off),
    /// true loops asked for up to 93 % of a 1.8 m path. 0: no limit.
    pub max_correction_share: f64,
    /// [`Self::max_correction_share`] for a loop within a monocular map (ours: 0.3). A
    /// monocular map holds no person who corrupted it unseen by depth, and its Sim(3) loop
    /// corrects scale along with pose, so real drift asks for a small share; a look-alike place
    /// on a drive asked for most of the path (a street 60 m apart in truth: 59 %).
    pub max_correction_share_monocular: f64,
    /// The least distance (m, map units) a correction may always move the keyframe.
    pub max_correction_floor_m: f64,
    /// The most a correction may turn the current keyframe (degrees; 0: no limit).
    pub max_correction_deg: f64,
    /// Search radii in pixels at octave 0: guided matching between the two keyframes
    /// (`SearchBySim3`: 7.5), projection of the loop group's points (`SearchByProjection`:
    /// 10), fusion into the corrected keyframes (`Fuse`: 4).
    pub guided_radius: f64,
    /// Radius of the projection of the loop group's points (`SearchByProjection`: 10).
    pub projection_radius: f64,
    /// Radius of the fusion into the corrected keyframes (`Fuse`: 4).
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
    /// Robust Levenberg-Marquardt steps of it, at most; it stops sooner once a step lowers
    /// the cost by less than a millionth (ORB-SLAM: 10 iterations. A monocular map just bent
    /// by a loop sits in a flat valley: `loop` read monocular at 320x240, seed 3, is 5.7 cm
    /// after 10 iterations and 2.2 cm at convergence, 20 steps: docs/maps.md).
    pub global_ba_iterations: usize,
    /// A rejected step of it is retried with more damping up to this many times in a row, and
    /// one more ends it (g2o's `maxTrialsAfterFailure`, in whose iterations ORB-SLAM's 10 are
    /// counted: 10); 0 = a rejection uses up an iteration, as local BA counts them.
    pub global_ba_trials_after_failure: usize,
    /// Global BA solves the reduced camera system densely: maps with more keyframes skip it.
    pub global_ba_max_keyframes: usize,
}

impl Default for LoopSettings {
    fn default() -> Self {
        Self {
            enabled: true,
            merge_maps: true,
            monocular_loops: true,
            merge_confirmations: 2,
            merge_check_keyframes: 5,
            database: DatabaseParams::default(),
            min_keyframes: 10,
            keyframes_after_loop: 10,
            consistency: 3,
            min_descriptor_matches: 20,
            match_ratio: 0.75,
            ransac_iterations: 300,
            ransac_min_inliers: 20,
            min_refined_inliers: 20,
            max_correction_share: 0.9,
            max_correction_share_monocular: 0.3,
            max_correction_floor_m: 0.5,
            max_correction_deg: 0.0,
            min_loop_matches: 40,
            min_parallax_deg_monocular: 5.0,
            guided_radius: 7.5,
            projection_radius: 10.0,
            fuse_radius: 4.0,
            correction_group_max: 30,
            essential_min_weight: 100,
            essential_max_covisibles: 10,
            pose_graph_iterations: 20,
            global_ba: true,
            global_ba_iterations: 100,
            global_ba_trials_after_failure: 10,
            global_ba_max_keyframes: 200,
        }
    }
}

/// One closed loop.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct LoopEvent {
    /// The keyframe that closed the loop.
    pub keyframe: KfId,
    /// Index of its frame.
    pub frame_index: usize,
    /// Time of its frame, seconds.
    pub timestamp: f64,
    /// The keyframe it was matched to.
    pub loop_keyframe: KfId,
    /// Index of that keyframe's frame.
    pub loop_frame_index: usize,
    /// Time of that keyframe's frame, seconds.
    pub loop_timestamp: f64,
    /// RANSAC inliers, inliers after refinement, matches with the loop group.
    pub ransac_inliers: usize,
    /// Inliers after guided matching and refinement.
    pub refined_inliers: usize,
    /// Matches with the loop keyframe's covisible group.
    pub loop_matches: usize,
    /// How far the keyframe moved (m, degrees): the drift the loop removed there.
    pub correction_m: f64,
    /// How far the keyframe turned, degrees.
    pub correction_deg: f64,
    /// The loop keyframe's map units per the current keyframe's (monocular: the scale drift
    /// the loop found; 1 with depth).
    pub correction_scale: f64,
    /// Keyframes in the essential graph and its edges.
    pub graph_keyframes: usize,
    /// Edges of the essential graph.
    pub graph_edges: usize,
    /// Time of the correction (fusion and pose graph), ms.
    pub correction_ms: f64,
    /// The loop keyframe was in an older map, merged into the current one: that map's number.
    pub merged_map: Option<u32>,
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
    /// Of those, the ones verification rejected.
    pub rejected_candidates: usize,
    /// Words in the vocabulary at the end.
    pub vocabulary_words: usize,
    /// The loops closed, in order.
    pub loops: Vec<LoopEvent>,
}

/// The keyframe poses a correction moved (world-to-camera, before and after): tracking moves
/// its last frame with its reference keyframe.
#[derive(Clone, Debug, Default)]
pub struct MapCorrection {
    /// Keyframe -> (world-to-camera pose before, after).
    pub poses: BTreeMap<KfId, (Se3, Se3)>,
    /// Monocular keyframes whose scale changed (a map merged into an older one took its scale;
    /// a loop corrected in Sim(3)): per keyframe, the factor by which the translation of a
    /// frame relative to it scales. Keyframes not in it keep theirs.
    pub rescaled: BTreeMap<KfId, f64>,
}

/// A place of an older map found by a keyframe whose covisible keyframes could not confirm it
/// yet: the next keyframes may (ORB-SLAM3 counts a merge's coincidences over new keyframes too).
struct PendingMerge {
    /// The keyframe that found it.
    kf: KfId,
    verified: Verified,
    /// Keyframes that saw the place so far (the finder and its covisible ones included).
    confirmed: usize,
    /// Later keyframes that did not see it.
    misses: usize,
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
    /// The loop keyframe's map's units per the current map's unit (1 but for monocular maps).
    scale: f64,
    ransac_inliers: usize,
    refined_inliers: usize,
}

impl LoopSettings {
    /// Whether a loop within one map that would move the current keyframe by `moved_m` and turn
    /// it by `turned_deg`, after `path_m` travelled since the loop keyframe, is drift
    /// ([`Self::max_correction_share`] or, `monocular`, [`Self::max_correction_share_monocular`];
    /// [`Self::max_correction_deg`]).
    pub fn correction_is_plausible(
        &self,
        moved_m: f64,
        turned_deg: f64,
        path_m: f64,
        monocular: bool,
    ) -> bool {
        let share = if monocular {
            self.max_correction_share_monocular
        } else {
            self.max_correction_share
        };
        let too_far = share > 0.0 && moved_m > self.max_correction_floor_m + share * path_m;
        let too_turned = self.max_correction_deg > 0.0 && turned_deg > self.max_correction_deg;
        !(too_far || too_turned)
    }
}

/// Loop-closing state: the keyframe database, the consistent groups, the loop edges.
pub struct LoopCloser {
    s: SlamSettings,
    /// Shared with tracking, which asks it for relocalisation candidates without waiting
    /// (`try_lock`: a frame that finds it busy, training, goes without).
    db: Arc<Mutex<KeyFrameDatabase>>,
    /// Covisibility groups of the last keyframe's candidates and how many consecutive
    /// keyframes each has been consistent for.
    groups: Vec<(BTreeSet<KfId>, usize)>,
    last_loop_kf: Option<KfId>,
    pending_merge: Option<PendingMerge>,
    loop_edges: BTreeSet<(KfId, KfId)>,
    scales: Vec<f64>,
    inv_sigma2: Vec<f64>,
    stats: LoopStats,
}

impl LoopCloser {
    /// A loop closer with an empty keyframe database (the vocabulary is trained online).
    pub fn new(s: SlamSettings) -> Self {
        Self {
            scales: s.scale_factors(),
            inv_sigma2: s.inv_level_sigma2(),
            s,
            db: Arc::new(Mutex::new(KeyFrameDatabase::new())),
            groups: Vec::new(),
            last_loop_kf: None,
            pending_merge: None,
            loop_edges: BTreeSet::new(),
            stats: LoopStats::default(),
        }
    }

    /// With a vocabulary given by the user (a DBoW2 file): no online training.
    pub fn with_vocabulary(s: SlamSettings, v: Vocabulary) -> Self {
        let mut c = Self::new(s);
        c.db = Arc::new(Mutex::new(KeyFrameDatabase::with_vocabulary(v)));
        c
    }

    /// Go on from a map loaded from a file: its good keyframes go into the keyframe database
    /// (once there is a vocabulary; an online one is trained at the next keyframe) and its loop
    /// edges into the essential graph.
    pub fn resume(&mut self, map: &Map, loop_edges: &BTreeSet<(KfId, KfId)>) {
        let mut db = lock(&self.db);
        for k in map.keyframes.values().filter(|k| !k.bad) {
            db.add(k.id, &k.descriptors);
        }
        drop(db);
        self.loop_edges.extend(loop_edges.iter().copied());
    }

    /// The place-recognition vocabulary, once trained or given.
    pub fn vocabulary(&self) -> Option<Vocabulary> {
        lock(&self.db).vocabulary().cloned()
    }

    /// The keyframe database, every map's keyframes once local mapping finished them: tracking
    /// asks it for relocalisation candidates (in a fresh run there is no other).
    pub fn database(&self) -> Arc<Mutex<KeyFrameDatabase>> {
        self.db.clone()
    }

    /// What it did so far.
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
        map: &SharedMap,
        kf: KfId,
        mapping_busy: Option<&Mutex<()>>,
        publish: Option<&Mutex<Vec<MapCorrection>>>,
    ) -> Option<MapCorrection> {
        // Monocular without loops within a map: until an older map exists there is nothing to
        // look for (the vocabulary is trained on every map's keyframes when there is).
        if self.s.monocular && !self.s.loop_closing.monocular_loops {
            let m = map.lock().ok()?;
            let lowest = m.keyframes.values().next();
            if lowest.is_none_or(|k| k.map_epoch >= m.epoch) {
                return None;
            }
        }
        let p = self.s.loop_closing.database.clone();
        // Train the vocabulary outside the map lock (it takes a while); copy the descriptors.
        let training: Option<Vec<(KfId, Vec<crate::Descriptor>)>> = {
            let m = map.lock().ok()?;
            // The keyframes places are searched among: the older maps' too when merging (a
            // training keeps only the keyframes it is given).
            let merge = self.s.loop_closing.merge_maps;
            let epoch = m.epoch;
            let searched = || {
                m.keyframes
                    .values()
                    .filter(move |k| !k.bad && (merge || k.map_epoch == epoch))
            };
            let n = searched().count();
            // Only keyframes local mapping has finished (ids up to this one): newer ones have
            // no covisibility yet, so they would not be excluded as neighbours of `kf`.
            lock(&self.db).needs_training(n, &p).then(|| {
                searched()
                    .filter(|k| k.id <= kf)
                    .map(|k| (k.id, k.descriptors.clone()))
                    .collect()
            })
        };
        if let Some(docs) = training {
            let t0 = Instant::now();
            let refs: Vec<(KfId, &[crate::Descriptor])> =
                docs.iter().map(|(k, d)| (*k, d.as_slice())).collect();
            lock(&self.db).train(&refs, &p);
            let ms = stillpoint_core::ms_since(t0);
            self.stats.training_ms.push(ms);
            self.stats.vocabulary_words = lock(&self.db).vocabulary().map_or(0, |v| v.words());
            info!(
                keyframes = docs.len(),
                words = self.stats.vocabulary_words,
                ms,
                "loop closing: vocabulary trained"
            );
            drop(docs);
            crate::module::return_freed_memory();
        }
        let t0 = Instant::now();
        let verified = {
            let m = map.lock().ok()?;
            let Some(k) = m.keyframes.get(&kf).filter(|k| !k.bad) else {
                self.groups.clear();
                return None;
            };
            lock(&self.db).add(kf, &k.descriptors);
            // A merge waiting for confirmation is checked in this keyframe first.
            self.confirm_pending_merge(&m, kf).or_else(|| {
                self.detect(&m, kf)
                    .and_then(|candidates| self.verify(&m, kf, &candidates))
                    .map(|v| (kf, v))
            })
        };
        self.stats.detection_ms.push(stillpoint_core::ms_since(t0));
        // (A confirmed merge is corrected at the keyframe that found it.)
        let (kf, v) = verified?;
        // Stop local mapping (it finishes its keyframe first), then take the map.
        let busy = mapping_busy.map(|b| b.lock().unwrap_or_else(|e| e.into_inner()));
        let mut m = map.lock().ok()?;
        let t1 = Instant::now();
        let outcome = self.correct(&mut m, kf, &v);
        let ms = stillpoint_core::ms_since(t1);
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
                self.stats.global_ba_ms.push(stillpoint_core::ms_since(t2));
            }
        }
        drop(busy);
        crate::module::return_freed_memory();
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
}

/// The keyframe database, whatever a panicking holder left in it (it stays consistent: every
/// change is one insertion or one training).
pub(super) fn lock(db: &Mutex<KeyFrameDatabase>) -> MutexGuard<'_, KeyFrameDatabase> {
    db.lock().unwrap_or_else(|e| e.into_inner())
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
    /// Start the thread: keyframes arrive from local mapping on `keyframes`; a correction holds
    /// `mapping_busy` so that local mapping waits between keyframes.
    pub fn spawn(
        closer: LoopCloser,
        map: Arc<SharedMap>,
        keyframes: Receiver<KfId>,
        mapping_busy: Arc<Mutex<()>>,
    ) -> std::io::Result<Self> {
        let corrections = Arc::new(Mutex::new(Vec::new()));
        let pending = corrections.clone();
        let handle = std::thread::Builder::new()
            .name("loop-closing".into())
            .spawn(move || {
                stillpoint_core::lower_this_thread_priority(closer.s.background_nice);
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

    /// The closer once [`LoopThread::finish`] returned.
    pub fn closer(&self) -> Option<&LoopCloser> {
        self.closer.as_ref()
    }

    /// The closer's statistics once [`LoopThread::finish`] returned.
    pub fn stats(&self) -> Option<&LoopStats> {
        self.closer.as_ref().map(|c| c.stats())
    }
}

#[cfg(test)]
mod tests {
    use super::LoopSettings;

    #[test]
    fn a_correction_is_plausible_only_as_drift() {
        let s = LoopSettings::default();
        // A lap of 6 m closing 20 cm and 3 degrees of drift.
        assert!(s.correction_is_plausible(0.2, 3.0, 6.0, false));
        // Short paths keep the floor (0.5 m); a map a person corrupted drifts far.
        assert!(s.correction_is_plausible(0.45, 1.0, 0.1, false));
        assert!(s.correction_is_plausible(1.85, 27.0, 2.26, false));
        // A street's look-alike facade 30 m on, over 30 m travelled.
        assert!(!s.correction_is_plausible(29.9, 0.6, 30.0, false));
        // Monocular (map units): a street 60 m apart in truth asked 1.6 over 2.7 travelled;
        // a lap's drift 0.2 over 3.
        assert!(!s.correction_is_plausible(1.6, 0.3, 2.7, true));
        assert!(s.correction_is_plausible(1.6, 0.3, 2.7, false));
        assert!(s.correction_is_plausible(0.2, 3.7, 3.0, true));
        // A turn limit, when one is set.
        let turning = LoopSettings {
            max_correction_deg: 30.0,
            ..LoopSettings::default()
        };
        assert!(!turning.correction_is_plausible(0.1, 60.0, 30.0, false));
        // 0 turns the limits off.
        let off = LoopSettings {
            max_correction_share: 0.0,
            max_correction_deg: 0.0,
            ..LoopSettings::default()
        };
        assert!(off.correction_is_plausible(29.9, 60.0, 30.0, false));
    }
}
