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

use crate::device_cli;
use crate::online::sampled_rows;
use crate::synth::{self, SynthConfig};
use crate::VoxelConfig;
use placedb::device::Device256K;
use placedb::persist::{sim::SimFlash, Log};
use placedb::protocol::{
    depth_rows_per_message, encode, DepthRows, HostFrame, HostMessage, MAX_FRAME_LEN,
};
use placedb::{Pose, SelectorConfig};
use std::path::Path;

/// Database frames of the small case.
pub const SMALL_DB: u32 = 10;
/// Sectors of the flash log (1 MiB, the boards' region).
const SECTORS: usize = 256;

/// One frame as wire messages (FrameBegin, DepthRows…, FrameEnd) for frame
/// number `index`, without sequence numbers.
struct Probe {
    timestamp: f64,
    pose: Pose,
    rows: Vec<(u16, u16, Vec<u8>)>,
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
        for (first_row, row_count, data) in &self.rows {
            let rows = DepthRows {
                frame: index,
                first_row: *first_row,
                row_count: *row_count,
                data,
            };
            encode_frame(seq, HostMessage::DepthRows(rows), &mut out);
        }
        encode_frame(seq, HostMessage::FrameEnd { frame: index }, &mut out);
        out
    }
}

/// Streams the building at `mu`; writes `small.flash`, `big.flash` and
/// `probe.bin` (the probe frame's messages for each) into `dir`; returns the
/// two database sizes.
pub fn prepare(dir: &Path, frames: usize, rooms: usize, mu: f32) -> Result<(u32, u32), String> {
    let seq = synth::sequence(&SynthConfig {
        frames,
        width: 160,
        height: 120,
        seed: 1,
        rooms,
    });
    let scan = device_cli::scan_config(&seq, &VoxelConfig::default()).map_err(|e| e.to_string())?;
    let window = placedb::profile::by_name("ram256k").map_or(16, |p| p.window as u16);
    let sel = SelectorConfig {
        mu,
        window,
        sketch_margin: 0.05,
    };
    let cfg = device_cli::device_config(&scan, &sel).map_err(|e| e.to_string())?;
    let per_msg = usize::from(depth_rows_per_message(cfg.width_sent()));
    let frame = |i: usize| -> Result<Probe, String> {
        let img = seq.depth(i).map_err(|e| e.to_string())?;
        let (w, values) = sampled_rows(&img, cfg.stride);
        let rows = values
            .chunks(w * per_msg)
            .enumerate()
            .map(|(k, c)| {
                let data = c.iter().flat_map(|d| d.to_le_bytes()).collect();
                ((k * per_msg) as u16, (c.len() / w) as u16, data)
            })
            .collect();
        Ok(Probe {
            timestamp: seq.frames[i].timestamp,
            pose: seq.frames[i].pose().map_err(|e| format!("{e:?}"))?,
            rows,
        })
    };
    let mut device = Box::new(Device256K::new());
    let end = (SECTORS * SimFlash::SECTOR) as u32;
    let mut log = Log::open(SimFlash::new(SECTORS), 0, end).map_err(|e| format!("{e:?}"))?;
    let mut seq_no = 0;
    let mut hello = Vec::new();
    encode_frame(&mut seq_no, HostMessage::Hello(cfg), &mut hello);
    device.receive_logged(&hello, &mut log, &mut |_| {});
    let mut small = None;
    for i in 0..frames {
        let bytes = frame(i)?.bytes(i as u32, &mut seq_no);
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
    // The probe: a frame from the middle of the walk, where the building
    // around it has its database frames.
    let probe = frame(frames / 2)?;
    std::fs::write(dir.join("probe.bin"), probe_file(&probe)).map_err(|e| e.to_string())?;
    Ok((small.unwrap_or(big), big))
}

/// The probe frame as a file: timestamp, pose, then each row chunk.
fn probe_file(p: &Probe) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend(p.timestamp.to_le_bytes());
    for v in p.pose.translation.iter().chain(&p.pose.rotation) {
        out.extend(v.to_le_bytes());
    }
    for (first, count, data) in &p.rows {
        out.extend(first.to_le_bytes());
        out.extend(count.to_le_bytes());
        out.extend((data.len() as u32).to_le_bytes());
        out.extend(data);
    }
    out
}

fn read_probe(bytes: &[u8]) -> Option<Probe> {
    let f64_at = |b: &[u8]| {
        b.get(..8)
            .and_then(|b| b.try_into().ok())
            .map(f64::from_le_bytes)
    };
    let f32_at = |b: &[u8]| {
        b.get(..4)
            .and_then(|b| b.try_into().ok())
            .map(f32::from_le_bytes)
    };
    let timestamp = f64_at(bytes)?;
    let mut rest = bytes.get(8..)?;
    let mut v = [0f32; 7];
    for x in v.iter_mut() {
        *x = f32_at(rest)?;
        rest = rest.get(4..)?;
    }
    let pose = Pose {
        translation: [v[0], v[1], v[2]],
        rotation: [v[3], v[4], v[5], v[6]],
    };
    let mut rows = Vec::new();
    while !rest.is_empty() {
        let first = u16::from_le_bytes(rest.get(..2)?.try_into().ok()?);
        let count = u16::from_le_bytes(rest.get(2..4)?.try_into().ok()?);
        let len = u32::from_le_bytes(rest.get(4..8)?.try_into().ok()?) as usize;
        rows.push((first, count, rest.get(8..8 + len)?.to_vec()));
        rest = rest.get(8 + len..)?;
    }
    Some(Probe {
        timestamp,
        pose,
        rows,
    })
}

/// The measured part: the probe frame's messages through the device. Kept
/// out of line so that callgrind counts it alone (`--toggle-collect`).
#[inline(never)]
pub fn probe_step(device: &mut Device256K, log: &mut Log<SimFlash>, bytes: &[u8]) -> usize {
    let mut replies = 0;
    device.receive_logged(bytes, log, &mut |_| replies += 1);
    replies
}

/// Child process: restores a device from `flash` and decides the probe.
pub fn run_probe(flash: &Path, probe: &Path) -> Result<(), String> {
    let bytes = std::fs::read(flash).map_err(|e| e.to_string())?;
    let mut sim = SimFlash::new(bytes.len() / SimFlash::SECTOR);
    sim.bytes_mut().copy_from_slice(&bytes);
    let end = bytes.len() as u32;
    let mut log = Log::open(sim, 0, end).map_err(|e| format!("{e:?}"))?;
    let mut device = Box::new(Device256K::new());
    device.restore(&mut log).map_err(|e| format!("{e:?}"))?;
    let st = device.status();
    let p =
        read_probe(&std::fs::read(probe).map_err(|e| e.to_string())?).ok_or("bad probe file")?;
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
