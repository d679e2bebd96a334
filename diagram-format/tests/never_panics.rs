//! Property tests: the reader survives any input, and random valid diagrams round-trip exactly.

mod common;

use kairos_diagram::{
    ComponentInstance, Connection, Diagram, HostSpec, OutputSettings, PackRequirement, PortRef, Position,
    ReaderPolicy, ThreadSettings, Value, parse, render_all, validate,
};
use proptest::prelude::*;

const CANONICAL: &str = include_str!("corpus/canonical.ron");

/// Parses, and on success validates, writes and rereads; renders whatever diagnostics come out.
fn exercise(source: &str) {
    match parse(source) {
        Ok(parsed) => {
            let found = parsed.validate(&common::library());
            let _ = render_all(&found, "fuzz.ron", source);
            let text = parsed.diagram.to_ron();
            let reread = parse(&text).expect("the writer's output reads back");
            assert_eq!(reread.diagram.to_ron(), text);
        }
        Err(found) => {
            assert!(!found.is_empty());
            let _ = render_all(&found, "fuzz.ron", source);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn arbitrary_text_never_panics(source in any::<String>()) {
        exercise(&source);
    }

    #[test]
    fn ron_like_text_never_panics(source in "[\\[\\](){}:,\"\\\\a-zA-Z0-9_.+\\-/* \n\té]{0,120}") {
        exercise(&source);
    }

    #[test]
    fn mutated_diagrams_never_panic(
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>(), 0..3_u8), 1..8),
    ) {
        let mut bytes = CANONICAL.as_bytes().to_vec();
        for (at, byte, operation) in edits {
            let position = at.index(bytes.len().max(1));
            match operation {
                0 => {
                    if let Some(b) = bytes.get_mut(position) {
                        *b = byte;
                    }
                }
                1 => bytes.insert(position.min(bytes.len()), byte),
                _ => {
                    if position < bytes.len() {
                        bytes.remove(position);
                    }
                }
            }
        }
        exercise(&String::from_utf8_lossy(&bytes));
    }

    #[test]
    fn truncated_diagrams_never_panic(at in any::<prop::sample::Index>()) {
        let cut = at.index(CANONICAL.len());
        let text = String::from_utf8_lossy(CANONICAL.as_bytes().get(..cut).unwrap_or_default());
        exercise(&text);
    }

    #[test]
    fn random_diagrams_round_trip(diagram in diagram()) {
        let text = diagram.to_ron();
        let reread = parse(&text).map_err(|d| TestCaseError::fail(render_all(&d, "rt.ron", &text)))?.diagram;
        let mut sorted = diagram.clone();
        sorted.sort_canonically();
        prop_assert_eq!(&reread, &sorted);
        prop_assert_eq!(reread.to_ron(), text);
        // Validation of nonsense must not panic either.
        let _ = validate(&diagram, None, &common::library());
    }
}

fn id() -> impl Strategy<Value = String> {
    prop_oneof![
        "[a-z][a-z0-9_-]{0,8}",
        Just("sine1".to_owned()),
        Just("gain1".to_owned()),
    ]
}

fn value() -> impl Strategy<Value = Value> {
    prop_oneof![
        any::<bool>().prop_map(Value::Bool),
        any::<i64>().prop_map(Value::I64),
        any::<f64>()
            .prop_filter("NaN never equals itself", |v| !v.is_nan())
            .prop_map(Value::F64),
        any::<String>().prop_map(Value::Text),
    ]
}

fn finite_or_infinite_f32() -> impl Strategy<Value = f32> {
    any::<f32>().prop_filter("NaN never equals itself", |v| !v.is_nan())
}

fn component() -> impl Strategy<Value = ComponentInstance> {
    (
        id(),
        prop_oneof![
            Just("core.sine".to_owned()),
            Just("core.gain".to_owned()),
            any::<String>()
        ],
        prop::collection::btree_map(any::<String>(), value(), 0..4),
        prop::collection::btree_map(
            any::<String>(),
            (any::<Option<usize>>(), any::<Option<u32>>()).prop_map(|(buffer_size, subsampling)| {
                OutputSettings {
                    buffer_size,
                    subsampling,
                }
            }),
            0..3,
        ),
        (any::<Option<u8>>(), prop::collection::vec(any::<usize>(), 0..3))
            .prop_map(|(priority, affinity)| ThreadSettings { priority, affinity }),
        prop_oneof![
            Just(Position::default()),
            (finite_or_infinite_f32(), finite_or_infinite_f32()).prop_map(|(x, y)| Position { x, y }),
        ],
        any::<Option<String>>(),
    )
        .prop_map(|(id, type_name, properties, outputs, thread, position, host)| {
            let mut instance = ComponentInstance::new(id, type_name);
            instance.properties = properties;
            instance.outputs = outputs;
            instance.thread = thread;
            instance.position = position;
            instance.host = host;
            instance
        })
}

fn connection() -> impl Strategy<Value = Connection> {
    (
        id(),
        "[a-z_]{1,5}",
        id(),
        "[a-z_]{1,5}",
        prop::option::of(prop::sample::select(ReaderPolicy::ALL.to_vec())),
        any::<Option<usize>>(),
        any::<Option<u32>>(),
    )
        .prop_map(
            |(from_id, from_port, to_id, to_port, policy, buffer_size, subsampling)| Connection {
                from: PortRef::new(from_id, from_port),
                to: PortRef::new(to_id, to_port),
                policy,
                buffer_size,
                subsampling,
            },
        )
}

fn diagram() -> impl Strategy<Value = Diagram> {
    (
        any::<u32>(),
        prop::collection::vec(
            (any::<String>(), any::<String>()).prop_map(|(name, version)| PackRequirement { name, version }),
            0..3,
        ),
        prop::collection::vec(component(), 0..5),
        prop::collection::vec(connection(), 0..5),
        prop::option::of("[a-z]{1,6}"),
        prop::collection::btree_map(
            any::<String>(),
            (
                any::<String>(),
                any::<Option<String>>(),
                any::<Option<String>>(),
                any::<Option<String>>(),
                proptest::option::of(0.0..=600.0_f64),
                proptest::option::of(0.0..=65_536.0_f64),
            )
                .prop_map(
                    |(endpoint, token_file, zenoh, certificate, ride_out_s, ride_out_mb)| HostSpec {
                        endpoint,
                        token_file,
                        zenoh,
                        certificate,
                        ride_out_s,
                        ride_out_mb,
                    },
                ),
            0..3,
        ),
    )
        .prop_map(
            |(format, packs, components, connections, clock_source, hosts)| Diagram {
                format,
                packs,
                components,
                connections,
                clock_source,
                hosts,
                viewers: Vec::new(),
                sequential: false,
                groups: std::collections::BTreeMap::new(),
                exposes: None,
            },
        )
}
