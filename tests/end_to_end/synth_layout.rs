//! `stillpoint synth` writes a TUM-layout sequence (and KITTI stereo, masks) that the project's
//! readers read back, with depth identical to the in-process frames up to the PNG's 0.2 mm steps.

use std::path::Path;
use stillpoint_synth::{Preset, SynthConfig, WriteOptions};

fn lines(p: &Path) -> Vec<String> {
    std::fs::read_to_string(p)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(str::to_string)
        .collect()
}

#[test]
fn tum_layout_reads_back_with_exact_depth_poses_and_boxes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("seq");
    let cfg = SynthConfig {
        preset: Preset::WalkingXyz,
        frames: 8,
        stereo_baseline: Some(0.12),
        ..Default::default()
    };
    let opts = WriteOptions {
        stereo: true,
        masks: true,
    };
    let summary = stillpoint_synth::write_sequence(&cfg, opts, &out).unwrap();
    assert_eq!(summary.frames, 8);
    assert!(summary.mean_person_fraction > 0.05);

    let rgb = lines(&out.join("rgb.txt"));
    let depth = lines(&out.join("depth.txt"));
    assert_eq!((rgb.len(), depth.len()), (8, 8));
    let gt = stillpoint_trajectory::read_tum(&out.join("groundtruth.txt")).unwrap();
    assert_eq!(gt.stamps.len(), 8);
    let boxes = stillpoint_datasets::annotations::read_boxes(&out.join("boxes.jsonl")).unwrap();
    assert_eq!(boxes.len(), 8);

    let g = stillpoint_synth::generate(&cfg).unwrap();
    for (i, (r, d)) in rgb.iter().zip(&depth).enumerate() {
        let (stamp, file) = r.split_once(' ').unwrap();
        let t: f64 = stamp.parse().unwrap();
        assert!((t - gt.stamps[i]).abs() < 1e-6 && t > 1e9);
        assert_eq!(d.split_once(' ').unwrap().0, stamp);
        let f = g.frame(i);
        assert_eq!(boxes[i].boxes, f.boxes);
        // pose in the file equals the generator's to 1e-8
        let dp = f.pose_wc.inverse() * gt.poses[i];
        assert!(dp.translation.vector.norm() < 1e-8 && dp.rotation.angle() < 1e-8);
        let img = stillpoint_image::read_rgb(&out.join(file)).unwrap();
        assert_eq!(img, f.rgb);
        let dm =
            stillpoint_image::read_depth_metres(&out.join(d.split_once(' ').unwrap().1), 5000.0)
                .unwrap();
        let max_err = dm
            .data
            .iter()
            .zip(&f.depth.data)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(
            max_err <= 1.0e-4 + 1e-6,
            "frame {i}: depth PNG off by {max_err} m"
        );
        let mask =
            stillpoint_image::read_gray(&out.join("mask").join(format!("{stamp}.png"))).unwrap();
        assert_eq!(mask, f.dynamic_mask);
    }
    // settings.toml names the camera
    let settings = std::fs::read_to_string(out.join("settings.toml")).unwrap();
    assert!(settings.contains("fx = 535.4") && settings.contains("sensor = \"rgbd\""));
    // KITTI stereo: calib, times, poses relative to the first frame, images
    let calib = lines(&out.join("calib.txt"));
    let p1: Vec<f64> = calib[1][4..]
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    assert!((p1[3] + 535.4 * 0.12).abs() < 1e-9);
    assert_eq!(lines(&out.join("times.txt")).len(), 8);
    let kitti = stillpoint_trajectory::read_kitti(&out.join("poses.txt")).unwrap();
    assert!(kitti.poses[0].translation.vector.norm() < 1e-12);
    assert!(out.join("image_1/000007.png").exists());
}

#[test]
fn cli_rejects_bad_arguments_with_clear_errors() {
    let bin = env!("CARGO_BIN_EXE_stillpoint");
    let dir = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        let o = std::process::Command::new(bin).args(args).output().unwrap();
        (
            o.status.success(),
            String::from_utf8_lossy(&o.stderr).to_string(),
        )
    };
    let out = dir.path().join("x");
    let out = out.to_str().unwrap();
    let (ok, err) = run(&["synth", "--preset", "nope", "--out", out]);
    assert!(!ok && err.contains("unknown preset"), "{err}");
    let (ok, err) = run(&["synth", "--size", "64by48", "--out", out]);
    assert!(!ok && err.contains("--size"), "{err}");
    let (ok, err) = run(&["synth", "--noise", "loud", "--out", out]);
    assert!(!ok && err.contains("--noise"), "{err}");
    let (ok, _) = run(&[
        "synth", "--preset", "static", "--frames", "2", "--size", "160x120", "--out", out,
    ]);
    assert!(ok);
    assert_eq!(lines(&Path::new(out).join("rgb.txt")).len(), 2);
    let (ok, err) = run(&["run", "--dataset", out, "--no-dynamic", "--frames", "0"]);
    assert!(!ok && err.contains("--frames 0: nothing to run"), "{err}");
    // Another run holds the trajectory file: this one stops before touching it.
    let busy = dir.path().join("busy.txt");
    std::fs::write(&busy, "0 0 0 0 0 0 0 1\n").unwrap();
    let holder = std::fs::OpenOptions::new().write(true).open(&busy).unwrap();
    holder.lock().unwrap();
    let busy_arg = busy.to_str().unwrap();
    let (ok, err) = run(&["run", "--dataset", out, "--no-dynamic", "--out", busy_arg]);
    assert!(!ok && err.contains("another run is writing"), "{err}");
    assert_eq!(std::fs::read_to_string(&busy).unwrap(), "0 0 0 0 0 0 0 1\n");
    drop(holder);
    // A run that tracks nothing says why.
    let none = dir.path().join("none.txt");
    let (ok, err) = run(&[
        "run",
        "--dataset",
        out,
        "--no-dynamic",
        "--set",
        "slam.init_min_keypoints=100000",
        "--out",
        none.to_str().unwrap(),
    ]);
    assert!(
        !ok && err.contains("no frame could be tracked: the most keypoints a frame kept was"),
        "{err}"
    );
    // A bare word is no level: it would have silenced every log line.
    let (ok, err) = run(&["--log", "bogus", "settings"]);
    assert!(!ok && err.contains("--log bogus: expected one of"), "{err}");
}
