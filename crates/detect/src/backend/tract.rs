//! tract-onnx backend: pure Rust, always available. The model is parsed once, given a fixed
//! input shape and optimised (`into_optimized`), so each frame only runs the plan.

use super::{InferenceBackend, check_model_file, choose_input_size};
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
        check_model_file(path)?;
        let not_onnx = |e: TractError| DetectError::NotOnnx {
            path: path.to_path_buf(),
            msg: format!("{e:#}"),
        };
        let shape_err = |msg: String| DetectError::ModelShape {
            path: path.to_path_buf(),
            msg,
        };
        let model = tract_onnx::onnx().model_for_path(path).map_err(not_onnx)?;
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
        let typed = model
            .with_input_fact(0, f32::fact([1, 3, h, w]).into())
            .and_then(|m| m.into_optimized())
            .map_err(|e| {
                shape_err(format!(
                    "cannot prepare for a [1, 3, {h}, {w}] input: {e:#}"
                ))
            })?;
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
        Ok(Self {
            state,
            input_size: (h, w),
            path: path.to_path_buf(),
        })
    }
}

impl InferenceBackend for TractBackend {
    fn name(&self) -> &'static str {
        "tract"
    }
    fn input_size(&self) -> (usize, usize) {
        self.input_size
    }
    fn run(&mut self, input: &[f32]) -> Result<(Vec<usize>, Vec<f32>), DetectError> {
        let (h, w) = self.input_size;
        let fail = |e: TractError| DetectError::Inference {
            backend: "tract",
            msg: format!("{}: {e:#}", self.path.display()),
        };
        let tensor = Tensor::from_shape(&[1, 3, h, w], input).map_err(fail)?;
        let outputs = self.state.run(tvec!(tensor.into())).map_err(fail)?;
        let out = outputs[0].to_plain_array_view::<f32>().map_err(fail)?;
        Ok((out.shape().to_vec(), out.iter().copied().collect()))
    }
}
