//! A diagram over several hosts through the real binaries: `kairos deploy` splitting it, links between
//! hosts over Zenoh, packs shipped, hosts lost and back, `kairos status`, and a runtime coordinating a
//! spread diagram for its client as the studio's Run does.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

mod common;
mod serving;

use common::{repo_root, text};
use serde_json::{Value, json};
use serving::{
    RoundTrip, Server, call, csv_values, deploy_in_background, folders, free_tcp_port, interrupt, now_ns,
    operator, samples_after_then_stop, serve, serve_on, serve_with_env, shared_machine, state,
    two_host_diagram, wait_for_log,
};
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};
use tungstenite::Message;

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
    if link["received"].as_u64().unwrap() > 0 {
        // One machine, one clock: a time in transit that is no less than nothing and well under a second.
        let transit = link["transit_p50_ns"]
            .as_i64()
            .expect("the time in transit, once samples came");
        assert!((0..1_000_000_000).contains(&transit), "{link}");
    }
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
fn deploy_runs_each_part_on_its_host_and_stops_them_all() {
    let _machine = shared_machine();
    let [dir_a, dir_b, here] = folders();
    let (a, b) = (serve(dir_a.path(), &[]), serve(dir_b.path(), &[]));
    std::fs::write(here.path().join("a.token"), &a.token).unwrap();
    std::fs::write(here.path().join("b.token"), &b.token).unwrap();
    let diagram = here.path().join("two_hosts.ron");
    // Host b's part runs in an execution group, with the group's thread settings shipped with it.
    let text_of_diagram = two_host_diagram(&a, &b.url)
        .replace(r#"host: "b""#, r#"host: "b", group: "on_b""#)
        .replace("packs: [],", r#"packs: [], groups: {"on_b": (affinity: [0])},"#);
    std::fs::write(&diagram, text_of_diagram).unwrap();
    let deployed = common::kairos(
        here.path(),
        &["deploy", diagram.to_str().unwrap(), "--for", "1500ms"],
    );
    let (_, stderr) = text(&deployed);
    assert!(deployed.status.success(), "{stderr}");
    assert!(stderr.contains("host 'a' started its part"), "{stderr}");
    let mut on_b = operator(&b);
    let deployed_on_b = call(&mut on_b, &json!({"id": 7, "type": "get_diagram"}));
    let part_text = deployed_on_b["result"]["diagram"].as_str().unwrap_or_default();
    assert!(
        part_text.contains(r#"group: "on_b""#) && part_text.contains("affinity: [0]"),
        "{deployed_on_b}"
    );
    // Each part ran where it was placed: its CSV is in that host's folder.
    for (folder, file) in [(&dir_a, "a.csv"), (&dir_b, "b.csv"), (&here, "here.csv")] {
        let rows = std::fs::read_to_string(folder.path().join(file)).unwrap_or_default();
        assert!(
            rows.lines().count() > 1,
            "{file}: no row after the header: {rows:?}\n{stderr}"
        );
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
    assert!(!stderr.contains("delivers nothing"), "{stderr}");
    let written_on_a: std::collections::BTreeMap<i64, f64> =
        csv_values(&dir_a.path().join("a.csv")).into_iter().collect();
    let received_here = csv_values(&here.path().join("here.csv"));
    assert!(!received_here.is_empty(), "no row here\n{stderr}");
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
    // How many were still in flight when everything stopped depends on the machine's speed: the
    // benchmarks measure the latency, this test what arrived.
}

#[test]
fn a_killed_host_is_reported_within_a_second_and_restarted_gets_its_part_again_in_new_files_every_loss_counted()
 {
    let _machine = shared_machine();
    let [dir_a, dir_b, here] = folders();
    let b_listen = format!("127.0.0.1:{}", free_tcp_port());
    let a = serve(dir_a.path(), &[]);
    let mut b = serve_on(dir_b.path(), &b_listen, &[], &[]);
    std::fs::write(here.path().join("a.token"), &a.token).unwrap();
    std::fs::write(here.path().join("b.token"), &b.token).unwrap();
    // A counter on host a, through host b (which writes it too) and back here, no consumer skipping.
    let diagram = format!(
        r#"Diagram(format: 1,
            hosts: {{
                "a": Host(endpoint: "{}", token_file: "a.token", zenoh: "tcp/127.0.0.1:{}"),
                "b": Host(endpoint: "{}", token_file: "b.token", zenoh: "tcp/127.0.0.1:{}"),
            }},
            components: [
                Component(id: "count", type: "core.counter", host: "a", properties: {{"rate": 100.0}}),
                Component(id: "gain", type: "core.gain", host: "b", properties: {{"gain": 1.0}}),
                Component(id: "csv_b", type: "core.csv_writer", host: "b", properties: {{"path": "b.csv"}}),
                Component(id: "csv_here", type: "core.csv_writer", properties: {{"path": "here.csv"}}),
            ],
            connections: [
                Connection(from: "count.out", to: "gain.in", policy: NeverSkipping),
                Connection(from: "gain.out", to: "csv_b.in1", policy: NeverSkipping),
                Connection(from: "gain.out", to: "csv_here.in1", policy: NeverSkipping),
            ])"#,
        a.url,
        free_tcp_port(),
        b.url,
        free_tcp_port()
    );
    let path = here.path().join("linked.ron");
    std::fs::write(&path, diagram).unwrap();
    let log = here.path().join("deploy.log");
    // Stopped as Ctrl-C stops it once the samples are back: the --for only bounds a run gone wrong.
    let mut deploying =
        deploy_in_background(None, here.path(), &[path.to_str().unwrap(), "--for", "60s"], &log);
    wait_for_log(&log, "host 'b' started its part", Duration::from_secs(30));
    // Killed once b has written a second's worth: waited for rather than slept, since a loaded
    // machine writes fewer rows in a fixed time.
    let b_csv = dir_b.path().join("b.csv");
    let waiting = Instant::now();
    while csv_values(&b_csv).len() <= 100 {
        assert!(
            waiting.elapsed() < Duration::from_secs(20),
            "b.csv has {} rows after 20 s",
            csv_values(&b_csv).len()
        );
        std::thread::sleep(Duration::from_millis(50));
    }

    // Host b is killed (SIGKILL): named within a second, with the links it cuts; host a runs on.
    let _ = b.child.kill();
    let _ = b.child.wait();
    let reported = wait_for_log(&log, "host 'b' is lost", Duration::from_secs(3));
    assert!(reported < Duration::from_secs(1), "reported after {reported:?}");
    let content = std::fs::read_to_string(&log).unwrap();
    assert!(
        content.contains("links cut: count.out on host 'a' -> gain.in on host 'b', gain.out on host 'b' -> csv_here.in1 on this machine"),
        "{content}"
    );
    let mut socket = operator(&a);
    assert_eq!(state(&mut socket), "running");
    let first_life = csv_values(&dir_b.path().join("b.csv"));

    // It comes back: its part is deployed and started again, and samples flow here again.
    let returned_at = now_ns();
    b = serve_on(dir_b.path(), &b_listen, &[], &[]);
    wait_for_log(&log, "host 'b' is back", Duration::from_secs(30));
    std::thread::sleep(Duration::from_secs(1));
    let (after, content) =
        samples_after_then_stop(&mut deploying, &here.path().join("here.csv"), returned_at, &log);
    assert!(after >= 1, "no sample after host b returned\n{content}");
    assert!(
        content.contains("host 'b' is back after a restart: its part was deployed and started again"),
        "{content}"
    );
    if std::env::var_os("SHOW_LOG").is_some() {
        eprintln!("{content}");
    }
    // The file b wrote before it was killed is whole; its second life writes beside it, and says so.
    assert!(
        first_life.len() > 100,
        "{} rows before the kill",
        first_life.len()
    );
    let still = csv_values(&dir_b.path().join("b.csv"));
    assert!(still.len() >= first_life.len() && still[..first_life.len()] == first_life[..]);
    assert!(
        !csv_values(&dir_b.path().join("b-1.csv")).is_empty(),
        "no b-1.csv"
    );
    let b_log = std::fs::read_to_string(dir_b.path().join("serve.log")).unwrap_or_default();
    assert!(b_log.contains("b.csv exists and is kept: writing"), "{b_log}");

    // Back here, each value at most once, in order; every one missing counted lost on one of the two
    // links. Beyond those, counted lost: what b took with it after its last status (published every
    // 0.5 s, read every 0.25 s: at most 75 values at 100 Hz), and what the stop left in flight.
    let values: Vec<f64> = csv_values(&here.path().join("here.csv"))
        .into_iter()
        .map(|(_, value)| value)
        .collect();
    RoundTrip::of(values, &content).assert_every_missing_value_counted(100, &content);
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

#[test]
fn a_part_one_host_refuses_changes_no_host() {
    let _machine = shared_machine();
    let [dir_a, dir_b, here] = folders();
    let a = serve(dir_a.path(), &[]);
    let b = serve(dir_b.path(), &[]);
    std::fs::write(here.path().join("a.token"), &a.token).unwrap();
    std::fs::write(here.path().join("b.token"), &b.token).unwrap();
    // Host a runs a counter into a CSV file, deployed before.
    let mut socket = operator(&a);
    let running = r#"Diagram(format: 1, components: [
        Component(id: "count", type: "core.counter", properties: {"rate": 200.0}),
        Component(id: "csv", type: "core.csv_writer", properties: {"path": "kept.csv"}),
    ], connections: [Connection(from: "count.out", to: "csv.in1")])"#;
    serving::deploy_and_start(&mut socket, running);
    let deployed_before =
        call(&mut socket, &json!({"id": 2, "type": "get_diagram"}))["result"]["diagram"].clone();

    // A recording this machine has and host b has not (a relative path, from each one's folder).
    std::fs::write(
        here.path().join("record_here.ron"),
        r#"Diagram(format: 1, components: [
            Component(id: "sine", type: "core.sine"),
            Component(id: "recorder", type: "recording.recorder", properties: {"path": "rec.mcap", "min_free_mb": 0.0}),
        ], connections: [Connection(from: "sine.out", to: "recorder.in1")])"#,
    )
    .unwrap();
    let recorded = common::kairos(here.path(), &["run", "record_here.ron", "--for", "400ms"]);
    assert!(recorded.status.success(), "{:?}", text(&recorded));
    assert!(here.path().join("rec.mcap").is_file());
    let diagram = here.path().join("a_and_b.ron");
    std::fs::write(
        &diagram,
        format!(
            r#"Diagram(format: 1,
                hosts: {{"a": Host(endpoint: "{}", token_file: "a.token"), "b": Host(endpoint: "{}", token_file: "b.token")}},
                components: [
                    Component(id: "sine_a", type: "core.sine", host: "a"),
                    Component(id: "csv_a", type: "core.csv_writer", host: "a", properties: {{"path": "replaced.csv"}}),
                    Component(id: "player", type: "recording.player", host: "b", properties: {{"path": "rec.mcap"}}),
                ],
                connections: [Connection(from: "sine_a.out", to: "csv_a.in1")])"#,
            a.url, b.url
        ),
    )
    .unwrap();
    let refused = common::kairos(here.path(), &["deploy", diagram.to_str().unwrap(), "--for", "2s"]);
    let (_, stderr) = text(&refused);
    assert!(!refused.status.success(), "{stderr}");
    assert!(
        stderr.contains("host 'b' refused") && stderr.contains("no host was changed"),
        "{stderr}"
    );

    // Host a runs on what it ran, untouched: the same diagram, running, its file growing.
    assert_eq!(state(&mut socket), "running", "{stderr}");
    let deployed_after =
        call(&mut socket, &json!({"id": 3, "type": "get_diagram"}))["result"]["diagram"].clone();
    assert_eq!(deployed_after, deployed_before);
    let kept = dir_a.path().join("kept.csv");
    let before = csv_values(&kept).len();
    let waiting = Instant::now();
    while csv_values(&kept).len() <= before {
        assert!(
            waiting.elapsed() < Duration::from_secs(10),
            "host a's file stopped growing at {before} lines"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    assert!(
        !dir_a.path().join("replaced.csv").exists(),
        "nothing of the refused part ran on a"
    );
    let mut on_b = operator(&b);
    assert_eq!(
        state(&mut on_b),
        "empty",
        "host b was not given the part it refused"
    );
}

#[test]
fn a_host_another_deployment_takes_leaves_the_first_which_says_so() {
    let _machine = shared_machine();
    let [dir_a, here] = folders();
    let a = serve(dir_a.path(), &[]);
    std::fs::write(here.path().join("a.token"), &a.token).unwrap();
    let on_a = |csv: &str| {
        format!(
            r#"Diagram(format: 1,
                hosts: {{"a": Host(endpoint: "{}", token_file: "a.token")}},
                components: [
                    Component(id: "count", type: "core.counter", host: "a", properties: {{"rate": 100.0}}),
                    Component(id: "csv", type: "core.csv_writer", host: "a", properties: {{"path": "{csv}"}}),
                ],
                connections: [Connection(from: "count.out", to: "csv.in1")])"#,
            a.url
        )
    };
    std::fs::write(here.path().join("first.ron"), on_a("first.csv")).unwrap();
    std::fs::write(here.path().join("second.ron"), on_a("second.csv")).unwrap();
    let log = here.path().join("first.log");
    let mut first = deploy_in_background(None, here.path(), &["first.ron", "--for", "60s"], &log);
    wait_for_log(&log, "host 'a' started its part", Duration::from_secs(30));

    let second = common::kairos(here.path(), &["deploy", "second.ron", "--for", "1s"]);
    assert!(second.status.success(), "{:?}", text(&second));
    // The first deployment says the host left it, and neither deploys its part there again nor stops it.
    wait_for_log(&log, "host 'a' runs another diagram now", Duration::from_secs(3));
    let (status, content) = interrupt(&mut first, &log);
    assert!(
        !status.success(),
        "a deployment a host left ends in failure\n{content}"
    );
    assert!(
        content.contains("left this deployment during the run"),
        "{content}"
    );
    let mut socket = operator(&a);
    let deployed = call(&mut socket, &json!({"id": 2, "type": "get_diagram"}));
    assert!(
        deployed["result"]["diagram"]
            .as_str()
            .unwrap()
            .contains("second.csv"),
        "the second deployment's part stays on a: {deployed}"
    );
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
    assert!(!values.is_empty(), "no value on b\n{stderr}");
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
    assert!(!values.is_empty(), "no value on b\n{stderr}");
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
        if line.contains("clock locked") || started.elapsed() > Duration::from_secs(30) {
            assert!(
                stdout.contains(&format!("a ({}): empty, clock master", a.url)),
                "{stdout}"
            );
            break line;
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    assert!(
        line_of_b.contains("clock locked (follows master), error ") && line_of_b.contains("error bound ±"),
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
    let one = serving::status_text(here.path(), &a, dir_a.path());
    assert!(one.contains("runtime ("), "{one}");
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
    let deadline = Instant::now() + Duration::from_secs(30);
    let telemetry = loop {
        let status = call(&mut socket, &json!({"id": 4, "type": "status"}));
        let telemetry = status["result"]["telemetry"].clone();
        let link = &telemetry["cross_links"][0];
        let received = link["received"].as_u64().unwrap_or(0);
        assert!(
            received + link["lost"].as_u64().unwrap_or(0) <= link["sent"].as_u64().unwrap_or(0),
            "never more received or lost than sent: {link}"
        );
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
    let deadline = Instant::now() + Duration::from_secs(30);
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
    // Until a sample with the new gain is written here (at once on a fast machine), then stopped.
    let spread_csv = dir_coordinator.path().join("spread.csv");
    let deadline = Instant::now() + Duration::from_secs(30);
    while Instant::now() < deadline && csv_values(&spread_csv).iter().all(|(_, v)| v.abs() <= 2.0) {
        std::thread::sleep(Duration::from_millis(100));
    }
    let stopped = call(&mut socket, &json!({"id": 8, "type": "stop"}));
    assert_eq!(stopped["ok"], true, "{stopped}");
    let b_status = call(&mut b_socket, &json!({"id": 2, "type": "status"}));
    assert_ne!(b_status["result"]["state"], "running", "stop stops b: {b_status}");
    // Once the hosts' last statuses are in, the link's counts are final: every sample sent was received
    // or counted lost.
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let status = call(&mut socket, &json!({"id": 9, "type": "status"}));
        let link = status["result"]["telemetry"]["cross_links"][0].clone();
        let count = |key: &str| link[key].as_u64().unwrap_or(0);
        if count("sent") > 0 && count("sent") == count("received") + count("lost") {
            break;
        }
        assert!(Instant::now() < deadline, "counts never final: {link}");
        std::thread::sleep(Duration::from_millis(100));
    }
    let values = csv_values(&spread_csv);
    let largest = values.iter().map(|(_, v)| v.abs()).fold(0.0, f64::max);
    assert!(
        largest > 2.0,
        "the gain set on b through the coordinator applied: largest {largest} of {}",
        values.len()
    );
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
            let kairos_sdk_core::Payload::Image(image) =
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
    // About 20 in 2 s at 10 Hz on a fast machine; each one whole.
    assert!(frames >= 1, "no frame arrived ({summary:?})");
}

#[test]
fn a_subgraph_placed_on_a_host_runs_its_parts_there_flat() {
    let _machine = shared_machine();
    let [dir_a, dir_b, here] = folders();
    let (a, b) = (serve(dir_a.path(), &[]), serve(dir_b.path(), &[]));
    std::fs::write(here.path().join("a.token"), &a.token).unwrap();
    std::fs::write(here.path().join("b.token"), &b.token).unwrap();
    // A sine into a CSV, as a subgraph whose file name the CSV's path comes from.
    std::fs::write(
        here.path().join("logged_sine.ron"),
        r#"Diagram(format: 1,
    exposes: Exposes(properties: {"path": "csv.path"}),
    components: [
        Component(id: "sine", type: "core.sine"),
        Component(id: "csv", type: "core.csv_writer"),
    ],
    connections: [Connection(from: "sine.out", to: "csv.in1")],
)"#,
    )
    .unwrap();
    // One instance placed on host a from outside; on host b, the host is said inside a subgraph of
    // its own.
    std::fs::write(
        here.path().join("on_b.ron"),
        r#"Diagram(format: 1,
    exposes: Exposes(),
    components: [Component(id: "inner", type: "logged_sine.ron", host: "b", properties: {"path": "b.csv"})],
)"#,
    )
    .unwrap();
    let diagram = here.path().join("spread.ron");
    std::fs::write(
        &diagram,
        format!(
            r#"Diagram(format: 1,
    hosts: {{"a": Host(endpoint: "{}", token_file: "a.token"), "b": Host(endpoint: "{}", token_file: "b.token")}},
    components: [
        Component(id: "first", type: "logged_sine.ron", host: "a", properties: {{"path": "a.csv"}}),
        Component(id: "second", type: "on_b.ron"),
    ],
)"#,
            a.url, b.url
        ),
    )
    .unwrap();
    let deployed = common::kairos(
        here.path(),
        &["deploy", diagram.to_str().unwrap(), "--for", "1500ms"],
    );
    let (_, stderr) = text(&deployed);
    assert!(deployed.status.success(), "{stderr}");
    for (folder, file) in [(&dir_a, "a.csv"), (&dir_b, "b.csv")] {
        let rows = std::fs::read_to_string(folder.path().join(file)).unwrap_or_default();
        assert!(rows.lines().count() > 1, "{file}: no row: {rows:?}\n{stderr}");
    }
    // Each host was sent its part flat, the inner ids under their instances.
    let mut on_b = operator(&b);
    let part = call(&mut on_b, &json!({"id": 7, "type": "get_diagram"}));
    let part_text = part["result"]["diagram"].as_str().unwrap_or_default();
    assert!(part_text.contains(r#"id: "second/inner/csv""#), "{part}");
    assert!(
        !part_text.contains(".ron\""),
        "no subgraph left in the part: {part}"
    );
}
