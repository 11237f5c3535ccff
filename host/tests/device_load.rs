//! Load: a long synthetic scan streamed through the device core at full
//! speed, in-process: every frame is encoded as wire frames (FrameBegin,
//! DepthRows, FrameEnd, with CRC and COBS) and handed to
//! `placedb::device::Device512K::receive` (the `ram512k` profile the QEMU
//! board runs), exactly as a board's transport would.
//!
//! Checks that memory stays constant: the core never touches the heap (no
//! allocation at all inside `receive`, counted by this binary's allocator),
//! every capacity's use and high-water mark (where it keeps one apart from
//! its use) is within its limit, and the process's
//! peak RSS does not grow between a quarter of the scan and its end. Prints
//! the core's frame rate and every high-water mark.
//!
//! The 20,000-frame scan (the size of the paper's largest sequence) runs in
//! release builds (`cargo test -p placedb-host --release --test device_load -- --nocapture`, about
//! 10 s) and is ignored in debug builds; a 4,000-frame version always runs.

use placedb::device::Device512K;
use placedb::protocol::{
    depth_rows_per_message, encode, CapacitySlot, Config, DepthRows, DeviceMessage, Feed,
    FrameDecoder, HostFrame, HostMessage, Status, MAX_FRAME_LEN, MAX_REPLY_LEN,
};
use placedb::SelectorConfig;
use placedb_host::board::scan;
use placedb_host::frame_rows::sampled_rows;
use placedb_host::synth::{self, SynthConfig};
use placedb_host::VoxelConfig;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::mpsc;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Counts the allocations of the current thread.
struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        System.alloc(layout)
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        System.alloc_zeroed(layout)
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> u64 {
    ALLOCATIONS.with(Cell::get)
}

/// One load test at a time: RSS is per process.
static SERIAL: Mutex<()> = Mutex::new(());

/// `VmRSS` (resident set now) of this process, bytes. (`VmHWM` is not used:
/// the kernel updates it lazily, so it can lag behind the real peak.) Panics
/// where `/proc/self/status` has none: a zero would pass the RSS check.
fn rss() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status")
        .expect("the RSS check reads /proc/self/status (Linux)");
    let kb = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        .expect("VmRSS in /proc/self/status");
    assert!(kb > 0, "VmRSS of 0 kB");
    kb * 1024
}

/// What a load run measured.
struct Load {
    frames: usize,
    /// Time inside `Device::receive` only.
    core: Duration,
    wall: Duration,
    /// Allocations made inside `Device::receive` (must be 0).
    core_allocations: u64,
    /// Error replies (must be 0).
    errors: u64,
    decisions: u64,
    status: Status,
    /// Largest RSS sampled (every 100 frames) up to the checkpoint, and after it.
    rss_checkpoint: u64,
    rss_end: u64,
}

/// Streams a `frames`-frame synthetic scan (80x60, stride 1, 8 rooms)
/// through a `Device512K`; RSS is sampled every 100 frames, its peak
/// reported up to `checkpoint` frames and after.
fn load(frames: usize, checkpoint: usize) -> Load {
    let synth_cfg = SynthConfig {
        frames,
        width: 80,
        height: 60,
        rooms: 8,
        ..SynthConfig::default()
    };
    let seq = synth::sequence(&synth_cfg);
    let vcfg = VoxelConfig {
        stride: 1,
        ..VoxelConfig::default()
    };
    let scan = scan::scan_config(&seq, &vcfg).unwrap();
    let sel = SelectorConfig {
        mu: 0.3,
        window: 32,
        sketch_margin: 0.05,
    };
    let cfg: Config = scan::device_config(&scan, &sel).unwrap();
    let width = cfg.width_sent();
    let rows_per_msg = usize::from(depth_rows_per_message(width));
    let started = Instant::now();

    // Frames are rendered on another thread, a few ahead (constant memory).
    let (tx, rx) = mpsc::sync_channel(8);
    let poses: Vec<_> = seq
        .frames
        .iter()
        .map(|f| (f.timestamp, f.pose().unwrap()))
        .collect();
    let renderer = std::thread::spawn(move || {
        for i in 0..seq.frames.len() {
            let img = seq.depth(i).unwrap();
            let (w, rows) = sampled_rows(&img, 1);
            let bytes: Vec<u8> = rows.iter().flat_map(|d| d.to_le_bytes()).collect();
            if tx.send((w, bytes)).is_err() {
                return;
            }
        }
    });

    // The device is large: build and run it on a thread with a big stack.
    std::thread::Builder::new()
        .stack_size(64 << 20)
        .spawn(move || {
            let mut device = Box::new(Device512K::new());
            let mut buf = vec![0u8; MAX_FRAME_LEN];
            let mut decoder = Box::new(FrameDecoder::<MAX_REPLY_LEN>::new());
            let (mut errors, mut decisions) = (0u64, 0u64);
            let mut core = Duration::ZERO;
            let mut core_allocations = 0;
            let (mut rss_checkpoint, mut rss_end) = (0, 0);
            let mut seq_no = 0u32;
            let mut feed = |msg: HostMessage<'_>,
                            device: &mut Device512K,
                            core: &mut Duration,
                            allocs: &mut u64| {
                seq_no += 1;
                let frame = encode(&HostFrame { seq: seq_no, msg }, &mut buf).unwrap();
                let (a0, t0) = (allocations(), Instant::now());
                device.receive(frame, &mut |reply: &[u8]| {
                    if let Feed::Frame { result, .. } = decoder.feed::<DeviceMessage>(reply) {
                        match result {
                            Ok(DeviceMessage::Decision { .. }) => decisions += 1,
                            Ok(DeviceMessage::Error { .. }) | Err(_) => errors += 1,
                            Ok(_) => {}
                        }
                    }
                });
                *core += t0.elapsed();
                *allocs += allocations() - a0;
            };
            feed(
                HostMessage::Hello(cfg),
                &mut device,
                &mut core,
                &mut core_allocations,
            );
            for (i, (timestamp, pose)) in poses.iter().copied().enumerate() {
                let (w, bytes) = rx.recv().unwrap();
                assert_eq!(w, usize::from(width));
                let frame = i as u32;
                feed(
                    HostMessage::FrameBegin {
                        frame,
                        timestamp,
                        pose,
                    },
                    &mut device,
                    &mut core,
                    &mut core_allocations,
                );
                for (k, chunk) in bytes.chunks(w * 2 * rows_per_msg).enumerate() {
                    let msg = HostMessage::DepthRows(DepthRows {
                        frame,
                        first_row: (k * rows_per_msg) as u16,
                        row_count: (chunk.len() / (w * 2)) as u16,
                        data: chunk,
                    });
                    feed(msg, &mut device, &mut core, &mut core_allocations);
                }
                feed(
                    HostMessage::FrameEnd { frame },
                    &mut device,
                    &mut core,
                    &mut core_allocations,
                );
                if (i + 1) % 100 == 0 || i + 1 == checkpoint {
                    let now = rss();
                    if i < checkpoint {
                        rss_checkpoint = rss_checkpoint.max(now);
                    } else {
                        rss_end = rss_end.max(now);
                    }
                }
            }
            feed(
                HostMessage::Finish,
                &mut device,
                &mut core,
                &mut core_allocations,
            );
            renderer.join().unwrap();
            Load {
                frames,
                core,
                wall: started.elapsed(),
                core_allocations,
                errors,
                decisions,
                status: device.status(),
                rss_checkpoint,
                rss_end: rss_end.max(rss()),
            }
        })
        .unwrap()
        .join()
        .unwrap()
}

/// Whether a slot's `peak` is a high-water mark apart from `used` (labels
/// and flash bytes never shrink within a scan: there `peak` is `used`).
fn tracks_peak(slot: CapacitySlot) -> bool {
    !matches!(slot, CapacitySlot::Labels | CapacitySlot::Flash)
}

/// Prints the figures and checks the invariants.
fn report_and_check(l: &Load) {
    let st = &l.status;
    println!(
        "load: {} frames (80x60, stride 1) through Device512K::receive: core {:.2} s = {:.0} frames/s \
         ({:.1} us/frame); wall {:.1} s (rendering included); {} decisions sent",
        l.frames,
        l.core.as_secs_f64(),
        l.frames as f64 / l.core.as_secs_f64(),
        1e6 * l.core.as_secs_f64() / l.frames as f64,
        l.wall.as_secs_f64(),
        l.decisions
    );
    // Labels and flash bytes only grow within a scan: their `peak` is `used`
    // by definition (src/device/mod.rs), not a high-water mark of its own.
    println!("  capacity      used      peak     limit");
    for slot in CapacitySlot::ALL {
        let c = st.capacity(slot);
        let peak = if tracks_peak(slot) {
            c.peak.to_string()
        } else {
            "-".into()
        };
        println!(
            "  {:<12} {:>6} {:>9} {:>9}",
            slot.name(),
            c.used,
            peak,
            c.limit
        );
    }
    println!(
        "  frames seen {}, decided {}, database {}, sketched {}, truncated {}, uncovered {}, \
         labels dropped {}, degradation flags {:#x}, refused {}",
        st.frames_seen,
        st.frames_decided,
        st.database_size,
        st.sketched_frames,
        st.truncated_frames,
        st.uncovered_frames,
        st.labels_dropped,
        st.degradation,
        st.refused
    );
    println!(
        "  heap allocations inside the core: {}; device state {} B (static, no heap); \
         peak RSS {} kB over frames 1..{}, {} kB over the rest up to {}",
        l.core_allocations,
        std::mem::size_of::<Device512K>(),
        l.rss_checkpoint / 1024,
        l.frames / 4,
        l.rss_end / 1024,
        l.frames
    );
    assert_eq!(l.errors, 0, "the device refused messages");
    assert_eq!(l.core_allocations, 0, "the core allocated on the heap");
    assert_eq!(st.frames_seen as usize, l.frames);
    assert_eq!(st.frames_decided as usize, l.frames);
    assert_eq!(st.refused, 0);
    for slot in CapacitySlot::ALL {
        let c = st.capacity(slot);
        assert!(c.used <= c.limit, "{}: {c:?}", slot.name());
        if tracks_peak(slot) {
            assert!(
                c.used <= c.peak && c.peak <= c.limit,
                "{}: {c:?}",
                slot.name()
            );
        } else {
            assert_eq!(c.peak, c.used, "{}", slot.name());
        }
    }
    // The scan filled the window and the frame voxel set at some point: the
    // high-water marks are above what is in use at the end.
    assert_eq!(st.capacity(CapacitySlot::Window).used, 0);
    assert!(st.capacity(CapacitySlot::Window).peak > 0);
    assert!(l.rss_checkpoint > 0 && l.rss_end > 0);
    // Labels beyond the store are dropped and counted, never overflow.
    let labels = st.capacity(CapacitySlot::Labels);
    assert_eq!(
        u64::from(labels.used) + u64::from(st.labels_dropped),
        l.frames as u64
    );
    // Peak RSS may not grow with frames: the last 3/4 of the scan add at most
    // 4 MiB (keeping 300 bytes per frame would add 4.5 MB over 15,000 frames).
    let grew = l.rss_end.saturating_sub(l.rss_checkpoint);
    assert!(
        grew <= 4 << 20,
        "peak RSS grew by {:.1} MB after the checkpoint",
        grew as f64 / 1e6
    );
}

#[test]
fn load_4000_frames_keeps_memory_constant() {
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let l = load(4000, 1000);
    report_and_check(&l);
}

/// About 10 s optimised (the README's test command); an unoptimised build
/// takes many times longer. Not gated on `debug_assertions`: the test
/// profile has them on and must still run this.
#[test]
fn load_20000_frames_keeps_memory_constant() {
    let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let l = load(20_000, 5_000);
    report_and_check(&l);
}
