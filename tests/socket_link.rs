//! Two `kairos run` processes exchanging samples over the network pack's Kairos encoding: what the sender
//! records and what the receiver records are the same samples, with both times, none lost.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::net::TcpListener;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn diagram(components: &str, connections: &str) -> String {
    format!("Diagram(format: 1, packs: [], components: [{components}], connections: [{connections}])")
}

fn run(dir: &Path, name: &str, text: &str, seconds: &str) -> Child {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    Command::new(env!("CARGO_BIN_EXE_kairos"))
        .args(["run", path.to_str().unwrap(), "--for", seconds])
        .current_dir(dir)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// (timestamp, time of issue, message bytes) of every message of a recording.
fn messages(path: &Path) -> Vec<(u64, u64, Vec<u8>)> {
    let bytes = std::fs::read(path).unwrap();
    mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|message| {
            let message = message.unwrap();
            (message.publish_time, message.log_time, message.data.into_owned())
        })
        .collect()
}

fn finish(child: Child) -> String {
    let output = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    assert!(output.status.success(), "{stderr}");
    stderr
}

fn exchange(transport: &str) {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let (sending_end, receiving_end) = match transport {
        "tcp" => (
            format!(
                r#"Component(id: "link", type: "net.tcp_sender", properties: {{"mode": "server",
                   "address": "127.0.0.1:{port}", "encoding": "kairos"}})"#
            ),
            format!(
                r#"Component(id: "link", type: "net.tcp_receiver", properties: {{"mode": "client",
                   "address": "127.0.0.1:{port}", "encoding": "kairos", "data_type": "imu"}})"#
            ),
        ),
        _ => (
            format!(
                r#"Component(id: "link", type: "net.udp_sender", properties: {{
                   "destination": "127.0.0.1:{port}", "encoding": "kairos"}})"#
            ),
            format!(
                r#"Component(id: "link", type: "net.udp_receiver", properties: {{
                   "address": "127.0.0.1:{port}", "encoding": "kairos", "data_type": "imu"}})"#
            ),
        ),
    };
    let recorder = |file: &str| {
        format!(r#"Component(id: "recorder", type: "recording.recorder", properties: {{"path": "{file}"}})"#)
    };
    // The receiver first, so a UDP sender's first datagrams find it listening.
    let receiving = run(
        dir.path(),
        "receiving.ron",
        &diagram(
            &format!("{receiving_end}, {}", recorder("received.mcap")),
            r#"Connection(from: "link.samples", to: "recorder.in1", buffer_size: 256)"#,
        ),
        // Past the sender's 2 s, however long a slow machine takes to start it.
        "6s",
    );
    std::thread::sleep(Duration::from_millis(500));
    let sending = run(
        dir.path(),
        "sending.ron",
        &diagram(
            &format!(
                r#"Component(id: "imu", type: "sensors.imu"), {sending_end}, {}"#,
                recorder("sent.mcap")
            ),
            r#"Connection(from: "imu.imu", to: "link.in", buffer_size: 256),
               Connection(from: "imu.imu", to: "recorder.in1", buffer_size: 256)"#,
        ),
        "2s",
    );
    finish(sending);
    let log = finish(receiving);
    let sent = messages(&dir.path().join("sent.mcap"));
    let received = messages(&dir.path().join("received.mcap"));
    assert!(!sent.is_empty(), "no IMU sample sent");
    assert!(!received.is_empty(), "none of {} received", sent.len());
    // A TCP client connects within its first second: what it gets is every sample from then on, in order,
    // with both times and the payload exactly as sent.
    let first = sent
        .iter()
        .position(|m| Some(m) == received.first())
        .unwrap_or_else(|| panic!("the first received sample was never sent; {log}"));
    assert_eq!(&sent[first..first + received.len()], &received[..], "{log}");
    assert!(
        sent.len() - first - received.len() <= 1,
        "the last samples were lost; {log}"
    );
}

#[test]
fn imu_samples_cross_between_two_runtimes_over_tcp_with_both_times() {
    exchange("tcp");
}

#[test]
fn imu_samples_cross_between_two_runtimes_over_udp_with_both_times() {
    exchange("udp");
}
