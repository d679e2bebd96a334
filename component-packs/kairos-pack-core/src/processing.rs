//! Processing: arithmetic, filtering, subsampling, synchronisation, latency measurement.

use std::collections::VecDeque;
use std::time::Duration;

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, PackRegistrar, Payload,
    Sample, Synchronizer, TypeFilter, Value,
};

fn numeric() -> TypeFilter {
    TypeFilter::OneOf(vec![DataType::F64, DataType::I64, DataType::Bool])
}

fn number(sample: &Sample) -> Result<f64, ComponentError> {
    sample.payload.as_f64().ok_or_else(|| {
        ComponentError::failed(format_args!(
            "expected a number, got {}",
            sample.payload.data_type()
        ))
    })
}

/// `core.gain`: multiplies by a gain.
#[derive(Debug, Default)]
pub struct Gain;

impl Gain {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "core.gain",
            "math",
            "Multiplies each sample by a gain, keeping its timestamp",
        )
        .label("Gain")
        .input("in", numeric(), "The signal")
        .output("out", DataType::F64, "gain × in")
        .property(Property::f64("gain", 1.0).live().doc("The factor"))
        .build()
    }
}

impl Component for Gain {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let value = ctx.f64_property("gain")? * number(&sample)?;
        ctx.write_processed("out", &sample, Payload::F64(value))
    }
}

/// `core.add`: the sum of two signals.
#[derive(Debug, Default)]
pub struct Add {
    latest: [Option<f64>; 2],
    synchronizer: Option<Synchronizer>,
}

impl Add {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "core.add",
            "math",
            "a + b: on each new sample with the latest of the other input, or on samples matched by timestamp",
        )
        .label("Add")
        .input("a", numeric(), "First term")
        .input("b", numeric(), "Second term")
        .output("out", DataType::F64, "a + b, stamped with the newer sample's timestamp")
        .property(
            Property::choice("mode", &["latest", "synchronized"], "latest")
                .doc("latest: add to the other input's latest value; synchronized: add samples whose timestamps match"),
        )
        .property(Property::f64("tolerance_ms", 1.0).unit("ms").range(0.0, 60_000.0).doc("synchronized: largest timestamp gap"))
        .build()
    }
}

impl Component for Add {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        if ctx.text_property("mode")? == "synchronized" {
            let tolerance = Duration::from_secs_f64(ctx.f64_property("tolerance_ms")? / 1000.0);
            self.synchronizer = Some(Synchronizer::new(
                Synchronizer::inputs_of(ctx, &["a", "b"])?,
                tolerance,
            ));
        }
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        if let Some(synchronizer) = &mut self.synchronizer {
            let matched = synchronizer.read(ctx)?;
            let (Some(a), Some(b)) = (matched.first(), matched.get(1)) else {
                return Ok(());
            };
            let newer = if a.timestamp >= b.timestamp { a } else { b };
            let sum = number(a)? + number(b)?;
            return ctx.write_processed("out", newer, Payload::F64(sum));
        }
        let (which, sample) = ctx.read_any(&["a", "b"])?;
        if let Some(slot) = self.latest.get_mut(which) {
            *slot = Some(number(&sample)?);
        }
        if let [Some(a), Some(b)] = self.latest {
            ctx.write_processed("out", &sample, Payload::F64(a + b))?;
        }
        Ok(())
    }
}

/// `core.moving_average`: the mean of the last N samples.
#[derive(Debug, Default)]
pub struct MovingAverage {
    window: VecDeque<f64>,
    sum: f64,
}

impl MovingAverage {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "core.moving_average",
            "math",
            "The mean of the last `window` samples",
        )
        .label("Moving average")
        .input("in", numeric(), "The signal")
        .output("out", DataType::F64, "The running mean")
        .property(
            Property::i64("window", 10)
                .unit("samples")
                .int_range(1, 1_000_000)
                .live()
                .doc("Number of samples averaged"),
        )
        .build()
    }
}

impl Component for MovingAverage {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let value = number(&sample)?;
        let size = usize::try_from(ctx.i64_property("window")?).unwrap_or(1).max(1);
        self.window.push_back(value);
        self.sum += value;
        while self.window.len() > size {
            if let Some(old) = self.window.pop_front() {
                self.sum -= old;
            }
        }
        let mean = self.sum / self.window.len() as f64;
        ctx.write_processed("out", &sample, Payload::F64(mean))
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        // Recompute from what is kept so rounding errors from the running sum do not accumulate.
        self.sum = self.window.iter().sum();
        Ok(())
    }
}

/// `core.threshold`: true above a threshold, with hysteresis.
#[derive(Debug, Default)]
pub struct Threshold {
    state: bool,
}

impl Threshold {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "core.threshold",
            "math",
            "true when the input rises above threshold + hysteresis/2, false below threshold − hysteresis/2",
        )
        .label("Threshold")
        .input("in", numeric(), "The signal")
        .output("out", DataType::Bool, "Whether the signal is above the threshold")
        .property(Property::f64("threshold", 0.0).live().doc("The level"))
        .property(
            Property::f64("hysteresis", 0.0)
                .range(0.0, f64::MAX)
                .live()
                .doc("Width of the dead band"),
        )
        .build()
    }
}

impl Component for Threshold {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let value = number(&sample)?;
        let level = ctx.f64_property("threshold")?;
        let half_band = ctx.f64_property("hysteresis")? / 2.0;
        if self.state && value < level - half_band {
            self.state = false;
        } else if !self.state && value > level + half_band {
            self.state = true;
        }
        ctx.write_processed("out", &sample, Payload::Bool(self.state))
    }
}

/// `core.subsampler`: keeps one sample in N.
#[derive(Debug, Default)]
pub struct Subsampler {
    seen: u64,
}

impl Subsampler {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "core.subsampler",
            "flow",
            "Passes one sample in `factor` on, unchanged (payload shared, not copied)",
        )
        .label("Subsampler")
        .input("in", TypeFilter::Any, "Any stream")
        .output_following("out", "in", "Every factor-th sample of the input")
        .property(
            Property::i64("factor", 2)
                .int_range(1, 1_000_000)
                .live()
                .doc("Keep one sample in this many"),
        )
        .build()
    }
}

impl Component for Subsampler {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let factor = u64::try_from(ctx.i64_property("factor")?).unwrap_or(1).max(1);
        let keep = self.seen.is_multiple_of(factor);
        self.seen += 1;
        if keep {
            ctx.forward("out", &sample)?;
        }
        Ok(())
    }
}

/// `core.synchronizer`: matches samples of up to four inputs by timestamp.
#[derive(Debug, Default)]
pub struct SynchronizerComponent {
    synchronizer: Option<Synchronizer>,
    outputs: Vec<&'static str>,
}

const SYNC_INPUTS: [&str; 4] = ["in1", "in2", "in3", "in4"];
const SYNC_OUTPUTS: [&str; 4] = ["out1", "out2", "out3", "out4"];

impl SynchronizerComponent {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        let mut descriptor = Descriptor::new(
            "core.synchronizer",
            "fusion",
            "Matches samples of its connected inputs whose timestamps lie within a tolerance, and writes each matched set",
        )
        .label("Synchronizer");
        for (input, output) in SYNC_INPUTS.iter().zip(SYNC_OUTPUTS) {
            descriptor = descriptor
                .input(
                    input,
                    TypeFilter::Any,
                    "A stream to match (FIFO keeps every candidate)",
                )
                .output_following(output, input, "The matched sample of the same-numbered input");
        }
        descriptor
            .property(
                Property::f64("tolerance_ms", 5.0)
                    .unit("ms")
                    .range(0.0, 60_000.0)
                    .live()
                    .doc("Largest timestamp gap within a matched set"),
            )
            .output(
                "dropped",
                DataType::I64,
                "Running count of samples that found no match",
            )
            .build()
    }
}

impl Component for SynchronizerComponent {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let connected: Vec<usize> = (0..SYNC_INPUTS.len()).filter(|i| ctx.is_connected(*i)).collect();
        self.outputs = connected
            .iter()
            .filter_map(|i| SYNC_OUTPUTS.get(*i).copied())
            .collect();
        let tolerance = Duration::from_secs_f64(ctx.f64_property("tolerance_ms")? / 1000.0);
        self.synchronizer = Some(Synchronizer::new(connected, tolerance));
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let Some(synchronizer) = &mut self.synchronizer else {
            return Err(ComponentError::Stopped);
        };
        if self.outputs.is_empty() {
            return Err(ComponentError::Stopped);
        }
        let dropped_before = synchronizer.dropped();
        let matched = synchronizer.read(ctx)?;
        let dropped = synchronizer.dropped();
        for (output, sample) in self.outputs.iter().zip(&matched) {
            ctx.forward(*output, sample)?;
        }
        if dropped != dropped_before
            && let Some(first) = matched.first()
        {
            ctx.write_processed(
                "dropped",
                first,
                Payload::I64(i64::try_from(dropped).unwrap_or(i64::MAX)),
            )?;
        }
        Ok(())
    }

    fn property_changed(&mut self, name: &str, _value: &Value, ctx: &mut Context) -> ComponentResult {
        if name == "tolerance_ms"
            && let Some(synchronizer) = &mut self.synchronizer
        {
            synchronizer.set_tolerance(Duration::from_secs_f64(
                ctx.f64_property("tolerance_ms")? / 1000.0,
            ));
        }
        Ok(())
    }
}

/// `core.latency_probe`: measures how old samples are when they arrive.
#[derive(Debug, Default)]
pub struct LatencyProbe;

impl LatencyProbe {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "core.latency_probe",
            "monitoring",
            "Measures end-to-end latency (arrival time − timestamp) and passes samples on unchanged",
        )
        .label("Latency probe")
        .input("in", TypeFilter::Any, "Any stream")
        .output_following("out", "in", "The input, passed on")
        .output(
            "latency_ms",
            DataType::F64,
            "Arrival time − timestamp, in milliseconds",
        )
        .output(
            "age_ms",
            DataType::F64,
            "Time of issue − timestamp of the arriving sample, in milliseconds",
        )
        .build()
    }
}

impl Component for LatencyProbe {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let arrival = ctx.now();
        let latency_ms = arrival.nanos_since(sample.timestamp) as f64 / 1e6;
        let age_ms = sample.latency_nanos() as f64 / 1e6;
        ctx.write_processed("latency_ms", &sample, Payload::F64(latency_ms))?;
        ctx.write_processed("age_ms", &sample, Payload::F64(age_ms))?;
        ctx.forward("out", &sample)
    }
}

/// `core.delay`: holds each sample for a while, as a slow algorithm would.
#[derive(Debug, Default)]
pub struct Delay;

impl Delay {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "core.delay",
            "flow",
            "Holds each sample for `delay_ms` before passing it on: stands in for a slow algorithm when sizing buffers",
        )
        .label("Delay")
        .input("in", TypeFilter::Any, "Any stream")
        .output_following("out", "in", "The input, later; timestamps kept")
        .blocking("it holds each sample for delay_ms before passing it on")
        .property(Property::f64("delay_ms", 10.0).unit("ms").range(0.0, 60_000.0).live().doc("Time spent on each sample"))
        .build()
    }
}

impl Component for Delay {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let deadline = ctx
            .now()
            .after(Duration::from_secs_f64(ctx.f64_property("delay_ms")? / 1000.0));
        // Interrupted early only by a stop: then the sample is dropped with the component.
        loop {
            match ctx.wait_until(deadline) {
                Ok(()) => break,
                // A pause or control request is applied after this sample; wait without being woken again.
                Err(ComponentError::Interrupted) => std::thread::sleep(Duration::from_millis(1)),
                Err(other) => return Err(other),
            }
        }
        ctx.forward("out", &sample)
    }
}

/// Registers the processing components.
pub fn register(pack: &mut PackRegistrar<'_>) {
    pack.component::<Gain>(Gain::info())
        .component::<Add>(Add::info())
        .component::<MovingAverage>(MovingAverage::info())
        .component::<Threshold>(Threshold::info())
        .component::<Subsampler>(Subsampler::info())
        .component::<SynchronizerComponent>(SynchronizerComponent::info())
        .component::<LatencyProbe>(LatencyProbe::info())
        .component::<Delay>(Delay::info());
}
