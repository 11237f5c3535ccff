//! The emulated Pico for the tests of its flash (host/tests/board_rp2040_flash.rs):
//! booting it with a flash timing and a power cut, streaming and exporting
//! through the host library, and reading the harness's exit lines.

use placedb::SelectorConfig;
use placedb_host::board::client::Client;
use placedb_host::board::emulator::rp2040::{Rp2040, Rp2040Options};
use placedb_host::board::export::ExportOptions;
use placedb_host::board::flash_timing::FlashTiming;
use placedb_host::board::link::Link;
use placedb_host::board::scan::StreamOptions;
use placedb_host::board::scan::StreamReport;
use placedb_host::board::{export, scan};
use placedb_host::testing::rp2040_firmware as firmware;
use placedb_host::{Sequence, VoxelConfig};
use std::path::Path;
use std::time::Duration;

/// The Pico's memory profile.
pub const PROFILE: &str = "ram256k";

/// Where the power goes, if it does.
#[derive(Debug, Clone, Copy)]
pub enum Cut {
    /// It does not.
    Never,
    /// In the middle of the firmware's `n`-th sector erase (from 1).
    DuringErase(u32),
    /// In the middle of the `n`-th page the firmware programs (from 1).
    DuringProgram(u32),
}

impl Cut {
    /// What the harness prints when it cuts.
    pub fn message(self) -> &'static str {
        match self {
            Cut::Never => "",
            Cut::DuringErase(_) => "power cut during the erase",
            Cut::DuringProgram(_) => "power cut during the program",
        }
    }
}

/// The emulated Pico at flash timing `timing`, on the flash file `flash`
/// (a fresh erased flash if `None`), losing power at `cut`.
pub fn boot(flash: Option<&Path>, timing: FlashTiming, cut: Cut) -> Rp2040 {
    boot_with_bus_resets(flash, timing, cut, &[])
}

/// [`boot`], with the host resetting the bus once it has handed the
/// firmware each FrameEnd numbered in `bus_reset_after_frames` (from 1).
pub fn boot_with_bus_resets(
    flash: Option<&Path>,
    timing: FlashTiming,
    cut: Cut,
    bus_reset_after_frames: &[u32],
) -> Rp2040 {
    let options = Rp2040Options {
        bus_reset_after_frames: bus_reset_after_frames.to_vec(),
        flash: flash.map(Path::to_path_buf),
        deadline: Duration::from_secs(300),
        flash_timing: timing,
        cut_during_erase: match cut {
            Cut::DuringErase(n) => Some(n),
            _ => None,
        },
        cut_during_program: match cut {
            Cut::DuringProgram(n) => Some(n),
            _ => None,
        },
        ..Rp2040Options::default()
    };
    Rp2040::start_with(&firmware(), &options).unwrap_or_else(|e| panic!("{e}"))
}

/// `database.csv` and `labels.csv` of everything the board holds.
pub fn export_csv<L: Link>(client: &mut Client<L>) -> (String, String) {
    export::export(
        client,
        Vec::new(),
        &ExportOptions::default(),
        None,
        &mut |_| Ok(()),
    )
    .unwrap_or_else(|e| panic!("export failed: {e}"))
    .csv()
}

/// Streams `seq` with `opts`; panics saying why if the host gave up.
pub fn stream<L: Link>(
    client: &mut Client<L>,
    seq: &Sequence,
    vcfg: &VoxelConfig,
    sel: SelectorConfig,
    opts: &StreamOptions,
) -> StreamReport {
    let scan = scan::scan_config(seq, vcfg).unwrap();
    let cfg = scan::device_config(&scan, &sel).unwrap();
    scan::stream(client, seq, &cfg, PROFILE, opts, None)
        .unwrap_or_else(|e| panic!("stream of {} failed: {e}", seq.name))
}

/// The harness's exit line of frame answer latencies ("latency frames=N
/// median_us=M worst_us=W answers_after_erase=K ...").
#[derive(Debug, Clone, Copy)]
pub struct Latency {
    /// Frame answers measured.
    pub frames: u64,
    /// Their median, microseconds of emulated time.
    pub median_us: u64,
    /// Their worst.
    pub worst_us: u64,
    /// Answers that left after a sector erase that ended after the frame's
    /// last DepthRows was handed over.
    pub waited: u64,
}

/// Field `name` of the harness's exit line that starts with `line` ("stats",
/// "latency"), as a number.
pub fn exit_field(console: &str, line: &str, name: &str) -> u64 {
    let line = console
        .lines()
        .find(|l| l.starts_with(line) && l[line.len()..].starts_with(' '))
        .unwrap_or_else(|| panic!("no {line} line: {console}"));
    line.split_whitespace()
        .find_map(|w| w.strip_prefix(name)?.strip_prefix('=')?.parse().ok())
        .unwrap_or_else(|| panic!("no {name} in {line}"))
}

/// The latency line of `console`.
pub fn latency(console: &str) -> Latency {
    let field = |name| exit_field(console, "latency", name);
    Latency {
        frames: field("frames"),
        median_us: field("median_us"),
        worst_us: field("worst_us"),
        waited: field("answers_after_erase"),
    }
}
