//! Benchmark 17 — a link between two hosts (two processes on loopback) against Zenoh alone.
//!
//! Both sides use one Zenoh session per process, configured as `kairos deploy` configures it, and the
//! baseline publishes and subscribes on that very session, so the configuration is the same by
//! construction.
//!
//! 1. Latency: a sample written into a `link.sender`'s input, received by a `link.receiver` in the other
//!    process, whose output feeds a `link.sender` back, received here by a `link.receiver`: half the round
//!    trip. Baseline: a Zenoh publisher putting the same frame bytes, a subscriber with the same queue in
//!    the other process putting them back. The components run as the engine calls them (`core` on a
//!    context whose ports are real buffers) on the measuring threads.
//! 2. Throughput: samples of 64 B and of 6 MB pushed back to back through a reliable (blocking) link and
//!    counted by the other process, against a blocking Zenoh publisher and a counting subscriber.
//!
//! The child process is this binary again, started with `KAIROS_BENCH_ZENOH_ROLE`.

#![allow(
    clippy::unwrap_used,
    reason = "a failure here is a broken benchmark, not something to carry on from"
)]

use std::io::{BufRead as _, BufReader};
use std::net::TcpListener;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use kairos_benches::{
    Goal, LatencySeries, Percentiles, Ratios, component_context, header, nanos, print_latency, size,
};
use kairos_diagram::{ComponentInstance, Diagram};
use kairos_pack_link::{LinkReceiver, LinkSender, network};
use kairos_protocol::LinkNetwork;
use kairos_sdk_core::host::{OutputBuffer, ReaderConfig};
use kairos_sdk_core::{
    Component, Context, Payload, ReaderPolicy, RealTimeClock, RunSignal, Sample, Timestamp, Value,
};
use zenoh::Wait as _;
use zenoh::handlers::{FifoChannel, RingChannel};
use zenoh::qos::CongestionControl;

const ROLE: &str = "KAIROS_BENCH_ZENOH_ROLE";
/// Latency: there (link), back (link), there (raw), back (raw).
const THERE: &str = "bench/link/there";
const BACK: &str = "bench/link/back";
const RAW_THERE: &str = "bench/raw/there";
const RAW_BACK: &str = "bench/raw/back";
/// Throughput: the streams, and the counts coming back.
const STREAM: &str = "bench/link/stream";
const RAW_STREAM: &str = "bench/raw/stream";
const DONE: &str = "bench/done";

fn link(type_name: &str, key: &str, reliable: bool, data_type: &str) -> ComponentInstance {
    let mut component = ComponentInstance::new(key.replace('/', "_"), type_name);
    component.properties.insert("key".into(), Value::Text(key.into()));
    component
        .properties
        .insert("reliable".into(), Value::Bool(reliable));
    component
        .properties
        .insert("peer".into(), Value::Text("the other process".into()));
    component
        .properties
        .insert("data_type".into(), Value::Text(data_type.into()));
    component.properties.insert("queue".into(), Value::I64(16));
    component
}

/// Joins the network and declares the link ends this process holds.
fn prepare(spec: &LinkNetwork, ends: Vec<ComponentInstance>) {
    network::join(spec).unwrap();
    let diagram = Diagram {
        components: ends,
        ..Diagram::default()
    };
    network::prepare(&diagram).unwrap();
}

/// A sender on `key` fed by a buffer of its own, or by `feed`.
fn sender(key: &str, feed: Option<&OutputBuffer>) -> (LinkSender, Context, OutputBuffer) {
    let buffer = feed
        .cloned()
        .unwrap_or_else(|| OutputBuffer::new("bench.out", 16));
    let reader = buffer.attach(
        ReaderConfig::new(ReaderPolicy::Fifo, "bench -> sender.in"),
        Arc::new(RunSignal::new()),
    );
    let (mut ctx, _) = component_context(
        &kairos_pack_link::sender_descriptor(),
        &[("key", Value::Text(key.into()))],
        vec![Some(reader)],
    );
    let mut component = LinkSender::default();
    component.birth(&mut ctx).unwrap();
    (component, ctx, buffer)
}

/// A receiver on `key` writing into the buffer returned.
fn receiver(key: &str, data_type: &str) -> (LinkReceiver, Context, OutputBuffer) {
    let properties =
        std::collections::BTreeMap::from([("data_type".to_owned(), Value::Text(data_type.into()))]);
    let info = kairos_pack_link::describe_receiver(&properties).unwrap();
    let (mut ctx, mut buffers) = component_context(
        &info,
        &[
            ("key", Value::Text(key.into())),
            ("data_type", Value::Text(data_type.into())),
        ],
        Vec::new(),
    );
    let mut component = LinkReceiver::default();
    component.birth(&mut ctx).unwrap();
    (component, ctx, buffers.remove(0))
}

/// Runs `receiver` until it has written one more sample (false if none came within 2 s).
fn receive_one(receiver: &mut LinkReceiver, ctx: &mut Context, written: &OutputBuffer) -> bool {
    let before = written.written();
    for _ in 0..40 {
        receiver.core(ctx).unwrap();
        if written.written() > before {
            return true;
        }
    }
    false
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// The child: echoes both latency streams and counts both throughput streams, each on its own thread.
fn child_main(port: u16) {
    let spec = LinkNetwork {
        listen: vec![format!("tcp/127.0.0.1:{port}")],
        ..LinkNetwork::default()
    };
    prepare(
        &spec,
        vec![
            link(kairos_pack_link::RECEIVER, THERE, false, "bytes"),
            link(kairos_pack_link::SENDER, BACK, false, "bytes"),
            link(kairos_pack_link::RECEIVER, STREAM, true, "bytes"),
        ],
    );
    let session = network::session().unwrap();
    let done = session.declare_publisher(DONE).wait().unwrap();
    let raw_back = session.declare_publisher(RAW_BACK).wait().unwrap();
    let raw_there = session
        .declare_subscriber(RAW_THERE)
        .with(RingChannel::new(16))
        .wait()
        .unwrap();
    let raw_stream = session
        .declare_subscriber(RAW_STREAM)
        .with(FifoChannel::new(16))
        .wait()
        .unwrap();
    std::thread::scope(|scope| {
        scope.spawn(|| {
            let (mut link_in, mut ctx, echoed) = receiver(THERE, "bytes");
            let (mut link_out, mut sender_ctx, _) = sender(BACK, Some(&echoed));
            loop {
                if receive_one(&mut link_in, &mut ctx, &echoed) {
                    link_out.core(&mut sender_ctx).unwrap();
                }
            }
        });
        scope.spawn(|| {
            while let Ok(sample) = raw_there.recv() {
                raw_back.put(sample.payload().clone()).wait().unwrap();
            }
        });
        scope.spawn(|| {
            let (mut link_in, mut ctx, counted_out) = receiver(STREAM, "bytes");
            let mut counted = 0;
            loop {
                link_in.core(&mut ctx).unwrap();
                // Each sample whole, decoded into its payload as a consumer would read it.
                while counted_out.written() > counted {
                    counted += 1;
                    done.put(format!("link {counted}")).wait().unwrap();
                }
            }
        });
        scope.spawn(|| {
            let mut counted = 0_u64;
            while let Ok(sample) = raw_stream.recv() {
                counted += 1;
                std::hint::black_box(sample.payload().to_bytes().len());
                done.put(format!("raw {counted}")).wait().unwrap();
            }
        });
        println!("ready");
    });
}

fn bytes_payload(size: usize) -> Payload {
    Payload::Bytes(Arc::from(vec![7_u8; size]))
}

fn latency(round_trips: usize, repetitions: usize) -> (LatencySeries, LatencySeries) {
    let session = network::session().unwrap();
    let (mut there, mut there_ctx, to_send) = sender(THERE, None);
    let (mut back, mut back_ctx, received) = receiver(BACK, "bytes");
    let mut reader = received.attach(
        ReaderConfig::new(ReaderPolicy::Fifo, "receiver.samples -> bench"),
        Arc::new(RunSignal::new()),
    );
    let raw_there = session.declare_publisher(RAW_THERE).wait().unwrap();
    let raw_back = session
        .declare_subscriber(RAW_BACK)
        .with(RingChannel::new(16))
        .wait()
        .unwrap();
    let payload = bytes_payload(64);
    let probe = Sample::new(payload.clone(), Timestamp(1_700_000_000_000_000_000));
    let frame = kairos_pack_link::frame_of("bench.out", &probe);
    let mut ours = LatencySeries::new(format!("link, 64 B of bytes ({} B frames)", frame.len()));
    let mut baseline = LatencySeries::new(format!("Zenoh alone, the same {} B", frame.len()));
    let clock = RealTimeClock::shared();
    let writer = Arc::new(RunSignal::new());
    for repetition in 0..=repetitions {
        let mut link_halves = Vec::with_capacity(round_trips);
        let mut raw_halves = Vec::with_capacity(round_trips);
        // Interleaved in blocks of 50, so drifts of the machine hit both alike.
        for _ in 0..round_trips / 50 {
            for _ in 0..50 {
                let start = Instant::now();
                to_send
                    .write(Sample::new(payload.clone(), clock.now()), &writer)
                    .unwrap();
                there.core(&mut there_ctx).unwrap();
                assert!(receive_one(&mut back, &mut back_ctx, &received), "no echo");
                std::hint::black_box(reader.try_read());
                link_halves.push(nanos(start.elapsed()) / 2.0);
            }
            for _ in 0..50 {
                let start = Instant::now();
                raw_there.put(frame.clone()).wait().unwrap();
                let echoed = raw_back
                    .recv_timeout(Duration::from_secs(2))
                    .unwrap()
                    .expect("no echo");
                std::hint::black_box(echoed.payload().to_bytes().len());
                raw_halves.push(nanos(start.elapsed()) / 2.0);
            }
        }
        // Repetition 0 warms up.
        if repetition > 0 {
            ours.reps.push(Percentiles::of(&mut link_halves));
            baseline.reps.push(Percentiles::of(&mut raw_halves));
        }
    }
    (ours, baseline)
}

/// Samples per second of `size` bytes through the link and through Zenoh alone, per repetition.
fn throughput(size: usize, count: u64, repetitions: usize) -> (Vec<f64>, Vec<f64>) {
    let session = network::session().unwrap();
    let done = session
        .declare_subscriber(DONE)
        .with(FifoChannel::new(1 << 16))
        .wait()
        .unwrap();
    let (mut link, mut link_ctx, to_send) = sender(STREAM, None);
    let raw = session
        .declare_publisher(RAW_STREAM)
        .congestion_control(CongestionControl::Block)
        .wait()
        .unwrap();
    let payload = bytes_payload(size);
    // The bytes the link puts on Zenoh for such a sample (compact, or header and shared payload).
    let frame = kairos_pack_link::frame_of(
        "bench.out",
        &Sample::new(payload.clone(), Timestamp(1_700_000_000_000_000_000)),
    );
    let clock = RealTimeClock::shared();
    let writer = Arc::new(RunSignal::new());
    let (mut link_counted, mut raw_counted) = (0_u64, 0_u64);
    let wait_for = |prefix: &str, target: u64| loop {
        let sample = done
            .recv_timeout(Duration::from_secs(30))
            .unwrap()
            .expect("the count never came");
        let text = sample.payload().try_to_string().unwrap().into_owned();
        if let Some(n) = text
            .strip_prefix(prefix)
            .and_then(|n| n.trim().parse::<u64>().ok())
            && n >= target
        {
            return;
        }
    };
    let (mut ours, mut baseline) = (Vec::new(), Vec::new());
    for repetition in 0..=repetitions {
        let start = Instant::now();
        for _ in 0..count {
            to_send
                .write(Sample::new(payload.clone(), clock.now()), &writer)
                .unwrap();
            link.core(&mut link_ctx).unwrap();
        }
        link_counted += count;
        wait_for("link ", link_counted);
        let link_rate = count as f64 / start.elapsed().as_secs_f64();
        let start = Instant::now();
        for _ in 0..count {
            // A clone of `ZBytes` shares the bytes: Zenoh alone pays no copy here.
            raw.put(frame.clone()).wait().unwrap();
        }
        raw_counted += count;
        wait_for("raw ", raw_counted);
        let raw_rate = count as f64 / start.elapsed().as_secs_f64();
        if repetition > 0 {
            ours.push(link_rate);
            baseline.push(raw_rate);
        }
    }
    (ours, baseline)
}

fn main() {
    if let Ok(role) = std::env::var(ROLE) {
        assert_eq!(role, "child");
        let port = std::env::args().nth(1).unwrap().parse().unwrap();
        child_main(port);
        return;
    }
    header(
        "17. A link between two hosts (two processes, loopback) against Zenoh alone",
        "latency: round trip / 2, back to back; throughput: back to back, reliable, counted by the other process",
        "the link components' `core` on the measuring threads; the baseline on the same Zenoh sessions",
    );
    let port = free_port();
    let mut child: Child = Command::new(std::env::current_exe().unwrap())
        .env(ROLE, "child")
        .arg(port.to_string())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    assert_eq!(line.trim(), "ready");
    let spec = LinkNetwork {
        connect: vec![format!("tcp/127.0.0.1:{port}")],
        ..LinkNetwork::default()
    };
    prepare(
        &spec,
        vec![
            link(kairos_pack_link::SENDER, THERE, false, "bytes"),
            link(kairos_pack_link::RECEIVER, BACK, false, "bytes"),
            link(kairos_pack_link::SENDER, STREAM, true, "bytes"),
        ],
    );
    // Wait for the other process's subscribers to match.
    let deadline = Instant::now() + Duration::from_secs(5);
    while network::ends().iter().any(|end| !end.matched) {
        assert!(Instant::now() < deadline, "the links never matched");
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(200));
    let repetitions = kairos_benches::repetitions();
    let mut ratios = Ratios::new();
    let (ours, baseline) = latency(size(500, 5000), repetitions);
    print_latency(&[&ours, &baseline]);
    ratios.add(
        "latency: link p50 / Zenoh alone p50 (64 B)",
        kairos_benches::ratio_spread(&ours, &baseline, |p| p.p50),
        Some(Goal::AtMost(1.2)),
    );
    let mut table = kairos_benches::Table::new(&["payload", "link (samples/s)", "Zenoh alone (samples/s)"]);
    for (label, bytes, count) in [
        ("64 B", 64, size(2_000, 20_000)),
        ("6 MB", 6_000_000, size(20, 100)),
    ] {
        let (ours, baseline) = throughput(bytes, count, repetitions);
        let spread = kairos_benches::Spread::of(ours.iter().zip(&baseline).map(|(o, b)| o / b));
        table.row(vec![
            label.to_owned(),
            kairos_benches::Spread::of(ours.iter().copied()).show(|r| format!("{r:.0}")),
            kairos_benches::Spread::of(baseline.iter().copied()).show(|r| format!("{r:.0}")),
        ]);
        ratios.add(
            format!("throughput at {label}: link / Zenoh alone"),
            spread,
            Some(Goal::AtLeast(0.9)),
        );
    }
    table.print();
    ratios.print();
    let _ = child.kill();
    let _ = child.wait();
}
