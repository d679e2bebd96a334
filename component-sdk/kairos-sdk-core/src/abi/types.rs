//! The C structs of the pack ABI, field for field as `kairos.h` declares them.

#![allow(unsafe_code, reason = "borrowed C strings are read through raw pointers")]

use std::ffi::c_void;

use crate::stats::{LatencySummary, LinkCounters};

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
    pub instance_info: unsafe extern "C" fn(frame: *mut c_void) -> KStr,
    pub input_counters: unsafe extern "C" fn(frame: *mut c_void, input: u32, out: *mut KLinkCounters) -> i32,
    pub set_status: unsafe extern "C" fn(frame: *mut c_void, json: KStr) -> i32,
    pub sleep_ns: unsafe extern "C" fn(frame: *mut c_void, timeout_ns: i64) -> i32,
}

/// A link's counters in C terms ([`LinkCounters`], latencies in nanoseconds).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
#[allow(
    missing_docs,
    reason = "each field is documented in kairos.h, next to its C declaration"
)]
pub struct KLinkCounters {
    pub written: u64,
    pub read: u64,
    pub skipped: u64,
    pub overwritten: u64,
    pub queued: u64,
    pub repeated: u64,
    pub latency_count: u64,
    pub latency_min_ns: i64,
    pub latency_mean_ns: i64,
    pub latency_p50_ns: i64,
    pub latency_p99_ns: i64,
    pub latency_max_ns: i64,
}

impl From<&LinkCounters> for KLinkCounters {
    fn from(counters: &LinkCounters) -> Self {
        let latency = &counters.latency;
        KLinkCounters {
            written: counters.written,
            read: counters.read,
            skipped: counters.skipped,
            overwritten: counters.overwritten,
            queued: counters.queued,
            repeated: counters.repeated,
            latency_count: latency.count,
            latency_min_ns: latency.min_nanos,
            latency_mean_ns: latency.mean_nanos,
            latency_p50_ns: latency.p50_nanos,
            latency_p99_ns: latency.p99_nanos,
            latency_max_ns: latency.max_nanos,
        }
    }
}

impl From<&KLinkCounters> for LinkCounters {
    fn from(k: &KLinkCounters) -> Self {
        LinkCounters {
            written: k.written,
            read: k.read,
            skipped: k.skipped,
            overwritten: k.overwritten,
            queued: k.queued,
            repeated: k.repeated,
            latency: LatencySummary {
                count: k.latency_count,
                min_nanos: k.latency_min_ns,
                mean_nanos: k.latency_mean_ns,
                p50_nanos: k.latency_p50_ns,
                p99_nanos: k.latency_p99_ns,
                max_nanos: k.latency_max_ns,
            },
        }
    }
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
    pub create: Option<unsafe extern "C" fn(data: *const c_void) -> *mut c_void>,
    pub destroy: Option<unsafe extern "C" fn(instance: *mut c_void)>,
    pub birth: Option<KLifecycleFn>,
    pub core: Option<KLifecycleFn>,
    pub death: Option<KLifecycleFn>,
    pub property_changed: Option<KNamedFn>,
    pub action: Option<KNamedFn>,
}

impl KComponentVTable {
    /// The first function pointer that is null, by its C name: a table with one is refused at load,
    /// since calling it would crash the runtime. (`Option` of a function pointer has the pointer's layout,
    /// null being `None`.)
    pub fn missing_function(&self) -> Option<&'static str> {
        [
            ("create", self.create.is_none()),
            ("destroy", self.destroy.is_none()),
            ("birth", self.birth.is_none()),
            ("core", self.core.is_none()),
            ("death", self.death.is_none()),
            ("property_changed", self.property_changed.is_none()),
            ("action", self.action.is_none()),
        ]
        .into_iter()
        .find_map(|(name, missing)| missing.then_some(name))
    }
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

/// The size of `T` as the layout check records it.
pub fn size_u32<T>() -> u32 {
    u32::try_from(size_of::<T>()).unwrap_or(u32::MAX)
}
