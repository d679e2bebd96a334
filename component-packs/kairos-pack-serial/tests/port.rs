//! `serial.reader` and `serial.writer` on a pseudo-terminal pair standing in for a device.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::io::{Read as _, Write as _};
use std::sync::Arc;
use std::time::{Duration, Instant};

use kairos_pack_serial::port::{SerialReader, SerialWriter, reader_descriptor, writer_descriptor};
use kairos_sdk::harness::{Harness, HarnessOutput};
use kairos_sdk::{Payload, Timestamp};

/// A pseudo-terminal pair in raw mode: the device's end (the master) and the path of the port.
fn device() -> (std::fs::File, String, std::os::fd::OwnedFd) {
    let pty = nix::pty::openpty(None, None).unwrap();
    let mut termios = nix::sys::termios::tcgetattr(&pty.slave).unwrap();
    nix::sys::termios::cfmakeraw(&mut termios);
    nix::sys::termios::tcsetattr(&pty.slave, nix::sys::termios::SetArg::TCSANOW, &termios).unwrap();
    let path = nix::unistd::ttyname(&pty.slave).unwrap().display().to_string();
    (std::fs::File::from(pty.master), path, pty.slave)
}

fn run_until(harness: &mut Harness, output: &str, count: usize) -> HarnessOutput {
    let mut out = HarnessOutput::default();
    let started = Instant::now();
    while out.samples(output).len() < count && started.elapsed() < Duration::from_secs(5) {
        out.extend(harness.run().unwrap());
    }
    out
}

#[test]
fn the_reader_gives_a_text_sample_per_line() {
    let (mut device, path, _slave) = device();
    let mut harness = Harness::new(reader_descriptor(), SerialReader::default());
    harness.set_property("device", path).unwrap();
    harness.run().unwrap();
    device.write_all(b"first line\r\nsecond").unwrap();
    device.write_all(b" line\n\xffbinary\n").unwrap();
    let out = run_until(&mut harness, "line", 3);
    let lines: Vec<String> = out
        .samples("line")
        .iter()
        .map(|s| s.payload.to_string())
        .collect();
    assert_eq!(lines.len(), 3, "{lines:?}");
    assert!(
        lines[0].contains("first line") && lines[1].contains("second line"),
        "{lines:?}"
    );
}

#[test]
fn the_reader_gives_bytes_as_they_come_in_bytes_mode() {
    let (mut device, path, _slave) = device();
    let mut harness = Harness::new(reader_descriptor(), SerialReader::default());
    harness.set_property("device", path).unwrap();
    harness.set_property("mode", "bytes").unwrap();
    harness.run().unwrap();
    device.write_all(&[0x00, 0xAA, 0x55, 0xFF, b'\n', 0x01]).unwrap();
    let out = run_until(&mut harness, "bytes", 1);
    let mut all = Vec::new();
    for sample in out.samples("bytes") {
        let Payload::Bytes(bytes) = &sample.payload else {
            panic!()
        };
        all.extend_from_slice(bytes);
    }
    assert_eq!(all, [0x00, 0xAA, 0x55, 0xFF, b'\n', 0x01]);
}

#[test]
fn the_writer_sends_text_with_its_line_ending_and_bytes_as_they_are() {
    let (mut device, path, _slave) = device();
    let mut harness = Harness::new(writer_descriptor(), SerialWriter::default());
    harness.set_property("device", path).unwrap();
    harness.push("in", Payload::Text(Arc::from("hello")), Timestamp(1));
    harness.push("in", Payload::Bytes(Arc::from(&[1_u8, 2, 3][..])), Timestamp(2));
    harness.run().unwrap();
    let mut received = [0_u8; 10];
    let mut got = 0;
    let started = Instant::now();
    while got < received.len() && started.elapsed() < Duration::from_secs(5) {
        got += device.read(&mut received[got..]).unwrap();
    }
    assert_eq!(&received[..got], b"hello\r\n\x01\x02\x03");
}

#[test]
fn a_missing_port_fails_the_component_naming_it() {
    let mut harness = Harness::new(writer_descriptor(), SerialWriter::default());
    harness.set_property("device", "/dev/ttyKAIROS_NONE").unwrap();
    let error = harness.run().unwrap_err().to_string();
    assert!(error.contains("/dev/ttyKAIROS_NONE"), "{error}");
}
