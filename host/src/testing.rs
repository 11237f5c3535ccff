//! What the tests share (`tests/`, `host/tests/` and the unit tests), in one
//! place: the recorded samples in `../shared/data`, the synthetic office cut
//! short, the stride and selector of the device tests, the emulators'
//! firmware built first, the two CSVs of the host replay that a device's
//! export must equal, and an MCAP file rewritten with compressed chunks.
//! Behind the `testing` feature (as the core's `sim-flash`): no command uses
//! it.

use crate::board::emulator::{qemu, rp2040};
use crate::board::scan::scan_config;
use crate::output;
use crate::read::{self, ReadOptions};
use crate::replay;
use crate::synth::{self, SynthConfig};
use crate::{Sequence, VoxelConfig};
use placedb::SelectorConfig;
use std::path::PathBuf;

/// The recorded sample `name` (`7scenes-1000`, `vprdb-test-db`) in
/// `../shared/data`; panics saying so if it is missing.
pub fn data(name: &str) -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data")
        .join(name);
    assert!(
        p.exists(),
        "sample {} is missing: the tests read ../shared/data",
        p.display()
    );
    p
}

/// The recorded sample `name`, read with the default options, its first
/// `frames` frames.
pub fn sample(name: &str, frames: usize) -> Sequence {
    let mut seq = read::open(&data(name), &ReadOptions::default())
        .unwrap_or_else(|e| panic!("sample {name}: {e}"));
    seq.frames.truncate(frames);
    seq
}

/// The first `frames` frames of the synthetic office scan (`--demo`).
pub fn demo(frames: usize) -> Sequence {
    let mut seq = synth::sequence(&SynthConfig::demo());
    seq.frames.truncate(frames);
    seq
}

/// The default voxel configuration at pixel stride `stride` (the device
/// tests stream at stride 8).
pub fn voxel_config(stride: u16) -> VoxelConfig {
    VoxelConfig {
        stride,
        ..VoxelConfig::default()
    }
}

/// The selector of the device tests: mu 0.3, a sketch margin of 0.05, and
/// `window` frames held undecided.
pub fn selector(window: u16) -> SelectorConfig {
    SelectorConfig {
        mu: 0.3,
        window,
        sketch_margin: 0.05,
    }
}

/// The QEMU board's firmware, built first (see
/// [`qemu::built_firmware`]); panics saying why it is missing.
pub fn qemu_firmware() -> PathBuf {
    qemu::built_firmware().unwrap_or_else(|e| panic!("{e}"))
}

/// The Pico's firmware, built first (see [`rp2040::built_firmware`]);
/// panics saying why it is missing.
pub fn rp2040_firmware() -> PathBuf {
    rp2040::built_firmware().unwrap_or_else(|e| panic!("{e}"))
}

/// The Pico's fault-injection firmware, built first (see
/// [`rp2040::built_fault_firmware`]); panics saying why it is missing.
pub fn rp2040_fault_firmware() -> PathBuf {
    rp2040::built_fault_firmware().unwrap_or_else(|e| panic!("{e}"))
}

/// `database.csv` and `labels.csv` of `placedb select --solver online
/// --profile PROFILE`: the host replay of the core with the same profile
/// and configuration, which a device's export must equal byte for byte.
pub fn replay_csv(
    profile: &str,
    seq: &Sequence,
    vcfg: &VoxelConfig,
    sel: SelectorConfig,
) -> (String, String) {
    let scan = scan_config(seq, vcfg).unwrap_or_else(|e| panic!("scan config: {e}"));
    let run =
        replay::replay(seq, profile, scan, sel, 8, None).unwrap_or_else(|e| panic!("replay: {e}"));
    let timestamps: Vec<f64> = seq.frames.iter().map(|f| f.timestamp).collect();
    output::run_csv(&run.database, &timestamps, &run.labels)
}

/// Rewrites the MCAP file `input` as `output` with its chunks compressed by
/// `compression` (`None`: plain), as a rosbag2 storage preset (`zstd_fast`,
/// `zstd_small`) records them, through the `mcap` crate's writer: every
/// message with its channel, schema, sequence and times. Returns how many
/// messages it wrote.
pub fn mcap_recompress(
    input: &std::path::Path,
    output: &std::path::Path,
    compression: Option<mcap::Compression>,
) -> Result<usize, Box<dyn std::error::Error>> {
    let bytes = std::fs::read(input)?;
    let out = std::io::BufWriter::new(std::fs::File::create(output)?);
    let mut writer = mcap::WriteOptions::new()
        .compression(compression)
        .profile("ros2")
        .create(out)?;
    // Channels by their id in the input: the id each has in the output.
    let mut channels = std::collections::BTreeMap::new();
    let mut n = 0;
    for message in mcap::MessageStream::new(&bytes)? {
        let message = message?;
        let channel = &message.channel;
        let id = match channels.get(&channel.id) {
            Some(&id) => id,
            None => {
                let schema = match &channel.schema {
                    Some(s) => writer.add_schema(&s.name, &s.encoding, &s.data)?,
                    None => 0,
                };
                let id = writer.add_channel(
                    schema,
                    &channel.topic,
                    &channel.message_encoding,
                    &channel.metadata,
                )?;
                channels.insert(channel.id, id);
                id
            }
        };
        let header = mcap::records::MessageHeader {
            channel_id: id,
            sequence: message.sequence,
            log_time: message.log_time,
            publish_time: message.publish_time,
        };
        writer.write_to_known_channel(&header, &message.data)?;
        n += 1;
    }
    writer.finish()?;
    Ok(n)
}
