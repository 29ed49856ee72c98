//! The YOLOX detector (any backend) and a factory for every detector by name.

use crate::backend::InferenceBackend;
use crate::settings::{Backend, DetectSettings};
use crate::yolox::{self, PostParams};
use crate::{
    DetectError, DetectInput, Detection, Detector, GtDetector, GtDetectorParams, NoDetector,
};
use std::path::{Path, PathBuf};

/// YOLOX on an ONNX model: letterbox, inference, decode + NMS.
pub struct YoloxDetector {
    backend: Box<dyn InferenceBackend>,
    post: PostParams,
    pad_value: f32,
    model: PathBuf,
    name: String,
}

impl std::fmt::Debug for YoloxDetector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("YoloxDetector")
            .field("name", &self.name)
            .field("model", &self.model)
            .field("input_size", &self.backend.input_size())
            .finish()
    }
}

impl YoloxDetector {
    /// Load the model at `model` with the settings' backend, threads and thresholds (the
    /// settings' own `model` entry is ignored here; see [`crate::model::resolve_model`]).
    pub fn load(model: &Path, settings: &DetectSettings) -> Result<Self, DetectError> {
        settings.validate()?;
        // A bad file is refused the same way whichever engine was asked for, and before that
        // engine's own availability is looked at (each backend checks it again on its own).
        crate::backend::guard::read_checked(model)?;
        let backend: Box<dyn InferenceBackend> = match settings.backend {
            Backend::Tract => load_tract(model, settings)?,
            Backend::Ort => load_ort(model, settings)?,
        };
        Ok(Self::from_backend(backend, model, settings))
    }

    /// Wrap an already loaded backend.
    pub fn from_backend(
        backend: Box<dyn InferenceBackend>,
        model: &Path,
        settings: &DetectSettings,
    ) -> Self {
        let name = format!("yolox-{}", backend.name());
        Self {
            backend,
            post: PostParams {
                conf_threshold: settings.conf_threshold,
                nms_threshold: settings.nms_threshold,
            },
            pad_value: settings.pad_value,
            model: model.to_path_buf(),
            name,
        }
    }

    /// Network input size (height, width).
    pub fn input_size(&self) -> (usize, usize) {
        self.backend.input_size()
    }

    /// The model file.
    pub fn model(&self) -> &Path {
        &self.model
    }
}

#[cfg(feature = "tract")]
fn load_tract(model: &Path, s: &DetectSettings) -> Result<Box<dyn InferenceBackend>, DetectError> {
    use crate::backend::tract::TractBackend;
    Ok(Box::new(TractBackend::load(
        model,
        s.threads,
        s.fallback_input_size,
    )?))
}

#[cfg(not(feature = "tract"))]
fn load_tract(
    _model: &Path,
    _s: &DetectSettings,
) -> Result<Box<dyn InferenceBackend>, DetectError> {
    Err(DetectError::BackendUnavailable("tract".into()))
}

#[cfg(feature = "ort")]
fn load_ort(model: &Path, s: &DetectSettings) -> Result<Box<dyn InferenceBackend>, DetectError> {
    use crate::backend::ort::{OrtBackend, resolve_dylib};
    let dylib = resolve_dylib(s.ort_dylib_path.as_deref())?;
    Ok(Box::new(OrtBackend::load(
        model,
        s.threads,
        s.fallback_input_size,
        &dylib,
        s.ort_memory_pattern,
    )?))
}

#[cfg(not(feature = "ort"))]
fn load_ort(_model: &Path, _s: &DetectSettings) -> Result<Box<dyn InferenceBackend>, DetectError> {
    Err(DetectError::BackendUnavailable("ort".into()))
}

impl Detector for YoloxDetector {
    fn detect(&mut self, input: &DetectInput) -> Result<Vec<Detection>, DetectError> {
        if input.rgb.is_empty() || input.rgb.data.len() != input.rgb.width * input.rgb.height {
            return Err(DetectError::BadInput(format!(
                "frame {}: image is empty or its buffer does not match {}x{}",
                input.index, input.rgb.width, input.rgb.height
            )));
        }
        let (h, w) = self.backend.input_size();
        let lb = yolox::letterbox(input.rgb, h, w, self.pad_value);
        let (shape, values) = self.backend.run(lb.tensor)?;
        yolox::decode(
            &values,
            &shape,
            (h, w),
            lb.ratio,
            (input.rgb.width, input.rgb.height),
            &self.post,
        )
        .map_err(|e| DetectError::ModelShape {
            path: self.model.clone(),
            msg: e.to_string(),
        })
    }
    fn name(&self) -> &str {
        &self.name
    }
    fn input_size(&self) -> Option<(usize, usize)> {
        Some(self.backend.input_size())
    }
}

/// Detector names accepted by [`open_detector`].
pub const DETECTOR_NAMES: &str = "yolox, gt, none";

/// Build a detector by name: `"yolox"` (model from `settings.model` or the default search,
/// see [`crate::model::resolve_model`]), `"gt"` (needs `boxes`, a `boxes.jsonl`) or `"none"`.
pub fn open_detector(
    name: &str,
    settings: &DetectSettings,
    boxes: Option<&Path>,
    gt: GtDetectorParams,
) -> Result<Box<dyn Detector>, DetectError> {
    match name {
        "none" => Ok(Box::new(NoDetector)),
        "gt" => {
            let path = boxes.ok_or_else(|| {
                DetectError::BadInput(
                    "the gt detector needs ground-truth boxes (boxes.jsonl, written by `stillpoint synth`)"
                        .into(),
                )
            })?;
            Ok(Box::new(GtDetector::open(path, gt)?))
        }
        "yolox" => {
            let model = crate::model::resolve_model(settings.model.as_deref())?;
            Ok(Box::new(YoloxDetector::load(&model, settings)?))
        }
        other => Err(DetectError::UnknownName {
            what: "detector",
            name: other.to_string(),
            expected: DETECTOR_NAMES,
        }),
    }
}
