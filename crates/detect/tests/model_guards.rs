//! Crafted models that crashed the process before the model guards (`backend::guard`): each is
//! refused with one error naming the file and what is wrong, on every backend, before an engine
//! runs it.

mod common;

use common::*;
use std::path::{Path, PathBuf};
use stillpoint_detect::{DetectError, DetectSettings, YoloxDetector};

fn write(dir: &Path, name: &str, bytes: Vec<u8>) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

/// Loads `path` on every backend; each must fail with `want` and the words given (and the file's
/// name). Returns the tract error's message.
fn refused(path: &Path, words: &[&str], want: fn(&DetectError) -> bool) -> String {
    let mut first = None;
    for backend in checked_backends() {
        let settings = DetectSettings {
            backend,
            ..Default::default()
        };
        let err = YoloxDetector::load(path, &settings).unwrap_err();
        let msg = err.to_string();
        assert!(want(&err), "{backend:?}: {msg}");
        let name = path.file_name().unwrap().to_string_lossy();
        assert!(msg.contains(&*name), "{backend:?}: no file name in {msg}");
        for w in words {
            assert!(msg.contains(w), "{backend:?}: no {w:?} in {msg}");
        }
        assert!(
            !msg.contains('\n'),
            "{backend:?}: more than one line: {msg:?}"
        );
        first.get_or_insert(msg);
    }
    first.unwrap()
}

fn is_refused(e: &DetectError) -> bool {
    matches!(e, DetectError::ModelRefused { .. })
}

#[test]
fn zero_windows_of_convolutions_and_poolings_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    // A stride of 0 was a divide by zero inside tract (a panic, the process gone).
    let cases: Vec<(&str, Vec<u8>, &[&str])> = vec![
        (
            "conv_stride0.onnx",
            conv_model(vec![attr_ints("strides", &[0, 0])], 6),
            &["node \"features\" (Conv)", "strides [0, 0]", "out of range"],
        ),
        (
            "conv_dilation0.onnx",
            conv_model(vec![attr_ints("dilations", &[1, 0])], 6),
            &["dilations [1, 0]"],
        ),
        (
            "conv_kernel0.onnx",
            conv_model(vec![attr_ints("kernel_shape", &[0, 0])], 6),
            &["kernel_shape [0, 0]"],
        ),
        (
            "conv_group0.onnx",
            conv_model(vec![attr_int("group", 0)], 6),
            &["group [0]"],
        ),
        (
            "conv_pads_huge.onnx",
            conv_model(vec![attr_ints("pads", &[0, 0, 100_000, 0])], 6),
            &["pads [0, 0, 100000, 0]"],
        ),
        (
            "maxpool_stride0.onnx",
            conv_model_op(
                "MaxPool",
                vec![
                    attr_ints("kernel_shape", &[2, 2]),
                    attr_ints("strides", &[0, 0]),
                ],
                6,
            ),
            &["(MaxPool)", "strides [0, 0]"],
        ),
        (
            "avgpool_kernel_negative.onnx",
            conv_model_op("AveragePool", vec![attr_ints("kernel_shape", &[-2, 2])], 6),
            &["(AveragePool)", "kernel_shape [-2, 2]"],
        ),
    ];
    for (name, bytes, words) in cases {
        let path = write(dir.path(), name, bytes);
        refused(&path, words, is_refused);
    }
}

#[test]
fn a_huge_declared_input_is_refused_before_anything_is_allocated() {
    let dir = tempfile::tempdir().unwrap();
    // 3 x 100000 x 100000 floats: the ~120 GB allocation that aborted the process.
    let path = write(
        dir.path(),
        "huge_input.onnx",
        constant_model_in(&[1, 3, 100_000, 100_000], &[1, 84, 6], vec![0.0; 504]),
    );
    let msg = refused(&path, &["[1, 3, 100000, 100000]", "4096x4096"], is_refused);
    assert!(msg.contains("input \"images\""), "{msg}");
    // Past the element cap with sides under 4096 cannot happen for 3 channels; a wide one can.
    let path = write(
        dir.path(),
        "wide_input.onnx",
        constant_model_in(&[1, 3, 64, 5000], &[1, 84, 6], vec![0.0; 504]),
    );
    refused(&path, &["[1, 3, 64, 5000]"], is_refused);
}

#[test]
fn inputs_that_are_not_an_image_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    for (name, dims) in [
        ("input_3d.onnx", vec![1, 3, 64]),
        ("input_5d.onnx", vec![1, 3, 64, 64, 1]),
        ("input_zero.onnx", vec![1, 3, 0, 64]),
        ("input_negative.onnx", vec![1, 3, -64, 64]),
    ] {
        let path = write(
            dir.path(),
            name,
            constant_model_in(&dims, &[1, 84, 6], vec![0.0; 504]),
        );
        refused(&path, &["expected [1, 3, height, width]"], is_refused);
    }
}

#[test]
fn an_output_that_is_not_boxes_and_classes_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    // Last axis 5: a box and an objectness, no class.
    let path = write(
        dir.path(),
        "five.onnx",
        constant_model(64, &[1, 84, 5], vec![0.0; 420]),
    );
    refused(&path, &["last axis (5)", "5 + classes"], is_refused);
    // A classifier's [1, 1000].
    let path = write(
        dir.path(),
        "classifier.onnx",
        constant_model(64, &[1, 1, 1000, 1], vec![0.0; 1000]),
    );
    refused(&path, &["[1, 1, 1000, 1]", "5 + classes"], is_refused);
}

#[test]
fn a_huge_stored_tensor_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mut m = decode(&conv_model(vec![], 6));
    let g = m.graph.as_mut().unwrap();
    // Declared 10^10 floats, with no data: refused by its declaration, not by reading it.
    g.initializer
        .push(tensor("big", &[100_000, 100_000], vec![]));
    let path = write(dir.path(), "big_weights.onnx", encode(&m));
    refused(
        &path,
        &["initializer \"big\"", "[100000, 100000]"],
        is_refused,
    );
}

#[test]
#[cfg(feature = "tract")]
fn a_node_that_blows_the_input_up_is_refused_before_running() {
    use stillpoint_detect::onnx_proto as pb;
    let dir = tempfile::tempdir().unwrap();
    // A Pad of 20000 on each side of a 64x64 input: [1, 3, 40064, 40064] floats, 19 GB.
    let pads = tensor_i64(
        "pads",
        &[8],
        vec![0, 0, 20_000, 20_000, 0, 0, 20_000, 20_000],
    );
    let bytes = model(pb::GraphProto {
        name: "pad".into(),
        node: vec![
            node("Pad", &["images", "pads"], "padded", vec![]),
            node(
                "ReduceMean",
                &["padded"],
                "mean",
                vec![attr_int("keepdims", 0)],
            ),
            node("Mul", &["mean", "zero"], "nothing", vec![]),
            node("Add", &["nothing", "planted"], "output", vec![]),
        ],
        initializer: vec![
            pads,
            tensor("zero", &[], vec![0.0]),
            tensor("planted", &[1, 84, 6], vec![0.0; 504]),
        ],
        input: vec![value_info("images", &[1, 3, 64, 64])],
        output: vec![value_info("output", &[1, 84, 6])],
        ..Default::default()
    });
    let path = write(dir.path(), "pad_huge.onnx", bytes);
    // tract only: ONNX Runtime sizes tensors when it runs.
    let settings = DetectSettings {
        backend: stillpoint_detect::Backend::Tract,
        ..Default::default()
    };
    let err = YoloxDetector::load(&path, &settings).unwrap_err();
    let msg = err.to_string();
    assert!(is_refused(&err), "{msg}");
    for w in ["pad_huge.onnx", "node \"padded\"", "[1, 3, 40064, 40064]"] {
        assert!(msg.contains(w), "no {w:?} in {msg}");
    }
}
