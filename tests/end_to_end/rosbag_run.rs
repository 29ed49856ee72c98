//! Cross-crate: `stillpoint run --bag rec.bag` on a ROS 1 bag. A synthetic RGB-D sequence is
//! written as a folder and as a bz2-chunked bag (sensor_msgs/Image rgb8 and 16UC1, CameraInfo):
//! both runs give the same trajectory. `stillpoint info` lists the bag; a truncated bag and a
//! wrong topic are one clear error line. A synthetic stereo pair (KITTI layout) written as a bag
//! with left and right topics runs as its folder does, the baseline from the right CameraInfo.

use std::path::Path;

use stillpoint_datasets::mcap::{DepthEncoding, McapTopics};
use stillpoint_datasets::rosbag::write::{BagCompression, BagWriter};

use crate::common::{
    assert_same_trajectory, error_line, ok_json, path_str, run_without_detector_on,
    run_without_detector_on_bag, stillpoint, synth_in_millimetres,
};

const RGB: &str = "/camera/rgb/image_color";
const DEPTH: &str = "/camera/depth_registered/image_raw";

/// The folder's frames as a ROS 1 bag.
fn write_bag(seq_dir: &Path, out: &Path, compression: BagCompression) {
    let seq = stillpoint_datasets::open(seq_dir, None, None).unwrap();
    let topics = McapTopics {
        rgb: RGB.into(),
        depth: Some(DEPTH.into()),
        right: None,
        camera_info: None,
    };
    let camera = seq.settings().camera;
    let mut w = BagWriter::create(
        out,
        &topics,
        DepthEncoding::Millimetres16,
        &camera,
        compression,
    )
    .unwrap();
    for i in 0..seq.len() {
        w.write_frame(&seq.frame(i).unwrap()).unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn a_ros1_bag_runs_as_its_folder_does() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth_in_millimetres(&seq, 20);
    let bag = tmp.path().join("rec.bag");
    write_bag(&seq, &bag, BagCompression::Bz2);

    let (a, b) = (tmp.path().join("folder.txt"), tmp.path().join("bag.txt"));
    let folder = ok_json(&run_without_detector_on(&["--dataset", path_str(&seq)], &a));
    // The camera comes from the bag's CameraInfo (no --settings).
    let recording = ok_json(&run_without_detector_on_bag(
        &bag,
        &["--rgb-topic", RGB, "--depth-topic", DEPTH],
        &b,
    ));
    assert_eq!(recording["sequence"], "rec");
    assert_eq!(recording["sensor"], folder["sensor"]);
    assert_eq!(recording["frames"], 20);
    assert!(folder["tracked"].as_u64().unwrap() >= 18, "{folder}");
    for k in ["tracked", "keyframes", "map_points"] {
        assert_eq!(recording[k], folder[k], "{k}");
    }
    assert_same_trajectory(&a, &b);

    // `info` names the topics, the ROS 1 types, the counts and the first images.
    let info = ok_json(
        &stillpoint()
            .args(["info", "--json"])
            .arg(&bag)
            .output()
            .unwrap(),
    );
    assert_eq!(info["compression"], serde_json::json!(["bz2"]));
    let topics = info["topics"].as_array().unwrap();
    let depth = topics.iter().find(|t| t["topic"] == DEPTH).unwrap();
    assert_eq!(depth["type"], "sensor_msgs/Image");
    assert_eq!(depth["encoding"], "ros1");
    assert_eq!(depth["messages"], 20);
    assert_eq!(depth["image_encoding"], "16UC1");
    let info_topic = topics
        .iter()
        .find(|t| t["topic"] == "/camera/rgb/camera_info")
        .unwrap();
    assert_eq!(info_topic["type"], "sensor_msgs/CameraInfo");
    let text = stillpoint().arg("info").arg(&bag).output().unwrap();
    let text = String::from_utf8(text.stdout).unwrap();
    assert!(text.contains("640x480 rgb8"), "{text}");

    // A wrong topic lists the topics there are.
    let e = error_line(&run_without_detector_on_bag(
        &bag,
        &["--rgb-topic", "/camera/color/image_raw"],
        &tmp.path().join("wrong.txt"),
    ));
    assert!(
        e.contains("no such topic; topics in the file: /camera/depth_registered/image_raw (sensor_msgs/Image)"),
        "{e}"
    );

    // Cut in the middle: one error naming the file and the byte.
    let bytes = std::fs::read(&bag).unwrap();
    let cut = tmp.path().join("cut.bag");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let e = error_line(&run_without_detector_on_bag(
        &cut,
        &["--rgb-topic", RGB],
        &tmp.path().join("cut.txt"),
    ));
    assert!(e.contains(&format!("{}: byte ", cut.display())), "{e}");
    assert!(e.contains("truncated"), "{e}");
    let e = error_line(&stillpoint().arg("info").arg(&cut).output().unwrap());
    assert!(e.contains("truncated"), "{e}");
}

const LEFT: &str = "/stereo/left/image_rect";
const RIGHT: &str = "/stereo/right/image_rect";

#[test]
fn a_stereo_bag_runs_as_its_kitti_folder_does() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    let st = stillpoint()
        .args(["synth", "--preset", "static", "--stereo", "--frames", "30"])
        .arg("--out")
        .arg(&seq)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );

    // The KITTI pair as a bag: mono8 left and right, the right CameraInfo's P[3] = -bf.
    let folder_seq =
        stillpoint_datasets::open(&seq, Some(stillpoint_datasets::DatasetKind::Kitti), None)
            .unwrap();
    let settings = folder_seq.settings();
    assert_eq!(settings.sensor, stillpoint_datasets::Sensor::Stereo);
    let topics = McapTopics {
        rgb: LEFT.into(),
        right: Some(RIGHT.into()),
        ..Default::default()
    };
    let bag = tmp.path().join("stereo.bag");
    let mut w = BagWriter::create(
        &bag,
        &topics,
        DepthEncoding::Millimetres16,
        &settings.camera,
        BagCompression::Lz4,
    )
    .unwrap()
    .with_stereo_bf(settings.bf.unwrap());
    for i in 0..folder_seq.len() {
        let f = folder_seq.frame(i).unwrap();
        assert!(f.right.is_some());
        w.write_frame(&f).unwrap();
    }
    w.finish().unwrap();

    let (a, b) = (tmp.path().join("folder.txt"), tmp.path().join("bag.txt"));
    let folder = ok_json(&run_without_detector_on(
        &["--dataset", path_str(&seq), "--kind", "kitti"],
        &a,
    ));
    // No --settings: the camera from the left CameraInfo, the baseline from the right one.
    let recording = ok_json(&run_without_detector_on_bag(
        &bag,
        &["--rgb-topic", LEFT, "--right-topic", RIGHT],
        &b,
    ));
    assert_eq!(folder["sensor"], "stereo", "{folder}");
    assert_eq!(recording["sensor"], folder["sensor"]);
    assert_eq!(recording["frames"], 30);
    assert_eq!(folder["tracked"], 30, "{folder}");
    for k in ["tracked", "keyframes", "map_points"] {
        assert_eq!(recording[k], folder[k], "{k}");
    }
    assert_same_trajectory(&a, &b);

    // A right topic the bag has not: one line naming the file, the flag and the topics there are.
    let e = error_line(&run_without_detector_on_bag(
        &bag,
        &[
            "--rgb-topic",
            LEFT,
            "--right-topic",
            "/stereo/right/image_raw",
        ],
        &tmp.path().join("wrong.txt"),
    ));
    assert!(
        e.contains(&format!(
            "{}: --right-topic /stereo/right/image_raw: no such topic; topics in the file: ",
            bag.display()
        )),
        "{e}"
    );
    assert!(e.contains(RIGHT), "{e}");

    // A right image topic without its camera info (the left info given as the right images'
    // neighbour is missing): no baseline, one line saying to pass --settings.
    let e = error_line(&run_without_detector_on_bag(
        &bag,
        &["--rgb-topic", LEFT, "--right-topic", LEFT],
        &tmp.path().join("same.txt"),
    ));
    assert!(e.contains("no baseline"), "{e}");
    assert!(e.contains("--settings"), "{e}");

    // Depth and right images are two different sensors.
    let e = error_line(&run_without_detector_on_bag(
        &bag,
        &[
            "--rgb-topic",
            LEFT,
            "--right-topic",
            RIGHT,
            "--depth-topic",
            DEPTH,
        ],
        &tmp.path().join("both.txt"),
    ));
    assert!(
        e.contains("--right-topic") && e.contains("--depth-topic"),
        "{e}"
    );
}
