//! Does a frame cost more against a bigger database? `placedb bench
//! --db-scaling` streams a synthetic building through the device state
//! machine on a simulated flash log, keeps the flash as it was when the
//! database first held [`SMALL_DB`] frames and at the end of the scan (before
//! Finish), then counts with callgrind the instructions of one and the same
//! probe frame (FrameBegin, its rows, FrameEnd: protocol decoding, voxelizing,
//! the overlaps read back from flash, the selection step, the log writes)
//! decided by a device restored from each flash. Restored database frames
//! all live in flash, so both counts include reading every nearby stored
//! frame back: the worst case for the bigger database.

use crate::board::scan;
use crate::frame_rows::{row_chunks, sampled_rows, RowChunk};
use crate::synth::{self, SynthConfig};
use crate::VoxelConfig;
use placedb::device::Device256K;
use placedb::persist::{sim::SimFlash, Log};
use placedb::protocol::{depth_rows_per_message, encode, HostFrame, HostMessage, MAX_FRAME_LEN};
use placedb::{Pose, SelectorConfig};
use std::path::Path;

/// Database frames of the small case.
pub const SMALL_DB: u32 = 10;
/// Overlap threshold of the scan (the largest databases).
pub const MU: f32 = 0.5;
/// Sectors of the flash log (1 MiB, the boards' region).
const SECTORS: usize = 256;

/// One frame as wire messages (FrameBegin, DepthRows…, FrameEnd) for frame
/// number `index`, without sequence numbers.
struct Probe {
    timestamp: f64,
    pose: Pose,
    rows: Vec<RowChunk>,
}

fn encode_frame(seq: &mut u32, msg: HostMessage<'_>, out: &mut Vec<u8>) {
    *seq += 1;
    let mut buf = vec![0u8; MAX_FRAME_LEN];
    let frame = encode(&HostFrame { seq: *seq, msg }, &mut buf).expect("encodes");
    out.extend_from_slice(frame);
}

impl Probe {
    fn bytes(&self, index: u32, seq: &mut u32) -> Vec<u8> {
        let mut out = Vec::new();
        let begin = HostMessage::FrameBegin {
            frame: index,
            timestamp: self.timestamp,
            pose: self.pose,
        };
        encode_frame(seq, begin, &mut out);
        for rows in &self.rows {
            encode_frame(seq, rows.message(index), &mut out);
        }
        encode_frame(seq, HostMessage::FrameEnd { frame: index }, &mut out);
        out
    }
}

/// The building at its scan settings: the sequence and the device's Hello.
struct Building {
    seq: crate::Sequence,
    cfg: placedb::protocol::Config,
}

impl Building {
    /// The synthetic building of `frames` frames (one room per 500, at least
    /// 2), 160x120, stride 1, on the ram256k profile's window at [`MU`].
    fn new(frames: usize) -> Result<Building, String> {
        let seq = synth::sequence(&SynthConfig {
            frames,
            width: 160,
            height: 120,
            seed: 1,
            rooms: (frames / 500).max(2),
        });
        let scan = scan::scan_config(&seq, &VoxelConfig::default()).map_err(|e| e.to_string())?;
        let window = placedb::profile::by_name("ram256k").map_or(16, |p| p.window as u16);
        let sel = SelectorConfig {
            mu: MU,
            window,
            sketch_margin: 0.05,
        };
        let cfg = scan::device_config(&scan, &sel).map_err(|e| e.to_string())?;
        Ok(Building { seq, cfg })
    }

    /// Frame `i` as the host sends it.
    fn frame(&self, i: usize) -> Result<Probe, String> {
        let per_msg = usize::from(depth_rows_per_message(self.cfg.width_sent()));
        let img = self.seq.depth(i).map_err(|e| e.to_string())?;
        let (w, values) = sampled_rows(&img, self.cfg.stride);
        let rows = row_chunks(w, &values, per_msg).collect();
        Ok(Probe {
            timestamp: self.seq.frames[i].timestamp,
            pose: self.seq.frames[i]
                .pose()
                .map_err(|e| format!("frame {i}: pose: {e}"))?,
            rows,
        })
    }

    /// The probe: a frame from the middle of the walk, where the building
    /// around it has its database frames.
    fn probe(&self) -> Result<Probe, String> {
        self.frame(self.seq.frames.len() / 2)
    }
}

/// Streams the building of `frames` frames; writes `small.flash` and
/// `big.flash` into `dir`; returns the two database sizes.
pub fn prepare(dir: &Path, frames: usize) -> Result<(u32, u32), String> {
    let building = Building::new(frames)?;
    let mut device = Box::new(Device256K::new());
    let end = (SECTORS * SimFlash::SECTOR) as u32;
    let mut log = Log::open(SimFlash::new(SECTORS), 0, end)
        .map_err(|e| format!("the simulated flash log does not open: {e}"))?;
    let mut seq_no = 0;
    let mut hello = Vec::new();
    encode_frame(&mut seq_no, HostMessage::Hello(building.cfg), &mut hello);
    device.receive_logged(&hello, &mut log, &mut |_| {});
    let mut small = None;
    for i in 0..frames {
        let bytes = building.frame(i)?.bytes(i as u32, &mut seq_no);
        device.receive_logged(&bytes, &mut log, &mut |_| {});
        let db = device.status().database_size;
        if small.is_none() && db >= SMALL_DB {
            small = Some(db);
            std::fs::write(dir.join("small.flash"), log.flash().bytes())
                .map_err(|e| e.to_string())?;
        }
    }
    let big = device.status().database_size;
    std::fs::write(dir.join("big.flash"), log.flash().bytes()).map_err(|e| e.to_string())?;
    Ok((small.unwrap_or(big), big))
}

/// The measured part: the probe frame's messages through the device. Kept
/// out of line so that callgrind counts it alone (`--toggle-collect`).
#[inline(never)]
pub fn probe_step(device: &mut Device256K, log: &mut Log<SimFlash>, bytes: &[u8]) -> usize {
    let mut replies = 0;
    device.receive_logged(bytes, log, &mut |_| replies += 1);
    replies
}

/// Child process: restores a device from `flash` (written by [`prepare`]
/// for a building of `frames` frames) and decides the probe frame, rendered
/// again here (the building is deterministic).
pub fn run_probe(flash: &Path, frames: usize) -> Result<(), String> {
    let name = flash.display();
    let bytes =
        std::fs::read(flash).map_err(|e| format!("{name}: {}", crate::error::io_words(&e)))?;
    // Whole sectors, or the copy below would not fit the flash.
    if bytes.len() % SimFlash::SECTOR != 0 {
        return Err(format!(
            "{name}: {} bytes, not a flash image of whole {}-byte sectors",
            bytes.len(),
            SimFlash::SECTOR
        ));
    }
    let mut sim = SimFlash::new(bytes.len() / SimFlash::SECTOR);
    sim.bytes_mut().copy_from_slice(&bytes);
    let end = u32::try_from(bytes.len())
        .map_err(|_| format!("{name}: {} bytes, more than a flash log spans", bytes.len()))?;
    let mut log =
        Log::open(sim, 0, end).map_err(|e| format!("{name}: not a flash log image: {e}"))?;
    let mut device = Box::new(Device256K::new());
    let records = device
        .restore(&mut log)
        .map_err(|e| format!("{name}: the device restores no scan from it: {e}"))?;
    // An erased or foreign image restores nothing: the probe frame would
    // meet an unconfigured device and count nothing worth reporting.
    if records == 0 {
        return Err(format!(
            "{name}: no scan in this flash log (give an image `bench --db-scaling` wrote)"
        ));
    }
    let st = device.status();
    let p = Building::new(frames)?.probe()?;
    let bytes = p.bytes(st.frames_seen, &mut 1000);
    let replies = probe_step(&mut device, &mut log, &bytes);
    let after = device.status();
    println!(
        "database {} frames ({} resident), {} replies, frames seen {}",
        after.database_size,
        after
            .capacity(placedb::protocol::CapacitySlot::Resident)
            .used,
        replies,
        after.frames_seen
    );
    Ok(())
}
