//! Benchmark 10 — the control protocol, against a real `kairos serve` (in this process, on loopback).
//!
//! 1. Round trip of a request: `set_property` on a running component → its reply (the request is decoded,
//!    delivered to the component's thread, applied, acknowledged and answered), against a bare WebSocket
//!    ping → pong over the same connection, interleaved in the same run: back to back, and each from a
//!    quiet server (0.5 ms after the previous one).
//! 2. The runtime's cost of telemetry: CPU time of the server's threads (named `k:net`: network and
//!    blocking pools, where snapshots are taken) with four clients subscribed at 10 Hz, reading every event,
//!    over the same time with no client, as a share of one core. The diagram runs either way; its own
//!    threads are not counted.

use std::net::{SocketAddr, TcpStream};
use std::time::{Duration, Instant};

use kairos_benches::{
    Goal, LatencySeries, Percentiles, Ratios, Table, header, nanos, print_latency, ratio_spread, size,
};
use serde_json::json;
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

type Socket = WebSocket<MaybeTlsStream<TcpStream>>;

/// The pause before each round trip measured from quiet: what the previous one left running (a
/// component's thread going back to sleep, the network workers parking) has settled, as before a control
/// request a person sends.
const QUIET: Duration = Duration::from_micros(500);

fn connect(address: SocketAddr) -> Option<Socket> {
    let (mut socket, _) = tungstenite::connect(format!("ws://{address}")).ok()?;
    call(
        &mut socket,
        &json!({"id": 0, "type": "hello", "protocol": 1, "client": "bench"}),
    )?;
    Some(socket)
}

fn call(socket: &mut Socket, request: &serde_json::Value) -> Option<serde_json::Value> {
    socket.send(Message::text(request.to_string())).ok()?;
    loop {
        if let Message::Text(text) = socket.read().ok()? {
            let reply: serde_json::Value = serde_json::from_str(text.as_str()).ok()?;
            if reply["type"] == "reply" && reply["id"] == request["id"] {
                return (reply["ok"] == true).then_some(reply);
            }
        }
    }
}

fn ping(socket: &mut Socket) -> Option<()> {
    socket.send(Message::Ping(vec![1_u8; 8].into())).ok()?;
    loop {
        if let Message::Pong(_) = socket.read().ok()? {
            return Some(());
        }
    }
}

/// CPU time of this process's threads whose name starts with `k:net`, in nanoseconds.
fn network_cpu_nanos() -> u64 {
    let ticks_per_second = 100.0; // USER_HZ on Linux
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return 0;
    };
    let mut total = 0.0;
    for task in tasks.flatten() {
        let path = task.path();
        let name = std::fs::read_to_string(path.join("comm")).unwrap_or_default();
        if !name.starts_with("k:net") {
            continue;
        }
        let stat = std::fs::read_to_string(path.join("stat")).unwrap_or_default();
        // Fields after the command name (which ends with ')'): utime is the 12th, stime the 13th.
        let fields: Vec<&str> = stat
            .rsplit_once(')')
            .map_or("", |(_, rest)| rest)
            .split_whitespace()
            .collect();
        let ticks: f64 = [11, 12]
            .iter()
            .filter_map(|i| fields.get(*i).and_then(|f| f.parse::<f64>().ok()))
            .sum();
        total += ticks / ticks_per_second;
    }
    (total * 1e9) as u64
}

fn telemetry_share(address: SocketAddr, clients: usize, window: Duration) -> Option<f64> {
    let mut sockets = Vec::new();
    for id in 0..clients {
        let mut socket = connect(address)?;
        call(
            &mut socket,
            &json!({"id": 100 + id, "type": "subscribe_telemetry", "interval_ms": 100}),
        )?;
        if let MaybeTlsStream::Plain(stream) = socket.get_ref() {
            stream.set_read_timeout(Some(Duration::from_millis(20))).ok()?;
        }
        sockets.push(socket);
    }
    let before = network_cpu_nanos();
    let started = Instant::now();
    let mut events = 0;
    while started.elapsed() < window {
        for socket in &mut sockets {
            while let Ok(Message::Text(_)) = socket.read() {
                events += 1;
            }
        }
        if clients == 0 {
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    let spent = network_cpu_nanos().saturating_sub(before);
    if clients > 0 && events < clients * 5 {
        return None;
    }
    Some(spent as f64 / nanos(started.elapsed()))
}

fn main() {
    let round_trips = size(300, 2_000);
    let window = Duration::from_secs(size(2, 5));
    header(
        "10. Control protocol: request round trip and telemetry cost",
        "loopback WebSocket, server in this process, a running example diagram",
        &format!(
            "{round_trips} round trips per repetition; telemetry windows of {} s",
            window.as_secs()
        ),
    );
    let Some(address) = kairos_benches::start_kairos_serve() else {
        println!("the server did not start");
        return;
    };
    let Some(mut socket) = connect(address) else {
        println!("cannot connect");
        return;
    };
    let diagram = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/fusion.ron"))
        .unwrap_or_default();
    let hello = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/hello.ron"))
        .unwrap_or_default();
    let mut ours = LatencySeries::new("ours: set_property → reply, back to back");
    let mut bare = LatencySeries::new("baseline: WebSocket ping → pong, back to back");
    let mut ours_quiet = LatencySeries::new("ours: set_property → reply, from quiet");
    let mut bare_quiet = LatencySeries::new("baseline: WebSocket ping → pong, from quiet");
    if call(&mut socket, &json!({"id": 1, "type": "deploy", "diagram": hello})).is_none()
        || call(&mut socket, &json!({"id": 2, "type": "start"})).is_none()
    {
        println!("cannot run the hello example");
        return;
    }
    let mut id = 10_u64;
    for _ in 0..kairos_benches::repetitions() {
        for (quiet, ours, bare) in [
            (Duration::ZERO, &mut ours, &mut bare),
            (QUIET, &mut ours_quiet, &mut bare_quiet),
        ] {
            let mut request_times = Vec::with_capacity(round_trips);
            let mut ping_times = Vec::with_capacity(round_trips);
            for i in 0..round_trips {
                id += 1;
                let gain = 1.0 + (i % 7) as f64;
                let request = json!({"id": id, "type": "set_property", "component": "gain1", "property": "gain", "value": gain});
                std::thread::sleep(quiet);
                let started = Instant::now();
                if call(&mut socket, &request).is_none() {
                    println!("set_property failed");
                    return;
                }
                request_times.push(nanos(started.elapsed()));
                std::thread::sleep(quiet);
                let started = Instant::now();
                if ping(&mut socket).is_none() {
                    println!("ping failed");
                    return;
                }
                ping_times.push(nanos(started.elapsed()));
            }
            ours.reps.push(Percentiles::of(&mut request_times));
            bare.reps.push(Percentiles::of(&mut ping_times));
        }
    }
    print_latency(&[&bare, &ours, &bare_quiet, &ours_quiet]);
    let mut ratios = Ratios::new();
    ratios.add(
        "p50: request round trip / ping, back to back",
        ratio_spread(&ours, &bare, |p| p.p50),
        Some(Goal::AtMost(2.0)),
    );
    ratios.add(
        "p50: request round trip / ping, from quiet",
        ratio_spread(&ours_quiet, &bare_quiet, |p| p.p50),
        Some(Goal::AtMost(2.0)),
    );
    ratios.add(
        "p99: request round trip / ping, back to back",
        ratio_spread(&ours, &bare, |p| p.p99),
        None,
    );
    ratios.print();

    if call(
        &mut socket,
        &json!({"id": 3, "type": "deploy", "diagram": diagram}),
    )
    .is_none()
        || call(&mut socket, &json!({"id": 4, "type": "start"})).is_none()
    {
        println!("cannot run the fusion example");
        return;
    }
    let mut table = Table::new(&[
        "repetition",
        "no client",
        "4 clients at 10 Hz",
        "difference",
        "goal",
    ]);
    for repetition in 0..kairos_benches::repetitions() {
        let (Some(idle), Some(busy)) = (
            telemetry_share(address, 0, window),
            telemetry_share(address, 4, window),
        ) else {
            println!("a telemetry run failed");
            return;
        };
        let cost = busy - idle;
        table.row(vec![
            repetition.to_string(),
            format!("{:.2} %", idle * 100.0),
            format!("{:.2} %", busy * 100.0),
            format!("{:.2} %", cost * 100.0),
            format!(
                "≤ 2 % of one core: {}",
                if cost <= 0.02 { "met" } else { "MISSED" }
            ),
        ]);
    }
    table.print();
}
