//! Power cuts on the host: a device writing its scan to a simulated NOR
//! flash (`placedb::persist::sim::SimFlash`) loses power at every single
//! erase and write step of a full run, reboots, restores from the log, and
//! finishes the scan.
//!
//! What is proven, for every cut point of a full run ([`FRAMES`] = 120
//! synthetic frames at stride 8 on the `ram512k` profile, a flash of 64
//! sectors of 4 KiB): step `k` of the run (each of its `N` erases and
//! writes) is the last one before the power goes, torn before it, half way
//! through it, or after it ([`Tear`]): `3 N` cut points, plus a second cut
//! at a later step of the resumed run for every 3rd step. After each cut the
//! host keeps only what it saw (a device without power sends nothing); a new
//! device opens the log on the same flash and restores, and:
//!
//! - every final decision the host received is in the restored export, with
//!   the same class; every frame it received as `Taken` is a database record
//!   with the pose and timestamp the host sent; an acknowledged Hello is in
//!   force and an acknowledged Finish is still finished;
//! - nothing corrupt comes back: the restore succeeds, the export decodes
//!   and its count and CRC check, labels are frames `0..frames_decided` in
//!   order with their own timestamps, every class is a database frame,
//!   database frames are distinct and carry their own pose and timestamp;
//!   the restored state is a prefix of what the device held in RAM when the
//!   power went (labels a prefix, database a subset) and, for a first cut, of
//!   the uninterrupted run; every restored database frame is the class of a
//!   restored label (a frame taken for a decision the log does not hold is
//!   not restored, so a scan that ends right after the restore exports no
//!   database frame that no label names);
//! - the log loses no completed write: the records restored grow by at most
//!   one per step, a torn step adds none, and a cut after the last step
//!   restores every record;
//! - the scan continues: the host sends the same Hello again (a no-op on a
//!   restored scan), the frames from `status.frames_seen`, and Finish; then
//!   every frame has a label, every class is a database frame, and a further
//!   reboot restores exactly what the device exports (the flash still works);
//! - the resumed scan's export is byte-identical to the uninterrupted run's,
//!   after every cut and every second cut (every key is kept in this run: the
//!   restored state is exactly the state at the last durable decision), and
//!   the key budget it counts, restored again at the final reboot, is the
//!   uninterrupted run's to the byte (key chunks written before a cut and
//!   again after it count once).
//!
//! The uninterrupted run with a log sends exactly the decisions and exports
//! exactly the records of a device without journal (`receive`).
//!
//! Counts (printed with `--nocapture`): the full run writes 86 records in
//! 5 sectors in 91 flash steps, so 273 cut points plus 92 second cuts:
//! 365 cuts and as many restores. The whole file runs in about 7 s in
//! the checked profile on 2 cores.
//!
//! Also here, on a small device and small flashes: generations rotating
//! around the end of a 8-sector range ([`generations_rotate_around_the_range`]),
//! a torn start of a new generation ([`a_torn_start_is_never_a_mix`]), a
//! full log ([`a_full_log_refuses_frame_end_and_changes_nothing`]), a flash
//! that stops working ([`a_failing_flash_degrades_and_restores_a_prefix`]),
//! and a new scan started after a restore that had brought back a database
//! frame of the old one before its first decision
//! ([`a_new_scan_after_a_restore_holds_nothing_of_the_old_one`]; this test
//! found that bug).
//! No sleeps, no clocks.

use placedb::device::harness::{durable_part, on_big_stack, AnyDevice, Harness};
use placedb::device::{Device, Device512K, RestoreFailure};
use placedb::persist::sim::{SimFlash, Tear};
use placedb::protocol::{
    degradation, depth_rows_per_message, Config, DecisionKind, DeviceMessage, ErrorKind,
    ExportRecord, HostMessage, Phase, RecordKind, Status,
};
use placedb::{Pose, SelectorConfig};
use placedb_host::frame_rows::{row_chunks, RowChunk};
use placedb_host::synth::{self, SynthConfig};
use placedb_host::{board::scan, VoxelConfig};
use std::collections::{BTreeMap, BTreeSet};
use std::ops::{Deref, DerefMut};
use std::sync::atomic::Ordering;
use std::sync::Arc;

/// Frames of the full run.
const FRAMES: usize = 120;
/// Sectors of the flash of the full run.
const SECTORS: usize = 64;
/// Every how many cut points the resumed run is cut again.
const DOUBLE_EVERY: u64 = 3;
const TEARS: [Tear; 3] = [Tear::Before, Tear::Half, Tear::After];

/// The device of the full run: a board profile.
type Big = Device512K;
/// A small device for the focused tests: window 8, sketches of 16 hashes
/// (log records of at most 180 bytes), 64 database frames, all resident.
type Small = Device<4096, 16384, 64, 8, 16, 512>;

// ---------------------------------------------------------------- the scan

/// One frame as the host sends it.
struct Frame {
    timestamp: f64,
    pose: Pose,
    /// Its DepthRows payloads.
    rows: Vec<RowChunk>,
}

/// A scan: its Hello and its frames, cut into messages once.
struct Scan {
    cfg: Config,
    frames: Vec<Frame>,
}

impl Scan {
    /// Frames `skip..skip + frames` of the demo route (sampled 4 times more
    /// sparsely than the demo, so that more frames join the database) at
    /// stride 8, as frames 0, 1, 2, … of a scan with selection window
    /// `window`.
    fn synthetic(skip: usize, frames: usize, window: u16) -> Scan {
        Scan::route(150, skip, frames, window, 0.3)
    }

    /// Frames `skip..skip + frames` of the demo route walked in `route`
    /// frames, at stride 8, selected with `window` and `mu`.
    fn route(route: usize, skip: usize, frames: usize, window: u16, mu: f32) -> Scan {
        Scan::strided(route, skip, frames, (window, mu), (8, 0.3))
    }

    /// [`Scan::route`] at `stride` and `voxel` metres (`selection`: window
    /// and mu).
    fn strided(
        route: usize,
        skip: usize,
        frames: usize,
        (window, mu): (u16, f32),
        (stride, voxel): (u16, f32),
    ) -> Scan {
        let synth = SynthConfig {
            frames: route,
            ..SynthConfig::demo()
        };
        let seq = synth::sequence(&synth);
        assert!(skip + frames <= seq.frames.len());
        let vcfg = VoxelConfig {
            stride,
            voxel,
            ..VoxelConfig::default()
        };
        let scan = scan::scan_config(&seq, &vcfg).unwrap();
        let sel = SelectorConfig {
            mu,
            window,
            sketch_margin: 0.05,
        };
        let cfg = scan::device_config(&scan, &sel).unwrap();
        let per_msg = usize::from(depth_rows_per_message(cfg.width_sent()));
        let frames = (skip..skip + frames)
            .map(|i| {
                let img = seq.depth(i).unwrap();
                let (w, values) = placedb_host::frame_rows::sampled_rows(&img, cfg.stride);
                assert_eq!(w, usize::from(cfg.width_sent()));
                let rows = row_chunks(w, &values, per_msg).collect();
                Frame {
                    timestamp: seq.frames[i].timestamp,
                    pose: seq.frames[i].pose().unwrap(),
                    rows,
                }
            })
            .collect();
        Scan { cfg, frames }
    }

    fn len(&self) -> u32 {
        self.frames.len() as u32
    }
}

// ------------------------------------------------------ the device and rig

/// The shared harness, with power: the host hears the device only while it
/// has power (the harness is silent while the flash's power is off), or
/// always after [`Rig::listen_always`]; and it can look at a device without
/// power (its RAM, and its flash as the power left it).
struct Rig<D>(Harness<D>);

impl<D> Deref for Rig<D> {
    type Target = Harness<D>;

    fn deref(&self) -> &Harness<D> {
        &self.0
    }
}

impl<D> DerefMut for Rig<D> {
    fn deref_mut(&mut self) -> &mut Harness<D> {
        &mut self.0
    }
}

impl<D: AnyDevice> Rig<D> {
    /// A device without flash (`receive`, no journal).
    fn without_flash() -> Self {
        Rig(Harness::without_flash())
    }

    /// Power on: a new device (all state as after power-on), the log opened
    /// on `flash`, and the scan restored from it. The host hears the device
    /// while it has power.
    fn boot(flash: SimFlash) -> (Self, Result<u32, RestoreFailure>) {
        let (mut harness, restored) = Harness::boot(flash);
        harness.silent_while = Some(harness.flash().power());
        (Rig(harness), restored)
    }

    /// Power off for good: the flash as the power left it.
    fn into_flash(self) -> SimFlash {
        self.0.into_flash()
    }

    /// The host hears every reply: the flash fails, but the device itself
    /// still runs.
    fn listen_always(&mut self) {
        self.silent_while = None;
    }

    fn is_off(&mut self) -> bool {
        self.log
            .as_mut()
            .is_some_and(|log| log.flash().inner().is_off())
    }

    /// The device's status (changes nothing; also from a device whose power
    /// is off, to look at its RAM).
    fn status(&mut self) -> Status {
        let silent = self.silent_while.take();
        let status = self.0.status();
        self.silent_while = silent;
        status
    }

    /// The whole export, checked by the harness (changes nothing; also from
    /// a device whose power is off, to look at what it held: its RAM, and
    /// the labels in its flash as the power left it).
    fn export(&mut self) -> Vec<ExportRecord> {
        let silent = self.silent_while.take();
        let power = self.log.as_mut().map(|log| log.flash().inner().power());
        let off = power
            .as_ref()
            .is_some_and(|power| power.swap(false, Ordering::Relaxed));
        let records = self.0.export();
        if let Some(power) = power {
            power.store(off, Ordering::Relaxed);
        }
        self.silent_while = silent;
        records
    }
}

// ------------------------------------------------------------ the host side

/// What the host saw acknowledged, over every boot of one scan.
#[derive(Debug, Default, Clone)]
struct Seen {
    /// Final decisions received, by frame.
    finals: BTreeMap<u32, DecisionKind>,
    /// Every decision received, in order (Pending included).
    decisions: Vec<(u32, DecisionKind)>,
    hello: bool,
    /// Finish was sent (acknowledged or not).
    finish_sent: bool,
    finish: bool,
}

impl Seen {
    fn note(&mut self, replies: &[DeviceMessage], ctx: &str) {
        for r in replies {
            if let DeviceMessage::Decision { frame, kind } = *r {
                self.decisions.push((frame, kind));
                if kind != DecisionKind::Pending {
                    let before = self.finals.insert(frame, kind);
                    assert!(
                        before.is_none(),
                        "{ctx}: frame {frame} decided twice: {before:?}, then {kind:?}"
                    );
                }
            }
        }
    }
}

/// Sends one message of a scan; `false` when the power went while the device
/// handled it (the host stops there).
fn step<D: AnyDevice>(rig: &mut Rig<D>, msg: HostMessage<'_>, seen: &mut Seen, ctx: &str) -> bool {
    let replies = rig.send(msg);
    seen.note(&replies, ctx);
    if !rig.hears() {
        return false;
    }
    assert_eq!(
        replies.last(),
        Some(&DeviceMessage::Ack { seq: rig.seq }),
        "{ctx}: {msg:?} not acknowledged"
    );
    true
}

/// Streams frame `i` of `scan`; `false` when the power went.
fn send_frame<D: AnyDevice>(
    rig: &mut Rig<D>,
    scan: &Scan,
    i: u32,
    seen: &mut Seen,
    ctx: &str,
) -> bool {
    let f = &scan.frames[i as usize];
    let begin = HostMessage::FrameBegin {
        frame: i,
        timestamp: f.timestamp,
        pose: f.pose,
    };
    if !step(rig, begin, seen, ctx) {
        return false;
    }
    for rows in &f.rows {
        if !step(rig, rows.message(i), seen, ctx) {
            return false;
        }
    }
    step(rig, HostMessage::FrameEnd { frame: i }, seen, ctx)
}

/// The host's run, as after any boot: Hello (the same again on a restored
/// scan), the frames from `status.frames_seen`, Finish. `true` when it got
/// to the end, `false` when the power went.
fn drive<D: AnyDevice>(rig: &mut Rig<D>, scan: &Scan, seen: &mut Seen, ctx: &str) -> bool {
    drive_to(rig, scan, scan.len(), true, seen, ctx)
}

/// [`drive`] up to frame `end` (excluded), then Finish if `finish`.
fn drive_to<D: AnyDevice>(
    rig: &mut Rig<D>,
    scan: &Scan,
    end: u32,
    finish: bool,
    seen: &mut Seen,
    ctx: &str,
) -> bool {
    let st = rig.status();
    let from = st.frames_seen;
    if !step(rig, HostMessage::Hello(scan.cfg), seen, ctx) {
        return false;
    }
    seen.hello = true;
    if st.phase == Phase::Finished {
        // (The board may erase its next sector ahead while idle after it.)
        assert_eq!(
            rig.status().stored_records,
            st.stored_records,
            "{ctx}: Hello again is not a no-op"
        );
    }
    if from > 0 || st.phase == Phase::Finished {
        // A scan restored unfinished logs its resume (one record), once.
        let logged = rig.status().stored_records - st.stored_records;
        assert!(logged <= 1, "{ctx}: Hello again wrote {logged} records");
        assert_eq!(rig.status().frames_seen, from, "{ctx}: Hello again");
    }
    for i in from..end {
        if !send_frame(rig, scan, i, seen, ctx) {
            return false;
        }
    }
    if !finish {
        return true;
    }
    seen.finish_sent = true;
    if !step(rig, HostMessage::Finish, seen, ctx) {
        return false;
    }
    seen.finish = true;
    true
}

// ----------------------------------------------------------------- checks

/// An export split into its database (by frame) and its labels (classes).
#[derive(Debug, Clone, PartialEq)]
struct Parsed {
    db: BTreeMap<u32, ExportRecord>,
    classes: Vec<u32>,
}

/// Checks that an export is well formed for `scan` (nothing corrupt): the
/// database first, frames distinct and increasing with their own pose and
/// timestamp; then labels of frames 0, 1, 2, … with their own timestamps,
/// every class a database frame.
fn parse(export: &[ExportRecord], scan: &Scan, ctx: &str) -> Parsed {
    let mut db = BTreeMap::new();
    let mut classes = Vec::new();
    for r in export {
        match r.kind {
            RecordKind::Database { pose } => {
                assert!(classes.is_empty(), "{ctx}: database record after labels");
                assert!(
                    db.keys().next_back().is_none_or(|&last| r.frame > last),
                    "{ctx}: database frames not distinct and increasing: {r:?}"
                );
                let f = scan
                    .frames
                    .get(r.frame as usize)
                    .unwrap_or_else(|| panic!("{ctx}: database frame {} not sent", r.frame));
                assert_eq!(pose, f.pose, "{ctx}: pose of database frame {}", r.frame);
                assert_eq!(r.timestamp, f.timestamp, "{ctx}: timestamp of {}", r.frame);
                db.insert(r.frame, *r);
            }
            RecordKind::Label { class } => {
                let j = classes.len() as u32;
                assert_eq!(r.frame, j, "{ctx}: labels out of order");
                let f = scan
                    .frames
                    .get(j as usize)
                    .unwrap_or_else(|| panic!("{ctx}: label of frame {j} not sent"));
                assert_eq!(r.timestamp, f.timestamp, "{ctx}: timestamp of label {j}");
                assert!(
                    db.contains_key(&class),
                    "{ctx}: label {j} has class {class}, not a database frame"
                );
                classes.push(class);
            }
            // This scan has one session (sessions: host/tests/device_sessions.rs).
            RecordKind::Session { .. } => panic!("{ctx}: a session record: {r:?}"),
        }
    }
    Parsed { db, classes }
}

/// `part` is what `whole` held at some point: labels a prefix, database a
/// subset (records identical). `slack` labels more are allowed: a batch of
/// decisions whose write landed as the power went, unacknowledged (the
/// device's export counts only the batches it saw written).
fn assert_prefix(part: &Parsed, whole: &Parsed, slack: usize, what: &str, ctx: &str) {
    let common = part.classes.len().min(whole.classes.len());
    assert!(
        part.classes.len() <= whole.classes.len() + slack
            && part.classes[..common] == whole.classes[..common],
        "{ctx}: restored labels are not a prefix of {what}:\n{:?}\n{:?}",
        part.classes,
        whole.classes
    );
    for (f, r) in &part.db {
        let mut r = *r;
        let w = whole.db.get(f).map(|w| {
            r.record = w.record;
            *w
        });
        assert_eq!(
            Some(r),
            w,
            "{ctx}: restored database frame {f} is not in {what}"
        );
    }
}

/// Every final decision the host received is in the export, same class;
/// every frame received as Taken is a database frame.
fn assert_acknowledged(got: &Parsed, seen: &Seen, ctx: &str) {
    for (&f, &kind) in &seen.finals {
        let class = kind.class(f).unwrap();
        assert_eq!(
            got.classes.get(f as usize),
            Some(&class),
            "{ctx}: acknowledged decision {kind:?} of frame {f} lost ({} labels)",
            got.classes.len()
        );
        if kind == DecisionKind::Taken {
            assert!(
                got.db.contains_key(&f),
                "{ctx}: frame {f} acknowledged as taken is not in the database"
            );
        }
    }
}

/// After a reboot: the restore worked and holds everything the host saw
/// acknowledged, nothing corrupt, and a prefix of what the device held in RAM
/// when the power went (`ram`) and, for a first cut, of the uninterrupted
/// run (`reference`). Returns the restored status.
fn check_restored<D: AnyDevice>(
    rig: &mut Rig<D>,
    restored: Result<u32, RestoreFailure>,
    scan: &Scan,
    seen: &Seen,
    ram: &Parsed,
    reference: Option<&Parsed>,
    ctx: &str,
) -> Status {
    let records = restored.unwrap_or_else(|e| panic!("{ctx}: restore failed: {e:?}"));
    let st = rig.status();
    let export = rig.export();
    let got = parse(&export, scan, ctx);
    assert_eq!(st.stored_records, records, "{ctx}: stored records");
    assert_eq!(
        st.degradation & degradation::RESTORED != 0,
        records > 0,
        "{ctx}: RESTORED flag, {records} records"
    );
    assert_eq!(st.degradation & degradation::STORAGE_FAILED, 0, "{ctx}");
    assert_eq!(
        st.frames_seen, st.frames_decided,
        "{ctx}: a window came back"
    );
    assert_eq!(got.classes.len() as u32, st.frames_decided, "{ctx}: labels");
    assert_eq!(
        got.db.len() as u32,
        st.database_size,
        "{ctx}: database size"
    );
    assert_ne!(st.phase, Phase::InFrame, "{ctx}: a frame came back open");
    if seen.hello {
        assert_ne!(
            st.phase,
            Phase::Unconfigured,
            "{ctx}: acknowledged Hello lost"
        );
    }
    if seen.finish {
        assert_eq!(st.phase, Phase::Finished, "{ctx}: acknowledged Finish lost");
    } else if !seen.finish_sent {
        assert_ne!(
            st.phase,
            Phase::Finished,
            "{ctx}: Finish before it was sent"
        );
    }
    if st.phase == Phase::Unconfigured {
        assert!(export.is_empty(), "{ctx}: records without a configuration");
    }
    assert_acknowledged(&got, seen, ctx);
    let named: BTreeSet<u32> = got.classes.iter().copied().collect();
    let unnamed: Vec<u32> = got
        .db
        .keys()
        .filter(|f| !named.contains(f))
        .copied()
        .collect();
    assert!(
        unnamed.is_empty(),
        "{ctx}: restored database frames {unnamed:?} are the class of no label"
    );
    let batch = placedb::persist::record::DECISION_BATCH;
    assert_prefix(&got, ram, batch, "the device's RAM at the cut", ctx);
    if let Some(reference) = reference {
        assert_prefix(&got, reference, 0, "the uninterrupted run", ctx);
    }
    st
}

/// After the scan went to the end: every frame has a label, every class is
/// a database frame, every acknowledged decision holds, and a further
/// reboot restores exactly this export. Returns the rig after that reboot
/// and the export.
fn check_complete<D: AnyDevice>(
    mut rig: Rig<D>,
    scan: &Scan,
    seen: &Seen,
    ctx: &str,
) -> (Rig<D>, Parsed) {
    let st = rig.status();
    let export = rig.export();
    let got = parse(&export, scan, ctx);
    assert_eq!(st.phase, Phase::Finished, "{ctx}");
    assert_eq!(
        (st.frames_seen, st.frames_decided),
        (scan.len(), scan.len()),
        "{ctx}"
    );
    assert_eq!(
        got.classes.len() as u32,
        scan.len(),
        "{ctx}: a frame has no label"
    );
    assert!(
        got.db.len() <= scan.frames.len(),
        "{ctx}: more database frames than frames"
    );
    assert_eq!(st.degradation & degradation::STORAGE_FAILED, 0, "{ctx}");
    assert_acknowledged(&got, seen, ctx);
    // The flash still works: all of it is durable.
    let (mut again, restored) = Rig::<D>::boot(rig.into_flash());
    assert_eq!(restored, Ok(st.stored_records), "{ctx}: final restore");
    assert_eq!(again.export(), export, "{ctx}: final restore differs");
    let st2 = again.status();
    assert_eq!(
        (st2.phase, st2.frames_seen, st2.database_size),
        (st.phase, st.frames_seen, st.database_size),
        "{ctx}: final restore"
    );
    (again, got)
}

// ---------------------------------------------------------------- helpers

fn tear_name(t: Tear) -> &'static str {
    match t {
        Tear::Before => "before",
        Tear::Half => "half",
        Tear::After => "after",
        Tear::Marginal => "marginal",
        Tear::Scattered(_) => "scattered",
        Tear::KeepHead => "erase from the end",
        Tear::Zeroed => "erase left zero",
    }
}

// ------------------------------------------------------------ the full run

/// The uninterrupted run with a log.
struct Reference {
    /// Flash steps (erases and writes) of the whole run.
    steps: u64,
    export: Parsed,
    /// Bytes of exact keys it gave the log (the selector's key budget count).
    key_bytes: u32,
}

/// What one cut point ended with.
#[derive(Debug, Default, Clone)]
struct Tally {
    cuts: u64,
    double_cuts: u64,
    restores: u64,
    /// Records restored after a first cut: (step, tear, records).
    restored: Vec<(u64, usize, u32)>,
}

impl Tally {
    fn add(&mut self, other: Tally) {
        self.cuts += other.cuts;
        self.double_cuts += other.double_cuts;
        self.restores += other.restores;
        self.restored.extend(other.restored);
    }
}

/// A cut after a reboot, at this many steps into the resumed run.
fn second_cut(k: u64, reference: &Reference) -> Option<(u64, Tear)> {
    k.is_multiple_of(DOUBLE_EVERY).then(|| {
        // Anywhere from the first step of the resumed run (a new sector, or
        // the Begin of a new generation) to about the end of the scan.
        let n = k / DOUBLE_EVERY;
        let left = reference.steps.saturating_sub(k).max(1);
        ((n * 11) % left, TEARS[n as usize % 3])
    })
}

/// One cut point: the run is cut at step `k` (torn as `tear`), rebooted,
/// checked, resumed (cut again if `second` says so, and checked), finished
/// and checked.
fn cut_point<D: AnyDevice>(
    (scan, sectors): (&Scan, usize),
    reference: &Reference,
    k: u64,
    tear: Tear,
    second: Option<(u64, Tear)>,
) -> Tally {
    let mut tally = Tally::default();
    let mut ctx = format!("cut at step {k} ({})", tear_name(tear));
    let (mut rig, restored) = Rig::<D>::boot(SimFlash::new(sectors));
    assert_eq!(restored, Ok(0), "{ctx}: a blank flash");
    rig.flash().cut_at(k, tear);
    let mut seen = Seen::default();
    assert!(!drive(&mut rig, scan, &mut seen, &ctx), "{ctx}: no cut");
    tally.cuts += 1;
    let ram = parse(&rig.export(), scan, &ctx);
    let (mut rig, restored) = Rig::<D>::boot(rig.into_flash());
    tally.restores += 1;
    let t = TEARS.iter().position(|&t| t == tear).unwrap();
    tally.restored.push((k, t, restored.unwrap_or(u32::MAX)));
    let mut st = check_restored(
        &mut rig,
        restored,
        scan,
        &seen,
        &ram,
        Some(&reference.export),
        &ctx,
    );
    if let Some((after, tear2)) = second {
        let at = rig.flash().steps() + after;
        rig.flash().cut_at(at, tear2);
        if !drive(&mut rig, scan, &mut seen, &ctx) {
            ctx = format!("{ctx}, then at step {at} ({})", tear_name(tear2));
            tally.double_cuts += 1;
            let ram = parse(&rig.export(), scan, &ctx);
            let (again, restored) = Rig::<D>::boot(rig.into_flash());
            rig = again;
            tally.restores += 1;
            st = check_restored(&mut rig, restored, scan, &seen, &ram, None, &ctx);
        } else {
            rig.flash().power_on();
        }
    }
    let steps = rig.flash().steps();
    if !seen.finish {
        assert!(drive(&mut rig, scan, &mut seen, &ctx), "{ctx}: cut again");
    }
    if st.phase != Phase::Finished {
        assert!(
            rig.flash().steps() > steps,
            "{ctx}: the resumed run wrote nothing"
        );
    }
    let key_bytes = |rig: &Rig<D>| rig.device.selector_status().stored_key_bytes;
    assert_eq!(key_bytes(&rig), reference.key_bytes, "{ctx}: key bytes");
    let (again, got) = check_complete(rig, scan, &seen, &ctx);
    assert_eq!(got, reference.export, "{ctx}: the resumed export differs");
    assert_eq!(
        key_bytes(&again),
        reference.key_bytes,
        "{ctx}: key bytes restored at the final reboot"
    );
    tally
}

/// The log itself, from the records restored after each first cut: a cut
/// before step 0 leaves nothing, a cut after the last step everything; a
/// step torn half way counts as not done; each step adds at most one record
/// (a write) and never loses one (an erase touches no live sector), and a
/// cut after step `k` restores what a cut before step `k + 1` does. So every
/// completed write is durable, in order.
fn durable_records_grow_one_write_at_a_time(
    restored: &[(u64, usize, u32)],
    steps: u64,
    total: u32,
) {
    let mut at = vec![[u32::MAX; 3]; steps as usize];
    for &(k, t, records) in restored {
        at[k as usize][t] = records;
    }
    assert_eq!(at[0][0], 0, "a cut before the first step restores records");
    assert_eq!(
        at[steps as usize - 1][2],
        total,
        "a cut after the last step"
    );
    let mut writes = 0;
    for (k, [before, half, after]) in at.iter().copied().enumerate() {
        assert_eq!(half, before, "step {k}: a torn step counts");
        assert!(
            after == before || after == before + 1,
            "step {k}: {before} records before it, {after} after it"
        );
        writes += after - before;
        if let Some(next) = at.get(k + 1) {
            assert_eq!(next[0], after, "steps {k} and {}", k + 1);
        }
    }
    assert_eq!(writes, total);
}

/// Every step of the reference run cut, with every tear ([`cut_point`],
/// a second cut for every 3rd step), spread over threads.
fn cut_at_every_step<D: AnyDevice>(
    scan: &Arc<Scan>,
    sectors: usize,
    reference: &Arc<Reference>,
) -> Tally {
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get().min(4));
    let handles: Vec<_> = (0..threads)
        .map(|t| {
            let (scan, reference) = (Arc::clone(scan), Arc::clone(reference));
            std::thread::Builder::new()
                .stack_size(64 << 20)
                .spawn(move || {
                    let mut tally = Tally::default();
                    for k in (t as u64..reference.steps).step_by(threads) {
                        for tear in TEARS {
                            let second = second_cut(k, &reference);
                            let run = (&*scan, sectors);
                            tally.add(cut_point::<D>(run, &reference, k, tear, second));
                        }
                    }
                    tally
                })
                .unwrap()
        })
        .collect();
    let mut tally = Tally::default();
    for h in handles {
        tally.add(h.join().unwrap());
    }
    tally
}

#[test]
fn a_power_cut_at_every_flash_step_loses_nothing_acknowledged() {
    on_big_stack(|| {
        let scan = Arc::new(Scan::synthetic(0, FRAMES, 8));
        // Without a journal.
        let mut plain = Rig::<Big>::without_flash();
        let mut plain_seen = Seen::default();
        assert!(drive(&mut plain, &scan, &mut plain_seen, "no journal"));
        let plain_export = plain.export();
        // With the log, uninterrupted: exactly the same replies and export.
        let (mut rig, restored) = Rig::<Big>::boot(SimFlash::new(SECTORS));
        assert_eq!(restored, Ok(0));
        let mut seen = Seen::default();
        assert!(drive(&mut rig, &scan, &mut seen, "uninterrupted"));
        // A device without flash decides the same (its decisions go out at
        // once, not in batches) and exports the same database, but no labels.
        assert_eq!(seen.finals, plain_seen.finals, "decisions with a log");
        let export = rig.export();
        let db = export
            .iter()
            .take_while(|r| matches!(r.kind, RecordKind::Database { .. }));
        assert_eq!(
            db.copied().collect::<Vec<_>>(),
            plain_export,
            "export with a log"
        );
        let steps = rig.flash().steps();
        let sectors = rig.log.as_ref().unwrap().sectors_used();
        let st = rig.status();
        assert!(sectors >= 3, "the run fits in {sectors} sectors");
        // The premise of an identical resume: every key is kept.
        let selector = rig.device.selector().status();
        assert_eq!(selector.sketched_frames, 0, "a frame without its keys");
        assert!(selector.stored_key_bytes > 0);
        let (_, parsed) = check_complete(rig, &scan, &seen, "uninterrupted");
        let reference = Arc::new(Reference {
            steps,
            export: parsed,
            key_bytes: selector.stored_key_bytes,
        });
        let database = reference.export.db.len();
        assert!(database > 1);
        let tally = cut_at_every_step::<Big>(&scan, SECTORS, &reference);
        assert_eq!(tally.cuts, 3 * steps);
        durable_records_grow_one_write_at_a_time(&tally.restored, steps, st.stored_records);
        assert!(tally.double_cuts > 0);
        println!(
            "power cuts: {FRAMES} frames, {} records in {sectors} of {SECTORS} sectors, {steps} flash steps; \
             {} cut points tried ({steps} steps x 3 tears) + {} second cuts while resuming = {} cuts, \
             {} restores, all acknowledged records intact; every resumed export identical to the \
             uninterrupted one ({database} database frames, {} key bytes)",
            st.stored_records,
            tally.cuts,
            tally.double_cuts,
            tally.cuts + tally.double_cuts,
            tally.restores,
            reference.key_bytes,
        );
    });
}

// ------------------------------------------------------- focused: the log

/// What silicon's cuts leave and a prefix-and-a-byte tear does not: a
/// record that restores at the next boot and reads wrong at the one after
/// (cells just past the read threshold), a write that took a random part of
/// its bits, an erase that went from the end (the record at offset 0
/// intact) or left the sector all zero. A cut at every flash step of a scan
/// with each of them, a boot that resumes to the end (every frame
/// acknowledged), time (what was weak reads wrong), and another boot: the
/// export is the uninterrupted run's.
#[test]
fn a_record_that_restores_once_then_fades_loses_nothing_acknowledged() {
    on_big_stack(|| {
        let scan = Scan::synthetic(0, FRAMES, 8);
        let (mut rig, _) = Rig::<Small>::boot(SimFlash::new(SECTORS));
        let mut seen = Seen::default();
        assert!(drive(&mut rig, &scan, &mut seen, "uninterrupted"));
        let steps = rig.flash().steps();
        let sectors = rig.log.as_ref().unwrap().sectors_used();
        assert!(sectors >= 3, "the scan fits in {sectors} sectors");
        let (_, reference) = check_complete(rig, &scan, &seen, "uninterrupted");
        let (mut cuts, mut faded) = (0u32, 0usize);
        for k in 0..steps {
            let tears = [
                Tear::Marginal,
                Tear::Scattered(k as u8),
                Tear::KeepHead,
                Tear::Zeroed,
            ];
            for tear in tears {
                let ctx = format!("cut at step {k} ({})", tear_name(tear));
                let (mut rig, _) = Rig::<Small>::boot(SimFlash::new(SECTORS));
                rig.flash().cut_at(k, tear);
                let mut seen = Seen::default();
                assert!(!drive(&mut rig, &scan, &mut seen, &ctx), "{ctx}: no cut");
                cuts += 1;
                let ram = parse(&rig.export(), &scan, &ctx);
                let (mut rig, restored) = Rig::<Small>::boot(rig.into_flash());
                check_restored(
                    &mut rig,
                    restored,
                    &scan,
                    &seen,
                    &ram,
                    Some(&reference),
                    &ctx,
                );
                if !seen.finish {
                    assert!(drive(&mut rig, &scan, &mut seen, &ctx), "{ctx}: cut again");
                }
                faded += rig.flash().fade();
                let (rig, restored) = Rig::<Small>::boot(rig.into_flash());
                let ctx = format!("{ctx}, after the weak cells faded");
                assert!(restored.is_ok(), "{ctx}: {restored:?}");
                let (_, got) = check_complete(rig, &scan, &seen, &ctx);
                assert_eq!(got, reference, "{ctx}: the export differs");
            }
        }
        println!("{cuts} cuts over {steps} flash steps, {faded} weak places faded");
        assert!(faded as u64 >= steps / 2, "{faded} faded");
    });
}

/// The live generation's number and head sector, read from the raw flash
/// (the layout of `placedb::persist::log`: "PDBL", format, length,
/// generation, seq, CRC; seq 0 opens the head sector).
fn live_head(flash: &SimFlash) -> (u32, usize) {
    let word = |b: &[u8], at: usize| u32::from_le_bytes(b[at..at + 4].try_into().unwrap());
    flash
        .bytes()
        .chunks(SimFlash::SECTOR)
        .enumerate()
        .filter(|(_, s)| &s[..4] == b"PDBL" && word(s, 12) == 0)
        .map(|(i, s)| (word(s, 8), i))
        .max()
        .expect("a live generation")
}

/// Reboots `rig` and checks that the scan comes back exactly as the device
/// exported it (labels, database, counters), as far as its decisions are
/// durable: of a scan not finished, the database frames taken for
/// decisions still in the window or their batch do not come back.
fn reboot_exact<D: AnyDevice>(rig: Rig<D>, ctx: &str) -> Rig<D> {
    let mut rig = rig;
    let st = rig.status();
    let export = durable_part(&rig.export());
    let (mut rig, restored) = Rig::<D>::boot(rig.into_flash());
    assert_eq!(restored, Ok(st.stored_records), "{ctx}: records restored");
    let back = rig.export();
    assert_eq!(back, export, "{ctx}: the scan does not restore exactly");
    let back = rig.status();
    // Decided frames come back as far as their batch of decisions reached
    // the log: the labels the live device had stored.
    let labels = |s: &Status| s.capacity(placedb::protocol::CapacitySlot::Labels).used;
    let database = export.len() as u32 - labels(&st);
    assert_eq!(
        back.database_size, database,
        "{ctx}: database after restore"
    );
    let key = |s: &Status| (s.phase, labels(s), s.stored_records);
    assert_eq!(key(&back), key(&st), "{ctx}: status after restore");
    assert_eq!(
        back.frames_decided,
        labels(&st),
        "{ctx}: decided after restore"
    );
    assert_ne!(back.degradation & degradation::RESTORED, 0, "{ctx}");
    rig
}

#[test]
fn generations_rotate_around_the_range() {
    on_big_stack(|| {
        // Small enough that generations wrap around often, large enough for
        // the longest scan and the room a FrameEnd keeps for a Finish.
        const SECTORS: usize = 8;
        let scan = Scan::synthetic(0, 40, 8);
        let (mut rig, restored) = Rig::<Small>::boot(SimFlash::new(SECTORS));
        assert_eq!(restored, Ok(0));
        let mut heads = Vec::new();
        let (mut scans, mut resets) = (0, 0);
        // At least 30 cycles, and on until the head has been in every
        // sector (how soon depends on the records' sizes).
        let visited = |heads: &[(u32, usize)]| heads.iter().map(|h| h.1).collect::<BTreeSet<_>>();
        for cycle in 0..200usize {
            if cycle >= 30 && visited(&heads).len() == SECTORS {
                break;
            }
            let ctx = format!("cycle {cycle}");
            if cycle > 0 {
                rig.ok(HostMessage::Reset);
            }
            if cycle % 5 == 4 {
                // Only a Reset: a generation holding nothing but `Cleared`.
                let (again, restored) = Rig::<Small>::boot(rig.into_flash());
                rig = again;
                assert_eq!(restored, Ok(1), "{ctx}");
                assert_eq!(rig.status().phase, Phase::Unconfigured, "{ctx}");
                assert!(rig.export().is_empty(), "{ctx}");
                heads.push(live_head(rig.flash()));
                resets += 1;
                continue;
            }
            let mut seen = Seen::default();
            rig.ok(HostMessage::Hello(scan.cfg));
            let frames = 6 + (cycle * 7) % 34;
            for i in 0..frames as u32 {
                assert!(send_frame(&mut rig, &scan, i, &mut seen, &ctx));
            }
            let finish = cycle % 3 != 1;
            if finish {
                assert!(step(&mut rig, HostMessage::Finish, &mut seen, &ctx));
            }
            rig = reboot_exact(rig, &ctx);
            heads.push(live_head(rig.flash()));
            if !finish {
                // The restored scan goes on to the end.
                assert!(drive(&mut rig, &scan, &mut seen, &ctx));
                rig = check_complete(rig, &scan, &seen, &ctx).0;
            }
            scans += 1;
        }
        // Generation numbers grow; the head went through every sector and
        // wrapped around the end of the range again and again.
        assert!(heads.windows(2).all(|w| w[1].0 > w[0].0), "{heads:?}");
        let sectors: BTreeSet<usize> = heads.iter().map(|h| h.1).collect();
        assert_eq!(sectors.len(), SECTORS, "{heads:?}");
        let wraps = heads.windows(2).filter(|w| w[1].1 <= w[0].1).count();
        assert!(wraps >= 5, "{heads:?}");
        println!(
            "rotation: {scans} scans and {resets} resets on {SECTORS} sectors, generation {} last, \
             the head wrapped {wraps} times; every last scan restored exactly",
            heads.last().unwrap().0
        );
    });
}

/// What a restore after a torn switch from scan A to scan B gave.
#[derive(Debug, Default)]
struct Outcomes {
    a: u32,
    cleared: u32,
    b: u32,
}

/// The switch from a finished scan A to scan B: Reset (if `reset`), Hello
/// B, the first frames of B. `false` when the power went.
fn switch<D: AnyDevice>(
    rig: &mut Rig<D>,
    b: &Scan,
    reset: bool,
    seen: &mut Seen,
    reset_acked: &mut bool,
    ctx: &str,
) -> bool {
    if reset {
        if !step(rig, HostMessage::Reset, seen, ctx) {
            return false;
        }
        *reset_acked = true;
    }
    if !step(rig, HostMessage::Hello(b.cfg), seen, ctx) {
        return false;
    }
    seen.hello = true;
    (0..8).all(|i| send_frame(rig, b, i, seen, ctx))
}

/// Boots on `flash` (holding the finished scan A): restored, or, without
/// `restore`, a device that did not restore (say, one whose firmware does
/// not know the log): it starts over with the next Hello.
fn boot_on_a(flash: &SimFlash, restore: bool, a_export: &[ExportRecord]) -> Rig<Small> {
    let (mut rig, restored) = Rig::<Small>::boot(flash.clone());
    assert!(restored.is_ok());
    assert_eq!(rig.export(), a_export);
    if !restore {
        rig.device = Small::new_boxed();
    }
    rig
}

#[test]
fn a_torn_start_is_never_a_mix() {
    on_big_stack(|| {
        let a = Scan::synthetic(0, 12, 8);
        // Other frames (other timestamps and poses) and another window.
        let b = Scan::synthetic(60, 10, 6);
        let short = Scan::synthetic(20, 10, 8);
        let mut outcomes = Outcomes::default();
        let mut cuts = 0;
        for phase in 0..4 {
            // Earlier scans shift where A lies in the 6-sector range.
            let (mut rig, _) = Rig::<Small>::boot(SimFlash::new(6));
            for p in 0..phase {
                let ctx = format!("phase {phase}, scan {p}");
                assert!(drive(&mut rig, &short, &mut Seen::default(), &ctx));
                rig.ok(HostMessage::Reset);
            }
            assert!(drive(&mut rig, &a, &mut Seen::default(), "scan A"));
            let a_export = rig.export();
            let flash_a = rig.into_flash();
            for restore in [true, false] {
                // Reset then Hello on the restored scan, or a Hello on a
                // device that did not restore.
                let reset = restore;
                let mut rig = boot_on_a(&flash_a, restore, &a_export);
                let base = rig.flash().steps();
                let (mut seen, mut acked) = (Seen::default(), false);
                assert!(switch(&mut rig, &b, reset, &mut seen, &mut acked, "uncut"));
                let m = rig.flash().steps() - base;
                assert!(m >= 4, "{m} steps");
                for j in 0..m {
                    for tear in TEARS {
                        let ctx = format!(
                            "phase {phase}, {}, cut at step {j} of {m} ({})",
                            if reset {
                                "Reset + Hello"
                            } else {
                                "Hello, no restore"
                            },
                            tear_name(tear)
                        );
                        let mut rig = boot_on_a(&flash_a, restore, &a_export);
                        rig.flash().cut_at(base + j, tear);
                        let (mut seen, mut reset_acked) = (Seen::default(), false);
                        assert!(
                            !switch(&mut rig, &b, reset, &mut seen, &mut reset_acked, &ctx),
                            "{ctx}: no cut"
                        );
                        cuts += 1;
                        let ram = rig.export();
                        let (mut rig, restored) = Rig::<Small>::boot(rig.into_flash());
                        let records = restored.unwrap_or_else(|e| panic!("{ctx}: {e:?}"));
                        let st = rig.status();
                        let export = rig.export();
                        match st.phase {
                            Phase::Finished => {
                                // A, exactly.
                                assert_eq!(export, a_export, "{ctx}: A is not intact");
                                assert!(!reset_acked && !seen.hello, "{ctx}: A came back");
                                outcomes.a += 1;
                                rig.ok(HostMessage::Reset);
                            }
                            Phase::Unconfigured => {
                                // Reset, exactly.
                                assert!(reset, "{ctx}: A lost without a Reset");
                                assert_eq!(records, 1, "{ctx}: neither A nor the Reset restored");
                                assert!(export.is_empty(), "{ctx}");
                                assert!(!seen.hello, "{ctx}: acknowledged Hello B lost");
                                outcomes.cleared += 1;
                            }
                            Phase::Ready => {
                                // B, and only B.
                                let got = parse(&export, &b, &ctx);
                                assert_prefix(
                                    &got,
                                    &parse(&ram, &b, &ctx),
                                    placedb::persist::record::DECISION_BATCH,
                                    "B in RAM",
                                    &ctx,
                                );
                                assert_acknowledged(&got, &seen, &ctx);
                                if st.frames_seen > 0 {
                                    assert_eq!(
                                        rig.refused(HostMessage::Hello(a.cfg)),
                                        ErrorKind::NeedsReset,
                                        "{ctx}: not B's configuration"
                                    );
                                }
                                outcomes.b += 1;
                            }
                            Phase::InFrame => panic!("{ctx}: a frame came back open"),
                        }
                        // Either way, scan B goes on to the end.
                        assert!(drive(&mut rig, &b, &mut seen, &ctx), "{ctx}");
                        check_complete(rig, &b, &seen, &ctx);
                    }
                }
            }
        }
        assert!(outcomes.a > 0 && outcomes.cleared > 0 && outcomes.b > 0);
        println!(
            "torn start: {cuts} cuts while switching from a finished scan A to a scan B; \
             restored A intact {} times, Reset {} times, B {} times, never a mix",
            outcomes.a, outcomes.cleared, outcomes.b
        );
    });
}

#[test]
fn a_full_log_refuses_frame_end_and_changes_nothing() {
    on_big_stack(|| {
        let scan = Scan::synthetic(0, 120, 8);
        // 6 sectors: a generation holds at most 5, and a FrameEnd keeps
        // room for 8 key chunks and two full windows' records.
        let (mut rig, _) = Rig::<Small>::boot(SimFlash::new(6));
        let mut seen = Seen::default();
        rig.ok(HostMessage::Hello(scan.cfg));
        let mut full_at = None;
        for i in 0..scan.len() {
            let ctx = format!("frame {i}");
            let f = &scan.frames[i as usize];
            rig.ok(HostMessage::FrameBegin {
                frame: i,
                timestamp: f.timestamp,
                pose: f.pose,
            });
            for rows in &f.rows {
                rig.ok(rows.message(i));
            }
            let (st, export, steps) = (rig.status(), rig.export(), rig.flash().steps());
            let replies = rig.send(HostMessage::FrameEnd { frame: i });
            seen.note(&replies, &ctx);
            match replies.as_slice() {
                [.., DeviceMessage::Ack { .. }] => continue,
                [DeviceMessage::Error {
                    kind: ErrorKind::StorageFull,
                    ..
                }] => {}
                other => panic!("{ctx}: {other:?}"),
            }
            // Refused: nothing changed, the frame is still open.
            let same = |s: &Status| {
                (
                    s.phase,
                    s.frames_seen,
                    s.frames_decided,
                    s.database_size,
                    s.stored_records,
                    s.degradation,
                )
            };
            let after = rig.status();
            assert_eq!(same(&after), same(&st), "{ctx}: status changed");
            assert_eq!(after.phase, Phase::InFrame);
            assert_eq!(after.refused, st.refused + 1);
            assert_eq!(rig.export(), export, "{ctx}: export changed");
            assert_eq!(rig.flash().steps(), steps, "{ctx}: the flash was written");
            // Again: refused too. Finish needs the frame closed first.
            assert_eq!(
                rig.refused(HostMessage::FrameEnd { frame: i }),
                ErrorKind::StorageFull
            );
            assert_eq!(rig.refused(HostMessage::Finish), ErrorKind::OutOfOrder);
            assert_eq!(same(&rig.status()), same(&st), "{ctx}");
            // The log kept room to end the scan: drop the open frame, Finish.
            rig.ok(HostMessage::FrameAbort { frame: i });
            assert_eq!(rig.status().phase, Phase::Ready);
            assert!(step(&mut rig, HostMessage::Finish, &mut seen, &ctx));
            let st = rig.status();
            assert_eq!(st.phase, Phase::Finished);
            assert_eq!((st.frames_seen, st.frames_decided), (i, i));
            full_at = Some(i);
            break;
        }
        let full_at = full_at.expect("the log never filled up");
        assert!(full_at > 8, "full at frame {full_at}");
        // Everything decided is durable: the reboot restores it exactly.
        let ctx = format!("full at frame {full_at}");
        let decided = rig.status().frames_decided;
        let export = rig.export();
        let (mut rig, restored) = Rig::<Small>::boot(rig.into_flash());
        assert!(restored.is_ok(), "{ctx}: {restored:?}");
        assert_eq!(rig.export(), export, "{ctx}: restore");
        assert_acknowledged(&parse(&export, &scan, &ctx), &seen, &ctx);
        let st = rig.status();
        assert_eq!((st.frames_seen, st.frames_decided), (decided, decided));
        assert_eq!(st.phase, Phase::Finished, "{ctx}: restore");
        // Every frame before the full point has its label.
        assert_eq!(decided, full_at);
        // A Reset starts a new generation: scans fit again.
        rig.ok(HostMessage::Reset);
        let short = Scan::synthetic(0, 30, 8);
        assert!(drive(&mut rig, &short, &mut Seen::default(), &ctx));
        let rig = reboot_exact(rig, &ctx);
        check_complete(rig, &short, &Seen::default(), &ctx);
        println!(
            "full log: FrameEnd of frame {full_at} refused with StorageFull ({} records \
             durable), nothing changed; FrameAbort + Finish ended the scan with every \
             frame before it decided; export and restore intact",
            st.stored_records
        );
    });
}

#[test]
fn a_failing_flash_degrades_and_restores_a_prefix() {
    on_big_stack(|| {
        let scan = Scan::synthetic(0, 40, 8);
        // The uninterrupted run (its flash steps are the log's own: see
        // below).
        let (mut rig, _) = Rig::<Small>::boot(SimFlash::new(SECTORS));
        rig.erase_ahead_when_idle = false;
        let mut reference_seen = Seen::default();
        assert!(drive(&mut rig, &scan, &mut reference_seen, "uninterrupted"));
        let steps = rig.flash().steps();
        let reference = rig.export();
        let reference_parsed = parse(&reference, &scan, "uninterrupted");
        let (mut hello_refusals, mut degraded, mut transient_runs) = (0, 0, 0);
        for k in 0..steps {
            // Every 5th time the flash comes back right after the failure,
            // without a reboot; otherwise it stays dead until one.
            let transient = k.is_multiple_of(5);
            let ctx = format!(
                "flash {} at step {k}",
                if transient { "failing once" } else { "dead" }
            );
            let (mut rig, _) = Rig::<Small>::boot(SimFlash::new(SECTORS));
            // The device itself keeps running: the host hears every reply.
            rig.listen_always();
            // The log's own writes fail here, not an erase while idle (which
            // the log never sees: it erases that sector again itself).
            rig.erase_ahead_when_idle = false;
            rig.flash().cut_at(k, Tear::Half);
            let hello = rig.send(HostMessage::Hello(scan.cfg));
            let seq = rig.seq;
            let failed = DeviceMessage::Error {
                seq: Some(seq),
                kind: ErrorKind::StorageFailed,
            };
            // The flash may also fail in the erase ahead after an
            // acknowledged Hello: the device meets that at its next write.
            if hello == [failed] {
                // The scan could not start: Hello refused, nothing configured.
                assert!(rig.is_off(), "{ctx}");
                assert_eq!(rig.status().phase, Phase::Unconfigured, "{ctx}");
                assert_eq!(rig.refused(HostMessage::Finish), ErrorKind::NotConfigured);
                hello_refusals += 1;
                let (mut rig, restored) = Rig::<Small>::boot(rig.into_flash());
                assert_eq!(restored, Ok(0), "{ctx}");
                let mut seen = Seen::default();
                assert!(drive(&mut rig, &scan, &mut seen, &ctx));
                check_complete(rig, &scan, &seen, &ctx);
                continue;
            }
            assert_eq!(hello, vec![DeviceMessage::Ack { seq }], "{ctx}");
            let mut seen = Seen {
                hello: true,
                ..Seen::default()
            };
            // What the host saw before the flash failed.
            let mut before = Seen {
                hello: true,
                ..Seen::default()
            };
            let mut failed_at = None;
            for i in 0..=scan.len() {
                if i < scan.len() {
                    assert!(send_frame(&mut rig, &scan, i, &mut seen, &ctx), "{ctx}");
                } else {
                    assert!(step(&mut rig, HostMessage::Finish, &mut seen, &ctx));
                }
                if failed_at.is_none() && rig.is_off() {
                    failed_at = Some(rig.flash().steps());
                    if transient {
                        rig.flash().power_on();
                    }
                }
                if failed_at.is_none() {
                    before.finals.clone_from(&seen.finals);
                }
            }
            let failed_at = failed_at.expect("the flash failed");
            // Selection went on as if nothing happened; the status tells.
            assert_eq!(seen.decisions, reference_seen.decisions, "{ctx}");
            // The database is whole (RAM holds it); the labels are those
            // whose batch reached the log before it failed, the rest counted.
            let export = rig.export();
            let n_db = reference_parsed.db.len();
            assert_eq!(export[..n_db], reference[..n_db], "{ctx}: database");
            let labels = export.len() - n_db;
            assert_eq!(export[n_db..], reference[n_db..n_db + labels], "{ctx}");
            let st = rig.status();
            let stored = st.capacity(placedb::protocol::CapacitySlot::Labels).used;
            assert_eq!(labels as u32, stored, "{ctx}: labels in the log");
            assert_eq!(stored + st.labels_dropped, scan.len(), "{ctx}");
            assert_ne!(st.degradation & degradation::STORAGE_FAILED, 0, "{ctx}");
            assert_eq!(st.phase, Phase::Finished, "{ctx}");
            degraded += 1;
            let ram = parse(&rig.export(), &scan, &ctx);
            if transient {
                // Nothing more was written in this scan (a record after a
                // missing one would not restore); a new scan writes again.
                assert_eq!(
                    rig.flash().steps(),
                    failed_at,
                    "{ctx}: written after a failure"
                );
                rig.ok(HostMessage::Reset);
                let mut again = Seen::default();
                assert!(drive(&mut rig, &scan, &mut again, &ctx));
                let st = rig.status();
                assert_eq!(st.degradation & degradation::STORAGE_FAILED, 0, "{ctx}");
                let rig = reboot_exact(rig, &ctx);
                check_complete(rig, &scan, &again, &ctx);
                transient_runs += 1;
                continue;
            }
            // A Reset would come undone at the next boot: refused.
            assert_eq!(rig.refused(HostMessage::Reset), ErrorKind::StorageFailed);
            assert_eq!(rig.status().phase, Phase::Finished, "{ctx}");
            // A real reboot: a consistent prefix, with every decision the
            // host saw before the flash failed.
            let (mut rig, restored) = Rig::<Small>::boot(rig.into_flash());
            let reference = Some(&reference_parsed);
            check_restored(&mut rig, restored, &scan, &before, &ram, reference, &ctx);
            assert!(drive(&mut rig, &scan, &mut before, &ctx));
            check_complete(rig, &scan, &before, &ctx);
        }
        assert!(hello_refusals > 0 && degraded > 0 && transient_runs > 0);
        println!(
            "failing flash at each of {steps} steps: Hello refused {hello_refusals} times, \
             {degraded} scans finished degraded (STORAGE_FAILED), {transient_runs} of them \
             recovered with a new scan without a reboot, the others restored a consistent prefix"
        );
    });
}

/// The power went between the two records of the first deciding step: a
/// database frame is durable, no decision is. The restore holds no database
/// frame (it was taken for a decision the log does not hold) and no frame
/// was seen, so a Hello with another configuration starts a new scan; that
/// scan must hold nothing of the old one.
/// A fault of the simulated flash, named.
type FlashFault = (&'static str, fn(&mut SimFlash));

/// A flash that reports success for writes that did not take (bits that
/// do not program in a worn sector, a write-protected sector): the log reads
/// every write back, so the device counts as durable only what a reboot
/// restores, stops writing, says so in its status, and the host turns that
/// into words (what `placedb stream` prints).
#[test]
fn a_flash_that_does_not_take_writes_is_never_durable_and_is_said_in_words() {
    on_big_stack(|| {
        let scan = Scan::synthetic(0, 40, 8);
        let faults: [FlashFault; 2] = [
            ("bits dropped in sector 1", |f| f.drop_bits(1, 0x10)),
            ("sector 1 protected", |f| f.protect(1)),
        ];
        for (ctx, fault) in faults {
            let (mut rig, _) = Rig::<Small>::boot(SimFlash::new(SECTORS));
            fault(rig.flash());
            let mut seen = Seen::default();
            assert!(drive(&mut rig, &scan, &mut seen, ctx), "{ctx}");
            let st = rig.status();
            assert_ne!(st.degradation & degradation::STORAGE_FAILED, 0, "{ctx}");
            let words = placedb_host::board::client::flash_warnings(&st).join("\n");
            assert!(words.contains("flash failed a write"), "{ctx}: {words}");
            assert!(
                words.contains(&format!("only {} records", st.stored_records)),
                "{ctx}: {words}"
            );
            assert!(
                !words.contains("StorageFailed"),
                "{ctx}: no type names: {words}"
            );
            let (mut again, restored) = Rig::<Small>::boot(rig.into_flash());
            assert_eq!(
                restored,
                Ok(st.stored_records),
                "{ctx}: exactly the records counted durable restore"
            );
            assert_eq!(again.status().stored_records, st.stored_records, "{ctx}");
        }
    });
}

#[test]
fn a_new_scan_after_a_restore_holds_nothing_of_the_old_one() {
    on_big_stack(|| {
        let old = Scan::synthetic(0, 20, 8);
        // One frame of elsewhere on the route, another window.
        let new = Scan::synthetic(100, 1, 6);
        let mut cases = 0;
        for k in 0..40 {
            for tear in TEARS {
                let ctx = format!("cut at step {k} ({})", tear_name(tear));
                let (mut rig, _) = Rig::<Small>::boot(SimFlash::new(8));
                rig.flash().cut_at(k, tear);
                if drive(&mut rig, &old, &mut Seen::default(), &ctx) {
                    continue;
                }
                let (mut rig, restored) = Rig::<Small>::boot(rig.into_flash());
                assert!(restored.is_ok(), "{ctx}");
                let st = rig.status();
                // Begin and a record after it (keys, a database frame),
                // but no decision.
                if st.frames_seen > 0 || st.stored_records < 2 {
                    continue;
                }
                assert_eq!(st.database_size, 0, "{ctx}: an undecided take restored");
                cases += 1;
                let mut seen = Seen::default();
                assert!(drive(&mut rig, &new, &mut seen, &ctx));
                parse(&rig.export(), &new, &ctx);
                let (mut rig, _) = Rig::<Small>::boot(rig.into_flash());
                parse(&rig.export(), &new, &format!("{ctx}, after a reboot"));
            }
        }
        assert!(
            cases > 0,
            "no cut leaves a database frame without a decision"
        );
    });
}

// --------------------------------------------------- at scale: 500 frames

/// Power cuts at scale: the demo office walked in 600 frames at mu 0.9, so
/// that nearly every frame joins the database (with its exact keys, well
/// inside the key budget): after [`SCALE_PREFIX`] frames more than 500
/// database frames are in flash, most of them no longer in RAM. From there,
/// the power is cut at every flash step of the next [`SCALE_CUT_FRAMES`]
/// frames, each torn three ways; after each cut a new device restores the
/// long log, every acknowledged decision is there, and the resumed scan's
/// export is byte-identical to the uninterrupted run's: restored database
/// frames are compared exactly, from the keys in flash, as before the cut.
/// The restore time of that log is printed.
#[test]
fn power_cuts_with_500_database_frames_in_flash() {
    on_big_stack(|| {
        const SECTORS_AT_SCALE: usize = 192;
        let scan = Scan::route(600, 0, SCALE_PREFIX as usize + 24, 8, 0.9);
        // The uninterrupted run.
        let (mut rig, _) = Rig::<Big>::boot(SimFlash::new(SECTORS_AT_SCALE));
        let mut seen = Seen::default();
        assert!(drive(&mut rig, &scan, &mut seen, "uninterrupted"));
        let (_, reference) = check_complete(rig, &scan, &seen, "uninterrupted");
        // The long prefix, without Finish.
        let (mut rig, _) = Rig::<Big>::boot(SimFlash::new(SECTORS_AT_SCALE));
        let mut prefix_seen = Seen::default();
        assert!(drive_to(
            &mut rig,
            &scan,
            SCALE_PREFIX,
            false,
            &mut prefix_seen,
            "prefix"
        ));
        let st = rig.status();
        let resident = st.capacity(placedb::protocol::CapacitySlot::Resident).used;
        assert!(st.database_size >= 500, "{st:?}");
        assert!(
            resident < st.database_size / 2,
            "most database frames in flash only"
        );
        let prefix = rig.into_flash();
        // Boot on it once: restore time, and the resumed run is identical.
        let t = std::time::Instant::now();
        let (mut rig, restored) = Rig::<Big>::boot(prefix.clone());
        let restore_s = t.elapsed().as_secs_f64();
        let records = restored.expect("the prefix restores");
        let start = rig.flash().steps();
        let mut seen = prefix_seen.clone();
        assert!(drive_to(
            &mut rig,
            &scan,
            SCALE_PREFIX + SCALE_CUT_FRAMES,
            false,
            &mut seen,
            "resumed"
        ));
        let steps = rig.flash().steps() - start;
        assert!(drive(&mut rig, &scan, &mut seen, "resumed"));
        let (_, resumed) = check_complete(rig, &scan, &seen, "resumed");
        assert_eq!(resumed, reference, "resumed after a reboot");
        // Every flash step of the next frames, every tear.
        let cuts = cut_after_prefix::<Big>(
            (&scan, &prefix, &prefix_seen),
            steps,
            &reference,
            "at scale",
        );
        println!(
            "power cuts at scale: {} database frames in flash ({resident} resident) after {SCALE_PREFIX} \
             frames, {records} records restored in {:.1} ms; {cuts} cuts over the {steps} flash steps \
             of the next {SCALE_CUT_FRAMES} frames, every resumed export identical",
            st.database_size,
            restore_s * 1e3
        );
    });
}

/// Frames streamed before the cuts at scale.
const SCALE_PREFIX: u32 = 540;
/// Frames whose flash steps are each cut.
const SCALE_CUT_FRAMES: u32 = 4;

/// A device whose window outgrows its key pool (16 frames of a stride-4
/// scan hold more voxels than its 6,144 words) and whose 16 resident frames
/// leave most of the database in flash only.
type Tight = Device<8192, 16384, 256, 16, 32, 16>;
/// Sectors of its flash: the key budget (half the log) runs out part way
/// through the scan, so that later database frames are kept without keys.
const TIGHT_SECTORS: usize = 34;

/// Issue 36: past the key budget and with the key pool full, a power cut
/// at any flash step (every erase and write, erases ahead while idle
/// included, every tear, a second cut for every 3rd) resumes to exactly the
/// uninterrupted run's export. Before the exactness of a comparison became
/// a fact of the frames (the store's keys, the window rule), a frame that
/// had been resident with its keys came back without them and the resumed
/// scan decided otherwise.
#[test]
fn power_cuts_past_the_key_budget_resume_to_the_same_export() {
    on_big_stack(|| {
        let scan = Arc::new(Scan::strided(300, 0, 90, (16, 0.5), (4, 0.1)));
        let (mut rig, _) = Rig::<Tight>::boot(SimFlash::new(TIGHT_SECTORS));
        let mut seen = Seen::default();
        assert!(drive(&mut rig, &scan, &mut seen, "uninterrupted"));
        let steps = rig.flash().steps();
        let sel = rig.device.selector_status();
        println!("past the budget: {sel:?}, {steps} flash steps");
        // The regime: keys kept for the first database frames only, and
        // window frames without room in the pool.
        assert!(sel.unkeyed_frames > 0, "the key budget did not run out");
        assert!(sel.sketched_frames > 0, "the key pool never filled");
        assert!(sel.stored_key_bytes > 0);
        let (_, parsed) = check_complete(rig, &scan, &seen, "uninterrupted");
        let reference = Arc::new(Reference {
            steps,
            export: parsed,
            key_bytes: sel.stored_key_bytes,
        });
        let tally = cut_at_every_step::<Tight>(&scan, TIGHT_SECTORS, &reference);
        assert_eq!(tally.cuts, 3 * steps);
        assert!(tally.double_cuts > 0);
        println!(
            "power cuts past the key budget: {} frames, {} database frames ({} kept without keys, \
             {} frames without room in the key pool), {steps} flash steps; {} cuts and {} second \
             cuts, every resumed export identical to the uninterrupted one",
            scan.len(),
            reference.export.db.len(),
            sel.unkeyed_frames,
            sel.sketched_frames,
            tally.cuts,
            tally.double_cuts,
        );
    });
}

/// The host's second session on a finished scan (or the resume of one):
/// Extend (a no-op on a restored open second session), the frames from
/// `from`, Finish. `false` when the power went.
fn extend_from<D: AnyDevice>(rig: &mut Rig<D>, scan: &Scan, from: u32, seen: &mut Seen) -> bool {
    let ctx = "second session";
    if !step(rig, HostMessage::Extend(scan.cfg), seen, ctx) {
        return false;
    }
    for i in from..scan.len() {
        if !send_frame(rig, scan, i, seen, ctx) {
            return false;
        }
    }
    step(rig, HostMessage::Finish, seen, ctx)
}

/// Issue 36: a power cut at every flash step (every tear) of a second
/// session, its Extend and Finish included, on the device of
/// [`power_cuts_past_the_key_budget_resume_to_the_same_export`]: the
/// restored scan holds every decision the host received, and the resumed
/// session ends with the uninterrupted two-session export.
#[test]
fn power_cuts_in_a_second_session_resume_to_the_same_export() {
    on_big_stack(|| {
        const FIRST: u32 = 45;
        let scan = Scan::strided(300, 0, 70, (16, 0.5), (4, 0.1));
        // The first session, finished: every cut starts from this flash.
        let (mut rig, _) = Rig::<Tight>::boot(SimFlash::new(TIGHT_SECTORS));
        let mut seen_a = Seen::default();
        assert!(drive_to(
            &mut rig,
            &scan,
            FIRST,
            true,
            &mut seen_a,
            "first session"
        ));
        let first = rig.into_flash();
        // The uninterrupted second session, and its flash steps.
        let (mut rig, _) = Rig::<Tight>::boot(first.clone());
        let start = rig.flash().steps();
        let mut seen = seen_a.clone();
        assert!(extend_from(&mut rig, &scan, FIRST, &mut seen));
        let steps = rig.flash().steps() - start;
        let reference = rig.export();
        assert_eq!(rig.status().sessions, 2);
        let mut cuts = 0;
        for k in 0..steps {
            for tear in TEARS {
                let ctx = format!("second session: cut at step {k} ({})", tear_name(tear));
                let (mut rig, _) = Rig::<Tight>::boot(first.clone());
                let at = rig.flash().steps() + k;
                rig.flash().cut_at(at, tear);
                let mut seen = seen_a.clone();
                assert!(
                    !extend_from(&mut rig, &scan, FIRST, &mut seen),
                    "{ctx}: no cut"
                );
                cuts += 1;
                let (mut rig, restored) = Rig::<Tight>::boot(rig.into_flash());
                assert!(restored.is_ok(), "{ctx}: {restored:?}");
                let st = rig.status();
                let from = st.frames_seen;
                assert!(from >= FIRST, "{ctx}: the first session is whole");
                // A second session finished before the cut is done; any
                // other state goes on with it.
                if !(st.sessions == 2 && st.phase == Phase::Finished) {
                    assert!(extend_from(&mut rig, &scan, from, &mut seen), "{ctx}");
                }
                let export = rig.export();
                // Every decision the host received is the exported one.
                let labels: BTreeMap<u32, u32> = export
                    .iter()
                    .filter_map(|r| match r.kind {
                        RecordKind::Label { class } => Some((r.frame, class)),
                        _ => None,
                    })
                    .collect();
                for (&frame, &kind) in &seen.finals {
                    let class = match kind {
                        DecisionKind::Taken => Some(frame),
                        DecisionKind::DominatedBy(k) => Some(k),
                        _ => None,
                    };
                    if let Some(class) = class {
                        assert_eq!(labels.get(&frame), Some(&class), "{ctx}: frame {frame}");
                    }
                }
                assert_eq!(export, reference, "{ctx}: the resumed export differs");
            }
        }
        assert_eq!(cuts, 3 * steps);
        println!(
            "power cuts in a second session: {cuts} cuts over the {steps} flash steps of its \
             {} frames, every resumed export identical",
            scan.len() - FIRST
        );
    });
}

/// Issue 36 at the real sizes: the Pico's profile (`ram256k`), its 1 MiB
/// log and the real key budget (384 KiB), on the demo building walked for
/// 1,200 frames at 0.1 m voxels and mu 0.8 (~900 database frames, ~1 KB of
/// keys each), so that the budget is spent half way: a power cut at every
/// flash step of 16 frames near the end (every tear) resumes to the
/// uninterrupted export.
#[test]
fn power_cuts_past_the_real_key_budget_on_the_pico_profile() {
    on_big_stack(|| {
        type Pico = placedb::profile::Device256K;
        const LOG_SECTORS: usize = 256;
        const CUT_FRAMES: u32 = 16;
        let scan = Scan::strided(1200, 0, 1200, (32, 0.8), (4, 0.1));
        let prefix_frames = scan.len() - 40;
        // The uninterrupted run.
        let (mut rig, _) = Rig::<Pico>::boot(SimFlash::new(LOG_SECTORS));
        let mut seen = Seen::default();
        assert!(drive(&mut rig, &scan, &mut seen, "uninterrupted"));
        let sel = rig.device.selector_status();
        assert!(
            sel.stored_key_bytes >= placedb::select::database::KEY_BUDGET,
            "{sel:?}"
        );
        assert!(
            sel.unkeyed_frames > 0,
            "the key budget was not spent: {sel:?}"
        );
        let (_, reference) = check_complete(rig, &scan, &seen, "uninterrupted");
        // The prefix, past the budget already.
        let (mut rig, _) = Rig::<Pico>::boot(SimFlash::new(LOG_SECTORS));
        let mut prefix_seen = Seen::default();
        assert!(drive_to(
            &mut rig,
            &scan,
            prefix_frames,
            false,
            &mut prefix_seen,
            "prefix"
        ));
        let at_prefix = rig.device.selector_status();
        assert!(
            at_prefix.unkeyed_frames > 0,
            "the prefix is not past the budget"
        );
        let prefix = rig.into_flash();
        // The flash steps of the next frames.
        let (mut rig, restored) = Rig::<Pico>::boot(prefix.clone());
        assert!(restored.is_ok(), "{restored:?}");
        let start = rig.flash().steps();
        let mut seen = prefix_seen.clone();
        let end = prefix_frames + CUT_FRAMES;
        assert!(drive_to(&mut rig, &scan, end, false, &mut seen, "resumed"));
        let steps = rig.flash().steps() - start;
        let cuts = cut_after_prefix::<Pico>(
            (&scan, &prefix, &prefix_seen),
            steps,
            &reference,
            "real sizes",
        );
        println!(
            "power cuts past the real key budget: {} frames on ram256k, {} database frames, \
             {} key bytes in flash, {} frames after the budget was spent, {} without room in \
             the key pool; {cuts} cuts over the {steps} flash steps of frames {prefix_frames}..{end}, \
             every resumed export identical",
            scan.len(),
            reference.db.len(),
            sel.stored_key_bytes,
            sel.unkeyed_frames,
            sel.sketched_frames,
        );
    });
}

/// A cut at each of the first `steps` flash steps after the `prefix` flash
/// (the scan streamed up to where `prefix_seen` stops), every tear: each
/// restore is checked, the scan resumed to its end, and its export must be
/// `reference`. Returns the cuts made.
fn cut_after_prefix<D: AnyDevice>(
    (scan, prefix, prefix_seen): (&Scan, &SimFlash, &Seen),
    steps: u64,
    reference: &Parsed,
    what: &str,
) -> u64 {
    let mut cuts = 0;
    for k in 0..steps {
        for tear in TEARS {
            let ctx = format!("{what}: cut at step {k} ({})", tear_name(tear));
            let (mut rig, _) = Rig::<D>::boot(prefix.clone());
            let at = rig.flash().steps() + k;
            rig.flash().cut_at(at, tear);
            let mut seen = prefix_seen.clone();
            assert!(!drive(&mut rig, scan, &mut seen, &ctx), "{ctx}: no cut");
            cuts += 1;
            let ram = parse(&rig.export(), scan, &ctx);
            let (mut rig, restored) = Rig::<D>::boot(rig.into_flash());
            check_restored(&mut rig, restored, scan, &seen, &ram, Some(reference), &ctx);
            assert!(drive(&mut rig, scan, &mut seen, &ctx), "{ctx}: cut again");
            let (_, got) = check_complete(rig, scan, &seen, &ctx);
            assert_eq!(&got, reference, "{ctx}: the resumed export differs");
        }
    }
    cuts
}
