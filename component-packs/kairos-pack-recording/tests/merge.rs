//! `merge`: recordings of several hosts on one timeline, channels prefixed by host; clashing names and
//! unsynchronised clocks refused with the reason, or marked when allowed.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::path::Path;
use std::sync::Arc;

use kairos_pack_recording::merge::{MergeError, MergeInput, MergeOptions, merge};
use kairos_pack_recording::recorder::Recorder;
use kairos_pack_recording::timeline::RecordingIndex;
use kairos_sdk::harness::Harness;
use kairos_sdk::{Payload, Timestamp};

/// Numbers every 10 ms from `start_ms`, and one marker.
fn record(path: &Path, start_ms: i64) {
    let mut harness = Harness::new(Recorder::info(), Recorder::default());
    harness.set_property("path", path.display().to_string()).unwrap();
    for step in 0..50_i64 {
        harness.push(
            "in1",
            Payload::F64(step as f64),
            Timestamp::from_millis(start_ms + step * 10),
        );
        if step == 20 {
            harness.push(
                "mark",
                Payload::Text(Arc::from("here")),
                Timestamp::from_millis(start_ms + step * 10),
            );
        }
    }
    harness.finish().unwrap();
}

#[test]
fn two_hosts_recordings_become_one_timeline_with_prefixed_channels() {
    let dir = tempfile::tempdir().unwrap();
    let (car, roadside) = (dir.path().join("car.mcap"), dir.path().join("rsu.mcap"));
    record(&car, 1_000);
    record(&roadside, 1_005);
    let output = dir.path().join("one.mcap");
    let inputs = [
        MergeInput::parse(car.to_str().unwrap()),
        MergeInput::parse(&format!("roadside={}", roadside.display())),
    ];
    // Both were made on one clock (the same description: here the offline harness's), so their times
    // line up: no flag needed. Clocks of different runtimes that were not locked are refused (tests/recording.rs).
    let merged = merge(&inputs, &output, MergeOptions::default()).unwrap();
    assert_eq!(merged.messages, 2 * 51);
    assert!(merged.unsynchronised.is_empty());
    let index = RecordingIndex::open(&output).unwrap();
    let mut topics: Vec<&str> = index.channels().iter().map(|c| c.topic.as_str()).collect();
    topics.sort_unstable();
    assert_eq!(
        topics,
        [
            "car/harness.in1",
            "car/kairos.markers",
            "roadside/harness.in1",
            "roadside/kairos.markers"
        ]
    );
    assert_eq!(
        index.markers().len(),
        2,
        "the markers of both, found under their prefixes"
    );
    let report = kairos_pack_recording::inspect(&output).unwrap();
    assert!(
        report.metadata["kairos.merge"].contains_key("host roadside"),
        "{:?}",
        report.metadata
    );
    // Interleaved by time: the first messages alternate between the hosts.
    let first = index.read_block(0).unwrap();
    assert!(first.windows(2).all(|w| w[0].log_time <= w[1].log_time));
}

#[test]
fn two_recordings_under_one_host_name_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a.mcap"), dir.path().join("b.mcap"));
    record(&a, 0);
    record(&b, 0);
    let inputs = [
        MergeInput::parse(&format!("car={}", a.display())),
        MergeInput::parse(&format!("car={}", b.display())),
    ];
    let error = merge(
        &inputs,
        &dir.path().join("one.mcap"),
        MergeOptions {
            allow_unsynchronised: true,
            ..MergeOptions::default()
        },
    )
    .unwrap_err();
    assert!(
        matches!(&error, MergeError::SameHost { host, .. } if host == "car"),
        "{error:?}"
    );
    let error = error.to_string();
    assert!(error.contains("both put their channels under 'car/'"), "{error}");
}
