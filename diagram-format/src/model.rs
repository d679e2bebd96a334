//! The diagram model: what a diagram file holds, with no knowledge of how it is shown or run.

use std::collections::BTreeMap;
use std::fmt;

use serde::{Deserialize, Serialize};

use crate::library::{ReaderPolicy, Value};

/// The largest `buffer_size` a diagram may ask for: a ring's slots are allocated when the diagram is built
/// (128 bytes each, so this many take 128 MiB), and about 17 minutes of a 1 kHz stream is more than any
/// link needs to ride out a slow reader.
pub const MAX_BUFFER_SIZE: usize = 1 << 20;

/// The diagram format version this crate reads and writes.
pub const FORMAT_VERSION: u32 = 1;

/// A whole diagram: the packs it needs, its component instances and their connections.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Diagram {
    /// The format version the file was written in.
    pub format: u32,
    /// The packs the diagram needs, with version requirements.
    pub packs: Vec<PackRequirement>,
    /// The component instances.
    pub components: Vec<ComponentInstance>,
    /// The connections, each from an output to an input.
    pub connections: Vec<Connection>,
    /// The component whose time the runtime clock follows (a GNSS receiver), if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clock_source: Option<String>,
    /// The machines parts of the diagram run on, by name; empty: everything runs where it is deployed.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub hosts: BTreeMap<String, HostSpec>,
    /// The viewers the studio had open when the diagram was saved, reopened with it. The runtime ignores
    /// them: they say how to look at the diagram, not what it does.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub viewers: Vec<ViewerSpec>,
    /// Every component runs in one thread, [`SEQUENTIAL_GROUP`], in the order of the links (RTMaps'
    /// sequential behaviour): runs that replay the same data give the same outputs.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub sequential: bool,
    /// The thread settings of execution groups, by group name. A group that components name but this map
    /// does not runs with the default settings.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub groups: BTreeMap<String, ThreadSettings>,
    /// What the diagram shows of itself when another uses it as a component (a subgraph): which inner
    /// ports and properties, under which names. Run on its own, a diagram ignores it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposes: Option<Exposes>,
}

/// The inner inputs, outputs and properties a subgraph exposes, under the names its instances use.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Exposes {
    /// Outer input name → the inner inputs it feeds, one or several (`convert.in`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub inputs: BTreeMap<String, Vec<PortRef>>,
    /// Outer output name → the inner output it is (`detect.boxes`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub outputs: BTreeMap<String, PortRef>,
    /// Outer property name → the inner properties it sets, one or several (`detect.threshold`, written
    /// as a port is: `component.property`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub properties: BTreeMap<String, Vec<PortRef>>,
}

/// What an exposed name stands for: an inner input, output or property.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ExposedKind {
    /// An inner input, fed from the subgraph's input of that name.
    Input,
    /// An inner output, shown as the subgraph's output of that name.
    Output,
    /// An inner property, set from the subgraph's property of that name.
    Property,
}

impl ExposedKind {
    /// The kind in words (`input`, `output`, `property`).
    pub fn name(self) -> &'static str {
        match self {
            ExposedKind::Input => "input",
            ExposedKind::Output => "output",
            ExposedKind::Property => "property",
        }
    }
}

/// Why a port or property cannot be exposed under a name: nothing changes.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ExposeError {
    /// Outer names are ids, so that `instance.name` reads as a port.
    #[error("\"{name}\" cannot name an exposed {}: use letters, digits, _ and -", .kind.name())]
    NotAnId {
        /// The name given.
        name: String,
        /// What was to be exposed.
        kind: ExposedKind,
    },
    /// Another inner output is shown under that name.
    #[error("the subgraph's output '{name}' already shows {port}: choose another name")]
    OutputShows {
        /// The name given.
        name: String,
        /// The inner output it shows.
        port: PortRef,
    },
    /// A port of the other side has that name.
    #[error("the subgraph's {} '{name}' has that name: choose another name", .by.name())]
    Taken {
        /// The name given.
        name: String,
        /// Which side has it.
        by: ExposedKind,
    },
}

impl Exposes {
    /// Whether nothing is exposed.
    pub fn is_empty(&self) -> bool {
        self.inputs.is_empty() && self.outputs.is_empty() && self.properties.is_empty()
    }

    /// The name `inner` is exposed under, if it is.
    pub fn name_of(&self, kind: ExposedKind, inner: &PortRef) -> Option<&str> {
        let name = match kind {
            ExposedKind::Output => self
                .outputs
                .iter()
                .find(|(_, port)| *port == inner)
                .map(|(n, _)| n),
            ExposedKind::Input => find_in(&self.inputs, inner),
            ExposedKind::Property => find_in(&self.properties, inner),
        };
        name.map(String::as_str)
    }

    /// Exposes `inner` under `name`, or stops exposing it (`None`). An input or property given a name
    /// already exposed joins it, so that one outer name feeds several inner ones; an output's name is
    /// its own. Refused, with the reason, for a name that is not an id or that another output, or a port
    /// of the other side, already has.
    pub fn set(&mut self, kind: ExposedKind, inner: &PortRef, name: Option<&str>) -> Result<(), ExposeError> {
        let name = name.map(str::trim);
        if let Some(name) = name {
            if !crate::validate::is_valid_id(name) {
                return Err(ExposeError::NotAnId {
                    name: name.to_owned(),
                    kind,
                });
            }
            let clash = match kind {
                ExposedKind::Output => self
                    .outputs
                    .get(name)
                    .filter(|port| *port != inner)
                    .map(|port| ExposeError::OutputShows {
                        name: name.to_owned(),
                        port: port.clone(),
                    })
                    .or_else(|| {
                        self.inputs.contains_key(name).then(|| ExposeError::Taken {
                            name: name.to_owned(),
                            by: ExposedKind::Input,
                        })
                    }),
                ExposedKind::Input => self.outputs.contains_key(name).then(|| ExposeError::Taken {
                    name: name.to_owned(),
                    by: ExposedKind::Output,
                }),
                ExposedKind::Property => None,
            };
            if let Some(clash) = clash {
                return Err(clash);
            }
        }
        match kind {
            ExposedKind::Output => {
                self.outputs.retain(|_, port| port != inner);
                if let Some(name) = name {
                    self.outputs.insert(name.to_owned(), inner.clone());
                }
            }
            ExposedKind::Input => set_in(&mut self.inputs, inner, name),
            ExposedKind::Property => set_in(&mut self.properties, inner, name),
        }
        Ok(())
    }

    /// A name no exposed input, output or property has, for exposing `inner`: its own name, else its
    /// component's and its own (`left_image`), numbered if need be. Two inner ports are never joined
    /// under one name unless the user names them so.
    pub fn free_name(&self, inner: &PortRef) -> String {
        let taken = |name: &str| {
            self.inputs.contains_key(name)
                || self.outputs.contains_key(name)
                || self.properties.contains_key(name)
        };
        let joined = format!("{}_{}", inner.component, inner.port);
        // Fewer names are taken than there are numbers to try, so one of these is free.
        let names_taken = self.inputs.len() + self.outputs.len() + self.properties.len();
        [inner.port.clone(), joined.clone()]
            .into_iter()
            .chain((2..names_taken + 3).map(|n| format!("{joined}_{n}")))
            .find(|name| !taken(name))
            .unwrap_or(joined)
    }

    /// Follows a component's new id.
    pub fn rename_component(&mut self, from: &str, to: &str) {
        let follow = |port: &mut PortRef| {
            if port.component == from {
                to.clone_into(&mut port.component);
            }
        };
        self.outputs.values_mut().for_each(follow);
        for ports in self.inputs.values_mut().chain(self.properties.values_mut()) {
            ports.iter_mut().for_each(follow);
        }
    }

    /// Forgets what these components exposed (they are gone).
    pub fn forget_components(&mut self, ids: &[String]) {
        let kept = |port: &PortRef| !ids.contains(&port.component);
        self.outputs.retain(|_, port| kept(port));
        for map in [&mut self.inputs, &mut self.properties] {
            for ports in map.values_mut() {
                ports.retain(kept);
            }
            map.retain(|_, ports| !ports.is_empty());
        }
    }
}

/// The name whose targets include `inner`.
fn find_in<'a>(map: &'a BTreeMap<String, Vec<PortRef>>, inner: &PortRef) -> Option<&'a String> {
    map.iter()
        .find(|(_, ports)| ports.contains(inner))
        .map(|(name, _)| name)
}

/// Moves `inner` to the targets of `name` (or out of every name), dropping names left with none.
fn set_in(map: &mut BTreeMap<String, Vec<PortRef>>, inner: &PortRef, name: Option<&str>) {
    for ports in map.values_mut() {
        ports.retain(|port| port != inner);
    }
    map.retain(|_, ports| !ports.is_empty());
    if let Some(name) = name {
        map.entry(name.to_owned()).or_default().push(inner.clone());
    }
}

/// The one group every component of a [`Diagram::sequential`] diagram runs in.
pub const SEQUENTIAL_GROUP: &str = "sequential";

/// A viewer saved with a diagram: which output it shows, how, and where.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewerSpec {
    /// The output shown (`camera.image`).
    pub output: String,
    /// How it is shown, as the studio names it (`image`, `plot`, `track`, `cloud`, `trajectory`, `table`);
    /// a kind the studio does not know shows as a table.
    pub kind: String,
    /// In the studio's dock (true) or a window of its own.
    #[serde(default = "docked_by_default")]
    pub docked: bool,
    /// Outputs drawn over the first (more GNSS fixes on a track, boxes in a point cloud).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub also: Vec<String>,
    /// In the dock, the area it shows in: viewers with the same area share it as tabs; areas are
    /// stacked in the order of their numbers. Absent: an area of its own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub area: Option<u32>,
    /// The area's height as a share of the dock's (1.0 for as much as an area of default height).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub share: Option<f32>,
}

fn docked_by_default() -> bool {
    true
}

/// A machine running `kairos serve` that a diagram deploys its components marked with the host's name to.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HostSpec {
    /// Its control protocol endpoint (`ws://10.0.0.2:7600`, or `wss://` with TLS).
    pub endpoint: String,
    /// The file holding its token, relative to the diagram's folder, when it asks for one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub token_file: Option<String>,
    /// Where the other hosts reach its Zenoh session for the links between parts (`tcp/10.0.0.2:7447`);
    /// absent: the endpoint's address, port 7447. It listens there.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub zenoh: Option<String>,
    /// With a `wss://` endpoint: the certificate to trust (the host's own, or its issuer's), a PEM file
    /// relative to the diagram's folder.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub certificate: Option<String>,
    /// How long a link from this host whose consumer never skips keeps what it sends, to send it again
    /// after a cut, seconds (0 to 600); absent: [`DEFAULT_RIDE_OUT_S`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ride_out_s: Option<f64>,
    /// The most memory each such link keeps for a cut, megabytes (0 to 65 536), the oldest going first;
    /// absent: [`DEFAULT_RIDE_OUT_MB`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ride_out_mb: Option<f64>,
}

/// How long a link whose consumer never skips rides out a cut when its host does not say.
pub const DEFAULT_RIDE_OUT_S: f64 = 5.0;
/// The longest ride-out a host may ask for, seconds.
pub const MAX_RIDE_OUT_S: f64 = 600.0;
/// The memory a link keeps for a cut when its host does not say, megabytes: 5 s of a 640×480 RGB camera
/// at 30 Hz (27.6 MB/s) take 138 MB.
pub const DEFAULT_RIDE_OUT_MB: f64 = 256.0;
/// The most memory a host may give one link for a cut, megabytes.
pub const MAX_RIDE_OUT_MB: f64 = 65_536.0;

/// The Zenoh port a host listens on when its `zenoh` endpoint is not given (Zenoh's own default).
pub const DEFAULT_ZENOH_PORT: u16 = 7447;

impl HostSpec {
    /// The Zenoh endpoint the host listens on and the others connect to: `zenoh`, or the control
    /// endpoint's address with port [`DEFAULT_ZENOH_PORT`], over TLS (`tls/`) when the control endpoint
    /// is (`wss://`), else TCP.
    pub fn zenoh_endpoint(&self) -> String {
        if let Some(explicit) = &self.zenoh {
            return explicit.clone();
        }
        let authority = self
            .endpoint
            .split("://")
            .nth(1)
            .and_then(|rest| rest.split('/').next())
            .unwrap_or_default();
        let address = authority
            .rsplit_once(':')
            .map_or(authority, |(address, _)| address);
        let transport = if self.endpoint.starts_with("wss://") {
            "tls"
        } else {
            "tcp"
        };
        format!("{transport}/{address}:{DEFAULT_ZENOH_PORT}")
    }
}

impl Default for Diagram {
    fn default() -> Self {
        Diagram {
            format: FORMAT_VERSION,
            packs: Vec::new(),
            components: Vec::new(),
            connections: Vec::new(),
            clock_source: None,
            hosts: BTreeMap::new(),
            viewers: Vec::new(),
            sequential: false,
            groups: BTreeMap::new(),
            exposes: None,
        }
    }
}

impl Diagram {
    /// The component instance with this id.
    pub fn component(&self, id: &str) -> Option<&ComponentInstance> {
        self.components.iter().find(|c| c.id == id)
    }

    /// The component instance with this id, mutably.
    pub fn component_mut(&mut self, id: &str) -> Option<&mut ComponentInstance> {
        self.components.iter_mut().find(|c| c.id == id)
    }

    /// The execution group `component` runs in: the diagram's one group when it is sequential, else the
    /// component's own; `None`: a thread of its own.
    pub fn group_of<'a>(&'a self, component: &'a ComponentInstance) -> Option<&'a str> {
        if self.sequential {
            Some(SEQUENTIAL_GROUP)
        } else {
            component.group.as_deref()
        }
    }

    /// Every execution group with its members' ids, in the diagram's order.
    pub fn execution_groups(&self) -> BTreeMap<&str, Vec<&str>> {
        let mut groups: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
        for component in &self.components {
            if let Some(group) = self.group_of(component) {
                groups.entry(group).or_default().push(component.id.as_str());
            }
        }
        groups
    }
}

/// A pack a diagram needs: its name and a semantic version requirement (`^0.1`, `>=1.2, <2`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct PackRequirement {
    /// The pack's name.
    pub name: String,
    /// A semantic version requirement.
    pub version: String,
}

/// A position on the studio's canvas, in canvas units.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Position {
    /// Horizontal, growing to the right.
    pub x: f32,
    /// Vertical, growing downwards.
    pub y: f32,
}

/// Scheduling settings for a component's thread.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ThreadSettings {
    /// Real-time priority, 1 (lowest) to 99 (highest); `None` keeps the normal scheduler.
    pub priority: Option<u8>,
    /// The CPU cores the thread may run on; empty means any.
    pub affinity: Vec<usize>,
}

impl ThreadSettings {
    /// Whether nothing is set.
    pub fn is_default(&self) -> bool {
        self.priority.is_none() && self.affinity.is_empty()
    }
}

/// Settings of one output of a component instance.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct OutputSettings {
    /// The circular buffer's size; `None` keeps the component's default.
    pub buffer_size: Option<usize>,
    /// Keep one written sample in this many; `None` or 1 keeps all.
    pub subsampling: Option<u32>,
}

/// One component instance in a diagram.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ComponentInstance {
    /// Unique within the diagram: letters, digits, `_` and `-`.
    pub id: String,
    /// The component type (`core.sine`).
    pub type_name: String,
    /// Property values that differ from, or restate, the defaults.
    pub properties: BTreeMap<String, Value>,
    /// Per-output settings, by output name.
    pub outputs: BTreeMap<String, OutputSettings>,
    /// Thread priority and CPU affinity.
    pub thread: ThreadSettings,
    /// Where the studio draws it.
    pub position: Position,
    /// The host it runs on (a name of the diagram's `hosts`); `None`: the machine that deploys.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub host: Option<String>,
    /// The execution group it runs in, sharing that group's thread with the other members; `None`: a
    /// thread of its own (RTMaps' default).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub group: Option<String>,
}

impl ComponentInstance {
    /// A new instance with no property values set.
    pub fn new(id: impl Into<String>, type_name: impl Into<String>) -> Self {
        ComponentInstance {
            id: id.into(),
            type_name: type_name.into(),
            properties: BTreeMap::new(),
            outputs: BTreeMap::new(),
            thread: ThreadSettings::default(),
            position: Position::default(),
            host: None,
            group: None,
        }
    }
}

/// A port of a component instance, written `component.port` in files.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct PortRef {
    /// The component instance's id.
    pub component: String,
    /// The port's name.
    pub port: String,
}

impl PortRef {
    /// A reference to `component.port`.
    pub fn new(component: impl Into<String>, port: impl Into<String>) -> Self {
        PortRef {
            component: component.into(),
            port: port.into(),
        }
    }

    /// Parses `component.port`; the port is what follows the last dot.
    pub fn parse(text: &str) -> Option<PortRef> {
        let (component, port) = text.rsplit_once('.')?;
        if component.is_empty() || port.is_empty() {
            return None;
        }
        Some(PortRef::new(component, port))
    }
}

impl fmt::Display for PortRef {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{}", self.component, self.port)
    }
}

/// A connection from an output to an input.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Connection {
    /// The producing output.
    pub from: PortRef,
    /// The consuming input.
    pub to: PortRef,
    /// The reader policy; `None` uses the input's default.
    pub policy: Option<ReaderPolicy>,
    /// This reader's share of the output's circular buffer; `None` uses the output's size.
    pub buffer_size: Option<usize>,
    /// Keep one sample in this many on the input; `None` or 1 keeps all.
    pub subsampling: Option<u32>,
}

impl Connection {
    /// A connection with default policy, buffer size and subsampling.
    pub fn new(from: PortRef, to: PortRef) -> Self {
        Connection {
            from,
            to,
            policy: None,
            buffer_size: None,
            subsampling: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn port(text: &str) -> PortRef {
        PortRef::parse(text).unwrap()
    }

    #[test]
    fn a_property_given_an_exposed_name_joins_it_and_leaves_its_old_name() {
        let mut exposes = Exposes::default();
        let (a, b) = (port("a.gain"), port("b.gain"));
        exposes.set(ExposedKind::Property, &a, Some("gain")).unwrap();
        exposes.set(ExposedKind::Property, &b, Some("b_gain")).unwrap();
        exposes.set(ExposedKind::Property, &b, Some("gain")).unwrap();
        assert_eq!(exposes.properties.len(), 1, "b_gain, left empty, is gone");
        assert_eq!(exposes.properties["gain"], vec![a.clone(), b.clone()]);
        assert_eq!(exposes.name_of(ExposedKind::Property, &b), Some("gain"));
        exposes.set(ExposedKind::Property, &a, None).unwrap();
        assert_eq!(exposes.properties["gain"], vec![b]);
        assert_eq!(exposes.name_of(ExposedKind::Property, &a), None);
    }

    #[test]
    fn an_output_name_is_its_own_and_names_must_be_ids() {
        let mut exposes = Exposes::default();
        exposes
            .set(ExposedKind::Output, &port("a.out"), Some("out"))
            .unwrap();
        let taken = exposes.set(ExposedKind::Output, &port("b.out"), Some("out"));
        assert!(taken.unwrap_err().to_string().contains("already shows a.out"));
        let clash = exposes.set(ExposedKind::Input, &port("b.in"), Some("out"));
        assert!(clash.unwrap_err().to_string().contains("choose another name"));
        let bad = exposes.set(ExposedKind::Input, &port("b.in"), Some("two words"));
        assert!(bad.unwrap_err().to_string().contains("letters, digits"));
        exposes
            .set(ExposedKind::Output, &port("a.out"), Some("renamed"))
            .unwrap();
        assert_eq!(exposes.outputs.keys().collect::<Vec<_>>(), ["renamed"]);
    }

    #[test]
    fn a_free_name_is_the_port_s_own_else_joined_with_its_component_s() {
        let mut exposes = Exposes::default();
        assert_eq!(exposes.free_name(&port("left.image")), "image");
        exposes
            .set(ExposedKind::Output, &port("left.image"), Some("image"))
            .unwrap();
        assert_eq!(exposes.free_name(&port("right.image")), "right_image");
        exposes
            .set(ExposedKind::Input, &port("x.in"), Some("right_image"))
            .unwrap();
        assert_eq!(exposes.free_name(&port("right.image")), "right_image_2");
    }

    #[test]
    fn exposures_follow_a_renamed_component_and_go_with_a_removed_one() {
        let mut exposes = Exposes::default();
        exposes
            .set(ExposedKind::Input, &port("a.in"), Some("in"))
            .unwrap();
        exposes
            .set(ExposedKind::Input, &port("b.in"), Some("in"))
            .unwrap();
        exposes
            .set(ExposedKind::Output, &port("b.out"), Some("out"))
            .unwrap();
        exposes.rename_component("a", "first");
        assert_eq!(exposes.inputs["in"], vec![port("first.in"), port("b.in")]);
        exposes.forget_components(&["b".to_owned()]);
        assert_eq!(exposes.inputs["in"], vec![port("first.in")]);
        assert!(exposes.outputs.is_empty());
        exposes.forget_components(&["first".to_owned()]);
        assert!(exposes.is_empty());
    }
}
