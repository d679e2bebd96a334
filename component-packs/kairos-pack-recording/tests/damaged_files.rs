//! Reading damaged recordings never panics: truncations and random corruption of a real recording, and
//! arbitrary bytes behind the MCAP magic (a property test standing in for a fuzz target).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::sync::{Arc, OnceLock};

use kairos_pack_recording::decode::decode;
use kairos_pack_recording::inspect_bytes;
use kairos_pack_recording::recorder::Recorder;
use kairos_pack_recording::timeline::RecordingIndex;
use kairos_sdk::harness::Harness;
use kairos_sdk::{Image, Payload, PixelFormat, Timestamp};
use proptest::prelude::*;

/// A small real recording: numbers, text and images on three channels, chunks closed often.
fn recording() -> &'static [u8] {
    static BYTES: OnceLock<Vec<u8>> = OnceLock::new();
    BYTES.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("small.mcap");
        let mut harness = Harness::new(Recorder::info(), Recorder::default());
        harness.set_property("path", path.display().to_string()).unwrap();
        harness.set_property("chunk_size_kb", 16_i64).unwrap();
        for i in 0..40_i64 {
            harness.push("in1", Payload::F64(i as f64), Timestamp::from_millis(i * 10));
            harness.push(
                "in2",
                Payload::Text(Arc::from(format!("sample {i}"))),
                Timestamp::from_millis(i * 10 + 1),
            );
            if i % 10 == 0 {
                let pixels: Vec<u8> = (0..32 * 24 * 3).map(|p| (p % 256) as u8).collect();
                let image = Image::packed(32, 24, PixelFormat::Rgb8, Arc::<[u8]>::from(pixels)).unwrap();
                harness.push("in3", Payload::Image(image), Timestamp::from_millis(i * 10 + 2));
            }
        }
        harness.finish().unwrap();
        std::fs::read(&path).unwrap()
    })
}

#[test]
fn the_intact_recording_reads_back_whole() {
    let report = inspect_bytes("small", recording()).unwrap();
    assert!(report.complete && report.damage.is_none(), "{report:?}");
    assert_eq!(report.messages, 40 + 40 + 4);
    assert_eq!(report.channels.len(), 3);
}

#[test]
fn every_truncation_reads_what_it_can() {
    let whole = recording();
    let mut previous = 0;
    for len in (8..whole.len()).step_by(97) {
        let report = inspect_bytes("cut", &whole[..len]).unwrap();
        assert!(report.damage.is_some(), "a cut at {len} bytes is reported");
        // A longer prefix holds every chunk a shorter one holds.
        assert!(
            report.messages >= previous,
            "{len} bytes: {} messages, fewer than {previous}",
            report.messages
        );
        previous = report.messages;
    }
    assert!(previous > 0, "most of the file yields messages");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn corrupted_recordings_never_panic(flips in prop::collection::vec((any::<usize>(), any::<u8>()), 1..16)) {
        let mut bytes = recording().to_vec();
        let len = bytes.len();
        for (at, value) in flips {
            if let Some(byte) = bytes.get_mut(at % len) {
                *byte ^= value | 1;
            }
        }
        let _ = inspect_bytes("corrupted", &bytes);
        replay_everything(&bytes);
    }

    #[test]
    fn arbitrary_bytes_after_the_magic_never_panic(tail in prop::collection::vec(any::<u8>(), 0..4096)) {
        let mut bytes = mcap::MAGIC.to_vec();
        bytes.extend(tail);
        let _ = inspect_bytes("arbitrary", &bytes);
        replay_everything(&bytes);
    }
}

/// Opens `bytes` as the player does and reads every block it indexed, decoding every message: whatever
/// the damage, this returns (errors are fine, panics and aborts are not).
fn replay_everything(bytes: &[u8]) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("damaged.mcap");
    std::fs::write(&path, bytes).unwrap();
    let Ok(index) = RecordingIndex::open(&path) else {
        return;
    };
    let schemas: std::collections::BTreeMap<u16, String> = index
        .channels()
        .iter()
        .map(|c| (c.id, c.schema.clone()))
        .collect();
    for block in 0..index.block_count() {
        for message in index.read_block(block).unwrap_or_default() {
            let schema = schemas.get(&message.channel).map_or("", String::as_str);
            let _ = decode(schema, &message.data);
        }
    }
}

#[test]
fn the_player_reads_a_truncated_recording_up_to_the_damage() {
    let whole = recording();
    for len in (8..whole.len()).step_by(389) {
        replay_everything(&whole[..len]);
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cut.mcap");
    std::fs::write(&path, &whole[..whole.len() / 2]).unwrap();
    let index = RecordingIndex::open(&path).unwrap();
    assert!(
        index.damage().unwrap().contains("past the end of the file"),
        "{:?}",
        index.damage()
    );
    assert!(index.block_count() > 0);
}
