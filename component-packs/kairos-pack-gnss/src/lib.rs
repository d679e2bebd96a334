//! The GNSS pack: receivers that speak NMEA 0183.
//!
//! | type | what it does |
//! | --- | --- |
//! | `gnss.nmea` | reads NMEA sentences from a serial port, UDP, a TCP server or a file (replayed at its timing or as fast as possible); writes fixes, the receiver's UTC time, satellites, HDOP, speed, course and the sentences as text |
//!
//! Sentences are parsed by the `nmea` crate (fields and checksums); [`sentence`] turns them into readings.
//! The bytes come through the serial pack's links (`kairos_pack_serial::link`).

pub mod receiver;
pub mod sentence;

use kairos_sdk::Registry;

/// Registers the pack "gnss".
pub fn register(registry: &mut Registry) {
    registry
        .pack("gnss", env!("CARGO_PKG_VERSION"), "built-in")
        .component::<receiver::NmeaReceiver>(receiver::descriptor());
}
