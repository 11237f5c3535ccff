//! placedb firmware for the MPS2 AN386 board (Cortex-M4F) under
//! `qemu-system-arm -machine mps2-an386`: the placedb wire protocol on UART0.
//!
//! The main loop is transport-agnostic: read a chunk from any
//! [`embedded_io::Read`], feed the frame decoder, hand every frame (or framing
//! error) to the handler, encode its replies and write them to any
//! [`embedded_io::Write`]. The handler is a stand-in answering `StatusRequest`
//! and refusing the rest with `Unsupported`, until `placedb::device::Device`
//! takes its place.
#![no_std]
#![no_main]

mod uart;

use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::{debug, hprintln};
use embedded_io::{Read, Write};
use placedb::protocol::{
    encode, Capacity, DeviceMessage, ErrorKind, Feed, FrameDecoder, HostFrame, HostMessage, Phase,
    ProtocolError, Status, CAPACITY_SLOTS, MAX_FRAME_LEN, PROTOCOL_VERSION,
};

/// Encode buffer for replies; every device message but a long `Log` fits.
const TX_LEN: usize = 256;
/// Bytes read from the transport per call (the UART returns what it has).
const RX_CHUNK: usize = 64;

/// Stand-in for `placedb::device::Device`.
struct Handler {
    frames_seen: u32,
}

impl Handler {
    const fn new() -> Self {
        Handler { frames_seen: 0 }
    }

    /// Answers one received frame; `reply` sends one message.
    fn handle(
        &mut self,
        frame: Result<HostFrame<'_>, ProtocolError>,
        reply: &mut impl FnMut(&DeviceMessage<'_>),
    ) {
        let HostFrame { seq, msg } = match frame {
            Ok(frame) => frame,
            Err(error) => return reply(&error.reply()),
        };
        match msg {
            HostMessage::StatusRequest => reply(&DeviceMessage::Status(Status {
                seq,
                phase: Phase::Unconfigured,
                frames_seen: self.frames_seen,
                database_size: 0,
                capacities: [Capacity::default(); CAPACITY_SLOTS],
                degradation: 0,
            })),
            _ => reply(&DeviceMessage::Error {
                seq: Some(seq),
                kind: ErrorKind::Unsupported,
            }),
        }
    }
}

/// Encodes `msg` and writes the frame; a message too large for `tx` is replaced
/// by an `Internal` error so the host still gets a reply.
fn send<W: Write>(out: &mut W, tx: &mut [u8], msg: &DeviceMessage<'_>) -> Result<(), W::Error> {
    match encode(msg, tx) {
        Ok(frame) => out.write_all(frame),
        Err(_) => {
            let fallback = DeviceMessage::Error {
                seq: None,
                kind: ErrorKind::Internal,
            };
            match encode(&fallback, tx) {
                Ok(frame) => out.write_all(frame),
                Err(_) => Ok(()),
            }
        }
    }
}

/// Runs the protocol on a byte transport until it fails.
fn serve<T: Read + Write>(
    io: &mut T,
    decoder: &mut FrameDecoder<MAX_FRAME_LEN>,
    handler: &mut Handler,
) -> T::Error {
    let mut rx = [0u8; RX_CHUNK];
    let mut tx = [0u8; TX_LEN];
    loop {
        let n = match io.read(&mut rx) {
            Ok(n) => n,
            Err(e) => return e,
        };
        let mut rest = rx.get(..n).unwrap_or_default();
        let mut failed = None;
        while let Feed::Frame { result, remaining } = decoder.feed::<HostFrame>(rest) {
            handler.handle(result, &mut |msg| {
                if failed.is_none() {
                    failed = send(io, &mut tx, msg).err();
                }
            });
            rest = remaining;
        }
        if let Some(e) = failed {
            return e;
        }
    }
}

#[entry]
fn main() -> ! {
    hprintln!(
        "placedb-qemu-mps2-an386 boot: protocol v{}, rx frame {} B",
        PROTOCOL_VERSION,
        MAX_FRAME_LEN
    );
    let Some(mut uart) = uart::Uart::take_uart0() else {
        hprintln!("UART0 unavailable");
        debug::exit(debug::EXIT_FAILURE);
        halt();
    };
    let mut decoder = FrameDecoder::<MAX_FRAME_LEN>::new();
    let mut handler = Handler::new();
    // The UART's error type is `Infallible`: `serve` never returns.
    match serve(&mut uart, &mut decoder, &mut handler) {}
}

fn halt() -> ! {
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("panic: {}", info);
    debug::exit(debug::EXIT_FAILURE);
    halt()
}

// cortex-m-rt requires the HardFault handler to be an `unsafe fn`; it performs
// no unsafe operation: it reports and makes QEMU exit with status 1.
#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    hprintln!("hard fault at pc {:#010x}", frame.pc());
    debug::exit(debug::EXIT_FAILURE);
    halt()
}
