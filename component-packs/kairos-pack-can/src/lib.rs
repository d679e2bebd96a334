//! The CAN pack: logs in the candump format, and DBC decoding.
//!
//! | type | what it does |
//! | --- | --- |
//! | `can.candump_reader` | replays a candump log at its timing or as fast as possible |
//! | `can.candump_writer` | writes frames to a candump log |
//! | `can.dbc_decoder` | decodes frames with a DBC: every signal as text, and one number output per signal |
//! | `can.socketcan_reader` | a live bus through SocketCAN, classic or FD, kernel filters, error frames counted |
//! | `can.socketcan_writer` | sends frames on a live bus |
//! | `can.dbc_encoder` | encodes signals into frames of one DBC message: one input per signal |
//!
//! [`candump`] reads and writes log lines; [`dbc`] decodes and encodes signals (the `can-dbc` crate parses
//! the file).

pub mod candump;
pub mod components;
pub mod dbc;
pub mod live;

use kairos_sdk::Registry;

/// Registers the pack "can".
pub fn register(registry: &mut Registry) {
    registry
        .pack("can", env!("CARGO_PKG_VERSION"), "built-in")
        .component::<components::CandumpReader>(components::reader_descriptor())
        .component::<components::CandumpWriter>(components::writer_descriptor())
        .component_described::<components::DbcDecoder>(
            components::decoder_descriptor(),
            components::describe_decoder,
        )
        .component::<live::SocketCanReader>(live::reader_descriptor())
        .component::<live::SocketCanWriter>(live::writer_descriptor())
        .component_described::<components::DbcEncoder>(
            components::encoder_descriptor(),
            components::describe_encoder,
        );
}
