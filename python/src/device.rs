//! `placedb.Device`: the device client ([`Session`]) for a board, an
//! emulator or the core in-process (`local:PROFILE`, which
//! `placedb.Selector` uses): configure, push depth frames from numpy
//! arrays, ask whether it is busy, status, finish, export.

use crate::database::{Database, Source};
use crate::errors::{released, Failure};
use numpy::{PyReadonlyArray2, PyUntypedArrayMethods};
use placedb::protocol::DecisionKind;
use placedb::{DepthRange, Intrinsics, Pose, ScanConfig, SelectorConfig, VoxelGrid};
use placedb_host::board::link::Link;
use placedb_host::board::scan::{device_config, StreamOptions};
use placedb_host::board::session::{DepthFrame, Session};
use pyo3::prelude::*;
use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

/// One frame's final decision: its index, "taken", "dominated" or
/// "uncovered", and its class (the database frame it is labelled with).
type Decided = (u32, &'static str, Option<u32>);

/// A placedb device and the one scan this client runs on it.
#[pyclass(frozen, module = "placedb._native")]
pub struct Device {
    session: Mutex<Session<Box<dyn Link>>>,
    /// The configured camera (a scan has one).
    camera: Mutex<Option<Intrinsics>>,
    port: String,
}

/// The words of a device error.
fn failed(e: impl std::error::Error + 'static) -> Failure {
    Failure::of(&e)
}

fn decided((frame, kind): (u32, DecisionKind)) -> Option<Decided> {
    Some(match kind {
        DecisionKind::Taken => (frame, "taken", Some(frame)),
        DecisionKind::DominatedBy(k) => (frame, "dominated", Some(k)),
        DecisionKind::Uncovered(k) => (frame, "uncovered", k),
        DecisionKind::Pending => return None,
    })
}

impl Device {
    fn session(&self) -> MutexGuard<'_, Session<Box<dyn Link>>> {
        // A panic mid-call was reported as an error; the session goes on.
        self.session.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Sends one frame (`unless_busy`: only when the device is not busy):
    /// its index or None, and the decisions that became final.
    fn send(
        &self,
        py: Python<'_>,
        depth: PyReadonlyArray2<'_, u16>,
        pose: PyReadonlyArray2<'_, f64>,
        timestamp: f64,
        unless_busy: bool,
    ) -> PyResult<(Option<u32>, Vec<Decided>)> {
        let Some(k) = *self.camera.lock().unwrap_or_else(|p| p.into_inner()) else {
            return Err(Failure::value("configure the scan before pushing frames").into());
        };
        let (h, w) = (depth.shape()[0], depth.shape()[1]);
        if (w, h) != (usize::from(k.width), usize::from(k.height)) {
            return Err(Failure::value(format!(
                "depth must be {} x {} (height x width, the configured camera), got {h} x {w}",
                k.height, k.width
            ))
            .into());
        }
        if pose.shape() != [4, 4] {
            return Err(Failure::value(format!(
                "pose must be 4 x 4 (camera to world), got {:?}",
                pose.shape()
            ))
            .into());
        }
        let p = pose.as_array();
        let r: [[f32; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| p[[i, j]] as f32));
        let t = [p[[0, 3]] as f32, p[[1, 3]] as f32, p[[2, 3]] as f32];
        let pose = Pose::from_matrix(r, t).map_err(|e| Failure::value(format!("pose: {e}")))?;
        if !timestamp.is_finite() {
            return Err(Failure::value(format!("timestamp {timestamp} is not finite")).into());
        }
        let owned;
        let data: &[u16] = match depth.as_slice() {
            Ok(s) => s,
            Err(_) => {
                owned = depth.as_array().iter().copied().collect::<Vec<u16>>();
                &owned
            }
        };
        let frame = DepthFrame {
            timestamp,
            pose,
            intrinsics: k,
            depth: data,
        };
        released(py, || {
            let mut s = self.session();
            let sent = if unless_busy {
                s.try_push_frame(&frame).map_err(failed)?
            } else {
                Some(s.push_frame(&frame).map_err(failed)?)
            };
            Ok((
                sent,
                s.take_decisions().into_iter().filter_map(decided).collect(),
            ))
        })
    }

    /// Writes the device's export into `out`, as `placedb export -o` does.
    pub fn write_export(&self, py: Python<'_>, out: &std::path::Path) -> PyResult<()> {
        released(py, || {
            self.session().export_to(out).map_err(failed)?;
            Ok(())
        })
    }
}

#[pymethods]
impl Device {
    /// Opens the device on `port`: a serial device ("/dev/ttyACM0"),
    /// "tcp:HOST:PORT" (an emulator) or "local:PROFILE" (the core in
    /// this process).
    #[new]
    #[pyo3(signature = (port, reply_timeout=60.0, new_scan=false))]
    fn new(py: Python<'_>, port: String, reply_timeout: f64, new_scan: bool) -> PyResult<Device> {
        if !(reply_timeout.is_finite() && reply_timeout > 0.0) {
            return Err(Failure::value(format!(
                "reply_timeout must be a number of seconds above 0, got {reply_timeout}"
            ))
            .into());
        }
        let opts = StreamOptions {
            reply_timeout: Duration::from_secs_f64(reply_timeout),
            new_scan,
            ..StreamOptions::default()
        };
        let p = port.clone();
        let session = released(py, move || Session::open(&p, opts).map_err(failed))?;
        Ok(Device {
            session: Mutex::new(session),
            camera: Mutex::new(None),
            port,
        })
    }

    fn __repr__(&self) -> String {
        format!("<placedb.Device {}>", self.port)
    }

    /// Starts a scan (refused, naming what it holds, when the device holds
    /// one and the device was not opened with new_scan=True); with
    /// `profile`, refused unless the device runs that profile.
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (intrinsics, width, height, depth_scale, depth_range, stride, voxel, mu, window, sketch_margin, profile=None))]
    fn configure(
        &self,
        py: Python<'_>,
        intrinsics: (f32, f32, f32, f32),
        width: u16,
        height: u16,
        depth_scale: f32,
        depth_range: (f32, f32),
        stride: u16,
        voxel: f32,
        mu: f32,
        window: u16,
        sketch_margin: f32,
        profile: Option<String>,
    ) -> PyResult<String> {
        let (fx, fy, cx, cy) = intrinsics;
        let k = Intrinsics {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
        };
        let grid = VoxelGrid::new(voxel, [0.0; 3])
            .map_err(|e| Failure::value(format!("voxel {voxel}: {e}")))?;
        let scan = ScanConfig {
            intrinsics: k,
            depth_scale,
            range: DepthRange {
                min: depth_range.0,
                max: depth_range.1,
            },
            stride,
            grid,
        };
        let sel = SelectorConfig {
            mu,
            window,
            sketch_margin,
        };
        // With a profile, the device must run it (as `stream --profile`),
        // so that its results are `select --profile`'s.
        let status = released(py, || {
            let cfg = device_config(&scan, &sel).map_err(failed)?;
            self.session()
                .start(&cfg, profile.as_deref())
                .map_err(failed)
        })?;
        *self.camera.lock().unwrap_or_else(|p| p.into_inner()) = Some(k);
        serde_json::to_string(&status).map_err(|e| Failure::value(e.to_string()).into())
    }

    /// Sends one frame; returns the decisions that became final since the
    /// last call, as (frame, kind, class).
    fn push(
        &self,
        py: Python<'_>,
        depth: PyReadonlyArray2<'_, u16>,
        pose: PyReadonlyArray2<'_, f64>,
        timestamp: f64,
    ) -> PyResult<Vec<Decided>> {
        Ok(self.send(py, depth, pose, timestamp, false)?.1)
    }
    /// Sends the frame unless the device is busy: (its index or None when
    /// skipped, the decisions that became final).
    fn try_push(
        &self,
        py: Python<'_>,
        depth: PyReadonlyArray2<'_, u16>,
        pose: PyReadonlyArray2<'_, f64>,
        timestamp: f64,
    ) -> PyResult<(Option<u32>, Vec<Decided>)> {
        self.send(py, depth, pose, timestamp, true)
    }

    /// Whether a push now would wait for the device (a live program skips
    /// the frame instead); takes the replies that arrived, waiting for none.
    fn busy(&self, py: Python<'_>) -> PyResult<bool> {
        released(py, || self.session().busy().map_err(failed))
    }

    /// The decisions that became final since the last push or call.
    fn take_decisions(&self) -> Vec<Decided> {
        self.session()
            .take_decisions()
            .into_iter()
            .filter_map(decided)
            .collect()
    }

    /// The device's status (JSON text; the Python API parses it).
    fn status_json(&self, py: Python<'_>) -> PyResult<String> {
        let st = released(py, || self.session().status().map_err(failed))?;
        serde_json::to_string(&st).map_err(|e| Failure::value(e.to_string()).into())
    }

    /// Ends the scan: every pending frame is decided. Returns the final
    /// status (JSON text).
    fn finish_json(&self, py: Python<'_>) -> PyResult<String> {
        let st = released(py, || self.session().finish().map_err(failed))?;
        serde_json::to_string(&st).map_err(|e| Failure::value(e.to_string()).into())
    }

    /// Pulls the database and every label from the device.
    fn export(slf: Bound<'_, Self>) -> PyResult<Database> {
        let py = slf.py();
        let device = slf.get();
        let export = released(py, || device.session().export().map_err(failed))?;
        Ok(Database {
            source: Source::Export {
                export: Arc::new(export),
                device: slf.unbind(),
            },
        })
    }

    /// Writes the export into `out` (database.csv, labels.csv,
    /// metrics.json, as `placedb export -o OUT`).
    fn export_to(&self, py: Python<'_>, out: PathBuf) -> PyResult<()> {
        self.write_export(py, &out)
    }
}
