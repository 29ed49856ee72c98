//! Finding the YOLOX model file.

use crate::DetectError;
use std::path::{Path, PathBuf};

/// Env variable naming the model when neither the command line nor the settings do.
pub const MODEL_ENV: &str = "STILLPOINT_MODEL";
/// Env variable naming a folder of models (a copy of `../shared/models`): its
/// [`MODEL_FILE_NAMES`] are looked for when `STILLPOINT_MODEL` is unset.
pub const MODELS_DIR_ENV: &str = "STILLPOINT_MODELS";
/// The file names looked for in a models folder, in order.
pub const MODEL_FILE_NAMES: [&str; 2] = ["yolox_nano_480x640.onnx", "yolox_nano.onnx"];
/// Where a packaged stillpoint keeps its model, relative to the binary's folder.
pub const BESIDE_BINARY: &str = "models/yolox_nano.onnx";
/// The shared model of this project's machines, relative to the working directory.
pub const SHARED_MODEL: &str = "../shared/models/yolox_nano_480x640.onnx";

/// Resolve the model: `explicit` (the command line's `--model`, else the settings' `model`),
/// then env `STILLPOINT_MODEL`, then the [`MODEL_FILE_NAMES`] in the folder env
/// `STILLPOINT_MODELS` names, then `models/yolox_nano.onnx` beside the binary, then
/// `../shared/models/yolox_nano_480x640.onnx` under the working directory.
///
/// A path named explicitly (argument or env) must exist: a typo is an error naming it, not a
/// silent fall-through to another model. Nothing found is [`DetectError::ModelNotFound`], whose
/// message says where to get YOLOX weights.
///
/// ```
/// let err = stillpoint_detect::model::resolve_model(Some(std::path::Path::new("/no/such.onnx")));
/// assert!(err.unwrap_err().to_string().contains("/no/such.onnx"));
/// ```
pub fn resolve_model(explicit: Option<&Path>) -> Result<PathBuf, DetectError> {
    let must_exist = |p: PathBuf, from: &str| -> Result<PathBuf, DetectError> {
        if p.is_file() {
            Ok(p)
        } else {
            Err(DetectError::ModelIo {
                path: p,
                error: std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    format!("no such model file (named by {from})"),
                ),
            })
        }
    };
    if let Some(p) = explicit {
        return must_exist(p.to_path_buf(), "--model or the settings");
    }
    if let Some(p) = std::env::var_os(MODEL_ENV).filter(|p| !p.is_empty()) {
        return must_exist(PathBuf::from(p), MODEL_ENV);
    }
    let mut searched = vec![format!("${MODEL_ENV} (unset)")];
    if let Some(dir) = std::env::var_os(MODELS_DIR_ENV).filter(|p| !p.is_empty()) {
        let dir = PathBuf::from(dir);
        let found = MODEL_FILE_NAMES
            .iter()
            .map(|n| dir.join(n))
            .find(|p| p.is_file());
        if let Some(p) = found {
            return Ok(p);
        }
        // A folder named on purpose that holds no model: say so rather than fall through.
        return Err(DetectError::ModelNotFound {
            searched: format!(
                "${MODELS_DIR_ENV}={} (no {} in it)",
                dir.display(),
                MODEL_FILE_NAMES.join(" or ")
            ),
        });
    }
    searched.push(format!("${MODELS_DIR_ENV} (unset)"));
    let beside = std::env::current_exe()
        .ok()
        .and_then(|exe| exe.parent().map(|dir| dir.join(BESIDE_BINARY)));
    for candidate in beside.into_iter().chain([PathBuf::from(SHARED_MODEL)]) {
        if candidate.is_file() {
            return Ok(candidate);
        }
        searched.push(candidate.display().to_string());
    }
    Err(DetectError::ModelNotFound {
        searched: searched.join(", "),
    })
}
