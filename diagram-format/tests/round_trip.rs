//! Reading and writing: the canonical text form is stable and loses nothing.

mod common;

use std::collections::BTreeMap;

use kairos_diagram::{
    ComponentInstance, Connection, Diagram, Exposes, HostSpec, OutputSettings, PackRequirement, PortRef,
    Position, ReaderPolicy, ThreadSettings, Value, ViewerSpec, parse, resolved_properties,
};

const CANONICAL: &str = include_str!("corpus/canonical.ron");

#[test]
fn the_canonical_file_rewrites_to_exactly_itself() {
    let parsed =
        parse(CANONICAL).unwrap_or_else(|d| panic!("{}", kairos_diagram::render_all(&d, "c", CANONICAL)));
    assert_eq!(parsed.diagram.to_ron(), CANONICAL);
}

#[test]
fn the_canonical_file_is_valid() {
    let parsed = parse(CANONICAL).unwrap();
    let problems = parsed.validate(&common::library());
    assert!(
        problems.is_empty(),
        "{}",
        kairos_diagram::render_all(&problems, "c", CANONICAL)
    );
}

#[test]
fn the_canonical_file_reads_as_expected() {
    let diagram = parse(CANONICAL).unwrap().diagram;
    let sine = diagram.component("sine1").unwrap();
    assert_eq!(sine.position, Position { x: 100.0, y: 80.0 });
    assert_eq!(sine.properties.get("amplitude"), Some(&Value::F64(-1.5e-7)));
    assert_eq!(
        sine.outputs.get("out"),
        Some(&OutputSettings {
            buffer_size: Some(32),
            subsampling: Some(2)
        })
    );
    assert_eq!(
        sine.thread,
        ThreadSettings {
            priority: Some(10),
            affinity: vec![0, 1]
        }
    );
    let camera = diagram.component("cam1").unwrap();
    assert_eq!(camera.properties.get("fps"), Some(&Value::I64(60)));
    let console = diagram.component("console1").unwrap();
    assert_eq!(
        console.properties.get("prefix"),
        Some(&Value::Text("gain says \"hi\"\n".to_owned()))
    );
    assert_eq!(diagram.component("imu1").unwrap().position, Position::default());
    let first = diagram.connections.first().unwrap();
    assert_eq!(first.policy, Some(ReaderPolicy::LastOrNext));
    assert_eq!(first.to, PortRef::new("console1", "in"));
}

fn scrambled_diagram() -> Diagram {
    let mut sine = ComponentInstance::new("sine1", "core.sine");
    sine.properties
        .insert("frequency".to_owned(), Value::F64(0.1 + 0.2));
    sine.properties.insert("cycles".to_owned(), Value::I64(i64::MIN));
    sine.properties.insert("on".to_owned(), Value::Bool(false));
    sine.properties.insert(
        "label".to_owned(),
        Value::Text("tab\there \u{7} \\ é 😀".to_owned()),
    );
    sine.properties.insert("huge".to_owned(), Value::F64(f64::MAX));
    sine.properties.insert("tiny".to_owned(), Value::F64(5e-324));
    sine.properties.insert("neg_zero".to_owned(), Value::F64(-0.0));
    sine.properties
        .insert("infinite".to_owned(), Value::F64(f64::NEG_INFINITY));
    sine.position = Position { x: 0.1, y: -0.0 };
    sine.outputs.insert("out".to_owned(), OutputSettings::default());
    let mut gain = ComponentInstance::new("gain1", "core.gain");
    gain.thread.priority = Some(99);
    gain.host = Some("roadside".to_owned());
    gain.group = Some("control".to_owned());
    let mut connection = Connection::new(PortRef::new("sine1", "out"), PortRef::new("gain1", "in"));
    connection.policy = Some(ReaderPolicy::NeverSkipping);
    Diagram {
        format: 1,
        packs: vec![
            PackRequirement {
                name: "z".to_owned(),
                version: "1".to_owned(),
            },
            PackRequirement {
                name: "a".to_owned(),
                version: "*".to_owned(),
            },
        ],
        components: vec![sine, gain],
        connections: vec![
            connection,
            Connection::new(PortRef::new("gain1", "out"), PortRef::new("console1", "in")),
        ],
        clock_source: Some("sine1".to_owned()),
        hosts: BTreeMap::from([
            (
                "roadside".to_owned(),
                HostSpec {
                    endpoint: "wss://10.0.0.3:7600".to_owned(),
                    token_file: Some("roadside \"token\".txt".to_owned()),
                    zenoh: Some("tls/10.0.0.3:7447".to_owned()),
                    certificate: Some("roadside.pem".to_owned()),
                    ride_out_s: Some(12.5),
                    ride_out_mb: Some(512.0),
                },
            ),
            (
                "car".to_owned(),
                HostSpec {
                    endpoint: "ws://car.local:7600".to_owned(),
                    token_file: None,
                    zenoh: None,
                    certificate: None,
                    ride_out_s: None,
                    ride_out_mb: None,
                },
            ),
        ]),
        // Viewers keep their order: the dock's.
        viewers: vec![
            ViewerSpec {
                output: "sine1.out".to_owned(),
                kind: "plot".to_owned(),
                docked: true,
                also: Vec::new(),
                area: Some(0),
                share: Some(0.75),
            },
            ViewerSpec {
                output: "gnss \"a\".fix".to_owned(),
                kind: "track".to_owned(),
                docked: false,
                also: vec!["gnss2.fix".to_owned(), "gnss3.fix".to_owned()],
                area: None,
                share: None,
            },
        ],
        sequential: true,
        groups: BTreeMap::from([(
            "control".to_owned(),
            ThreadSettings {
                priority: Some(40),
                affinity: vec![1],
            },
        )]),
        // A property fed to one inner property is written as a string, to several as a list.
        exposes: Some(Exposes {
            inputs: BTreeMap::from([(
                "signal".to_owned(),
                vec![PortRef::new("gain1", "in"), PortRef::new("sine1", "sync")],
            )]),
            outputs: BTreeMap::from([("scaled \"x\"".to_owned(), PortRef::new("gain1", "out"))]),
            properties: BTreeMap::from([
                ("gain".to_owned(), vec![PortRef::new("gain1", "gain")]),
                (
                    "frequency".to_owned(),
                    vec![
                        PortRef::new("sine1", "frequency"),
                        PortRef::new("gain1", "frequency"),
                    ],
                ),
            ]),
        }),
    }
}

#[test]
fn parse_of_write_gives_the_canonically_sorted_diagram() {
    let diagram = scrambled_diagram();
    let text = diagram.to_ron();
    let reread = parse(&text).unwrap().diagram;
    let mut sorted = diagram.clone();
    sorted.sort_canonically();
    assert_eq!(reread, sorted);
    assert_ne!(sorted, diagram, "the test diagram should need sorting");
    let sine = reread.component("sine1").unwrap();
    // Bits, not values: -0.0 == 0.0 would hide a lost sign.
    assert_eq!(sine.position.y.to_bits(), (-0.0_f32).to_bits());
    assert_eq!(
        sine.properties
            .get("neg_zero")
            .and_then(Value::as_f64)
            .map(f64::to_bits),
        Some((-0.0_f64).to_bits())
    );
}

#[test]
fn writing_is_deterministic_and_idempotent() {
    let diagram = scrambled_diagram();
    let once = diagram.to_ron();
    assert_eq!(diagram.to_ron(), once);
    let mut sorted = diagram.clone();
    sorted.sort_canonically();
    assert_eq!(sorted.to_ron(), once, "the input order must not matter");
    let twice = parse(&once).unwrap().diagram.to_ron();
    assert_eq!(twice, once);
}

#[test]
fn resolved_properties_fill_defaults_and_normalise() {
    let library = common::library();
    let sine_info = library.component("core.sine").unwrap();
    let mut sine = ComponentInstance::new("sine1", "core.sine");
    sine.properties.insert("frequency".to_owned(), Value::I64(5));
    sine.properties
        .insert("waveform".to_owned(), Value::Text("nonsense".to_owned()));
    sine.properties.insert("unknown".to_owned(), Value::Bool(true));
    let resolved = resolved_properties(&sine, sine_info);
    let expected: BTreeMap<String, Value> = [
        ("amplitude", Value::F64(1.0)),
        ("frequency", Value::F64(5.0)),
        ("waveform", Value::Text("sine".to_owned())),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_owned(), v))
    .collect();
    assert_eq!(resolved, expected);
}

#[test]
fn load_reads_files_and_reports_with_the_path() {
    let directory = std::env::temp_dir().join(format!("kairos-diagram-load-{}", std::process::id()));
    std::fs::create_dir_all(&directory).unwrap();
    let good = directory.join("good.ron");
    kairos_diagram::save(&good, &scrambled_diagram()).unwrap();
    let (text, parsed) = kairos_diagram::load(&good).unwrap();
    assert_eq!(text, scrambled_diagram().to_ron());
    assert_eq!(parsed.diagram.connections.len(), 2);

    let bad = directory.join("bad.ron");
    std::fs::write(&bad, "Diagram(format: 1,\n  packs: [Pack(name: 1)],\n)\n").unwrap();
    let error = kairos_diagram::load(&bad).unwrap_err();
    assert!(
        error
            .to_string()
            .ends_with("bad.ron:2:11: error: Pack is missing field 'version' (and 1 more problems)"),
        "{error}"
    );
    let rendered = error.render();
    assert!(
        rendered.contains("2 |   packs: [Pack(name: 1)],\n  |           ^^^^\n"),
        "{rendered}"
    );
    assert!(
        rendered.contains("2 |   packs: [Pack(name: 1)],\n  |                      ^\n"),
        "{rendered}"
    );

    let missing = kairos_diagram::load(&directory.join("missing.ron")).unwrap_err();
    assert!(matches!(missing, kairos_diagram::LoadError::Io { .. }));
    std::fs::remove_dir_all(&directory).unwrap();
}
