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
//! Rust packs never write this by hand: [`crate::export_pack!`] generates the shim. C and C++ packs include
//! `kairos.h` (see [`C_HEADER`]). This is the only module of the project allowed `unsafe`.

#![allow(
    unsafe_code,
    reason = "the pack ABI is the one place that crosses a C boundary"
)]

use std::collections::BTreeMap;
use std::ffi::c_void;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use glam::{DQuat, DVec3, Vec3};
use kairos_diagram::{ComponentInfo, ExecutionMode, Value};

use crate::component::{Component, ComponentError, ComponentResult, Context, ContextParts};
use crate::payload::{
    CanFrame, CustomPayload, FixStatus, GnssFix, Image, Imu, Matrix, Payload, PixelFormat, PointCloud, Pose,
};
use crate::registry::Registry;
use crate::sample::Sample;
use crate::signal::RunSignal;
use crate::time::{Clock, Timestamp};

/// `KAIROSPK` in ASCII: the first field of every pack descriptor.
pub const ABI_MAGIC: u64 = u64::from_be_bytes(*b"KAIROSPK");
/// The ABI version this SDK speaks. A pack with another version is refused.
pub const ABI_VERSION: u32 = 1;
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

/// A borrowed UTF-8 string: pointer and length, no terminator needed.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct KStr {
    /// The first byte (may be null when `len` is 0).
    pub ptr: *const u8,
    /// The number of bytes.
    pub len: usize,
}

impl KStr {
    /// Borrows `text`.
    pub fn new(text: &str) -> Self {
        KStr {
            ptr: text.as_ptr(),
            len: text.len(),
        }
    }

    /// The text, or `None` when the pointer is null or the bytes are not UTF-8.
    ///
    /// # Safety
    /// `ptr` must point to `len` readable bytes that outlive `'a`.
    pub unsafe fn as_str<'a>(self) -> Option<&'a str> {
        if self.len == 0 {
            return Some("");
        }
        if self.ptr.is_null() {
            return None;
        }
        // SAFETY: the caller guarantees `len` readable bytes at `ptr` for `'a`.
        let bytes = unsafe { std::slice::from_raw_parts(self.ptr, self.len) };
        std::str::from_utf8(bytes).ok()
    }
}

/// One sample in C terms. See [`kind`] for which fields each payload kind uses.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct KSample {
    /// A [`kind`] constant.
    pub kind: u32,
    /// Kind-specific flags.
    pub flags: u32,
    /// Nanoseconds since the UNIX epoch: when the data originated.
    pub timestamp_ns: i64,
    /// Nanoseconds since the UNIX epoch: when it was last written.
    pub time_of_issue_ns: i64,
    /// Position in its output's stream.
    pub sequence: u64,
    /// F64.
    pub scalar_f64: f64,
    /// I64, BOOL, GNSS status, CAN identifier.
    pub scalar_i64: i64,
    /// Image width, matrix columns, point count.
    pub width: u32,
    /// Image height, matrix rows.
    pub height: u32,
    /// Image stride in bytes.
    pub stride: u32,
    /// Image pixel format: 1 Gray8, 2 Gray16, 3 Rgb8, 4 Rgba8, 5 Bgr8, 6 Bgra8.
    pub pixel_format: u32,
    /// Small structured payloads (IMU, GNSS, pose).
    pub values: [f64; 16],
    /// Large payloads: borrowed bytes.
    pub data: *const u8,
    /// Number of bytes at `data`.
    pub data_len: usize,
    /// Custom payloads: the registered type name.
    pub type_name: KStr,
}

impl Default for KSample {
    fn default() -> Self {
        KSample {
            kind: 0,
            flags: 0,
            timestamp_ns: 0,
            time_of_issue_ns: 0,
            sequence: 0,
            scalar_f64: 0.0,
            scalar_i64: 0,
            width: 0,
            height: 0,
            stride: 0,
            pixel_format: 0,
            values: [0.0; 16],
            data: std::ptr::null(),
            data_len: 0,
            type_name: KStr::new(""),
        }
    }
}

/// A property value in C terms: `kind` 1 bool (`integer` 0/1), 2 integer, 3 float, 4 text.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct KValue {
    /// Which field holds the value.
    pub kind: u32,
    /// Booleans and integers.
    pub integer: i64,
    /// Floats.
    pub float: f64,
    /// Text, borrowed until the next property call.
    pub text: KStr,
}

/// Where a pack writes an error message: a host-owned buffer.
#[repr(C)]
#[derive(Debug)]
pub struct KError {
    /// The buffer.
    pub buffer: *mut u8,
    /// Its size.
    pub capacity: usize,
    /// How many bytes the pack wrote.
    pub len: usize,
}

/// Functions the host offers a component. `frame` is the host's handle for the call.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
#[allow(
    missing_docs,
    reason = "each field is documented in kairos.h, next to its C declaration"
)]
pub struct KHost {
    pub struct_size: u32,
    pub read:
        unsafe extern "C" fn(frame: *mut c_void, input: u32, interruptible: i32, out: *mut KSample) -> i32,
    pub try_read: unsafe extern "C" fn(frame: *mut c_void, input: u32, out: *mut KSample) -> i32,
    pub wait: unsafe extern "C" fn(frame: *mut c_void, interruptible: i32) -> i32,
    pub input_state: unsafe extern "C" fn(frame: *mut c_void, input: u32) -> i32,
    pub write: unsafe extern "C" fn(
        frame: *mut c_void,
        output: u32,
        sample: *const KSample,
        keep_timestamp: i32,
        error: *mut KError,
    ) -> i32,
    pub now_ns: unsafe extern "C" fn(frame: *mut c_void) -> i64,
    pub wait_until: unsafe extern "C" fn(frame: *mut c_void, deadline_ns: i64) -> i32,
    pub stop_requested: unsafe extern "C" fn(frame: *mut c_void) -> i32,
    pub set_period_ns: unsafe extern "C" fn(frame: *mut c_void, period_ns: i64),
    pub property: unsafe extern "C" fn(frame: *mut c_void, name: KStr, out: *mut KValue) -> i32,
    pub log: unsafe extern "C" fn(frame: *mut c_void, level: u32, message: KStr),
}

/// A lifecycle call into a component instance.
pub type KLifecycleFn = unsafe extern "C" fn(
    instance: *mut c_void,
    frame: *mut c_void,
    host: *const KHost,
    error: *mut KError,
) -> i32;
/// A named call (property changed, action) into a component instance.
pub type KNamedFn = unsafe extern "C" fn(
    instance: *mut c_void,
    frame: *mut c_void,
    host: *const KHost,
    name: KStr,
    error: *mut KError,
) -> i32;

/// One component type of a pack.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
#[allow(
    missing_docs,
    reason = "each field is documented in kairos.h, next to its C declaration"
)]
pub struct KComponentVTable {
    pub type_name: KStr,
    pub descriptor_json: KStr,
    pub data: *const c_void,
    pub create: unsafe extern "C" fn(data: *const c_void) -> *mut c_void,
    pub destroy: unsafe extern "C" fn(instance: *mut c_void),
    pub birth: KLifecycleFn,
    pub core: KLifecycleFn,
    pub death: KLifecycleFn,
    pub property_changed: KNamedFn,
    pub action: KNamedFn,
}

// SAFETY: a component table is immutable data in a library that is never unloaded; its functions may be
// called from any thread (the ABI requires it).
unsafe impl Sync for KComponentVTable {}
// SAFETY: as above.
unsafe impl Send for KComponentVTable {}

/// What `kairos_pack_entry` returns.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
#[allow(
    missing_docs,
    reason = "each field is documented in kairos.h, next to its C declaration"
)]
pub struct KPackDescriptor {
    pub magic: u64,
    pub abi_version: u32,
    pub descriptor_size: u32,
    pub sample_size: u32,
    pub host_size: u32,
    pub vtable_size: u32,
    pub value_size: u32,
    pub sdk_version: KStr,
    pub name: KStr,
    pub version: KStr,
    pub components: *const KComponentVTable,
    pub component_count: usize,
}

fn size_u32<T>() -> u32 {
    u32::try_from(size_of::<T>()).unwrap_or(u32::MAX)
}

fn write_error(error: *mut KError, message: &str) {
    // SAFETY: the caller of a pack function passes either null or a valid, exclusive KError whose buffer
    // has `capacity` writable bytes.
    let Some(error) = (unsafe { error.as_mut() }) else {
        return;
    };
    if error.buffer.is_null() {
        return;
    }
    let mut len = message.len().min(error.capacity);
    while !message.is_char_boundary(len) {
        len -= 1;
    }
    // SAFETY: `len <= capacity` bytes fit in the buffer; source and destination do not overlap.
    unsafe { std::ptr::copy_nonoverlapping(message.as_ptr(), error.buffer, len) };
    error.len = len;
}

// ----------------------------------------------------------------------------------------------------
// Payload conversions.

fn pixel_format_code(format: PixelFormat) -> u32 {
    match format {
        PixelFormat::Gray8 => 1,
        PixelFormat::Gray16 => 2,
        PixelFormat::Rgb8 => 3,
        PixelFormat::Rgba8 => 4,
        PixelFormat::Bgr8 => 5,
        PixelFormat::Bgra8 => 6,
    }
}

fn pixel_format_from(code: u32) -> Option<PixelFormat> {
    Some(match code {
        1 => PixelFormat::Gray8,
        2 => PixelFormat::Gray16,
        3 => PixelFormat::Rgb8,
        4 => PixelFormat::Rgba8,
        5 => PixelFormat::Bgr8,
        6 => PixelFormat::Bgra8,
        _ => return None,
    })
}

fn f64_bytes(values: &[f64]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_ne_bytes()).collect()
}

fn f64s_from(bytes: &[u8]) -> Vec<f64> {
    bytes
        .chunks_exact(8)
        .map(|c| f64::from_ne_bytes(c.try_into().unwrap_or([0; 8])))
        .collect()
}

fn f32s_from(bytes: &[u8]) -> Vec<f32> {
    bytes
        .chunks_exact(4)
        .map(|c| f32::from_ne_bytes(c.try_into().unwrap_or([0; 4])))
        .collect()
}

/// Describes `sample` in C terms. Pointers borrow from `sample` and from `scratch` (for payloads that need
/// re-encoding), so both must outlive the `KSample`.
#[allow(
    clippy::too_many_lines,
    reason = "one arm per payload kind, each a few lines; splitting hides the mapping"
)]
pub fn sample_to_c(sample: &Sample, scratch: &mut Vec<u8>) -> KSample {
    let mut k = KSample {
        timestamp_ns: sample.timestamp.as_nanos(),
        time_of_issue_ns: sample.time_of_issue.as_nanos(),
        sequence: sample.sequence,
        ..KSample::default()
    };
    let borrow = |bytes: &[u8], k: &mut KSample| {
        k.data = bytes.as_ptr();
        k.data_len = bytes.len();
    };
    match &sample.payload {
        Payload::F64(v) => {
            k.kind = kind::F64;
            k.scalar_f64 = *v;
        }
        Payload::I64(v) => {
            k.kind = kind::I64;
            k.scalar_i64 = *v;
        }
        Payload::Bool(v) => {
            k.kind = kind::BOOL;
            k.scalar_i64 = i64::from(*v);
        }
        Payload::Vector(v) => {
            k.kind = kind::VECTOR;
            *scratch = f64_bytes(v);
            borrow(scratch, &mut k);
        }
        Payload::Matrix(m) => {
            k.kind = kind::MATRIX;
            k.width = u32::try_from(m.cols).unwrap_or(0);
            k.height = u32::try_from(m.rows).unwrap_or(0);
            *scratch = f64_bytes(&m.values);
            borrow(scratch, &mut k);
        }
        Payload::Text(t) => {
            k.kind = kind::TEXT;
            borrow(t.as_bytes(), &mut k);
        }
        Payload::Bytes(b) => {
            k.kind = kind::BYTES;
            borrow(b, &mut k);
        }
        Payload::Image(image) => {
            k.kind = kind::IMAGE;
            k.width = image.width;
            k.height = image.height;
            k.stride = image.stride;
            k.pixel_format = pixel_format_code(image.format);
            borrow(&image.pixels, &mut k);
        }
        Payload::PointCloud(cloud) => {
            k.kind = kind::POINT_CLOUD;
            k.width = u32::try_from(cloud.points.len()).unwrap_or(0);
            scratch.clear();
            for p in &cloud.points {
                scratch.extend(p.to_array().iter().flat_map(|v| v.to_ne_bytes()));
            }
            if let Some(intensity) = &cloud.intensity {
                k.flags = 1;
                scratch.extend(intensity.iter().flat_map(|v| v.to_ne_bytes()));
            }
            borrow(scratch, &mut k);
        }
        Payload::Imu(imu) => {
            k.kind = kind::IMU;
            let [gx, gy, gz] = imu.angular_velocity.to_array();
            let [ax, ay, az] = imu.linear_acceleration.to_array();
            let [qx, qy, qz, qw] = imu.orientation.map_or([0.0; 4], |q| q.to_array());
            k.flags = u32::from(imu.orientation.is_some());
            k.values[..10].copy_from_slice(&[gx, gy, gz, ax, ay, az, qx, qy, qz, qw]);
        }
        Payload::GnssFix(fix) => {
            k.kind = kind::GNSS_FIX;
            k.values[..5].copy_from_slice(&[
                fix.latitude_deg,
                fix.longitude_deg,
                fix.altitude_m,
                fix.horizontal_accuracy_m,
                fix.vertical_accuracy_m,
            ]);
            k.scalar_i64 = match fix.status {
                FixStatus::NoFix => 0,
                FixStatus::Fix => 1,
                FixStatus::Differential => 2,
                FixStatus::RtkFixed => 3,
            };
        }
        Payload::CanFrame(frame) => {
            k.kind = kind::CAN_FRAME;
            k.scalar_i64 = i64::from(frame.id);
            k.flags = u32::from(frame.extended) | (u32::from(frame.fd) << 1);
            borrow(frame.data(), &mut k);
        }
        Payload::Pose(pose) => {
            k.kind = kind::POSE;
            let [x, y, z] = pose.position.to_array();
            let [qx, qy, qz, qw] = pose.orientation.to_array();
            k.values[..7].copy_from_slice(&[x, y, z, qx, qy, qz, qw]);
        }
        Payload::Custom(custom) => {
            k.kind = kind::CUSTOM;
            k.type_name = KStr::new(&custom.type_name);
            borrow(&custom.data, &mut k);
        }
    }
    k
}

/// Builds a sample from its C description, copying any borrowed bytes into memory of this side.
///
/// # Safety
/// `k.data` must point to `k.data_len` readable bytes and `k.type_name` must be valid, for the call.
pub unsafe fn sample_from_c(k: &KSample) -> Result<Sample, String> {
    let data: &[u8] = if k.data_len == 0 || k.data.is_null() {
        &[]
    } else {
        // SAFETY: guaranteed by the caller.
        unsafe { std::slice::from_raw_parts(k.data, k.data_len) }
    };
    let v = &k.values;
    let payload = match k.kind {
        kind::F64 => Payload::F64(k.scalar_f64),
        kind::I64 => Payload::I64(k.scalar_i64),
        kind::BOOL => Payload::Bool(k.scalar_i64 != 0),
        kind::VECTOR => Payload::Vector(Arc::from(f64s_from(data))),
        kind::MATRIX => {
            let values = f64s_from(data);
            let (rows, cols) = (k.height as usize, k.width as usize);
            if rows * cols != values.len() {
                return Err(format!("matrix of {rows}x{cols} with {} values", values.len()));
            }
            Payload::Matrix(Arc::new(Matrix { rows, cols, values }))
        }
        kind::TEXT => Payload::Text(Arc::from(
            std::str::from_utf8(data).map_err(|e| format!("text is not UTF-8: {e}"))?,
        )),
        kind::BYTES => Payload::Bytes(Arc::from(data)),
        kind::IMAGE => {
            let format = pixel_format_from(k.pixel_format)
                .ok_or_else(|| format!("unknown pixel format {}", k.pixel_format))?;
            // The one copy across the boundary goes into a buffer that local viewers can map as it is.
            let mut pixels = crate::pixels::PixelsMut::new(data.len());
            pixels.copy_from_slice(data);
            Payload::Image(
                Image::with_stride(k.width, k.height, format, k.stride, pixels.freeze())
                    .map_err(|e| e.to_string())?,
            )
        }
        kind::POINT_CLOUD => {
            let count = k.width as usize;
            let floats = f32s_from(data);
            let needed = count * if k.flags & 1 == 1 { 4 } else { 3 };
            if floats.len() < needed {
                return Err(format!(
                    "point cloud of {count} points with {} floats",
                    floats.len()
                ));
            }
            let points = floats
                .chunks_exact(3)
                .take(count)
                .map(|c| Vec3::new(c[0], c[1], c[2]))
                .collect();
            let intensity =
                (k.flags & 1 == 1).then(|| floats.iter().skip(3 * count).take(count).copied().collect());
            Payload::PointCloud(Arc::new(PointCloud { points, intensity }))
        }
        kind::IMU => Payload::Imu(Imu {
            angular_velocity: DVec3::new(v[0], v[1], v[2]),
            linear_acceleration: DVec3::new(v[3], v[4], v[5]),
            orientation: (k.flags & 1 == 1).then(|| DQuat::from_xyzw(v[6], v[7], v[8], v[9])),
        }),
        kind::GNSS_FIX => Payload::GnssFix(GnssFix {
            latitude_deg: v[0],
            longitude_deg: v[1],
            altitude_m: v[2],
            horizontal_accuracy_m: v[3],
            vertical_accuracy_m: v[4],
            status: match k.scalar_i64 {
                1 => FixStatus::Fix,
                2 => FixStatus::Differential,
                3 => FixStatus::RtkFixed,
                _ => FixStatus::NoFix,
            },
        }),
        kind::CAN_FRAME => Payload::CanFrame(
            CanFrame::new(u32::try_from(k.scalar_i64).unwrap_or(0), k.flags & 1 == 1, data)
                .ok_or_else(|| format!("CAN frame of {} bytes", data.len()))?,
        ),
        kind::POSE => Payload::Pose(Pose {
            position: DVec3::new(v[0], v[1], v[2]),
            orientation: DQuat::from_xyzw(v[3], v[4], v[5], v[6]),
        }),
        kind::CUSTOM => {
            // SAFETY: guaranteed by the caller.
            let name = unsafe { k.type_name.as_str() }.ok_or("custom type name is not UTF-8")?;
            Payload::Custom(CustomPayload {
                type_name: Arc::from(name),
                data: Arc::from(data),
            })
        }
        other => return Err(format!("unknown payload kind {other}")),
    };
    Ok(Sample {
        payload,
        timestamp: Timestamp::from_nanos(k.timestamp_ns),
        time_of_issue: Timestamp::from_nanos(k.time_of_issue_ns),
        sequence: k.sequence,
    })
}

fn error_status(error: &ComponentError) -> i32 {
    match error {
        ComponentError::Stopped => status::STOPPED,
        ComponentError::Interrupted => status::INTERRUPTED,
        ComponentError::EndOfStream => status::END_OF_STREAM,
        ComponentError::NoData => status::NO_DATA,
        ComponentError::Failed(_) => status::FAILED,
    }
}

fn status_error(code: i32, message: impl FnOnce() -> String) -> ComponentResult {
    match code {
        status::OK => Ok(()),
        status::STOPPED => Err(ComponentError::Stopped),
        status::INTERRUPTED => Err(ComponentError::Interrupted),
        status::END_OF_STREAM => Err(ComponentError::EndOfStream),
        status::NO_DATA => Err(ComponentError::NoData),
        _ => Err(ComponentError::Failed(message())),
    }
}

// ----------------------------------------------------------------------------------------------------
// Host side: the functions a loaded component calls, and the component that calls into a pack.

/// What the host keeps for one component between calls: the context of the current call and the samples
/// the pack borrows.
struct HostFrame {
    ctx: *mut Context,
    held: BTreeMap<u32, (Sample, Vec<u8>)>,
    property_text: String,
}

/// # Safety
/// `frame` must be the pointer the host passed to the current pack call.
unsafe fn frame_mut<'a>(frame: *mut c_void) -> Option<(&'a mut HostFrame, &'a mut Context)> {
    // SAFETY: the host passes its own exclusive `HostFrame` for the duration of a pack call, and the pack
    // hands it back only within that call.
    let frame = unsafe { frame.cast::<HostFrame>().as_mut() }?;
    // SAFETY: `ctx` points to the component's context, exclusively borrowed for the same call.
    let ctx = unsafe { frame.ctx.as_mut() }?;
    Some((frame, ctx))
}

/// Runs a host function body, turning a panic into a failure status: nothing unwinds into a pack.
fn host_guard(body: impl FnOnce() -> i32) -> i32 {
    catch_unwind(AssertUnwindSafe(body)).unwrap_or(status::FAILED)
}

unsafe extern "C" fn host_read(frame: *mut c_void, input: u32, interruptible: i32, out: *mut KSample) -> i32 {
    host_guard(|| {
        // SAFETY: called by a pack within a host call, with the frame it was given.
        let Some((frame, ctx)) = (unsafe { frame_mut(frame) }) else {
            return status::FAILED;
        };
        // Whether a read may be interrupted is the host context's call (only before the cycle's first
        // sample); the flag a pack passes is advisory.
        let _ = interruptible;
        let result = ctx.read(input as usize);
        match result {
            Ok(sample) => hold(frame, input, sample, out),
            Err(error) => error_status(&error),
        }
    })
}

fn hold(frame: &mut HostFrame, input: u32, sample: Sample, out: *mut KSample) -> i32 {
    let entry = frame
        .held
        .entry(input)
        .or_insert_with(|| (sample.clone(), Vec::new()));
    entry.0 = sample;
    let described = sample_to_c(&entry.0, &mut entry.1);
    // SAFETY: `out` is a valid, writable KSample supplied by the pack for this call.
    match unsafe { out.as_mut() } {
        Some(out) => {
            *out = described;
            status::OK
        }
        None => status::FAILED,
    }
}

unsafe extern "C" fn host_try_read(frame: *mut c_void, input: u32, out: *mut KSample) -> i32 {
    host_guard(|| {
        // SAFETY: called by a pack within a host call, with the frame it was given.
        let Some((frame, ctx)) = (unsafe { frame_mut(frame) }) else {
            return status::FAILED;
        };
        match ctx.try_read(input as usize) {
            Ok(Some(sample)) => hold(frame, input, sample, out),
            Ok(None) => status::NO_DATA,
            Err(error) => error_status(&error),
        }
    })
}

unsafe extern "C" fn host_wait(frame: *mut c_void, interruptible: i32) -> i32 {
    host_guard(|| {
        // SAFETY: called by a pack within a host call, with the frame it was given.
        let Some((_, ctx)) = (unsafe { frame_mut(frame) }) else {
            return status::FAILED;
        };
        match ctx.wait_from_pack(interruptible != 0) {
            Ok(()) => status::OK,
            Err(error) => error_status(&error),
        }
    })
}

unsafe extern "C" fn host_input_state(frame: *mut c_void, input: u32) -> i32 {
    host_guard(|| {
        // SAFETY: called by a pack within a host call, with the frame it was given.
        let Some((_, ctx)) = (unsafe { frame_mut(frame) }) else {
            return INPUT_UNCONNECTED;
        };
        let index = input as usize;
        if !ctx.is_connected(index) {
            INPUT_UNCONNECTED
        } else if ctx.is_input_exhausted(index) {
            INPUT_EXHAUSTED
        } else {
            INPUT_CONNECTED
        }
    })
}

unsafe extern "C" fn host_write(
    frame: *mut c_void,
    output: u32,
    sample: *const KSample,
    keep_timestamp: i32,
    error: *mut KError,
) -> i32 {
    host_guard(|| {
        // SAFETY: called by a pack within a host call, with the frame it was given.
        let Some((_, ctx)) = (unsafe { frame_mut(frame) }) else {
            return status::FAILED;
        };
        // SAFETY: the pack passes a valid KSample whose borrowed bytes live for this call.
        let Some(described) = (unsafe { sample.as_ref() }) else {
            return status::FAILED;
        };
        // SAFETY: as above; the bytes are copied into host memory here.
        let decoded = match unsafe { sample_from_c(described) } {
            Ok(decoded) => decoded,
            Err(message) => {
                write_error(error, &message);
                return status::FAILED;
            }
        };
        let result = if keep_timestamp != 0 {
            ctx.write_at(output as usize, decoded.payload, decoded.timestamp)
        } else {
            ctx.write(output as usize, decoded.payload)
        };
        match result {
            Ok(()) => status::OK,
            Err(failure) => {
                write_error(error, &failure.to_string());
                error_status(&failure)
            }
        }
    })
}

unsafe extern "C" fn host_now_ns(frame: *mut c_void) -> i64 {
    // SAFETY: called by a pack within a host call, with the frame it was given.
    catch_unwind(AssertUnwindSafe(|| {
        unsafe { frame_mut(frame) }.map_or(0, |(_, ctx)| ctx.now().as_nanos())
    }))
    .unwrap_or(0)
}

unsafe extern "C" fn host_wait_until(frame: *mut c_void, deadline_ns: i64) -> i32 {
    host_guard(|| {
        // SAFETY: called by a pack within a host call, with the frame it was given.
        let Some((_, ctx)) = (unsafe { frame_mut(frame) }) else {
            return 0;
        };
        i32::from(
            ctx.clock()
                .wait_until(Timestamp::from_nanos(deadline_ns), ctx.signal()),
        )
    })
}

unsafe extern "C" fn host_stop_requested(frame: *mut c_void) -> i32 {
    // SAFETY: called by a pack within a host call, with the frame it was given.
    host_guard(|| unsafe { frame_mut(frame) }.map_or(1, |(_, ctx)| i32::from(ctx.stop_requested())))
}

unsafe extern "C" fn host_set_period_ns(frame: *mut c_void, period_ns: i64) {
    let _ = catch_unwind(AssertUnwindSafe(|| {
        // SAFETY: called by a pack within a host call, with the frame it was given.
        if let Some((_, ctx)) = unsafe { frame_mut(frame) } {
            ctx.set_period(Duration::from_nanos(u64::try_from(period_ns).unwrap_or(1)));
        }
    }));
}

unsafe extern "C" fn host_property(frame: *mut c_void, name: KStr, out: *mut KValue) -> i32 {
    host_guard(|| {
        // SAFETY: called by a pack within a host call, with the frame it was given.
        let Some((frame, ctx)) = (unsafe { frame_mut(frame) }) else {
            return status::FAILED;
        };
        // SAFETY: the pack passes a valid string for the call.
        let Some(name) = (unsafe { name.as_str() }) else {
            return status::FAILED;
        };
        let Some(value) = ctx.property(name).cloned() else {
            return status::NO_DATA;
        };
        let mut described = KValue {
            kind: 0,
            integer: 0,
            float: 0.0,
            text: KStr::new(""),
        };
        match value {
            Value::Bool(b) => {
                described.kind = 1;
                described.integer = i64::from(b);
            }
            Value::I64(i) => {
                described.kind = 2;
                described.integer = i;
            }
            Value::F64(f) => {
                described.kind = 3;
                described.float = f;
            }
            Value::Text(t) => {
                described.kind = 4;
                frame.property_text = t;
                described.text = KStr::new(&frame.property_text);
            }
        }
        // SAFETY: `out` is a valid, writable KValue supplied by the pack.
        match unsafe { out.as_mut() } {
            Some(out) => {
                *out = described;
                status::OK
            }
            None => status::FAILED,
        }
    })
}

unsafe extern "C" fn host_log(frame: *mut c_void, level: u32, message: KStr) {
    let _ = catch_unwind(AssertUnwindSafe(|| {
        // SAFETY: called by a pack within a host call, with the frame it was given.
        let id = unsafe { frame_mut(frame) }.map_or_else(String::new, |(_, ctx)| ctx.id().to_owned());
        // SAFETY: the pack passes a valid string for the call.
        let text = unsafe { message.as_str() }.unwrap_or("(message not UTF-8)");
        match level {
            0 => tracing::error!(component = %id, "{text}"),
            1 => tracing::warn!(component = %id, "{text}"),
            2 => tracing::info!(component = %id, "{text}"),
            _ => tracing::debug!(component = %id, "{text}"),
        }
    }));
}

/// The host function table handed to every loaded component.
pub static HOST_API: KHost = KHost {
    struct_size: size_of::<KHost>() as u32,
    read: host_read,
    try_read: host_try_read,
    wait: host_wait,
    input_state: host_input_state,
    write: host_write,
    now_ns: host_now_ns,
    wait_until: host_wait_until,
    stop_requested: host_stop_requested,
    set_period_ns: host_set_period_ns,
    property: host_property,
    log: host_log,
};

const ERROR_CAPACITY: usize = 1024;

/// A component living in a loaded pack library, driven through its vtable.
pub struct DynamicComponent {
    vtable: &'static KComponentVTable,
    instance: *mut c_void,
    frame: HostFrame,
    error: Vec<u8>,
}

// SAFETY: a component instance is used by one thread at a time (the engine moves it into its thread or
// behind a mutex); the ABI requires packs to allow an instance to move between threads.
unsafe impl Send for DynamicComponent {}

impl std::fmt::Debug for DynamicComponent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DynamicComponent")
            .field("instance", &self.instance)
            .finish_non_exhaustive()
    }
}

impl DynamicComponent {
    fn new(vtable: &'static KComponentVTable) -> Self {
        // SAFETY: the vtable passed the loader's checks; `create` may return null (its constructor failed),
        // which `call` reports as the component's failure.
        let instance = unsafe { (vtable.create)(vtable.data) };
        DynamicComponent {
            vtable,
            instance,
            frame: HostFrame {
                ctx: std::ptr::null_mut(),
                held: BTreeMap::new(),
                property_text: String::new(),
            },
            error: vec![0; ERROR_CAPACITY],
        }
    }

    fn call(
        &mut self,
        stage: &str,
        ctx: &mut Context,
        invoke: impl FnOnce(*mut c_void, *mut c_void, *mut KError) -> i32,
    ) -> ComponentResult {
        if self.instance.is_null() {
            return Err(ComponentError::failed(format_args!(
                "its constructor failed in the pack (during {stage})"
            )));
        }
        self.frame.ctx = std::ptr::from_mut(ctx);
        let mut error = KError {
            buffer: self.error.as_mut_ptr(),
            capacity: self.error.len(),
            len: 0,
        };
        let code = invoke(
            self.instance,
            std::ptr::from_mut(&mut self.frame).cast(),
            &raw mut error,
        );
        self.frame.ctx = std::ptr::null_mut();
        let message = || {
            let bytes = self.error.get(..error.len.min(ERROR_CAPACITY)).unwrap_or(&[]);
            let text = String::from_utf8_lossy(bytes).into_owned();
            if text.is_empty() {
                format!("{stage} failed in the pack")
            } else {
                text
            }
        };
        status_error(code, message)
    }
}

impl Component for DynamicComponent {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let f = self.vtable.birth;
        // SAFETY: instance, frame and error are valid for the call, as the ABI requires.
        self.call("birth", ctx, |i, frame, e| unsafe {
            f(i, frame, &raw const HOST_API, e)
        })
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let f = self.vtable.core;
        // SAFETY: as in `birth`.
        self.call("core", ctx, |i, frame, e| unsafe {
            f(i, frame, &raw const HOST_API, e)
        })
    }

    fn death(&mut self, ctx: &mut Context) -> ComponentResult {
        let f = self.vtable.death;
        // SAFETY: as in `birth`.
        self.call("death", ctx, |i, frame, e| unsafe {
            f(i, frame, &raw const HOST_API, e)
        })
    }

    fn property_changed(&mut self, name: &str, _value: &Value, ctx: &mut Context) -> ComponentResult {
        let f = self.vtable.property_changed;
        let name = KStr::new(name);
        // SAFETY: as in `birth`; `name` lives for the call.
        self.call("property_changed", ctx, |i, frame, e| unsafe {
            f(i, frame, &raw const HOST_API, name, e)
        })
    }

    fn action(&mut self, name: &str, ctx: &mut Context) -> ComponentResult {
        let f = self.vtable.action;
        let name = KStr::new(name);
        // SAFETY: as in `birth`; `name` lives for the call.
        self.call("action", ctx, |i, frame, e| unsafe {
            f(i, frame, &raw const HOST_API, name, e)
        })
    }
}

impl Drop for DynamicComponent {
    fn drop(&mut self) {
        if !self.instance.is_null() {
            // SAFETY: `instance` came from this vtable's `create` and is destroyed once.
            unsafe { (self.vtable.destroy)(self.instance) };
        }
    }
}

// ----------------------------------------------------------------------------------------------------
// Host side: loading a pack library.

/// Why a pack library was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PackLoadError {
    /// The file could not be opened as a shared library (not a library, truncated, wrong architecture).
    #[error("not a loadable shared library: {0}")]
    NotALibrary(String),
    /// The library has no entry symbol.
    #[error("no `{ENTRY_SYMBOL}` symbol: not a Kairos pack (build it with kairos_sdk::export_pack!)")]
    NoEntrySymbol,
    /// The entry returned null (the pack failed to describe itself).
    #[error("`{ENTRY_SYMBOL}` returned no descriptor (the pack failed while describing itself)")]
    NullDescriptor,
    /// Wrong magic number.
    #[error("wrong magic number {found:#018x}: not a Kairos pack descriptor")]
    BadMagic {
        /// What was found.
        found: u64,
    },
    /// Another ABI version.
    #[error("pack ABI version {found} is {}; this runtime speaks version {ABI_VERSION}: rebuild the pack against this SDK", if *.found > ABI_VERSION { "newer" } else { "older" })]
    AbiVersion {
        /// The pack's version.
        found: u32,
    },
    /// A struct size differs: the pack was built from another header.
    #[error(
        "layout mismatch: {what} is {found} bytes in the pack, {expected} here; rebuild the pack against this SDK"
    )]
    Layout {
        /// Which struct.
        what: &'static str,
        /// Its size in the pack.
        found: u32,
        /// Its size here.
        expected: u32,
    },
    /// A string field is not UTF-8 or the name is empty.
    #[error("invalid {0} in the pack descriptor")]
    BadField(&'static str),
    /// A component descriptor could not be read.
    #[error("component {index}: descriptor is not valid JSON for this SDK: {reason}")]
    BadComponent {
        /// Position in the table.
        index: usize,
        /// Why.
        reason: String,
    },
    /// The pack was built against an incompatible SDK.
    #[error("built against kairos-sdk {found}, incompatible with this runtime's {expected}")]
    SdkVersion {
        /// The pack's SDK version.
        found: String,
        /// This SDK's version.
        expected: &'static str,
    },
}

/// A pack library that passed every check; its code stays loaded for the life of the process.
#[derive(Debug, Clone)]
pub struct LoadedPack {
    /// Where it was loaded from.
    pub path: PathBuf,
    /// The pack's name.
    pub name: String,
    /// The pack's version.
    pub version: String,
    /// The SDK version it was built with.
    pub sdk_version: String,
    components: Vec<(ComponentInfo, &'static KComponentVTable)>,
}

impl LoadedPack {
    /// The component types it offers.
    pub fn component_infos(&self) -> impl Iterator<Item = &ComponentInfo> {
        self.components.iter().map(|(info, _)| info)
    }

    /// Adds the pack and its components to `registry`.
    pub fn register(&self, registry: &mut Registry) {
        let origin = self.path.display().to_string();
        let mut pack = registry.pack(&self.name, &self.version, &origin);
        for (info, vtable) in &self.components {
            let vtable: &'static KComponentVTable = vtable;
            pack.component_with(info.clone(), move || Box::new(DynamicComponent::new(vtable)));
        }
    }
}

/// Whether a pack built with SDK `version` can run here: the same major version, and for 0.x the same
/// minor version (semantic versioning's rule for pre-1.0 releases).
fn sdk_compatible(version: &str) -> bool {
    let (Ok(theirs), Ok(ours)) = (
        semver::Version::parse(version),
        semver::Version::parse(crate::SDK_VERSION),
    ) else {
        return false;
    };
    theirs.major == ours.major && (ours.major > 0 || theirs.minor == ours.minor)
}

/// Checks that an ELF file is a complete shared object before handing it to the dynamic loader, which
/// maps a truncated file and then dies of SIGBUS touching the missing pages.
#[cfg(target_os = "linux")]
fn check_elf(path: &Path) -> Result<(), PackLoadError> {
    fn field(bytes: &[u8], at: usize, size: usize) -> Option<u64> {
        let slice = bytes.get(at..at.checked_add(size)?)?;
        let mut value = [0_u8; 8];
        value.get_mut(..size)?.copy_from_slice(slice);
        Some(u64::from_le_bytes(value))
    }
    let refuse = |why: &str| PackLoadError::NotALibrary(why.to_owned());
    let bytes =
        std::fs::read(path).map_err(|e| PackLoadError::NotALibrary(format!("cannot read it: {e}")))?;
    if bytes.get(..4) != Some(b"\x7fELF".as_slice()) {
        return Err(refuse("not an ELF file"));
    }
    // 64-bit, little-endian: what this runtime is built for.
    if bytes.get(4) != Some(&2) || bytes.get(5) != Some(&1) {
        return Err(refuse("not a 64-bit little-endian ELF file"));
    }
    if field(&bytes, 16, 2) != Some(3) {
        return Err(refuse(
            "an ELF file, but not a shared library (build the pack with crate-type cdylib, or -shared)",
        ));
    }
    let len = bytes.len() as u64;
    let truncated = || refuse("truncated: the file ends before the data its headers describe");
    let table_end = |offset: u64, entry: u64, count: u64| offset.checked_add(entry.checked_mul(count)?);
    let (phoff, phentsize, phnum) = (field(&bytes, 32, 8), field(&bytes, 54, 2), field(&bytes, 56, 2));
    let (shoff, shentsize, shnum) = (field(&bytes, 40, 8), field(&bytes, 58, 2), field(&bytes, 60, 2));
    let (Some(phoff), Some(phentsize), Some(phnum), Some(shoff), Some(shentsize), Some(shnum)) =
        (phoff, phentsize, phnum, shoff, shentsize, shnum)
    else {
        return Err(truncated());
    };
    if table_end(phoff, phentsize, phnum).is_none_or(|end| end > len)
        || table_end(shoff, shentsize, shnum).is_none_or(|end| end > len)
    {
        return Err(truncated());
    }
    for index in 0..phnum {
        let header = usize::try_from(phoff + index * phentsize).map_err(|_| truncated())?;
        let (offset, file_size) = (field(&bytes, header + 8, 8), field(&bytes, header + 32, 8));
        let (Some(offset), Some(file_size)) = (offset, file_size) else {
            return Err(truncated());
        };
        if offset.checked_add(file_size).is_none_or(|end| end > len) {
            return Err(truncated());
        }
    }
    Ok(())
}

#[cfg(not(target_os = "linux"))]
fn check_elf(_path: &Path) -> Result<(), PackLoadError> {
    Ok(())
}

/// Opens `path`, checks its descriptor entirely, and keeps the library loaded for good.
pub fn load_pack(path: &Path) -> Result<LoadedPack, PackLoadError> {
    check_elf(path)?;
    // SAFETY: loading a library runs its initialisers. Pack libraries are trusted code chosen by the user
    // (a pack path); everything after this is checked before it is called.
    let library =
        unsafe { libloading::Library::new(path) }.map_err(|e| PackLoadError::NotALibrary(e.to_string()))?;
    // Never unloaded: component code and static data may be referenced for the rest of the process.
    let library: &'static libloading::Library = Box::leak(Box::new(library));
    let symbol = format!("{ENTRY_SYMBOL}\0");
    // SAFETY: the symbol, if present, is the pack entry with this signature (the ABI contract); a wrong
    // signature is caught by the magic and layout checks before any further call.
    let entry: libloading::Symbol<'static, unsafe extern "C" fn() -> *const KPackDescriptor> =
        unsafe { library.get(symbol.as_bytes()) }.map_err(|_| PackLoadError::NoEntrySymbol)?;
    // SAFETY: calling the entry is the first call into the pack; it returns a pointer to static data.
    let descriptor = unsafe { entry() };
    // SAFETY: non-null pointers from the entry point to a descriptor that lives as long as the library.
    let descriptor: &'static KPackDescriptor =
        unsafe { descriptor.as_ref() }.ok_or(PackLoadError::NullDescriptor)?;
    check_descriptor(descriptor)?;
    // SAFETY: the layout check passed, so the string fields are KStr pointing into the library's data.
    let text = |field: KStr, what: &'static str| {
        unsafe { field.as_str() }
            .map(str::to_owned)
            .ok_or(PackLoadError::BadField(what))
    };
    let name = text(descriptor.name, "pack name")?;
    let version = text(descriptor.version, "pack version")?;
    let sdk_version = text(descriptor.sdk_version, "SDK version")?;
    if name.is_empty() || semver::Version::parse(&version).is_err() {
        return Err(PackLoadError::BadField("pack name or semantic version"));
    }
    if !sdk_compatible(&sdk_version) {
        return Err(PackLoadError::SdkVersion {
            found: sdk_version,
            expected: crate::SDK_VERSION,
        });
    }
    let vtables: &'static [KComponentVTable] = if descriptor.component_count == 0 {
        &[]
    } else if descriptor.components.is_null() {
        return Err(PackLoadError::BadField("component table"));
    } else {
        // SAFETY: the descriptor promises `component_count` vtables at `components`, static in the library.
        unsafe { std::slice::from_raw_parts(descriptor.components, descriptor.component_count) }
    };
    let mut components = Vec::new();
    for (index, vtable) in vtables.iter().enumerate() {
        let bad = |reason: String| PackLoadError::BadComponent { index, reason };
        // SAFETY: as for the pack's own strings.
        let json = unsafe { vtable.descriptor_json.as_str() }.ok_or_else(|| bad("not UTF-8".to_owned()))?;
        let mut info: ComponentInfo = serde_json::from_str(json).map_err(|e| bad(e.to_string()))?;
        info.pack.clone_from(&name);
        components.push((info, vtable));
    }
    Ok(LoadedPack {
        path: path.to_owned(),
        name,
        version,
        sdk_version,
        components,
    })
}

fn check_descriptor(descriptor: &KPackDescriptor) -> Result<(), PackLoadError> {
    if descriptor.magic != ABI_MAGIC {
        return Err(PackLoadError::BadMagic {
            found: descriptor.magic,
        });
    }
    if descriptor.abi_version != ABI_VERSION {
        return Err(PackLoadError::AbiVersion {
            found: descriptor.abi_version,
        });
    }
    let checks = [
        (
            "the pack descriptor",
            descriptor.descriptor_size,
            size_u32::<KPackDescriptor>(),
        ),
        ("the sample struct", descriptor.sample_size, size_u32::<KSample>()),
        ("the host table", descriptor.host_size, size_u32::<KHost>()),
        (
            "the component table",
            descriptor.vtable_size,
            size_u32::<KComponentVTable>(),
        ),
        ("the value struct", descriptor.value_size, size_u32::<KValue>()),
    ];
    for (what, found, expected) in checks {
        if found != expected {
            return Err(PackLoadError::Layout {
                what,
                found,
                expected,
            });
        }
    }
    Ok(())
}

// ----------------------------------------------------------------------------------------------------
// Pack side: a Rust component's context reaching the host, and the exported descriptor.

/// The pack-side link to the host for one component call.
#[derive(Debug)]
pub(crate) struct RemoteHost {
    host: *const KHost,
    frame: *mut c_void,
    reactive: bool,
}

// SAFETY: the pointers are only used within a host call on the thread the host made it from.
unsafe impl Send for RemoteHost {}

impl RemoteHost {
    fn api(&self) -> Option<&KHost> {
        // SAFETY: `host` is the table the host passed for the current call, static in the host.
        unsafe { self.host.as_ref() }
    }

    pub(crate) fn is_reactive(&self) -> bool {
        self.reactive
    }

    fn receive(code: i32, described: &KSample) -> Result<Sample, ComponentError> {
        status_error(code, || "reading failed in the host".to_owned())?;
        // SAFETY: the host filled `described` with bytes it keeps alive until our next read of this input.
        unsafe { sample_from_c(described) }.map_err(ComponentError::Failed)
    }

    pub(crate) fn read(&self, index: usize, interruptible: bool) -> Result<Sample, ComponentError> {
        let api = self.api().ok_or(ComponentError::Stopped)?;
        let mut described = KSample::default();
        // SAFETY: frame and out pointer are valid for the call.
        let code = unsafe {
            (api.read)(
                self.frame,
                index as u32,
                i32::from(interruptible),
                &raw mut described,
            )
        };
        Self::receive(code, &described)
    }

    pub(crate) fn try_read(&self, index: usize) -> Option<Sample> {
        let api = self.api()?;
        let mut described = KSample::default();
        // SAFETY: frame and out pointer are valid for the call.
        let code = unsafe { (api.try_read)(self.frame, index as u32, &raw mut described) };
        (code == status::OK)
            .then(|| Self::receive(code, &described).ok())
            .flatten()
    }

    pub(crate) fn wait(&self, interruptible: bool) -> ComponentResult {
        let api = self.api().ok_or(ComponentError::Stopped)?;
        // SAFETY: the frame is valid for the call.
        let code = unsafe { (api.wait)(self.frame, i32::from(interruptible)) };
        status_error(code, || "waiting failed in the host".to_owned())
    }

    pub(crate) fn input_state(&self, index: usize) -> i32 {
        // SAFETY: the frame is valid for the call.
        self.api().map_or(INPUT_UNCONNECTED, |api| unsafe {
            (api.input_state)(self.frame, index as u32)
        })
    }

    /// Writes through the host: `timestamp` `None` stamps the sample now (one clock read, in the host);
    /// `Some` keeps the given timestamp. The host sets the time of issue.
    pub(crate) fn write(
        &self,
        index: usize,
        payload: &Payload,
        timestamp: Option<Timestamp>,
    ) -> ComponentResult {
        let api = self.api().ok_or(ComponentError::Stopped)?;
        let sample = Sample {
            payload: payload.clone(),
            timestamp: timestamp.unwrap_or_default(),
            time_of_issue: Timestamp::ZERO,
            sequence: 0,
        };
        let mut scratch = Vec::new();
        let described = sample_to_c(&sample, &mut scratch);
        // On the stack: a write must not allocate for a message it almost never gets.
        let mut buffer = [0_u8; 256];
        let mut error = KError {
            buffer: buffer.as_mut_ptr(),
            capacity: buffer.len(),
            len: 0,
        };
        let keep_timestamp = i32::from(timestamp.is_some());
        // SAFETY: every pointer is valid for the call; the host copies what it keeps.
        let code = unsafe {
            (api.write)(
                self.frame,
                index as u32,
                &raw const described,
                keep_timestamp,
                &raw mut error,
            )
        };
        status_error(code, || {
            String::from_utf8_lossy(buffer.get(..error.len).unwrap_or(&[])).into_owned()
        })
    }

    pub(crate) fn stop_requested(&self) -> bool {
        // SAFETY: the frame is valid for the call.
        self.api()
            .is_none_or(|api| unsafe { (api.stop_requested)(self.frame) } != 0)
    }

    pub(crate) fn set_period(&self, period: Duration) {
        if let Some(api) = self.api() {
            // SAFETY: the frame is valid for the call.
            unsafe { (api.set_period_ns)(self.frame, i64::try_from(period.as_nanos()).unwrap_or(i64::MAX)) };
        }
    }

    fn property(&self, name: &str) -> Option<Value> {
        let api = self.api()?;
        let mut out = KValue {
            kind: 0,
            integer: 0,
            float: 0.0,
            text: KStr::new(""),
        };
        // SAFETY: pointers valid for the call; the text is copied before the next property call.
        let code = unsafe { (api.property)(self.frame, KStr::new(name), &raw mut out) };
        if code != status::OK {
            return None;
        }
        Some(match out.kind {
            1 => Value::Bool(out.integer != 0),
            2 => Value::I64(out.integer),
            3 => Value::F64(out.float),
            // SAFETY: the host's text lives until its next property call.
            _ => Value::Text(unsafe { out.text.as_str() }.unwrap_or_default().to_owned()),
        })
    }
}

/// The runtime clock as seen from a pack: each reading asks the host.
#[derive(Debug, Default)]
struct RemoteClock {
    host: std::sync::atomic::AtomicUsize,
    frame: std::sync::atomic::AtomicUsize,
}

impl RemoteClock {
    fn set_link(&self, host: *const KHost, frame: *mut c_void) {
        self.host
            .store(host as usize, std::sync::atomic::Ordering::Relaxed);
        self.frame
            .store(frame as usize, std::sync::atomic::Ordering::Relaxed);
    }

    fn link(&self) -> Option<(*const KHost, *mut c_void)> {
        let host = self.host.load(std::sync::atomic::Ordering::Relaxed) as *const KHost;
        let frame = self.frame.load(std::sync::atomic::Ordering::Relaxed) as *mut c_void;
        (!host.is_null()).then_some((host, frame))
    }
}

impl Clock for RemoteClock {
    fn now(&self) -> Timestamp {
        let Some((host, frame)) = self.link() else {
            return Timestamp::ZERO;
        };
        // SAFETY: the link is refreshed at every call into the pack and used within it.
        Timestamp::from_nanos(unsafe { host.as_ref() }.map_or(0, |api| unsafe { (api.now_ns)(frame) }))
    }

    fn wait_until(&self, deadline: Timestamp, _signal: &RunSignal) -> bool {
        let Some((host, frame)) = self.link() else {
            return false;
        };
        // SAFETY: as in `now`.
        unsafe { host.as_ref() }
            .is_some_and(|api| unsafe { (api.wait_until)(frame, deadline.as_nanos()) } != 0)
    }

    fn describe(&self) -> String {
        "the host runtime's clock".to_owned()
    }
}

/// One component instance inside a pack library.
struct PackInstance {
    component: Box<dyn Component>,
    info: &'static ComponentInfo,
    ctx: Option<Context>,
    clock: Arc<RemoteClock>,
}

impl PackInstance {
    /// The context for this call, created on first use, its host link refreshed.
    fn context(&mut self, host: *const KHost, frame: *mut c_void) -> &mut Context {
        self.clock.set_link(host, frame);
        let info = self.info;
        let clock: Arc<dyn Clock> = Arc::clone(&self.clock) as Arc<dyn Clock>;
        let ctx = self.ctx.get_or_insert_with(|| {
            let remote = RemoteHost {
                host,
                frame,
                reactive: info.mode == ExecutionMode::Reactive,
            };
            let inputs = info
                .inputs
                .iter()
                .map(|i| crate::component::InputPort::new(i.name.clone(), None))
                .collect();
            let outputs = info
                .outputs
                .iter()
                .map(|o| {
                    crate::component::OutputPort::new(
                        o.name.clone(),
                        None,
                        crate::buffer::OutputBuffer::new(o.name.clone(), 1),
                        1,
                    )
                })
                .collect();
            Context::new_remote(
                ContextParts {
                    id: String::new(),
                    inputs,
                    outputs,
                    properties: BTreeMap::new(),
                    clock,
                    signal: Arc::new(RunSignal::new()),
                },
                remote,
            )
        });
        if let Some(remote) = ctx.remote_mut() {
            remote.host = host;
            remote.frame = frame;
        }
        ctx
    }

    /// Copies every property's current value from the host.
    fn refresh_properties(&mut self, host: *const KHost, frame: *mut c_void) {
        let names: Vec<String> = self.info.properties.iter().map(|p| p.name.clone()).collect();
        let ctx = self.context(host, frame);
        for name in names {
            let value = ctx.remote_mut().and_then(|r| r.property(&name));
            if let Some(value) = value {
                ctx.set_property(&name, value);
            }
        }
    }
}

/// A pack's exported descriptor and everything it points to, built once.
#[derive(Debug)]
pub struct ExportedPack {
    descriptor: KPackDescriptor,
    _vtables: Vec<KComponentVTable>,
    _strings: Vec<String>,
}

// SAFETY: the descriptor's pointers refer to data owned by this struct, immutable once built.
unsafe impl Send for ExportedPack {}
// SAFETY: as above.
unsafe impl Sync for ExportedPack {}

struct ExportedComponent {
    info: ComponentInfo,
    factory: crate::registry::Factory,
}

fn pack_guard(error: *mut KError, body: impl FnOnce() -> ComponentResult) -> i32 {
    match catch_unwind(AssertUnwindSafe(body)) {
        Ok(Ok(())) => status::OK,
        Ok(Err(failure)) => {
            write_error(error, &failure.to_string());
            error_status(&failure)
        }
        Err(panic) => {
            write_error(
                error,
                &format!("panicked: {}", crate::panic_message(panic.as_ref())),
            );
            status::FAILED
        }
    }
}

unsafe extern "C" fn pack_create(data: *const c_void) -> *mut c_void {
    catch_unwind(|| {
        // SAFETY: `data` is the ExportedComponent this vtable was built with, alive for the process.
        let Some(exported) = (unsafe { data.cast::<ExportedComponent>().as_ref() }) else {
            return std::ptr::null_mut();
        };
        // SAFETY: as above: the reference is 'static because exported packs are never dropped.
        let info: &'static ComponentInfo = unsafe { &*std::ptr::from_ref(&exported.info) };
        let instance = PackInstance {
            component: (exported.factory)(),
            info,
            ctx: None,
            clock: Arc::new(RemoteClock::default()),
        };
        Box::into_raw(Box::new(instance)).cast::<c_void>()
    })
    .unwrap_or(std::ptr::null_mut())
}

unsafe extern "C" fn pack_destroy(instance: *mut c_void) {
    if !instance.is_null() {
        // SAFETY: `instance` came from `pack_create` and the host destroys it once.
        let _ = catch_unwind(AssertUnwindSafe(|| {
            drop(unsafe { Box::from_raw(instance.cast::<PackInstance>()) });
        }));
    }
}

/// # Safety
/// `instance` must come from `pack_create` and be used by one thread at a time.
unsafe fn instance_mut<'a>(instance: *mut c_void) -> Option<&'a mut PackInstance> {
    // SAFETY: guaranteed by the caller.
    unsafe { instance.cast::<PackInstance>().as_mut() }
}

/// The shared body of every pack-side entry point: finds the instance, links its context to this host
/// call (re-reading the properties first when `refresh`), and runs `call` under `catch_unwind`.
fn with_instance(
    instance: *mut c_void,
    frame: *mut c_void,
    host: *const KHost,
    error: *mut KError,
    refresh: bool,
    call: impl FnOnce(&mut dyn Component, &mut Context) -> ComponentResult,
) -> i32 {
    pack_guard(error, || {
        // SAFETY: the host passes an instance it created, exclusively for this call.
        let instance =
            unsafe { instance_mut(instance) }.ok_or_else(|| ComponentError::failed("no instance"))?;
        if refresh {
            instance.refresh_properties(host, frame);
        } else {
            instance.context(host, frame);
        }
        let PackInstance { component, ctx, .. } = instance;
        let ctx = ctx.as_mut().ok_or_else(|| ComponentError::failed("no context"))?;
        call(component.as_mut(), ctx)
    })
}

unsafe extern "C" fn pack_birth(
    instance: *mut c_void,
    frame: *mut c_void,
    host: *const KHost,
    error: *mut KError,
) -> i32 {
    with_instance(instance, frame, host, error, true, |component, ctx| {
        component.birth(ctx)
    })
}

unsafe extern "C" fn pack_core(
    instance: *mut c_void,
    frame: *mut c_void,
    host: *const KHost,
    error: *mut KError,
) -> i32 {
    with_instance(instance, frame, host, error, false, |component, ctx| {
        ctx.begin_cycle();
        component.core(ctx)
    })
}

unsafe extern "C" fn pack_death(
    instance: *mut c_void,
    frame: *mut c_void,
    host: *const KHost,
    error: *mut KError,
) -> i32 {
    with_instance(instance, frame, host, error, false, |component, ctx| {
        component.death(ctx)
    })
}

unsafe extern "C" fn pack_property_changed(
    instance: *mut c_void,
    frame: *mut c_void,
    host: *const KHost,
    name: KStr,
    error: *mut KError,
) -> i32 {
    // SAFETY: the host passes a valid name for the call.
    let name = unsafe { name.as_str() }.unwrap_or_default().to_owned();
    with_instance(instance, frame, host, error, true, |component, ctx| {
        let value = ctx
            .property(&name)
            .cloned()
            .ok_or_else(|| ComponentError::failed(format_args!("no property '{name}'")))?;
        component.property_changed(&name, &value, ctx)
    })
}

unsafe extern "C" fn pack_action(
    instance: *mut c_void,
    frame: *mut c_void,
    host: *const KHost,
    name: KStr,
    error: *mut KError,
) -> i32 {
    // SAFETY: the host passes a valid name for the call.
    let name = unsafe { name.as_str() }.unwrap_or_default().to_owned();
    with_instance(instance, frame, host, error, false, |component, ctx| {
        component.action(&name, ctx)
    })
}

/// Builds (once) and returns a pack's descriptor from its `register` function. Called by the code
/// [`crate::export_pack!`] generates; returns null if registering panicked.
pub fn export_entry(
    cell: &'static OnceLock<Option<ExportedPack>>,
    register: fn(&mut Registry),
) -> *const KPackDescriptor {
    let exported = cell.get_or_init(|| catch_unwind(|| build_export(register)).ok().flatten());
    exported
        .as_ref()
        .map_or(std::ptr::null(), |e| &raw const e.descriptor)
}

fn build_export(register: fn(&mut Registry)) -> Option<ExportedPack> {
    let mut registry = Registry::new();
    register(&mut registry);
    let pack = registry.packs().next()?.clone();
    let mut strings = vec![
        crate::SDK_VERSION.to_owned(),
        pack.name.clone(),
        pack.version.clone(),
    ];
    let mut vtables = Vec::new();
    for registered in registry.components() {
        let json = serde_json::to_string(&registered.info).ok()?;
        // Leaked on purpose: exported packs live as long as the process, and vtables point into them.
        let exported: &'static ExportedComponent = Box::leak(Box::new(ExportedComponent {
            info: registered.info.clone(),
            factory: Arc::clone(&registered.factory),
        }));
        strings.push(json);
        strings.push(registered.info.type_name.clone());
        let (Some(json), Some(type_name)) = (strings.get(strings.len() - 2), strings.last()) else {
            return None;
        };
        vtables.push(KComponentVTable {
            type_name: KStr::new(type_name),
            descriptor_json: KStr::new(json),
            data: std::ptr::from_ref(exported).cast(),
            create: pack_create,
            destroy: pack_destroy,
            birth: pack_birth,
            core: pack_core,
            death: pack_death,
            property_changed: pack_property_changed,
            action: pack_action,
        });
    }
    let (Some(sdk), Some(name), Some(version)) = (strings.first(), strings.get(1), strings.get(2)) else {
        return None;
    };
    let descriptor = KPackDescriptor {
        magic: ABI_MAGIC,
        abi_version: ABI_VERSION,
        descriptor_size: size_u32::<KPackDescriptor>(),
        sample_size: size_u32::<KSample>(),
        host_size: size_u32::<KHost>(),
        vtable_size: size_u32::<KComponentVTable>(),
        value_size: size_u32::<KValue>(),
        sdk_version: KStr::new(sdk),
        name: KStr::new(name),
        version: KStr::new(version),
        components: vtables.as_ptr(),
        component_count: vtables.len(),
    };
    // Strings moved into the struct keep their heap buffers, so the KStr pointers stay valid.
    Some(ExportedPack {
        descriptor,
        _vtables: vtables,
        _strings: strings,
    })
}

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

/// The C header for C and C++ packs (`component-sdk/include/kairos.h`), kept in step with this module by a
/// test that compiles it and compares every struct's size and every constant.
pub const C_HEADER: &str = include_str!("../include/kairos.h");
