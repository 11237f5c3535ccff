//! The protocol client on top of a [`Link`]: numbered host frames out,
//! device messages in ([`Client`]), and the one way to send a message and
//! wait for its terminal reply ([`send_and_wait`]), with the one parser of a
//! status reply ([`status_of`]).

use crate::board::error::DeviceError;
use crate::board::link::{self, Link};
use crate::board::resend::ResendTimer;
use placedb::profile::{Capacities, PROFILES};
use placedb::protocol::{
    encode, CapacitySlot, DeviceMessage, FrameDecoder, HostFrame, HostMessage, ProtocolError, Push,
    ResetCause, Status, MAX_FRAME_LEN,
};
use std::collections::HashMap;
use std::io;
use std::time::{Duration, Instant};

/// One thing received from a device.
// A Status (protocol 8's last_reset holds a panic's file name) makes a
// message 264 bytes: a Received lives for one reply on its way to a match,
// and boxing every reply would cost an allocation each.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum Received {
    /// A decoded message (every variant but `Log`, which is [`Received::Log`]).
    Message(DeviceMessage<'static>),
    /// A `DeviceMessage::Log` line.
    Log(String),
    /// A frame that could not be read (damaged on the way, or oversized).
    Damaged(ProtocolError),
}

impl Received {
    fn from_message(msg: DeviceMessage<'_>) -> Received {
        match (msg, msg.into_static()) {
            (_, Some(owned)) => Received::Message(owned),
            (DeviceMessage::Log(text), None) => Received::Log(text.to_owned()),
            (other, None) => Received::Log(format!("{other:?}")),
        }
    }

    /// The sequence number if this is the terminal reply of a host message
    /// (Ack, Status, ExportEnd, or Error with a known sequence number).
    pub fn terminal_seq(&self) -> Option<u32> {
        match self {
            Received::Message(DeviceMessage::Ack { seq })
            | Received::Message(DeviceMessage::ExportEnd { seq, .. }) => Some(*seq),
            Received::Message(DeviceMessage::Status(status)) => Some(status.seq),
            Received::Message(DeviceMessage::LogBytes(bytes)) => Some(bytes.seq),
            Received::Message(DeviceMessage::Error { seq, .. }) => *seq,
            _ => None,
        }
    }
}

/// The protocol on top of a [`Link`]: numbered host frames out, device
/// messages in.
pub struct Client<L: Link> {
    link: L,
    decoder: Box<FrameDecoder<MAX_FRAME_LEN>>,
    pending: Vec<u8>,
    next_seq: u32,
    tx: Vec<u8>,
    /// Bytes of every message's first transmission (retransmissions not
    /// counted): what a scan costs the link.
    first_sent_bytes: u64,
    /// The round trip of each kind of message (a frame's end, which decides
    /// and may write flash, takes longer than its rows), for how long
    /// [`exchange`] waits.
    resend: HashMap<&'static str, ResendTimer>,
}

impl<L: Link> Client<L> {
    /// A client whose first sequence number is drawn at random: a session
    /// nonce. A board may still send replies to an earlier session (a
    /// program killed with requests pending, a board without DTR, the QEMU
    /// board's UART): they carry that session's numbers, so they are
    /// dropped as late replies, never taken as answers to this one's.
    pub fn new(link: L) -> Client<L> {
        Client {
            link,
            decoder: Box::new(FrameDecoder::new()),
            pending: Vec::new(),
            next_seq: session_first_seq(),
            tx: vec![0u8; MAX_FRAME_LEN],
            first_sent_bytes: 0,
            resend: HashMap::new(),
        }
    }

    /// Bytes of every message sent by [`Client::send`] so far, as encoded
    /// (retransmissions by [`Client::send_as`] not counted).
    pub fn first_sent_bytes(&self) -> u64 {
        self.first_sent_bytes
    }

    /// How long [`exchange`] would first wait for a reply to a message of
    /// kind `kind` (`"DepthRows"`, `"FrameEnd"`, ...) under `ceiling`: the
    /// measured round trip of that kind, `ceiling` before any.
    pub fn first_wait(&self, kind: &str, ceiling: Duration) -> Duration {
        self.resend
            .get(kind)
            .copied()
            .unwrap_or_default()
            .first_wait(ceiling)
    }

    /// Takes a round trip of a message of kind `kind` answered at its first
    /// sending ([`exchange`]'s, and an export batch's records).
    pub(crate) fn note_round_trip(&mut self, kind: &'static str, rtt: Duration) {
        self.resend.entry(kind).or_default().sample(rtt);
    }

    /// The underlying link.
    pub fn link(&mut self) -> &mut L {
        &mut self.link
    }

    /// Gives the link back.
    pub fn into_link(self) -> L {
        self.link
    }

    /// Takes the next sequence number (for frames built by hand).
    pub fn take_seq(&mut self) -> u32 {
        let seq = self.next_seq;
        self.next_seq = self.next_seq.wrapping_add(1);
        seq
    }

    /// Sends `msg` with the next sequence number and returns that number.
    /// A frame larger than [`MAX_FRAME_LEN`] is refused with `InvalidInput`.
    pub fn send(&mut self, msg: HostMessage<'_>) -> io::Result<u32> {
        let seq = self.take_seq();
        let frame = encode(&HostFrame { seq, msg }, &mut self.tx)
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
        self.first_sent_bytes += frame.len() as u64;
        self.link.send(frame)?;
        Ok(seq)
    }

    /// Sends `msg` with sequence number `seq` (a retransmission keeps the
    /// number of the first transmission; see [`placedb::protocol`]).
    pub fn send_as(&mut self, seq: u32, msg: HostMessage<'_>) -> io::Result<()> {
        let frame = encode(&HostFrame { seq, msg }, &mut self.tx)
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
        self.link.send(frame)
    }

    /// Sends raw bytes (e.g. a deliberately damaged frame).
    pub fn send_raw(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.link.send(bytes)
    }

    /// Sends a lone 0x00 so the device drops any partial frame.
    pub fn resync(&mut self) -> io::Result<()> {
        self.link.send(&[0])
    }

    /// The next thing the device sends, within `timeout`.
    pub fn recv(&mut self, timeout: Duration) -> io::Result<Received> {
        let end = Instant::now() + timeout;
        loop {
            if !self.pending.is_empty() {
                let total = self.pending.len();
                let (consumed, outcome) = match self.decoder.push(&self.pending) {
                    Push::NeedMore => (total, None),
                    Push::Ready { remaining } => (total - remaining.len(), Some(Ok(()))),
                    Push::Error { error, remaining } => (total - remaining.len(), Some(Err(error))),
                };
                self.pending.drain(..consumed);
                match outcome {
                    Some(Ok(())) => {
                        return Ok(match self.decoder.decode::<DeviceMessage>() {
                            Ok(msg) => Received::from_message(msg),
                            Err(e) => Received::Damaged(e),
                        })
                    }
                    Some(Err(e)) => return Ok(Received::Damaged(e)),
                    None => {}
                }
            }
            let left = end.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!(
                        "no complete frame from the device within {}",
                        crate::error::seconds(timeout)
                    ),
                ));
            }
            let bytes = self.link.recv(left)?;
            self.pending.extend_from_slice(&bytes);
        }
    }

    /// Everything received until the terminal reply for `seq` (included, last),
    /// within `timeout` overall.
    pub fn replies_to(&mut self, seq: u32, timeout: Duration) -> io::Result<Vec<Received>> {
        let end = Instant::now() + timeout;
        let mut got = Vec::new();
        loop {
            let left = end.saturating_duration_since(Instant::now());
            let item = self.recv(left)?;
            let done = item.terminal_seq() == Some(seq);
            got.push(item);
            if done {
                return Ok(got);
            }
        }
    }

    /// Sends `msg` and collects the replies up to its terminal reply.
    pub fn request(
        &mut self,
        msg: HostMessage<'_>,
        timeout: Duration,
    ) -> io::Result<(u32, Vec<Received>)> {
        let seq = self.send(msg)?;
        let replies = self.replies_to(seq, timeout)?;
        Ok((seq, replies))
    }
}

/// How [`send_and_wait`] waits for a message's terminal reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wait {
    /// Once, up to this long: the link is trusted (a pipelined stream).
    Once(Duration),
    /// Stop-and-wait with retransmission ([`exchange`]): `after` this long
    /// without a reply, or on an error saying the frame was damaged, the
    /// same message again with the same sequence number, at most `retries`
    /// times.
    Resend {
        /// How long to wait for the reply before sending again.
        after: Duration,
        /// Retransmissions allowed.
        retries: usize,
    },
}

/// Sends `msg` and waits for its terminal reply as `wait` says: the one way
/// the host sends a message and waits. Returns what arrived for it (the
/// terminal reply last) and the retransmissions it took; a refusal is
/// [`DeviceError::Refused`].
pub fn send_and_wait<L: Link>(
    client: &mut Client<L>,
    msg: HostMessage<'_>,
    what: &str,
    wait: Wait,
) -> Result<(Vec<Received>, u64), DeviceError> {
    match wait {
        Wait::Once(timeout) => request(client, msg, what, timeout).map(|replies| (replies, 0)),
        Wait::Resend { after, retries } => exchange(client, msg, what, after, retries),
    }
}

/// The device's status, asked through [`send_and_wait`]; with the
/// retransmissions it took.
pub fn ask_status<L: Link>(
    client: &mut Client<L>,
    wait: Wait,
) -> Result<(Status, u64), DeviceError> {
    let (replies, resent) =
        send_and_wait(client, HostMessage::StatusRequest, "StatusRequest", wait)?;
    Ok((status_of(&replies)?, resent))
}

/// The device's status, waiting up to `timeout` for it.
pub fn status<L: Link>(client: &mut Client<L>, timeout: Duration) -> Result<Status, DeviceError> {
    ask_status(client, Wait::Once(timeout)).map(|(status, _)| status)
}

/// Sends one message and waits for its terminal reply (other messages before
/// it are returned too).
fn request<L: Link>(
    client: &mut Client<L>,
    msg: HostMessage<'_>,
    what: &str,
    timeout: Duration,
) -> Result<Vec<Received>, DeviceError> {
    let (seq, replies) = client.request(msg, timeout)?;
    match replies.last() {
        Some(Received::Message(DeviceMessage::Error { kind, .. })) => Err(DeviceError::Refused {
            what: what.to_string(),
            seq,
            kind: *kind,
        }),
        _ => Ok(replies),
    }
}

/// Sends `msg` and waits for its terminal reply, stop-and-wait: when none
/// comes in time, or an error says a frame was damaged on the way
/// ([`ErrorKind::is_damage`]), the link is resynchronised and the same
/// message is sent again with the same sequence number. The first wait is
/// the link's measured round trip ([`ResendTimer`]), each later one twice
/// the one before, up to `resend_after`; `retries` counts the resends
/// after a wait of the whole `resend_after` (or a damaged frame), so a
/// reply slower than the estimate costs a resend, never the exchange.
/// Returns what arrived for it (decisions, logs, the terminal reply last;
/// replies to other sequence numbers are dropped) and the number of
/// retransmissions. A refusal (any other error) is returned as
/// [`DeviceError::Refused`].
pub fn exchange<L: Link>(
    client: &mut Client<L>,
    msg: HostMessage<'_>,
    what: &str,
    resend_after: Duration,
    retries: usize,
) -> Result<(Vec<Received>, u64), DeviceError> {
    let seq = client.take_seq();
    let mut got = Vec::new();
    let kind = kind(&msg);
    let mut wait = client.first_wait(kind, resend_after);
    let (mut sent, mut counted) = (0u64, 0usize);
    while counted <= retries {
        if sent > 0 {
            client.resync()?;
        }
        client.send_as(seq, msg)?;
        let sent_at = Instant::now();
        let deadline = sent_at + wait;
        let mut damaged = false;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let item = match client.recv(left) {
                Ok(item) => item,
                Err(e) if e.kind() == io::ErrorKind::TimedOut => break,
                Err(e) => return Err(e.into()),
            };
            match &item {
                // Under stop-and-wait a damaged frame is ours (or a harmless
                // repeat): send again at once.
                Received::Message(DeviceMessage::Error { kind, .. }) if kind.is_damage() => {
                    damaged = true;
                    break;
                }
                Received::Message(DeviceMessage::Error { seq: Some(s), kind }) if *s == seq => {
                    return Err(DeviceError::Refused {
                        what: what.to_string(),
                        seq,
                        kind: *kind,
                    })
                }
                _ => {}
            }
            match item.terminal_seq() {
                Some(s) if s == seq => {
                    got.push(item);
                    if sent == 0 {
                        client.note_round_trip(kind, sent_at.elapsed());
                    }
                    return Ok((got, sent));
                }
                // A late reply to an earlier message.
                Some(_) => {}
                None => got.push(item),
            }
        }
        // A wait shorter than the user's only tried the estimate.
        if damaged || wait >= resend_after {
            counted += 1;
        }
        if !damaged {
            wait = ResendTimer::next_wait(wait, resend_after);
        }
        sent += 1;
    }
    Err(DeviceError::Protocol(format!(
        "no reply to {what} (seq {seq}) after {retries} retransmissions, {} apart",
        crate::error::seconds(resend_after)
    )))
}

/// A message's kind, by which its round trip is estimated.
fn kind(msg: &HostMessage<'_>) -> &'static str {
    match msg {
        HostMessage::Hello(_) => "Hello",
        HostMessage::Extend(_) => "Extend",
        HostMessage::FrameBegin { .. } => "FrameBegin",
        HostMessage::DepthRows(_) => "DepthRows",
        HostMessage::FrameEnd { .. } => "FrameEnd",
        HostMessage::FrameAbort { .. } => "FrameAbort",
        HostMessage::Finish => "Finish",
        HostMessage::StatusRequest => "StatusRequest",
        HostMessage::ExportRequest { .. } => "ExportRequest",
        HostMessage::LogRead { .. } => "LogRead",
        HostMessage::Reset => "Reset",
    }
}

/// The status a request's replies end with: the one parser of a status
/// reply.
pub fn status_of(replies: &[Received]) -> Result<Status, DeviceError> {
    match replies.last() {
        Some(Received::Message(DeviceMessage::Status(s))) => Ok(*s),
        other => Err(DeviceError::Protocol(format!(
            "expected a Status, got {other:?}"
        ))),
    }
}

/// What a status says of the device's flash, in words for a user: a
/// write that failed (reported by the flash, or read back otherwise than
/// written: a worn or protected sector, a supply too low), after which the
/// device writes nothing more in the scan; records dropped at boot.
pub fn flash_warnings(st: &Status) -> Vec<String> {
    let mut out = Vec::new();
    if st.degradation & placedb::protocol::degradation::STORAGE_FAILED != 0 {
        out.push(format!(
            "the device's flash failed a write (it reported an error, or the bytes read back \
             were not those written: a worn or write-protected sector, or a supply too low): \
             the device stopped writing, so only {} records of this scan are durable and a \
             power cut now would lose the rest (export it now; reset the device to start \
             again on fresh sectors)",
            st.stored_records
        ));
    }
    if st.degradation & placedb::protocol::degradation::TAIL_DROPPED != 0 {
        out.push(
            "at boot the device found records in its flash log that no scan can hold \
             (damaged flash) and dropped them with everything after them; the scan went on \
             from the last good record"
                .to_string(),
        );
    }
    out
}

/// Why the board last started, in words, when it restarted by itself (its
/// watchdog, or a panic and where): `None` after a power-on.
pub fn restart_words(st: &Status) -> Option<String> {
    match st.last_reset {
        ResetCause::PowerOn => None,
        ResetCause::Watchdog => Some(
            "the board restarted after its watchdog fired (its firmware hung); it restored \
             its scan from flash"
                .to_string(),
        ),
        ResetCause::Panic(place) => Some(format!(
            "the board restarted after a panic at {place}; it restored its scan from flash \
             (report the place with the firmware's version)"
        )),
    }
}

/// The profile whose capacities the device reports, if any.
pub fn device_profile(st: &Status) -> Option<&'static Capacities> {
    PROFILES.iter().find(|p| {
        st.capacity(CapacitySlot::Database).limit as usize == p.database_frames
            && st.capacity(CapacitySlot::Pool).limit as usize == p.pool_words
            && st.capacity(CapacitySlot::Window).limit as usize == p.window
            && st.capacity(CapacitySlot::FrameVoxels).limit as usize
                == p.frame_voxel_slots - p.frame_voxel_slots / 4
    })
}

pub(crate) fn check_profile(st: &Status, profile: &str) -> Result<(), DeviceError> {
    match device_profile(st) {
        Some(p) if p.name == profile => Ok(()),
        Some(p) => Err(DeviceError::Profile(format!(
            "the device runs profile {} but --profile {profile} was given: \
             the results would not match `placedb select --profile {profile}`",
            p.name
        ))),
        None => Err(DeviceError::Profile(format!(
            "the device's capacities (database {}, pool {}, window {}) match no profile",
            st.capacity(CapacitySlot::Database).limit,
            st.capacity(CapacitySlot::Pool).limit,
            st.capacity(CapacitySlot::Window).limit
        ))),
    }
}

/// A random sequence number below 2^31 (its varint stays 5 bytes at
/// most, and a session has room before it wraps), from the standard
/// library's per-process random hash keys and the clock: two sessions'
/// numbers meet with a chance of one in two billion per reply in flight.
fn session_first_seq() -> u32 {
    use std::hash::{BuildHasher, Hasher};
    let mut hasher = std::collections::hash_map::RandomState::new().build_hasher();
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default();
    hasher.write_u128(now.as_nanos());
    hasher.write_u32(std::process::id());
    (hasher.finish() as u32 & 0x7FFF_FFFF).max(1)
}

/// Opens the link `port` for the device subcommands.
pub fn connect(port: &str) -> Result<Client<Box<dyn Link>>, DeviceError> {
    let link = link::open(port, Duration::from_secs(10))?;
    Ok(Client::new(link))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::link::open;
    use placedb::protocol::{ErrorKind, Feed, Phase, Status};
    use std::io::{Read, Write};
    use std::net::TcpListener;
    use std::thread::{self, JoinHandle};

    /// Each session numbers its messages from its own random start, so a
    /// reply to an earlier session's message is not one to this one's.
    #[test]
    fn sessions_start_their_sequence_numbers_apart() {
        let starts: Vec<u32> = (0..4).map(|_| session_first_seq()).collect();
        for (i, a) in starts.iter().enumerate() {
            assert!((1..1 << 31).contains(a), "{a}");
            assert!(!starts[i + 1..].contains(a), "two sessions start at {a}");
        }
    }

    /// A fake device on loopback: answers StatusRequest with Status, logs once,
    /// refuses anything else, reports framing errors.
    fn fake_device(listener: TcpListener) -> JoinHandle<()> {
        thread::spawn(move || {
            let (mut stream, _) = listener.accept().unwrap();
            let mut decoder = FrameDecoder::<MAX_FRAME_LEN>::new();
            let mut tx = vec![0u8; 256];
            let mut buf = [0u8; 100];
            loop {
                let n = match stream.read(&mut buf) {
                    Ok(0) | Err(_) => return,
                    Ok(n) => n,
                };
                let mut rest = &buf[..n];
                while let Feed::Frame { result, remaining } = decoder.feed::<HostFrame>(rest) {
                    let mut replies = Vec::new();
                    match result {
                        Ok(HostFrame {
                            seq,
                            msg: HostMessage::StatusRequest,
                        }) => {
                            replies.push(
                                encode(&DeviceMessage::Log("status"), &mut tx)
                                    .unwrap()
                                    .to_vec(),
                            );
                            let status = DeviceMessage::Status(Status {
                                frames_seen: 3,
                                database_size: 1,
                                ..Status::new(seq, Phase::Ready)
                            });
                            replies.push(encode(&status, &mut tx).unwrap().to_vec());
                        }
                        Ok(HostFrame { seq, .. }) => {
                            let e = DeviceMessage::Error {
                                seq: Some(seq),
                                kind: ErrorKind::Internal,
                            };
                            replies.push(encode(&e, &mut tx).unwrap().to_vec());
                        }
                        Err(e) => replies.push(encode(&e.reply(), &mut tx).unwrap().to_vec()),
                    }
                    for r in replies {
                        // Byte by byte, to exercise reassembly on the host.
                        for b in r {
                            stream.write_all(&[b]).unwrap();
                        }
                    }
                    rest = remaining;
                }
            }
        })
    }

    #[test]
    fn client_over_tcp_matches_replies() {
        let listener = TcpListener::bind(("127.0.0.1", 0)).unwrap();
        let port = listener.local_addr().unwrap().port();
        let device = fake_device(listener);
        let link = open(&format!("tcp:127.0.0.1:{port}"), Duration::from_secs(5)).unwrap();
        let mut client = Client::new(link);
        client.resync().unwrap();
        let (seq, replies) = client
            .request(HostMessage::StatusRequest, Duration::from_secs(5))
            .unwrap();
        assert_eq!(replies.len(), 2);
        assert_eq!(replies[0], Received::Log("status".into()));
        assert!(matches!(
            replies[1],
            Received::Message(DeviceMessage::Status(Status { seq: s, frames_seen: 3, .. })) if s == seq
        ));
        let (seq, replies) = client
            .request(HostMessage::Reset, Duration::from_secs(5))
            .unwrap();
        assert_eq!(
            replies,
            vec![Received::Message(DeviceMessage::Error {
                seq: Some(seq),
                kind: ErrorKind::Internal
            })]
        );
        // Nothing more: a timeout, not a hang.
        let err = client.recv(Duration::from_millis(50)).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::TimedOut);
        drop(client);
        device.join().unwrap();
    }
}
