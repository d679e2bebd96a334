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
use kairos_pack_recording::safe_read::{Catalog, walk};
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

/// A recording of many chunks: 24 images of noise (which does not compress), each a chunk or more, between
/// numbers on a second channel.
fn many_chunks() -> &'static [u8] {
    static BYTES: OnceLock<Vec<u8>> = OnceLock::new();
    BYTES.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("chunks.mcap");
        let mut harness = Harness::new(Recorder::info(), Recorder::default());
        harness.set_property("path", path.display().to_string()).unwrap();
        harness.set_property("chunk_size_kb", 16_i64).unwrap();
        let mut noise = 0x2545_f491_u32;
        for i in 0..24_i64 {
            let pixels: Vec<u8> = (0..96 * 64 * 3)
                .map(|_| {
                    noise ^= noise << 13;
                    noise ^= noise >> 17;
                    noise ^= noise << 5;
                    noise as u8
                })
                .collect();
            let image = Image::packed(96, 64, PixelFormat::Rgb8, Arc::<[u8]>::from(pixels)).unwrap();
            harness.push("in1", Payload::Image(image), Timestamp::from_millis(i * 100));
            for j in 0..5 {
                harness.push(
                    "in2",
                    Payload::F64((i * 5 + j) as f64),
                    Timestamp::from_millis(i * 100 + j),
                );
            }
        }
        harness.finish().unwrap();
        std::fs::read(&path).unwrap()
    })
}

/// The intact blocks of `bytes`: (offset, length, messages).
fn blocks(bytes: &[u8]) -> Vec<(u64, u64, usize)> {
    let mut blocks = Vec::new();
    let walked = walk(
        bytes,
        Catalog::default(),
        |block| blocks.push((block.offset, block.length, block.messages.len())),
        |_| {},
        |_| {},
    )
    .unwrap();
    assert!(walked.damaged.is_empty(), "{:?}", walked.damaged);
    blocks
}

/// `recover` on `bytes`: what it says, and the recovered file's report.
fn recover_bytes(bytes: &[u8]) -> (kairos_pack_recording::Recovered, kairos_pack_recording::Report) {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("damaged.mcap");
    let output = dir.path().join("recovered.mcap");
    std::fs::write(&input, bytes).unwrap();
    let recovered = kairos_pack_recording::recover(&input, &output).unwrap();
    let report = kairos_pack_recording::inspect(&output).unwrap();
    (recovered, report)
}

#[test]
fn a_chunk_failing_its_crc_is_left_out_whole_and_every_chunk_after_it_is_kept() {
    let whole = many_chunks();
    let blocks = blocks(whole);
    let total: usize = blocks.iter().map(|b| b.2).sum();
    assert!(blocks.len() >= 10, "{} blocks", blocks.len());
    // One flipped byte in the middle of the third chunk's data.
    let (offset, length, lost) = blocks[2];
    let mut bytes = whole.to_vec();
    bytes[usize::try_from(offset + length / 2).unwrap()] ^= 0x20;

    let report = inspect_bytes("flipped", &bytes).unwrap();
    assert_eq!(report.damaged_chunks.len(), 1, "{report:?}");
    let region = &report.damaged_chunks[0];
    assert_eq!((region.offset, region.length), (offset, length));
    assert_eq!(
        region.messages,
        Some(lost as u64),
        "counted from its message indexes"
    );
    assert_eq!(
        report.messages,
        (total - lost) as u64,
        "its messages are not counted as intact"
    );
    assert_eq!(report.summary_messages, Some(total as u64));
    assert!(
        report
            .damage
            .as_deref()
            .unwrap()
            .contains(&format!("bytes {offset} to"))
    );

    let (recovered, fixed) = recover_bytes(&bytes);
    assert_eq!(
        recovered.messages,
        (total - lost) as u64,
        "every intact chunk after it is kept"
    );
    assert_eq!(recovered.left_out.len(), 1);
    assert_eq!(recovered.messages_left_out(), lost as u64);
    assert!(fixed.complete && fixed.damage.is_none(), "{fixed:?}");
    assert_eq!(fixed.messages, (total - lost) as u64);
}

#[test]
fn a_chunk_whose_length_is_damaged_is_passed_and_reading_resumes_at_the_next_chunk() {
    let whole = many_chunks();
    let blocks = blocks(whole);
    let total: usize = blocks.iter().map(|b| b.2).sum();
    let (offset, _, _) = blocks[3];
    let mut bytes = whole.to_vec();
    // The length's highest byte: the record now claims more than the file holds.
    bytes[usize::try_from(offset).unwrap() + 8] ^= 0x40;
    let report = inspect_bytes("length", &bytes).unwrap();
    assert_eq!(report.damaged_chunks.len(), 1, "{report:?}");
    assert_eq!(report.damaged_chunks[0].offset, offset);
    assert_eq!(report.messages, (total - blocks[3].2) as u64, "{report:?}");
    let (recovered, _) = recover_bytes(&bytes);
    assert_eq!(recovered.messages, report.messages);
}

#[test]
fn a_file_never_closed_with_its_first_chunk_damaged_keeps_the_later_chunks() {
    // No summary (cut before it) and the first chunk, which defines the channels, damaged.
    let whole = many_chunks();
    let blocks = blocks(whole);
    let (first, first_length, lost) = blocks[0];
    let (final_offset, final_length, _) = *blocks.last().unwrap();
    let mut bytes = whole[..usize::try_from(final_offset + final_length).unwrap()].to_vec();
    bytes[usize::try_from(first + first_length / 2).unwrap()] ^= 0x01;
    let report = inspect_bytes("crashed", &bytes).unwrap();
    let total: usize = blocks.iter().map(|b| b.2).sum();
    assert!(!report.complete);
    assert_eq!(report.damaged_chunks.len(), 1, "{report:?}");
    assert_eq!(report.messages, (total - lost) as u64, "{report:?}");
}

#[test]
fn drop_counts_are_in_the_file_before_it_is_closed() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("running.mcap");
    let mut harness = Harness::new(Recorder::info(), Recorder::default());
    harness.set_property("path", path.display().to_string()).unwrap();
    harness.set_property("chunk_period_s", 0.05).unwrap();
    for i in 0..3_i64 {
        harness.push("in1", Payload::F64(i as f64), Timestamp::from_millis(i));
        harness.run().unwrap();
        std::thread::sleep(std::time::Duration::from_millis(60));
    }
    // The recorder still runs: the file as a crash now would leave it.
    let report = inspect_bytes("running", &std::fs::read(&path).unwrap()).unwrap();
    assert!(!report.complete);
    let drops = report
        .metadata
        .get("kairos.drops")
        .expect("drop counts written as it goes");
    assert!(
        drops.values().any(|counts| counts.starts_with("written=")),
        "{drops:?}"
    );
    drop(harness);
}

#[test]
fn a_file_cut_between_two_whole_chunks_is_still_reported_unclosed() {
    // A writer killed right after it wrote a chunk: no record is cut, but the data never ended.
    let whole = many_chunks();
    let (offset, length, _) = blocks(whole)[2];
    let bytes = &whole[..usize::try_from(offset + length).unwrap()];
    let walked = walk(bytes, Catalog::default(), |_| {}, |_| {}, |_| {}).unwrap();
    assert!(walked.cut_short.is_none() && walked.damaged.is_empty());
    let summary = walked.summary().expect("an unclosed file is not intact");
    assert!(summary.contains("without a data end"), "{summary}");
    let report = inspect_bytes("cut at a chunk", bytes).unwrap();
    assert!(!report.complete && report.damage.is_some(), "{report:?}");
}
