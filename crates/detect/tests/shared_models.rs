//! Checks against the real YOLOX-nano models and photos in `../shared` (ignored by default:
//! `cargo test -p stillpoint-detect --features tract -- --ignored`; set ORT_DYLIB_PATH to check
//! ONNX Runtime too).

use std::path::PathBuf;
use stillpoint_detect::{Backend, DetectInput, DetectSettings, Detection, Detector, YoloxDetector};

fn shared() -> PathBuf {
    std::env::var_os("STILLPOINT_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared"))
}

fn detect(model: &str, backend: Backend, image: &std::path::Path) -> Vec<Detection> {
    let settings = DetectSettings {
        backend,
        ..Default::default()
    };
    let mut det = YoloxDetector::load(&shared().join("models").join(model), &settings).unwrap();
    let rgb = stillpoint_image::read_rgb(image).unwrap();
    det.detect(&DetectInput {
        index: 0,
        timestamp: 0.0,
        rgb: &rgb,
    })
    .unwrap()
}

fn backends() -> Vec<Backend> {
    let b = stillpoint_detect::backend::available(None);
    assert!(
        !b.is_empty(),
        "no inference backend: build with --features tract, or set ORT_DYLIB_PATH"
    );
    b
}

#[test]
#[ignore = "needs ../shared/data"]
fn two_people_and_two_tvs_as_the_models_readme_lists() {
    let image = shared().join("data/detector_images/tum_fr3_two_people.png");
    // ../shared/models/README.md: class, score, x1 y1 x2 y2 at conf 0.3, NMS 0.45.
    let expected: [(u16, f32, [f32; 4]); 4] = [
        (0, 0.88, [243.0, 169.0, 537.0, 444.0]),
        (0, 0.86, [0.0, 103.0, 181.0, 434.0]),
        (62, 0.89, [283.0, 146.0, 417.0, 243.0]),
        (62, 0.88, [80.0, 159.0, 177.0, 238.0]),
    ];
    for backend in backends() {
        let dets = detect("yolox_nano_480x640.onnx", backend, &image);
        for d in &dets {
            eprintln!(
                "{backend:?}: {} {:.3} {:?}",
                d.class_name(),
                d.score,
                d.bbox
            );
        }
        // The README lists the four confident objects; anything else must be a weak guess (the
        // floor below the people gives a skateboard at 0.33).
        let confident: Vec<_> = dets.iter().filter(|d| d.score > 0.5).collect();
        assert_eq!(confident.len(), expected.len(), "{backend:?}: {dets:?}");
        for (class, score, b) in expected {
            let hit = dets.iter().find(|d| {
                let got = [d.bbox.x1, d.bbox.y1, d.bbox.x2, d.bbox.y2];
                d.class_id == class
                    && (d.score - score).abs() <= 0.01
                    && got.iter().zip(b).all(|(g, w)| (g - w).abs() <= 2.0)
            });
            assert!(
                hit.is_some(),
                "{backend:?}: no match for {class} {score} {b:?} in {dets:?}"
            );
        }
    }
}

#[test]
#[cfg(feature = "tract")]
#[ignore = "needs ../shared/data and ORT_DYLIB_PATH"]
fn tract_and_ort_agree_on_every_detector_image() {
    if !stillpoint_detect::backend::ort_dylib_available(None) {
        eprintln!("ONNX Runtime not available (set ORT_DYLIB_PATH): nothing to compare");
        return;
    }
    let mut images: Vec<PathBuf> = std::fs::read_dir(shared().join("data/detector_images"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    images.sort();
    for model in [
        "yolox_nano_480x640.onnx",
        "yolox_nano_256x320.onnx",
        "yolox_nano_416x416.onnx",
    ] {
        for image in &images {
            let a = detect(model, Backend::Tract, image);
            let b = detect(model, Backend::Ort, image);
            let name = image.file_name().unwrap().to_string_lossy();
            eprintln!("{model} {name}: {} boxes", a.len());
            // Boxes near the score threshold may flip; everything clearly above must match.
            let clear = |d: &&Detection| d.score > 0.32;
            let (a, b): (Vec<_>, Vec<_>) = (
                a.iter().filter(clear).collect(),
                b.iter().filter(clear).collect(),
            );
            assert_eq!(a.len(), b.len(), "{model} {name}: tract {a:?} vs ort {b:?}");
            for d in &a {
                let twin = b.iter().find(|e| {
                    e.class_id == d.class_id
                        && (e.score - d.score).abs() <= 0.01
                        && e.bbox.iou(&d.bbox) > 0.98
                });
                assert!(
                    twin.is_some(),
                    "{model} {name}: tract {d:?} has no ort twin in {b:?}"
                );
            }
        }
    }
}

#[test]
#[ignore = "needs ../shared/data"]
fn detector_thread_gives_the_same_boxes_as_a_direct_call() {
    let image = shared().join("data/detector_images/tum_fr3_two_people.png");
    let backend = backends()[0];
    let direct = detect("yolox_nano_256x320.onnx", backend, &image);
    let settings = DetectSettings {
        model: Some(shared().join("models/yolox_nano_256x320.onnx")),
        backend,
        ..Default::default()
    };
    let worker = stillpoint_detect::DetectorThread::spawn(move || {
        stillpoint_detect::open_detector("yolox", &settings, None, Default::default())
    })
    .unwrap();
    assert_eq!(worker.name(), format!("yolox-{}", backend.as_str()));
    let rgb = std::sync::Arc::new(stillpoint_image::read_rgb(&image).unwrap());
    for i in 0..3 {
        worker.send(i, i as f64 / 30.0, rgb.clone()).unwrap();
    }
    for i in 0..3 {
        let (index, boxes) = worker.recv().unwrap();
        assert_eq!(index, i);
        assert_eq!(boxes.unwrap(), direct);
    }
}
