//! One suite every component of every built-in pack passes: its descriptor is sound, its defaults fit
//! their own kinds, and it starts, runs and stops inside a real engine without failing.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::collections::BTreeSet;
use std::thread::sleep;
use std::time::{Duration, Instant};

use kairos_diagram::{ComponentInstance, Diagram, PropertyKind, Value};
use kairos_runtime::{ComponentState, Engine};
use kairos_sdk_core::RealTimeClock;
use kairos_sdk_core::host::RegistryValidation as _;

#[test]
fn every_descriptor_is_sound() {
    let library = kairos::builtin_registry().library_info();
    assert!(
        library.components.len() >= 18,
        "{} components",
        library.components.len()
    );
    for (name, info) in &library.components {
        assert!(
            name.starts_with(&format!("{}.", info.pack)),
            "{name} is not named after its pack"
        );
        assert!(
            !info.doc.is_empty() && !info.category.is_empty(),
            "{name}: doc and category"
        );
        for ports in [
            info.inputs.iter().map(|p| p.name.as_str()).collect::<Vec<_>>(),
            info.outputs.iter().map(|p| p.name.as_str()).collect(),
            info.properties.iter().map(|p| p.name.as_str()).collect(),
        ] {
            let unique: BTreeSet<_> = ports.iter().collect();
            assert_eq!(unique.len(), ports.len(), "{name}: duplicate names in {ports:?}");
        }
        for output in &info.outputs {
            if let Some(input) = &output.follows_input {
                assert!(
                    info.input(input).is_some(),
                    "{name}.{} follows unknown input {input}",
                    output.name
                );
            }
            assert!(output.default_buffer_size >= 1);
        }
        for property in &info.properties {
            let checked = property.kind.check(&property.default);
            assert!(
                checked.is_ok(),
                "{name}.{}: default {} does not fit {}",
                property.name,
                property.default,
                property.kind.describe()
            );
        }
    }
}

#[test]
fn every_component_starts_runs_and_stops_alone() {
    let registry = kairos::builtin_registry();
    let library = registry.library_info();
    let dir = tempfile::tempdir().unwrap();
    let recording = small_recording(dir.path());
    // Stand-ins for the devices of the sensor and I/O packs: pseudo-terminals for serial ports.
    let ptys: Vec<nix::pty::OpenptyResult> = (0..2).map(|_| nix::pty::openpty(None, None).unwrap()).collect();
    let mut diagram = Diagram::default();
    for (index, info) in library.components.values().enumerate() {
        let mut instance = ComponentInstance::new(format!("c{index}"), info.type_name.clone());
        for property in &info.properties {
            if property.kind == PropertyKind::Path {
                let path = dir.path().join(format!("c{index}-{}", property.name));
                instance
                    .properties
                    .insert(property.name.clone(), Value::Text(path.display().to_string()));
            }
        }
        for (name, value) in hardware_stand_in(&info.type_name, &ptys, dir.path()) {
            instance.properties.insert(name.to_owned(), value);
        }
        if info.type_name == "recording.player" {
            // A player needs a recording to describe its outputs; looping, it runs until stopped.
            instance
                .properties
                .insert("path".to_owned(), Value::Text(recording.clone()));
            for extra in ["path2", "path3", "path4"] {
                instance
                    .properties
                    .insert(extra.to_owned(), Value::Text(String::new()));
            }
            instance.properties.insert("loop".to_owned(), Value::Bool(true));
        }
        diagram.components.push(instance);
    }
    // Instances whose ports depend on their properties have the inputs their own descriptor gives.
    let described = registry.instance_infos(&diagram);
    // Without a CAN bus or a camera here, a component for one must fail at birth naming its device; a
    // link's end, naming what places it.
    let absent = |type_name: &str| match type_name {
        "can.socketcan_reader" | "can.socketcan_writer" => {
            (!std::path::Path::new("/sys/class/net/vcan0").exists()).then_some("'vcan0'")
        }
        "video.v4l2_camera" => (!std::path::Path::new("/dev/video0").exists()).then_some("/dev/video0"),
        // The ends of a link between hosts exist only as `kairos deploy` declares them.
        "link.sender" | "link.receiver" => Some("kairos deploy"),
        _ => None,
    };
    // The sources that can run here, in the diagram's order.
    let sources: Vec<bool> = diagram
        .components
        .iter()
        .zip(library.components.values())
        .map(|(instance, info)| {
            let inputs = match described.get(&instance.id) {
                Some(Ok(own)) => own.inputs.len(),
                _ => info.inputs.len(),
            };
            inputs == 0 && absent(&info.type_name).is_none()
        })
        .collect();
    let mut engine = Engine::build(&diagram, &registry, RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    sleep(Duration::from_millis(300));
    // Then until every source has run a cycle (done already on a fast machine).
    let deadline = Instant::now() + Duration::from_secs(30);
    while Instant::now() < deadline
        && engine
            .snapshot()
            .components
            .iter()
            .zip(&sources)
            .any(|(component, &source)| source && component.cycles == 0)
    {
        sleep(Duration::from_millis(20));
    }
    engine.stop();
    let snapshot = engine.snapshot();
    for (component, info) in snapshot.components.iter().zip(library.components.values()) {
        if let Some(named) = absent(&info.type_name) {
            assert!(
                matches!(&component.state, ComponentState::Failed(why) if why.contains(named)),
                "{} ({}): {:?}",
                component.id,
                info.type_name,
                component.state
            );
            continue;
        }
        assert_eq!(
            component.state,
            ComponentState::Stopped,
            "{} ({})",
            component.id,
            info.type_name
        );
        let inputs = match described.get(&component.id) {
            Some(Ok(own)) => own.inputs.len(),
            _ => info.inputs.len(),
        };
        if inputs == 0 {
            assert!(component.cycles > 0, "source {} never ran", info.type_name);
        }
    }
}

/// Properties that give a component that reads or writes a device something real to work on here.
fn hardware_stand_in(
    type_name: &str,
    ptys: &[nix::pty::OpenptyResult],
    dir: &std::path::Path,
) -> Vec<(&'static str, Value)> {
    let pty = |index: usize| {
        let path = nix::unistd::ttyname(&ptys[index].slave).unwrap();
        Value::Text(path.display().to_string())
    };
    let examples = concat!(env!("CARGO_MANIFEST_DIR"), "/../../examples/data/images");
    match type_name {
        "gnss.nmea" => vec![
            ("source", Value::Text("udp".to_owned())),
            ("address", Value::Text("127.0.0.1:0".to_owned())),
        ],
        "serial.reader" => vec![("device", pty(0))],
        // Any free port, so that nothing else listening makes them fail.
        "net.udp_receiver" | "lidar.velodyne" => {
            vec![("address", Value::Text("127.0.0.1:0".to_owned()))]
        }
        "serial.writer" => vec![("device", pty(1))],
        "can.socketcan_reader" | "can.socketcan_writer" => {
            vec![("interface", Value::Text("vcan0".to_owned()))]
        }
        "video.v4l2_camera" => vec![("device", Value::Text("/dev/video0".to_owned()))],
        "fusion.frame_transform" => {
            let frames = dir.join("stand-in-frames.toml");
            std::fs::write(
                &frames,
                "[frame.lidar]\nparent = \"vehicle\"\ntranslation = [1.0, 0.0, 1.8]\n",
            )
            .unwrap();
            vec![("frames_file", Value::Text(frames.display().to_string()))]
        }
        "vision.undistort" => {
            let calibration = dir.join("stand-in-camera.toml");
            std::fs::write(
                &calibration,
                "width = 64\nheight = 48\nfx = 50.0\nfy = 50.0\ncx = 32.0\ncy = 24.0\nk1 = -0.1\n",
            )
            .unwrap();
            vec![("calibration", Value::Text(calibration.display().to_string()))]
        }
        "can.candump_reader" => {
            let log = dir.join("stand-in.log");
            std::fs::write(
                &log,
                "(1.000000) can0 100#4000EC01\n(1.010000) can0 100#4100EC01\n",
            )
            .unwrap();
            vec![
                ("path", Value::Text(log.display().to_string())),
                ("loop", Value::Bool(true)),
            ]
        }
        "can.dbc_decoder" | "can.dbc_encoder" => {
            let dbc = dir.join("stand-in.dbc");
            std::fs::write(
                &dbc,
                "VERSION \"\"\n\nNS_ :\n\nBS_:\n\nBU_: ECU\n\nBO_ 256 Engine: 8 ECU\n SG_ Speed : 0|16@1+ (0.25,0) [0|16383.75] \"rpm\" ECU\n",
            )
            .unwrap();
            let dbc = ("dbc", Value::Text(dbc.display().to_string()));
            if type_name == "can.dbc_encoder" {
                vec![dbc, ("message", Value::Text("Engine".to_owned()))]
            } else {
                vec![dbc]
            }
        }
        "video.image_sequence" => vec![
            ("folder", Value::Text(examples.to_owned())),
            ("loop", Value::Bool(true)),
        ],
        _ => Vec::new(),
    }
}

/// A recording of a few numbers, for the player.
fn small_recording(dir: &std::path::Path) -> String {
    let path = dir.join("small.mcap");
    let mut harness = kairos_sdk_core::harness::Harness::new(
        kairos_pack_recording::recorder::Recorder::info(),
        kairos_pack_recording::recorder::Recorder::default(),
    );
    harness.set_property("path", path.display().to_string()).unwrap();
    for i in 0..20 {
        harness.push(
            "in1",
            kairos_sdk_core::Payload::F64(f64::from(i)),
            kairos_sdk_core::Timestamp::from_millis(i64::from(i) * 10),
        );
    }
    harness.finish().unwrap();
    path.display().to_string()
}
