//! The runtime's half of the SDK: output buffers and their readers, building the [`Context`] a component
//! runs with, validating a diagram against a [`Registry`], and the C conversions the pack loader needs.
//! `kairos-sdk` does not re-export this module: a pack cannot name any of it.

use std::sync::Arc;

use kairos_diagram::{DataType, Diagnostic, Diagram, InstanceInfos, SourceMap, Value};

pub use crate::abi::convert::{
    error_status, sample_from_c, sample_to_c, status_error, value_from_c, value_to_c, write_error,
};
pub use crate::buffer::{OutputBuffer, ReadError, Reader, ReaderConfig, WriteError};
use crate::component::{ComponentError, Context, InputPort, OutputPort};
pub use crate::component::{ContextParts, StatusCell};
use crate::registry::Registry;
use crate::signal::RunSignal;
use crate::time::Clock;

/// A context for one component instance.
pub fn context(parts: ContextParts) -> Context {
    Context::new(parts)
}

/// An input read through `reader` (unconnected without one); its source is the reader's output.
pub fn input_port(name: impl Into<String>, reader: Option<Reader>) -> InputPort {
    InputPort::new(name, reader)
}

/// An output writing into `buffer`, keeping one sample in `subsampling`; writes are checked against
/// `data_type` (`None`: any type, for an output that follows an input).
pub fn output_port(
    name: impl Into<String>,
    data_type: Option<DataType>,
    buffer: OutputBuffer,
    subsampling: u32,
) -> OutputPort {
    OutputPort::new(name, data_type, buffer, subsampling)
}

/// What the runtime does to a context between and around component calls.
pub trait ContextHost {
    /// Marks the start of a `core` call.
    fn begin_cycle(&mut self);
    /// Gives the component the text of its diagram.
    fn set_diagram_text(&mut self, text: Arc<str>);
    /// The cell the component's status is published in.
    fn status_cell(&self) -> StatusCell;
    /// The component's signal (stop, pause, control, wake-ups).
    fn signal(&self) -> &Arc<RunSignal>;
    /// The runtime clock.
    fn clock(&self) -> &Arc<dyn Clock>;
    /// Replaces a property's value before `property_changed` is called.
    fn set_property(&mut self, name: &str, value: Value) -> Option<Value>;
    /// A loaded component's request to sleep until woken (its own any-of or synchronised reads).
    fn wait_from_pack(&self, interruptible: bool) -> Result<(), ComponentError>;
    /// Whether input `index`'s stream ended and everything was read.
    fn is_input_exhausted(&self, index: usize) -> bool;
    /// Every output's buffer, in descriptor order.
    fn output_buffers(&self) -> Vec<&OutputBuffer>;
    /// Whether an input holds a sample not read yet (a Sampling input, which always has its newest,
    /// does not count).
    fn has_unread_input(&self) -> bool;
}

impl ContextHost for Context {
    fn begin_cycle(&mut self) {
        Context::begin_cycle(self);
    }

    fn set_diagram_text(&mut self, text: Arc<str>) {
        Context::set_diagram_text(self, text);
    }

    fn status_cell(&self) -> StatusCell {
        Context::status_cell(self)
    }

    fn signal(&self) -> &Arc<RunSignal> {
        Context::signal(self)
    }

    fn clock(&self) -> &Arc<dyn Clock> {
        Context::clock(self)
    }

    fn set_property(&mut self, name: &str, value: Value) -> Option<Value> {
        Context::set_property(self, name, value)
    }

    fn wait_from_pack(&self, interruptible: bool) -> Result<(), ComponentError> {
        Context::wait_from_pack(self, interruptible)
    }

    fn is_input_exhausted(&self, index: usize) -> bool {
        Context::is_input_exhausted(self, index)
    }

    fn output_buffers(&self) -> Vec<&OutputBuffer> {
        self.outputs().iter().map(OutputPort::buffer).collect()
    }

    fn has_unread_input(&self) -> bool {
        self.inputs()
            .iter()
            .filter_map(InputPort::reader)
            .any(|reader| reader.policy() != kairos_diagram::ReaderPolicy::Sampling && reader.has_pending())
    }
}

/// Checking diagrams against the components a registry holds: the runtime's use of a [`Registry`], kept
/// out of the methods a pack sees while it registers.
pub trait RegistryValidation {
    /// The descriptors of the diagram's instances whose ports depend on their properties, by id. A
    /// describe function that panics is reported as that instance's error, never propagated.
    fn instance_infos(&self, diagram: &Diagram) -> InstanceInfos;
    /// Validates `diagram` against the registry, instances that describe themselves included; see
    /// [`kairos_diagram::validate_with`].
    fn validate(&self, diagram: &Diagram, source_map: Option<&SourceMap>) -> Vec<Diagnostic>;
}

impl RegistryValidation for Registry {
    fn instance_infos(&self, diagram: &Diagram) -> InstanceInfos {
        Registry::instance_infos(self, diagram)
    }

    fn validate(&self, diagram: &Diagram, source_map: Option<&SourceMap>) -> Vec<Diagnostic> {
        Registry::validate(self, diagram, source_map)
    }
}
