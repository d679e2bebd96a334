//! A small component library shared by the integration tests.

use kairos_diagram::{
    ComponentInfo, DataType, ExecutionMode, InputInfo, LibraryInfo, OutputInfo, PackInfo, PropertyInfo,
    PropertyKind, ReaderPolicy, TypeFilter, Value,
};

fn input(name: &str, filter: TypeFilter) -> InputInfo {
    InputInfo {
        name: name.to_owned(),
        filter,
        default_policy: ReaderPolicy::Fifo,
        doc: String::new(),
    }
}

fn output(name: &str, data_type: DataType) -> OutputInfo {
    OutputInfo {
        name: name.to_owned(),
        data_type,
        follows_input: None,
        default_buffer_size: 16,
        doc: String::new(),
        known_as: None,
    }
}

fn property(name: &str, kind: PropertyKind, default: Value) -> PropertyInfo {
    PropertyInfo {
        device: None,
        name: name.to_owned(),
        kind,
        default,
        live: true,
        doc: String::new(),
        unit: String::new(),
    }
}

fn component(type_name: &str, pack: &str, mode: ExecutionMode) -> ComponentInfo {
    ComponentInfo {
        type_name: type_name.to_owned(),
        pack: pack.to_owned(),
        label: String::new(),
        category: "test".to_owned(),
        doc: String::new(),
        mode,
        inputs: Vec::new(),
        outputs: Vec::new(),
        properties: Vec::new(),
        actions: Vec::new(),
        time_source: false,
        simulated_time: false,
        holds_inputs: false,
        stops_at_once: false,
        blocking: None,
    }
}

/// `core` 0.1.3: sine, gain (reactive), console, camera; `sensors` 0.2.0: imu.
pub fn library() -> LibraryInfo {
    let mut sine = component("core.sine", "core", ExecutionMode::Periodic);
    sine.outputs.push(output("out", DataType::F64));
    sine.properties = vec![
        property(
            "frequency",
            PropertyKind::F64 {
                min: Some(0.001),
                max: Some(10_000.0),
            },
            Value::F64(1.0),
        ),
        property(
            "waveform",
            PropertyKind::Choice(vec![
                "sine".to_owned(),
                "square".to_owned(),
                "triangle".to_owned(),
            ]),
            Value::Text("sine".to_owned()),
        ),
        property(
            "amplitude",
            PropertyKind::F64 { min: None, max: None },
            Value::F64(1.0),
        ),
    ];

    let mut gain = component("core.gain", "core", ExecutionMode::Reactive);
    gain.inputs
        .push(input("in", TypeFilter::OneOf(vec![DataType::F64, DataType::I64])));
    gain.outputs.push(output("out", DataType::F64));
    gain.properties.push(property(
        "gain",
        PropertyKind::F64 { min: None, max: None },
        Value::F64(1.0),
    ));

    let mut console = component("core.console", "core", ExecutionMode::Threaded);
    console.inputs.push(input("in", TypeFilter::Any));
    console
        .properties
        .push(property("prefix", PropertyKind::Text, Value::Text(String::new())));

    let mut camera = component("core.camera", "core", ExecutionMode::Threaded);
    camera.outputs.push(output("image", DataType::Image));
    camera.properties = vec![
        property(
            "device",
            PropertyKind::Path,
            Value::Text("/dev/video0".to_owned()),
        ),
        property(
            "fps",
            PropertyKind::I64 {
                min: Some(1),
                max: Some(240),
            },
            Value::I64(30),
        ),
    ];

    let mut imu = component("sensors.imu", "sensors", ExecutionMode::Threaded);
    imu.outputs.push(output("imu", DataType::Imu));

    let mut library = LibraryInfo::default();
    for (name, version) in [("core", "0.1.3"), ("sensors", "0.2.0")] {
        let pack = PackInfo {
            name: name.to_owned(),
            version: version.to_owned(),
            origin: "built-in".to_owned(),
        };
        library.packs.insert(name.to_owned(), pack);
    }
    for info in [sine, gain, console, camera, imu] {
        library.components.insert(info.type_name.clone(), info);
    }
    library
}
