//! The live SocketCAN components. A missing interface is tested everywhere; frames on a bus only where a
//! virtual one, `vcan0`, exists (this kernel may have no SocketCAN at all: the test says what it skipped).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::path::Path;

use kairos_pack_can::live::{SocketCanReader, SocketCanWriter, reader_descriptor, writer_descriptor};
use kairos_sdk::harness::Harness;
use kairos_sdk::{CanFrame, Payload, Timestamp};

#[test]
fn a_missing_interface_is_named_with_the_cause_and_the_fix() {
    let mut reader = Harness::new(reader_descriptor(), SocketCanReader::default());
    reader.set_property("interface", "kairos-none0").unwrap();
    let error = reader.run().unwrap_err().to_string();
    assert!(error.contains("'kairos-none0'"), "{error}");
    assert!(
        error.contains("no SocketCAN") || error.contains("kairos devices"),
        "the cause and what to do: {error}"
    );
    let mut writer = Harness::new(writer_descriptor(), SocketCanWriter::default());
    writer.set_property("interface", "kairos-none0").unwrap();
    assert!(writer.run().unwrap_err().to_string().contains("'kairos-none0'"));
}

#[test]
fn frames_sent_on_vcan0_are_read_back_with_their_ids_and_data() {
    if !Path::new("/sys/class/net/vcan0").exists() {
        eprintln!(
            "SocketCAN on a bus NOT TESTED: no vcan0 interface here (create one with `ip link add dev vcan0 \
             type vcan && ip link set up vcan0`, or this kernel has no SocketCAN)"
        );
        return;
    }
    let mut reader = Harness::new(reader_descriptor(), SocketCanReader::default());
    reader.set_property("interface", "vcan0").unwrap();
    reader.set_property("filters", "123, 18FF0000:1FFF0000").unwrap();
    let mut writer = Harness::new(writer_descriptor(), SocketCanWriter::default());
    writer.set_property("interface", "vcan0").unwrap();
    // The reader opens its socket first: frames sent before are not queued for it.
    let _ = reader.run().unwrap();
    for (id, extended) in [(0x123, false), (0x456, false), (0x18FF_0001, true)] {
        let frame = CanFrame::new(id, extended, &[1, 2, 3]).unwrap();
        writer.push("frame", Payload::CanFrame(frame), Timestamp(1));
    }
    let request = CanFrame::remote_request(0x123, false, 4).unwrap();
    writer.push("frame", Payload::CanFrame(request), Timestamp(2));
    writer.finish().unwrap();
    let mut received = Vec::new();
    for _ in 0..20 {
        for sample in reader.run().unwrap().samples("frame") {
            if let Payload::CanFrame(frame) = sample.payload {
                received.push(frame);
            }
        }
        if received.len() >= 3 {
            break;
        }
    }
    // 0x456 is filtered out by the kernel; the remote request goes through as one.
    assert_eq!(
        received,
        [
            CanFrame::new(0x123, false, &[1, 2, 3]).unwrap(),
            CanFrame::new(0x18FF_0001, true, &[1, 2, 3]).unwrap(),
            request
        ]
    );
}
