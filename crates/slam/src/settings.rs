//! Every tunable of the SLAM core, with ORB-SLAM3's defaults and where each comes from.

use serde::{Deserialize, Serialize};
use stillpoint_geometry::PinholeCamera;

fn default_scale_factor() -> f64 {
    1.2
}

fn default_n_levels() -> usize {
    8
}

/// Settings of tracking, local mapping and the optimisers.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SlamSettings {
    /// Camera of the (left / RGB) image, distortion included.
    pub camera: PinholeCamera,
    /// Monocular: no keypoint has depth; the map starts from two views
    /// ([`crate::module::initializer`]) at an arbitrary scale, and tracking and mapping use
    /// ORB-SLAM3's monocular rules. [`SlamSettings::monocular`] sets the thresholds that go with
    /// it.
    #[serde(default)]
    pub monocular: bool,
    /// Monocular initialisation.
    #[serde(default)]
    pub mono_init: MonoInitSettings,
    /// Baseline x fx in pixel-metres (`Camera.bf`): RGB-D uses it for the virtual right coordinate
    /// u_r = u - bf / z. ORB-SLAM TUM files use 40.
    pub bf: f64,
    /// Close/far split in baselines (`ThDepth`, ORB-SLAM TUM files: 40).
    pub th_depth: f64,
    /// Frames per second (`Camera.fps`): max frames between keyframes.
    pub fps: f64,
    /// ORB pyramid scale factor (`ORBextractor.scaleFactor`, 1.2). Not a setting of its own:
    /// the extractor's (`orb.scale_factor`) is copied here, so the two never disagree.
    #[serde(skip, default = "default_scale_factor")]
    pub scale_factor: f64,
    /// ORB pyramid levels (`ORBextractor.nLevels`, 8); the extractor's (`orb.n_levels`), as
    /// `scale_factor`.
    #[serde(skip, default = "default_n_levels")]
    pub n_levels: usize,
    /// Keypoints needed to initialise a map (ORB-SLAM, stereo and RGB-D: more than 500).
    pub init_min_keypoints: usize,
    /// Of those, keypoints with depth needed (ours: ORB-SLAM needs none; stereo matches only a
    /// part of the keypoints, ~60 % on synth, and a frame without depth must not start a map).
    pub init_min_with_depth: usize,
    /// Of a 4 x 4 grid over the image, cells holding a keypoint with depth needed to start a
    /// map (ours: 6; with depth a map needs far fewer than ORB-SLAM's 500 keypoints, but spread
    /// ones: a plain wall with one poster is no map). 0 turns the check off.
    pub init_min_cells_with_depth: usize,
    /// Hamming threshold for accepted matches (ORB-SLAM `ORBmatcher::TH_HIGH`).
    pub th_high: u32,
    /// Stricter Hamming threshold for BoW / brute-force matches (`ORBmatcher::TH_LOW`).
    pub th_low: u32,
    /// Motion-model search radius in pixels at octave 0 (ORB-SLAM3 RGB-D/stereo: 7; mono 15).
    pub motion_search_radius: f64,
    /// Fewer matches than this with the motion model doubles the radius (ORB-SLAM3: 20).
    pub motion_min_matches: usize,
    /// Local-map projection search window factor (ORB-SLAM3 `SearchLocalPoints`, RGB-D: 3,
    /// monocular: 1).
    pub local_map_search_th: f64,
    /// Nearest / second ratio in local-map search (ORB-SLAM3 `ORBmatcher(0.8)`).
    pub local_map_ratio: f32,
    /// Nearest / second ratio for reference-keyframe and relocalisation matching (ORB-SLAM3: 0.7).
    pub ref_kf_ratio: f32,
    /// Inliers after local-map tracking needed to call the frame tracked (ORB-SLAM3: 30).
    pub min_tracked_inliers: usize,
    /// Inliers needed to accept a relocalisation (ORB-SLAM3: 50).
    pub reloc_min_inliers: usize,
    /// Chi-square threshold, 3 DoF (u, v, u_r) residuals, 95 % (ORB-SLAM3: 7.815).
    pub chi2_stereo: f64,
    /// Chi-square threshold, 2 DoF (u, v) residuals, 95 % (ORB-SLAM3: 5.991).
    pub chi2_mono: f64,
    /// Pose optimisation rounds x iterations (ORB-SLAM3: 4 x 10).
    pub pose_rounds: usize,
    /// Iterations a round (ORB-SLAM3: 10).
    pub pose_iterations: usize,
    /// Keyframe ratio threshold vs the reference keyframe's tracked points (ORB-SLAM3 RGB-D: 0.75,
    /// monocular: 0.9).
    pub kf_ref_ratio: f64,
    /// Close points tracked below this and ...
    pub kf_close_tracked_max: usize,
    /// ... untracked close points above this force a keyframe (ORB-SLAM3: 100 / 70).
    pub kf_close_untracked_min: usize,
    /// Ours: the close-points rule asks for a keyframe only this many frames after the last
    /// one (0: ORB-SLAM3, on any frame). In rooms whose walls hold little texture it fired on
    /// nearly every other frame; at 2 the realistic RGB-D rooms make 37 % fewer keyframes at
    /// the same ATE (docs/realtime.md).
    pub kf_close_min_gap_frames: usize,
    /// Fewer tracked inliers than this also ask for a keyframe (ours, not in ORB-SLAM3: 50). In
    /// dynamic scenes the front-end removes a third to half of the keypoints, and the reference
    /// keyframe can have too few well-observed points for the 0.75 ratio to fire while the
    /// inliers sink until tracking is lost. 0 gives ORB-SLAM3's rule. Measurements:
    /// docs/measurements.md.
    pub kf_weak_tracking_inliers: usize,
    /// Ours: a map point rejected by the chi-square test of local-map tracking this many times,
    /// and at least as often as it was found, is erased at once (0 = off). ORB-SLAM3 only culls
    /// points by found/visible during their first 3 keyframes; a point on a mover that the
    /// front-end missed keeps failing afterwards. Off by default: its effect on accuracy was
    /// erratic. Measurements: docs/measurements.md.
    pub point_max_rejections: u32,
    /// RGB-D map hygiene (ours): a map point through which the depth image shows a surface
    /// well behind it in this many frames is erased (`Map::erase_points_seen_through`; 0 = off):
    /// the point is no longer there, most often one made on a mover that has gone.
    /// Measurements: docs/measurements.md.
    pub erase_seen_through_after: u32,
    /// Ours: each tracked frame's pose is optimised again against the map once local mapping
    /// has refined the keyframes around it (this many keyframes later; 0 = off, ORB-SLAM's
    /// saved trajectory), and the frame then follows its reference keyframe from there. ORB-SLAM
    /// keeps a frame's pose relative to its reference keyframe as tracking left it, so a
    /// keyframe that bundle adjustment later moves a long way (one made while a mover the
    /// detector missed dragged tracking) drags its frames along although they were tracked
    /// right. Measurements: docs/measurements.md.
    #[serde(default = "default_settle_keyframes")]
    pub trajectory_settle_keyframes: usize,
    /// Ours: frames settle on the map the run ends with, not `trajectory_settle_keyframes`
    /// keyframes later: the points a frame saw are refined again whenever later keyframes see
    /// them (a hand-held camera comes back) and by loop corrections, so a pose optimised
    /// against the final map fits the map the trajectory is read in. Past
    /// `trajectory_settle_max_pending` waiting frames the oldest settle on the map as it is
    /// then. `false`: `trajectory_settle_keyframes` keyframes later (the release before's
    /// rule); `trajectory_settle_keyframes = 0` turns settling off either way. Measurements:
    /// docs/measurements.md.
    #[serde(default = "default_settle_at_end")]
    pub trajectory_settle_at_end: bool,
    /// ... the settled pose is kept when it has at least this many inliers (else the frame
    /// follows its keyframe as tracking left it).
    #[serde(default = "default_settle_min_inliers")]
    pub trajectory_settle_min_inliers: usize,
    /// ... and at most this many frames wait to settle: older ones settle on the map as it is
    /// (each waiting frame's observations hold memory, about 20 KiB). Default 300, 10 s at 30
    /// Hz. Measurements: docs/measurements.md.
    #[serde(default = "default_settle_max_pending")]
    pub trajectory_settle_max_pending: usize,
    /// ... and with local mapping in its own thread (real time) at most this many settle after
    /// one frame (0 = no limit), the rest after the next frames or at the end: a batch of frames
    /// due at once would hold up the tracking thread. Inline mapping (`run --sequential`)
    /// settles every due frame at once. Measurements: docs/measurements.md.
    #[serde(default = "default_settle_max_per_frame")]
    pub trajectory_settle_max_per_frame: usize,
    /// Monocular: a frame tracked within this many seconds of its map's start keeps its
    /// keypoints, and settles on the points of the final map that its keyframes' neighbourhood
    /// holds, matched again around its pose, not only on the points it was tracked against
    /// (0 = off). A young map's first points come from two views a degree or so apart; half of
    /// them are culled later, and a frame tracked on them settled on the rest, biased, while
    /// the keyframes around it, seeing the better points made since, stood right.
    /// Measurements: docs/monocular.md.
    #[serde(default = "default_settle_rematch_seconds")]
    pub trajectory_settle_rematch_seconds: f64,
    /// ... and the settling frame's position is held near where its neighbours in time put
    /// it (the mean of the positions interpolated between the k-th frame before and the k-th
    /// after, k = 1 to `trajectory_smooth_neighbours`, each at most
    /// `trajectory_smooth_max_gap_s` away): a prior with this standard deviation, as a share of
    /// the median depth of the points the frame sees (ours: 0.001, 2.5 mm at 2.5 m; 0 = off; a
    /// share, so that a monocular map's unknown scale does not matter). A frame's pose from
    /// its own keypoints alone jitters along the directions they fix weakly (a sideways shift
    /// and a turn look alike on walls at one depth), millimetres a frame, where a camera at
    /// 30 Hz moves smoothly. The rotation stays the observations'. Measurements:
    /// docs/measurements.md.
    #[serde(default = "default_smooth_sigma_depth")]
    pub trajectory_smooth_sigma_depth: f64,
    /// ... the pairs of neighbours (ours: 2).
    #[serde(default = "default_smooth_neighbours")]
    pub trajectory_smooth_neighbours: usize,
    /// ... the farthest a neighbour may be in time, seconds.
    #[serde(default = "default_smooth_max_gap_s")]
    pub trajectory_smooth_max_gap_s: f64,
    /// ... "well behind": by more than this many pixels of virtual disparity (`bf / z`) and
    /// 10 cm (ours: 1 px). Measurements: docs/measurements.md.
    pub seen_through_gap_px: f64,
    /// New RGB-D keyframes create map points from depth for at least this many closest keypoints
    /// (ORB-SLAM3 `CreateNewKeyFrame`: 100).
    pub kf_new_points_min: usize,
    /// Two keyframes' rays to a new point without depth must meet at an angle whose cosine is
    /// below this (ORB-SLAM3 `CreateNewMapPoints`: 0.9998, 1.15 degrees).
    pub new_point_max_cos_parallax: f64,
    /// Monocular: the parallax cut `new_point_max_cos_parallax` is also asked at the depth the
    /// keyframe's map points round the keypoint have (a quantile of its cell of the image,
    /// `new_point_prior_depth_quantile`), and of the point's own two rays
    /// `new_point_max_cos_parallax_measured`. A pair's noise widens some far points' rays past
    /// the cut and narrows others', so a cut on the rays alone keeps
    /// far points made too near (the map's scale shrinks along a drive); at the neighbours'
    /// depth their noise cannot pass them (docs/monocular.md).
    #[serde(default = "default_true")]
    pub new_point_parallax_from_neighbours: bool,
    /// With `new_point_parallax_from_neighbours`: the cosine the point's own two rays must be
    /// below (0.9998 as the cut; 0.99999, 0.26 degrees, leaves the decision to the neighbours'
    /// depth: measured in docs/monocular.md).
    #[serde(default = "default_new_point_max_cos_parallax_measured")]
    pub new_point_max_cos_parallax_measured: f64,
    /// With `new_point_parallax_from_neighbours`: which depth of a cell's map points is asked,
    /// as a quantile, nearest 0 (ours: 0.5, the median). The map's own points set that depth,
    /// so where they lie too far the nearer points that would correct them are refused; a
    /// lower quantile lets them in, and lets in more of a turning camera's and a drive's
    /// poorly seen points (measured in docs/monocular.md).
    #[serde(default = "default_new_point_prior_depth_quantile")]
    pub new_point_prior_depth_quantile: f64,
    /// Covisibility edge weight: shared points needed for an edge (ORB-SLAM3: 15).
    pub covisibility_min_shared: usize,
    /// Neighbours taken into the local map (ORB-SLAM3 tracking: 10 per keyframe).
    pub local_neighbours: usize,
    /// Covisible keyframes local mapping triangulates and fuses with (ORB-SLAM3
    /// `CreateNewMapPoints`, `SearchInNeighbors`: 10 stereo/RGB-D, 30 monocular).
    #[serde(default = "default_mapping_neighbours")]
    pub mapping_neighbours: usize,
    /// Ours: threads that match and triangulate the new keyframe with its neighbours when
    /// local mapping runs inline (a recording), each taking a share of the neighbours; the
    /// points are added in the neighbours' order, so the map is the same for any count.
    /// Monocular 2: matching along epipolar lines is a third of a monocular keyframe's mapping
    /// (30 neighbours, nearly every keypoint free), and on a recording the second core waits
    /// while a keyframe is mapped. With depth 1: a keyframe has few free keypoints (1.3-1.6
    /// ms of a 22 ms keyframe on the RGB-D room), no gain, and the second thread's allocator
    /// arena costs 4 MB. With local mapping on its own thread it stays one: tracking shares the
    /// map lock. Measurements: docs/realtime.md.
    #[serde(default = "default_triangulation_threads")]
    pub triangulation_threads: usize,
    /// Local BA optimises the new keyframe and at most this many - 1 of its best covisible
    /// keyframes (ours; ORB-SLAM takes them all).
    pub local_ba_max_keyframes: usize,
    /// Local mapping triangulates new points between the new keyframe and its neighbours
    /// (ORB-SLAM3 `CreateNewMapPoints`).
    pub triangulate_new_points: bool,
    /// Map points whose found/visible ratio falls below this are culled (ORB-SLAM3: 0.25).
    pub point_found_ratio: f64,
    /// Map points with at most this many observations 2 keyframes after creation are culled;
    /// an observation with depth counts 2, as in ORB-SLAM3 (`cnThObs`: 3 stereo/RGB-D, 2 mono),
    /// so an RGB-D point must be seen with depth by 2 keyframes.
    pub point_min_observations: usize,
    /// Keyframe culling redundancy (ORB-SLAM3: 0.9).
    pub kf_redundancy: f64,
    /// Ours: a redundant keyframe is kept when culling it would leave more than this many
    /// seconds between the good keyframes before and after it (0 = no limit, as ORB-SLAM3
    /// without an IMU; with one it keeps 0.5 s). Where a keyframe comes every frame (stereo in
    /// a plain room while a person hides its texture) each is redundant with its neighbours,
    /// and culling one after the other left none for 3.7 s. Measurements: docs/results.md.
    #[serde(default = "default_kf_cull_max_gap_s")]
    pub kf_cull_max_gap_s: f64,
    /// ... the same for a monocular map (0 = no limit, ORB-SLAM3). A turning camera asks for a
    /// keyframe on nearly every frame and each is redundant with its neighbours; culled one
    /// after the other they end up degrees apart and the map bends where the camera turns
    /// (docs/monocular.md).
    #[serde(default = "default_kf_cull_max_gap_s_monocular")]
    pub kf_cull_max_gap_s_monocular: f64,
    /// Local BA iterations before and after outlier removal (ORB-SLAM3: 5 + 10).
    pub ba_iterations: [usize; 2],
    /// Run local mapping (and loop closing) in their own threads, as ORB-SLAM3 does: for live
    /// input, where tracking must not wait for them (`run` sets it for a camera and
    /// `--realtime`). `false` (the default) maps inline after each keyframe: the result is the
    /// same however busy the machine is, which a recording needs.
    pub local_mapping_thread: bool,
    /// How many nice steps (Linux) the local-mapping and loop-closing threads run below tracking.
    /// On two cores beside a detector, tracking must not wait for mapping (ORB-SLAM's tracking is
    /// the real-time thread too); a busy mapper then takes fewer keyframes, as ORB-SLAM's does.
    pub background_nice: i32,
    /// Frames of failed relocalisation after which a new map is started (ORB-SLAM3 Atlas starts a
    /// new map when relocalisation keeps failing; 1 s of frames here).
    pub new_map_after_lost_frames: usize,
    /// Ours: for this many frames after tracking is lost, the last tracked frame's matches are
    /// searched for from where it stood before relocalisation is tried; the frame counts as
    /// tracked when the local map then gives `recover_min_inliers` (0: ORB-SLAM's way, straight
    /// to relocalisation). 1 s of frames.
    pub recover_lost_frames: usize,
    /// Inliers of the local map that search needs (a relocalisation needs `reloc_min_inliers`).
    pub recover_min_inliers: usize,
    /// That search's windows, as a multiple of the local map's (`local_map_search_th` 1 is
    /// ORB-SLAM's 2.5-4 px at level 0).
    pub recover_search_th: f64,
    /// Monocular: keep relocalising in the lost map while a new map waits for its two views
    /// (ORB-SLAM3 stops at the new map's first frame): a camera back on mapped ground within a
    /// few frames stays in one map instead of starting a second one from scratch.
    #[serde(default = "default_true")]
    pub relocalise_while_initialising: bool,
    /// Relocalisation tries the keyframes of every map, not only the current one's; a frame
    /// found in an older map makes that map current again (the one left becomes an older map
    /// that may merge later). Place recognition's candidates come from every map; the nearest
    /// keyframes of older maps only with depth or stereo (a new monocular map has a frame of its
    /// own).
    #[serde(default = "default_true")]
    pub relocalise_in_every_map: bool,
    /// A fresh run relocalises by place recognition too: the loop closer's keyframe database
    /// (every map's keyframes, once its vocabulary is trained) proposes candidates before the
    /// nearest keyframes are tried. A monocular run has no other way into an older map. Off:
    /// only a loaded map's database proposes.
    #[serde(default = "default_true")]
    pub relocalise_with_loop_database: bool,
    /// Keyframes tried per relocalisation attempt (ORB-SLAM3 uses BoW candidates; we take the most
    /// recent and the closest to the last pose).
    pub reloc_candidates: usize,
    /// Loop closing (ORB-SLAM's, SE3 for RGB-D / stereo).
    #[serde(default)]
    pub loop_closing: crate::module::loop_closing::LoopSettings,
}

fn default_true() -> bool {
    true
}

fn default_mapping_neighbours() -> usize {
    10
}

fn default_triangulation_threads() -> usize {
    1
}

/// Monocular initialisation (ORB-SLAM `Tracking::MonocularInitialization` and `Initializer` /
/// ORB-SLAM3 `TwoViewReconstruction`).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default)]
pub struct MonoInitSettings {
    /// A reference frame needs more keypoints than this, and so does the frame matched to it
    /// (ORB-SLAM: 100).
    pub min_keypoints: usize,
    /// Half-size of the square window around a keypoint's last matched position in which it is
    /// searched (ORB-SLAM `SearchForInitialization(..., 100)`).
    pub window_px: f64,
    /// Nearest / second Hamming ratio (ORB-SLAM `ORBmatcher(0.9, true)`).
    pub ratio: f32,
    /// Keypoints up to this pyramid level are matched, each to keypoints of its own level
    /// (ORB-SLAM: 0, the finest level only). 2 starts the synthetic rooms' slow cameras at
    /// frame 0 (level 0 holds a fifth of the keypoints), but it delayed the real bedroom clip's
    /// map from frame 9 to 40, so it stays 0 (docs/monocular.md).
    pub max_octave: i32,
    /// Ours: where the matches up to `max_octave` give no two-view reconstruction, keypoints
    /// up to this level are matched as well (each to its own level, in a search of their own)
    /// and tried (`max_octave` or below: off, ORB-SLAM's way). 2: the slow cameras of the
    /// rooms' seed 2 are tracked from frame 0 instead of 45, the real clips as before
    /// (docs/monocular.md).
    pub fallback_max_octave: i32,
    /// Ours: the coarser levels are tried only once the reference has been held this many
    /// frames: a camera that renews its reference keeps ORB-SLAM's way (tried at once, the
    /// street with YOLOX started from frame 3 and drifted twice as far), a slow one that holds
    /// one reference without parallax enough at the finest level gets the second try.
    pub fallback_after_frames: usize,
    /// Fewer matches than this drop the reference frame (ORB-SLAM: 100) ...
    pub min_matches: usize,
    /// ... unless they fell below this share of the previous frame's matches at once and the
    /// next frame matches the reference again (ours: 0.8; 0, ORB-SLAM's rule: the frame after
    /// the short one becomes the reference). A walker's box (culled, and kept off by ORB's
    /// budget) that sweeps over the reference's ground takes a third of the matches in one
    /// frame while the view is still there; a camera that moves on loses them a few at a time
    /// and drops the reference as ORB-SLAM does, and one that stays short after a sudden fall
    /// too, on the next frame, which then becomes the reference as ORB-SLAM's rule makes it.
    /// The short frame is kept for tracking once the map stands.
    pub keep_reference_over_sudden_fall: f64,
    /// RANSAC iterations of 8 points for H and F (ORB-SLAM: 200).
    pub ransac_iterations: usize,
    /// Parallax needed, degrees (ORB-SLAM: 1).
    pub min_parallax_deg: f64,
    /// Triangulated points needed (ORB-SLAM: 50).
    pub min_triangulated: usize,
    /// Share of the two-view model's inliers that must triangulate (ORB-SLAM: 0.9).
    pub min_triangulated_share: f64,
    /// Rounds of refitting the best RANSAC sample's fundamental matrix to all its inliers, kept
    /// while its score grows (ORB-SLAM: 0). It changes the motion only: the choice between the
    /// homography and F compares the two samples' scores (compared refitted, F took the real
    /// bedroom clip's turning views from the homography and its map never started). Alone it
    /// started the synthetic rooms later, so it stays 0 (docs/monocular.md).
    pub refit_rounds: usize,
    /// Ours: where the homography is chosen but two of its motions explain the points about as
    /// well, the fundamental matrix's motion is tried (ORB-SLAM: false, no map from that pair).
    /// A road ahead with house fronts gives such pairs: the road dominates the homography's
    /// score, the fronts fix F's motion (docs/measurements.md).
    pub fundamental_when_ambiguous: bool,
    /// A two-view map that bundle adjustment leaves with too few points drops the reference
    /// frame (ORB-SLAM: true). False keeps it: a later frame, with more parallax, may pass.
    pub reset_on_rejection: bool,
    /// The homography is chosen when S_H / (S_H + S_F) is above this. ORB-SLAM2 0.40, ORB-SLAM3
    /// 0.50. 0.40: when the scene is a plane both models explain it and the share is near 0.5,
    /// and the fundamental matrix of a plane is degenerate, so ties go to the homography; a
    /// scene with depth gives shares far below either value (measured in the two-view tests).
    pub homography_ratio: f64,
    /// Points the initial map must keep after bundle adjustment (ORB-SLAM2: 100; ORB-SLAM3: 50).
    pub min_points_after_ba: usize,
    /// Features the extractor should deliver while initialising, as a multiple of the usual
    /// count (ORB-SLAM3 `mpIniORBextractor`: 5): initialisation matches level-0 keypoints only.
    /// Read by the caller that extracts features ([`crate::System::wants_initial_features`]).
    pub feature_factor: usize,
    /// Seconds after the map starts during which frames are still extracted with
    /// `feature_factor` times the features (ORB-SLAM3: `mMaxFrames`, one second of frames).
    pub young_map_seconds: f64,
    /// Ours: after `young_map_seconds`, frames are still extracted with `feature_factor` times
    /// the features while the last frame tracked fewer than `thin_map_inliers` map points, up
    /// to this many seconds after the map starts. A map started from little parallax (a slow
    /// hand-held camera) has few points, and its keyframes triangulate few more until the
    /// camera has moved on. 0 (ORB-SLAM's one second only): 5 kept living_turn seed 2's thin
    /// map (300 of 300 frames against 217), but the real bedroom clip's frames then culled
    /// twice as many keypoints (docs/monocular.md).
    pub thin_map_seconds: f64,
    /// See `thin_map_seconds`.
    pub thin_map_inliers: usize,
    /// Ours: once the map stands, the frames offered to the initialiser (up to this many, the
    /// newest) are tracked in it and get their poses late: those between its two views, and
    /// (`backfill_before_reference`) those of earlier reference frames dropped for too few
    /// matches, so that a recording's trajectory starts where the camera first saw the map's
    /// ground rather than at the frame that had the parallax (0: ORB-SLAM's way, those frames
    /// stay without a pose).
    pub backfill_frames: usize,
    /// Ours: the frames of reference frames dropped for too few matches are kept too, and
    /// tracked back from the map's first view until one fails. A turning hand-held camera in a
    /// plain room drops one or two references before one starts the map; a car driving forward
    /// gets those frames placed from far-off points, 5-10 % off along the road (false: the
    /// trajectory starts at the map's first view; docs/monocular.md).
    pub backfill_before_reference: bool,
    /// Ours: the frames before a map stood that its first two views could not track (their
    /// points too few by then: a car driving forward sees the map's ground small and far) are
    /// tracked once more at the end of the run, back from the map's first tracked frame until
    /// one fails, in the map as it ended, whose later keyframes hold many more points there
    /// (false: they stay without a pose). Measurements: docs/monocular.md.
    pub place_before_map_at_end: bool,
    /// Ours: with local mapping in its own thread (live input), for this many seconds after a
    /// monocular map starts each new keyframe is mapped before the next frame is tracked, as on
    /// a recording (0: never). A young map holds 100-200 points and a frame tracked before the
    /// last keyframe's points are made can lose it: a live living_turn run on a busy machine
    /// lost its map at frame 12 and ended 5.9 cm off. Live frames that arrive meanwhile are
    /// dropped, as when tracking is slow: at 2 s a busy machine's live runs kept 205-283 of 300
    /// frames, at 0.5 s 295-300 (docs/realtime.md).
    pub map_keyframes_at_once_seconds: f64,
}

impl MonoInitSettings {
    /// How many frames of a dropped reference the initialiser keeps.
    pub fn frames_kept_before(&self) -> usize {
        if self.backfill_before_reference {
            self.backfill_frames
        } else {
            0
        }
    }
}

impl Default for MonoInitSettings {
    fn default() -> Self {
        Self {
            min_keypoints: 100,
            window_px: 100.0,
            ratio: 0.9,
            max_octave: 0,
            fallback_max_octave: 2,
            fallback_after_frames: 10,
            min_matches: 100,
            keep_reference_over_sudden_fall: 0.8,
            ransac_iterations: 200,
            min_parallax_deg: 1.0,
            min_triangulated: 50,
            min_triangulated_share: 0.9,
            refit_rounds: 0,
            fundamental_when_ambiguous: true,
            reset_on_rejection: true,
            homography_ratio: 0.4,
            min_points_after_ba: 100,
            feature_factor: 5,
            young_map_seconds: 1.0,
            thin_map_seconds: 0.0,
            thin_map_inliers: 100,
            backfill_frames: 100,
            backfill_before_reference: true,
            place_before_map_at_end: true,
            map_keyframes_at_once_seconds: 0.5,
        }
    }
}

impl SlamSettings {
    /// Monocular settings with ORB-SLAM3's monocular values where they differ from RGB-D:
    /// motion-model radius 15 px, local-map search window 1, keyframe ratio 0.9 (no close-point
    /// rule), points culled with fewer than 2 observations, triangulation and fusion with 30
    /// neighbours. `bf` only scales the unused virtual right coordinate; 40 as for RGB-D.
    pub fn monocular(camera: PinholeCamera, fps: f64) -> Self {
        Self {
            monocular: true,
            motion_search_radius: 15.0,
            local_map_search_th: 1.0,
            kf_ref_ratio: 0.9,
            point_min_observations: 2,
            mapping_neighbours: 30,
            triangulation_threads: 2,
            ..Self::rgbd(camera, 40.0, fps)
        }
    }

    /// RGB-D settings with ORB-SLAM3's defaults for a camera, `bf` and frame rate.
    pub fn rgbd(camera: PinholeCamera, bf: f64, fps: f64) -> Self {
        Self {
            camera,
            monocular: false,
            mono_init: MonoInitSettings::default(),
            bf,
            th_depth: 40.0,
            fps,
            scale_factor: 1.2,
            n_levels: 8,
            // Ours: a depth camera starts a map on the first frame with 100 keypoints, 80 with
            // depth, spread over 6 of 16 cells (ORB-SLAM waits for 500 keypoints, which a plain
            // room may not give for seconds). Measurements: docs/measurements.md.
            init_min_keypoints: 100,
            init_min_with_depth: 80,
            init_min_cells_with_depth: 6,
            th_high: 100,
            th_low: 50,
            motion_search_radius: 7.0,
            motion_min_matches: 20,
            local_map_search_th: 3.0,
            local_map_ratio: 0.8,
            ref_kf_ratio: 0.7,
            min_tracked_inliers: 30,
            reloc_min_inliers: 50,
            chi2_stereo: 7.815,
            chi2_mono: 5.991,
            pose_rounds: 4,
            pose_iterations: 10,
            kf_ref_ratio: 0.75,
            kf_close_tracked_max: 100,
            kf_close_untracked_min: 70,
            kf_close_min_gap_frames: 2,
            kf_weak_tracking_inliers: 50,
            point_max_rejections: 0,
            erase_seen_through_after: 2,
            trajectory_settle_keyframes: default_settle_keyframes(),
            trajectory_settle_at_end: default_settle_at_end(),
            trajectory_settle_min_inliers: default_settle_min_inliers(),
            trajectory_smooth_sigma_depth: default_smooth_sigma_depth(),
            trajectory_smooth_neighbours: default_smooth_neighbours(),
            trajectory_smooth_max_gap_s: default_smooth_max_gap_s(),
            trajectory_settle_max_pending: default_settle_max_pending(),
            trajectory_settle_max_per_frame: default_settle_max_per_frame(),
            trajectory_settle_rematch_seconds: default_settle_rematch_seconds(),
            seen_through_gap_px: 1.0,
            kf_new_points_min: 100,
            new_point_max_cos_parallax: 0.9998,
            new_point_parallax_from_neighbours: true,
            new_point_max_cos_parallax_measured: default_new_point_max_cos_parallax_measured(),
            new_point_prior_depth_quantile: default_new_point_prior_depth_quantile(),
            covisibility_min_shared: 15,
            local_neighbours: 10,
            mapping_neighbours: default_mapping_neighbours(),
            triangulation_threads: 1,
            triangulate_new_points: true,
            local_ba_max_keyframes: 20,
            point_found_ratio: 0.25,
            point_min_observations: 3,
            kf_redundancy: 0.9,
            kf_cull_max_gap_s: default_kf_cull_max_gap_s(),
            kf_cull_max_gap_s_monocular: default_kf_cull_max_gap_s_monocular(),
            ba_iterations: [5, 10],
            local_mapping_thread: false,
            background_nice: 10,
            new_map_after_lost_frames: fps.max(1.0).round() as usize,
            recover_lost_frames: fps.max(1.0).round() as usize,
            recover_search_th: 8.0,
            recover_min_inliers: 30,
            relocalise_while_initialising: true,
            relocalise_in_every_map: true,
            relocalise_with_loop_database: true,
            reloc_candidates: 20,
            loop_closing: Default::default(),
        }
    }

    /// Depth below which a point is "close": ThDepth baselines.
    pub fn close_depth(&self) -> f64 {
        self.th_depth * self.bf / self.camera.fx
    }

    /// Scale of each pyramid level (1, 1.2, 1.44, ...).
    pub fn scale_factors(&self) -> Vec<f64> {
        (0..self.n_levels)
            .map(|l| self.scale_factor.powi(l as i32))
            .collect()
    }

    /// Inverse squared scale per level: the information weight of an observation at that octave.
    pub fn inv_level_sigma2(&self) -> Vec<f64> {
        self.scale_factors().iter().map(|s| 1.0 / (s * s)).collect()
    }
}

fn default_kf_cull_max_gap_s() -> f64 {
    0.5
}

fn default_kf_cull_max_gap_s_monocular() -> f64 {
    0.3
}

fn default_settle_keyframes() -> usize {
    2
}

fn default_settle_at_end() -> bool {
    true
}

fn default_settle_min_inliers() -> usize {
    20
}

fn default_settle_max_pending() -> usize {
    300
}

fn default_smooth_sigma_depth() -> f64 {
    0.001
}

fn default_smooth_neighbours() -> usize {
    2
}

fn default_smooth_max_gap_s() -> f64 {
    0.1
}

fn default_settle_rematch_seconds() -> f64 {
    2.0
}

fn default_settle_max_per_frame() -> usize {
    3
}

fn default_new_point_max_cos_parallax_measured() -> f64 {
    0.9998
}

fn default_new_point_prior_depth_quantile() -> f64 {
    0.5
}
