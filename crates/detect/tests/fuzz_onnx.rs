//! Property tests of the ONNX loader: random bytes, and random edits of a valid small YOLOX-shaped
//! model (bytes flipped, cut or inserted; shapes, attributes, operators and tensors changed in the
//! decoded graph). Loading gives `Ok` or an error naming the file, never a panic or an abort;
//! a model that loads runs on a frame with `Ok` or such an error.
//!
//! A panic inside tract that the checks before it did not foresee is caught and comes back as
//! `DetectError::EnginePanicked`: an error, as it must be, but also a hole in the checks. Those
//! are counted and printed; with `STILLPOINT_FUZZ_STRICT=1` they fail the property.
//!
//! `cargo test` runs 256 cases a property. The `#[ignore]`d `long_*` variants run
//! `STILLPOINT_FUZZ_CASES` cases (default 20,000):
//! `STILLPOINT_FUZZ_CASES=100000 cargo test -p stillpoint-detect --features tract --test fuzz_onnx -- --ignored --nocapture`.
//! It runs the models on tract, so it needs the `tract` feature.
#![cfg(feature = "tract")]

mod common;

use common::*;
use proptest::prelude::*;
use proptest::test_runner::Config;
use std::collections::BTreeMap;
use std::sync::Mutex;
use stillpoint_detect::onnx_proto as pb;
use stillpoint_detect::{DetectError, DetectInput, DetectSettings, Detector, YoloxDetector};
use stillpoint_image::Rgb8;

fn long_cases() -> u32 {
    std::env::var("STILLPOINT_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20_000)
}

fn config(cases: u32) -> Config {
    Config {
        cases,
        failure_persistence: None,
        ..Config::default()
    }
}

/// Engine panics caught by the guard, by message, with how often.
static CAUGHT: Mutex<BTreeMap<String, usize>> = Mutex::new(BTreeMap::new());

/// The valid model the edits start from: a 1x1 convolution, a mean, a planted YOLOX output.
fn base_model() -> Vec<u8> {
    conv_model(
        vec![
            attr_ints("kernel_shape", &[1, 1]),
            attr_ints("strides", &[1, 1]),
            attr_ints("dilations", &[1, 1]),
            attr_ints("pads", &[0, 0, 0, 0]),
            attr_int("group", 1),
        ],
        6,
    )
}

/// Load `bytes` as a model file and run it on a frame: Ok, or an error naming the file.
fn check_model(bytes: &[u8]) -> Result<(), TestCaseError> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fuzzed.onnx");
    std::fs::write(&path, bytes).unwrap();
    let settings = DetectSettings {
        // Small, for models with a dynamic input.
        fallback_input_size: (64, 64),
        ..Default::default()
    };
    let named = |e: &DetectError| -> Result<(), TestCaseError> {
        let msg = e.to_string();
        prop_assert!(msg.contains("fuzzed.onnx"), "error without the file: {msg}");
        if let DetectError::EnginePanicked { msg, .. } = e {
            let key: String = msg.chars().take(200).collect();
            *CAUGHT.lock().unwrap().entry(key).or_default() += 1;
            prop_assert!(
                std::env::var_os("STILLPOINT_FUZZ_STRICT").is_none(),
                "tract panicked past the checks: {e}"
            );
        }
        Ok(())
    };
    match YoloxDetector::load(&path, &settings) {
        Err(e) => named(&e)?,
        Ok(mut det) => {
            let rgb = Rgb8::new(80, 60, [120, 90, 60]);
            for index in 0..2 {
                let input = DetectInput {
                    index,
                    timestamp: 0.0,
                    rgb: &rgb,
                };
                if let Err(e) = det.detect(&input) {
                    named(&e)?;
                }
            }
        }
    }
    Ok(())
}

/// One edit of the model's bytes.
#[derive(Clone, Debug)]
enum ByteEdit {
    Flip(usize, u8),
    Set(usize, u8),
    Insert(usize, Vec<u8>),
    Delete(usize, usize),
    Truncate(usize),
}

fn byte_edit() -> impl Strategy<Value = ByteEdit> {
    prop_oneof![
        (any::<usize>(), 1..=255u8).prop_map(|(p, b)| ByteEdit::Flip(p, b)),
        (
            any::<usize>(),
            prop_oneof![Just(0u8), Just(0x7f), Just(0x80), Just(0xff), any::<u8>()]
        )
            .prop_map(|(p, b)| ByteEdit::Set(p, b)),
        (
            any::<usize>(),
            proptest::collection::vec(any::<u8>(), 1..12)
        )
            .prop_map(|(p, v)| ByteEdit::Insert(p, v)),
        (any::<usize>(), 1..64usize).prop_map(|(p, n)| ByteEdit::Delete(p, n)),
        any::<usize>().prop_map(ByteEdit::Truncate),
    ]
}

fn apply_bytes(mut b: Vec<u8>, edits: &[ByteEdit]) -> Vec<u8> {
    for e in edits {
        let len = b.len();
        if len == 0 {
            break;
        }
        match e {
            ByteEdit::Flip(p, x) => b[p % len] ^= x,
            ByteEdit::Set(p, x) => b[p % len] = *x,
            ByteEdit::Insert(p, v) => {
                let p = p % (len + 1);
                b.splice(p..p, v.iter().copied());
            }
            ByteEdit::Delete(p, n) => {
                let p = p % len;
                b.drain(p..(p + n).min(len));
            }
            ByteEdit::Truncate(p) => b.truncate(p % len),
        }
    }
    b
}

/// Integers at the edges: what shapes and attributes are made of.
fn edge_int() -> impl Strategy<Value = i64> {
    prop_oneof![
        Just(0i64),
        Just(-1),
        Just(1),
        Just(2),
        Just(3),
        Just(32),
        Just(64),
        Just(84),
        Just(4096),
        Just(100_000),
        Just(i64::MAX),
        Just(i64::MIN),
        Just(1 << 31),
        -8..300i64,
    ]
}

/// Operators a node may be turned into (the ones a YOLOX graph holds, and some that reshape).
const OPS: &[&str] = &[
    "Conv",
    "MaxPool",
    "AveragePool",
    "Add",
    "Mul",
    "Sigmoid",
    "Concat",
    "Reshape",
    "Transpose",
    "Slice",
    "Resize",
    "ReduceMean",
    "Exp",
    "Identity",
    "Flatten",
    "Squeeze",
    "Unsqueeze",
    "Gather",
    "Split",
    "Pad",
    "Expand",
    "Tile",
    "ConstantOfShape",
    "Softmax",
    "DepthToSpace",
    "SpaceToDepth",
    "MatMul",
    "Gemm",
    "BatchNormalization",
    "Cast",
    "Shape",
    "Range",
    "TopK",
    "NonMaxSuppression",
    "Bogus",
];

const ATTRS: &[&str] = &[
    "kernel_shape",
    "strides",
    "dilations",
    "pads",
    "group",
    "axis",
    "axes",
    "keepdims",
    "perm",
    "blocksize",
    "split",
    "to",
    "mode",
    "auto_pad",
    "ceil_mode",
];

/// One edit of the decoded model.
#[derive(Clone, Debug)]
enum GraphEdit {
    /// An axis of the input (0) or output (1) declared shape.
    Dim(bool, usize, i64),
    /// Drop or add an axis of the input or output.
    Rank(bool, bool),
    /// A value of an attribute of a node (or a new attribute).
    Attr(usize, usize, Vec<i64>, bool),
    /// A node's operator.
    Op(usize, usize),
    /// Remove a node.
    DropNode(usize),
    /// A node's input renamed to another tensor's name.
    Rewire(usize, usize, usize),
    /// An initializer's dims.
    InitDims(usize, Vec<i64>),
    /// An initializer's element type.
    InitType(usize, i32),
    /// The opset version.
    Opset(i64),
}

fn graph_edit() -> impl Strategy<Value = GraphEdit> {
    let idx = 0..8usize;
    prop_oneof![
        (any::<bool>(), 0..5usize, edge_int()).prop_map(|(o, a, v)| GraphEdit::Dim(o, a, v)),
        (any::<bool>(), any::<bool>()).prop_map(|(o, add)| GraphEdit::Rank(o, add)),
        (
            idx.clone(),
            0..ATTRS.len(),
            proptest::collection::vec(edge_int(), 0..6),
            any::<bool>()
        )
            .prop_map(|(n, a, v, list)| GraphEdit::Attr(n, a, v, list)),
        (idx.clone(), 0..OPS.len()).prop_map(|(n, o)| GraphEdit::Op(n, o)),
        idx.clone().prop_map(GraphEdit::DropNode),
        (idx.clone(), 0..3usize, 0..12usize).prop_map(|(n, i, t)| GraphEdit::Rewire(n, i, t)),
        (idx.clone(), proptest::collection::vec(edge_int(), 0..5))
            .prop_map(|(i, d)| GraphEdit::InitDims(i, d)),
        (idx, -1..20i32).prop_map(|(i, t)| GraphEdit::InitType(i, t)),
        prop_oneof![
            Just(0i64),
            Just(1),
            Just(7),
            Just(13),
            Just(18),
            Just(30),
            Just(-1)
        ]
        .prop_map(GraphEdit::Opset),
    ]
}

/// The declared dims of a tensor.
fn dims_of(v: &mut pb::ValueInfoProto) -> Option<&mut Vec<pb::tensor_shape_proto::Dimension>> {
    let pb::type_proto::Value::TensorType(t) = v.r#type.as_mut()?.value.as_mut()?;
    Some(&mut t.shape.as_mut()?.dim)
}

fn apply_graph(bytes: &[u8], edits: &[GraphEdit]) -> Vec<u8> {
    use pb::tensor_shape_proto::{Dimension, dimension::Value};
    let mut m = decode(bytes);
    for e in edits {
        let g = m.graph.as_mut().unwrap();
        let names: Vec<String> = g
            .node
            .iter()
            .flat_map(|n| n.output.clone())
            .chain(g.initializer.iter().map(|t| t.name.clone()))
            .chain(g.input.iter().map(|i| i.name.clone()))
            .collect();
        match e {
            GraphEdit::Dim(out, axis, v) => {
                let vi = if *out {
                    g.output.first_mut()
                } else {
                    g.input.first_mut()
                };
                if let Some(dims) = vi.and_then(dims_of)
                    && !dims.is_empty()
                {
                    let n = dims.len();
                    dims[axis % n].value = Some(Value::DimValue(*v));
                }
            }
            GraphEdit::Rank(out, add) => {
                let vi = if *out {
                    g.output.first_mut()
                } else {
                    g.input.first_mut()
                };
                if let Some(dims) = vi.and_then(dims_of) {
                    if *add {
                        dims.push(Dimension {
                            denotation: String::new(),
                            value: Some(Value::DimValue(1)),
                        });
                    } else {
                        dims.pop();
                    }
                }
            }
            GraphEdit::Attr(n, a, values, list) => {
                if g.node.is_empty() {
                    continue;
                }
                let len = g.node.len();
                let node = &mut g.node[n % len];
                let attr = if *list {
                    attr_ints(ATTRS[*a], values)
                } else {
                    attr_int(ATTRS[*a], values.first().copied().unwrap_or(0))
                };
                node.attribute.retain(|x| x.name != attr.name);
                node.attribute.push(attr);
            }
            GraphEdit::Op(n, o) => {
                if !g.node.is_empty() {
                    let len = g.node.len();
                    g.node[n % len].op_type = OPS[*o].into();
                }
            }
            GraphEdit::DropNode(n) => {
                if !g.node.is_empty() {
                    let len = g.node.len();
                    g.node.remove(n % len);
                }
            }
            GraphEdit::Rewire(n, i, t) => {
                if !g.node.is_empty() && !names.is_empty() {
                    let len = g.node.len();
                    let node = &mut g.node[n % len];
                    if !node.input.is_empty() {
                        let k = node.input.len();
                        node.input[i % k] = names[t % names.len()].clone();
                    }
                }
            }
            GraphEdit::InitDims(i, d) => {
                if !g.initializer.is_empty() {
                    let len = g.initializer.len();
                    g.initializer[i % len].dims = d.clone();
                }
            }
            GraphEdit::InitType(i, t) => {
                if !g.initializer.is_empty() {
                    let len = g.initializer.len();
                    g.initializer[i % len].data_type = *t;
                }
            }
            GraphEdit::Opset(v) => m.opset_import[0].version = *v,
        }
    }
    encode(&m)
}

/// Run `check` on `cases` values of `strategy`; fail with the smallest failing value. Prints the
/// case count and the engine panics the guard caught.
fn fuzz<S: Strategy>(
    name: &str,
    cases: u32,
    strategy: S,
    check: impl Fn(S::Value) -> Result<(), TestCaseError>,
) where
    S::Value: std::fmt::Debug,
{
    let started = std::time::Instant::now();
    let result = proptest::test_runner::TestRunner::new(config(cases)).run(&strategy, check);
    eprintln!("{name}: {cases} cases in {:.0?}", started.elapsed());
    let caught = CAUGHT.lock().unwrap();
    if !caught.is_empty() {
        eprintln!(
            "engine panics caught by the guard so far ({} kinds):",
            caught.len()
        );
        for (msg, n) in caught.iter() {
            eprintln!("  {n} x {msg}");
        }
    }
    if let Err(e) = result {
        panic!("{name}: {e}");
    }
}

fn random_bytes(cases: u32) {
    fuzz(
        "random bytes",
        cases,
        proptest::collection::vec(any::<u8>(), 0..4096),
        |bytes| check_model(&bytes),
    );
}

fn mutated_bytes(cases: u32) {
    fuzz(
        "mutated bytes",
        cases,
        proptest::collection::vec(byte_edit(), 1..6),
        |edits| check_model(&apply_bytes(base_model(), &edits)),
    );
}

fn mutated_graph(cases: u32) {
    fuzz(
        "mutated graph",
        cases,
        proptest::collection::vec(graph_edit(), 1..5),
        |edits| check_model(&apply_graph(&base_model(), &edits)),
    );
}

#[test]
fn onnx_random_bytes() {
    random_bytes(256);
}

#[test]
fn onnx_mutated_bytes() {
    mutated_bytes(256);
}

#[test]
fn onnx_mutated_graph() {
    mutated_graph(256);
}

#[test]
#[ignore = "long fuzz run: STILLPOINT_FUZZ_CASES cases"]
fn long_onnx_random_bytes() {
    random_bytes(long_cases());
}

#[test]
#[ignore = "long fuzz run: STILLPOINT_FUZZ_CASES cases"]
fn long_onnx_mutated_bytes() {
    mutated_bytes(long_cases());
}

#[test]
#[ignore = "long fuzz run: STILLPOINT_FUZZ_CASES cases"]
fn long_onnx_mutated_graph() {
    mutated_graph(long_cases());
}

/// The base model loads and runs: the edits start from a model that works.
#[test]
fn the_unmutated_model_runs() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("base.onnx");
    std::fs::write(&path, base_model()).unwrap();
    let mut det = YoloxDetector::load(&path, &DetectSettings::default()).unwrap();
    let rgb = Rgb8::new(80, 60, [120, 90, 60]);
    let input = DetectInput {
        index: 0,
        timestamp: 0.0,
        rgb: &rgb,
    };
    assert!(det.detect(&input).unwrap().is_empty());
}
