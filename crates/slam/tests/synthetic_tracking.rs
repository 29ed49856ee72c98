//! End to end on a synthetic scene projected here (no other stillpoint crate involved): random
//! textured points, a camera on a smooth path, keypoints with depth, descriptors with bit noise.

use rand::{Rng, SeedableRng};
use stillpoint_geometry::{PinholeCamera, Se3, Vec3};
use stillpoint_image::DepthMetres;
use stillpoint_slam::TrackInput;
use stillpoint_slam::{SlamSettings, System, TrackingState};

mod common;
use common::{Scene, observe};

fn scene(seed: u64, n: usize) -> Scene {
    // A room: back wall, floor and side walls around the camera path.
    common::scene_of(seed, n, |rng| match rng.random_range(0..4) {
        0 => Vec3::new(
            rng.random_range(-3.0..3.0),
            rng.random_range(-2.0..2.0),
            4.0,
        ),
        1 => Vec3::new(rng.random_range(-3.0..3.0), 1.5, rng.random_range(0.5..4.0)),
        2 => Vec3::new(
            -2.5,
            rng.random_range(-2.0..2.0),
            rng.random_range(0.5..4.0),
        ),
        _ => Vec3::new(2.5, rng.random_range(-2.0..2.0), rng.random_range(0.5..4.0)),
    })
}

/// Camera-to-world pose at frame i: a slow sideways/forward wobble with some yaw.
fn truth(i: usize) -> Se3 {
    let t = i as f64 / 30.0;
    Se3::new(
        nalgebra::Vector3::new(
            0.8 * (0.8 * t).sin(),
            0.05 * (1.3 * t).sin(),
            0.4 * (0.5 * t).sin(),
        ),
        nalgebra::Vector3::new(0.0, 0.5 * (0.7 * t).sin(), 0.02 * t.sin()),
    )
}

fn run(frames: usize, blank: impl Fn(usize) -> bool) -> (f64, usize, bool) {
    let (rmse, tracked, new_map, _) = run_with(frames, blank, |_| {});
    (rmse, tracked, new_map)
}

/// As `run`, with the settings changed by `tune`; also returns the frames that made keyframes.
fn run_with(
    frames: usize,
    blank: impl Fn(usize) -> bool,
    tune: impl Fn(&mut SlamSettings),
) -> (f64, usize, bool, Vec<usize>) {
    let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
    let mut s = SlamSettings::rgbd(cam, 40.0, 30.0);
    s.local_mapping_thread = false;
    tune(&mut s);
    let mut keyframes = Vec::new();
    let sc = scene(3, 4000);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(9);
    let mut sys = System::new(s);
    let origin = truth(0);
    let (mut sse, mut n, mut any_new_map) = (0.0, 0, false);
    for i in 0..frames {
        let gt = truth(i);
        let (f, d, depth) = if blank(i) {
            let depth = DepthMetres::new(cam.width as usize, cam.height as usize, 0.0);
            (Vec::new(), Vec::new(), depth)
        } else {
            observe(&sc, &gt, &cam, &mut rng)
        };
        let r = sys
            .track(TrackInput::new(i, i as f64 / 30.0, &f, &d).with_depth(Some(&depth)))
            .unwrap();
        any_new_map |= r.new_map;
        if r.new_keyframe {
            keyframes.push(i);
        }
        if let Some(p) = r.pose_wc {
            // The map starts at the identity: compare against the truth relative to frame 0.
            let rel = origin.inverse() * gt;
            sse += (rel.translation.vector - p.translation.vector).norm_squared();
            n += 1;
        }
    }
    eprintln!(
        "keyframes {} points {}",
        sys.keyframe_count(),
        sys.map_point_count()
    );
    sys.shutdown().unwrap();
    let rmse = (sse / n.max(1) as f64).sqrt();
    eprintln!("tracked {n}/{frames} frames, ATE RMSE {rmse:.5} m, new map {any_new_map}");
    (rmse, n, any_new_map, keyframes)
}

#[test]
fn the_close_points_rule_waits_its_gap_between_keyframes() {
    // The close-points rule set to fire on every frame (any untracked close keypoint, however
    // many are tracked): a keyframe a frame without a gap, one every third frame with a gap of 3.
    let tune = |gap: usize| {
        move |s: &mut SlamSettings| {
            s.kf_close_tracked_max = usize::MAX;
            s.kf_close_untracked_min = 0;
            s.kf_close_min_gap_frames = gap;
        }
    };
    let (rmse0, tracked0, _, kfs0) = run_with(60, |_| false, tune(0));
    let (rmse3, tracked3, _, kfs3) = run_with(60, |_| false, tune(3));
    eprintln!("keyframes made: {kfs0:?} / {kfs3:?}");
    assert_eq!((tracked0, tracked3), (60, 60));
    let gaps = |kfs: &[usize]| kfs.windows(2).map(|w| w[1] - w[0]).collect::<Vec<_>>();
    assert!(gaps(&kfs0).contains(&1), "{kfs0:?}");
    assert!(gaps(&kfs3).iter().all(|&g| g >= 3), "{kfs3:?}");
    assert!(kfs3.len() > 10, "{kfs3:?}");
    assert!(rmse0 < 0.005 && rmse3 < 0.005, "ATE RMSE {rmse0} / {rmse3}");
}

#[test]
fn tracks_a_synthetic_room_to_millimetres() {
    let (rmse, tracked, _) = run(90, |_| false);
    assert_eq!(tracked, 90);
    assert!(rmse < 0.005, "ATE RMSE {rmse}");
}

#[test]
fn blank_frames_do_not_abort_and_tracking_recovers() {
    // 5 blank frames at 30..35: lost, then relocalised on the same map.
    let (rmse, tracked, new_map) = run(70, |i| (30..35).contains(&i));
    assert_eq!(tracked, 65);
    assert!(!new_map);
    assert!(rmse < 0.01, "ATE RMSE {rmse}");
    let _ = TrackingState::Lost;
}

#[test]
fn a_camera_lost_a_moment_is_found_again_where_it_was_without_place_recognition() {
    // Relocalisation has no keyframe to try (no candidates): after the 5 blank frames the
    // points around the last tracked frame, searched for from where it stood, find the camera
    // on the same map; without that search it stays lost and starts a new map.
    let no_candidates = |recover: usize| {
        move |s: &mut SlamSettings| {
            s.reloc_candidates = 0;
            s.recover_lost_frames = recover;
        }
    };
    let (rmse, tracked, new_map, _) = run_with(70, |i| (30..35).contains(&i), no_candidates(30));
    assert_eq!((tracked, new_map), (65, false));
    assert!(rmse < 0.01, "ATE RMSE {rmse}");
    let (_, tracked, new_map, _) = run_with(70, |i| (30..35).contains(&i), no_candidates(0));
    assert!(
        tracked < 65 || new_map,
        "{tracked} tracked, new map {new_map}"
    );
}

#[test]
fn pose_optimiser_converges_from_a_rotated_start() {
    use stillpoint_slam::optimize::{PoseObservation, optimize_pose};
    let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
    let s = SlamSettings::rgbd(cam, 40.0, 30.0);
    let sc = scene(3, 4000);
    for i in [30usize, 36, 38, 39] {
        let cw = truth(i).inverse();
        let mut obs = Vec::new();
        for p in &sc.points {
            let pc = (cw * nalgebra::Point3::from(*p)).coords;
            let Some(px) = cam.project(&pc) else { continue };
            if !cam.in_image(&px, 2.0) {
                continue;
            }
            obs.push(PoseObservation {
                world: *p,
                u: px.x,
                v: px.y,
                u_right: Some(px.x - 40.0 / pc.z),
                inv_sigma2: 1.0,
            });
        }
        let mut pose = Se3::new(
            nalgebra::Vector3::new(0.03, 0.0, -0.01),
            nalgebra::Vector3::new(0.0, 0.04, 0.0),
        ) * truth(i - 2).inverse();
        let out = optimize_pose(&mut pose, &obs, &s);
        let e = cw.inverse() * pose;
        assert!(out.iter().all(|&o| !o));
        assert!(
            e.translation.vector.norm() < 1e-6 && e.rotation.angle() < 1e-6,
            "frame {i}: {e:?}"
        );
    }
}

/// A room seen only beyond the close depth (40 baselines: 3 m here) while the camera pans.
/// ORB-SLAM3 counts an observation with depth twice; counted once, the first keyframe's points
/// (one observation each) made the reference count 0, and no keyframe came until tracking had
/// nearly failed (the weak-tracking rule: fewer than 50 inliers).
#[test]
fn far_room_gets_keyframes_while_tracking_is_strong() {
    let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
    let mut s = SlamSettings::rgbd(cam, 40.0, 30.0);
    s.local_mapping_thread = false;
    let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
    let mut points = Vec::new();
    let mut descriptors = Vec::new();
    for _ in 0..5000 {
        // 4-5 m away, from 40 degrees left to 100 degrees right of the first view.
        let (yaw, r) = (
            rng.random_range(-0.7f64..1.75),
            rng.random_range(4.0f64..5.0),
        );
        let y = r * rng.random_range(-0.45f64..0.45);
        points.push(Vec3::new(r * yaw.sin(), y, r * yaw.cos()));
        let mut d = [0u8; 32];
        rng.fill(&mut d[..]);
        descriptors.push(d);
    }
    let sc = Scene {
        points,
        descriptors,
    };
    let mut sys = System::new(s);
    let (mut keyframes, mut min_inliers) = (0, usize::MAX);
    for i in 0..120 {
        // A pan of 1 rad in 4 s, about the vertical axis.
        let gt = Se3::new(
            nalgebra::Vector3::zeros(),
            nalgebra::Vector3::new(0.0, i as f64 / 120.0, 0.0),
        );
        let (f, d, depth) = observe(&sc, &gt, &cam, &mut rng);
        let r = sys
            .track(TrackInput::new(i, i as f64 / 30.0, &f, &d).with_depth(Some(&depth)))
            .unwrap();
        assert_eq!(r.state, TrackingState::Ok, "frame {i}");
        keyframes += r.new_keyframe as usize;
        if i > 0 {
            min_inliers = min_inliers.min(r.inliers);
        }
    }
    sys.shutdown().unwrap();
    assert!(keyframes >= 3, "{keyframes} keyframes");
    assert!(min_inliers >= 150, "tracking fell to {min_inliers} inliers");
}

/// Keyframes that sit 10 cm off while frames are tracked and are put right afterwards (as bundle
/// adjustment puts right a keyframe that a missed mover dragged): ORB-SLAM's saved trajectory
/// carries the 10 cm into every frame anchored to them; settled frames are optimised again
/// against the map once it is refined and follow their keyframes from there.
fn rebuilt_error_after_keyframes_moved(settle_keyframes: usize) -> f64 {
    let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
    let mut s = SlamSettings::rgbd(cam, 40.0, 30.0);
    s.local_mapping_thread = false;
    s.trajectory_settle_keyframes = settle_keyframes;
    let sc = scene(3, 4000);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(9);
    let mut sys = System::new(s);
    let origin = truth(0);
    let offset = Se3::translation(0.1, 0.0, 0.0);
    let shift_keyframes = |sys: &System, by: &Se3| {
        let map = sys.map();
        let mut m = map.lock().unwrap();
        for k in m.keyframes.values_mut() {
            k.pose_cw *= by;
        }
    };
    for i in 0..60 {
        let (f, d, depth) = observe(&sc, &truth(i), &cam, &mut rng);
        // Frame 40 is tracked while every keyframe is off; the map points are not.
        if i == 40 {
            shift_keyframes(&sys, &offset);
        }
        sys.track(TrackInput::new(i, i as f64 / 30.0, &f, &d).with_depth(Some(&depth)))
            .unwrap();
        if i == 40 {
            shift_keyframes(&sys, &offset.inverse());
        }
    }
    sys.shutdown().unwrap();
    let (_, pose, _) = sys
        .rebuilt_trajectory()
        .into_iter()
        .find(|(t, _, _)| (t - 40.0 / 30.0).abs() < 1e-9)
        .expect("frame 40 tracked");
    let truth_rel = origin.inverse() * truth(40);
    (truth_rel.translation.vector - pose.translation.vector).norm()
}

#[test]
fn frames_settle_on_the_refined_map_instead_of_following_a_keyframe_that_moved() {
    let anchored = rebuilt_error_after_keyframes_moved(0);
    let settled = rebuilt_error_after_keyframes_moved(2);
    assert!(anchored > 0.05, "without settling: {anchored} m");
    assert!(settled < 0.005, "settled: {settled} m");
}

#[test]
fn a_camera_that_makes_no_keyframes_keeps_few_frames_waiting_to_settle() {
    let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
    let mut s = SlamSettings::rgbd(cam, 40.0, 30.0);
    s.local_mapping_thread = false;
    s.trajectory_settle_max_pending = 10;
    let sc = scene(3, 4000);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(4);
    let mut sys = System::new(s);
    // A camera standing still: after the first keyframe nothing asks for another.
    let mut most_waiting = 0;
    for i in 0..50 {
        let (f, d, depth) = observe(&sc, &truth(0), &cam, &mut rng);
        let r = sys
            .track(TrackInput::new(i, i as f64 / 30.0, &f, &d).with_depth(Some(&depth)))
            .unwrap();
        assert_eq!(r.state, TrackingState::Ok, "frame {i}");
        most_waiting = most_waiting.max(sys.frames_waiting_to_settle());
    }
    assert!(
        sys.keyframe_count() <= 2,
        "{} keyframes",
        sys.keyframe_count()
    );
    assert_eq!(most_waiting, 10);
    sys.shutdown().unwrap();
    assert_eq!(sys.frames_waiting_to_settle(), 0);
    assert_eq!(sys.rebuilt_trajectory().len(), 50);
}

/// Frames settle on the map the run ends with (`trajectory_settle_at_end`): every tracked frame
/// waits for the end, however many keyframes come after it; with it off (the release before)
/// the first settle two keyframes later.
#[test]
fn frames_wait_to_settle_on_the_map_the_run_ends_with() {
    const FRAMES: usize = 120;
    let waiting_at_the_end = |at_end: bool| {
        let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
        let mut s = SlamSettings::rgbd(cam, 40.0, 30.0);
        s.local_mapping_thread = false;
        s.trajectory_settle_at_end = at_end;
        let sc = scene(3, 4000);
        let mut rng = rand_pcg::Pcg64::seed_from_u64(9);
        let mut sys = System::new(s);
        for i in 0..FRAMES {
            let (f, d, depth) = observe(&sc, &truth(i), &cam, &mut rng);
            sys.track(TrackInput::new(i, i as f64 / 30.0, &f, &d).with_depth(Some(&depth)))
                .unwrap();
        }
        let waiting = (sys.frames_waiting_to_settle(), sys.keyframe_count());
        sys.shutdown().unwrap();
        assert_eq!(sys.frames_waiting_to_settle(), 0, "all settle at the end");
        assert_eq!(sys.rebuilt_trajectory().len(), FRAMES);
        waiting
    };
    let (at_end, keyframes) = waiting_at_the_end(true);
    assert!(keyframes >= 4, "{keyframes} keyframes");
    assert_eq!(at_end, FRAMES, "frames waiting at the end");
    let (two_keyframes_later, _) = waiting_at_the_end(false);
    assert!(
        two_keyframes_later < FRAMES,
        "two keyframes later, none settled before the end"
    );
}

/// The rebuilt trajectory over 90 frames of a camera on a smooth path before a textured wall
/// and floor, keypoints 1 px off, with `trajectory_smooth_sigma_depth` = `share`: its RMSE and
/// its jitter (the RMS of the error's second difference, frame to frame), metres.
fn rebuilt_error_with_smoothing(share: f64) -> (f64, f64) {
    let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
    let mut s = SlamSettings::rgbd(cam, 40.0, 30.0);
    s.local_mapping_thread = false;
    s.trajectory_smooth_sigma_depth = share;
    let sc = common::scene_of(5, 3000, |rng| {
        if rng.random_range(0..4) == 0 {
            Vec3::new(rng.random_range(-3.0..3.0), 1.5, rng.random_range(1.0..4.0))
        } else {
            Vec3::new(
                rng.random_range(-3.0..3.0),
                rng.random_range(-2.0..2.0),
                4.0,
            )
        }
    });
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    let mut sys = System::new(s);
    for i in 0..90 {
        let (f, d, depth) = common::observe_with_noise(&sc, &truth(i), &cam, &mut rng, 1.0);
        sys.track(TrackInput::new(i, i as f64 / 30.0, &f, &d).with_depth(Some(&depth)))
            .unwrap();
    }
    sys.shutdown().unwrap();
    let origin = truth(0);
    let rebuilt = sys.rebuilt_trajectory();
    assert_eq!(rebuilt.len(), 90, "every frame tracked");
    let errors: Vec<Vec3> = rebuilt
        .iter()
        .map(|(t, pose, _)| {
            let i = (t * 30.0).round() as usize;
            (origin.inverse() * truth(i)).translation.vector - pose.translation.vector
        })
        .collect();
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    let ate: Vec<f64> = errors.iter().map(|e| e.norm()).collect();
    let jitter: Vec<f64> = errors
        .windows(3)
        .map(|w| (w[0] - 2.0 * w[1] + w[2]).norm())
        .collect();
    (rms(&ate), rms(&jitter))
}

#[test]
fn a_frame_settles_near_where_its_neighbours_put_it() {
    let (alone, alone_jitter) = rebuilt_error_with_smoothing(0.0);
    let (smoothed, smoothed_jitter) = rebuilt_error_with_smoothing(0.001);
    assert!(
        smoothed_jitter < 0.5 * alone_jitter && smoothed < alone,
        "smoothed {smoothed:.5} m (jitter {smoothed_jitter:.5}), each frame on its own \
         {alone:.5} m ({alone_jitter:.5})"
    );
}
