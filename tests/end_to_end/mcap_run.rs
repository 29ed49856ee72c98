//! Cross-crate: `stillpoint run --bag` on a ROS 2 recording. A synthetic RGB-D sequence is
//! written as a folder and as MCAP (rgb8, 16UC1 depth, CameraInfo; CDR, ROS 2 schema names):
//! both runs give the same trajectory. `stillpoint info` lists the recording; a truncated
//! recording, a wrong topic and a recording given as `--dataset` are one clear error line.

use std::path::{Path, PathBuf};

use stillpoint_datasets::mcap::{DepthEncoding, McapTopics, RecordingWriter};

use crate::common::{
    error_line, ok_json, path_str, run_without_detector_on, run_without_detector_on_bag,
    stillpoint, synth_in_millimetres,
};

const RGB: &str = "/camera/color/image_raw";
const DEPTH: &str = "/camera/aligned_depth_to_color/image_raw";

/// The folder's frames as a ROS 2 recording.
fn write_recording(seq_dir: &Path, out: &Path) {
    let seq = stillpoint_datasets::open(seq_dir, None, None).unwrap();
    let topics = McapTopics {
        rgb: RGB.into(),
        depth: Some(DEPTH.into()),
        right: None,
        camera_info: None,
    };
    let camera = seq.settings().camera;
    let mut w =
        RecordingWriter::create(out, &topics, DepthEncoding::Millimetres16, &camera).unwrap();
    for i in 0..seq.len() {
        w.write_frame(&seq.frame(i).unwrap()).unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn a_recording_runs_as_its_folder_does() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth_in_millimetres(&seq, 40);
    let bag: PathBuf = tmp.path().join("rec.mcap");
    write_recording(&seq, &bag);

    let (a, b) = (tmp.path().join("folder.txt"), tmp.path().join("bag.txt"));
    let folder = ok_json(&run_without_detector_on(&["--dataset", path_str(&seq)], &a));
    // The camera comes from the recording's CameraInfo (no --settings).
    let recording = ok_json(&run_without_detector_on_bag(
        &bag,
        &["--rgb-topic", RGB, "--depth-topic", DEPTH],
        &b,
    ));
    assert_eq!(recording["sequence"], "rec");
    assert_eq!(recording["sensor"], folder["sensor"]);
    assert_eq!(recording["frames"], 40);
    assert!(folder["tracked"].as_u64().unwrap() >= 35, "{folder}");
    for k in ["tracked", "keyframes", "map_points"] {
        assert_eq!(recording[k], folder[k], "{k}");
    }
    crate::common::assert_same_trajectory(&a, &b);

    // `info` names the topics, the types, the counts and the first images.
    let out = stillpoint()
        .args(["info", "--json"])
        .arg(&bag)
        .output()
        .unwrap();
    let info = ok_json(&out);
    let topics = info["topics"].as_array().unwrap();
    let depth = topics.iter().find(|t| t["topic"] == DEPTH).unwrap();
    assert_eq!(depth["type"], "sensor_msgs/msg/Image");
    assert_eq!(depth["encoding"], "cdr");
    assert_eq!(depth["messages"], 40);
    assert_eq!(
        (depth["width"].clone(), depth["height"].clone()),
        (640.into(), 480.into())
    );
    assert_eq!(depth["image_encoding"], "16UC1");
    let text = stillpoint().arg("info").arg(&bag).output().unwrap();
    let text = String::from_utf8(text.stdout).unwrap();
    assert!(text.contains("640x480 rgb8"), "{text}");

    // A wrong topic lists the topics there are.
    let e = error_line(&run_without_detector_on_bag(
        &bag,
        &["--rgb-topic", "/camera/rgb/image_color"],
        &tmp.path().join("wrong.txt"),
    ));
    assert!(e.contains("no such topic; topics in the file: /camera/aligned_depth_to_color/image_raw (sensor_msgs/msg/Image)"), "{e}");

    // Cut in the middle: one error naming the file and the byte, no trajectory from nowhere.
    let bytes = std::fs::read(&bag).unwrap();
    let cut = tmp.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let e = error_line(&run_without_detector_on_bag(
        &cut,
        &["--rgb-topic", RGB, "--depth-topic", DEPTH],
        &tmp.path().join("cut.txt"),
    ));
    assert!(e.contains(&format!("{}: byte ", cut.display())), "{e}");
    assert!(e.contains("truncated"), "{e}");
    let e = error_line(&stillpoint().arg("info").arg(&cut).output().unwrap());
    assert!(e.contains("truncated"), "{e}");

    // A recording given as a folder says how to give it.
    let e = error_line(&run_without_detector_on(
        &["--dataset", path_str(&bag)],
        &tmp.path().join("d.txt"),
    ));
    assert!(e.contains("--bag FILE --rgb-topic TOPIC"), "{e}");
}
