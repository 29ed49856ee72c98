//! Cross-crate: `stillpoint run --video clip.mp4`. Frames are encoded into an H.264 MP4 in a temp
//! folder (openh264's encoder, the mp4 crate's muxer) and run monocular: a synthetic static
//! sequence tracks from its video as from its folder; a clip cut short keeps the trajectory of
//! the frames before the cut and ends with one error line naming the file, the sample and its
//! byte. Real hand-held video with people (../shared/data): ignored without it.

use std::path::Path;
use std::process::Output;

use stillpoint_datasets::video::write::{VideoOptions, VideoWriter};

use crate::common::{error_line, ok_json, path_str, shared, stillpoint, synth_static};

/// Every frame of the sequence at `seq` as an MP4 at `fps`.
fn encode(seq: &Path, out: &Path, fps: f64, faststart: bool) -> usize {
    let seq = stillpoint_datasets::open(seq, None, None).unwrap();
    let first = seq.frame(0).unwrap();
    let (w, h) = (first.gray.width, first.gray.height);
    let opts = VideoOptions {
        fps,
        faststart,
        bitrate: 20_000_000,
    };
    let mut v = VideoWriter::create(out, w, h, opts).unwrap();
    for i in 0..seq.len() {
        v.write(seq.frame(i).unwrap().rgb.as_ref().unwrap())
            .unwrap();
    }
    v.finish().unwrap();
    seq.len()
}

fn run(args: &[&str], traj: &Path) -> Output {
    stillpoint()
        .args(["run", "--json"])
        .args(args)
        .arg("--out")
        .arg(traj)
        .output()
        .unwrap()
}

#[test]
fn a_synthetic_sequence_tracks_from_its_video_and_a_cut_video_keeps_its_first_poses() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth_static(&seq, 75, 0);
    let clip = tmp.path().join("clip.mp4");
    assert_eq!(encode(&seq, &clip, 30.0, true), 75);
    let settings = seq.join("settings.toml");
    let no_detector = ["--detector", "none", "--sequential"];

    let traj = tmp.path().join("video.txt");
    let mut args = vec![
        "--video",
        path_str(&clip),
        "--settings",
        path_str(&settings),
    ];
    args.extend(no_detector);
    let summary = ok_json(&run(&args, &traj));
    assert_eq!(summary["sequence"], "clip");
    assert_eq!(summary["sensor"], "mono");
    assert_eq!(summary["frames"], 75);
    // The folder, monocular, tracks 54 of 75 frames (slam_mono.rs); the H.264 frames
    // (20 Mbit/s) 54 too.
    let tracked = summary["tracked"].as_u64().unwrap();
    assert!(tracked >= 40, "{summary}");
    // Stamps are the sample times: frame i at i / 30 s.
    let t = stillpoint_trajectory::read_tum(&traj).unwrap();
    assert_eq!(t.len() as u64, tracked);
    for stamp in &t.stamps {
        let i = (stamp * 30.0).round();
        assert!((stamp - i / 30.0).abs() < 1e-9, "{stamp}");
    }

    // Without settings: a guessed camera, and a warning saying so (monocular needs a few dozen
    // frames of parallax before its map starts).
    let out = run(
        &[
            "--video",
            path_str(&clip),
            "--detector",
            "none",
            "--sequential",
        ],
        &tmp.path().join("guess.txt"),
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr
            .contains("no settings; guessing a pinhole camera with a 60° horizontal field of view"),
        "{stderr}"
    );

    // Cut at two thirds: the frames before the cut are run and their poses kept, then one error
    // line names the file, the sample and its byte.
    let bytes = std::fs::read(&clip).unwrap();
    let cut = tmp.path().join("cut.mp4");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let cut_traj = tmp.path().join("cut.txt");
    let mut args = vec!["--video", path_str(&cut), "--settings", path_str(&settings)];
    args.extend(no_detector);
    let e = error_line(&run(&args, &cut_traj));
    let prefix = format!("error: {}: sample ", cut.display());
    assert!(e.starts_with(&prefix), "{e}");
    assert!(e.contains("(byte ") && e.contains("cut short"), "{e}");
    let sample: usize = e[prefix.len()..]
        .split(' ')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!((30..75).contains(&sample), "{e}");
    assert!(
        e.contains("the trajectory and keyframe files are complete"),
        "{e}"
    );
    let kept = stillpoint_trajectory::read_tum(&cut_traj).unwrap();
    assert!(!kept.is_empty(), "{e}");
    assert!(kept.stamps.iter().all(|&t| t < sample as f64 / 30.0), "{e}");

    // A video given as a folder says how to give it.
    let e = error_line(&run(
        &["--dataset", path_str(&clip)],
        &tmp.path().join("d.txt"),
    ));
    assert!(e.contains("give it as --video FILE"), "{e}");
}

/// Real hand-held video with people: the 200 JPEG frames of SAM 2's bedroom clip (960x540,
/// children jumping on a bed while the camera pans), run monocular as a user has them (a folder
/// of images, the camera guessed, the default mode) with YOLOX culling people's keypoints when
/// the model is there; then the same frames as H.264 at 24 fps through `--video`.
#[test]
#[ignore = "needs ../shared/data"]
fn real_hand_held_video_with_people_initialises_and_tracks() {
    let frames = shared().join("data/video/sam2_bedroom/rgb");
    let tmp = tempfile::tempdir().unwrap();
    let model = shared().join("models/yolox_nano_480x640.onnx");
    let detector = if model.is_file() {
        vec!["--detector", "yolox", "--model", path_str(&model)]
    } else {
        vec!["--detector", "none"]
    };
    let mut args = vec!["--dataset", path_str(&frames)];
    args.extend(&detector);
    let folder = ok_json(&run(&args, &tmp.path().join("folder.txt")));
    eprintln!("folder: {folder}");
    assert_eq!(folder["frames"], 200);
    assert_eq!(folder["sensor"], "mono");
    assert_eq!(folder["new_maps"], 0, "{folder}");
    let tracked = folder["tracked"].as_u64().unwrap();
    if model.is_file() {
        // Measured with YOLOX-nano 480x640 (tract): the map stands at frame 9, the first with a
        // degree of parallax over frame 0, and frames 0-8 are tracked in it then: 200 of 200
        // (191 without them); 145 keypoints culled a frame (median 1: once the map is up, ORB
        // skips the moving boxes). The bed the children jump on is judged on its own points,
        // not theirs: judged on theirs it was "moving", and its box took 2,700 keypoints a
        // frame and the whole map with it.
        assert!(tracked >= 196, "{folder}");
        let culled = folder["culled_per_frame"]["mean"].as_f64().unwrap();
        assert!(culled < 200.0, "{folder}");
    } else {
        assert!(tracked >= 100, "{folder}");
    }

    let clip = tmp.path().join("bedroom.mp4");
    assert_eq!(encode(&frames, &clip, 24.0, false), 200);
    let mut args = vec!["--video", path_str(&clip)];
    args.extend(&detector);
    let video = ok_json(&run(&args, &tmp.path().join("video.txt")));
    eprintln!("video: {video}");
    assert_eq!(video["frames"], 200);
    if model.is_file() {
        // Measured: 200 of 200 tracked, 156 keypoints culled a frame (median 1). The bed is
        // judged the same way as in the folder now; before, it stayed still here by a hair
        // (its outlier ratio on the other side of ATA's 0.4) and the clip tracked 196.
        assert!(video["tracked"].as_u64().unwrap() >= 196, "{video}");
    } else {
        assert!(video["tracked"].as_u64().unwrap() >= 100, "{video}");
    }
}
