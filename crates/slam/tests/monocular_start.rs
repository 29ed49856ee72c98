//! Where a monocular trajectory starts: the frames offered before the map stood, including
//! those of a reference frame the initialiser dropped, get poses once it stands. A scene
//! projected here (no images): a camera going round a 1 m circle, looking out at a room's walls.

use rand::{Rng, SeedableRng};
use stillpoint_geometry::{PinholeCamera, Se3, Vec3};
use stillpoint_slam::{SlamSettings, System, TrackInput};

mod common;
use common::{ate_rmse, observe_with_noise, room};

/// Camera to world at frame `i`: 1.2 degrees and 2 cm round the circle a frame, looking out.
fn truth(i: usize) -> Se3 {
    let a = std::f64::consts::TAU * i as f64 / 300.0;
    let z = Vec3::new(a.cos(), 0.0, a.sin());
    let y = Vec3::new(0.0, 1.0, 0.0);
    let r = nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[
        y.cross(&z),
        y,
        z,
    ]));
    Se3::from_parts(
        nalgebra::Translation3::from(Vec3::new(a.cos(), 0.0, a.sin())),
        nalgebra::UnitQuaternion::from_rotation_matrix(&r),
    )
}

/// Runs `frames` monocular frames with `settings` changed by `adjust`; frame 1 is blurred (80
/// more bits of each descriptor flipped: too far for initialisation's matching, near enough for
/// tracking's). Returns the frames the trajectory has a pose for and its Sim(3) ATE (m).
fn run(frames: usize, adjust: impl Fn(&mut SlamSettings)) -> (Vec<usize>, f64) {
    run_along(frames, truth, 16_000, adjust)
}

/// [`run`] along the path `truth` in a room of `points` points.
fn run_along(
    frames: usize,
    truth: impl Fn(usize) -> Se3,
    points: usize,
    adjust: impl Fn(&mut SlamSettings),
) -> (Vec<usize>, f64) {
    let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
    let mut s = SlamSettings::monocular(cam, 30.0);
    s.local_mapping_thread = false;
    adjust(&mut s);
    let sc = room(5, points);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    let mut sys = System::new(s);
    for i in 0..frames {
        let (f, mut d, _) = observe_with_noise(&sc, &truth(i), &cam, &mut rng, 0.3);
        if i == 1 {
            for desc in &mut d {
                for _ in 0..80 {
                    let b = rng.random_range(0..256);
                    desc[b / 8] ^= 1 << (b % 8);
                }
            }
        }
        sys.track(TrackInput::new(i, i as f64 / 30.0, &f, &d))
            .expect("tracking");
    }
    sys.shutdown().expect("shutdown");
    let trajectory = sys.rebuilt_trajectory();
    let posed: Vec<usize> = trajectory
        .iter()
        .map(|(t, _, _)| (t * 30.0).round() as usize)
        .collect();
    let est: Vec<Vec3> = trajectory
        .iter()
        .map(|(_, p, _)| p.translation.vector)
        .collect();
    let gt: Vec<Vec3> = posed.iter().map(|&i| truth(i).translation.vector).collect();
    let ate = ate_rmse(&est, &gt, true);
    (posed, ate)
}

#[test]
fn frames_of_a_dropped_reference_are_tracked_once_the_map_stands() {
    // The blurred frame 1 drops reference frame 0; frame 2 becomes the reference and starts the
    // map a few frames later. Without the dropped reference's frames kept, the trajectory starts
    // at the map's first view; without any frame kept, at its second.
    let (posed, _) = run(30, |s| s.mono_init.backfill_before_reference = false);
    assert_eq!(posed[..2], [2, 3]);
    let (posed, _) = run(30, |s| s.mono_init.backfill_frames = 0);
    assert!(
        posed[0] > 2,
        "without backfill the trajectory starts at {}",
        posed[0]
    );
    let (posed, ate) = run(30, |_| {});
    assert_eq!(posed, (0..30).collect::<Vec<_>>(), "every frame has a pose");
    assert!(ate < 0.01, "ATE {ate} m");
}

#[test]
fn frames_the_first_views_cannot_track_are_placed_in_the_map_the_run_ends_with() {
    // The camera turns in from the side over its first frames (24 degrees at frame 0, 8 a
    // frame), and a frame counts as tracked only with 600 inliers (a view here holds ~1,500
    // points): frame 0 shares too few with the map's first two views, and tracking back from
    // them stops at it. The keyframes made as the camera goes on round map that side, and at
    // the end of the run it is tracked in the map as it ended.
    let turned_in = |i: usize| {
        let yaw = (3.0 - i.min(3) as f64) * 8f64.to_radians();
        truth(i)
            * Se3::from_parts(
                nalgebra::Translation3::identity(),
                nalgebra::UnitQuaternion::from_euler_angles(0.0, -yaw, 0.0),
            )
    };
    let (posed_off, off) = run_along(60, turned_in, 16_000, |s| {
        s.mono_init.place_before_map_at_end = false;
        s.min_tracked_inliers = 600;
    });
    let (posed, on) = run_along(60, turned_in, 16_000, |s| s.min_tracked_inliers = 600);
    assert!(
        !posed_off.contains(&0),
        "frame 0 tracked back: {posed_off:?}"
    );
    let placed: Vec<usize> = posed
        .iter()
        .copied()
        .filter(|i| !posed_off.contains(i))
        .collect();
    assert_eq!(placed, [0], "placed at the end");
    assert_eq!(
        posed.len(),
        posed_off.len() + 1,
        "the other frames are the same"
    );
    assert!(
        on < 0.005 && on < 1.5 * off,
        "ATE {on} m placed, {off} m not"
    );
}

#[test]
fn frames_tracked_before_the_map_stood_settle_as_tracked_frames_do() {
    // Their poses are optimised again once the map around them is refined, as every tracked
    // frame's is (`trajectory_settle_at_end`): right after the map stands they wait, with
    // the frame that started it; the map's first view, a keyframe, does not.
    let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
    let mut s = SlamSettings::monocular(cam, 30.0);
    s.local_mapping_thread = false;
    let sc = room(5, 16_000);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    let mut sys = System::new(s);
    for i in 0..30 {
        let (f, d, _) = observe_with_noise(&sc, &truth(i), &cam, &mut rng, 0.3);
        let report = sys
            .track(TrackInput::new(i, i as f64 / 30.0, &f, &d))
            .expect("tracking");
        if !report.backfilled.is_empty() {
            assert!(report.backfilled.len() >= 2, "{:?}", report.backfilled);
            assert_eq!(sys.frames_waiting_to_settle(), report.backfilled.len());
            return;
        }
    }
    panic!("no map stood in 30 frames");
}

#[test]
fn frames_of_a_young_map_settle_on_the_points_made_after_them() {
    // The map's first points come from two views a few degrees apart; a frame tracked on them
    // alone settles on their errors. Matched again to the points of the map the run ends
    // with (`trajectory_settle_rematch_seconds`), the frames of the map's first two seconds
    // come closer to the truth (here 1.6 -> 0.5 mm).
    let (posed_off, off) = run(60, |s| s.trajectory_settle_rematch_seconds = 0.0);
    let (posed_on, on) = run(60, |_| {});
    assert_eq!(posed_on, posed_off, "the same frames have poses");
    assert!(on < 0.5 * off, "ATE {on} m matched again, {off} m not");
}

#[test]
fn a_young_map_is_mapped_keyframe_by_keyframe_with_mapping_in_its_own_thread() {
    // Live input maps in a thread of its own, and tracking does not wait for it; a young
    // monocular map's keyframes are mapped before the next frame all the same
    // (`mono_init.map_keyframes_at_once_seconds`), so that run is the recording's, where
    // mapping runs inline after each keyframe, to the last digit.
    let at_once = |s: &mut SlamSettings| s.mono_init.map_keyframes_at_once_seconds = 100.0;
    let (posed_inline, inline) = run(60, at_once);
    let (posed_thread, thread) = run(60, |s| {
        at_once(s);
        s.local_mapping_thread = true;
    });
    assert_eq!(posed_thread, posed_inline, "the same frames have poses");
    assert_eq!(
        thread, inline,
        "ATE {thread} m in a thread, {inline} m inline"
    );
}
