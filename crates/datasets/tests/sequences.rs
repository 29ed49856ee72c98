//! Self-contained readers on small temp-dir sequences: the good path and clear errors.

use proptest::prelude::*;
use std::path::Path;
use stillpoint_datasets::euroc::EurocSequence;
use stillpoint_datasets::{
    DatasetKind, Sensor, Sequence, Settings, detect_kind, open, parse_orbslam_yaml,
    parse_settings_toml, write_settings_toml,
};
use stillpoint_geometry::PinholeCamera;
use stillpoint_image::{Gray8, ImageBuf, Rgb8, write_depth16, write_gray, write_rgb};

fn small_settings(sensor: Sensor) -> Settings {
    Settings::with_camera(sensor, PinholeCamera::new(40.0, 40.0, 16.0, 12.0, 32, 24))
}

/// A TUM-layout sequence of `n` frames with depth 30 ms after each rgb frame.
fn tum_dir(dir: &Path, n: usize) {
    std::fs::create_dir_all(dir.join("rgb")).unwrap();
    std::fs::create_dir_all(dir.join("depth")).unwrap();
    let (mut rgb, mut depth) = (String::from("# rgb\n"), String::from("# depth\n"));
    for i in 0..n {
        let t = 1.0 + i as f64 * 0.1;
        write_rgb(
            &dir.join(format!("rgb/{i}.png")),
            &Rgb8::new(32, 24, [i as u8 * 10, 50, 90]),
        )
        .unwrap();
        write_depth16(
            &dir.join(format!("depth/{i}.png")),
            &ImageBuf::<u16>::new(32, 24, 5000),
        )
        .unwrap();
        rgb.push_str(&format!("{t:.6} rgb/{i}.png\n"));
        depth.push_str(&format!("{:.6} depth/{i}.png\n", t + 0.015));
    }
    std::fs::write(dir.join("rgb.txt"), rgb).unwrap();
    std::fs::write(dir.join("depth.txt"), depth).unwrap();
    write_settings_toml(&dir.join("settings.toml"), &small_settings(Sensor::Rgbd)).unwrap();
}

#[test]
fn tum_layout_reads_lazily_and_associates_depth() {
    let d = tempfile::tempdir().unwrap();
    tum_dir(d.path(), 4);
    assert_eq!(detect_kind(d.path()).unwrap(), DatasetKind::Tum);
    let seq = open(d.path(), None, None).unwrap();
    assert_eq!((seq.len(), seq.settings().sensor), (4, Sensor::Rgbd));
    let f = seq.frame(2).unwrap();
    assert_eq!((f.index, f.gray.width), (2, 32));
    assert!((f.timestamp - 1.2).abs() < 1e-9);
    assert_eq!(f.depth.unwrap().get(3, 3), 1.0);
    assert!(
        seq.frame(4)
            .unwrap_err()
            .to_string()
            .contains("out of range")
    );
    std::fs::write(d.path().join("boxes.jsonl"), "").unwrap();
    assert_eq!(detect_kind(d.path()).unwrap(), DatasetKind::Synth);
    assert!(open(d.path(), None, None).unwrap().boxes().is_some());
    // Settings of another camera: an error when the sequence is opened, not frame by frame.
    let other = Settings::with_camera(
        Sensor::Rgbd,
        PinholeCamera::new(40.0, 40.0, 32.0, 24.0, 64, 48),
    );
    write_settings_toml(&d.path().join("settings.toml"), &other).unwrap();
    let e = open(d.path(), None, None).err().unwrap().to_string();
    assert!(
        e.contains("image is 32x24 but the settings say 64x48"),
        "{e}"
    );
}

#[test]
fn tum_errors_name_file_and_line() {
    let d = tempfile::tempdir().unwrap();
    tum_dir(d.path(), 3);
    // Unsorted stamps.
    std::fs::write(d.path().join("rgb.txt"), "2.0 rgb/0.png\n1.0 rgb/1.png\n").unwrap();
    let e = open(d.path(), None, None).err().unwrap().to_string();
    assert!(e.contains("rgb.txt:2:") && e.contains("sorted"), "{e}");
    // A line with three fields, and a non-number.
    std::fs::write(d.path().join("rgb.txt"), "1.0 rgb/0.png x\n").unwrap();
    assert!(
        open(d.path(), None, None)
            .err()
            .unwrap()
            .to_string()
            .contains("rgb.txt:1:")
    );
    std::fs::write(d.path().join("rgb.txt"), "abc rgb/0.png\n").unwrap();
    assert!(
        open(d.path(), None, None)
            .err()
            .unwrap()
            .to_string()
            .contains("\"abc\"")
    );
    // A missing depth image fails when its frame is read, naming it.
    std::fs::write(d.path().join("rgb.txt"), "1.0 rgb/0.png\n1.1 rgb/1.png\n").unwrap();
    std::fs::remove_file(d.path().join("depth/1.png")).unwrap();
    let seq = open(d.path(), None, None).unwrap();
    assert!(seq.frame(0).is_ok());
    let e = seq.frame(1).unwrap_err().to_string();
    assert!(e.contains("depth/1.png"), "{e}");
    // A corrupt PNG.
    std::fs::write(d.path().join("rgb/0.png"), b"\x89PNG not really").unwrap();
    let e = seq.frame(0).unwrap_err().to_string();
    assert!(e.contains("rgb/0.png"), "{e}");
    // Without depth.txt the sequence is monocular.
    std::fs::remove_file(d.path().join("depth.txt")).unwrap();
    assert_eq!(
        open(d.path(), None, None).unwrap().settings().sensor,
        Sensor::Mono
    );
    // A missing directory.
    assert!(
        open(&d.path().join("nope"), None, None)
            .err()
            .unwrap()
            .to_string()
            .contains("nope")
    );
}

#[test]
fn kitti_folder_and_euroc_layouts() {
    let d = tempfile::tempdir().unwrap();
    let k = d.path().join("kitti");
    for cam in ["image_0", "image_1"] {
        std::fs::create_dir_all(k.join(cam)).unwrap();
        for i in 0..3 {
            write_gray(&k.join(format!("{cam}/{i:06}.png")), &Gray8::new(32, 24, 7)).unwrap();
        }
    }
    std::fs::write(
        k.join("calib.txt"),
        "P0: 40 0 16 0 0 40 12 0 0 0 1 0\nP1: 40 0 16 -20 0 40 12 0 0 0 1 0\n",
    )
    .unwrap();
    std::fs::write(k.join("times.txt"), "0.0\n0.1\n0.2\n").unwrap();
    let seq = open(&k, None, None).unwrap();
    assert_eq!(
        (seq.len(), seq.settings().sensor, seq.settings().bf),
        (3, Sensor::Stereo, Some(20.0))
    );
    assert!(seq.frame(1).unwrap().right.is_some());
    std::fs::write(k.join("times.txt"), "0.0\n0.2\n0.1\n").unwrap();
    assert!(
        open(&k, None, None)
            .err()
            .unwrap()
            .to_string()
            .contains("times.txt:3:")
    );
    std::fs::write(k.join("times.txt"), "0.0\n0.1\n0.2\n").unwrap();
    // A calibration that parses but is no camera: named, not run.
    for (calib, key) in [
        (
            "P0: 0 0 16 0 0 40 12 0 0 0 1 0\nP1: 40 0 16 -20 0 40 12 0 0 0 1 0\n",
            "P0[0] (fx)",
        ),
        (
            "P0: 40 0 16 0 0 40 12 0 0 0 1 0\nP1: 40 0 16 20 0 40 12 0 0 0 1 0\n",
            "P1[3]",
        ),
    ] {
        std::fs::write(k.join("calib.txt"), calib).unwrap();
        let e = open(&k, None, None).err().unwrap().to_string();
        assert!(e.contains("calib.txt") && e.contains(key), "{e}");
    }

    let f = d.path().join("folder");
    std::fs::create_dir_all(&f).unwrap();
    for i in 0..2 {
        write_rgb(&f.join(format!("{i}.jpg")), &Rgb8::new(32, 24, [1, 2, 3])).unwrap();
    }
    let seq = open(&f, None, None).unwrap();
    assert_eq!((seq.len(), seq.settings().camera.fx), (2, 32.0));
    assert!((seq.frame(1).unwrap().timestamp - 1.0 / 30.0).abs() < 1e-12);

    let e = d.path().join("euroc/mav0/cam0");
    std::fs::create_dir_all(e.join("data")).unwrap();
    write_gray(
        &e.join("data/1403636579763555584.png"),
        &Gray8::new(32, 24, 3),
    )
    .unwrap();
    std::fs::write(
        e.join("data.csv"),
        "#timestamp [ns],filename\n1403636579763555584,1403636579763555584.png\n",
    )
    .unwrap();
    std::fs::write(
        e.join("sensor.yaml"),
        "%YAML:1.0\nrate_hz: 20\nresolution: [32, 24]\nintrinsics: [40.0, 41.0, 16.0, 12.0]\ndistortion_coefficients: [-0.28, 0.07, 0.0002, 0.00002]\n",
    )
    .unwrap();
    let seq = open(&d.path().join("euroc"), None, None).unwrap();
    assert_eq!(
        (seq.len(), seq.settings().camera.fy, seq.settings().fps),
        (1, 41.0, 20.0)
    );
    assert!((seq.frame(0).unwrap().timestamp - 1_403_636_579.763_555_6).abs() < 1e-6);

    // A stereo EuRoC right image of the wrong size is an error naming it, as on KITTI.
    let r = d.path().join("euroc/mav0/cam1");
    std::fs::create_dir_all(r.join("data")).unwrap();
    std::fs::copy(e.join("data.csv"), r.join("data.csv")).unwrap();
    let right = r.join("data/1403636579763555584.png");
    write_gray(&right, &Gray8::new(16, 12, 3)).unwrap();
    let stereo = Settings {
        sensor: Sensor::Stereo,
        ..seq.settings().clone()
    };
    let seq = EurocSequence::open(&d.path().join("euroc"), Some(stereo)).unwrap();
    let err = seq.frame(0).unwrap_err().to_string();
    assert!(err.contains("cam1") && err.contains("16x12"), "{err}");
}

#[test]
fn orbslam_yaml_dialect_and_toml_form() {
    let text = "%YAML:1.0\nCamera1.fx: 500\nCamera1.fy: 501\nCamera1.cx: 320\nCamera1.cy: 240\n\
                Camera.width: 640\nCamera.height: 480\nStereo.b: 0.1\nViewer.PointSize:2\n\
                M: !!opencv-matrix\n   rows: 1\n   cols: 2\n   dt: d\n   data:[1.0, 2.0]\n";
    let s = parse_orbslam_yaml(text, "a.yaml".as_ref()).unwrap();
    assert_eq!((s.camera.fx, s.sensor), (500.0, Sensor::Stereo));
    assert!((s.bf.unwrap() - 50.0).abs() < 1e-12);
    let e = parse_orbslam_yaml("%YAML:1.0\nCamera.fx: 500\n", "b.yaml".as_ref())
        .unwrap_err()
        .to_string();
    assert!(e.contains("b.yaml") && e.contains("Camera.fy"), "{e}");
    let e = parse_orbslam_yaml("Camera.fx: [oops\n", "c.yaml".as_ref())
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("c.yaml: line"), "{e}");
    let e = parse_orbslam_yaml("Camera.fx: .nan\n", "d.yaml".as_ref())
        .unwrap_err()
        .to_string();
    assert!(e.contains("line 1") && e.contains("finite"), "{e}");

    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.toml");
    write_settings_toml(&p, &s).unwrap();
    assert_eq!(stillpoint_datasets::read_settings(&p).unwrap(), s);
    let e = parse_settings_toml(
        "sensor = \"rgbd\"\n[camera]\nfx = \"x\"\n",
        "t.toml".as_ref(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.starts_with("t.toml: line 3"), "{e}");
}

/// Values that parse but make nonsense are refused, naming the file, the line and the key.
#[test]
fn settings_out_of_range_are_errors_naming_file_line_and_key() {
    let base = "%YAML:1.0\nCamera.fx: 500\nCamera.fy: 500\nCamera.cx: 320\nCamera.cy: 240\n\
                Camera.width: 640\nCamera.height: 480\nDepthMapFactor: 5000\n";
    assert!(parse_orbslam_yaml(base, "ok.yaml".as_ref()).is_ok());
    for (change, key) in [
        ("Camera.fx: 500", "Camera.fx: 1e-300"),
        ("DepthMapFactor: 5000", "DepthMapFactor: -1"),
        (
            "DepthMapFactor: 5000",
            "DepthMapFactor: 5000\nORBextractor.scaleFactor: 1.0",
        ),
        (
            "DepthMapFactor: 5000",
            "DepthMapFactor: 5000\nORBextractor.nFeatures: 0",
        ),
        (
            "DepthMapFactor: 5000",
            "DepthMapFactor: 5000\nORBextractor.nLevels: 0",
        ),
    ] {
        let text = base.replace(change, key);
        let e = parse_orbslam_yaml(&text, "bad.yaml".as_ref())
            .unwrap_err()
            .to_string();
        let name = key.lines().last().unwrap().split(':').next().unwrap();
        assert!(
            e.starts_with("bad.yaml: line ") && e.contains(name),
            "{key}: {e}"
        );
    }
    // A byte-order mark (Windows editors) is no part of the first key.
    let d = tempfile::tempdir().unwrap();
    let bom = d.path().join("bom.yaml");
    std::fs::write(&bom, format!("\u{feff}{base}")).unwrap();
    assert_eq!(
        stillpoint_datasets::read_settings(&bom).unwrap().camera.fx,
        500.0
    );
    let toml = "sensor = \"rgbd\"\ndepth_factor = 0.0\n[camera]\nfx = 500.0\nfy = 500.0\n\
                cx = 320.0\ncy = 240.0\nwidth = 640\nheight = 480\n";
    let e = parse_settings_toml(toml, "bad.toml".as_ref())
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("bad.toml: line 2: depth_factor"), "{e}");
    // RGB-D uses bf too (its close-point depth): a NaN one is refused, not only a stereo one's.
    let toml = toml.replace("depth_factor = 0.0", "depth_factor = 5000.0\nbf = nan");
    let e = parse_settings_toml(&toml, "bad.toml".as_ref())
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("bad.toml: line 3: bf"), "{e}");
}

#[test]
fn stereo_rectification_blocks_are_read_whole_and_checked_against_the_camera() {
    let head = "%YAML:1.0\nCamera.fx: 400\nCamera.fy: 400\nCamera.cx: 320\nCamera.cy: 240\n\
                Camera.width: 640\nCamera.height: 480\nCamera.bf: 40\n";
    let side = |name: &str, fx: f64, tx: f64| {
        format!(
            "{name}.D: !!opencv-matrix\n   rows: 1\n   cols: 4\n   dt: d\n   data:[-0.2, 0.05, 0, 0]\n\
             {name}.K: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data:[410, 0, 321, 0, 411, 239, 0, 0, 1]\n\
             {name}.R: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data:[1, 0, 0, 0, 1, 0, 0, 0, 1]\n\
             {name}.P: !!opencv-matrix\n   rows: 3\n   cols: 4\n   dt: d\n   data:[{fx}, 0, 320, {tx}, 0, {fx}, 240, 0, 0, 0, 1, 0]\n"
        )
    };
    let both = format!(
        "{head}{}{}",
        side("LEFT", 400.0, 0.0),
        side("RIGHT", 400.0, -40.0)
    );
    let s = parse_orbslam_yaml(&both, "r.yaml".as_ref()).unwrap();
    let r = s.rectification.expect("rectification");
    assert_eq!(
        (r.bf(), r.left.raw.fx, r.left.raw.distortion.k1),
        (40.0, 410.0, -0.2)
    );
    assert_eq!((r.right.p[0][3], r.left.raw.width), (-40.0, 640));
    // Without the blocks: none, as before.
    assert_eq!(
        parse_orbslam_yaml(head, "h.yaml".as_ref())
            .unwrap()
            .rectification,
        None
    );
    let err = |text: &str| {
        parse_orbslam_yaml(text, "e.yaml".as_ref())
            .unwrap_err()
            .to_string()
    };
    let e = err(&format!("{head}{}", side("LEFT", 400.0, 0.0)));
    assert!(e.contains("both LEFT.* and RIGHT.*"), "{e}");
    let partial = side("RIGHT", 400.0, -40.0).replace("RIGHT.P", "RIGHT.Q");
    let e = err(&format!("{head}{}{partial}", side("LEFT", 400.0, 0.0)));
    assert!(e.contains("RIGHT.P go together"), "{e}");
    // The tracked camera must be the rectified one (LEFT.P), and bf its baseline.
    let e = err(&format!(
        "{head}{}{}",
        side("LEFT", 390.0, 0.0),
        side("RIGHT", 390.0, -39.0)
    ));
    assert!(e.contains("must be LEFT.P's"), "{e}");
    let e = err(&format!(
        "{head}{}{}",
        side("LEFT", 400.0, 0.0),
        side("RIGHT", 400.0, -44.0)
    ));
    assert!(e.contains("Camera.bf 40 differs"), "{e}");
    let bad = side("LEFT", 400.0, 0.0).replace("data:[410, 0, 321,", "data:[410, 0,");
    let e = err(&format!("{head}{bad}{}", side("RIGHT", 400.0, -40.0)));
    assert!(e.contains("LEFT.K must be a 3x3 matrix"), "{e}");
    // The TOML form carries it too.
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.toml");
    write_settings_toml(&p, &s).unwrap();
    assert_eq!(stillpoint_datasets::read_settings(&p).unwrap(), s);
}

proptest! {
    #[test]
    fn settings_parsers_never_panic(text in "[ -~\n]{0,300}") {
        let _ = parse_orbslam_yaml(&text, "r.yaml".as_ref());
        let _ = parse_settings_toml(&text, "r.toml".as_ref());
    }
}

#[test]
fn yaml_aliases_are_refused_before_they_are_expanded() {
    // Nine levels of ten aliases each: 10^9 nodes once expanded (the process was killed).
    let mut text = String::from(
        "%YAML:1.0\nCamera.fx: 500\nCamera.fy: 500\nCamera.cx: 320\nCamera.cy: 240\n\
         Camera.width: 640\nCamera.height: 480\na0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]\n",
    );
    for i in 1..9 {
        let p = format!("*a{}", i - 1);
        text.push_str(&format!("a{i}: &a{i} [{}]\n", vec![p; 10].join(", ")));
    }
    let e = parse_orbslam_yaml(&text, "bomb.yaml".as_ref())
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("bomb.yaml: line 9: YAML aliases"), "{e}");
    // A single alias is refused the same way.
    let one = "%YAML:1.0\nCamera.fx: &f 500\nCamera.fy: *f\n";
    let e = parse_orbslam_yaml(one, "one.yaml".as_ref())
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("one.yaml: line 3: YAML aliases"), "{e}");
}

#[test]
fn tiny_numbers_are_shown_short_and_huge_cameras_are_refused() {
    let base = "%YAML:1.0\nCamera.fx: 500\nCamera.fy: 500\nCamera.cx: 320\nCamera.cy: 240\n\
                Camera.width: 640\nCamera.height: 480\n";
    // 1e-300 was printed with its 300 zeros.
    let e = parse_orbslam_yaml(
        &base.replace("Camera.fx: 500", "Camera.fx: 1e-300"),
        "tiny.yaml".as_ref(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("Camera.fx = 1e-300: a focal length"), "{e}");
    // ~80 bytes a pixel: 12000x12000 would take ~11 GB.
    let e = parse_orbslam_yaml(
        &base
            .replace("Camera.width: 640", "Camera.width: 12000")
            .replace("Camera.height: 480", "Camera.height: 12000"),
        "huge.yaml".as_ref(),
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.starts_with("huge.yaml: line 6: Camera.width = 12000x12000: images of 1 to 16384"),
        "{e}"
    );
    let toml = "sensor = \"mono\"\n[camera]\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\n\
                width = 100000\nheight = 480\n";
    let e = parse_settings_toml(toml, "wide.toml".as_ref())
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("wide.toml: line 7: camera.width = 100000x480"),
        "{e}"
    );
}

/// A PNG of only its header: signature, IHDR of `width` x `height` RGB, an empty IDAT, IEND.
fn png_header_only(width: u32, height: u32) -> Vec<u8> {
    fn crc32(bytes: &[u8]) -> u32 {
        let mut c = 0xffff_ffffu32;
        for &b in bytes {
            c ^= b as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 {
                    0xedb8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
            }
        }
        !c
    }
    let chunk = |kind: &[u8], data: &[u8]| {
        let mut out = (data.len() as u32).to_be_bytes().to_vec();
        let body = [kind, data].concat();
        out.extend(&body);
        out.extend(crc32(&body).to_be_bytes());
        out
    };
    let mut ihdr = width.to_be_bytes().to_vec();
    ihdr.extend(height.to_be_bytes());
    ihdr.extend([8, 2, 0, 0, 0]);
    [
        b"\x89PNG\r\n\x1a\n".to_vec(),
        chunk(b"IHDR", &ihdr),
        // An empty zlib stream: the pixels are missing.
        chunk(b"IDAT", &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01]),
        chunk(b"IEND", &[]),
    ]
    .concat()
}

#[test]
fn an_image_of_another_size_is_told_from_its_header_before_it_is_decoded() {
    let d = tempfile::tempdir().unwrap();
    tum_dir(d.path(), 3);
    // 100000 x 100000 RGB is 30 GB decoded; the file is 65 bytes.
    std::fs::write(
        d.path().join("rgb/0.png"),
        png_header_only(100_000, 100_000),
    )
    .unwrap();
    let e = open(d.path(), None, None).err().unwrap().to_string();
    assert!(
        e.contains("rgb/0.png: image is 100000x100000 but the settings say 32x24"),
        "{e}"
    );
    // The same for a later frame, and for depth.
    tum_dir(d.path(), 3);
    std::fs::write(d.path().join("depth/2.png"), png_header_only(50_000, 9)).unwrap();
    let seq = open(d.path(), None, None).unwrap();
    let e = seq.frame(2).unwrap_err().to_string();
    assert!(e.contains("depth/2.png: image is 50000x9"), "{e}");
}

/// ORB-SLAM2's own settings files give no image size: a source that knows it (a video) fills it
/// in, a size the file gives is kept (and checked against each frame where it is read), and
/// without an image size the key is still required, named in the error.
#[test]
fn a_settings_file_without_the_image_size_takes_the_images() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("TUM1.yaml");
    let camera =
        "%YAML:1.0\nCamera.fx: 517.3\nCamera.fy: 516.5\nCamera.cx: 318.6\nCamera.cy: 255.3\n";
    std::fs::write(&p, camera).unwrap();
    let s = stillpoint_datasets::read_settings_for_images(&p, (960, 540)).unwrap();
    assert_eq!((s.camera.width, s.camera.height), (960, 540));
    assert_eq!(s.camera.fx, 517.3);
    let e = stillpoint_datasets::read_settings(&p)
        .unwrap_err()
        .to_string();
    assert!(e.contains("TUM1.yaml") && e.contains("Camera.width"), "{e}");
    std::fs::write(
        &p,
        format!("{camera}Camera.width: 640\nCamera.height: 480\n"),
    )
    .unwrap();
    let s = stillpoint_datasets::read_settings_for_images(&p, (960, 540)).unwrap();
    assert_eq!((s.camera.width, s.camera.height), (640, 480));
}
