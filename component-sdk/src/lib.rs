//! The Kairos component SDK: everything a pack author programs against.
//!
//! - [`Sample`] and [`Payload`]: time-stamped data; heavy payloads are shared, never copied.
//! - [`Component`] and [`Context`]: the lifecycle (birth → core → death), reading under the connection's
//!   reader policy, writing, properties and actions; [`Synchronizer`] for data fusion.
//! - [`descriptor`]: builders for component descriptors; [`Registry`]: how packs register components.
//! - [`harness`]: run one component offline on scripted samples, for unit tests.
//! - [`export_pack!`]: the same crate as a pack library a runtime loads (the C ABI is in [`abi`]).
//! - [`pixels`]: image buffers a camera draws into, shared with local viewers without a copy.
//! - [`rng`]: a small seeded generator, so simulated components repeat exactly.
//!
//! A component behaves the same whether it is linked into a runtime or loaded from a pack library: its
//! [`Context`] answers the same questions (its id, its inputs' sources and counters, its properties, the
//! clock) either way. The runtime's half (output buffers and readers, building contexts, the loader's C
//! types) is the [`host`] module, compiled only with the `host` feature, which `kairos-runtime` enables and
//! packs never need.

#![warn(missing_docs)]
#![cfg_attr(
    not(feature = "host"),
    allow(
        dead_code,
        reason = "the runtime's half of the buffers and contexts is used only with the `host` feature"
    )
)]

pub mod abi;
mod buffer;
pub mod component;
pub mod descriptor;
pub mod disciplined;
pub mod harness;
#[cfg(feature = "host")]
pub mod host;
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
    PropertyKind, ReaderPolicy, TypeFilter, Value,
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
pub use time::{Clock, ManualClock, RealTimeClock, Timestamp, wait_in_real_time};

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
