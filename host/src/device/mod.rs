//! The device client, bottom up: transports ([`link`]), the emulated boards
//! ([`emulator`]), streaming a scan ([`scan`]) and the public [`session`].

pub mod emulator;
pub mod link;
pub mod scan;
pub mod session;
