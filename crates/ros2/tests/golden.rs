//! The node's messages against the bytes Eclipse Cyclone DDS's own serializer writes for the
//! same messages (`tests/ros2/golden.py`, the rmw_cyclonedds wire format), and the camera
//! messages Cyclone writes read back by the project's decoder.

use stillpoint_datasets::mcap::cdr::Wire;
use stillpoint_datasets::mcap::ros::{CameraInfoMsg, ImageMsg, MessageType};
use stillpoint_geometry::{Se3, se3_from_tum};
use stillpoint_ros2::msg::{self, Stamp, Transform};

const STAMP: Stamp = Stamp {
    sec: 1341846313,
    nanosec: 533333000,
};
const STAMP_S: f64 = 1341846313.533333;

fn golden(name: &str) -> Vec<u8> {
    let path = format!("{}/tests/golden/{name}.cdr", env!("CARGO_MANIFEST_DIR"));
    std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
}

fn pose() -> Se3 {
    se3_from_tum([0.5, -1.25, 2.0], [0.0, 0.0, 0.6, 0.8]).expect("a unit quaternion")
}

/// Bytes equal, or the first difference shown.
fn same(name: &str, ours: &[u8]) {
    let theirs = golden(name);
    if ours != theirs.as_slice() {
        let at = ours
            .iter()
            .zip(&theirs)
            .position(|(a, b)| a != b)
            .unwrap_or(ours.len().min(theirs.len()));
        panic!(
            "{name}: ours {} bytes, Cyclone's {}; first difference at byte {at}: ours {:02x?}, theirs {:02x?}",
            ours.len(),
            theirs.len(),
            &ours[at.saturating_sub(4)..(at + 8).min(ours.len())],
            &theirs[at.saturating_sub(4)..(at + 8).min(theirs.len())]
        );
    }
}

#[test]
fn published_messages_are_cyclones_bytes() {
    same(
        "odometry",
        &msg::odometry(STAMP, "map", "camera_color_optical_frame", &pose()),
    );
    same(
        "tf",
        &msg::tf_message(
            STAMP,
            &[Transform {
                parent: "map",
                child: "camera_color_optical_frame",
                transform: pose(),
            }],
        ),
    );
    same(
        "path",
        &msg::path(
            STAMP,
            "map",
            &[
                (
                    Stamp {
                        sec: 1341846313,
                        nanosec: 500000000,
                    },
                    Se3::identity(),
                ),
                (STAMP, pose()),
            ],
        ),
    );
    same(
        "point_cloud",
        &msg::point_cloud(
            STAMP,
            "map",
            &[
                ([1.0, 2.0, 3.0], [255, 128, 0]),
                ([-0.5, 0.25, 4.0], [1, 2, 3]),
            ],
        ),
    );
    same(
        "compressed_image",
        &msg::compressed_image(STAMP, "camera", "jpeg", &[0xFF, 0xD8, 0xFF, 0xD9]),
    );
    same("string", &msg::string("tracking"));
}

#[test]
fn cyclones_camera_messages_decode() {
    let bytes = golden("image_rgb8");
    let img = ImageMsg::decode(&bytes, Wire::Cdr, MessageType::Image).expect("decodes");
    assert_eq!(img.stamp, STAMP_S);
    let rgb = img.to_rgb().expect("rgb8");
    assert_eq!((rgb.width, rgb.height), (3, 2));
    assert_eq!(rgb.data[5], [15, 16, 17]);

    let bytes = golden("image_32fc1");
    let img = ImageMsg::decode(&bytes, Wire::Cdr, MessageType::Image).expect("decodes");
    let (depth, units) = img.to_depth().expect("32FC1");
    assert_eq!(units, 1.0);
    assert_eq!(depth.data, vec![0.5, 1.0, 1.5, 0.0, 2.25, 3.0]);

    let info = CameraInfoMsg::decode(&golden("camera_info"), Wire::Cdr).expect("decodes");
    assert_eq!((info.width, info.height), (640, 480));
    assert_eq!(info.distortion_model, "plumb_bob");
    assert_eq!(info.d, vec![0.1, -0.2, 0.001, 0.002, 0.0]);
    let cam = info.camera(false).expect("calibrated");
    assert_eq!(
        (cam.fx, cam.fy, cam.cx, cam.cy),
        (535.4, 539.2, 320.1, 247.6)
    );
}

#[test]
fn a_truncated_sample_is_an_error_not_a_panic() {
    let bytes = golden("image_rgb8");
    for cut in [0, 3, 10, 40, bytes.len() - 1] {
        let r = ImageMsg::decode(&bytes[..cut], Wire::Cdr, MessageType::Image)
            .map_err(|e| e.to_string())
            .and_then(|m| m.to_rgb());
        assert!(r.is_err(), "{cut} bytes decoded");
    }
}

#[test]
fn cyclones_tf_message_decodes() {
    let t = msg::decode_tf(&golden("tf")).expect("decodes");
    assert_eq!(t.len(), 1);
    let (parent, child, pose_) = &t[0];
    assert_eq!(
        (parent.as_str(), child.as_str()),
        ("map", "camera_color_optical_frame")
    );
    assert!((pose_.to_homogeneous() - pose().to_homogeneous()).norm() < 1e-12);
    let mut bytes = golden("tf");
    bytes[4] = 200; // two hundred transforms in 116 bytes
    assert!(msg::decode_tf(&bytes).is_err());
}
