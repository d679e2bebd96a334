//! The engine: builds a running diagram from a validated one, runs each component, stops them all.

use std::collections::{BTreeMap, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, SyncSender};
use std::sync::{Arc, Mutex, MutexGuard, OnceLock, Weak};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use kairos_diagram::{
    ComponentInfo, Diagram, ExecutionMode, InstanceInfos, ReaderPolicy, ThreadSettings, Value,
};
use kairos_sdk_core::component::StatusSchedule;
use kairos_sdk_core::host::{
    ContextHost as _, ContextParts, OutputBuffer, ReaderConfig, RegistryValidation as _,
};
use kairos_sdk_core::{
    Clock, Component, ComponentError, ComponentResult, Context, Registry, RunSignal, Timestamp,
};

use crate::group::{GroupRun, GroupShared, Member};
use crate::scheduling;
use crate::start_gate::{START_GATE_LIMIT, StartGate};
use crate::stats::{ComponentState, ComponentStats, LinkStats, StatsSnapshot};
use crate::stop_order::{AttachedLink, Drain, StopLayer, stop_layers};

/// Why a diagram could not be built.
#[derive(Debug, thiserror::Error)]
pub enum BuildError {
    /// The diagram did not validate against the library; every problem is listed.
    #[error("the diagram is not valid:\n{}", .0.iter().map(ToString::to_string).collect::<Vec<_>>().join("\n"))]
    Invalid(Vec<kairos_diagram::Diagnostic>),
}

/// Why a control request (property change, action) was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ControlError {
    /// No component has that id.
    #[error("no component '{0}' in the diagram")]
    UnknownComponent(String),
    /// The component has no such property.
    #[error("component '{component}' has no property '{property}'")]
    UnknownProperty {
        /// The component.
        component: String,
        /// The property.
        property: String,
    },
    /// The component has no such action.
    #[error("component '{component}' has no action '{action}'")]
    UnknownAction {
        /// The component.
        component: String,
        /// The action.
        action: String,
    },
    /// The value does not fit the property; the old value stays.
    #[error("property '{property}' of '{component}': {reason}; it keeps its value")]
    InvalidValue {
        /// The component.
        component: String,
        /// The property.
        property: String,
        /// Why.
        reason: String,
    },
    /// The property may not change while the diagram runs.
    #[error("property '{property}' of '{component}' cannot change while running; stop the diagram first")]
    NotLive {
        /// The component.
        component: String,
        /// The property.
        property: String,
    },
    /// The component refused the request or is not running.
    #[error("'{component}' refused: {reason}")]
    Refused {
        /// The component.
        component: String,
        /// Why.
        reason: String,
    },
}

/// Where the engine is in its life.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EngineState {
    /// Built, not started.
    Ready,
    /// Running.
    Running,
    /// Paused.
    Paused,
    /// Stopped; every thread joined.
    Stopped,
}

type Reply = SyncSender<Result<(), ComponentError>>;

enum ControlRequest {
    SetProperty {
        name: String,
        value: Value,
        reply: Reply,
    },
    Action {
        name: String,
        reply: Reply,
    },
}

/// What a component's thread and the engine share.
pub(crate) struct Monitor {
    state: Mutex<ComponentState>,
    pub(crate) cycles: AtomicU64,
    pub(crate) busy_nanos: AtomicU64,
    /// Periodic ticks skipped because the component fell more than a period behind.
    pub(crate) missed_ticks: AtomicU64,
    controls: Mutex<VecDeque<ControlRequest>>,
    status: kairos_sdk_core::host::StatusCell,
}

pub(crate) fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    match mutex.lock() {
        Ok(guard) => guard,
        Err(poisoned) => poisoned.into_inner(),
    }
}

impl Monitor {
    fn new(status: kairos_sdk_core::host::StatusCell) -> Self {
        Monitor {
            state: Mutex::new(ComponentState::Idle),
            cycles: AtomicU64::new(0),
            busy_nanos: AtomicU64::new(0),
            missed_ticks: AtomicU64::new(0),
            controls: Mutex::new(VecDeque::new()),
            status,
        }
    }

    pub(crate) fn set_state(&self, state: ComponentState) {
        *lock(&self.state) = state;
    }

    fn state(&self) -> ComponentState {
        lock(&self.state).clone()
    }

    pub(crate) fn is_failed(&self) -> bool {
        matches!(*lock(&self.state), ComponentState::Failed(_))
    }

    /// Marks the component failed and reports it by id, once.
    pub(crate) fn fail(&self, id: &str, stage: &str, message: &str) {
        let mut current = lock(&self.state);
        if !matches!(*current, ComponentState::Failed(_)) {
            tracing::error!(
                component = id,
                "component '{id}' failed in {stage}: {message}; the rest of the diagram keeps running"
            );
            *current = ComponentState::Failed(format!("{stage}: {message}"));
        }
    }
}

/// Makes a component with its type's factory. A constructor that panics fails that component alone: it
/// is replaced by one whose `birth` reports the panic, so the diagram still builds and the rest runs.
fn construct(id: &str, factory: &kairos_sdk_core::Factory) -> Box<dyn Component> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| factory())) {
        Ok(component) => component,
        Err(panic) => {
            let message = format!(
                "its constructor panicked: {}",
                kairos_sdk_core::panic_message(panic.as_ref())
            );
            tracing::debug!(component = %id, "{message}");
            Box::new(FailedConstruction { message })
        }
    }
}

/// Stands in for a component whose constructor panicked, and fails at birth with the panic's message.
#[derive(Debug)]
struct FailedConstruction {
    message: String,
}

impl Component for FailedConstruction {
    fn birth(&mut self, _ctx: &mut Context) -> ComponentResult {
        Err(ComponentError::Failed(self.message.clone()))
    }

    fn core(&mut self, _ctx: &mut Context) -> ComponentResult {
        Err(ComponentError::Failed(self.message.clone()))
    }
}

/// Runs one lifecycle call, turning a panic into an error so it never leaves the component.
pub(crate) fn guarded(call: impl FnOnce() -> Result<(), ComponentError>) -> Result<(), ComponentError> {
    unwinding(call).unwrap_or_else(|panicked| Err(ComponentError::failed(panicked)))
}

/// A component's code that panicked: the component fails, whichever call it was.
#[derive(Debug, thiserror::Error)]
#[error("panicked: {0}")]
pub(crate) struct Panicked(String);

/// Calls a component's code, telling a panic apart from the error it returned.
fn unwinding(
    call: impl FnOnce() -> Result<(), ComponentError>,
) -> Result<Result<(), ComponentError>, Panicked> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(call))
        .map_err(|panic| Panicked(kairos_sdk_core::panic_message(panic.as_ref())))
}

/// Applies queued property changes and actions on the component's own thread.
pub(crate) fn apply_controls(
    id: &str,
    component: &mut dyn Component,
    ctx: &mut Context,
    monitor: &Monitor,
) -> bool {
    loop {
        let Some(request) = lock(&monitor.controls).pop_front() else {
            return true;
        };
        match request {
            ControlRequest::SetProperty { name, value, reply } => {
                let old = ctx.set_property(&name, value.clone());
                let result = unwinding(|| component.property_changed(&name, &value, ctx));
                if !matches!(result, Ok(Ok(())))
                    && let Some(old) = old
                {
                    ctx.set_property(&name, old);
                }
                if !answer_control(id, "property_changed", result, &reply, monitor) {
                    return false;
                }
            }
            ControlRequest::Action { name, reply } => {
                let result = unwinding(|| component.action(&name, ctx));
                if !answer_control(id, "action", result, &reply, monitor) {
                    return false;
                }
            }
        }
    }
}

/// Answers a control request with its outcome; a panic fails the component too. Returns whether the
/// component may go on.
fn answer_control(
    id: &str,
    call: &str,
    result: Result<Result<(), ComponentError>, Panicked>,
    reply: &Reply,
    monitor: &Monitor,
) -> bool {
    match result {
        Ok(answer) => {
            let _ = reply.try_send(answer);
            true
        }
        Err(panicked) => {
            monitor.fail(id, call, &panicked.to_string());
            let _ = reply.try_send(Err(ComponentError::failed(panicked)));
            false
        }
    }
}

/// How a control call blocks when the component does not answer at once: it calls the function it is
/// given, which blocks. A caller on an asynchronous runtime's thread moves its other tasks aside first;
/// others just call it.
pub type LongWait<'a> = &'a dyn Fn(&mut dyn FnMut());

/// How long a control call waits for the component's answer yielding its core before it blocks. A
/// component waiting for data answers within tens of microseconds once its thread runs, and that thread
/// is often woken onto the caller's core: yielding lets it run there at once, where blocking would cost
/// a wake-up of each thread (measured in BENCHMARKS.md, benchmark 10).
const ANSWER_SPIN: Duration = Duration::from_micros(300);
/// How long `start` waits for the clock source's first reference before starting the rest anyway.
const CLOCK_LOCK_WAIT: Duration = Duration::from_secs(10);

/// How long a stop waits in all for consumers to read what their producers wrote before stopping: long
/// enough for a recorder to take its last frames, short enough that a stuck consumer does not hold the
/// stop a user asked for.
pub const DRAIN_LIMIT: Duration = Duration::from_secs(1);

/// The component's answer: waited for yielding the core for a while, then through `long_wait`, 2 s at
/// most.
fn wait_for_answer(
    answer: &Receiver<Result<(), ComponentError>>,
    long_wait: LongWait<'_>,
) -> Result<Result<(), ComponentError>, RecvTimeoutError> {
    let spinning = Instant::now();
    loop {
        match answer.try_recv() {
            Ok(result) => return Ok(result),
            Err(mpsc::TryRecvError::Disconnected) => return Err(RecvTimeoutError::Disconnected),
            Err(mpsc::TryRecvError::Empty) if spinning.elapsed() < ANSWER_SPIN => std::thread::yield_now(),
            Err(mpsc::TryRecvError::Empty) => break,
        }
    }
    let mut outcome = Err(RecvTimeoutError::Timeout);
    long_wait(&mut || outcome = answer.recv_timeout(Duration::from_secs(2)));
    outcome
}

/// A component that runs without a thread of its own, in the thread of whoever writes to it.
struct ReactiveCell {
    id: String,
    inner: Mutex<(Box<dyn Component>, Context, StatusSchedule)>,
    monitor: Arc<Monitor>,
}

impl ReactiveCell {
    fn on_data(&self) {
        if self.monitor.is_failed() {
            return;
        }
        let started = Instant::now();
        let mut guard = lock(&self.inner);
        let (component, ctx, status) = &mut *guard;
        ctx.begin_cycle();
        let result = guarded(|| component.core(ctx));
        let now = Instant::now();
        status.after_core(component.as_ref(), ctx, false, now);
        drop(guard);
        self.monitor
            .busy_nanos
            .fetch_add(now.duration_since(started).as_nanos() as u64, Ordering::Relaxed);
        match result {
            Ok(()) => {
                self.monitor.cycles.fetch_add(1, Ordering::Relaxed);
            }
            Err(ComponentError::Failed(message)) => self.monitor.fail(&self.id, "core", &message),
            Err(_) => {}
        }
    }
}

enum Driver {
    Threaded {
        mode: ExecutionMode,
        pending: Option<Box<(Box<dyn Component>, Context)>>,
        handle: Option<JoinHandle<()>>,
    },
    Reactive(Arc<ReactiveCell>),
    /// A member of an execution group: the group's thread runs it.
    Grouped(Arc<GroupShared>),
}

struct Slot {
    id: String,
    info: ComponentInfo,
    thread: ThreadSettings,
    signal: Arc<RunSignal>,
    monitor: Arc<Monitor>,
    driver: Driver,
}

/// A component made but not yet started, while `Engine::build` wires its ports.
struct Pending {
    id: String,
    info: ComponentInfo,
    component: Box<dyn Component>,
    signal: Arc<RunSignal>,
    reactive: Option<Arc<OnceLock<Weak<ReactiveCell>>>>,
    group: Option<GroupRole>,
    inputs: Vec<kairos_sdk_core::InputPort>,
    outputs: Vec<kairos_sdk_core::OutputPort>,
    properties: BTreeMap<String, Value>,
    thread: ThreadSettings,
}

/// A component's place in its execution group.
struct GroupRole {
    shared: Arc<GroupShared>,
    ready: Arc<AtomicBool>,
    drives: bool,
}

/// An execution group of the engine: its members until its thread starts, then the thread.
struct GroupSlot {
    shared: Arc<GroupShared>,
    settings: ThreadSettings,
    member_ids: Vec<String>,
    members: Option<Vec<Member>>,
    handle: Option<JoinHandle<()>>,
}

/// A diagram instantiated on a component library: buffers allocated, readers attached, components made.
pub struct Engine {
    clock: Arc<dyn Clock>,
    /// The component the clock follows, started first so the clock can lock before anything else runs.
    clock_source: Option<String>,
    slots: Vec<Slot>,
    groups: Vec<GroupSlot>,
    buffers: Vec<OutputBuffer>,
    policies: BTreeMap<String, ReaderPolicy>,
    /// Producers before consumers: see [`crate::stop_order`].
    stop_layers: Vec<StopLayer>,
    state: EngineState,
    supervisor: Option<(SyncSender<()>, JoinHandle<()>)>,
}

impl std::fmt::Debug for Engine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Engine")
            .field("components", &self.slots.len())
            .field("state", &self.state)
            .finish_non_exhaustive()
    }
}

/// An engine runs a diagram on one machine: a part placed on another host must not run here unnoticed.
fn placed_elsewhere(diagram: &Diagram) -> Vec<kairos_diagram::Diagnostic> {
    diagram
        .components
        .iter()
        .filter_map(|component| {
            let host = component.host.as_ref()?;
            Some(
                kairos_diagram::Diagnostic::error(
                    kairos_diagram::DiagnosticCode::UnknownHost,
                    format!(
                        "'{}' is placed on host '{host}': a runtime runs the part of a diagram that is its own",
                        component.id
                    ),
                )
                .with_suggestion(Some(format!(
                    "`kairos deploy` sends each host its part; or remove `host: \"{host}\"` from '{}' to run it \
                     here",
                    component.id
                ))),
            )
        })
        .collect()
}

/// What building an engine reads from: the diagram, the library and each instance's description.
struct Wiring<'a> {
    diagram: &'a Diagram,
    registry: &'a Registry,
    instances: &'a InstanceInfos,
    /// The connections from each output, by (component, port): looked up once per output, so that a
    /// diagram of ten thousand components builds in linear time.
    from_output: BTreeMap<(&'a str, &'a str), Vec<&'a kairos_diagram::Connection>>,
    /// Each component by id.
    by_id: BTreeMap<&'a str, &'a kairos_diagram::ComponentInstance>,
}

impl Wiring<'_> {
    /// `instance` made, with a buffer for each of its outputs (kept in `buffers` by component and port);
    /// `None` for a type the library lacks (validation has refused it already).
    fn pending(
        &self,
        instance: &kairos_diagram::ComponentInstance,
        buffers: &mut BTreeMap<(String, String), OutputBuffer>,
        groups: &mut BTreeMap<String, Arc<GroupShared>>,
    ) -> Option<Pending> {
        let registered = self.registry.component(&instance.type_name)?;
        let info = match self.instances.get(&instance.id) {
            Some(Ok(described)) => described.clone(),
            _ => registered.info.clone(),
        };
        let group = self.diagram.group_of(instance).map(|name| {
            let shared = groups
                .entry(name.to_owned())
                .or_insert_with(|| Arc::new(GroupShared::new(name)));
            GroupRole {
                shared: Arc::clone(shared),
                ready: Arc::new(AtomicBool::new(false)),
                drives: info.blocking_reason().is_some(),
            }
        });
        let (signal, reactive) = if let Some(role) = &group {
            // The driver waits in its calls like a thread of its own; the others read without waiting.
            let signal = if role.drives {
                let signal = Arc::new(RunSignal::new());
                role.shared.set_driver(&signal);
                signal
            } else {
                Arc::new(role.shared.member_signal(&role.ready))
            };
            (signal, None)
        } else if info.mode == ExecutionMode::Reactive {
            let cell: Arc<OnceLock<Weak<ReactiveCell>>> = Arc::new(OnceLock::new());
            let hook = Arc::clone(&cell);
            let signal = RunSignal::reactive(move || {
                if let Some(cell) = hook.get().and_then(Weak::upgrade) {
                    cell.on_data();
                }
            });
            (Arc::new(signal), Some(cell))
        } else {
            (Arc::new(RunSignal::new()), None)
        };
        let mut outputs = Vec::new();
        for output in &info.outputs {
            let buffer = self.output_buffer(instance, output);
            buffers.insert((instance.id.clone(), output.name.clone()), buffer.clone());
            let subsampling = instance
                .outputs
                .get(&output.name)
                .and_then(|s| s.subsampling)
                .unwrap_or(1);
            let data_type = output.follows_input.is_none().then(|| output.data_type.clone());
            outputs.push(kairos_sdk_core::host::output_port(
                output.name.clone(),
                data_type,
                buffer,
                subsampling,
            ));
        }
        Some(Pending {
            id: instance.id.clone(),
            properties: kairos_diagram::resolved_properties(instance, &info),
            component: construct(&instance.id, &registered.factory),
            info,
            signal,
            reactive,
            group,
            inputs: Vec::new(),
            outputs,
            thread: instance.thread.clone(),
        })
    }

    /// The buffer of `instance`'s `output`: its size, with room for the largest share a connection from it
    /// asks for, and for the newest kept sample of a subsampled reader of the newest (one in N needs N
    /// slots).
    fn output_buffer(
        &self,
        instance: &kairos_diagram::ComponentInstance,
        output: &kairos_diagram::OutputInfo,
    ) -> OutputBuffer {
        let size = instance
            .outputs
            .get(&output.name)
            .and_then(|s| s.buffer_size)
            .unwrap_or(output.default_buffer_size);
        let slots = self
            .from_output
            .get(&(instance.id.as_str(), output.name.as_str()))
            .into_iter()
            .flatten()
            .flat_map(|c| {
                let newest_kept = c.subsampling.filter(|_| self.policy(c).reads_newest());
                [c.buffer_size, newest_kept.map(|n| n as usize)]
            })
            .flatten()
            .fold(size, usize::max);
        let name = output
            .known_as
            .clone()
            .unwrap_or_else(|| format!("{}.{}", instance.id, output.name));
        OutputBuffer::with_slots(name, size, slots)
    }

    fn policy(&self, connection: &kairos_diagram::Connection) -> ReaderPolicy {
        connection.policy.unwrap_or_else(|| {
            let consumer = connection.to.component.as_str();
            let described = match self.instances.get(consumer) {
                Some(Ok(info)) => Some(info),
                _ => self
                    .by_id
                    .get(consumer)
                    .and_then(|c| self.registry.component(&c.type_name))
                    .map(|registered| &registered.info),
            };
            described
                .and_then(|info| info.input(&connection.to.port))
                .map_or(ReaderPolicy::default(), |input| input.default_policy)
        })
    }

    /// Attaches a reader to its producer's buffer for every connection, under the connection's policy, and
    /// gives each pending component its inputs; the policy of each link, by the link's name.
    fn attach_inputs(
        &self,
        buffers: &BTreeMap<(String, String), OutputBuffer>,
        pending: &mut [Pending],
    ) -> Vec<AttachedLink> {
        let mut attached = Vec::new();
        let buffer_index: BTreeMap<&(String, String), usize> = buffers
            .keys()
            .enumerate()
            .map(|(index, key)| (key, index))
            .collect();
        let mut readers: BTreeMap<(String, String), kairos_sdk_core::host::Reader> = BTreeMap::new();
        let pending_index: BTreeMap<String, usize> = pending
            .iter()
            .enumerate()
            .map(|(index, p)| (p.id.clone(), index))
            .collect();
        for connection in &self.diagram.connections {
            let key = (connection.from.component.clone(), connection.from.port.clone());
            let (Some(buffer), Some(&buffer_at)) = (buffers.get(&key), buffer_index.get(&key)) else {
                continue;
            };
            let Some(consumer) = pending_index
                .get(connection.to.component.as_str())
                .and_then(|&index| pending.get(index))
            else {
                continue;
            };
            if consumer.info.input(&connection.to.port).is_none() {
                continue;
            }
            let policy = self.policy(connection);
            // Named by the producer's buffer: an output known by another name (a link from another
            // host, known by the output it comes from) is called by that name, as in the whole diagram.
            let link = format!("{} -> {}", buffer.output(), connection.to);
            let subsampling = connection.subsampling.unwrap_or(1);
            attached.push(AttachedLink {
                producer: connection.from.component.clone(),
                consumer: connection.to.component.clone(),
                buffer: buffer_at,
                link: link.clone(),
                policy,
                subsampling,
            });
            let reader = buffer.attach(
                ReaderConfig {
                    policy,
                    capacity: connection.buffer_size,
                    subsampling,
                    link,
                },
                Arc::clone(&consumer.signal),
            );
            readers.insert(
                (connection.to.component.clone(), connection.to.port.clone()),
                reader,
            );
        }
        for component in pending {
            component.inputs = component
                .info
                .inputs
                .iter()
                .map(|input| {
                    kairos_sdk_core::host::input_port(
                        input.name.clone(),
                        readers.remove(&(component.id.clone(), input.name.clone())),
                    )
                })
                .collect();
        }
        attached
    }
}

impl Pending {
    /// The slot this component runs in: its context built, in its producer's thread when reactive; a
    /// group's member as well, for the group's thread.
    fn into_slot(self, clock: &Arc<dyn Clock>, diagram_text: &Arc<str>) -> (Slot, Option<Member>) {
        let mut ctx = kairos_sdk_core::host::context(ContextParts {
            id: self.id.clone(),
            inputs: self.inputs,
            outputs: self.outputs,
            properties: self.properties,
            clock: Arc::clone(clock),
            signal: Arc::clone(&self.signal),
        });
        ctx.set_diagram_text(Arc::clone(diagram_text));
        let monitor = Arc::new(Monitor::new(ctx.status_cell()));
        if let Some(role) = self.group {
            let member = Member {
                id: self.id.clone(),
                mode: self.info.mode,
                holds_inputs: self.info.holds_inputs,
                drives: role.drives,
                component: self.component,
                ctx,
                signal: Arc::clone(&self.signal),
                monitor: Arc::clone(&monitor),
                ready: role.ready,
                status: StatusSchedule::default(),
                next_tick: None,
                missed: MissedTicks::default(),
                done: false,
            };
            let slot = Slot {
                id: self.id,
                info: self.info,
                thread: self.thread,
                signal: self.signal,
                monitor,
                driver: Driver::Grouped(role.shared),
            };
            return (slot, Some(member));
        }
        let driver = match self.reactive {
            Some(hook) => {
                let cell = Arc::new(ReactiveCell {
                    id: self.id.clone(),
                    inner: Mutex::new((self.component, ctx, StatusSchedule::default())),
                    monitor: Arc::clone(&monitor),
                });
                let _ = hook.set(Arc::downgrade(&cell));
                Driver::Reactive(cell)
            }
            None => Driver::Threaded {
                mode: self.info.mode,
                pending: Some(Box::new((self.component, ctx))),
                handle: None,
            },
        };
        let slot = Slot {
            id: self.id,
            info: self.info,
            thread: self.thread,
            signal: self.signal,
            monitor,
            driver,
        };
        (slot, None)
    }
}

impl Engine {
    /// Validates `diagram` against `registry` and builds it; nothing runs until [`Engine::start`]. One pass
    /// per phase: components with their output buffers, readers attaching inputs to them, then the slots
    /// the components run in.
    pub fn build(
        diagram: &Diagram,
        registry: &Registry,
        clock: Arc<dyn Clock>,
    ) -> Result<Engine, BuildError> {
        let instances = registry.instance_infos(diagram);
        let mut diagnostics =
            kairos_diagram::validate_with(diagram, None, &registry.library_info(), &instances);
        diagnostics.extend(placed_elsewhere(diagram));
        if diagnostics.iter().any(kairos_diagram::Diagnostic::is_error) {
            return Err(BuildError::Invalid(diagnostics));
        }
        let mut from_output: BTreeMap<(&str, &str), Vec<&kairos_diagram::Connection>> = BTreeMap::new();
        for connection in &diagram.connections {
            from_output
                .entry((connection.from.component.as_str(), connection.from.port.as_str()))
                .or_default()
                .push(connection);
        }
        let wiring = Wiring {
            diagram,
            registry,
            instances: &instances,
            from_output,
            by_id: diagram.components.iter().map(|c| (c.id.as_str(), c)).collect(),
        };
        let mut pending: Vec<Pending> = Vec::new();
        let mut buffers: BTreeMap<(String, String), OutputBuffer> = BTreeMap::new();
        let mut group_shares: BTreeMap<String, Arc<GroupShared>> = BTreeMap::new();
        for instance in &diagram.components {
            if let Some(component) = wiring.pending(instance, &mut buffers, &mut group_shares) {
                pending.push(component);
            }
        }
        let attached = wiring.attach_inputs(&buffers, &mut pending);
        let policies = attached
            .iter()
            .map(|link| (link.link.clone(), link.policy))
            .collect();
        let diagram_text: Arc<str> = Arc::from(diagram.to_ron());
        let mut slots = Vec::with_capacity(pending.len());
        let mut members: BTreeMap<String, Member> = BTreeMap::new();
        for component in pending {
            let (slot, member) = component.into_slot(&clock, &diagram_text);
            if let Some(member) = member {
                members.insert(member.id.clone(), member);
            }
            slots.push(slot);
        }
        let groups = group_slots(diagram, group_shares, members);
        let slot_ids: Vec<&str> = slots.iter().map(|slot| slot.id.as_str()).collect();
        let group_of = |slot: usize| match &slots[slot].driver {
            Driver::Grouped(shared) => groups.iter().position(|group| Arc::ptr_eq(&group.shared, shared)),
            _ => None,
        };
        let mut stop_layers = stop_layers(&slot_ids, &group_of, &attached);
        for layer in &mut stop_layers {
            // A reactive consumer reads in its producer's thread, joined before it: it will read no more.
            layer.drains.retain(|drain| {
                let consumer = &slots[drain.consumer];
                !consumer.info.stops_at_once && !matches!(consumer.driver, Driver::Reactive(_))
            });
        }
        Ok(Engine {
            clock,
            clock_source: diagram.clock_source.clone(),
            slots,
            groups,
            buffers: buffers.into_values().collect(),
            policies,
            stop_layers,
            state: EngineState::Ready,
            supervisor: None,
        })
    }

    /// The engine's state.
    pub fn state(&self) -> EngineState {
        self.state
    }

    /// The runtime clock.
    pub fn clock(&self) -> &Arc<dyn Clock> {
        &self.clock
    }

    /// Starts every component: reactive ones are born first (they run inside their producers), then each
    /// threaded and periodic component gets its named thread.
    pub fn start(&mut self) -> std::io::Result<()> {
        if self.state != EngineState::Ready {
            return Ok(());
        }
        for slot in &mut self.slots {
            if let Driver::Reactive(cell) = &slot.driver {
                let mut guard = lock(&cell.inner);
                let (component, ctx, _) = &mut *guard;
                match guarded(|| component.birth(ctx)) {
                    Ok(()) => slot.monitor.set_state(ComponentState::Running),
                    Err(error) => slot.monitor.fail(&slot.id, "birth", &error.to_string()),
                }
            }
        }
        // The clock source first: the clock steps to its time once, before anything else reads it, and
        // only slews from then on.
        let source = self
            .clock_source
            .clone()
            .filter(|_| self.clock.status().is_some());
        if let Some(source) = &source
            && let Some(slot) = self.slots.iter_mut().find(|slot| &slot.id == source)
        {
            if let Driver::Grouped(shared) = &slot.driver {
                let shared = Arc::clone(shared);
                if let Some(group) = self.groups.iter_mut().find(|g| Arc::ptr_eq(&g.shared, &shared)) {
                    Self::spawn_group(group, &self.clock, None)?;
                }
            } else {
                Self::spawn(slot, &self.clock, None)?;
            }
            self.wait_for_clock_lock(source);
        }
        self.clock.forbid_steps();
        // The clock source already runs: it alone cannot wait for the others' births.
        let waiting_groups = self
            .groups
            .iter()
            .filter(|group| group.members.is_some())
            .flat_map(|group| group.member_ids.iter().cloned());
        let gate = Arc::new(StartGate::new(
            self.slots
                .iter()
                .filter(|slot| matches!(&slot.driver, Driver::Threaded { pending: Some(_), .. }))
                .map(|slot| slot.id.clone())
                .chain(waiting_groups),
            START_GATE_LIMIT,
        ));
        let clock = &self.clock;
        let spawned = self
            .groups
            .iter_mut()
            .try_for_each(|group| Self::spawn_group(group, clock, Some(&gate)))
            .and_then(|()| {
                self.slots
                    .iter_mut()
                    .try_for_each(|slot| Self::spawn(slot, clock, Some(&gate)))
            });
        if let Err(error) = spawned {
            self.state = EngineState::Running;
            self.stop();
            return Err(error);
        }
        self.state = EngineState::Running;
        self.start_supervisor();
        Ok(())
    }

    /// Gives a threaded or periodic component not started yet its named thread, which waits at `gate`
    /// after its birth.
    fn spawn(slot: &mut Slot, clock: &Arc<dyn Clock>, gate: Option<&Arc<StartGate>>) -> std::io::Result<()> {
        let Driver::Threaded {
            mode,
            pending,
            handle,
        } = &mut slot.driver
        else {
            return Ok(());
        };
        let Some(boxed) = pending.take() else {
            return Ok(());
        };
        let (component, ctx) = *boxed;
        let worker = Worker {
            id: slot.id.clone(),
            mode: *mode,
            thread: slot.thread.clone(),
            signal: Arc::clone(&slot.signal),
            monitor: Arc::clone(&slot.monitor),
            clock: Arc::clone(clock),
            gate: gate.map(Arc::clone),
        };
        slot.monitor.set_state(ComponentState::Running);
        let spawned = std::thread::Builder::new()
            .name(thread_name(&slot.id))
            .spawn(move || worker.run(component, ctx));
        match spawned {
            Ok(joined) => {
                *handle = Some(joined);
                Ok(())
            }
            Err(error) => {
                slot.monitor
                    .fail(&slot.id, "start", &format!("cannot spawn its thread: {error}"));
                Err(error)
            }
        }
    }

    /// Gives an execution group not started yet its named thread.
    fn spawn_group(
        group: &mut GroupSlot,
        clock: &Arc<dyn Clock>,
        gate: Option<&Arc<StartGate>>,
    ) -> std::io::Result<()> {
        let Some(members) = group.members.take() else {
            return Ok(());
        };
        let run = GroupRun {
            shared: Arc::clone(&group.shared),
            settings: group.settings.clone(),
            members,
            clock: Arc::clone(clock),
            gate: gate.map(Arc::clone),
        };
        let spawned = std::thread::Builder::new()
            .name(thread_name(&format!("g:{}", group.shared.name)))
            .spawn(move || run.run());
        match spawned {
            Ok(joined) => {
                group.handle = Some(joined);
                Ok(())
            }
            Err(error) => {
                tracing::error!(
                    "group '{}' cannot start: cannot spawn its thread: {error}",
                    group.shared.name
                );
                Err(error)
            }
        }
    }

    /// Waits, at most [`CLOCK_LOCK_WAIT`], for the clock source's first reference.
    fn wait_for_clock_lock(&self, source: &str) {
        let started = Instant::now();
        let running = || {
            self.slots
                .iter()
                .find(|slot| slot.id == source)
                .is_some_and(|slot| slot.monitor.state() == ComponentState::Running)
        };
        let referenced = || self.clock.status().filter(|status| status.references > 0);
        let mut still_running = running();
        while started.elapsed() < CLOCK_LOCK_WAIT && still_running && referenced().is_none() {
            std::thread::sleep(Duration::from_millis(10));
            still_running = running();
        }
        // Looked at once more: a source that gives its time and ends within one look (a file replayed
        // fast) has still set the clock.
        if let Some(status) = referenced() {
            tracing::info!(
                "the clock follows '{source}': set to its time ({:+.3} s from the machine's) in {:.1} s",
                status.step_ns as f64 * 1e-9,
                started.elapsed().as_secs_f64()
            );
        } else if still_running {
            tracing::warn!(
                "no time from the clock source '{source}' within {} s: the diagram starts on the machine's \
                 clock, which will only be slewed towards the source's time (at most 1 ms/s); start again \
                 once the source has a fix to set the clock at once",
                CLOCK_LOCK_WAIT.as_secs()
            );
        } else {
            tracing::warn!(
                "the clock source '{source}' stopped before it gave a time: the diagram runs on the machine's \
                 clock (see the source's own messages for why it stopped)"
            );
        }
    }

    /// Warns about overflowing links at most once a second each, naming the link.
    fn start_supervisor(&mut self) {
        let (stop_tx, stop_rx): (SyncSender<()>, Receiver<()>) = mpsc::sync_channel(1);
        let buffers = self.buffers.clone();
        let spawned = std::thread::Builder::new().name("kairos-supervisor".to_owned()).spawn(move || {
            let mut overwritten_before: BTreeMap<Arc<str>, u64> = BTreeMap::new();
            loop {
                match stop_rx.recv_timeout(Duration::from_secs(1)) {
                    Err(RecvTimeoutError::Timeout) => {}
                    Ok(()) | Err(RecvTimeoutError::Disconnected) => return,
                }
                for buffer in &buffers {
                    for (link, counters) in buffer.link_counters() {
                        let before = overwritten_before.insert(Arc::clone(&link), counters.overwritten).unwrap_or(0);
                        let lost = counters.overwritten.saturating_sub(before);
                        if lost > 0 {
                            tracing::warn!(
                                link = &*link,
                                "overflow on link '{link}': {lost} samples overwritten before the reader got them \
                                 ({} in all); the reader is slower than the writer: enlarge buffer_size, subsample, \
                                 or read with LastOrNext",
                                counters.overwritten
                            );
                        }
                    }
                }
            }
        });
        if let Ok(handle) = spawned {
            self.supervisor = Some((stop_tx, handle));
        }
    }

    /// Pauses every component: periodic ones stop ticking, threaded ones stop between cycles.
    pub fn pause(&mut self) {
        if self.state == EngineState::Running {
            for slot in &self.slots {
                slot.signal.set_paused(true);
                if !slot.monitor.is_failed() && matches!(slot.driver, Driver::Reactive(_)) {
                    slot.monitor.set_state(ComponentState::Paused);
                }
            }
            // Simulated time stands still with the diagram.
            self.clock.hold(true);
            self.state = EngineState::Paused;
        }
    }

    /// Resumes after [`Engine::pause`].
    pub fn resume(&mut self) {
        if self.state == EngineState::Paused {
            self.clock.hold(false);
            for slot in &self.slots {
                slot.signal.set_paused(false);
                if !slot.monitor.is_failed() && matches!(slot.driver, Driver::Reactive(_)) {
                    slot.monitor.set_state(ComponentState::Running);
                }
            }
            self.state = EngineState::Running;
        }
    }

    /// Stops the diagram layer by layer, producers first (see [`crate::stop_order`]): each consumer first
    /// reads what its producers wrote before they stopped, for at most [`DRAIN_LIMIT`] in all; every
    /// thread is joined. Safe to call twice.
    pub fn stop(&mut self) {
        if matches!(self.state, EngineState::Stopped | EngineState::Ready) {
            self.state = EngineState::Stopped;
            return;
        }
        // A paused diagram reads nothing: waiting for it to drain would only delay the stop.
        let drain_until = (self.state == EngineState::Running).then(|| Instant::now() + DRAIN_LIMIT);
        let layers = std::mem::take(&mut self.stop_layers);
        for layer in &layers {
            if let Some(deadline) = drain_until {
                self.drain(layer, deadline);
            }
            for &slot in &layer.slots {
                self.slots[slot].signal.request_stop();
            }
            for &slot in &layer.slots {
                let slot = &mut self.slots[slot];
                if let Driver::Threaded { handle, .. } = &mut slot.driver
                    && let Some(handle) = handle.take()
                    && handle.join().is_err()
                {
                    slot.monitor
                        .fail(&slot.id, "thread", "its thread ended abnormally");
                }
            }
            for &group in &layer.groups {
                let group = &mut self.groups[group];
                group.shared.wake();
                if let Some(handle) = group.handle.take()
                    && handle.join().is_err()
                {
                    for slot in self.slots.iter().filter(|s| group.member_ids.contains(&s.id)) {
                        slot.monitor.fail(
                            &slot.id,
                            "thread",
                            &format!("the thread of its group '{}' ended abnormally", group.shared.name),
                        );
                    }
                }
            }
        }
        self.stop_layers = layers;
        for slot in &self.slots {
            if let Driver::Reactive(cell) = &slot.driver {
                let mut guard = lock(&cell.inner);
                let (component, ctx, status) = &mut *guard;
                if let Err(error) = guarded(|| component.death(ctx)) {
                    slot.monitor.fail(&slot.id, "death", &error.to_string());
                }
                status.at_end(component.as_ref(), ctx);
                if !slot.monitor.is_failed() {
                    slot.monitor.set_state(ComponentState::Stopped);
                }
            }
        }
        if let Some((stop, handle)) = self.supervisor.take() {
            let _ = stop.try_send(());
            let _ = handle.join();
        }
        self.state = EngineState::Stopped;
    }

    /// Waits until every link of `layer` that reads each sample has nothing left queued, or its consumer
    /// ended, or `deadline` passed; what is still queued then is said, link by link.
    ///
    /// A consumer asleep waiting for input while samples stay queued for it waits for what its stopped
    /// producers will never write (the partner of a synchronised read, another input first): once that
    /// holds for a few polls in a row, it has read all it can.
    fn drain(&self, layer: &StopLayer, deadline: Instant) {
        const IDLE_POLLS: u32 = 5;
        // Each link with the count queued at the last poll and for how many polls in a row its consumer
        // slept waiting for input with that count unchanged.
        let mut left: Vec<(&Drain, u64, u32)> =
            layer.drains.iter().map(|drain| (drain, u64::MAX, 0)).collect();
        loop {
            left.retain_mut(|(drain, last, idle_polls)| {
                let Some(queued) = self.queued(drain).filter(|queued| *queued >= drain.below) else {
                    return false;
                };
                let waiting = self.slots[drain.consumer].signal.awaits_input();
                *idle_polls = if waiting && queued == *last {
                    *idle_polls + 1
                } else {
                    0
                };
                *last = queued;
                *idle_polls < IDLE_POLLS
            });
            if left.is_empty() {
                return;
            }
            if Instant::now() >= deadline {
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        for (drain, ..) in left {
            let queued = self.queued(drain).unwrap_or(0);
            let consumer = &self.slots[drain.consumer].id;
            tracing::warn!(
                link = drain.link.as_str(),
                "'{consumer}' stopped with {queued} samples unread on link '{}': it did not read them \
                 within {} s of the stop (they stay counted as queued)",
                drain.link,
                DRAIN_LIMIT.as_secs_f64()
            );
        }
    }

    /// How many samples `drain`'s link holds for its consumer; `None` once the consumer ended on its own
    /// (finished, failed, its thread gone): it will read nothing more.
    fn queued(&self, drain: &Drain) -> Option<u64> {
        let slot = &self.slots[drain.consumer];
        let thread_ended =
            matches!(&slot.driver, Driver::Threaded { handle: Some(handle), .. } if handle.is_finished());
        if thread_ended
            || matches!(
                slot.monitor.state(),
                ComponentState::Finished | ComponentState::Failed(_)
            )
        {
            return None;
        }
        self.buffers[drain.buffer]
            .link_counters()
            .into_iter()
            .find(|(link, _)| **link == *drain.link)
            .map(|(_, counters)| counters.queued)
    }

    /// Whether every threaded component has finished or failed on its own (e.g. its stream ended), or the
    /// simulator that keeps the diagram's time has.
    pub fn all_finished(&self) -> bool {
        // A simulation ends with its simulator: what else runs (a constant, a timer) lives in its time.
        let simulation_over = self.clock_source.as_ref().is_some_and(|source| {
            self.slots.iter().any(|slot| {
                &slot.id == source
                    && slot.info.simulated_time
                    && matches!(
                        slot.monitor.state(),
                        ComponentState::Finished | ComponentState::Failed(_)
                    )
            })
        });
        simulation_over
            || self
                .slots
                .iter()
                .filter(|s| matches!(s.driver, Driver::Threaded { .. } | Driver::Grouped(_)))
                .all(|s| {
                    matches!(
                        s.monitor.state(),
                        ComponentState::Finished | ComponentState::Failed(_)
                    )
                })
    }

    /// Changes a property: checked against its kind and range and whether it may change while running,
    /// then applied by the component on its own thread. A refused value keeps the old one.
    pub fn set_property(&self, id: &str, name: &str, value: &Value) -> Result<(), ControlError> {
        self.set_property_waiting(id, name, value, &|wait| wait())
    }

    /// [`Engine::set_property`], blocking through `long_wait` when the component does not answer at once.
    pub fn set_property_waiting(
        &self,
        id: &str,
        name: &str,
        value: &Value,
        long_wait: LongWait<'_>,
    ) -> Result<(), ControlError> {
        let slot = self.slot(id)?;
        let info = slot
            .info
            .property(name)
            .ok_or_else(|| ControlError::UnknownProperty {
                component: id.to_owned(),
                property: name.to_owned(),
            })?;
        let value = info
            .kind
            .check(value)
            .map_err(|error| ControlError::InvalidValue {
                component: id.to_owned(),
                property: name.to_owned(),
                reason: error.to_string(),
            })?;
        if !info.live && self.state != EngineState::Ready {
            return Err(ControlError::NotLive {
                component: id.to_owned(),
                property: name.to_owned(),
            });
        }
        let (reply, answer) = mpsc::sync_channel(1);
        self.deliver(
            slot,
            ControlRequest::SetProperty {
                name: name.to_owned(),
                value,
                reply,
            },
            &answer,
            long_wait,
        )
    }

    /// Triggers an action on a component.
    pub fn trigger_action(&self, id: &str, name: &str) -> Result<(), ControlError> {
        self.trigger_action_waiting(id, name, &|wait| wait())
    }

    /// [`Engine::trigger_action`], blocking through `long_wait` when the component does not answer at once.
    pub fn trigger_action_waiting(
        &self,
        id: &str,
        name: &str,
        long_wait: LongWait<'_>,
    ) -> Result<(), ControlError> {
        let slot = self.slot(id)?;
        if slot.info.action(name).is_none() {
            return Err(ControlError::UnknownAction {
                component: id.to_owned(),
                action: name.to_owned(),
            });
        }
        let (reply, answer) = mpsc::sync_channel(1);
        self.deliver(
            slot,
            ControlRequest::Action {
                name: name.to_owned(),
                reply,
            },
            &answer,
            long_wait,
        )
    }

    fn slot(&self, id: &str) -> Result<&Slot, ControlError> {
        self.slots
            .iter()
            .find(|s| s.id == id)
            .ok_or_else(|| ControlError::UnknownComponent(id.to_owned()))
    }

    fn deliver(
        &self,
        slot: &Slot,
        request: ControlRequest,
        answer: &Receiver<Result<(), ComponentError>>,
        long_wait: LongWait<'_>,
    ) -> Result<(), ControlError> {
        let refused = |reason: String| ControlError::Refused {
            component: slot.id.clone(),
            reason,
        };
        match slot.monitor.state() {
            ComponentState::Failed(_) => return Err(refused("the component has failed".to_owned())),
            // Its thread is gone: nothing would ever answer.
            ComponentState::Finished => {
                return Err(refused(
                    "the component has finished (its input streams ended)".to_owned(),
                ));
            }
            ComponentState::Stopped if self.state == EngineState::Running => {
                return Err(refused(
                    "the component has stopped (an input it reads is not connected?)".to_owned(),
                ));
            }
            _ => {}
        }
        match &slot.driver {
            Driver::Reactive(cell) => {
                lock(&slot.monitor.controls).push_back(request);
                let mut guard = lock(&cell.inner);
                let (component, ctx, _) = &mut *guard;
                apply_controls(&slot.id, component.as_mut(), ctx, &slot.monitor);
            }
            Driver::Threaded { .. } | Driver::Grouped(_) if self.state == EngineState::Ready => {
                // Not started: the request waits in the queue and applies right after birth.
                lock(&slot.monitor.controls).push_back(request);
                slot.signal.raise_control();
                return Ok(());
            }
            Driver::Threaded { .. } => {
                if matches!(self.state, EngineState::Stopped) {
                    return Err(refused("the diagram is stopped".to_owned()));
                }
                lock(&slot.monitor.controls).push_back(request);
                slot.signal.raise_control();
            }
            Driver::Grouped(group) => {
                if matches!(self.state, EngineState::Stopped) {
                    return Err(refused("the diagram is stopped".to_owned()));
                }
                lock(&slot.monitor.controls).push_back(request);
                slot.signal.raise_control();
                group.attention();
            }
        }
        match wait_for_answer(answer, long_wait) {
            Ok(Ok(())) => Ok(()),
            Ok(Err(reason)) => Err(refused(reason.to_string())),
            Err(_) => Err(refused(
                "no answer within 2 s (the component is busy in a long cycle); the request stays queued"
                    .to_owned(),
            )),
        }
    }

    /// Statistics of every link and component now (rates are filled in by
    /// [`StatsSnapshot::with_rates_since`]).
    pub fn snapshot(&self) -> StatsSnapshot {
        let mut links = Vec::new();
        for buffer in &self.buffers {
            for (link, counters) in buffer.link_counters() {
                // Only the diagram's own links: extra readers (viewers) report elsewhere.
                let Some(policy) = self.policies.get(&*link).copied() else {
                    continue;
                };
                links.push(LinkStats {
                    link: link.to_string(),
                    policy,
                    counters,
                    rate_hz: 0.0,
                });
            }
        }
        let components = self
            .slots
            .iter()
            .map(|slot| ComponentStats {
                id: slot.id.clone(),
                type_name: slot.info.type_name.clone(),
                state: slot.monitor.state(),
                cycles: slot.monitor.cycles.load(Ordering::Relaxed),
                busy_nanos: slot.monitor.busy_nanos.load(Ordering::Relaxed),
                missed_ticks: slot.monitor.missed_ticks.load(Ordering::Relaxed),
                cycle_rate_hz: 0.0,
                cpu_share: 0.0,
                status: slot.monitor.status.get(),
                group: match &slot.driver {
                    Driver::Grouped(group) => Some(group.name.clone()),
                    _ => None,
                },
            })
            .collect();
        StatsSnapshot {
            at: self.clock.now(),
            links,
            components,
            clock: self.clock.status(),
            groups: self
                .groups
                .iter()
                .map(|group| group.shared.stats(group.member_ids.clone()))
                .collect(),
        }
    }

    /// Every output's name (`component.port`).
    pub fn output_names(&self) -> Vec<String> {
        self.buffers.iter().map(|b| b.output().to_owned()).collect()
    }

    /// The output buffer of `component.output`, to attach extra readers (viewers, recorders).
    pub fn output_buffer(&self, component: &str, output: &str) -> Option<&OutputBuffer> {
        let name = format!("{component}.{output}");
        self.buffers.iter().find(|b| b.output() == name)
    }
}

/// The engine's execution groups, each with its members in the order they run.
fn group_slots(
    diagram: &Diagram,
    shares: BTreeMap<String, Arc<GroupShared>>,
    mut members: BTreeMap<String, Member>,
) -> Vec<GroupSlot> {
    let by_group = diagram.execution_groups();
    shares
        .into_iter()
        .map(|(name, shared)| {
            let ids: Vec<String> = by_group
                .get(name.as_str())
                .into_iter()
                .flatten()
                .filter(|id| members.contains_key(**id))
                .map(|id| (*id).to_owned())
                .collect();
            let holds = |id: &str| members.get(id).is_some_and(|m| m.holds_inputs);
            let member_ids = crate::group::run_order(diagram, &ids, &holds);
            let ordered = member_ids.iter().filter_map(|id| members.remove(id)).collect();
            GroupSlot {
                settings: diagram.groups.get(&name).cloned().unwrap_or_default(),
                shared,
                member_ids,
                members: Some(ordered),
                handle: None,
            }
        })
        .collect()
}

impl Drop for Engine {
    fn drop(&mut self) {
        self.stop();
    }
}

/// Linux limits thread names to 15 bytes; keep the id's end, which is usually the distinctive part.
fn thread_name(id: &str) -> String {
    let name = format!("k:{id}");
    if name.len() <= 15 {
        return name;
    }
    let mut start = name.len() - 15;
    while !name.is_char_boundary(start) {
        start += 1;
    }
    name.get(start..).unwrap_or("kairos").to_owned()
}

/// Everything a component's own thread needs.
struct Worker {
    id: String,
    mode: ExecutionMode,
    thread: ThreadSettings,
    signal: Arc<RunSignal>,
    monitor: Arc<Monitor>,
    clock: Arc<dyn Clock>,
    /// Where the first cycle waits for every other component's birth.
    gate: Option<Arc<StartGate>>,
}

/// Missed periodic ticks not yet said in the log: at most one warning a second per component.
#[derive(Default)]
pub(crate) struct MissedTicks {
    unsaid: u64,
    last_said: Option<Instant>,
}

impl MissedTicks {
    /// `ticks` of `period` skipped by `id`; `place` says where it runs, when that explains the delay
    /// (`in group 'control'; …`), else is empty.
    pub(crate) fn skipped(&mut self, id: &str, ticks: u64, period: Duration, place: &str) {
        self.unsaid += ticks;
        if self
            .last_said
            .is_some_and(|at| at.elapsed() < Duration::from_secs(1))
        {
            return;
        }
        self.last_said = Some(Instant::now());
        tracing::warn!(
            component = id,
            "'{id}' missed {} periodic ticks of {:.1} ms{}{place}: a cycle, or the machine, took longer than \
             its period; the ticks are skipped, not run late (lower its rate or lighten its work)",
            std::mem::take(&mut self.unsaid),
            period.as_secs_f64() * 1e3,
            if place.is_empty() { "" } else { " " },
        );
    }
}

/// How often a component's thread reads its own CPU time.
pub(crate) const CPU_SAMPLE_PERIOD: Duration = Duration::from_millis(50);

impl Worker {
    /// The tick after `tick`. Fallen more than a period behind (a long cycle, a stall), it skips the missed
    /// ticks, rather than run them back to back, and counts them.
    fn next_tick(&self, tick: Timestamp, period: Duration, missed: &mut MissedTicks) -> Timestamp {
        let next = tick.after(period);
        let now = self.clock.now();
        let behind = now.nanos_since(next);
        let period_nanos = period.as_nanos().max(1) as i64;
        if behind <= period_nanos {
            return next;
        }
        let skipped = (behind / period_nanos) as u64;
        self.monitor.missed_ticks.fetch_add(skipped, Ordering::Relaxed);
        missed.skipped(&self.id, skipped, period, "");
        now
    }

    fn run(self, mut component: Box<dyn Component>, mut ctx: Context) {
        self.signal.bind_current_thread();
        scheduling::apply_to_current_thread(&self.id, &self.thread);
        let span = tracing::info_span!("component", id = %self.id);
        let _entered = span.enter();
        let cpu_start = scheduling::thread_cpu_nanos();
        let mut cpu_checked = Instant::now();

        let mut outcome = match guarded(|| component.birth(&mut ctx)) {
            Ok(()) => None,
            Err(error) => {
                self.monitor.fail(&self.id, "birth", &error.to_string());
                Some(ComponentState::Failed(error.to_string()))
            }
        };
        if let Some(gate) = &self.gate {
            if outcome.is_some() {
                gate.arrive(&self.id);
            } else if !gate.arrive_and_wait(&self.id, &self.signal) {
                outcome = Some(ComponentState::Stopped);
            }
        }
        let mut next_tick = self.clock.now();
        let mut missed = MissedTicks::default();
        let mut paused = false;
        let mut status = StatusSchedule::default();
        while outcome.is_none() {
            if self.signal.stop_requested() {
                outcome = Some(ComponentState::Stopped);
                break;
            }
            if self.signal.take_control()
                && !apply_controls(&self.id, component.as_mut(), &mut ctx, &self.monitor)
            {
                outcome = Some(self.monitor.state());
                break;
            }
            if self.signal.is_paused() {
                if !paused {
                    paused = true;
                    self.monitor.set_state(ComponentState::Paused);
                }
                self.signal.park_timeout(Duration::from_millis(100));
                continue;
            }
            if paused {
                paused = false;
                self.monitor.set_state(ComponentState::Running);
                next_tick = self.clock.now();
            }
            let period = if self.mode == ExecutionMode::Periodic {
                let Some(period) = ctx.period() else {
                    self.monitor.fail(
                        &self.id,
                        "birth",
                        "a periodic component must set its period (ctx.set_frequency)",
                    );
                    outcome = Some(self.monitor.state());
                    break;
                };
                if !self.clock.wait_until(next_tick, &self.signal) {
                    continue;
                }
                Some(period)
            } else {
                None
            };
            ctx.begin_cycle();
            let result = guarded(|| component.core(&mut ctx));
            // One clock read a cycle, for the status and the CPU sample both.
            let now = Instant::now();
            status.after_core(component.as_ref(), &ctx, self.signal.take_quiet(), now);
            match result {
                Ok(()) => {
                    self.monitor.cycles.fetch_add(1, Ordering::Relaxed);
                    self.signal.arm_quiet_break();
                }
                Err(ComponentError::Stopped) => outcome = Some(ComponentState::Stopped),
                Err(ComponentError::EndOfStream) => outcome = Some(ComponentState::Finished),
                Err(ComponentError::Interrupted | ComponentError::NoData) => {}
                // A failure, or a kind of error newer than this engine: failed, with what it says.
                Err(failure) => {
                    self.monitor.fail(&self.id, "core", &failure.to_string());
                    outcome = Some(self.monitor.state());
                }
            }
            if let Some(period) = period {
                next_tick = self.next_tick(next_tick, period, &mut missed);
            }
            if now.saturating_duration_since(cpu_checked) >= CPU_SAMPLE_PERIOD {
                cpu_checked = now;
                self.monitor.busy_nanos.store(
                    scheduling::thread_cpu_nanos().saturating_sub(cpu_start),
                    Ordering::Relaxed,
                );
            }
        }
        if let Err(error) = guarded(|| component.death(&mut ctx)) {
            self.monitor.fail(&self.id, "death", &error.to_string());
        }
        status.at_end(component.as_ref(), &ctx);
        if matches!(outcome, Some(ComponentState::Finished)) {
            // Its streams ended: readers drain what is left, then finish in turn.
            for buffer in ctx.output_buffers() {
                buffer.close();
            }
        }
        self.monitor.busy_nanos.store(
            scheduling::thread_cpu_nanos().saturating_sub(cpu_start),
            Ordering::Relaxed,
        );
        if !self.monitor.is_failed() {
            self.monitor.set_state(outcome.unwrap_or(ComponentState::Stopped));
        }
        // Drop the readers now so NeverSkipping writers upstream are released.
        drop(ctx);
    }
}
