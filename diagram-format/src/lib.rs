//! The Kairos diagram format: the model of a diagram, its RON text form, and validation against a
//! component library with located, every-problem-at-once diagnostics.
//!
//! This crate is pure data: no engine, no GUI. The runtime, the CLI and the studio all read and write
//! diagrams through it.
//!
//! ```
//! use kairos_diagram::{LibraryInfo, parse};
//!
//! let text = "Diagram(format: 1, components: [Component(id: \"a\", type: \"core.nothing\")])";
//! let parsed = parse(text).expect("valid RON");
//! assert_eq!(parse(&parsed.diagram.to_ron()).expect("canonical text").diagram, parsed.diagram);
//!
//! let problems = parsed.validate(&LibraryInfo::default());
//! assert_eq!(problems[0].to_string(), "1:58: error: unknown component type 'core.nothing' for 'a'");
//! ```

#![warn(missing_docs)]

pub mod diagnostic;
pub mod library;
pub mod model;
pub mod read;
mod ron_syntax;
pub mod subgraph;
pub mod validate;
pub mod write;

pub use diagnostic::{
    Diagnostic, DiagnosticCode, Location, Note, Severity, closest, did_you_mean, render_all,
};
pub use library::{
    ActionInfo, ComponentInfo, DataType, DescribeError, DeviceKind, ExecutionMode, InputInfo, InstanceInfos,
    LibraryInfo, OutputInfo, PackInfo, PropertyInfo, PropertyKind, ReaderPolicy, TypeFilter, Value,
    ValueError, port_name_for_topic, readable_type_name,
};
pub use model::{
    ComponentInstance, Connection, DEFAULT_RIDE_OUT_MB, DEFAULT_RIDE_OUT_S, DEFAULT_ZENOH_PORT, Diagram,
    ExposeError, ExposedKind, Exposes, FORMAT_VERSION, HostSpec, MAX_BUFFER_SIZE, MAX_RIDE_OUT_MB,
    MAX_RIDE_OUT_S, OutputSettings, PackRequirement, PortRef, Position, SEQUENTIAL_GROUP, ThreadSettings,
    ViewerSpec,
};
pub use read::{
    ComponentLocations, ConnectionLocations, EntryLocations, ExposesLocations, GroupLocations, HostLocations,
    LoadError, OutputLocations, PackLocations, ParsedDiagram, SourceMap, load, parse,
};
pub use ron_syntax::MAX_DEPTH;
pub use subgraph::{Flattened, Origins, Sources, flatten, flatten_from, is_subgraph_type, load_flattened};
pub use validate::{
    is_valid_id, is_valid_path_id, output_type, resolved_properties, validate, validate_with,
};
pub use write::save;
