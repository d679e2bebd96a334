//! `gnss.nmea` reading real byte streams: a serial port (a pseudo-terminal pair), UDP and TCP on loopback,
//! and files; bad input is counted and skipped, a vanished port is reported and reopened.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::io::Write as _;
use std::net::{TcpListener, UdpSocket};
use std::os::fd::AsRawFd as _;
use std::time::{Duration, Instant};

use kairos_pack_gnss::receiver::{NmeaReceiver, descriptor};
use kairos_pack_gnss::sentence::with_checksum;
use kairos_sdk::harness::{Harness, HarnessOutput};
use kairos_sdk::{FixStatus, Payload};

/// A drive of `count` seconds: RMC then GGA each second, moving north, with a GSV in between.
fn drive(count: u32) -> Vec<String> {
    let mut lines = Vec::new();
    for second in 0..count {
        let time = format!("1200{second:02}.00");
        let minutes = 21.0 + f64::from(second) * 0.001;
        lines.push(with_checksum(&format!(
            "GPRMC,{time},A,48{minutes:07.4},N,00213.9980,E,10.0,0.0,251126,,"
        )));
        lines.push(with_checksum("GPGSV,1,1,01,03,03,111,40"));
        lines.push(with_checksum(&format!(
            "GPGGA,{time},48{minutes:07.4},N,00213.9980,E,4,12,0.8,100.0,M,47.0,M,,"
        )));
    }
    lines
}

fn harness(properties: &[(&str, kairos_sdk::Value)]) -> Harness {
    let mut harness = Harness::new(descriptor(), NmeaReceiver::default());
    for (name, value) in properties {
        harness.set_property(name, value.clone()).unwrap();
    }
    harness
}

/// Runs the component until `fixes` fixes came out or 5 s passed.
fn run_until_fixes(harness: &mut Harness, fixes: usize) -> HarnessOutput {
    let mut out = HarnessOutput::default();
    let started = Instant::now();
    while out.samples("fix").len() < fixes && started.elapsed() < Duration::from_secs(5) {
        out.extend(harness.run().unwrap());
    }
    out
}

/// Runs the component `cycles` times (a file replays one line a cycle), then finishes it.
fn run_cycles(mut harness: Harness, cycles: usize) -> HarnessOutput {
    let mut out = HarnessOutput::default();
    for _ in 0..cycles {
        out.extend(harness.run().unwrap());
    }
    out.extend(harness.finish().unwrap());
    out
}

fn check_drive(out: &HarnessOutput, seconds: usize) {
    let fixes = out.samples("fix");
    assert_eq!(fixes.len(), seconds, "{out:?}");
    let Payload::GnssFix(first) = fixes[0].payload else {
        panic!()
    };
    assert!((first.latitude_deg - (48.0 + 21.0 / 60.0)).abs() < 1e-9);
    assert!((first.altitude_m - 147.0).abs() < 1e-3);
    assert_eq!(first.status, FixStatus::RtkFixed);
    assert!((first.horizontal_accuracy_m - 0.8 * 3.0).abs() < 1e-5);
    assert_eq!(out.samples("satellites")[0].payload, Payload::I64(12));
    // RMC and GGA each carry the time, once the date is known: 2026-11-25 12:00:00 UTC.
    let utc = out.f64_values("utc");
    assert_eq!(utc.len(), 2 * seconds);
    assert!((utc[0] - 1_795_608_000.0).abs() < 1e-6, "{utc:?}");
    assert!((out.f64_values("speed")[0] - 10.0 * 1852.0 / 3600.0).abs() < 1e-6);
    assert_eq!(out.samples("sentence").len(), 3 * seconds);
}

#[test]
fn a_serial_receiver_through_a_pseudo_terminal() {
    let pty = nix::pty::openpty(None, None).unwrap();
    let device = nix::unistd::ttyname(&pty.slave).unwrap();
    let mut harness = harness(&[
        ("source", "serial".into()),
        ("device", device.display().to_string().into()),
        ("baud", 115_200_i64.into()),
    ]);
    let mut master = std::fs::File::from(pty.master);
    harness.run().unwrap();
    for line in drive(3) {
        write!(master, "{line}\r\n").unwrap();
    }
    let out = run_until_fixes(&mut harness, 3);
    check_drive(&out, 3);
    drop(harness);
    let _ = pty.slave.as_raw_fd();
}

#[test]
fn a_missing_serial_port_names_its_path_and_the_cause() {
    let mut harness = harness(&[
        ("source", "serial".into()),
        ("device", "/dev/ttyKAIROS_NONE".into()),
    ]);
    let error = harness.run().unwrap_err().to_string();
    assert!(
        error.contains("/dev/ttyKAIROS_NONE") && error.contains("No such file"),
        "{error}"
    );
}

#[test]
fn udp_datagrams_each_holding_sentences() {
    let port = UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let address = format!("127.0.0.1:{port}");
    let mut harness = harness(&[("source", "udp".into()), ("address", address.clone().into())]);
    harness.run().unwrap();
    let sender = UdpSocket::bind("127.0.0.1:0").unwrap();
    let lines = drive(3);
    for pair in lines.chunks(3) {
        // A datagram per second; the last line without its line ending.
        sender.send_to(pair.join("\r\n").as_bytes(), &address).unwrap();
    }
    let out = run_until_fixes(&mut harness, 3);
    check_drive(&out, 3);
}

#[test]
fn tcp_reconnects_when_the_receiver_drops_the_connection() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let address = listener.local_addr().unwrap().to_string();
    let mut harness = harness(&[("source", "tcp".into()), ("address", address.into())]);
    harness.run().unwrap();
    let lines = drive(4);
    let (mut first, _) = listener.accept().unwrap();
    // Two seconds, then the peer goes away in the middle of a sentence.
    for line in &lines[..6] {
        write!(first, "{line}\r\n").unwrap();
    }
    write!(first, "$GPGGA,12").unwrap();
    drop(first);
    let out = run_until_fixes(&mut harness, 2);
    assert_eq!(out.samples("fix").len(), 2);
    // It connects again within a second or so and goes on.
    listener.set_nonblocking(false).unwrap();
    let server = std::thread::Builder::new()
        .name("receiver".to_owned())
        .spawn(move || listener.accept().unwrap().0)
        .expect("starting a thread");
    let started = Instant::now();
    while !server.is_finished() && started.elapsed() < Duration::from_secs(5) {
        harness.run().unwrap();
    }
    let mut second = server.join().unwrap();
    for line in &lines[6..] {
        write!(second, "{line}\r\n").unwrap();
    }
    let out = run_until_fixes(&mut harness, 2);
    assert_eq!(
        out.samples("fix").len(),
        2,
        "the half sentence was not joined to the next"
    );
}

#[test]
fn bad_lines_are_counted_and_skipped_and_the_good_ones_around_them_kept() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("noisy.nmea");
    let mut lines = drive(3);
    let good = lines[2].clone();
    lines.insert(1, format!("{}00", &good[..good.len() - 2]));
    lines.insert(3, good[..20].to_owned());
    lines.insert(4, "\u{0}\u{7f}binary noise".to_owned());
    lines.insert(5, "x".repeat(400));
    let mut text = lines.join("\r\n").into_bytes();
    text.extend(b"\r\n\xff\xfe\n");
    std::fs::write(&path, text).unwrap();
    let mut harness = harness(&[
        ("source", "file".into()),
        ("path", path.display().to_string().into()),
        ("replay", "fast".into()),
    ]);
    let mut out = HarnessOutput::default();
    for _ in 0..20 {
        out.extend(harness.run().unwrap());
    }
    // Published at the end of the file (and at most twice a second before).
    let status = harness.status().unwrap();
    assert_eq!(status["bad_checksum"], 1, "{status}");
    // A cut sentence, binary noise and bytes that are not text.
    assert_eq!(status["malformed"], 3, "{status}");
    assert_eq!(status["sentences"], 9, "{status}");
    assert_eq!(status["overlong"], 1, "{status}");
    out.extend(harness.finish().unwrap());
    check_drive(&out, 3);
}

#[test]
fn a_file_at_its_timing_takes_the_time_the_receiver_took() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("drive.nmea");
    std::fs::write(&path, drive(3).join("\n")).unwrap();
    let harness = harness(&[
        ("source", "file".into()),
        ("path", path.display().to_string().into()),
    ]);
    let started = harness.now();
    let out = run_cycles(harness, 12);
    check_drive(&out, 3);
    // The harness clock moved over the two seconds between the first and the last sentence.
    let last = out.samples("fix").last().unwrap().timestamp;
    assert_eq!(last.0 - started.0, 2_000_000_000);
}

#[test]
fn a_serial_port_that_vanishes_is_reported_and_the_component_keeps_running() {
    let pty = nix::pty::openpty(None, None).unwrap();
    let device = nix::unistd::ttyname(&pty.slave).unwrap();
    let mut harness = harness(&[
        ("source", "serial".into()),
        ("device", device.display().to_string().into()),
    ]);
    let mut master = std::fs::File::from(pty.master);
    harness.run().unwrap();
    for line in drive(1) {
        write!(master, "{line}\r\n").unwrap();
    }
    assert_eq!(run_until_fixes(&mut harness, 1).samples("fix").len(), 1);
    // The other end goes: reads fail, the port cannot be opened again; the component runs on.
    drop(master);
    drop(pty.slave);
    let started = Instant::now();
    let mut status = serde_json::Value::Null;
    while started.elapsed() < Duration::from_secs(3) {
        harness.run().unwrap();
        status = harness.status().unwrap();
        if status["connected"] == false {
            break;
        }
    }
    assert_eq!(status["connected"], false, "{status}");
    harness.run().unwrap();
}

proptest::proptest! {
    #[test]
    fn any_bytes_are_split_and_decoded_without_a_panic(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..2048)) {
        let mut decoder = kairos_pack_gnss::sentence::Decoder::new();
        let mut splitter = kairos_pack_serial::link::LineSplitter::new(256);
        splitter.feed(&bytes, |line| {
            if let Ok(text) = std::str::from_utf8(line) {
                let _ = decoder.decode(text);
            }
        });
    }

    #[test]
    fn sentences_with_random_fields_never_panic(fields in proptest::collection::vec("[0-9A-Z.,-]{0,12}", 0..16), kind in "(GPGGA|GPRMC|GPVTG|GNGGA|GPXYZ)") {
        let line = with_checksum(&format!("{kind},{}", fields.join(",")));
        let _ = kairos_pack_gnss::sentence::Decoder::new().decode(&line);
    }
}
