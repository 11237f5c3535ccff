//! What a later session must share with the sessions it extends, checked
//! before any work: a mismatch is refused naming both values.

use crate::pipeline::{Solver, SolverParams};
use crate::sessions::extension::Extension;
use crate::voxelize::VoxelConfig;
use placedb::VoxelGrid;
use std::path::Path;

/// The grid every session of `ext` was voxelized on.
pub fn grid_of(ext: &Extension) -> VoxelGrid {
    VoxelGrid {
        voxel_size: ext.config.voxel,
        origin: ext.config.grid_corner,
    }
}

/// The name a grid origin has on the command line and in files.
pub fn origin_name(config: &VoxelConfig) -> String {
    match serde_json::to_value(config.origin) {
        Ok(serde_json::Value::String(s)) => s,
        _ => String::new(),
    }
}

/// Refuses, in words naming both values, a configuration of the new
/// session that differs from the earlier sessions' (read from `from`).
pub fn check_config(
    ext: &Extension,
    from: &Path,
    config: &VoxelConfig,
    mu: f32,
    solver: Solver,
    params: &SolverParams,
) -> Result<(), String> {
    let c = &ext.config;
    let mismatch = |what: &str, ours: String, theirs: String| {
        Err(format!(
            "{what} {ours} does not match the {theirs} of the database in {} (every session of a database has one configuration)",
            from.display()
        ))
    };
    if config.voxel != c.voxel {
        return mismatch(
            "--voxel",
            config.voxel.to_string(),
            format!("voxel {}", c.voxel),
        );
    }
    let origin = origin_name(config);
    if origin != c.grid_origin {
        return mismatch(
            "--grid-origin",
            origin,
            format!("grid origin {}", c.grid_origin),
        );
    }
    if config.stride != c.stride {
        return mismatch(
            "--stride",
            config.stride.to_string(),
            format!("stride {}", c.stride),
        );
    }
    let range = [config.range.min, config.range.max];
    if range != c.depth_range {
        let show = |r: [f32; 2]| format!("{},{}", r[0], r[1]);
        return mismatch(
            "--depth-range",
            show(range),
            format!("depth range {}", show(c.depth_range)),
        );
    }
    if mu != c.mu {
        return mismatch("--mu", mu.to_string(), format!("mu {}", c.mu));
    }
    if solver.name() != c.solver {
        return mismatch(
            "--solver",
            solver.name().to_string(),
            format!("solver {}", c.solver),
        );
    }
    if let (Solver::Online, Some(o)) = (solver, &c.online) {
        if params.profile != o.profile {
            return mismatch(
                "--profile",
                params.profile.clone(),
                format!("profile {}", o.profile),
            );
        }
        if params.window != o.window {
            return mismatch(
                "--window",
                params.window.to_string(),
                format!("window {}", o.window),
            );
        }
        if params.sketch_margin != o.sketch_margin {
            return mismatch(
                "--sketch-margin",
                params.sketch_margin.to_string(),
                format!("sketch margin {}", o.sketch_margin),
            );
        }
    }
    Ok(())
}
