//! What a component library offers, as plain data: component descriptors, port types, property kinds.
//!
//! The runtime builds this from its packs; the validator, the CLI and (later) the studio read it without
//! running anything.

use std::collections::BTreeMap;
use std::fmt;

use serde::{Deserialize, Serialize};

/// The type of the samples an output produces.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DataType {
    /// One `f64`.
    F64,
    /// One `i64`.
    I64,
    /// One `bool`.
    Bool,
    /// A vector of `f64`.
    Vector,
    /// A row-major matrix of `f64`.
    Matrix,
    /// UTF-8 text.
    Text,
    /// Raw bytes.
    Bytes,
    /// An image with its pixel format.
    Image,
    /// 3D points with optional intensity.
    PointCloud,
    /// An inertial measurement: angular velocity and linear acceleration.
    Imu,
    /// A satellite navigation fix.
    GnssFix,
    /// A CAN bus frame.
    CanFrame,
    /// A position and orientation.
    Pose,
    /// A type defined by a pack, registered under this name.
    Custom(String),
}

impl DataType {
    /// Every built-in type, in a stable order.
    pub const BUILT_IN: [DataType; 13] = [
        DataType::F64,
        DataType::I64,
        DataType::Bool,
        DataType::Vector,
        DataType::Matrix,
        DataType::Text,
        DataType::Bytes,
        DataType::Image,
        DataType::PointCloud,
        DataType::Imu,
        DataType::GnssFix,
        DataType::CanFrame,
        DataType::Pose,
    ];

    /// The name used in diagrams and listings (`f64`, `image`, or a custom type's own name).
    pub fn name(&self) -> &str {
        match self {
            DataType::F64 => "f64",
            DataType::I64 => "i64",
            DataType::Bool => "bool",
            DataType::Vector => "vector",
            DataType::Matrix => "matrix",
            DataType::Text => "text",
            DataType::Bytes => "bytes",
            DataType::Image => "image",
            DataType::PointCloud => "point_cloud",
            DataType::Imu => "imu",
            DataType::GnssFix => "gnss_fix",
            DataType::CanFrame => "can_frame",
            DataType::Pose => "pose",
            DataType::Custom(name) => name,
        }
    }

    /// Parses a name as printed by [`DataType::name`]; anything else is a custom type.
    pub fn from_name(name: &str) -> DataType {
        DataType::BUILT_IN
            .iter()
            .find(|t| t.name() == name)
            .cloned()
            .unwrap_or_else(|| DataType::Custom(name.to_owned()))
    }
}

impl fmt::Display for DataType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A kind of device a property can name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DeviceKind {
    /// A serial port (`/dev/ttyUSB0`).
    Serial,
    /// A CAN interface (`can0`).
    Can,
    /// A camera (`/dev/video0`).
    Camera,
    /// A topic on a live ROS 2 graph (`/imu/data`), as the component's `router` and `domain_id` reach it.
    Ros2Topic,
    /// A service on a live ROS 2 graph (`/reset`), reached as a topic is.
    Ros2Service,
}

impl DeviceKind {
    /// The name used in listings and the protocol (`serial`, `can`, `camera`).
    pub fn name(self) -> &'static str {
        match self {
            DeviceKind::Serial => "serial",
            DeviceKind::Can => "can",
            DeviceKind::Camera => "camera",
            DeviceKind::Ros2Topic => "ros2_topic",
            DeviceKind::Ros2Service => "ros2_service",
        }
    }
}

impl fmt::Display for DeviceKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Which output types an input accepts.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TypeFilter {
    /// Any type at all.
    Any,
    /// Exactly one of these types.
    OneOf(Vec<DataType>),
}

impl TypeFilter {
    /// A filter accepting exactly one type.
    pub fn only(data_type: DataType) -> TypeFilter {
        TypeFilter::OneOf(vec![data_type])
    }

    /// Whether an output of `data_type` may feed an input with this filter.
    pub fn accepts(&self, data_type: &DataType) -> bool {
        match self {
            TypeFilter::Any => true,
            TypeFilter::OneOf(types) => types.contains(data_type),
        }
    }
}

impl fmt::Display for TypeFilter {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TypeFilter::Any => f.write_str("any"),
            TypeFilter::OneOf(types) => {
                let names: Vec<&str> = types.iter().map(DataType::name).collect();
                f.write_str(&names.join(" | "))
            }
        }
    }
}

/// How an input reads its producer's circular buffer (paper, section 2.2.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
pub enum ReaderPolicy {
    /// Oldest unread first; blocks when nothing is new; overwritten samples are counted.
    #[default]
    Fifo,
    /// Newest unread; skips (and counts) older pending ones; blocks when nothing is new.
    LastOrNext,
    /// Ignores everything pending and waits for the next sample.
    WaitForNext,
    /// Returns the newest sample at once, possibly the same one again.
    Sampling,
    /// Like FIFO, but a full buffer blocks the writer instead of overwriting.
    NeverSkipping,
}

impl ReaderPolicy {
    /// Every policy, in the paper's order.
    pub const ALL: [ReaderPolicy; 5] = [
        ReaderPolicy::Fifo,
        ReaderPolicy::LastOrNext,
        ReaderPolicy::WaitForNext,
        ReaderPolicy::Sampling,
        ReaderPolicy::NeverSkipping,
    ];

    /// What the policy does, in one line for people choosing it (the studio's reader settings).
    pub fn explanation(self) -> &'static str {
        match self {
            ReaderPolicy::Fifo => {
                "Every sample in order, the oldest first; if the reader falls behind, the oldest are \
                 overwritten (and counted)"
            }
            ReaderPolicy::LastOrNext => {
                "The newest sample not read yet: older ones waiting are skipped (and counted)"
            }
            ReaderPolicy::WaitForNext => {
                "Only a sample that arrives after the reader asks: whatever is waiting is ignored"
            }
            ReaderPolicy::Sampling => {
                "The newest sample at once, even one read before: the reader never waits"
            }
            ReaderPolicy::NeverSkipping => {
                "Every sample in order and none lost: when the buffer is full the producer waits"
            }
        }
    }

    /// Whether a read takes the newest sample, passing over older pending ones (LastOrNext, WaitForNext,
    /// Sampling), rather than the oldest (FIFO, NeverSkipping).
    pub fn reads_newest(self) -> bool {
        matches!(
            self,
            ReaderPolicy::LastOrNext | ReaderPolicy::WaitForNext | ReaderPolicy::Sampling
        )
    }

    /// The name used in diagram files.
    pub fn name(self) -> &'static str {
        match self {
            ReaderPolicy::Fifo => "Fifo",
            ReaderPolicy::LastOrNext => "LastOrNext",
            ReaderPolicy::WaitForNext => "WaitForNext",
            ReaderPolicy::Sampling => "Sampling",
            ReaderPolicy::NeverSkipping => "NeverSkipping",
        }
    }
}

impl fmt::Display for ReaderPolicy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A property value.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Value {
    /// A boolean.
    Bool(bool),
    /// An integer.
    I64(i64),
    /// A floating-point number.
    F64(f64),
    /// Text: free text, a choice, or a file path.
    Text(String),
}

impl Value {
    /// The value as a float, converting integers.
    pub fn as_f64(&self) -> Option<f64> {
        match self {
            Value::F64(v) => Some(*v),
            Value::I64(v) => Some(*v as f64),
            _ => None,
        }
    }

    /// The value as an integer (floats are not converted).
    pub fn as_i64(&self) -> Option<i64> {
        match self {
            Value::I64(v) => Some(*v),
            _ => None,
        }
    }

    /// The value as a boolean.
    pub fn as_bool(&self) -> Option<bool> {
        match self {
            Value::Bool(v) => Some(*v),
            _ => None,
        }
    }

    /// The value as text.
    pub fn as_text(&self) -> Option<&str> {
        match self {
            Value::Text(v) => Some(v),
            _ => None,
        }
    }

    /// A short name of the value's kind, for messages.
    pub fn kind_name(&self) -> &'static str {
        match self {
            Value::Bool(_) => "a boolean",
            Value::I64(_) => "an integer",
            Value::F64(_) => "a number",
            Value::Text(_) => "text",
        }
    }
}

impl From<f64> for Value {
    fn from(value: f64) -> Self {
        Value::F64(value)
    }
}

impl From<i64> for Value {
    fn from(value: i64) -> Self {
        Value::I64(value)
    }
}

impl From<bool> for Value {
    fn from(value: bool) -> Self {
        Value::Bool(value)
    }
}

impl From<&str> for Value {
    fn from(value: &str) -> Self {
        Value::Text(value.to_owned())
    }
}

impl From<String> for Value {
    fn from(value: String) -> Self {
        Value::Text(value)
    }
}

impl fmt::Display for Value {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Value::Bool(v) => write!(f, "{v}"),
            Value::I64(v) => write!(f, "{v}"),
            Value::F64(v) => write!(f, "{v:?}"),
            Value::Text(v) => write!(f, "{v:?}"),
        }
    }
}

/// The kind of a property, with its constraints.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PropertyKind {
    /// A float within an inclusive range (either bound optional).
    F64 {
        /// The smallest accepted value.
        min: Option<f64>,
        /// The largest accepted value.
        max: Option<f64>,
    },
    /// An integer within an inclusive range (either bound optional).
    I64 {
        /// The smallest accepted value.
        min: Option<i64>,
        /// The largest accepted value.
        max: Option<i64>,
    },
    /// A boolean.
    Bool,
    /// Free text.
    Text,
    /// One of a fixed list of texts.
    Choice(Vec<String>),
    /// A file system path.
    Path,
}

/// Why a value does not fit a property.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ValueError {
    /// The value has the wrong kind.
    #[error("expected {expected}, found {found}")]
    WrongKind {
        /// What the property takes.
        expected: String,
        /// What was given.
        found: String,
    },
    /// The value lies outside the property's range.
    #[error("{value} is out of range {range}")]
    OutOfRange {
        /// The value given.
        value: String,
        /// The accepted range, as text.
        range: String,
    },
    /// The text is not one of the choices.
    #[error("{value:?} is not one of {choices}")]
    NotAChoice {
        /// The value given.
        value: String,
        /// The accepted choices, as text.
        choices: String,
    },
}

/// A number as people read it: short even when huge or tiny (-1e308, not 309 digits).
struct Readable(f64);

impl fmt::Display for Readable {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.0.abs() >= 1e15 || (self.0 != 0.0 && self.0.abs() < 1e-6) {
            write!(f, "{:e}", self.0)
        } else {
            write!(f, "{}", self.0)
        }
    }
}

impl PropertyKind {
    /// A short description for messages and listings (`f64 in [0, 100]`).
    pub fn describe(&self) -> String {
        fn range<T: fmt::Display>(min: Option<&T>, max: Option<&T>) -> String {
            match (min, max) {
                (None, None) => String::new(),
                (Some(lo), None) => format!(" >= {lo}"),
                (None, Some(hi)) => format!(" <= {hi}"),
                (Some(lo), Some(hi)) => format!(" in [{lo}, {hi}]"),
            }
        }
        match self {
            PropertyKind::F64 { min, max } => format!(
                "f64{}",
                range(min.map(Readable).as_ref(), max.map(Readable).as_ref())
            ),
            PropertyKind::I64 { min, max } => format!("i64{}", range(min.as_ref(), max.as_ref())),
            PropertyKind::Bool => "bool".to_owned(),
            PropertyKind::Text => "text".to_owned(),
            PropertyKind::Choice(choices) => format!("one of {}", choices.join(" | ")),
            PropertyKind::Path => "path".to_owned(),
        }
    }

    /// Checks a value against this kind and returns it normalised (an integer given for a float
    /// property becomes a float).
    pub fn check(&self, value: &Value) -> Result<Value, ValueError> {
        let wrong_kind = || ValueError::WrongKind {
            expected: self.describe(),
            found: value.kind_name().to_owned(),
        };
        match self {
            PropertyKind::F64 { min, max } => {
                let v = value.as_f64().ok_or_else(wrong_kind)?;
                let below = min.is_some_and(|lo| v < lo);
                let above = max.is_some_and(|hi| v > hi);
                if below || above || v.is_nan() {
                    return Err(ValueError::OutOfRange {
                        value: Readable(v).to_string(),
                        range: self.describe(),
                    });
                }
                Ok(Value::F64(v))
            }
            PropertyKind::I64 { min, max } => {
                let v = value.as_i64().ok_or_else(wrong_kind)?;
                if min.is_some_and(|lo| v < lo) || max.is_some_and(|hi| v > hi) {
                    return Err(ValueError::OutOfRange {
                        value: v.to_string(),
                        range: self.describe(),
                    });
                }
                Ok(Value::I64(v))
            }
            PropertyKind::Bool => value.as_bool().map(Value::Bool).ok_or_else(wrong_kind),
            PropertyKind::Text | PropertyKind::Path => value
                .as_text()
                .map(|t| Value::Text(t.to_owned()))
                .ok_or_else(wrong_kind),
            PropertyKind::Choice(choices) => {
                let text = value.as_text().ok_or_else(wrong_kind)?;
                if choices.iter().any(|c| c == text) {
                    Ok(Value::Text(text.to_owned()))
                } else {
                    Err(ValueError::NotAChoice {
                        value: text.to_owned(),
                        choices: choices.join(" | "),
                    })
                }
            }
        }
    }
}

/// How the runtime drives a component.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ExecutionMode {
    /// In a named thread of its own; `core` is called in a loop and blocks on its inputs.
    Threaded,
    /// Without a thread of its own: `core` runs in the producer's thread when a sample arrives
    /// (the paper's "sequential behaviour").
    Reactive,
    /// In a thread of its own, `core` called once per period on the runtime clock.
    Periodic,
}

/// One input port.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InputInfo {
    /// The port's name, unique among the component's inputs.
    pub name: String,
    /// The output types it accepts.
    pub filter: TypeFilter,
    /// The policy used when a connection names none.
    pub default_policy: ReaderPolicy,
    /// One line of documentation.
    pub doc: String,
}

/// One output port.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OutputInfo {
    /// The port's name, unique among the component's outputs.
    pub name: String,
    /// The type of the samples it produces (for an output that follows an input, the type it shows when
    /// that input is not connected).
    pub data_type: DataType,
    /// When set, the output carries samples of whatever type feeds this input (a subsampler, a
    /// pass-through probe): its effective type is resolved through the diagram's connections.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub follows_input: Option<String>,
    /// The circular buffer's size when no connection overrides it.
    pub default_buffer_size: usize,
    /// One line of documentation.
    pub doc: String,
    /// The name its samples go by, when not `component.port`: the end of a link from another host
    /// carries its producer's (`camera.image`), so recorders, viewers and statistics on this host name
    /// them as the diagram does.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub known_as: Option<String>,
}

/// One property.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PropertyInfo {
    /// The property's name.
    pub name: String,
    /// Its kind and constraints.
    pub kind: PropertyKind,
    /// The value used when the diagram gives none.
    pub default: Value,
    /// Whether it may change while the diagram runs.
    pub live: bool,
    /// One line of documentation.
    pub doc: String,
    /// The unit of a number (`Hz`, `m`, `ms`); empty when it has none.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub unit: String,
    /// The kind of device the property names (a serial port, a CAN interface, a camera), so an editor
    /// can offer the devices present.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub device: Option<DeviceKind>,
}

/// One action: a button a user may press at any time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ActionInfo {
    /// The action's name.
    pub name: String,
    /// One line of documentation.
    pub doc: String,
}

/// Everything known about a component type without running it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[expect(
    clippy::struct_excessive_bools,
    reason = "each flag is a declaration of its own a descriptor makes, written by name in a pack's description"
)]
pub struct ComponentInfo {
    /// The type name used in diagrams, `pack.name` by convention (`core.sine`).
    pub type_name: String,
    /// The pack that provides it.
    pub pack: String,
    /// The name people read in the studio's palette (`Sine wave`); empty when the pack gives none, and
    /// then [`ComponentInfo::display_name`] derives one from the type name.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub label: String,
    /// A category for grouping (`generators`, `math`, `sensors`, ...).
    pub category: String,
    /// One line of documentation.
    pub doc: String,
    /// How the runtime drives it.
    pub mode: ExecutionMode,
    /// Its inputs.
    pub inputs: Vec<InputInfo>,
    /// Its outputs.
    pub outputs: Vec<OutputInfo>,
    /// Its properties.
    pub properties: Vec<PropertyInfo>,
    /// Its actions.
    pub actions: Vec<ActionInfo>,
    /// Whether it can be the diagram's clock source (it gives the runtime clock references of true time,
    /// as a GNSS receiver does).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub time_source: bool,
    /// Whether its time is simulated time (a simulator): as the diagram's clock source it does not
    /// discipline the runtime clock, it is the runtime clock, paced by its `time_scale` property (1: real
    /// time, 0: as fast as the diagram runs, which needs a sequential diagram).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub simulated_time: bool,
    /// Whether it reads its inputs at its own ticks as held values (a simulator's commands): the links
    /// into it do not order an execution group, so a loop through it is allowed there.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub holds_inputs: bool,
    /// Whether it stops as soon as a stop is asked for, without first reading what its producers wrote
    /// before they stopped: a link's sending end, whose receiving end on another host stops at the same
    /// instant and would take nothing sent after it.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub stops_at_once: bool,
    /// Why a call of it may wait for long (on a device, a socket, its own timing), in words ("waits for
    /// each frame of the camera"): such a
    /// component cannot share an execution group's thread, except as the group's driver.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub blocking: Option<String>,
}

impl ComponentInfo {
    /// Why the component may keep an execution group's thread waiting: what its descriptor says, or,
    /// for a threaded source (no inputs), that it keeps its own time. `None`: it can share a group.
    pub fn blocking_reason(&self) -> Option<String> {
        if let Some(reason) = &self.blocking {
            return Some(reason.clone());
        }
        (self.mode == ExecutionMode::Threaded && self.inputs.is_empty())
            .then(|| "a source that keeps its own time: a device, a file or a socket".to_owned())
    }

    /// The name people read: the pack's label, else one derived from the type name
    /// ([`readable_type_name`]).
    pub fn display_name(&self) -> String {
        if self.label.trim().is_empty() {
            readable_type_name(&self.type_name)
        } else {
            self.label.trim().to_owned()
        }
    }

    /// The input with this name.
    pub fn input(&self, name: &str) -> Option<&InputInfo> {
        self.inputs.iter().find(|p| p.name == name)
    }

    /// The output with this name.
    pub fn output(&self, name: &str) -> Option<&OutputInfo> {
        self.outputs.iter().find(|p| p.name == name)
    }

    /// The property with this name.
    pub fn property(&self, name: &str) -> Option<&PropertyInfo> {
        self.properties.iter().find(|p| p.name == name)
    }

    /// The value of property `name` among an instance's `properties`, else its default.
    pub fn property_value<'a>(
        &'a self,
        properties: &'a BTreeMap<String, Value>,
        name: &str,
    ) -> Option<&'a Value> {
        properties
            .get(name)
            .or_else(|| self.property(name).map(|p| &p.default))
    }

    /// The action with this name.
    pub fn action(&self, name: &str) -> Option<&ActionInfo> {
        self.actions.iter().find(|a| a.name == name)
    }
}

/// Short words that are read letter by letter, written in capitals by [`readable_type_name`].
const ACRONYMS: [&str; 12] = [
    "csv", "gnss", "imu", "can", "dbc", "nmea", "rgb", "mcap", "ekf", "enu", "gps", "id",
];

/// The output a `recording.player` gives a recorded topic (`camera.image` → `camera_image`): each
/// character that is not a letter, a digit or `_` becomes `_`, and `_` at either end goes (`channel` when
/// nothing is left). The studio's Replay names the player's outputs by the same rule.
pub fn port_name_for_topic(topic: &str) -> String {
    let name: String = topic
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    let name = name.trim_matches('_');
    if name.is_empty() {
        "channel".to_owned()
    } else {
        name.to_owned()
    }
}

/// A readable name made from a type name, for components whose pack gives no label: the part after the
/// pack, words spaced and the first capitalised, acronyms in capitals (`core.moving_average` is
/// "Moving average", `core.csv_writer` "CSV writer").
pub fn readable_type_name(type_name: &str) -> String {
    let short = type_name.rsplit('.').next().unwrap_or(type_name);
    let words: Vec<String> = short
        .split(['_', '-'])
        .filter(|w| !w.is_empty())
        .enumerate()
        .map(|(index, word)| {
            if ACRONYMS.contains(&word.to_ascii_lowercase().as_str()) {
                word.to_uppercase()
            } else if index == 0 {
                let mut chars = word.chars();
                chars
                    .next()
                    .map_or_else(String::new, |first| first.to_uppercase().chain(chars).collect())
            } else {
                word.to_owned()
            }
        })
        .collect();
    if words.is_empty() {
        type_name.to_owned()
    } else {
        words.join(" ")
    }
}

/// Why a component whose ports depend on its properties (a player's outputs come from its recording)
/// could not describe itself.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct DescribeError {
    /// The property at fault, when one is.
    pub property: Option<String>,
    /// What went wrong.
    pub message: String,
    /// How to fix it, when known.
    pub suggestion: Option<String>,
}

impl DescribeError {
    /// An error about `property`.
    pub fn property(property: &str, message: impl Into<String>) -> Self {
        DescribeError {
            property: Some(property.to_owned()),
            message: message.into(),
            suggestion: None,
        }
    }

    /// Adds a suggestion.
    #[must_use]
    pub fn with_suggestion(mut self, suggestion: impl Into<String>) -> Self {
        self.suggestion = Some(suggestion.into());
        self
    }
}

/// Descriptors of component instances whose ports depend on their properties, by component id: what
/// [`crate::validate_with`] uses instead of the library's descriptor of their type.
pub type InstanceInfos = BTreeMap<String, Result<ComponentInfo, DescribeError>>;

/// A pack as the library knows it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct PackInfo {
    /// The pack's name (`core`).
    pub name: String,
    /// Its semantic version (`0.1.0`).
    pub version: String,
    /// Where it came from: `built-in` or a library path.
    pub origin: String,
}

/// A whole component library: packs, components and pack-defined types.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct LibraryInfo {
    /// The packs, by name.
    pub packs: BTreeMap<String, PackInfo>,
    /// The components, by type name.
    pub components: BTreeMap<String, ComponentInfo>,
    /// Names of pack-defined data types.
    pub custom_types: Vec<String>,
    /// Descriptions of particular instances, by id, for types whose ports depend on their properties (a
    /// player's outputs follow its recordings). Filled by clients that asked the runtime for them
    /// (`describe_instances`); empty in the library the runtime sends.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub instances: BTreeMap<String, ComponentInfo>,
    /// The subgraphs packs ship, by type name (`vision.lane_pipeline`): each one's diagram text, used as
    /// a subgraph file is (see [`crate::subgraph`]) and versioned with its pack.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub subgraphs: BTreeMap<String, String>,
}

impl LibraryInfo {
    /// The component type with this name.
    pub fn component(&self, type_name: &str) -> Option<&ComponentInfo> {
        self.components.get(type_name)
    }

    /// Whether `type_name` names a subgraph: a diagram file, or one a pack of this library ships.
    pub fn names_subgraph(&self, type_name: &str) -> bool {
        crate::subgraph::is_subgraph_type(type_name) || self.subgraphs.contains_key(type_name)
    }

    /// What `instance` is: its own description when one is known for it (and still of its type), else its
    /// type's.
    pub fn component_of(&self, instance: &crate::model::ComponentInstance) -> Option<&ComponentInfo> {
        self.instances
            .get(&instance.id)
            .filter(|info| info.type_name == instance.type_name)
            .or_else(|| self.component(&instance.type_name))
    }
}

#[cfg(test)]
mod tests {
    use super::{PropertyKind, Value, ValueError};

    #[test]
    fn numbers_in_range_errors_stay_short() {
        let kind = PropertyKind::F64 {
            min: Some(0.0),
            max: Some(1e300),
        };
        let error = kind.check(&Value::F64(-1e308)).unwrap_err();
        assert_eq!(
            error,
            ValueError::OutOfRange {
                value: "-1e308".to_owned(),
                range: "f64 in [0, 1e300]".to_owned(),
            }
        );
        assert_eq!(error.to_string(), "-1e308 is out of range f64 in [0, 1e300]");
    }

    #[test]
    fn a_component_without_a_label_gets_a_name_from_its_type() {
        assert_eq!(super::readable_type_name("core.moving_average"), "Moving average");
        assert_eq!(super::readable_type_name("core.csv_writer"), "CSV writer");
        assert_eq!(super::readable_type_name("sensors.gnss"), "GNSS");
        assert_eq!(super::readable_type_name("lab.scale"), "Scale");
        assert_eq!(super::readable_type_name("odd"), "Odd");
        assert_eq!(super::readable_type_name("x._"), "x._");
        let unlabelled = super::ComponentInfo {
            type_name: "core.sine".to_owned(),
            pack: "core".to_owned(),
            label: " ".to_owned(),
            category: "generators".to_owned(),
            doc: String::new(),
            mode: super::ExecutionMode::Periodic,
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
        assert_eq!(unlabelled.display_name(), "Sine");
        let labelled = super::ComponentInfo {
            label: "Sine wave".to_owned(),
            ..unlabelled
        };
        assert_eq!(labelled.display_name(), "Sine wave");
    }
}
