//! The pack ABI: how a runtime and a pack built as a shared library talk, in C terms.
//!
//! A pack library exports one symbol, `kairos_pack_entry`, returning a [`KPackDescriptor`]: magic, ABI
//! version, the sizes of every shared struct (the layout check), the SDK version, the pack's name and
//! version, and one [`KComponentVTable`] per component (its descriptor as JSON and its lifecycle
//! functions). The host checks all of it before any other call. Components reach their ports through the
//! [`KHost`] table of host functions. Samples cross as [`KSample`]: the host owns every sample; a pack
//! borrows what it reads (valid until its next read of that input) and the host copies what a pack writes,
//! so no memory is ever freed by another allocator. Every call into a pack runs under `catch_unwind` on the
//! pack's side: a panic becomes that component's failure, never an unwind across the boundary.
//!
//! The module has three parts: [`types`] (the C structs, mirrored by `kairos.h`, see [`C_HEADER`]),
//! `convert` (samples, values and status codes to and from their C form) and `pack_side` (the shim behind
//! [`crate::export_pack!`], so Rust packs never write any of this by hand). The host's half, the loader
//! and the host functions, lives in `kairos-runtime`.

pub(crate) mod convert;
mod pack_side;
pub mod types;

#[doc(hidden)]
pub use pack_side::{ExportedPack, export_entry};
pub use types::{
    KComponentVTable, KError, KHost, KLifecycleFn, KLinkCounters, KNamedFn, KPackDescriptor, KSample, KStr,
    KValue,
};

/// `KAIROSPK` in ASCII: the first field of every pack descriptor.
pub const ABI_MAGIC: u64 = u64::from_be_bytes(*b"KAIROSPK");
/// The ABI version this SDK speaks. A pack with another version is refused.
///
/// Version 2 added the instance's description, link counters, status and sleeping to the host table, and
/// made every function pointer of a component table nullable so the loader can refuse a null one.
pub const ABI_VERSION: u32 = 2;
/// The symbol every pack library exports.
pub const ENTRY_SYMBOL: &str = "kairos_pack_entry";

/// Status codes of host and pack calls.
pub mod status {
    /// Done.
    pub const OK: i32 = 0;
    /// The component is being stopped.
    pub const STOPPED: i32 = 1;
    /// A control request waits; return from `core`.
    pub const INTERRUPTED: i32 = 2;
    /// The input's stream ended.
    pub const END_OF_STREAM: i32 = 3;
    /// Nothing to read now.
    pub const NO_DATA: i32 = 4;
    /// Failed; a message says why.
    pub const FAILED: i32 = 5;
}

/// [`KHost::input_state`]: the input has no connection.
pub const INPUT_UNCONNECTED: i32 = 0;
/// [`KHost::input_state`]: the input is connected.
pub const INPUT_CONNECTED: i32 = 1;
/// [`KHost::input_state`]: the input's stream ended and everything was read.
pub const INPUT_EXHAUSTED: i32 = 2;

/// Payload kinds in [`KSample::kind`].
pub mod kind {
    /// `scalar_f64`.
    pub const F64: u32 = 1;
    /// `scalar_i64`.
    pub const I64: u32 = 2;
    /// `scalar_i64` != 0.
    pub const BOOL: u32 = 3;
    /// `data`: `len / 8` native-endian f64.
    pub const VECTOR: u32 = 4;
    /// `height` rows × `width` columns of native-endian f64 in `data`.
    pub const MATRIX: u32 = 5;
    /// UTF-8 in `data`.
    pub const TEXT: u32 = 6;
    /// `data`.
    pub const BYTES: u32 = 7;
    /// `width`, `height`, `stride`, `pixel_format`; pixels in `data`.
    pub const IMAGE: u32 = 8;
    /// `width` points as x, y, z native-endian f32 in `data`, then, if `flags & 1`, one f32 intensity each.
    pub const POINT_CLOUD: u32 = 9;
    /// `values`: gyro x y z, accel x y z, then if `flags & 1` orientation x y z w.
    pub const IMU: u32 = 10;
    /// `values`: latitude, longitude, altitude, horizontal and vertical accuracy; `scalar_i64`: status.
    pub const GNSS_FIX: u32 = 11;
    /// `scalar_i64`: identifier; `flags & 1`: extended, `flags & 2`: FD; data bytes in `data`.
    pub const CAN_FRAME: u32 = 12;
    /// `values`: x y z, then orientation x y z w.
    pub const POSE: u32 = 13;
    /// `type_name` and `data`.
    pub const CUSTOM: u32 = 14;
}

/// The C header for C and C++ packs (`component-sdk/include/kairos.h`), kept in step with this module by a
/// test that compiles it and compares every struct's size and every constant.
pub const C_HEADER: &str = include_str!("../../../include/kairos.h");

/// Exports a pack from a crate built as a shared library (`crate-type = ["rlib", "cdylib"]`):
/// `kairos_sdk::export_pack!(my_pack::register);` generates the C entry point, the component shims and
/// the descriptor. The same crate still links statically into a runtime through `register`.
#[macro_export]
macro_rules! export_pack {
    ($register:path) => {
        /// The pack entry point the Kairos runtime looks for.
        #[allow(unsafe_code, reason = "the exported C entry point of the pack ABI")]
        #[unsafe(no_mangle)]
        pub extern "C" fn kairos_pack_entry() -> *const $crate::abi::KPackDescriptor {
            static PACK: ::std::sync::OnceLock<::std::option::Option<$crate::abi::ExportedPack>> =
                ::std::sync::OnceLock::new();
            $crate::abi::export_entry(&PACK, $register)
        }
    };
}
