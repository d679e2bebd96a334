//! Benchmark 15 — the network pack's Kairos-sample link between two processes on loopback.
//!
//! 1. Latency: a sample sent by `net.udp_sender` (encoding kairos) to another process, whose
//!    `net.udp_receiver` writes it and whose `net.udp_sender` sends it back, read from the first process's
//!    `net.udp_receiver`: half the round trip, against a raw UDP ping-pong of the same bytes between two
//!    processes (`send_to` → `recv_from` → `send_to` → `recv`). The components run as the engine calls
//!    them (`core` on a context whose ports are real buffers) on the measuring thread, so the figure is the
//!    link's own cost (encoding, decoding, buffers, sockets) without the thread hops of a diagram, which
//!    benchmarks 1 and 2 measure.
//! 2. Throughput: a simulated 1920×1080 RGB camera at 30 Hz in one `Engine` (a child process) sent by a
//!    `net.tcp_sender` to a `net.tcp_receiver` in another `Engine` (this process): samples lost.
//!
//! The child processes are this binary again, started with `KAIROS_BENCH_SOCKET_ROLE`.

#![allow(
    clippy::unwrap_used,
    reason = "a failure here is a broken benchmark, not something to carry on from"
)]

use std::io::{BufRead as _, BufReader};
use std::net::{TcpListener, UdpSocket};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::DVec3;
use kairos_benches::{
    Goal, LatencySeries, Percentiles, Ratios, component_context, header, nanos, print_latency, size,
};
use kairos_pack_net::udp::{UdpReceiver, UdpSender};
use kairos_runtime::Engine;
use kairos_sdk_core::host::{OutputBuffer, ReaderConfig};
use kairos_sdk_core::{
    Component, Context, Imu, Payload, ReaderPolicy, RealTimeClock, Registry, RunSignal, Sample, Timestamp,
    Value,
};

const ROLE: &str = "KAIROS_BENCH_SOCKET_ROLE";

fn free_port() -> u16 {
    UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn free_tcp_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn child(role: &str, args: &[String]) -> Child {
    Command::new(std::env::current_exe().unwrap())
        .env(ROLE, role)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap()
}

/// A `net.udp_receiver` on `listen` and a `net.udp_sender` to `destination`, Kairos encoding, their
/// contexts, and the buffer the receiver writes into (which feeds the sender when `echo`).
struct KairosEnds {
    receiver: UdpReceiver,
    receiver_ctx: Context,
    received: OutputBuffer,
    sender: UdpSender,
    sender_ctx: Context,
    /// The buffer feeding the sender, when it is not `received`.
    to_send: Option<OutputBuffer>,
    reader: Option<kairos_sdk_core::host::Reader>,
}

impl KairosEnds {
    fn new(listen: u16, destination: u16, data_type: &str, echo: bool) -> Self {
        let kairos = ("encoding", Value::Text("kairos".into()));
        let properties = std::collections::BTreeMap::from([
            ("encoding".to_owned(), Value::Text("kairos".into())),
            ("data_type".to_owned(), Value::Text(data_type.into())),
        ]);
        let receiver_info = kairos_pack_net::udp::describe_receiver(&properties).unwrap();
        let (mut receiver_ctx, mut buffers) = component_context(
            &receiver_info,
            &[
                ("address", Value::Text(format!("127.0.0.1:{listen}"))),
                kairos.clone(),
                ("data_type", Value::Text(data_type.into())),
            ],
            Vec::new(),
        );
        let receiver_output = buffers.remove(0);
        let (to_send, feeding) = if echo {
            (None, receiver_output.clone())
        } else {
            let buffer = OutputBuffer::new("bench.out", 4);
            (Some(buffer.clone()), buffer)
        };
        let sender_info = kairos_pack_net::udp::describe_sender(&properties).unwrap();
        let feed = feeding.attach(
            ReaderConfig::new(ReaderPolicy::Fifo, "bench -> sender.in"),
            Arc::new(RunSignal::new()),
        );
        let (mut sender_ctx, _) = component_context(
            &sender_info,
            &[
                ("destination", Value::Text(format!("127.0.0.1:{destination}"))),
                kairos,
            ],
            vec![Some(feed)],
        );
        let mut receiver = UdpReceiver::default();
        let mut sender = UdpSender::default();
        receiver.birth(&mut receiver_ctx).unwrap();
        sender.birth(&mut sender_ctx).unwrap();
        let reader = (!echo).then(|| {
            receiver_output.attach(
                ReaderConfig::new(ReaderPolicy::Fifo, "receiver.samples -> bench"),
                Arc::new(RunSignal::new()),
            )
        });
        KairosEnds {
            receiver,
            receiver_ctx,
            received: receiver_output,
            sender,
            sender_ctx,
            to_send,
            reader,
        }
    }

    /// Receives until one sample was written (a receive waits at most 50 ms); false if none came.
    fn receive_one(&mut self) -> bool {
        let before = self.received.written();
        for _ in 0..40 {
            self.receiver.core(&mut self.receiver_ctx).unwrap();
            if self.received.written() > before {
                return true;
            }
        }
        false
    }
}

fn payload(kind: &str) -> Payload {
    if kind == "imu" {
        Payload::Imu(Imu {
            angular_velocity: DVec3::new(0.01, -0.02, 0.3),
            linear_acceleration: DVec3::new(0.5, 0.1, 9.81),
            orientation: None,
        })
    } else {
        Payload::Bytes(Arc::from(vec![7_u8; 8192]))
    }
}

/// Child: echoes Kairos samples back, through the components.
fn kairos_echo(listen: u16, destination: u16, data_type: &str) {
    kairos_benches::pin_current_thread(true);
    let mut ends = KairosEnds::new(listen, destination, data_type, true);
    println!("ready");
    loop {
        if ends.receive_one() {
            ends.sender.core(&mut ends.sender_ctx).unwrap();
        }
    }
}

/// Child: echoes datagrams back as they are.
fn raw_echo(listen: u16) {
    kairos_benches::pin_current_thread(true);
    let socket = UdpSocket::bind(("127.0.0.1", listen)).unwrap();
    let mut buffer = vec![0; 65_536];
    println!("ready");
    loop {
        let (read, from) = socket.recv_from(&mut buffer).unwrap();
        socket.send_to(&buffer[..read], from).unwrap();
    }
}

/// Child: a 1080p camera at 30 Hz into a TCP server sending Kairos samples; prints what it produced.
fn camera_server(port: u16, seconds: u64) {
    let text = format!(
        r#"Diagram(format: 1, packs: [], components: [
            Component(id: "camera", type: "sensors.camera", properties: {{"width": 1920, "height": 1080,
                      "rate": 30.0, "pattern": "color_bars"}}),
            Component(id: "link", type: "net.tcp_sender", properties: {{"mode": "server",
                      "address": "127.0.0.1:{port}", "encoding": "kairos"}})],
          connections: [Connection(from: "camera.image", to: "link.in", buffer_size: 8)])"#
    );
    let diagram = kairos_diagram::parse(&text).unwrap().diagram;
    let mut registry = Registry::new();
    kairos_pack_sensors::register(&mut registry);
    kairos_pack_net::register(&mut registry);
    let mut engine = Engine::build(&diagram, &registry, RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    println!("ready");
    std::thread::sleep(Duration::from_secs(seconds));
    let snapshot = engine.snapshot();
    engine.stop();
    let link = &snapshot.links[0].counters;
    let sender = snapshot.components.iter().find(|c| c.id == "link").unwrap();
    println!(
        "{}",
        serde_json::json!({
            "written": link.written, "overwritten": link.overwritten, "skipped": link.skipped,
            "sender": sender.status,
        })
    );
}

fn wait_ready(child: &mut Child) -> BufReader<std::process::ChildStdout> {
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    assert_eq!(line.trim(), "ready");
    out
}

fn latency(kind: &str, round_trips: usize, repetitions: usize) -> (LatencySeries, LatencySeries) {
    let (kairos_listen, kairos_echo_port, raw_port) = (free_port(), free_port(), free_port());
    let mut kairos_child = child(
        "kairos-echo",
        &[
            kairos_echo_port.to_string(),
            kairos_listen.to_string(),
            kind.to_owned(),
        ],
    );
    let mut raw_child = child("raw-echo", &[raw_port.to_string()]);
    wait_ready(&mut kairos_child);
    wait_ready(&mut raw_child);
    let mut ends = KairosEnds::new(kairos_listen, kairos_echo_port, kind, false);
    let to_send = ends.to_send.clone().unwrap();
    let writer = Arc::new(RunSignal::new());
    // The raw baseline sends the very bytes the Kairos link sends.
    let probe = Sample::new(payload(kind), Timestamp(1_700_000_000_000_000_000));
    let bytes = kairos_sample_frame::encode_whole("bench.out", &probe);
    let raw = UdpSocket::bind("127.0.0.1:0").unwrap();
    raw.connect(("127.0.0.1", raw_port)).unwrap();
    let mut buffer = vec![0; 65_536];
    let mut ours = LatencySeries::new(format!("Kairos samples, {kind} ({} B frames)", bytes.len()));
    let mut baseline = LatencySeries::new(format!("raw UDP, the same {} B", bytes.len()));
    let clock = RealTimeClock::shared();
    let sent = payload(kind);
    for repetition in 0..=repetitions {
        let mut kairos_halves = Vec::with_capacity(round_trips);
        let mut raw_halves = Vec::with_capacity(round_trips);
        // Interleaved in blocks of 50, so drifts of the machine hit both alike.
        for block in 0..round_trips / 50 {
            let _ = block;
            for _ in 0..50 {
                let start = Instant::now();
                let sample = Sample::new(sent.clone(), clock.now());
                to_send.write(sample, &writer).unwrap();
                ends.sender.core(&mut ends.sender_ctx).unwrap();
                assert!(ends.receive_one(), "the echo never answered");
                let back = ends.reader.as_mut().unwrap().try_read().unwrap();
                kairos_halves.push(nanos(start.elapsed()) / 2.0);
                std::hint::black_box(back);
            }
            for _ in 0..50 {
                let start = Instant::now();
                raw.send(&bytes).unwrap();
                let read = raw.recv(&mut buffer).unwrap();
                raw_halves.push(nanos(start.elapsed()) / 2.0);
                std::hint::black_box(read);
            }
        }
        // Repetition 0 warms up.
        if repetition > 0 {
            ours.reps.push(Percentiles::of(&mut kairos_halves));
            baseline.reps.push(Percentiles::of(&mut raw_halves));
        }
    }
    let _ = kairos_child.kill();
    let _ = raw_child.kill();
    let _ = kairos_child.wait();
    let _ = raw_child.wait();
    (ours, baseline)
}

fn stream(seconds: u64) {
    let port = free_tcp_port();
    let mut server = child("camera-server", &[port.to_string(), (seconds + 3).to_string()]);
    let mut out = wait_ready(&mut server);
    let text = format!(
        r#"Diagram(format: 1, packs: [], components: [
            Component(id: "link", type: "net.tcp_receiver", properties: {{"mode": "client",
                      "address": "127.0.0.1:{port}", "encoding": "kairos", "data_type": "image"}})],
          connections: [])"#
    );
    let diagram = kairos_diagram::parse(&text).unwrap().diagram;
    let mut registry = Registry::new();
    kairos_pack_net::register(&mut registry);
    let mut engine = Engine::build(&diagram, &registry, RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    std::thread::sleep(Duration::from_secs(seconds));
    let snapshot = engine.snapshot();
    engine.stop();
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    let _ = server.wait();
    let produced: serde_json::Value = serde_json::from_str(&line).unwrap();
    let receiver = &snapshot.components[0];
    let status = receiver.status.clone().unwrap_or_default();
    let count = |value: &serde_json::Value, name: &str| {
        value.get(name).and_then(serde_json::Value::as_u64).unwrap_or(0)
    };
    println!("| figure | value |");
    println!("| --- | --- |");
    println!(
        "| camera frames written (sender, {} s + 3 s) | {} |",
        seconds,
        count(&produced, "written")
    );
    println!(
        "| lost before the socket (overwritten + skipped on the camera → sender link) | {} |",
        count(&produced, "overwritten") + count(&produced, "skipped")
    );
    println!(
        "| sent / dropped by the sender (dropped: before the client connected) | {} / {} |",
        count(&produced["sender"], "sent"),
        count(&produced["sender"], "dropped")
    );
    println!(
        "| received in {seconds} s | {} ({:.1} per s) |",
        count(&status, "received"),
        count(&status, "received") as f64 / seconds as f64
    );
    println!(
        "| **lost in transit** (sequence gaps) | **{}** |",
        count(&status, "lost")
    );
    println!(
        "| reordered / duplicates / malformed | {} / {} / {} |",
        count(&status, "reordered"),
        count(&status, "duplicates"),
        count(&status, "malformed")
    );
}

fn main() {
    if let Ok(role) = std::env::var(ROLE) {
        let args: Vec<String> = std::env::args().skip(1).collect();
        let number = |index: usize| args[index].parse::<u16>().unwrap();
        match role.as_str() {
            "kairos-echo" => kairos_echo(number(0), number(1), &args[2]),
            "raw-echo" => raw_echo(number(0)),
            "camera-server" => camera_server(number(0), u64::from(number(1))),
            other => panic!("unknown role {other}"),
        }
        return;
    }
    header(
        "15. Kairos-sample socket link between two processes on loopback",
        "latency: round trip / 2, back to back; throughput: 1080p RGB at 30 Hz over TCP",
        &format!(
            "the components' `core` called on the measuring thread; raw UDP ping-pong of the same bytes; {}",
            kairos_benches::pinning_note()
        ),
    );
    kairos_benches::pin_current_thread(false);
    let round_trips = size(500, 5000);
    let repetitions = kairos_benches::repetitions();
    let mut ratios = Ratios::new();
    for kind in ["imu", "bytes"] {
        let (ours, baseline) = latency(kind, round_trips, repetitions);
        print_latency(&[&ours, &baseline]);
        ratios.add(
            format!("{kind}: Kairos-sample link p50 / raw UDP p50"),
            kairos_benches::ratio_spread(&ours, &baseline, |p| p.p50),
            Some(Goal::AtMost(1.3)),
        );
    }
    ratios.print();
    // The engines' threads inherit this thread's placement: every core again.
    let mut every_core = nix::sched::CpuSet::new();
    for cpu in 0..kairos_benches::cores() {
        let _ = every_core.set(cpu);
    }
    let _ = nix::sched::sched_setaffinity(nix::unistd::Pid::from_raw(0), &every_core);
    stream(size(5, 60));
}
