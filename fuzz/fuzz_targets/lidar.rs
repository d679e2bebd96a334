//! Any bytes as a VLP-16 packet, and as a pcap capture: never a panic.
#![no_main]

use kairos_pack_lidar::pcap::Capture;
use kairos_pack_lidar::packets::Decoder;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut decoder = Decoder::new();
    let _ = decoder.packet(data, |_| {});
    let _ = decoder.finish();
    let Ok(file) = tempfile::NamedTempFile::new() else { return };
    if std::fs::write(file.path(), data).is_ok()
        && let Ok(mut capture) = Capture::open(file.path())
    {
        while let Some(datagram) = capture.next_datagram() {
            let _ = decoder.packet(&datagram.payload, |_| {});
        }
    }
});
