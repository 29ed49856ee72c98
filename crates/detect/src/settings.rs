//! Every parameter of the detect crate in one place, with where its default comes from.

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Which inference engine runs the YOLOX ONNX model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// tract-onnx (cargo feature `tract`, off by default): pure Rust, needs nothing on the
    /// machine, but adds ~7 minutes to a cold build on two cores.
    Tract,
    /// ONNX Runtime through the `ort` crate (cargo feature `ort`, on by default), loaded at run
    /// time from `libonnxruntime.so` (`scripts/setup-onnxruntime.sh`). About 2x faster than tract.
    Ort,
}

impl Default for Backend {
    /// tract when it is compiled in (a fresh machine needs nothing else), else ONNX Runtime.
    fn default() -> Self {
        if cfg!(feature = "tract") {
            Backend::Tract
        } else {
            Backend::Ort
        }
    }
}

impl Backend {
    /// Backend names accepted on the command line and in settings files.
    pub const NAMES: &'static str = "tract, ort";

    /// The name as the command line spells it.
    pub fn as_str(self) -> &'static str {
        match self {
            Backend::Tract => "tract",
            Backend::Ort => "ort",
        }
    }
}

impl std::str::FromStr for Backend {
    type Err = crate::DetectError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "tract" => Ok(Backend::Tract),
            "ort" | "onnxruntime" => Ok(Backend::Ort),
            _ => Err(crate::DetectError::UnknownName {
                what: "backend",
                name: s.to_string(),
                expected: Backend::NAMES,
            }),
        }
    }
}

/// Most intra-op threads a detector may ask for (100,000 hung).
pub const MAX_THREADS: usize = 256;

/// Settings of the YOLOX detector (the `[detect]` table of a stillpoint TOML settings file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DetectSettings {
    /// YOLOX ONNX file; `None` searches the default places (see `model::resolve_model`).
    pub model: Option<PathBuf>,
    /// Inference engine: tract in a build with it (a fresh machine needs nothing else), else
    /// ONNX Runtime.
    pub backend: Backend,
    /// Intra-op threads of the inference engine. 1 by default: the paper runs detection beside
    /// tracking, and on a 2-core laptop the other core must stay free for tracking.
    pub threads: usize,
    /// Keep boxes whose score (objectness x class probability) is at least this. 0.3 as in
    /// YOLOX's `demo/ONNXRuntime/onnx_inference.py` (`--score_thr 0.3`).
    pub conf_threshold: f32,
    /// Class-wise NMS IoU threshold: 0.45, YOLOX's demo (`multiclass_nms(..., nms_thr=0.45)`).
    pub nms_threshold: f32,
    /// Letterbox padding value: 114, YOLOX's `preproc` (`np.ones(...) * 114`).
    pub pad_value: f32,
    /// Input size (height, width) for models whose declared input shape is dynamic; a model
    /// with a fixed shape always uses its own. 640x640 is YOLOX-s/m/l/x's test size.
    pub fallback_input_size: (usize, usize),
    /// `libonnxruntime.so` for the `ort` backend; `None` reads env `ORT_DYLIB_PATH`, then
    /// `third_party/onnxruntime/libonnxruntime.so` under the working directory.
    pub ort_dylib_path: Option<PathBuf>,
    /// ONNX Runtime plans all of a run's tensors in one block before the first inference
    /// (its memory pattern). Off by default: YOLOX-nano 480x640 in a recording then peaks 7 MB
    /// lower (131 -> 124 MB) at the same speed (docs/realtime.md).
    pub ort_memory_pattern: bool,
}

impl Default for DetectSettings {
    fn default() -> Self {
        Self {
            model: None,
            backend: Backend::default(),
            threads: 1,
            conf_threshold: 0.3,
            nms_threshold: 0.45,
            pad_value: 114.0,
            fallback_input_size: (640, 640),
            ort_dylib_path: None,
            ort_memory_pattern: false,
        }
    }
}

impl DetectSettings {
    /// Reject settings that would silently give nonsense (NaN thresholds, zero threads, or
    /// 100,000 threads, which hung).
    pub fn validate(&self) -> Result<(), crate::DetectError> {
        let unit = |v: f32| v.is_finite() && (0.0..=1.0).contains(&v);
        if !unit(self.conf_threshold) || !unit(self.nms_threshold) {
            return Err(crate::DetectError::BadInput(format!(
                "detect settings: thresholds must be in 0..1 (conf {}, nms {})",
                self.conf_threshold, self.nms_threshold
            )));
        }
        if !(1..=MAX_THREADS).contains(&self.threads) || !self.pad_value.is_finite() {
            return Err(crate::DetectError::BadInput(format!(
                "detect settings: threads must be 1 to {MAX_THREADS} and the pad value finite (threads {}, pad {})",
                self.threads, self.pad_value
            )));
        }
        let (h, w) = self.fallback_input_size;
        let side = crate::backend::guard::MAX_INPUT_SIDE;
        if h == 0 || w == 0 || h % 32 != 0 || w % 32 != 0 || h > side || w > side {
            return Err(crate::DetectError::BadInput(format!(
                "detect settings: fallback input size {h}x{w} must be positive multiples of 32, \
                 at most {side}"
            )));
        }
        Ok(())
    }
}

/// Read the `[detect]` table of a stillpoint TOML settings file (other tables are ignored; a
/// file without one gives the defaults). Unknown keys in `[detect]` are errors, so typos show.
///
/// ```toml
/// [detect]
/// model = "models/yolox_nano.onnx"
/// backend = "ort"
/// threads = 2
/// ```
pub fn load_toml(path: &std::path::Path) -> Result<DetectSettings, crate::DetectError> {
    #[derive(Deserialize)]
    struct File {
        #[serde(default)]
        detect: DetectSettings,
    }
    let text = std::fs::read_to_string(path).map_err(|e| {
        crate::DetectError::BadInput(format!("{}: cannot read settings: {e}", path.display()))
    })?;
    let file: File = toml::from_str(&text).map_err(|e| {
        crate::DetectError::BadInput(format!("{}: {}", path.display(), e.to_string().trim_end()))
    })?;
    file.detect
        .validate()
        .map_err(|e| crate::DetectError::BadInput(format!("{}: {e}", path.display())))?;
    Ok(file.detect)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn toml_detect_table_is_read_and_typos_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("settings.toml");
        std::fs::write(
            &path,
            "[camera]\nfx = 1.0\n\n[detect]\nbackend = \"ort\"\nthreads = 2\nmodel = \"m.onnx\"\n",
        )
        .unwrap();
        let s = load_toml(&path).unwrap();
        assert_eq!(s.backend, Backend::Ort);
        assert_eq!(s.threads, 2);
        assert_eq!(s.model.as_deref(), Some(std::path::Path::new("m.onnx")));
        assert_eq!(s.conf_threshold, 0.3);
        std::fs::write(&path, "[detect]\nthreshold = 0.5\n").unwrap();
        let err = load_toml(&path).unwrap_err().to_string();
        assert!(
            err.contains("settings.toml") && err.contains("threshold"),
            "{err}"
        );
        std::fs::write(&path, "[detect]\nthreads = 0\n").unwrap();
        assert!(load_toml(&path).is_err());
        std::fs::write(&path, "[other]\n").unwrap();
        assert_eq!(load_toml(&path).unwrap(), DetectSettings::default());
    }
}
