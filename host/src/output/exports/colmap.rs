//! `--colmap DIR`: the database frames as a COLMAP text model with known
//! poses, the reference model that hloc's triangulation starts from:
//!
//! ```text
//! DIR/sparse/0/cameras.txt    one PINHOLE camera: the sequence's intrinsics
//! DIR/sparse/0/images.txt     per database frame: IMAGE_ID QW QX QY QZ TX TY TZ 1 NAME, then an empty line
//! DIR/sparse/0/points3D.txt   no points (comments only)
//! DIR/images/NAME             the frame's JPEG (NNNNNN.jpg, the frame index)
//! DIR/sources.csv             per image: its frame, timestamp and sequence file
//! ```
//!
//! COLMAP's pose is world to camera: `X_cam = R X_world + T`, `R` the
//! Hamilton quaternion `(QW, QX, QY, QZ)`, so the camera centre is
//! `-R^T T`. The sequences' poses are camera to world with the same camera
//! axes (x right, y down, z forward), so `R` is their rotation transposed.
//! COLMAP puts the centre of the top-left pixel at (0.5, 0.5), the
//! sequences' intrinsics at (0, 0): the principal point is shifted by half
//! a pixel.

use super::{image_name, Selection};
use crate::error::OutputError;
use crate::output::DbRow;
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use rayon::prelude::*;
use std::fmt::Write as _;
use std::path::Path;

/// The model's folder inside the export.
pub const MODEL: &str = "sparse/0";

/// Whether `dir` holds a COLMAP export (so that it may be replaced).
pub fn is_export(dir: &Path) -> bool {
    dir.join(MODEL).join("images.txt").is_file()
}

/// COLMAP's world-to-camera `([qw, qx, qy, qz], [tx, ty, tz])` of a
/// camera-to-world pose `[tx ty tz qx qy qz qw]`, with `qw >= 0`.
pub fn world_to_camera(pose: &[f64; 7]) -> ([f64; 4], [f64; 3]) {
    let [tx, ty, tz, qx, qy, qz, qw] = *pose;
    let to_world = UnitQuaternion::from_quaternion(Quaternion::new(qw, qx, qy, qz));
    let to_camera = to_world.inverse();
    let t = -(to_camera * Vector3::new(tx, ty, tz));
    let q = to_camera.quaternion();
    let s = if q.w < 0.0 { -1.0 } else { 1.0 };
    ([s * q.w, s * q.i, s * q.j, s * q.k], [t.x, t.y, t.z])
}

/// Writes the model of `sel`'s database into `dir`; returns the images.
pub fn write(dir: &Path, sel: &Selection) -> Result<usize, OutputError> {
    let model = dir.join(MODEL);
    let images = dir.join("images");
    for d in [&model, &images] {
        std::fs::create_dir_all(d).map_err(OutputError::writing(d))?;
    }
    let k = &sel.seq.camera;
    let (w, h) = sel.seq.size;
    let cameras = format!(
        "# Camera list with one line of data per camera:\n\
         #   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n\
         # Number of cameras: 1\n\
         1 PINHOLE {w} {h} {} {} {} {}\n",
        k.fx,
        k.fy,
        k.cx + 0.5,
        k.cy + 0.5
    );
    let rows = sel.database_rows();
    let mut text = format!(
        "# Image list with two lines of data per image:\n\
         #   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n\
         #   POINTS2D[] as (X, Y, POINT3D_ID)\n\
         # Number of images: {}, mean observations per image: 0\n",
        rows.len()
    );
    for (id, (i, _, pose)) in rows.iter().enumerate() {
        let ([qw, qx, qy, qz], [tx, ty, tz]) = world_to_camera(pose);
        let _ = writeln!(
            text,
            "{} {qw} {qx} {qy} {qz} {tx} {ty} {tz} 1 {}\n",
            id + 1,
            image_name(sel.seq.frames[*i].index)
        );
    }
    let points = "# 3D point list with one line of data per point:\n\
                  #   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n\
                  # Number of points: 0, mean track length: 0\n";
    for (file, body) in [
        ("cameras.txt", cameras.as_str()),
        ("images.txt", text.as_str()),
        ("points3D.txt", points),
    ] {
        let path = model.join(file);
        std::fs::write(&path, body).map_err(OutputError::writing(&path))?;
    }
    rows.par_iter()
        .try_for_each(|&(i, _, _): &DbRow| -> Result<(), OutputError> {
            let bytes = super::image::frame_jpeg(sel.seq, i)?;
            let path = images.join(image_name(sel.seq.frames[i].index));
            std::fs::write(&path, bytes).map_err(OutputError::writing(&path))
        })?;
    let sources = super::sources_csv(rows.iter().map(|&(i, _, _)| {
        let name = image_name(sel.seq.frames[i].index);
        (format!("images/{name}"), sel.seq, i)
    }));
    let path = dir.join(super::SOURCES);
    std::fs::write(&path, sources).map_err(OutputError::writing(&path))?;
    Ok(rows.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn world_to_camera_inverts_the_pose() {
        // 90 degrees about z, camera at (1, 2, 3).
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let pose = [1.0, 2.0, 3.0, 0.0, 0.0, h, h];
        let (q, t) = world_to_camera(&pose);
        let r = UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3]));
        // Centre -R^T T is the camera position.
        let c = -(r.inverse() * Vector3::new(t[0], t[1], t[2]));
        assert!((c - Vector3::new(1.0, 2.0, 3.0)).norm() < 1e-12);
        // World to camera is about z by -90 degrees.
        assert!(
            (q[0] - h).abs() < 1e-12 && (q[3] + h).abs() < 1e-12,
            "{q:?}"
        );
        assert!(q[0] >= 0.0);
    }
}
