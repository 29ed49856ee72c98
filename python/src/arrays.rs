//! numpy arrays in, the pipeline's images out, and back: each check names the argument and what
//! it expected.

use numpy::{
    PyArray1, PyArray2, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArray,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use stillpoint::geometry::Se3;
use stillpoint::image::{DepthMetres, Gray8, ImageBuf, Rgb8};

/// What `obj` is, for an error message: a numpy array's dtype and shape, else its type.
fn describe(obj: &Bound<'_, PyAny>) -> String {
    match obj.cast::<PyUntypedArray>() {
        Ok(a) => format!("a {} array of shape {:?}", a.dtype(), a.shape()),
        Err(_) => obj
            .get_type()
            .name()
            .map_or_else(|_| "an object".into(), |n| n.to_string()),
    }
}

/// The array's elements in row-major order: borrowed where it is C-contiguous, else copied.
fn row_major<T: numpy::Element + Copy>(a: &PyReadonlyArrayDyn<'_, T>) -> Vec<T> {
    match a.as_slice() {
        Ok(s) => s.to_vec(),
        Err(_) => a.as_array().iter().copied().collect(),
    }
}

/// An 8-bit image: `(height, width, 3)` RGB or `(height, width)` gray, the camera's size.
/// Returns the gray image and, for colour, the RGB one.
pub fn image_u8(
    name: &str,
    obj: &Bound<'_, PyAny>,
    size: (usize, usize),
) -> PyResult<(Gray8, Option<Rgb8>)> {
    let (w, h) = size;
    let expected = || {
        PyValueError::new_err(format!(
            "{name}: expected a uint8 array of shape ({h}, {w}, 3) or ({h}, {w}), got {}",
            describe(obj)
        ))
    };
    let arr = obj
        .cast::<PyArrayDyn<u8>>()
        .map_err(|_| expected())?
        .try_readonly()
        .map_err(|e| PyValueError::new_err(format!("{name}: {e}")))?;
    match arr.shape() {
        [hh, ww, 3] if (*hh, *ww) == (h, w) => {
            // One copy, straight into the pipeline's pixel layout.
            let mut rgb = vec![[0u8; 3]; w * h];
            match arr.as_slice() {
                Ok(s) => rgb.as_flattened_mut().copy_from_slice(s),
                Err(_) => rgb
                    .as_flattened_mut()
                    .iter_mut()
                    .zip(arr.as_array().iter())
                    .for_each(|(d, s)| *d = *s),
            }
            let rgb = ImageBuf::from_vec(w, h, rgb).map_err(|_| expected())?;
            Ok((stillpoint::image::rgb_to_gray(&rgb), Some(rgb)))
        }
        [hh, ww] if (*hh, *ww) == (h, w) => {
            let gray = ImageBuf::from_vec(w, h, row_major(&arr)).map_err(|_| expected())?;
            Ok((gray, None))
        }
        _ => Err(expected()),
    }
}

/// A depth image of the camera's size: `uint16` in units of `1 / depth_scale` metres (TUM:
/// 5000 a metre), or `float32` metres; 0 (or not finite) is no measurement.
pub fn depth(
    obj: &Bound<'_, PyAny>,
    size: (usize, usize),
    depth_scale: f32,
) -> PyResult<DepthMetres> {
    let (w, h) = size;
    let expected = || {
        PyValueError::new_err(format!(
            "depth: expected a uint16 (units of 1/depth_scale m) or float32 (metres) array of \
             shape ({h}, {w}), got {}",
            describe(obj)
        ))
    };
    let check = |shape: &[usize]| (shape == [h, w]).then_some(()).ok_or_else(expected);
    if let Ok(a) = obj.cast::<PyArrayDyn<u16>>() {
        let a = a
            .try_readonly()
            .map_err(|e| PyValueError::new_err(format!("depth: {e}")))?;
        check(a.shape())?;
        // The same division as the dataset readers' (read_depth_metres): equal metres.
        let data = row_major(&a)
            .into_iter()
            .map(|d| d as f32 / depth_scale)
            .collect();
        return ImageBuf::from_vec(w, h, data).map_err(|_| expected());
    }
    if let Ok(a) = obj.cast::<PyArrayDyn<f32>>() {
        let a = a
            .try_readonly()
            .map_err(|e| PyValueError::new_err(format!("depth: {e}")))?;
        check(a.shape())?;
        return ImageBuf::from_vec(w, h, row_major(&a)).map_err(|_| expected());
    }
    Err(expected())
}

/// A camera-to-world pose as a 4x4 float64 matrix.
pub fn pose_matrix<'py>(py: Python<'py>, p: &Se3) -> Bound<'py, PyArray2<f64>> {
    let m = p.to_homogeneous();
    let rows: Vec<Vec<f64>> = (0..4)
        .map(|r| (0..4).map(|c| m[(r, c)]).collect())
        .collect();
    PyArray2::from_vec2(py, &rows).expect("4 rows of 4")
}

/// A TUM row: `t tx ty tz qx qy qz qw`.
pub fn tum_row(t: f64, p: &Se3) -> [f64; 8] {
    let q = p.rotation.coords;
    let v = p.translation.vector;
    [t, v.x, v.y, v.z, q.x, q.y, q.z, q.w]
}

/// Rows of equal length as a 2-D float64 array (shape `(0, width)` when empty).
pub fn table<'py, const W: usize>(py: Python<'py>, rows: &[[f64; W]]) -> Bound<'py, PyArray2<f64>> {
    let flat: Vec<f64> = rows.iter().flatten().copied().collect();
    PyArray1::from_vec(py, flat)
        .reshape([rows.len(), W])
        .expect("rows x width elements")
}

/// The Gray8 image as a `(height, width)` uint8 array.
pub fn gray_array<'py>(py: Python<'py>, g: &Gray8) -> Bound<'py, PyArray2<u8>> {
    PyArray1::from_slice(py, &g.data)
        .reshape([g.height, g.width])
        .expect("height x width pixels")
}

/// The Rgb8 image as a `(height, width, 3)` uint8 array.
pub fn rgb_array<'py>(py: Python<'py>, c: &Rgb8) -> Bound<'py, PyArrayDyn<u8>> {
    let flat: Vec<u8> = c.data.iter().flatten().copied().collect();
    PyArray1::from_vec(py, flat)
        .reshape(vec![c.height, c.width, 3])
        .expect("height x width x 3 values")
}

/// The depth image as a `(height, width)` float32 array of metres.
pub fn depth_array<'py>(py: Python<'py>, d: &DepthMetres) -> Bound<'py, PyArray2<f32>> {
    PyArray1::from_slice(py, &d.data)
        .reshape([d.height, d.width])
        .expect("height x width pixels")
}
