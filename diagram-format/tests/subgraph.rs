//! Subgraphs flattened: ids, links, properties, nesting, and every refusal at its place.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use kairos_diagram::subgraph::{ExtractError, SubgraphReadError};
use kairos_diagram::{Value, flatten, parse};

/// Two gains in a row, exposing their input, output and one gain for both.
const GAINS: &str = r#"Diagram(format: 1,
    exposes: Exposes(
        inputs: {"in": "first.in"},
        outputs: {"out": "second.out"},
        properties: {"gain": ["first.gain", "second.gain"]},
    ),
    packs: [Pack(name: "core", version: "^0.1")],
    components: [
        Component(id: "first", type: "core.gain"),
        Component(id: "second", type: "core.gain"),
    ],
    connections: [Connection(from: "first.out", to: "second.in")],
)"#;

/// Files by name, read as a folder would be.
fn files(entries: &[(&str, &str)]) -> impl FnMut(&Path) -> Result<String, SubgraphReadError> {
    let files: BTreeMap<PathBuf, String> = entries
        .iter()
        .map(|(name, text)| (Path::new("rig").join(name), (*text).to_owned()))
        .collect();
    move |path: &Path| {
        files
            .get(path)
            .cloned()
            .ok_or_else(|| std::io::Error::from_raw_os_error(2).into())
    }
}

fn flattened(main: &str, entries: &[(&str, &str)]) -> Result<kairos_diagram::Flattened, Vec<String>> {
    let parsed = parse(main).unwrap();
    flatten(parsed, Path::new("rig/main.ron"), &mut files(entries))
        .map_err(|problems| problems.iter().map(ToString::to_string).collect())
}

#[test]
fn instances_become_their_components_with_links_and_properties_carried_through() {
    let main = r#"Diagram(format: 1,
    packs: [Pack(name: "core", version: "^0.1")],
    components: [
        Component(id: "sine", type: "core.sine"),
        Component(id: "a", type: "gains.ron", properties: {"gain": 2.0}),
        Component(id: "b", type: "gains.ron"),
        Component(id: "console", type: "core.console"),
    ],
    connections: [
        Connection(from: "sine.out", to: "a.in"),
        Connection(from: "a.out", to: "b.in", policy: NeverSkipping),
        Connection(from: "b.out", to: "console.in"),
    ],
)"#;
    let flat = flattened(main, &[("gains.ron", GAINS)]).unwrap();
    let diagram = &flat.parsed.diagram;
    let ids: Vec<&str> = diagram.components.iter().map(|c| c.id.as_str()).collect();
    assert_eq!(
        ids,
        ["sine", "a/first", "a/second", "b/first", "b/second", "console"]
    );
    let links: Vec<String> = diagram
        .connections
        .iter()
        .map(|c| {
            format!(
                "{} -> {} {}",
                c.from,
                c.to,
                c.policy.map_or("default", |p| p.name())
            )
        })
        .collect();
    assert_eq!(
        links,
        [
            "a/first.out -> a/second.in default",
            "b/first.out -> b/second.in default",
            "sine.out -> a/first.in default",
            "a/second.out -> b/first.in NeverSkipping",
            "b/second.out -> console.in default",
        ]
    );
    // The instance's property feeds both inner gains; the other instance keeps theirs.
    for id in ["a/first", "a/second"] {
        assert_eq!(diagram.component(id).unwrap().properties["gain"], Value::F64(2.0));
    }
    assert!(diagram.component("b/first").unwrap().properties.is_empty());
    // The flat diagram is valid against the library, and reads back from its own text.
    assert!(flat.parsed.validate(&common::library()).is_empty());
    let text = diagram.to_ron();
    assert_eq!(parse(&text).unwrap().diagram.to_ron(), text);
    assert_eq!(flat.origins.of("a/second"), Some("gains.ron:10:23"));
}

#[test]
fn subgraphs_nest_to_any_depth_and_expose_what_they_use_inside() {
    // A subgraph of subgraphs, exposing an inner subgraph's ports and property.
    let twice = r#"Diagram(format: 1,
    exposes: Exposes(
        inputs: {"in": "one.in"},
        outputs: {"out": "two.out"},
        properties: {"gain": ["one.gain", "two.gain"]},
    ),
    components: [
        Component(id: "one", type: "gains.ron"),
        Component(id: "two", type: "../rig/gains.ron"),
    ],
    connections: [Connection(from: "one.out", to: "two.in")],
)"#;
    let main = r#"Diagram(format: 1,
    components: [
        Component(id: "sine", type: "core.sine"),
        Component(id: "x", type: "twice.ron", properties: {"gain": 3.0}),
    ],
    connections: [Connection(from: "sine.out", to: "x.in")],
)"#;
    let flat = flattened(main, &[("gains.ron", GAINS), ("twice.ron", twice)]).unwrap();
    let diagram = &flat.parsed.diagram;
    let ids: Vec<&str> = diagram.components.iter().map(|c| c.id.as_str()).collect();
    assert_eq!(
        ids,
        [
            "sine",
            "x/one/first",
            "x/one/second",
            "x/two/first",
            "x/two/second"
        ]
    );
    assert!(
        diagram
            .connections
            .iter()
            .any(|c| c.from.to_string() == "x/one/second.out" && c.to.to_string() == "x/two/first.in")
    );
    assert!(
        diagram
            .connections
            .iter()
            .any(|c| c.from.to_string() == "sine.out" && c.to.to_string() == "x/one/first.in")
    );
    for id in ["x/one/first", "x/one/second", "x/two/first", "x/two/second"] {
        assert_eq!(
            diagram.component(id).unwrap().properties["gain"],
            Value::F64(3.0),
            "{id}"
        );
    }
    assert_eq!(
        flat.origins.of("x/two/first"),
        Some("twice.ron:9:23, in ../rig/gains.ron:9:23")
    );
    assert!(flat.parsed.validate(&common::library()).is_empty());
}

#[test]
fn a_subgraph_that_includes_itself_is_refused_at_the_instance() {
    let a = r#"Diagram(format: 1, components: [Component(id: "inner", type: "b.ron")])"#;
    let b = r#"Diagram(format: 1, components: [Component(id: "deeper", type: "a.ron")])"#;
    let main = r#"Diagram(format: 1, components: [Component(id: "top", type: "a.ron")])"#;
    let problems = flattened(main, &[("a.ron", a), ("b.ron", b)]).unwrap_err();
    assert_eq!(
        problems,
        [
            "1:60: error: in a.ron:1:62: in b.ron:1:63: subgraph 'a.ron' includes itself: a.ron → b.ron → a.ron"
        ]
    );
    let myself = r#"Diagram(format: 1, components: [Component(id: "me", type: "main.ron")])"#;
    let problems = flattened(myself, &[]).unwrap_err();
    assert_eq!(
        problems,
        ["1:59: error: subgraph 'main.ron' includes itself: main.ron → main.ron"]
    );
}

#[test]
fn a_port_or_property_a_subgraph_does_not_expose_is_refused_where_it_is_named() {
    let main = r#"Diagram(format: 1,
    components: [
        Component(id: "sine", type: "core.sine"),
        Component(id: "a", type: "gains.ron", properties: {"gian": 2.0}),
    ],
    connections: [Connection(from: "sine.out", to: "a.inn")],
)"#;
    let problems = flattened(main, &[("gains.ron", GAINS)]).unwrap_err();
    assert_eq!(
        problems,
        [
            "4:60: error: subgraph 'gains.ron' exposes no property 'gian' (it exposes gain); did you mean 'gain'?",
            "6:52: error: 'a' (subgraph 'gains.ron') exposes no input 'inn' (it exposes in); did you mean 'in'?",
        ]
    );
}

#[test]
fn a_subgraph_exposing_what_it_lacks_or_one_property_twice_is_refused_in_its_file() {
    let lacking = GAINS.replace(r#""out": "second.out""#, r#""out": "third.out""#);
    let twice = GAINS.replace(
        r#"properties: {"gain": ["first.gain", "second.gain"]}"#,
        r#"properties: {"gain": ["first.gain", "second.gain"], "other": "second.gain"}"#,
    );
    let main = r#"Diagram(format: 1, components: [Component(id: "a", type: "gains.ron")])"#;
    let problems = flattened(main, &[("gains.ron", &lacking)]).unwrap_err();
    assert_eq!(
        problems,
        [
            "1:58: error: in gains.ron:4:26: exposed output 'out' names 'third.out', but the diagram has no component 'third'"
        ]
    );
    let problems = flattened(main, &[("gains.ron", &twice)]).unwrap_err();
    assert_eq!(
        problems,
        [
            "1:58: error: in gains.ron:5:70: 'second.gain' is exposed twice: as 'gain' and as 'other'; expose each inner property under one name; a name may feed several"
        ]
    );
}

#[test]
fn a_fault_inside_is_reported_at_its_own_line_and_at_the_instance() {
    let broken = GAINS.replace(
        r#"Component(id: "second", type: "core.gain")"#,
        r#"Component(id: "second", typ: "core.gain")"#,
    );
    let main = r#"Diagram(format: 1,
    components: [Component(id: "a", type: "gains.ron")],
)"#;
    let problems = flattened(main, &[("gains.ron", &broken)]).unwrap_err();
    assert_eq!(
        problems,
        [
            "2:43: error: in gains.ron:10:9: Component is missing field 'type'",
            "2:43: error: in gains.ron:10:33: unknown field 'typ' in Component; did you mean 'type'?",
        ]
    );
    let problems = flattened(main, &[]).unwrap_err();
    assert_eq!(
        problems,
        [
            "2:43: error: cannot read subgraph 'gains.ron': No such file or directory (os error 2); the path is relative to this diagram's folder (rig)"
        ]
    );
    // What the validator finds inside names the inner component and says where it is written.
    let unknown = GAINS.replace(r#"type: "core.gain")"#, r#"type: "core.gian")"#);
    let flat = flattened(main, &[("gains.ron", &unknown)]).unwrap();
    let mut found = flat.parsed.validate(&common::library());
    flat.origins.annotate(&mut found);
    let first = &found[0];
    assert!(first.message.contains("'a/first'"), "{first}");
    assert_eq!(first.location.unwrap().line, 2);
    assert_eq!(first.notes[0].message, "'a/first' is written at gains.ron:9:23");
}

#[test]
fn components_made_into_a_subgraph_run_as_they_did_through_its_exposed_ports() {
    let main = r#"Diagram(format: 1,
    packs: [Pack(name: "core", version: "^0.1")],
    components: [
        Component(id: "sine", type: "core.sine", position: (x: 0.0, y: 0.0)),
        Component(id: "a", type: "core.gain", position: (x: 200.0, y: 100.0), properties: {"gain": 2.0}),
        Component(id: "b", type: "core.gain", position: (x: 400.0, y: 100.0)),
        Component(id: "console", type: "core.console"),
        Component(id: "other", type: "core.console"),
    ],
    connections: [
        Connection(from: "sine.out", to: "a.in", policy: NeverSkipping),
        Connection(from: "a.out", to: "b.in"),
        Connection(from: "b.out", to: "console.in"),
        Connection(from: "a.out", to: "other.in"),
    ],
    viewers: [Viewer(output: "b.out", kind: "plot"), Viewer(output: "a.out", kind: "table")],
)"#;
    let original = parse(main).unwrap().diagram;
    let ids = ["a".to_owned(), "b".to_owned()];
    let (subgraph, outer) = kairos_diagram::subgraph::extract(&original, &ids, "pair", "pair.ron").unwrap();
    let exposes = subgraph.exposes.clone().unwrap();
    assert_eq!(exposes.inputs["in"], [kairos_diagram::PortRef::new("a", "in")]);
    assert_eq!(exposes.outputs["out"], kairos_diagram::PortRef::new("b", "out"));
    assert_eq!(exposes.outputs["a_out"], kairos_diagram::PortRef::new("a", "out"));
    // Placed from the origin; what was set inside stays inside.
    let a = subgraph.component("a").unwrap();
    assert_eq!((a.position.x, a.position.y), (40.0, 40.0));
    assert_eq!(a.properties["gain"], Value::F64(2.0));
    let links: Vec<String> = outer
        .connections
        .iter()
        .map(|c| format!("{} -> {}", c.from, c.to))
        .collect();
    assert_eq!(
        links,
        [
            "sine.out -> pair.in",
            "pair.out -> console.in",
            "pair.a_out -> other.in"
        ]
    );
    assert_eq!(
        outer.connections[0].policy,
        Some(kairos_diagram::ReaderPolicy::NeverSkipping)
    );
    // The viewer of an exposed output follows it; every exposed output is one, so both stay.
    let viewed: Vec<&str> = outer.viewers.iter().map(|v| v.output.as_str()).collect();
    assert_eq!(viewed, ["pair.out", "pair.a_out"]);

    // Flattened, the diagram is the original one, its moved components under `pair/`.
    let subgraph_text = subgraph.to_ron();
    let flat = flatten(
        parse(&outer.to_ron()).unwrap(),
        Path::new("rig/main.ron"),
        &mut files(&[("pair.ron", &subgraph_text)]),
    )
    .unwrap();
    assert!(flat.parsed.validate(&common::library()).is_empty());
    let mut flat_links: Vec<String> = flat
        .parsed
        .diagram
        .connections
        .iter()
        .map(|c| format!("{} -> {}", c.from, c.to).replace("pair/", ""))
        .collect();
    let mut original_links: Vec<String> = original
        .connections
        .iter()
        .map(|c| format!("{} -> {}", c.from, c.to))
        .collect();
    flat_links.sort();
    original_links.sort();
    assert_eq!(flat_links, original_links);

    // Refused: nothing selected, a taken instance name, the clock source moved in.
    assert!(kairos_diagram::subgraph::extract(&original, &[], "pair", "pair.ron").is_err());
    let taken = kairos_diagram::subgraph::extract(&original, &ids, "console", "pair.ron").unwrap_err();
    assert_eq!(taken, ExtractError::InstanceNameTaken("console".to_owned()));
    assert_eq!(
        taken.to_string(),
        "'console' is taken: name the subgraph's instance otherwise"
    );
}

#[test]
fn an_instance_s_host_and_group_reach_its_parts_and_its_own_groups_stay_its_copy_s() {
    let grouped = r#"Diagram(format: 1,
    exposes: Exposes(inputs: {"in": "first.in"}, outputs: {"out": "second.out"}),
    groups: {"pair": (priority: 20)},
    components: [
        Component(id: "first", type: "core.gain", group: "pair"),
        Component(id: "second", type: "core.gain"),
    ],
    connections: [Connection(from: "first.out", to: "second.in")],
)"#;
    let sequential = r#"Diagram(format: 1, sequential: true,
    exposes: Exposes(inputs: {"in": "only.in"}),
    components: [Component(id: "only", type: "core.console")],
)"#;
    let main = r#"Diagram(format: 1,
    hosts: {"car": Host(endpoint: "ws://10.0.0.2:7400")},
    components: [
        Component(id: "sine", type: "core.sine"),
        Component(id: "a", type: "grouped.ron", host: "car", group: "fast"),
        Component(id: "b", type: "grouped.ron"),
        Component(id: "log", type: "sequential.ron"),
    ],
    connections: [
        Connection(from: "sine.out", to: "a.in"),
        Connection(from: "a.out", to: "b.in"),
        Connection(from: "b.out", to: "log.in"),
    ],
)"#;
    let flat = flattened(main, &[("grouped.ron", grouped), ("sequential.ron", sequential)]).unwrap();
    let diagram = &flat.parsed.diagram;
    let placed = |id: &str| {
        let c = diagram.component(id).unwrap();
        (c.host.clone(), c.group.clone())
    };
    let car = Some("car".to_owned());
    assert_eq!(placed("a/first"), (car.clone(), Some("a/pair".to_owned())));
    assert_eq!(placed("a/second"), (car, Some("fast".to_owned())));
    assert_eq!(placed("b/first"), (None, Some("b/pair".to_owned())));
    assert_eq!(placed("b/second"), (None, None));
    assert_eq!(placed("log/only"), (None, Some("log/sequential".to_owned())));
    assert_eq!(diagram.groups["a/pair"].priority, Some(20));
    assert_eq!(diagram.groups["b/pair"].priority, Some(20));
}
