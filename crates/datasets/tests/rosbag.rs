//! ROS 1 bags: frames written with `BagWriter` (format 2.0, chunks uncompressed, bz2 or lz4)
//! read back the same through the recording opener, with the camera of their CameraInfo;
//! truncated and corrupted bags are one error naming the file and the byte, never a panic.

use std::path::Path;
use stillpoint_datasets::mcap::{DepthEncoding, McapTopics, inspect};
use stillpoint_datasets::rosbag::write::{BagCompression, BagWriter};
use stillpoint_datasets::{DatasetError, Sensor, Sequence};

mod common;
use common::{W, camera, frame};

fn topics() -> McapTopics {
    common::topics_named("/camera/rgb/image_raw")
}

fn write(path: &Path, compression: BagCompression, depth: DepthEncoding, n: usize) {
    let mut w = BagWriter::create(path, &topics(), depth, &camera(), compression).unwrap();
    for i in 0..n {
        w.write_frame(&frame(i)).unwrap();
    }
    w.finish().unwrap();
}

fn open(path: &Path, topics: &McapTopics) -> Result<Box<dyn Sequence>, DatasetError> {
    stillpoint_datasets::open_recording(path, topics, None)
}

#[test]
fn frames_read_back_equal_whatever_the_compression() {
    let dir = tempfile::tempdir().unwrap();
    for c in [
        BagCompression::None,
        BagCompression::Bz2,
        BagCompression::Lz4,
    ] {
        let path = dir.path().join(format!("{c:?}.bag"));
        write(&path, c, DepthEncoding::Millimetres16, 9);
        let seq = open(&path, &topics()).unwrap();
        assert_eq!(seq.len(), 9, "{c:?}");
        let s = seq.settings();
        assert_eq!(s.camera, camera(), "{c:?}: the camera of CameraInfo");
        assert_eq!(
            (s.sensor, s.depth_factor, s.fps),
            (Sensor::Rgbd, 1000.0, 30.0)
        );
        // Out of order on purpose: chunks are found again by offset.
        for i in [5, 0, 8, 6, 1] {
            let (got, want) = (seq.frame(i).unwrap(), frame(i));
            assert_eq!(got.timestamp, want.timestamp, "{c:?} frame {i}");
            assert_eq!(got.rgb, want.rgb, "{c:?} frame {i}");
            assert_eq!(got.depth, want.depth, "{c:?} frame {i}");
        }
        let info = inspect(&path).unwrap();
        let name = format!("{c:?}").to_lowercase();
        assert_eq!(info.compression, vec![name], "{c:?}");
        assert_eq!(info.messages, 27);
        let rgb = info
            .topics
            .iter()
            .find(|t| t.topic == topics().rgb)
            .unwrap();
        assert_eq!(
            (rgb.ty.as_str(), rgb.width, rgb.image_encoding.as_deref()),
            ("sensor_msgs/Image", Some(W as u32), Some("rgb8"))
        );
    }
}

#[test]
fn metres_depth_and_monocular() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("f32.bag");
    write(&path, BagCompression::Lz4, DepthEncoding::Metres32, 4);
    let seq = open(&path, &topics()).unwrap();
    assert_eq!(seq.settings().depth_factor, 1.0);
    assert_eq!(seq.frame(2).unwrap().depth, frame(2).depth);
    let mono = McapTopics {
        depth: None,
        ..topics()
    };
    let seq = open(&path, &mono).unwrap();
    assert_eq!(seq.settings().sensor, Sensor::Mono);
    assert!(seq.frame(3).unwrap().depth.is_none());
}

#[test]
fn truncated_and_corrupted_bags_are_errors_naming_the_byte_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rec.bag");
    write(&path, BagCompression::Bz2, DepthEncoding::Millimetres16, 6);
    let bytes = std::fs::read(&path).unwrap();
    let cut = dir.path().join("cut.bag");
    for at in [bytes.len() / 2, 4200, 20, bytes.len() - 30] {
        std::fs::write(&cut, &bytes[..at]).unwrap();
        let e = open(&cut, &topics()).err().unwrap().to_string();
        assert!(
            e.starts_with(&format!("{}: byte ", cut.display())),
            "{at}: {e}"
        );
        assert!(!e.contains('\n'), "one line: {e}");
        assert!(e.contains("truncated"), "{at}: {e}");
    }
    // Bytes of the second chunk's compressed data flipped: its byte is named.
    let mut bad = bytes.clone();
    let second_chunk = bytes
        .windows(15)
        .enumerate()
        .filter(|(_, w)| *w == b"compression=bz2")
        .map(|(i, _)| i)
        .nth(1)
        .unwrap();
    for b in &mut bad[second_chunk + 120..second_chunk + 160] {
        *b ^= 0x5a;
    }
    std::fs::write(&cut, &bad).unwrap();
    let e = open(&cut, &topics()).err().unwrap().to_string();
    assert!(e.starts_with(&format!("{}: byte ", cut.display())), "{e}");
    assert!(e.contains("bz2"), "{e}");
    // Anything at all: no panic.
    for step in [1usize, 7, 97] {
        let mut bad = bytes.clone();
        for i in (13..bad.len()).step_by(step * 131) {
            bad[i] = bad[i].wrapping_add(77);
        }
        std::fs::write(&cut, &bad).unwrap();
        if let Ok(seq) = open(&cut, &topics()) {
            for f in 0..seq.len() {
                let _ = seq.frame(f);
            }
        }
        let _ = inspect(&cut);
    }
}
