//! The studio against a real runtime: it starts `kairos serve`, a diagram built in the interface is
//! deployed and run with the Run button, and the components' states come back on the nodes.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

mod common;

use std::time::{Duration, Instant};

use common::{context_menu_entry, kairos_binary};
use egui::{Pos2, Vec2};
use egui_kittest::Harness;
use egui_kittest::kittest::{NodeT as _, Queryable as _};
use kairos_studio::client::RuntimeClient;
use kairos_studio::local::LocalRuntime;
use kairos_studio::session::NodeState;
use kairos_studio::{Document, StudioApp};

fn run_until(harness: &mut Harness<'_, StudioApp>, what: &str, done: impl Fn(&StudioApp) -> bool) {
    let started = Instant::now();
    while !done(harness.state()) {
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "timed out waiting for {what}"
        );
        std::thread::sleep(Duration::from_millis(20));
        harness.run_steps(1);
    }
}

fn drag(harness: &mut Harness<'_, StudioApp>, from: Pos2, to: Pos2) {
    harness.hover_at(from);
    harness.run_steps(1);
    harness.drag_at(from);
    harness.run_steps(1);
    for step in 1..=8 {
        harness.hover_at(from + (to - from) * (step as f32 / 8.0));
        harness.run_steps(1);
    }
    harness.drop_at(to);
    harness.run_steps(2);
}

/// A studio on `document` driving a local runtime of this build, its window `size`, once connected.
fn studio_on_local_runtime(document: Document, size: Vec2) -> Harness<'static, StudioApp> {
    let local = LocalRuntime::start_binary(&kairos_binary()).unwrap();
    let client = RuntimeClient::connect(&local.url, Some(local.token.clone()), || {});
    let label = format!("local runtime {}", local.url);
    let app = StudioApp::new(
        document,
        kairos_diagram::LibraryInfo::default(),
        Some(client),
        label,
        Some(local),
    )
    .with_kairos_binary(kairos_binary());
    let mut harness = Harness::new_ui_state(|ui, app: &mut StudioApp| app.show(ui), app);
    harness.set_size(size);
    run_until(&mut harness, "the connection", StudioApp::is_connected);
    harness
}

#[test]
fn a_diagram_built_in_the_studio_runs_on_a_real_runtime_and_publishes_to_foxglove() {
    let mut harness = studio_on_local_runtime(Document::default(), Vec2::new(1280.0, 800.0));
    run_until(&mut harness, "the library", |app| {
        app.session.library.component("core.counter").is_some()
    });
    harness.run_steps(2);

    let from = harness.get_by_label("Counter").rect().center();
    drag(&mut harness, from, Pos2::new(500.0, 300.0));
    let from = harness.get_by_label("Console").rect().center();
    drag(&mut harness, from, Pos2::new(800.0, 300.0));
    let output = harness.get_by_label("output counter1.out (i64)").rect().center();
    let input = harness.get_by_label("input console1.in (any)").rect().center();
    let (output, input) = (
        harness.state().canvas.to_screen(output),
        harness.state().canvas.to_screen(input),
    );
    drag(&mut harness, output, input);
    assert_eq!(harness.state().session.document.diagram().connections.len(), 1);

    harness.get_by_label("Run").click();
    harness.run_steps(1);
    run_until(&mut harness, "both components running", |app| {
        app.node_state("counter1") == Some(&NodeState::Running)
            && app.node_state("console1") == Some(&NodeState::Running)
    });

    // The output's context menu publishes it live to Foxglove: the runtime starts its server on loopback.
    context_menu_entry(&mut harness, "output counter1.out (i64)", "Publish to Foxglove");
    run_until(&mut harness, "the output published to Foxglove", |app| {
        app.session.foxglove().outputs == ["counter1.out"] && app.session.foxglove().address.is_some()
    });
    let address = harness.state().session.foxglove().address.clone().unwrap();
    let listening = address.strip_prefix("ws://").unwrap();
    assert!(
        std::net::TcpStream::connect(listening).is_ok(),
        "Foxglove connects to {address}"
    );
    assert!(
        harness
            .state()
            .session
            .log
            .lines()
            .any(|l| l.text.contains("Foxglove: publishing counter1.out on ws://")),
        "the log says where to connect"
    );
    context_menu_entry(&mut harness, "output counter1.out (i64)", "Publish to Foxglove");
    run_until(&mut harness, "the output no longer published", |app| {
        app.session.foxglove().outputs.is_empty()
    });

    harness.get_by_label("Stop").click();
    harness.run_steps(1);
    run_until(
        &mut harness,
        "the stop",
        |app| matches!(app.node_state("counter1"), Some(NodeState::Waiting(state)) if state == "stopped"),
    );
}

#[test]
fn a_diagram_spread_over_hosts_runs_from_run_and_shows_each_host_and_link() {
    // Host b is a second runtime on this machine; the studio's own runtime coordinates.
    let b = LocalRuntime::start_binary(&kairos_binary()).unwrap();
    let folder = tempfile::tempdir().unwrap();
    std::fs::write(folder.path().join("b.token"), b.token.reveal()).unwrap();
    let zenoh_port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let path = folder.path().join("spread.ron");
    std::fs::write(
        &path,
        format!(
            r#"Diagram(format: 1,
                hosts: {{"b": Host(endpoint: "{}", token_file: "b.token", zenoh: "tcp/127.0.0.1:{zenoh_port}")}},
                components: [
                    Component(id: "sine", type: "core.sine", host: "b", position: (x: 0.0, y: 0.0)),
                    Component(id: "gain", type: "core.gain", position: (x: 300.0, y: 0.0)),
                ],
                connections: [Connection(from: "sine.out", to: "gain.in")])"#,
            b.url
        ),
    )
    .unwrap();
    let mut harness = studio_on_local_runtime(Document::open(&path).unwrap(), Vec2::new(1280.0, 800.0));
    harness.get_by_label("Run").click();
    harness.run_steps(1);
    run_until(&mut harness, "both parts running", |app| {
        app.node_state("sine") == Some(&NodeState::Running)
            && app.node_state("gain") == Some(&NodeState::Running)
    });
    run_until(&mut harness, "samples across the link", |app| {
        let (from, to) = (
            kairos_diagram::PortRef::new("sine", "out"),
            kairos_diagram::PortRef::new("gain", "in"),
        );
        app.session
            .monitor
            .cross_link(&from, &to)
            .is_some_and(|link| link.matched && link.received > 10 && link.from_host.as_deref() == Some("b"))
    });
    // The top bar names the host and its clock.
    harness.get_by_label("b: own clock");
    harness.get_by_label("Stop").click();
    harness.run_steps(1);
    run_until(
        &mut harness,
        "the stop on host b",
        |app| matches!(app.node_state("sine"), Some(NodeState::Waiting(state)) if state == "stopped"),
    );
}

#[test]
fn the_connect_dialog_connects_to_a_runtime_and_remembers_it() {
    let local = LocalRuntime::start_binary(&kairos_binary()).unwrap();
    let config = tempfile::tempdir().unwrap();
    let app = StudioApp::new(
        Document::default(),
        kairos_diagram::LibraryInfo::default(),
        None,
        "no runtime".to_owned(),
        None,
    )
    .with_config_dir(config.path().to_owned());
    let mut harness = Harness::new_ui_state(|ui, app: &mut StudioApp| app.show(ui), app);
    harness.set_size(Vec2::new(1280.0, 800.0));
    harness.run_steps(2);
    harness.get_by_label("File").click();
    harness.run_steps(2);
    harness.get_by_label("Connect to a runtime…").click();
    harness.run_steps(2);
    let address = harness.get_by_role_and_label(
        egui::accesskit::Role::TextInput,
        "Address of a `kairos serve` (ws://HOST:PORT, or wss:// over TLS):",
    );
    address.focus();
    harness.run_steps(1);
    harness.key_press_modifiers(egui::Modifiers::COMMAND, egui::Key::A);
    harness.run_steps(1);
    harness
        .get_by_role_and_label(
            egui::accesskit::Role::TextInput,
            "Address of a `kairos serve` (ws://HOST:PORT, or wss:// over TLS):",
        )
        .type_text(&local.url);
    harness.run_steps(1);
    let token_file = local.token_file().display().to_string();
    harness
        .get_by_role_and_label(
            egui::accesskit::Role::TextInput,
            "File holding its token (empty when it needs none):",
        )
        .focus();
    harness.run_steps(1);
    harness
        .get_by_role_and_label(
            egui::accesskit::Role::TextInput,
            "File holding its token (empty when it needs none):",
        )
        .type_text(&token_file);
    harness.run_steps(1);
    harness.get_by_label("Connect").click();
    harness.run_steps(1);
    run_until(&mut harness, "the connection", StudioApp::is_connected);
    let remembered = std::fs::read_to_string(config.path().join("studio-remotes.txt")).unwrap();
    assert_eq!(remembered, format!("{}\t{token_file}\t\n", local.url));
    assert!(
        !remembered.contains(local.token.reveal()),
        "the token itself is never written"
    );
}

/// Opens a viewer on `output` through its context menu on the canvas.
fn open_viewer(harness: &mut Harness<'_, StudioApp>, output: &str, menu_entry: &str) {
    context_menu_entry(harness, output, menu_entry);
}

#[test]
fn viewers_and_monitoring_show_a_running_diagram() {
    let example = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/sensors.ron");
    let mut harness = studio_on_local_runtime(Document::open(&example).unwrap(), Vec2::new(1400.0, 900.0));
    run_until(&mut harness, "the library", |app| {
        app.session.library.component("sensors.camera").is_some()
    });
    harness.run_steps(2);
    open_viewer(
        &mut harness,
        "output camera.image (image)",
        "Open a viewer (image)",
    );
    open_viewer(&mut harness, "output imu.imu (imu)", "Open a viewer (plot)");
    open_viewer(
        &mut harness,
        "output gnss.fix (gnss_fix)",
        "Open a viewer (GNSS track)",
    );
    open_viewer(&mut harness, "output counter.out (i64)", "Open a viewer (plot)");
    open_viewer(
        &mut harness,
        "output lidar.points (point_cloud)",
        "Open a viewer (3D point cloud)",
    );
    open_viewer(
        &mut harness,
        "output gnss.fix (gnss_fix)",
        "Open a viewer (latest samples)",
    );
    open_viewer(&mut harness, "output imu.pose (pose)", "Open a viewer (3D poses)");
    assert_eq!(harness.state().session.viewers.list.len(), 7);
    assert!(
        harness.state().uses_shared_memory(),
        "a local runtime hands viewer frames over in shared memory"
    );

    harness.get_by_label("Run").click();
    harness.run_steps(1);
    run_until(&mut harness, "every viewer's first samples", |app| {
        let list = &app.session.viewers.list;
        list[0].texture_size().is_some()
            && list[1].series().len() == 6
            && list[2].track().len() >= 3
            && list[3].series().first().is_some_and(|(_, n)| *n >= 10)
            && list[4].cloud_points() > 1000
            && list[5].rows().count() >= 3
            && list[6].cloud_points() > 93
    });
    let list = &harness.state().session.viewers.list;
    assert!(
        list[5].rows().all(|row| row.contains("latitude_deg")),
        "the table shows the fixes: {:?}",
        list[5].rows().next()
    );
    let list = &harness.state().session.viewers.list;
    assert_eq!(
        list[0].texture_size(),
        Some([320, 240]),
        "the camera's frames, full size"
    );
    assert!(
        list[1]
            .series()
            .iter()
            .any(|(name, _)| *name == "linear_acceleration.z")
    );
    // The simulated vehicle stays within a few kilometres of its reference point.
    assert!(
        list[2]
            .track()
            .iter()
            .all(|[e, n]| e.abs() < 5_000.0 && n.abs() < 5_000.0)
    );

    // The slow consumer's 4-sample FIFO overflows: the monitor counts the losses and raises a notice that
    // names the link.
    run_until(&mut harness, "the overflow on the canvas", |app| {
        app.session
            .monitor
            .links
            .get("counter.out -> slow.in")
            .is_some_and(|l| l.latest.overwritten > 0 && l.dropping())
    });
    run_until(&mut harness, "the overflow notice", |app| {
        app.session
            .monitor
            .recent_notices()
            .any(|n| n.starts_with("counter.out -> slow.in loses samples") && n.contains("lost so far"))
    });
    run_until(&mut harness, "the camera's cycle rate", |app| {
        app.session.monitor.components.get("camera").is_some_and(|c| {
            c.latest.state == kairos_protocol::ComponentState::Running && c.latest.cycle_rate_hz > 0.0
        })
    });

    harness.get_by_label("Stop").click();
    harness.run_steps(1);
}

/// The newcomer's first session, through the interface alone: an example opened from the empty canvas,
/// run, two viewers, a recording, its replay with the same viewers, saved, and opened again with them.
#[test]
fn a_newcomer_records_replays_saves_and_reopens_with_the_viewers() {
    // The examples offered: the repository's recording example, writing into a folder of the test's.
    let dir = tempfile::tempdir().unwrap();
    let examples = dir.path().join("examples");
    std::fs::create_dir(&examples).unwrap();
    let recording = dir.path().join("drive.mcap");
    let record = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/record.ron"),
    )
    .unwrap()
    .replace(
        "\"drive.mcap\"",
        &format!("{:?}", recording.display().to_string()),
    );
    std::fs::write(examples.join("record.ron"), record).unwrap();
    let local = LocalRuntime::start_binary(&kairos_binary()).unwrap();
    let client = RuntimeClient::connect(&local.url, Some(local.token.clone()), || {});
    let app = StudioApp::new(
        Document::default(),
        kairos_diagram::LibraryInfo::default(),
        Some(client),
        format!("local runtime {}", local.url),
        Some(local),
    )
    .with_kairos_binary(kairos_binary())
    .with_examples(&examples);
    let mut harness = Harness::builder()
        .with_size(Vec2::new(1400.0, 900.0))
        .build_ui_state(|ui, app: &mut StudioApp| app.show(ui), app);
    run_until(&mut harness, "the connection", StudioApp::is_connected);

    // Open an example → record.
    harness.get_by_label("Open an example").click();
    harness.run_steps(2);
    harness.get_by_label_contains("Record a simulated camera").click();
    harness.run_steps(2);
    run_until(&mut harness, "the example's library", |app| {
        app.session.document.diagram().components.len() == 4
            && app.session.library.component("sensors.camera").is_some()
    });
    harness.run_steps(2);
    open_viewer(
        &mut harness,
        "output camera.image (image)",
        "Open a viewer (image)",
    );
    open_viewer(&mut harness, "output imu.imu (imu)", "Open a viewer (plot)");

    // Run: the recorder records from the start, the viewers show the sensors.
    harness.get_by_label("Run").click();
    harness.run_steps(1);
    run_until(&mut harness, "the recording and the viewers", |app| {
        let list = &app.session.viewers.list;
        status(app, "recorder", "recording") == Some(serde_json::json!(true))
            && list[0].texture_size().is_some()
            && !list[1].series().is_empty()
    });
    let started = Instant::now();
    while started.elapsed() < Duration::from_secs(3) {
        std::thread::sleep(Duration::from_millis(20));
        harness.run_steps(1);
    }
    // The strip's Stop (the menu bar's comes first) closes the file; Replay is offered for it.
    harness.get_all_by_label("Stop").last().unwrap().click();
    harness.run_steps(1);
    run_until(&mut harness, "the file closed", |app| {
        status(app, "recorder", "last_file").is_some_and(|f| f.is_string())
    });
    harness.run_steps(2);
    // The menu bar's Stop: the whole diagram.
    harness.get_all_by_label("Stop").next().unwrap().click();
    harness.run_steps(2);
    harness.get_by_label("Replay").click();
    harness.run_steps(2);

    // The replay: a player on the file, the viewers on its outputs, not yet saved.
    let document = &harness.state().session.document;
    let player = document.diagram().component("player").unwrap();
    assert_eq!(player.type_name, "recording.player");
    assert_eq!(
        player.properties["path"],
        kairos_diagram::Value::Text(recording.display().to_string())
    );
    assert!(document.path().is_none() && document.is_dirty());
    let shown = |app: &StudioApp| -> Vec<(String, String)> {
        app.session
            .viewers
            .list
            .iter()
            .map(|v| (v.output.clone(), v.kind.key().to_owned()))
            .collect()
    };
    let replay_viewers = vec![
        ("player.camera_image".to_owned(), "image".to_owned()),
        ("player.imu_imu".to_owned(), "plot".to_owned()),
    ];
    assert_eq!(shown(harness.state()), replay_viewers);
    harness.get_by_label("Run").click();
    harness.run_steps(1);
    run_until(&mut harness, "the replayed frames in the viewers", |app| {
        let list = &app.session.viewers.list;
        list[0].texture_size() == Some([320, 240]) && list[1].series().len() == 6
    });
    // Viewers of the replay were opened while the recording's diagram was still deployed: nothing was
    // an error, and frames still come through shared memory.
    let errors: Vec<String> = harness
        .state()
        .session
        .log
        .lines()
        .filter(|l| l.level == kairos_protocol::LogLevel::Error)
        .map(|l| l.text.clone())
        .collect();
    assert!(errors.is_empty(), "{errors:?}");
    assert!(harness.state().uses_shared_memory());
    run_until(&mut harness, "the replay's end", |app| {
        status(app, "player", "held_at_end") == Some(serde_json::json!(true))
    });
    let duration = status(harness.state(), "player", "duration_s")
        .and_then(|d| d.as_f64())
        .unwrap();
    assert!(duration > 2.5, "a recording of {duration} s");

    // Saved, and opened again in a new studio: with its viewers.
    let saved = dir.path().join("replay.ron");
    harness.state_mut().session.save_as(&saved);
    // The menu bar's Stop: the whole diagram.
    harness.get_all_by_label("Stop").next().unwrap().click();
    harness.run_steps(2);
    let reopened = StudioApp::new(
        Document::open(&saved).unwrap(),
        kairos_diagram::LibraryInfo::default(),
        None,
        "no runtime (test)".to_owned(),
        None,
    );
    let reopened = Harness::new_ui_state(|ui, app: &mut StudioApp| app.show(ui), reopened);
    assert_eq!(shown(reopened.state()), replay_viewers);
}

/// A diagram using a subgraph twice, in the studio: each instance shows the ports its file exposes,
/// runs flat on the runtime, its exposed output is viewed and its exposed property changed live.
#[test]
fn a_subgraph_instance_shows_its_exposed_ports_runs_and_is_viewed_and_set_live() {
    let dir = tempfile::tempdir().unwrap();
    let examples = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/subgraph");
    for file in ["two_cameras.ron", "lane_pipeline.ron"] {
        std::fs::copy(examples.join(file), dir.path().join(file)).unwrap();
    }
    let document = Document::open(&dir.path().join("two_cameras.ron")).unwrap();
    let mut harness = studio_on_local_runtime(document, Vec2::new(1400.0, 900.0));
    run_until(&mut harness, "the subgraphs described", |app| {
        app.session
            .library
            .instances
            .get("front")
            .is_some_and(|info| info.outputs.len() == 2)
    });
    harness.run_steps(2);
    let front = harness.state().session.library.instances["front"].clone();
    let names = |ports: Vec<&str>| ports.join(" ");
    assert_eq!(
        names(front.inputs.iter().map(|i| i.name.as_str()).collect()),
        "image"
    );
    assert_eq!(
        names(front.outputs.iter().map(|o| o.name.as_str()).collect()),
        "lines out"
    );
    let properties: Vec<&str> = front.properties.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(properties, ["edge_high", "edge_low", "label"]);
    // On the canvas, with its ports and the camera's link into it.
    assert!(harness.query_by_label("output front.out (image)").is_some());
    assert!(harness.query_by_label("input front.image (image)").is_some());
    // The palette offers the subgraph beside the diagram, and those the packs ship; dropped, one is
    // one more instance.
    assert!(harness.query_by_label("Subgraphs (beside the diagram)").is_some());
    assert!(harness.query_by_label("Subgraphs (vision)").is_some());
    assert!(
        harness
            .state()
            .session
            .library
            .component("vision.edges")
            .is_some()
    );
    let from = harness.get_by_label("lane pipeline").rect().center();
    drag(&mut harness, from, Pos2::new(700.0, 600.0));
    let added = harness
        .state()
        .session
        .document
        .diagram()
        .component("lane_pipeline1")
        .map(|c| c.type_name.clone());
    assert_eq!(added.as_deref(), Some("lane_pipeline.ron"));
    run_until(&mut harness, "the new instance described", |app| {
        app.session.library.instances.contains_key("lane_pipeline1")
    });
    harness.key_press_modifiers(egui::Modifiers::COMMAND, egui::Key::Z);
    harness.run_steps(2);
    assert!(
        harness
            .state()
            .session
            .document
            .diagram()
            .component("lane_pipeline1")
            .is_none()
    );

    open_viewer(&mut harness, "output front.out (image)", "Open a viewer (image)");
    harness.get_by_label("Run").click();
    harness.run_steps(1);
    run_until(&mut harness, "the front pipeline's frames", |app| {
        app.session.viewers.list[0].texture_size() == Some([640, 480])
    });
    // Its node shows its parts' figures, rolled up: running, at the camera's rate.
    run_until(&mut harness, "the rolled-up figures", |app| {
        app.session.monitor.subgraphs.get("front").is_some_and(|f| {
            f.state == kairos_protocol::ComponentState::Running && f.cycle_rate_hz > 1.0 && f.cpu_share > 0.0
        })
    });
    assert_eq!(
        harness.state().session.node_state("rear"),
        Some(&NodeState::Running)
    );
    // Inside it, from the inspector: a viewer on an inner output, as the runtime names it.
    harness.state_mut().canvas.selected = ["front".to_owned()].into();
    harness.run_steps(2);
    harness.get_by_label("Inside").click();
    harness.run_steps(2);
    harness.get_by_label("edges.out").click();
    harness.run_steps(2);
    run_until(&mut harness, "the inner edges' frames", |app| {
        app.session
            .viewers
            .list
            .iter()
            .any(|v| v.output == "front/edges.out" && v.texture_size() == Some([640, 480]))
    });
    harness
        .state_mut()
        .session
        .set_property("front", "edge_low", kairos_diagram::Value::F64(30.0));
    let started = Instant::now();
    while started.elapsed() < Duration::from_millis(500) {
        std::thread::sleep(Duration::from_millis(20));
        harness.run_steps(1);
    }
    let errors: Vec<String> = harness
        .state()
        .session
        .log
        .lines()
        .filter(|l| l.level == kairos_protocol::LogLevel::Error)
        .map(|l| l.text.clone())
        .collect();
    assert!(errors.is_empty(), "{errors:?}");
    harness.get_all_by_label("Stop").next().unwrap().click();
    harness.run_steps(1);
}

/// The status a component publishes, from the latest telemetry.
fn status(app: &StudioApp, id: &str, key: &str) -> Option<serde_json::Value> {
    app.session
        .monitor
        .components
        .get(id)?
        .latest
        .status
        .as_ref()?
        .get(key)
        .cloned()
}

#[test]
fn the_timeline_pauses_seeks_and_plays_a_recording() {
    // A 4-second recording of the simulated sensors, made by the runtime itself.
    let dir = tempfile::tempdir().unwrap();
    let record = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/record.ron");
    let made = std::process::Command::new(kairos_binary())
        .current_dir(dir.path())
        .args(["run", record.to_str().unwrap(), "--for", "4s"])
        .output()
        .unwrap();
    assert!(made.status.success(), "{}", String::from_utf8_lossy(&made.stderr));
    let recording = dir.path().join("drive.mcap");
    let diagram = dir.path().join("replay.ron");
    std::fs::write(
        &diagram,
        format!(
            "Diagram(format: 1, packs: [Pack(name: \"recording\", version: \"^0.1\")], components: [\
             Component(id: \"player\", type: \"recording.player\", position: (x: 40.0, y: 40.0), \
             properties: {{\"path\": {:?}, \"at_end\": \"hold\"}})], connections: [])",
            recording.display().to_string()
        ),
    )
    .unwrap();

    let mut harness = studio_on_local_runtime(Document::open(&diagram).unwrap(), Vec2::new(1400.0, 900.0));
    // The player's outputs come from its recording: the runtime describes them to the studio.
    run_until(&mut harness, "the player's outputs", |app| {
        app.session
            .library
            .instances
            .get("player")
            .is_some_and(|info| info.outputs.len() >= 3)
    });
    harness.run_steps(2);
    assert!(harness.query_by_label("output player.imu_imu (imu)").is_some());

    harness.get_by_label("Run").click();
    harness.run_steps(1);
    run_until(&mut harness, "the timeline", |app| {
        status(app, "player", "playing") == Some(serde_json::json!(true))
    });
    harness.run_steps(2);
    // The menu bar has a Pause of its own (the whole diagram); the player's is the last one.
    harness.get_all_by_label("Pause").last().unwrap().click();
    harness.run_steps(1);
    run_until(&mut harness, "the pause", |app| {
        status(app, "player", "playing") == Some(serde_json::json!(false))
    });
    let duration = status(harness.state(), "player", "duration_s")
        .unwrap()
        .as_f64()
        .unwrap();
    assert!(duration > 3.0, "{duration}");

    // Drag along the timeline to three quarters of the recording: the player jumps there.
    let timeline = harness.get_by_label("timeline of player").rect();
    let bar_left = timeline.left() + 130.0_f32.min(timeline.width() * 0.3);
    let bar_right = timeline.right() - 6.0;
    let y = timeline.top() + 7.0;
    drag(
        &mut harness,
        Pos2::new(bar_left + 10.0, y),
        Pos2::new(bar_left + (bar_right - bar_left) * 0.75, y),
    );
    run_until(&mut harness, "the seek", |app| {
        status(app, "player", "position_s")
            .and_then(|p| p.as_f64())
            .is_some_and(|p| (p - duration * 0.75).abs() < 0.3)
    });
    // A plain click seeks too, even with its press and release in one slow frame.
    click_at(
        &mut harness,
        Pos2::new(bar_left + (bar_right - bar_left) * 0.25, y),
    );
    run_until(&mut harness, "the seek by a click", |app| {
        status(app, "player", "position_s")
            .and_then(|p| p.as_f64())
            .is_some_and(|p| (p - duration * 0.25).abs() < 0.3)
    });
    harness.get_by_label("Play").click();
    harness.run_steps(1);
    run_until(&mut harness, "the end of the replay", |app| {
        status(app, "player", "held_at_end") == Some(serde_json::json!(true))
    });
    // Held at its end (`at_end: hold`), the replay is sought back by a click and plays on from there.
    click_at(
        &mut harness,
        Pos2::new(bar_left + (bar_right - bar_left) * 0.5, y),
    );
    run_until(&mut harness, "a replay from half-way", |app| {
        status(app, "player", "held_at_end") == Some(serde_json::json!(false))
            && status(app, "player", "position_s")
                .and_then(|p| p.as_f64())
                .is_some_and(|p| p >= duration * 0.5 - 0.3 && p < duration - 0.2)
    });
    assert_eq!(
        status(harness.state(), "player", "ended"),
        Some(serde_json::json!(false))
    );
}

/// A press and release at `at` in one frame: a click as a slow frame sees it.
fn click_at(harness: &mut Harness<'_, StudioApp>, at: Pos2) {
    harness.hover_at(at);
    harness.run_steps(1);
    for pressed in [true, false] {
        harness.event(egui::Event::PointerButton {
            pos: at,
            button: egui::PointerButton::Primary,
            pressed,
            modifiers: egui::Modifiers::NONE,
        });
    }
    harness.run_steps(2);
}

type Frames = std::collections::BTreeMap<u64, (kairos_protocol::frame::SampleHeader, Vec<u8>)>;

/// Every sample frame each client gets, by sequence number, until `common` frames came to both (at
/// most a minute).
fn frames_by_sequence(a: &RuntimeClient, b: &RuntimeClient, common: usize) -> (Frames, Frames) {
    let (mut frames_a, mut frames_b) = (Frames::new(), Frames::new());
    let started = Instant::now();
    while frames_a.keys().filter(|&s| frames_b.contains_key(s)).count() < common {
        assert!(
            started.elapsed() < Duration::from_mins(1),
            "{} frames by one, {} by the other, in a minute",
            frames_a.len(),
            frames_b.len()
        );
        for (client, frames) in [(a, &mut frames_a), (b, &mut frames_b)] {
            for event in client.poll() {
                match event {
                    kairos_studio::client::ClientEvent::Sample(header, payload) => {
                        frames.insert(header.sequence, (header, payload));
                    }
                    kairos_studio::client::ClientEvent::SharedMemory(Err(error)) => {
                        panic!("shared memory: {error}")
                    }
                    _ => {}
                }
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    (frames_a, frames_b)
}

fn wait_for_reply(client: &RuntimeClient, id: u64) -> kairos_protocol::ReplyBody {
    let started = Instant::now();
    loop {
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "no reply to request {id}"
        );
        for event in client.poll() {
            if let kairos_studio::client::ClientEvent::Reply(answer) = event
                && answer.id == Some(id)
            {
                return answer.outcome.unwrap();
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Subscribes to a camera through the socket and through shared memory, with pixels in the frames or
/// (`shared_pixels`) named in the runtime's memory, and compares the frames both deliver.
fn frames_compare_by_socket_and_shared_memory(shared_pixels: bool) {
    use kairos_protocol::{RequestBody, SampleTransport};
    let local = LocalRuntime::start_binary(&kairos_binary()).unwrap();
    let mut socket = RuntimeClient::connect(&local.url, Some(local.token.clone()), || {});
    let mut shared = RuntimeClient::connect(&local.url, Some(local.token.clone()), || {});
    let deploy = socket.request(RequestBody::Deploy {
        diagram: "Diagram(format: 1, packs: [Pack(name: \"sensors\", version: \"^0.1\")], components: [\
                  Component(id: \"camera\", type: \"sensors.camera\", position: (x: 0.0, y: 0.0), \
                  properties: {\"width\": 640, \"height\": 480, \"rate\": 20.0})], connections: [])"
            .to_owned(),
        network: None,
        folder: None,
    });
    wait_for_reply(&socket, deploy);
    let start = socket.request(RequestBody::Start {
        at_ns: None,
        forced: None,
        start_unlocked: false,
        lock_bound_ns: None,
    });
    wait_for_reply(&socket, start);
    let subscribe = |client: &mut RuntimeClient, transport, shared_pixels| {
        client.request(RequestBody::SubscribeSamples {
            outputs: vec!["camera.image".to_owned()],
            max_rate_hz: 100.0,
            max_image_width: None,
            transport,
            shared_pixels,
        })
    };
    let id = subscribe(&mut socket, SampleTransport::Socket, false);
    wait_for_reply(&socket, id);
    // The camera's frames lie in shared memory and the runtime is another process of this user: the
    // frames name the camera's buffers, which this process maps, as the studio does.
    let id = subscribe(&mut shared, SampleTransport::SharedMemory, shared_pixels);
    let kairos_protocol::ReplyBody::SubscribeSamples(subscribed) = wait_for_reply(&shared, id) else {
        panic!("not the reply to subscribe_samples");
    };
    shared.receive_shared(subscribed.services.unwrap()).unwrap();

    // 20 frames that came both ways (a second at 20 Hz on a fast machine), however long a slow one takes.
    let (by_socket, by_memory) = frames_by_sequence(&socket, &shared, 20);
    let common: Vec<u64> = by_socket
        .keys()
        .filter(|s| by_memory.contains_key(s))
        .copied()
        .collect();
    assert!(
        common.len() >= 20,
        "{} frames in common ({} by socket, {} by shared memory)",
        common.len(),
        by_socket.len(),
        by_memory.len()
    );
    for sequence in common {
        let (mut a, pixels_a) = by_socket[&sequence].clone();
        let (mut b, pixels_b) = by_memory[&sequence].clone();
        // How many samples each path passed over depends on its own timing; the rest must be equal.
        (a.skipped, b.skipped) = (0, 0);
        assert_eq!(a, b, "frame {sequence}");
        assert!(pixels_a == pixels_b, "frame {sequence}: the pixels differ");
        assert_eq!(pixels_a.len(), 640 * 480 * 3);
    }
}

#[test]
fn shared_memory_and_the_socket_deliver_identical_frames() {
    frames_compare_by_socket_and_shared_memory(false);
}

#[test]
fn frames_naming_the_runtimes_pixel_buffers_deliver_the_same_pixels_as_the_socket() {
    frames_compare_by_socket_and_shared_memory(true);
}

/// Runs frames until a label containing `text` shows: the dialog's checks run off the interface's thread.
fn wait_for_text(harness: &mut Harness<'_, StudioApp>, text: &str) {
    let started = Instant::now();
    while harness.query_by_label_contains(text).is_none() {
        assert!(
            started.elapsed() < Duration::from_mins(1),
            "timed out waiting for '{text}'"
        );
        std::thread::sleep(Duration::from_millis(20));
        harness.run_steps(1);
    }
}

fn type_into(harness: &mut Harness<'_, StudioApp>, label: &str, text: &str) {
    harness
        .get_by_role_and_label(egui::accesskit::Role::TextInput, label)
        .focus();
    harness.run_steps(1);
    harness.key_press_modifiers(egui::Modifiers::COMMAND, egui::Key::A);
    harness.run_steps(1);
    harness
        .get_by_role_and_label(egui::accesskit::Role::TextInput, label)
        .type_text(text);
    harness.run_steps(1);
}

#[test]
fn a_component_made_in_the_studio_is_built_loaded_and_in_the_palette() {
    let mut harness = studio_on_local_runtime(Document::default(), Vec2::new(1400.0, 900.0));
    harness.get_by_label("File").click();
    harness.run_steps(2);
    harness.get_by_label("New component…").click();
    harness.run_steps(2);

    // Answers are checked by `kairos new` itself, and what it says shows in the dialog.
    let dir = tempfile::tempdir().unwrap();
    let pack = dir.path().join("lab");
    type_into(&mut harness, "Pack folder", pack.to_str().unwrap());
    type_into(&mut harness, "Name", "match");
    harness.get_by_label("Check").click();
    wait_for_text(&mut harness, "is a Rust keyword");
    type_into(&mut harness, "Name", "smoother");
    type_into(&mut harness, "Inputs", "in:f46");
    harness.get_by_label("Check").click();
    wait_for_text(&mut harness, "did you mean 'f64'?");
    type_into(&mut harness, "Inputs", "in:f64");
    type_into(&mut harness, "Properties", "gain:f64=3");
    harness.get_by_label("Check").click();
    wait_for_text(&mut harness, "the answers are fine");
    assert!(!pack.exists(), "checking writes nothing");

    // Create: the pack and the component are generated, built, and loaded into a restarted local runtime.
    harness.get_by_label("Create, build and load").click();
    let generating = Instant::now();
    while !pack.join("src/smoother.rs").is_file() {
        assert!(
            generating.elapsed() < Duration::from_mins(1),
            "the component was never generated"
        );
        std::thread::sleep(Duration::from_millis(20));
        harness.run_steps(1);
    }
    let started = Instant::now();
    while harness
        .state()
        .session
        .library
        .component("lab.smoother")
        .is_none()
    {
        assert!(
            started.elapsed() < Duration::from_mins(5),
            "the new component never reached the palette"
        );
        std::thread::sleep(Duration::from_millis(100));
        harness.run_steps(1);
    }
    harness.run_steps(2);
    assert!(harness.query_by_label("Smoother").is_some(), "in the palette");
}

#[test]
fn a_python_component_made_in_the_studio_is_loaded_without_a_build() {
    let mut harness = studio_on_local_runtime(Document::default(), Vec2::new(1400.0, 900.0));
    harness.get_by_label("File").click();
    harness.run_steps(2);
    harness.get_by_label("New component…").click();
    harness.run_steps(2);

    let dir = tempfile::tempdir().unwrap();
    let pack = dir.path().join("py_lab");
    type_into(&mut harness, "Pack folder", pack.to_str().unwrap());
    harness
        .get_by_role_and_label(egui::accesskit::Role::ComboBox, "New pack in")
        .click();
    harness.run_steps(2);
    harness.get_by_label("Python").click();
    harness.run_steps(2);
    type_into(&mut harness, "Name", "doubler");
    type_into(&mut harness, "Inputs", "in:f64");
    type_into(&mut harness, "Outputs", "out:f64");
    harness.get_by_label("Check").click();
    wait_for_text(&mut harness, "the answers are fine");
    assert!(!pack.exists(), "checking writes nothing");

    harness.get_by_label("Create, build and load").click();
    let started = Instant::now();
    while harness
        .state()
        .session
        .library
        .component("py_lab.doubler")
        .is_none()
    {
        assert!(
            started.elapsed() < Duration::from_mins(1),
            "the new Python component never reached the palette"
        );
        std::thread::sleep(Duration::from_millis(100));
        harness.run_steps(1);
    }
    assert!(pack.join("doubler.py").is_file() && pack.join("test_doubler.py").is_file());
    assert!(pack.join("kairos-pack.toml").is_file());
}

/// A ROS 2 component's topic is picked from the live graph, as the runtime reaches it: a node in Python
/// declares the liveliness tokens `rmw_zenoh` declares; picking a topic sets the topic and its message
/// type, and a topic of a type Kairos does not carry cannot be picked.
#[test]
fn a_ros2_topic_and_a_ros2_service_are_picked_from_the_live_graph() {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/ros2/graph_node.py");
    let mut node = std::process::Command::new("python3")
        .arg(script)
        .args([&endpoint, "60"])
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
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ros.ron");
    std::fs::write(
        &path,
        format!(
            r#"Diagram(format: 1, components: [
                Component(id: "lidar", type: "ros2.subscriber", properties: {{"router": "{endpoint}"}}),
                Component(id: "reset", type: "ros2.service_client", properties: {{"router": "{endpoint}"}}),
            ])"#
        ),
    )
    .unwrap();
    let mut harness = studio_on_local_runtime(Document::open(&path).unwrap(), Vec2::new(1400.0, 900.0));
    run_until(&mut harness, "the library", |app| {
        app.session.library.component("ros2.subscriber").is_some()
    });
    harness.state_mut().canvas.selected = ["lidar".to_owned()].into();
    harness.run_steps(2);
    harness.get_by_label("topics…").click();
    wait_for_text(&mut harness, "The topics of the ROS 2 graph at");
    let picker = harness.get_by_label_contains("The topics of the ROS 2 graph at");
    assert_eq!(picker.value().as_deref(), Some("2 on the graph"));
    picker.click();
    harness.run_steps(2);
    let twist = harness.get_by_label_contains("/robot1/cmd_vel — geometry_msgs/msg/Twist (0 pub, 1 sub)");
    assert!(
        twist.accesskit_node().is_disabled(),
        "Kairos does not carry Twist"
    );
    harness
        .get_by_label_contains("/lidar/points — sensor_msgs/msg/PointCloud2 (1 pub, 0 sub)")
        .click();
    harness.run_steps(3);

    // A service client's service from the same graph, already listed: a service of a type Kairos does not
    // call is shown but cannot be picked.
    harness.state_mut().canvas.selected = ["reset".to_owned()].into();
    harness.run_steps(2);
    let picker = harness.get_by_label_contains("The services of the ROS 2 graph at");
    assert_eq!(picker.value().as_deref(), Some("2 on the graph"));
    picker.click();
    harness.run_steps(2);
    let plan = harness.get_by_label_contains("/robot1/plan — nav_msgs/srv/GetPlan (0 server, 1 client)");
    assert!(
        plan.accesskit_node().is_disabled(),
        "Kairos does not call GetPlan"
    );
    harness
        .get_by_label_contains("/scanner/reset — std_srvs/srv/Trigger (1 server, 0 client)")
        .click();
    harness.run_steps(3);
    let _ = node.kill();
    let _ = node.wait();
    let reset = harness
        .state()
        .session
        .document
        .diagram()
        .component("reset")
        .unwrap()
        .clone();
    assert_eq!(
        reset.properties.get("service"),
        Some(&kairos_diagram::Value::Text("/scanner/reset".into()))
    );
    assert_eq!(
        reset.properties.get("type"),
        Some(&kairos_diagram::Value::Text("std_srvs/srv/Trigger".into()))
    );
    let lidar = harness
        .state()
        .session
        .document
        .diagram()
        .component("lidar")
        .unwrap()
        .clone();
    assert_eq!(
        lidar.properties.get("topic"),
        Some(&kairos_diagram::Value::Text("/lidar/points".into()))
    );
    assert_eq!(
        lidar.properties.get("type"),
        Some(&kairos_diagram::Value::Text("sensor_msgs/msg/PointCloud2".into()))
    );
}
