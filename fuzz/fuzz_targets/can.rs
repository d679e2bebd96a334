//! Any text as candump log lines and as a DBC file, and any bytes as a frame to decode: never a panic.
#![no_main]

use kairos_pack_can::candump;
use kairos_pack_can::dbc::Database;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    for line in text.lines() {
        let _ = candump::parse(line);
    }
    if let Ok(database) = Database::parse(&text) {
        for (id, extended) in database.messages.keys() {
            if let Some(frame) = kairos_sdk::CanFrame::new(*id, *extended, data.get(..8).unwrap_or(data)) {
                let _ = database.decode(&frame);
            }
        }
    }
});
