//! `stillpoint.open`: a dataset folder, a ROS recording or a video as numpy frames.

use std::path::PathBuf;
use std::sync::Mutex;

use numpy::{PyArray2, PyArrayDyn};
use pyo3::exceptions::{PyIndexError, PyUserWarning, PyValueError};
use pyo3::prelude::*;
use stillpoint::datasets::DatasetError;
use stillpoint::{SensorSettings, Sequence};

use crate::arrays;
use crate::slam::{Camera, sensor_name};
use crate::wait::detached;
use crate::{Error, error};

/// Extensions read as video (`stillpoint run --video`).
const VIDEO: [&str; 5] = ["mp4", "m4v", "mov", "h264", "264"];
/// Extensions read as ROS recordings (`stillpoint run --bag`).
const RECORDING: [&str; 3] = ["mcap", "bag", "db3"];

/// Open a sequence: a dataset folder (TUM, Bonn, KITTI, EuRoC, `stillpoint.synth`'s, a folder
/// of images), a video file, or a ROS 1 / ROS 2 recording (with `rgb_topic`, and `depth_topic`
/// or `right_topic`). `kind` forces the folder's layout ("tum", "kitti", ...); `settings` is an
/// ORB-SLAM YAML or stillpoint TOML file with the camera.
#[pyfunction]
#[pyo3(signature = (path, *, kind=None, settings=None, rgb_topic=None, depth_topic=None,
    right_topic=None, camera_info_topic=None))]
#[allow(clippy::too_many_arguments)] // Python keyword arguments.
pub fn open(
    py: Python<'_>,
    path: PathBuf,
    kind: Option<&str>,
    settings: Option<PathBuf>,
    rgb_topic: Option<String>,
    depth_topic: Option<String>,
    right_topic: Option<String>,
    camera_info_topic: Option<String>,
) -> PyResult<Source> {
    let kind = kind
        .map(|k| k.parse::<stillpoint::DatasetKind>())
        .transpose()
        .map_err(|e| PyValueError::new_err(format!("kind: {e}")))?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    let is_recording = RECORDING.contains(&ext.as_str()) || path.join("metadata.yaml").is_file();
    let topics = match rgb_topic {
        Some(rgb) => Some(stillpoint::datasets::mcap::McapTopics {
            rgb,
            depth: depth_topic,
            right: right_topic,
            camera_info: camera_info_topic,
        }),
        None if is_recording => {
            return Err(PyValueError::new_err(format!(
                "rgb_topic: {} is a ROS recording; name its image topic (and depth_topic or \
                 right_topic), e.g. rgb_topic=\"/camera/color/image_raw\"",
                path.display()
            )));
        }
        None => None,
    };
    let settings_file = settings.clone();
    let at = path.clone();
    let opened = detached(py, move || {
        let s = settings_file.as_deref();
        match &topics {
            Some(t) => stillpoint::datasets::open_recording(&at, t, s),
            None if VIDEO.contains(&ext.as_str()) => stillpoint::datasets::open_video(&at, s),
            None => stillpoint::open(&at, kind, s),
        }
    })?;
    let seq = opened.map_err(|e| error(&e))?;
    Ok(Source {
        ds: seq.settings().clone(),
        name: seq.name(),
        path,
        seq: Mutex::new(seq),
    })
}

/// An opened sequence: `len(source)`, `source[i]`, and iteration give `SourceFrame`s.
#[pyclass(module = "stillpoint", frozen)]
pub struct Source {
    seq: Mutex<Box<dyn Sequence>>,
    ds: SensorSettings,
    /// The sequence's name (its folder's).
    #[pyo3(get)]
    name: String,
    /// What was opened.
    #[pyo3(get)]
    path: PathBuf,
}

impl Source {
    pub fn dataset_settings(&self) -> &SensorSettings {
        &self.ds
    }

    fn len(&self) -> usize {
        self.seq.lock().unwrap_or_else(|p| p.into_inner()).len()
    }

    fn read(&self, py: Python<'_>, i: usize) -> PyResult<Result<SourceFrame, DatasetError>> {
        let read = detached(py, || {
            self.seq.lock().unwrap_or_else(|p| p.into_inner()).frame(i)
        })?;
        Ok(match read {
            Ok(f) => Ok(SourceFrame::of(py, &f)),
            Err(e) => Err(e),
        })
    }
}

#[pymethods]
impl Source {
    fn __len__(&self) -> usize {
        self.len()
    }

    fn __getitem__(&self, py: Python<'_>, i: isize) -> PyResult<SourceFrame> {
        let n = self.len();
        let k = if i < 0 { n as isize + i } else { i };
        if k < 0 || k as usize >= n {
            return Err(PyIndexError::new_err(format!(
                "frame {i}: the sequence has {n} frames"
            )));
        }
        self.read(py, k as usize)?.map_err(|e| error(&e))
    }

    fn __iter__(slf: Py<Self>) -> SourceIter {
        SourceIter {
            source: slf,
            next: 0,
        }
    }

    /// The camera (intrinsics, size, distortion).
    #[getter]
    fn camera(&self) -> Camera {
        Camera::of(&self.ds.camera)
    }

    /// "rgbd", "stereo" or "mono".
    #[getter]
    fn sensor(&self) -> &'static str {
        sensor_name(self.ds.sensor)
    }

    /// Depth units per metre of the depth images (TUM 5000).
    #[getter]
    fn depth_scale(&self) -> f64 {
        self.ds.depth_factor
    }

    /// Frames a second.
    #[getter]
    fn fps(&self) -> f64 {
        self.ds.fps
    }

    /// The stereo baseline in metres, when known.
    #[getter]
    fn baseline(&self) -> Option<f64> {
        self.ds.baseline()
    }

    /// The ground-truth trajectory file, when the sequence has one.
    #[getter]
    fn ground_truth(&self) -> Option<PathBuf> {
        self.seq
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .ground_truth()
    }

    /// The sequence's `boxes.jsonl` (ground-truth boxes), when it has one.
    #[getter]
    fn boxes(&self) -> Option<PathBuf> {
        self.seq.lock().unwrap_or_else(|p| p.into_inner()).boxes()
    }

    fn __repr__(&self) -> String {
        format!(
            "Source({:?}, sensor={:?}, frames={}, camera={}x{})",
            self.name,
            sensor_name(self.ds.sensor),
            self.len(),
            self.ds.camera.width,
            self.ds.camera.height
        )
    }
}

/// Iterates a `Source`; a frame that cannot be read is skipped with a warning.
#[pyclass(module = "stillpoint")]
pub struct SourceIter {
    source: Py<Source>,
    next: usize,
}

#[pymethods]
impl SourceIter {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__(&mut self, py: Python<'_>) -> PyResult<Option<SourceFrame>> {
        let source = self.source.get();
        let n = source.len();
        while self.next < n {
            let i = self.next;
            self.next += 1;
            match source.read(py, i)? {
                Ok(f) => return Ok(Some(f)),
                // The source gives nothing after this.
                Err(DatasetError::Ended { .. }) => return Ok(None),
                Err(e) => {
                    let msg = format!("frame {i}: skipped: {}", stillpoint::run::error_chain(&e));
                    let msg =
                        std::ffi::CString::new(msg).map_err(|e| Error::new_err(e.to_string()))?;
                    PyErr::warn(py, &py.get_type::<PyUserWarning>(), &msg, 1)?;
                }
            }
        }
        Ok(None)
    }
}

/// One frame of a `Source`, as numpy arrays.
#[pyclass(module = "stillpoint", frozen, get_all)]
pub struct SourceFrame {
    /// Position in the sequence.
    pub index: usize,
    /// Seconds, as the sequence gives them.
    pub timestamp: f64,
    /// (H, W, 3) uint8 RGB, or None for a gray camera.
    pub image: Option<Py<PyArrayDyn<u8>>>,
    /// (H, W) uint8.
    pub gray: Py<PyArray2<u8>>,
    /// (H, W) float32 metres (0: no measurement), or None.
    pub depth: Option<Py<PyArray2<f32>>>,
    /// (H, W) uint8 right image of a stereo pair, or None.
    pub right: Option<Py<PyArray2<u8>>>,
}

impl SourceFrame {
    fn of(py: Python<'_>, f: &stillpoint::Frame) -> Self {
        Self {
            index: f.index,
            timestamp: f.timestamp,
            image: f.rgb.as_ref().map(|c| arrays::rgb_array(py, c).unbind()),
            gray: arrays::gray_array(py, &f.gray).unbind(),
            depth: f
                .depth
                .as_ref()
                .map(|d| arrays::depth_array(py, d).unbind()),
            right: f.right.as_ref().map(|r| arrays::gray_array(py, r).unbind()),
        }
    }

    /// The colour image, else the gray one.
    pub fn image_or_gray<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        match &self.image {
            Some(c) => c.bind(py).clone().into_any(),
            None => self.gray.bind(py).clone().into_any(),
        }
    }
}

#[pymethods]
impl SourceFrame {
    fn __repr__(&self) -> String {
        format!(
            "SourceFrame(index={}, timestamp={}, colour={}, depth={}, right={})",
            self.index,
            self.timestamp,
            self.image.is_some(),
            self.depth.is_some(),
            self.right.is_some()
        )
    }
}
