//! The host replay (`select --solver online`: the profile's selector over
//! `replay::MemStore`) decides exactly as the device (the same selector over
//! its flash log) up to the last frame the device's log accepts, on a scan
//! that fills the log while the key budget still lasts: one rule says when
//! a database frame's exact keys are stored (the selector's, see
//! `placedb::select`), and the device refuses a frame (`StorageFull`)
//! before its log could not hold the keys that rule offers.
//!
//! The scan makes keys matter: every place is taken, and from place 130 on
//! a place 129 back (evicted from RAM: 128 frames resident) is revisited
//! from 5 pixels aside, IoU 11/21 = 0.524 over mu 0.5 exactly but below
//! mu + margin by sketch. A database frame stored without its keys is not
//! found again and the revisit is taken instead of dominated.
//!
//! The log is 48 sectors of 4 KiB (a board has 256), so that it fills in
//! ~1,800 frames, in about a second.

use placedb::device::harness::{on_big_stack, Harness};
use placedb::device::Device512K;
use placedb::persist::Record;
use placedb::profile::Ram512K;
use placedb::protocol::{Config, DecisionKind, DepthRows, DeviceMessage, ErrorKind, HostMessage};
use placedb::select::database::KEY_BUDGET;
use placedb::{DepthRange, FrameMeta, Intrinsics, Pose, ScanConfig, SelectorConfig, VoxelGrid};
use placedb_host::replay::MemStore;

const WIDTH: u16 = 16;
/// Places of the scan: more than the log holds.
const PLACES: u32 = 1000;
const SECTORS: usize = 48;

fn scan_config() -> ScanConfig {
    ScanConfig {
        // One row of 16 pixels, 0.25 m apart on a wall 3.05 m ahead: 16 voxels.
        intrinsics: Intrinsics {
            width: WIDTH,
            height: 1,
            fx: 12.2,
            fy: 12.2,
            cx: 7.5,
            cy: 0.5,
        },
        depth_scale: 1000.0,
        range: DepthRange::default(),
        stride: 1,
        grid: VoxelGrid {
            voxel_size: 0.1,
            origin: [0.0; 3],
        },
    }
}

fn selector_config() -> SelectorConfig {
    SelectorConfig {
        mu: 0.5,
        window: 1,
        sketch_margin: 0.05,
    }
}

/// Place `p` (10 m apart), seen from `shift` pixels to the right.
fn pose(p: u32, shift: u32) -> Pose {
    Pose {
        translation: [0.25 * shift as f32, 10.0 * p as f32, 0.0],
        rotation: [0.0, 0.0, 0.0, 1.0],
    }
}

/// Every place seen three times, and from place 130 on a revisit of place
/// `p - 129` from 5 pixels aside; with, for a revisit, the first frame of
/// the place it revisits (the database frame that covers it).
fn frames() -> Vec<(Pose, Option<u32>)> {
    let (mut out, mut first) = (Vec::new(), Vec::new());
    for p in 0..PLACES {
        first.push(out.len() as u32);
        out.extend([(pose(p, 0), None); 3]);
        if p >= 130 {
            out.push((pose(p - 129, 5), Some(first[(p - 129) as usize])));
        }
    }
    out
}

fn finals(replies: &[DeviceMessage<'_>], out: &mut Vec<(u32, DecisionKind)>) {
    for m in replies {
        if let DeviceMessage::Decision { frame, kind } = *m {
            if kind != DecisionKind::Pending {
                out.push((frame, kind));
            }
        }
    }
}

#[test]
fn the_host_replay_decides_as_the_device_until_its_log_is_full() {
    on_big_stack(|| {
        let frames = frames();
        let row = vec![3050u16; usize::from(WIDTH)];
        let data: Vec<u8> = row.iter().flat_map(|d| d.to_le_bytes()).collect();
        // The device, until its log refuses a frame; then FrameAbort, Finish.
        let mut h = Harness::<Device512K>::new(SECTORS);
        h.ok(HostMessage::Hello(Config::new(
            &scan_config(),
            &selector_config(),
        )));
        let mut device = Vec::new();
        let mut streamed = 0u32;
        let mut full = false;
        for (i, (pose, _)) in frames.iter().enumerate() {
            let i = i as u32;
            let begin = HostMessage::FrameBegin {
                frame: i,
                timestamp: f64::from(i),
                pose: *pose,
            };
            h.ok(begin);
            h.ok(HostMessage::DepthRows(DepthRows {
                frame: i,
                first_row: 0,
                row_count: 1,
                data: &data,
            }));
            let r = h.send(HostMessage::FrameEnd { frame: i });
            if let Some(DeviceMessage::Error {
                kind: ErrorKind::StorageFull,
                ..
            }) = r.last()
            {
                h.ok(HostMessage::FrameAbort { frame: i });
                full = true;
                break;
            }
            finals(&r, &mut device);
            streamed += 1;
        }
        let r = h.ok(HostMessage::Finish);
        finals(&r, &mut device);
        assert!(
            full,
            "the log of {SECTORS} sectors held all {} frames",
            frames.len()
        );
        let st = h.status();
        let device_keys = h.device.selector().status().stored_key_bytes;
        // The host replay of the same frames.
        let mut sel = Box::new(Ram512K::new());
        sel.configure(scan_config(), selector_config()).unwrap();
        let mut store = MemStore::<32>::default();
        let mut host = Vec::new();
        let mut note = |d: placedb::FrameDecision| {
            if d.decision != placedb::Decision::Pending {
                host.push((d.index, d.decision.into()));
            }
        };
        for (i, (pose, _)) in frames.iter().enumerate().take(streamed as usize) {
            let i = i as u32;
            let meta = FrameMeta {
                index: i,
                timestamp: f64::from(i),
                pose: *pose,
            };
            sel.begin_frame(meta).unwrap();
            sel.push_rows(0, &row).unwrap();
            sel.end_frame_with(&mut store, &mut note).unwrap();
        }
        sel.finish_with(&mut store, &mut note).unwrap();
        let host_keys = sel.status().stored_key_bytes;
        // The premise: keys were worth keeping to the end, the budget lasted.
        assert!(host_keys < KEY_BUDGET, "{host_keys} key bytes");
        assert_eq!(st.uncovered_frames, 0);
        assert_eq!(st.sketched_frames, 0, "a frame without its exact keys");
        // Every database record in the log has its keys.
        let mut log = h.log.take().unwrap();
        let (mut records, mut unkeyed) = (0, Vec::new());
        log.replay(&mut |_, payload| {
            if let Ok((Record::Database { meta, keys, .. }, _)) = Record::decode(payload) {
                records += 1;
                if keys.count == 0 {
                    unkeyed.push(meta.index);
                }
            }
        })
        .unwrap();
        assert_eq!(records, st.database_size);
        assert!(
            unkeyed.is_empty(),
            "{} of {records} database records without their keys, the first of frame {:?}",
            unkeyed.len(),
            unkeyed.first()
        );
        assert_eq!(device_keys, host_keys, "key bytes stored");
        // Decisions, one by one (the first difference named).
        assert_eq!(device.len(), streamed as usize, "every frame decided");
        let first = device.iter().zip(&host).position(|(d, h)| d != h);
        assert_eq!(
            first.map(|k| (device[k], host[k])),
            None,
            "device and host replay differ ({streamed} frames streamed)"
        );
        assert_eq!(device, host);
        // Keys mattered: revisits of places long evicted from RAM, right
        // up to the end, were dominated exactly from the keys in flash.
        let revisits: Vec<_> = device
            .iter()
            .filter_map(|&(i, kind)| frames[i as usize].1.map(|p| (i, p, kind)))
            .collect();
        assert!(revisits.len() > 200, "{} revisits", revisits.len());
        let missed: Vec<_> = revisits
            .iter()
            .filter(|&&(_, place, kind)| kind != DecisionKind::DominatedBy(place))
            .collect();
        assert!(missed.is_empty(), "revisits not found again: {missed:?}");
        println!(
            "full log: {streamed} of {} frames accepted ({} database frames, {} revisits \
             dominated), every database frame with its keys ({host_keys} bytes of \
             {KEY_BUDGET}), host replay identical",
            frames.len(),
            st.database_size,
            revisits.len()
        );
    });
}
