//! The socket components against real sockets on loopback: datagrams both ways, TCP as client and as
//! server in every framing, a peer that leaves mid-message, messages too large.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::io::{Read as _, Write as _};
use std::net::{TcpListener, TcpStream, UdpSocket};
use std::sync::Arc;
use std::time::{Duration, Instant};

use kairos_pack_net::framing::Framing;
use kairos_pack_net::{tcp, udp};
use kairos_sdk::harness::{Harness, HarnessOutput};
use kairos_sdk::{Payload, Timestamp};

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn run_until(harness: &mut Harness, output: &str, count: usize) -> HarnessOutput {
    let mut out = HarnessOutput::default();
    let started = Instant::now();
    while out.samples(output).len() < count && started.elapsed() < Duration::from_secs(5) {
        out.extend(harness.run().unwrap());
    }
    out
}

fn bytes_of(out: &HarnessOutput, output: &str) -> Vec<Vec<u8>> {
    out.samples(output)
        .iter()
        .map(|s| match &s.payload {
            Payload::Bytes(bytes) => bytes.to_vec(),
            Payload::Text(text) => text.as_bytes().to_vec(),
            other => panic!("{other:?}"),
        })
        .collect()
}

#[test]
fn a_udp_receiver_gives_one_sample_per_datagram() {
    let port = UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let mut harness = Harness::new(udp::receiver_descriptor(), udp::UdpReceiver::default());
    harness
        .set_property("address", format!("127.0.0.1:{port}"))
        .unwrap();
    harness.run().unwrap();
    let sender = UdpSocket::bind("127.0.0.1:0").unwrap();
    for datagram in [&b"first"[..], &[0, 1, 2, 255], &vec![7_u8; 60_000]] {
        sender.send_to(datagram, ("127.0.0.1", port)).unwrap();
    }
    let out = run_until(&mut harness, "data", 3);
    let got = bytes_of(&out, "data");
    assert_eq!(got.len(), 3);
    assert_eq!(got[0], b"first");
    assert_eq!(got[1], [0, 1, 2, 255]);
    assert_eq!(got[2].len(), 60_000);
}

#[test]
fn a_udp_sender_sends_text_and_bytes_and_counts_what_is_too_large() {
    let receiver = UdpSocket::bind("127.0.0.1:0").unwrap();
    receiver.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
    let mut harness = Harness::new(udp::sender_descriptor(), udp::UdpSender::default());
    harness
        .set_property("destination", receiver.local_addr().unwrap().to_string())
        .unwrap();
    harness.push("in", Payload::Text(Arc::from("hello")), Timestamp(1));
    harness.push("in", Payload::Bytes(Arc::from(vec![9_u8; 70_000])), Timestamp(2));
    harness.push("in", Payload::Bytes(Arc::from(&[1_u8, 2][..])), Timestamp(3));
    harness.run().unwrap();
    let mut buffer = [0_u8; 1024];
    let read = receiver.recv(&mut buffer).unwrap();
    assert_eq!(&buffer[..read], b"hello");
    let read = receiver.recv(&mut buffer).unwrap();
    assert_eq!(&buffer[..read], [1, 2], "the oversized one was not sent");
    std::thread::sleep(Duration::from_millis(600));
    harness.push("in", Payload::Text(Arc::from("again")), Timestamp(4));
    harness.run().unwrap();
    let status = harness.status().unwrap();
    assert_eq!(
        (status["sent"].as_u64(), status["too_large"].as_u64()),
        (Some(3), Some(1)),
        "{status}"
    );
}

#[test]
fn a_tcp_client_reads_lines_counts_a_line_cut_off_and_connects_again() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let mut harness = Harness::new(tcp::receiver_descriptor(), tcp::TcpReceiver::default());
    harness
        .set_property("address", listener.local_addr().unwrap().to_string())
        .unwrap();
    harness.set_property("framing", "lines").unwrap();
    harness.run().unwrap();
    let (mut server, _) = listener.accept().unwrap();
    server.write_all(b"one\r\ntwo\nthr").unwrap();
    let out = run_until(&mut harness, "line", 2);
    assert_eq!(bytes_of(&out, "line"), [b"one".to_vec(), b"two".to_vec()]);
    drop(server);
    // The half line is not joined to what the next connection sends.
    let accepted = std::thread::Builder::new()
        .name("sockets".to_owned())
        .spawn(move || listener.accept().unwrap().0)
        .expect("starting a thread");
    let started = Instant::now();
    while !accepted.is_finished() && started.elapsed() < Duration::from_secs(5) {
        harness.run().unwrap();
    }
    let mut server = accepted.join().unwrap();
    server.write_all(b"four\n").unwrap();
    let out = run_until(&mut harness, "line", 1);
    assert_eq!(bytes_of(&out, "line"), [b"four".to_vec()]);
    std::thread::sleep(Duration::from_millis(600));
    harness.run().unwrap();
    assert_eq!(harness.status().unwrap()["cut_off"], 1);
}

#[test]
fn a_tcp_server_reads_length_prefixed_messages_from_several_clients() {
    let port = free_port();
    let mut harness = Harness::new(tcp::receiver_descriptor(), tcp::TcpReceiver::default());
    harness.set_property("mode", "server").unwrap();
    harness
        .set_property("address", format!("127.0.0.1:{port}"))
        .unwrap();
    harness.set_property("framing", "length_prefixed").unwrap();
    harness.run().unwrap();
    let mut first = TcpStream::connect(("127.0.0.1", port)).unwrap();
    let mut second = TcpStream::connect(("127.0.0.1", port)).unwrap();
    first
        .write_all(&Framing::LengthPrefixed.frame(b"from the first"))
        .unwrap();
    let framed = Framing::LengthPrefixed.frame(&[5_u8; 1000]);
    second.write_all(&framed[..10]).unwrap();
    let out = run_until(&mut harness, "data", 1);
    second.write_all(&framed[10..]).unwrap();
    let mut all = bytes_of(&out, "data");
    all.extend(bytes_of(&run_until(&mut harness, "data", 1), "data"));
    assert_eq!(all, [b"from the first".to_vec(), vec![5_u8; 1000]]);
    // A length no message may have closes that connection only.
    first.write_all(&[0xff, 0xff, 0xff, 0xff]).unwrap();
    second
        .write_all(&Framing::LengthPrefixed.frame(b"still here"))
        .unwrap();
    let out = run_until(&mut harness, "data", 1);
    assert_eq!(bytes_of(&out, "data"), [b"still here".to_vec()]);
}

#[test]
fn a_tcp_sender_serves_every_client_and_a_client_sender_reaches_its_server() {
    let port = free_port();
    let mut harness = Harness::new(tcp::sender_descriptor(), tcp::TcpSender::default());
    harness.set_property("mode", "server").unwrap();
    harness
        .set_property("address", format!("127.0.0.1:{port}"))
        .unwrap();
    harness.set_property("framing", "lines").unwrap();
    harness.run().unwrap();
    let mut clients: Vec<TcpStream> = (0..2)
        .map(|_| TcpStream::connect(("127.0.0.1", port)).unwrap())
        .collect();
    std::thread::sleep(Duration::from_millis(50));
    harness.push("in", Payload::Text(Arc::from("to everyone")), Timestamp(1));
    harness.run().unwrap();
    for client in &mut clients {
        let mut line = [0_u8; 12];
        client.read_exact(&mut line).unwrap();
        assert_eq!(&line, b"to everyone\n");
    }

    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let mut harness = Harness::new(tcp::sender_descriptor(), tcp::TcpSender::default());
    harness
        .set_property("address", listener.local_addr().unwrap().to_string())
        .unwrap();
    harness.push("in", Payload::Bytes(Arc::from(&[1_u8, 2, 3][..])), Timestamp(1));
    harness.run().unwrap();
    let (mut server, _) = listener.accept().unwrap();
    let mut got = [0_u8; 3];
    server.read_exact(&mut got).unwrap();
    assert_eq!(got, [1, 2, 3]);
}

#[test]
fn a_kairos_receiver_counts_garbage_other_types_gaps_and_late_samples_and_passes_the_rest_on() {
    use kairos_sample_frame::{encode_json_whole, encode_whole};
    use kairos_sdk::Sample;

    let port = UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let properties = std::collections::BTreeMap::from([
        ("encoding".to_owned(), kairos_sdk::Value::Text("kairos".into())),
        ("data_type".to_owned(), kairos_sdk::Value::Text("f64".into())),
    ]);
    let mut harness = Harness::new(
        udp::describe_receiver(&properties).unwrap(),
        udp::UdpReceiver::default(),
    );
    harness
        .set_property("address", format!("127.0.0.1:{port}"))
        .unwrap();
    harness.set_property("encoding", "kairos").unwrap();
    harness.set_property("data_type", "f64").unwrap();
    harness.run().unwrap();
    let sender = UdpSocket::bind("127.0.0.1:0").unwrap();
    let frame = |sequence: u64, payload: Payload| {
        let mut sample = Sample::new(payload, Timestamp(1_000 + i64::try_from(sequence).unwrap()));
        sample.time_of_issue = Timestamp(5_000);
        sample.sequence = sequence;
        // A program of the user's may send the control protocol's JSON frame: taken as Kairos's own.
        if sequence == 4 {
            encode_json_whole("remote.out", &sample)
        } else {
            encode_whole("remote.out", &sample)
        }
    };
    let datagrams = [
        frame(0, Payload::F64(0.0)),
        b"KSF1 not a frame".to_vec(),
        frame(1, Payload::Text(Arc::from("a text"))),
        frame(3, Payload::F64(3.0)),
        frame(2, Payload::F64(2.0)),
        frame(4, Payload::F64(4.0)),
    ];
    for datagram in &datagrams {
        sender.send_to(datagram, ("127.0.0.1", port)).unwrap();
    }
    let out = run_until(&mut harness, "samples", 3);
    // 0, 3 and 4 in order; 2 came after 3: counted, not written (the output stays in time order).
    assert_eq!(out.f64_values("samples"), [0.0, 3.0, 4.0]);
    let first = &out.samples("samples")[0];
    assert_eq!(
        (first.timestamp, first.time_of_issue),
        (Timestamp(1_000), Timestamp(5_000))
    );
    std::thread::sleep(Duration::from_millis(600));
    harness.run().unwrap();
    let status = harness.status().unwrap();
    // Sequence 1 (the text) was refused for its type, so it counts as lost in transit as well.
    for (count, expected) in [
        ("malformed", 1),
        ("wrong_type", 1),
        ("reordered", 1),
        ("lost", 1),
        ("received", 3),
    ] {
        assert_eq!(status[count], expected, "{count}: {status}");
    }
}
