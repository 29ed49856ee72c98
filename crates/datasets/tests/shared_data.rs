//! Readers on the real files in `../shared/data` (ignored without them).

use std::path::PathBuf;
use stillpoint_datasets::{Sensor, associate_nearest, open, read_associations, read_orbslam_yaml};

fn data() -> PathBuf {
    std::env::var_os("STILLPOINT_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared"))
        .join("data")
}

#[test]
#[ignore = "needs ../shared/data"]
fn every_calib_file_parses_to_the_right_numbers() {
    // file, fx, fy, cx, cy, bf, depth factor (RGB-D only), n_features, sensor, k1, fps, th_depth
    type Row = (
        &'static str,
        f64,
        f64,
        f64,
        f64,
        f64,
        Option<f64>,
        usize,
        Sensor,
        f64,
        f64,
        f64,
    );
    let rows: [Row; 8] = [
        (
            "EuRoC_orbslam2_stereo.yaml",
            435.2046959714599,
            435.2046959714599,
            367.4517211914062,
            252.2008514404297,
            47.90639384423901,
            None,
            1200,
            Sensor::Stereo,
            0.0,
            20.0,
            35.0,
        ),
        (
            "KITTI00-02_orbslam2_stereo.yaml",
            718.856,
            718.856,
            607.1928,
            185.2157,
            386.1448,
            None,
            2000,
            Sensor::Stereo,
            0.0,
            10.0,
            35.0,
        ),
        (
            "KITTI03_orbslam2_stereo.yaml",
            721.5377,
            721.5377,
            609.5593,
            172.854,
            387.5744,
            None,
            2000,
            Sensor::Stereo,
            0.0,
            10.0,
            40.0,
        ),
        (
            "KITTI04-12_orbslam2_stereo.yaml",
            707.0912,
            707.0912,
            601.8873,
            183.1104,
            379.8145,
            None,
            2000,
            Sensor::Stereo,
            0.0,
            10.0,
            40.0,
        ),
        (
            "bonn_orbslam2.yaml",
            542.822841,
            542.576870,
            315.593520,
            237.756098,
            40.0,
            Some(5000.0),
            1000,
            Sensor::Rgbd,
            0.039903,
            30.0,
            40.0,
        ),
        (
            "tum1_orbslam2_rgbd.yaml",
            517.306408,
            516.469215,
            318.643040,
            255.313989,
            40.0,
            Some(5000.0),
            1000,
            Sensor::Rgbd,
            0.262383,
            30.0,
            40.0,
        ),
        (
            "tum2_orbslam2_rgbd.yaml",
            520.908620,
            521.007327,
            325.141442,
            249.701764,
            40.0,
            Some(5208.0),
            1000,
            Sensor::Rgbd,
            0.231222,
            30.0,
            40.0,
        ),
        (
            "tum3_orbslam2_rgbd.yaml",
            535.4,
            539.2,
            320.1,
            247.6,
            40.0,
            Some(5000.0),
            1000,
            Sensor::Rgbd,
            0.0,
            30.0,
            40.0,
        ),
    ];
    for (file, fx, fy, cx, cy, bf, factor, nf, sensor, k1, fps, th) in rows {
        let s =
            read_orbslam_yaml(&data().join("calib").join(file)).unwrap_or_else(|e| panic!("{e}"));
        let c = &s.camera;
        assert_eq!((c.fx, c.fy, c.cx, c.cy), (fx, fy, cx, cy), "{file}");
        assert_eq!(s.bf, Some(bf), "{file}");
        assert_eq!(s.sensor, sensor, "{file}");
        if let Some(f) = factor {
            assert_eq!(s.depth_factor, f, "{file}");
        }
        assert_eq!(s.orb.n_features, nf, "{file}");
        // KITTI04-12 lowers iniThFAST to 12.
        let ini = if file.starts_with("KITTI04") { 12 } else { 20 };
        assert_eq!(
            (
                s.orb.scale_factor,
                s.orb.n_levels,
                s.orb.ini_th_fast,
                s.orb.min_th_fast
            ),
            (1.2, 8, ini, 7),
            "{file}"
        );
        assert_eq!(
            (c.distortion.k1, s.fps, s.th_depth, s.rgb),
            (k1, fps, th, true),
            "{file}"
        );
    }
    let tum1 = read_orbslam_yaml(&data().join("calib/tum1_orbslam2_rgbd.yaml")).unwrap();
    assert_eq!(
        (
            tum1.camera.distortion.k3,
            tum1.camera.width,
            tum1.camera.height
        ),
        (1.163314, 640, 480)
    );
    // The copies beside the association files too.
    for f in [
        "orbslam2_examples/Examples/RGB-D/TUM1.yaml",
        "orbslam2_examples/Examples/Stereo/EuRoC.yaml",
        "bonn_crowdslam/bonn.yaml",
    ] {
        read_orbslam_yaml(&data().join("associations").join(f)).unwrap_or_else(|e| panic!("{e}"));
    }
}

#[test]
#[ignore = "needs ../shared/data"]
fn kitti_reader_reads_seq01_first51() {
    let seq = open(&data().join("kitti/seq01_first51_left"), None, None).unwrap();
    assert_eq!(seq.len(), 51);
    let s = seq.settings();
    assert_eq!(
        (s.camera.fx, s.camera.cx, s.camera.cy),
        (718.856, 607.1928, 185.2157)
    );
    assert_eq!(
        (s.camera.width, s.camera.height, s.sensor),
        (1241, 376, Sensor::Mono)
    );
    assert!((s.bf.unwrap() - 386.1448).abs() < 1e-9);
    let f = seq.frame(50).unwrap();
    assert_eq!((f.index, f.gray.width, f.gray.height), (50, 1241, 376));
    assert!((f.timestamp - seq.timestamp(50).unwrap()).abs() < 1e-12 && f.timestamp > 5.0);
    assert!(seq.frame(51).is_err());
    let gt = seq.ground_truth().unwrap();
    assert!(gt.to_string_lossy().contains("poses"));
}

#[test]
#[ignore = "needs ../shared/data"]
fn tum_association_reproduces_the_shipped_association_files() {
    let mut files = Vec::new();
    for sub in [
        "tum_dynamic_dynaslam",
        "bonn_crowdslam",
        "orbslam2_examples/Examples/RGB-D/associations",
    ] {
        for e in std::fs::read_dir(data().join("associations").join(sub)).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "txt") {
                files.push(p);
            }
        }
    }
    assert!(files.len() >= 20, "{files:?}");
    for f in files {
        let entries = read_associations(&f, f.parent().unwrap()).unwrap_or_else(|e| panic!("{e}"));
        let rgb: Vec<f64> = entries.iter().map(|e| e.rgb_stamp).collect();
        let mut depth: Vec<f64> = entries.iter().map(|e| e.depth_stamp).collect();
        depth.sort_by(f64::total_cmp);
        depth.dedup();
        let pairs = associate_nearest(&rgb, &depth, 0.02);
        let mine: Vec<(f64, f64)> = pairs.iter().map(|&(i, j)| (rgb[i], depth[j])).collect();
        let theirs: Vec<(f64, f64)> = entries
            .iter()
            .map(|e| (e.rgb_stamp, e.depth_stamp))
            .collect();
        assert_eq!(mine, theirs, "{}", f.display());
    }
}

#[test]
#[ignore = "needs ../shared/data"]
fn real_depth_maps_pass_the_scale_check_and_fail_it_with_the_wrong_factor() {
    use stillpoint_datasets::depth_scale_warning;
    use stillpoint_image::read_depth_metres;
    // TUM fr1 desk and ICL-NUIM living room, both 5000 per metre.
    let files = [
        data().join("rgbd_pairs/pair/1_depth.png"),
        data().join("rgbd_pairs/pair/2_depth.png"),
        data().join("rgbd_pairs/five_frames_with_poses/depth/1.png"),
        data().join("rgbd_pairs/five_frames_with_poses/depth/5.png"),
    ];
    for f in &files {
        let right = read_depth_metres(f, 5000.0).unwrap();
        assert_eq!(depth_scale_warning(&right, 5000.0), None, "{}", f.display());
        // Read as millimetres the same maps are 5x too deep (medians 7.2-15 m).
        let as_mm = read_depth_metres(f, 1000.0).unwrap();
        let w = depth_scale_warning(&as_mm, 1000.0).expect("read with 1000");
        assert!(w.contains("with 5000"), "{w}");
        // Read with a factor 10x too large (medians 0.14-0.30 m): too shallow.
        let tiny = read_depth_metres(f, 50000.0).unwrap();
        assert!(
            depth_scale_warning(&tiny, 50000.0).is_some(),
            "{}",
            f.display()
        );
    }
}

#[test]
#[ignore = "needs ../shared/data"]
fn euroc_stereo_settings_carry_orbslams_rectification() {
    let s = read_orbslam_yaml(&data().join("calib/EuRoC_orbslam2_stereo.yaml")).unwrap();
    let r = s.rectification.expect("LEFT/RIGHT blocks");
    assert!((r.bf() - 47.90639384423901).abs() < 1e-12);
    assert_eq!((r.left.raw.fx, r.right.raw.cx), (458.654, 379.999));
    assert_eq!(r.left.raw.distortion.k1, -0.28340811);
    assert_eq!(r.left.rectified_camera().fx, s.camera.fx);
    assert_eq!(r.right.r[2][2], 0.999945173484644);
}
