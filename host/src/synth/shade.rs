//! A simple colour picture from a depth image alone, so the TUM layout has its
//! `rgb/` images: surface normals from neighbouring back-projected pixels,
//! Lambert shading with the light at the camera, distance fall-off, and a tint
//! by the normal's world direction (floor, ceiling, walls along x, along y).

use super::render::rotation_matrix;
use crate::sequence::{CameraModel, DepthImage};

/// Interleaved 8-bit RGB of `depth` seen with `camera` and camera-to-world
/// `rotation`; black where there is no depth.
pub fn shade(
    depth: &DepthImage,
    camera: &CameraModel,
    depth_scale: f64,
    rotation: [f64; 4],
) -> Vec<u8> {
    let (w, h) = (depth.width as usize, depth.height as usize);
    let r = rotation_matrix(rotation);
    let point = |u: usize, v: usize| -> Option<[f64; 3]> {
        let raw = depth.data[v * w + u];
        (raw != 0).then(|| {
            let z = raw as f64 / depth_scale;
            [
                (u as f64 - camera.cx) * z / camera.fx,
                (v as f64 - camera.cy) * z / camera.fy,
                z,
            ]
        })
    };
    let mut rgb = vec![0u8; w * h * 3];
    for v in 0..h {
        for u in 0..w {
            let Some(p) = point(u, v) else { continue };
            // A neighbour on the same surface: within 3 % of the depth.
            let near = |q: Option<[f64; 3]>| q.filter(|q| (q[2] - p[2]).abs() < 0.03 * p[2]);
            let du = near((u + 1 < w).then(|| point(u + 1, v)).flatten())
                .map(|q| sub(q, p))
                .or_else(|| near((u > 0).then(|| point(u - 1, v)).flatten()).map(|q| sub(p, q)));
            let dv = near((v + 1 < h).then(|| point(u, v + 1)).flatten())
                .map(|q| sub(q, p))
                .or_else(|| near((v > 0).then(|| point(u, v - 1)).flatten()).map(|q| sub(p, q)));
            let dist = dot(p, p).sqrt();
            let view = p.map(|c| -c / dist);
            let mut n = match (du, dv) {
                (Some(a), Some(b)) => cross(a, b),
                _ => view,
            };
            let len = dot(n, n).sqrt();
            n = if len > 0.0 { n.map(|c| c / len) } else { view };
            if dot(n, view) < 0.0 {
                n = n.map(|c| -c);
            }
            let nw = [0, 1, 2].map(|i| r[i][0] * n[0] + r[i][1] * n[1] + r[i][2] * n[2]);
            let tint: [f64; 3] = if nw[2] > 0.7 {
                [150.0, 120.0, 90.0]
            } else if nw[2] < -0.7 {
                [235.0, 235.0, 228.0]
            } else if nw[0].abs() > nw[1].abs() {
                [205.0, 190.0, 165.0]
            } else {
                [165.0, 185.0, 205.0]
            };
            let light = (0.3 + 0.7 * dot(n, view)) / (1.0 + 0.08 * dist);
            let px = &mut rgb[(v * w + u) * 3..(v * w + u) * 3 + 3];
            for (out, t) in px.iter_mut().zip(tint) {
                *out = (t * light).round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    rgb
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
