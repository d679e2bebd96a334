//! An offline harness: run one component on scripted input samples and collect what it writes.
//!
//! The harness runs the component in the calling thread on a manual clock. It delivers the scripted
//! samples one at a time, in the order they were pushed, setting the clock to each sample's timestamp,
//! and calls `core` until the component finds nothing more to read. Periodic components run for a
//! number of periods, the clock jumping from tick to tick. Results are exact and repeatable.
//!
//! ```
//! use kairos_sdk::descriptor::Descriptor;
//! use kairos_sdk::harness::Harness;
//! use kairos_sdk::{Component, ComponentResult, Context, DataType, Payload, Timestamp, TypeFilter};
//!
//! struct Double;
//! impl Component for Double {
//!     fn core(&mut self, ctx: &mut Context) -> ComponentResult {
//!         let sample = ctx.read("in")?;
//!         let value = sample.payload.as_f64().unwrap_or_default();
//!         ctx.write_processed("out", &sample, Payload::F64(2.0 * value))
//!     }
//! }
//!
//! let info = Descriptor::new("demo.double", "math", "Doubles")
//!     .input("in", TypeFilter::only(DataType::F64), "")
//!     .output("out", DataType::F64, "")
//!     .build();
//! let mut harness = Harness::new(info, Double);
//! harness.push("in", Payload::F64(1.5), Timestamp::from_millis(10));
//! let out = harness.run().unwrap();
//! assert_eq!(out.f64_values("out"), vec![3.0]);
//! assert_eq!(out.samples("out")[0].timestamp, Timestamp::from_millis(10));
//! ```

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use kairos_diagram::{ComponentInfo, ReaderPolicy, Value, ValueError};

use crate::buffer::{OutputBuffer, Reader, ReaderConfig};
use crate::component::{Component, ComponentError, Context, ContextParts, InputPort, OutputPort};
use crate::payload::Payload;
use crate::sample::Sample;
use crate::signal::RunSignal;
use crate::time::{Clock, ManualClock, Timestamp};

/// Room per scripted input.
const INPUT_CAPACITY: usize = 1024;
/// Room per output: what one `core` call may write before the harness collects it.
const OUTPUT_CAPACITY: usize = 4096;

/// What went wrong in a harness run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum HarnessError {
    /// The component has no property of that name.
    #[error("no property '{0}'")]
    UnknownProperty(String),
    /// The value does not fit the property.
    #[error("property '{name}': {error}")]
    InvalidProperty {
        /// The property.
        name: String,
        /// Why the value was refused.
        error: ValueError,
    },
    /// The component has no input of that name.
    #[error("no input '{0}'")]
    UnknownInput(String),
    /// The component failed (returned an error or panicked).
    #[error("component failed in {stage}: {message}")]
    Failed {
        /// `birth`, `core`, `death`, `property_changed` or `action`.
        stage: &'static str,
        /// The error.
        message: String,
    },
    /// A periodic run was asked of a component that set no period.
    #[error("the component set no period in birth (call ctx.set_period or ctx.set_frequency)")]
    NoPeriod,
}

/// Samples a harness run produced, by output name.
#[derive(Debug, Clone, Default)]
pub struct HarnessOutput {
    outputs: BTreeMap<String, Vec<Sample>>,
}

impl HarnessOutput {
    /// The samples written on `output`, in order.
    pub fn samples(&self, output: &str) -> &[Sample] {
        self.outputs.get(output).map_or(&[], Vec::as_slice)
    }

    /// The float values written on `output` (other payloads are left out).
    pub fn f64_values(&self, output: &str) -> Vec<f64> {
        self.samples(output)
            .iter()
            .filter_map(|s| s.payload.as_f64())
            .collect()
    }

    /// Every output's samples.
    pub fn all(&self) -> &BTreeMap<String, Vec<Sample>> {
        &self.outputs
    }

    /// Adds the samples of `other` after these (to gather several runs).
    pub fn extend(&mut self, other: HarnessOutput) {
        for (name, samples) in other.outputs {
            self.outputs.entry(name).or_default().extend(samples);
        }
    }
}

struct Running {
    ctx: Context,
    input_buffers: Vec<OutputBuffer>,
    collectors: Vec<(String, Reader)>,
    feeder: Arc<RunSignal>,
}

/// Runs one component offline. See the module documentation.
pub struct Harness {
    info: ComponentInfo,
    component: Box<dyn Component>,
    properties: BTreeMap<String, Value>,
    policies: BTreeMap<String, ReaderPolicy>,
    unconnected: BTreeSet<String>,
    pending: Vec<(usize, Sample)>,
    clock: Arc<ManualClock>,
    output_capacity: usize,
    running: Option<Running>,
}

impl std::fmt::Debug for Harness {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Harness")
            .field("type_name", &self.info.type_name)
            .finish_non_exhaustive()
    }
}

fn catch<T>(
    stage: &'static str,
    call: impl FnOnce() -> Result<T, ComponentError>,
) -> Result<T, HarnessError> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(call)) {
        Ok(Ok(value)) => Ok(value),
        Ok(Err(error)) => Err(HarnessError::Failed {
            stage,
            message: error.to_string(),
        }),
        Err(panic) => Err(HarnessError::Failed {
            stage,
            message: format!("panicked: {}", crate::panic_message(panic.as_ref())),
        }),
    }
}

impl Harness {
    /// A harness for `component` described by `info`, with every property at its default.
    pub fn new(info: ComponentInfo, component: impl Component) -> Self {
        Self::boxed(info, Box::new(component))
    }

    /// Like [`Harness::new`] for a boxed component (what a registry's factory makes).
    pub fn boxed(info: ComponentInfo, component: Box<dyn Component>) -> Self {
        let properties = info
            .properties
            .iter()
            .map(|p| (p.name.clone(), p.default.clone()))
            .collect();
        Harness {
            info,
            component,
            properties,
            policies: BTreeMap::new(),
            unconnected: BTreeSet::new(),
            pending: Vec::new(),
            clock: Arc::new(ManualClock::new(Timestamp::ZERO)),
            output_capacity: OUTPUT_CAPACITY,
            running: None,
        }
    }

    /// The component's descriptor.
    pub fn info(&self) -> &ComponentInfo {
        &self.info
    }

    /// Sets a property, checked against its kind. Before the first run it is the initial value; after,
    /// it is a live change delivered through `property_changed`.
    pub fn set_property(&mut self, name: &str, value: impl Into<Value>) -> Result<&mut Self, HarnessError> {
        let property = self
            .info
            .property(name)
            .ok_or_else(|| HarnessError::UnknownProperty(name.to_owned()))?;
        let value = property
            .kind
            .check(&value.into())
            .map_err(|error| HarnessError::InvalidProperty {
                name: name.to_owned(),
                error,
            })?;
        self.properties.insert(name.to_owned(), value.clone());
        if let Some(running) = &mut self.running {
            running.ctx.set_property(name, value.clone());
            let component = &mut self.component;
            let ctx = &mut running.ctx;
            catch("property_changed", || {
                component.property_changed(name, &value, ctx)
            })?;
        }
        Ok(self)
    }

    /// How many samples each output's buffer keeps (4096 unless set; at least 1; set before the first
    /// run). Collected samples stay in the buffer until overwritten, as in a diagram: a benchmark of an
    /// image component keeps a few, so its pixel buffers are recycled through the pool as they are when
    /// it runs in a diagram instead of being made anew each time.
    pub fn set_output_capacity(&mut self, capacity: usize) -> &mut Self {
        self.output_capacity = capacity.max(1);
        self
    }

    /// Leaves `input` unconnected, as in a diagram with no link to it (before the first run): for a
    /// component whose optional input changes what it does.
    pub fn leave_unconnected(&mut self, input: &str) -> &mut Self {
        self.unconnected.insert(input.to_owned());
        self
    }

    /// Reads `input` with `policy` instead of the input's default (before the first run).
    pub fn set_policy(&mut self, input: &str, policy: ReaderPolicy) -> &mut Self {
        self.policies.insert(input.to_owned(), policy);
        self
    }

    /// Scripts a sample on `input` with both times set to `timestamp`.
    pub fn push(&mut self, input: &str, payload: Payload, timestamp: Timestamp) -> &mut Self {
        self.push_sample(input, Sample::new(payload, timestamp))
    }

    /// Scripts a whole sample on `input`. Pushing to an input the component does not have is recorded
    /// and reported by the next run.
    pub fn push_sample(&mut self, input: &str, sample: Sample) -> &mut Self {
        let index = self
            .info
            .inputs
            .iter()
            .position(|i| i.name == input)
            .unwrap_or(usize::MAX);
        if index == usize::MAX {
            self.pending.push((
                usize::MAX,
                Sample::new(Payload::Text(Arc::from(input)), sample.timestamp),
            ));
        } else {
            self.pending.push((index, sample));
        }
        self
    }

    fn start(&mut self) -> Result<(), HarnessError> {
        if self.running.is_some() {
            return Ok(());
        }
        // The harness feeds and drains in the calling thread, so reads must never block: the component's
        // signal is a reactive one whose wake-up does nothing.
        let signal = Arc::new(RunSignal::reactive(|| {}));
        let feeder = Arc::new(RunSignal::new());
        let mut input_buffers = Vec::new();
        let mut inputs = Vec::new();
        for input in &self.info.inputs {
            // Samples arrive one at a time and `core` runs until idle, so only an input the component leaves
            // unread (waiting for a match elsewhere) ever holds many: room for a thousand.
            let buffer = OutputBuffer::new(format!("harness.{}", input.name), INPUT_CAPACITY);
            let policy = self
                .policies
                .get(&input.name)
                .copied()
                .unwrap_or(input.default_policy);
            let reader = buffer.attach(
                ReaderConfig::new(policy, format!("harness -> {}", input.name)),
                Arc::clone(&signal),
            );
            let connected = !self.unconnected.contains(&input.name);
            inputs.push(InputPort::new(input.name.clone(), connected.then_some(reader)));
            input_buffers.push(buffer);
        }
        let mut outputs = Vec::new();
        let mut collectors = Vec::new();
        for output in &self.info.outputs {
            let buffer = OutputBuffer::new(
                format!("{}.{}", self.info.type_name, output.name),
                self.output_capacity,
            );
            let reader = buffer.attach(
                ReaderConfig::new(ReaderPolicy::Fifo, format!("{} -> harness", output.name)),
                Arc::clone(&feeder),
            );
            collectors.push((output.name.clone(), reader));
            outputs.push(OutputPort::new(
                output.name.clone(),
                output.follows_input.is_none().then(|| output.data_type.clone()),
                buffer,
                1,
            ));
        }
        let clock: Arc<dyn Clock> = Arc::clone(&self.clock) as Arc<dyn Clock>;
        let mut ctx = Context::new(ContextParts {
            id: "harness".to_owned(),
            inputs,
            outputs,
            properties: self.properties.clone(),
            clock,
            signal,
        });
        let component = &mut self.component;
        catch("birth", || component.birth(&mut ctx))?;
        self.running = Some(Running {
            ctx,
            input_buffers,
            collectors,
            feeder,
        });
        Ok(())
    }

    fn drain(running: &mut Running) -> HarnessOutput {
        let mut out = HarnessOutput::default();
        for (name, reader) in &mut running.collectors {
            let samples = out.outputs.entry(name.clone()).or_default();
            while let Some(sample) = reader.try_read() {
                samples.push(sample);
            }
        }
        out
    }

    /// Calls `core` until it reads nothing more; a component that reads no input is called once.
    fn cycle_until_idle(component: &mut Box<dyn Component>, ctx: &mut Context) -> Result<(), HarnessError> {
        loop {
            ctx.begin_cycle();
            let result = catch("core", || component.core(ctx));
            match result {
                Ok(()) if ctx.samples_read_this_cycle() > 0 => {}
                Ok(()) => return Ok(()),
                Err(HarnessError::Failed { message, .. })
                    if message == ComponentError::NoData.to_string()
                        || message == ComponentError::EndOfStream.to_string()
                        || message == ComponentError::Stopped.to_string() =>
                {
                    return Ok(());
                }
                Err(error) => return Err(error),
            }
        }
    }

    /// A sample pushed to an input the component does not have is an error of the next run.
    fn refuse_unknown_inputs(&self) -> Result<(), HarnessError> {
        match self.pending.iter().find(|(index, _)| *index == usize::MAX) {
            Some((_, unknown)) => Err(HarnessError::UnknownInput(unknown.payload.to_string())),
            None => Ok(()),
        }
    }

    /// Delivers every sample pushed since the last run, one at a time, and returns what the component
    /// wrote meanwhile.
    pub fn run(&mut self) -> Result<HarnessOutput, HarnessError> {
        self.refuse_unknown_inputs()?;
        self.start()?;
        let Some(running) = self.running.as_mut() else {
            return Ok(HarnessOutput::default());
        };
        let mut out = HarnessOutput::default();
        for (index, sample) in std::mem::take(&mut self.pending) {
            self.clock.set(sample.time_of_issue.max(sample.timestamp));
            if let Some(buffer) = running.input_buffers.get(index) {
                // The feeder never blocks: harness readers are FIFO with room for every scripted sample.
                let _ = buffer.write(sample, &running.feeder);
            }
            Self::cycle_until_idle(&mut self.component, &mut running.ctx)?;
            out.extend(Self::drain(running));
        }
        if running.input_buffers.is_empty() {
            Self::cycle_until_idle(&mut self.component, &mut running.ctx)?;
            out.extend(Self::drain(running));
        }
        Ok(out)
    }

    /// Runs a periodic component (or any component, once per tick) for `cycles` periods from the current
    /// harness time, jumping the clock from tick to tick. Samples pushed meanwhile arrive at their
    /// timestamps: those due by a tick are on the inputs when it comes.
    pub fn run_periodic(&mut self, cycles: usize) -> Result<HarnessOutput, HarnessError> {
        self.refuse_unknown_inputs()?;
        self.start()?;
        let Some(running) = self.running.as_mut() else {
            return Ok(HarnessOutput::default());
        };
        self.pending.sort_by_key(|(_, sample)| sample.timestamp);
        let mut out = HarnessOutput::default();
        for _ in 0..cycles {
            let now = self.clock.now();
            let due = self
                .pending
                .iter()
                .take_while(|(_, sample)| sample.timestamp <= now)
                .count();
            for (index, sample) in self.pending.drain(..due) {
                if let Some(buffer) = running.input_buffers.get(index) {
                    let _ = buffer.write(sample, &running.feeder);
                }
            }
            let period = running.ctx.period().ok_or(HarnessError::NoPeriod)?;
            running.ctx.begin_cycle();
            let component = &mut self.component;
            let ctx = &mut running.ctx;
            catch("core", || component.core(ctx))?;
            out.extend(Self::drain(running));
            self.clock.advance(period);
        }
        Ok(out)
    }

    /// Triggers an action and returns what the component wrote in response.
    pub fn action(&mut self, name: &str) -> Result<HarnessOutput, HarnessError> {
        self.start()?;
        let Some(running) = self.running.as_mut() else {
            return Ok(HarnessOutput::default());
        };
        let component = &mut self.component;
        let ctx = &mut running.ctx;
        catch("action", || component.action(name, ctx))?;
        Ok(Self::drain(running))
    }

    /// The component's status as the runtime would publish it now: what [`Component::status`] says,
    /// or else what it last set with `ctx.set_status`, if anything.
    pub fn status(&self) -> Option<serde_json::Value> {
        self.component.status().or_else(|| {
            self.running
                .as_ref()
                .and_then(|running| running.ctx.status_cell().get())
        })
    }

    /// The harness clock's current time.
    pub fn now(&self) -> Timestamp {
        self.clock.now()
    }

    /// Closes the inputs, lets the component finish, calls `death`, and returns the last outputs.
    pub fn finish(mut self) -> Result<HarnessOutput, HarnessError> {
        let mut out = self.run()?;
        if let Some(mut running) = self.running.take() {
            for buffer in &running.input_buffers {
                buffer.close();
            }
            Self::cycle_until_idle(&mut self.component, &mut running.ctx)?;
            let component = &mut self.component;
            let ctx = &mut running.ctx;
            catch("death", || component.death(ctx))?;
            out.extend(Self::drain(&mut running));
        }
        Ok(out)
    }
}
