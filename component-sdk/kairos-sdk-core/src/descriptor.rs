//! Builders that make component descriptors short to write.
//!
//! ```
//! use kairos_sdk::descriptor::{Descriptor, Property};
//! use kairos_sdk::{DataType, ExecutionMode, TypeFilter};
//!
//! let info = Descriptor::new("core.gain", "math", "Multiplies its input by a gain")
//!     .label("Gain")
//!     .mode(ExecutionMode::Threaded)
//!     .input("in", TypeFilter::OneOf(vec![DataType::F64, DataType::I64]), "The signal")
//!     .output("out", DataType::F64, "The signal times the gain")
//!     .property(Property::f64("gain", 1.0).doc("The factor").live())
//!     .build();
//! assert_eq!(info.inputs.len(), 1);
//! ```

use kairos_diagram::{
    ActionInfo, ComponentInfo, DataType, DeviceKind, ExecutionMode, InputInfo, OutputInfo, PropertyInfo,
    PropertyKind, ReaderPolicy, TypeFilter, Value,
};

/// The buffer size an output gets unless its descriptor or the diagram says otherwise.
pub const DEFAULT_BUFFER_SIZE: usize = 16;

/// Builds a [`ComponentInfo`].
#[derive(Debug, Clone)]
#[must_use]
pub struct Descriptor {
    info: ComponentInfo,
}

impl Descriptor {
    /// A threaded component with no ports, properties or actions yet. The pack is filled in when the
    /// component is registered.
    pub fn new(type_name: &str, category: &str, doc: &str) -> Self {
        Descriptor {
            info: ComponentInfo {
                type_name: type_name.to_owned(),
                pack: String::new(),
                label: String::new(),
                category: category.to_owned(),
                doc: doc.to_owned(),
                mode: ExecutionMode::Threaded,
                inputs: Vec::new(),
                outputs: Vec::new(),
                properties: Vec::new(),
                actions: Vec::new(),
                time_source: false,
                simulated_time: false,
                holds_inputs: false,
                stops_at_once: false,
                blocking: None,
            },
        }
    }

    /// Declares that the component can be the diagram's clock source: it calls
    /// [`crate::Context::clock_reference`] with the true time it receives (a GNSS receiver's UTC).
    pub fn time_source(mut self) -> Self {
        self.info.time_source = true;
        self
    }

    /// Declares that the component keeps simulated time (a simulator): as the diagram's clock source it
    /// is the runtime clock, paced by its `time_scale` property, which it must declare (1: real time, 0:
    /// as fast as the diagram runs, for a sequential diagram).
    pub fn simulated_time(mut self) -> Self {
        self.info.time_source = true;
        self.info.simulated_time = true;
        self
    }

    /// Declares that the component reads its inputs at its own ticks, as held values (a simulator's
    /// commands): links into it do not order an execution group, so a loop may close through it.
    pub fn holds_inputs(mut self) -> Self {
        self.info.holds_inputs = true;
        self
    }

    /// Declares that the component stops as soon as a stop is asked for: the runtime otherwise lets it
    /// read what its producers wrote before they stopped (for up to a second). For a component whose far
    /// end stops at the same instant, such as a link to another host.
    pub fn stops_at_once(mut self) -> Self {
        self.info.stops_at_once = true;
        self
    }

    /// Declares that a call of the component may wait for long (on a device, a socket, its own timing),
    /// and why, in words: it cannot then share an execution group's thread except as the group's
    /// driver. Threaded sources (no inputs) are taken to wait without saying so.
    pub fn blocking(mut self, reason: &str) -> Self {
        self.info.blocking = Some(reason.to_owned());
        self
    }

    /// Sets the name people read in the studio's palette (`Sine wave`). Without one the studio derives a
    /// name from the type name (`core.moving_average` is "Moving average").
    pub fn label(mut self, label: &str) -> Self {
        label.trim().clone_into(&mut self.info.label);
        self
    }

    /// Sets how the runtime drives the component.
    pub fn mode(mut self, mode: ExecutionMode) -> Self {
        self.info.mode = mode;
        self
    }

    /// Adds an input read FIFO unless the connection says otherwise.
    pub fn input(self, name: &str, filter: TypeFilter, doc: &str) -> Self {
        self.input_with_policy(name, filter, ReaderPolicy::Fifo, doc)
    }

    /// Adds an input with its default reader policy.
    pub fn input_with_policy(
        mut self,
        name: &str,
        filter: TypeFilter,
        policy: ReaderPolicy,
        doc: &str,
    ) -> Self {
        self.info.inputs.push(InputInfo {
            name: name.to_owned(),
            filter,
            default_policy: policy,
            doc: doc.to_owned(),
        });
        self
    }

    /// Adds an output with the default buffer size.
    pub fn output(self, name: &str, data_type: DataType, doc: &str) -> Self {
        self.output_with_buffer(name, data_type, DEFAULT_BUFFER_SIZE, doc)
    }

    /// Adds an output with its own default buffer size.
    pub fn output_with_buffer(
        mut self,
        name: &str,
        data_type: DataType,
        buffer_size: usize,
        doc: &str,
    ) -> Self {
        self.info.outputs.push(OutputInfo {
            name: name.to_owned(),
            data_type,
            follows_input: None,
            default_buffer_size: buffer_size.max(1),
            doc: doc.to_owned(),
            known_as: None,
        });
        self
    }

    /// Adds an output that carries samples of whatever type feeds `input` (a pass-through).
    pub fn output_following(mut self, name: &str, input: &str, doc: &str) -> Self {
        self.info.outputs.push(OutputInfo {
            name: name.to_owned(),
            data_type: DataType::Custom(format!("same as {input}")),
            follows_input: Some(input.to_owned()),
            default_buffer_size: DEFAULT_BUFFER_SIZE,
            doc: doc.to_owned(),
            known_as: None,
        });
        self
    }

    /// Adds a property.
    pub fn property(mut self, property: Property) -> Self {
        self.info.properties.push(property.info);
        self
    }

    /// Adds an action.
    pub fn action(mut self, name: &str, doc: &str) -> Self {
        self.info.actions.push(ActionInfo {
            name: name.to_owned(),
            doc: doc.to_owned(),
        });
        self
    }

    /// The finished descriptor.
    pub fn build(self) -> ComponentInfo {
        self.info
    }
}

/// Builds a [`PropertyInfo`].
#[derive(Debug, Clone)]
#[must_use]
pub struct Property {
    info: PropertyInfo,
}

impl Property {
    fn new(name: &str, kind: PropertyKind, default: Value) -> Self {
        Property {
            info: PropertyInfo {
                name: name.to_owned(),
                kind,
                default,
                live: false,
                doc: String::new(),
                unit: String::new(),
                device: None,
            },
        }
    }

    /// Marks the property as naming a device of `kind`: the studio offers the devices of that kind
    /// present on the runtime's machine.
    pub fn device(mut self, kind: DeviceKind) -> Self {
        self.info.device = Some(kind);
        self
    }

    /// A float property.
    pub fn f64(name: &str, default: f64) -> Self {
        Self::new(
            name,
            PropertyKind::F64 { min: None, max: None },
            Value::F64(default),
        )
    }

    /// An integer property.
    pub fn i64(name: &str, default: i64) -> Self {
        Self::new(
            name,
            PropertyKind::I64 { min: None, max: None },
            Value::I64(default),
        )
    }

    /// A boolean property.
    pub fn bool(name: &str, default: bool) -> Self {
        Self::new(name, PropertyKind::Bool, Value::Bool(default))
    }

    /// A free-text property.
    pub fn text(name: &str, default: &str) -> Self {
        Self::new(name, PropertyKind::Text, Value::Text(default.to_owned()))
    }

    /// A file-path property.
    pub fn path(name: &str, default: &str) -> Self {
        Self::new(name, PropertyKind::Path, Value::Text(default.to_owned()))
    }

    /// A choice among fixed texts.
    pub fn choice(name: &str, choices: &[&str], default: &str) -> Self {
        Self::new(
            name,
            PropertyKind::Choice(choices.iter().map(|c| (*c).to_owned()).collect()),
            Value::Text(default.to_owned()),
        )
    }

    /// Sets an inclusive range on a float property.
    pub fn range(mut self, min: f64, max: f64) -> Self {
        if let PropertyKind::F64 { .. } = self.info.kind {
            self.info.kind = PropertyKind::F64 {
                min: Some(min),
                max: Some(max),
            };
        }
        self
    }

    /// Sets an inclusive range on an integer property.
    pub fn int_range(mut self, min: i64, max: i64) -> Self {
        if let PropertyKind::I64 { .. } = self.info.kind {
            self.info.kind = PropertyKind::I64 {
                min: Some(min),
                max: Some(max),
            };
        }
        self
    }

    /// Allows changing the property while the diagram runs.
    pub fn live(mut self) -> Self {
        self.info.live = true;
        self
    }

    /// Sets the one-line documentation.
    pub fn doc(mut self, doc: &str) -> Self {
        doc.clone_into(&mut self.info.doc);
        self
    }

    /// Sets the unit of a number (`Hz`, `m`, `ms`), shown beside its value in the studio.
    pub fn unit(mut self, unit: &str) -> Self {
        unit.clone_into(&mut self.info.unit);
        self
    }
}
