//! The control protocol over a real socket against the real `kairos serve`: the role table, bad input,
//! tokens, isolation of a running diagram from misbehaving clients, recorders and players driven over it,
//! and the Python example client.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

mod common;
mod serving;

use common::{example, repo_root, text};
use kairos_protocol::{RequestKind, Role};
use serde_json::{Value, json};
use serving::{
    Socket, call, connect, deploy_and_start, hello, operator, serve, shared_machine, state, whole_machine,
};
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};
use tungstenite::Message;
use tungstenite::stream::MaybeTlsStream;

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

/// A request of each type, with plausible fields (what they name may not exist: only the role check
/// matters for the matrix).
fn sample_request(kind: RequestKind, id: u64) -> Value {
    let mut request = json!({"id": id, "type": kind.name()});
    let fields = match kind {
        RequestKind::Hello => json!({"protocol": 1, "client": "x"}),
        RequestKind::Deploy | RequestKind::PrepareDeploy => json!({"diagram": "Diagram(format: 1)"}),
        RequestKind::CommitDeploy | RequestKind::AbandonDeploy => json!({"ticket": 1}),
        RequestKind::SetProperty => json!({"component": "gain1", "property": "gain", "value": 3.0}),
        RequestKind::TriggerAction => json!({"component": "gain1", "action": "reset"}),
        RequestKind::SubscribeTelemetry => json!({"interval_ms": 1000}),
        RequestKind::SubscribeSamples => json!({"outputs": ["sine1.out"]}),
        RequestKind::FoxglovePublish => json!({"outputs": ["sine1.out"], "publish": true}),
        RequestKind::PlayerSeek => json!({"component": "gain1", "seconds": 1.0}),
        RequestKind::PlayerSpeed => json!({"component": "gain1", "factor": 2.0}),
        RequestKind::Ros2Topics => json!({"router": "tcp/127.0.0.1:1"}),
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

/// The counts in the CSV the 1 kHz counter's diagram writes, in the file's order.
fn counts_written(csv: &Path) -> Vec<i64> {
    let content = std::fs::read_to_string(csv).unwrap();
    content
        .lines()
        .skip(1)
        .filter_map(|l| l.split(',').next_back()?.parse().ok())
        .collect()
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
    assert_eq!(
        state(&mut admin),
        "running",
        "the diagram runs on after {round} connections in {churn:?}"
    );
    assert_eq!(call(&mut admin, &json!({"id": 30, "type": "stop"}))["ok"], true);
    // Every count reached the file, in order, while clients misbehaved. (How evenly the ticks came is
    // for the benchmarks.)
    let counts = counts_written(&dir.path().join("ticks.csv"));
    assert!(!counts.is_empty(), "no sample in {churn:?} ({round} connections)");
    assert!(
        counts.windows(2).all(|pair| pair[1] == pair[0] + 1),
        "a count lost or out of order: {counts:?}"
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

/// The topics a ROS 2 graph advertises, as `rmw_zenoh`'s liveliness tokens say them (a node in Python
/// declaring them as its design document gives), for the studio's topic picker; the library marks the
/// properties naming one; a router out of reach is named, not taken for an empty graph.
#[test]
fn ros2_topics_lists_what_a_ros2_graph_advertises_and_names_a_router_out_of_reach() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let server = serve(dir.path(), &[]);
    let mut socket = operator(&server);
    let endpoint = format!("tcp/127.0.0.1:{}", serving::free_tcp_port());
    let mut node = Command::new("python3")
        .arg(repo_root().join("tests/ros2/graph_node.py"))
        .args([&endpoint, "30"])
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("python3");
    let mut ready = String::new();
    std::io::BufRead::read_line(
        &mut std::io::BufReader::new(node.stdout.take().unwrap()),
        &mut ready,
    )
    .unwrap();
    assert_eq!(ready.trim(), "ready");
    let reply = call(
        &mut socket,
        &json!({"id": 5, "type": "ros2_topics", "router": endpoint, "domain_id": 0}),
    );
    let other_domain = call(
        &mut socket,
        &json!({"id": 6, "type": "ros2_topics", "router": endpoint, "domain_id": 7}),
    );
    let _ = node.kill();
    let _ = node.wait();
    assert_eq!(reply["ok"], true, "{reply}");
    assert_eq!(
        reply["result"]["topics"],
        json!([
            {"name": "/lidar/points", "type": "sensor_msgs/msg/PointCloud2", "publishers": 1, "subscriptions": 0},
            {"name": "/robot1/cmd_vel", "type": "geometry_msgs/msg/Twist", "publishers": 0, "subscriptions": 1},
        ])
    );
    assert_eq!(
        reply["result"]["services"],
        json!([
            {"name": "/robot1/plan", "type": "nav_msgs/srv/GetPlan", "servers": 0, "clients": 1},
            {"name": "/scanner/reset", "type": "std_srvs/srv/Trigger", "servers": 1, "clients": 0},
        ])
    );
    assert_eq!(other_domain["result"]["topics"], json!([]), "{other_domain}");

    let absent = format!("tcp/127.0.0.1:{}", serving::free_tcp_port());
    let refused = call(
        &mut socket,
        &json!({"id": 7, "type": "ros2_topics", "router": absent, "domain_id": 0}),
    );
    assert_eq!(refused["error"]["code"], "invalid_value", "{refused}");
    let said = refused["error"]["message"].as_str().unwrap_or_default();
    assert!(said.contains(&absent) && said.contains("rmw_zenohd"), "{said}");

    let library = call(&mut socket, &json!({"id": 8, "type": "library"}));
    for type_name in ["ros2.subscriber", "ros2.publisher"] {
        let topic = library["result"]["components"][type_name]["properties"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["name"] == "topic")
            .unwrap()
            .clone();
        assert_eq!(topic["device"], "ros2_topic", "{type_name}: {topic}");
    }
    for type_name in ["ros2.service_client", "ros2.service_server"] {
        let service = library["result"]["components"][type_name]["properties"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["name"] == "service")
            .unwrap()
            .clone();
        assert_eq!(service["device"], "ros2_service", "{type_name}: {service}");
    }
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
    // For 1.5 s from the first frame, however long a slow machine takes to send it.
    let mut first: Option<Instant> = None;
    let mut frames = 0;
    while first.is_none_or(|at| at.elapsed() < Duration::from_millis(1500)) {
        if let Message::Binary(bytes) = socket.read().unwrap() {
            let (header, pixels) = kairos_protocol::frame::decode(&bytes).unwrap();
            let image = header.image.unwrap();
            assert_eq!((image.width, image.original_width), (160, Some(640)));
            assert_eq!(pixels.len(), (image.stride * image.height) as usize);
            if first.is_none() {
                first = Some(Instant::now());
            }
            frames += 1;
        }
    }
    // At most 5 per second: 8 in 1.5 s, with one for the timing's slack.
    assert!(
        (1..=9).contains(&frames),
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
    // About 120 in 1.2 s at 100 Hz on a fast machine.
    assert!(report.complete && report.messages >= 1, "{report:?}");

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

/// Telemetry events received within `window`, with their states.
fn telemetry_within(socket: &mut Socket, window: Duration) -> Vec<String> {
    let mut states = Vec::new();
    let until = Instant::now() + window;
    while let Some(left) = until.checked_duration_since(Instant::now()) {
        if let MaybeTlsStream::Plain(stream) = socket.get_ref() {
            stream
                .set_read_timeout(Some(left.max(Duration::from_millis(1))))
                .unwrap();
        }
        let Ok(Message::Text(text)) = socket.read() else {
            continue;
        };
        let message: Value = serde_json::from_str(text.as_str()).unwrap();
        if message["type"] == "telemetry" {
            states.push(message["state"].as_str().unwrap_or_default().to_owned());
        }
    }
    states
}

#[test]
fn a_diagram_whose_components_all_finish_stops_and_says_so() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let server = serve(dir.path(), &[]);
    let mut socket = operator(&server);
    // A simulation of half a second, in real time: its vehicle finishes, and so does every component.
    deploy_and_start(
        &mut socket,
        r#"Diagram(format: 1,
            components: [
                Component(id: "vehicle", type: "sim.vehicle", properties: {"duration": 0.5}),
            ],
            connections: [])"#,
    );
    let started = Instant::now();
    while state(&mut socket) == "running" {
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "still running after every component finished"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    assert_eq!(state(&mut socket), "ready");
    drop(server);
    let log = std::fs::read_to_string(dir.path().join("serve.log")).unwrap();
    assert!(
        log.contains("every component has finished: the diagram stopped"),
        "{log}"
    );
}

#[test]
fn telemetry_flows_while_the_diagram_runs_and_rests_once_it_is_stopped() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let server = serve(dir.path(), &[]);
    let mut admin = operator(&server);
    let hello_text = std::fs::read_to_string(example("hello")).unwrap();
    deploy_and_start(&mut admin, &hello_text);
    let reply = call(
        &mut admin,
        &json!({"id": 20, "type": "subscribe_telemetry", "interval_ms": 50}),
    );
    assert_eq!(reply["ok"], true, "{reply}");
    let running = telemetry_within(&mut admin, Duration::from_secs(1));
    assert!(running.len() >= 5, "{running:?}");
    assert_eq!(call(&mut admin, &json!({"id": 21, "type": "stop"}))["ok"], true);
    // What the stop changed is said once; then nothing changes, and nothing is sent but a reminder.
    let _ = telemetry_within(&mut admin, Duration::from_millis(500));
    let stopped = telemetry_within(&mut admin, Duration::from_secs(2));
    assert!(stopped.len() <= 1, "{stopped:?}");
    assert_eq!(call(&mut admin, &json!({"id": 22, "type": "start"}))["ok"], true);
    let again = telemetry_within(&mut admin, Duration::from_secs(1));
    assert!(again.iter().filter(|s| *s == "running").count() >= 5, "{again:?}");
}

#[test]
fn a_diagram_with_subgraphs_deploys_with_its_folder_and_is_refused_clearly_without() {
    let _machine = shared_machine();
    let dir = tempfile::tempdir().unwrap();
    let server = serve(dir.path(), &[]);
    let mut socket = operator(&server);
    let folder = dir.path().join("rig");
    std::fs::create_dir(&folder).unwrap();
    std::fs::write(
        folder.join("doubled.ron"),
        r#"Diagram(format: 1,
    exposes: Exposes(inputs: {"in": "twice.in"}, outputs: {"out": "twice.out"}, properties: {"factor": "twice.gain"}),
    components: [Component(id: "twice", type: "core.gain", properties: {"gain": 2.0})],
)"#,
    )
    .unwrap();
    let diagram = r#"Diagram(format: 1,
    components: [
        Component(id: "count", type: "core.counter", properties: {"rate": 50.0}),
        Component(id: "scale", type: "doubled.ron", properties: {"factor": 3.0}),
    ],
    connections: [Connection(from: "count.out", to: "scale.in")],
)"#;
    // Sent alone, the runtime cannot read the subgraph, and says so at the instance.
    let reply = call(
        &mut socket,
        &json!({"id": 2, "type": "deploy", "diagram": diagram}),
    );
    assert_eq!(reply["error"]["code"], "invalid_diagram", "{reply}");
    let message = reply["error"]["message"].as_str().unwrap();
    assert!(
        message.contains("cannot read subgraph 'doubled.ron': the diagram came without its folder"),
        "{message}"
    );
    assert_eq!(
        reply["error"]["diagnostics"][0]["code"], "invalid_subgraph",
        "{reply}"
    );
    assert_eq!(reply["error"]["diagnostics"][0]["location"]["line"], 4, "{reply}");
    // With its folder, it runs flat: the inner gain is `scale/twice`, set by the instance's property.
    let reply = call(
        &mut socket,
        &json!({"id": 3, "type": "deploy", "diagram": diagram, "folder": folder.display().to_string()}),
    );
    assert_eq!(reply["ok"], true, "{reply}");
    assert_eq!(call(&mut socket, &json!({"id": 4, "type": "start"}))["ok"], true);
    let deployed = call(&mut socket, &json!({"id": 5, "type": "get_diagram"}));
    let text = deployed["result"]["diagram"].as_str().unwrap();
    let flat = kairos_diagram::parse(text).unwrap().diagram;
    let inner = flat.component("scale/twice").unwrap();
    assert_eq!(inner.properties["gain"], kairos_diagram::Value::F64(3.0));
    assert!(
        flat.connections
            .iter()
            .any(|c| c.to.to_string() == "scale/twice.in")
    );
    let status = call(&mut socket, &json!({"id": 6, "type": "status"}));
    let ids: Vec<&str> = status["result"]["telemetry"]["components"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|c| c["id"].as_str())
        .collect();
    assert!(ids.contains(&"scale/twice"), "{ids:?}");
}
