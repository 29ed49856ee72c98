//! Errors of the detect crate; each names the file (and line, where one applies).

use std::path::PathBuf;

/// Where to get YOLOX weights, appended to "model not found" errors.
pub const WEIGHTS_HINT: &str = "get YOLOX ONNX weights from the YOLOX project's GitHub releases \
(https://github.com/Megvii-BaseDetection/YOLOX/releases, e.g. yolox_nano.onnx) and pass --model FILE, \
set `model` in the [detect] settings, set STILLPOINT_MODEL, or put it at models/yolox_nano.onnx beside \
the stillpoint binary";

/// Everything that can go wrong while loading a detector or detecting.
#[derive(Debug, thiserror::Error)]
pub enum DetectError {
    /// No model file anywhere on the search path.
    #[error("no YOLOX model found (looked in: {searched}); {hint}", hint = WEIGHTS_HINT)]
    ModelNotFound {
        /// The places looked in.
        searched: String,
    },
    /// A model path that was named explicitly does not exist or cannot be read.
    #[error("{path}: cannot read model: {error}")]
    ModelIo {
        /// The file.
        path: PathBuf,
        /// Not a `#[source]`: it is already in the message, and error chains would repeat it.
        error: std::io::Error,
    },
    /// The file is not a loadable ONNX model.
    #[error("{path}: not a loadable ONNX model: {msg}")]
    NotOnnx {
        /// The file.
        path: PathBuf,
        /// The loader's message.
        msg: String,
    },
    /// The model loads but is not shaped like a YOLOX detector.
    #[error("{path}: not a YOLOX model: {msg}")]
    ModelShape {
        /// The file.
        path: PathBuf,
        /// What does not fit.
        msg: String,
    },
    /// The model declares something this program does not run: a size past the caps, a
    /// convolution or pooling window of 0, more than one input, ... (checked before any engine
    /// sees the file, see `backend::guard`).
    #[error("{path}: model refused: {msg}")]
    ModelRefused {
        /// The file.
        path: PathBuf,
        /// What is wrong, and where in the graph.
        msg: String,
    },
    /// The inference engine panicked on this model; the panic was caught and the model is not
    /// used further.
    #[error(
        "{path}: {backend} failed on this model while {stage} (internal error: {msg}); the model cannot be used"
    )]
    EnginePanicked {
        /// The file.
        path: PathBuf,
        /// The engine's name.
        backend: &'static str,
        /// What it was doing (loading, running the first frame, ...).
        stage: &'static str,
        /// The panic's message and place.
        msg: String,
    },
    /// The inference backend failed at run time.
    #[error("{backend}: inference failed: {msg}")]
    Inference {
        /// The backend's name.
        backend: &'static str,
        /// Its message.
        msg: String,
    },
    /// ONNX Runtime's shared library is not available.
    #[error(
        "ONNX Runtime library not found ({msg}); run scripts/setup-onnxruntime.sh and set \
         ORT_DYLIB_PATH to the libonnxruntime.so it prints (or `ort_dylib_path` in the [detect] \
         settings), or use the tract backend (`--set detect.backend=tract`, in a build with \
         `--features tract`)"
    )]
    OrtLibrary {
        /// The loader's message.
        msg: String,
    },
    /// The backend was asked for but not compiled in.
    #[error("backend `{0}` is not compiled into this build (rebuild with `--features {0}`)")]
    BackendUnavailable(String),
    /// An unknown backend or detector name.
    #[error("unknown {what} `{name}` (expected one of: {expected})")]
    UnknownName {
        /// What was named (backend, detector).
        what: &'static str,
        /// The name given.
        name: String,
        /// The names known.
        expected: &'static str,
    },
    /// Bad parameters or bad input data (empty image, NaN threshold, ...).
    #[error("{0}")]
    BadInput(String),
    /// Ground-truth boxes could not be read.
    #[error(transparent)]
    Annotations(#[from] stillpoint_detection::annotations::AnnotationsError),
    /// The detector thread is gone (it panicked or was shut down).
    #[error("detector thread stopped: {0}")]
    ThreadStopped(String),
}
