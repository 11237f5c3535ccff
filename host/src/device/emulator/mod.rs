//! The emulated boards: the Pico under rp2040js ([`rp2040`]) and the
//! process plumbing of `placedb device` ([`foreground`]).

pub mod foreground;
pub mod rp2040;
