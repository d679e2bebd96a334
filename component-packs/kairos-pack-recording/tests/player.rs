//! The player on the offline harness (manual clock, exact times): what was recorded comes back with both
//! times, real-time spacing scales with speed, seeks restore state, step and pause, loops, several files
//! on one timeline, damaged files.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use kairos_pack_recording::player::Player;
use kairos_pack_recording::recorder::Recorder;
use kairos_sdk::harness::Harness;
use kairos_sdk::{Payload, Sample, Timestamp, Value};

/// The recording's samples: numbers every 10 ms on `in1`, text every 25 ms on `in2`; the time of issue
/// is 3 ms after the timestamp, and the whole thing starts at `start_ms`.
fn record(path: &Path, start_ms: i64, steps: i64) -> Vec<(usize, Sample)> {
    let mut harness = Harness::new(Recorder::info(), Recorder::default());
    harness.set_property("path", path.display().to_string()).unwrap();
    harness.set_property("chunk_size_kb", 16_i64).unwrap();
    let mut written = Vec::new();
    for step in 0..steps {
        let time = start_ms + step * 5;
        let payload = if step % 2 == 0 {
            Payload::F64(step as f64 * 0.5)
        } else if step % 5 == 0 {
            Payload::Text(Arc::from(format!("note {step}")))
        } else {
            continue;
        };
        let input = usize::from(!matches!(payload, Payload::F64(_)));
        let sample = Sample {
            payload,
            timestamp: Timestamp::from_millis(time),
            time_of_issue: Timestamp::from_millis(time + 3),
            sequence: 0,
        };
        harness.push_sample(["in1", "in2"][input], sample.clone());
        written.push((input, sample));
    }
    harness.finish().unwrap();
    written
}

fn player(properties: &[(&str, Value)]) -> (Harness, Vec<String>) {
    let mut values: BTreeMap<String, Value> = Player::info()
        .properties
        .iter()
        .map(|p| (p.name.clone(), p.default.clone()))
        .collect();
    for (name, value) in properties {
        values.insert((*name).to_owned(), value.clone());
    }
    let info = Player::describe(&values).unwrap();
    let outputs = info.outputs.iter().map(|o| o.name.clone()).collect();
    let mut harness = Harness::new(info, Player::default());
    for (name, value) in properties {
        harness.set_property(name, value.clone()).unwrap();
    }
    (harness, outputs)
}

/// Runs the player `cycles` times (one sample each) and returns what came out, by output, in order.
fn run(harness: &mut Harness, cycles: usize) -> Vec<(String, Sample)> {
    let mut out = Vec::new();
    for _ in 0..cycles {
        let produced = harness.run().unwrap();
        for (name, samples) in produced.all() {
            out.extend(samples.iter().map(|s| (name.clone(), s.clone())));
        }
    }
    out
}

/// Payload and both times: what a replay must give back (sequence numbers are the output's own).
fn same(a: &Sample, b: &Sample) -> bool {
    a.payload == b.payload && a.timestamp == b.timestamp && a.time_of_issue == b.time_of_issue
}

fn path_value(path: &Path) -> Value {
    Value::Text(path.display().to_string())
}

fn temp_recording(start_ms: i64) -> (tempfile::TempDir, PathBuf, Vec<(usize, Sample)>) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("r.mcap");
    let written = record(&path, start_ms, 100);
    (dir, path, written)
}

#[test]
fn a_replay_gives_back_every_sample_with_its_values_and_both_times() {
    let (_dir, path, written) = temp_recording(1_000);
    let (mut harness, outputs) = player(&[
        ("path", path_value(&path)),
        ("mode", Value::from("as_fast_as_possible")),
    ]);
    assert_eq!(outputs.len(), 2, "one output per recorded channel: {outputs:?}");
    let replayed = run(&mut harness, written.len() + 5);
    assert_eq!(replayed.len(), written.len());
    for ((output, got), (input, sent)) in replayed.iter().zip(&written) {
        assert_eq!(output, &outputs[*input]);
        assert_eq!(got.payload, sent.payload);
        assert_eq!(got.timestamp, sent.timestamp);
        assert_eq!(got.time_of_issue, sent.time_of_issue);
    }
}

#[test]
fn real_time_keeps_the_recorded_spacing_divided_by_the_speed() {
    let (_dir, path, written) = temp_recording(1_000);
    let (mut harness, _) = player(&[
        ("path", path_value(&path)),
        ("speed", Value::F64(2.0)),
        ("times", Value::from("replay")),
    ]);
    let replayed = run(&mut harness, written.len());
    let first_sent = written[0].1.time_of_issue;
    let first_got = replayed[0].1.time_of_issue;
    for ((_, got), (_, sent)) in replayed.iter().zip(&written) {
        let recorded = sent.time_of_issue.nanos_since(first_sent);
        assert_eq!(got.time_of_issue.nanos_since(first_got), recorded / 2);
        // Moved onto the runtime clock, the latency stays what it was.
        assert_eq!(got.latency_nanos(), sent.latency_nanos());
    }
}

#[test]
fn a_seek_first_re_emits_each_output_s_last_sample_before_the_target() {
    let (_dir, path, written) = temp_recording(1_000);
    let (mut harness, outputs) = player(&[
        ("path", path_value(&path)),
        ("mode", Value::from("as_fast_as_possible")),
    ]);
    run(&mut harness, 3);
    // 0.2 s after the first message (logged at 1003 ms): the target is 1203 ms.
    harness.set_property("seek_s", 0.2).unwrap();
    let after = run(&mut harness, 4);
    let target = Timestamp::from_millis(1_203);
    let last_before = |input: usize| {
        written
            .iter()
            .rfind(|(i, s)| *i == input && s.time_of_issue < target)
            .unwrap()
            .1
            .clone()
    };
    // The two restored samples, oldest first, then the first sample at or after the target.
    let mut restored = vec![
        (outputs[0].clone(), last_before(0)),
        (outputs[1].clone(), last_before(1)),
    ];
    restored.sort_by_key(|(_, s)| s.time_of_issue);
    for ((got_output, got), (output, sent)) in after.iter().zip(&restored) {
        assert_eq!(got_output, output);
        assert!(same(got, sent), "{got:?} != {sent:?}");
    }
    let next = written.iter().find(|(_, s)| s.time_of_issue >= target).unwrap();
    assert!(same(&after[2].1, &next.1));
}

#[test]
fn step_emits_one_sample_and_pause_holds_the_rest() {
    let (_dir, path, written) = temp_recording(1_000);
    let (mut harness, _) = player(&[("path", path_value(&path)), ("start_paused", Value::Bool(true))]);
    assert!(run(&mut harness, 2).is_empty(), "paused at start");
    let stepped = harness.action("step").unwrap();
    assert!(
        stepped.all().values().all(Vec::is_empty),
        "the step happens on the next cycle"
    );
    let one = run(&mut harness, 3);
    assert_eq!(one.len(), 1);
    assert!(same(&one[0].1, &written[0].1));
    harness.action("play").unwrap();
    assert_eq!(run(&mut harness, 2).len(), 2);
}

#[test]
fn a_replay_held_at_its_end_replays_from_where_it_is_sought_or_from_the_start_on_play() {
    let (_dir, path, written) = temp_recording(1_000);
    let (mut harness, _) = player(&[
        ("path", path_value(&path)),
        ("mode", Value::from("as_fast_as_possible")),
        ("at_end", Value::from("hold")),
    ]);
    let everything = run(&mut harness, written.len());
    assert_eq!(everything.len(), written.len());
    // At the end it waits rather than ending: further cycles give nothing, and no error.
    assert!(run(&mut harness, 3).is_empty());
    assert_eq!(harness.status().unwrap()["held_at_end"], true);
    // A seek to half-way replays the second half (after each output's last sample before it).
    harness.set_property("seek_s", Value::F64(0.25)).unwrap();
    let second_half = run(&mut harness, written.len());
    let last = &written.last().unwrap().1;
    assert!(
        second_half.len() < written.len() && second_half.len() > 2,
        "{}",
        second_half.len()
    );
    assert!(same(&second_half.last().unwrap().1, last), "to the end again");
    // Play at the end starts from the start.
    harness.action("play").unwrap();
    let again = run(&mut harness, 1);
    assert!(same(&again[0].1, &written[0].1));
}

#[test]
fn a_loop_starts_again_at_the_start_offset() {
    let (_dir, path, written) = temp_recording(1_000);
    let (mut harness, _) = player(&[
        ("path", path_value(&path)),
        ("mode", Value::from("as_fast_as_possible")),
        ("loop", Value::Bool(true)),
        ("start_s", Value::F64(0.1)),
        ("end_s", Value::F64(0.3)),
    ]);
    let in_range: Vec<&Sample> = written
        .iter()
        .map(|(_, s)| s)
        .filter(|s| {
            let since = s.time_of_issue.nanos_since(Timestamp::from_millis(1_003));
            (100_000_000..=300_000_000).contains(&since)
        })
        .collect();
    // Starting past the first message restores each output's last sample before the start first.
    let replayed = run(&mut harness, 2 * (in_range.len() + 3));
    let times: Vec<Timestamp> = replayed.iter().map(|(_, s)| s.time_of_issue).collect();
    let first_pass: Vec<Timestamp> = in_range.iter().map(|s| s.time_of_issue).collect();
    let start = times.iter().position(|t| *t == first_pass[0]).unwrap();
    assert_eq!(times[start..start + first_pass.len()], first_pass[..]);
    let again = times[start + first_pass.len()..]
        .iter()
        .position(|t| *t == first_pass[0])
        .expect("the replay loops");
    assert!(again <= 2, "at most the two restored samples between passes");
}

#[test]
fn two_recordings_aligned_at_their_starts_interleave_on_one_timeline() {
    let (_a, first, written_a) = temp_recording(1_000);
    let (_b, second, written_b) = temp_recording(50_000);
    let (mut harness, outputs) = player(&[
        ("path", path_value(&first)),
        ("path2", path_value(&second)),
        ("mode", Value::from("as_fast_as_possible")),
        ("align", Value::from("start")),
    ]);
    assert_eq!(outputs.len(), 4, "names stay distinct: {outputs:?}");
    let replayed = run(&mut harness, written_a.len() + written_b.len() + 2);
    assert_eq!(replayed.len(), written_a.len() + written_b.len());
    // Aligned at their starts, sample k of both files comes out together, the first file's first.
    let from_second: Vec<&Sample> = replayed
        .iter()
        .filter(|(o, _)| o == &outputs[2] || o == &outputs[3])
        .map(|(_, s)| s)
        .collect();
    assert_eq!(from_second.len(), written_b.len());
    assert_eq!(
        from_second[0].time_of_issue, written_b[0].1.time_of_issue,
        "times are not shifted"
    );
    let position_of = |wanted: &Sample| replayed.iter().position(|(_, s)| same(s, wanted)).unwrap();
    assert_eq!(position_of(&written_b[0].1), position_of(&written_a[0].1) + 1);
}

#[test]
fn a_truncated_recording_replays_its_intact_part() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("long.mcap");
    // Long enough for several 16 KiB chunks.
    let written = record(&path, 1_000, 4_000);
    let bytes = std::fs::read(&path).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let (mut harness, _) = player(&[
        ("path", path_value(&cut)),
        ("mode", Value::from("as_fast_as_possible")),
    ]);
    let replayed = run(&mut harness, written.len());
    assert!(
        !replayed.is_empty() && replayed.len() < written.len(),
        "{} samples",
        replayed.len()
    );
    for ((_, got), (_, sent)) in replayed.iter().zip(&written) {
        assert!(same(got, sent), "{got:?} != {sent:?}");
    }
}

#[test]
fn a_missing_or_foreign_file_is_refused_naming_the_property() {
    let dir = tempfile::tempdir().unwrap();
    let mut properties: BTreeMap<String, Value> = BTreeMap::new();
    properties.insert("path".to_owned(), path_value(&dir.path().join("nothing.mcap")));
    let error = Player::describe(&properties).unwrap_err();
    assert_eq!(error.property.as_deref(), Some("path"));
    assert!(error.message.contains("nothing.mcap"), "{}", error.message);

    let text = dir.path().join("notes.txt");
    std::fs::write(&text, "not a recording").unwrap();
    properties.insert("path2".to_owned(), path_value(&text));
    let (_keep, good, _) = temp_recording(0);
    properties.insert("path".to_owned(), path_value(&good));
    let error = Player::describe(&properties).unwrap_err();
    assert_eq!(error.property.as_deref(), Some("path2"));
    assert!(
        error.message.contains("not an MCAP recording"),
        "{}",
        error.message
    );
}

#[test]
fn markers_written_by_action_and_input_are_on_the_timeline_and_the_player_jumps_to_them() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("marked.mcap");
    let mut recorder = Harness::new(Recorder::info(), Recorder::default());
    recorder.set_property("path", path.display().to_string()).unwrap();
    recorder.set_property("marker_text", "button").unwrap();
    for step in 0..100_i64 {
        recorder.push(
            "in1",
            Payload::F64(step as f64),
            Timestamp::from_millis(1_000 + step * 10),
        );
        if step == 30 {
            // A trigger input: its text is the marker's.
            recorder.push(
                "mark",
                Payload::Text(Arc::from("braking")),
                Timestamp::from_millis(1_300),
            );
        }
        if step == 70 {
            recorder.run().unwrap();
            // The action: marker_text, at the harness clock (the last sample's time).
            recorder.action("mark").unwrap();
        }
    }
    recorder.run().unwrap();
    assert_eq!(recorder.status().unwrap()["markers"], 2);
    recorder.finish().unwrap();

    let (mut harness, outputs) = player(&[
        ("path", path_value(&path)),
        ("mode", Value::from("as_fast_as_possible")),
    ]);
    assert!(
        outputs.iter().any(|o| o.contains("markers")),
        "markers replay as text: {outputs:?}"
    );
    run(&mut harness, 1);
    let status = harness.status().unwrap();
    let markers = status["markers"].as_array().unwrap();
    assert_eq!(markers.len(), 2, "{status}");
    assert_eq!(markers[0]["text"], "braking");
    assert_eq!(markers[1]["text"], "button");
    assert!(
        (markers[0]["t_s"].as_f64().unwrap() - 0.3).abs() < 1e-6,
        "{status}"
    );
    // Next marker: the replay goes on from 1.3 s (after each output's last sample before it).
    harness.action("next_marker").unwrap();
    let after = run(&mut harness, 3);
    let marker = after
        .iter()
        .find(|(o, _)| o.contains("markers"))
        .expect("the marker itself is replayed");
    assert_eq!(marker.1.payload, Payload::Text(Arc::from("braking")));
    harness.action("next_marker").unwrap();
    run(&mut harness, 3);
    let reached = harness.status().unwrap()["position_s"].as_f64().unwrap();
    assert!((reached - 0.7).abs() < 0.02, "at the second marker: {reached}");
    // Back: to the marker just played past, then, standing on it, to the one before.
    run(&mut harness, 10);
    harness.action("previous_marker").unwrap();
    let reached = harness.status().unwrap()["position_s"].as_f64().unwrap();
    assert!(
        (reached - 0.7).abs() < 1e-6,
        "back at the second marker: {reached}"
    );
    harness.action("previous_marker").unwrap();
    let reached = harness.status().unwrap()["position_s"].as_f64().unwrap();
    assert!(
        (reached - 0.3).abs() < 1e-6,
        "back at the first marker: {reached}"
    );
}

#[test]
fn the_recorder_s_status_gives_the_size_on_disk_beside_the_samples_size() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sizes.mcap");
    let mut recorder = Harness::new(Recorder::info(), Recorder::default());
    recorder.set_property("path", path.display().to_string()).unwrap();
    recorder.set_property("chunk_size_kb", 64_i64).unwrap();
    // Text that compresses well: the samples' size and the file's part ways.
    let line: Arc<str> = Arc::from("the same words again and again ".repeat(32));
    for step in 0..2_000_i64 {
        recorder.push(
            "in1",
            Payload::Text(Arc::clone(&line)),
            Timestamp::from_millis(1_000 + step),
        );
    }
    recorder.run().unwrap();
    let status = recorder.status().unwrap();
    let (bytes, disk_bytes) = (
        status["bytes"].as_u64().unwrap(),
        status["disk_bytes"].as_u64().unwrap(),
    );
    let on_disk = std::fs::metadata(&path).unwrap().len();
    assert!(bytes >= 2_000 * 992, "{status}");
    assert!(
        disk_bytes > 0 && disk_bytes <= on_disk,
        "{disk_bytes} vs {on_disk} on disk"
    );
    assert!(disk_bytes * 10 < bytes, "compressed: {status}");
    recorder.finish().unwrap();
}
