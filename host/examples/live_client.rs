//! A robot-side program streaming live depth frames to a placedb device
//! through the client API (`placedb_host::board::session`): open the port,
//! configure the scan once, push each frame from memory as the camera
//! delivers it, react to decisions as they arrive, finish, export.
//!
//! ```sh
//! cargo run --release -p placedb-host --example live_client              # in-process device
//! cargo run --release -p placedb-host --example live_client -- tcp:127.0.0.1:4321 out/live
//! ```
//!
//! The frames here come from the built-in synthetic office renderer so the
//! example runs anywhere; a robot replaces `camera_frames` with its driver
//! (e.g. a ROS 2 node's `sensor_msgs/Image` callback: 16UC1 data is the
//! `u16` buffer as it is, with `depth_scale` 1000) and its localisation.

use placedb_host::board::scan::StreamOptions;
use placedb_host::board::session::{DepthFrame, Session};
use placedb_host::synth::{self, SynthConfig};
use std::path::PathBuf;

type Error = Box<dyn std::error::Error>;

fn main() -> Result<(), Error> {
    let mut args = std::env::args().skip(1);
    let port = args.next().unwrap_or_else(|| "local:ram512k".into());
    let out = PathBuf::from(args.next().unwrap_or_else(|| "out/live".into()));

    // The camera: its intrinsics (CameraInfo's k) and depth units.
    let cam = synth::sequence(&SynthConfig::demo());
    let intrinsics = cam.intrinsics();
    let scan = placedb::ScanConfig {
        intrinsics,
        depth_scale: cam.depth_scale as f32,
        range: placedb::DepthRange {
            min: 0.1,
            max: 10.0,
        },
        // Every 8th pixel in u and v: what a USB full-speed link carries live.
        stride: 8,
        grid: placedb::VoxelGrid::new(0.3, [0.0; 3]).map_err(|e| format!("{e:?}"))?,
    };
    let sel = placedb::SelectorConfig {
        mu: 0.3,
        window: 16,
        sketch_margin: 0.05,
    };

    let mut session = Session::open(&port, StreamOptions::default())?;
    session.configure(&scan, &sel)?;
    for (timestamp, pose, depth) in camera_frames(&cam, 60) {
        session.push_frame(&DepthFrame {
            timestamp,
            pose,
            intrinsics,
            depth: &depth,
        })?;
        report(&mut session);
    }
    // Finish decides the frames still held in the device's window.
    let status = session.finish()?;
    report(&mut session);
    println!(
        "{} frames seen, {} database frames",
        status.frames_seen, status.database_size
    );
    let export = session.export_to(&out)?;
    println!(
        "wrote {}/{{database.csv,labels.csv,metrics.json}}: {} records",
        out.display(),
        export.records.len()
    );
    Ok(())
}

/// What the robot does with decisions as they arrive (here: print the frames
/// that join the database).
fn report<L: placedb_host::board::link::Link>(session: &mut Session<L>) {
    for (frame, decision) in session.take_decisions() {
        if decision == placedb::protocol::DecisionKind::Taken {
            println!("frame {frame} joins the database");
        }
    }
}

/// Stand-in for the robot's camera and localisation: `n` frames as
/// (timestamp, camera-to-world pose, depth buffer).
fn camera_frames(
    cam: &placedb_host::Sequence,
    n: usize,
) -> impl Iterator<Item = (f64, placedb::Pose, Vec<u16>)> + '_ {
    cam.frames.iter().take(n).enumerate().filter_map(|(i, f)| {
        let depth = cam.depth(i).ok()?.data;
        Some((f.timestamp, f.pose().ok()?, depth))
    })
}
