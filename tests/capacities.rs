//! Deterministic tests of every capacity of a small custom `placedb::Selector`
//! and of its documented degradation (src/select/mod.rs, `flags`), and of refused
//! inputs: each returns its typed error and changes nothing.
//!
//! Scenes are fronto-parallel walls seen by a camera with the identity
//! rotation: with a wide field of view and a small voxel every valid pixel is
//! a voxel of its own, so voxel counts are exact by construction, and cameras
//! 100 m apart see disjoint voxel sets.

use placedb::select::flags;
use placedb::{
    CameraError, DbRecord, Decision, DepthRange, FrameDecision, FrameError, FrameMeta, Intrinsics,
    Pose, ScanConfig, SelectError, Selector, SelectorConfig, Status, VoxelGrid,
};

/// A full-resolution depth image.
#[derive(Debug, Clone)]
struct Image {
    width: u16,
    height: u16,
    data: Vec<u16>,
}

impl Image {
    /// Every pixel at `units` (1000 per metre).
    fn wall(width: u16, height: u16, units: u16) -> Image {
        Image {
            width,
            height,
            data: vec![units; width as usize * height as usize],
        }
    }

    /// A wall at `units` where only the pixels (row-major numbers) in `valid` measure.
    fn wall_pixels(
        width: u16,
        height: u16,
        units: u16,
        valid: impl Iterator<Item = usize>,
    ) -> Image {
        let mut img = Image {
            width,
            height,
            data: vec![0; width as usize * height as usize],
        };
        for p in valid {
            img.data[p] = units;
        }
        img
    }

    /// Sampled rows at `stride`, as a board receives them: (samples per row, rows).
    fn sampled(&self, stride: u16) -> (usize, Vec<u16>) {
        let (w, s) = (self.width as usize, stride as usize);
        let mut out = Vec::new();
        for v in (0..self.height as usize).step_by(s) {
            out.extend(self.data[v * w..(v + 1) * w].iter().step_by(s));
        }
        (w.div_ceil(s), out)
    }
}

/// A pinhole of 90 degrees horizontal field of view.
fn intrinsics(width: u16, height: u16) -> Intrinsics {
    Intrinsics {
        width,
        height,
        fx: width as f32 / 2.0,
        fy: width as f32 / 2.0,
        cx: (width as f32 - 1.0) / 2.0,
        cy: (height as f32 - 1.0) / 2.0,
    }
}

/// Depth in millimetres, `voxel` metres, stride `stride`.
fn scan_config(width: u16, height: u16, voxel: f32, stride: u16) -> ScanConfig {
    ScanConfig {
        intrinsics: intrinsics(width, height),
        depth_scale: 1000.0,
        range: DepthRange::default(),
        stride,
        grid: VoxelGrid::new(voxel, [0.0; 3]).unwrap(),
    }
}

/// Looking along world +z from `(x, y, 0)`.
fn at(x: f32, y: f32) -> Pose {
    Pose::from_quaternion([x, y, 0.0], [0.0, 0.0, 0.0, 1.0]).unwrap()
}

/// One frame fed whole; its decisions appended to `log`.
fn feed<const FV: usize, const POOL: usize, const DB: usize, const W: usize, const K: usize>(
    sel: &mut Selector<FV, POOL, DB, W, K>,
    index: u32,
    pose: Pose,
    img: &Image,
    log: &mut Vec<FrameDecision>,
) {
    let stride = sel.scan_config().unwrap().stride;
    let meta = FrameMeta {
        index,
        timestamp: index as f64,
        pose,
    };
    sel.begin_frame(meta).unwrap();
    let (_, rows) = img.sampled(stride);
    sel.push_rows(0, &rows).unwrap();
    sel.end_frame(|d| log.push(d)).unwrap();
}

/// Final decisions in emission order (`Pending` dropped).
fn finals(log: &[FrameDecision]) -> Vec<(u32, Decision)> {
    log.iter()
        .filter(|d| d.decision != Decision::Pending)
        .map(|d| (d.index, d.decision))
        .collect()
}

fn database<const FV: usize, const POOL: usize, const DB: usize, const W: usize, const K: usize>(
    sel: &Selector<FV, POOL, DB, W, K>,
) -> Vec<DbRecord> {
    (0..sel.database_len())
        .map(|i| {
            sel.database_record(i, &mut placedb::select::NoStore)
                .unwrap()
        })
        .collect()
}

fn check_limits(st: &Status) {
    for u in [st.database, st.pool, st.window, st.frame_voxels] {
        assert!(u.used <= u.peak && u.peak <= u.limit, "{u:?} in {st:?}");
    }
}

fn cfg(mu: f32, window: u16) -> SelectorConfig {
    SelectorConfig {
        mu,
        window,
        ..SelectorConfig::default()
    }
}

/// (i) A frame with more distinct voxels than the frame set holds is
/// truncated to the set's limit, counted and flagged, and still decided; its
/// truncated set is deterministic, so the same view again is dominated by it.
#[test]
fn frame_voxel_set_full() {
    // 64 slots: 48 keys. A 32x32 wall at 2 m with 5 cm voxels: 1024 voxels.
    let mut sel = Box::new(Selector::<64, 4096, 8, 4, 16>::new());
    assert_eq!(sel.status().frame_voxels.limit, 48);
    sel.configure(scan_config(32, 32, 0.05, 1), cfg(0.3, 1))
        .unwrap();
    let big = Image::wall(32, 32, 2000);
    let small = Image::wall_pixels(32, 32, 2000, 0..10);
    let mut log = Vec::new();
    feed(&mut sel, 0, at(0.0, 0.0), &big, &mut log);
    let st = sel.status();
    assert_eq!(st.truncated_frames, 1);
    assert_eq!(st.flags, flags::FRAME_VOXELS_FULL);
    assert_eq!((st.frame_voxels.used, st.frame_voxels.peak), (48, 48));
    assert_eq!(st.valid_pixels, 1024);
    // A small frame far away: not truncated; the flag stays (it records what was seen).
    feed(&mut sel, 1, at(100.0, 0.0), &small, &mut log);
    let st = sel.status();
    assert_eq!(st.truncated_frames, 1);
    assert_eq!((st.frame_voxels.used, st.frame_voxels.peak), (10, 48));
    // The big view again: truncated the same way, IoU 1 with frame 0.
    feed(&mut sel, 2, at(0.0, 0.0), &big, &mut log);
    sel.finish(|d| log.push(d)).unwrap();
    assert_eq!(
        finals(&log),
        vec![
            (0, Decision::Taken),
            (1, Decision::Taken),
            (2, Decision::DominatedBy(0))
        ]
    );
    let st = sel.status();
    assert_eq!(st.truncated_frames, 2);
    assert_eq!(st.flags, flags::FRAME_VOXELS_FULL);
    assert_eq!(st.frames_decided, 3);
    check_limits(&st);
    let db = database(&sel);
    assert_eq!(
        db.iter().map(|r| r.voxels).collect::<Vec<_>>(),
        vec![48, 10]
    );
}

/// (ii) Frames whose keys do not fit the key pool are kept as sketches,
/// counted and flagged; every frame is still decided, and sketched database
/// frames still cover what they overlap.
#[test]
fn key_pool_full() {
    // 8x8 walls at 2 m, 5 cm voxels: 64 voxels each; a pool of 100 words
    // holds one frame.
    let mut sel = Box::new(Selector::<256, 100, 16, 4, 16>::new());
    sel.configure(scan_config(8, 8, 0.05, 1), cfg(0.3, u16::MAX))
        .unwrap();
    let img = Image::wall(8, 8, 2000);
    let mut log = Vec::new();
    for i in 0..8u32 {
        feed(&mut sel, i, at(100.0 * i as f32, 0.0), &img, &mut log);
        check_limits(&sel.status());
    }
    // Frame 8 sees what frame 0 saw (stored exactly), frame 9 what frame 5
    // saw (stored as a sketch).
    feed(&mut sel, 8, at(0.0, 0.0), &img, &mut log);
    feed(&mut sel, 9, at(500.0, 0.0), &img, &mut log);
    sel.finish(|d| log.push(d)).unwrap();
    let mut expect: Vec<(u32, Decision)> = (0..8).map(|i| (i, Decision::Taken)).collect();
    expect.push((8, Decision::DominatedBy(0)));
    expect.push((9, Decision::DominatedBy(5)));
    assert_eq!(finals(&log), expect);
    let st = sel.status();
    assert_eq!(st.sketched_frames, 9, "{st:?}");
    assert_eq!(st.flags, flags::POOL_FULL);
    // Each database frame gave its keys up to a later frame (oldest first),
    // and window frames free theirs on leaving: nothing exact is left.
    assert_eq!((st.pool.used, st.pool.peak, st.pool.limit), (0, 64, 100));
    assert_eq!(st.frames_decided, 10);
    assert_eq!(st.uncovered_frames, 0);
    check_limits(&st);
}

/// (ii, continued) A sketched frame counts as overlapping only above
/// `mu + sketch_margin`: a pair with IoU 1/3 is an overlap at mu 0.3 when the
/// database frame is stored exactly, not when it is a sketch (margin 0.05).
#[test]
fn sketched_frames_need_the_margin() {
    // Small sets are sketched exactly (K = 16 >= the union), so the estimate is 1/3.
    let a = Image::wall_pixels(8, 8, 2000, 0..8);
    let b = Image::wall_pixels(8, 8, 2000, 4..12);
    let far = Image::wall(8, 8, 2000);
    // Exact: a pool of 64 holds a and b.
    let mut sel = Box::new(Selector::<256, 64, 16, 1, 16>::new());
    sel.configure(scan_config(8, 8, 0.05, 1), cfg(0.3, 1))
        .unwrap();
    let mut log = Vec::new();
    feed(&mut sel, 0, at(0.0, 0.0), &a, &mut log);
    feed(&mut sel, 1, at(0.0, 0.0), &b, &mut log);
    assert_eq!(
        finals(&log),
        vec![(0, Decision::Taken), (1, Decision::DominatedBy(0))]
    );
    assert_eq!(sel.status().flags, 0);
    // Sketched: when the pool is full, the oldest database frame gives up its
    // keys. Frame 1 (a) loses them to frame 2, a 64-voxel frame elsewhere;
    // b is then compared with a by sketch and is not covered.
    let mut sel = Box::new(Selector::<256, 64, 16, 1, 16>::new());
    sel.configure(scan_config(8, 8, 0.05, 1), cfg(0.3, 1))
        .unwrap();
    let mut log = Vec::new();
    feed(&mut sel, 0, at(100.0, 0.0), &far, &mut log);
    feed(&mut sel, 1, at(0.0, 0.0), &a, &mut log);
    feed(&mut sel, 2, at(200.0, 0.0), &far, &mut log);
    feed(&mut sel, 3, at(0.0, 0.0), &b, &mut log);
    feed(&mut sel, 4, at(0.0, 0.0), &a, &mut log);
    assert_eq!(
        finals(&log),
        vec![
            (0, Decision::Taken),
            (1, Decision::Taken),
            (2, Decision::Taken),
            (3, Decision::Taken),
            (4, Decision::DominatedBy(1)),
        ]
    );
    let st = sel.status();
    assert_eq!(st.flags, flags::POOL_FULL);
    // Keys given up by frames 0, 1 and 2.
    assert_eq!(st.sketched_frames, 3);
    // Only frame 3 (b) is still exact.
    let b_voxels = database(&sel)
        .iter()
        .find(|r| r.index == 3)
        .map(|r| r.voxels);
    assert_eq!(Some(st.pool.used), b_voxels);
}

/// (ii, continued) Keys that do not fit the pool's relative encoding (a frame
/// spanning more than 2048 voxels along x) are sketched too, even with the
/// pool empty.
#[test]
fn key_box_too_wide_for_the_pool() {
    // 1 mm voxels: an 8x8 wall at 2 m spans 3.5 m, 3500 voxels along x.
    let mut sel = Box::new(Selector::<256, 4096, 4, 1, 16>::new());
    sel.configure(scan_config(8, 8, 0.001, 1), cfg(0.3, 1))
        .unwrap();
    let mut log = Vec::new();
    feed(
        &mut sel,
        0,
        at(0.0, 0.0),
        &Image::wall(8, 8, 2000),
        &mut log,
    );
    feed(
        &mut sel,
        1,
        at(0.0, 0.0),
        &Image::wall(8, 8, 2000),
        &mut log,
    );
    assert_eq!(
        finals(&log),
        vec![(0, Decision::Taken), (1, Decision::DominatedBy(0))]
    );
    let st = sel.status();
    assert_eq!(st.flags, flags::POOL_FULL);
    assert_eq!(st.sketched_frames, 2);
    assert_eq!((st.pool.used, st.pool.peak), (0, 0));
}

/// Points beyond the key range (here 400 km from the origin) are counted and
/// flagged, never wrapped; the frame is still decided.
#[test]
fn points_out_of_key_range() {
    let mut sel = Box::new(Selector::<256, 4096, 4, 2, 16>::new());
    sel.configure(scan_config(8, 8, 0.3, 1), cfg(0.3, 2))
        .unwrap();
    let img = Image::wall(8, 8, 2000);
    let mut log = Vec::new();
    feed(&mut sel, 0, at(4.0e5, 0.0), &img, &mut log);
    feed(&mut sel, 1, at(0.0, 0.0), &img, &mut log);
    sel.finish(|d| log.push(d)).unwrap();
    assert_eq!(
        finals(&log),
        vec![(0, Decision::Taken), (1, Decision::Taken)]
    );
    let st = sel.status();
    assert_eq!(st.out_of_range_points, 64);
    assert_eq!(st.flags, flags::OUT_OF_RANGE);
    assert_eq!(database(&sel)[0].voxels, 0);
}

/// (iii) With the database full, frames no database frame overlaps are
/// `Uncovered(nearest)`, counted and flagged; overlapped frames are still
/// dominated; nothing panics.
#[test]
fn database_full() {
    let mut sel = Box::new(Selector::<256, 4096, 2, 4, 16>::new());
    sel.configure(scan_config(8, 8, 0.05, 1), cfg(0.3, u16::MAX))
        .unwrap();
    let img = Image::wall(8, 8, 2000);
    let mut log = Vec::new();
    for i in 0..6u32 {
        feed(&mut sel, i, at(100.0 * i as f32, 0.0), &img, &mut log);
        check_limits(&sel.status());
    }
    // Frame 6 sees what frame 1 (in the database) saw.
    feed(&mut sel, 6, at(100.0, 0.0), &img, &mut log);
    sel.finish(|d| log.push(d)).unwrap();
    // Every IoU with the database is 0: the nearest is the lowest index, 0.
    let u = Decision::Uncovered(Some(0));
    assert_eq!(
        finals(&log),
        vec![
            (0, Decision::Taken),
            (1, Decision::Taken),
            (2, u),
            (3, u),
            (4, u),
            (5, u),
            (6, Decision::DominatedBy(1)),
        ]
    );
    let st = sel.status();
    assert_eq!(st.uncovered_frames, 4);
    assert_eq!(st.flags, flags::DATABASE_FULL);
    assert_eq!((st.database.used, st.database.limit), (2, 2));
    assert_eq!(st.frames_decided, 7);
    check_limits(&st);
    // Uncovered frames leave the pool: only the two database frames remain.
    assert_eq!(st.pool.used, 2 * 64);
    assert_eq!(
        database(&sel).iter().map(|r| r.index).collect::<Vec<_>>(),
        vec![0, 1]
    );
    // It keeps working after finish: a further frame is decided, uncovered.
    let mut more = Vec::new();
    feed(&mut sel, 7, at(900.0, 0.0), &img, &mut more);
    sel.finish(|d| more.push(d)).unwrap();
    assert_eq!(finals(&more), vec![(7, u)]);
    assert_eq!(sel.status().uncovered_frames, 5);
}

/// (iv) The window in force is clamped to the window capacity; a window of 0
/// is refused; the window never holds more frames than that.
#[test]
fn window_clamped_to_capacity() {
    let mut sel = Box::new(Selector::<256, 4096, 16, 4, 16>::new());
    let scan = scan_config(8, 8, 0.3, 1);
    for (asked, used) in [(10u16, 4u16), (u16::MAX, 4), (4, 4), (3, 3), (1, 1)] {
        sel.configure(scan, cfg(0.3, asked)).unwrap();
        assert_eq!(sel.config().unwrap().window, used, "asked {asked}");
    }
    sel.configure(scan, cfg(0.3, 64)).unwrap();
    assert_eq!(
        sel.configure(scan, cfg(0.3, 0)),
        Err(SelectError::BadConfig)
    );
    assert_eq!(sel.config().unwrap().window, 4);
    // Disjoint frames: each is decided exactly when 4 frames are held.
    let img = Image::wall(8, 8, 2000);
    let mut log = Vec::new();
    for i in 0..10u32 {
        let before = log.len();
        feed(&mut sel, i, at(100.0 * i as f32, 0.0), &img, &mut log);
        let decided: Vec<u32> = finals(&log[before..]).iter().map(|d| d.0).collect();
        let expect: Vec<u32> = if i >= 3 { vec![i - 3] } else { vec![] };
        assert_eq!(decided, expect, "at frame {i}");
        let st = sel.status();
        assert!(st.window.used <= 3 && st.window.peak <= 4, "{st:?}");
    }
    assert_eq!(sel.status().window.peak, 4);
    // Narrowed between frames: the frames held are decided at the next frame's
    // end, in order, and the new frame too (window 1).
    sel.configure(scan, cfg(0.3, 1)).unwrap();
    let before = log.len();
    feed(&mut sel, 10, at(1000.0, 0.0), &img, &mut log);
    let decided: Vec<(u32, Decision)> = finals(&log[before..]);
    assert_eq!(
        decided,
        (7..=10).map(|i| (i, Decision::Taken)).collect::<Vec<_>>()
    );
    assert_eq!(log.len() - before, 4, "no Pending with window 1");
    assert_eq!(sel.status().window.used, 0);
    assert_eq!(sel.status().frames_decided, 11);
}

/// What must not change when a step is refused.
#[derive(Debug, Clone, PartialEq)]
struct Snapshot {
    status: Status,
    database: Vec<DbRecord>,
    scan: Option<ScanConfig>,
    cfg: Option<SelectorConfig>,
    current: Option<FrameMeta>,
    samples_per_row: Option<u16>,
}

type Small = Selector<1024, 8192, 16, 3, 16>;

fn snapshot(sel: &Small) -> Snapshot {
    Snapshot {
        status: sel.status(),
        database: database(sel),
        scan: sel.scan_config().copied(),
        cfg: sel.config().copied(),
        current: sel.current_frame().copied(),
        samples_per_row: sel.samples_per_row(),
    }
}

/// Asserts that `step` fails with `expected` and leaves `sel` as it was.
#[track_caller]
fn refused<T: std::fmt::Debug>(
    sel: &mut Small,
    expected: SelectError,
    step: impl FnOnce(&mut Small) -> Result<T, SelectError>,
) {
    let before = snapshot(sel);
    let got = step(sel);
    assert_eq!(got.unwrap_err(), expected);
    assert_eq!(snapshot(sel), before, "a refused step changed the selector");
}

/// The bad-input scene: a 15x12 image (odd width, so stride 2 gives 8
/// samples per row and 6 rows) of a slanted wall, cameras 13 cm apart.
const W: u16 = 15;
const H: u16 = 12;
const STRIDE: u16 = 2;
const FRAMES: u32 = 8;

fn bad_input_scan() -> ScanConfig {
    scan_config(W, H, 0.3, STRIDE)
}

fn bad_input_cfg() -> SelectorConfig {
    cfg(0.2, 3)
}

fn bad_input_frame(i: u32) -> (FrameMeta, Image) {
    let mut img = Image::wall(W, H, 0);
    for v in 0..H as usize {
        for u in 0..W as usize {
            let p = v * W as usize + u;
            // Slanted, with a hole pattern that moves from frame to frame.
            img.data[p] = if (p + i as usize).is_multiple_of(7) {
                0
            } else {
                (1500 + 150 * u + 40 * v) as u16
            };
        }
    }
    let meta = FrameMeta {
        index: i,
        timestamp: 10.0 + i as f64,
        pose: at(0.12 * i as f32, 0.05 * i as f32),
    };
    (meta, img)
}

/// The valid frames alone, fed whole: what the abused selector must end with.
fn reference() -> (Vec<FrameDecision>, Snapshot) {
    let mut sel = Box::new(Small::new());
    sel.configure(bad_input_scan(), bad_input_cfg()).unwrap();
    let mut log = Vec::new();
    for i in 0..FRAMES {
        let (meta, img) = bad_input_frame(i);
        sel.begin_frame(meta).unwrap();
        sel.push_rows(0, &img.sampled(STRIDE).1).unwrap();
        sel.end_frame(|d| log.push(d)).unwrap();
    }
    sel.finish(|d| log.push(d)).unwrap();
    (log, snapshot(&sel))
}

/// (v) Every refused step returns its typed error and changes nothing: the
/// selector then goes on, and ends exactly as one that never saw them.
#[test]
fn bad_inputs_change_nothing() {
    let (ref_log, ref_end) = reference();
    assert!(ref_end.database.len() >= 2, "{:?}", ref_end.database);
    assert!(ref_log
        .iter()
        .any(|d| matches!(d.decision, Decision::DominatedBy(_))));

    let mut sel = Box::new(Small::new());
    let scan = bad_input_scan();
    let good = bad_input_cfg();
    let (meta0, img0) = bad_input_frame(0);
    let (width, rows0) = img0.sampled(STRIDE);
    assert_eq!(width, 8);
    let nrows = (rows0.len() / width) as u16;
    assert_eq!(nrows, 6);
    let row = |r: usize| &rows0[r * width..(r + 1) * width];
    let mut log = Vec::new();

    // Not configured yet.
    refused(&mut sel, SelectError::NotConfigured, |s| {
        s.begin_frame(meta0)
    });
    let no_frame = SelectError::Frame(FrameError::NoFrame);
    refused(&mut sel, no_frame, |s| s.push_rows(0, row(0)));
    refused(&mut sel, no_frame, |s| s.end_frame(|d| log.push(d)));

    // Invalid configurations, before and after a valid one.
    let bad_scans: Vec<ScanConfig> = {
        let mut v = Vec::new();
        for (fx, fy, cx, cy) in [
            (0.0, 7.5, 7.0, 5.5),
            (f32::NAN, 7.5, 7.0, 5.5),
            (7.5, -1.0, 7.0, 5.5),
            (7.5, f32::INFINITY, 7.0, 5.5),
            (7.5, 7.5, f32::NAN, 5.5),
            (7.5, 7.5, 7.0, f32::NEG_INFINITY),
        ] {
            let mut s = scan;
            s.intrinsics = Intrinsics {
                fx,
                fy,
                cx,
                cy,
                ..s.intrinsics
            };
            v.push(s);
        }
        let mut s = scan;
        s.intrinsics.width = 0;
        v.push(s);
        let mut s = scan;
        s.intrinsics.height = Intrinsics::MAX_SIDE + 1;
        v.push(s);
        for d in [0.0, -1000.0, f32::NAN] {
            let mut s = scan;
            s.depth_scale = d;
            v.push(s);
        }
        for stride in [0, Intrinsics::MAX_SIDE + 1] {
            let mut s = scan;
            s.stride = stride;
            v.push(s);
        }
        for range in [(1.0, 1.0), (f32::NAN, 10.0), (-1.0, 10.0), (0.1, f32::NAN)] {
            let mut s = scan;
            s.range = DepthRange {
                min: range.0,
                max: range.1,
            };
            v.push(s);
        }
        for (voxel, origin) in [(0.0, 0.0), (f32::NAN, 0.0), (-0.3, 0.0), (0.3, f32::NAN)] {
            let mut s = scan;
            s.grid = VoxelGrid {
                voxel_size: voxel,
                origin: [origin; 3],
            };
            v.push(s);
        }
        v
    };
    let bad_cfgs = [
        SelectorConfig {
            mu: f32::NAN,
            ..good
        },
        SelectorConfig { mu: 1.0, ..good },
        SelectorConfig { mu: -0.1, ..good },
        SelectorConfig { window: 0, ..good },
        SelectorConfig {
            sketch_margin: f32::NAN,
            ..good
        },
        SelectorConfig {
            sketch_margin: -0.01,
            ..good
        },
        SelectorConfig {
            sketch_margin: f32::INFINITY,
            ..good
        },
    ];
    for round in 0..2 {
        for s in &bad_scans {
            refused(&mut sel, SelectError::BadConfig, |sel| {
                sel.configure(*s, good)
            });
        }
        for c in &bad_cfgs {
            refused(&mut sel, SelectError::BadConfig, |sel| {
                sel.configure(scan, *c)
            });
        }
        if round == 0 {
            assert_eq!(sel.config(), None);
            sel.configure(scan, good).unwrap();
        }
    }
    assert_eq!(sel.scan_config(), Some(&scan));
    assert_eq!(sel.config(), Some(&good));

    // Refused frame starts.
    let with_pose = |pose: Pose| FrameMeta { pose, ..meta0 };
    let camera = |e| SelectError::Frame(FrameError::Camera(e));
    refused(
        &mut sel,
        SelectError::Frame(FrameError::WrongIndex { expected: 0 }),
        |s| s.begin_frame(FrameMeta { index: 1, ..meta0 }),
    );
    for t in [[f32::NAN, 0.0, 0.0], [0.0, f32::INFINITY, 0.0]] {
        let pose = Pose {
            translation: t,
            rotation: [0.0, 0.0, 0.0, 1.0],
        };
        refused(&mut sel, camera(CameraError::NonFinitePose), |s| {
            s.begin_frame(with_pose(pose))
        });
    }
    for q in [
        [0.0, 0.0, 0.0, 2.0],
        [0.0, 0.0, 0.0, 0.0],
        [0.5, 0.5, 0.5, 0.4],
    ] {
        let pose = Pose {
            translation: [0.0; 3],
            rotation: q,
        };
        refused(&mut sel, camera(CameraError::NotARotation), |s| {
            s.begin_frame(with_pose(pose))
        });
    }
    let nan_q = Pose {
        translation: [0.0; 3],
        rotation: [0.0, f32::NAN, 0.0, 1.0],
    };
    refused(&mut sel, camera(CameraError::NonFinitePose), |s| {
        s.begin_frame(with_pose(nan_q))
    });
    refused(&mut sel, camera(CameraError::NonFinitePose), |s| {
        s.begin_frame(FrameMeta {
            timestamp: f64::NAN,
            ..meta0
        })
    });

    // Frame 0 with every refused step a frame in progress can see.
    sel.begin_frame(meta0).unwrap();
    refused(
        &mut sel,
        SelectError::Frame(FrameError::FrameInProgress),
        |s| s.begin_frame(meta0),
    );
    refused(&mut sel, SelectError::FrameInProgress, |s| {
        s.configure(scan, good)
    });
    refused(&mut sel, SelectError::FrameInProgress, |s| {
        s.finish(|d| log.push(d))
    });
    let missing = |received| {
        SelectError::Frame(FrameError::MissingRows {
            received,
            expected: nrows,
        })
    };
    refused(&mut sel, missing(0), |s| s.end_frame(|d| log.push(d)));
    let out_of_order = |expected| SelectError::Frame(FrameError::RowOutOfOrder { expected });
    refused(&mut sel, out_of_order(0), |s| s.push_rows(1, row(1)));
    let bad_chunk = SelectError::Frame(FrameError::BadRowChunk);
    refused(&mut sel, bad_chunk, |s| s.push_rows(0, &rows0[..width + 1]));
    refused(&mut sel, bad_chunk, |s| s.push_rows(0, &rows0[..width - 1]));
    let too_many: Vec<u16> = rows0.iter().chain(row(0)).copied().collect();
    refused(&mut sel, bad_chunk, |s| s.push_rows(0, &too_many));
    sel.push_rows(0, row(0)).unwrap();
    refused(&mut sel, out_of_order(1), |s| s.push_rows(0, row(0)));
    refused(&mut sel, out_of_order(1), |s| s.push_rows(2, row(2)));
    refused(&mut sel, missing(1), |s| s.end_frame(|d| log.push(d)));
    refused(&mut sel, bad_chunk, |s| s.push_rows(1, &too_many[width..]));
    sel.push_rows(1, &rows0[width..3 * width]).unwrap();
    sel.push_rows(3, &rows0[3 * width..]).unwrap();
    // Past the last row.
    refused(&mut sel, bad_chunk, |s| s.push_rows(nrows, row(0)));
    sel.end_frame(|d| log.push(d)).unwrap();

    // The other frames, with refused steps between and inside them, and one
    // abandoned attempt.
    for i in 1..FRAMES {
        let (meta, img) = bad_input_frame(i);
        let (_, rows) = img.sampled(STRIDE);
        refused(&mut sel, no_frame, |s| s.push_rows(0, &rows[..width]));
        refused(&mut sel, no_frame, |s| s.end_frame(|d| log.push(d)));
        for wrong in [0, i - 1, i + 1, u32::MAX] {
            refused(
                &mut sel,
                SelectError::Frame(FrameError::WrongIndex { expected: i }),
                |s| {
                    s.begin_frame(FrameMeta {
                        index: wrong,
                        ..meta
                    })
                },
            );
        }
        if i == 4 {
            // Abandoned half-way: nothing of it remains.
            let (_, other) = bad_input_frame(99).1.sampled(STRIDE);
            sel.begin_frame(FrameMeta {
                pose: at(50.0, 0.0),
                ..meta
            })
            .unwrap();
            sel.push_rows(0, &other[..3 * width]).unwrap();
            sel.abort_frame();
            assert_eq!(sel.current_frame(), None);
        }
        sel.begin_frame(meta).unwrap();
        for r in 0..nrows as usize {
            refused(&mut sel, missing(r as u16), |s| {
                s.end_frame(|d| log.push(d))
            });
            sel.push_rows(r as u16, &rows[r * width..(r + 1) * width])
                .unwrap();
        }
        sel.end_frame(|d| log.push(d)).unwrap();
    }
    sel.finish(|d| log.push(d)).unwrap();
    assert_eq!(log, ref_log);
    assert_eq!(snapshot(&sel), ref_end);
}
