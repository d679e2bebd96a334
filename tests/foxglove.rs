//! Live in Foxglove: outputs published through the `foxglove` crate's WebSocket server, read by a client
//! speaking its protocol, from `kairos serve` and `kairos run`.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

mod common;
mod serving;

use common::{example, text};
use serde_json::{Value, json};
use serving::{Socket, call, deploy_and_start, operator, serve, shared_machine, whole_machine};
use std::io::{BufRead as _, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use tungstenite::Message;
use tungstenite::stream::MaybeTlsStream;

/// A Foxglove client and the subscriptions it made. A subscription the server refuses as "Unknown channel
/// ID" is made again: the `foxglove` crate (0.30) sends a channel's advertisement before it records the
/// channel as advertised to the client, so a subscription that a quick client sends in between is refused.
struct Viewer {
    socket: Socket,
    subscriptions: Vec<(u32, Value)>,
}

impl std::ops::Deref for Viewer {
    type Target = Socket;
    fn deref(&self) -> &Socket {
        &self.socket
    }
}

impl std::ops::DerefMut for Viewer {
    fn deref_mut(&mut self) -> &mut Socket {
        &mut self.socket
    }
}

/// A client of `kairos serve --foxglove`, speaking `subprotocol`.
fn foxglove_client(url: &str, subprotocol: &str) -> Result<Viewer, tungstenite::Error> {
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
    Ok(Viewer {
        socket,
        subscriptions: Vec::new(),
    })
}

/// Reads until each of `topics` is advertised: their channels (`id`, `schemaName`, ...) by topic.
fn foxglove_channels(socket: &mut Viewer, topics: &[&str]) -> std::collections::BTreeMap<String, Value> {
    let mut channels = std::collections::BTreeMap::new();
    let deadline = Instant::now() + Duration::from_secs(30);
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

fn foxglove_subscribe(viewer: &mut Viewer, subscription: u32, channel: &Value) {
    let request =
        json!({"op": "subscribe", "subscriptions": [{"id": subscription, "channelId": channel["id"]}]});
    viewer.send(Message::text(request.to_string())).unwrap();
    viewer.subscriptions.push((subscription, channel.clone()));
}

/// A message-data frame: its subscription, log time and payload; other JSON messages are passed over.
fn foxglove_message(viewer: &mut Viewer) -> (u32, u64, Vec<u8>) {
    loop {
        match viewer.read().unwrap() {
            Message::Binary(frame) if frame.first() == Some(&1) => {
                let subscription = u32::from_le_bytes(frame[1..5].try_into().unwrap());
                let log_time = u64::from_le_bytes(frame[5..13].try_into().unwrap());
                return (subscription, log_time, frame[13..].to_vec());
            }
            Message::Text(text) => {
                let message: Value = serde_json::from_str(text.as_str()).unwrap();
                let refused = message["message"]
                    .as_str()
                    .and_then(|m| m.strip_prefix("Unknown channel ID: "));
                let again: Vec<(u32, Value)> = viewer
                    .subscriptions
                    .iter()
                    .filter(|(_, channel)| refused == Some(channel["id"].to_string().as_str()))
                    .cloned()
                    .collect();
                for (subscription, channel) in again {
                    viewer.subscriptions.retain(|(id, _)| *id != subscription);
                    foxglove_subscribe(viewer, subscription, &channel);
                }
            }
            _ => {}
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
    let kairos_sdk_core::Payload::Image(image) =
        kairos_pack_recording::decode::decode(schema, &first).unwrap()
    else {
        panic!("not an image")
    };
    assert_eq!((image.width, image.height), (640, 480));

    std::thread::sleep(Duration::from_secs(2));
    let rss_before = resident_kib(server.child.id());
    let (mut images, mut imus) = (0_u32, 0_u32);
    let mut imu_payload = Vec::new();
    // Whatever the stuck viewer does, the other goes on getting both outputs: 150 images (the stuck one
    // would hold 130 MiB of them, unbounded) and 1000 IMU samples, 5 s at 30 Hz and 200 Hz on a fast
    // machine, however long a slow one takes.
    let counting = Instant::now();
    while images < 150 || imus < 1000 {
        assert!(
            counting.elapsed() < Duration::from_mins(1),
            "{images} images and {imus} IMU samples in a minute"
        );
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
            Ok(kairos_sdk_core::Payload::Imu(_))
        ),
        "{imu}"
    );
    // The stuck viewer holds at most 16 images (15 MB) plus what its socket holds; unbounded, it would
    // have held at least the 150 images the other got (130 MiB) by now.
    let grown_mib = rss_after.saturating_sub(rss_before) / 1024;
    assert!(
        grown_mib < 60,
        "the runtime grew by {grown_mib} MiB while a viewer did not read"
    );
    // `kairos status` tells where Foxglove connects and how many are connected.
    let stdout = serving::status_text(dir.path(), &server, dir.path());
    assert!(
        stdout.contains(&format!("Foxglove on {url} (every output, 2 client(s))")),
        "{stdout}"
    );
    drop(stuck);
}

#[test]
fn foxglove_refuses_a_wrong_subprotocol_serves_the_former_name_and_refuses_an_open_address_without_the_flag_and_an_unknown_output()
 {
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
    // A client of before the protocol's rename offers its former name: it is answered in that name
    // (tungstenite checks the answer is one it offered) and served the same channels and messages.
    let mut former = foxglove_client(&url, "foxglove.websocket.v1").unwrap();
    let channels = foxglove_channels(&mut former, &["imu.imu"]);
    foxglove_subscribe(&mut former, 7, &channels["imu.imu"]);
    let (subscription, log_time, payload) = foxglove_message(&mut former);
    assert_eq!(subscription, 7);
    assert!(log_time > 0 && !payload.is_empty());
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
            Ok(kairos_sdk_core::Payload::F64(_))
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
    let deadline = Instant::now() + Duration::from_secs(30);
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
    std::thread::Builder::new()
        .name("foxglove".to_owned())
        .spawn(move || for _ in lines {})
        .expect("starting a thread");
    let mut viewer = foxglove_client(&url, "foxglove.sdk.v1").unwrap();
    let channels = foxglove_channels(&mut viewer, &["imu.imu"]);
    assert_eq!(channels.len(), 1, "only the chosen output: {channels:?}");
    foxglove_subscribe(&mut viewer, 1, &channels["imu.imu"]);
    let (_, _, payload) = foxglove_message(&mut viewer);
    let schema = channels["imu.imu"]["schemaName"].as_str().unwrap();
    assert!(matches!(
        kairos_pack_recording::decode::decode(schema, &payload),
        Ok(kairos_sdk_core::Payload::Imu(_))
    ));
    let _ = child.kill();
    let _ = child.wait();
}
