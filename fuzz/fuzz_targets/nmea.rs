//! Any bytes cut into lines and decoded as NMEA sentences: never a panic.
#![no_main]

use kairos_pack_gnss::sentence::Decoder;
use kairos_pack_serial::link::LineSplitter;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut decoder = Decoder::new();
    let mut splitter = LineSplitter::new(256);
    splitter.feed(data, |line| {
        if let Ok(text) = std::str::from_utf8(line) {
            let _ = decoder.decode(text);
        }
    });
});
