//! The Kairos component SDK: everything a pack author programs against, and nothing more.
//!
//! - [`Sample`] and [`Payload`]: time-stamped data; heavy payloads are shared, never copied.
//! - [`Component`] and [`Context`]: the lifecycle (birth → core → death), reading under the connection's
//!   reader policy, writing, properties and actions; [`Synchronizer`] for data fusion.
//! - [`descriptor`]: builders for component descriptors; [`Registry`]: how packs register components.
//! - [`harness`]: run one component offline on scripted samples, for unit tests.
//! - [`export_pack!`]: the same crate as a pack library a runtime loads.
//! - [`pixels`]: image buffers a camera draws into, shared with local viewers without a copy.
//! - [`rng`]: a small seeded generator, so simulated components repeat exactly.
//! - [`files`]: creating the files a component writes without overwriting one that is there.
//!
//! A component behaves the same whether it is linked into a runtime or loaded from a pack library: its
//! [`Context`] answers the same questions (its id, its inputs' sources and counters, its properties, the
//! clock) either way.
//!
//! The runtime's half of the SDK (output buffers and readers, building contexts, run signals, validating
//! diagrams, the loader's C conversions) lives in `kairos-sdk-core`, which this crate re-exports only in
//! part: a pack cannot reach it through this crate, and `tests/sealed.rs` compiles one that tries.

pub use kairos_sdk_core::{descriptor, files, harness, payload, pixels, rng, sample, text};

pub use kairos_sdk_core::component::{
    Component, ComponentError, ComponentResult, Context, InputPort, OutputPort, PortKey, StatusWriter,
    Synchronizer,
};
pub use kairos_sdk_core::disciplined::{ClockState, ClockStatus};
pub use kairos_sdk_core::export_pack;
pub use kairos_sdk_core::{
    CanFrame, CustomPayload, FixStatus, GnssFix, Image, Imu, Matrix, Payload, PixelFormat, PointCloud, Pose,
};
pub use kairos_sdk_core::{
    ComponentInfo, DataType, DescribeError, DeviceKind, ExecutionMode, LibraryInfo, OutputInfo, PackInfo,
    PropertyKind, ReaderPolicy, TypeFilter, Value, port_name_for_topic,
};
pub use kairos_sdk_core::{
    Describe, Factory, PackRegistrar, RefusedComponent, RegisteredComponent, Registry,
};
pub use kairos_sdk_core::{LatencySummary, LinkCounters};
pub use kairos_sdk_core::{Pixels, PixelsMut, Sample};
pub use kairos_sdk_core::{SDK_VERSION, STATUS_PERIOD, Throttle, Timestamp, WARNING_PERIOD};
