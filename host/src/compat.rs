//! The module paths of the flat layout before the crate was organised by
//! job (`placedb_host::device_cli`, `link`, `session`, `online`, ...),
//! re-exported so that code written against them keeps building. New code
//! uses the paths of [`crate::device`], [`crate::replay`],
//! [`crate::voxelize`], [`crate::yardstick`], [`crate::output`] and
//! [`crate::bench`].

#[doc(hidden)]
pub use crate::bench::{db_scaling as dbscale, pixel_cost as pixelcost};
#[doc(hidden)]
pub use crate::device::emulator::{foreground, rp2040};
#[doc(hidden)]
pub use crate::device::link::fault;
#[doc(hidden)]
pub use crate::device::session;
#[doc(hidden)]
pub use crate::output::{dataset, topview as plot};
#[doc(hidden)]
pub use crate::replay as online;
#[doc(hidden)]
pub use crate::voxelize::frame_keys;
#[doc(hidden)]
pub use crate::yardstick::{graph, metrics, solve};

/// The transports, the protocol client and the QEMU board, as one module.
#[doc(hidden)]
pub mod link {
    pub use crate::device::client::{Client, Received};
    pub use crate::device::emulator::build_board;
    pub use crate::device::emulator::qemu::{
        built_firmware, default_firmware, prepare_flash_file, qemu_command, Qemu, QemuOptions,
        FIRMWARE_BUILD, FLASH_FILE_SIZE,
    };
    pub use crate::device::link::*;
}

/// Streaming, exporting and the `placedb stream`/`export`/`device`
/// commands, as one module.
#[doc(hidden)]
pub mod device_cli {
    pub use crate::cli::export::export_cmd;
    pub use crate::cli::stream::stream_cmd;
    pub use crate::device::client::{connect, device_profile, exchange, status};
    pub use crate::device::emulator::qemu::device_cmd as qemu_device_cmd;
    pub use crate::device::error::DeviceError;
    pub use crate::device::export::{
        export, export_to, export_to_with, read_partial, resume_file, Export, ExportOptions,
    };
    pub use crate::device::scan::{
        device_config, scan_config, status_line, stream, Recovery, StreamOptions, StreamReport,
    };
}
