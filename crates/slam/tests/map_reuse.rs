//! A map saved to bytes and loaded again ([`stillpoint_slam::map_file`]), on a scene projected
//! here: localisation finds its place by bag of words and leaves the map bit for bit as it was;
//! mapping on adds keyframes with the ids that follow the saved ones.

use rand::SeedableRng;
use stillpoint_geometry::{PinholeCamera, Se3, Vec3};
use stillpoint_slam::TrackInput;
use stillpoint_slam::map_file::{decode, encode};
use stillpoint_slam::{LoadedMapMode, SlamSettings, System};

mod common;
use common::{Scene, observe, room};

/// Camera-to-world pose on a circle of `radius` round the room's centre, looking outwards,
/// at angle `a` (radians).
fn on_circle(a: f64, radius: f64) -> Se3 {
    let z = Vec3::new(a.cos(), 0.0, a.sin());
    let y = Vec3::new(0.0, 1.0, 0.0);
    let r = nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[
        y.cross(&z),
        y,
        z,
    ]));
    Se3::from_parts(
        nalgebra::Translation3::from(z * radius),
        nalgebra::UnitQuaternion::from_rotation_matrix(&r),
    )
}

fn settings() -> SlamSettings {
    let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
    let mut s = SlamSettings::rgbd(cam, 40.0, 30.0);
    s.local_mapping_thread = false;
    s
}

/// Track the poses; per frame, whether it was relocalised and its camera-to-world pose.
fn track(sys: &mut System, sc: &Scene, poses: &[Se3], seed: u64) -> Vec<(bool, Option<Se3>)> {
    let cam = sys.settings.camera;
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    poses
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let (f, d, depth) = observe(sc, p, &cam, &mut rng);
            let r = sys
                .track(TrackInput::new(i, i as f64 / 30.0, &f, &d).with_depth(Some(&depth)))
                .unwrap();
            (r.relocalised, r.pose_wc)
        })
        .collect()
}

#[test]
fn localising_leaves_the_map_as_it_was_and_mapping_on_extends_it() {
    let sc = room(3, 12_000);
    // Mapping: 5/6 of a lap of radius 1 m.
    let lap = |i: usize| std::f64::consts::TAU * i as f64 / 300.0;
    let mapping: Vec<Se3> = (0..250).map(|i| on_circle(lap(i), 1.0)).collect();
    let mut sys = System::new(settings());
    track(&mut sys, &sc, &mapping, 1);
    sys.shutdown().unwrap();
    let saved = encode(&sys.map_file());
    let (keyframes, points) = (sys.keyframe_count(), sys.map_point_count());
    assert!(keyframes >= 10, "{keyframes} keyframes");
    let file = decode(&saved).unwrap();
    assert!(file.vocabulary.is_some(), "loop closing trained one");

    // Localisation on another path through the mapped stretch (radius 0.7 m, backwards),
    // starting far from where the mapping ended: place recognition finds it.
    let other: Vec<Se3> = (0..40).map(|i| on_circle(lap(150 - i), 0.7)).collect();
    // Besides place recognition's candidates, only the newest keyframe is tried (it looks at
    // another wall): the first frame relocalises by bag of words or not at all.
    let mut s = settings();
    s.reloc_candidates = 1;
    let mut loc = System::with_map(s, file, LoadedMapMode::Localize).unwrap();
    let out = track(&mut loc, &sc, &other, 2);
    loc.shutdown().unwrap();
    assert!(out[0].0, "relocalised at the first frame");
    let mut worst: f64 = 0.0;
    for ((_, pose), truth) in out.iter().zip(&other) {
        // The map's frame is the first mapping frame's camera.
        let in_world = mapping[0] * pose.expect("tracked");
        worst = worst.max((in_world.translation.vector - truth.translation.vector).norm());
    }
    assert!(worst < 0.03, "worst position error {worst} m");
    assert_eq!(encode(&loc.map_file()), saved, "the map changed");
    assert!(loc.keyframe_trajectory().is_empty());

    // Mapping on: past the mapped stretch, new keyframes join the loaded ones.
    let beyond: Vec<Se3> = (240..300).map(|i| on_circle(lap(i), 1.0)).collect();
    let mut ext =
        System::with_map(settings(), decode(&saved).unwrap(), LoadedMapMode::Extend).unwrap();
    let out = track(&mut ext, &sc, &beyond, 3);
    ext.shutdown().unwrap();
    assert!(out.iter().all(|(_, p)| p.is_some()), "every frame tracked");
    assert!(ext.keyframe_count() > keyframes && ext.map_point_count() > points);
    let grown = ext.map_file();
    let new_ids: Vec<u64> = grown
        .map
        .keyframes
        .keys()
        .copied()
        .filter(|&k| k >= grown.map.session_first_kf)
        .collect();
    assert_eq!(new_ids.len(), ext.keyframe_trajectory().len());
    assert!(!new_ids.is_empty());
    // And the grown map saves and loads again.
    assert_eq!(
        decode(&encode(&grown)).unwrap().map.keyframes.len(),
        grown.map.keyframes.len()
    );
}
