//! What the engine's test files share: building diagrams of the core pack, and waiting for counts.

use std::thread::sleep;
use std::time::{Duration, Instant};

use kairos_diagram::{ComponentInstance, Connection, Diagram, PackRequirement, PortRef, Value};
use kairos_runtime::{ComponentStats, StatsSnapshot};

/// A component of type `type_name` with these property values.
pub fn component(id: &str, type_name: &str, properties: &[(&str, Value)]) -> ComponentInstance {
    let mut instance = ComponentInstance::new(id, type_name);
    for (name, value) in properties {
        instance.properties.insert((*name).to_owned(), value.clone());
    }
    instance
}

/// `from` (`component.output`) to `to` (`component.input`).
pub fn connect(from: &str, to: &str) -> Connection {
    Connection::new(PortRef::parse(from).unwrap(), PortRef::parse(to).unwrap())
}

/// A diagram needing the core pack.
pub fn diagram(components: Vec<ComponentInstance>, connections: Vec<Connection>) -> Diagram {
    Diagram {
        packs: vec![PackRequirement {
            name: "core".into(),
            version: "^0.1".into(),
        }],
        components,
        connections,
        ..Diagram::default()
    }
}

/// `id`'s statistics in `snapshot`.
pub fn stats<'s>(snapshot: &'s StatsSnapshot, id: &str) -> &'s ComponentStats {
    snapshot.components.iter().find(|c| c.id == id).unwrap()
}

/// Waits until `done` holds: at once on a fast machine, failing only after 30 s. Counts that must grow
/// are waited for, never timed: speed is for the benchmarks.
pub fn eventually(what: &str, mut done: impl FnMut() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(30);
    while !done() {
        assert!(Instant::now() < deadline, "not within 30 s: {what}");
        sleep(Duration::from_millis(5));
    }
}
