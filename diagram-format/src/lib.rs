//! The Kairos diagram format: the model of a diagram, its RON text form, and validation against a
//! component library with located, every-problem-at-once diagnostics.
//!
//! This crate is pure data: no engine, no GUI. The runtime, the CLI and the studio all read and write
//! diagrams through it.

#![warn(missing_docs)]

pub mod library;
pub mod model;

pub use library::{
    ActionInfo, ComponentInfo, DataType, ExecutionMode, InputInfo, LibraryInfo, OutputInfo, PackInfo,
    PropertyInfo, PropertyKind, ReaderPolicy, TypeFilter, Value, ValueError,
};
pub use model::{
    ComponentInstance, Connection, Diagram, FORMAT_VERSION, OutputSettings, PackRequirement, PortRef,
    Position, ThreadSettings,
};
