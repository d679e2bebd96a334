//! Whatever a client sends, decoding it never panics: requests (text) and sample frames (binary). Run with
//! `cargo +nightly fuzz run protocol` in `fuzz/`.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = kairos_protocol::decode_request(text);
    }
    let _ = kairos_protocol::frame::decode(data);
});
