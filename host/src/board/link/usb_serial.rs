//! A board found by its USB serial number: `--port placedb.example:E6614103E7452D2F`,
//! or just the end of its hex ID (`--port 2D2F`), resolved to the serial
//! device of the one USB port whose serial number it names (the serialport
//! crate's port listing: on Linux `/sys/class/tty`, the USB device's
//! `serial`). Boards share VID:PID 16c0:27dd and are told apart by serial
//! number: the Pico firmware makes its own from its flash chip's 64-bit
//! unique ID (`boards/rp-pico/src/link.rs`).

use std::io;

/// The domain that opens a placedb board's serial number, then ":" and the
/// flash's unique ID in 16 upper-case hex digits. A placeholder (`.example`
/// is reserved and owned by no one): the project must replace it with a
/// domain it owns before boards ship. `boards/rp-pico/src/link.rs` has the
/// same constant (a test checks they agree).
pub const SERIAL_DOMAIN: &str = "placedb.example";

/// A USB serial port as the system lists it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UsbPort {
    /// The device to open (`/dev/ttyACM0`, `COM3`).
    pub path: String,
    /// The USB device's serial number, if it has one.
    pub serial: Option<String>,
}

/// Whether a `--port` value names a board by serial number rather than
/// being a path or a link: a whole serial number (`DOMAIN:ID`, the ID 16
/// hex digits) or the end of one (1 to 16 hex digits).
pub fn looks_like_serial(spec: &str) -> bool {
    let hex = |s: &str| !s.is_empty() && s.len() <= 16 && s.bytes().all(|b| b.is_ascii_hexdigit());
    match spec.rsplit_once(':') {
        Some((domain, id)) => !domain.is_empty() && id.len() == 16 && hex(id),
        None => hex(spec),
    }
}

/// Whether `serial` is the one `spec` names: equal to it (case aside), or,
/// for a hex-digit `spec`, its ID (after the last ":") ends with it.
fn names(spec: &str, serial: &str) -> bool {
    if serial.eq_ignore_ascii_case(spec) {
        return true;
    }
    if spec.contains(':') {
        return false;
    }
    let id = serial.rsplit_once(':').map_or(serial, |(_, id)| id);
    id.len() >= spec.len()
        && id
            .get(id.len() - spec.len()..)
            .is_some_and(|end| end.eq_ignore_ascii_case(spec))
}

/// The path of the one port in `ports` whose serial number `spec` names;
/// an error in words when none or several do.
pub fn resolve(spec: &str, ports: &[UsbPort]) -> io::Result<String> {
    let matching: Vec<&UsbPort> = ports
        .iter()
        .filter(|p| p.serial.as_deref().is_some_and(|s| names(spec, s)))
        .collect();
    let describe = |ps: &[&UsbPort]| {
        ps.iter()
            .map(|p| {
                format!(
                    "{} (serial {})",
                    p.path,
                    p.serial.as_deref().unwrap_or("none")
                )
            })
            .collect::<Vec<_>>()
            .join(", ")
    };
    match matching.as_slice() {
        [one] => Ok(one.path.clone()),
        [] => {
            let seen: Vec<&UsbPort> = ports.iter().collect();
            let seen = if seen.is_empty() {
                "no USB serial port is connected".to_string()
            } else {
                format!("the USB serial ports are {}", describe(&seen))
            };
            Err(io::Error::new(
                io::ErrorKind::NotFound,
                format!(
                    "no board has a USB serial number `{spec}` or one ending in it: {seen}; \
                     is the board plugged in?"
                ),
            ))
        }
        several => Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!(
                "`{spec}` is the end of {} boards' serial numbers: {}; give more of the \
                 serial number (or the device path)",
                several.len(),
                describe(several)
            ),
        )),
    }
}

/// The USB serial ports this system has now, with their serial numbers.
pub fn usb_ports() -> io::Result<Vec<UsbPort>> {
    // The crate's listing without libudev reads /sys/class/tty and panics
    // where there is none (a container without sysfs): no ports there.
    if cfg!(target_os = "linux") && !std::path::Path::new("/sys/class/tty").is_dir() {
        return Ok(Vec::new());
    }
    let ports = serialport::available_ports()
        .map_err(|e| io::Error::other(format!("cannot list the serial ports: {e}")))?;
    Ok(ports
        .into_iter()
        .filter_map(|p| match p.port_type {
            serialport::SerialPortType::UsbPort(usb) => Some(UsbPort {
                path: p.port_name,
                serial: usb.serial_number,
            }),
            _ => None,
        })
        .collect())
}

/// The serial device of the board whose USB serial number `spec` names,
/// among the ports connected now.
pub fn find(spec: &str) -> io::Result<String> {
    resolve(spec, &usb_ports()?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn port(path: &str, serial: Option<&str>) -> UsbPort {
        UsbPort {
            path: path.into(),
            serial: serial.map(Into::into),
        }
    }

    fn two_boards() -> Vec<UsbPort> {
        vec![
            port("/dev/ttyACM0", Some("placedb.example:E6614103E7452D2F")),
            port("/dev/ttyACM1", Some("placedb.example:E6614103E7451A2F")),
            port("/dev/ttyUSB0", None),
        ]
    }

    #[test]
    fn serial_numbers_and_their_ends_are_told_from_paths_and_links() {
        assert!(looks_like_serial("placedb.example:E6614103E7452D2F"));
        assert!(looks_like_serial("2d2f"));
        assert!(looks_like_serial("E6614103E7452D2F"));
        assert!(!looks_like_serial("E6614103E7452D2F0"));
        assert!(!looks_like_serial("udp:1.2.3.4:5"));
        assert!(!looks_like_serial(":E6614103E7452D2F"));
        assert!(!looks_like_serial("ttyACM0"));
        assert!(!looks_like_serial(""));
    }

    #[test]
    fn a_whole_serial_or_a_unique_end_finds_its_port() {
        let ports = two_boards();
        assert_eq!(
            resolve("placedb.example:E6614103E7452D2F", &ports).unwrap(),
            "/dev/ttyACM0"
        );
        assert_eq!(resolve("e6614103e7451a2f", &ports).unwrap(), "/dev/ttyACM1");
        assert_eq!(resolve("2D2F", &ports).unwrap(), "/dev/ttyACM0");
        assert_eq!(resolve("1a2f", &ports).unwrap(), "/dev/ttyACM1");
    }

    #[test]
    fn none_or_several_matching_is_said_in_words() {
        let ports = two_boards();
        let several = resolve("2F", &ports).unwrap_err();
        assert_eq!(several.kind(), io::ErrorKind::InvalidInput);
        let text = several.to_string();
        assert!(text.contains("2 boards"), "{text}");
        assert!(text.contains("/dev/ttyACM0") && text.contains("/dev/ttyACM1"));
        assert!(text.contains("give more of the serial number"), "{text}");

        let none = resolve("BEEF", &ports).unwrap_err();
        assert_eq!(none.kind(), io::ErrorKind::NotFound);
        let text = none.to_string();
        assert!(
            text.contains("`BEEF`") && text.contains("/dev/ttyACM1"),
            "{text}"
        );
        // Another domain's serial with the same ID is another board.
        assert!(resolve("other.example:E6614103E7452D2F", &ports).is_err());

        let empty = resolve("2D2F", &[]).unwrap_err().to_string();
        assert!(empty.contains("no USB serial port is connected"), "{empty}");
    }
}
