//! `placedb.Sequence`: a recorded sequence opened by the command line's
//! readers (every layout and bag, the same options), or frames handed over
//! as numpy arrays; poses and times at once, depth decoded on demand.

use crate::args::select_args;
use crate::errors::{interruptible, Failure};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray1, PyReadonlyArray3};
use numpy::{PyArrayMethods, PyUntypedArrayMethods};
use placedb_host::read::arrays::{self, Arrays};
use placedb_host::{CameraModel, Sequence as HostSequence};
use pyo3::prelude::*;
use std::sync::Arc;

/// A sequence of depth frames with their poses (camera to world).
#[pyclass(frozen, module = "placedb._native")]
pub struct Sequence {
    /// The frames.
    pub inner: Arc<HostSequence>,
    /// The command-line arguments it was read with (the sequence first),
    /// which `select` on it goes on from.
    #[pyo3(get)]
    pub argv: Vec<String>,
}

/// Opens the sequence `argv` names (`placedb select`'s sequence and
/// reading options).
#[pyfunction]
pub fn read_sequence(py: Python<'_>, argv: Vec<String>) -> PyResult<Sequence> {
    let a = select_args(&argv)?;
    let seq = interruptible(py, move || a.open_sequence().map_err(Failure::from))?;
    Ok(Sequence {
        inner: Arc::new(seq),
        argv,
    })
}

/// A sequence of frames in memory: `depth` (N x H x W, uint16 in
/// `depth_scale` units a metre), `poses` (N x 4 x 4 camera to world),
/// optional `timestamps` (N seconds).
#[pyfunction]
#[pyo3(signature = (depth, poses, intrinsics, depth_scale, timestamps=None, name="arrays".to_string()))]
pub fn sequence_from_arrays(
    depth: PyReadonlyArray3<'_, u16>,
    poses: PyReadonlyArray3<'_, f64>,
    intrinsics: (f64, f64, f64, f64),
    depth_scale: f64,
    timestamps: Option<PyReadonlyArray1<'_, f64>>,
    name: String,
) -> PyResult<Sequence> {
    let (n, h, w) = (depth.shape()[0], depth.shape()[1], depth.shape()[2]);
    let size = (dim(w, "width")?, dim(h, "height")?);
    if poses.shape() != [n, 4, 4] {
        return Err(Failure::value(format!(
            "poses must be {n} x 4 x 4 (one camera-to-world matrix a depth image), got {:?}",
            poses.shape()
        ))
        .into());
    }
    // The one copy of the stack: numpy's memory is the caller's to change.
    let depth = match depth.as_slice() {
        Ok(s) => s.to_vec(),
        Err(_) => depth.as_array().iter().copied().collect(),
    };
    let p = poses.as_array();
    let poses = (0..n)
        .map(|i| std::array::from_fn(|r| std::array::from_fn(|c| p[[i, r, c]])))
        .collect();
    let timestamps = timestamps.map(|t| t.as_array().to_vec());
    let (fx, fy, cx, cy) = intrinsics;
    let seq = arrays::sequence(Arrays {
        name,
        camera: CameraModel { fx, fy, cx, cy },
        depth_scale,
        size,
        depth,
        poses,
        timestamps,
    })
    .map_err(|e| Failure::value(e.to_string()))?;
    Ok(Sequence {
        inner: Arc::new(seq),
        argv: vec!["<arrays>".to_string()],
    })
}

/// An image dimension as the core holds it.
fn dim(n: usize, what: &str) -> Result<u16, Failure> {
    u16::try_from(n).ok().filter(|&n| n > 0).ok_or_else(|| {
        Failure::value(format!(
            "the depth images' {what} must be 1 to 65535, got {n}"
        ))
    })
}

#[pymethods]
impl Sequence {
    fn __len__(&self) -> usize {
        self.inner.frames.len()
    }

    fn __repr__(&self) -> String {
        let s = &self.inner;
        format!(
            "<placedb.Sequence {:?}: {} frames of {}x{}>",
            s.name,
            s.frames.len(),
            s.size.0,
            s.size.1
        )
    }

    /// The sequence's name (its directory's, or the bag's).
    #[getter]
    fn name(&self) -> String {
        self.inner.name.clone()
    }

    /// The layout it was read from ("tum", "7scenes", "ros2", ...).
    #[getter]
    fn format(&self) -> String {
        serde_json::to_value(self.inner.format)
            .ok()
            .and_then(|v| v.as_str().map(str::to_string))
            .unwrap_or_default()
    }

    /// Pinhole intrinsics (fx, fy, cx, cy), pixels.
    #[getter]
    fn intrinsics(&self) -> (f64, f64, f64, f64) {
        let k = self.inner.camera;
        (k.fx, k.fy, k.cx, k.cy)
    }

    /// Width of every depth image, pixels.
    #[getter]
    fn width(&self) -> u16 {
        self.inner.size.0
    }

    /// Height of every depth image, pixels.
    #[getter]
    fn height(&self) -> u16 {
        self.inner.size.1
    }

    /// Depth units a metre (TUM 5000, 7-Scenes 1000).
    #[getter]
    fn depth_scale(&self) -> f64 {
        self.inner.depth_scale
    }

    /// Frames of the source the reader skipped (a depth image without a pose).
    #[getter]
    fn frames_skipped(&self) -> usize {
        self.inner.frames_skipped
    }

    /// Every frame's time, seconds (N, float64).
    #[getter]
    fn timestamps<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let t: Vec<f64> = self.inner.frames.iter().map(|f| f.timestamp).collect();
        t.into_pyarray(py)
    }

    /// Every frame's camera-to-world pose (N x 4 x 4, float64).
    #[getter]
    fn poses<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<f64>>> {
        let frames = &self.inner.frames;
        let mut m = Vec::with_capacity(frames.len() * 16);
        for f in frames {
            let [qx, qy, qz, qw] = f.rotation;
            let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                qw, qx, qy, qz,
            ));
            let r = q.to_rotation_matrix();
            for row in 0..3 {
                for col in 0..3 {
                    m.push(r[(row, col)]);
                }
                m.push(f.translation[row]);
            }
            m.extend([0.0, 0.0, 0.0, 1.0]);
        }
        m.into_pyarray(py).reshape([frames.len(), 4, 4])
    }

    /// Frame `i`'s depth image (H x W): uint16 as recorded, or with
    /// `metres=True` float32 metres (0 where there is no measurement).
    #[pyo3(signature = (i, metres=false))]
    fn depth<'py>(&self, py: Python<'py>, i: isize, metres: bool) -> PyResult<PyObject> {
        let n = self.inner.frames.len();
        let at = if i < 0 { i + n as isize } else { i };
        let Some(at) = usize::try_from(at).ok().filter(|&k| k < n) else {
            return Err(pyo3::exceptions::PyIndexError::new_err(format!(
                "frame {i} is not in the sequence's {n} frames"
            )));
        };
        let seq = Arc::clone(&self.inner);
        let img = py
            .allow_threads(move || seq.depth(at))
            .map_err(|e| Failure::of(&e))?;
        let shape = [img.height as usize, img.width as usize];
        if metres {
            let scale = self.inner.depth_scale;
            let m: Vec<f32> = img
                .data
                .iter()
                .map(|&d| (d as f64 / scale) as f32)
                .collect();
            Ok(m.into_pyarray(py).reshape(shape)?.into_any().unbind())
        } else {
            let a: Bound<'py, PyArray2<u16>> = img.data.into_pyarray(py).reshape(shape)?;
            Ok(a.into_any().unbind())
        }
    }
}
