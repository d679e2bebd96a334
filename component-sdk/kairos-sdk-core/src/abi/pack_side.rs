//! The pack side of the ABI: what `export_pack!` builds into a Rust pack library. A component there gets
//! the same [`Context`] as in the runtime's own process; its ports, clock and status reach the host
//! through [`HostPorts`], implemented here over the host's function table.

#![allow(
    unsafe_code,
    reason = "the exported C entry points, and calls through the host's function table"
)]

use std::collections::BTreeMap;
use std::ffi::c_void;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use kairos_diagram::{ComponentInfo, ExecutionMode};
use serde::Deserialize;

use super::convert::{error_status, sample_from_c, sample_to_c, status_error, value_from_c, write_error};
use super::types::{
    KComponentVTable, KError, KHost, KLinkCounters, KPackDescriptor, KSample, KStr, KValue, size_u32,
};
use super::{ABI_MAGIC, ABI_VERSION, INPUT_CONNECTED, INPUT_EXHAUSTED, status};
use crate::buffer::OutputBuffer;
use crate::component::{
    Component, ComponentError, ComponentResult, Context, ContextParts, HostPorts, InputPort, InputState,
    OutputPort, StatusSchedule,
};
use crate::payload::Payload;
use crate::registry::Registry;
use crate::sample::Sample;
use crate::signal::RunSignal;
use crate::stats::LinkCounters;
use crate::time::{Clock, Timestamp};

/// What the host says about an instance once (`KHost::instance_info`), as JSON. Unknown fields are
/// ignored, so a later host may say more.
#[derive(Debug, Default, Deserialize)]
#[serde(default)]
pub(crate) struct InstanceInfo {
    /// The instance's id in the diagram.
    pub id: String,
    /// Per input in descriptor order: the output feeding it (`camera.image`), `None` when unconnected.
    pub input_sources: Vec<Option<String>>,
    /// The runtime clock, in one line.
    pub clock: String,
    /// The diagram's text, when the host gives it.
    pub diagram: Option<String>,
}

/// The host table and frame of the call in progress. Set at every entry into the pack and read only
/// within that call, on the calling thread: the context, its ports and its clock share one.
#[derive(Debug, Default)]
struct HostLink {
    host: AtomicUsize,
    frame: AtomicUsize,
}

impl HostLink {
    fn set(&self, host: *const KHost, frame: *mut c_void) {
        self.host.store(host as usize, Ordering::Relaxed);
        self.frame.store(frame as usize, Ordering::Relaxed);
    }

    /// The host table and the frame, while a host call is in progress.
    fn get(&self) -> Option<(&KHost, *mut c_void)> {
        let host = self.host.load(Ordering::Relaxed) as *const KHost;
        let frame = self.frame.load(Ordering::Relaxed) as *mut c_void;
        // SAFETY: a non-null `host` is the table the host passed for the current call; host tables are
        // static in the host.
        let api = unsafe { host.as_ref() }?;
        Some((api, frame))
    }
}

/// A component's ports and services, reached through the host's function table.
#[derive(Debug)]
struct RemotePorts {
    link: Arc<HostLink>,
    reactive: bool,
}

impl RemotePorts {
    fn receive(code: i32, described: &KSample) -> Result<Sample, ComponentError> {
        status_error(code, || "reading failed in the host".to_owned())?;
        // SAFETY: the host filled `described` with bytes it keeps alive until our next read of this input.
        unsafe { sample_from_c(described) }.map_err(ComponentError::failed)
    }
}

impl HostPorts for RemotePorts {
    fn is_reactive(&self) -> bool {
        self.reactive
    }

    fn read(&self, input: usize, interruptible: bool) -> Result<Sample, ComponentError> {
        let (api, frame) = self.link.get().ok_or(ComponentError::Stopped)?;
        let mut described = KSample::default();
        // SAFETY: frame and out pointer are valid for the call.
        let code = unsafe { (api.read)(frame, input as u32, i32::from(interruptible), &raw mut described) };
        Self::receive(code, &described)
    }

    fn try_read(&self, input: usize) -> Option<Sample> {
        let (api, frame) = self.link.get()?;
        let mut described = KSample::default();
        // SAFETY: frame and out pointer are valid for the call.
        let code = unsafe { (api.try_read)(frame, input as u32, &raw mut described) };
        (code == status::OK)
            .then(|| Self::receive(code, &described).ok())
            .flatten()
    }

    fn wait(&self, interruptible: bool) -> ComponentResult {
        let (api, frame) = self.link.get().ok_or(ComponentError::Stopped)?;
        // SAFETY: the frame is valid for the call.
        let code = unsafe { (api.wait)(frame, i32::from(interruptible)) };
        status_error(code, || "waiting failed in the host".to_owned())
    }

    fn input_state(&self, input: usize) -> InputState {
        let Some((api, frame)) = self.link.get() else {
            return InputState::Unconnected;
        };
        // SAFETY: the frame is valid for the call.
        match unsafe { (api.input_state)(frame, input as u32) } {
            INPUT_CONNECTED => InputState::Connected,
            INPUT_EXHAUSTED => InputState::Exhausted,
            _ => InputState::Unconnected,
        }
    }

    fn write(&self, output: usize, payload: &Payload, timestamp: Option<Timestamp>) -> ComponentResult {
        let (api, frame) = self.link.get().ok_or(ComponentError::Stopped)?;
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
                frame,
                output as u32,
                &raw const described,
                keep_timestamp,
                &raw mut error,
            )
        };
        status_error(code, || {
            String::from_utf8_lossy(buffer.get(..error.len).unwrap_or(&[])).into_owned()
        })
    }

    fn stop_requested(&self) -> bool {
        // SAFETY: the frame is valid for the call.
        self.link
            .get()
            .is_none_or(|(api, frame)| unsafe { (api.stop_requested)(frame) } != 0)
    }

    fn set_period(&self, period: Duration) {
        if let Some((api, frame)) = self.link.get() {
            // SAFETY: the frame is valid for the call.
            unsafe { (api.set_period_ns)(frame, i64::try_from(period.as_nanos()).unwrap_or(i64::MAX)) };
        }
    }

    fn input_counters(&self, input: usize) -> Option<LinkCounters> {
        let (api, frame) = self.link.get()?;
        let mut counters = KLinkCounters::default();
        // SAFETY: frame and out pointer are valid for the call.
        let code = unsafe { (api.input_counters)(frame, input as u32, &raw mut counters) };
        (code == status::OK).then(|| LinkCounters::from(&counters))
    }

    fn set_status(&self, status: &serde_json::Value) {
        if let Some((api, frame)) = self.link.get() {
            let text = status.to_string();
            // SAFETY: the frame and the text are valid for the call; the host copies the text.
            unsafe { (api.set_status)(frame, KStr::new(&text)) };
        }
    }

    fn wait_until(&self, deadline: Timestamp) -> ComponentResult {
        let (api, frame) = self.link.get().ok_or(ComponentError::Stopped)?;
        // SAFETY: the frame is valid for the call.
        if unsafe { (api.wait_until)(frame, deadline.as_nanos()) } != 0 {
            return Ok(());
        }
        if self.stop_requested() {
            Err(ComponentError::Stopped)
        } else {
            Err(ComponentError::Interrupted)
        }
    }

    fn sleep(&self, timeout: Duration) -> ComponentResult {
        let (api, frame) = self.link.get().ok_or(ComponentError::Stopped)?;
        let timeout_ns = i64::try_from(timeout.as_nanos()).unwrap_or(i64::MAX);
        // SAFETY: the frame is valid for the call.
        let code = unsafe { (api.sleep_ns)(frame, timeout_ns) };
        status_error(code, || "sleeping failed in the host".to_owned())
    }
}

/// The runtime clock as seen from a pack: each reading asks the host.
#[derive(Debug)]
struct RemoteClock {
    link: Arc<HostLink>,
    description: String,
}

impl Clock for RemoteClock {
    fn now(&self) -> Timestamp {
        // SAFETY: the frame is valid for the call.
        Timestamp::from_nanos(
            self.link
                .get()
                .map_or(0, |(api, frame)| unsafe { (api.now_ns)(frame) }),
        )
    }

    fn wait_until(&self, deadline: Timestamp, _signal: &RunSignal) -> bool {
        // SAFETY: the frame is valid for the call.
        self.link
            .get()
            .is_some_and(|(api, frame)| unsafe { (api.wait_until)(frame, deadline.as_nanos()) } != 0)
    }

    fn describe(&self) -> String {
        self.description.clone()
    }
}

/// One component instance inside a pack library.
struct PackInstance {
    component: Box<dyn Component>,
    info: &'static ComponentInfo,
    ctx: Option<Context>,
    link: Arc<HostLink>,
    status: StatusSchedule,
}

impl PackInstance {
    /// The context for this call, built at the first call from what the host says of the instance.
    fn context(&mut self, host: *const KHost, frame: *mut c_void) -> &mut Context {
        self.link.set(host, frame);
        let (info, link) = (self.info, &self.link);
        self.ctx.get_or_insert_with(|| {
            let described = instance_info(link);
            let inputs = info
                .inputs
                .iter()
                .enumerate()
                .map(|(index, input)| {
                    let source = described.input_sources.get(index).cloned().flatten();
                    InputPort::remote(input.name.clone(), source)
                })
                .collect();
            let outputs = info
                .outputs
                .iter()
                .map(|o| OutputPort::new(o.name.clone(), None, OutputBuffer::new(o.name.clone(), 1), 1))
                .collect();
            let clock = Arc::new(RemoteClock {
                link: Arc::clone(link),
                description: described.clock,
            });
            let ports = RemotePorts {
                link: Arc::clone(link),
                reactive: info.mode == ExecutionMode::Reactive,
            };
            let mut ctx = Context::new_remote(
                ContextParts {
                    id: described.id,
                    inputs,
                    outputs,
                    properties: BTreeMap::new(),
                    clock,
                    signal: Arc::new(RunSignal::new()),
                },
                Box::new(ports),
            );
            if let Some(text) = described.diagram {
                ctx.set_diagram_text(Arc::from(text));
            }
            ctx
        })
    }

    /// Copies every property's current value from the host.
    fn refresh_properties(&mut self, host: *const KHost, frame: *mut c_void) {
        let names: Vec<&str> = self.info.properties.iter().map(|p| p.name.as_str()).collect();
        let link = Arc::clone(&self.link);
        let ctx = self.context(host, frame);
        for name in names {
            if let Some(value) = property(&link, name) {
                ctx.set_property(name, value);
            }
        }
    }
}

/// What the host says of the instance of the call in progress.
fn instance_info(link: &HostLink) -> InstanceInfo {
    let Some((api, frame)) = link.get() else {
        return InstanceInfo::default();
    };
    // SAFETY: the frame is valid for the call; the host keeps the text for the instance's life.
    let text = unsafe { (api.instance_info)(frame).as_str() }.unwrap_or_default();
    serde_json::from_str(text).unwrap_or_else(|error| InstanceInfo {
        id: format!("(the host's description is unreadable: {error})"),
        ..InstanceInfo::default()
    })
}

/// A property's current value, asked of the host.
fn property(link: &HostLink, name: &str) -> Option<kairos_diagram::Value> {
    let (api, frame) = link.get()?;
    let mut out = KValue {
        kind: 0,
        integer: 0,
        float: 0.0,
        text: KStr::new(""),
    };
    // SAFETY: pointers valid for the call.
    let code = unsafe { (api.property)(frame, KStr::new(name), &raw mut out) };
    // SAFETY: the host's text lives until its next property call; it is copied here.
    (code == status::OK).then(|| unsafe { value_from_c(&out) })
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
            // SAFETY: the host passes a valid error buffer for the call.
            unsafe { write_error(error, &failure.to_string()) };
            error_status(&failure)
        }
        Err(panic) => {
            let message = format!("panicked: {}", crate::panic_message(panic.as_ref()));
            // SAFETY: the host passes a valid error buffer for the call.
            unsafe { write_error(error, &message) };
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
            link: Arc::new(HostLink::default()),
            status: StatusSchedule::default(),
        };
        Box::into_raw(Box::new(instance)).cast::<c_void>()
    })
    .unwrap_or(std::ptr::null_mut())
}

unsafe extern "C" fn pack_destroy(instance: *mut c_void) {
    if !instance.is_null() {
        let _ = catch_unwind(AssertUnwindSafe(|| {
            // SAFETY: `instance` came from `pack_create` and the host destroys it once.
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
    call: impl FnOnce(&mut dyn Component, &mut Context, &mut StatusSchedule) -> ComponentResult,
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
        let PackInstance {
            component,
            ctx,
            status,
            ..
        } = instance;
        let ctx = ctx.as_mut().ok_or_else(|| ComponentError::failed("no context"))?;
        call(component.as_mut(), ctx, status)
    })
}

unsafe extern "C" fn pack_birth(
    instance: *mut c_void,
    frame: *mut c_void,
    host: *const KHost,
    error: *mut KError,
) -> i32 {
    with_instance(instance, frame, host, error, true, |component, ctx, _| {
        component.birth(ctx)
    })
}

unsafe extern "C" fn pack_core(
    instance: *mut c_void,
    frame: *mut c_void,
    host: *const KHost,
    error: *mut KError,
) -> i32 {
    with_instance(instance, frame, host, error, false, |component, ctx, status| {
        ctx.begin_cycle();
        let result = component.core(ctx);
        // The host's read returns Interrupted when the input went quiet after work (or a control
        // request waits): either way the status is published now.
        let went_quiet = result == Err(ComponentError::Interrupted);
        status.after_core(component, ctx, went_quiet, std::time::Instant::now());
        result
    })
}

unsafe extern "C" fn pack_death(
    instance: *mut c_void,
    frame: *mut c_void,
    host: *const KHost,
    error: *mut KError,
) -> i32 {
    with_instance(instance, frame, host, error, false, |component, ctx, status| {
        let result = component.death(ctx);
        status.at_end(component, ctx);
        result
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
    with_instance(instance, frame, host, error, true, |component, ctx, _| {
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
    with_instance(instance, frame, host, error, false, |component, ctx, _| {
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
    for registered in registry.exported() {
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
            create: Some(pack_create),
            destroy: Some(pack_destroy),
            birth: Some(pack_birth),
            core: Some(pack_core),
            death: Some(pack_death),
            property_changed: Some(pack_property_changed),
            action: Some(pack_action),
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
