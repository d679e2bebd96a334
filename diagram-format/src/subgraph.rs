//! Subgraphs: a diagram used as a component. An instance whose type names a diagram file
//! (`Component(id: "front", type: "camera_pipeline.ron")`, the path relative to the file using it)
//! stands for that diagram's components; the subgraph says, in its `exposes` section, which inner inputs,
//! outputs and properties its instances see and under what names.
//!
//! [`flatten`] replaces every instance by the subgraph's components, to any depth, before anything
//! else reads the diagram: ids become `front/convert`, links to the instance's ports are rewired to the
//! inner ports they expose, a property set on the instance is set on each inner property it feeds. The
//! engine, the validator, the statistics and the protocol then see one flat diagram. A fault inside a
//! subgraph is reported at the instance that uses it, its message naming the file, line and column
//! inside.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::diagnostic::{Diagnostic, DiagnosticCode, Location, Note, did_you_mean};
use crate::model::{Connection, Diagram, Exposes, PortRef};
use crate::read::{ComponentLocations, ConnectionLocations, LoadError, ParsedDiagram, SourceMap, parse};

/// Whether a component type names a subgraph (a diagram file) rather than a component of a pack.
pub fn is_subgraph_type(type_name: &str) -> bool {
    Path::new(type_name)
        .extension()
        .is_some_and(|extension| extension.eq_ignore_ascii_case("ron"))
}

/// Why a subgraph's file could not be read; said at the instance, with the folder it is relative to.
#[derive(Debug, thiserror::Error)]
pub enum SubgraphReadError {
    /// An include that fans out without end.
    #[error("more than {0} subgraph instances in one diagram")]
    TooMany(usize),
    /// What the file system said.
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// A runtime sent a diagram without its folder cannot read the files it names.
    #[error(
        "the diagram came without its folder, so this runtime cannot read {}; deploy it from the machine \
         that has the file (`kairos run --deploy`, the studio)",
        .0.display()
    )]
    WithoutFolder(PathBuf),
}

/// Why a subgraph cannot be described as a component type. Cloned: clients keep the description, or
/// why there is none, until the file changes.
#[derive(Debug, Clone, thiserror::Error)]
pub enum DescribeSubgraphError {
    /// A subgraph a pack ships that does not read or flatten: its first problem.
    #[error("{type_name}: {problem}")]
    Shipped {
        /// The pack's subgraph type.
        type_name: String,
        /// The first problem found.
        problem: Box<Diagnostic>,
    },
    /// The file does not load or flatten.
    #[error(transparent)]
    Load(std::sync::Arc<LoadError>),
    /// A component inside of a type the library lacks.
    #[error("{}: '{component}' is of a type this library lacks", .file.display())]
    UnknownType {
        /// The subgraph's file.
        file: PathBuf,
        /// The component's id inside.
        component: String,
    },
    /// An exposure naming a port or property its component does not have.
    #[error("exposed {kind} '{name}': '{component}' has no {kind} '{port}'")]
    NoSuchPort {
        /// `input`, `output` or `property`.
        kind: &'static str,
        /// The outer name.
        name: String,
        /// The inner component.
        component: String,
        /// The port or property named.
        port: String,
    },
}

/// Why components cannot be made into a subgraph: nothing changes.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ExtractError {
    /// Nothing selected.
    #[error("select the components to put in the subgraph")]
    NothingSelected,
    /// An id that is not in the diagram.
    #[error("there is no component '{0}'")]
    NoComponent(String),
    /// The instance's name is another component's.
    #[error("'{0}' is taken: name the subgraph's instance otherwise")]
    InstanceNameTaken(String),
    /// The diagram's clock must stay where its id is.
    #[error("'{0}' is the diagram's clock source: keep it outside the subgraph")]
    ClockSource(String),
}

/// Where subgraphs are read from: files, by path, and the subgraphs packs ship, by type name.
pub struct Sources<'a> {
    /// A file's text, or why it cannot be read.
    pub read: &'a mut dyn FnMut(&Path) -> Result<String, SubgraphReadError>,
    /// Type name → diagram text of the subgraphs packs ship ([`crate::LibraryInfo::subgraphs`]).
    pub shipped: &'a BTreeMap<String, String>,
}

impl std::fmt::Debug for Sources<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Sources")
            .field("shipped", &self.shipped.keys().collect::<Vec<_>>())
            .finish_non_exhaustive()
    }
}

impl Sources<'_> {
    /// Whether `type_name` is a subgraph: a file, or one a pack ships.
    pub fn names_subgraph(&self, type_name: &str) -> bool {
        is_subgraph_type(type_name) || self.shipped.contains_key(type_name)
    }

    fn used_by(&self, diagram: &Diagram) -> bool {
        diagram
            .components
            .iter()
            .any(|c| self.names_subgraph(&c.type_name))
    }
}

/// Where each component that came from a subgraph was written: its flat id → `file:line:column` (the
/// files named as their users name them, `camera_pipeline.ron`, nested ones after their includers).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Origins(BTreeMap<String, String>);

impl Origins {
    /// Adds to each diagnostic that names an inner component (`'front/convert'`) a note saying where that
    /// component is written.
    pub fn annotate(&self, diagnostics: &mut [Diagnostic]) {
        if self.0.is_empty() {
            return;
        }
        for diagnostic in diagnostics {
            let named: Vec<(&String, &String)> = self
                .0
                .iter()
                .filter(|(id, _)| diagnostic.message.contains(&format!("'{id}'")))
                .collect();
            for (id, place) in named {
                diagnostic.notes.push(Note {
                    message: format!("'{id}' is written at {place}"),
                    location: None,
                });
            }
        }
    }

    /// Where the inner component `id` is written, if it came from a subgraph.
    pub fn of(&self, id: &str) -> Option<&str> {
        self.0.get(id).map(String::as_str)
    }
}

/// A flat diagram, and where its inner components came from.
#[derive(Debug, Clone, PartialEq)]
pub struct Flattened {
    /// The diagram with every subgraph instance replaced by its components; its source map points
    /// inner components and links at the instance that brought them.
    pub parsed: ParsedDiagram,
    /// Where each inner component is written.
    pub origins: Origins,
}

/// Replaces every subgraph instance of `parsed` (read from `file`) by its components, reading subgraph
/// files with `read` (a path → its text, or why it cannot be read). Errors are located in `file`.
pub fn flatten(
    parsed: ParsedDiagram,
    file: &Path,
    read: &mut dyn FnMut(&Path) -> Result<String, SubgraphReadError>,
) -> Result<Flattened, Vec<Diagnostic>> {
    let none = BTreeMap::new();
    flatten_from(parsed, file, &mut Sources { read, shipped: &none })
}

/// [`flatten`], with the subgraphs packs ship as well as files.
pub fn flatten_from(
    parsed: ParsedDiagram,
    file: &Path,
    sources: &mut Sources<'_>,
) -> Result<Flattened, Vec<Diagnostic>> {
    let mut origins = Origins::default();
    let chain = vec![normal(file)];
    let parsed = expand(parsed, file, &chain, sources, &mut origins)?;
    Ok(Flattened { parsed, origins })
}

/// A file's path with `.` and `..` taken out, to compare includes without touching the disk.
fn normal(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for part in path.components() {
        match part {
            std::path::Component::CurDir => {}
            std::path::Component::ParentDir if out.file_name().is_some() => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    out
}

/// One subgraph instance once expanded: what it exposes, in flat ids.
struct Instance {
    file: String,
    exposes: Exposes,
}

fn expand(
    parsed: ParsedDiagram,
    file: &Path,
    chain: &[PathBuf],
    sources: &mut Sources<'_>,
    origins: &mut Origins,
) -> Result<ParsedDiagram, Vec<Diagnostic>> {
    if !sources.used_by(&parsed.diagram) {
        let mut parsed = parsed;
        check_exposes(&mut parsed, &BTreeMap::new()).map_err(|d| vec![d])?;
        return Ok(parsed);
    }
    let ParsedDiagram { diagram, source_map } = parsed;
    let mut expansion = Expansion {
        folder: file.parent().unwrap_or_else(|| Path::new("")),
        chain,
        sources,
        origins,
        flat: Diagram {
            components: Vec::new(),
            connections: Vec::new(),
            ..diagram.clone()
        },
        flat_map: SourceMap {
            components: Vec::new(),
            connections: Vec::new(),
            ..source_map.clone()
        },
        instances: BTreeMap::new(),
        problems: Vec::new(),
    };
    for (index, component) in diagram.components.iter().enumerate() {
        let at = source_map.components.get(index);
        if expansion.sources.names_subgraph(&component.type_name) {
            expansion.instance(component, at);
        } else {
            expansion.flat.components.push(component.clone());
            expansion.flat_map.components.extend(at.cloned());
        }
    }
    for (index, connection) in diagram.connections.iter().enumerate() {
        expansion.connection(connection, source_map.connections.get(index).copied());
    }
    let Expansion {
        flat,
        flat_map,
        instances,
        mut problems,
        ..
    } = expansion;
    let mut flat = ParsedDiagram {
        diagram: flat,
        source_map: flat_map,
    };
    if let Err(problem) = check_exposes(&mut flat, &instances) {
        problems.push(problem);
    }
    if problems.is_empty() {
        Ok(flat)
    } else {
        Err(problems)
    }
}

/// One diagram being flattened: what is read, and the flat diagram so far.
struct Expansion<'a, 'r, 's> {
    folder: &'a Path,
    chain: &'a [PathBuf],
    sources: &'r mut Sources<'s>,
    origins: &'a mut Origins,
    flat: Diagram,
    flat_map: SourceMap,
    instances: BTreeMap<String, Instance>,
    problems: Vec<Diagnostic>,
}

impl Expansion<'_, '_, '_> {
    /// Reads, flattens and puts in place the subgraph `component` instantiates.
    fn instance(&mut self, component: &crate::model::ComponentInstance, at: Option<&ComponentLocations>) {
        let type_at = at.map(|l| l.type_name);
        let Some((inner, inner_origins)) = self.subgraph(component, type_at) else {
            return;
        };
        let prefix = |id: &str| format!("{}/{id}", component.id);
        for (i, inner_component) in inner.diagram.components.iter().enumerate() {
            let here = inner.source_map.components.get(i).map_or_else(
                || component.type_name.clone(),
                |l| format!("{}:{}:{}", component.type_name, l.id.line, l.id.column),
            );
            let written = inner_origins
                .of(&inner_component.id)
                .map_or_else(|| here.clone(), |deeper| format!("{here}, in {deeper}"));
            self.origins.0.insert(prefix(&inner_component.id), written);
        }
        let exposes = inner.diagram.exposes.clone().unwrap_or_default();
        let mut placed = inner.diagram.clone();
        place_inside(&mut placed, component, &exposes, at, &mut self.problems);
        for inner_component in placed.components {
            self.flat.components.push(inner_component);
            self.flat_map.components.extend(at.map(inside_at));
        }
        for connection in placed.connections {
            self.flat.connections.push(connection);
            self.flat_map.connections.extend(at.map(|at| ConnectionLocations {
                connection: at.type_name,
                from: at.type_name,
                to: at.type_name,
                policy: None,
                buffer_size: None,
                subsampling: None,
            }));
        }
        for pack in inner.diagram.packs {
            if !self.flat.packs.iter().any(|p| p.name == pack.name) {
                self.flat.packs.push(pack);
            }
        }
        for (name, host) in inner.diagram.hosts {
            self.flat.hosts.entry(name).or_insert(host);
        }
        for (name, settings) in inner.diagram.groups {
            self.flat.groups.insert(prefix(&name), settings);
        }
        self.instances.insert(
            component.id.clone(),
            Instance {
                file: component.type_name.clone(),
                exposes: prefixed(&exposes, &component.id),
            },
        );
    }

    /// The subgraph `component` names, read and flattened, with where its inner components came from;
    /// `None` (and the problem noted) when it cannot be.
    fn subgraph(
        &mut self,
        component: &crate::model::ComponentInstance,
        type_at: Option<Location>,
    ) -> Option<(ParsedDiagram, Origins)> {
        let shipped = self.sources.shipped.get(&component.type_name).cloned();
        // A pack's subgraph is named by its type; its own subgraphs are its pack's too.
        let path = if shipped.is_some() {
            Path::new("(packs)").join(&component.type_name)
        } else {
            normal(&self.folder.join(&component.type_name))
        };
        if let Some(first) = self.chain.iter().position(|p| *p == path) {
            let mut names: Vec<String> = self.chain[first..]
                .iter()
                .map(|p| {
                    p.file_name()
                        .map_or_else(String::new, |n| n.to_string_lossy().into_owned())
                })
                .collect();
            names.push(component.type_name.clone());
            let message = format!(
                "subgraph '{}' includes itself: {}",
                component.type_name,
                names.join(" → ")
            );
            self.problems
                .push(Diagnostic::error(DiagnosticCode::InvalidSubgraph, message).at(type_at));
            return None;
        }
        let read = match shipped {
            Some(text) => Ok(text),
            None => (self.sources.read)(&path),
        };
        let text = match read {
            Ok(text) => text,
            Err(why) => {
                let folder = if self.folder.as_os_str().is_empty() {
                    ".".to_owned()
                } else {
                    self.folder.display().to_string()
                };
                self.problems.push(
                    Diagnostic::error(
                        DiagnosticCode::InvalidSubgraph,
                        format!("cannot read subgraph '{}': {why}", component.type_name),
                    )
                    .at(type_at)
                    .with_suggestion(Some(format!(
                        "the path is relative to this diagram's folder ({folder})"
                    ))),
                );
                return None;
            }
        };
        let chain: Vec<PathBuf> = self.chain.iter().cloned().chain([path.clone()]).collect();
        let mut origins = Origins::default();
        match parse(&text).and_then(|inner| expand(inner, &path, &chain, self.sources, &mut origins)) {
            Ok(inner) => Some((inner, origins)),
            Err(inside) => {
                self.problems.extend(
                    inside
                        .into_iter()
                        .map(|d| from_inside(d, &component.type_name, type_at)),
                );
                None
            }
        }
    }

    /// A link of the diagram, its ends on subgraph instances rewired to the inner ports they expose.
    fn connection(&mut self, connection: &Connection, at: Option<ConnectionLocations>) {
        let from = resolve(&connection.from, &self.instances, false, at.map(|l| l.from));
        let to = resolve(&connection.to, &self.instances, true, at.map(|l| l.to));
        match (from, to) {
            (Ok(from), Ok(to)) => {
                // An output is one port; an exposed input may feed several inner ones.
                for from in &from {
                    for to in &to {
                        self.flat.connections.push(Connection {
                            from: from.clone(),
                            to: to.clone(),
                            ..connection.clone()
                        });
                        self.flat_map.connections.extend(at);
                    }
                }
            }
            (from, to) => self.problems.extend(from.err().into_iter().chain(to.err())),
        }
    }
}

/// An inner component's place in the including file: the instance's, so that what the validator finds
/// about it points at the instance.
fn inside_at(at: &ComponentLocations) -> ComponentLocations {
    ComponentLocations {
        properties: BTreeMap::new(),
        outputs: BTreeMap::new(),
        ..at.clone()
    }
}

/// `exposes` with its inner ids under `instance/`.
fn prefixed(exposes: &Exposes, instance: &str) -> Exposes {
    let port = |p: &PortRef| PortRef::new(format!("{instance}/{}", p.component), p.port.clone());
    let all = |targets: &BTreeMap<String, Vec<PortRef>>| -> BTreeMap<String, Vec<PortRef>> {
        targets
            .iter()
            .map(|(n, ps)| (n.clone(), ps.iter().map(port).collect()))
            .collect()
    };
    Exposes {
        inputs: all(&exposes.inputs),
        outputs: exposes
            .outputs
            .iter()
            .map(|(n, p)| (n.clone(), port(p)))
            .collect(),
        properties: all(&exposes.properties),
    }
}

/// Puts `inner` (a flattened subgraph) in place of `instance`: ids under `instance/`, the instance's
/// properties on the inner properties they feed, its host, group and output settings on its parts.
fn place_inside(
    inner: &mut Diagram,
    instance: &crate::model::ComponentInstance,
    exposes: &Exposes,
    at: Option<&ComponentLocations>,
    problems: &mut Vec<Diagnostic>,
) {
    let prefix = |id: &str| format!("{}/{id}", instance.id);
    for (name, value) in &instance.properties {
        let Some(targets) = exposes.properties.get(name) else {
            let names: Vec<&str> = exposes.properties.keys().map(String::as_str).collect();
            problems.push(
                Diagnostic::error(
                    DiagnosticCode::InvalidSubgraph,
                    format!(
                        "subgraph '{}' exposes no property '{name}' (it exposes {})",
                        instance.type_name,
                        listed(&names)
                    ),
                )
                .at(at.and_then(|l| l.properties.get(name)).map(|e| e.key))
                .with_suggestion(did_you_mean(name, names.iter().copied())),
            );
            continue;
        };
        for target in targets {
            if let Some(component) = inner.component_mut(&target.component) {
                component.properties.insert(target.port.clone(), value.clone());
            }
        }
    }
    for (name, settings) in &instance.outputs {
        match exposes.outputs.get(name) {
            Some(target) => {
                if let Some(component) = inner.component_mut(&target.component) {
                    component.outputs.insert(target.port.clone(), settings.clone());
                }
            }
            None => problems.push(
                Diagnostic::error(
                    DiagnosticCode::InvalidSubgraph,
                    format!(
                        "subgraph '{}' exposes no output '{name}' to set",
                        instance.type_name
                    ),
                )
                .at(at.and_then(|l| l.outputs.get(name)).map(|o| o.key)),
            ),
        }
    }
    let sequential = inner.sequential.then(|| prefix(crate::model::SEQUENTIAL_GROUP));
    for component in &mut inner.components {
        component.id = prefix(&component.id);
        if component.host.is_none() {
            component.host.clone_from(&instance.host);
        }
        component.group = match component.group.take() {
            Some(group) => Some(prefix(&group)),
            None => sequential.clone().or_else(|| instance.group.clone()),
        };
        if component.thread == crate::model::ThreadSettings::default() {
            component.thread = instance.thread.clone();
        }
    }
    for connection in &mut inner.connections {
        connection.from.component = prefix(&connection.from.component);
        connection.to.component = prefix(&connection.to.component);
    }
}

/// The inner ports a link's end stands for: itself, or, on a subgraph instance, the inner inputs (one
/// or several) or the inner output its name exposes.
fn resolve(
    port: &PortRef,
    instances: &BTreeMap<String, Instance>,
    input: bool,
    at: Option<Location>,
) -> Result<Vec<PortRef>, Diagnostic> {
    let Some(instance) = instances.get(&port.component) else {
        return Ok(vec![port.clone()]);
    };
    let (found, names, what) = if input {
        (
            instance.exposes.inputs.get(&port.port).cloned(),
            instance
                .exposes
                .inputs
                .keys()
                .map(String::as_str)
                .collect::<Vec<_>>(),
            "input",
        )
    } else {
        (
            instance.exposes.outputs.get(&port.port).map(|p| vec![p.clone()]),
            instance.exposes.outputs.keys().map(String::as_str).collect(),
            "output",
        )
    };
    found.ok_or_else(|| {
        Diagnostic::error(
            DiagnosticCode::InvalidSubgraph,
            format!(
                "'{}' (subgraph '{}') exposes no {what} '{}' (it exposes {})",
                port.component,
                instance.file,
                port.port,
                listed(&names)
            ),
        )
        .at(at)
        .with_suggestion(did_you_mean(&port.port, names.iter().copied()))
    })
}

/// Rewrites the diagram's own `exposes` through the instances it uses, and checks that each names a
/// component it has and that no inner input or property is exposed under two names.
fn check_exposes(
    parsed: &mut ParsedDiagram,
    instances: &BTreeMap<String, Instance>,
) -> Result<(), Diagnostic> {
    let Some(exposes) = parsed.diagram.exposes.take() else {
        return Ok(());
    };
    let places = parsed.source_map.exposes.clone().unwrap_or_default();
    let diagram = &parsed.diagram;
    let mut resolved = Exposes::default();
    for (name, port) in &exposes.outputs {
        let at = places.outputs.get(name).map(|e| e.value);
        for port in resolve(port, instances, false, at)? {
            exists(diagram, "output", name, &port, at)?;
            resolved.outputs.insert(name.clone(), port);
        }
    }
    resolved.inputs = exposed_targets(diagram, instances, "input", &exposes.inputs, &places.inputs)?;
    resolved.properties = exposed_targets(
        diagram,
        instances,
        "property",
        &exposes.properties,
        &places.properties,
    )?;
    parsed.diagram.exposes = Some(resolved);
    Ok(())
}

/// An error unless the diagram has the component `port` names.
fn exists(
    diagram: &Diagram,
    what: &str,
    name: &str,
    port: &PortRef,
    at: Option<Location>,
) -> Result<(), Diagnostic> {
    if diagram.component(&port.component).is_some() {
        return Ok(());
    }
    Err(Diagnostic::error(
        DiagnosticCode::InvalidSubgraph,
        format!(
            "exposed {what} '{name}' names '{port}', but the diagram has no component '{}'",
            port.component
        ),
    )
    .at(at))
}

/// Exposed inputs or properties, each name's targets resolved through the instances inside (whose
/// exposed names they may use), each inner target exposed under one name only.
fn exposed_targets(
    diagram: &Diagram,
    instances: &BTreeMap<String, Instance>,
    what: &str,
    targets_by_name: &BTreeMap<String, Vec<PortRef>>,
    places: &BTreeMap<String, (Location, Vec<Location>)>,
) -> Result<BTreeMap<String, Vec<PortRef>>, Diagnostic> {
    let mut resolved = BTreeMap::new();
    let mut fed: BTreeMap<String, &str> = BTreeMap::new();
    for (name, targets) in targets_by_name {
        let target_places = places.get(name).map(|(_, t)| t.as_slice()).unwrap_or_default();
        let mut inner = Vec::new();
        for (index, target) in targets.iter().enumerate() {
            let at = target_places.get(index).copied();
            let deeper = if let Some(instance) = instances.get(&target.component) {
                let exposed = if what == "input" {
                    instance.exposes.inputs.get(&target.port)
                } else {
                    instance.exposes.properties.get(&target.port)
                };
                exposed.cloned().ok_or_else(|| {
                    Diagnostic::error(
                        DiagnosticCode::InvalidSubgraph,
                        format!(
                            "exposed {what} '{name}' names '{target}', but '{}' (subgraph '{}') exposes no {what} '{}'",
                            target.component, instance.file, target.port
                        ),
                    )
                    .at(at)
                })?
            } else {
                exists(diagram, what, name, target, at)?;
                vec![target.clone()]
            };
            for target in deeper {
                let key = target.to_string();
                if let Some(first) = fed.get(&key) {
                    return Err(Diagnostic::error(
                        DiagnosticCode::InvalidSubgraph,
                        format!("'{key}' is exposed twice: as '{first}' and as '{name}'"),
                    )
                    .at(at)
                    .with_suggestion(Some(format!(
                        "expose each inner {what} under one name; a name may feed several"
                    ))));
                }
                fed.insert(key, name);
                inner.push(target);
            }
        }
        resolved.insert(name.clone(), inner);
    }
    Ok(resolved)
}

/// A problem found inside a subgraph, reported at the instance (`at`) that uses it, its message naming
/// the place inside.
fn from_inside(inside: Diagnostic, file: &str, at: Option<Location>) -> Diagnostic {
    let place = inside
        .location
        .map_or_else(String::new, |l| format!(":{}:{}", l.line, l.column));
    let notes = inside
        .notes
        .into_iter()
        .map(|note| Note {
            message: match note.location {
                Some(l) => format!("{} ({file}:{}:{})", note.message, l.line, l.column),
                None => note.message,
            },
            location: None,
        })
        .collect();
    Diagnostic {
        message: format!("in {file}{place}: {}", inside.message),
        location: at,
        notes,
        ..inside
    }
}

fn listed(names: &[&str]) -> String {
    if names.is_empty() {
        "none".to_owned()
    } else {
        names.join(", ")
    }
}

/// What an instance of the subgraph `type_name` (a pack's, or the file `file`) looks like from outside,
/// as a component type: its exposed
/// inputs, outputs and properties, each described as the inner port or property it stands for (an
/// output whose type follows an inner input follows the exposed input feeding it). `library` describes
/// the inner components; the description names a problem with the file as text. With it, what the
/// subgraph exposes, in the flat ids of its inside (`overlay.out`, `inner/edges.low`).
pub fn describe(
    file: &Path,
    type_name: &str,
    library: &crate::LibraryInfo,
) -> Result<Described, DescribeSubgraphError> {
    let (text, flattened) = match library.subgraphs.get(type_name) {
        Some(text) => {
            let first = |problems: Vec<Diagnostic>| DescribeSubgraphError::Shipped {
                type_name: type_name.to_owned(),
                problem: Box::new(problems.into_iter().next().unwrap_or_else(|| {
                    Diagnostic::error(DiagnosticCode::InvalidSubgraph, "it does not flatten")
                })),
            };
            let parsed = parse(text).map_err(first)?;
            let mut read = from_files(MAX_SUBGRAPH_READS);
            let mut sources = Sources {
                read: &mut read,
                shipped: &library.subgraphs,
            };
            let shipped_at = Path::new("(packs)").join(type_name);
            (
                text.clone(),
                flatten_from(parsed, &shipped_at, &mut sources).map_err(first)?,
            )
        }
        None => load_flattened(file, &library.subgraphs)
            .map_err(|error| DescribeSubgraphError::Load(std::sync::Arc::new(error)))?,
    };
    let diagram = &flattened.parsed.diagram;
    let exposes = diagram.exposes.clone().unwrap_or_default();
    let info_of = |port: &PortRef| {
        diagram
            .component(&port.component)
            .and_then(|c| library.component_of(c))
            .ok_or_else(|| DescribeSubgraphError::UnknownType {
                file: file.to_owned(),
                component: port.component.clone(),
            })
    };
    let mut info = crate::ComponentInfo {
        type_name: type_name.to_owned(),
        pack: String::new(),
        label: file
            .file_stem()
            .map_or_else(String::new, |stem| stem.to_string_lossy().replace('_', " ")),
        category: "subgraphs".to_owned(),
        // The file's first comment line says what it is.
        doc: text
            .lines()
            .find_map(|line| line.trim().strip_prefix("//"))
            .map_or_else(String::new, |line| line.trim().to_owned()),
        mode: crate::ExecutionMode::Threaded,
        inputs: Vec::new(),
        outputs: Vec::new(),
        properties: Vec::new(),
        actions: Vec::new(),
        time_source: false,
        simulated_time: false,
        holds_inputs: false,
        stops_at_once: false,
        blocking: None,
    };
    for (name, targets) in &exposes.inputs {
        let Some(first) = targets.first() else { continue };
        let inner = info_of(first)?;
        let mut input = inner
            .input(&first.port)
            .cloned()
            .ok_or_else(|| no_such_port("input", name, first))?;
        input.name.clone_from(name);
        info.inputs.push(input);
    }
    for (name, port) in &exposes.outputs {
        let inner = info_of(port)?;
        let mut output = inner
            .output(&port.port)
            .cloned()
            .ok_or_else(|| no_such_port("output", name, port))?;
        output.name.clone_from(name);
        match crate::validate::output_type(diagram, port, |c| library.component_of(c)) {
            Some(data_type) => {
                output.data_type = data_type;
                output.follows_input = None;
            }
            None => {
                // Fed from outside: it follows the exposed input that feeds the inner one it follows.
                output.follows_input = output.follows_input.as_ref().and_then(|inner_input| {
                    let fed = PortRef::new(port.component.clone(), inner_input.clone());
                    exposes
                        .inputs
                        .iter()
                        .find(|(_, targets)| targets.contains(&fed))
                        .map(|(outer, _)| outer.clone())
                });
            }
        }
        info.outputs.push(output);
    }
    for (name, targets) in &exposes.properties {
        let Some(first) = targets.first() else { continue };
        let inner = info_of(first)?;
        let mut property = inner
            .property(&first.port)
            .cloned()
            .ok_or_else(|| no_such_port("property", name, first))?;
        // Its default is what the subgraph sets inside, if it sets it.
        if let Some(set) = diagram
            .component(&first.component)
            .and_then(|c| c.properties.get(&first.port))
        {
            property.default = set.clone();
        }
        property.name.clone_from(name);
        info.properties.push(property);
    }
    let inside = diagram
        .components
        .iter()
        .filter_map(|component| {
            let kind = library.component_of(component)?;
            let outputs = kind
                .outputs
                .iter()
                .filter_map(|output| {
                    let at = PortRef::new(component.id.clone(), output.name.clone());
                    let data_type = crate::validate::output_type(diagram, &at, |c| library.component_of(c))?;
                    Some((output.name.clone(), data_type))
                })
                .collect();
            let actions = kind.actions.iter().map(|a| a.name.clone()).collect();
            Some(InnerPart {
                id: component.id.clone(),
                outputs,
                actions,
            })
        })
        .collect();
    Ok(Described {
        info,
        exposes,
        inside,
    })
}

fn no_such_port(kind: &'static str, name: &str, inner: &PortRef) -> DescribeSubgraphError {
    DescribeSubgraphError::NoSuchPort {
        kind,
        name: name.to_owned(),
        component: inner.component.clone(),
        port: inner.port.clone(),
    }
}

/// A subgraph as its users see it ([`describe`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Described {
    /// Its instances as a component type: the exposed ports and properties.
    pub info: crate::ComponentInfo,
    /// What it exposes, in the flat ids of its inside.
    pub exposes: Exposes,
    /// Its inner components (flat ids inside it, `edges`, `inner/edges`), each with its outputs' types
    /// (an output whose type follows an input fed from outside is left out) and its actions.
    pub inside: Vec<InnerPart>,
}

/// One component inside a subgraph, as [`Described::inside`] lists it.
#[derive(Debug, Clone, PartialEq)]
pub struct InnerPart {
    /// Its id inside the subgraph.
    pub id: String,
    /// Its outputs and their types.
    pub outputs: Vec<(String, crate::DataType)>,
    /// Its actions' names.
    pub actions: Vec<String>,
}

/// Moves the components `ids` of `diagram` into a new subgraph: returns the subgraph (their components
/// and the links between them, placed from the origin, exposing each inner input fed from outside and
/// each inner output read outside) and `diagram` with one instance `instance` of `type_name` (the
/// subgraph's file) in their place, the links that crossed rewired to its exposed ports. An outside
/// output feeding several moved inputs is one exposed input feeding them all. Viewers of an exposed
/// output follow it; those of an output kept inside are dropped.
pub fn extract(
    diagram: &Diagram,
    ids: &[String],
    instance: &str,
    type_name: &str,
) -> Result<(Diagram, Diagram), ExtractError> {
    let inside = |id: &str| ids.iter().any(|i| i == id);
    if ids.is_empty() {
        return Err(ExtractError::NothingSelected);
    }
    if let Some(missing) = ids.iter().find(|id| diagram.component(id).is_none()) {
        return Err(ExtractError::NoComponent(missing.clone()));
    }
    if diagram.component(instance).is_some() && !inside(instance) {
        return Err(ExtractError::InstanceNameTaken(instance.to_owned()));
    }
    if let Some(clock) = diagram.clock_source.as_deref().filter(|c| inside(c)) {
        return Err(ExtractError::ClockSource(clock.to_owned()));
    }
    let moved: Vec<&crate::model::ComponentInstance> =
        diagram.components.iter().filter(|c| inside(&c.id)).collect();
    let left = moved.iter().map(|c| c.position.x).fold(f32::INFINITY, f32::min);
    let top = moved.iter().map(|c| c.position.y).fold(f32::INFINITY, f32::min);
    let count = moved.len() as f32;
    let centre = crate::model::Position {
        x: moved.iter().map(|c| c.position.x).sum::<f32>() / count,
        y: moved.iter().map(|c| c.position.y).sum::<f32>() / count,
    };
    let mut subgraph = Diagram {
        packs: diagram.packs.clone(),
        components: moved
            .iter()
            .map(|c| {
                let mut inner = (*c).clone();
                inner.position.x -= left - 40.0;
                inner.position.y -= top - 40.0;
                inner
            })
            .collect(),
        ..Diagram::default()
    };
    let mut outer = Diagram {
        components: diagram
            .components
            .iter()
            .filter(|c| !inside(&c.id))
            .cloned()
            .collect(),
        connections: Vec::new(),
        ..diagram.clone()
    };
    let mut place = crate::model::ComponentInstance::new(instance, type_name);
    place.position = centre;
    outer.components.push(place);
    let mut exposes = Exposes::default();
    // An exposed name: the inner port's, or `component_port` when two would share it.
    let name_for = |taken: &dyn Fn(&str) -> bool, port: &PortRef| {
        if taken(&port.port) {
            format!("{}_{}", port.component, port.port)
        } else {
            port.port.clone()
        }
    };
    // Outside sources, each with the exposed input it became.
    let mut sources: Vec<(PortRef, String)> = Vec::new();
    for connection in &diagram.connections {
        match (
            inside(&connection.from.component),
            inside(&connection.to.component),
        ) {
            (true, true) => subgraph.connections.push(connection.clone()),
            (false, false) => outer.connections.push(connection.clone()),
            (false, true) => {
                let known = sources.iter().find(|(from, _)| *from == connection.from);
                let name = if let Some((_, name)) = known {
                    name.clone()
                } else {
                    let name = name_for(&|n| exposes.inputs.contains_key(n), &connection.to);
                    sources.push((connection.from.clone(), name.clone()));
                    outer.connections.push(Connection {
                        to: PortRef::new(instance, name.clone()),
                        ..connection.clone()
                    });
                    name
                };
                exposes
                    .inputs
                    .entry(name)
                    .or_default()
                    .push(connection.to.clone());
            }
            (true, false) => {
                let known = exposes.outputs.iter().find(|(_, p)| **p == connection.from);
                let name = if let Some((name, _)) = known {
                    name.clone()
                } else {
                    let name = name_for(&|n| exposes.outputs.contains_key(n), &connection.from);
                    exposes.outputs.insert(name.clone(), connection.from.clone());
                    name
                };
                outer.connections.push(Connection {
                    from: PortRef::new(instance, name),
                    ..connection.clone()
                });
            }
        }
    }
    outer.viewers = diagram
        .viewers
        .iter()
        .filter_map(|viewer| {
            let Some(port) = PortRef::parse(&viewer.output) else {
                return Some(viewer.clone());
            };
            if !inside(&port.component) {
                return Some(viewer.clone());
            }
            let (name, _) = exposes.outputs.iter().find(|(_, p)| **p == port)?;
            Some(crate::model::ViewerSpec {
                output: format!("{instance}.{name}"),
                ..viewer.clone()
            })
        })
        .collect();
    subgraph.exposes = Some(exposes);
    Ok((subgraph, outer))
}

/// The most subgraph files one diagram may read (each instance reads its file): far beyond a real
/// rig, and a bound on a diagram that fans out through its includes.
pub const MAX_SUBGRAPH_READS: usize = 10_000;

/// Loads a diagram file and flattens its subgraphs, read beside the files that use them. Problems
/// found while flattening are located in the file loaded, as a parse error is.
/// `shipped` are the subgraphs the packs ship ([`crate::LibraryInfo::subgraphs`]).
pub fn load_flattened(
    path: &Path,
    shipped: &BTreeMap<String, String>,
) -> Result<(String, Flattened), LoadError> {
    let (text, parsed) = crate::read::load(path)?;
    let mut read = from_files(MAX_SUBGRAPH_READS);
    match flatten_from(
        parsed,
        path,
        &mut Sources {
            read: &mut read,
            shipped,
        },
    ) {
        Ok(flat) => Ok((text, flat)),
        Err(diagnostics) => Err(LoadError::Invalid {
            path: path.to_owned(),
            text,
            diagnostics,
        }),
    }
}

/// Reads subgraph files from the file system, refusing more than `limit` of them in one diagram (an
/// include that fans out without end).
pub fn from_files(limit: usize) -> impl FnMut(&Path) -> Result<String, SubgraphReadError> {
    let mut count = 0_usize;
    move |path: &Path| {
        count += 1;
        if count > limit {
            return Err(SubgraphReadError::TooMany(limit));
        }
        Ok(std::fs::read_to_string(path)?)
    }
}
