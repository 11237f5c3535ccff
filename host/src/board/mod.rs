//! The host's side of a board: the client of the device that runs on it
//! (the core's `placedb::device::Device`, on a board, an emulator or
//! in-process), one layer, bottom up: transports and fault injection
//! ([`link`]), the emulated boards ([`emulator`]), the protocol client with
//! the one send-and-wait ([`client`]; how long it waits: [`resend`]), streaming a scan ([`scan`]), pulling
//! its results ([`export`]; the flash log's records for the extension file:
//! [`log_records`]), and the public [`session`] a robot program calls.
//! Imports go one way, from the top: session → scan → export → log_records
//! → client → resend, link, emulator → link, and every one may name
//! [`error`].

pub mod client;
pub mod config_words;
pub mod emulator;
pub mod error;
pub mod export;
pub mod flash_timing;
pub mod link;
pub mod log_records;
pub mod pacing;
pub mod resend;
pub mod scan;
pub mod session;

pub use error::DeviceError;
