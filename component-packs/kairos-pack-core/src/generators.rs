//! Periodic sources: waveforms, a counter, a constant, random numbers, a timer.
//!
//! Each is a [`Generate`] implementation wrapped in [`Generator`], which owns what they share: the `rate`
//! property drives the period, live, and time is measured from the first sample.

use std::f64::consts::TAU;

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::rng::NoiseRng;
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, ExecutionMode,
    PackRegistrar, Payload, Timestamp, Value,
};

/// The sample-rate property every generator has.
fn rate_property(default_hz: f64) -> Property {
    Property::f64("rate", default_hz)
        .unit("Hz")
        .range(0.001, 100_000.0)
        .live()
        .doc("Samples per second (Hz)")
}

fn generator(type_name: &str, doc: &str, default_rate_hz: f64) -> Descriptor {
    Descriptor::new(type_name, "generators", doc)
        .mode(ExecutionMode::Periodic)
        .property(rate_property(default_rate_hz))
}

/// A waveform generator: its output and the properties every wave has.
fn wave(type_name: &str, doc: &str) -> Descriptor {
    generator(type_name, doc, 100.0)
        .output("out", DataType::F64, "The wave")
        .property(
            Property::f64("frequency", 1.0)
                .unit("Hz")
                .range(0.0, 50_000.0)
                .live()
                .doc("Wave frequency (Hz)"),
        )
        .property(
            Property::f64("amplitude", 1.0)
                .live()
                .doc("Peak amplitude (half the peak-to-peak swing)"),
        )
        .property(Property::f64("offset", 0.0).live().doc("Added to every value"))
}

/// What differs between generators: what they write at each tick.
pub trait Generate: Default + Send + 'static {
    /// Called once before the first tick (after the period is set).
    fn start(&mut self, ctx: &mut Context) -> ComponentResult {
        let _ = ctx;
        Ok(())
    }

    /// Writes this tick's samples; `elapsed_secs` counts from the first tick.
    fn tick(&mut self, ctx: &mut Context, elapsed_secs: f64) -> ComponentResult;

    /// Handles an action.
    fn action(&mut self, name: &str) -> ComponentResult {
        Err(ComponentError::failed(format_args!("no action '{name}'")))
    }
}

/// A periodic component around a [`Generate`]: the rate, the period and the time base.
#[derive(Debug, Default)]
pub struct Generator<G> {
    inner: G,
    start: Option<Timestamp>,
}

impl<G: Generate> Component for Generator<G> {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let rate = ctx.f64_property("rate")?;
        ctx.set_frequency(rate);
        self.inner.start(ctx)
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let now = ctx.now();
        let start = *self.start.get_or_insert(now);
        self.inner.tick(ctx, now.nanos_since(start) as f64 * 1e-9)
    }

    fn property_changed(&mut self, name: &str, _value: &Value, ctx: &mut Context) -> ComponentResult {
        if name == "rate" {
            let rate = ctx.f64_property("rate")?;
            ctx.set_frequency(rate);
        }
        Ok(())
    }

    fn action(&mut self, name: &str, _ctx: &mut Context) -> ComponentResult {
        self.inner.action(name)
    }
}

/// `core.sine`: a sine wave.
#[derive(Debug, Default)]
pub struct Sine;

impl Sine {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        wave(
            "core.sine",
            "A sine wave: offset + amplitude × sin(2π × frequency × t + phase)",
        )
        .label("Sine wave")
        .property(
            Property::f64("phase_deg", 0.0)
                .unit("deg")
                .range(-360.0, 360.0)
                .live()
                .doc("Phase at t = 0 (degrees)"),
        )
        .build()
    }
}

impl Generate for Sine {
    fn tick(&mut self, ctx: &mut Context, t: f64) -> ComponentResult {
        let angle = TAU * ctx.f64_property("frequency")? * t + ctx.f64_property("phase_deg")?.to_radians();
        let value = ctx.f64_property("offset")? + ctx.f64_property("amplitude")? * angle.sin();
        ctx.write("out", Payload::F64(value))
    }
}

/// `core.square`: a square wave.
#[derive(Debug, Default)]
pub struct Square;

impl Square {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        wave(
            "core.square",
            "A square wave between offset − amplitude and offset + amplitude",
        )
        .label("Square wave")
        .property(
            Property::f64("duty", 0.5)
                .range(0.0, 1.0)
                .live()
                .doc("Fraction of each period spent high"),
        )
        .build()
    }
}

impl Generate for Square {
    fn tick(&mut self, ctx: &mut Context, t: f64) -> ComponentResult {
        let phase = (ctx.f64_property("frequency")? * t).fract();
        let sign = if phase < ctx.f64_property("duty")? {
            1.0
        } else {
            -1.0
        };
        let value = ctx.f64_property("offset")? + sign * ctx.f64_property("amplitude")?;
        ctx.write("out", Payload::F64(value))
    }
}

/// `core.counter`: counts up by a step.
#[derive(Debug, Default)]
pub struct Counter {
    next: Option<i64>,
}

impl Counter {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        generator(
            "core.counter",
            "Counts: start, start + step, start + 2 × step, ...",
            10.0,
        )
        .label("Counter")
        .output("out", DataType::I64, "The count")
        .property(Property::i64("start", 0).doc("The first value"))
        .property(Property::i64("step", 1).live().doc("Added at each sample"))
        .action("reset", "Starts counting again from `start`")
        .build()
    }
}

impl Generate for Counter {
    fn tick(&mut self, ctx: &mut Context, _t: f64) -> ComponentResult {
        let value = match self.next {
            Some(value) => value,
            None => ctx.i64_property("start")?,
        };
        ctx.write("out", Payload::I64(value))?;
        self.next = Some(value.wrapping_add(ctx.i64_property("step")?));
        Ok(())
    }

    fn action(&mut self, name: &str) -> ComponentResult {
        if name != "reset" {
            return Err(ComponentError::failed(format_args!("no action '{name}' (reset)")));
        }
        self.next = None;
        Ok(())
    }
}

/// `core.constant`: the same value at a fixed rate.
#[derive(Debug, Default)]
pub struct Constant;

impl Constant {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        generator(
            "core.constant",
            "A constant value, repeated at a fixed rate",
            10.0,
        )
        .label("Constant")
        .output("out", DataType::F64, "The value")
        .property(Property::f64("value", 0.0).live().doc("The value written"))
        .build()
    }
}

impl Generate for Constant {
    fn tick(&mut self, ctx: &mut Context, _t: f64) -> ComponentResult {
        let value = ctx.f64_property("value")?;
        ctx.write("out", Payload::F64(value))
    }
}

/// `core.random`: uniform or normal random numbers from a seeded generator.
#[derive(Debug, Default)]
pub struct Random {
    rng: Option<NoiseRng>,
}

impl Random {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        generator(
            "core.random",
            "Random numbers, uniform in (min, max] or normal (mean, std_dev); seeded, so repeatable",
            10.0,
        )
        .label("Random numbers")
        .output("out", DataType::F64, "The numbers")
        .property(
            Property::choice("distribution", &["uniform", "normal"], "uniform")
                .live()
                .doc("The distribution"),
        )
        .property(Property::f64("min", 0.0).live().doc("Uniform: lower bound"))
        .property(Property::f64("max", 1.0).live().doc("Uniform: upper bound"))
        .property(Property::f64("mean", 0.0).live().doc("Normal: mean"))
        .property(
            Property::f64("std_dev", 1.0)
                .range(0.0, f64::MAX)
                .live()
                .doc("Normal: standard deviation"),
        )
        .property(Property::i64("seed", 1).doc("Same seed, same numbers"))
        .build()
    }
}

impl Generate for Random {
    fn start(&mut self, ctx: &mut Context) -> ComponentResult {
        self.rng = Some(NoiseRng::new(ctx.i64_property("seed")?, 0));
        Ok(())
    }

    fn tick(&mut self, ctx: &mut Context, _t: f64) -> ComponentResult {
        let rng = self.rng.get_or_insert_with(|| NoiseRng::new(1, 0));
        let value = if ctx.text_property("distribution")? == "normal" {
            ctx.f64_property("mean")? + ctx.f64_property("std_dev")? * rng.gaussian()
        } else {
            let (min, max) = (ctx.f64_property("min")?, ctx.f64_property("max")?);
            min + (max - min) * rng.uniform()
        };
        ctx.write("out", Payload::F64(value))
    }
}

/// `core.timer`: ticks at a fixed rate, to trigger or resample other components.
#[derive(Debug, Default)]
pub struct Timer {
    ticks: i64,
}

impl Timer {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        generator(
            "core.timer",
            "Ticks at a fixed rate; connect it to a triggered or Sampling reader to resample",
            10.0,
        )
        .label("Timer")
        .output("tick", DataType::I64, "The tick number, from 0")
        .output("elapsed", DataType::F64, "Seconds since the first tick")
        .build()
    }
}

impl Generate for Timer {
    fn tick(&mut self, ctx: &mut Context, t: f64) -> ComponentResult {
        ctx.write("tick", Payload::I64(self.ticks))?;
        ctx.write("elapsed", Payload::F64(t))?;
        self.ticks += 1;
        Ok(())
    }
}

/// Registers the generators.
pub fn register(pack: &mut PackRegistrar<'_>) {
    pack.component::<Generator<Sine>>(Sine::info())
        .component::<Generator<Square>>(Square::info())
        .component::<Generator<Counter>>(Counter::info())
        .component::<Generator<Constant>>(Constant::info())
        .component::<Generator<Random>>(Random::info())
        .component::<Generator<Timer>>(Timer::info());
}

#[cfg(test)]
mod tests {
    use kairos_sdk::harness::Harness;

    use super::*;

    #[test]
    fn a_sine_at_100_hz_samples_its_wave_every_10_ms() {
        let mut harness = Harness::new(Sine::info(), Generator::<Sine>::default());
        harness.set_property("frequency", 25.0).unwrap();
        let out = harness.run_periodic(5).unwrap();
        let values = out.f64_values("out");
        let expected: Vec<f64> = (0..5).map(|i| (TAU * 25.0 * 0.01 * f64::from(i)).sin()).collect();
        for (got, want) in values.iter().zip(&expected) {
            assert!((got - want).abs() < 1e-9, "{values:?} vs {expected:?}");
        }
        let stamps: Vec<i64> = out
            .samples("out")
            .iter()
            .map(|s| s.timestamp.as_nanos())
            .collect();
        assert_eq!(stamps, vec![0, 10_000_000, 20_000_000, 30_000_000, 40_000_000]);
    }

    #[test]
    fn the_counter_counts_and_resets() {
        let mut harness = Harness::new(Counter::info(), Generator::<Counter>::default());
        harness.set_property("step", 3_i64).unwrap();
        let first = harness.run_periodic(3).unwrap();
        harness.action("reset").unwrap();
        let second = harness.run_periodic(2).unwrap();
        let values = |out: &kairos_sdk::harness::HarnessOutput| -> Vec<i64> {
            out.samples("out")
                .iter()
                .filter_map(|s| {
                    if let Payload::I64(v) = s.payload {
                        Some(v)
                    } else {
                        None
                    }
                })
                .collect()
        };
        assert_eq!(values(&first), vec![0, 3, 6]);
        assert_eq!(values(&second), vec![0, 3]);
        assert!(harness.action("explode").is_err());
    }

    #[test]
    fn the_same_seed_gives_the_same_numbers() {
        let run = || {
            let mut harness = Harness::new(Random::info(), Generator::<Random>::default());
            harness.set_property("seed", 42_i64).unwrap();
            harness.run_periodic(20).unwrap().f64_values("out")
        };
        let (a, b) = (run(), run());
        assert_eq!(a, b);
        assert!(a.iter().all(|v| (0.0..=1.0).contains(v)));
        assert!(
            a.windows(2).any(|w| (w[0] - w[1]).abs() > 0.0),
            "the numbers vary"
        );
    }
}
