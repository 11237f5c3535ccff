//! Writes seed inputs of valid conversations for the raw `device` and
//! `frame_decoder` targets (whose CRC-checked frames a mutator rarely forges):
//! `cargo run --release --example seeds -- <dir>`.

use placedb::camera::{DepthRange, Intrinsics, Pose};
use placedb::protocol::{encode, Config, DepthRows, HostFrame, HostMessage, PROTOCOL_VERSION};

fn config(window: u16) -> Config {
    Config {
        version: PROTOCOL_VERSION,
        voxel_size: 0.1,
        mu: 0.3,
        depth_scale: 1000.0,
        intrinsics: Intrinsics {
            width: 16,
            height: 12,
            fx: 12.0,
            fy: 12.0,
            cx: 7.5,
            cy: 5.5,
        },
        stride: 2,
        depth_range: DepthRange::default(),
        grid_origin: [0.0; 3],
        window,
        sketch_margin: 0.05,
    }
}

fn conversation(frames: u32, window: u16, rows_per_msg: u16) -> Vec<u8> {
    let mut out = Vec::new();
    let mut buf = vec![0u8; placedb::protocol::MAX_FRAME_LEN];
    let mut seq = 0;
    let mut send = |msg: HostMessage<'_>| {
        seq += 1;
        out.extend_from_slice(encode(&HostFrame { seq, msg }, &mut buf).unwrap());
    };
    send(HostMessage::Hello(config(window)));
    for i in 0..frames {
        send(HostMessage::FrameBegin {
            frame: i,
            timestamp: f64::from(i) / 30.0,
            pose: Pose {
                translation: [0.4 * i as f32, 0.0, 0.0],
                rotation: [0.0, 0.0, 0.0, 1.0],
            },
        });
        let mut row = 0;
        while row < 6 {
            let n = rows_per_msg.min(6 - row);
            let data: Vec<u8> = (0..n * 8)
                .flat_map(|k| (2000 + 50 * (k % 8) + 100 * (i as u16 % 3)).to_le_bytes())
                .collect();
            send(HostMessage::DepthRows(DepthRows {
                frame: i,
                first_row: row,
                row_count: n,
                data: &data,
            }));
            row += n;
        }
        send(HostMessage::FrameEnd { frame: i });
    }
    send(HostMessage::Finish);
    send(HostMessage::StatusRequest);
    send(HostMessage::ExportRequest {
        from_record: 0,
        max_records: u32::MAX,
    });
    send(HostMessage::Reset);
    out
}

fn main() {
    let dir = std::env::args().nth(1).expect("usage: seeds <dir>");
    std::fs::create_dir_all(&dir).unwrap();
    let seeds = [
        (0u8, conversation(0, 1, 6)),
        (0, conversation(1, 1, 6)),
        (0, conversation(3, 2, 2)),
        (0, conversation(8, 3, 1)),
        (0, conversation(20, 4, 3)),
    ];
    for (k, (head, body)) in seeds.iter().enumerate() {
        let mut input = vec![*head];
        input.extend_from_slice(body);
        std::fs::write(format!("{dir}/seed-{k}"), &input).unwrap();
        // The same, fed in chunks of 3, 1 and 17 bytes.
        let mut chunked = vec![3u8, 2, 0, 16];
        chunked.extend_from_slice(body);
        std::fs::write(format!("{dir}/seed-{k}-chunked"), &chunked).unwrap();
    }
}
