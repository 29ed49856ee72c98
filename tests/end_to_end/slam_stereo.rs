//! Cross-crate: `stillpoint run --kind kitti` on the KITTI-layout stereo pair that
//! `stillpoint synth --stereo` writes: tracks every frame from stereo depth alone, and reads the
//! KITTI ground truth (12 numbers a line, stamps from times.txt) to report an ATE.

use crate::common::stillpoint;
use std::path::{Path, PathBuf};
use stillpoint_features::{OrbExtractor, OrbParams};
use stillpoint_slam::Feature;
use stillpoint_slam::matching::stereo::{StereoParams, StereoView, stereo_depths};

/// `stillpoint synth --preset static --frames N --stereo` into `dir/seq`; must succeed.
fn synth_static_stereo(dir: &std::path::Path, frames: usize) -> std::path::PathBuf {
    let seq = dir.join("seq");
    let st = stillpoint()
        .args(["synth", "--preset", "static", "--stereo", "--frames"])
        .arg(frames.to_string())
        .arg("--out")
        .arg(&seq)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&st.stderr);
    assert!(st.status.success(), "{stderr}");
    seq
}

#[test]
fn synthetic_stereo_sequence_tracks_and_reports_ate_against_kitti_poses() {
    let dir = tempfile::tempdir().unwrap();
    let seq = synth_static_stereo(dir.path(), 40);
    let out = stillpoint()
        .args([
            "run",
            "--kind",
            "kitti",
            "--detector",
            "none",
            "--sequential",
            "--json",
        ])
        .arg("--dataset")
        .arg(&seq)
        .arg("--out")
        .arg(dir.path().join("traj.txt"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(!stderr.contains("ground truth unreadable"), "{stderr}");
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(summary["tracked"].as_u64(), Some(40), "{summary}");
    let ate = summary["ate"]["rmse"].as_f64().expect("an ATE");
    assert!(ate < 0.01, "{summary}");
}

/// ORB (n features) on both images and [`stereo_depths`]: the left keypoints and their depths.
fn keypoint_depths(
    left: &stillpoint_image::Gray8,
    right: &stillpoint_image::Gray8,
    n_features: usize,
    bf: f64,
    fx: f64,
) -> (Vec<Feature>, Vec<f32>) {
    let params = OrbParams {
        n_features,
        ..OrbParams::default()
    };
    let (mut ol, mut or) = (OrbExtractor::new(params.clone()), OrbExtractor::new(params));
    let (fl, fr) = (ol.extract(left), or.extract(right));
    let feats = |k: &[stillpoint_features::KeyPoint]| -> Vec<Feature> {
        k.iter().map(Feature::from).collect()
    };
    let (kl, kr) = (feats(&fl.keypoints), feats(&fr.keypoints));
    let depth = stereo_depths(
        &StereoView {
            keypoints: &kl,
            descriptors: &fl.descriptors,
            levels: ol.pyramid(left),
        },
        &StereoView {
            keypoints: &kr,
            descriptors: &fr.descriptors,
            levels: or.pyramid(right),
        },
        bf,
        fx,
        ol.scale_factors(),
        &StereoParams::default(),
    );
    (kl, depth)
}

/// The first image of a folder, by name.
fn first_image(dir: &Path) -> PathBuf {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    v.sort();
    v[0].clone()
}

/// The first left and right images of a one-frame `synth --preset static --stereo` in `dir`,
/// and the renderer's depth for the left one.
fn first_rendered_pair(
    dir: &Path,
) -> (
    stillpoint_image::Gray8,
    stillpoint_image::Gray8,
    stillpoint_image::DepthMetres,
) {
    let seq = synth_static_stereo(dir, 1);
    let first = |sub: &str| first_image(&seq.join(sub));
    (
        stillpoint_image::read_gray(&first("image_0")).unwrap(),
        stillpoint_image::read_gray(&first("image_1")).unwrap(),
        stillpoint_image::read_depth_metres(&first("depth"), 5000.0).unwrap(),
    )
}

/// Median and 90th percentile of relative errors.
fn median_and_p90(mut rel: Vec<f32>) -> (f32, f32) {
    rel.sort_by(f32::total_cmp);
    (rel[rel.len() / 2], rel[rel.len() * 9 / 10])
}

/// Stereo depths against the renderer's exact depth map (synth static, 0.1 m baseline).
#[test]
fn stereo_depths_match_the_rendered_depth() {
    let dir = tempfile::tempdir().unwrap();
    let (left, right, truth) = first_rendered_pair(dir.path());
    // settings_stereo.toml: fx 535.4, bf 53.54 (0.1 m).
    let (kps, depth) = keypoint_depths(&left, &right, 1000, 53.54, 535.4);
    let rel: Vec<f32> = kps
        .iter()
        .zip(&depth)
        .filter(|(_, z)| **z > 0.0)
        .filter_map(|(k, z)| {
            let t = truth.get_checked(k.x.round() as isize, k.y.round() as isize)?;
            (t > 0.0).then(|| (z - t).abs() / t)
        })
        .collect();
    let share = rel.len() as f32 / kps.len() as f32;
    let (p50, p90) = median_and_p90(rel);
    eprintln!("{share:.2} of keypoints with depth; relative error p50 {p50:.4} p90 {p90:.4}");
    // Measured: 0.55 with depth, p50 0.030, p90 0.093 (disparity errors -0.7..+1.0 px p10-p90,
    // mostly from keypoints on coarse levels, refined at their level as ORB-SLAM does).
    assert!(
        share > 0.4 && p50 < 0.05 && p90 < 0.15,
        "{share} {p50} {p90}"
    );
}

/// The dense stereo depth the front-end and the dense cloud read, against the renderer's depth.
#[test]
fn dense_stereo_depth_matches_the_rendered_depth() {
    use stillpoint_image::stereo_depth::{DenseStereo, DenseStereoParams};
    let dir = tempfile::tempdir().unwrap();
    let (left, right, truth) = first_rendered_pair(dir.path());
    let dense = DenseStereo::default().depth(&left, &right, 53.54, &DenseStereoParams::default());
    let rel: Vec<f32> = dense
        .data
        .iter()
        .zip(&truth.data)
        .filter(|(z, t)| **z > 0.0 && **t > 0.0)
        .map(|(z, t)| (z - t).abs() / t)
        .collect();
    let share = rel.len() as f32 / dense.data.len() as f32;
    let (p50, p90) = median_and_p90(rel);
    eprintln!("{share:.2} of pixels with depth; relative error p50 {p50:.4} p90 {p90:.4}");
    assert!(
        share > 0.2 && p50 < 0.03 && p90 < 0.10,
        "{share} {p50} {p90}"
    );
}

/// `run --dense-cloud` on a stereo pair fuses the keyframes' dense stereo depth.
#[test]
fn a_stereo_run_writes_a_dense_cloud() {
    let dir = tempfile::tempdir().unwrap();
    let seq = synth_static_stereo(dir.path(), 20);
    let ply = dir.path().join("dense.ply");
    let out = stillpoint()
        .args(["run", "--kind", "kitti", "--no-dynamic", "--json"])
        .arg("--dataset")
        .arg(&seq)
        .arg("--out")
        .arg(dir.path().join("traj.txt"))
        .arg("--dense-cloud")
        .arg(&ply)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let points = summary["dense_points"].as_u64().unwrap_or(0);
    assert!(points > 1000, "{summary}");
    let header = std::fs::read(&ply).unwrap();
    let header = String::from_utf8_lossy(&header[..200]);
    assert!(
        header.contains(&format!("element vertex {points}")),
        "{header}"
    );
}

/// The real KITTI pair (sequences 00-02 calibration: fx 718.856, bf 386.1448): most keypoints
/// find a right match, and the depths are those of a street (metres to tens of metres).
#[test]
#[ignore = "needs ../shared/data"]
fn real_kitti_pair_gets_street_depths() {
    let dir =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/kitti/stereo_pair");
    let left = stillpoint_image::read_gray(&dir.join("left.png")).unwrap();
    let right = stillpoint_image::read_gray(&dir.join("right.png")).unwrap();
    let (kl, depth) = keypoint_depths(&left, &right, 2000, 386.1448, 718.856);
    let mut z: Vec<f32> = depth.iter().copied().filter(|&z| z > 0.0).collect();
    z.sort_by(f32::total_cmp);
    let share = z.len() as f32 / kl.len() as f32;
    let median = z[z.len() / 2];
    eprintln!(
        "{} of {} keypoints with depth ({share:.2}); depth p10 {:.1} median {median:.1} p90 {:.1} m",
        z.len(),
        kl.len(),
        z[z.len() / 10],
        z[z.len() * 9 / 10]
    );
    assert!(share > 0.35, "{share}");
    assert!((4.0..40.0).contains(&median), "{median}");
}

/// A rectified synth pair "unrectified" as a raw EuRoC-like rig would record it (barrel
/// distortion, each camera rotated ~0.6 degrees off the rectified frame), written in the EuRoC
/// layout with ORB-SLAM's stereo settings (`LEFT/RIGHT.K, D, R, P`): the EuRoC reader rectifies
/// it back, and stereo matching along rows finds the depths again.
#[test]
fn euroc_layout_stereo_is_rectified_before_matching() {
    use stillpoint_geometry::{PinholeCamera, RadTan, RectifyingView, StereoRectification};
    use stillpoint_image::{Gray8, read_gray, remap_bilinear, write_gray};
    let dir = tempfile::tempdir().unwrap();
    let seq = synth_static_stereo(dir.path(), 1);
    let first = |sub: &str| first_image(&seq.join(sub));
    let rect_l = read_gray(&first("image_0")).unwrap();
    let rect_r = read_gray(&first("image_1")).unwrap();
    let truth = stillpoint_image::read_depth_metres(&first("depth"), 5000.0).unwrap();
    // settings_stereo.toml of synth: fx 535.4 fy 539.2 cx 320.1 cy 247.6, 0.1 m baseline.
    let (fx, fy, cx, cy, bf) = (535.4, 539.2, 320.1, 247.6, 53.54);
    let rotation = |q: [f64; 4]| {
        let m = stillpoint_geometry::se3_from_tum([0.0; 3], q)
            .unwrap()
            .rotation
            .to_rotation_matrix();
        [0, 1, 2].map(|i| [0, 1, 2].map(|j| m[(i, j)]))
    };
    let view = |k: [f64; 4], d: [f64; 4], q: [f64; 4], tx: f64| RectifyingView {
        raw: PinholeCamera {
            distortion: RadTan {
                k1: d[0],
                k2: d[1],
                p1: d[2],
                p2: d[3],
                k3: 0.0,
            },
            ..PinholeCamera::new(k[0], k[1], k[2], k[3], 640, 480)
        },
        r: rotation(q),
        p: [[fx, 0.0, cx, tx], [0.0, fy, cy, 0.0], [0.0, 0.0, 1.0, 0.0]],
    };
    let rig = StereoRectification {
        left: view(
            [520.0, 521.0, 322.0, 244.0],
            [-0.28, 0.074, 0.0002, 0.00002],
            [0.004, -0.003, 0.002, 1.0],
            0.0,
        ),
        right: view(
            [518.0, 519.5, 317.0, 251.0],
            [-0.27, 0.071, -0.0001, -0.00004],
            [-0.003, 0.004, -0.003, 1.0],
            -bf,
        ),
    };
    // The raw image samples the rendered (rectified) one where each raw pixel's ray lands.
    let unrectify = |img: &Gray8, v: &RectifyingView| {
        let map: Vec<[f32; 2]> = (0..640 * 480)
            .map(|i| {
                let raw = stillpoint_geometry::Vec2::new((i % 640) as f64, (i / 640) as f64);
                v.rectified_pixel(&raw)
                    .map_or([-1.0, -1.0], |q| [q.x as f32, q.y as f32])
            })
            .collect();
        remap_bilinear(img, &map, 640, 480).unwrap()
    };
    let (raw_l, raw_r) = (
        unrectify(&rect_l, &rig.left),
        unrectify(&rect_r, &rig.right),
    );
    let mav = dir.path().join("euroc/mav0");
    for (cam, img) in [("cam0", &raw_l), ("cam1", &raw_r)] {
        std::fs::create_dir_all(mav.join(cam).join("data")).unwrap();
        write_gray(&mav.join(cam).join("data/1403636579763555584.png"), img).unwrap();
        std::fs::write(
            mav.join(cam).join("data.csv"),
            "#timestamp [ns],filename\n1403636579763555584,1403636579763555584.png\n",
        )
        .unwrap();
    }
    let matrix = |name: &str, rows: usize, v: &[f64]| {
        let data: Vec<String> = v.iter().map(|x| format!("{x:?}")).collect();
        format!(
            "{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {}\n   dt: d\n   data:[{}]\n",
            v.len() / rows,
            data.join(", ")
        )
    };
    let mut yaml = format!(
        "%YAML:1.0\nCamera.fx: {fx}\nCamera.fy: {fy}\nCamera.cx: {cx}\nCamera.cy: {cy}\n\
         Camera.width: 640\nCamera.height: 480\nCamera.fps: 20.0\nCamera.bf: {bf}\nThDepth: 35\n"
    );
    for (side, v) in [("LEFT", &rig.left), ("RIGHT", &rig.right)] {
        let c = &v.raw;
        let d = &c.distortion;
        yaml += &format!("{side}.height: 480\n{side}.width: 640\n");
        yaml += &matrix(&format!("{side}.D"), 1, &[d.k1, d.k2, d.p1, d.p2, 0.0]);
        yaml += &matrix(
            &format!("{side}.K"),
            3,
            &[c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0],
        );
        yaml += &matrix(&format!("{side}.R"), 3, v.r.as_flattened());
        yaml += &matrix(&format!("{side}.P"), 3, v.p.as_flattened());
    }
    let settings = dir.path().join("EuRoC.yaml");
    std::fs::write(&settings, yaml).unwrap();
    let seq = stillpoint_datasets::open(
        &dir.path().join("euroc"),
        Some(stillpoint_datasets::DatasetKind::Euroc),
        Some(&settings),
    )
    .unwrap();
    assert_eq!(seq.settings().rectification, Some(rig));
    let f = seq.frame(0).unwrap();
    let right = f.right.expect("a right image");
    // Back on the rendered pair, up to two bilinear resamplings (the centre, away from the
    // black corners the distortion leaves).
    let mean_diff = |a: &Gray8, b: &Gray8| {
        let (mut sum, mut n) = (0u64, 0u64);
        for y in 96..384 {
            for x in 128..512 {
                sum += (a.get(x, y) as i64 - b.get(x, y) as i64).unsigned_abs();
                n += 1;
            }
        }
        sum as f64 / n as f64
    };
    let (back_l, back_r, raw_off) = (
        mean_diff(&f.gray, &rect_l),
        mean_diff(&right, &rect_r),
        mean_diff(&raw_l, &rect_l),
    );
    eprintln!(
        "mean |diff| rectified-rendered: left {back_l:.2}, right {back_r:.2}; raw {raw_off:.2}"
    );
    assert!(back_l < 3.0 && back_r < 3.0 && raw_off > 4.0 * back_l.max(back_r));
    let stats = |l: &Gray8, r: &Gray8| {
        let (kps, depth) = keypoint_depths(l, r, 1000, bf, fx);
        let mut rel: Vec<f32> = kps
            .iter()
            .zip(&depth)
            .filter(|(_, z)| **z > 0.0)
            .filter_map(|(k, z)| {
                let t = truth.get_checked(k.x.round() as isize, k.y.round() as isize)?;
                (t > 0.0).then(|| (z - t).abs() / t)
            })
            .collect();
        rel.sort_by(f32::total_cmp);
        let share = rel.len() as f32 / kps.len() as f32;
        (share, rel.get(rel.len() / 2).copied().unwrap_or(f32::NAN))
    };
    let (share, p50) = stats(&f.gray, &right);
    let (raw_share, raw_p50) = stats(&raw_l, &raw_r);
    eprintln!(
        "keypoints with stereo depth: rectified {share:.2} (p50 error {p50:.3}), raw {raw_share:.2} ({raw_p50:.3})"
    );
    assert!(share > 0.4 && p50 < 0.05, "{share} {p50}");
    assert!(
        share > 1.5 * raw_share || raw_p50 > 2.0 * p50,
        "{raw_share} {raw_p50}"
    );
}
