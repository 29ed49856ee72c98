//! Real data: the five ICL-NUIM frames in `../shared/data/rgbd_pairs/five_frames_with_poses`
//! (fy negative: the ICL convention with flipped rows; depth factor 5000). Frame 1 becomes a
//! keyframe with a map point per keypoint with depth; every other frame is registered against it
//! as relocalisation does (descriptor matching, RANSAC, pose optimisation) and the relative pose
//! is compared with pose.txt.

use crate::common::shared;
use stillpoint_features::{OrbExtractor, OrbParams};
use stillpoint_geometry::{PinholeCamera, Se3};
use stillpoint_slam::data::Map;
use stillpoint_slam::matching::search_by_descriptors;
use stillpoint_slam::optimize::{PoseObservation, optimize_pose};
use stillpoint_slam::solve::{Correspondence, RansacParams, ransac_pose};
use stillpoint_slam::{Feature, Frame, SlamSettings};

fn load(dir: &std::path::Path, i: usize, s: &SlamSettings, orb: &mut OrbExtractor) -> Frame {
    let rgb = stillpoint_image::read_rgb(&dir.join(format!("color/{i}.png"))).unwrap();
    let gray = stillpoint_image::rgb_to_gray(&rgb);
    let depth =
        stillpoint_image::read_depth_metres(&dir.join(format!("depth/{i}.png")), 5000.0).unwrap();
    let f = orb.extract(&gray);
    let feats: Vec<Feature> = f.keypoints.iter().map(Feature::from).collect();
    Frame::new(i, i as f64, &feats, &f.descriptors, Some(&depth), s).unwrap()
}

#[test]
#[ignore = "needs ../shared/data"]
fn icl_relative_poses_agree_with_pose_txt() {
    let dir = shared().join("data/rgbd_pairs/five_frames_with_poses");
    let cam = PinholeCamera::new(481.20, -480.0, 319.5, 239.5, 640, 480);
    let s = SlamSettings::rgbd(cam, 40.0, 30.0);
    let inv_sigma2 = s.inv_level_sigma2();
    let mut orb = OrbExtractor::new(OrbParams::default());
    let truth: Vec<Se3> = std::fs::read_to_string(dir.join("pose.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            stillpoint_geometry::se3_from_tum([v[0], v[1], v[2]], [v[3], v[4], v[5], v[6]]).unwrap()
        })
        .collect();
    let mut f1 = load(&dir, 1, &s, &mut orb);
    f1.pose_cw = Some(Se3::identity());
    let mut map = Map::new();
    let kf = map.add_keyframe(&f1).unwrap();
    for i in 0..f1.len() {
        if let Some(p) = f1.unproject_world(i, &cam) {
            map.add_point(p, kf, i);
        }
    }
    let mut worst = (0.0f64, 0.0f64);
    for i in 2..=5 {
        let mut f = load(&dir, i, &s, &mut orb);
        let n = search_by_descriptors(&mut f, &map.keyframes[&kf], &map, 0.9, s.th_high);
        let idx: Vec<usize> = (0..f.len())
            .filter(|&k| f.map_points[k].is_some())
            .collect();
        let corr: Vec<Correspondence> = idx
            .iter()
            .map(|&k| Correspondence {
                world: map.points[&f.map_points[k].unwrap()].position,
                camera: f.unproject_camera(k, &cam),
                u: f.points[k].x,
                v: f.points[k].y,
                inv_sigma2: inv_sigma2[f.octaves[k] as usize],
            })
            .collect();
        let Some((mut pose, flags)) = ransac_pose(&corr, &cam, &RansacParams::default()) else {
            panic!("frame {i}: RANSAC found no pose from {n} matches");
        };
        let obs: Vec<PoseObservation> = idx
            .iter()
            .zip(&flags)
            .filter(|(_, f)| **f)
            .map(|(&k, _)| PoseObservation {
                world: map.points[&f.map_points[k].unwrap()].position,
                u: f.points[k].x,
                v: f.points[k].y,
                u_right: (f.u_right[k] > 0.0).then_some(f.u_right[k] as f64),
                inv_sigma2: inv_sigma2[f.octaves[k] as usize],
            })
            .collect();
        let out = optimize_pose(&mut pose, &obs, &s);
        let inliers = out.iter().filter(|o| !**o).count();
        let est_1i = pose.inverse();
        let gt_1i = truth[0].inverse() * truth[i - 1];
        let e = gt_1i.inverse() * est_1i;
        let (et, er) = (e.translation.vector.norm(), e.rotation.angle().to_degrees());
        eprintln!(
            "frame 1 -> {i}: {n} matches, {inliers} inliers, true motion {:.3} m / {:.1} deg, error {:.4} m / {:.3} deg",
            gt_1i.translation.vector.norm(),
            gt_1i.rotation.angle().to_degrees(),
            et,
            er
        );
        worst = (worst.0.max(et), worst.1.max(er));
    }
    assert!(worst.0 < 0.05 && worst.1 < 2.0, "worst error {worst:?}");
}
