//! Cross-crate: `stillpoint run --bag` on a ROS 2 recording. A synthetic RGB-D sequence is
//! written as a folder and as MCAP (rgb8, 16UC1 depth, CameraInfo; CDR, ROS 2 schema names):
//! both runs give the same trajectory. `stillpoint info` lists the recording; a truncated
//! recording, a wrong topic and a recording given as `--dataset` are one clear error line.

use std::path::{Path, PathBuf};
use std::process::Output;

use stillpoint_datasets::mcap::{DepthEncoding, McapTopics, RecordingWriter};

use crate::common::{stillpoint, synth_in_millimetres};

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

/// `stillpoint run --detector none --sequential --json` with `source` (`--dataset D` or
/// `--bag F --rgb-topic ..`).
fn run(source: &[&str], traj: &Path) -> Output {
    stillpoint()
        .args(["run", "--detector", "none", "--sequential", "--json"])
        .args(source)
        .arg("--out")
        .arg(traj)
        .output()
        .unwrap()
}

fn ok_json(out: &Output) -> serde_json::Value {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{e}: {stderr}"))
}

/// The one error line of a failed command (`error: ...`), with no panic.
fn error_line(out: &Output) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let errors: Vec<&str> = stderr.lines().filter(|l| l.starts_with("error")).collect();
    assert_eq!(errors.len(), 1, "{stderr}");
    errors[0].to_string()
}

fn path_str(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn a_recording_runs_as_its_folder_does() {
    let tmp = tempfile::tempdir().unwrap();
    let seq = tmp.path().join("seq");
    synth_in_millimetres(&seq, 40);
    let bag: PathBuf = tmp.path().join("rec.mcap");
    write_recording(&seq, &bag);

    let (a, b) = (tmp.path().join("folder.txt"), tmp.path().join("bag.txt"));
    let folder = ok_json(&run(&["--dataset", path_str(&seq)], &a));
    // The camera comes from the recording's CameraInfo (no --settings).
    let recording = ok_json(&run(
        &[
            "--bag",
            path_str(&bag),
            "--rgb-topic",
            RGB,
            "--depth-topic",
            DEPTH,
        ],
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
    let e = error_line(&run(
        &[
            "--bag",
            path_str(&bag),
            "--rgb-topic",
            "/camera/rgb/image_color",
        ],
        &tmp.path().join("wrong.txt"),
    ));
    assert!(e.contains("no such topic; topics in the file: /camera/aligned_depth_to_color/image_raw (sensor_msgs/msg/Image)"), "{e}");

    // Cut in the middle: one error naming the file and the byte, no trajectory from nowhere.
    let bytes = std::fs::read(&bag).unwrap();
    let cut = tmp.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let e = error_line(&run(
        &[
            "--bag",
            path_str(&cut),
            "--rgb-topic",
            RGB,
            "--depth-topic",
            DEPTH,
        ],
        &tmp.path().join("cut.txt"),
    ));
    assert!(e.contains(&format!("{}: byte ", cut.display())), "{e}");
    assert!(e.contains("truncated"), "{e}");
    let e = error_line(&stillpoint().arg("info").arg(&cut).output().unwrap());
    assert!(e.contains("truncated"), "{e}");

    // A recording given as a folder says how to give it.
    let e = error_line(&run(
        &["--dataset", path_str(&bag)],
        &tmp.path().join("d.txt"),
    ));
    assert!(e.contains("--bag FILE --rgb-topic TOPIC"), "{e}");
}
