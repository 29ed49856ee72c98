//! `stillpoint.Slam`: frames in, `stillpoint.Frame`s out, `stillpoint.Run` at the end.

use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::sync::{Arc, Mutex, TryLockError};
use std::time::Instant;

use numpy::{PyArray1, PyArray2, PyArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use stillpoint::detect::{DetectError, DetectInput, NoDetector};
use stillpoint::geometry::{BBox, PinholeCamera};
use stillpoint::run::SettingsTree;
use stillpoint::slam::map_file::{self, MapFile};
use stillpoint::{
    COCO_CLASSES, Detection, Detector, DynamicFrontEnd, FrameResult, FrontEnd, Pipeline, Sensor,
    SensorSettings, TrackingState,
};

use crate::arrays::{self, pose_matrix, table, tum_row};
use crate::wait::{detached, interruptible};
use crate::{Error, error};

/// A pinhole camera with radial-tangential distortion (OpenCV's k1, k2, p1, p2, k3).
#[pyclass(module = "stillpoint", frozen, get_all)]
pub struct Camera {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point, x.
    pub cx: f64,
    /// Principal point, y.
    pub cy: f64,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Radial distortion, r^2.
    pub k1: f64,
    /// Radial distortion, r^4.
    pub k2: f64,
    /// Tangential distortion.
    pub p1: f64,
    /// Tangential distortion.
    pub p2: f64,
    /// Radial distortion, r^6.
    pub k3: f64,
}

#[pymethods]
impl Camera {
    #[new]
    #[pyo3(signature = (fx, fy, cx, cy, width, height, k1=0.0, k2=0.0, p1=0.0, p2=0.0, k3=0.0))]
    #[allow(clippy::too_many_arguments)] // Python keyword arguments, one per intrinsic.
    fn new(
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        width: u32,
        height: u32,
        k1: f64,
        k2: f64,
        p1: f64,
        p2: f64,
        k3: f64,
    ) -> PyResult<Self> {
        for (name, v) in [("fx", fx), ("fy", fy)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(PyValueError::new_err(format!(
                    "{name}: a focal length in pixels must be positive, got {v}"
                )));
            }
        }
        for (name, v) in [("cx", cx), ("cy", cy), ("k1", k1), ("k2", k2)]
            .into_iter()
            .chain([("p1", p1), ("p2", p2), ("k3", k3)])
        {
            if !v.is_finite() {
                return Err(PyValueError::new_err(format!(
                    "{name}: must be finite, got {v}"
                )));
            }
        }
        if width < 16 || height < 16 {
            return Err(PyValueError::new_err(format!(
                "width, height: an image of at least 16x16 pixels, got {width}x{height}"
            )));
        }
        Ok(Self {
            fx,
            fy,
            cx,
            cy,
            width,
            height,
            k1,
            k2,
            p1,
            p2,
            k3,
        })
    }

    fn __repr__(&self) -> String {
        let distortion = if [self.k1, self.k2, self.p1, self.p2, self.k3]
            .iter()
            .all(|&v| v == 0.0)
        {
            String::new()
        } else {
            format!(
                ", k1={}, k2={}, p1={}, p2={}, k3={}",
                self.k1, self.k2, self.p1, self.p2, self.k3
            )
        };
        format!(
            "Camera(fx={}, fy={}, cx={}, cy={}, width={}, height={}{distortion})",
            self.fx, self.fy, self.cx, self.cy, self.width, self.height
        )
    }
}

impl Camera {
    pub fn pinhole(&self) -> PinholeCamera {
        let mut c = PinholeCamera::new(self.fx, self.fy, self.cx, self.cy, self.width, self.height);
        c.distortion.k1 = self.k1;
        c.distortion.k2 = self.k2;
        c.distortion.p1 = self.p1;
        c.distortion.p2 = self.p2;
        c.distortion.k3 = self.k3;
        c
    }

    pub fn of(c: &PinholeCamera) -> Self {
        let d = c.distortion;
        Self {
            fx: c.fx,
            fy: c.fy,
            cx: c.cx,
            cy: c.cy,
            width: c.width,
            height: c.height,
            k1: d.k1,
            k2: d.k2,
            p1: d.p1,
            p2: d.p2,
            k3: d.k3,
        }
    }
}

/// `"rgbd"`, `"stereo"` or `"mono"` (also `"monocular"`).
pub fn parse_sensor(s: &str) -> PyResult<Sensor> {
    match s.to_ascii_lowercase().as_str() {
        "rgbd" | "rgb-d" => Ok(Sensor::Rgbd),
        "stereo" => Ok(Sensor::Stereo),
        "mono" | "monocular" => Ok(Sensor::Mono),
        other => Err(PyValueError::new_err(format!(
            "sensor: expected \"rgbd\", \"stereo\" or \"mono\", got {other:?}"
        ))),
    }
}

pub fn sensor_name(s: Sensor) -> &'static str {
    match s {
        Sensor::Rgbd => "rgbd",
        Sensor::Stereo => "stereo",
        Sensor::Mono => "mono",
    }
}

/// The image only one sensor takes with every frame (`depth` for RGB-D, `right` for stereo):
/// required there, refused elsewhere. `name`s: the argument, the image, the sensor with its
/// article.
fn sensor_image<T>(
    (arg, image, wanting): (&str, &str, &str),
    (wants, sensor): (Sensor, Sensor),
    given: Option<&Bound<'_, PyAny>>,
    convert: impl FnOnce(&Bound<'_, PyAny>) -> PyResult<T>,
) -> PyResult<Option<T>> {
    match (sensor == wants, given) {
        (true, Some(g)) => convert(g).map(Some),
        (true, None) => Err(PyValueError::new_err(format!(
            "{arg}: {wanting} Slam needs {image} with every frame"
        ))),
        (false, Some(_)) => Err(PyValueError::new_err(format!(
            "{arg}: a {} Slam takes no {arg} image (make it with sensor=\"{}\")",
            sensor_name(sensor),
            sensor_name(wants)
        ))),
        (false, None) => Ok(None),
    }
}

/// Boxes handed to `track(boxes=...)`, by frame index, taken by the detector on that frame.
type GivenBoxes = Arc<Mutex<HashMap<usize, Vec<Detection>>>>;

/// The user's boxes on the frames that came with them, the detector's on the others.
struct GivenOrDetected {
    given: GivenBoxes,
    detector: Box<dyn Detector>,
}

impl Detector for GivenOrDetected {
    fn detect(&mut self, input: &DetectInput) -> Result<Vec<Detection>, DetectError> {
        let given = self
            .given
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .remove(&input.index);
        match given {
            Some(boxes) => Ok(boxes),
            None => self.detector.detect(input),
        }
    }
    fn name(&self) -> &str {
        self.detector.name()
    }
    fn input_size(&self) -> Option<(usize, usize)> {
        self.detector.input_size()
    }
}

/// Everything a `Slam` is made from besides the sensor's settings.
pub struct Options {
    pub detector: String,
    pub model: Option<PathBuf>,
    pub sets: Vec<String>,
    pub config: Option<PathBuf>,
    pub sequential: bool,
    pub dynamic: bool,
}

/// A running pipeline and what `track` checks its frames against.
struct Session {
    pipeline: Pipeline,
    given: Option<GivenBoxes>,
    sensor: Sensor,
    size: (usize, usize),
    depth_scale: f32,
    next_index: usize,
    last_timestamp: Option<f64>,
    tracked: usize,
}

/// The `libonnxruntime.so` of an installed `onnxruntime` Python package, if there is one.
fn python_onnxruntime(py: Python<'_>) -> Option<PathBuf> {
    let spec = py
        .import("importlib.util")
        .ok()?
        .call_method1("find_spec", ("onnxruntime",))
        .ok()?;
    let dirs: Vec<String> = spec
        .getattr("submodule_search_locations")
        .ok()?
        .extract()
        .ok()?;
    dirs.iter().find_map(|d| {
        let capi = PathBuf::from(d).join("capi");
        let mut libs: Vec<PathBuf> = std::fs::read_dir(&capi)
            .ok()?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with("libonnxruntime.so"))
            })
            .collect();
        libs.sort();
        libs.pop()
    })
}

/// The detector a `Slam` asked for.
fn open_detector(
    py: Python<'_>,
    name: &str,
    tree: &SettingsTree,
    backend_set: bool,
) -> PyResult<Box<dyn Detector>> {
    match name {
        "none" => Ok(Box::new(NoDetector)),
        "yolox" => {
            let mut detect = tree.detect.clone();
            // ONNX Runtime from an installed `onnxruntime` package is about twice tract's speed;
            // a library that will not load leaves tract (when the wheel has it).
            if !backend_set && let Some(lib) = python_onnxruntime(py) {
                let mut ort = detect.clone();
                ort.backend = stillpoint::detect::Backend::Ort;
                ort.ort_dylib_path.get_or_insert(lib);
                match stillpoint::open_detector("yolox", &ort, None, Default::default()) {
                    Ok(d) => return Ok(d),
                    Err(e) if cfg!(feature = "tract") => {
                        tracing::warn!(
                            "ONNX Runtime from the onnxruntime package: {e}; YOLOX runs on tract"
                        );
                        detect.backend = stillpoint::detect::Backend::Tract;
                    }
                    Err(e) => return Err(error(&e)),
                }
            }
            stillpoint::open_detector("yolox", &detect, None, Default::default())
                .map_err(|e| error(&e))
        }
        other => Err(PyValueError::new_err(format!(
            "detector: expected \"yolox\" or \"none\" (your own boxes go to track(boxes=...)), \
             got {other:?}"
        ))),
    }
}

/// A session over `ds`, optionally in a saved map (`(file, localize)`).
fn start(
    py: Python<'_>,
    ds: &SensorSettings,
    o: &Options,
    map: Option<(PathBuf, MapFile, bool)>,
) -> PyResult<Session> {
    let files: Vec<&std::path::Path> = o.config.iter().map(|p| p.as_path()).collect();
    let layers = SettingsTree::from_dataset(ds)
        .layered(&files, &o.sets)
        .map_err(|e| error(&e))?;
    let mut tree = layers.tree;
    if let Some(m) = &o.model {
        tree.detect.model = Some(m.clone());
    }
    let mut settings = tree.pipeline();
    if !layers.sources.contains_key("slam.local_mapping_thread") {
        settings.slam.local_mapping_thread = !o.sequential;
    }
    let given = o.dynamic.then(GivenBoxes::default);
    let front: Option<Box<dyn FrontEnd>> = match &given {
        Some(given) => {
            let backend_set = layers.sources.contains_key("detect.backend");
            let detector = open_detector(py, &o.detector, &tree, backend_set)?;
            let detector = GivenOrDetected {
                given: given.clone(),
                detector,
            };
            let front = DynamicFrontEnd::new(Box::new(detector), tree.front_end.clone());
            let front = if tree.front_end.detector_in_background {
                front.detect_in_background().map_err(|e| error(&e))?
            } else {
                front
            };
            Some(Box::new(front))
        }
        None => None,
    };
    let size = (ds.camera.width as usize, ds.camera.height as usize);
    let pipeline = match map {
        Some((path, file, localize)) => {
            let mode = if localize {
                stillpoint::slam::LoadedMapMode::Localize
            } else {
                stillpoint::slam::LoadedMapMode::Extend
            };
            Pipeline::with_map(settings, front, None, file, mode).map_err(|e| {
                Error::new_err(format!(
                    "{}: {}",
                    path.display(),
                    stillpoint::run::error_chain(&e)
                ))
            })?
        }
        None => Pipeline::new(settings, front, None),
    };
    Ok(Session {
        pipeline,
        given,
        sensor: ds.sensor,
        size,
        depth_scale: ds.depth_factor as f32,
        next_index: 0,
        last_timestamp: None,
        tracked: 0,
    })
}

/// The settings dictionary as `key=value` overrides (`True` -> `true`).
fn overrides(settings: Option<&Bound<'_, PyDict>>) -> PyResult<Vec<String>> {
    let Some(d) = settings else {
        return Ok(Vec::new());
    };
    let mut sets = Vec::new();
    for (k, v) in d.iter() {
        let key: String = k
            .extract()
            .map_err(|_| PyValueError::new_err("settings: keys are dotted names (str)"))?;
        let value = if let Ok(b) = v.cast::<pyo3::types::PyBool>() {
            b.is_true().to_string()
        } else if let Ok(s) = v.cast::<pyo3::types::PyString>() {
            s.to_string()
        } else if v.is_none() {
            return Err(PyValueError::new_err(format!(
                "settings[{key:?}]: None is no value (leave the key out for its default)"
            )));
        } else {
            v.str()?.to_string()
        };
        sets.push(format!("{key}={value}"));
    }
    Ok(sets)
}

/// The state's name in Python.
fn state_name(s: TrackingState) -> &'static str {
    match s {
        TrackingState::NotInitialized => "not_initialized",
        TrackingState::Ok => "ok",
        TrackingState::Lost => "lost",
    }
}

/// `(class, score, x1, y1, x2, y2)` rows as detections.
fn parse_boxes(obj: &Bound<'_, PyAny>, size: (usize, usize)) -> PyResult<Vec<Detection>> {
    let rows: Vec<Vec<f64>> = obj.extract().map_err(|_| {
        PyValueError::new_err(
            "boxes: expected rows of (class, score, x1, y1, x2, y2): a list of 6-tuples or an \
             (N, 6) array",
        )
    })?;
    let (w, h) = (size.0 as f64, size.1 as f64);
    rows.iter()
        .enumerate()
        .map(|(i, r)| {
            let bad = |why: &str| PyValueError::new_err(format!("boxes[{i}]: {why}, got {r:?}"));
            let [class, score, x1, y1, x2, y2] = r[..] else {
                return Err(bad("expected 6 values (class, score, x1, y1, x2, y2)"));
            };
            if !(class >= 0.0 && class.fract() == 0.0 && class <= f64::from(u16::MAX)) {
                return Err(bad("class must be a COCO class index (0 = person)"));
            }
            if !(0.0..=1.0).contains(&score) {
                return Err(bad("score must be within 0..1"));
            }
            if ![x1, y1, x2, y2].iter().all(|v| v.is_finite()) || x2 < x1 || y2 < y1 {
                return Err(bad("corners must be finite with x1 <= x2 and y1 <= y2"));
            }
            if x2 < 0.0 || y2 < 0.0 || x1 > w || y1 > h {
                return Err(bad("the box lies outside the image"));
            }
            Ok(Detection {
                class_id: class as u16,
                score: score as f32,
                bbox: BBox::new(x1 as f32, y1 as f32, x2 as f32, y2 as f32),
            })
        })
        .collect()
}

/// What happened to one frame.
#[pyclass(module = "stillpoint", frozen, get_all)]
pub struct Frame {
    /// Position of the frame in this Slam's input, from 0.
    index: usize,
    /// The frame's timestamp (seconds).
    timestamp: f64,
    /// Camera-to-world pose, (4, 4) float64, or None when the frame was not tracked.
    pose: Py<PyAny>,
    /// "ok", "lost" or "not_initialized".
    state: &'static str,
    /// Every ORB keypoint, (N, 2) float32 pixels, culled ones included.
    keypoints: Py<PyArray2<f32>>,
    /// Per keypoint: judged on a moving object and removed before tracking, (N,) bool.
    dynamic: Py<PyArray1<bool>>,
    /// Per keypoint: matched to a map point and kept by the pose, (N,) bool.
    matched: Py<PyArray1<bool>>,
    /// The objects the front-end saw: dicts with id, class_id, class, x1, y1, x2, y2, state
    /// ("moving", "static" or "carried") and moving.
    boxes: Py<PyList>,
    /// Milliseconds per stage: semantic, geometry, orb, tracking, map_wait, binding (this
    /// call's own conversions and checks) and total.
    timings: Py<PyDict>,
    /// Map points matched by the pose.
    inliers: usize,
    /// The frame became a keyframe.
    keyframe: bool,
    /// Tracking was lost and came back in the same map.
    relocalised: bool,
    /// A new map was started.
    new_map: bool,
    /// Monocular, on the frame that started a map: (index, timestamp, pose) of earlier frames
    /// that got their poses now.
    backfilled: Py<PyList>,
}

#[pymethods]
impl Frame {
    fn __repr__(&self, py: Python<'_>) -> String {
        let n = self.keypoints.bind(py).len().unwrap_or(0);
        let culled = self
            .dynamic
            .bind(py)
            .readonly()
            .as_slice()
            .map_or(0, |d| d.iter().filter(|&&x| x).count());
        format!(
            "Frame(index={}, timestamp={}, state={:?}, keypoints={n}, culled={culled}, inliers={})",
            self.index, self.timestamp, self.state, self.inliers
        )
    }
}

impl Frame {
    fn of(py: Python<'_>, r: &FrameResult) -> PyResult<Self> {
        let pose = match &r.pose_wc {
            Some(p) => pose_matrix(py, p).into_any().unbind(),
            None => py.None(),
        };
        let flat: Vec<f32> = r.keypoints.iter().flatten().copied().collect();
        let keypoints = PyArray1::from_vec(py, flat).reshape([r.keypoints.len(), 2])?;
        let matched = if r.matched.len() == r.keypoints.len() {
            PyArray1::from_slice(py, &r.matched)
        } else {
            PyArray1::from_vec(py, vec![false; r.keypoints.len()])
        };
        let boxes = PyList::empty(py);
        for o in &r.objects.tracked {
            let (_, state) = stillpoint::run::record::box_state(o, &r.objects.carried);
            let d = PyDict::new(py);
            d.set_item("id", o.id)?;
            d.set_item("class_id", o.class_id)?;
            d.set_item(
                "class",
                COCO_CLASSES
                    .get(o.class_id as usize)
                    .copied()
                    .unwrap_or("unknown"),
            )?;
            d.set_item("x1", o.bbox.x1)?;
            d.set_item("y1", o.bbox.y1)?;
            d.set_item("x2", o.bbox.x2)?;
            d.set_item("y2", o.bbox.y2)?;
            d.set_item("state", state)?;
            d.set_item("moving", o.moving)?;
            boxes.append(d)?;
        }
        let t = PyDict::new(py);
        t.set_item("semantic", r.timings.semantic_ms)?;
        t.set_item("geometry", r.timings.geometry_ms)?;
        t.set_item("orb", r.timings.orb_ms)?;
        t.set_item("tracking", r.timings.tracking_ms)?;
        t.set_item("map_wait", r.timings.map_wait_ms)?;
        let backfilled = PyList::empty(py);
        for b in &r.backfilled {
            backfilled.append((b.index, b.timestamp, pose_matrix(py, &b.pose_wc)))?;
        }
        Ok(Self {
            index: r.index,
            timestamp: r.timestamp,
            pose,
            state: state_name(r.state),
            keypoints: keypoints.unbind(),
            dynamic: PyArray1::from_slice(py, &r.dynamic).unbind(),
            matched: matched.unbind(),
            boxes: boxes.unbind(),
            timings: t.unbind(),
            inliers: r.inliers,
            keyframe: r.new_keyframe,
            relocalised: r.relocalised,
            new_map: r.new_map,
            backfilled: backfilled.unbind(),
        })
    }
}

/// Visual SLAM that stays accurate when the world moves: feed frames with `track`, end with
/// `finish`. One Slam is used from one thread at a time (it may move between threads; a call
/// while another thread is inside one raises `stillpoint.Error`).
#[pyclass(module = "stillpoint")]
pub struct Slam {
    session: Mutex<Option<Session>>,
    camera: PinholeCamera,
    sensor: Sensor,
}

/// The keyword arguments `Slam(...)`, `Slam.for_source(...)` and `Slam.from_map(...)` share.
macro_rules! options {
    ($detector:expr, $model:expr, $settings:expr, $config:expr, $sequential:expr, $dynamic:expr) => {
        Options {
            detector: $detector.to_ascii_lowercase(),
            model: $model,
            sets: overrides($settings)?,
            config: $config,
            sequential: $sequential,
            dynamic: $dynamic,
        }
    };
}

#[pymethods]
impl Slam {
    #[new]
    #[pyo3(signature = (camera, sensor="rgbd", *, depth_scale=5000.0, baseline=None, fps=30.0,
        detector="yolox", model=None, settings=None, config=None, sequential=true, dynamic=true))]
    #[allow(clippy::too_many_arguments)] // Python keyword arguments.
    fn new(
        py: Python<'_>,
        camera: PyRef<'_, Camera>,
        sensor: &str,
        depth_scale: f64,
        baseline: Option<f64>,
        fps: f64,
        detector: &str,
        model: Option<PathBuf>,
        settings: Option<&Bound<'_, PyDict>>,
        config: Option<PathBuf>,
        sequential: bool,
        dynamic: bool,
    ) -> PyResult<Self> {
        let sensor = parse_sensor(sensor)?;
        let cam = camera.pinhole();
        let mut ds = SensorSettings::with_camera(sensor, cam);
        if !(depth_scale.is_finite() && depth_scale > 0.0) {
            return Err(PyValueError::new_err(format!(
                "depth_scale: depth units per metre must be positive (TUM 5000, RealSense 1000), \
                 got {depth_scale}"
            )));
        }
        ds.depth_factor = depth_scale;
        if !(fps.is_finite() && fps > 0.0) {
            return Err(PyValueError::new_err(format!(
                "fps: must be positive, got {fps}"
            )));
        }
        ds.fps = fps;
        match (sensor, baseline) {
            (Sensor::Stereo, None) => {
                return Err(PyValueError::new_err(
                    "baseline: a stereo Slam needs the baseline of its rectified pair (metres)",
                ));
            }
            (_, Some(b)) if !(b.is_finite() && b > 0.0) => {
                return Err(PyValueError::new_err(format!(
                    "baseline: must be positive metres, got {b}"
                )));
            }
            (_, Some(b)) => ds.bf = Some(b * cam.fx),
            (_, None) => {}
        }
        let o = options!(detector, model, settings, config, sequential, dynamic);
        Self::build(py, ds, o, None)
    }

    /// A Slam with the camera, sensor, depth scale, baseline and ORB settings of a source that
    /// `stillpoint.open` opened: what `stillpoint run` makes of the same folder.
    #[staticmethod]
    #[pyo3(signature = (source, *, detector="yolox", model=None, settings=None, config=None,
        sequential=true, dynamic=true))]
    #[allow(clippy::too_many_arguments)] // Python keyword arguments.
    fn for_source(
        py: Python<'_>,
        source: PyRef<'_, crate::source::Source>,
        detector: &str,
        model: Option<PathBuf>,
        settings: Option<&Bound<'_, PyDict>>,
        config: Option<PathBuf>,
        sequential: bool,
        dynamic: bool,
    ) -> PyResult<Self> {
        let ds = source.dataset_settings().clone();
        let o = options!(detector, model, settings, config, sequential, dynamic);
        Self::build(py, ds, o, None)
    }

    /// A Slam that starts in a map saved by `Run.save_map` (or `stillpoint run --save-map`):
    /// it relocalises in it, then only tracks against it (`localize=True`) or maps on in it.
    /// The camera and sensor default to the map's.
    #[staticmethod]
    #[pyo3(signature = (path, camera=None, sensor=None, *, localize=true, depth_scale=5000.0,
        fps=30.0, detector="yolox", model=None, settings=None, config=None, sequential=true,
        dynamic=true))]
    #[allow(clippy::too_many_arguments)] // Python keyword arguments.
    fn from_map(
        py: Python<'_>,
        path: PathBuf,
        camera: Option<PyRef<'_, Camera>>,
        sensor: Option<&str>,
        localize: bool,
        depth_scale: f64,
        fps: f64,
        detector: &str,
        model: Option<PathBuf>,
        settings: Option<&Bound<'_, PyDict>>,
        config: Option<PathBuf>,
        sequential: bool,
        dynamic: bool,
    ) -> PyResult<Self> {
        let read = path.clone();
        let file = interruptible(py, move || map_file::load(&read))?.map_err(|e| {
            Error::new_err(format!(
                "{}: {}",
                path.display(),
                stillpoint::run::error_chain(&e)
            ))
        })?;
        let m = &file.sensor;
        let cam = camera.map_or(m.camera, |c| c.pinhole());
        let sensor = match sensor {
            Some(s) => parse_sensor(s)?,
            None if m.monocular => Sensor::Mono,
            None => Sensor::Rgbd,
        };
        let mut ds = SensorSettings::with_camera(sensor, cam);
        ds.depth_factor = depth_scale;
        ds.fps = fps;
        ds.bf = Some(m.bf);
        ds.orb.scale_factor = m.scale_factor as f32;
        ds.orb.n_levels = m.n_levels;
        let o = options!(detector, model, settings, config, sequential, dynamic);
        Self::build(py, ds, o, Some((path, file, localize)))
    }

    /// Track one frame. `image`: (H, W, 3) RGB or (H, W) gray uint8; `depth` (RGB-D): (H, W)
    /// uint16 in units of 1/depth_scale metres or float32 metres; `right` (stereo): the right
    /// image of the rectified pair; `boxes`: your own detector's boxes for this frame, rows of
    /// (class, score, x1, y1, x2, y2), used instead of the Slam's detector. Timestamps
    /// (seconds) must increase.
    #[pyo3(signature = (image, timestamp, depth=None, right=None, boxes=None))]
    fn track(
        &self,
        py: Python<'_>,
        image: &Bound<'_, PyAny>,
        timestamp: f64,
        depth: Option<&Bound<'_, PyAny>>,
        right: Option<&Bound<'_, PyAny>>,
        boxes: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Frame> {
        let t0 = Instant::now();
        let mut guard = self.lock()?;
        let s = guard
            .as_mut()
            .ok_or_else(|| Error::new_err("this Slam has finished; make a new one"))?;
        if !timestamp.is_finite() {
            return Err(PyValueError::new_err(format!(
                "timestamp: must be finite seconds, got {timestamp:?}"
            )));
        }
        if let Some(last) = s.last_timestamp.filter(|&l| timestamp <= l) {
            return Err(PyValueError::new_err(format!(
                "timestamp: {timestamp:?} is not after the previous frame's {last:?}"
            )));
        }
        let (gray, rgb) = arrays::image_u8("image", image, s.size)?;
        let (size, scale) = (s.size, s.depth_scale);
        let depth = sensor_image(
            ("depth", "a depth image", "an RGB-D"),
            (Sensor::Rgbd, s.sensor),
            depth,
            |d| arrays::depth(d, size, scale),
        )?;
        let right = sensor_image(
            ("right", "the right image", "a stereo"),
            (Sensor::Stereo, s.sensor),
            right,
            |r| Ok(arrays::image_u8("right", r, size)?.0),
        )?;
        let index = s.next_index;
        if let Some(b) = boxes {
            let detections = parse_boxes(b, s.size)?;
            let given = s.given.as_ref().ok_or_else(|| {
                PyValueError::new_err("boxes: this Slam has no dynamic front-end (dynamic=False)")
            })?;
            given
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .insert(index, detections);
        }
        let frame = stillpoint::Frame {
            index,
            timestamp,
            gray,
            rgb,
            depth,
            right,
        };
        let t1 = Instant::now();
        let pipeline = &mut s.pipeline;
        let result = detached(py, || pipeline.track(&frame))?;
        let pipeline_ms = t1.elapsed().as_secs_f64() * 1e3;
        if let Some(given) = &s.given {
            // Boxes of a frame the detector never saw (a front-end that skipped it) go.
            given
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .retain(|&i, _| i > index);
        }
        let result = result.map_err(|e| error(&e))?;
        s.next_index += 1;
        s.last_timestamp = Some(timestamp);
        s.tracked += result.poses_in_time_order().count();
        let frame = Frame::of(py, &result)?;
        // The binding's own time: this call's conversions, checks and result, all but the
        // pipeline's.
        let total_ms = t0.elapsed().as_secs_f64() * 1e3;
        let timings = frame.timings.bind(py);
        timings.set_item("binding", total_ms - pipeline_ms)?;
        timings.set_item("total", total_ms)?;
        drop(guard);
        py.check_signals()?;
        Ok(frame)
    }

    /// Track a frame that `stillpoint.open` gave (its image, depth or right image, timestamp).
    #[pyo3(signature = (frame, boxes=None))]
    fn track_frame(
        &self,
        py: Python<'_>,
        frame: PyRef<'_, crate::source::SourceFrame>,
        boxes: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Frame> {
        let image = frame.image_or_gray(py);
        let depth = frame.depth.as_ref().map(|d| d.bind(py).clone().into_any());
        let right = frame.right.as_ref().map(|r| r.bind(py).clone().into_any());
        self.track(
            py,
            &image,
            frame.timestamp,
            depth.as_ref(),
            right.as_ref(),
            boxes,
        )
    }

    /// Stop local mapping and loop closing and return the run: trajectory, keyframes, map.
    /// The Slam takes no frames after it.
    fn finish(&self, py: Python<'_>) -> PyResult<Run> {
        let session = self
            .lock()?
            .take()
            .ok_or_else(|| Error::new_err("this Slam has already finished"))?;
        let tracked = session.tracked;
        let frames = session.next_index;
        let done = interruptible(py, move || {
            session.pipeline.finish().map(|fin| {
                let map = fin.system.map_file();
                (fin, map)
            })
        })?;
        let (fin, map) = done.map_err(|e| error(&e))?;
        // Frames placed only at the end are in the trajectory, not in any frame's result.
        Run::of(py, &fin, map, frames, tracked + fin.placed_at_end)
    }

    /// The camera this Slam was made with.
    #[getter]
    fn camera(&self) -> Camera {
        Camera::of(&self.camera)
    }

    /// "rgbd", "stereo" or "mono".
    #[getter]
    fn sensor(&self) -> &'static str {
        sensor_name(self.sensor)
    }

    fn __repr__(&self) -> String {
        format!(
            "Slam(sensor={:?}, camera={}x{})",
            sensor_name(self.sensor),
            self.camera.width,
            self.camera.height
        )
    }
}

impl Slam {
    fn build(
        py: Python<'_>,
        ds: SensorSettings,
        o: Options,
        map: Option<(PathBuf, MapFile, bool)>,
    ) -> PyResult<Self> {
        let session = start(py, &ds, &o, map)?;
        Ok(Self {
            session: Mutex::new(Some(session)),
            camera: ds.camera,
            sensor: ds.sensor,
        })
    }

    fn lock(&self) -> PyResult<std::sync::MutexGuard<'_, Option<Session>>> {
        match self.session.try_lock() {
            Ok(g) => Ok(g),
            Err(TryLockError::WouldBlock) => Err(Error::new_err(
                "this Slam is in use by another thread (one Slam takes frames from one thread \
                 at a time)",
            )),
            Err(TryLockError::Poisoned(_)) => Err(Error::new_err(
                "this Slam stopped after an internal error; make a new one",
            )),
        }
    }
}

/// A finished run: the trajectory, the keyframes and the map.
#[pyclass(module = "stillpoint", frozen)]
pub struct Run {
    /// (N, 8) float64: timestamp tx ty tz qx qy qz qw per tracked frame (TUM order), each
    /// following its keyframe as bundle adjustment and loop closing left it.
    #[pyo3(get)]
    trajectory: Py<PyArray2<f64>>,
    /// (K, 8) float64: the keyframes' poses, TUM order.
    #[pyo3(get)]
    keyframes: Py<PyArray2<f64>>,
    /// (M, 3) float64: the map points' positions (movers kept out).
    #[pyo3(get)]
    map_points: Py<PyArray2<f64>>,
    /// A loop closed during the run.
    #[pyo3(get)]
    loop_closed: bool,
    /// Maps made: the first, and a new one each time tracking was lost for good.
    #[pyo3(get)]
    maps_made: usize,
    /// Older maps merged into the current one (a place of theirs seen again).
    #[pyo3(get)]
    maps_merged: usize,
    /// Maps that never merged with the trajectory's: map number -> (N, 8) frames, TUM order,
    /// each in a frame of reference of its own.
    #[pyo3(get)]
    other_maps: BTreeMap<u32, Py<PyArray2<f64>>>,
    /// Frames given to `track`.
    #[pyo3(get)]
    frames: usize,
    /// Frames with a pose.
    #[pyo3(get)]
    tracked: usize,
    traj: stillpoint::Trajectory,
    map: Arc<MapFile>,
}

#[pymethods]
impl Run {
    /// Write the map to `path` (atomically); `Slam.from_map` and `stillpoint run --load-map`
    /// read it. Returns the bytes written.
    fn save_map(&self, py: Python<'_>, path: PathBuf) -> PyResult<usize> {
        let map = self.map.clone();
        let to = path.clone();
        interruptible(py, move || map_file::save(&to, &map))?
            .map_err(|e| Error::new_err(format!("{}: {e}", path.display())))
    }

    /// Write the trajectory to `path` as TUM text (as `stillpoint run --out` writes it).
    fn save_trajectory(&self, path: PathBuf) -> PyResult<()> {
        stillpoint::write_tum(&path, &self.traj)
            .map_err(|e| Error::new_err(format!("{}: {e}", path.display())))
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        let k = self.keyframes.bind(py).len().unwrap_or(0);
        let m = self.map_points.bind(py).len().unwrap_or(0);
        format!(
            "Run(tracked={} of {}, keyframes={k}, map_points={m}, loop_closed={})",
            self.tracked,
            self.frames,
            if self.loop_closed { "True" } else { "False" }
        )
    }
}

impl Run {
    fn of(
        py: Python<'_>,
        fin: &stillpoint::Finished,
        map: MapFile,
        frames: usize,
        tracked: usize,
    ) -> PyResult<Self> {
        let rows = |t: &stillpoint::Trajectory| -> Vec<[f64; 8]> {
            t.stamps
                .iter()
                .zip(&t.poses)
                .map(|(s, p)| tum_row(*s, p))
                .collect()
        };
        let points: Vec<[f64; 3]> = map
            .map
            .points
            .values()
            .map(|p| [p.position.x, p.position.y, p.position.z])
            .collect();
        Ok(Self {
            trajectory: table(py, &rows(&fin.trajectory)).unbind(),
            keyframes: table(py, &rows(&fin.keyframe_trajectory)).unbind(),
            map_points: table(py, &points).unbind(),
            loop_closed: fin.loop_closed,
            maps_made: fin.maps.made,
            maps_merged: fin.maps.merged,
            other_maps: fin
                .other_maps
                .iter()
                .map(|(k, t)| (*k, table(py, &rows(t)).unbind()))
                .collect(),
            frames,
            tracked,
            traj: fin.trajectory.clone(),
            map: Arc::new(map),
        })
    }
}
