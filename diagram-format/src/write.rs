//! Writing a diagram as canonical RON text: the same diagram always gives the same bytes, so files
//! diff well under version control and `write(read(write(d))) == write(d)`.

use std::cmp::Ordering;
use std::fmt::{self, Write as _};
use std::path::Path;

use crate::library::{ReaderPolicy, Value};
use crate::model::{ComponentInstance, Connection, Diagram, OutputSettings, PackRequirement, ThreadSettings};

impl Diagram {
    /// The diagram as canonical RON text.
    ///
    /// Packs are sorted by name, components by id and connections by (from, to); fields holding their
    /// default are left out; floats are written so they read back to the same bits and always look like
    /// floats (`2.0`).
    pub fn to_ron(&self) -> String {
        CanonicalRon(self).to_string()
    }

    /// Sorts packs, components and connections into the order [`Diagram::to_ron`] writes them, so that a
    /// diagram compares equal to what reading its text gives back.
    pub fn sort_canonically(&mut self) {
        self.packs.sort_by(compare_packs);
        self.components.sort_by(compare_components);
        self.connections.sort_by(compare_connections);
    }
}

/// Writes `diagram` to `path` as canonical RON text.
pub fn save(path: &Path, diagram: &Diagram) -> std::io::Result<()> {
    std::fs::write(path, diagram.to_ron())
}

fn compare_packs(a: &PackRequirement, b: &PackRequirement) -> Ordering {
    (&a.name, &a.version).cmp(&(&b.name, &b.version))
}

fn compare_components(a: &ComponentInstance, b: &ComponentInstance) -> Ordering {
    a.id.cmp(&b.id)
}

fn compare_connections(a: &Connection, b: &Connection) -> Ordering {
    // Past (from, to) the remaining fields only break ties, so the order never depends on the input's.
    let key = |c: &Connection| (c.policy.map(ReaderPolicy::name), c.buffer_size, c.subsampling);
    (&a.from, &a.to)
        .cmp(&(&b.from, &b.to))
        .then_with(|| key(a).cmp(&key(b)))
}

/// `Display` does the writing so that every write can use `?` and none can panic.
struct CanonicalRon<'d>(&'d Diagram);

impl fmt::Display for CanonicalRon<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let diagram = self.0;
        f.write_str("// Kairos diagram\nDiagram(\n")?;
        writeln!(f, "    format: {},", diagram.format)?;
        if let Some(source) = &diagram.clock_source {
            writeln!(f, "    clock_source: {},", Quoted(source))?;
        }
        if !diagram.hosts.is_empty() {
            f.write_str("    hosts: {\n")?;
            for (name, host) in &diagram.hosts {
                write!(
                    f,
                    "        {}: Host(endpoint: {}",
                    Quoted(name),
                    Quoted(&host.endpoint)
                )?;
                if let Some(token_file) = &host.token_file {
                    write!(f, ", token_file: {}", Quoted(token_file))?;
                }
                if let Some(zenoh) = &host.zenoh {
                    write!(f, ", zenoh: {}", Quoted(zenoh))?;
                }
                if let Some(certificate) = &host.certificate {
                    write!(f, ", certificate: {}", Quoted(certificate))?;
                }
                if let Some(ride_out_s) = host.ride_out_s {
                    write!(f, ", ride_out_s: {ride_out_s:?}")?;
                }
                if let Some(ride_out_mb) = host.ride_out_mb {
                    write!(f, ", ride_out_mb: {ride_out_mb:?}")?;
                }
                f.write_str("),\n")?;
            }
            f.write_str("    },\n")?;
        }
        if diagram.sequential {
            f.write_str("    sequential: true,\n")?;
        }
        if !diagram.groups.is_empty() {
            f.write_str("    groups: {\n")?;
            for (name, settings) in &diagram.groups {
                writeln!(f, "        {}: {},", Quoted(name), RonThread(settings))?;
            }
            f.write_str("    },\n")?;
        }

        if let Some(exposes) = &diagram.exposes {
            write_exposes(f, exposes)?;
        }

        let mut packs: Vec<&PackRequirement> = diagram.packs.iter().collect();
        packs.sort_by(|a, b| compare_packs(a, b));
        write_list(f, "packs", &packs, |f, pack| {
            write!(
                f,
                "Pack(name: {}, version: {})",
                Quoted(&pack.name),
                Quoted(&pack.version)
            )
        })?;

        let mut components: Vec<&ComponentInstance> = diagram.components.iter().collect();
        components.sort_by(|a, b| compare_components(a, b));
        write_list(f, "components", &components, |f, component| {
            write_component(f, component)
        })?;

        let mut connections: Vec<&Connection> = diagram.connections.iter().collect();
        connections.sort_by(|a, b| compare_connections(a, b));
        write_list(f, "connections", &connections, |f, connection| {
            write_connection(f, connection)
        })?;
        // In the order the studio opened them (the dock's order), absent when there are none.
        if !diagram.viewers.is_empty() {
            write_list(f, "viewers", &diagram.viewers, |f, viewer| {
                write!(
                    f,
                    "Viewer(output: {}, kind: {}",
                    Quoted(&viewer.output),
                    Quoted(&viewer.kind)
                )?;
                if !viewer.docked {
                    f.write_str(", docked: false")?;
                }
                if !viewer.also.is_empty() {
                    f.write_str(", also: [")?;
                    for (index, output) in viewer.also.iter().enumerate() {
                        if index > 0 {
                            f.write_str(", ")?;
                        }
                        write!(f, "{}", Quoted(output))?;
                    }
                    f.write_str("]")?;
                }
                if let Some(area) = viewer.area {
                    write!(f, ", area: {area}")?;
                }
                if let Some(share) = viewer.share {
                    write!(f, ", share: {share:?}")?;
                }
                f.write_str(")")
            })?;
        }
        f.write_str(")\n")
    }
}

/// `    name: [\n        item,\n    ],` or `    name: [],` when empty.
fn write_list<T>(
    f: &mut fmt::Formatter<'_>,
    name: &str,
    items: &[T],
    mut write_item: impl FnMut(&mut fmt::Formatter<'_>, &T) -> fmt::Result,
) -> fmt::Result {
    if items.is_empty() {
        return writeln!(f, "    {name}: [],");
    }
    writeln!(f, "    {name}: [")?;
    for item in items {
        f.write_str("        ")?;
        write_item(f, item)?;
        f.write_str(",\n")?;
    }
    f.write_str("    ],\n")
}

fn write_component(f: &mut fmt::Formatter<'_>, component: &ComponentInstance) -> fmt::Result {
    const FIELD: &str = "            ";
    const ENTRY: &str = "                ";
    f.write_str("Component(\n")?;
    writeln!(f, "{FIELD}id: {},", Quoted(&component.id))?;
    writeln!(f, "{FIELD}type: {},", Quoted(&component.type_name))?;
    if let Some(host) = &component.host {
        writeln!(f, "{FIELD}host: {},", Quoted(host))?;
    }
    if let Some(group) = &component.group {
        writeln!(f, "{FIELD}group: {},", Quoted(group))?;
    }
    let position = component.position;
    // Compare bits, not values: `-0.0` is not the default and must survive a round trip.
    if position.x.to_bits() != 0 || position.y.to_bits() != 0 {
        writeln!(f, "{FIELD}position: (x: {:?}, y: {:?}),", position.x, position.y)?;
    }
    if !component.properties.is_empty() {
        writeln!(f, "{FIELD}properties: {{")?;
        for (name, value) in &component.properties {
            writeln!(f, "{ENTRY}{}: {},", Quoted(name), RonValue(value))?;
        }
        writeln!(f, "{FIELD}}},")?;
    }
    if !component.outputs.is_empty() {
        writeln!(f, "{FIELD}outputs: {{")?;
        for (name, settings) in &component.outputs {
            writeln!(f, "{ENTRY}{}: {},", Quoted(name), RonOutputSettings(settings))?;
        }
        writeln!(f, "{FIELD}}},")?;
    }
    if !component.thread.is_default() {
        writeln!(f, "{FIELD}thread: {},", RonThread(&component.thread))?;
    }
    f.write_str("        )")
}

fn write_connection(f: &mut fmt::Formatter<'_>, connection: &Connection) -> fmt::Result {
    write!(
        f,
        "Connection(from: {}, to: {}",
        Quoted(&connection.from.to_string()),
        Quoted(&connection.to.to_string())
    )?;
    if let Some(policy) = connection.policy {
        write!(f, ", policy: {policy}")?;
    }
    if let Some(size) = connection.buffer_size {
        write!(f, ", buffer_size: {size}")?;
    }
    if let Some(subsampling) = connection.subsampling {
        write!(f, ", subsampling: {subsampling}")?;
    }
    f.write_char(')')
}

/// A string literal that reads back as the same string.
struct Quoted<'s>(&'s str);

impl fmt::Display for Quoted<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_char('"')?;
        for c in self.0.chars() {
            match c {
                '"' => f.write_str("\\\"")?,
                '\\' => f.write_str("\\\\")?,
                '\n' => f.write_str("\\n")?,
                '\r' => f.write_str("\\r")?,
                '\t' => f.write_str("\\t")?,
                // Other control characters would be invisible or break lines: escape them.
                c if c.is_control() => write!(f, "\\u{{{:x}}}", u32::from(c))?,
                c => f.write_char(c)?,
            }
        }
        f.write_char('"')
    }
}

struct RonValue<'v>(&'v Value);

impl fmt::Display for RonValue<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.0 {
            Value::Bool(value) => write!(f, "{value}"),
            Value::I64(value) => write!(f, "{value}"),
            // `{:?}` prints the shortest text that reads back to the same bits, with `.0` when whole.
            Value::F64(value) => write!(f, "{value:?}"),
            Value::Text(text) => write!(f, "{}", Quoted(text)),
        }
    }
}

struct RonOutputSettings<'s>(&'s OutputSettings);

impl fmt::Display for RonOutputSettings<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut fields = Vec::new();
        if let Some(size) = self.0.buffer_size {
            fields.push(format!("buffer_size: {size}"));
        }
        if let Some(subsampling) = self.0.subsampling {
            fields.push(format!("subsampling: {subsampling}"));
        }
        write!(f, "({})", fields.join(", "))
    }
}

struct RonThread<'t>(&'t ThreadSettings);

impl fmt::Display for RonThread<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut fields = Vec::new();
        if let Some(priority) = self.0.priority {
            fields.push(format!("priority: {priority}"));
        }
        if !self.0.affinity.is_empty() {
            let cores: Vec<String> = self.0.affinity.iter().map(ToString::to_string).collect();
            fields.push(format!("affinity: [{}]", cores.join(", ")));
        }
        write!(f, "({})", fields.join(", "))
    }
}

/// `exposes: Exposes(...)`, each map on lines of its own; an input or property feeding one inner one is
/// written as a string, one feeding several as a list.
fn write_exposes(f: &mut fmt::Formatter<'_>, exposes: &crate::model::Exposes) -> fmt::Result {
    f.write_str("    exposes: Exposes(\n")?;
    if !exposes.inputs.is_empty() {
        write_targets(f, "inputs", &exposes.inputs)?;
    }
    if !exposes.outputs.is_empty() {
        f.write_str("        outputs: {\n")?;
        for (name, port) in &exposes.outputs {
            writeln!(f, "            {}: {},", Quoted(name), Quoted(&port.to_string()))?;
        }
        f.write_str("        },\n")?;
    }
    if !exposes.properties.is_empty() {
        write_targets(f, "properties", &exposes.properties)?;
    }
    f.write_str("    ),\n")
}

fn write_targets(
    f: &mut fmt::Formatter<'_>,
    field: &str,
    targets_by_name: &std::collections::BTreeMap<String, Vec<crate::model::PortRef>>,
) -> fmt::Result {
    writeln!(f, "        {field}: {{")?;
    for (name, targets) in targets_by_name {
        write!(f, "            {}: ", Quoted(name))?;
        if let [one] = targets.as_slice() {
            write!(f, "{}", Quoted(&one.to_string()))?;
        } else {
            f.write_str("[")?;
            for (index, target) in targets.iter().enumerate() {
                if index > 0 {
                    f.write_str(", ")?;
                }
                write!(f, "{}", Quoted(&target.to_string()))?;
            }
            f.write_str("]")?;
        }
        f.write_str(",\n")?;
    }
    f.write_str("        },\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strings_are_escaped() {
        assert_eq!(Quoted("a\"b\\c\nd\u{1}é").to_string(), r#""a\"b\\c\nd\u{1}é""#);
    }

    #[test]
    fn floats_always_look_like_floats() {
        let text = |v: f64| RonValue(&Value::F64(v)).to_string();
        assert_eq!(text(2.0), "2.0");
        assert_eq!(text(1e20), "1e20");
        assert_eq!(text(-0.0), "-0.0");
        assert_eq!(RonValue(&Value::I64(2)).to_string(), "2");
    }

    #[test]
    fn empty_diagram() {
        assert_eq!(
            Diagram::default().to_ron(),
            "// Kairos diagram\nDiagram(\n    format: 1,\n    packs: [],\n    components: [],\n    connections: [],\n)\n"
        );
    }
}
