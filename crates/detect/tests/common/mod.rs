//! Tiny ONNX models built in the test, with the crate's own ONNX protobuf types (no model download).
#![allow(dead_code)] // each test binary uses its own part

use prost::Message;
use stillpoint_detect::onnx_proto as pb;

/// The backends to load models with: those that can run one here (tract in a build with it, ort
/// with its library), or the default one when there is neither, since the model checks refuse a
/// bad file before any engine is needed.
pub fn checked_backends() -> Vec<stillpoint_detect::Backend> {
    let available = stillpoint_detect::backend::available(None);
    if available.is_empty() {
        eprintln!("no inference backend here: checking the model checks only");
        vec![stillpoint_detect::Backend::default()]
    } else {
        available
    }
}

/// ONNX `TensorProto.DataType` FLOAT.
pub const FLOAT: i32 = 1;
/// ONNX `TensorProto.DataType` INT64.
pub const INT64: i32 = 7;

/// A float tensor's type and shape; `None` is a symbolic axis.
pub fn value_info_dyn(name: &str, dims: &[Option<i64>]) -> pb::ValueInfoProto {
    use pb::tensor_shape_proto::{Dimension, dimension::Value};
    pb::ValueInfoProto {
        name: name.into(),
        r#type: Some(pb::TypeProto {
            denotation: String::new(),
            value: Some(pb::type_proto::Value::TensorType(pb::type_proto::Tensor {
                elem_type: FLOAT,
                shape: Some(pb::TensorShapeProto {
                    dim: dims
                        .iter()
                        .map(|d| Dimension {
                            denotation: String::new(),
                            value: Some(match d {
                                Some(v) => Value::DimValue(*v),
                                None => Value::DimParam("n".into()),
                            }),
                        })
                        .collect(),
                }),
            })),
        }),
        doc_string: String::new(),
    }
}

/// A float tensor's type and fixed shape.
pub fn value_info(name: &str, dims: &[i64]) -> pb::ValueInfoProto {
    let dims: Vec<Option<i64>> = dims.iter().map(|&d| Some(d)).collect();
    value_info_dyn(name, &dims)
}

/// A float initializer.
pub fn tensor(name: &str, dims: &[i64], data: Vec<f32>) -> pb::TensorProto {
    pb::TensorProto {
        name: name.into(),
        dims: dims.to_vec(),
        data_type: FLOAT,
        float_data: data,
        ..Default::default()
    }
}

/// An int64 initializer.
pub fn tensor_i64(name: &str, dims: &[i64], data: Vec<i64>) -> pb::TensorProto {
    pb::TensorProto {
        name: name.into(),
        dims: dims.to_vec(),
        data_type: INT64,
        int64_data: data,
        ..Default::default()
    }
}

/// A node with one output, named after it.
pub fn node(
    op: &str,
    inputs: &[&str],
    output: &str,
    attribute: Vec<pb::AttributeProto>,
) -> pb::NodeProto {
    pb::NodeProto {
        op_type: op.into(),
        input: inputs.iter().map(|s| s.to_string()).collect(),
        output: vec![output.into()],
        name: output.into(),
        attribute,
        ..Default::default()
    }
}

/// An integer attribute.
pub fn attr_int(name: &str, i: i64) -> pb::AttributeProto {
    pb::AttributeProto {
        name: name.into(),
        r#type: pb::attribute_proto::AttributeType::Int as i32,
        i,
        ..Default::default()
    }
}

/// A list-of-integers attribute.
pub fn attr_ints(name: &str, ints: &[i64]) -> pb::AttributeProto {
    pb::AttributeProto {
        name: name.into(),
        r#type: pb::attribute_proto::AttributeType::Ints as i32,
        ints: ints.to_vec(),
        ..Default::default()
    }
}

/// A model (opset 11) of one graph.
pub fn model(graph: pb::GraphProto) -> Vec<u8> {
    pb::ModelProto {
        ir_version: 7,
        opset_import: vec![pb::OperatorSetIdProto {
            domain: String::new(),
            version: 11,
        }],
        producer_name: "stillpoint-detect tests".into(),
        graph: Some(graph),
        ..Default::default()
    }
    .encode_to_vec()
}

/// Decode a model built here (for tests that edit one).
pub fn decode(bytes: &[u8]) -> pb::ModelProto {
    pb::ModelProto::decode(bytes).unwrap()
}

/// Encode a model.
pub fn encode(m: &pb::ModelProto) -> Vec<u8> {
    m.encode_to_vec()
}

/// Nodes that turn `from` (any float tensor) into the constant `output` (`dims` shaped) while
/// depending on it: `mean(from) * 0 + planted`.
fn plant(from: &str, dims: &[i64], output: Vec<f32>) -> (Vec<pb::NodeProto>, Vec<pb::TensorProto>) {
    (
        vec![
            node("ReduceMean", &[from], "mean", vec![attr_int("keepdims", 0)]),
            node("Mul", &["mean", "zero"], "nothing", vec![]),
            node("Add", &["nothing", "planted"], "output", vec![]),
        ],
        vec![
            tensor("zero", &[], vec![0.0]),
            tensor("planted", dims, output),
        ],
    )
}

/// A model with input `[1, 3, size, size]` whose output is the constant `output`
/// (`dims` shaped), made to depend on the input: `mean(images) * 0 + output`.
pub fn constant_model(size: i64, dims: &[i64], output: Vec<f32>) -> Vec<u8> {
    constant_model_in(&[1, 3, size, size], dims, output)
}

/// [`constant_model`] with any declared input shape.
pub fn constant_model_in(input: &[i64], dims: &[i64], output: Vec<f32>) -> Vec<u8> {
    let (node, initializer) = plant("images", dims, output);
    model(pb::GraphProto {
        name: "tiny".into(),
        node,
        initializer,
        input: vec![value_info("images", input)],
        output: vec![value_info("output", dims)],
        ..Default::default()
    })
}

/// A 64x64 YOLOX-shaped model (84 anchors, `k` values a row) with a 1x1 convolution first
/// (`attribute` its attributes: strides, dilations, ...), the rest as [`constant_model`].
pub fn conv_model(attribute: Vec<pb::AttributeProto>, k: i64) -> Vec<u8> {
    conv_model_op("Conv", attribute, k)
}

/// [`conv_model`] with another windowed operator (`MaxPool`, `AveragePool`) or `Conv`.
pub fn conv_model_op(op: &str, attribute: Vec<pb::AttributeProto>, k: i64) -> Vec<u8> {
    let dims = [1, 84, k];
    let (planted_nodes, mut initializer) = plant("features", &dims, vec![0.0; 84 * k as usize]);
    let inputs: &[&str] = if op == "Conv" {
        &["images", "weights"]
    } else {
        &["images"]
    };
    let mut nodes = vec![node(op, inputs, "features", attribute)];
    nodes.extend(planted_nodes);
    initializer.push(tensor("weights", &[4, 3, 1, 1], vec![0.25; 12]));
    model(pb::GraphProto {
        name: "conv".into(),
        node: nodes,
        initializer,
        input: vec![value_info("images", &[1, 3, 64, 64])],
        output: vec![value_info("output", &dims)],
        ..Default::default()
    })
}
