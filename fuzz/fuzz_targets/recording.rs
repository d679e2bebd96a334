//! Any bytes behind the MCAP magic, read as `kairos inspect` and the player read recordings: errors are
//! fine, panics and aborts are not. Run with `cargo +nightly fuzz run recording` in `fuzz/`.
#![no_main]

use kairos_pack_recording::decode::ChannelDecoder;
use kairos_pack_recording::inspect_bytes;
use kairos_pack_recording::timeline::RecordingIndex;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|tail: &[u8]| {
    let mut bytes = mcap::MAGIC.to_vec();
    bytes.extend_from_slice(tail);
    let _ = inspect_bytes("fuzz", &bytes);

    let Ok(dir) = tempfile::tempdir() else { return };
    let path = dir.path().join("fuzz.mcap");
    if std::fs::write(&path, &bytes).is_err() {
        return;
    }
    let Ok(index) = RecordingIndex::open(&path) else { return };
    for block in 0..index.block_count() {
        for message in index.read_block(block).unwrap_or_default() {
            // Each channel as the player decodes it: by its schema's name, or a rosbag2 channel through
            // the definition the file carries.
            let decoder = index.channel_definition(message.channel).map_or_else(
                || ChannelDecoder::Named(String::new()),
                |channel| ChannelDecoder::of(channel),
            );
            let _ = decoder.decode(&message.data);
        }
    }
});
