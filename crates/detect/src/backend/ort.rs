//! ONNX Runtime backend through the `ort` crate, loading `libonnxruntime.so` at run time
//! (`load-dynamic`: nothing is downloaded or linked at build time). Get the library with
//! `scripts/setup-onnxruntime.sh`.

use super::{InferenceBackend, choose_input_size, guard};
use crate::{DetectError, yolox};
use ort::session::Session;
use ort::session::builder::GraphOptimizationLevel;
use ort::value::TensorRef;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

/// Where `scripts/setup-onnxruntime.sh` puts the library, relative to the working directory.
pub const DEFAULT_DYLIB: &str = "third_party/onnxruntime/libonnxruntime.so";

/// The library to load: the settings entry, then env `ORT_DYLIB_PATH`, then [`DEFAULT_DYLIB`].
pub fn resolve_dylib(configured: Option<&Path>) -> Result<PathBuf, DetectError> {
    let (path, from) = match (configured, std::env::var_os("ORT_DYLIB_PATH")) {
        (Some(p), _) => (p.to_path_buf(), "the [detect] settings"),
        (None, Some(p)) if !p.is_empty() => (PathBuf::from(p), "ORT_DYLIB_PATH"),
        _ => (PathBuf::from(DEFAULT_DYLIB), "the default place"),
    };
    if path.is_file() {
        Ok(path)
    } else {
        Err(DetectError::OrtLibrary {
            msg: format!("{} (from {from}) does not exist", path.display()),
        })
    }
}

/// ONNX Runtime allows one environment per process; it is created on first use and kept.
static ENVIRONMENT: OnceLock<Mutex<Option<ort::environment::Environment>>> = OnceLock::new();

fn environment(dylib: &Path) -> Result<ort::environment::Environment, DetectError> {
    let cell = ENVIRONMENT.get_or_init(|| Mutex::new(None));
    let mut guard = cell.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    if let Some(env) = guard.as_ref() {
        return Ok(env.clone());
    }
    let lib_err = |msg: String| DetectError::OrtLibrary { msg };
    let env = ort::init_from(dylib)
        .map_err(|e| lib_err(e.to_string()))?
        .with_name("stillpoint")
        .build()
        .map_err(|e| lib_err(format!("{}: {e}", dylib.display())))?;
    *guard = Some(env.clone());
    Ok(env)
}

/// A YOLOX model loaded with ONNX Runtime.
#[derive(Debug)]
pub struct OrtBackend {
    session: Session,
    input_size: (usize, usize),
    path: PathBuf,
}

impl OrtBackend {
    /// Load `path` with ONNX Runtime from `dylib` (see [`resolve_dylib`]) on `threads` intra-op
    /// threads, with or without ONNX Runtime's memory pattern (`DetectSettings::ort_memory_pattern`).
    pub fn load(
        path: &Path,
        threads: usize,
        fallback_size: (usize, usize),
        dylib: &Path,
        memory_pattern: bool,
    ) -> Result<Self, DetectError> {
        // The same checks as tract's: ONNX Runtime refuses most bad models itself, but not a
        // huge declared size.
        guard::read_checked(path)?;
        let env = environment(dylib)?;
        let not_onnx = |msg: String| DetectError::NotOnnx {
            path: path.to_path_buf(),
            msg,
        };
        let shape_err = |msg: String| DetectError::ModelShape {
            path: path.to_path_buf(),
            msg,
        };
        let session = guard::guarded(path, "ort", "loading it", || {
            Session::builder(&env)
                .and_then(|b| Ok(b.with_optimization_level(GraphOptimizationLevel::All)?))
                .and_then(|b| Ok(b.with_intra_threads(threads)?))
                .and_then(|b| Ok(b.with_inter_threads(1)?))
                // No spinning: the tracking thread shares the cores and must not be starved.
                .and_then(|b| Ok(b.with_intra_op_spinning(false)?))
                .and_then(|b| Ok(b.with_memory_pattern(memory_pattern)?))
                .and_then(|mut b| b.commit_from_file(path))
                .map_err(|e| not_onnx(e.to_string()))
        })?;
        if session.inputs().len() != 1 || session.outputs().is_empty() {
            return Err(not_onnx(format!(
                "graph has {} inputs and {} outputs, expected 1 image input and an output",
                session.inputs().len(),
                session.outputs().len()
            )));
        }
        let declared: Vec<Option<usize>> = session.inputs()[0]
            .dtype()
            .tensor_shape()
            .map(|s| s.iter().map(|&d| usize::try_from(d).ok()).collect())
            .unwrap_or_default();
        let (h, w) = choose_input_size(path, &declared, fallback_size)?;
        // Check the declared output shape where it is fixed; dynamic ones are checked per frame.
        if let Some(shape) = session.outputs()[0].dtype().tensor_shape()
            && shape.iter().all(|&d| d > 0)
        {
            let dims: Vec<usize> = shape.iter().map(|&d| d as usize).collect();
            yolox::check_output_shape(&dims, h, w).map_err(shape_err)?;
        }
        Ok(Self {
            session,
            input_size: (h, w),
            path: path.to_path_buf(),
        })
    }
}

impl InferenceBackend for OrtBackend {
    fn name(&self) -> &'static str {
        "ort"
    }
    fn input_size(&self) -> (usize, usize) {
        self.input_size
    }
    fn run(&mut self, input: Vec<f32>) -> Result<(Vec<usize>, Vec<f32>), DetectError> {
        let (h, w) = self.input_size;
        let path = self.path.display().to_string();
        let fail = |e: ort::Error| DetectError::Inference {
            backend: "ort",
            msg: format!("{path}: {e}"),
        };
        let session = &mut self.session;
        guard::guarded(&self.path, "ort", "running it on a frame", || {
            let tensor =
                TensorRef::from_array_view(([1usize, 3, h, w], input.as_slice())).map_err(fail)?;
            let outputs = session.run(ort::inputs![tensor]).map_err(fail)?;
            let (shape, values) = outputs[0].try_extract_tensor::<f32>().map_err(fail)?;
            let dims = shape.iter().map(|&d| d.max(0) as usize).collect();
            Ok((dims, values.to_vec()))
        })
    }
}
