//! Benchmark 21 — live in Foxglove against the same subscription over Kairos's own protocol.
//!
//! A real `kairos serve` (in this process, on loopback) runs a simulated camera (640×480 RGB, 30 Hz) and IMU
//! (100 Hz: within the 120 frames a second the control protocol sends per output, so both paths carry every
//! sample). One client reads both outputs in full, either over the control protocol (`subscribe_samples`,
//! frames on the socket) or as a Foxglove client subscribed to both channels. The figure is the CPU time
//! of the server's threads that serve that client, from their scheduler statistics (ns): `k:net` for the
//! control protocol (network workers and blocking pool), `k:foxglove` for Foxglove (the crate's server
//! runtime and the thread that reads and encodes). The diagram's own threads are not counted by either.
//! Repetitions alternate the two.

use std::net::{SocketAddr, TcpStream};
use std::time::{Duration, Instant};

use kairos_benches::{Goal, Ratios, Spread, Table, header, repetitions, size};
use serde_json::{Value, json};
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

type Socket = WebSocket<MaybeTlsStream<TcpStream>>;

const DIAGRAM: &str = r#"Diagram(
    format: 1,
    components: [
        Component(id: "camera", type: "sensors.camera", properties: {"width": 640, "height": 480, "rate": 30.0}),
        Component(id: "imu", type: "sensors.imu", properties: {"rate": 100.0}),
    ],
)"#;

fn call(socket: &mut Socket, request: &Value) -> Option<Value> {
    socket.send(Message::text(request.to_string())).ok()?;
    loop {
        if let Message::Text(text) = socket.read().ok()? {
            let reply: Value = serde_json::from_str(text.as_str()).ok()?;
            if reply["type"] == "reply" && reply["id"] == request["id"] {
                return (reply["ok"] == true).then_some(reply);
            }
        }
    }
}

fn control_client(address: SocketAddr) -> Option<Socket> {
    let (mut socket, _) = tungstenite::connect(format!("ws://{address}")).ok()?;
    call(
        &mut socket,
        &json!({"id": 0, "type": "hello", "protocol": 1, "client": "bench"}),
    )?;
    Some(socket)
}

/// On-CPU time of this process's threads whose name starts with `prefix`, in nanoseconds.
fn threads_cpu_nanos(prefix: &str) -> f64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return 0.0;
    };
    tasks
        .flatten()
        .filter(|task| {
            std::fs::read_to_string(task.path().join("comm")).is_ok_and(|name| name.starts_with(prefix))
        })
        .filter_map(|task| {
            let stat = std::fs::read_to_string(task.path().join("schedstat")).ok()?;
            stat.split_whitespace().next()?.parse::<f64>().ok()
        })
        .sum()
}

/// Reads whatever `socket` receives for `window`; how many data messages came (binary frames).
fn read_for(socket: &mut Socket, window: Duration) -> u64 {
    if let MaybeTlsStream::Plain(stream) = socket.get_ref() {
        let _ = stream.set_read_timeout(Some(Duration::from_millis(50)));
    }
    let until = Instant::now() + window;
    let mut frames = 0;
    while Instant::now() < until {
        if let Ok(Message::Binary(_)) = socket.read() {
            frames += 1;
        }
    }
    frames
}

/// One measured window; the share of one core the serving threads took, and the frames the client got.
struct Window {
    cpu_share: f64,
    frames: u64,
}

fn over_control_protocol(address: SocketAddr, warm_up: Duration, window: Duration) -> Option<Window> {
    let mut client = control_client(address)?;
    call(
        &mut client,
        &json!({"id": 1, "type": "subscribe_samples", "outputs": ["camera.image", "imu.imu"], "max_rate_hz": 120}),
    )?;
    read_for(&mut client, warm_up);
    let before = threads_cpu_nanos("k:net");
    let frames = read_for(&mut client, window);
    let spent = threads_cpu_nanos("k:net") - before;
    Some(Window {
        cpu_share: spent / window.as_nanos() as f64,
        frames,
    })
}

fn foxglove_client(url: &str) -> Option<Socket> {
    use tungstenite::client::IntoClientRequest as _;
    let mut request = url.into_client_request().ok()?;
    request
        .headers_mut()
        .insert("Sec-WebSocket-Protocol", "foxglove.sdk.v1".parse().ok()?);
    let (socket, _) = tungstenite::connect(request).ok()?;
    Some(socket)
}

fn over_foxglove(url: &str, warm_up: Duration, window: Duration) -> Option<Window> {
    let mut client = foxglove_client(url)?;
    let mut channels = Vec::new();
    while channels.len() < 2 {
        if let Message::Text(text) = client.read().ok()? {
            let message: Value = serde_json::from_str(text.as_str()).ok()?;
            if message["op"] == "advertise" {
                channels.extend(message["channels"].as_array()?.iter().map(|c| c["id"].clone()));
            }
        }
    }
    let subscriptions: Vec<Value> = channels
        .iter()
        .enumerate()
        .map(|(id, channel)| json!({"id": id, "channelId": channel}))
        .collect();
    let subscribe = json!({"op": "subscribe", "subscriptions": subscriptions});
    client.send(Message::text(subscribe.to_string())).ok()?;
    read_for(&mut client, warm_up);
    let before = threads_cpu_nanos("k:foxglove");
    let frames = read_for(&mut client, window);
    let spent = threads_cpu_nanos("k:foxglove") - before;
    Some(Window {
        cpu_share: spent / window.as_nanos() as f64,
        frames,
    })
}

fn main() {
    let window = Duration::from_secs(size(2, 5));
    let warm_up = Duration::from_secs(1);
    header(
        "21. Live in Foxglove against the control protocol",
        "one client reading a 640×480 camera at 30 Hz and an IMU at 100 Hz",
        &format!(
            "windows of {} s after 1 s of warm-up, alternating",
            window.as_secs()
        ),
    );
    let Some(address) = kairos_benches::start_kairos_serve() else {
        eprintln!("kairos serve did not start");
        return;
    };
    let Some(mut operator) = control_client(address) else {
        eprintln!("cannot connect to kairos serve");
        return;
    };
    let deployed = call(&mut operator, &json!({"id": 2, "type": "deploy", "diagram": DIAGRAM}))
        .and_then(|_| call(&mut operator, &json!({"id": 3, "type": "start"})))
        .and_then(|_| {
            call(
                &mut operator,
                &json!({"id": 4, "type": "foxglove_publish", "outputs": ["camera.image", "imu.imu"], "publish": true}),
            )
        });
    let Some(url) = deployed.and_then(|r| r["result"]["address"].as_str().map(str::to_owned)) else {
        eprintln!("the diagram or Foxglove did not start");
        return;
    };
    let mut table = Table::new(&["rep", "control protocol", "frames", "Foxglove", "messages"]);
    let (mut control, mut foxglove) = (Vec::new(), Vec::new());
    for rep in 0..repetitions() {
        let (Some(ours), Some(theirs)) = (
            over_control_protocol(address, warm_up, window),
            over_foxglove(&url, warm_up, window),
        ) else {
            eprintln!("a client failed");
            return;
        };
        table.row(vec![
            rep.to_string(),
            format!("{:.2} %", ours.cpu_share * 100.0),
            ours.frames.to_string(),
            format!("{:.2} %", theirs.cpu_share * 100.0),
            theirs.frames.to_string(),
        ]);
        control.push(ours.cpu_share);
        foxglove.push(theirs.cpu_share);
    }
    table.print();
    let per_rep: Vec<f64> = foxglove.iter().zip(&control).map(|(f, c)| f / c).collect();
    let mut ratios = Ratios::new();
    ratios.add(
        "server CPU: Foxglove / control protocol",
        Spread::of(per_rep),
        Some(Goal::AtMost(1.2)),
    );
    ratios.print();
    let share = |values: &[f64]| Spread::of(values.iter().map(|v| v * 100.0)).show(|v| format!("{v:.2} %"));
    println!(
        "share of one core: control protocol {}, Foxglove {}",
        share(&control),
        share(&foxglove)
    );
}
