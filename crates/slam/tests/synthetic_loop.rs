//! Loop closing end to end on a scene projected here (no images): the camera goes round a
//! circle looking out at the walls of a room and comes back to its start. Keypoints carry
//! +-0.3 px of noise, which is enough for tracking to drift by centimetres and a degree or two
//! over a lap; loop closing must find the revisit, correct it and lower the error.

use rand::SeedableRng;
use stillpoint_geometry::{PinholeCamera, Se3, Vec3, umeyama};
use stillpoint_slam::TrackInput;
use stillpoint_slam::{SlamSettings, System};

/// Frames per lap.
const LAP: usize = 300;

mod common;
use common::{observe, room};

/// Camera-to-world pose at frame i: on a 1 m circle, looking outwards, a lap every `LAP`.
fn truth(i: usize) -> Se3 {
    let a = std::f64::consts::TAU * i as f64 / LAP as f64;
    let z = Vec3::new(a.cos(), 0.0, a.sin());
    let y = Vec3::new(0.0, 1.0, 0.0);
    let x = y.cross(&z);
    let r = nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[x, y, z]));
    Se3::from_parts(
        nalgebra::Translation3::from(z),
        nalgebra::UnitQuaternion::from_rotation_matrix(&r),
    )
}

struct Outcome {
    /// ATE RMSE (SE3-aligned) of the final trajectory.
    ate: f64,
    tracked: usize,
    /// (frame, loop frame) of each loop closed.
    loops: Vec<(usize, usize)>,
}

fn run(frames: usize, loop_closing: bool) -> Outcome {
    let cam = PinholeCamera::new(525.0, 525.0, 319.5, 239.5, 640, 480);
    let mut s = SlamSettings::rgbd(cam, 40.0, 30.0);
    s.local_mapping_thread = false;
    s.loop_closing.enabled = loop_closing;
    let sc = room(5, 16_000);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    let mut sys = System::new(s);
    let mut online = Vec::new();
    for i in 0..frames {
        let (f, d, depth) = observe(&sc, &truth(i), &cam, &mut rng);
        let r = sys
            .track(TrackInput::new(i, i as f64 / 30.0, &f, &d).with_depth(Some(&depth)))
            .expect("tracking");
        if let Some(p) = r.pose_wc {
            online.push((i as f64 / 30.0, p));
        }
    }
    sys.shutdown().expect("shutdown");
    let loops: Vec<(usize, usize)> = sys
        .loop_stats()
        .map(|l| {
            l.loops
                .iter()
                .map(|e| (e.frame_index, e.loop_frame_index))
                .collect()
        })
        .unwrap_or_default();
    // After a loop the frames follow their keyframes, as `stillpoint run` writes them.
    let estimate = if loops.is_empty() {
        online
    } else {
        sys.rebuilt_trajectory()
    };
    let est: Vec<Vec3> = estimate.iter().map(|(_, p)| p.translation.vector).collect();
    let gt: Vec<Vec3> = estimate
        .iter()
        .map(|(t, _)| truth((t * 30.0).round() as usize).translation.vector)
        .collect();
    let align = umeyama(&est, &gt, false).expect("alignment");
    let sse: f64 = est
        .iter()
        .zip(&gt)
        .map(|(e, g)| (align.transform_point(e) - g).norm_squared())
        .sum();
    let ate = (sse / est.len() as f64).sqrt();
    eprintln!(
        "loop closing {loop_closing}: {} of {frames} tracked, ATE {ate:.4} m, loops {loops:?}",
        est.len()
    );
    Outcome {
        ate,
        tracked: est.len(),
        loops,
    }
}

#[test]
fn the_loop_is_closed_at_the_revisit_and_the_error_drops() {
    let frames = LAP + LAP / 3;
    let off = run(frames, false);
    let on = run(frames, true);
    assert_eq!(off.tracked, frames);
    assert_eq!(on.tracked, frames);
    assert!(off.loops.is_empty());
    let &(frame, loop_frame) = on.loops.first().expect("a loop closed");
    // A true revisit: the two keyframes look the same way (the field of view is 63 degrees).
    let apart = truth(frame).rotation.angle_to(&truth(loop_frame).rotation);
    assert!(
        frame > loop_frame + LAP / 2 && apart.to_degrees() < 30.0,
        "loop {frame} -> {loop_frame}, {:.1} degrees apart",
        apart.to_degrees()
    );
    assert!(off.ate > 0.02, "too little drift to test: {}", off.ate);
    assert!(on.ate < 0.5 * off.ate, "ATE {} -> {}", off.ate, on.ate);
}

#[test]
fn no_loop_without_a_revisit() {
    // Three quarters of a lap: the camera never sees its start again.
    let out = run(LAP * 3 / 4, true);
    assert!(out.loops.is_empty(), "{:?}", out.loops);
}
