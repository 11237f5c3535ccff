//! [`LocalLink`]: the core's device in-process (`local:PROFILE`).

use super::{recv_channel, Link};
use std::io;
use std::sync::mpsc::{self, Receiver};
use std::thread::{self, JoinHandle};
use std::time::Duration;

/// Sectors of the in-process device's flash log: 1 MiB, the log region of
/// both boards (the Pico's second MiB of QSPI flash, the QEMU board's PSRAM).
pub const LOCAL_FLASH_SECTORS: usize = 256;

/// The core's device state machine run in-process on a thread, behind the
/// same byte interface as a board: what every board runs, without hardware,
/// with its flash log on a simulated 1 MiB NOR flash.
pub struct LocalLink {
    to_device: Option<mpsc::Sender<Vec<u8>>>,
    rx: Receiver<io::Result<Vec<u8>>>,
    closed: bool,
    worker: Option<JoinHandle<()>>,
}

impl LocalLink {
    /// A fresh device of capacity profile `profile` (`ram256k`, `ram512k`, `ram1m`).
    pub fn start(profile: &str) -> io::Result<LocalLink> {
        use placedb::device::{Device1M, Device256K, Device512K};
        use placedb::persist::{sim::SimFlash, Log};
        let (to_device, inbox) = mpsc::channel::<Vec<u8>>();
        let (tx, rx) = mpsc::channel();
        /// `Device::receive` of some profile.
        type Receive<'a> = dyn FnMut(&[u8], &mut dyn FnMut(&[u8])) + 'a;
        /// Hands every chunk from the inbox to `receive` and the replies back.
        fn serve(
            receive: &mut Receive<'_>,
            inbox: Receiver<Vec<u8>>,
            tx: mpsc::Sender<io::Result<Vec<u8>>>,
        ) {
            for bytes in inbox {
                let mut out = Vec::new();
                receive(&bytes, &mut |frame: &[u8]| out.extend_from_slice(frame));
                if !out.is_empty() && tx.send(Ok(out)).is_err() {
                    return;
                }
            }
        }
        let profile = profile.to_string();
        if placedb::profile::by_name(&profile).is_none() {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("unknown profile {profile:?} (known: ram256k, ram512k, ram1m)"),
            ));
        }
        let worker = thread::Builder::new()
            .name("placedb-local-device".into())
            // A device is built on this stack before it is boxed (debug builds).
            .stack_size(64 << 20)
            .spawn(move || {
                // The boards' flash log: 1 MiB of 4 KiB sectors, in RAM here.
                let flash = SimFlash::new(LOCAL_FLASH_SECTORS);
                let end = (LOCAL_FLASH_SECTORS * SimFlash::SECTOR) as u32;
                let mut log = Log::open(flash, 0, end).expect("an erased flash opens");
                match profile.as_str() {
                    "ram256k" => {
                        let mut d = Box::new(Device256K::new());
                        serve(&mut |b, s| d.receive_logged(b, &mut log, s), inbox, tx)
                    }
                    "ram512k" => {
                        let mut d = Box::new(Device512K::new());
                        serve(&mut |b, s| d.receive_logged(b, &mut log, s), inbox, tx)
                    }
                    _ => {
                        let mut d = Box::new(Device1M::new());
                        serve(&mut |b, s| d.receive_logged(b, &mut log, s), inbox, tx)
                    }
                }
            })?;
        Ok(LocalLink {
            to_device: Some(to_device),
            rx,
            closed: false,
            worker: Some(worker),
        })
    }
}

impl Link for LocalLink {
    fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        match &self.to_device {
            Some(tx) if tx.send(bytes.to_vec()).is_ok() => Ok(()),
            _ => Err(io::ErrorKind::BrokenPipe.into()),
        }
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Vec<u8>> {
        recv_channel(&self.rx, &mut self.closed, timeout)
    }
}

impl Drop for LocalLink {
    fn drop(&mut self) {
        self.to_device = None;
        if let Some(worker) = self.worker.take() {
            let _ = worker.join();
        }
    }
}
