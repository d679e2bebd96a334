//! Edits made while a diagram runs that the runtime does not have yet: a reader policy, a buffer size, a
//! property that is not live, a component or connection added or removed. The runtime applies them when
//! the diagram is deployed again, so the studio says which they are and offers Restart, rather than
//! showing on the canvas what the runtime does not do.

use kairos_diagram::{Connection, Diagram};

/// The edits of `now` that the `deployed` diagram lacks, in words; where things are drawn is left out.
pub fn not_applied(deployed: &Diagram, now: &Diagram) -> Vec<String> {
    let mut edits = Vec::new();
    for component in &now.components {
        let Some(before) = deployed.component(&component.id) else {
            edits.push(format!("{} added", component.id));
            continue;
        };
        if before.type_name != component.type_name {
            edits.push(format!("{}: now a {}", component.id, component.type_name));
            continue;
        }
        let names = before.properties.keys().chain(component.properties.keys());
        let mut seen = std::collections::BTreeSet::new();
        for name in names {
            if !seen.insert(name) {
                continue;
            }
            let (old, new) = (before.properties.get(name), component.properties.get(name));
            if old != new {
                let new = new.map_or_else(|| "its default".to_owned(), ToString::to_string);
                edits.push(format!("{}.{name} = {new}", component.id));
            }
        }
        if before.outputs != component.outputs {
            edits.push(format!("{}: output buffers", component.id));
        }
        if before.thread != component.thread {
            edits.push(format!("{}: thread settings", component.id));
        }
    }
    for component in &deployed.components {
        if now.component(&component.id).is_none() {
            edits.push(format!("{} removed", component.id));
        }
    }
    let find = |diagram: &'_ Diagram, c: &Connection| -> Option<Connection> {
        diagram
            .connections
            .iter()
            .find(|d| d.from == c.from && d.to == c.to)
            .cloned()
    };
    for connection in &now.connections {
        match find(deployed, connection) {
            None => edits.push(format!("{} -> {} added", connection.from, connection.to)),
            Some(before) => {
                let reader = |c: &Connection| (c.policy, c.buffer_size, c.subsampling);
                if reader(&before) != reader(connection) {
                    edits.push(format!(
                        "{} -> {}: reader {}",
                        connection.from,
                        connection.to,
                        describe_reader(connection)
                    ));
                }
            }
        }
    }
    for connection in &deployed.connections {
        if find(now, connection).is_none() {
            edits.push(format!("{} -> {} removed", connection.from, connection.to));
        }
    }
    edits
}

/// A connection's reader settings in a few words.
fn describe_reader(connection: &Connection) -> String {
    let mut words = vec![
        connection
            .policy
            .map_or_else(|| "default policy".to_owned(), |p| p.name().to_owned()),
    ];
    if let Some(size) = connection.buffer_size {
        words.push(format!("buffer {size}"));
    }
    if let Some(n) = connection.subsampling.filter(|n| *n > 1) {
        words.push(format!("1 in {n}"));
    }
    words.join(", ")
}

#[cfg(test)]
mod tests {
    use kairos_diagram::{ReaderPolicy, Value};

    use super::not_applied;

    const DIAGRAM: &str = "Diagram(format: 1, components: [\
        Component(id: \"counter1\", type: \"core.counter\", position: (x: 0.0, y: 0.0)), \
        Component(id: \"console1\", type: \"core.console\", position: (x: 300.0, y: 0.0))], \
        connections: [Connection(from: \"counter1.out\", to: \"console1.in\")])";

    #[test]
    fn reader_settings_properties_and_structure_are_told_but_not_positions() {
        let deployed = kairos_diagram::parse(DIAGRAM).unwrap().diagram;
        let mut now = deployed.clone();
        assert!(not_applied(&deployed, &now).is_empty());
        now.components[0].position.x = 99.0;
        assert!(
            not_applied(&deployed, &now).is_empty(),
            "a move is not an edit the runtime needs"
        );
        now.connections[0].policy = Some(ReaderPolicy::LastOrNext);
        now.connections[0].buffer_size = Some(8);
        now.components[0]
            .properties
            .insert("step".to_owned(), Value::I64(2));
        now.components.pop();
        assert_eq!(
            not_applied(&deployed, &now),
            [
                "counter1.step = 2",
                "console1 removed",
                "counter1.out -> console1.in: reader LastOrNext, buffer 8"
            ]
        );
    }
}
