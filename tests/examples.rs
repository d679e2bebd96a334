//! The example diagrams, validated and run through the real `kairos` binary.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

mod common;

use common::{example, kairos, text};

#[test]
fn every_example_validates() {
    // From the repository's folder, as the examples say to run them: their data files are named from there.
    let root = common::repo_root();
    for name in [
        "hello",
        "camera",
        "fusion",
        "record",
        "sensors",
        "gnss_replay",
        "gnss_serial",
        "image_sequence",
        "udp_link",
        "can_replay",
        "python/threshold",
        "python/edges",
        "vision/lanes",
        "fusion/gnss_imu",
        "lidar/obstacles",
        "two_hosts",
        "rig",
        "scale/threaded_900",
        "scale/grouped_900",
        "subgraph/lane_pipeline",
        "subgraph/two_cameras",
        "ros2/record",
        "ros2/live",
        "sim/lane_keeping",
        "sim/gym_mountain_car",
        "sim/all_sensors",
        "sim/gym_over_udp",
    ] {
        let path = example(name);
        let output = kairos(&root, &["validate", path.to_str().unwrap()]);
        let (stdout, stderr) = text(&output);
        assert!(output.status.success(), "{name}: {stdout}{stderr}");
        assert!(stdout.contains("valid"), "{name}: {stdout}");
    }
}

#[test]
fn replay_fuses_a_recording_as_if_the_sensors_were_live() {
    let dir = tempfile::tempdir().unwrap();
    let record = kairos(
        dir.path(),
        &["run", example("record").to_str().unwrap(), "--for", "1500ms"],
    );
    assert!(record.status.success(), "{}", text(&record).1);
    // No --for: the replay ends with the recording.
    let output = kairos(dir.path(), &["run", example("replay").to_str().unwrap()]);
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    assert!(stderr.contains("every component has finished"), "{stderr}");
    let (header, rows) = csv_rows(&dir.path().join("replay.csv"));
    // As many fixes as the recording holds (about 15 in 1.5 s on a fast machine): at least one.
    assert!(!rows.is_empty(), "no fused row from the recording");
    let column = |name: &str| header.iter().position(|h| h == name).unwrap();
    let (imu, gnss) = (column("in1.timestamp_ns"), column("in2.timestamp_ns"));
    for row in &rows {
        let (a, b): (i64, i64) = (row[imu].parse().unwrap(), row[gnss].parse().unwrap());
        assert!((a - b).abs() <= 5_000_000, "matched within 5 ms: {row:?}");
    }
}

#[test]
fn a_rosbag2_recording_made_by_the_ros2_example_replays_through_the_lane_pipeline() {
    let dir = tempfile::tempdir().unwrap();
    let record = kairos(
        dir.path(),
        &["run", example("ros2/record").to_str().unwrap(), "--for", "1500ms"],
    );
    assert!(record.status.success(), "{}", text(&record).1);
    let inspected = kairos(dir.path(), &["inspect", "drive_ros.mcap"]);
    let (report, _) = text(&inspected);
    assert!(
        report.contains("/camera/image") && report.contains("sensor_msgs/msg/Image"),
        "{report}"
    );
    // No --for: the replay ends with the bag.
    let output = kairos(
        dir.path(),
        &["run", example("ros2/lanes_from_bag").to_str().unwrap(), "--stats"],
    );
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    // Every image in the bag went through every stage of the pipeline, and its lines to the console.
    let images = report
        .lines()
        .find(|l| l.starts_with("/camera/image"))
        .and_then(|l| l.split_whitespace().nth(3))
        .and_then(|n| n.parse::<u64>().ok())
        .unwrap();
    assert!(images > 0, "{report}");
    for stage in ["grey", "blur", "edges", "lines", "overlay"] {
        assert_eq!(
            common::stats_cycles(&stderr, &format!("lanes/{stage}")),
            images,
            "{stage}: {stderr}"
        );
    }
    assert_eq!(
        stdout.lines().filter(|l| l.starts_with("lines:")).count() as u64,
        images,
        "{stdout}"
    );
}

/// A ROS 2 node in Python (`tests/ros2/SCRIPT`: eclipse-zenoh and rosbags) listening on a free port of
/// loopback for `seconds`, once it says it is ready: its endpoint, the process, and its standard output's
/// lines to come.
fn ros2_node_in_python(
    script: &str,
    seconds: &str,
) -> (
    String,
    std::process::Child,
    std::io::Lines<std::io::BufReader<std::process::ChildStdout>>,
) {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let mut peer = std::process::Command::new("python3")
        .arg(common::repo_root().join("tests/ros2").join(script))
        .args([&endpoint, seconds])
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("python3");
    let mut lines = std::io::BufRead::lines(std::io::BufReader::new(peer.stdout.take().unwrap()));
    assert_eq!(lines.next().unwrap().unwrap(), "ready");
    (endpoint, peer, lines)
}

/// Transient-local topics both ways, against `zenoh-ext`'s advanced publisher and subscriber (what
/// `rmw_zenoh`'s transient-local publishers and subscriptions are made of) in Python, and a publisher that
/// appears late with messages it kept.
#[test]
fn transient_local_topics_give_late_subscriptions_the_last_messages_both_ways() {
    let (endpoint, mut peer, mut lines) = ros2_node_in_python("transient_peer.py", "7");
    let dir = tempfile::tempdir().unwrap();
    let diagram = dir.path().join("transient.ron");
    std::fs::write(
        &diagram,
        format!(
            r#"Diagram(format: 1, components: [
    Component(id: "count", type: "core.counter", properties: {{"rate": 10.0, "start": 1}}),
    Component(id: "count_to_ros", type: "ros2.publisher", properties: {{"topic": "/kairos/count",
        "durability": "transient_local", "depth": 5, "router": "{endpoint}"}}),
    Component(id: "map_from_ros", type: "ros2.subscriber", properties: {{"topic": "/map",
        "type": "std_msgs/msg/Float64", "durability": "transient_local", "depth": 3, "router": "{endpoint}"}}),
    Component(id: "map", type: "core.console"),
], connections: [
    Connection(from: "count.out", to: "count_to_ros.in"),
    Connection(from: "map_from_ros.out", to: "map.in"),
])"#
        ),
    )
    .unwrap();
    let output = kairos(
        dir.path(),
        &["run", diagram.to_str().unwrap(), "--for", "5s", "--stats"],
    );
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&lines.next().unwrap().unwrap()).unwrap();
    assert!(peer.wait().unwrap().success());

    // Kairos' subscription of depth 3, started after the node published 1..8: 6, 7 and 8 (as 3.0, 3.5,
    // 4.0), then 9..12 live, then the late publisher's last three of four, asked for with `_max=3`.
    let values: Vec<f64> = stdout
        .lines()
        .filter(|l| l.starts_with("map:"))
        .filter_map(|l| l.rsplit(' ').next()?.parse().ok())
        .collect();
    assert_eq!(
        values,
        [3.0, 3.5, 4.0, 4.5, 5.0, 5.5, 6.0, 50.0, 50.5, 51.0],
        "{stdout}{stderr}"
    );
    assert!(stderr.contains("lost 0, received 10"), "{stderr}");
    assert!(
        report["late_query"]
            .as_str()
            .unwrap_or_default()
            .contains("_max=3"),
        "{report}"
    );
    // The node's transient-local subscription of depth 5, declared 1.5 s after Kairos began publishing:
    // the five Kairos kept, at once, then the live ones, each once and in order.
    assert_eq!(report["problems"], serde_json::json!([]), "{report}");
    let count = report["count"].as_array().unwrap();
    assert!(count.len() >= 10, "{report}");
    let first = count[0]["sequence"].as_i64().unwrap();
    assert!(first > 1, "{report}");
    for (index, message) in count.iter().enumerate() {
        assert_eq!(
            message["sequence"].as_i64().unwrap(),
            first + index as i64,
            "{report}"
        );
        assert_eq!(message["data"], message["sequence"], "{report}");
    }
    let kept_over = count[4]["at"].as_f64().unwrap() - count[0]["at"].as_f64().unwrap();
    assert!(
        kept_over < 0.09,
        "the kept five came over {kept_over} s: {report}"
    );
}

/// Services both ways against a node in Python that carries them as `rmw_zenoh` does: Kairos calls its
/// `std_srvs/srv/Trigger` server (keyed by the type hash ROS 2 gives Trigger) twice a second, and the node
/// calls Kairos' `std_srvs/srv/SetBool` server on the key its liveliness token names.
#[test]
fn ros2_services_are_called_and_offered_as_rmw_zenoh_carries_them() {
    let (endpoint, mut peer, mut lines) = ros2_node_in_python("service_peer.py", "6");
    let dir = tempfile::tempdir().unwrap();
    let diagram = dir.path().join("services.ron");
    std::fs::write(
        &diagram,
        format!(
            r#"Diagram(format: 1, components: [
    Component(id: "tick", type: "core.counter", properties: {{"rate": 2.0, "start": 1}}),
    Component(id: "reset", type: "ros2.service_client", properties: {{"service": "/reset",
        "type": "std_srvs/srv/Trigger", "router": "{endpoint}"}}),
    Component(id: "mark", type: "ros2.service_server", properties: {{"service": "/kairos/mark",
        "type": "std_srvs/srv/SetBool", "message": "marked", "router": "{endpoint}"}}),
    Component(id: "said", type: "core.console"),
    Component(id: "marks", type: "core.console"),
], connections: [
    Connection(from: "tick.out", to: "reset.call"),
    Connection(from: "reset.message", to: "said.in"),
    Connection(from: "mark.called", to: "marks.in"),
])"#
        ),
    )
    .unwrap();
    let output = kairos(
        dir.path(),
        &["run", diagram.to_str().unwrap(), "--for", "4s", "--stats"],
    );
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&lines.next().unwrap().unwrap()).unwrap();
    assert!(peer.wait().unwrap().success());
    assert_eq!(report["problems"], serde_json::json!([]), "{report}");

    // Kairos' calls as the node's server saw them: numbered one by one from 1 (a call made before the
    // server was reached, at the very start, is counted unanswered), each request Trigger's one byte after
    // the CDR header; and each response as Kairos wrote it, in order.
    let requests = report["requests"].as_array().unwrap();
    assert!(requests.len() >= 4, "{report}");
    let first = requests[0]["sequence"].as_u64().unwrap();
    for (index, request) in requests.iter().enumerate() {
        assert_eq!(request["sequence"], first + index as u64, "{report}");
        assert_eq!(request["payload"], "0001000000", "{report}");
    }
    let said: Vec<&str> = stdout
        .lines()
        .filter(|l| l.starts_with("said:"))
        .filter_map(|l| l.split("reset ").nth(1))
        .collect();
    let expected: Vec<String> = (first..first + requests.len() as u64)
        .map(|n| n.to_string())
        .collect();
    assert_eq!(said, expected, "{stdout}");
    assert!(stderr.contains(&format!("unanswered {}", first - 1)), "{stderr}");

    // The node's calls of Kairos' server: answered with the sequence number and GID echoed, the message
    // set, and each request written as a sample.
    assert!(
        report["mark_token"]
            .as_str()
            .unwrap_or_default()
            .contains("/SS/%/%/kairos/%kairos%mark/std_srvs::srv::dds_::SetBool_/RIHS01_"),
        "{report}"
    );
    assert_eq!(
        report["marks"],
        serde_json::json!([
            {"sequence": 1, "gid_echoed": true, "success": true, "message": "marked"},
            {"sequence": 2, "gid_echoed": true, "success": true, "message": "marked"},
        ]),
        "{report}"
    );
    let marks: Vec<&str> = stdout
        .lines()
        .filter(|l| l.starts_with("marks:"))
        .filter_map(|l| l.rsplit(' ').next())
        .collect();
    assert_eq!(marks, ["true", "false"], "{stdout}");
}

#[test]
fn the_live_ros2_example_talks_to_a_ros2_node_as_rmw_zenoh_makes_one() {
    let (endpoint, mut peer, mut lines) = ros2_node_in_python("live_peer.py", "8");
    let dir = tempfile::tempdir().unwrap();
    let routers: Vec<String> = ["camera_to_ros", "imu_to_ros", "speed_from_ros"]
        .iter()
        .map(|id| format!("{id}.router={endpoint}"))
        .collect();
    let diagram = example("ros2/live");
    let mut args = vec!["run", diagram.to_str().unwrap(), "--for", "4s", "--stats"];
    for router in &routers {
        args.extend(["--set", router.as_str()]);
    }
    let output = kairos(dir.path(), &args);
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&lines.next().unwrap().unwrap()).unwrap();
    assert!(peer.wait().unwrap().success());

    // Kairos' IMU as the node received it: on the key rmw_zenoh uses (the type hash rosbags computes),
    // numbered without a gap (from 1, less what was put before the node's subscription reached Kairos),
    // decoded by rosbags.
    assert_eq!(report["problems"], serde_json::json!([]), "{report}");
    let imu = report["imu"].as_array().unwrap();
    assert!(imu.len() >= 50, "{} IMU messages", imu.len());
    let first = imu[0]["sequence"].as_u64().unwrap();
    assert!(first >= 1);
    for (index, message) in imu.iter().enumerate() {
        assert_eq!(message["sequence"], first + index as u64);
        assert_eq!(message["frame_id"], "imu.imu");
        assert!(
            (message["acceleration_z"].as_f64().unwrap() - 9.81).abs() < 0.5,
            "{message}"
        );
    }
    // The graph: each node and its publisher or subscription, as `ros2 topic list` reads them.
    let tokens: Vec<&str> = report["tokens"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|t| t.as_str())
        .collect();
    for wanted in [
        "/MP/%/%/kairos/%kairos%imu/sensor_msgs::msg::dds_::Imu_/RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b/::,10:,:,:,,",
        "/MP/%/%/kairos/%kairos%camera%image/sensor_msgs::msg::dds_::Image_/RIHS01_",
        "/MS/%/%/kairos/%speed/std_msgs::msg::dds_::Float64_/RIHS01_",
        "/NN/%/%/kairos",
    ] {
        assert!(
            tokens.iter().any(|t| t.contains(wanted)),
            "{wanted} in {tokens:?}"
        );
    }
    // The node's topic: 19 values printed (number 11 never sent), and the one gap counted lost.
    let speeds: Vec<f64> = stdout
        .lines()
        .filter(|l| l.starts_with("speed:"))
        .filter_map(|l| l.rsplit(' ').next()?.parse().ok())
        .collect();
    let sent: Vec<f64> = (1..=20)
        .filter(|n| *n != 11)
        .map(|n| f64::from(n) * 0.5)
        .collect();
    assert_eq!(speeds, sent, "{stdout}");
    assert!(stderr.contains("lost 1, received 19"), "{stderr}");
}

#[test]
fn the_lane_marking_chain_handles_frames_at_every_stage() {
    let root = common::repo_root();
    let path = example("vision/lanes");
    let output = kairos(&root, &["run", path.to_str().unwrap(), "--for", "2s", "--stats"]);
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    // Every stage handled frames (how many in 2 s depends on the machine: the benchmarks measure that).
    for stage in ["grey", "blur", "edges", "lines", "overlay"] {
        let row = stderr
            .lines()
            .rev()
            .find(|l| l.split_whitespace().next() == Some(stage))
            .unwrap_or_else(|| panic!("{stage} in the stats: {stderr}"));
        let cycles: u64 = row.split_whitespace().nth(3).unwrap().parse().unwrap();
        assert!(cycles >= 1, "{stage} handled no frame: {row}");
    }
    assert!(!stderr.contains("failed"), "{stderr}");
}

#[test]
fn a_subgraph_used_twice_runs_each_copy_under_its_instance_id() {
    let root = common::repo_root();
    let path = example("subgraph/two_cameras");
    let output = kairos(&root, &["run", path.to_str().unwrap(), "--for", "2s", "--stats"]);
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    for instance in ["front", "rear"] {
        for stage in ["grey", "blur", "edges", "lines", "overlay"] {
            let id = format!("{instance}/{stage}");
            assert!(common::stats_cycles(&stderr, &id) >= 1, "{id} handled no frame");
        }
    }
    // The exposed input feeds both inner inputs it names.
    assert!(stderr.contains("front_camera.image -> front/grey.in"), "{stderr}");
    assert!(
        stderr.contains("front_camera.image -> front/overlay.image"),
        "{stderr}"
    );
}

#[test]
fn a_subgraph_the_vision_pack_ships_is_used_as_its_type() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("edges.ron"),
        r#"Diagram(format: 1,
    components: [
        Component(id: "camera", type: "sensors.camera", properties: {"rate": 10.0}),
        Component(id: "outline", type: "vision.edges", properties: {"low": 40.0}),
    ],
    connections: [Connection(from: "camera.image", to: "outline.image")],
)"#,
    )
    .unwrap();
    let output = kairos(dir.path(), &["run", "edges.ron", "--for", "2s", "--stats"]);
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    for id in ["outline/grey", "outline/blur", "outline/canny"] {
        assert!(common::stats_cycles(&stderr, id) >= 1, "{id} handled no frame");
    }
    // A property it does not expose is refused at the instance, naming those it does.
    let refused = std::fs::read_to_string(dir.path().join("edges.ron"))
        .unwrap()
        .replace(r#""low": 40.0"#, r#""lo": 40.0"#);
    std::fs::write(dir.path().join("edges.ron"), refused).unwrap();
    let output = kairos(dir.path(), &["validate", "edges.ron"]);
    let (_, stderr) = text(&output);
    assert!(
        stderr.contains("subgraph 'vision.edges' exposes no property 'lo' (it exposes blur, high, low)"),
        "{stderr}"
    );
}

#[test]
fn a_recorder_inside_a_subgraph_records_under_flat_names_and_the_replay_plays_them() {
    let dir = tempfile::tempdir().unwrap();
    // A sensor rig as a subgraph: an IMU recorded where it is, its output exposed too.
    std::fs::write(
        dir.path().join("rig.ron"),
        r#"Diagram(format: 1,
    exposes: Exposes(outputs: {"imu": "imu.imu"}, properties: {"file": "recorder.path"}),
    components: [
        Component(id: "imu", type: "sensors.imu"),
        Component(id: "recorder", type: "recording.recorder"),
    ],
    connections: [Connection(from: "imu.imu", to: "recorder.in1")],
)"#,
    )
    .unwrap();
    std::fs::write(
        dir.path().join("car.ron"),
        r#"Diagram(format: 1,
    components: [Component(id: "front", type: "rig.ron", properties: {"file": "front.mcap"})],
)"#,
    )
    .unwrap();
    let output = kairos(dir.path(), &["run", "car.ron", "--for", "1s"]);
    assert!(output.status.success(), "{}", text(&output).1);
    let output = kairos(dir.path(), &["inspect", "front.mcap"]);
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    assert!(
        stdout.contains("front/imu.imu"),
        "the topic is the flat output's name: {stdout}"
    );
    // Replayed, the player names its output after that topic.
    std::fs::write(
        dir.path().join("replay.ron"),
        r#"Diagram(format: 1,
    components: [
        Component(id: "player", type: "recording.player", properties: {"path": "front.mcap"}),
        Component(id: "log", type: "core.console"),
    ],
    connections: [Connection(from: "player.front_imu_imu", to: "log.in")],
)"#,
    )
    .unwrap();
    let output = kairos(dir.path(), &["run", "replay.ron", "--stats"]);
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    assert!(common::stats_cycles(&stderr, "log") >= 1, "{stderr}");
}

#[test]
fn a_fault_inside_a_subgraph_is_reported_inside_and_at_each_instance() {
    let dir = tempfile::tempdir().unwrap();
    let pipeline = std::fs::read_to_string(example("subgraph/lane_pipeline"))
        .unwrap()
        .replace("\"vision.canny\"", "\"vision.cany\"");
    std::fs::write(dir.path().join("lane_pipeline.ron"), pipeline).unwrap();
    let cameras = std::fs::read_to_string(example("subgraph/two_cameras")).unwrap();
    std::fs::write(dir.path().join("two_cameras.ron"), &cameras).unwrap();
    let output = kairos(dir.path(), &["validate", "two_cameras.ron"]);
    let (_, stderr) = text(&output);
    assert!(!output.status.success());
    for instance in ["front", "rear"] {
        assert!(
            stderr.contains(&format!(
                "error: unknown component type 'vision.cany' for '{instance}/edges'"
            )),
            "{stderr}"
        );
        assert!(
            stderr.contains(&format!(
                "note: '{instance}/edges' is written at lane_pipeline.ron:33:17"
            )),
            "{stderr}"
        );
    }
    // A subgraph that uses the diagram using it is refused, named at its place.
    std::fs::write(
        dir.path().join("lane_pipeline.ron"),
        r#"Diagram(format: 1, components: [Component(id: "back", type: "two_cameras.ron")])"#,
    )
    .unwrap();
    let output = kairos(dir.path(), &["run", "two_cameras.ron", "--for", "1s"]);
    let (_, stderr) = text(&output);
    assert!(!output.status.success());
    assert!(
        stderr.contains("subgraph 'two_cameras.ron' includes itself: two_cameras.ron → lane_pipeline.ron → two_cameras.ron"),
        "{stderr}"
    );
    assert!(stderr.contains("--> two_cameras.ron:13:19"), "{stderr}");
}

#[test]
fn hello_prints_the_amplified_sine() {
    let dir = tempfile::tempdir().unwrap();
    let path = example("hello");
    let output = kairos(
        dir.path(),
        &[
            "run",
            path.to_str().unwrap(),
            "--for",
            "1500ms",
            "--stats",
            "--set",
            "console1.every=1",
        ],
    );
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    let values: Vec<f64> = stdout
        .lines()
        .filter(|l| l.starts_with("console1:"))
        .filter_map(|l| l.rsplit(' ').next()?.parse().ok())
        .collect();
    // About 150 lines at 100 Hz on a fast machine; the content is what is checked.
    assert!(!values.is_empty(), "no value printed:\n{stdout}");
    // gain 2.5 × sine of amplitude 1: every value lies within ±2.5 and the wave leaves ±1.
    assert!(values.iter().all(|v| v.abs() <= 2.5 + 1e-9), "{values:?}");
    assert!(
        values.iter().any(|v| v.abs() > 1.0),
        "the gain was not applied: {values:?}"
    );
    // The final statistics table names both links and their counts balance.
    assert!(stderr.contains("sine1.out -> gain1.in"), "{stderr}");
    assert!(stderr.contains("=== final"), "{stderr}");
}

#[test]
fn the_grouped_900_example_runs_its_chains_in_100_threads_and_says_so_in_its_statistics() {
    let dir = tempfile::tempdir().unwrap();
    let path = example("scale/grouped_900");
    let output = kairos(
        dir.path(),
        &["run", path.to_str().unwrap(), "--for", "1s", "--stats"],
    );
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    let final_table = stderr.rsplit("=== final").next().unwrap_or_default();
    // The group table: one row per chain, its nine members, in the order of its links.
    assert!(final_table.contains("passes/s"), "{final_table}");
    let row = final_table
        .lines()
        .find(|line| line.starts_with("chain00 "))
        .unwrap_or_else(|| panic!("no row for chain00:\n{final_table}"));
    assert_eq!(row.split_whitespace().nth(1), Some("9"), "{row}");
    assert!(!final_table.contains("FAILED"), "{final_table}");
}

fn csv_rows(path: &std::path::Path) -> (Vec<String>, Vec<Vec<String>>) {
    let content = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = content.lines();
    let header = lines
        .next()
        .unwrap_or_default()
        .split(',')
        .map(str::to_owned)
        .collect();
    let rows = lines.map(|l| l.split(',').map(str::to_owned).collect()).collect();
    (header, rows)
}

/// Runs example `name` for 2 s with its CSV writer `csv` redirected into a temporary folder, and returns the
/// CSV's header and rows.
fn run_to_csv(name: &str) -> (Vec<String>, Vec<Vec<String>>) {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join(format!("{name}.csv"));
    let set = format!("csv.path={}", csv.display());
    let path = example(name);
    let output = kairos(
        dir.path(),
        &["run", path.to_str().unwrap(), "--for", "2s", "--set", &set],
    );
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    csv_rows(&csv)
}

/// Runs the lane-keeping showcase headless in simulated time as fast as it computes, its CSV in `csv`.
fn lane_keeping_to(csv: &std::path::Path) -> String {
    let set = format!("csv.path={}", csv.display());
    let path = example("sim/lane_keeping");
    let output = kairos(
        &common::repo_root(),
        &[
            "run",
            path.to_str().unwrap(),
            "--set",
            "vehicle.time_scale=0",
            "--set",
            &set,
        ],
    );
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    stderr
}

#[test]
fn lane_keeping_in_closed_loop_holds_the_lane_centre_and_runs_the_same_twice() {
    let dir = tempfile::tempdir().unwrap();
    let (first, second) = (dir.path().join("first.csv"), dir.path().join("second.csv"));
    let log = lane_keeping_to(&first);
    assert!(log.contains("simulation over after 60.0 s"), "{log}");
    assert!(log.contains("0 lane departures, 0 collisions"), "{log}");
    assert!(!log.contains("failed"), "{log}");
    let (header, rows) = csv_rows(&first);
    assert_eq!(header.last().map(String::as_str), Some("value"), "{header:?}");
    // 0 to 60 simulated seconds at the vehicle's 100 Hz, stamped in simulated time from its start time.
    assert_eq!(rows.len(), 6001);
    let stamps: Vec<i64> = rows.iter().map(|r| r[1].parse().unwrap()).collect();
    assert_eq!(stamps[0], 1_767_225_600_000_000_000);
    assert!(stamps.windows(2).all(|w| w[1] - w[0] == 10_000_000));
    let errors: Vec<f64> = rows.iter().map(|r| r.last().unwrap().parse().unwrap()).collect();
    let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
    let worst = errors.iter().fold(0.0_f64, |m, e| m.max(e.abs()));
    assert!(rms <= 0.3, "lateral error RMS {rms:.3} m");
    assert!(
        worst < 0.85,
        "largest lateral error {worst:.3} m: a wheel on the line"
    );
    // Simulated time in one thread: the same run again is the same file, byte for byte.
    lane_keeping_to(&second);
    assert_eq!(std::fs::read(&first).unwrap(), std::fs::read(&second).unwrap());
}

#[test]
fn a_simulator_from_pypi_is_driven_by_a_policy_to_the_hilltop() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("mountain_car.csv");
    let set = format!("csv.path={}", csv.display());
    let path = example("sim/gym_mountain_car");
    let output = kairos(
        dir.path(),
        &["run", path.to_str().unwrap(), "--for", "8s", "--set", &set],
    );
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    // The textbook policy reaches the goal in about 80 to 110 steps: at 30 steps a second, twice at least.
    assert!(stderr.contains("episode 1: "), "{stderr}");
    assert!(stderr.contains("terminated (goal reached)"), "{stderr}");
    let (header, rows) = csv_rows(&csv);
    let column = |name: &str| header.iter().position(|h| h == name).unwrap();
    let (position, sim_time) = (column("in1.v0"), column("in2.value"));
    let highest = rows
        .iter()
        .map(|r| r[position].parse::<f64>().unwrap())
        .fold(f64::MIN, f64::max);
    assert!(highest >= 0.45, "the car never reached the hilltop: {highest}");
    // The environment's own time goes a step (1/30 s) a tick, beside the runtime clock's stamp.
    let times: Vec<f64> = rows.iter().map(|r| r[sim_time].parse().unwrap()).collect();
    assert!(times.len() > 150, "{} rows", times.len());
    assert!(times.windows(2).all(|w| {
        let steps = (w[1] - w[0]) * 30.0;
        steps > 0.5 && (steps - steps.round()).abs() < 1e-6
    }));
}

#[test]
fn a_simulator_in_its_own_process_is_bridged_over_udp_in_lock_step_with_both_times() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("bridge.csv");
    let free = || {
        std::net::UdpSocket::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port()
    };
    let (to_diagram, to_simulator) = (format!("127.0.0.1:{}", free()), format!("127.0.0.1:{}", free()));
    let path = example("sim/gym_over_udp");
    let mut diagram = std::process::Command::new(env!("CARGO_BIN_EXE_kairos"))
        .args(["run", path.to_str().unwrap(), "--for", "6s"])
        .args(["--set", &format!("csv.path={}", csv.display())])
        .args(["--set", &format!("from_sim.address={to_diagram}")])
        .args(["--set", &format!("to_sim.destination={to_simulator}")])
        .current_dir(dir.path())
        .env("RUST_LOG", "info")
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let log = once_running(&mut diagram);
    // The Python worker of the policy starts with the diagram; give it a moment before the first frame.
    std::thread::sleep(std::time::Duration::from_secs(2));
    let simulator = std::process::Command::new("python3")
        .arg(common::repo_root().join("examples/sim/bridge/udp_mountain_car.py"))
        .args(["--to", &to_diagram, "--listen", &to_simulator, "--episodes", "2"])
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&simulator.stdout).into_owned();
    let complaints = String::from_utf8_lossy(&simulator.stderr).into_owned();
    assert!(simulator.status.success(), "{said}{complaints}");
    assert_eq!(said.matches("terminated (goal reached)").count(), 2, "{said}");
    let _ = diagram.wait();
    let log = log.join().unwrap();
    let (header, rows) = csv_rows(&csv);
    assert_eq!(
        &header[..4],
        ["input", "timestamp_ns", "time_of_issue_ns", "sequence"],
        "{log}"
    );
    assert!(rows.len() > 150, "{} rows: {log}", rows.len());
    // Each observation keeps both times: the simulation's as its timestamp, a step (1/30 s) apart from a
    // fixed start, and the wall clock's when it was sent as its time of issue.
    for row in &rows {
        let (stamp, issued, sequence): (i64, i64, i64) = (
            row[1].parse().unwrap(),
            row[2].parse().unwrap(),
            row[3].parse().unwrap(),
        );
        assert_eq!(
            stamp,
            1_767_225_600_000_000_000 + sequence * 33_333_333,
            "{row:?}"
        );
        assert!(issued > 1_790_000_000_000_000_000, "{row:?}");
    }
}

#[test]
fn camera_latency_reaches_the_csv() {
    let (header, rows) = run_to_csv("camera");
    assert_eq!(
        header,
        ["input", "timestamp_ns", "time_of_issue_ns", "sequence", "value"]
    );
    // 30 Hz subsampled by 3 for 2 s: about 20 rows, never more than 25 (the subsampling holds).
    assert!((1..=25).contains(&rows.len()), "{} rows", rows.len());
    for row in &rows {
        let timestamp: i64 = row[1].parse().unwrap();
        let issued: i64 = row[2].parse().unwrap();
        let latency_ms: f64 = row[4].parse().unwrap();
        assert!(issued >= timestamp, "time of issue before timestamp: {row:?}");
        assert!(latency_ms > 0.0 && latency_ms < 1000.0, "{row:?}");
    }
    let sequences: Vec<u64> = rows.iter().map(|r| r[3].parse().unwrap()).collect();
    assert_eq!(sequences, (0..rows.len() as u64).collect::<Vec<_>>());
}

#[test]
fn fusion_matches_imu_and_gnss_by_timestamp() {
    let (header, rows) = run_to_csv("fusion");
    let imu_ts = header.iter().position(|h| h == "in1.timestamp_ns").unwrap();
    let gnss_ts = header.iter().position(|h| h == "in2.timestamp_ns").unwrap();
    assert!(
        header.contains(&"in1.acc_z".to_owned()) && header.contains(&"in2.latitude_deg".to_owned()),
        "{header:?}"
    );
    // GNSS at 10 Hz for 2 s: about 20 matched pairs (never more than 22), each within the 5 ms tolerance.
    assert!((1..=22).contains(&rows.len()), "{} rows", rows.len());
    for row in &rows {
        let a: i64 = row[imu_ts].parse().unwrap();
        let b: i64 = row[gnss_ts].parse().unwrap();
        assert!(
            (a - b).abs() <= 5_000_000,
            "pair {} ms apart",
            (a - b) as f64 / 1e6
        );
    }
}

#[test]
fn image_sequence_plays_the_folder_at_the_times_in_the_names_and_loops() {
    let output = kairos(
        &common::repo_root(),
        &[
            "run",
            example("image_sequence").to_str().unwrap(),
            "--for",
            "4s",
            "--set",
            "console1.every=1",
        ],
    );
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    // Each image is stamped with the time its name gives (t=SECONDS.NANOSECONDS on the console).
    let stamps: Vec<f64> = stdout
        .lines()
        .filter(|l| l.contains("Image(160x120 Rgb8)"))
        .map(|l| {
            let stamp = l.split_whitespace().find_map(|field| field.strip_prefix("t="));
            stamp
                .and_then(|s| s.parse().ok())
                .unwrap_or_else(|| panic!("no time in {l}"))
        })
        .collect();
    // 20 images at 10 Hz (2 s), then the loop goes on: more than 20 images, however long a slow machine
    // took to show them.
    assert!(stamps.len() > 20, "{} images: {stdout}", stamps.len());
    // A tenth of a second apart, as their names say, across the loop too.
    for pair in stamps.windows(2) {
        let apart_ms = (pair[1] - pair[0]) * 1e3;
        assert!(
            (90.0..=110.0).contains(&apart_ms),
            "{apart_ms:.1} ms apart: {stdout}"
        );
    }
}

#[test]
fn gnss_replay_prints_a_fix_a_second_at_the_receivers_timing() {
    let output = kairos(
        &common::repo_root(),
        &["run", example("gnss_replay").to_str().unwrap(), "--for", "2500ms"],
    );
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    let fixes: Vec<&str> = stdout.lines().filter(|l| l.contains("lat 48.71")).collect();
    // At t = 0, 1 and 2 s: the file holds a minute of them, but they come at the receiver's timing.
    assert!((1..=3).contains(&fixes.len()), "{stdout}{stderr}");
    assert!(fixes.iter().all(|l| l.contains("(Differential)")), "{stdout}");
    // A second apart, not as fast as the file reads: each is stamped when it came (t=SECONDS.NANOSECONDS),
    // no earlier than its second; a slow machine may only make one late.
    let stamps: Vec<f64> = fixes
        .iter()
        .map(|l| {
            let stamp = l.split_whitespace().find_map(|field| field.strip_prefix("t="));
            stamp
                .and_then(|s| s.parse().ok())
                .unwrap_or_else(|| panic!("no time in {l}"))
        })
        .collect();
    for pair in stamps.windows(2) {
        assert!(
            pair[1] - pair[0] > 0.5,
            "fixes {:.3} s apart: {stdout}",
            pair[1] - pair[0]
        );
    }
}

/// Starts `kairos run` for `duration` on a diagram in `dir` whose `gnss.nmea` listens on a free UDP port
/// of loopback and prints its fixes; returns the process and the port.
fn gnss_on_udp(dir: &std::path::Path, duration: &str) -> (std::process::Child, u16) {
    gnss_on_udp_printing(dir, duration, "fix", &[])
}

/// As [`gnss_on_udp`], printing the receiver's output `printed`, with `extra` arguments to `kairos run`.
fn gnss_on_udp_printing(
    dir: &std::path::Path,
    duration: &str,
    printed: &str,
    extra: &[&str],
) -> (std::process::Child, u16) {
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let diagram = dir.join("udp.ron");
    std::fs::write(
        &diagram,
        format!(
            r#"Diagram(
    format: 1,
    packs: [Pack(name: "core", version: "^0.1"), Pack(name: "gnss", version: "^0.1")],
    components: [
        Component(id: "gnss", type: "gnss.nmea", properties: {{"source": "udp", "address": "127.0.0.1:{port}"}}),
        Component(id: "print", type: "core.console"),
    ],
    connections: [Connection(from: "gnss.{printed}", to: "print.in")],
)"#
        ),
    )
    .unwrap();
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_kairos"))
        .args(["run", diagram.to_str().unwrap(), "--for", duration])
        .args(extra)
        .current_dir(dir)
        .env("RUST_LOG", "info")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    (child, port)
}

/// Waits until the runtime `child` says it runs (its diagram started: `running ...` on its standard
/// error), at most 30 s, or until it ends; returns the thread gathering its standard error, to join for
/// the text once the child has ended.
fn once_running(child: &mut std::process::Child) -> std::thread::JoinHandle<String> {
    use std::io::BufRead as _;
    let stderr = child.stderr.take().unwrap();
    let (running_tx, running_rx) = std::sync::mpsc::channel();
    let gathering = std::thread::Builder::new()
        .name("kairos stderr".to_owned())
        .spawn(move || {
            let mut gathered = String::new();
            for line in std::io::BufReader::new(stderr).lines().map_while(Result::ok) {
                if line.contains("running ") {
                    // The test may have stopped waiting: nobody to tell then.
                    let _ = running_tx.send(());
                }
                gathered.push_str(&line);
                gathered.push('\n');
            }
            gathered
        })
        .unwrap();
    // Also over at once when the child ends without running: its standard error then says why.
    let _ = running_rx.recv_timeout(std::time::Duration::from_secs(30));
    gathering
}

#[test]
fn a_gnss_receiver_on_udp_takes_sentences_from_another_process() {
    let dir = tempfile::tempdir().unwrap();
    let (mut child, port) = gnss_on_udp(dir.path(), "5s");
    let sentences = std::fs::read_to_string(common::repo_root().join("examples/data/drive.nmea")).unwrap();
    let sender = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    // Until the runtime runs, then a second of sentences.
    let stderr = once_running(&mut child);
    for datagram in sentences.lines().collect::<Vec<_>>().chunks(3).take(10) {
        sender
            .send_to(datagram.join("\r\n").as_bytes(), ("127.0.0.1", port))
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    let output = child.wait_with_output().unwrap();
    let (stdout, _) = text(&output);
    let stderr = stderr.join().unwrap();
    assert!(output.status.success(), "{stderr}");
    let fixes = stdout.lines().filter(|l| l.contains("lat 48.71")).count();
    // A fix a datagram; the first may come before the receiver's socket is open.
    assert!((1..=10).contains(&fixes), "{fixes} fixes: {stdout}{stderr}");
}

#[test]
fn sentences_that_arrive_with_the_one_that_sets_the_clock_are_stamped_on_its_time() {
    let dir = tempfile::tempdir().unwrap();
    let (mut child, port) = gnss_on_udp_printing(dir.path(), "2s", "sentence", &["--clock-source", "gnss"]);
    let sentences = std::fs::read_to_string(common::repo_root().join("examples/data/drive.nmea")).unwrap();
    // RMC (its time steps the clock from the machine's to 2026-11-25 10:00 UTC while the runtime waits for
    // its clock source's first time), GGA and GSV (no time of its own) in one datagram, from the start
    // (the first may come before the receiver's socket is open), ten a second.
    let sending = std::thread::Builder::new()
        .name("nmea sender".to_owned())
        .spawn(move || {
            let sender = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
            for datagram in sentences.lines().collect::<Vec<_>>().chunks(3).take(30) {
                sender
                    .send_to(datagram.join("\r\n").as_bytes(), ("127.0.0.1", port))
                    .unwrap();
                std::thread::sleep(std::time::Duration::from_millis(100));
            }
        });
    let stderr = once_running(&mut child);
    sending.unwrap().join().unwrap();
    let output = child.wait_with_output().unwrap();
    let (stdout, _) = text(&output);
    let stderr = stderr.join().unwrap();
    assert!(output.status.success(), "{stderr}");
    let stamps: Vec<(f64, &str)> = stdout
        .lines()
        .filter_map(|l| {
            let time = l.split("t=").nth(1)?.split_whitespace().next()?.parse().ok()?;
            Some((time, l))
        })
        .collect();
    assert!(stamps.iter().any(|(_, l)| l.contains("GSV")), "{stdout}{stderr}");
    // Every sentence on the receiver's time, the GSV that came after the stepping RMC too, none going back.
    for (time, line) in &stamps {
        assert!(
            (1_795_600_799.0..1_795_600_900.0).contains(time),
            "{line}\n{stdout}"
        );
    }
    assert!(stamps.windows(2).all(|w| w[1].0 >= w[0].0), "{stdout}");
}

#[test]
fn two_runtimes_exchange_sentences_over_udp_through_the_socket_components() {
    let dir = tempfile::tempdir().unwrap();
    // Long enough for the sending runtime to start and play its 2.5 s, even on a slow machine.
    let (mut listening, port) = gnss_on_udp(dir.path(), "10s");
    // Until the receiving runtime runs.
    let stderr = once_running(&mut listening);
    let destination = format!("sender.destination=127.0.0.1:{port}");
    let sending = kairos(
        &common::repo_root(),
        &[
            "run",
            example("udp_link").to_str().unwrap(),
            "--for",
            "2500ms",
            "--set",
            &destination,
        ],
    );
    assert!(sending.status.success(), "{}", text(&sending).1);
    let output = listening.wait_with_output().unwrap();
    let (stdout, _) = text(&output);
    let stderr = stderr.join().unwrap();
    let fixes = stdout.lines().filter(|l| l.contains("lat 48.71")).count();
    // A fix a second for 2.5 s: at 0, 1 and 2 s (the first may come before the receiver's socket is open).
    assert!((1..=3).contains(&fixes), "{fixes} fixes: {stdout}{stderr}");
}

#[test]
fn can_replay_decodes_the_log_into_signals_with_units() {
    let output = kairos(
        &common::repo_root(),
        &[
            "run",
            example("can_replay").to_str().unwrap(),
            "--for",
            "1500ms",
            "--set",
            "console1.every=1",
        ],
    );
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    let engine = stdout.lines().filter(|l| l.contains("Engine: Speed = ")).count();
    let wheels = stdout
        .lines()
        .filter(|l| l.contains("Wheels: FrontLeft = "))
        .count();
    // 100 engine frames a second, 50 wheel frames: about 150 and 75 in 1.5 s, never more than the log's
    // timing allows, and the stop reaching the reader up to 50 ms late on a loaded machine (153 seen).
    assert!(
        (1..=157).contains(&engine) && (1..=80).contains(&wheels),
        "{engine} {wheels}: {stdout}"
    );
    assert!(
        stdout.contains("Temperature = 85 degC; Throttle = 20 %"),
        "{stdout}"
    );
}
