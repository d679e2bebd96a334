//! The Kairos component SDK.
//!
//! - [`Sample`] and [`Payload`]: time-stamped data; heavy payloads are shared, never copied.
//! - [`buffer`]: the circular buffer each output owns and the five reader policies.
//! - [`Component`] and [`Context`]: the lifecycle (birth → core → death), reading and writing, properties
//!   and actions; [`Synchronizer`] for data fusion.
//! - [`descriptor`]: builders for component descriptors; [`Registry`]: how packs register components.
//! - [`harness`]: run one component offline on scripted samples, for unit tests.
//! - [`rng`]: a small seeded generator, so simulated components repeat exactly.

#![warn(missing_docs)]

pub mod abi;
pub mod buffer;
pub mod component;
pub mod descriptor;
pub mod harness;
pub mod payload;
pub mod pixels;
pub mod registry;
pub mod rng;
pub mod sample;
pub mod signal;
pub mod stats;
mod sync;
pub mod time;

pub use buffer::{OutputBuffer, ReadError, Reader, ReaderConfig, WriteError};
pub use component::{
    Component, ComponentError, ComponentResult, Context, ContextParts, InputPort, OutputPort, PortKey,
    StatusCell, Synchronizer,
};
pub use kairos_diagram::{
    ComponentInfo, DataType, DescribeError, ExecutionMode, LibraryInfo, OutputInfo, PackInfo, PropertyKind,
    ReaderPolicy, TypeFilter, Value,
};
pub use payload::{
    CanFrame, CustomPayload, FixStatus, GnssFix, Image, Imu, Matrix, Payload, PixelFormat, PointCloud, Pose,
};
pub use pixels::{Pixels, PixelsMut};
pub use registry::{Describe, Factory, PackRegistrar, RegisteredComponent, Registry};
pub use sample::Sample;
pub use signal::RunSignal;
pub use stats::{LatencySummary, LinkCounters};
pub use time::{Clock, ManualClock, RealTimeClock, Timestamp};

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
