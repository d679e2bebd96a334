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
