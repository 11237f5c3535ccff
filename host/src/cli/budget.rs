//! `placedb budget`: each device capacity profile, its exact state size and
//! what it holds.

use crate::error::CommandError as Error;

/// Runs `placedb budget`: one row a capacity profile.
pub fn run() -> Result<(), Error> {
    println!(
        "{:<8} {:>6} {:>10} {:>10} {:>9} {:>12} {:>9} {:>5} {:>6} {:>8} {:>6}",
        "profile",
        "ram",
        "selector",
        "device",
        "headroom",
        "frame_voxels",
        "pool_keys",
        "db",
        "window",
        "resident",
        "sketch"
    );
    for p in placedb::profile::PROFILES {
        println!(
            "{:<8} {:>5}K {:>9}B {:>9}B {:>8}K {:>12} {:>9} {:>5} {:>6} {:>8} {:>6}",
            p.name,
            p.ram / 1024,
            p.state_bytes,
            p.device_bytes,
            (p.ram as i64 - p.device_bytes as i64) / 1024,
            p.frame_voxel_slots - p.frame_voxel_slots / 4,
            p.pool_words,
            p.database_frames,
            p.window,
            p.resident,
            p.sketch
        );
    }
    println!("selector = the online core alone; device = selector + receive and reply buffers (what a board holds)");
    println!("db = database frames indexed in RAM (24 B each; the frames and every label live in the flash log); resident = database frames held whole in RAM");
    println!("headroom = ram - device, for the stack and the board's own buffers");
    Ok(())
}
