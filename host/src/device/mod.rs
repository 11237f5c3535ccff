//! The device client, one layer, bottom up: transports and fault injection
//! ([`link`]), the emulated boards ([`emulator`]), the protocol client with
//! the one send-and-wait ([`client`]), streaming a scan ([`scan`]), pulling
//! its results ([`export`]), and the public [`session`] a robot program
//! calls. A module imports only those before it (and [`error`]).

pub mod error;
pub mod link;
pub mod emulator;
pub mod client;
pub mod scan;
pub mod export;
pub mod session;

pub use error::DeviceError;
