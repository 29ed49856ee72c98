//! Inference engines behind one small interface: a fixed-size `[1, 3, H, W]` float input in,
//! one float output (with its shape) out. YOLOX pre/post-processing lives in [`crate::yolox`].

pub mod guard;
#[cfg(feature = "tract")]
pub mod tract;

#[cfg(feature = "ort")]
pub mod ort;

use crate::DetectError;
use std::path::Path;

/// One loaded model, ready to run many times.
pub trait InferenceBackend: Send {
    /// Short name for logs and benchmarks (`"tract"`, `"ort"`).
    fn name(&self) -> &'static str;
    /// Network input size (height, width), fixed at load time.
    fn input_size(&self) -> (usize, usize);
    /// Run the model on a `[1, 3, height, width]` tensor; returns the first output's shape and
    /// values. The input is the backend's, to drop once it has its own copy (3.7 MB at 640x480
    /// that would otherwise stay through the inference).
    fn run(&mut self, input: Vec<f32>) -> Result<(Vec<usize>, Vec<f32>), DetectError>;
}

/// Pick the input size: the model's declared `[1, 3, H, W]` when H and W are fixed, else
/// `fallback`. `declared` holds one entry per axis, `None` for a symbolic / unknown one.
pub(crate) fn choose_input_size(
    path: &Path,
    declared: &[Option<usize>],
    fallback: (usize, usize),
) -> Result<(usize, usize), DetectError> {
    let shape_err = |msg: String| DetectError::ModelShape {
        path: path.to_path_buf(),
        msg,
    };
    let shown: Vec<String> = declared
        .iter()
        .map(|d| d.map_or("?".to_string(), |v| v.to_string()))
        .collect();
    if declared.len() != 4
        || declared[1].is_some_and(|c| c != 3)
        || declared[0].is_some_and(|b| b != 1)
    {
        return Err(shape_err(format!(
            "input shape [{}], expected [1, 3, height, width]",
            shown.join(", ")
        )));
    }
    let size = match (declared[2], declared[3]) {
        (Some(h), Some(w)) => (h, w),
        _ => {
            tracing::info!(
                "{}: input shape [{}] is dynamic; using {}x{}",
                path.display(),
                shown.join(", "),
                fallback.0,
                fallback.1
            );
            fallback
        }
    };
    let side = guard::MAX_INPUT_SIDE;
    if size.0 > side || size.1 > side || 3 * size.0 * size.1 > guard::MAX_INPUT_ELEMENTS {
        return Err(DetectError::ModelRefused {
            path: path.to_path_buf(),
            msg: format!(
                "input size {}x{} is larger than the {side}x{side} this program runs",
                size.0, size.1
            ),
        });
    }
    if size.0 < 32 || size.1 < 32 {
        return Err(shape_err(format!(
            "input size {}x{} is smaller than YOLOX's largest stride (32)",
            size.0, size.1
        )));
    }
    Ok(size)
}

/// Check that a model file can be read and is not trivially empty, before a backend parses it
/// (an empty file is a valid, empty protobuf, which would otherwise give a confusing error).
pub(crate) fn check_model_file(path: &Path) -> Result<(), DetectError> {
    let meta = std::fs::metadata(path).map_err(|error| DetectError::ModelIo {
        path: path.to_path_buf(),
        error,
    })?;
    if !meta.is_file() {
        return Err(DetectError::ModelIo {
            path: path.to_path_buf(),
            error: std::io::Error::other("not a regular file"),
        });
    }
    if meta.len() < 16 {
        return Err(DetectError::NotOnnx {
            path: path.to_path_buf(),
            msg: format!("file is only {} bytes", meta.len()),
        });
    }
    Ok(())
}

/// The backends that can run a model here: tract when compiled in, ort when compiled in and
/// its library is found (`configured`: the settings' `ort_dylib_path`).
pub fn available(configured: Option<&Path>) -> Vec<crate::Backend> {
    let mut backends = Vec::new();
    if cfg!(feature = "tract") {
        backends.push(crate::Backend::Tract);
    }
    if ort_dylib_available(configured) {
        backends.push(crate::Backend::Ort);
    }
    backends
}

/// Whether the `ort` backend can run here: compiled in and its library found (see
/// `ort::resolve_dylib`; `configured` is the settings' `ort_dylib_path`).
pub fn ort_dylib_available(configured: Option<&Path>) -> bool {
    #[cfg(feature = "ort")]
    {
        ort::resolve_dylib(configured).is_ok()
    }
    #[cfg(not(feature = "ort"))]
    {
        let _ = configured;
        false
    }
}
