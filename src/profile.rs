//! Named capacity profiles: one selector type per RAM class of board.
//!
//! Every capacity is a compile-time constant; a board picks the profile that
//! fits its RAM (the firmware's `memory.x` makes an oversized choice fail to
//! link). `placedb budget` prints each profile's exact size and what it holds.

use crate::device::Device;
use crate::select::Selector;

/// Capacities of one profile, as plain numbers for reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Capacities {
    /// Profile name as the command line spells it.
    pub name: &'static str,
    /// RAM of the board class, bytes.
    pub ram: usize,
    /// Slots of the per-frame voxel set (three quarters usable).
    pub frame_voxel_slots: usize,
    /// Key pool words: exact voxel keys of kept frames.
    pub pool_words: usize,
    /// Database frames (index entries; the frames live in flash).
    pub database_frames: usize,
    /// Window frames (lookahead + 1).
    pub window: usize,
    /// Hashes per sketch.
    pub sketch: usize,
    /// Database frames held whole in RAM.
    pub resident: usize,
    /// `size_of` the selector, bytes.
    pub state_bytes: usize,
    /// `size_of` the whole device (selector, receive buffer, buffers), bytes.
    pub device_bytes: usize,
}

macro_rules! profiles {
    ($( $(#[$doc:meta])* $ty:ident, $dev:ident = $name:literal, $ram:expr,
        [$fv:expr, $pool:expr, $db:expr, $w:expr, $k:expr, $resident:expr]; )*) => {
        $(
            $(#[$doc])*
            pub type $ty = Selector<$fv, $pool, $db, $w, $k, $resident>;
            #[doc = concat!("The device of profile `", $name, "`: its selector and receive buffer.")]
            pub type $dev = Device<$fv, $pool, $db, $w, $k, $resident>;
        )*
        /// Every profile's capacities.
        pub const PROFILES: &[Capacities] = &[$(
            Capacities {
                name: $name,
                ram: $ram,
                frame_voxel_slots: $fv,
                pool_words: $pool,
                database_frames: $db,
                window: $w,
                sketch: $k,
                resident: $resident,
                state_bytes: core::mem::size_of::<$ty>(),
                device_bytes: core::mem::size_of::<$dev>(),
            },
        )*];
    };
}

profiles! {
    /// Boards with 256 KiB of RAM (e.g. RP2040).
    Ram256K, Device256K = "ram256k", 256 * 1024, [4096, 24576, 2048, 32, 64, 64];
    /// Boards with 512 KiB of RAM (e.g. RP2350, STM32F7).
    Ram512K, Device512K = "ram512k", 512 * 1024, [4096, 65536, 4096, 32, 32, 128];
    /// Boards with 1 MiB of RAM (e.g. Teensy 4.1, STM32H7).
    Ram1M, Device1M = "ram1m", 1024 * 1024, [8192, 163840, 8192, 48, 48, 128];
}

/// The profile named `name`.
pub fn by_name(name: &str) -> Option<&'static Capacities> {
    PROFILES.iter().find(|p| p.name == name)
}
