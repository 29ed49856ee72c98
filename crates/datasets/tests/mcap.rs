//! ROS recordings: frames written with `RecordingWriter` (the `mcap` crate's writer, CDR, ROS 2
//! schema names) read back the same through `mcap::open`, whatever the chunking; bad files
//! (truncated, corrupted, a ROS 1 bag, a missing topic, an unknown encoding) are one error
//! naming the file, never a panic.

use std::collections::BTreeMap;
use std::io::Cursor;
use std::path::Path;
use stillpoint_datasets::mcap::{
    DepthEncoding, McapSequence, McapTopics, RecordingWriter, cdr::CdrWriter, inspect,
};
use stillpoint_datasets::{DatasetError, Sensor, Sequence};
use stillpoint_geometry::PinholeCamera;
use stillpoint_image::ImageBuf;

mod common;
use common::{H, W, camera, frame};

fn topics() -> McapTopics {
    common::topics_named("/camera/color/image_raw")
}

fn write(path: &Path, options: mcap::WriteOptions, depth: DepthEncoding, n: usize) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let name = path.display().to_string();
    let mut w = RecordingWriter::new(file, options, &name, &topics(), depth, &camera()).unwrap();
    for i in 0..n {
        w.write_frame(&frame(i)).unwrap();
    }
    w.finish().unwrap();
}

fn open(path: &Path, topics: &McapTopics) -> Result<Box<dyn Sequence>, DatasetError> {
    stillpoint_datasets::mcap::open(path, topics, None)
}

#[test]
fn frames_read_back_equal_whatever_the_chunking() {
    let dir = tempfile::tempdir().unwrap();
    let options = [
        ("zstd", mcap::WriteOptions::new()),
        (
            "lz4",
            mcap::WriteOptions::new()
                .compression(Some(mcap::Compression::Lz4))
                .chunk_size(Some(3000)),
        ),
        ("chunks", mcap::WriteOptions::new().compression(None)),
        ("none", mcap::WriteOptions::new().use_chunks(false)),
    ];
    for (name, options) in options {
        let path = dir.path().join(format!("{name}.mcap"));
        write(&path, options, DepthEncoding::Millimetres16, 12);
        let seq = open(&path, &topics()).unwrap();
        assert_eq!(seq.len(), 12, "{name}");
        let s = seq.settings();
        assert_eq!(s.camera, camera(), "{name}: the camera of CameraInfo");
        assert_eq!(
            (s.sensor, s.depth_factor, s.fps),
            (Sensor::Rgbd, 1000.0, 30.0)
        );
        // Out of order on purpose: chunks are found again by offset.
        for i in [5, 0, 11, 6, 1] {
            let (got, want) = (seq.frame(i).unwrap(), frame(i));
            assert_eq!(got.timestamp, want.timestamp, "{name} frame {i}");
            assert_eq!(got.rgb, want.rgb, "{name} frame {i}");
            assert_eq!(got.gray, want.gray, "{name} frame {i}");
            assert_eq!(got.depth, want.depth, "{name} frame {i}");
        }
    }
}

#[test]
fn metres_depth_monocular_and_given_settings() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("f32.mcap");
    write(&path, mcap::WriteOptions::new(), DepthEncoding::Metres32, 4);
    let seq = open(&path, &topics()).unwrap();
    assert_eq!(seq.settings().depth_factor, 1.0);
    assert_eq!(seq.frame(2).unwrap().depth, frame(2).depth);
    // Without a depth topic: monocular.
    let mono = McapTopics {
        depth: None,
        ..topics()
    };
    let seq = open(&path, &mono).unwrap();
    assert_eq!(seq.settings().sensor, Sensor::Mono);
    assert!(seq.frame(0).unwrap().depth.is_none());
    // A settings file of another camera size: one error naming the message.
    let toml = dir.path().join("cam.toml");
    std::fs::write(
        &toml,
        "sensor = \"rgbd\"\n[camera]\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\nwidth = 640\nheight = 480\n",
    )
    .unwrap();
    let e = stillpoint_datasets::mcap::open(&path, &topics(), Some(&toml))
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("f32.mcap: /camera/color/image_raw message 0: image is 32x24"),
        "{e}"
    );
}

#[test]
fn a_missing_topic_lists_the_topics_there_are() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rec.mcap");
    write(
        &path,
        mcap::WriteOptions::new(),
        DepthEncoding::Millimetres16,
        2,
    );
    let wrong = McapTopics {
        rgb: "/camera/rgb/image_color".into(),
        ..topics()
    };
    let e = open(&path, &wrong).err().unwrap().to_string();
    assert!(e.starts_with(&format!("{}: --rgb-topic /camera/rgb/image_color: no such topic; topics in the file: /camera/color/camera_info (sensor_msgs/msg/CameraInfo), /camera/color/image_raw (sensor_msgs/msg/Image)", path.display())), "{e}");
    // No camera info where it is looked for, no settings: say what to pass.
    let moved = McapTopics {
        camera_info: Some("/info".into()),
        ..topics()
    };
    let e = open(&path, &moved).err().unwrap().to_string();
    assert!(e.contains("topic /info: no such topic"), "{e}");
    assert!(e.contains("pass --settings"), "{e}");
}

#[test]
fn truncated_and_corrupted_files_are_errors_naming_the_file_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rec.mcap");
    write(
        &path,
        mcap::WriteOptions::new().use_chunks(false),
        DepthEncoding::Millimetres16,
        6,
    );
    let bytes = std::fs::read(&path).unwrap();
    let cut = dir.path().join("cut.mcap");
    for at in [bytes.len() / 2, 9, 3, bytes.len() - 30] {
        std::fs::write(&cut, &bytes[..at]).unwrap();
        let e = open(&cut, &topics()).err().unwrap().to_string();
        assert!(e.starts_with(&format!("{}: byte ", cut.display())), "{e}");
        assert!(!e.contains('\n'), "one line: {e}");
        if at > 8 {
            assert!(e.contains("truncated"), "{e}");
        }
    }
    // Chunked and compressed, cut in the middle.
    let zstd = dir.path().join("zstd.mcap");
    write(
        &zstd,
        mcap::WriteOptions::new().chunk_size(Some(4000)),
        DepthEncoding::Millimetres16,
        6,
    );
    let z = std::fs::read(&zstd).unwrap();
    std::fs::write(&cut, &z[..z.len() / 2]).unwrap();
    let e = open(&cut, &topics()).err().unwrap().to_string();
    assert!(e.contains("truncated"), "{e}");
    // Flipped bytes anywhere: an error or frames, never a panic.
    for file in [&bytes, &z] {
        for k in 0..200 {
            let mut bad = file.clone();
            let i = (k * 7919 + 13) % bad.len();
            bad[i] ^= 0x5a;
            std::fs::write(&cut, &bad).unwrap();
            if let Ok(seq) = open(&cut, &topics()) {
                for f in 0..seq.len() {
                    let _ = seq.frame(f);
                }
            }
            let _ = inspect(&cut);
        }
    }
}

#[test]
fn broken_bags_and_other_files_are_refused_clearly() {
    let dir = tempfile::tempdir().unwrap();
    // A ROS 1 bag is read (tests/rosbag.rs); one cut in its first record names the byte.
    let bag = dir.path().join("old.bag");
    std::fs::write(&bag, b"#ROSBAG V2.0\nE\x00\x00\x00").unwrap();
    let e = open(&bag, &topics()).err().unwrap().to_string();
    assert!(
        e.contains("old.bag: byte 13: a record header of 69 bytes"),
        "{e}"
    );
    assert!(e.contains("truncated"), "{e}");
    let txt = dir.path().join("notes.mcap");
    std::fs::write(&txt, b"hello world, not mcap").unwrap();
    let e = open(&txt, &topics()).err().unwrap().to_string();
    assert!(e.contains("notes.mcap: byte 0: not an MCAP file"), "{e}");
    // A `ros2 bag` folder: its one .mcap is read.
    let folder = dir.path().join("rosbag2_2024_01_01");
    std::fs::create_dir(&folder).unwrap();
    write(
        &folder.join("rosbag2_2024_01_01_0.mcap"),
        mcap::WriteOptions::new(),
        DepthEncoding::Millimetres16,
        3,
    );
    std::fs::write(
        folder.join("metadata.yaml"),
        "rosbag2_bagfile_information: {}\n",
    )
    .unwrap();
    assert_eq!(open(&folder, &topics()).unwrap().len(), 3);
}

/// An MCAP of one image message with `encoding`, hand-written (`wire`: cdr or ros1).
fn one_image(path: &Path, encoding: &str, ros1: bool) {
    let mut out = mcap::Writer::new(Cursor::new(Vec::new())).unwrap();
    let (schema, schema_enc, msg_enc) = if ros1 {
        ("sensor_msgs/Image", "ros1msg", "ros1")
    } else {
        ("sensor_msgs/msg/Image", "ros2msg", "cdr")
    };
    let s = out.add_schema(schema, schema_enc, b"").unwrap();
    let c = out
        .add_channel(s, "/cam/image", msg_enc, &BTreeMap::new())
        .unwrap();
    let data = if ros1 {
        // seq, secs, nsecs, frame_id "", height 1, width 2, "rgb8", is_bigendian, step, data.
        let mut m = Vec::new();
        for v in [0u32, 5, 500_000_000, 0, 1, 2, 4] {
            m.extend_from_slice(&v.to_le_bytes());
        }
        m.extend_from_slice(encoding.as_bytes());
        m.push(0);
        m.extend_from_slice(&6u32.to_le_bytes());
        m.extend_from_slice(&6u32.to_le_bytes());
        m.extend_from_slice(&[1, 2, 3, 4, 5, 6]);
        m
    } else {
        let mut m = CdrWriter::new();
        m.header(5.5, "cam").u32(1).u32(2).string(encoding);
        m.u8(0).u32(4).bytes(&[0; 4]);
        m.finish()
    };
    let header = mcap::records::MessageHeader {
        channel_id: c,
        sequence: 0,
        log_time: 1,
        publish_time: 1,
    };
    out.write_to_known_channel(&header, &data).unwrap();
    out.finish().unwrap();
    std::fs::write(path, out.into_inner().into_inner()).unwrap();
}

#[test]
fn an_unsupported_encoding_names_the_message_and_ros1_messages_read() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("yuv.mcap");
    one_image(&path, "yuv422", false);
    let topics = McapTopics {
        rgb: "/cam/image".into(),
        ..Default::default()
    };
    let cam = PinholeCamera::new(2.0, 2.0, 1.0, 0.5, 2, 1);
    let settings = stillpoint_datasets::Settings::with_camera(Sensor::Mono, cam);
    let e = McapSequence::open(&path, &topics, Some(settings.clone()))
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.starts_with(&format!("{}: /cam/image message 0 (byte ", path.display())),
        "{e}"
    );
    assert!(e.contains("\"yuv422\" is not supported"), "{e}");
    // ROS 1 serialisation (what `mcap convert` makes of a .bag).
    let path = dir.path().join("ros1.mcap");
    one_image(&path, "rgb8", true);
    let seq = McapSequence::open(&path, &topics, Some(settings)).unwrap();
    let f = seq.frame(0).unwrap();
    assert_eq!(f.timestamp, 5.5);
    assert_eq!(f.rgb.unwrap().data, vec![[1, 2, 3], [4, 5, 6]]);
}

#[test]
fn inspect_lists_topics_counts_and_first_images() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rec.mcap");
    write(
        &path,
        mcap::WriteOptions::new(),
        DepthEncoding::Millimetres16,
        10,
    );
    let info = inspect(&path).unwrap();
    assert_eq!(info.messages, 30);
    assert_eq!(info.compression, vec!["zstd".to_string()]);
    assert!((info.duration_s - 9.0 / 30.0).abs() < 1e-6);
    let t: Vec<String> = info
        .topics
        .iter()
        .map(|t| {
            let first = t.width.zip(t.height).zip(t.image_encoding.as_deref());
            format!("{} {} {} {first:?}", t.topic, t.ty, t.messages)
        })
        .collect();
    assert_eq!(
        t,
        vec![
            "/camera/color/camera_info sensor_msgs/msg/CameraInfo 10 None",
            "/camera/color/image_raw sensor_msgs/msg/Image 10 Some(((32, 24), \"rgb8\"))",
            "/camera/depth/image_raw sensor_msgs/msg/Image 10 Some(((32, 24), \"16UC1\"))",
        ]
    );
    assert!((info.topics[1].rate_hz.unwrap() - 30.0).abs() < 1e-3);
    let table = info.table();
    assert!(table.contains("32x24 16UC1"), "{table}");
}

/// A rectified stereo pair: left colour and right `mono8` images read back as stereo frames,
/// the camera from the left CameraInfo's P and `bf` from the right one's `P[3]`; a wrong right
/// topic names the flag, and a right camera with no baseline says to pass --settings.
#[test]
fn a_stereo_pair_reads_back_with_the_baseline_of_the_right_camera_info() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("stereo.mcap");
    let topics = McapTopics {
        rgb: "/stereo/left/image_rect_color".into(),
        right: Some("/stereo/right/image_rect".into()),
        ..Default::default()
    };
    let cam = PinholeCamera::new(30.5, 30.5, 15.5, 11.25, W as u32, H as u32);
    let stereo = |i: usize| {
        let mut f = frame(i);
        f.depth = None;
        let right = f.gray.data.iter().map(|v| v.wrapping_add(9)).collect();
        f.right = Some(ImageBuf::from_vec(W, H, right).unwrap());
        f
    };
    let write = |bf: f64| {
        let file = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
        let options = mcap::WriteOptions::new();
        let name = path.display().to_string();
        let w = RecordingWriter::new(file, options, &name, &topics, DepthEncoding::Metres32, &cam);
        let mut w = w.unwrap().with_stereo_bf(bf);
        for i in 0..4 {
            w.write_frame(&stereo(i)).unwrap();
        }
        w.finish().unwrap();
    };
    write(3.05);
    let seq = open(&path, &topics).unwrap();
    let s = seq.settings();
    assert_eq!(
        (s.sensor, s.camera, s.bf),
        (Sensor::Stereo, cam, Some(3.05))
    );
    for i in [2, 0] {
        let (got, want) = (seq.frame(i).unwrap(), stereo(i));
        assert_eq!(got.gray, want.gray, "frame {i}");
        assert_eq!(got.right, want.right, "frame {i}");
        assert_eq!(got.depth, None);
    }

    let wrong = McapTopics {
        right: Some("/stereo/right/image_raw".into()),
        ..topics.clone()
    };
    let e = open(&path, &wrong).err().unwrap().to_string();
    assert!(
        e.starts_with(&format!(
            "{}: --right-topic /stereo/right/image_raw: no such topic",
            path.display()
        )),
        "{e}"
    );

    write(0.0);
    let e = open(&path, &topics).err().unwrap().to_string();
    assert!(
        e.starts_with(&format!(
            "{}: /stereo/right/camera_info message 0 (byte ",
            path.display()
        )),
        "{e}"
    );
    assert!(e.contains("no baseline") && e.contains("--settings"), "{e}");
}
