//! Reading a diagram from its RON text, remembering where everything was so that later checks can
//! point at the offending token.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use crate::diagnostic::{Diagnostic, DiagnosticCode, LineIndex, Location, did_you_mean, render_all};
use crate::library::{LibraryInfo, ReaderPolicy, Value};
use crate::model::{
    ComponentInstance, Connection, Diagram, Exposes, HostSpec, OutputSettings, PackRequirement, PortRef,
    Position, ThreadSettings, ViewerSpec,
};
use crate::ron_syntax::{Field, Node, NodeKind, Span, parse_document};

/// Where the parts of a parsed diagram are in its source text.
///
/// Entry `i` of each list describes item `i` of the matching list of the diagram as it was parsed; after
/// the diagram is edited (or sorted) the map no longer fits it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SourceMap {
    /// The `Diagram` keyword (or its opening parenthesis).
    pub diagram: Location,
    /// The format version's value.
    pub format: Location,
    /// One entry per pack requirement.
    pub packs: Vec<PackLocations>,
    /// One entry per component instance.
    pub components: Vec<ComponentLocations>,
    /// One entry per connection.
    pub connections: Vec<ConnectionLocations>,
    /// The clock source's value, when given.
    pub clock_source: Option<Location>,
    /// Each host's name and endpoint.
    pub hosts: BTreeMap<String, HostLocations>,
    /// Each execution group's name in the `groups` section, and where its priority is.
    pub groups: BTreeMap<String, GroupLocations>,
    /// The `sequential` switch's value, when given.
    pub sequential: Option<Location>,
    /// Where each exposed name and its inner targets are, when the diagram exposes any.
    pub exposes: Option<ExposesLocations>,
}

/// Where a subgraph's exposed names are: each name's key, and each inner port or property it names.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ExposesLocations {
    /// Each exposed input: its name, and each inner input's string.
    pub inputs: BTreeMap<String, (Location, Vec<Location>)>,
    /// Each exposed output: its name, and the inner output's string.
    pub outputs: BTreeMap<String, EntryLocations>,
    /// Each exposed property: its name, and each inner property's string.
    pub properties: BTreeMap<String, (Location, Vec<Location>)>,
}

/// Where an execution group of the `groups` section is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GroupLocations {
    /// Its name (the map's key).
    pub name: Location,
    /// Its thread priority's value, when given.
    pub priority: Option<Location>,
}

/// Where a host of the `hosts` section is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HostLocations {
    /// Its name (the map's key).
    pub name: Location,
    /// Its endpoint's value.
    pub endpoint: Location,
    /// Its Zenoh endpoint's value, when given.
    pub zenoh: Option<Location>,
}

/// Where a pack requirement is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PackLocations {
    /// The `Pack` keyword.
    pub pack: Location,
    /// The name's string.
    pub name: Location,
    /// The version requirement's string.
    pub version: Location,
}

/// Where a component instance is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ComponentLocations {
    /// The `Component` keyword.
    pub component: Location,
    /// The id's string.
    pub id: Location,
    /// The type's string.
    pub type_name: Location,
    /// The position's value, when given.
    pub position: Option<Location>,
    /// Each property's key and value.
    pub properties: BTreeMap<String, EntryLocations>,
    /// Each output's key and settings.
    pub outputs: BTreeMap<String, OutputLocations>,
    /// The thread priority's value, when given.
    pub priority: Option<Location>,
    /// The host's value, when given.
    pub host: Option<Location>,
    /// The execution group's value, when given.
    pub group: Option<Location>,
}

/// Where a map entry's key and value are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EntryLocations {
    /// The key.
    pub key: Location,
    /// The value.
    pub value: Location,
}

/// Where an output's settings are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OutputLocations {
    /// The output's name, as the map key.
    pub key: Location,
    /// The buffer size's value, when given.
    pub buffer_size: Option<Location>,
    /// The subsampling's value, when given.
    pub subsampling: Option<Location>,
}

/// Where a connection is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConnectionLocations {
    /// The `Connection` keyword.
    pub connection: Location,
    /// The `from` port's string.
    pub from: Location,
    /// The `to` port's string.
    pub to: Location,
    /// The policy's value, when given.
    pub policy: Option<Location>,
    /// The buffer size's value, when given.
    pub buffer_size: Option<Location>,
    /// The subsampling's value, when given.
    pub subsampling: Option<Location>,
}

/// A diagram read from text, with where its parts were.
#[derive(Debug, Clone, PartialEq)]
pub struct ParsedDiagram {
    /// The diagram.
    pub diagram: Diagram,
    /// Where its parts are in the text it was read from.
    pub source_map: SourceMap,
}

impl ParsedDiagram {
    /// Checks the diagram against a component library; see [`crate::validate()`].
    pub fn validate(&self, library: &LibraryInfo) -> Vec<Diagnostic> {
        crate::validate::validate(&self.diagram, Some(&self.source_map), library)
    }

    /// Like [`ParsedDiagram::validate`], with the descriptors of instances whose ports depend on their
    /// properties; see [`crate::validate_with()`].
    pub fn validate_with(&self, library: &LibraryInfo, instances: &crate::InstanceInfos) -> Vec<Diagnostic> {
        crate::validate::validate_with(&self.diagram, Some(&self.source_map), library, instances)
    }
}

/// Reads a diagram from its RON text.
///
/// A syntax error stops the reading and is the only diagnostic; structural problems (a missing or
/// unknown field, a value of the wrong type, a key given twice) are all reported together. Whether the
/// diagram makes sense for a component library is [`crate::validate()`]'s business.
pub fn parse(source: &str) -> Result<ParsedDiagram, Vec<Diagnostic>> {
    let lines = LineIndex::new(source);
    let root = parse_document(source).map_err(|error| {
        vec![
            Diagnostic::error(error.code, error.message)
                .at(Some(lines.location(error.span.start, error.span.end))),
        ]
    })?;
    let mut reader = Reader {
        lines,
        diagnostics: Vec::new(),
    };
    let parsed = reader.diagram(&root);
    match parsed {
        Some(parsed) if reader.diagnostics.is_empty() => Ok(parsed),
        _ => {
            let mut diagnostics = reader.diagnostics;
            diagnostics.sort_by_key(|d| d.location.map(|l| l.offset));
            Err(diagnostics)
        }
    }
}

impl Diagram {
    /// Reads a diagram from its RON text, dropping the source map; see [`parse`].
    pub fn from_ron(source: &str) -> Result<Diagram, Vec<Diagnostic>> {
        parse(source).map(|parsed| parsed.diagram)
    }
}

/// Why a diagram file could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    /// The file could not be read.
    #[error("cannot read {}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The file is not a valid diagram.
    #[error("{}", summarize(path, diagnostics))]
    Invalid {
        /// The file.
        path: PathBuf,
        /// Its text, for rendering the diagnostics.
        text: String,
        /// Every problem found.
        diagnostics: Vec<Diagnostic>,
    },
}

impl LoadError {
    /// The full report: rustc-like rendering of every diagnostic, or the I/O error.
    pub fn render(&self) -> String {
        match self {
            LoadError::Io { .. } => format!("error: {self}\n"),
            LoadError::Invalid {
                path,
                text,
                diagnostics,
            } => render_all(diagnostics, &path.display().to_string(), text),
        }
    }
}

fn summarize(path: &Path, diagnostics: &[Diagnostic]) -> String {
    let first = diagnostics.first().map(ToString::to_string).unwrap_or_default();
    match diagnostics.len() {
        0 | 1 => format!("{}:{first}", path.display()),
        n => format!("{}:{first} (and {} more problems)", path.display(), n - 1),
    }
}

/// Reads and parses a diagram file; returns its text (for rendering later diagnostics) with the result.
pub fn load(path: &Path) -> Result<(String, ParsedDiagram), LoadError> {
    let bytes = std::fs::read(path).map_err(|source| LoadError::Io {
        path: path.to_owned(),
        source,
    })?;
    let text = match String::from_utf8(bytes) {
        Ok(text) => text,
        Err(error) => return Err(not_utf8(path, &error)),
    };
    match parse(&text) {
        Ok(parsed) => Ok((text, parsed)),
        Err(diagnostics) => Err(LoadError::Invalid {
            path: path.to_owned(),
            text,
            diagnostics,
        }),
    }
}

/// A file that is not UTF-8 text, located at its first bad byte (rendered over the text up to there).
fn not_utf8(path: &Path, error: &std::string::FromUtf8Error) -> LoadError {
    let good = error.utf8_error().valid_up_to();
    let bytes = error.as_bytes();
    let bad = bytes.get(good).copied().unwrap_or_default();
    // The valid part, and the bad byte shown as the replacement character, so the location renders.
    let text = format!(
        "{}\u{fffd}",
        String::from_utf8_lossy(bytes.get(..good).unwrap_or_default())
    );
    let location = LineIndex::new(&text).location(good, good + '\u{fffd}'.len_utf8());
    LoadError::Invalid {
        path: path.to_owned(),
        diagnostics: vec![
            Diagnostic::error(
                DiagnosticCode::Syntax,
                format!(
                    "the file is not UTF-8 text: byte 0x{bad:02x} here cannot be read; save the file as \
                     UTF-8 (most editors offer it under Save as or Encoding)"
                ),
            )
            .at(Some(location)),
        ],
        text,
    }
}

/// A value was present but did not read; the problem is already among the diagnostics.
struct Reported;

/// Converts the value tree into the model, collecting every structural problem.
struct Reader<'s> {
    lines: LineIndex<'s>,
    diagnostics: Vec<Diagnostic>,
}

/// The fields of one struct, checked for unknown and duplicate names.
struct Fields<'n> {
    type_name: &'static str,
    head: Span,
    accepted: Vec<&'n Field>,
}

impl<'n> Fields<'n> {
    /// The field's value; `None` when absent or written `None`. A `Some(x)` gives `x`.
    fn optional(&self, name: &str) -> Option<&'n Node> {
        let node = &self.accepted.iter().find(|f| f.name == name)?.value;
        match &node.kind {
            NodeKind::Ident(ident) if ident == "None" => None,
            NodeKind::Tuple {
                name: Some(wrapper),
                items,
            } if wrapper == "Some" && items.len() == 1 => items.first(),
            _ => Some(node),
        }
    }
}

/// Which kind of integer a field holds, for range checks and messages.
trait IntegerField: TryFrom<i128> {
    const DESCRIPTION: &'static str;
}

impl IntegerField for u8 {
    const DESCRIPTION: &'static str = "an integer in 0..=255";
}

impl IntegerField for u32 {
    const DESCRIPTION: &'static str = "a non-negative 32-bit integer";
}

impl IntegerField for usize {
    const DESCRIPTION: &'static str = "a non-negative integer";
}

impl IntegerField for i64 {
    const DESCRIPTION: &'static str = "a 64-bit integer";
}

impl Reader<'_> {
    fn location(&self, span: Span) -> Location {
        self.lines.location(span.start, span.end)
    }

    fn report(&mut self, code: DiagnosticCode, span: Span, message: impl Into<String>) {
        let diagnostic = Diagnostic::error(code, message).at(Some(self.location(span)));
        self.diagnostics.push(diagnostic);
    }

    fn wrong_type(&mut self, node: &Node, expected: &str) {
        let message = format!("expected {expected}, found {}", node.describe());
        self.report(DiagnosticCode::WrongType, node.head, message);
    }

    /// Opens `TypeName(...)` (or an anonymous `(...)`), reporting unknown and repeated fields.
    fn fields<'n>(&mut self, node: &'n Node, type_name: &'static str, known: &[&str]) -> Option<Fields<'n>> {
        let NodeKind::Struct { name, fields } = &node.kind else {
            if matches!(node.kind, NodeKind::Tuple { .. }) {
                let example = known.first().copied().unwrap_or("name");
                let message = format!("expected named fields in {type_name}(...), such as '{example}: ...'");
                self.report(DiagnosticCode::WrongType, node.head, message);
            } else {
                self.wrong_type(node, &format!("{type_name}(...)"));
            }
            return None;
        };
        if let Some(name) = name.as_deref().filter(|n| *n != type_name) {
            let message = format!("expected {type_name}(...), found {name}(...)");
            let diagnostic = Diagnostic::error(DiagnosticCode::WrongType, message)
                .at(Some(self.location(node.head)))
                .with_suggestion(did_you_mean(name, [type_name]));
            self.diagnostics.push(diagnostic);
            return None;
        }
        let mut accepted: Vec<&Field> = Vec::new();
        for field in fields {
            if let Some(first) = accepted.iter().find(|f| f.name == field.name) {
                let diagnostic = Diagnostic::error(
                    DiagnosticCode::DuplicateKey,
                    format!("field '{}' is given twice in {type_name}", field.name),
                )
                .at(Some(self.location(field.name_span)))
                .with_note("first given here", Some(self.location(first.name_span)));
                self.diagnostics.push(diagnostic);
            } else if known.contains(&field.name.as_str()) {
                accepted.push(field);
            } else {
                let suggestion = did_you_mean(&field.name, known.iter().copied())
                    .unwrap_or_else(|| format!("the fields of {type_name} are: {}", known.join(", ")));
                let diagnostic = Diagnostic::error(
                    DiagnosticCode::UnknownField,
                    format!("unknown field '{}' in {type_name}", field.name),
                )
                .at(Some(self.location(field.name_span)))
                .with_suggestion(Some(suggestion));
                self.diagnostics.push(diagnostic);
            }
        }
        Some(Fields {
            type_name,
            head: node.head,
            accepted,
        })
    }

    /// The field's value, or a "missing field" report.
    fn required<'n>(&mut self, fields: &Fields<'n>, name: &str) -> Option<&'n Node> {
        let node = fields.optional(name);
        if node.is_none() {
            let message = format!("{} is missing field '{name}'", fields.type_name);
            self.report(DiagnosticCode::MissingField, fields.head, message);
        }
        node
    }

    /// Reads an optional field's value: `Ok(None)` when absent.
    fn optional<T>(
        &mut self,
        node: Option<&Node>,
        read: impl FnOnce(&mut Self, &Node) -> Option<T>,
    ) -> Result<Option<T>, Reported> {
        match node {
            None => Ok(None),
            Some(node) => read(self, node).map(Some).ok_or(Reported),
        }
    }

    fn text(&mut self, node: &Node) -> Option<String> {
        if let NodeKind::Text(text) = &node.kind {
            Some(text.clone())
        } else {
            self.wrong_type(node, "a string");
            None
        }
    }

    fn integer<T: IntegerField>(&mut self, node: &Node) -> Option<T> {
        let NodeKind::Integer(value) = node.kind else {
            self.wrong_type(node, T::DESCRIPTION);
            return None;
        };
        let converted = T::try_from(value).ok();
        if converted.is_none() {
            let message = format!("expected {}, found {value}", T::DESCRIPTION);
            self.report(DiagnosticCode::WrongType, node.span, message);
        }
        converted
    }

    fn float32(&mut self, node: &Node) -> Option<f32> {
        let parsed = match &node.kind {
            NodeKind::Float(text) => text.parse::<f32>().ok(),
            // Whole canvas coordinates are often typed without a fraction.
            NodeKind::Integer(value) => Some(*value as f32),
            _ => None,
        };
        if parsed.is_none() {
            self.wrong_type(node, "a number");
        }
        parsed
    }

    /// A host's ride-out: seconds from 0 to [`crate::model::MAX_RIDE_OUT_S`].
    fn ride_out(&mut self, node: &Node) -> Option<f64> {
        self.bounded(
            node,
            "a number of seconds",
            crate::model::MAX_RIDE_OUT_S,
            |seconds, most| {
                format!("a ride-out of {seconds} s: it is from 0 (a cut loses what it cuts) to {most} s")
            },
        )
    }

    /// The memory a host's links keep for a cut: megabytes from 0 to [`crate::model::MAX_RIDE_OUT_MB`].
    fn ride_out_memory(&mut self, node: &Node) -> Option<f64> {
        self.bounded(
            node,
            "a number of megabytes",
            crate::model::MAX_RIDE_OUT_MB,
            |megabytes, most| {
                format!(
                    "a ride-out memory of {megabytes} MB: it is from 0 (nothing kept for a cut) to {most} MB"
                )
            },
        )
    }

    /// A number from 0 to `most`; out of range, the error `message(value, most)` at its place.
    fn bounded(
        &mut self,
        node: &Node,
        expected: &str,
        most: f64,
        message: impl Fn(f64, f64) -> String,
    ) -> Option<f64> {
        let value = match &node.kind {
            NodeKind::Float(text) => text.parse::<f64>().ok(),
            NodeKind::Integer(value) => Some(*value as f64),
            _ => None,
        };
        let Some(value) = value else {
            self.wrong_type(node, expected);
            return None;
        };
        if !(0.0..=most).contains(&value) {
            self.report(DiagnosticCode::InvalidSetting, node.head, message(value, most));
            return None;
        }
        Some(value)
    }

    fn list<'n>(&mut self, node: &'n Node) -> Option<&'n [Node]> {
        if let NodeKind::List(items) = &node.kind {
            Some(items)
        } else {
            self.wrong_type(node, "a list");
            None
        }
    }

    /// A `{ "key": value }` map: the entries with string keys, repeated keys reported.
    fn string_map<'n>(&mut self, node: &'n Node, what: &str) -> Vec<(String, Span, &'n Node)> {
        let NodeKind::Map(entries) = &node.kind else {
            self.wrong_type(node, &format!("a map of {what}s"));
            return Vec::new();
        };
        let mut accepted: Vec<(String, Span, &Node)> = Vec::new();
        // A set rather than a scan of `accepted`, so a hostile map with many keys stays linear.
        let mut first_spans: HashMap<&str, Span> = HashMap::new();
        for entry in entries {
            let NodeKind::Text(key) = &entry.key.kind else {
                let message = format!(
                    "expected a {what} name as a string, found {}",
                    entry.key.describe()
                );
                let quoted = match &entry.key.kind {
                    NodeKind::Ident(ident) => Some(format!("write it in quotes: \"{ident}\"")),
                    _ => None,
                };
                let diagnostic = Diagnostic::error(DiagnosticCode::WrongType, message)
                    .at(Some(self.location(entry.key.span)))
                    .with_suggestion(quoted);
                self.diagnostics.push(diagnostic);
                continue;
            };
            if let Some(first_span) = first_spans.get(key.as_str()) {
                let diagnostic = Diagnostic::error(
                    DiagnosticCode::DuplicateKey,
                    format!("{what} '{key}' is given twice"),
                )
                .at(Some(self.location(entry.key.span)))
                .with_note("first given here", Some(self.location(*first_span)));
                self.diagnostics.push(diagnostic);
                continue;
            }
            first_spans.insert(key, entry.key.span);
            accepted.push((key.clone(), entry.key.span, &entry.value));
        }
        accepted
    }

    fn diagram(&mut self, node: &Node) -> Option<ParsedDiagram> {
        let fields = self.fields(
            node,
            "Diagram",
            &[
                "format",
                "clock_source",
                "hosts",
                "packs",
                "components",
                "connections",
                "viewers",
                "sequential",
                "groups",
                "exposes",
            ],
        )?;
        let (hosts, host_locations) = fields
            .optional("hosts")
            .map(|n| self.hosts(n))
            .unwrap_or_default();
        let clock_source_node = fields.optional("clock_source");
        let clock_source = self.optional(clock_source_node, Self::text).ok()?;
        let format_node = self.required(&fields, "format");
        let format = format_node.and_then(|n| self.integer::<u32>(n));
        let packs = self.items(fields.optional("packs"), Self::pack);
        let components = self.items(fields.optional("components"), Self::component);
        let connections = self.items(fields.optional("connections"), Self::connection);
        let viewers = self.items(fields.optional("viewers"), Self::viewer);
        let sequential_node = fields.optional("sequential");
        let sequential = self.optional(sequential_node, Self::boolean);
        let (groups, group_locations) = fields
            .optional("groups")
            .map(|n| self.groups(n))
            .unwrap_or_default();
        let exposes = fields.optional("exposes").map(|n| self.exposes(n));
        let (exposes, exposes_locations) = match exposes {
            Some(read) => {
                let (exposes, locations) = read?;
                (Some(exposes), Some(locations))
            }
            None => (None, None),
        };
        let (format, format_node) = (format?, format_node?);
        let (packs, pack_locations) = packs.into_iter().unzip();
        let (components, component_locations) = components.into_iter().unzip();
        let (connections, connection_locations) = connections.into_iter().unzip();
        Some(ParsedDiagram {
            diagram: Diagram {
                format,
                packs,
                components,
                connections,
                clock_source,
                hosts,
                viewers,
                sequential: sequential.ok()?.unwrap_or(false),
                groups,
                exposes,
            },
            source_map: SourceMap {
                hosts: host_locations,
                groups: group_locations,
                sequential: sequential_node.map(|n| self.location(n.span)),
                exposes: exposes_locations,
                diagram: self.location(node.head),
                format: self.location(format_node.span),
                clock_source: clock_source_node.map(|n| self.location(n.span)),
                packs: pack_locations,
                components: component_locations,
                connections: connection_locations,
            },
        })
    }

    /// Reads every item of an optional list, keeping those that read without problems.
    fn items<T>(&mut self, node: Option<&Node>, read: fn(&mut Self, &Node) -> Option<T>) -> Vec<T> {
        let Some(items) = node.and_then(|n| self.list(n)) else {
            return Vec::new();
        };
        items.iter().filter_map(|item| read(self, item)).collect()
    }

    fn pack(&mut self, node: &Node) -> Option<(PackRequirement, PackLocations)> {
        let fields = self.fields(node, "Pack", &["name", "version"])?;
        let name_node = self.required(&fields, "name");
        let version_node = self.required(&fields, "version");
        let name = name_node.and_then(|n| self.text(n));
        let version = version_node.and_then(|n| self.text(n));
        let locations = PackLocations {
            pack: self.location(node.head),
            name: self.location(name_node?.span),
            version: self.location(version_node?.span),
        };
        Some((
            PackRequirement {
                name: name?,
                version: version?,
            },
            locations,
        ))
    }

    fn component(&mut self, node: &Node) -> Option<(ComponentInstance, ComponentLocations)> {
        let known = [
            "id",
            "type",
            "host",
            "position",
            "properties",
            "outputs",
            "thread",
            "group",
        ];
        let fields = self.fields(node, "Component", &known)?;
        let id_node = self.required(&fields, "id");
        let type_node = self.required(&fields, "type");
        let id = id_node.and_then(|n| self.text(n));
        let type_name = type_node.and_then(|n| self.text(n));
        let position_node = fields.optional("position");
        let position = position_node.map(|n| self.position(n));
        let properties = fields.optional("properties").map(|n| self.properties(n));
        let outputs = fields.optional("outputs").map(|n| self.outputs(n));
        let thread = fields.optional("thread").map(|n| self.thread(n));
        let host_node = fields.optional("host");
        let host = self.optional(host_node, Self::text).ok()?;
        let group_node = fields.optional("group");
        let group = self.optional(group_node, Self::text).ok()?;

        let (properties, property_locations) = properties.unwrap_or_default();
        let (outputs, output_locations) = outputs.unwrap_or_default();
        let (thread, priority) = match thread {
            Some(read) => read?,
            None => (ThreadSettings::default(), None),
        };
        let mut instance = ComponentInstance::new(id?, type_name?);
        instance.position = position.unwrap_or(Some(Position::default()))?;
        instance.properties = properties;
        instance.outputs = outputs;
        instance.thread = thread;
        instance.host = host;
        instance.group = group;
        let locations = ComponentLocations {
            host: host_node.map(|n| self.location(n.span)),
            group: group_node.map(|n| self.location(n.span)),
            component: self.location(node.head),
            id: self.location(id_node?.span),
            type_name: self.location(type_node?.span),
            position: position_node.map(|n| self.location(n.span)),
            properties: property_locations,
            outputs: output_locations,
            priority,
        };
        Some((instance, locations))
    }

    /// The `hosts` map: `"name": Host(endpoint: "ws://…", token_file: "…")`.
    fn hosts(&mut self, node: &Node) -> (BTreeMap<String, HostSpec>, BTreeMap<String, HostLocations>) {
        let mut hosts = BTreeMap::new();
        let mut locations = BTreeMap::new();
        for (name, name_span, value) in self.string_map(node, "host") {
            let Some(fields) = self.fields(
                value,
                "Host",
                &[
                    "endpoint",
                    "token_file",
                    "zenoh",
                    "certificate",
                    "ride_out_s",
                    "ride_out_mb",
                ],
            ) else {
                continue;
            };
            let endpoint_node = self.required(&fields, "endpoint");
            let endpoint = endpoint_node.and_then(|n| self.text(n));
            let Ok(token_file) = self.optional(fields.optional("token_file"), Self::text) else {
                continue;
            };
            let Ok(certificate) = self.optional(fields.optional("certificate"), Self::text) else {
                continue;
            };
            let Ok(ride_out_s) = self.optional(fields.optional("ride_out_s"), Self::ride_out) else {
                continue;
            };
            let Ok(ride_out_mb) = self.optional(fields.optional("ride_out_mb"), Self::ride_out_memory) else {
                continue;
            };
            let zenoh_node = fields.optional("zenoh");
            let Ok(zenoh) = self.optional(zenoh_node, Self::text) else {
                continue;
            };
            let (Some(endpoint), Some(endpoint_node)) = (endpoint, endpoint_node) else {
                continue;
            };
            locations.insert(
                name.clone(),
                HostLocations {
                    name: self.location(name_span),
                    endpoint: self.location(endpoint_node.span),
                    zenoh: zenoh_node.map(|n| self.location(n.span)),
                },
            );
            hosts.insert(
                name,
                HostSpec {
                    endpoint,
                    token_file,
                    zenoh,
                    certificate,
                    ride_out_s,
                    ride_out_mb,
                },
            );
        }
        (hosts, locations)
    }

    /// The `groups` map: `"name": (priority: Some(50), affinity: [1])`, a group's thread settings.
    fn groups(
        &mut self,
        node: &Node,
    ) -> (BTreeMap<String, ThreadSettings>, BTreeMap<String, GroupLocations>) {
        let mut groups = BTreeMap::new();
        let mut locations = BTreeMap::new();
        for (name, name_span, value) in self.string_map(node, "group") {
            let Some((settings, priority)) = self.thread(value) else {
                continue;
            };
            let name_location = self.location(name_span);
            locations.insert(
                name.clone(),
                GroupLocations {
                    name: name_location,
                    priority,
                },
            );
            groups.insert(name, settings);
        }
        (groups, locations)
    }

    /// `Exposes(inputs: {"image": ["convert.in", "overlay.image"]}, outputs: {"out": "overlay.out"},
    /// properties: {"gain": ["a.gain", "b.gain"]})`: an input or a property may feed several inner ones.
    fn exposes(&mut self, node: &Node) -> Option<(Exposes, ExposesLocations)> {
        let fields = self.fields(node, "Exposes", &["inputs", "outputs", "properties"])?;
        let mut exposes = Exposes::default();
        let mut locations = ExposesLocations::default();
        let mut complete = true;
        if let Some(map) = fields.optional("outputs") {
            for (name, name_span, value) in self.string_map(map, "output") {
                let Some(port) = self.port(value) else {
                    complete = false;
                    continue;
                };
                let entry = EntryLocations {
                    key: self.location(name_span),
                    value: self.location(value.span),
                };
                exposes.outputs.insert(name.clone(), port);
                locations.outputs.insert(name, entry);
            }
        }
        for (field, what) in [("inputs", "input"), ("properties", "property")] {
            let Some(map) = fields.optional(field) else {
                continue;
            };
            for (name, name_span, value) in self.string_map(map, what) {
                // One inner port or property as a string, or several as a list.
                let targets: Vec<&Node> = match &value.kind {
                    NodeKind::List(items) => items.iter().collect(),
                    _ => vec![value],
                };
                let mut inner = Vec::new();
                let mut places = Vec::new();
                for target in targets {
                    match self.port(target) {
                        Some(port) => {
                            inner.push(port);
                            places.push(self.location(target.span));
                        }
                        None => complete = false,
                    }
                }
                let (ports, place_map) = if field == "inputs" {
                    (&mut exposes.inputs, &mut locations.inputs)
                } else {
                    (&mut exposes.properties, &mut locations.properties)
                };
                place_map.insert(name.clone(), (self.location(name_span), places));
                ports.insert(name, inner);
            }
        }
        complete.then_some((exposes, locations))
    }

    fn position(&mut self, node: &Node) -> Option<Position> {
        let fields = self.fields(node, "Position", &["x", "y"])?;
        let x = self.required(&fields, "x").and_then(|n| self.float32(n));
        let y = self.required(&fields, "y").and_then(|n| self.float32(n));
        Some(Position { x: x?, y: y? })
    }

    fn properties(&mut self, node: &Node) -> (BTreeMap<String, Value>, BTreeMap<String, EntryLocations>) {
        let mut values = BTreeMap::new();
        let mut locations = BTreeMap::new();
        for (key, key_span, value_node) in self.string_map(node, "property") {
            let value = match &value_node.kind {
                NodeKind::Bool(value) => Some(Value::Bool(*value)),
                NodeKind::Integer(_) => self.integer::<i64>(value_node).map(Value::I64),
                NodeKind::Float(text) => text.parse::<f64>().ok().map(Value::F64),
                NodeKind::Text(text) => Some(Value::Text(text.clone())),
                _ => {
                    self.wrong_type(
                        value_node,
                        "a property value (a boolean, an integer, a number or a string)",
                    );
                    None
                }
            };
            let Some(value) = value else { continue };
            let entry = EntryLocations {
                key: self.location(key_span),
                value: self.location(value_node.span),
            };
            locations.insert(key.clone(), entry);
            values.insert(key, value);
        }
        (values, locations)
    }

    fn outputs(
        &mut self,
        node: &Node,
    ) -> (
        BTreeMap<String, OutputSettings>,
        BTreeMap<String, OutputLocations>,
    ) {
        let mut settings = BTreeMap::new();
        let mut locations = BTreeMap::new();
        for (key, key_span, value_node) in self.string_map(node, "output") {
            let Some(fields) = self.fields(value_node, "OutputSettings", &["buffer_size", "subsampling"])
            else {
                continue;
            };
            let buffer_node = fields.optional("buffer_size");
            let subsampling_node = fields.optional("subsampling");
            let buffer_size = self.optional(buffer_node, Self::integer::<usize>);
            let subsampling = self.optional(subsampling_node, Self::integer::<u32>);
            let (Some(buffer_size), Some(subsampling)) = (buffer_size.ok(), subsampling.ok()) else {
                continue;
            };
            let entry = OutputLocations {
                key: self.location(key_span),
                buffer_size: buffer_node.map(|n| self.location(n.span)),
                subsampling: subsampling_node.map(|n| self.location(n.span)),
            };
            locations.insert(key.clone(), entry);
            settings.insert(
                key,
                OutputSettings {
                    buffer_size,
                    subsampling,
                },
            );
        }
        (settings, locations)
    }

    /// The thread settings and where the priority is; `None` when they did not read.
    fn thread(&mut self, node: &Node) -> Option<(ThreadSettings, Option<Location>)> {
        let fields = self.fields(node, "ThreadSettings", &["priority", "affinity"])?;
        let priority_node = fields.optional("priority");
        let priority = self.optional(priority_node, Self::integer::<u8>);
        let cores = fields
            .optional("affinity")
            .and_then(|n| self.list(n))
            .unwrap_or_default();
        let affinity: Vec<Option<usize>> = cores.iter().map(|n| self.integer::<usize>(n)).collect();
        let affinity: Option<Vec<usize>> = affinity.into_iter().collect();
        let settings = ThreadSettings {
            priority: priority.ok()?,
            affinity: affinity?,
        };
        Some((settings, priority_node.map(|n| self.location(n.span))))
    }

    fn viewer(&mut self, node: &Node) -> Option<ViewerSpec> {
        let known = ["output", "kind", "docked", "also", "area", "share"];
        let fields = self.fields(node, "Viewer", &known)?;
        let output = self.required(&fields, "output").and_then(|n| self.text(n));
        let kind = self.required(&fields, "kind").and_then(|n| self.text(n));
        let docked = self.optional(fields.optional("docked"), Self::boolean);
        let also = fields
            .optional("also")
            .and_then(|n| self.list(n))
            .unwrap_or_default();
        let also: Option<Vec<String>> = also.iter().map(|n| self.text(n)).collect();
        let area = self.optional(fields.optional("area"), Self::integer::<u32>);
        let share = self.optional(fields.optional("share"), Self::dock_share);
        Some(ViewerSpec {
            output: output?,
            kind: kind?,
            docked: docked.ok()?.unwrap_or(true),
            also: also?,
            area: area.ok()?,
            share: share.ok()?,
        })
    }

    /// A dock area's share of the dock's height: a positive number.
    fn dock_share(&mut self, node: &Node) -> Option<f32> {
        let share = self.float32(node)?;
        if share > 0.0 && share.is_finite() {
            Some(share)
        } else {
            let message = format!(
                "a dock area's share is a positive number (1.0 for the height of an area by default), not {share}"
            );
            self.report(DiagnosticCode::InvalidSetting, node.head, message);
            None
        }
    }

    fn boolean(&mut self, node: &Node) -> Option<bool> {
        if let NodeKind::Bool(value) = node.kind {
            Some(value)
        } else {
            self.wrong_type(node, "true or false");
            None
        }
    }

    fn connection(&mut self, node: &Node) -> Option<(Connection, ConnectionLocations)> {
        let known = ["from", "to", "policy", "buffer_size", "subsampling"];
        let fields = self.fields(node, "Connection", &known)?;
        let from_node = self.required(&fields, "from");
        let to_node = self.required(&fields, "to");
        let from = from_node.and_then(|n| self.port(n));
        let to = to_node.and_then(|n| self.port(n));
        let policy_node = fields.optional("policy");
        let buffer_node = fields.optional("buffer_size");
        let subsampling_node = fields.optional("subsampling");
        let policy = self.optional(policy_node, Self::policy);
        let buffer_size = self.optional(buffer_node, Self::integer::<usize>);
        let subsampling = self.optional(subsampling_node, Self::integer::<u32>);
        let connection = Connection {
            from: from?,
            to: to?,
            policy: policy.ok()?,
            buffer_size: buffer_size.ok()?,
            subsampling: subsampling.ok()?,
        };
        let locations = ConnectionLocations {
            connection: self.location(node.head),
            from: self.location(from_node?.span),
            to: self.location(to_node?.span),
            policy: policy_node.map(|n| self.location(n.span)),
            buffer_size: buffer_node.map(|n| self.location(n.span)),
            subsampling: subsampling_node.map(|n| self.location(n.span)),
        };
        Some((connection, locations))
    }

    fn port(&mut self, node: &Node) -> Option<PortRef> {
        let text = self.text(node)?;
        let port = PortRef::parse(&text);
        if port.is_none() {
            let message = format!("expected a port written \"component.port\", found {text:?}");
            self.report(DiagnosticCode::WrongType, node.span, message);
        }
        port
    }

    fn policy(&mut self, node: &Node) -> Option<ReaderPolicy> {
        let names = ReaderPolicy::ALL.map(ReaderPolicy::name);
        let NodeKind::Ident(name) = &node.kind else {
            self.wrong_type(node, &format!("a reader policy ({})", names.join(", ")));
            return None;
        };
        let policy = ReaderPolicy::ALL.into_iter().find(|p| p.name() == name);
        if policy.is_none() {
            let suggestion = did_you_mean(name, names)
                .unwrap_or_else(|| format!("the reader policies are: {}", names.join(", ")));
            let diagnostic = Diagnostic::error(
                DiagnosticCode::WrongType,
                format!("unknown reader policy '{name}'"),
            )
            .at(Some(self.location(node.span)))
            .with_suggestion(Some(suggestion));
            self.diagnostics.push(diagnostic);
        }
        policy
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn messages(source: &str) -> Vec<String> {
        parse(source)
            .unwrap_err()
            .iter()
            .map(ToString::to_string)
            .collect()
    }

    #[test]
    fn reads_a_minimal_diagram() {
        let parsed = parse("Diagram(format: 1)").unwrap();
        assert_eq!(parsed.diagram, Diagram::default());
        assert_eq!(parsed.source_map.format.column, 17);
    }

    #[test]
    fn a_byte_order_mark_at_the_start_is_accepted_and_anywhere_else_refused() {
        let parsed = parse("\u{feff}// saved by an editor that marks UTF-8\nDiagram(format: 1)").unwrap();
        assert_eq!(parsed.diagram, Diagram::default());
        assert_eq!(parsed.source_map.format.line, 2);
        assert!(parse("Diagram(\u{feff}format: 1)").is_err());
    }

    #[test]
    fn a_file_that_is_not_utf8_is_refused_at_its_first_bad_byte() {
        let dir = std::env::temp_dir().join(format!("kairos-utf8-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("latin1.ron");
        // "é" written in Latin-1 on the third line, after two characters.
        std::fs::write(&path, b"Diagram(\n  format: 1,\n  /* \xe9 */\n)").unwrap();
        let error = load(&path).unwrap_err();
        let LoadError::Invalid { diagnostics, .. } = &error else {
            panic!("{error}");
        };
        let location = diagnostics[0].location.unwrap();
        assert_eq!((location.line, location.column), (3, 6));
        assert!(error.to_string().contains("not UTF-8 text: byte 0xe9"), "{error}");
        assert!(error.render().contains("latin1.ron:3:6"), "{}", error.render());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn accepts_some_none_and_anonymous_structs() {
        let source = r#"(
            format: 1,
            components: [(id: "a", type: "t", position: None, thread: (priority: Some(5)))],
            connections: [(from: "a.out", to: "b.in", policy: Some(Sampling), buffer_size: None)],
        )"#;
        let diagram = parse(source).unwrap().diagram;
        let component = diagram.component("a").unwrap();
        assert_eq!(component.thread.priority, Some(5));
        let connection = diagram.connections.first().unwrap();
        assert_eq!(connection.policy, Some(ReaderPolicy::Sampling));
        assert_eq!(connection.buffer_size, None);
    }

    #[test]
    fn reports_every_structural_problem_at_once() {
        let source = r#"Diagram(
    format: 1,
    components: [
        Component(id: "a", typ: "t", id: "b"),
        Component(id: 3, type: "t", position: (x: 1.0)),
    ],
    connections: [Connection(from: "a", to: "b.in", policy: Fifoo)],
)"#;
        assert_eq!(
            messages(source),
            [
                "4:9: error: Component is missing field 'type'",
                "4:28: error: unknown field 'typ' in Component; did you mean 'type'?",
                "4:38: error: field 'id' is given twice in Component",
                "5:23: error: expected a string, found an integer",
                "5:47: error: Position is missing field 'y'",
                "7:36: error: expected a port written \"component.port\", found \"a\"",
                "7:61: error: unknown reader policy 'Fifoo'; did you mean 'Fifo'?",
            ]
        );
    }

    #[test]
    fn a_host_s_ride_out_is_read_and_one_out_of_range_refused_at_its_place() {
        let source = |seconds: &str| {
            format!(
                r#"Diagram(format: 1, hosts: {{
    "car": Host(endpoint: "ws://10.0.0.2:7400", ride_out_s: {seconds}),
}})"#
            )
        };
        let parsed = parse(&source("12.5")).unwrap();
        assert_eq!(parsed.diagram.hosts["car"].ride_out_s, Some(12.5));
        assert_eq!(
            messages(&source("-1.0")),
            ["2:61: error: a ride-out of -1 s: it is from 0 (a cut loses what it cuts) to 600 s"]
        );
        assert_eq!(
            messages(&source("\"5 s\"")),
            ["2:61: error: expected a number of seconds, found a string"]
        );
    }

    #[test]
    fn a_viewer_s_place_in_the_dock_is_read_and_a_share_not_positive_refused_at_its_place() {
        let source = |share: &str| {
            format!(
                r#"Diagram(format: 1, viewers: [
    Viewer(output: "a.out", kind: "plot", area: 2, share: {share}),
])"#
            )
        };
        let parsed = parse(&source("0.5")).unwrap();
        assert_eq!(parsed.diagram.viewers[0].area, Some(2));
        assert_eq!(parsed.diagram.viewers[0].share, Some(0.5));
        assert_eq!(
            messages(&source("0.0")),
            [
                "2:59: error: a dock area's share is a positive number (1.0 for the height of an area by default), not 0"
            ]
        );
    }

    #[test]
    fn a_host_s_ride_out_memory_is_read_and_one_out_of_range_refused_at_its_place() {
        let source = |megabytes: &str| {
            format!(
                r#"Diagram(format: 1, hosts: {{
    "car": Host(endpoint: "ws://10.0.0.2:7400", ride_out_mb: {megabytes}),
}})"#
            )
        };
        assert_eq!(
            parse(&source("512")).unwrap().diagram.hosts["car"].ride_out_mb,
            Some(512.0)
        );
        assert_eq!(
            messages(&source("100000.0")),
            [
                "2:62: error: a ride-out memory of 100000 MB: it is from 0 (nothing kept for a cut) to 65536 MB"
            ]
        );
    }

    #[test]
    fn positional_values_where_fields_belong_are_explained() {
        assert_eq!(
            messages("Diagram(format: 1, packs: [Pack(\"core\", \"^0.1\")])"),
            ["1:28: error: expected named fields in Pack(...), such as 'name: ...'"]
        );
        assert_eq!(
            messages("[1]"),
            ["1:1: error: expected Diagram(...), found a list"]
        );
    }
}
