//! Self-contained checks of model loading: tiny ONNX files are written to a temp dir with the
//! crate's ONNX protobuf types, so no model download is needed. Running one needs a backend:
//! tract (`--features tract`) or ONNX Runtime's library.

mod common;

use common::{checked_backends, constant_model};
use std::path::{Path, PathBuf};
use stillpoint_detect::{Backend, DetectError, DetectSettings, YoloxDetector};

/// A 64x64 YOLOX-shaped model (84 anchors, 1 class) with one confident anchor at the
/// stride-16 cell (gx 2, gy 1): box centre (40, 20), size 32x16 in network pixels.
fn planted_yolox(dir: &Path) -> PathBuf {
    let k = 6;
    let mut out = vec![0.0f32; 84 * k];
    let row = 64 + 4 + 2;
    out[row * k..row * k + k].copy_from_slice(&[0.5, 0.25, 2f32.ln(), 0.0, 0.9, 0.8]);
    let path = dir.join("planted.onnx");
    std::fs::write(&path, constant_model(64, &[1, 84, k as i64], out)).unwrap();
    path
}

fn settings(backend: Backend) -> DetectSettings {
    DetectSettings {
        backend,
        ..Default::default()
    }
}

#[test]
#[cfg(feature = "tract")]
fn planted_detection_comes_through_every_backend() {
    use stillpoint_detect::{DetectInput, Detector};
    let rgb = stillpoint_image::Rgb8::new(128, 128, [90, 120, 30]);
    let dir = tempfile::tempdir().unwrap();
    let model = planted_yolox(dir.path());
    for backend in stillpoint_detect::backend::available(None) {
        let mut det = YoloxDetector::load(&model, &settings(backend)).unwrap();
        assert_eq!(det.input_size(), (64, 64));
        // A 128x128 image is letterboxed at ratio 0.5, so the box doubles.
        let dets = det
            .detect(&DetectInput {
                index: 3,
                timestamp: 0.1,
                rgb: &rgb,
            })
            .unwrap();
        assert_eq!(dets.len(), 1, "{backend:?}: {dets:?}");
        let d = dets[0];
        assert_eq!(d.class_id, 0);
        assert!((d.score - 0.72).abs() < 1e-5, "{backend:?}: {d:?}");
        let b = d.bbox;
        let want = [48.0, 24.0, 112.0, 56.0];
        for (got, want) in [b.x1, b.y1, b.x2, b.y2].into_iter().zip(want) {
            assert!((got - want).abs() < 1e-3, "{backend:?}: {b:?}");
        }
        assert!(det.name().starts_with("yolox-"));
    }
}

#[test]
fn missing_file_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.onnx");
    for backend in checked_backends() {
        let err = YoloxDetector::load(&missing, &settings(backend)).unwrap_err();
        assert!(matches!(err, DetectError::ModelIo { .. }), "{err}");
        assert!(err.to_string().contains("nope.onnx"), "{err}");
    }
}

#[test]
fn non_onnx_file_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let text = dir.path().join("notes.onnx");
    std::fs::write(&text, "this is not an ONNX model, just some text\n").unwrap();
    let empty = dir.path().join("empty.onnx");
    std::fs::write(&empty, b"").unwrap();
    for backend in checked_backends() {
        for path in [&text, &empty] {
            let err = YoloxDetector::load(path, &settings(backend)).unwrap_err();
            assert!(
                matches!(err, DetectError::NotOnnx { .. }),
                "{backend:?}: {err}"
            );
            let msg = err.to_string();
            assert!(
                msg.contains(&*path.to_string_lossy()) && msg.contains("ONNX"),
                "{msg}"
            );
        }
    }
}

#[test]
#[cfg(feature = "tract")]
fn wrong_output_shape_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    // 50 rows instead of the 84 anchors of a 64x64 YOLOX.
    let path = dir.path().join("classifier.onnx");
    std::fs::write(&path, constant_model(64, &[1, 50, 6], vec![0.0; 300])).unwrap();
    for backend in stillpoint_detect::backend::available(None) {
        let err = YoloxDetector::load(&path, &settings(backend)).unwrap_err();
        assert!(
            matches!(err, DetectError::ModelShape { .. }),
            "{backend:?}: {err}"
        );
        let msg = err.to_string();
        assert!(
            msg.contains("classifier.onnx") && msg.contains("84"),
            "{msg}"
        );
    }
    // And the same check on the decode function directly.
    assert!(stillpoint_detect::yolox::check_output_shape(&[1, 50, 6], 64, 64).is_err());
}

#[test]
fn ort_without_its_library_names_the_script() {
    let dir = tempfile::tempdir().unwrap();
    let model = planted_yolox(dir.path());
    if !cfg!(feature = "ort") {
        let err = YoloxDetector::load(&model, &settings(Backend::Ort)).unwrap_err();
        assert!(err.to_string().contains("--features ort"), "{err}");
        return;
    }
    let s = DetectSettings {
        backend: Backend::Ort,
        ort_dylib_path: Some(dir.path().join("libonnxruntime.so")),
        ..Default::default()
    };
    let err = YoloxDetector::load(&model, &s).unwrap_err();
    assert!(matches!(err, DetectError::OrtLibrary { .. }), "{err}");
    assert!(err.to_string().contains("setup-onnxruntime.sh"), "{err}");
}
