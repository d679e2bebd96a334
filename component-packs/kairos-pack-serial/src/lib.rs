//! The serial pack: raw reading and writing on serial ports, and the byte links (serial, UDP, TCP, files)
//! that sensor packs read through.
//!
//! | type | what it does |
//! | --- | --- |
//! | `serial.reader` | reads a serial port: one text sample per line, or one bytes sample per read |
//! | `serial.writer` | writes text (with a chosen line ending) or bytes to a serial port |

pub mod link;
pub mod port;

use kairos_sdk::Registry;

/// Registers the pack "serial".
pub fn register(registry: &mut Registry) {
    registry
        .pack("serial", env!("CARGO_PKG_VERSION"), "built-in")
        .component::<port::SerialReader>(port::reader_descriptor())
        .component::<port::SerialWriter>(port::writer_descriptor());
}
