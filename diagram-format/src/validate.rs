//! Checking a diagram against a component library: every problem at once, each located when the
//! diagram came from text, with a suggestion where one exists.

use std::collections::{BTreeMap, BTreeSet, HashMap};

use crate::diagnostic::{Diagnostic, DiagnosticCode, Location, closest, did_you_mean};
use crate::library::{ComponentInfo, DescribeError, ExecutionMode, InstanceInfos, LibraryInfo, Value};
#[cfg(test)]
use crate::model::HostSpec;
use crate::model::{ComponentInstance, Connection, Diagram, FORMAT_VERSION, MAX_BUFFER_SIZE, PortRef};
use crate::read::{ComponentLocations, ConnectionLocations, PackLocations, SourceMap};

mod groups;

/// Checks `diagram` against `library` and returns every problem found, in source order.
///
/// With `source_map` (from [`crate::parse()`], for the diagram as parsed) each diagnostic points at the
/// offending token; without it, diagnostics carry no location. An empty result means the diagram can be
/// built; warnings alone do not prevent that.
pub fn validate(diagram: &Diagram, source_map: Option<&SourceMap>, library: &LibraryInfo) -> Vec<Diagnostic> {
    validate_with(diagram, source_map, library, &InstanceInfos::new())
}

/// Like [`validate`], for a diagram with components whose ports depend on their properties: `instances`
/// gives their descriptors by component id (the runtime's registry computes them). An instance whose
/// description failed is reported where its fault lies, and its connections are not checked further.
pub fn validate_with(
    diagram: &Diagram,
    source_map: Option<&SourceMap>,
    library: &LibraryInfo,
    instances: &InstanceInfos,
) -> Vec<Diagnostic> {
    let mut first_with_id = HashMap::new();
    for (index, component) in diagram.components.iter().enumerate() {
        first_with_id.entry(component.id.as_str()).or_insert(index);
    }
    let mut validator = Validator {
        diagram,
        source_map,
        library,
        instances,
        first_with_id,
        found: Vec::new(),
    };
    validator.check_format();
    validator.check_clock_source();
    validator.check_hosts();
    validator.check_packs();
    validator.check_components();
    validator.check_connections();
    validator.check_reactive_cycles();
    validator.check_groups();
    let mut found = validator.found;
    // Stable, so problems at the same place keep the order the checks found them in.
    found.sort_by_key(|d| d.location.map_or(usize::MAX, |l| l.offset));
    found
}

/// Every property of the component type, with the instance's value where it sets a valid one and the
/// default otherwise, normalised by [`crate::PropertyKind::check`] (an integer for a float property
/// becomes a float). Properties the type does not have are left out; run [`validate`] to hear about them.
pub fn resolved_properties(instance: &ComponentInstance, info: &ComponentInfo) -> BTreeMap<String, Value> {
    info.properties
        .iter()
        .map(|property| {
            let given = instance
                .properties
                .get(&property.name)
                .and_then(|v| property.kind.check(v).ok());
            let value = given.unwrap_or_else(|| {
                property
                    .kind
                    .check(&property.default)
                    .unwrap_or_else(|_| property.default.clone())
            });
            (property.name.clone(), value)
        })
        .collect()
}

/// The type output `port` really carries: its declared type, or for an output that follows an input, the
/// type of whatever feeds that input. `info_of` gives each instance's descriptor. `None` when unknown
/// (unconnected, unknown port, a cycle).
pub fn output_type<'i>(
    diagram: &Diagram,
    port: &PortRef,
    info_of: impl Fn(&ComponentInstance) -> Option<&'i ComponentInfo>,
) -> Option<crate::library::DataType> {
    let mut port = port.clone();
    for _ in 0..=crate::MAX_DEPTH {
        let info = info_of(diagram.component(&port.component)?)?;
        let output = info.output(&port.port)?;
        let Some(input) = &output.follows_input else {
            return Some(output.data_type.clone());
        };
        let feeding = diagram
            .connections
            .iter()
            .find(|c| c.to.component == port.component && &c.to.port == input)?;
        port = feeding.from.clone();
    }
    None
}

/// Whether `id` is a valid component id: non-empty, ASCII letters, digits, `_` and `-` only (ids end up
/// in thread names, file names and command lines).
pub fn is_valid_id(id: &str) -> bool {
    !id.is_empty()
        && id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
}

/// Whether `id` is valid for a component or an execution group: ids joined by `/`, as a flattened
/// subgraph names its parts (`front/convert`).
pub fn is_valid_path_id(id: &str) -> bool {
    id.split('/').all(is_valid_id)
}

struct Validator<'a> {
    diagram: &'a Diagram,
    source_map: Option<&'a SourceMap>,
    library: &'a LibraryInfo,
    instances: &'a InstanceInfos,
    /// Component ids to the index of the first component with that id.
    first_with_id: HashMap<&'a str, usize>,
    found: Vec<Diagnostic>,
}

/// Which end of a connection a port is.
#[derive(Clone, Copy, PartialEq, Eq)]
enum End {
    From,
    To,
}

impl<'a> Validator<'a> {
    fn pack_at(&self, index: usize) -> Option<&'a PackLocations> {
        self.source_map.and_then(|m| m.packs.get(index))
    }

    fn component_at(&self, index: usize) -> Option<&'a ComponentLocations> {
        self.source_map.and_then(|m| m.components.get(index))
    }

    fn connection_at(&self, index: usize) -> Option<&'a ConnectionLocations> {
        self.source_map.and_then(|m| m.connections.get(index))
    }

    fn check_format(&mut self) {
        if self.diagram.format != FORMAT_VERSION {
            let message = format!(
                "unsupported format version {}; this version of Kairos reads format {FORMAT_VERSION}",
                self.diagram.format
            );
            let location = self.source_map.map(|m| m.format);
            self.found
                .push(Diagnostic::error(DiagnosticCode::UnsupportedFormat, message).at(location));
        }
    }

    fn check_clock_source(&mut self) {
        let Some(source) = &self.diagram.clock_source else {
            return;
        };
        let location = self.source_map.and_then(|m| m.clock_source);
        let able: Vec<&str> = self
            .diagram
            .components
            .iter()
            .filter(|c| {
                self.library
                    .components
                    .get(&c.type_name)
                    .is_some_and(|i| i.time_source)
            })
            .map(|c| c.id.as_str())
            .collect();
        let suggestion = if able.is_empty() {
            "add a component that gives the time (a GNSS receiver, gnss.nmea) and name it here, or remove \
             clock_source"
                .to_owned()
        } else {
            format!("components that can: {}", able.join(", "))
        };
        let message = match self.diagram.component(source) {
            None => format!("the clock source '{source}' is not a component of this diagram"),
            Some(instance) => match self.library.components.get(&instance.type_name) {
                // An unknown type is reported on the component itself.
                None => return,
                Some(info) if info.simulated_time => {
                    self.check_simulated_time(instance, info);
                    return;
                }
                Some(info) if info.time_source => return,
                Some(_) => format!(
                    "'{source}' ({}) cannot be the clock source: it does not give the time",
                    instance.type_name
                ),
            },
        };
        self.found.push(
            Diagnostic::error(DiagnosticCode::InvalidClockSource, message)
                .at(location)
                .with_suggestion(Some(suggestion)),
        );
    }

    /// Simulated time as fast as possible jumps to each deadline: right for one thread running every
    /// component in turn, meaningless for threads that each wait on their own.
    fn check_simulated_time(&mut self, instance: &ComponentInstance, info: &ComponentInfo) {
        let time_scale = info
            .property_value(&instance.properties, "time_scale")
            .and_then(Value::as_f64)
            .unwrap_or(0.0);
        if time_scale > 0.0 || self.diagram.sequential {
            return;
        }
        let location = self.source_map.and_then(|m| m.clock_source);
        self.found.push(
            Diagnostic::error(
                DiagnosticCode::InvalidClockSource,
                format!(
                    "'{}' runs simulated time as fast as possible (time_scale 0), which needs every \
                     component to run in turn in one thread",
                    instance.id
                ),
            )
            .at(location)
            .with_suggestion(Some(
                "add `sequential: true` to the diagram, or give the simulator a time_scale above 0 (1: real \
                 time)"
                    .to_owned(),
            )),
        );
    }

    fn check_hosts(&mut self) {
        for (name, host) in &self.diagram.hosts {
            let at = self.source_map.and_then(|m| m.hosts.get(name)).copied();
            if !is_valid_id(name) {
                self.found.push(
                    Diagnostic::error(
                        DiagnosticCode::InvalidId,
                        format!("'{name}' cannot name a host: use letters, digits, _ and -"),
                    )
                    .at(at.map(|l| l.name)),
                );
            }
            if let Err(why) = check_endpoint(&host.endpoint) {
                self.found.push(
                    Diagnostic::error(
                        DiagnosticCode::InvalidEndpoint,
                        format!("host '{name}': the endpoint {:?} {why}", host.endpoint),
                    )
                    .at(at.map(|l| l.endpoint))
                    .with_suggestion(Some(
                        "write the address `kairos serve` listens on there, as ws://HOST:PORT (wss:// with TLS)"
                            .to_owned(),
                    )),
                );
            }
            if let Some(zenoh) = &host.zenoh
                && let Err(why) = check_zenoh_endpoint(zenoh)
            {
                self.found.push(
                    Diagnostic::error(
                        DiagnosticCode::InvalidEndpoint,
                        format!("host '{name}': the Zenoh endpoint {zenoh:?} {why}"),
                    )
                    .at(at.and_then(|l| l.zenoh))
                    .with_suggestion(Some(
                        "write where the other hosts reach this one's links, as tcp/HOST:PORT (tls/HOST:PORT with TLS)"
                            .to_owned(),
                    )),
                );
            }
        }
        let known: Vec<&str> = self.diagram.hosts.keys().map(String::as_str).collect();
        for (index, component) in self.diagram.components.iter().enumerate() {
            let Some(host) = &component.host else { continue };
            if self.diagram.hosts.contains_key(host) {
                continue;
            }
            let location = self
                .source_map
                .and_then(|m| m.components.get(index))
                .and_then(|l| l.host);
            let suggestion = if known.is_empty() {
                format!("add a hosts section: hosts: {{ \"{host}\": Host(endpoint: \"ws://ADDRESS:PORT\") }}")
            } else {
                format!("the hosts are: {}; or add '{host}' to them", known.join(", "))
            };
            self.found.push(
                Diagnostic::error(
                    DiagnosticCode::UnknownHost,
                    format!(
                        "'{}' runs on host '{host}', which the diagram's hosts do not name",
                        component.id
                    ),
                )
                .at(location)
                .with_suggestion(Some(suggestion)),
            );
        }
    }

    fn check_packs(&mut self) {
        let mut first_listed: HashMap<&str, usize> = HashMap::new();
        for (index, requirement) in self.diagram.packs.iter().enumerate() {
            let at = self.pack_at(index);
            if let Some(&first) = first_listed.get(requirement.name.as_str()) {
                let diagnostic = Diagnostic::error(
                    DiagnosticCode::DuplicatePack,
                    format!("pack '{}' is listed twice", requirement.name),
                )
                .at(at.map(|l| l.name))
                .with_note("first listed here", self.pack_at(first).map(|l| l.name));
                self.found.push(diagnostic);
                continue;
            }
            first_listed.insert(&requirement.name, index);

            let wanted = match semver::VersionReq::parse(&requirement.version) {
                Ok(wanted) => wanted,
                Err(error) => {
                    let message = format!(
                        "the `version` of pack '{}' is {:?}, not a version requirement: {error}",
                        requirement.name, requirement.version
                    );
                    let diagnostic = Diagnostic::error(DiagnosticCode::InvalidVersionRequirement, message)
                        .at(at.map(|l| l.version))
                        .with_suggestion(Some("write a semver requirement such as \"^0.1\"".to_owned()));
                    self.found.push(diagnostic);
                    continue;
                }
            };
            let Some(pack) = self.library.packs.get(&requirement.name) else {
                let suggestion =
                    did_you_mean(&requirement.name, self.library.packs.keys().map(String::as_str));
                let diagnostic = Diagnostic::missing_pack(&requirement.name)
                    .at(at.map(|l| l.name))
                    .with_suggestion(suggestion);
                self.found.push(diagnostic);
                continue;
            };
            let found = semver::Version::parse(&pack.version);
            if !found.as_ref().is_ok_and(|found| wanted.matches(found)) {
                let message = format!(
                    "pack '{}' is required at version {}, but the library has version {}",
                    requirement.name, requirement.version, pack.version
                );
                let suggestion = found.ok().map(|found| {
                    format!(
                        "require \"{}\" to use the library's {} ({}), or install a matching pack",
                        caret_requirement(&found),
                        pack.name,
                        pack.origin
                    )
                });
                let diagnostic = Diagnostic::error(DiagnosticCode::PackVersionMismatch, message)
                    .at(at.map(|l| l.version))
                    .with_suggestion(suggestion);
                self.found.push(diagnostic);
            }
        }
    }

    fn check_components(&mut self) {
        let mut unlisted_packs_reported: BTreeSet<&str> = BTreeSet::new();
        for (index, component) in self.diagram.components.iter().enumerate() {
            let at = self.component_at(index);
            if !is_valid_path_id(&component.id) {
                let message = format!(
                    "invalid component id {:?}: use ASCII letters, digits, '_' and '-' only",
                    component.id
                );
                self.found
                    .push(Diagnostic::error(DiagnosticCode::InvalidId, message).at(at.map(|l| l.id)));
            }
            let first = self
                .first_with_id
                .get(component.id.as_str())
                .copied()
                .unwrap_or(index);
            if first != index {
                let diagnostic = Diagnostic::error(
                    DiagnosticCode::DuplicateId,
                    format!("two components have the id '{}'", component.id),
                )
                .at(at.map(|l| l.id))
                .with_note("the first one is here", self.component_at(first).map(|l| l.id));
                self.found.push(diagnostic);
            }
            self.check_settings(component, at);

            let Some(info) = self.library.component(&component.type_name) else {
                let suggestion = did_you_mean(
                    &component.type_name,
                    self.library.components.keys().map(String::as_str),
                );
                let message = format!(
                    "unknown component type '{}' for '{}'",
                    component.type_name, component.id
                );
                let diagnostic = Diagnostic::error(DiagnosticCode::UnknownComponentType, message)
                    .at(at.map(|l| l.type_name))
                    .with_suggestion(suggestion);
                self.found.push(diagnostic);
                continue;
            };
            let pack_listed = self.diagram.packs.iter().any(|p| p.name == info.pack);
            if !pack_listed && unlisted_packs_reported.insert(&info.pack) {
                self.report_unlisted_pack(component, info, at);
            }
            let info = match self.instances.get(&component.id) {
                Some(Ok(described)) => described,
                Some(Err(error)) => {
                    self.check_properties(component, info, at);
                    self.report_describe_error(component, error, at);
                    continue;
                }
                None => info,
            };
            self.check_properties(component, info, at);
            self.check_output_names(component, info, at);
        }
    }

    fn report_describe_error(
        &mut self,
        component: &ComponentInstance,
        error: &DescribeError,
        at: Option<&ComponentLocations>,
    ) {
        let location = match &error.property {
            Some(property) => at
                .and_then(|l| l.properties.get(property))
                .map(|l| l.value)
                .or_else(|| at.map(|l| l.type_name)),
            None => at.map(|l| l.type_name),
        };
        let message = match &error.property {
            Some(property) => format!("'{}' (property '{property}'): {}", component.id, error.message),
            None => format!("'{}': {}", component.id, error.message),
        };
        let diagnostic = Diagnostic::error(DiagnosticCode::CannotDescribe, message)
            .at(location)
            .with_suggestion(error.suggestion.clone());
        self.found.push(diagnostic);
    }

    /// The descriptor of `instance`: its own when its ports depend on its properties, else its type's.
    /// `None` for an unknown type or an instance that could not describe itself.
    fn info_of(&self, instance: &ComponentInstance) -> Option<&'a ComponentInfo> {
        match self.instances.get(&instance.id) {
            Some(described) => described.as_ref().ok(),
            None => self.library.component(&instance.type_name),
        }
    }

    fn report_unlisted_pack(
        &mut self,
        component: &ComponentInstance,
        info: &ComponentInfo,
        at: Option<&ComponentLocations>,
    ) {
        let message = format!(
            "'{}' uses pack '{}', which the diagram's packs do not list",
            component.id, info.pack
        );
        let requirement = self
            .library
            .packs
            .get(&info.pack)
            .and_then(|p| semver::Version::parse(&p.version).ok())
            .map_or_else(|| "*".to_owned(), |v| caret_requirement(&v));
        let suggestion = format!(
            "add Pack(name: \"{}\", version: \"{requirement}\") to packs",
            info.pack
        );
        let diagnostic = Diagnostic::warning(DiagnosticCode::UnlistedPack, message)
            .at(at.map(|l| l.type_name))
            .with_suggestion(Some(suggestion));
        self.found.push(diagnostic);
    }

    /// Buffer sizes, subsampling and thread priority: checks that need no library.
    fn check_settings(&mut self, component: &ComponentInstance, at: Option<&ComponentLocations>) {
        for (output, settings) in &component.outputs {
            let output_at = at.and_then(|l| l.outputs.get(output));
            let what = format!("output '{output}' of '{}'", component.id);
            if let Some(size) = settings.buffer_size {
                self.check_buffer_size(size, &what, output_at.and_then(|l| l.buffer_size));
            }
            if settings.subsampling == Some(0) {
                self.report_zero("subsampling", &what, output_at.and_then(|l| l.subsampling));
            }
        }
        if let Some(priority) = component.thread.priority.filter(|p| !(1..=99).contains(p)) {
            let message = format!(
                "thread priority {priority} of '{}' is out of range 1..=99",
                component.id
            );
            let diagnostic = Diagnostic::error(DiagnosticCode::InvalidSetting, message)
                .at(at.and_then(|l| l.priority))
                .with_suggestion(Some("leave priority out to keep the normal scheduler".to_owned()));
            self.found.push(diagnostic);
        }
    }

    fn check_buffer_size(&mut self, size: usize, what: &str, location: Option<Location>) {
        if size == 0 {
            self.report_zero("buffer_size", what, location);
        } else if size > MAX_BUFFER_SIZE {
            let message = format!("buffer_size {size} of {what} is above the maximum of {MAX_BUFFER_SIZE}");
            let suggestion = "a ring's slots are allocated up front; subsample the link or read it with \
                              LastOrNext if the reader cannot keep up";
            let diagnostic = Diagnostic::error(DiagnosticCode::InvalidSetting, message)
                .at(location)
                .with_suggestion(Some(suggestion.to_owned()));
            self.found.push(diagnostic);
        }
    }

    fn report_zero(&mut self, setting: &str, what: &str, location: Option<Location>) {
        let message = format!("{setting} of {what} must be at least 1");
        self.found
            .push(Diagnostic::error(DiagnosticCode::InvalidSetting, message).at(location));
    }

    fn check_properties(
        &mut self,
        component: &ComponentInstance,
        info: &ComponentInfo,
        at: Option<&ComponentLocations>,
    ) {
        for (name, value) in &component.properties {
            let property_at = at.and_then(|l| l.properties.get(name));
            let Some(property) = info.property(name) else {
                let names = info.properties.iter().map(|p| p.name.as_str());
                let suggestion = did_you_mean(name, names)
                    .unwrap_or_else(|| list_of("properties", &info.properties, |p| &p.name));
                let message = format!("unknown property '{name}' on '{}'", component.id);
                let diagnostic = Diagnostic::error(DiagnosticCode::UnknownProperty, message)
                    .at(property_at.map(|l| l.key))
                    .with_suggestion(Some(suggestion));
                self.found.push(diagnostic);
                continue;
            };
            if let Err(error) = property.kind.check(value) {
                let message = format!(
                    "invalid value for property '{name}' of '{}': {error}",
                    component.id
                );
                let diagnostic = Diagnostic::error(DiagnosticCode::InvalidPropertyValue, message)
                    .at(property_at.map(|l| l.value));
                self.found.push(diagnostic);
            }
        }
    }

    fn check_output_names(
        &mut self,
        component: &ComponentInstance,
        info: &ComponentInfo,
        at: Option<&ComponentLocations>,
    ) {
        for name in component.outputs.keys() {
            if info.output(name).is_some() {
                continue;
            }
            let names = info.outputs.iter().map(|o| o.name.as_str());
            let suggestion =
                did_you_mean(name, names).unwrap_or_else(|| list_of("outputs", &info.outputs, |o| &o.name));
            let message = format!(
                "unknown output '{name}' on '{}' ({})",
                component.id, info.type_name
            );
            let diagnostic = Diagnostic::error(DiagnosticCode::UnknownOutput, message)
                .at(at.and_then(|l| l.outputs.get(name)).map(|l| l.key))
                .with_suggestion(Some(suggestion));
            self.found.push(diagnostic);
        }
    }

    /// The component with this id (the first, when ids repeat).
    fn instance(&self, id: &str) -> Option<&'a ComponentInstance> {
        self.first_with_id
            .get(id)
            .and_then(|&i| self.diagram.components.get(i))
    }

    fn check_connections(&mut self) {
        let mut feeding: HashMap<&PortRef, usize> = HashMap::new();
        for (index, connection) in self.diagram.connections.iter().enumerate() {
            let at = self.connection_at(index);
            let output = self.resolve(connection, End::From, at.map(|l| l.from));
            let input = self.resolve(connection, End::To, at.map(|l| l.to));
            let produced = match output {
                Some(Resolved::Output) => self.effective_type(&connection.from),
                _ => None,
            };
            if let (Some(produced), Some(Resolved::Input(input))) = (produced, input)
                && !input.filter.accepts(&produced)
            {
                let message = format!(
                    "input '{}' accepts {}, but '{}' produces {produced}",
                    connection.to, input.filter, connection.from
                );
                let diagnostic = Diagnostic::error(DiagnosticCode::TypeMismatch, message)
                    .at(at.map(|l| l.to))
                    .with_note(
                        format!("'{}' is connected here", connection.from),
                        at.map(|l| l.from),
                    );
                self.found.push(diagnostic);
            }
            let what = format!("the connection from '{}' to '{}'", connection.from, connection.to);
            if let Some(size) = connection.buffer_size {
                self.check_buffer_size(size, &what, at.and_then(|l| l.buffer_size));
            }
            if connection.subsampling == Some(0) {
                self.report_zero("subsampling", &what, at.and_then(|l| l.subsampling));
            }
            if let Some(&first) = feeding.get(&connection.to) {
                self.report_fed_twice(first, index, connection);
            } else {
                feeding.insert(&connection.to, index);
            }
        }
    }

    fn report_fed_twice(&mut self, first: usize, second: usize, connection: &Connection) {
        let first_from = self
            .diagram
            .connections
            .get(first)
            .map(|c| c.from.to_string())
            .unwrap_or_default();
        let message = format!(
            "input '{}' is fed twice: from '{first_from}' and from '{}'",
            connection.to, connection.from
        );
        let diagnostic = Diagnostic::error(DiagnosticCode::InputFedTwice, message)
            .at(self.connection_at(second).map(|l| l.to))
            .with_note(
                format!("the connection from '{first_from}' is here"),
                self.connection_at(first).map(|l| l.to),
            )
            .with_suggestion(Some(
                "an input takes one connection; remove one of them".to_owned(),
            ));
        self.found.push(diagnostic);
    }

    /// Finds the port a connection end names, reporting what is missing. `None` when it does not resolve
    /// (or its component's type is unknown, which was reported already).
    fn effective_type(&self, port: &PortRef) -> Option<crate::library::DataType> {
        output_type(self.diagram, port, |instance| self.info_of(instance))
    }

    fn resolve(
        &mut self,
        connection: &Connection,
        end: End,
        location: Option<Location>,
    ) -> Option<Resolved<'a>> {
        let port = if end == End::From {
            &connection.from
        } else {
            &connection.to
        };
        let Some(instance) = self.instance(&port.component) else {
            let ids = self.diagram.components.iter().map(|c| c.id.as_str());
            let message = format!("unknown component '{}' in '{port}'", port.component);
            let diagnostic = Diagnostic::error(DiagnosticCode::UnknownComponent, message)
                .at(location)
                .with_suggestion(did_you_mean(&port.component, ids));
            self.found.push(diagnostic);
            return None;
        };
        let info = self.info_of(instance)?;
        let resolved = match end {
            End::From => info.output(&port.port).map(|_| Resolved::Output),
            End::To => info.input(&port.port).map(Resolved::Input),
        };
        if resolved.is_none() {
            self.report_unknown_port(port, end, info, location);
        }
        resolved
    }

    fn report_unknown_port(
        &mut self,
        port: &PortRef,
        end: End,
        info: &ComponentInfo,
        location: Option<Location>,
    ) {
        let (kind, names): (&str, Vec<&str>) = match end {
            End::From => ("output", info.outputs.iter().map(|o| o.name.as_str()).collect()),
            End::To => ("input", info.inputs.iter().map(|i| i.name.as_str()).collect()),
        };
        let wrong_direction = match end {
            End::From => info.input(&port.port).is_some(),
            End::To => info.output(&port.port).is_some(),
        };
        let message = if wrong_direction {
            let other = if end == End::From { "an input" } else { "an output" };
            format!("'{port}' is {other}, but a connection goes from an output to an input")
        } else {
            format!(
                "unknown {kind} '{}' on '{}' ({})",
                port.port, port.component, info.type_name
            )
        };
        let suggestion = closest(&port.port, names.iter().copied())
            .map(|name| format!("did you mean '{}.{name}'?", port.component))
            .or_else(|| {
                Some(if names.is_empty() {
                    format!("{} has no {kind}s", info.type_name)
                } else {
                    format!("the {kind}s of {} are: {}", info.type_name, names.join(", "))
                })
            });
        let diagnostic = Diagnostic::error(DiagnosticCode::UnknownPort, message)
            .at(location)
            .with_suggestion(suggestion);
        self.found.push(diagnostic);
    }

    /// Reactive components run in their producer's thread; a loop of them would wait on itself forever.
    fn check_reactive_cycles(&mut self) {
        let components = &self.diagram.components;
        let reactive = |id: &str| -> Option<usize> {
            let index = self.first_with_id.get(id).copied()?;
            let instance = components.get(index)?;
            // In an execution group the group's thread runs it, not its producer's.
            if self.diagram.group_of(instance).is_some() {
                return None;
            }
            let info = self.info_of(instance)?;
            (info.mode == ExecutionMode::Reactive).then_some(index)
        };
        let mut edges: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        let mut edge_connections: Vec<(usize, usize, usize)> = Vec::new();
        for (index, connection) in self.diagram.connections.iter().enumerate() {
            if let (Some(from), Some(to)) = (
                reactive(&connection.from.component),
                reactive(&connection.to.component),
            ) {
                edges.entry(from).or_default().push(to);
                edges.entry(to).or_default();
                edge_connections.push((from, to, index));
            }
        }
        for members in strongly_connected_components(&edges) {
            let Some(&(from, _, connection)) = edge_connections
                .iter()
                .find(|(from, to, _)| members.contains(from) && members.contains(to))
            else {
                // A single component without a connection to itself is no cycle.
                continue;
            };
            let ids: Vec<String> = members
                .iter()
                .filter_map(|&i| components.get(i))
                .map(|c| format!("'{}'", c.id))
                .collect();
            let message = if ids.len() == 1 {
                let id = components.get(from).map(|c| c.id.as_str()).unwrap_or_default();
                format!("reactive component '{id}' feeds itself, which would deadlock")
            } else {
                format!(
                    "reactive components {} are connected in a cycle, which would deadlock",
                    join_with_and(&ids)
                )
            };
            let diagnostic = Diagnostic::error(DiagnosticCode::ReactiveCycle, message)
                .at(self.connection_at(connection).map(|l| l.connection))
                .with_suggestion(Some(
                    "break the loop, or put a threaded component in it".to_owned(),
                ));
            self.found.push(diagnostic);
        }
    }
}

/// A connection end that resolved to a port of a known component type.
#[derive(Clone, Copy)]
enum Resolved<'a> {
    Output,
    Input(&'a crate::library::InputInfo),
}

/// `its properties are: a, b` style help, for when no name is close enough to suggest.
fn list_of<T>(what: &str, items: &[T], name: impl Fn(&T) -> &String) -> String {
    if items.is_empty() {
        return format!("this component type has no {what}");
    }
    let names: Vec<&str> = items.iter().map(|i| name(i).as_str()).collect();
    format!("its {what} are: {}", names.join(", "))
}

/// The usual requirement for a version: `^0.1` for 0.1.3, `^2.0` for 2.0.1.
fn caret_requirement(version: &semver::Version) -> String {
    format!("^{}.{}", version.major, version.minor)
}

/// `a`, `a and b`, `a, b and c`.
fn join_with_and(items: &[String]) -> String {
    match items.split_last() {
        None => String::new(),
        Some((last, [])) => last.clone(),
        Some((last, rest)) => format!("{} and {last}", rest.join(", ")),
    }
}

/// Tarjan's algorithm, iterative so that long chains cannot exhaust the stack. Each component's members
/// come out sorted, and components in order of their smallest member.
fn strongly_connected_components(edges: &BTreeMap<usize, Vec<usize>>) -> Vec<Vec<usize>> {
    #[derive(Clone, Copy)]
    struct Visit {
        index: usize,
        low: usize,
        on_stack: bool,
    }
    let mut visits: HashMap<usize, Visit> = HashMap::new();
    let mut stack: Vec<usize> = Vec::new();
    let mut components: Vec<Vec<usize>> = Vec::new();
    let no_edges = Vec::new();
    for &root in edges.keys() {
        if visits.contains_key(&root) {
            continue;
        }
        // Each frame: a node and how many of its edges have been followed.
        let mut frames: Vec<(usize, usize)> = vec![(root, 0)];
        let fresh = visits.len();
        visits.insert(
            root,
            Visit {
                index: fresh,
                low: fresh,
                on_stack: true,
            },
        );
        stack.push(root);
        while let Some(&mut (node, ref mut followed)) = frames.last_mut() {
            let successors = edges.get(&node).unwrap_or(&no_edges);
            if let Some(&next) = successors.get(*followed) {
                *followed += 1;
                match visits.get(&next).copied() {
                    None => {
                        let fresh = visits.len();
                        visits.insert(
                            next,
                            Visit {
                                index: fresh,
                                low: fresh,
                                on_stack: true,
                            },
                        );
                        stack.push(next);
                        frames.push((next, 0));
                    }
                    Some(seen) if seen.on_stack => {
                        if let Some(visit) = visits.get_mut(&node) {
                            visit.low = visit.low.min(seen.index);
                        }
                    }
                    Some(_) => {}
                }
                continue;
            }
            frames.pop();
            let Some(&Visit { index, low, .. }) = visits.get(&node) else {
                continue;
            };
            if let Some(&(parent, _)) = frames.last()
                && let Some(visit) = visits.get_mut(&parent)
            {
                visit.low = visit.low.min(low);
            }
            if low == index {
                let mut members = Vec::new();
                while let Some(member) = stack.pop() {
                    if let Some(visit) = visits.get_mut(&member) {
                        visit.on_stack = false;
                    }
                    members.push(member);
                    if member == node {
                        break;
                    }
                }
                members.sort_unstable();
                components.push(members);
            }
        }
    }
    components.sort_by_key(|members| members.first().copied());
    components
}

/// Whether `endpoint` is a `ws://` or `wss://` address with a host and a port; why not.
fn check_endpoint(endpoint: &str) -> Result<(), &'static str> {
    let Some(rest) = endpoint
        .strip_prefix("ws://")
        .or_else(|| endpoint.strip_prefix("wss://"))
    else {
        return Err("does not start with ws:// or wss://");
    };
    let authority = rest.split('/').next().unwrap_or_default();
    let Some((host, port)) = authority.rsplit_once(':') else {
        return Err("has no port");
    };
    if host.is_empty() || host == "[" {
        return Err("has no host");
    }
    match port.parse::<u16>() {
        Ok(port) if port > 0 => Ok(()),
        _ => Err("has no valid port (1 to 65535)"),
    }
}

/// A Zenoh endpoint as the hosts section takes it: `tcp/HOST:PORT` or `tls/HOST:PORT`.
fn check_zenoh_endpoint(endpoint: &str) -> Result<(), &'static str> {
    let Some(authority) = endpoint
        .strip_prefix("tcp/")
        .or_else(|| endpoint.strip_prefix("tls/"))
    else {
        return Err("does not start with tcp/ or tls/");
    };
    let Some((host, port)) = authority.rsplit_once(':') else {
        return Err("has no port");
    };
    if host.is_empty() || host.contains(['/', '#', '?']) {
        return Err("has no host");
    }
    match port.parse::<u16>() {
        Ok(port) if port > 0 => Ok(()),
        _ => Err("has no valid port (1 to 65535)"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zenoh_endpoints_are_tcp_or_tls_addresses_with_a_port() {
        for good in ["tcp/10.0.0.2:7447", "tls/car.local:7447", "tcp/[::1]:7447"] {
            assert_eq!(check_zenoh_endpoint(good), Ok(()), "{good}");
        }
        for (bad, why) in [
            ("10.0.0.2:7447", "does not start with tcp/ or tls/"),
            ("udp/10.0.0.2:7447", "does not start with tcp/ or tls/"),
            ("tcp/10.0.0.2", "has no port"),
            ("tcp/:7447", "has no host"),
            ("tcp/car:0", "has no valid port (1 to 65535)"),
        ] {
            assert_eq!(check_zenoh_endpoint(bad), Err(why), "{bad}");
        }
        let spec = HostSpec {
            endpoint: "ws://10.0.0.2:7600".to_owned(),
            token_file: None,
            zenoh: None,
            certificate: None,
            ride_out_s: None,
            ride_out_mb: None,
        };
        assert_eq!(spec.zenoh_endpoint(), "tcp/10.0.0.2:7447");
        let secure = HostSpec {
            endpoint: "wss://car.local:7600".to_owned(),
            ..spec
        };
        assert_eq!(
            secure.zenoh_endpoint(),
            "tls/car.local:7447",
            "secure control, secure links"
        );
    }

    #[test]
    fn endpoints_are_websocket_addresses_with_a_port() {
        for good in ["ws://10.0.0.2:7600", "wss://car.local:7600/", "ws://[::1]:7600"] {
            assert_eq!(check_endpoint(good), Ok(()), "{good}");
        }
        for (bad, why) in [
            ("10.0.0.2:7600", "does not start with ws:// or wss://"),
            ("ws://10.0.0.2", "has no port"),
            ("ws://:7600", "has no host"),
            ("ws://car:0", "has no valid port (1 to 65535)"),
            ("wss://car:http", "has no valid port (1 to 65535)"),
        ] {
            assert_eq!(check_endpoint(bad), Err(why), "{bad}");
        }
    }

    #[test]
    fn ids() {
        assert!(is_valid_id("sine_1-a"));
        assert!(!is_valid_id(""));
        assert!(!is_valid_id("a.b"));
        assert!(!is_valid_id("a b"));
    }

    #[test]
    fn tarjan_finds_cycles_and_singletons() {
        let edges: BTreeMap<usize, Vec<usize>> = [
            (0, vec![1]),
            (1, vec![2]),
            (2, vec![0, 3]),
            (3, vec![]),
            (4, vec![4]),
        ]
        .into_iter()
        .collect();
        assert_eq!(
            strongly_connected_components(&edges),
            [vec![0, 1, 2], vec![3], vec![4]]
        );
    }

    #[test]
    fn long_chains_do_not_overflow() {
        let edges: BTreeMap<usize, Vec<usize>> = (0..200_000).map(|i| (i, vec![(i + 1) % 200_000])).collect();
        let components = strongly_connected_components(&edges);
        assert_eq!(components.len(), 1);
    }

    #[test]
    fn join_with_and_reads_naturally() {
        let items = |n: usize| (0..n).map(|i| i.to_string()).collect::<Vec<_>>();
        assert_eq!(join_with_and(&items(1)), "0");
        assert_eq!(join_with_and(&items(2)), "0 and 1");
        assert_eq!(join_with_and(&items(3)), "0, 1 and 2");
    }
}
