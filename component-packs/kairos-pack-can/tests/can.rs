//! The CAN components on logs and databases written from the formats: replay at the log's timing, bad
//! lines counted, decoding to signals, writing logs that read back.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::collections::BTreeMap;

use kairos_pack_can::components::{
    CandumpReader, CandumpWriter, DbcDecoder, DbcEncoder, decoder_descriptor, describe_decoder,
    describe_encoder, reader_descriptor, writer_descriptor,
};
use kairos_sdk::harness::{Harness, HarnessOutput};
use kairos_sdk::{CanFrame, Payload, Timestamp, Value};

const DBC: &str = "VERSION \"\"\n\nNS_ :\n\nBS_:\n\nBU_: ECU DASH\n\nBO_ 256 Engine: 8 ECU\n SG_ Speed : 0|16@1+ (0.25,0) [0|16383.75] \"rpm\" DASH\n SG_ Temperature : 16|8@1- (1,-40) [-168|87] \"degC\" DASH\n";

fn reader(path: &std::path::Path, replay: &str) -> Harness {
    let mut harness = Harness::new(reader_descriptor(), CandumpReader::default());
    harness.set_property("path", path.display().to_string()).unwrap();
    harness.set_property("replay", replay).unwrap();
    harness
}

fn run(mut harness: Harness, cycles: usize) -> (HarnessOutput, serde_json::Value) {
    let mut out = HarnessOutput::default();
    for _ in 0..cycles {
        out.extend(harness.run().unwrap());
    }
    let status = harness.status().unwrap_or_default();
    out.extend(harness.finish().unwrap());
    (out, status)
}

#[test]
fn a_log_replays_at_its_timing_and_bad_lines_and_error_frames_are_counted() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("bus.log");
    std::fs::write(
        &log,
        "(100.000000) can0 100#40001401\n\
         not a frame\n\
         (100.020000) can0 20000080#0000000000000000\n\
         (100.050000) can1 1ABCDEF0#01\n\
         (100.250000) can0 100#80001401\n",
    )
    .unwrap();
    let harness = reader(&log, "timing");
    let started = harness.now();
    let (out, status) = run(harness, 6);
    let frames = out.samples("frame");
    assert_eq!(frames.len(), 3);
    let offsets: Vec<i64> = frames
        .iter()
        .map(|s| (s.timestamp.0 - started.0) / 1_000_000)
        .collect();
    assert_eq!(offsets, [0, 50, 250]);
    assert_eq!(
        (status["malformed"].as_u64(), status["error_frames"].as_u64()),
        (Some(1), Some(1)),
        "{status}"
    );

    let mut only = reader(&log, "fast");
    only.set_property("interface", "can1").unwrap();
    let (out, _) = run(only, 6);
    assert_eq!(out.samples("frame").len(), 1);
}

#[test]
fn the_decoder_gives_signals_by_name_with_units_and_a_number_output_each() {
    let dir = tempfile::tempdir().unwrap();
    let dbc = dir.path().join("engine.dbc");
    std::fs::write(&dbc, DBC).unwrap();
    let properties = BTreeMap::from([("dbc".to_owned(), Value::Text(dbc.display().to_string()))]);
    let info = describe_decoder(&properties).unwrap();
    let outputs: Vec<&str> = info.outputs.iter().map(|o| o.name.as_str()).collect();
    assert_eq!(outputs, ["signals", "Engine_Speed", "Engine_Temperature"]);
    let mut harness = Harness::new(info, DbcDecoder::default());
    harness.set_property("dbc", dbc.display().to_string()).unwrap();
    let frame = CanFrame::new(256, false, &[0x40, 0x1F, 0xEC, 0, 0, 0, 0, 0]).unwrap();
    harness.push("frame", Payload::CanFrame(frame), Timestamp(5));
    harness.push(
        "frame",
        Payload::CanFrame(CanFrame::new(0x300, false, &[1]).unwrap()),
        Timestamp(6),
    );
    let out = harness.finish().unwrap();
    assert_eq!(out.f64_values("Engine_Speed"), [2000.0]);
    assert_eq!(out.f64_values("Engine_Temperature"), [-60.0]);
    let Payload::Text(line) = &out.samples("signals")[0].payload else {
        panic!()
    };
    assert_eq!(line.as_ref(), "Engine: Speed = 2000 rpm; Temperature = -60 degC");
    assert_eq!(
        out.samples("signals")[0].timestamp,
        Timestamp(5),
        "the frame's timestamp is kept"
    );
    let _ = decoder_descriptor();
}

#[test]
fn described_values_are_said_in_words_in_the_text_and_on_a_text_output_of_their_own() {
    let dir = tempfile::tempdir().unwrap();
    let dbc = dir.path().join("brakes.dbc");
    std::fs::write(
        &dbc,
        format!(
            "{DBC}\nBO_ 512 Brakes: 2 ECU\n SG_ ParkingBrake : 0|1@1+ (1,0) [0|1] \"\" DASH\n \
             SG_ Gear : 8|4@1- (1,0) [-1|6] \"\" DASH\n\n\
             VAL_ 512 ParkingBrake 0 \"Off\" 1 \"On\" ;\nVAL_ 512 Gear -1 \"Reverse\" 0 \"Neutral\" 1 \"First\" ;\n"
        ),
    )
    .unwrap();
    let properties = BTreeMap::from([("dbc".to_owned(), Value::Text(dbc.display().to_string()))]);
    let info = describe_decoder(&properties).unwrap();
    let outputs: Vec<&str> = info.outputs.iter().map(|o| o.name.as_str()).collect();
    assert_eq!(
        outputs,
        [
            "signals",
            "Engine_Speed",
            "Engine_Temperature",
            "Brakes_ParkingBrake",
            "Brakes_Gear",
            "Brakes_ParkingBrake_text",
            "Brakes_Gear_text"
        ]
    );
    let mut harness = Harness::new(info, DbcDecoder::default());
    harness.set_property("dbc", dbc.display().to_string()).unwrap();
    // Parking brake on, gear -1 (4-bit two's complement 0xF); then off, gear 5 (no description).
    for (data, at) in [([0x01, 0x0F], 1), ([0x00, 0x05], 2)] {
        let frame = CanFrame::new(512, false, &data).unwrap();
        harness.push("frame", Payload::CanFrame(frame), Timestamp(at));
    }
    let out = harness.finish().unwrap();
    let texts = |output: &str| -> Vec<String> {
        out.samples(output)
            .iter()
            .map(|s| match &s.payload {
                Payload::Text(text) => text.to_string(),
                other => panic!("{other:?}"),
            })
            .collect()
    };
    assert_eq!(
        texts("signals"),
        [
            "Brakes: ParkingBrake = On; Gear = Reverse",
            "Brakes: ParkingBrake = Off; Gear = 5"
        ]
    );
    assert_eq!(texts("Brakes_ParkingBrake_text"), ["On", "Off"]);
    assert_eq!(
        texts("Brakes_Gear_text"),
        ["Reverse"],
        "a value without words has none"
    );
    assert_eq!(out.f64_values("Brakes_ParkingBrake"), [1.0, 0.0]);
    assert_eq!(out.f64_values("Brakes_Gear"), [-1.0, 5.0]);
}

#[test]
fn the_encoder_makes_frames_the_decoder_reads_back_with_the_newest_value_of_each_signal() {
    let dir = tempfile::tempdir().unwrap();
    let dbc = dir.path().join("engine.dbc");
    std::fs::write(&dbc, DBC).unwrap();
    let path = Value::Text(dbc.display().to_string());
    let properties = BTreeMap::from([
        ("dbc".to_owned(), path.clone()),
        ("message".to_owned(), Value::Text("Engine".into())),
    ]);
    let info = describe_encoder(&properties).unwrap();
    let inputs: Vec<&str> = info.inputs.iter().map(|i| i.name.as_str()).collect();
    assert_eq!(inputs, ["Speed", "Temperature"]);
    let mut encoder = Harness::new(info, DbcEncoder::default());
    encoder.set_property("dbc", dbc.display().to_string()).unwrap();
    encoder.set_property("message", "Engine").unwrap();
    encoder.push("Speed", Payload::F64(2000.0), Timestamp(5));
    encoder.push("Temperature", Payload::I64(-60), Timestamp(6));
    let frames = encoder.finish().unwrap();
    let frames = frames.samples("frame");
    assert_eq!(frames.len(), 2, "one frame per value received");
    assert_eq!(frames[1].timestamp, Timestamp(6));
    let mut decoder = Harness::new(
        describe_decoder(&BTreeMap::from([("dbc".to_owned(), path)])).unwrap(),
        DbcDecoder::default(),
    );
    decoder.set_property("dbc", dbc.display().to_string()).unwrap();
    for frame in frames {
        decoder.push_sample("frame", frame.clone());
    }
    let signals = decoder.finish().unwrap();
    // The first frame carries the speed and a temperature not yet received (0 degC); the second both.
    assert_eq!(signals.f64_values("Engine_Speed"), [2000.0, 2000.0]);
    assert_eq!(signals.f64_values("Engine_Temperature"), [0.0, -60.0]);
}

#[test]
fn an_encoder_for_a_message_the_dbc_lacks_names_the_messages_it_has() {
    let dir = tempfile::tempdir().unwrap();
    let dbc = dir.path().join("engine.dbc");
    std::fs::write(&dbc, DBC).unwrap();
    let properties = BTreeMap::from([
        ("dbc".to_owned(), Value::Text(dbc.display().to_string())),
        ("message".to_owned(), Value::Text("Brakes".into())),
    ]);
    let error = describe_encoder(&properties).unwrap_err();
    assert_eq!(error.property.as_deref(), Some("message"));
    assert!(
        error.message.contains("no message \"Brakes\""),
        "{}",
        error.message
    );
    assert_eq!(error.suggestion.as_deref(), Some("one of: Engine"));
}

#[test]
fn a_dbc_with_an_error_is_refused_on_its_property_with_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let dbc = dir.path().join("broken.dbc");
    std::fs::write(&dbc, DBC.replace("0|16@1+", "0|16@7+")).unwrap();
    let properties = BTreeMap::from([("dbc".to_owned(), Value::Text(dbc.display().to_string()))]);
    let error = describe_decoder(&properties).unwrap_err();
    assert_eq!(error.property.as_deref(), Some("dbc"));
    // At the fault: line 10, column 19 (the byte order), as FILE:LINE:COLUMN.
    assert!(
        error
            .message
            .contains("broken.dbc:10:19: expected the byte order"),
        "{}",
        error.message
    );
}

#[test]
fn a_written_log_reads_back_frame_for_frame() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("out.log");
    let mut writer = Harness::new(writer_descriptor(), CandumpWriter::default());
    writer.set_property("path", log.display().to_string()).unwrap();
    let frames = [
        CanFrame::new(0x123, false, &[1, 2, 3]).unwrap(),
        CanFrame::new(0x1ABC_DEF0, true, &[]).unwrap(),
        CanFrame::new(0x7FF, false, &[9; 12]).unwrap(),
        CanFrame::remote_request(0x123, false, 0).unwrap(),
        CanFrame::remote_request(0x1ABC_DEF0, true, 8).unwrap(),
    ];
    for (index, frame) in frames.iter().enumerate() {
        writer.push(
            "frame",
            Payload::CanFrame(*frame),
            Timestamp(1_000_000_000 + index as i64 * 10_000_000),
        );
    }
    writer.finish().unwrap();
    let (out, _) = run(reader(&log, "fast"), 7);
    let read: Vec<CanFrame> = out
        .samples("frame")
        .iter()
        .map(|s| match s.payload {
            Payload::CanFrame(frame) => frame,
            _ => panic!(),
        })
        .collect();
    assert_eq!(read, frames);
}
