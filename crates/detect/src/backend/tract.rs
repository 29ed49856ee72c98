//! tract-onnx backend (feature `tract`): pure Rust, nothing needed on the machine. The model is parsed once, given a fixed
//! input shape and optimised (`into_optimized`), so each frame only runs the plan.

use super::{InferenceBackend, choose_input_size, guard};
use crate::{DetectError, yolox};
use std::path::{Path, PathBuf};
use tract_onnx::prelude::*;
use tract_onnx::tract_core::runtime::RunOptions;
use tract_onnx::tract_hir::infer::Factoid;
use tract_onnx::tract_hir::internal::DimLike;

/// A YOLOX model loaded with tract.
pub struct TractBackend {
    /// Kept between frames so tract reuses its buffers.
    state: TypedSimpleState,
    input_size: (usize, usize),
    path: PathBuf,
    /// Set when tract panicked on a frame: its state is not trusted after that.
    broken: bool,
}

impl std::fmt::Debug for TractBackend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TractBackend")
            .field("path", &self.path)
            .field("input_size", &self.input_size)
            .finish()
    }
}

impl TractBackend {
    /// Load and optimise `path` for a fixed input size (the model's own, or `fallback_size` when
    /// it declares a dynamic one), running on `threads` intra-op threads.
    pub fn load(
        path: &Path,
        threads: usize,
        fallback_size: (usize, usize),
    ) -> Result<Self, DetectError> {
        let bytes = guard::read_checked(path)?;
        let (state, input_size) = guard::guarded(path, "tract", "loading it", || {
            let proto = <tract_onnx::pb::ModelProto as prost::Message>::decode(bytes.as_slice())
                .map_err(|e| DetectError::NotOnnx {
                    path: path.to_path_buf(),
                    msg: format!("not an ONNX protobuf: {e}"),
                })?;
            prepare(path, &proto, threads, fallback_size)
        })?;
        Ok(Self {
            state,
            input_size,
            path: path.to_path_buf(),
            broken: false,
        })
    }
}

/// Parse the checked model, fix its input size, type it, check every tensor's size, optimise
/// it and make the plan.
fn prepare(
    path: &Path,
    proto: &tract_onnx::pb::ModelProto,
    threads: usize,
    fallback_size: (usize, usize),
) -> Result<(TypedSimpleState, (usize, usize)), DetectError> {
    let not_onnx = |e: TractError| DetectError::NotOnnx {
        path: path.to_path_buf(),
        msg: format!("{e:#}"),
    };
    let shape_err = |msg: String| DetectError::ModelShape {
        path: path.to_path_buf(),
        msg,
    };
    let dir = path.parent().and_then(|d| d.to_str());
    let parsed = tract_onnx::onnx().parse(proto, dir).map_err(not_onnx)?;
    if !parsed.unresolved_inputs.is_empty() {
        return Err(DetectError::NotOnnx {
            path: path.to_path_buf(),
            msg: format!(
                "nodes read inputs that nothing makes: {:?}",
                parsed.unresolved_inputs
            ),
        });
    }
    let model = parsed.model;
    if model.inputs.len() != 1 || model.outputs.is_empty() {
        return Err(DetectError::NotOnnx {
            path: path.to_path_buf(),
            msg: format!(
                "graph has {} inputs and {} outputs, expected 1 image input and an output",
                model.inputs.len(),
                model.outputs.len()
            ),
        });
    }
    let fact = model.input_fact(0).map_err(not_onnx)?;
    let declared: Vec<Option<usize>> = if fact.shape.is_open() {
        Vec::new()
    } else {
        fact.shape
            .dims()
            .map(|d| d.concretize().and_then(|d| d.to_usize().ok()))
            .collect()
    };
    let (h, w) = choose_input_size(path, &declared, fallback_size)?;
    let prepare_err = |e: TractError| {
        shape_err(format!(
            "cannot prepare for a [1, 3, {h}, {w}] input: {e:#}"
        ))
    };
    let typed = model
        .with_input_fact(0, f32::fact([1, 3, h, w]).into())
        .and_then(|m| m.into_typed())
        .map_err(prepare_err)?;
    // Every tensor the plan will hold, before it is allocated: a node can blow a small input up
    // (a Resize by 1000, a Pad of 10^5), and a failed allocation aborts the process.
    for node in typed.nodes() {
        for out in &node.outputs {
            let Some(dims) = out.fact.shape.as_concrete() else {
                continue;
            };
            let n = dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d));
            if n.is_none_or(|n| n > guard::MAX_TENSOR_ELEMENTS) {
                return Err(DetectError::ModelRefused {
                    path: path.to_path_buf(),
                    msg: format!(
                        "node {:?} ({}) makes a {dims:?} tensor for a [1, 3, {h}, {w}] input, \
                         more than the {} Mi values this program allows one tensor",
                        node.name,
                        node.op.name(),
                        guard::MAX_TENSOR_ELEMENTS >> 20
                    ),
                });
            }
        }
    }
    let typed = typed.into_optimized().map_err(prepare_err)?;
    let out_fact = typed.output_fact(0).map_err(not_onnx)?;
    let out_shape = out_fact
        .shape
        .as_concrete()
        .ok_or_else(|| shape_err(format!("output shape {:?} is not fixed", out_fact.shape)))?;
    yolox::check_output_shape(out_shape, h, w).map_err(shape_err)?;
    let options = RunOptions {
        executor: (threads > 1).then(|| multithread::Executor::multithread(threads)),
        ..Default::default()
    };
    let plan = typed
        .into_runnable_with_options(&options)
        .map_err(not_onnx)?;
    let state = plan.spawn().map_err(not_onnx)?;
    Ok((state, (h, w)))
}

impl InferenceBackend for TractBackend {
    fn name(&self) -> &'static str {
        "tract"
    }
    fn input_size(&self) -> (usize, usize) {
        self.input_size
    }
    fn run(&mut self, input: Vec<f32>) -> Result<(Vec<usize>, Vec<f32>), DetectError> {
        let (h, w) = self.input_size;
        let path = self.path.display().to_string();
        if self.broken {
            return Err(DetectError::Inference {
                backend: "tract",
                msg: format!("{path}: not run again after it failed on an earlier frame"),
            });
        }
        let fail = |e: TractError| DetectError::Inference {
            backend: "tract",
            msg: format!("{path}: {e:#}"),
        };
        let state = &mut self.state;
        let result = guard::guarded(&self.path, "tract", "running it on a frame", move || {
            // tract copies the input into its own aligned tensor: ours goes before the run
            let tensor = Tensor::from_shape(&[1, 3, h, w], &input).map_err(fail)?;
            drop(input);
            let outputs = state.run(tvec!(tensor.into())).map_err(fail)?;
            let out = outputs[0].to_plain_array_view::<f32>().map_err(fail)?;
            Ok((out.shape().to_vec(), out.iter().copied().collect()))
        });
        if matches!(result, Err(DetectError::EnginePanicked { .. })) {
            self.broken = true;
        }
        result
    }
}
