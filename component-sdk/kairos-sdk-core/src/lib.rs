//! The component SDK's implementation, both halves.
//!
//! Pack authors depend on `kairos-sdk`, which re-exports the pack author's half of this crate and nothing
//! else: samples and payloads, [`Component`] and [`Context`], descriptors, registration, [`export_pack!`],
//! the harness. The runtime depends on this crate for the other half: the [`host`] module (output
//! buffers and readers, building contexts, registry validation, the loader's C conversions),
//! [`RunSignal`], [`DisciplinedClock`] and [`panic_message`]. A pack cannot reach that half through
//! `kairos-sdk`; the split is checked by compiling an outside pack that tries (`component-sdk/tests/sealed.rs`).
//!
//! A component behaves the same whether it is linked into a runtime or loaded from a pack library: its
//! [`Context`] answers the same questions (its id, its inputs' sources and counters, its properties, the
//! clock) either way.

#![warn(missing_docs)]

pub mod abi;
mod buffer;
pub mod component;
pub mod descriptor;
pub mod disciplined;
pub mod files;
pub mod harness;
pub mod host;
mod name_key;
pub mod payload;
pub mod pixels;
pub mod registry;
pub mod rng;
pub mod sample;
pub mod signal;
pub mod stats;
mod sync;
pub mod text;
mod throttle;
pub mod time;

pub use component::{
    Component, ComponentError, ComponentResult, Context, InputPort, OutputPort, PortKey, Synchronizer,
};
pub use disciplined::{ClockState, ClockStatus, DisciplinedClock};
pub use kairos_diagram::{
    ComponentInfo, DataType, DescribeError, DeviceKind, ExecutionMode, LibraryInfo, OutputInfo, PackInfo,
    PropertyKind, ReaderPolicy, TypeFilter, Value, port_name_for_topic,
};
pub use payload::{
    CanFrame, CustomPayload, FixStatus, GnssFix, Image, Imu, Matrix, Payload, PixelFormat, PointCloud, Pose,
};
pub use pixels::{Pixels, PixelsMut};
pub use registry::{Describe, Factory, PackRegistrar, RefusedComponent, RegisteredComponent, Registry};
pub use sample::Sample;
pub use signal::RunSignal;
pub use stats::{LatencySummary, LinkCounters};
pub use throttle::{STATUS_PERIOD, Throttle, WARNING_PERIOD};
pub use time::{Clock, ManualClock, RealTimeClock, SimulatedClock, Timestamp, wait_in_real_time};

/// The text of a panic payload, for reports.
pub fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    if let Some(text) = payload.downcast_ref::<&str>() {
        (*text).to_owned()
    } else if let Some(text) = payload.downcast_ref::<String>() {
        text.clone()
    } else {
        "a panic with a non-text payload".to_owned()
    }
}

/// The SDK's version, checked against packs built with another one.
pub const SDK_VERSION: &str = env!("CARGO_PKG_VERSION");
