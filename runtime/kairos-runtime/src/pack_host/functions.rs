//! The host functions a loaded component calls (`KHost`): each finds the component's [`Context`] through
//! the frame of the call in progress and does what the context would do for a built-in component.

#![allow(
    unsafe_code,
    reason = "functions called from C with raw pointers to the frame, samples and buffers"
)]

use std::collections::BTreeMap;
use std::ffi::c_void;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::time::Duration;

use kairos_sdk_core::abi::{
    INPUT_CONNECTED, INPUT_EXHAUSTED, INPUT_UNCONNECTED, KError, KHost, KLinkCounters, KSample, KStr, KValue,
    status,
};
use kairos_sdk_core::host::{ContextHost, error_status, sample_from_c, sample_to_c, value_to_c, write_error};
use kairos_sdk_core::{Context, Sample, Timestamp};

/// What the host keeps for one component between calls: the context of the current call and the samples
/// the pack borrows.
pub(super) struct HostFrame {
    pub(super) ctx: *mut Context,
    held: BTreeMap<u32, (Sample, Vec<u8>)>,
    property_value: kairos_sdk_core::Value,
    /// What `instance_info` returns, made at its first call: the context does not change after that.
    instance_info: Option<String>,
}

impl HostFrame {
    pub(super) fn new() -> Self {
        HostFrame {
            ctx: std::ptr::null_mut(),
            held: BTreeMap::new(),
            property_value: kairos_sdk_core::Value::Bool(false),
            instance_info: None,
        }
    }
}

/// # Safety
/// `frame` must be the pointer the host passed to the current pack call.
pub(super) unsafe fn frame_mut<'a>(frame: *mut c_void) -> Option<(&'a mut HostFrame, &'a mut Context)> {
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
                // SAFETY: the pack passes a valid error buffer for the call.
                unsafe { write_error(error, &message.to_string()) };
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
                // SAFETY: the pack passes a valid error buffer for the call.
                unsafe { write_error(error, &failure.to_string()) };
                error_status(&failure)
            }
        }
    })
}

unsafe extern "C" fn host_now_ns(frame: *mut c_void) -> i64 {
    catch_unwind(AssertUnwindSafe(|| {
        // SAFETY: called by a pack within a host call, with the frame it was given.
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
        i32::from(ctx.wait_until(Timestamp::from_nanos(deadline_ns)).is_ok())
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
        // Kept in the frame: a text value is borrowed until the pack's next property call.
        frame.property_value = value;
        let described = value_to_c(&frame.property_value);
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

unsafe extern "C" fn host_instance_info(frame: *mut c_void) -> KStr {
    catch_unwind(AssertUnwindSafe(|| {
        // SAFETY: called by a pack within a host call, with the frame it was given.
        let Some((frame, ctx)) = (unsafe { frame_mut(frame) }) else {
            return KStr::new("");
        };
        let text = frame.instance_info.get_or_insert_with(|| describe_instance(ctx));
        KStr::new(text)
    }))
    .unwrap_or(KStr::new(""))
}

/// The instance as `instance_info` describes it to the pack side, which builds its context from it.
fn describe_instance(ctx: &Context) -> String {
    let sources: Vec<Option<&str>> = ctx
        .inputs()
        .iter()
        .map(kairos_sdk_core::InputPort::source)
        .collect();
    serde_json::json!({
        "id": ctx.id(),
        "input_sources": sources,
        "clock": ctx.clock_description(),
        "diagram": ctx.diagram_text().map(AsRef::<str>::as_ref),
    })
    .to_string()
}

unsafe extern "C" fn host_input_counters(frame: *mut c_void, input: u32, out: *mut KLinkCounters) -> i32 {
    host_guard(|| {
        // SAFETY: called by a pack within a host call, with the frame it was given.
        let Some((_, ctx)) = (unsafe { frame_mut(frame) }) else {
            return status::FAILED;
        };
        let Some(counters) = ctx.input_counters(input as usize) else {
            return status::NO_DATA;
        };
        // SAFETY: `out` is a valid, writable KLinkCounters supplied by the pack.
        match unsafe { out.as_mut() } {
            Some(out) => {
                *out = KLinkCounters::from(&counters);
                status::OK
            }
            None => status::FAILED,
        }
    })
}

unsafe extern "C" fn host_set_status(frame: *mut c_void, json: KStr) -> i32 {
    host_guard(|| {
        // SAFETY: called by a pack within a host call, with the frame it was given.
        let Some((_, ctx)) = (unsafe { frame_mut(frame) }) else {
            return status::FAILED;
        };
        // SAFETY: the pack passes a valid string for the call.
        let Some(text) = (unsafe { json.as_str() }) else {
            return status::FAILED;
        };
        match serde_json::from_str(text) {
            Ok(value) => {
                ctx.set_status(value);
                status::OK
            }
            Err(_) => status::FAILED,
        }
    })
}

unsafe extern "C" fn host_sleep_ns(frame: *mut c_void, timeout_ns: i64) -> i32 {
    host_guard(|| {
        // SAFETY: called by a pack within a host call, with the frame it was given.
        let Some((_, ctx)) = (unsafe { frame_mut(frame) }) else {
            return status::FAILED;
        };
        let timeout = Duration::from_nanos(u64::try_from(timeout_ns).unwrap_or(0));
        match ctx.sleep(timeout) {
            Ok(()) => status::OK,
            Err(error) => error_status(&error),
        }
    })
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
    instance_info: host_instance_info,
    input_counters: host_input_counters,
    set_status: host_set_status,
    sleep_ns: host_sleep_ns,
};
