//! `stillpoint.synth`, and the trajectory metrics behind `stillpoint.eval`.

use std::path::PathBuf;

use numpy::{PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use stillpoint::geometry::Se3;
use stillpoint::synth::{KinectNoise, Noise, Preset, SynthConfig, WriteOptions};
use stillpoint::trajectory::{
    Alignment, AteOptions, DeltaUnit, ErrorStats, Matching, RpeOptions, Trajectory,
    TrajectoryFormat,
};

use crate::wait::interruptible;
use crate::{Error, error};

/// Write a synthetic sequence with exact ground truth (what `stillpoint synth` writes): the TUM
/// layout (rgb/, depth/, rgb.txt, depth.txt, groundtruth.txt), boxes.jsonl, settings.toml, and
/// with `stereo` a KITTI-layout pair beside it, with `masks` the moving pixels. Returns a
/// summary dict.
#[pyfunction]
#[pyo3(signature = (preset, out, *, seed=0, frames=300, size=(640, 480), noise=None,
    textures=None, stereo=false, baseline=0.1, masks=false, path_offset=0.0))]
#[allow(clippy::too_many_arguments)] // Python keyword arguments.
pub fn synth<'py>(
    py: Python<'py>,
    preset: &str,
    out: PathBuf,
    seed: u64,
    frames: usize,
    size: (u32, u32),
    noise: Option<&str>,
    textures: Option<PathBuf>,
    stereo: bool,
    baseline: f64,
    masks: bool,
    path_offset: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let preset = Preset::from_name(preset).ok_or_else(|| {
        let names: Vec<&str> = Preset::ALL.iter().map(|p| p.name()).collect();
        PyValueError::new_err(format!(
            "preset: unknown {preset:?}; known: {}",
            names.join(", ")
        ))
    })?;
    if frames == 0 {
        return Err(PyValueError::new_err("frames: at least 1"));
    }
    let (w, h) = size;
    if !(16..=8192).contains(&w) || !(16..=8192).contains(&h) {
        return Err(PyValueError::new_err(format!(
            "size: (width, height) within 16..8192, got ({w}, {h})"
        )));
    }
    let noise = match noise {
        None => preset.default_noise(),
        Some("none") => Noise::None,
        Some("kinect") => Noise::Kinect(KinectNoise::default()),
        Some(other) => {
            return Err(PyValueError::new_err(format!(
                "noise: expected \"none\" or \"kinect\", got {other:?}"
            )));
        }
    };
    if stereo && !(baseline.is_finite() && baseline > 0.0) {
        return Err(PyValueError::new_err(format!(
            "baseline: must be positive metres, got {baseline}"
        )));
    }
    if !(path_offset.is_finite() && path_offset >= 0.0) {
        return Err(PyValueError::new_err(format!(
            "path_offset: must be 0 or more seconds, got {path_offset}"
        )));
    }
    let config = SynthConfig {
        preset,
        frames,
        seed,
        camera: stillpoint::synth::tum_fr3_camera_sized(w, h),
        noise,
        textures,
        stereo_baseline: stereo.then_some(baseline),
        path_offset,
        ..SynthConfig::default()
    };
    let dir = out.clone();
    let written = interruptible(py, move || {
        stillpoint::synth::write_sequence(&config, WriteOptions { stereo, masks }, &dir)
    })?
    .map_err(|e| {
        Error::new_err(format!(
            "{}: {}",
            out.display(),
            stillpoint::run::error_chain(&e)
        ))
    })?;
    let d = PyDict::new(py);
    d.set_item("dir", written.dir)?;
    d.set_item("frames", written.frames)?;
    d.set_item("seconds", written.seconds)?;
    d.set_item("mean_dynamic_fraction", written.mean_dynamic_fraction)?;
    d.set_item("mean_person_fraction", written.mean_person_fraction)?;
    Ok(d)
}

/// A trajectory from a file (TUM, KITTI or EuRoC, `format`) or an (N, 8) array of TUM rows.
fn trajectory(
    name: &str,
    obj: &Bound<'_, PyAny>,
    format: TrajectoryFormat,
) -> PyResult<Trajectory> {
    if let Ok(rows) = obj.extract::<PyReadonlyArray2<'_, f64>>() {
        let shape = rows.shape().to_vec();
        if shape.len() != 2 || shape[1] != 8 {
            return Err(PyValueError::new_err(format!(
                "{name}: expected an (N, 8) float64 array of t tx ty tz qx qy qz qw, got shape \
                 {shape:?}"
            )));
        }
        let a = rows.as_array();
        let mut stamps = Vec::with_capacity(shape[0]);
        let mut poses = Vec::with_capacity(shape[0]);
        for (i, r) in a.rows().into_iter().enumerate() {
            let q = nalgebra_quaternion(r[7], r[4], r[5], r[6]).ok_or_else(|| {
                PyValueError::new_err(format!("{name}[{i}]: the quaternion has zero length"))
            })?;
            stamps.push(r[0]);
            poses.push(Se3::from_parts(
                stillpoint::geometry::Vec3::new(r[1], r[2], r[3]).into(),
                q,
            ));
        }
        return Trajectory::from_parts(stamps, poses)
            .map_err(|e| PyValueError::new_err(format!("{name}: {e}")));
    }
    let path: PathBuf = obj.extract().map_err(|_| {
        PyValueError::new_err(format!(
            "{name}: expected a trajectory file's path or an (N, 8) float64 array"
        ))
    })?;
    stillpoint::trajectory::read_trajectory_lenient(&path, format)
        .map(|(t, _)| t)
        .map_err(|e| error(&e))
}

fn nalgebra_quaternion(w: f64, x: f64, y: f64, z: f64) -> Option<nalgebra::UnitQuaternion<f64>> {
    let q = nalgebra::Quaternion::new(w, x, y, z);
    (q.norm() > 0.0 && q.norm().is_finite()).then(|| nalgebra::UnitQuaternion::from_quaternion(q))
}

fn stats<'py>(py: Python<'py>, s: &ErrorStats) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let values = [
        ("rmse", s.rmse),
        ("mean", s.mean),
        ("median", s.median),
        ("std", s.std),
        ("min", s.min),
        ("max", s.max),
        ("sse", s.sse),
    ];
    for (k, v) in values {
        d.set_item(k, v)?;
    }
    d.set_item("count", s.count)?;
    Ok(d)
}

/// The two trajectories, read in `format`, and how to align and pair them.
fn pair(
    (gt, est): (&Bound<'_, PyAny>, &Bound<'_, PyAny>),
    align: &str,
    format: &str,
    (max_diff, offset): (f64, f64),
) -> PyResult<(Trajectory, Trajectory, Alignment, Matching)> {
    let align: Alignment = align
        .parse()
        .map_err(|e: String| PyValueError::new_err(format!("align: {e}")))?;
    let format: TrajectoryFormat = format
        .parse()
        .map_err(|e: String| PyValueError::new_err(format!("format: {e}")))?;
    if !(max_diff.is_finite() && max_diff >= 0.0 && offset.is_finite()) {
        return Err(PyValueError::new_err(
            "max_diff, offset: finite seconds, max_diff 0 or more",
        ));
    }
    let matching = Matching::for_formats(format, format, max_diff, offset);
    Ok((
        trajectory("gt", gt, format)?,
        trajectory("est", est, format)?,
        align,
        matching,
    ))
}

/// Absolute trajectory error, translation part, metres: evo_ape's numbers.
#[pyfunction]
#[pyo3(signature = (gt, est, *, align="se3", format="tum", max_diff=0.01, offset=0.0))]
pub fn ate<'py>(
    py: Python<'py>,
    gt: &Bound<'py, PyAny>,
    est: &Bound<'py, PyAny>,
    align: &str,
    format: &str,
    max_diff: f64,
    offset: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let (gt, est, align, matching) = pair((gt, est), align, format, (max_diff, offset))?;
    let r = stillpoint::trajectory::ate(&gt, &est, &AteOptions { align, matching })
        .map_err(|e| error(&e))?;
    stats(py, &r.stats)
}

/// Relative pose error over pairs `delta` apart (`delta_unit` "f" frames, "m" metres, "s"
/// seconds): translation (metres) and rotation (degrees) parts, evo_rpe's numbers.
#[pyfunction]
#[pyo3(signature = (gt, est, *, delta=1.0, delta_unit="f", align="none", format="tum",
    max_diff=0.01, offset=0.0))]
#[allow(clippy::too_many_arguments)] // Python keyword arguments.
pub fn rpe<'py>(
    py: Python<'py>,
    gt: &Bound<'py, PyAny>,
    est: &Bound<'py, PyAny>,
    delta: f64,
    delta_unit: &str,
    align: &str,
    format: &str,
    max_diff: f64,
    offset: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let (gt, est, align, matching) = pair((gt, est), align, format, (max_diff, offset))?;
    let delta_unit: DeltaUnit = delta_unit
        .parse()
        .map_err(|e: String| PyValueError::new_err(format!("delta_unit: {e}")))?;
    if !(delta.is_finite() && delta > 0.0) {
        return Err(PyValueError::new_err(format!(
            "delta: must be positive, got {delta}"
        )));
    }
    let opts = RpeOptions {
        align,
        matching,
        delta,
        delta_unit,
    };
    let r = stillpoint::trajectory::rpe(&gt, &est, &opts).map_err(|e| error(&e))?;
    let d = PyDict::new(py);
    d.set_item("translation", stats(py, &r.translation)?)?;
    d.set_item("rotation_deg", stats(py, &r.rotation_deg)?)?;
    Ok(d)
}
