//! A resume is recorded: the first Hello of a host that goes on with a scan
//! restored unfinished from flash writes one `Record::Resumed` at the frames
//! seen, so that an export says how often and where the scan was resumed;
//! a retried Hello, a restart of a finished scan and an uninterrupted scan
//! write none, and the decisions are the uninterrupted scan's.

use super::*;

/// The log's records, decoded, as a host reads them with LogRead.
fn logged<D: AnyDevice>(b: &mut Harness<D>) -> Vec<Record> {
    let mut out = Vec::new();
    for record in 0..b.status().stored_records {
        let mut payload = Vec::new();
        loop {
            let offset = payload.len() as u32;
            match b.send(HostMessage::LogRead { record, offset }).last() {
                Some(DeviceMessage::LogBytes(c)) => {
                    payload.extend_from_slice(c.bytes());
                    if c.bytes().is_empty() || payload.len() >= c.total as usize {
                        break;
                    }
                }
                other => panic!("no LogBytes: {other:?}"),
            }
        }
        out.push(Record::decode(&payload).unwrap().0);
    }
    out
}

fn resumes(records: &[Record]) -> Vec<u32> {
    records
        .iter()
        .filter_map(|r| match r {
            Record::Resumed { at } => Some(*at),
            _ => None,
        })
        .collect()
}

/// Frames of the scan: a few batches of decisions.
const FRAMES: u32 = 60;

#[test]
fn a_resume_after_a_restart_is_logged_once_where_it_happened() {
    on_big_stack(|| {
        let cfg = config(4);
        let mut whole = bench::<Small>();
        whole.ok(HostMessage::Hello(cfg));
        for i in 0..FRAMES {
            frame(&mut whole, i, 5);
        }
        whole.ok(HostMessage::Finish);
        let want = whole.export();
        assert!(
            resumes(&logged(&mut whole)).is_empty(),
            "no restart, no resume"
        );
        // Cut after 22 frames, then after 41: two resumes.
        let mut b = bench::<Small>();
        b.ok(HostMessage::Hello(cfg));
        let mut next = 0;
        let mut at = Vec::new();
        for cut in [22, 41] {
            while next < cut {
                frame(&mut b, next, 5);
                next += 1;
            }
            let (again, restored) = Harness::<Small>::boot(b.into_flash());
            assert!(restored.is_ok(), "{restored:?}");
            b = again;
            let seen = b.status().frames_seen;
            assert!(seen > 0, "a batch of decisions is durable by frame {cut}");
            // The host resumes: Hello, and once more (a retry).
            b.ok(HostMessage::Hello(cfg));
            b.ok(HostMessage::Hello(cfg));
            at.push(seen);
            next = seen;
        }
        while next < FRAMES {
            frame(&mut b, next, 5);
            next += 1;
        }
        b.ok(HostMessage::Finish);
        assert_eq!(
            b.export(),
            want,
            "the resumed scan decides as the whole one"
        );
        assert_eq!(resumes(&logged(&mut b)), at);
        // A restart of the finished scan is not a resume.
        let (mut done, restored) = Harness::<Small>::boot(b.into_flash());
        assert!(restored.is_ok(), "{restored:?}");
        done.ok(HostMessage::Hello(cfg));
        assert_eq!(resumes(&logged(&mut done)), at);
        assert_eq!(done.export(), want);
    });
}
