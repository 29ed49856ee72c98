//! Checks of a user's ONNX file before an inference engine is given it, and a net under the
//! engine for what the checks do not foresee.
//!
//! A crafted or broken model could crash the whole process rather than fail: a convolution with
//! a stride of 0 panicked inside tract (a divide by zero), and a model declaring a
//! 100000x100000 input aborted on a ~120 GB allocation (an allocation failure cannot be caught).
//! `read_checked` reads the file's protobuf and refuses, with one error naming the file, what
//! is known to do that: declared sizes past [`MAX_INPUT_SIDE`] / [`MAX_INPUT_ELEMENTS`] /
//! [`MAX_TENSOR_ELEMENTS`], zero or negative windows of convolutions and poolings, and outputs
//! that cannot be YOLOX's. `guarded` turns any remaining panic of the engine into an error.

use crate::DetectError;
use crate::onnx_proto as pb;
use prost::Message;
use std::cell::{Cell, RefCell};
use std::collections::HashMap;
use std::path::Path;

/// Largest network input side (height or width) a model may declare: YOLOX is trained at 416 to
/// 1280; 4096 leaves room and keeps one input tensor at 200 MB.
pub const MAX_INPUT_SIDE: usize = 4096;
/// Most elements of the network input (`3 x height x width`; 64 Mi floats are 256 MB).
pub const MAX_INPUT_ELEMENTS: usize = 64 << 20;
/// Most elements of any one tensor of the model, stored (weights, constants) or computed
/// (256 Mi floats are 1 GB; YOLOX-x at 1280x1280 peaks at 13 Mi).
pub const MAX_TENSOR_ELEMENTS: usize = 256 << 20;
/// Largest kernel, stride, dilation or padding a convolution or pooling may declare (YOLOX's
/// largest kernel is 13, its largest stride 2).
pub const MAX_WINDOW: i64 = 1024;

/// Operators with `kernel_shape` / `strides` / `dilations` / `pads` windows.
const WINDOWED: [&str; 9] = [
    "Conv",
    "ConvInteger",
    "QLinearConv",
    "ConvTranspose",
    "MaxPool",
    "AveragePool",
    "LpPool",
    "MaxUnpool",
    "DeformConv",
];

fn refused(path: &Path, msg: String) -> DetectError {
    DetectError::ModelRefused {
        path: path.to_path_buf(),
        msg,
    }
}

/// Read `path` as an ONNX model and check it (see the module's text); every refusal names the
/// file. Returns the file's bytes, for the engine to parse.
pub(crate) fn read_checked(path: &Path) -> Result<Vec<u8>, DetectError> {
    super::check_model_file(path)?;
    let bytes = std::fs::read(path).map_err(|error| DetectError::ModelIo {
        path: path.to_path_buf(),
        error,
    })?;
    let proto = pb::ModelProto::decode(bytes.as_slice()).map_err(|e| DetectError::NotOnnx {
        path: path.to_path_buf(),
        msg: format!("not an ONNX protobuf: {e}"),
    })?;
    check_model(&proto).map_err(|msg| refused(path, msg))?;
    Ok(bytes)
}

/// What `read_checked` checks, on a decoded model; the message says which node or tensor and
/// why.
pub fn check_model(model: &pb::ModelProto) -> Result<(), String> {
    let graph = model
        .graph
        .as_ref()
        .ok_or_else(|| "the file holds no graph".to_string())?;
    check_graph(graph, 0)?;
    // The image input: the graph's inputs that are not initializers (ONNX before IR 4 lists
    // initializers among the inputs too).
    let inputs: Vec<&pb::ValueInfoProto> = graph
        .input
        .iter()
        .filter(|i| !graph.initializer.iter().any(|t| t.name == i.name))
        .collect();
    if inputs.len() != 1 || graph.output.is_empty() {
        return Err(format!(
            "graph has {} inputs and {} outputs, expected 1 image input and an output",
            inputs.len(),
            graph.output.len()
        ));
    }
    // Every output made by something (a node, an initializer, the input).
    for out in &graph.output {
        let made = graph.node.iter().any(|n| n.output.contains(&out.name))
            || graph.initializer.iter().any(|t| t.name == out.name)
            || graph.input.iter().any(|i| i.name == out.name);
        if !made {
            return Err(format!("output {:?} is made by no node", out.name));
        }
    }
    if let Some(dims) = declared_dims(inputs[0]) {
        check_input(&inputs[0].name, &dims)?;
    }
    if let Some(dims) = declared_dims(&graph.output[0]) {
        check_output(&graph.output[0].name, &dims)?;
    }
    Ok(())
}

/// The declared dims of a tensor, `None` for a symbolic axis; `None` when there is no shape.
fn declared_dims(v: &pb::ValueInfoProto) -> Option<Vec<Option<i64>>> {
    use pb::tensor_shape_proto::dimension::Value;
    let Some(pb::type_proto::Value::TensorType(t)) = v.r#type.as_ref()?.value.as_ref() else {
        return None;
    };
    let shape = t.shape.as_ref()?;
    Some(
        shape
            .dim
            .iter()
            .map(|d| match d.value {
                Some(Value::DimValue(v)) => Some(v),
                _ => None,
            })
            .collect(),
    )
}

fn show(dims: &[Option<i64>]) -> String {
    let d: Vec<String> = dims
        .iter()
        .map(|d| d.map_or("?".into(), |v| v.to_string()))
        .collect();
    format!("[{}]", d.join(", "))
}

/// The declared image input: `[1, 3, H, W]` (any axis may be symbolic), H and W at most
/// [`MAX_INPUT_SIDE`], the whole at most [`MAX_INPUT_ELEMENTS`].
fn check_input(name: &str, dims: &[Option<i64>]) -> Result<(), String> {
    if dims.len() != 4 || dims.iter().flatten().any(|&d| d <= 0) {
        return Err(format!(
            "input {name:?} is declared {}, expected [1, 3, height, width]",
            show(dims)
        ));
    }
    let side = MAX_INPUT_SIDE as i64;
    let too_big = dims[2..].iter().flatten().any(|&d| d > side)
        || dims
            .iter()
            .flatten()
            .try_fold(1i64, |acc, &d| acc.checked_mul(d))
            .is_none_or(|n| n > MAX_INPUT_ELEMENTS as i64);
    if too_big {
        return Err(format!(
            "input {name:?} is declared {}, larger than the {side}x{side} (and {} Mi values) \
             this program runs",
            show(dims),
            MAX_INPUT_ELEMENTS >> 20
        ));
    }
    Ok(())
}

/// The declared first output: `[1, anchors, 5 + classes]` (or without the batch axis), where
/// fixed.
fn check_output(name: &str, dims: &[Option<i64>]) -> Result<(), String> {
    let expected = "[1, anchors, 5 + classes] (box, objectness, class scores per anchor)";
    if !(2..=3).contains(&dims.len()) || dims.iter().flatten().any(|&d| d <= 0) {
        return Err(format!(
            "output {name:?} is declared {}, expected {expected}",
            show(dims)
        ));
    }
    if let Some(Some(k)) = dims.last()
        && !(6..=5 + u16::MAX as i64).contains(k)
    {
        return Err(format!(
            "output {name:?} is declared {}: its last axis ({k}) is not 5 + a number of \
             classes; expected {expected}",
            show(dims)
        ));
    }
    Ok(())
}

/// Nodes, stored tensors and subgraphs (`If` / `Loop` / `Scan` bodies) of one graph.
fn check_graph(graph: &pb::GraphProto, depth: usize) -> Result<(), String> {
    if depth > 16 {
        return Err("subgraphs nested more than 16 deep".into());
    }
    for t in &graph.initializer {
        check_tensor(t, &format!("initializer {:?}", t.name))?;
    }
    // Constant tensors by name: initializers and `Constant` nodes' values.
    let mut constants: HashMap<&str, &pb::TensorProto> = graph
        .initializer
        .iter()
        .map(|t| (t.name.as_str(), t))
        .collect();
    for node in &graph.node {
        if node.op_type == "Constant"
            && let (Some(out), Some(t)) = (
                node.output.first(),
                node.attribute.iter().find_map(|a| a.t.as_ref()),
            )
        {
            constants.insert(out, t);
        }
    }
    for node in &graph.node {
        let what = || format!("node {:?} ({})", node.name, node.op_type);
        for a in &node.attribute {
            if let Some(t) = &a.t {
                check_tensor(t, &format!("{} attribute {:?}", what(), a.name))?;
            }
            for t in &a.tensors {
                check_tensor(t, &format!("{} attribute {:?}", what(), a.name))?;
            }
            for g in a.g.iter().chain(&a.graphs) {
                check_graph(g, depth + 1)?;
            }
        }
        let constant = |i: usize| {
            node.input
                .get(i)
                .and_then(|name| constants.get(name.as_str()).copied())
        };
        check_node(node, constant).map_err(|m| format!("{}: {m}", what()))?;
    }
    Ok(())
}

/// The attributes and constant inputs of one node that are known to make tract divide by zero,
/// loop without end or allocate without bound.
fn check_node<'a>(
    node: &pb::NodeProto,
    constant: impl Fn(usize) -> Option<&'a pb::TensorProto>,
) -> Result<(), String> {
    let op = node.op_type.as_str();
    if WINDOWED.contains(&op) {
        return check_window(node);
    }
    let ints = |i: usize| constant(i).and_then(int_values);
    let cap = MAX_TENSOR_ELEMENTS as i64;
    // The product of a constant shape (or repeat counts), when every entry is 0 or more.
    let volume = |v: &[i64]| {
        v.iter().try_fold(
            1i64,
            |acc, &d| {
                if d < 0 { None } else { acc.checked_mul(d) }
            },
        )
    };
    match op {
        "Transpose" => {
            // [0, 0, 1, 2] is no permutation: tract ran out of memory on it.
            if let Some(perm) = node.attribute.iter().find(|a| a.name == "perm") {
                let p = &perm.ints;
                let mut seen = vec![false; p.len()];
                for &v in p {
                    match usize::try_from(v).ok().filter(|&v| v < p.len()) {
                        Some(v) if !seen[v] => seen[v] = true,
                        _ => return Err(format!("perm {p:?} is not a permutation")),
                    }
                }
            }
        }
        "DepthToSpace" | "SpaceToDepth" => {
            if let Some(b) = node.attribute.iter().find(|a| a.name == "blocksize")
                && !(1..=MAX_WINDOW).contains(&b.i)
            {
                return Err(format!(
                    "blocksize {} is out of range (1 to {MAX_WINDOW})",
                    b.i
                ));
            }
        }
        "Split" => {
            if let Some(split) = node.attribute.iter().find(|a| a.name == "split")
                && (split.ints.len() != node.output.len() || split.ints.iter().any(|&v| v < 0))
            {
                return Err(format!(
                    "split {:?} for {} outputs",
                    split.ints,
                    node.output.len()
                ));
            }
        }
        "Slice" => {
            if let Some(steps) = ints(4)
                && steps.contains(&0)
            {
                return Err(format!("steps {steps:?}: a step of 0"));
            }
        }
        "ConstantOfShape" | "Expand" | "Tile" => {
            let (i, what) = match op {
                "ConstantOfShape" => (0, "shape"),
                "Expand" => (1, "shape"),
                _ => (1, "repeats"),
            };
            if let Some(v) = ints(i)
                && volume(&v).is_none_or(|n| n > cap)
            {
                return Err(if v.iter().any(|&d| d < 0) {
                    format!("{what} {v:?} has a negative entry")
                } else {
                    format!(
                        "{what} {v:?} makes more than the {} Mi values this program allows \
                         one tensor",
                        MAX_TENSOR_ELEMENTS >> 20
                    )
                });
            }
        }
        "Range" => {
            let scalar = |i: usize| {
                constant(i)
                    .and_then(float_values)
                    .and_then(|v| v.first().copied())
            };
            if let (Some(start), Some(limit), Some(delta)) = (scalar(0), scalar(1), scalar(2)) {
                let n = ((limit - start) / delta).ceil();
                if delta == 0.0 || !n.is_finite() || n > cap as f64 {
                    return Err(format!(
                        "from {start} to {limit} by {delta}: not a range of at most {} Mi values",
                        MAX_TENSOR_ELEMENTS >> 20
                    ));
                }
            }
        }
        "OneHot" => {
            if let Some(depth) = constant(1)
                .and_then(float_values)
                .and_then(|v| v.first().copied())
                && !(depth.is_finite() && depth.abs() <= cap as f64)
            {
                return Err(format!("depth {depth} is out of range"));
            }
        }
        "Resize" | "Upsample" => {
            // Upsample's scales are input 1; Resize's input 2 (scales) or 3 (sizes).
            let scales = if op == "Upsample" { 1 } else { 2 };
            if let Some(v) = constant(scales).and_then(float_values)
                && v.iter()
                    .any(|s| !(s.is_finite() && (0.0..=MAX_WINDOW as f64).contains(s)))
            {
                return Err(format!("scales {v:?} are out of range (0 to {MAX_WINDOW})"));
            }
            if op == "Resize"
                && let Some(v) = ints(3)
                && volume(&v).is_none_or(|n| n > cap)
            {
                return Err(format!("sizes {v:?} are out of range"));
            }
        }
        _ => {}
    }
    Ok(())
}

/// The values of a constant integer tensor (int32 or int64, in its typed field or raw bytes).
fn int_values(t: &pb::TensorProto) -> Option<Vec<i64>> {
    const INT32: i32 = 6;
    const INT64: i32 = 7;
    match t.data_type {
        INT64 if !t.raw_data.is_empty() => Some(
            t.raw_data
                .chunks_exact(8)
                .map(|c| i64::from_le_bytes(c.try_into().unwrap_or_default()))
                .collect(),
        ),
        INT64 => Some(t.int64_data.clone()),
        INT32 if !t.raw_data.is_empty() => Some(
            t.raw_data
                .chunks_exact(4)
                .map(|c| i32::from_le_bytes(c.try_into().unwrap_or_default()) as i64)
                .collect(),
        ),
        INT32 => Some(t.int32_data.iter().map(|&v| v as i64).collect()),
        _ => None,
    }
}

/// The values of a constant number tensor as f64 (floats and integers).
fn float_values(t: &pb::TensorProto) -> Option<Vec<f64>> {
    const FLOAT: i32 = 1;
    const DOUBLE: i32 = 11;
    match t.data_type {
        FLOAT if !t.raw_data.is_empty() => Some(
            t.raw_data
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes(c.try_into().unwrap_or_default()) as f64)
                .collect(),
        ),
        FLOAT => Some(t.float_data.iter().map(|&v| v as f64).collect()),
        DOUBLE if !t.raw_data.is_empty() => Some(
            t.raw_data
                .chunks_exact(8)
                .map(|c| f64::from_le_bytes(c.try_into().unwrap_or_default()))
                .collect(),
        ),
        DOUBLE => Some(t.double_data.clone()),
        _ => int_values(t).map(|v| v.into_iter().map(|v| v as f64).collect()),
    }
}

/// A stored tensor: no negative dims, at most [`MAX_TENSOR_ELEMENTS`] elements.
fn check_tensor(t: &pb::TensorProto, what: &str) -> Result<(), String> {
    let n = t.dims.iter().try_fold(
        1i64,
        |acc, &d| {
            if d < 0 { None } else { acc.checked_mul(d) }
        },
    );
    match n {
        Some(n) if n <= MAX_TENSOR_ELEMENTS as i64 => Ok(()),
        _ => Err(format!(
            "{what} is declared {:?}, a shape this program does not load (at most {} Mi values)",
            t.dims,
            MAX_TENSOR_ELEMENTS >> 20
        )),
    }
}

/// The window attributes of a convolution or pooling: kernel, strides and dilations 1 to
/// [`MAX_WINDOW`], pads 0 to it, group at least 1; one value per spatial axis (pads two).
fn check_window(node: &pb::NodeProto) -> Result<(), String> {
    use pb::attribute_proto::AttributeType;
    let mut axes: Option<(&str, usize)> = None;
    for a in &node.attribute {
        let per_axis = match a.name.as_str() {
            "kernel_shape" | "strides" | "dilations" => 1,
            "pads" => 2,
            _ => continue,
        };
        let n = a.ints.len();
        if n == 0 || n % per_axis != 0 {
            return Err(format!(
                "{} {:?}: not one value per spatial axis",
                a.name, a.ints
            ));
        }
        match axes {
            Some((first, m)) if m != n / per_axis => {
                return Err(format!(
                    "{} {:?} is for {} axes, {first} for {m}",
                    a.name,
                    a.ints,
                    n / per_axis
                ));
            }
            _ => axes = Some((&a.name, n / per_axis)),
        }
    }
    for a in &node.attribute {
        let range = match a.name.as_str() {
            "kernel_shape" | "strides" | "dilations" => 1..=MAX_WINDOW,
            "pads" | "output_padding" => 0..=MAX_WINDOW,
            "group" => 1..=1 << 20,
            _ => continue,
        };
        let values: &[i64] = if a.r#type == AttributeType::Int as i32 {
            std::slice::from_ref(&a.i)
        } else {
            &a.ints
        };
        if let Some(bad) = values.iter().find(|v| !range.contains(v)) {
            return Err(format!(
                "{} {values:?}: {bad} is out of range ({} to {})",
                a.name,
                range.start(),
                range.end()
            ));
        }
    }
    Ok(())
}

thread_local! {
    /// Set while this thread runs [`guarded`] code: a panic is recorded, not printed.
    static GUARDED: Cell<bool> = const { Cell::new(false) };
    /// The last panic recorded on this thread.
    static PANIC: RefCell<Option<String>> = const { RefCell::new(None) };
}

/// A panic hook that keeps quiet about panics inside [`guarded`] (their message goes into the
/// error) and passes every other panic to the hook it replaced. Installed once.
fn install_hook() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if GUARDED.with(Cell::get) {
                let msg = info.payload_as_str().unwrap_or("(no message)");
                let at = info
                    .location()
                    .map(|l| format!(" at {}:{}", l.file(), l.line()))
                    .unwrap_or_default();
                PANIC.with(|p| *p.borrow_mut() = Some(format!("{msg}{at}")));
            } else {
                previous(info);
            }
        }));
    });
}

/// Run `f` (an inference engine's work on the model at `path`); a panic in it becomes
/// [`DetectError::EnginePanicked`] naming the file, the engine and what it was doing.
pub(crate) fn guarded<T>(
    path: &Path,
    backend: &'static str,
    stage: &'static str,
    f: impl FnOnce() -> Result<T, DetectError>,
) -> Result<T, DetectError> {
    install_hook();
    let was = GUARDED.with(|g| g.replace(true));
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    GUARDED.with(|g| g.set(was));
    result.unwrap_or_else(|_| {
        let msg = PANIC
            .with(|p| p.borrow_mut().take())
            .unwrap_or_else(|| "(no message)".into());
        Err(DetectError::EnginePanicked {
            path: path.to_path_buf(),
            backend,
            stage,
            msg,
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_panic_becomes_an_error_naming_the_file_and_stage() {
        let path = Path::new("/models/crafted.onnx");
        let r: Result<usize, _> = guarded(path, "tract", "loading it", || {
            let zero = std::hint::black_box(0usize);
            Ok(7 / zero)
        });
        let e = r.unwrap_err();
        assert!(matches!(e, DetectError::EnginePanicked { .. }), "{e}");
        let msg = e.to_string();
        for w in [
            "/models/crafted.onnx",
            "tract",
            "loading it",
            "divide by zero",
            "guard.rs",
        ] {
            assert!(msg.contains(w), "no {w:?} in {msg}");
        }
        // The guard is off again after it: results pass through.
        assert_eq!(guarded(path, "tract", "x", || Ok(3)).unwrap(), 3);
        assert!(!GUARDED.with(Cell::get));
    }

    #[test]
    fn windows_and_permutations_are_checked() {
        let attr = |name: &str, ints: &[i64]| pb::AttributeProto {
            name: name.into(),
            r#type: pb::attribute_proto::AttributeType::Ints as i32,
            ints: ints.to_vec(),
            ..Default::default()
        };
        let node = |op: &str, attribute| pb::NodeProto {
            op_type: op.into(),
            attribute,
            ..Default::default()
        };
        let none = |_: usize| None;
        assert!(check_node(&node("Conv", vec![attr("strides", &[2, 2])]), none).is_ok());
        let e = check_node(&node("Conv", vec![attr("strides", &[2, 0])]), none).unwrap_err();
        assert!(e.contains("strides [2, 0]"), "{e}");
        assert!(check_node(&node("MaxPool", vec![attr("pads", &[1, 1, 1])]), none).is_err());
        assert!(check_node(&node("Conv", vec![attr("pads", &[])]), none).is_err());
        let mixed = vec![attr("strides", &[1, 1]), attr("pads", &[0, 0, 0, 0, 0, 0])];
        let e = check_node(&node("Conv", mixed), none).unwrap_err();
        assert!(
            e.contains("pads [0, 0, 0, 0, 0, 0] is for 3 axes, strides for 2"),
            "{e}"
        );
        assert!(check_node(&node("Transpose", vec![attr("perm", &[0, 2, 1])]), none).is_ok());
        for perm in [&[0, 0, 1][..], &[0, 3, 1], &[-1, 0, 1]] {
            let e = check_node(&node("Transpose", vec![attr("perm", perm)]), none).unwrap_err();
            assert!(e.contains("not a permutation"), "{e}");
        }
    }

    #[test]
    fn constant_shapes_are_checked_in_typed_and_raw_form() {
        let shape = |dims: &[i64], raw: bool| pb::TensorProto {
            dims: vec![dims.len() as i64],
            data_type: 7,
            int64_data: if raw { vec![] } else { dims.to_vec() },
            raw_data: if raw {
                dims.iter().flat_map(|d| d.to_le_bytes()).collect()
            } else {
                vec![]
            },
            ..Default::default()
        };
        let cos = pb::NodeProto {
            op_type: "ConstantOfShape".into(),
            input: vec!["shape".into()],
            ..Default::default()
        };
        for raw in [false, true] {
            let small = shape(&[1, 3, 64, 64], raw);
            assert!(check_node(&cos, |_| Some(&small)).is_ok());
            let huge = shape(&[100_000, 100_000], raw);
            let e = check_node(&cos, |_| Some(&huge)).unwrap_err();
            assert!(e.contains("[100000, 100000]"), "{e}");
            let negative = shape(&[-3, 4], raw);
            assert!(check_node(&cos, |_| Some(&negative)).is_err());
        }
    }
}
