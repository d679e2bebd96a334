//! The control protocol over a real socket against the real `kairos serve`: the role table, bad input,
//! tokens, isolation of a running diagram from misbehaving clients, and the Python example client.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

mod common;

use std::fmt::Write as _;
use std::io::{BufRead as _, BufReader};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::{RwLock, RwLockReadGuard, RwLockWriteGuard};
use std::time::{Duration, Instant};

use common::{example, repo_root, text};
use kairos_protocol::{RequestKind, Role};
use serde_json::{Value, json};
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

type Socket = WebSocket<MaybeTlsStream<TcpStream>>;

/// A `kairos serve` on a free loopback port, killed when dropped.
struct Server {
    child: Child,
    url: String,
    token: String,
    /// What `--foxglove` printed: `ws://127.0.0.1:PORT`.
    foxglove: Option<String>,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `N` fresh temporary folders: the runtimes' and the deploying machine's.
fn folders<const N: usize>() -> [tempfile::TempDir; N] {
    std::array::from_fn(|_| tempfile::tempdir().unwrap())
}

fn serve(dir: &Path, extra: &[&str]) -> Server {
    serve_with_env(dir, extra, &[])
}

fn serve_with_env(dir: &Path, extra: &[&str], env: &[(&str, &str)]) -> Server {
    serve_on(dir, "127.0.0.1:0", extra, env)
}

fn serve_on(dir: &Path, listen: &str, extra: &[&str], env: &[(&str, &str)]) -> Server {
    serve_in(None, dir, listen, extra, env)
}

/// `kairos serve` in network namespace `namespace` (`ip netns exec`), or in this one.
fn serve_in(
    namespace: Option<&str>,
    dir: &Path,
    listen: &str,
    extra: &[&str],
    env: &[(&str, &str)],
) -> Server {
    let token_file = dir.join("token.txt");
    let mut command = match namespace {
        Some(namespace) => {
            let mut command = Command::new("ip");
            command.args(["netns", "exec", namespace, env!("CARGO_BIN_EXE_kairos")]);
            command
        }
        None => Command::new(env!("CARGO_BIN_EXE_kairos")),
    };
    let mut child = command
        .envs(env.iter().copied())
        .args(["serve", "--listen", listen, "--token-file"])
        .arg(&token_file)
        .arg("--monitor-token-file")
        .arg(dir.join("monitor.txt"))
        .args(extra)
        .current_dir(dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let mut foxglove = None;
    let url = loop {
        let line = lines.next().expect("serve printed its address").unwrap();
        if let Some(url) = line.strip_prefix("listening on ") {
            break url.to_owned();
        }
        if let Some(url) = line.strip_prefix("foxglove on ") {
            foxglove = Some(url.to_owned());
        }
    };
    // Keep draining standard output (the console component prints there) so the server never blocks.
    std::thread::spawn(move || for _ in lines {});
    let token = std::fs::read_to_string(&token_file).unwrap().trim().to_owned();
    Server {
        child,
        url,
        token,
        foxglove,
    }
}

fn connect(server: &Server) -> Socket {
    let (socket, _) = tungstenite::connect(&server.url).unwrap();
    if let MaybeTlsStream::Plain(stream) = socket.get_ref() {
        stream.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    }
    socket
}

/// Sends `request` and returns the reply with its id, skipping events and sample frames.
fn call(socket: &mut Socket, request: &Value) -> Value {
    socket.send(Message::text(request.to_string())).unwrap();
    loop {
        match socket.read().unwrap() {
            Message::Text(text) => {
                let message: Value = serde_json::from_str(text.as_str()).unwrap();
                if message["type"] == "reply" && message["id"] == request["id"] {
                    return message;
                }
            }
            Message::Close(_) => panic!("closed while waiting for {request}"),
            _ => {}
        }
    }
}

/// The next reply, whatever its id.
fn next_reply(socket: &mut Socket) -> Value {
    loop {
        if let Message::Text(text) = socket.read().unwrap() {
            let message: Value = serde_json::from_str(text.as_str()).unwrap();
            if message["type"] == "reply" {
                return message;
            }
        }
    }
}

fn hello(socket: &mut Socket, token: &str, role: &str) -> Value {
    call(
        socket,
        &json!({"id": 1, "type": "hello", "protocol": 1, "client": "test", "token": token, "role": role}),
    )
}

fn operator(server: &Server) -> Socket {
    let mut socket = connect(server);
    let reply = hello(&mut socket, &server.token, "operator");
    assert_eq!(reply["ok"], true, "{reply}");
    socket
}

fn deploy_and_start(socket: &mut Socket, diagram: &str) {
    let reply = call(socket, &json!({"id": 2, "type": "deploy", "diagram": diagram}));
    assert_eq!(reply["ok"], true, "{reply}");
    let reply = call(socket, &json!({"id": 3, "type": "start"}));
    assert_eq!(reply["ok"], true, "{reply}");
}

fn state(socket: &mut Socket) -> String {
    let reply = call(socket, &json!({"id": 99, "type": "status"}));
    reply["result"]["state"].as_str().unwrap().to_owned()
}

/// A request of each type, with plausible fields (what they name may not exist: only the role check
/// matters for the matrix).
fn sample_request(kind: RequestKind, id: u64) -> Value {
    let mut request = json!({"id": id, "type": kind.name()});
    let fields = match kind {
        RequestKind::Hello => json!({"protocol": 1, "client": "x"}),
        RequestKind::Deploy => json!({"diagram": "Diagram(format: 1)"}),
        RequestKind::SetProperty => json!({"component": "gain1", "property": "gain", "value": 3.0}),
        RequestKind::TriggerAction => json!({"component": "gain1", "action": "reset"}),
        RequestKind::SubscribeTelemetry => json!({"interval_ms": 1000}),
        RequestKind::SubscribeSamples => json!({"outputs": ["sine1.out"]}),
        RequestKind::FoxglovePublish => json!({"outputs": ["sine1.out"], "publish": true}),
        RequestKind::PlayerSeek => json!({"component": "gain1", "seconds": 1.0}),
        RequestKind::PlayerSpeed => json!({"component": "gain1", "factor": 2.0}),
        RequestKind::InstallPack => {
            json!({"name": "x", "version": "0.1.0", "platform": "none", "size": 0, "offset": 0, "data": ""})
        }
        RequestKind::RecordStart
        | RequestKind::RecordStop
        | RequestKind::RecordSplit
        | RequestKind::PlayerPlay
        | RequestKind::PlayerPause
        | RequestKind::PlayerStep => json!({"component": "gain1"}),
        _ => json!({}),
    };
    for (key, value) in fields.as_object().unwrap() {
        request[key] = value.clone();
    }
    request
}

/// Tests that time a running diagram take the machine alone: on two cores, servers started by the other
/// tests of this file in parallel took enough CPU to make a 1 kHz diagram miss a third of its ticks.
static MACHINE: RwLock<()> = RwLock::new(());

/// Shares the machine with the other tests.
fn shared_machine() -> RwLockReadGuard<'static, ()> {
    MACHINE.read().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Has the machine alone while timing.
fn whole_machine() -> RwLockWriteGuard<'static, ()> {
    MACHINE.write().unwrap_or_else(std::sync::PoisonError::into_inner)
}

#[test]
fn every_request_type_is_checked_against_the_role_table() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let server = serve(dir.path(), &[]);
    let mut admin = operator(&server);
    let hello_text = std::fs::read_to_string(example("hello")).unwrap();
    deploy_and_start(&mut admin, &hello_text);

    let monitor_token = std::fs::read_to_string(dir.path().join("monitor.txt")).unwrap();
    let mut monitor = connect(&server);
    let reply = hello(&mut monitor, monitor_token.trim(), "monitor");
    assert_eq!(reply["result"]["role"], "monitor", "{reply}");
    for (index, kind) in RequestKind::ALL.into_iter().enumerate() {
        if kind == RequestKind::Hello {
            continue;
        }
        let request = sample_request(kind, 100 + index as u64);
        let reply = call(&mut monitor, &request);
        let forbidden = reply["error"]["code"] == "forbidden";
        assert_eq!(
            forbidden,
            kind.required_role() == Role::Operator,
            "{}: {reply}",
            kind.name()
        );
    }
    assert_eq!(state(&mut admin), "running", "the monitor changed nothing");
    let diagram = call(&mut admin, &json!({"id": 7, "type": "get_diagram"}));
    assert!(
        diagram["result"]["diagram"]
            .as_str()
            .unwrap()
            .contains("\"gain\": 2.5")
    );

    // An operator may make every request (the replies may be errors, but never `forbidden`).
    for (index, kind) in RequestKind::ALL.into_iter().enumerate() {
        if kind == RequestKind::Hello {
            continue;
        }
        let request = sample_request(kind, 200 + index as u64);
        let reply = call(&mut admin, &request);
        assert_ne!(reply["error"]["code"], "forbidden", "{}: {reply}", kind.name());
    }

    // A monitor token cannot buy the operator role.
    let mut sneaky = connect(&server);
    let reply = hello(&mut sneaky, monitor_token.trim(), "operator");
    assert_eq!(reply["error"]["code"], "forbidden", "{reply}");
}

#[test]
fn wrong_or_missing_tokens_and_versions_are_refused() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let server = serve(dir.path(), &[]);
    let monitor = std::fs::read_to_string(dir.path().join("monitor.txt"))
        .unwrap()
        .trim()
        .to_owned();
    // The monitor token grants monitor whether or not the client asks for it.
    let mut socket = connect(&server);
    let reply = call(
        &mut socket,
        &json!({"id": 1, "type": "hello", "protocol": 1, "client": "t", "token": monitor}),
    );
    assert_eq!(reply["result"]["role"], "monitor", "{reply}");
    for (hello_request, code) in [
        (
            json!({"id": 1, "type": "hello", "protocol": 1, "client": "t", "token": "x".repeat(64)}),
            "unauthorized",
        ),
        (
            json!({"id": 1, "type": "hello", "protocol": 1, "client": "t"}),
            "unauthorized",
        ),
        (
            json!({"id": 1, "type": "hello", "protocol": 99, "client": "t", "token": server.token}),
            "unsupported_version",
        ),
        (json!({"id": 1, "type": "status"}), "unauthorized"),
        (
            json!({"id": 1, "type": "hello", "protocol": 1, "client": "t", "token": monitor, "role": "operator"}),
            "forbidden",
        ),
    ] {
        let mut socket = connect(&server);
        let reply = call(&mut socket, &hello_request);
        assert_eq!(reply["error"]["code"], code, "{hello_request}: {reply}");
        if code == "unsupported_version" {
            let message = reply["error"]["message"].as_str().unwrap();
            assert!(
                message.contains("version 1") && message.contains("99"),
                "{message}"
            );
        }
    }
}

#[test]
fn bad_messages_get_error_replies_and_the_server_carries_on() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let server = serve(dir.path(), &[]);
    let mut socket = operator(&server);
    for (message, needle) in [
        ("{not json", "not JSON"),
        (r#"{"id": 5, "type": "explode"}"#, "unknown request type"),
        (
            r#"{"id": 6, "type": "set_property", "component": 3}"#,
            "invalid type",
        ),
        (r#"{"id": 7, "type": "deploy"}"#, "missing field"),
        (
            r#"{"id": 8, "type": "deploy", "diagram": "Diagram(format: 1, components: [Component(id: \"a\", type: \"core.nothing\")])"}"#,
            "unknown component type",
        ),
        (r#"{"id": 9, "type": "start"}"#, "deploy a diagram first"),
        (
            r#"{"id": 12, "type": "set_property", "component": "a", "property": "p", "value": null}"#,
            "\"value\" must be a boolean, a number or a text, not null",
        ),
        (
            r#"{"id": 13, "type": "subscribe_samples", "outputs": [], "max_rate_hz": 500}"#,
            "at most 120",
        ),
        (
            r#"{"id": 14, "type": "subscribe_samples", "outputs": [], "max_rate_hz": 0}"#,
            "must be above 0",
        ),
    ] {
        socket.send(Message::text(message)).unwrap();
        let reply = next_reply(&mut socket);
        assert_eq!(reply["ok"], false, "{message}");
        let error = reply["error"]["message"].as_str().unwrap();
        assert!(error.contains(needle), "{message}: {error}");
    }
    socket.send(Message::binary(vec![1_u8, 2, 3])).unwrap();
    let reply = next_reply(&mut socket);
    assert!(
        reply["error"]["message"].as_str().unwrap().contains("JSON text"),
        "{reply}"
    );
    // A deploy with errors lists every diagnostic.
    let reply = call(
        &mut socket,
        &json!({"id": 10, "type": "deploy", "diagram": "Diagram(format: 1, components: [Component(id: \"a\", type: \"core.nothing\"), Component(id: \"b\", type: \"core.sine\", properties: {\"rate\": \"fast\"})])"}),
    );
    assert_eq!(reply["error"]["code"], "invalid_diagram");
    let errors = reply["error"]["diagnostics"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|d| d["severity"] == "error")
        .count();
    assert_eq!(errors, 2, "{reply}");

    // Too large: the reply, then close code 1009, every time; and the server still serves others.
    for size in [(4 << 20) + 1, 10 << 20, 4 << 20, 10 << 20, 5 << 20] {
        let mut socket = operator(&server);
        let huge = format!(
            r#"{{"id": 11, "type": "deploy", "diagram": "{}"}}"#,
            "x".repeat(size)
        );
        socket.send(Message::text(huge)).unwrap();
        let reply = next_reply(&mut socket);
        assert_eq!(reply["error"]["code"], "too_large", "{size} bytes: {reply}");
        let close = loop {
            match socket.read() {
                Ok(Message::Close(frame)) => break frame,
                Ok(_) => {}
                Err(error) => panic!("{size} bytes: no close frame after the reply: {error}"),
            }
        };
        let code = close.map(|f| u16::from(f.code));
        assert_eq!(code, Some(1009), "{size} bytes");
    }
    let mut again = operator(&server);
    assert_eq!(state(&mut again), "empty");
}

/// The longest gap between consecutive timestamps in the CSV the 1 kHz diagram writes.
fn longest_gap_ms(csv: &Path) -> (f64, usize) {
    let content = std::fs::read_to_string(csv).unwrap();
    let stamps: Vec<i64> = content
        .lines()
        .skip(1)
        .filter_map(|l| l.split(',').nth(1)?.parse().ok())
        .collect();
    let gap = stamps.windows(2).map(|w| w[1] - w[0]).max().unwrap_or(0);
    (gap as f64 / 1e6, stamps.len())
}

#[test]
fn clients_that_flood_vanish_or_never_read_do_not_disturb_a_running_diagram() {
    let _machine = whole_machine();
    let dir = tempfile::tempdir().unwrap();
    let server = serve(dir.path(), &[]);
    let mut admin = operator(&server);
    let diagram = r#"Diagram(
    format: 1,
    packs: [Pack(name: "core", version: "^0.1")],
    components: [
        Component(id: "counter", type: "core.counter", properties: {"rate": 1000.0}),
        Component(id: "csv", type: "core.csv_writer", properties: {"path": "ticks.csv"}),
    ],
    connections: [Connection(from: "counter.out", to: "csv.in1", buffer_size: 4096)],
)"#;
    deploy_and_start(&mut admin, diagram);

    // A client that subscribes to everything and never reads again.
    let mut sluggish = operator(&server);
    for request in [
        json!({"id": 20, "type": "subscribe_telemetry", "interval_ms": 20}),
        json!({"id": 21, "type": "subscribe_samples", "outputs": ["counter.out"], "max_rate_hz": 120}),
        json!({"id": 22, "type": "subscribe_log", "level": "trace"}),
    ] {
        assert_eq!(call(&mut sluggish, &request)["ok"], true);
    }
    // A client flooding requests without reading replies.
    let mut flooder = operator(&server);
    for id in 0..2000 {
        if flooder
            .send(Message::text(
                json!({"id": 1000 + id, "type": "status"}).to_string(),
            ))
            .is_err()
        {
            break;
        }
    }
    // 300 connections (and more, for at least two seconds) that come and go, some mid-message.
    let started = Instant::now();
    let mut round = 0;
    while round < 300 || started.elapsed() < Duration::from_secs(2) {
        round += 1;
        let mut socket = connect(&server);
        if round % 3 == 0 {
            let _ = socket.send(Message::text(
                json!({"id": 1, "type": "hello", "protocol": 1, "client": "x", "token": server.token})
                    .to_string(),
            ));
        }
        if round % 5 == 0 {
            // Half a frame, then gone.
            if let MaybeTlsStream::Plain(stream) = socket.get_mut() {
                use std::io::Write as _;
                let _ = stream.write_all(&[0x81, 0xFE, 0x10]);
            }
        }
        drop(socket);
    }
    let churn = started.elapsed();
    assert_eq!(call(&mut admin, &json!({"id": 30, "type": "stop"}))["ok"], true);
    let (gap_ms, samples) = longest_gap_ms(&dir.path().join("ticks.csv"));
    assert!(
        samples > 1500,
        "{samples} samples in {churn:?} ({round} connections)"
    );
    assert!(
        gap_ms <= 50.0,
        "a gap of {gap_ms:.1} ms in the 1 kHz output while clients misbehaved"
    );
    drop(sluggish);
    drop(flooder);
}

#[test]
fn devices_lists_what_kairos_devices_lists_and_the_library_marks_the_properties_naming_them() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let server = serve(dir.path(), &[]);
    let mut socket = operator(&server);
    let reply = call(&mut socket, &json!({"id": 5, "type": "devices"}));
    assert_eq!(reply["ok"], true, "{reply}");
    let listed = common::kairos(dir.path(), &["devices", "--json"]);
    let listed: Value = serde_json::from_slice(&listed.stdout).unwrap();
    assert_eq!(
        reply["result"]["devices"], listed,
        "the protocol and the command agree"
    );
    let library = call(&mut socket, &json!({"id": 6, "type": "library"}));
    let kind_of = |type_name: &str, property: &str| {
        library["result"]["components"][type_name]["properties"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["name"] == property)
            .map(|p| p["device"].clone())
            .unwrap()
    };
    assert_eq!(kind_of("gnss.nmea", "device"), "serial");
    assert_eq!(kind_of("serial.reader", "device"), "serial");
    assert_eq!(kind_of("can.socketcan_reader", "interface"), "can");
    assert_eq!(kind_of("gnss.nmea", "path"), Value::Null);
}

#[test]
fn a_sample_subscription_gets_the_latest_frames_at_the_asked_rate() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let server = serve(dir.path(), &[]);
    let mut socket = operator(&server);
    deploy_and_start(&mut socket, &std::fs::read_to_string(example("camera")).unwrap());
    let reply = call(
        &mut socket,
        &json!({"id": 4, "type": "subscribe_samples", "outputs": ["camera.image"], "max_rate_hz": 5, "max_image_width": 160}),
    );
    assert_eq!(reply["ok"], true, "{reply}");
    let started = Instant::now();
    let mut frames = 0;
    while started.elapsed() < Duration::from_millis(1500) {
        if let Message::Binary(bytes) = socket.read().unwrap() {
            let (header, pixels) = kairos_protocol::frame::decode(&bytes).unwrap();
            let image = header.image.unwrap();
            assert_eq!((image.width, image.original_width), (160, Some(640)));
            assert_eq!(pixels.len(), (image.stride * image.height) as usize);
            frames += 1;
        }
    }
    assert!(
        (4..=9).contains(&frames),
        "{frames} frames in 1.5 s at 5 per second"
    );
    let reply = call(
        &mut socket,
        &json!({"id": 5, "type": "subscribe_samples", "outputs": ["camera.nothing"]}),
    );
    assert_eq!(reply["error"]["code"], "not_found");
}

#[test]
fn serve_refuses_a_network_address_without_a_token_and_says_how_to_make_one() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let output = Command::new(env!("CARGO_BIN_EXE_kairos"))
        .args(["serve", "--listen", "0.0.0.0:0"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    let (_, stderr) = text(&output);
    assert_eq!(output.status.code(), Some(1));
    assert!(
        stderr.contains("--token-file") && stderr.contains("openssl rand -hex 32"),
        "{stderr}"
    );
}

#[test]
fn an_unreadable_token_file_is_named_with_its_cause_and_nothing_listens() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let folder = dir.path().join("a folder");
    std::fs::create_dir(&folder).unwrap();
    let garbled = dir.path().join("garbled");
    std::fs::write(&garbled, b"\xff\xfe not text\n").unwrap();
    let under_a_file = garbled.join("token");
    for (option, path, what, cause) in [
        ("--token-file", &folder, "cannot read", "Is a directory"),
        (
            "--monitor-token-file",
            &garbled,
            "cannot read",
            "did not contain valid UTF-8",
        ),
        // Whether it exists cannot be told: it is not taken for missing (to be made afresh).
        ("--token-file", &under_a_file, "cannot reach", "Not a directory"),
    ] {
        let output = Command::new(env!("CARGO_BIN_EXE_kairos"))
            .args(["serve", "--listen", "127.0.0.1:0", option])
            .arg(path)
            .current_dir(dir.path())
            .output()
            .unwrap();
        let (stdout, stderr) = text(&output);
        assert_eq!(
            output.status.code(),
            Some(1),
            "{option} {}: {stderr}",
            path.display()
        );
        assert!(!stdout.contains("listening"), "{stdout}");
        assert!(
            stderr.contains(&format!("{what} the token file {}", path.display())) && stderr.contains(cause),
            "{option} {}: {stderr}",
            path.display()
        );
    }
}

#[test]
fn every_thread_of_a_busy_server_is_named() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let server = serve(dir.path(), &[]);
    let mut admin = operator(&server);
    let hello_text = std::fs::read_to_string(example("hello")).unwrap();
    deploy_and_start(&mut admin, &hello_text);
    for request in [
        json!({"id": 20, "type": "subscribe_telemetry", "interval_ms": 20}),
        json!({"id": 21, "type": "subscribe_log", "level": "trace"}),
        json!({"id": 22, "type": "subscribe_samples", "outputs": ["sine1.out"], "max_rate_hz": 50}),
        json!({"id": 23, "type": "subscribe_samples", "outputs": ["gain1.out"], "transport": "shared_memory"}),
        json!({"id": 24, "type": "stop"}),
        json!({"id": 25, "type": "start"}),
        json!({"id": 26, "type": "status"}),
    ] {
        let reply = call(&mut admin, &request);
        // Shared memory may be missing here; the other threads are still there to check.
        assert!(reply["ok"] == true || request["id"] == 23, "{request}: {reply}");
    }
    std::thread::sleep(Duration::from_millis(300));
    // A thread without a name of its own carries the program's: only the main thread may.
    let tasks = Path::new("/proc")
        .join(server.child.id().to_string())
        .join("task");
    let names: Vec<String> = std::fs::read_dir(tasks)
        .unwrap()
        .map(|task| {
            std::fs::read_to_string(task.unwrap().path().join("comm"))
                .unwrap()
                .trim()
                .to_owned()
        })
        .collect();
    assert!(names.iter().any(|n| n == "k:net"), "{names:?}");
    assert_eq!(names.iter().filter(|n| *n == "kairos").count(), 1, "{names:?}");
}

#[test]
fn the_python_example_client_drives_a_real_server() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let server = serve(dir.path(), &[]);
    let output = Command::new("python3")
        .arg(repo_root().join("examples/clients/python/demo.py"))
        .args(["--url", &server.url, "--token-file"])
        .arg(dir.path().join("token.txt"))
        .args(["--seconds", "1.5"])
        .output()
        .expect("python3");
    let (stdout, stderr) = text(&output);
    assert!(
        output.status.success(),
        "the demo failed (pip install websockets?):\n{stdout}\n{stderr}"
    );
    assert!(
        stdout.contains("-- done") && stdout.contains("sine1.out -> gain1.in"),
        "{stdout}"
    );
}

#[test]
fn the_log_stream_and_the_connection_limit() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let server = serve(dir.path(), &["--max-connections", "2"]);
    let mut first = operator(&server);
    assert_eq!(
        call(
            &mut first,
            &json!({"id": 2, "type": "subscribe_log", "level": "info"})
        )["ok"],
        true
    );
    let hello_text = std::fs::read_to_string(example("hello")).unwrap();
    first
        .send(Message::text(
            json!({"id": 3, "type": "deploy", "diagram": hello_text}).to_string(),
        ))
        .unwrap();
    // The log event may come before or after the deploy's reply.
    let (mut logged, mut replied) = (false, false);
    for _ in 0..20 {
        if let Message::Text(text) = first.read().unwrap() {
            let event: Value = serde_json::from_str(text.as_str()).unwrap();
            if event["type"] == "log" && event["message"].as_str().unwrap().contains("deployed a diagram") {
                assert_eq!(event["level"], "info");
                logged = true;
            }
            replied |= event["type"] == "reply" && event["id"] == 3 && event["ok"] == true;
        }
        if logged && replied {
            break;
        }
    }
    assert!(logged, "the deploy was logged to the subscriber");

    let _second = operator(&server);
    let mut third = connect(&server);
    let refusal = next_reply(&mut third);
    assert_eq!(refusal["error"]["code"], "busy", "{refusal}");
    assert!(
        refusal["error"]["message"]
            .as_str()
            .unwrap()
            .contains("2 clients")
    );
}

#[test]
fn recorders_and_players_are_driven_over_the_protocol() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let server = serve(dir.path(), &[]);
    let mut socket = operator(&server);
    let recording = r#"Diagram(
    format: 1,
    packs: [Pack(name: "sensors", version: "^0.1"), Pack(name: "recording", version: "^0.1")],
    components: [
        Component(id: "imu", type: "sensors.imu"),
        Component(id: "recorder", type: "recording.recorder", properties: {"path": "imu.mcap", "record_at_start": false}),
    ],
    connections: [Connection(from: "imu.imu", to: "recorder.in1", buffer_size: 64)],
)"#;
    deploy_and_start(&mut socket, recording);
    std::thread::sleep(Duration::from_millis(200));
    assert!(
        !dir.path().join("imu.mcap").exists(),
        "not recording before record_start"
    );
    assert_eq!(
        call(
            &mut socket,
            &json!({"id": 4, "type": "record_start", "component": "recorder"})
        )["ok"],
        true
    );
    std::thread::sleep(Duration::from_millis(1200));
    assert_eq!(
        call(
            &mut socket,
            &json!({"id": 5, "type": "record_stop", "component": "recorder"})
        )["ok"],
        true
    );
    let report = kairos_pack_recording::inspect(&dir.path().join("imu.mcap")).unwrap();
    assert!(report.complete && report.messages > 80, "{report:?}");

    let playback = r#"Diagram(
    format: 1,
    packs: [Pack(name: "recording", version: "^0.1")],
    components: [Component(id: "player", type: "recording.player", properties: {"path": "imu.mcap", "loop": true})],
)"#;
    deploy_and_start(&mut socket, playback);
    for (id, request) in [
        (10, json!({"type": "player_pause"})),
        (11, json!({"type": "player_seek", "seconds": 0.5})),
        (12, json!({"type": "player_step"})),
        (13, json!({"type": "player_speed", "factor": 4.0})),
        (14, json!({"type": "player_play"})),
    ] {
        let mut request = request;
        request["id"] = json!(id);
        request["component"] = json!("player");
        let reply = call(&mut socket, &request);
        assert_eq!(reply["ok"], true, "{request}: {reply}");
    }
    let reply = call(
        &mut socket,
        &json!({"id": 15, "type": "player_speed", "component": "player", "factor": 500.0}),
    );
    assert_eq!(reply["error"]["code"], "invalid_value", "{reply}");
    assert!(
        reply["error"]["message"].as_str().unwrap().contains("100"),
        "{reply}"
    );
    let status = call(&mut socket, &json!({"id": 16, "type": "status"}));
    let player = &status["result"]["telemetry"]["components"][0];
    assert_eq!(player["state"], "running", "{status}");
}

/// A diagram over two served hosts and this machine: a sine into a CSV file on each.
fn two_host_diagram(a: &Server, b: &str) -> String {
    let connection =
        r#"Connection(from: "sine_a.out", to: "csv_a.in1"), Connection(from: "sine_b.out", to: "csv_b.in1")"#;
    format!(
        r#"Diagram(format: 1,
            hosts: {{"a": Host(endpoint: "{}", token_file: "a.token"), "b": Host(endpoint: "{b}", token_file: "b.token")}},
            packs: [],
            components: [
                Component(id: "sine_a", type: "core.sine", host: "a"),
                Component(id: "csv_a", type: "core.csv_writer", host: "a", properties: {{"path": "a.csv"}}),
                Component(id: "sine_b", type: "core.sine", host: "b"),
                Component(id: "csv_b", type: "core.csv_writer", host: "b", properties: {{"path": "b.csv"}}),
                Component(id: "sine_here", type: "core.sine"),
                Component(id: "csv_here", type: "core.csv_writer", properties: {{"path": "here.csv"}}),
            ],
            connections: [{connection}, Connection(from: "sine_here.out", to: "csv_here.in1")])"#,
        a.url
    )
}

#[test]
fn deploy_runs_each_part_on_its_host_and_stops_them_all() {
    let _machine = shared_machine();
    let [dir_a, dir_b, here] = folders();
    let (a, b) = (serve(dir_a.path(), &[]), serve(dir_b.path(), &[]));
    std::fs::write(here.path().join("a.token"), &a.token).unwrap();
    std::fs::write(here.path().join("b.token"), &b.token).unwrap();
    let diagram = here.path().join("two_hosts.ron");
    std::fs::write(&diagram, two_host_diagram(&a, &b.url)).unwrap();
    let deployed = common::kairos(
        here.path(),
        &["deploy", diagram.to_str().unwrap(), "--for", "1500ms"],
    );
    let (_, stderr) = text(&deployed);
    assert!(deployed.status.success(), "{stderr}");
    assert!(stderr.contains("host 'a' started its part"), "{stderr}");
    // Each part ran where it was placed: its CSV is in that host's folder.
    for (folder, file) in [(&dir_a, "a.csv"), (&dir_b, "b.csv"), (&here, "here.csv")] {
        let rows = std::fs::read_to_string(folder.path().join(file)).unwrap_or_default();
        assert!(rows.lines().count() > 10, "{file}: {rows:?}\n{stderr}");
    }
    for server in [&a, &b] {
        let mut socket = operator(server);
        assert_eq!(state(&mut socket), "ready", "stopped at the end");
    }
    // Started together: the first samples of the three parts are stamped within a few milliseconds.
    let first_stamp = |folder: &tempfile::TempDir, file: &str| -> i64 {
        let rows = std::fs::read_to_string(folder.path().join(file)).unwrap();
        let row = rows.lines().nth(1).unwrap().to_owned();
        row.split(',').nth(1).unwrap().parse().unwrap()
    };
    let stamps = [
        first_stamp(&dir_a, "a.csv"),
        first_stamp(&dir_b, "b.csv"),
        first_stamp(&here, "here.csv"),
    ];
    let spread_ms = (stamps.iter().max().unwrap() - stamps.iter().min().unwrap()) as f64 / 1e6;
    assert!(spread_ms < 20.0, "first samples {spread_ms} ms apart: {stamps:?}");
    // And stopped together: the last samples too.
    let last_stamp = |folder: &tempfile::TempDir, file: &str| -> i64 {
        csv_values(&folder.path().join(file)).last().unwrap().0
    };
    let stamps = [
        last_stamp(&dir_a, "a.csv"),
        last_stamp(&dir_b, "b.csv"),
        last_stamp(&here, "here.csv"),
    ];
    let spread_ms = (stamps.iter().max().unwrap() - stamps.iter().min().unwrap()) as f64 / 1e6;
    assert!(spread_ms < 30.0, "last samples {spread_ms} ms apart: {stamps:?}");
}

fn free_tcp_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// `timestamp → value` of each row of a CSV written by `core.csv_writer`.
fn csv_values(path: &Path) -> Vec<(i64, f64)> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .skip(1)
        .filter_map(|row| {
            let fields: Vec<&str> = row.split(',').collect();
            Some((fields.get(1)?.parse().ok()?, fields.last()?.parse().ok()?))
        })
        .collect()
}

#[test]
fn links_between_hosts_carry_every_sample_with_its_timestamp_over_zenoh() {
    let _machine = shared_machine();
    let [dir_a, dir_b, here] = folders();
    let (a, b) = (serve(dir_a.path(), &[]), serve(dir_b.path(), &[]));
    std::fs::write(here.path().join("a.token"), &a.token).unwrap();
    std::fs::write(here.path().join("b.token"), &b.token).unwrap();
    // A sine on host a, doubled on host b, written here; the sine also written on a, to compare.
    let diagram = format!(
        r#"Diagram(format: 1,
            hosts: {{
                "a": Host(endpoint: "{}", token_file: "a.token", zenoh: "tcp/127.0.0.1:{}"),
                "b": Host(endpoint: "{}", token_file: "b.token", zenoh: "tcp/127.0.0.1:{}"),
            }},
            components: [
                Component(id: "sine", type: "core.sine", host: "a", properties: {{"rate": 400.0}}),
                Component(id: "csv_a", type: "core.csv_writer", host: "a", properties: {{"path": "a.csv"}}),
                Component(id: "gain", type: "core.gain", host: "b", properties: {{"gain": 2.0}}),
                Component(id: "csv_here", type: "core.csv_writer", properties: {{"path": "here.csv"}}),
            ],
            connections: [
                Connection(from: "sine.out", to: "csv_a.in1", policy: NeverSkipping),
                Connection(from: "sine.out", to: "gain.in", policy: NeverSkipping),
                Connection(from: "gain.out", to: "csv_here.in1", policy: NeverSkipping),
            ])"#,
        a.url,
        free_tcp_port(),
        b.url,
        free_tcp_port()
    );
    let path = here.path().join("linked.ron");
    std::fs::write(&path, diagram).unwrap();
    let deployed = common::kairos(here.path(), &["deploy", path.to_str().unwrap(), "--for", "2s"]);
    let (_, stderr) = text(&deployed);
    assert!(deployed.status.success(), "{stderr}");
    assert!(
        stderr.contains("linked sine.out on host 'a' -> gain.in on host 'b'"),
        "{stderr}"
    );
    assert!(
        stderr.contains("linked gain.out on host 'b' -> csv_here.in1 on this machine"),
        "{stderr}"
    );
    let written_on_a: std::collections::BTreeMap<i64, f64> =
        csv_values(&dir_a.path().join("a.csv")).into_iter().collect();
    let received_here = csv_values(&here.path().join("here.csv"));
    assert!(
        received_here.len() > 300,
        "{} rows\n{stderr}",
        received_here.len()
    );
    // Every sample crossed two hosts with its timestamp, in order, none lost: the stream here is the
    // stream on a, doubled, up to the samples still in flight when everything stopped.
    let mut on_a = written_on_a.iter();
    for (stamp, value) in &received_here {
        let (a_stamp, a_value) = on_a.next().expect("no more samples on a than here");
        assert_eq!(stamp, a_stamp, "in order, none lost");
        assert!(
            (value - 2.0 * a_value).abs() < 1e-9,
            "{stamp}: {value} vs 2 × {a_value}"
        );
    }
    assert!(
        written_on_a.len() - received_here.len() < 40,
        "{} written on a, {} received here",
        written_on_a.len(),
        received_here.len()
    );
}

/// Waits until `log` (a file being written) holds `text`; the time waited.
fn wait_for_log(log: &Path, text: &str, within: Duration) -> Duration {
    let start = Instant::now();
    loop {
        let content = std::fs::read_to_string(log).unwrap_or_default();
        if content.contains(text) {
            return start.elapsed();
        }
        assert!(
            start.elapsed() < within,
            "no {text:?} within {within:?}:\n{content}"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn a_killed_host_is_reported_within_a_second_and_its_part_runs_again_when_it_returns() {
    let _machine = shared_machine();
    let [dir_a, dir_b, here] = folders();
    let b_listen = format!("127.0.0.1:{}", free_tcp_port());
    let a = serve(dir_a.path(), &[]);
    let mut b = serve_on(dir_b.path(), &b_listen, &[], &[]);
    std::fs::write(here.path().join("a.token"), &a.token).unwrap();
    std::fs::write(here.path().join("b.token"), &b.token).unwrap();
    // A sine on host a, doubled on host b, written here.
    let diagram = format!(
        r#"Diagram(format: 1,
            hosts: {{
                "a": Host(endpoint: "{}", token_file: "a.token", zenoh: "tcp/127.0.0.1:{}"),
                "b": Host(endpoint: "{}", token_file: "b.token", zenoh: "tcp/127.0.0.1:{}"),
            }},
            components: [
                Component(id: "sine", type: "core.sine", host: "a", properties: {{"rate": 100.0}}),
                Component(id: "gain", type: "core.gain", host: "b", properties: {{"gain": 2.0}}),
                Component(id: "csv_here", type: "core.csv_writer", properties: {{"path": "here.csv"}}),
            ],
            connections: [
                Connection(from: "sine.out", to: "gain.in"),
                Connection(from: "gain.out", to: "csv_here.in1"),
            ])"#,
        a.url,
        free_tcp_port(),
        b.url,
        free_tcp_port()
    );
    let path = here.path().join("linked.ron");
    std::fs::write(&path, diagram).unwrap();
    let log = here.path().join("deploy.log");
    let mut deploying = Command::new(env!("CARGO_BIN_EXE_kairos"))
        .args(["deploy", path.to_str().unwrap(), "--for", "8s"])
        .current_dir(here.path())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .unwrap();
    wait_for_log(&log, "host 'b' started its part", Duration::from_secs(10));
    std::thread::sleep(Duration::from_millis(1500));

    // Host b dies: named within a second, with the links it cuts; host a runs on.
    let _ = b.child.kill();
    let _ = b.child.wait();
    let reported = wait_for_log(&log, "host 'b' is lost", Duration::from_secs(3));
    assert!(reported < Duration::from_secs(1), "reported after {reported:?}");
    let content = std::fs::read_to_string(&log).unwrap();
    assert!(
        content.contains("links cut: sine.out on host 'a' -> gain.in on host 'b', gain.out on host 'b' -> csv_here.in1 on this machine"),
        "{content}"
    );
    let mut socket = operator(&a);
    assert_eq!(state(&mut socket), "running");

    // It comes back: its part is deployed and started again, and samples flow here again.
    let returned_at = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as i64;
    b = serve_on(dir_b.path(), &b_listen, &[], &[]);
    wait_for_log(&log, "host 'b' is back", Duration::from_secs(4));
    let status = deploying.wait().unwrap();
    let content = std::fs::read_to_string(&log).unwrap();
    assert!(status.success(), "{content}");
    let rows = csv_values(&here.path().join("here.csv"));
    let after = rows.iter().filter(|(stamp, _)| *stamp > returned_at).count();
    assert!(after > 50, "{after} samples after host b returned\n{content}");
    if std::env::var_os("SHOW_LOG").is_some() {
        eprintln!("{content}");
    }
    drop(b);
}

#[test]
fn deploy_starts_nothing_when_a_host_is_unreachable_or_refuses() {
    let _machine = shared_machine();
    let [dir_a, here] = folders();
    let a = serve(dir_a.path(), &[]);
    std::fs::write(here.path().join("a.token"), &a.token).unwrap();
    std::fs::write(here.path().join("b.token"), "not the token").unwrap();
    let diagram = here.path().join("two_hosts.ron");
    let unused = free_tcp_port();
    for (b, expected) in [
        (
            format!("ws://127.0.0.1:{unused}"),
            "host 'b' is unreachable".to_owned(),
        ),
        (a.url.clone(), "host 'b' refused".to_owned()),
        // A token never crosses the network in clear text unless the user says so.
        (
            "ws://192.0.2.1:7600".to_owned(),
            "host 'b': its token would cross the network in clear text".to_owned(),
        ),
    ] {
        std::fs::write(&diagram, two_host_diagram(&a, &b)).unwrap();
        let deployed = common::kairos(here.path(), &["deploy", diagram.to_str().unwrap(), "--for", "1s"]);
        let (_, stderr) = text(&deployed);
        assert!(!deployed.status.success());
        assert!(stderr.contains(&expected), "{expected}: {stderr}");
        let mut socket = operator(&a);
        assert_ne!(state(&mut socket), "running", "nothing started: {stderr}");
        assert!(
            !here.path().join("here.csv").exists(),
            "nothing started here either"
        );
    }
}

/// The C++ example pack (`cpp` 0.1.0, `cpp.clamp`) compiled into `folder`.
fn cpp_pack_in(folder: &Path) {
    std::fs::create_dir_all(folder).unwrap();
    let output = folder.join(format!(
        "{}kairos_pack_cpp{}",
        std::env::consts::DLL_PREFIX,
        std::env::consts::DLL_SUFFIX
    ));
    let status = Command::new("c++")
        .args(["-shared", "-fPIC", "-O1", "-std=c++17", "-I"])
        .arg(repo_root().join("component-sdk/include"))
        .arg(repo_root().join("component-packs/cpp-clamp/clamp.cpp"))
        .arg("-o")
        .arg(&output)
        .status()
        .unwrap();
    assert!(status.success(), "c++ failed on the example pack");
}

fn clamp_on_host_b(b: &Server) -> String {
    format!(
        r#"Diagram(format: 1,
            hosts: {{"b": Host(endpoint: "{}", token_file: "b.token")}},
            components: [
                Component(id: "sine", type: "core.sine", host: "b", properties: {{"frequency": 5.0}}),
                Component(id: "clamp", type: "cpp.clamp", host: "b", properties: {{"min": -0.5, "max": 0.5}}),
                Component(id: "csv", type: "core.csv_writer", host: "b", properties: {{"path": "b.csv"}}),
            ],
            connections: [Connection(from: "sine.out", to: "clamp.in"), Connection(from: "clamp.out", to: "csv.in1")])"#,
        b.url
    )
}

#[test]
fn a_pack_a_host_lacks_is_shipped_and_one_for_another_platform_is_refused() {
    let _machine = shared_machine();
    let [dir_b, shipped, here] = folders();
    // The pack is beside the diagram here, and nowhere on host b.
    cpp_pack_in(&here.path().join("packs"));
    let b = serve(
        dir_b.path(),
        &["--shipped-pack-dir", shipped.path().to_str().unwrap()],
    );
    std::fs::write(here.path().join("b.token"), &b.token).unwrap();
    let diagram = here.path().join("clamp_on_b.ron");
    std::fs::write(&diagram, clamp_on_host_b(&b)).unwrap();
    let deploy = || common::kairos(here.path(), &["deploy", diagram.to_str().unwrap(), "--for", "1s"]);
    let deployed = deploy();
    let (stdout, stderr) = text(&deployed);
    assert!(deployed.status.success(), "{stdout}{stderr}");
    assert!(stdout.contains("shipped pack cpp 0.1.0 to host 'b'"), "{stdout}");
    let values = csv_values(&dir_b.path().join("b.csv"));
    assert!(values.len() > 10, "{values:?}\n{stderr}");
    assert!(
        values.iter().all(|(_, v)| (-0.5..=0.5).contains(v)),
        "clamped on b: {values:?}"
    );
    assert!(values.iter().any(|(_, v)| (*v - 0.5).abs() < 1e-9), "{values:?}");
    let written: Vec<_> = std::fs::read_dir(shipped.path()).unwrap().collect();
    assert_eq!(written.len(), 1, "the library written to --shipped-pack-dir");
    // Deployed again: the host has it now.
    let again = deploy();
    let (stdout, stderr) = text(&again);
    assert!(again.status.success(), "{stderr}");
    assert!(!stdout.contains("shipped pack"), "{stdout}");

    // A host of another platform: refused, with both platforms named, and nothing started.
    let dir_c = tempfile::tempdir().unwrap();
    let c = serve_with_env(dir_c.path(), &[], &[("KAIROS_TEST_PLATFORM", "linux-riscv64")]);
    std::fs::write(here.path().join("b.token"), &c.token).unwrap();
    std::fs::write(&diagram, clamp_on_host_b(&c)).unwrap();
    let refused = deploy();
    let (_, stderr) = text(&refused);
    assert!(!refused.status.success());
    assert!(
        stderr.contains("host 'b' lacks pack 'cpp' 0.1.0")
            && stderr.contains("cannot load on that host (linux-riscv64)")
            && stderr.contains("build the pack for linux-riscv64"),
        "{stderr}"
    );
    let mut socket = operator(&c);
    assert_eq!(state(&mut socket), "empty", "nothing deployed on c: {stderr}");
    // And the host itself refuses a library announced for another platform, whoever sends it.
    let reply = call(
        &mut socket,
        &json!({"id": 9, "type": "install_pack", "name": "cpp", "version": "0.1.0", "platform": "linux-x86_64",
                "size": 4, "offset": 0, "data": "AAAAAA=="}),
    );
    assert_eq!(reply["ok"], false, "{reply}");
    assert!(
        reply["error"]["message"]
            .as_str()
            .unwrap()
            .contains("this machine is linux-riscv64"),
        "{reply}"
    );
}

#[test]
fn a_python_pack_a_host_lacks_is_shipped_without_this_machine_s_environment() {
    let _machine = shared_machine();
    let [dir_b, shipped, here] = folders();
    // A Python pack beside the diagram here, with a virtual environment and compiled files of this
    // machine's that must stay here.
    let pack = here.path().join("packs/py_ship");
    std::fs::create_dir_all(pack.join(".venv/bin")).unwrap();
    std::fs::write(pack.join(".venv/pyvenv.cfg"), "home = /usr/bin\n").unwrap();
    std::fs::create_dir_all(pack.join("__pycache__")).unwrap();
    std::fs::write(pack.join("__pycache__/stale.pyc"), "junk").unwrap();
    std::fs::write(
        pack.join("kairos-pack.toml"),
        "[pack]\nname = \"py_ship\"\nversion = \"0.2.0\"\n",
    )
    .unwrap();
    std::fs::write(
        pack.join("double.py"),
        r#"from kairos_sdk import F64, Component, Descriptor


class Double(Component):
    descriptor = Descriptor("double", doc="Twice its input").input("in", F64).output("out", F64)

    def core(self, ctx):
        sample = ctx.read("in")
        ctx.write_processed("out", sample, 2.0 * sample.data)
"#,
    )
    .unwrap();
    let b = serve(
        dir_b.path(),
        &["--shipped-pack-dir", shipped.path().to_str().unwrap()],
    );
    std::fs::write(here.path().join("b.token"), &b.token).unwrap();
    let diagram = here.path().join("double_on_b.ron");
    std::fs::write(
        &diagram,
        clamp_on_host_b(&b)
            .replace("\"cpp.clamp\"", "\"py_ship.double\"")
            .replace(", properties: {\"min\": -0.5, \"max\": 0.5}", ""),
    )
    .unwrap();
    let deployed = common::kairos(here.path(), &["deploy", diagram.to_str().unwrap(), "--for", "2s"]);
    let (stdout, stderr) = text(&deployed);
    assert!(deployed.status.success(), "{stdout}{stderr}");
    assert!(
        stdout.contains("shipped Python pack py_ship 0.2.0 to host 'b'"),
        "{stdout}"
    );
    let values = csv_values(&dir_b.path().join("b.csv"));
    assert!(values.len() > 10, "{values:?}\n{stderr}");
    assert!(
        values.iter().any(|(_, v)| *v > 1.5) && values.iter().all(|(_, v)| v.abs() <= 2.0 + 1e-9),
        "doubled on b: {values:?}"
    );
    let unpacked = shipped.path().join("py_ship-0.2.0");
    assert!(unpacked.join("double.py").is_file() && unpacked.join("kairos-pack.toml").is_file());
    assert!(
        !unpacked.join(".venv").exists() && !unpacked.join("__pycache__/stale.pyc").exists(),
        "this machine's environment stays here"
    );
}

#[test]
fn deploy_starts_nothing_while_a_host_clock_is_not_locked_unless_told_to() {
    let _machine = shared_machine();
    let [dir_a, dir_b, here] = folders();
    // Host b follows a master that never answers: its clock stays acquiring.
    let silent = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let master = silent.local_addr().unwrap().to_string();
    let a = serve(dir_a.path(), &[]);
    let b = serve(dir_b.path(), &["--clock-slave-of", &master]);
    std::fs::write(here.path().join("a.token"), &a.token).unwrap();
    std::fs::write(here.path().join("b.token"), &b.token).unwrap();
    let diagram = here.path().join("two_hosts.ron");
    // Host b records too: a forced start is marked in its recording.
    let recorded = two_host_diagram(&a, &b.url)
        .replace(
            "            ],\n",
            "                Component(id: \"rec_b\", type: \"recording.recorder\", host: \"b\", properties: {\"path\": \"b.mcap\"}),\n            ],\n",
        )
        .replace(
            "connections: [",
            "connections: [Connection(from: \"sine_b.out\", to: \"rec_b.in1\"), ",
        );
    assert!(
        recorded.contains("rec_b.in1") && recorded.contains("id: \"rec_b\""),
        "{recorded}"
    );
    std::fs::write(&diagram, recorded).unwrap();
    let refused = common::kairos(here.path(), &["deploy", diagram.to_str().unwrap(), "--for", "1s"]);
    let (_, stderr) = text(&refused);
    assert!(!refused.status.success(), "{stderr}");
    assert!(
        stderr.contains("host 'b': clock acquiring") && stderr.contains("--start-unlocked"),
        "{stderr}"
    );
    assert!(stderr.contains("host 'a' follows no clock master"), "{stderr}");
    assert_ne!(state(&mut operator(&b)), "running");
    let forced = common::kairos(
        here.path(),
        &[
            "deploy",
            diagram.to_str().unwrap(),
            "--for",
            "1s",
            "--start-unlocked",
        ],
    );
    let (_, stderr) = text(&forced);
    assert!(forced.status.success(), "{stderr}");
    assert!(stderr.contains("starting with clocks not locked"), "{stderr}");
    assert!(
        std::fs::read_to_string(dir_b.path().join("b.csv"))
            .unwrap()
            .lines()
            .count()
            > 10
    );
    let recording = dir_b.path().join("b.mcap");
    let inspected = common::kairos(here.path(), &["inspect", recording.to_str().unwrap(), "--json"]);
    let report: Value = serde_json::from_slice(&inspected.stdout).unwrap();
    let description = report["metadata"]["kairos.clock"]["description"]
        .as_str()
        .unwrap_or_default();
    assert!(
        description.contains("STARTED WITH CLOCKS NOT LOCKED")
            && description.contains("host 'b': clock acquiring"),
        "{description}"
    );
}

#[test]
fn status_shows_each_host_state_clock_and_links_and_names_the_unreachable() {
    let _machine = shared_machine();
    let [dir_a, dir_b, here] = folders();
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let master = format!("127.0.0.1:{port}");
    let a = serve(dir_a.path(), &["--clock-master", &master]);
    let b = serve(dir_b.path(), &["--clock-slave-of", &master]);
    std::fs::write(here.path().join("a.token"), &a.token).unwrap();
    std::fs::write(here.path().join("b.token"), &b.token).unwrap();
    let diagram = here.path().join("two_hosts.ron");
    std::fs::write(&diagram, two_host_diagram(&a, &b.url)).unwrap();
    let started = Instant::now();
    let line_of_b = loop {
        let shown = common::kairos(here.path(), &["status", diagram.to_str().unwrap()]);
        let (stdout, stderr) = text(&shown);
        assert!(shown.status.success(), "{stdout}{stderr}");
        let line = stdout.lines().find(|l| l.starts_with("b (")).unwrap().to_owned();
        if line.contains("clock locked") || started.elapsed() > Duration::from_secs(5) {
            assert!(
                stdout.contains(&format!("a ({}): empty, clock master", a.url)),
                "{stdout}"
            );
            break line;
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    assert!(
        line_of_b.contains("clock locked ±") && line_of_b.contains("(follows master)"),
        "{line_of_b}"
    );
    drop(b);
    let shown = common::kairos(here.path(), &["status", diagram.to_str().unwrap()]);
    let (stdout, _) = text(&shown);
    assert!(!shown.status.success());
    assert!(
        stdout.contains("b (") && stdout.contains("NOT REACHED"),
        "{stdout}"
    );
    let one = common::kairos(
        here.path(),
        &[
            "status",
            &a.url,
            "--token-file",
            dir_a.path().join("token.txt").to_str().unwrap(),
        ],
    );
    assert!(text(&one).0.contains("runtime ("), "{}", text(&one).0);
}

/// Two network namespaces joined by a veth pair (10.200.N.1 in the first, .2 in the second), made for a
/// test and removed after it.
struct Namespaces {
    names: [String; 2],
    veth: String,
    subnet: u32,
}

impl Namespaces {
    /// The pair, or `None` (saying why) where this machine does not allow making them.
    fn make() -> Option<Self> {
        let id = std::process::id() % 100_000;
        let names = [format!("kairos_a{id}"), format!("kairos_b{id}")];
        let veth = format!("kva{id}");
        let subnet = id % 250;
        let made = Namespaces {
            names: names.clone(),
            veth: veth.clone(),
            subnet,
        };
        let steps: Vec<Vec<String>> = vec![
            vec!["netns".into(), "add".into(), names[0].clone()],
            vec!["netns".into(), "add".into(), names[1].clone()],
            vec![
                "link".into(),
                "add".into(),
                veth.clone(),
                "netns".into(),
                names[0].clone(),
                "type".into(),
                "veth".into(),
                "peer".into(),
                "name".into(),
                format!("kvb{id}"),
                "netns".into(),
                names[1].clone(),
            ],
            vec![
                "-n".into(),
                names[0].clone(),
                "addr".into(),
                "add".into(),
                format!("10.200.{subnet}.1/24"),
                "dev".into(),
                veth.clone(),
            ],
            vec![
                "-n".into(),
                names[1].clone(),
                "addr".into(),
                "add".into(),
                format!("10.200.{subnet}.2/24"),
                "dev".into(),
                format!("kvb{id}"),
            ],
            vec![
                "-n".into(),
                names[0].clone(),
                "link".into(),
                "set".into(),
                veth.clone(),
                "up".into(),
            ],
            vec![
                "-n".into(),
                names[1].clone(),
                "link".into(),
                "set".into(),
                format!("kvb{id}"),
                "up".into(),
            ],
            vec![
                "-n".into(),
                names[0].clone(),
                "link".into(),
                "set".into(),
                "lo".into(),
                "up".into(),
            ],
            vec![
                "-n".into(),
                names[1].clone(),
                "link".into(),
                "set".into(),
                "lo".into(),
                "up".into(),
            ],
        ];
        for step in steps {
            let done = Command::new("ip").args(&step).stderr(Stdio::piped()).output();
            match done {
                Ok(output) if output.status.success() => {}
                Ok(output) => {
                    eprintln!(
                        "skipped: cannot make network namespaces here (ip {}: {})",
                        step.join(" "),
                        String::from_utf8_lossy(&output.stderr).trim()
                    );
                    return None;
                }
                Err(error) => {
                    eprintln!("skipped: no `ip` command to make network namespaces ({error})");
                    return None;
                }
            }
        }
        Some(made)
    }

    fn address(&self, index: u8) -> String {
        format!("10.200.{}.{index}", self.subnet)
    }

    /// Takes the veth link down or up.
    fn set_link(&self, up: bool) {
        let state = if up { "up" } else { "down" };
        let done = Command::new("ip")
            .args(["-n", &self.names[0], "link", "set", &self.veth, state])
            .status()
            .unwrap();
        assert!(done.success());
    }
}

impl Drop for Namespaces {
    fn drop(&mut self) {
        for name in &self.names {
            let _ = Command::new("ip").args(["netns", "del", name]).status();
        }
    }
}

/// A sine on host a, doubled on host b, written on host a: both ways across the veth pair. Host a's
/// endpoints, control and links, take TLS and are trusted through its certificate `a.pem`: b connects to
/// a's `tls/` link endpoint.
fn namespace_diagram(a_url: &str, b_url: &str, address_a: &str, address_b: &str) -> String {
    format!(
        r#"Diagram(format: 1,
            hosts: {{
                "a": Host(endpoint: "{a_url}", token_file: "a.token", zenoh: "tls/{address_a}:7447", certificate: "a.pem"),
                "b": Host(endpoint: "{b_url}", token_file: "b.token", zenoh: "tcp/{address_b}:7447"),
            }},
            components: [
                Component(id: "sine", type: "core.sine", host: "a", properties: {{"rate": 100.0}}),
                Component(id: "gain", type: "core.gain", host: "b", properties: {{"gain": 2.0}}),
                Component(id: "csv", type: "core.csv_writer", host: "a", properties: {{"path": "back.csv"}}),
            ],
            connections: [
                Connection(from: "sine.out", to: "gain.in"),
                Connection(from: "gain.out", to: "csv.in1"),
            ])"#
    )
}

#[test]
fn across_two_network_namespaces_a_cut_link_is_reported_and_the_part_resumes_when_it_returns() {
    let _machine = whole_machine();
    let Some(namespaces) = Namespaces::make() else {
        return;
    };
    let [dir_a, dir_b, here] = folders();
    let (address_a, address_b) = (namespaces.address(1), namespaces.address(2));
    // Host a serves over TLS; host b in clear text, which deploying refuses until told otherwise.
    if !make_certificate(here.path(), "a", &address_a) {
        return;
    }
    let (cert, key) = (here.path().join("a.pem"), here.path().join("a.key"));
    let tls = [
        "--tls-cert",
        cert.to_str().unwrap(),
        "--tls-key",
        key.to_str().unwrap(),
    ];
    let a = serve_in(
        Some(&namespaces.names[0]),
        dir_a.path(),
        &format!("{address_a}:7400"),
        &tls,
        &[],
    );
    assert!(a.url.starts_with("wss://"), "{}", a.url);
    let b = serve_in(
        Some(&namespaces.names[1]),
        dir_b.path(),
        &format!("{address_b}:7400"),
        &[],
        &[],
    );
    std::fs::write(here.path().join("a.token"), &a.token).unwrap();
    std::fs::write(here.path().join("b.token"), &b.token).unwrap();
    let diagram = namespace_diagram(&a.url, &b.url, &address_a, &address_b);
    let path = here.path().join("namespaces.ron");
    std::fs::write(&path, diagram).unwrap();
    let deploy = |extra: &[&str], log: &Path| {
        Command::new("ip")
            .args([
                "netns",
                "exec",
                &namespaces.names[0],
                env!("CARGO_BIN_EXE_kairos"),
                "deploy",
            ])
            .arg(&path)
            .args(extra)
            .current_dir(here.path())
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(log).unwrap())
            .spawn()
            .unwrap()
    };
    // Off loopback, a token is not sent in clear text unless the user says so: b's is refused (a's goes
    // over TLS).
    let refused_log = here.path().join("refused.log");
    let refused = deploy(&["--for", "1s"], &refused_log).wait_with_output().unwrap();
    assert!(!refused.status.success());
    wait_for_log(
        &refused_log,
        "host 'b': its token would cross the network in clear text",
        Duration::from_secs(1),
    );

    let log = here.path().join("deploy.log");
    let mut deploying = deploy(&["--for", "9s", "--allow-clear-text-tokens"], &log);
    wait_for_log(&log, "host 'b' started its part", Duration::from_secs(15));
    std::thread::sleep(Duration::from_millis(1500));
    namespaces.set_link(false);
    let reported = wait_for_log(&log, "host 'b' is lost", Duration::from_secs(3));
    assert!(reported < Duration::from_secs(1), "reported after {reported:?}");
    std::thread::sleep(Duration::from_secs(1));
    namespaces.set_link(true);
    let returned_at = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as i64;
    wait_for_log(&log, "host 'b' is back", Duration::from_secs(5));
    let status = deploying.wait().unwrap();
    let content = std::fs::read_to_string(&log).unwrap();
    assert!(status.success(), "{content}");
    let rows = csv_values(&dir_a.path().join("back.csv"));
    let after = rows.iter().filter(|(stamp, _)| *stamp > returned_at).count();
    assert!(
        after > 50,
        "{after} samples back on a after the link returned\n{content}"
    );
    drop((a, b));
}

/// The rows of a CSV from `core.csv_writer`, without the columns that depend on when a run happened (times
/// of issue) or how its streams were numbered.
fn timeless_rows(path: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let keep: Vec<usize> = (0..header.len())
        .filter(|&i| !header[i].ends_with("time_of_issue_ns") && !header[i].ends_with("sequence"))
        .collect();
    lines
        .map(|row| {
            let fields: Vec<&str> = row.split(',').collect();
            keep.iter()
                .filter_map(|&i| fields.get(i).copied())
                .collect::<Vec<_>>()
                .join(",")
        })
        .collect()
}

#[test]
fn fusion_spread_over_three_hosts_gives_the_one_host_output_by_timestamp() {
    let _machine = shared_machine();
    let dirs: Vec<tempfile::TempDir> = (0..4).map(|_| tempfile::tempdir().unwrap()).collect();
    let here = dirs[3].path();
    // A recording of a simulated IMU (100 Hz) and GNSS (10 Hz): the same input for both runs.
    let recording = here.join("drive.mcap");
    std::fs::write(
        here.join("record.ron"),
        format!(
            r#"Diagram(format: 1, components: [
                Component(id: "imu", type: "sensors.imu", properties: {{"rate": 100.0}}),
                Component(id: "gnss", type: "sensors.gnss", properties: {{"rate": 10.0}}),
                Component(id: "recorder", type: "recording.recorder", properties: {{"path": {:?}}}),
            ], connections: [
                Connection(from: "imu.imu", to: "recorder.in1", buffer_size: 64),
                Connection(from: "gnss.fix", to: "recorder.in2"),
            ])"#,
            recording.display().to_string()
        ),
    )
    .unwrap();
    let recorded = common::kairos(here, &["run", "record.ron", "--for", "2s"]);
    assert!(recorded.status.success(), "{}", text(&recorded).1);

    let fusion = |placed: [&str; 3], hosts: &str, csv: &Path| {
        let at = |index: usize| {
            if placed[index].is_empty() {
                String::new()
            } else {
                format!(r#", host: "{}""#, placed[index])
            }
        };
        format!(
            r#"Diagram(format: 1, {hosts} components: [
                Component(id: "imu_player", type: "recording.player", properties: {{"path": {rec:?}}}{}),
                Component(id: "gnss_player", type: "recording.player", properties: {{"path": {rec:?}}}{}),
                Component(id: "sync", type: "core.synchronizer", properties: {{"tolerance_ms": 5.0}}{}),
                Component(id: "csv", type: "core.csv_writer", properties: {{"path": {csv:?}, "synchronize": true, "tolerance_ms": 5.0}}{}),
            ], connections: [
                Connection(from: "imu_player.imu_imu", to: "sync.in1", policy: NeverSkipping, buffer_size: 256),
                Connection(from: "gnss_player.gnss_fix", to: "sync.in2", policy: NeverSkipping, buffer_size: 64),
                Connection(from: "sync.out1", to: "csv.in1", policy: NeverSkipping, buffer_size: 256),
                Connection(from: "sync.out2", to: "csv.in2", policy: NeverSkipping, buffer_size: 256),
            ])"#,
            at(0),
            at(1),
            at(2),
            at(2),
            rec = recording.display().to_string(),
            csv = csv.display().to_string(),
        )
    };
    // On one machine.
    let one_csv = here.join("one.csv");
    std::fs::write(here.join("one.ron"), fusion(["", "", ""], "", &one_csv)).unwrap();
    let one = common::kairos(here, &["run", "one.ron", "--for", "3s"]);
    assert!(one.status.success(), "{}", text(&one).1);

    // The IMU's player on host a, the GNSS's on host b, the fusion on host c.
    let servers: Vec<Server> = dirs[..3].iter().map(|d| serve(d.path(), &[])).collect();
    let mut hosts = String::from("hosts: {");
    for (name, server) in ["a", "b", "c"].iter().zip(&servers) {
        std::fs::write(here.join(format!("{name}.token")), &server.token).unwrap();
        let _ = write!(
            hosts,
            r#""{name}": Host(endpoint: "{}", token_file: "{name}.token", zenoh: "tcp/127.0.0.1:{}"),"#,
            server.url,
            free_tcp_port()
        );
    }
    hosts.push_str("},");
    let spread_csv = dirs[2].path().join("spread.csv");
    std::fs::write(
        here.join("spread.ron"),
        fusion(["a", "b", "c"], &hosts, &spread_csv),
    )
    .unwrap();
    let spread = common::kairos(here, &["deploy", "spread.ron", "--for", "3s"]);
    assert!(spread.status.success(), "{}", text(&spread).1);

    let (alone, across) = (timeless_rows(&one_csv), timeless_rows(&spread_csv));
    // One fused row per GNSS fix (10 Hz for 2 s), each with the IMU sample nearest in time.
    assert!(alone.len() >= 15, "{} fused rows on one machine", alone.len());
    assert_eq!(
        across.len(),
        alone.len(),
        "as many fused rows across hosts as on one machine"
    );
    for (row, (a, b)) in alone.iter().zip(&across).enumerate() {
        assert_eq!(a, b, "fused row {row} differs");
    }
}

/// A self-signed certificate for the IP address `ip` and its key, made with `openssl`, as `NAME.pem` and
/// `NAME.key` in `dir`; false (saying why) where `openssl` is missing.
fn make_certificate(dir: &Path, name: &str, ip: &str) -> bool {
    let made = Command::new("openssl")
        .args([
            "req",
            "-x509",
            "-newkey",
            "ec",
            "-pkeyopt",
            "ec_paramgen_curve:prime256v1",
            "-nodes",
            "-days",
            "2",
        ])
        .args(["-subj", "/CN=kairos test", "-addext"])
        .arg(format!("subjectAltName=IP:{ip}"))
        .args(["-addext", "basicConstraints=critical,CA:FALSE"])
        .arg("-keyout")
        .arg(dir.join(format!("{name}.key")))
        .arg("-out")
        .arg(dir.join(format!("{name}.pem")))
        .stderr(Stdio::null())
        .status();
    match made {
        Ok(status) if status.success() => true,
        other => {
            eprintln!("skipped: openssl could not make a test certificate ({other:?})");
            false
        }
    }
}

#[test]
fn deploy_over_tls_trusts_the_named_certificate_and_refuses_another() {
    let _machine = shared_machine();
    let [dir_a, here] = folders();
    if !make_certificate(here.path(), "host", "127.0.0.1")
        || !make_certificate(here.path(), "other", "127.0.0.1")
    {
        return;
    }
    let (cert, key) = (here.path().join("host.pem"), here.path().join("host.key"));
    let a = serve(
        dir_a.path(),
        &[
            "--tls-cert",
            cert.to_str().unwrap(),
            "--tls-key",
            key.to_str().unwrap(),
        ],
    );
    assert!(a.url.starts_with("wss://"), "{}", a.url);
    std::fs::write(here.path().join("a.token"), &a.token).unwrap();
    let diagram = |certificate: &str| {
        format!(
            r#"Diagram(format: 1,
                hosts: {{"a": Host(endpoint: "{}", token_file: "a.token", certificate: "{certificate}")}},
                components: [
                    Component(id: "sine", type: "core.sine", host: "a"),
                    Component(id: "csv", type: "core.csv_writer", host: "a", properties: {{"path": "a.csv"}}),
                ],
                connections: [Connection(from: "sine.out", to: "csv.in1")])"#,
            a.url
        )
    };
    let path = here.path().join("tls.ron");
    std::fs::write(&path, diagram("host.pem")).unwrap();
    let deployed = common::kairos(here.path(), &["deploy", path.to_str().unwrap(), "--for", "1s"]);
    let (_, stderr) = text(&deployed);
    assert!(deployed.status.success(), "{stderr}");
    let rows = csv_values(&dir_a.path().join("a.csv"));
    assert!(rows.len() > 10, "{} rows over TLS\n{stderr}", rows.len());

    // A certificate that is not the host's: refused with the reason, nothing started.
    std::fs::remove_file(dir_a.path().join("a.csv")).unwrap();
    std::fs::write(&path, diagram("other.pem")).unwrap();
    let refused = common::kairos(here.path(), &["deploy", path.to_str().unwrap(), "--for", "1s"]);
    let (_, stderr) = text(&refused);
    assert!(!refused.status.success());
    assert!(
        stderr.contains("host 'a' at wss://") && stderr.contains("certificate"),
        "{stderr}"
    );
    assert!(!dir_a.path().join("a.csv").exists(), "nothing started");
    // And one without any certificate named is told what to add.
    std::fs::write(&path, diagram("").replace(r#", certificate: """#, "")).unwrap();
    let unnamed = common::kairos(here.path(), &["deploy", path.to_str().unwrap(), "--for", "1s"]);
    assert!(
        text(&unnamed).1.contains("needs the certificate to trust"),
        "{}",
        text(&unnamed).1
    );
}

#[test]
fn a_slave_whose_clock_is_250_ms_off_and_drifts_locks_to_its_master_and_learns_its_rate() {
    let _machine = shared_machine();
    let [dir_master, dir_slave] = folders();
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let address = format!("127.0.0.1:{port}");
    let _master = serve(dir_master.path(), &["--clock-master", &address]);
    let slave = serve_with_env(
        dir_slave.path(),
        &["--clock-slave-of", &address],
        &[
            ("KAIROS_TEST_CLOCK_OFFSET_MS", "250"),
            ("KAIROS_TEST_CLOCK_DRIFT_PPM", "100"),
        ],
    );
    let mut socket = operator(&slave);
    let hello = std::fs::read_to_string(example("hello")).unwrap();
    let reply = call(&mut socket, &json!({"id": 2, "type": "deploy", "diagram": hello}));
    assert_eq!(reply["ok"], true, "{reply}");
    let started = Instant::now();
    let clock = loop {
        let status = call(&mut socket, &json!({"id": 4, "type": "status"}));
        let clock = status["result"]["telemetry"]["clock"].clone();
        if clock["state"] == "locked" && clock["references"].as_u64().unwrap_or(0) >= 8 {
            break clock;
        }
        assert!(started.elapsed() < Duration::from_secs(3), "not locked: {status}");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(
        started.elapsed() < Duration::from_secs(2),
        "locked in {:?}",
        started.elapsed()
    );
    assert_eq!(clock["source"], "master");
    eprintln!("locked in {:?}: {clock}", started.elapsed());
    // The slave started 250 ms ahead: its first lock set it back by as much (within 5 ms of scheduling).
    let step_ms = clock["step_ns"].as_f64().unwrap() / 1e6;
    assert!((step_ms + 250.0).abs() < 5.0, "stepped {step_ms} ms: {clock}");
    // On one machine the two clocks are the same clock: what remains is the exchange's own error.
    let error_us = clock["error_ns"].as_f64().unwrap().abs() / 1e3;
    assert!(error_us < 500.0, "error {error_us} µs: {clock}");
    // Its crystal runs 100 ppm fast: once the references span 2 s, the rate is learnt.
    let clock = loop {
        let status = call(&mut socket, &json!({"id": 5, "type": "status"}));
        let clock = status["result"]["clock"].clone();
        if clock["rate_ppm"].as_f64().is_some_and(|ppm| ppm != 0.0) {
            break clock;
        }
        assert!(started.elapsed() < Duration::from_secs(6), "no rate: {status}");
        std::thread::sleep(Duration::from_millis(100));
    };
    let rate = clock["rate_ppm"].as_f64().unwrap();
    assert!(
        (rate + 100.0).abs() < 10.0,
        "rate {rate} ppm against -100: {clock}"
    );
    assert_eq!(clock["state"], "locked", "{clock}");
}

#[test]
fn a_start_instant_too_far_ahead_is_refused_and_one_in_the_past_starts_at_once() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let server = serve(dir.path(), &[]);
    let mut socket = operator(&server);
    let hello = std::fs::read_to_string(example("hello")).unwrap();
    let reply = call(&mut socket, &json!({"id": 2, "type": "deploy", "diagram": hello}));
    assert_eq!(reply["ok"], true, "{reply}");
    let now_ns = i64::try_from(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos(),
    )
    .unwrap();
    let far = call(
        &mut socket,
        &json!({"id": 3, "type": "start", "at_ns": now_ns + 120_000_000_000_i64}),
    );
    assert_eq!(far["ok"], false, "{far}");
    assert!(
        far["error"]["message"].as_str().unwrap().contains("120.0 s away"),
        "{far}"
    );
    assert_eq!(state(&mut socket), "ready");
    let past = call(
        &mut socket,
        &json!({"id": 4, "type": "start", "at_ns": now_ns - 1_000_000_000_i64}),
    );
    assert_eq!(past["ok"], true, "{past}");
    assert_eq!(state(&mut socket), "running");
}

/// The coordinator's telemetry of a sine and gain on host b written to a CSV here: b's components, b's
/// state, and the link's counts, the consumer's buffer named as in the diagram.
fn assert_spread_telemetry(telemetry: &Value) {
    let ids: Vec<&str> = telemetry["components"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|c| c["id"].as_str())
        .collect();
    assert!(
        ids.contains(&"sine") && ids.contains(&"gain") && ids.contains(&"csv"),
        "{ids:?}"
    );
    assert!(
        !ids.iter().any(|id| id.starts_with("link_")),
        "link ends are counted as cross links: {ids:?}"
    );
    assert_eq!(telemetry["hosts"][0]["name"], "b", "{telemetry}");
    assert_eq!(telemetry["hosts"][0]["answering"], true, "{telemetry}");
    let link = &telemetry["cross_links"][0];
    assert_eq!(link["from"], "gain.out", "{link}");
    assert_eq!(link["to"], "csv.in1", "{link}");
    assert_eq!(link["from_host"], "b", "{link}");
    assert_eq!(link["matched"], true, "{link}");
    assert_eq!(link["lost"], 0, "{link}");
    let link_names: Vec<&str> = telemetry["links"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|l| l["link"].as_str())
        .collect();
    assert!(
        link_names.contains(&"gain.out -> csv.in1"),
        "the consumer's buffer named as in the diagram: {link_names:?}"
    );
}

#[test]
fn a_runtime_given_a_spread_diagram_coordinates_its_hosts_as_the_studio_runs_it() {
    let _machine = shared_machine();
    let [dir_coordinator, dir_b, here] = folders();
    let (coordinator, b) = (serve(dir_coordinator.path(), &[]), serve(dir_b.path(), &[]));
    std::fs::write(here.path().join("b.token"), &b.token).unwrap();
    // A sine and its gain on host b, written to a CSV by the coordinating runtime.
    let diagram = format!(
        r#"Diagram(format: 1,
            hosts: {{"b": Host(endpoint: "{}", token_file: "b.token", zenoh: "tcp/127.0.0.1:{}")}},
            components: [
                Component(id: "sine", type: "core.sine", host: "b", properties: {{"rate": 100.0}}),
                Component(id: "gain", type: "core.gain", host: "b", properties: {{"gain": 1.0}}),
                Component(id: "csv", type: "core.csv_writer", properties: {{"path": "spread.csv"}}),
            ],
            connections: [
                Connection(from: "sine.out", to: "gain.in"),
                Connection(from: "gain.out", to: "csv.in1"),
            ])"#,
        b.url,
        free_tcp_port()
    );
    let mut socket = operator(&coordinator);
    let folder = here.path().display().to_string();
    // Without the folder holding b's token, b refuses, and the reason says which host.
    let refused = call(
        &mut socket,
        &json!({"id": 1, "type": "deploy", "diagram": diagram, "folder": dir_b.path().join("none").display().to_string()}),
    );
    assert_eq!(refused["ok"], false, "{refused}");
    assert!(
        refused["error"]["message"]
            .as_str()
            .unwrap_or_default()
            .contains("host 'b'"),
        "{refused}"
    );
    let deployed = call(
        &mut socket,
        &json!({"id": 2, "type": "deploy", "diagram": diagram, "folder": folder}),
    );
    assert_eq!(deployed["ok"], true, "{deployed}");
    let started = call(&mut socket, &json!({"id": 3, "type": "start"}));
    assert_eq!(started["ok"], true, "{started}");
    let mut b_socket = operator(&b);
    let b_status = call(&mut b_socket, &json!({"id": 1, "type": "status"}));
    assert_eq!(b_status["result"]["state"], "running", "{b_status}");

    // The coordinator's telemetry holds b's components, b's state and clock, and the link's counts.
    let deadline = Instant::now() + Duration::from_secs(5);
    let telemetry = loop {
        let status = call(&mut socket, &json!({"id": 4, "type": "status"}));
        let telemetry = status["result"]["telemetry"].clone();
        let received = telemetry["cross_links"][0]["received"].as_u64().unwrap_or(0);
        if received > 20 {
            break telemetry;
        }
        assert!(Instant::now() < deadline, "no samples across: {status}");
        std::thread::sleep(Duration::from_millis(100));
    };
    assert_spread_telemetry(&telemetry);

    // An output of b linked here is known here by its own name: a viewer gets it from the coordinator.
    let subscribed = call(
        &mut socket,
        &json!({"id": 40, "type": "subscribe_samples", "outputs": ["gain.out"], "max_rate_hz": 20}),
    );
    assert_eq!(subscribed["ok"], true, "{subscribed}");
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        assert!(Instant::now() < deadline, "no frame of gain.out");
        if let Message::Binary(frame) = socket.read().unwrap() {
            let (header, _) = kairos_protocol::frame::decode(&frame).unwrap();
            assert_eq!(header.output, "gain.out");
            break;
        }
    }
    let unsubscribed = call(&mut socket, &json!({"id": 41, "type": "unsubscribe_samples"}));
    assert_eq!(unsubscribed["ok"], true, "{unsubscribed}");

    // A property of a component on b, changed through the coordinator, takes effect there.
    let changed = call(
        &mut socket,
        &json!({"id": 5, "type": "set_property", "component": "gain", "property": "gain", "value": 10.0}),
    );
    assert_eq!(changed["ok"], true, "{changed}");
    let refused = call(
        &mut socket,
        &json!({"id": 6, "type": "set_property", "component": "gain", "property": "no_such", "value": 1.0}),
    );
    assert_eq!(refused["ok"], false, "{refused}");
    let whole = call(&mut socket, &json!({"id": 7, "type": "get_diagram"}));
    let text = whole["result"]["diagram"].as_str().unwrap_or_default();
    assert!(text.contains("host: \"b\"") && text.contains("10.0"), "{text}");
    std::thread::sleep(Duration::from_millis(600));
    let stopped = call(&mut socket, &json!({"id": 8, "type": "stop"}));
    assert_eq!(stopped["ok"], true, "{stopped}");
    let b_status = call(&mut b_socket, &json!({"id": 2, "type": "status"}));
    assert_ne!(b_status["result"]["state"], "running", "stop stops b: {b_status}");
    let values = csv_values(&dir_coordinator.path().join("spread.csv"));
    let largest = values.iter().map(|(_, v)| v.abs()).fold(0.0, f64::max);
    assert!(
        largest > 2.0,
        "the gain set on b through the coordinator applied: largest {largest} of {}",
        values.len()
    );
}

/// The runtime's clock as `status` gives it, once `done` holds for it (within 5 s).
fn clock_once(server: &Server, done: impl Fn(&Value) -> bool) -> Value {
    let mut socket = operator(server);
    let started = Instant::now();
    loop {
        let status = call(&mut socket, &json!({"id": 1, "type": "status"}));
        let clock = status["result"]["clock"].clone();
        if done(&clock) {
            return clock;
        }
        assert!(started.elapsed() < Duration::from_secs(5), "{status}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn a_runtime_on_its_system_clock_is_measured_against_the_master_and_alarms_past_the_bound() {
    let _machine = shared_machine();
    let dirs: Vec<tempfile::TempDir> = (0..3).map(|_| tempfile::tempdir().unwrap()).collect();
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let address = format!("127.0.0.1:{port}");
    let _master = serve(dirs[0].path(), &["--clock-master", &address]);
    let calm = serve(dirs[1].path(), &["--clock-system-against", &address]);
    // One machine has one clock: a bound of a nanosecond is always crossed.
    let alarmed = serve(
        dirs[2].path(),
        &["--clock-system-against", &address, "--clock-alarm", "0.001us"],
    );
    let clock = clock_once(&calm, |clock| clock["references"].as_u64().unwrap_or(0) >= 8);
    assert_eq!(clock["source"], "system", "{clock}");
    assert_eq!(clock["state"], "locked", "{clock}");
    assert_eq!(clock["step_ns"], 0, "the system clock is never stepped: {clock}");
    let error_us = clock["error_ns"].as_f64().unwrap().abs() / 1e3;
    assert!(error_us < 1000.0, "measured {error_us} µs: {clock}");
    assert!(clock["error_bound_ns"].as_i64().is_some(), "{clock}");
    let clock = clock_once(&alarmed, |clock| clock["references"].as_u64().unwrap_or(0) >= 1);
    assert_eq!(clock["state"], "alarm", "{clock}");
}

#[test]
fn a_coordinated_start_refused_for_an_unlocked_clock_goes_ahead_when_asked_to() {
    let _machine = shared_machine();
    let [dir_coordinator, dir_b, here] = folders();
    // b follows a clock master that never answers: its clock stays unlocked.
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let silent_master = format!("127.0.0.1:{port}");
    let (coordinator, b) = (
        serve(dir_coordinator.path(), &[]),
        serve(dir_b.path(), &["--clock-slave-of", &silent_master]),
    );
    std::fs::write(here.path().join("b.token"), &b.token).unwrap();
    let diagram = format!(
        r#"Diagram(format: 1,
            hosts: {{"b": Host(endpoint: "{}", token_file: "b.token", zenoh: "tcp/127.0.0.1:{}")}},
            components: [
                Component(id: "sine", type: "core.sine", host: "b", properties: {{"rate": 100.0}}),
                Component(id: "console", type: "core.console", properties: {{"every": 50}}),
            ],
            connections: [Connection(from: "sine.out", to: "console.in")])"#,
        b.url,
        free_tcp_port()
    );
    let mut socket = operator(&coordinator);
    let folder = here.path().display().to_string();
    let deployed = call(
        &mut socket,
        &json!({"id": 1, "type": "deploy", "diagram": diagram, "folder": folder}),
    );
    assert_eq!(deployed["ok"], true, "{deployed}");
    let refused = call(&mut socket, &json!({"id": 2, "type": "start"}));
    assert_eq!(refused["ok"], false, "{refused}");
    let message = refused["error"]["message"].as_str().unwrap_or_default();
    assert!(
        message.contains("clock is locked to its master")
            && message.contains("host 'b': clock acquiring (no exchange with its master yet)"),
        "{refused}"
    );
    let mut b_socket = operator(&b);
    let b_status = call(&mut b_socket, &json!({"id": 1, "type": "status"}));
    assert_ne!(
        b_status["result"]["state"], "running",
        "nothing started: {b_status}"
    );

    let started = call(
        &mut socket,
        &json!({"id": 3, "type": "start", "start_unlocked": true}),
    );
    assert_eq!(started["ok"], true, "{started}");
    let b_status = call(&mut b_socket, &json!({"id": 2, "type": "status"}));
    assert_eq!(b_status["result"]["state"], "running", "{b_status}");
    let stopped = call(&mut socket, &json!({"id": 4, "type": "stop"}));
    assert_eq!(stopped["ok"], true, "{stopped}");
}

// ---- Live in Foxglove ----------------------------------------------------------------------------------

/// A client of `kairos serve --foxglove`, speaking `subprotocol`.
fn foxglove_client(url: &str, subprotocol: &str) -> Result<Socket, tungstenite::Error> {
    use tungstenite::client::IntoClientRequest as _;
    let mut request = url.into_client_request()?;
    request
        .headers_mut()
        .insert("Sec-WebSocket-Protocol", subprotocol.parse().unwrap());
    let (socket, response) = tungstenite::connect(request)?;
    if response.headers().get("Sec-WebSocket-Protocol").is_none() {
        return Err(tungstenite::Error::Protocol(
            tungstenite::error::ProtocolError::SecWebSocketSubProtocolError(
                tungstenite::error::SubProtocolError::NoSubProtocol,
            ),
        ));
    }
    if let MaybeTlsStream::Plain(stream) = socket.get_ref() {
        stream.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    }
    Ok(socket)
}

/// Reads until each of `topics` is advertised: their channels (`id`, `schemaName`, ...) by topic.
fn foxglove_channels(socket: &mut Socket, topics: &[&str]) -> std::collections::BTreeMap<String, Value> {
    let mut channels = std::collections::BTreeMap::new();
    let deadline = Instant::now() + Duration::from_secs(10);
    while !topics.iter().all(|t| channels.contains_key(*t)) {
        assert!(Instant::now() < deadline, "advertised only {channels:?}");
        if let Message::Text(text) = socket.read().unwrap() {
            let message: Value = serde_json::from_str(text.as_str()).unwrap();
            if message["op"] == "advertise" {
                for channel in message["channels"].as_array().unwrap() {
                    channels.insert(channel["topic"].as_str().unwrap().to_owned(), channel.clone());
                }
            }
        }
    }
    channels
}

fn foxglove_subscribe(socket: &mut Socket, subscription: u32, channel: &Value) {
    let request =
        json!({"op": "subscribe", "subscriptions": [{"id": subscription, "channelId": channel["id"]}]});
    socket.send(Message::text(request.to_string())).unwrap();
}

/// A message-data frame: its subscription, log time and payload; JSON messages are passed over.
fn foxglove_message(socket: &mut Socket) -> (u32, u64, Vec<u8>) {
    loop {
        if let Message::Binary(frame) = socket.read().unwrap()
            && frame.first() == Some(&1)
        {
            let subscription = u32::from_le_bytes(frame[1..5].try_into().unwrap());
            let log_time = u64::from_le_bytes(frame[5..13].try_into().unwrap());
            return (subscription, log_time, frame[13..].to_vec());
        }
    }
}

fn resident_kib(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let line = status.lines().find(|l| l.starts_with("VmRSS:")).unwrap();
    line.split_whitespace().nth(1).unwrap().parse().unwrap()
}

const CAMERA_AND_IMU: &str = r#"Diagram(
    format: 1,
    components: [
        Component(id: "camera", type: "sensors.camera", properties: {"width": 640, "height": 480, "rate": 30.0}),
        Component(id: "imu", type: "sensors.imu", properties: {"rate": 200.0}),
    ],
)"#;

#[test]
fn foxglove_gets_outputs_in_the_recordings_schemas_and_a_viewer_that_never_reads_slows_nothing() {
    let _machine = whole_machine();
    let dir = tempfile::tempdir().unwrap();
    let diagram = dir.path().join("sensors.ron");
    std::fs::write(&diagram, CAMERA_AND_IMU).unwrap();
    let server = serve(
        dir.path(),
        &[
            "--diagram",
            diagram.to_str().unwrap(),
            "--start",
            "--foxglove",
            "127.0.0.1:0",
            "--foxglove-backlog",
            "16",
        ],
    );
    let url = server
        .foxglove
        .clone()
        .expect("serve printed the Foxglove address");
    let mut viewer = foxglove_client(&url, "foxglove.sdk.v1").unwrap();
    let channels = foxglove_channels(&mut viewer, &["camera.image", "imu.imu", "imu.pose"]);
    let camera = &channels["camera.image"];
    assert_eq!(camera["schemaName"], "foxglove.RawImage", "{camera}");
    assert_eq!(camera["encoding"], "protobuf", "{camera}");
    let imu = &channels["imu.imu"];
    foxglove_subscribe(&mut viewer, 1, camera);
    foxglove_subscribe(&mut viewer, 2, imu);

    // A viewer that subscribes to the images and then never reads again.
    let mut stuck = foxglove_client(&url, "foxglove.sdk.v1").unwrap();
    let stuck_channels = foxglove_channels(&mut stuck, &["camera.image"]);
    foxglove_subscribe(&mut stuck, 7, &stuck_channels["camera.image"]);

    let (_, _, first) = loop {
        let message = foxglove_message(&mut viewer);
        if message.0 == 1 {
            break message;
        }
    };
    let schema = camera["schemaName"].as_str().unwrap();
    let kairos_sdk::Payload::Image(image) = kairos_pack_recording::decode::decode(schema, &first).unwrap()
    else {
        panic!("not an image")
    };
    assert_eq!((image.width, image.height), (640, 480));

    std::thread::sleep(Duration::from_secs(2));
    let rss_before = resident_kib(server.child.id());
    let (mut images, mut imus) = (0_u32, 0_u32);
    let mut imu_payload = Vec::new();
    let counting = Instant::now();
    while counting.elapsed() < Duration::from_secs(6) {
        let (subscription, _, payload) = foxglove_message(&mut viewer);
        match subscription {
            1 => images += 1,
            2 => {
                imus += 1;
                imu_payload = payload;
            }
            other => panic!("subscription {other}"),
        }
    }
    let rss_after = resident_kib(server.child.id());
    let imu_schema = imu["schemaName"].as_str().unwrap();
    assert!(
        matches!(
            kairos_pack_recording::decode::decode(imu_schema, &imu_payload),
            Ok(kairos_sdk::Payload::Imu(_))
        ),
        "{imu}"
    );
    // 6 s at 30 Hz and 200 Hz: whatever the stuck viewer does, the other gets nearly everything.
    assert!(images >= 150, "{images} images in 6 s");
    assert!(imus >= 1000, "{imus} IMU samples in 6 s");
    // The stuck viewer holds at most 16 images (15 MB) plus what its socket holds; unbounded, it would
    // have held 6 s of images (165 MB) by now.
    let grown_mib = rss_after.saturating_sub(rss_before) / 1024;
    assert!(
        grown_mib < 60,
        "the runtime grew by {grown_mib} MiB while a viewer did not read"
    );
    // `kairos status` tells where Foxglove connects and how many are connected.
    let shown = common::kairos(
        dir.path(),
        &[
            "status",
            &server.url,
            "--token-file",
            dir.path().join("token.txt").to_str().unwrap(),
        ],
    );
    let (stdout, _) = text(&shown);
    assert!(
        stdout.contains(&format!("Foxglove on {url} (every output, 2 client(s))")),
        "{stdout}"
    );
    drop(stuck);
}

#[test]
fn foxglove_refuses_a_wrong_subprotocol_an_open_address_without_the_flag_and_an_unknown_output() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let output = common::kairos(
        dir.path(),
        &["serve", "--listen", "127.0.0.1:0", "--foxglove", "0.0.0.0:0"],
    );
    let (_, stderr) = text(&output);
    assert!(!output.status.success());
    assert!(stderr.contains("--foxglove-open-to-network"), "{stderr}");
    assert!(stderr.contains("carries no token"), "{stderr}");

    let diagram = dir.path().join("sensors.ron");
    std::fs::write(&diagram, CAMERA_AND_IMU).unwrap();
    let output = common::kairos(
        dir.path(),
        &[
            "serve",
            "--listen",
            "127.0.0.1:0",
            "--diagram",
            diagram.to_str().unwrap(),
            "--foxglove",
            "127.0.0.1:0",
            "--foxglove-output",
            "camera.img",
        ],
    );
    let (_, stderr) = text(&output);
    assert!(!output.status.success());
    assert!(
        stderr.contains("--foxglove-output camera.img: no such output")
            && stderr.contains("camera.image, imu.imu, imu.pose"),
        "{stderr}"
    );

    let server = serve(
        dir.path(),
        &[
            "--diagram",
            diagram.to_str().unwrap(),
            "--start",
            "--foxglove",
            "127.0.0.1:0",
        ],
    );
    let url = server.foxglove.clone().unwrap();
    let refused = foxglove_client(&url, "kairos.v1");
    assert!(
        refused.is_err(),
        "a client speaking another subprotocol is refused"
    );
    let mut viewer = foxglove_client(&url, "foxglove.sdk.v1").unwrap();
    foxglove_channels(&mut viewer, &["camera.image"]);
}

#[test]
fn foxglove_publish_starts_a_server_for_chosen_outputs_and_stops_publishing_them() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let server = serve(dir.path(), &[]);
    let mut admin = operator(&server);
    deploy_and_start(&mut admin, &std::fs::read_to_string(example("hello")).unwrap());
    let reply = call(&mut admin, &json!({"id": 10, "type": "foxglove"}));
    assert!(reply["result"]["address"].is_null(), "no server yet: {reply}");

    let reply = call(
        &mut admin,
        &json!({"id": 11, "type": "foxglove_publish", "outputs": ["sine1.outt"], "publish": true}),
    );
    assert_eq!(reply["error"]["code"], "not_found", "{reply}");
    assert!(
        reply["error"]["message"].as_str().unwrap().contains("sine1.out"),
        "the outputs there are named: {reply}"
    );

    let reply = call(
        &mut admin,
        &json!({"id": 12, "type": "foxglove_publish", "outputs": ["gain1.out"], "publish": true}),
    );
    assert_eq!(reply["ok"], true, "{reply}");
    assert_eq!(reply["result"]["outputs"], json!(["gain1.out"]), "{reply}");
    let url = reply["result"]["address"].as_str().unwrap().to_owned();
    assert!(url.starts_with("ws://127.0.0.1:"), "{url}");

    let mut viewer = foxglove_client(&url, "foxglove.sdk.v1").unwrap();
    let channels = foxglove_channels(&mut viewer, &["gain1.out"]);
    assert_eq!(channels.len(), 1, "only the chosen output: {channels:?}");
    let channel = &channels["gain1.out"];
    foxglove_subscribe(&mut viewer, 3, channel);
    let (_, _, payload) = foxglove_message(&mut viewer);
    let schema = channel["schemaName"].as_str().unwrap();
    assert!(
        matches!(
            kairos_pack_recording::decode::decode(schema, &payload),
            Ok(kairos_sdk::Payload::F64(_))
        ),
        "{channel}"
    );
    let reply = call(&mut admin, &json!({"id": 13, "type": "foxglove"}));
    assert_eq!(reply["result"]["clients"], 1, "{reply}");

    // Deployed again: the old channel goes, and the output is published again from the new diagram.
    deploy_and_start(&mut admin, &std::fs::read_to_string(example("hello")).unwrap());
    let mut taken_back = false;
    let channel = loop {
        if let Message::Text(text) = viewer.read().unwrap() {
            let message: Value = serde_json::from_str(text.as_str()).unwrap();
            taken_back |= message["op"] == "unadvertise" && message["channelIds"] == json!([channel["id"]]);
            if message["op"] == "advertise" && taken_back {
                break message["channels"][0].clone();
            }
        }
    };
    assert_eq!(channel["topic"], "gain1.out", "{channel}");

    let reply = call(
        &mut admin,
        &json!({"id": 14, "type": "foxglove_publish", "outputs": ["gain1.out"], "publish": false}),
    );
    assert_eq!(reply["result"]["outputs"], json!([]), "{reply}");
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        assert!(Instant::now() < deadline, "the channel was not taken back");
        if let Message::Text(text) = viewer.read().unwrap() {
            let message: Value = serde_json::from_str(text.as_str()).unwrap();
            if message["op"] == "unadvertise" {
                assert_eq!(message["channelIds"], json!([channel["id"]]), "{message}");
                break;
            }
        }
    }
}

#[test]
fn kairos_run_publishes_to_foxglove_too() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let diagram = dir.path().join("sensors.ron");
    std::fs::write(&diagram, CAMERA_AND_IMU).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_kairos"))
        .args(["run", diagram.to_str().unwrap(), "--for", "20s"])
        .args(["--foxglove", "127.0.0.1:0", "--foxglove-output", "imu.imu"])
        .current_dir(dir.path())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let url = loop {
        let line = lines.next().expect("run printed the Foxglove address").unwrap();
        if let Some(url) = line.strip_prefix("foxglove on ") {
            break url.to_owned();
        }
    };
    std::thread::spawn(move || for _ in lines {});
    let mut viewer = foxglove_client(&url, "foxglove.sdk.v1").unwrap();
    let channels = foxglove_channels(&mut viewer, &["imu.imu"]);
    assert_eq!(channels.len(), 1, "only the chosen output: {channels:?}");
    foxglove_subscribe(&mut viewer, 1, &channels["imu.imu"]);
    let (_, _, payload) = foxglove_message(&mut viewer);
    let schema = channels["imu.imu"]["schemaName"].as_str().unwrap();
    assert!(matches!(
        kairos_pack_recording::decode::decode(schema, &payload),
        Ok(kairos_sdk::Payload::Imu(_))
    ));
    let _ = child.kill();
    let _ = child.wait();
}

#[test]
fn camera_frames_from_another_host_arrive_whole_in_a_recording_here() {
    let _machine = shared_machine();
    let [dir_b, here] = folders();
    let b = serve(dir_b.path(), &[]);
    std::fs::write(here.path().join("b.token"), &b.token).unwrap();
    let diagram = here.path().join("camera_on_b.ron");
    // 640×480 RGB frames (921 600 bytes) cross in many Zenoh fragments.
    std::fs::write(
        &diagram,
        format!(
            r#"Diagram(format: 1,
            hosts: {{"b": Host(endpoint: "{}", token_file: "b.token")}},
            components: [
                Component(id: "camera", type: "sensors.camera", host: "b", properties: {{"width": 640, "height": 480, "rate": 10.0}}),
                Component(id: "recorder", type: "recording.recorder", properties: {{"path": "here.mcap", "compression": "none"}}),
            ],
            connections: [Connection(from: "camera.image", to: "recorder.in1")])"#,
            b.url
        ),
    )
    .unwrap();
    let deployed = common::kairos(here.path(), &["deploy", diagram.to_str().unwrap(), "--for", "2s"]);
    let (stdout, stderr) = text(&deployed);
    assert!(deployed.status.success(), "{stdout}{stderr}");
    let mut frames = 0;
    let bytes = std::fs::read(here.path().join("here.mcap")).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let message = message.unwrap();
        // Recorded under the name the diagram gives them, though a link's end writes them here.
        if message.channel.topic == "camera.image" {
            let schema = message.channel.schema.as_ref().unwrap().name.clone();
            let kairos_sdk::Payload::Image(image) =
                kairos_pack_recording::decode::decode(&schema, &message.data).unwrap()
            else {
                panic!("not an image")
            };
            assert_eq!(
                (image.width, image.height, image.pixels.len()),
                (640, 480, 921_600)
            );
            frames += 1;
        }
    }
    assert!(frames >= 10, "{frames} frames in 2 s at 10 Hz ({summary:?})");
}
