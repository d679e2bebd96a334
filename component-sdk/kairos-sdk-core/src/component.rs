//! The component API: the [`Component`] trait and the [`Context`] a component reads, writes and
//! configures itself through.

use std::collections::BTreeMap;
use std::fmt;
use std::sync::Arc;
use std::time::Duration;

use kairos_diagram::{DataType, Value};

use crate::buffer::{OutputBuffer, ReadError, Reader, WriteError};
use crate::name_key::{NameKey, position_of};
use crate::payload::Payload;
use crate::sample::Sample;
use crate::signal::RunSignal;
use crate::stats::LinkCounters;
use crate::time::{Clock, Timestamp};

/// Why a component call ended without doing its work.
///
/// The first four are flow control, not failures: return them with `?` and the runtime does the right
/// thing (stop, apply a control request, finish, wait for data). [`ComponentError::Failed`] marks the
/// component failed; the rest of the diagram keeps running.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ComponentError {
    /// The runtime is stopping the component.
    #[error("stopped")]
    Stopped,
    /// A pause, property change or action waits; the runtime calls `core` again afterwards.
    #[error("interrupted to apply a control request")]
    Interrupted,
    /// An input's stream ended (in the offline harness, or a finished replay).
    #[error("end of stream")]
    EndOfStream,
    /// Nothing to read now (a reactive component woken for another input).
    #[error("no data")]
    NoData,
    /// The component cannot go on.
    #[error("{0}")]
    Failed(String),
}

impl ComponentError {
    /// A failure with this message.
    pub fn failed(message: impl fmt::Display) -> Self {
        ComponentError::Failed(message.to_string())
    }

    /// Whether this is a failure rather than flow control.
    pub fn is_failure(&self) -> bool {
        matches!(self, ComponentError::Failed(_))
    }
}

impl From<ReadError> for ComponentError {
    fn from(error: ReadError) -> Self {
        match error {
            ReadError::Stopped => ComponentError::Stopped,
            ReadError::Interrupted => ComponentError::Interrupted,
            ReadError::EndOfStream => ComponentError::EndOfStream,
            ReadError::NoData => ComponentError::NoData,
        }
    }
}

impl From<WriteError> for ComponentError {
    fn from(error: WriteError) -> Self {
        match error {
            WriteError::Stopped => ComponentError::Stopped,
            error @ WriteError::ReaderInWritersThread { .. } => ComponentError::failed(error),
        }
    }
}

/// What a component returns.
pub type ComponentResult = Result<(), ComponentError>;

/// A building block of a diagram.
///
/// The runtime calls `birth` once, then `core` repeatedly (threaded: in a loop on the component's own
/// thread, blocking on reads; reactive: once per arriving sample, in the producer's thread; periodic: once
/// per period), then `death` once. Property changes and actions arrive between `core` calls, on the same
/// thread, so a component never needs a lock of its own.
pub trait Component: Send + 'static {
    /// Called once before the first `core`: open devices, read properties, set a period.
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let _ = ctx;
        Ok(())
    }

    /// One cycle of work: read inputs, process, write outputs.
    fn core(&mut self, ctx: &mut Context) -> ComponentResult;

    /// Called once after the last `core`, also after a failure: release what `birth` took.
    fn death(&mut self, ctx: &mut Context) -> ComponentResult {
        let _ = ctx;
        Ok(())
    }

    /// A live property changed; `ctx` already holds the new value. Refuse it by returning an error.
    fn property_changed(&mut self, name: &str, value: &Value, ctx: &mut Context) -> ComponentResult {
        let _ = (name, value, ctx);
        Ok(())
    }

    /// The user triggered the action `name`.
    fn action(&mut self, name: &str, ctx: &mut Context) -> ComponentResult {
        let _ = ctx;
        Err(ComponentError::failed(format_args!("no action named '{name}'")))
    }

    /// What the component wants its users to see about itself (counters, a file and its size), as
    /// JSON. The runtime asks for it and publishes it: at most every [`crate::STATUS_PERIOD`] while the
    /// component works, once when its input goes quiet after work, and after `death`, so what the user
    /// sees covers everything it did. `None` (the default) publishes nothing; a component may instead
    /// call [`Context::set_status`] itself.
    fn status(&self) -> Option<serde_json::Value> {
        None
    }
}

/// When a component's [`Component::status`] is published: one mechanism for every component, so that
/// none has to remember to publish at its end or when its input stops.
#[derive(Debug, Default)]
pub struct StatusSchedule {
    published: crate::Throttle,
}

impl StatusSchedule {
    /// After a `core` call that ended at `now`: publishes when a status period has passed since the
    /// last, or at once when the component's input `went_quiet` (see [`RunSignal::take_quiet`]).
    pub fn after_core(
        &mut self,
        component: &dyn Component,
        ctx: &Context,
        went_quiet: bool,
        now: std::time::Instant,
    ) {
        if went_quiet {
            self.published.reset();
        }
        if self.published.ready_at(crate::STATUS_PERIOD, now) {
            Self::publish(component, ctx);
        }
    }

    /// After `death`: the last word, whatever the period.
    pub fn at_end(&mut self, component: &dyn Component, ctx: &Context) {
        Self::publish(component, ctx);
    }

    fn publish(component: &dyn Component, ctx: &Context) {
        if let Some(status) = component.status() {
            ctx.set_status(status);
        }
    }
}

/// The properties whose names fit a [`NameKey`], by key.
fn keyed(properties: &BTreeMap<String, Value>) -> Vec<(NameKey, Value)> {
    properties
        .iter()
        .map(|(name, value)| (NameKey::of(name), value.clone()))
        .filter(|(key, _)| key.is_whole())
        .collect()
}

/// Names a port either by its index in the descriptor or by its name.
pub trait PortKey: Copy + fmt::Display {
    /// The index among `names`, if any.
    fn index_in<'a>(self, names: impl Iterator<Item = &'a str>) -> Option<usize>;

    /// The name, when the key is one: looked up by the ports' inline keys rather than their heap names.
    fn as_name(&self) -> Option<&str> {
        None
    }
}

impl PortKey for usize {
    fn index_in<'a>(self, names: impl Iterator<Item = &'a str>) -> Option<usize> {
        (self < names.count()).then_some(self)
    }
}

impl PortKey for &str {
    fn index_in<'a>(self, mut names: impl Iterator<Item = &'a str>) -> Option<usize> {
        names.position(|name| name == self)
    }

    fn as_name(&self) -> Option<&str> {
        Some(self)
    }
}

/// An input port as a component sees it.
#[derive(Debug)]
pub struct InputPort {
    name: String,
    key: NameKey,
    /// The output feeding it, as `component.output`.
    source: Option<String>,
    /// In the process that runs the component: the reader of the source's buffer.
    reader: Option<Reader>,
}

impl InputPort {
    /// An input read through `reader`, unconnected without one.
    pub(crate) fn new(name: impl Into<String>, reader: Option<Reader>) -> Self {
        let name = name.into();
        InputPort {
            key: NameKey::of(&name),
            name,
            source: reader.as_ref().map(|r| r.output().to_owned()),
            reader,
        }
    }

    /// An input of a component in a pack library: the host reads it; this side knows its source.
    pub(crate) fn remote(name: impl Into<String>, source: Option<String>) -> Self {
        let name = name.into();
        InputPort {
            key: NameKey::of(&name),
            name,
            source,
            reader: None,
        }
    }

    /// The port's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Whether a connection feeds it.
    pub fn is_connected(&self) -> bool {
        self.source.is_some()
    }

    /// The output that feeds it, as `component.output` (what a recorder names its track), if connected.
    pub fn source(&self) -> Option<&str> {
        self.source.as_deref()
    }

    pub(crate) fn reader(&self) -> Option<&Reader> {
        self.reader.as_ref()
    }
}

/// Whether an input is connected, and whether its stream ended with everything read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum InputState {
    Unconnected,
    Connected,
    Exhausted,
}

/// How a context reaches its ports when its component lives in a pack library: the host's half of the
/// ABI, behind the pack-side shim, so that the context itself never sees the ABI. Each method does what
/// the [`Context`] method of the same name does for a component in the runtime's own process.
pub(crate) trait HostPorts: Send + fmt::Debug {
    fn is_reactive(&self) -> bool;
    fn read(&self, input: usize, interruptible: bool) -> Result<Sample, ComponentError>;
    fn try_read(&self, input: usize) -> Option<Sample>;
    fn wait(&self, interruptible: bool) -> ComponentResult;
    fn input_state(&self, input: usize) -> InputState;
    /// `timestamp` `None` stamps the sample now, in the host; the host sets the time of issue.
    fn write(&self, output: usize, payload: &Payload, timestamp: Option<Timestamp>) -> ComponentResult;
    fn stop_requested(&self) -> bool;
    fn set_period(&self, period: Duration);
    fn input_counters(&self, input: usize) -> Option<LinkCounters>;
    fn set_status(&self, status: &serde_json::Value);
    fn wait_until(&self, deadline: Timestamp) -> ComponentResult;
    fn sleep(&self, timeout: Duration) -> ComponentResult;
}

/// An output port as a component sees it.
#[derive(Debug)]
pub struct OutputPort {
    name: String,
    key: NameKey,
    data_type: Option<DataType>,
    buffer: OutputBuffer,
    subsampling: u64,
    offered: u64,
    sequence: u64,
}

impl OutputPort {
    /// An output writing into `buffer`, keeping one sample in `subsampling`. Writes are checked against
    /// `data_type`; `None` accepts any type (an output that follows an input).
    pub(crate) fn new(
        name: impl Into<String>,
        data_type: Option<DataType>,
        buffer: OutputBuffer,
        subsampling: u32,
    ) -> Self {
        let name = name.into();
        OutputPort {
            key: NameKey::of(&name),
            name,
            data_type,
            buffer,
            subsampling: u64::from(subsampling.max(1)),
            offered: 0,
            sequence: 0,
        }
    }

    /// The port's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The output's buffer.
    pub(crate) fn buffer(&self) -> &OutputBuffer {
        &self.buffer
    }
}

/// Everything the runtime hands a [`Context`] when it builds one.
#[derive(Debug)]
pub struct ContextParts {
    /// The component instance's id.
    pub id: String,
    /// Inputs in descriptor order.
    pub inputs: Vec<InputPort>,
    /// Outputs in descriptor order.
    pub outputs: Vec<OutputPort>,
    /// Every property's current value (defaults filled in).
    pub properties: BTreeMap<String, Value>,
    /// The runtime clock.
    pub clock: Arc<dyn Clock>,
    /// The component's signal.
    pub signal: Arc<RunSignal>,
}

/// A component's view of the runtime: its ports, properties, clock and period.
#[derive(Debug)]
pub struct Context {
    id: String,
    inputs: Vec<InputPort>,
    outputs: Vec<OutputPort>,
    properties: BTreeMap<String, Value>,
    /// The properties whose names fit a [`NameKey`], by key: what a component asks for at every call is
    /// found without following a pointer. Kept equal to `properties`.
    property_keys: Vec<(NameKey, Value)>,
    clock: Arc<dyn Clock>,
    signal: Arc<RunSignal>,
    period: Option<Duration>,
    samples_read_this_cycle: u32,
    any_rotation: usize,
    /// Set in a component loaded from a shared library: ports live in the host, reached through the ABI.
    remote: Option<Box<dyn HostPorts>>,
    /// The diagram this component runs in, as its file text, when the runtime provides it.
    diagram_text: Option<Arc<str>>,
    /// What the component last said about itself (see [`Context::set_status`]).
    status: StatusCell,
}

/// A component's latest self-description, shared between its context and the runtime that reports it.
#[derive(Debug, Clone, Default)]
pub struct StatusCell(Arc<std::sync::Mutex<Option<serde_json::Value>>>);

impl StatusCell {
    /// The latest status, if the component set one.
    pub fn get(&self) -> Option<serde_json::Value> {
        self.0
            .lock()
            .map_or_else(|p| p.into_inner().clone(), |s| s.clone())
    }

    pub(crate) fn set(&self, status: serde_json::Value) {
        match self.0.lock() {
            Ok(mut slot) => *slot = Some(status),
            Err(poisoned) => *poisoned.into_inner() = Some(status),
        }
    }
}

/// A component's published status, written from a thread of its own: for a component whose `core` can
/// block (a put waiting for room in a network queue) while a callback learns what the user must hear of
/// at once (the far end gone). Its fields are merged into the last status the component published.
#[derive(Debug, Clone)]
pub struct StatusWriter(StatusCell);

impl StatusWriter {
    /// Sets `fields` (a JSON object's) in the published status, keeping the others; a component that
    /// published none yet gets `fields` as its status.
    pub fn merge(&self, fields: serde_json::Map<String, serde_json::Value>) {
        let mut slot = match self.0.0.lock() {
            Ok(slot) => slot,
            Err(poisoned) => poisoned.into_inner(),
        };
        match slot.as_mut() {
            Some(serde_json::Value::Object(status)) => status.extend(fields),
            _ => *slot = Some(serde_json::Value::Object(fields)),
        }
    }
}

impl Context {
    /// Builds a context (the runtime and the harness do this).
    pub(crate) fn new(parts: ContextParts) -> Self {
        Context {
            id: parts.id,
            inputs: parts.inputs,
            outputs: parts.outputs,
            property_keys: keyed(&parts.properties),
            properties: parts.properties,
            clock: parts.clock,
            signal: parts.signal,
            period: None,
            samples_read_this_cycle: 0,
            any_rotation: 0,
            remote: None,
            diagram_text: None,
            status: StatusCell::default(),
        }
    }

    /// A context whose ports live in the host across the pack ABI (built by the pack-side shim).
    pub(crate) fn new_remote(parts: ContextParts, remote: Box<dyn HostPorts>) -> Self {
        let mut ctx = Self::new(parts);
        ctx.remote = Some(remote);
        ctx
    }

    fn is_reactive(&self) -> bool {
        self.remote
            .as_ref()
            .map_or_else(|| self.signal.is_reactive(), |remote| remote.is_reactive())
    }

    /// Takes the next sample of input `index` without blocking.
    fn take_index(&mut self, index: usize) -> Option<Sample> {
        let sample = match &self.remote {
            Some(remote) => remote.try_read(index),
            None => self
                .inputs
                .get_mut(index)
                .and_then(|p| p.reader.as_mut())
                .and_then(Reader::try_read),
        };
        if sample.is_some() {
            self.samples_read_this_cycle += 1;
        }
        sample
    }

    fn input_connected(&self, index: usize) -> bool {
        self.inputs.get(index).is_some_and(InputPort::is_connected)
    }

    fn input_exhausted(&self, index: usize) -> bool {
        match &self.remote {
            Some(remote) => remote.input_state(index) == InputState::Exhausted,
            None => self
                .inputs
                .get(index)
                .and_then(InputPort::reader)
                .is_some_and(Reader::is_exhausted),
        }
    }

    /// Publishes what the component wants its users to see about it (a player's position and duration, a
    /// recorder's file and size), as JSON; the runtime sends the latest with its telemetry and the studio
    /// shows it. Cheap, but meant for a few updates a second, not one per sample.
    pub fn set_status(&self, status: serde_json::Value) {
        match &self.remote {
            Some(remote) => remote.set_status(&status),
            None => self.status.set(status),
        }
    }

    /// Publishes `component`'s [`Component::status`] now, outside its period: for what the user must
    /// hear of at once (a port lost or back).
    pub fn publish_status(&self, component: &dyn Component) {
        if let Some(status) = component.status() {
            self.set_status(status);
        }
    }

    /// A handle to write this component's status from another thread (see [`StatusWriter`]); `None` for
    /// a component loaded from a shared library, whose status crosses the pack ABI only from its own
    /// calls.
    pub fn status_writer(&self) -> Option<StatusWriter> {
        self.remote.is_none().then(|| StatusWriter(self.status.clone()))
    }

    /// The cell the runtime reads the status from.
    pub(crate) fn status_cell(&self) -> StatusCell {
        self.status.clone()
    }

    /// The component instance's id in the diagram.
    pub fn id(&self) -> &str {
        &self.id
    }

    /// The text of the diagram the component runs in (what a recorder stores with its data), if known.
    pub fn diagram_text(&self) -> Option<&Arc<str>> {
        self.diagram_text.as_ref()
    }

    /// Gives the component the text of its diagram (the runtime does this).
    pub(crate) fn set_diagram_text(&mut self, text: Arc<str>) {
        self.diagram_text = Some(text);
    }

    /// The current time on the runtime clock.
    pub fn now(&self) -> Timestamp {
        self.clock.now()
    }

    /// What the runtime clock is, in one line (`real time, epoch …`), for logs and recordings.
    pub fn clock_description(&self) -> String {
        self.clock.describe()
    }

    /// Where the runtime clock stands when something disciplines it (a clock master, a GNSS receiver):
    /// its source, state and error; `None` for the machine's own clock.
    pub fn clock_status(&self) -> Option<crate::disciplined::ClockStatus> {
        self.clock.status()
    }

    /// For a time source (a GNSS receiver): at `measured_at` on the runtime clock (when the data arrived),
    /// the true time was `reference`. When the diagram makes this component its clock source, the runtime
    /// clock follows these references; otherwise they are ignored. Returns whether the clock took it.
    pub fn clock_reference(&self, measured_at: Timestamp, reference: Timestamp) -> bool {
        self.clock.take_reference(&self.id, measured_at, reference)
    }

    /// Sleeps until `deadline` on the runtime clock. A stop cuts the sleep short with
    /// [`ComponentError::Stopped`], a pause, property change or action with
    /// [`ComponentError::Interrupted`]: return either from `core` with `?`.
    pub fn wait_until(&self, deadline: Timestamp) -> ComponentResult {
        if let Some(remote) = &self.remote {
            return remote.wait_until(deadline);
        }
        if self.clock.wait_until(deadline, &self.signal) {
            return Ok(());
        }
        self.attention()?;
        Err(ComponentError::Interrupted)
    }

    /// Sleeps for `timeout` of real time (whatever the clock: a paused replay waiting for the user), or
    /// less when woken; ends with [`ComponentError::Stopped`] or [`ComponentError::Interrupted`] as
    /// [`Context::wait_until`] does when a stop or a control request is waiting.
    pub fn sleep(&self, timeout: Duration) -> ComponentResult {
        if let Some(remote) = &self.remote {
            return remote.sleep(timeout);
        }
        self.attention()?;
        self.signal.park_timeout(timeout);
        self.attention()
    }

    /// `Err` when a stop or a control request waits for the component.
    fn attention(&self) -> ComponentResult {
        if self.signal.stop_requested() {
            Err(ComponentError::Stopped)
        } else if self.signal.wants_attention() {
            Err(ComponentError::Interrupted)
        } else {
            Ok(())
        }
    }

    /// The runtime clock.
    pub(crate) fn clock(&self) -> &Arc<dyn Clock> {
        &self.clock
    }

    /// The component's signal (stop, pause, control, wake-ups).
    pub(crate) fn signal(&self) -> &Arc<RunSignal> {
        &self.signal
    }

    /// Whether the runtime asked the component to stop; long loops inside `core` should check it.
    pub fn stop_requested(&self) -> bool {
        if let Some(remote) = &self.remote {
            return remote.stop_requested();
        }
        self.signal.stop_requested()
    }

    // ----- properties -----

    /// A property's current value.
    pub fn property(&self, name: &str) -> Option<&Value> {
        let key = NameKey::of(name);
        if key.is_whole() {
            self.property_keys
                .iter()
                .find(|(candidate, _)| *candidate == key)
                .map(|(_, value)| value)
        } else {
            self.properties.get(name)
        }
    }

    /// Every property's current value.
    pub fn properties(&self) -> &BTreeMap<String, Value> {
        &self.properties
    }

    /// Replaces a property's value (the runtime does this before calling `property_changed`).
    pub(crate) fn set_property(&mut self, name: &str, value: Value) -> Option<Value> {
        let before = self.properties.insert(name.to_owned(), value);
        self.property_keys = keyed(&self.properties);
        before
    }

    fn typed<T>(
        &self,
        name: &str,
        get: impl Fn(&Value) -> Option<T>,
        kind: &str,
    ) -> Result<T, ComponentError> {
        let value = self
            .property(name)
            .ok_or_else(|| ComponentError::failed(format_args!("no property '{name}'")))?;
        get(value)
            .ok_or_else(|| ComponentError::failed(format_args!("property '{name}' is not {kind}: {value}")))
    }

    /// A float property (integers are converted).
    pub fn f64_property(&self, name: &str) -> Result<f64, ComponentError> {
        self.typed(name, Value::as_f64, "a number")
    }

    /// An integer property.
    pub fn i64_property(&self, name: &str) -> Result<i64, ComponentError> {
        self.typed(name, Value::as_i64, "an integer")
    }

    /// A boolean property.
    pub fn bool_property(&self, name: &str) -> Result<bool, ComponentError> {
        self.typed(name, Value::as_bool, "a boolean")
    }

    /// A text, choice or path property.
    pub fn text_property(&self, name: &str) -> Result<String, ComponentError> {
        self.typed(name, |v| v.as_text().map(str::to_owned), "text")
    }

    // ----- timing -----

    /// Sets the period of a periodic component (the runtime calls `core` once per period).
    pub fn set_period(&mut self, period: Duration) {
        let period = period.max(Duration::from_micros(1));
        if let Some(remote) = &self.remote {
            remote.set_period(period);
        }
        self.period = Some(period);
    }

    /// Sets the period from a frequency in hertz (ignored unless finite and positive).
    pub fn set_frequency(&mut self, hertz: f64) {
        if hertz.is_finite() && hertz > 0.0 {
            self.set_period(Duration::from_secs_f64(1.0 / hertz));
        }
    }

    /// The period set by the component, if any.
    pub fn period(&self) -> Option<Duration> {
        self.period
    }

    /// How many samples `core` has read since the cycle began.
    pub fn samples_read_this_cycle(&self) -> u32 {
        self.samples_read_this_cycle
    }

    /// Marks the start of a `core` call (the runtime does this).
    pub(crate) fn begin_cycle(&mut self) {
        self.samples_read_this_cycle = 0;
    }

    // ----- inputs -----

    fn input_index(&self, key: impl PortKey) -> Result<usize, ComponentError> {
        let found = match key.as_name() {
            Some(name) => position_of(name, self.inputs.iter().map(|p| (p.key, p.name.as_str()))),
            None => key.index_in(self.inputs.iter().map(InputPort::name)),
        };
        found.ok_or_else(|| ComponentError::failed(format_args!("component has no input '{key}'")))
    }

    /// The input ports.
    pub fn inputs(&self) -> &[InputPort] {
        &self.inputs
    }

    /// Whether the input is connected.
    pub fn is_connected(&self, input: impl PortKey) -> bool {
        self.input_index(input).is_ok_and(|i| self.input_connected(i))
    }

    /// The counters of the link feeding `input` (written, read, skipped, overwritten, queued, latency),
    /// `None` when it is unconnected.
    pub fn input_counters(&self, input: impl PortKey) -> Option<LinkCounters> {
        let index = self.input_index(input).ok()?;
        match &self.remote {
            Some(remote) => remote.input_counters(index),
            None => self.inputs.get(index)?.reader.as_ref().map(Reader::counters),
        }
    }

    /// Reads one sample from `input` under its reader policy, sleeping until one is there.
    ///
    /// In a reactive component this never blocks: with nothing to read it returns
    /// [`ComponentError::NoData`]. An unconnected input waits until the component is stopped.
    pub fn read(&mut self, input: impl PortKey) -> Result<Sample, ComponentError> {
        let index = self.input_index(input)?;
        if self.is_reactive() {
            return self.try_read(index)?.ok_or(ComponentError::NoData);
        }
        let interruptible = self.samples_read_this_cycle == 0;
        if let Some(remote) = &self.remote {
            let sample = remote.read(index, interruptible)?;
            self.samples_read_this_cycle += 1;
            return Ok(sample);
        }
        let Some(reader) = self.inputs.get_mut(index).and_then(|p| p.reader.as_mut()) else {
            self.wait_for_attention(interruptible)?;
            return Err(ComponentError::Stopped);
        };
        let sample = reader.read(interruptible)?;
        self.samples_read_this_cycle += 1;
        Ok(sample)
    }

    /// Whether `input`'s stream ended (its producer finished) and every sample of it was read: a
    /// component polling an input with [`Context::try_read`] finishes on it.
    pub fn input_ended(&self, input: impl PortKey) -> bool {
        self.input_index(input)
            .is_ok_and(|index| self.input_exhausted(index))
    }

    /// Reads one sample from `input` if one is there under its policy, without blocking.
    pub fn try_read(&mut self, input: impl PortKey) -> Result<Option<Sample>, ComponentError> {
        let index = self.input_index(input)?;
        Ok(self.take_index(index))
    }

    /// Reads from whichever of `inputs` has data first ("any-of"); returns the position in `inputs` and
    /// the sample. Inputs are polled in turn starting after the last one served, so none starves.
    pub fn read_any<K: PortKey>(&mut self, inputs: &[K]) -> Result<(usize, Sample), ComponentError> {
        let indices: Vec<usize> = inputs
            .iter()
            .map(|k| self.input_index(*k))
            .collect::<Result<_, _>>()?;
        let count = indices.len();
        loop {
            // Start after the input served last time, so a busy input cannot starve the others.
            for step in 0..count {
                let position = (self.any_rotation + step) % count;
                let Some(index) = indices.get(position) else {
                    continue;
                };
                if let Some(sample) = self.take_index(*index) {
                    self.any_rotation = position + 1;
                    return Ok((position, sample));
                }
            }
            let all_ended = indices
                .iter()
                .all(|i| !self.input_connected(*i) || self.input_exhausted(*i));
            if all_ended && indices.iter().any(|i| self.input_connected(*i)) {
                return Err(ComponentError::EndOfStream);
            }
            if self.is_reactive() {
                return Err(ComponentError::NoData);
            }
            self.wait_for_attention(self.samples_read_this_cycle == 0)?;
        }
    }

    /// Triggered reading: a blocking read of `trigger` (usually FIFO), then the newest sample of each of
    /// `sampled` (usually Sampling inputs), `None` where one has no data yet.
    pub fn read_triggered<K: PortKey>(
        &mut self,
        trigger: K,
        sampled: &[K],
    ) -> Result<(Sample, Vec<Option<Sample>>), ComponentError> {
        let sample = self.read(trigger)?;
        let mut others = Vec::with_capacity(sampled.len());
        for key in sampled {
            others.push(self.try_read(*key)?);
        }
        Ok((sample, others))
    }

    /// Sleeps until woken; returns an error when the component must leave `core`.
    fn wait_for_attention(&self, interruptible: bool) -> Result<(), ComponentError> {
        if let Some(remote) = &self.remote {
            return remote.wait(interruptible);
        }
        if self.signal.stop_requested() {
            return Err(ComponentError::Stopped);
        }
        if interruptible && self.signal.wants_attention() {
            return Err(ComponentError::Interrupted);
        }
        self.signal.park_for_input();
        if self.signal.stop_requested() {
            return Err(ComponentError::Stopped);
        }
        Ok(())
    }

    pub(crate) fn wait_for_data(&self) -> Result<(), ComponentError> {
        if self.is_reactive() {
            return Err(ComponentError::NoData);
        }
        self.wait_for_attention(self.samples_read_this_cycle == 0)
    }

    /// A pack's request to sleep until woken (its own any-of or synchronised reads).
    pub(crate) fn wait_from_pack(&self, interruptible: bool) -> Result<(), ComponentError> {
        // A loaded component may believe it has a thread of its own; run by its group or its producer,
        // it must not sleep there.
        if self.is_reactive() {
            return Err(ComponentError::NoData);
        }
        self.wait_for_attention(interruptible && self.samples_read_this_cycle == 0)
    }

    pub(crate) fn try_read_index(&mut self, index: usize) -> Option<Sample> {
        self.take_index(index)
    }

    pub(crate) fn is_input_exhausted(&self, index: usize) -> bool {
        self.input_exhausted(index)
    }

    pub(crate) fn resolve_input(&self, key: impl PortKey) -> Result<usize, ComponentError> {
        self.input_index(key)
    }

    // ----- outputs -----

    fn output_index(&self, key: impl PortKey) -> Result<usize, ComponentError> {
        let found = match key.as_name() {
            Some(name) => position_of(name, self.outputs.iter().map(|p| (p.key, p.name.as_str()))),
            None => key.index_in(self.outputs.iter().map(OutputPort::name)),
        };
        found.ok_or_else(|| ComponentError::failed(format_args!("component has no output '{key}'")))
    }

    /// The output ports.
    pub fn outputs(&self) -> &[OutputPort] {
        &self.outputs
    }

    /// Writes a new sample stamped now: timestamp and time of issue come from one clock read.
    pub fn write(&mut self, output: impl PortKey, payload: Payload) -> Result<(), ComponentError> {
        self.emit(output, payload, None)
    }

    /// Writes a new sample whose data originated at `timestamp` (a sensor's own acquisition time).
    pub fn write_at(
        &mut self,
        output: impl PortKey,
        payload: Payload,
        timestamp: Timestamp,
    ) -> Result<(), ComponentError> {
        self.emit(output, payload, Some(timestamp))
    }

    /// Writes the result of processing `input`: it keeps the input's timestamp.
    pub fn write_processed(
        &mut self,
        output: impl PortKey,
        input: &Sample,
        payload: Payload,
    ) -> Result<(), ComponentError> {
        self.emit(output, payload, Some(input.timestamp))
    }

    /// Writes one of the samples that came of one event (a sentence, a CAN frame): stamped `timestamp`,
    /// issued at `issued`, a time read once with [`Context::now`] for them all. Each other write reads
    /// the clock itself (about 20 ns), which is most of a write's cost where one event gives many samples.
    pub fn write_issued(
        &mut self,
        output: impl PortKey,
        payload: Payload,
        timestamp: Timestamp,
        issued: Timestamp,
    ) -> Result<(), ComponentError> {
        self.emit_with_times(output, payload, Some(timestamp), Some(issued))
    }

    /// Passes `sample` on unchanged but for its time of issue; the payload is shared, not copied.
    pub fn forward(&mut self, output: impl PortKey, sample: &Sample) -> Result<(), ComponentError> {
        self.write_processed(output, sample, sample.payload.clone())
    }

    /// Writes a sample with both of its times given: a replayed recording's samples, exactly as recorded.
    ///
    /// In a component of a loaded pack the host stamps the time of issue itself (ABI version 1 carries
    /// only the timestamp).
    pub fn write_replayed(
        &mut self,
        output: impl PortKey,
        payload: Payload,
        timestamp: Timestamp,
        time_of_issue: Timestamp,
    ) -> Result<(), ComponentError> {
        self.emit_with_times(output, payload, Some(timestamp), Some(time_of_issue))
    }

    /// Writes `payload` on `output`; `timestamp` `None` stamps it now. One clock read gives the time of
    /// issue (and the timestamp when none is given).
    fn emit(
        &mut self,
        output: impl PortKey,
        payload: Payload,
        timestamp: Option<Timestamp>,
    ) -> Result<(), ComponentError> {
        self.emit_with_times(output, payload, timestamp, None)
    }

    fn emit_with_times(
        &mut self,
        output: impl PortKey,
        payload: Payload,
        timestamp: Option<Timestamp>,
        time_of_issue: Option<Timestamp>,
    ) -> Result<(), ComponentError> {
        let index = self.output_index(output)?;
        if let Some(remote) = &self.remote {
            // The host stamps: one clock read there, none here.
            return remote.write(index, &payload, timestamp);
        }
        let time_of_issue = time_of_issue.unwrap_or_else(|| self.clock.now());
        let timestamp = timestamp.unwrap_or(time_of_issue);
        let Some(port) = self.outputs.get_mut(index) else {
            return Err(ComponentError::failed(format_args!(
                "component has no output '{output}'"
            )));
        };
        if let Some(data_type) = &port.data_type
            && !payload.is_of(data_type)
        {
            return Err(ComponentError::failed(format_args!(
                "wrote {} on output '{}' of type {data_type}",
                payload.data_type(),
                port.name,
            )));
        }
        // Most outputs keep every sample: no division on their path.
        if port.subsampling > 1 {
            let keep = port.offered % port.subsampling == 0;
            port.offered += 1;
            if !keep {
                return Ok(());
            }
        }
        let sample = Sample {
            payload,
            timestamp,
            time_of_issue,
            sequence: port.sequence,
        };
        port.sequence += 1;
        port.buffer.write(sample, &self.signal)?;
        Ok(())
    }
}

/// Matches samples from several inputs by timestamp, for data fusion.
///
/// Each call returns one sample per input, all with timestamps within `tolerance` of each other. A
/// sample that can no longer be matched (another input is already past it by more than the tolerance)
/// is dropped; `dropped` counts them. Use FIFO or NeverSkipping inputs so no sample is skipped before
/// it can be matched.
#[derive(Debug)]
pub struct Synchronizer {
    inputs: Vec<usize>,
    tolerance_nanos: i64,
    pending: Vec<Option<Sample>>,
    dropped: u64,
}

impl Synchronizer {
    /// A synchroniser over the inputs at these indices.
    pub fn new(inputs: Vec<usize>, tolerance: Duration) -> Self {
        let pending = inputs.iter().map(|_| None).collect();
        Synchronizer {
            inputs,
            tolerance_nanos: i64::try_from(tolerance.as_nanos()).unwrap_or(i64::MAX),
            pending,
            dropped: 0,
        }
    }

    /// Changes the tolerance.
    pub fn set_tolerance(&mut self, tolerance: Duration) {
        self.tolerance_nanos = i64::try_from(tolerance.as_nanos()).unwrap_or(i64::MAX);
    }

    /// How many samples could not be matched and were dropped.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// The next matched set, one sample per input in the order given at construction.
    pub fn read(&mut self, ctx: &mut Context) -> Result<Vec<Sample>, ComponentError> {
        loop {
            if let Some(matched) = self.try_read(ctx)? {
                return Ok(matched);
            }
            ctx.wait_for_data()?;
        }
    }

    /// The next matched set if the inputs hold one now, without waiting; `None` to wait for more data
    /// (a component with something else to wait on as well waits its own way, then calls it again).
    /// [`ComponentError::EndOfStream`] when an input that lacks a sample has ended.
    pub fn try_read(&mut self, ctx: &mut Context) -> Result<Option<Vec<Sample>>, ComponentError> {
        loop {
            let mut missing = false;
            for (slot, index) in self.pending.iter_mut().zip(&self.inputs) {
                if slot.is_none() {
                    *slot = ctx.try_read_index(*index);
                    missing |= slot.is_none();
                }
            }
            if missing {
                let ended = self
                    .inputs
                    .iter()
                    .zip(&self.pending)
                    .any(|(index, slot)| slot.is_none() && ctx.is_input_exhausted(*index));
                return if ended {
                    Err(ComponentError::EndOfStream)
                } else {
                    Ok(None)
                };
            }
            let stamps: Vec<i64> = self
                .pending
                .iter()
                .flatten()
                .map(|s| s.timestamp.as_nanos())
                .collect();
            let (Some(newest), Some(oldest)) = (stamps.iter().max().copied(), stamps.iter().min().copied())
            else {
                continue;
            };
            if newest - oldest <= self.tolerance_nanos {
                return Ok(Some(self.pending.iter_mut().filter_map(Option::take).collect()));
            }
            // Timestamps only grow per input: a sample older than the newest minus the tolerance can
            // never be matched, so drop it and read on.
            for slot in &mut self.pending {
                if slot
                    .as_ref()
                    .is_some_and(|s| newest - s.timestamp.as_nanos() > self.tolerance_nanos)
                {
                    *slot = None;
                    self.dropped += 1;
                }
            }
        }
    }

    /// Resolves input names to indices for [`Synchronizer::new`].
    pub fn inputs_of<K: PortKey>(ctx: &Context, keys: &[K]) -> Result<Vec<usize>, ComponentError> {
        keys.iter().map(|k| ctx.resolve_input(*k)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::{StatusCell, StatusWriter};

    #[test]
    fn a_status_writer_on_another_thread_sets_its_fields_and_keeps_the_component_s() {
        let cell = StatusCell::default();
        let writer = StatusWriter(cell.clone());
        let fields = |value: serde_json::Value| value.as_object().cloned().unwrap();
        // Before the component published anything, the fields are the status.
        writer.merge(fields(serde_json::json!({"matched": true})));
        assert_eq!(cell.get(), Some(serde_json::json!({"matched": true})));
        cell.set(serde_json::json!({"sent": 7, "matched": true}));
        std::thread::Builder::new()
            .name("callback".to_owned())
            .spawn(move || writer.merge(fields(serde_json::json!({"matched": false}))))
            .unwrap()
            .join()
            .unwrap();
        assert_eq!(cell.get(), Some(serde_json::json!({"sent": 7, "matched": false})));
    }
}
