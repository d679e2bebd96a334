//! Pre-trigger recording on the offline harness: the seconds before a trigger and after it reach the
//! file, overlapping events merge, a trigger storm stays one event, memory stays within its bound, and
//! a file that cannot be written keeps the ring.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::path::{Path, PathBuf};
use std::sync::Arc;

use kairos_pack_recording::inspect_bytes;
use kairos_pack_recording::recorder::Recorder;
use kairos_sdk::harness::Harness;
use kairos_sdk::{Payload, Timestamp, Value};

fn recorder(path: &Path, properties: &[(&str, Value)]) -> Harness {
    let mut harness = Harness::new(Recorder::info(), Recorder::default());
    harness.set_property("path", path.display().to_string()).unwrap();
    harness.set_property("mode", "pre_trigger").unwrap();
    harness.set_property("pre_trigger_s", 1.0).unwrap();
    harness.set_property("post_trigger_s", 2.0).unwrap();
    for (name, value) in properties {
        harness.set_property(name, value.clone()).unwrap();
    }
    harness
}

/// Numbers every 10 ms on in1 from 0 to `seconds`, with triggers at the times given (seconds).
fn drive(harness: &mut Harness, seconds: i64, triggers: &[f64]) {
    for ms in (0..seconds * 1000).step_by(10) {
        harness.push(
            "in1",
            Payload::F64(ms as f64 / 1000.0),
            Timestamp::from_millis(ms),
        );
        for t in triggers {
            if (t * 1000.0).round() as i64 == ms {
                harness.push("trigger", Payload::Bool(true), Timestamp::from_millis(ms));
            }
        }
    }
    harness.run().unwrap();
}

/// The recorded values of in1, per file, files in name order.
fn files(dir: &Path) -> Vec<(PathBuf, Vec<f64>)> {
    let mut paths: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    paths.sort();
    paths
        .into_iter()
        .map(|path| {
            let bytes = std::fs::read(&path).unwrap();
            let mut values = Vec::new();
            kairos_pack_recording::safe_read::read_intact(
                &bytes,
                |message| {
                    let schema = message.channel.schema.as_ref().map_or("", |s| s.name.as_str());
                    if let Ok(Payload::F64(v)) = kairos_pack_recording::decode::decode(schema, &message.data)
                    {
                        values.push(v);
                    }
                },
                |_| {},
            );
            (path, values)
        })
        .collect()
}

#[test]
fn an_event_holds_the_second_before_its_trigger_and_the_two_after() {
    let dir = tempfile::tempdir().unwrap();
    let mut harness = recorder(&dir.path().join("events.mcap"), &[]);
    drive(&mut harness, 10, &[5.0]);
    let status = harness.status().unwrap();
    harness.finish().unwrap();
    let recorded = files(dir.path());
    assert_eq!(recorded.len(), 1, "{recorded:?}");
    let values = &recorded[0].1;
    assert!(
        (values[0] - 4.0).abs() < 1e-9 && (values[values.len() - 1] - 7.0).abs() < 1e-9,
        "{values:?}"
    );
    assert_eq!(values.len(), 301, "every sample from 4 s to 7 s, once");
    assert_eq!(status["events"], 1, "{status}");
    let report = inspect_bytes("events", &std::fs::read(&recorded[0].0).unwrap()).unwrap();
    assert!(
        report.complete,
        "the event's file is closed when the event ends: {report:?}"
    );
}

#[test]
fn overlapping_events_merge_and_separate_ones_get_files_of_their_own() {
    let dir = tempfile::tempdir().unwrap();
    let mut harness = recorder(&dir.path().join("events.mcap"), &[]);
    // 2 s and 3 s overlap (one event, 1 to 5 s); 8 s is another (7 to 10 s, cut by the end).
    drive(&mut harness, 10, &[2.0, 3.0, 8.0]);
    harness.finish().unwrap();
    let events = files(dir.path());
    assert_eq!(events.len(), 2, "{events:?}");
    let first = &events[0].1;
    assert!((first[0] - 1.0).abs() < 1e-9 && (first[first.len() - 1] - 5.0).abs() < 1e-9);
    assert!((events[1].1[0] - 7.0).abs() < 1e-9);
    // In one file instead: the same samples, both events.
    let single = tempfile::tempdir().unwrap();
    let mut harness = recorder(
        &single.path().join("all.mcap"),
        &[("event_files", Value::from("single_file"))],
    );
    drive(&mut harness, 10, &[2.0, 3.0, 8.0]);
    harness.finish().unwrap();
    let all = files(single.path());
    assert_eq!(all.len(), 1);
    assert_eq!(all[0].1.len(), first.len() + events[1].1.len());
}

#[test]
fn a_trigger_storm_is_one_event_and_memory_stays_within_its_bound() {
    let dir = tempfile::tempdir().unwrap();
    let mut harness = recorder(&dir.path().join("storm.mcap"), &[("ring_mb", Value::from(1.0))]);
    // 1000 triggers a second for three seconds, from 3 s (below).
    for ms in (0..10_000).step_by(10) {
        harness.push(
            "in1",
            Payload::F64(ms as f64 / 1000.0),
            Timestamp::from_millis(ms),
        );
        // 20 kB of bytes on in2 every 10 ms: twice what the ring may hold over its second.
        harness.push(
            "in2",
            Payload::Bytes(Arc::from(vec![7_u8; 20_000])),
            Timestamp::from_millis(ms),
        );
        for sub in 0..10 {
            let at = ms + sub;
            if (3000..6000).contains(&at) {
                harness.push("trigger", Payload::Bool(true), Timestamp::from_millis(at));
            }
        }
        if ms == 2000 {
            harness.run().unwrap();
            let status = harness.status().unwrap();
            let held = status["ring_bytes"].as_u64().unwrap();
            assert!(held <= 1_000_000, "the ring holds {held} bytes, over its 1 MB");
            assert!(status["ring_dropped"].as_u64().unwrap() > 0, "{status}");
        }
    }
    harness.run().unwrap();
    let status = harness.status().unwrap();
    harness.finish().unwrap();
    assert_eq!(status["events"], 1, "{status}");
    assert_eq!(files(dir.path()).len(), 1);
}

#[test]
fn a_file_that_cannot_be_written_names_the_error_and_keeps_the_ring() {
    let dir = tempfile::tempdir().unwrap();
    // A plain file where the events' folder should be: no event file can be created. (A file or folder
    // at the event file's own name would be kept, the event written beside it.)
    std::fs::write(dir.path().join("plain"), "").unwrap();
    let mut harness = recorder(&dir.path().join("plain/blocked.mcap"), &[]);
    drive(&mut harness, 3, &[2.0]);
    let status = harness.status().unwrap();
    let error = status["last_error"].as_str().unwrap_or_default();
    assert!(
        error.contains("plain") && error.contains("still in memory"),
        "{status}"
    );
    assert!(
        status["ring_s"].as_f64().unwrap() > 0.9,
        "the ring is kept: {status}"
    );
}
