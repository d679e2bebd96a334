//! Periodic sources: waveforms, a counter, a constant, random numbers, a timer.

use std::f64::consts::TAU;

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{Component, PackRegistrar};
use kairos_sdk::{ComponentInfo, ComponentResult, Context, DataType, ExecutionMode, Payload, Value};

use kairos_sdk::rng::NoiseRng;

/// The sample-rate property every generator has.
fn rate_property(default_hz: f64) -> Property {
    Property::f64("rate", default_hz)
        .range(0.001, 100_000.0)
        .live()
        .doc("Samples per second (Hz)")
}

fn generator(type_name: &str, doc: &str) -> Descriptor {
    Descriptor::new(type_name, "generators", doc).mode(ExecutionMode::Periodic)
}

/// Re-reads the rate after a change; shared by every generator.
fn follow_rate(name: &str, ctx: &mut Context) -> ComponentResult {
    if name == "rate" {
        let rate = ctx.f64_property("rate")?;
        ctx.set_frequency(rate);
    }
    Ok(())
}

fn elapsed_secs(ctx: &Context, start: Option<kairos_sdk::Timestamp>) -> f64 {
    start.map_or(0.0, |s| ctx.now().nanos_since(s) as f64 * 1e-9)
}

/// `core.sine`: a sine wave.
#[derive(Debug, Default)]
pub struct Sine {
    start: Option<kairos_sdk::Timestamp>,
}

impl Sine {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        generator(
            "core.sine",
            "A sine wave: offset + amplitude × sin(2π × frequency × t + phase)",
        )
        .output("out", DataType::F64, "The wave")
        .property(rate_property(100.0))
        .property(
            Property::f64("frequency", 1.0)
                .range(0.0, 50_000.0)
                .live()
                .doc("Wave frequency (Hz)"),
        )
        .property(Property::f64("amplitude", 1.0).live().doc("Peak amplitude"))
        .property(Property::f64("offset", 0.0).live().doc("Added to every value"))
        .property(
            Property::f64("phase_deg", 0.0)
                .range(-360.0, 360.0)
                .live()
                .doc("Phase at t = 0 (degrees)"),
        )
        .build()
    }
}

impl Component for Sine {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        follow_rate("rate", ctx)
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let now = ctx.now();
        let start = *self.start.get_or_insert(now);
        let t = now.nanos_since(start) as f64 * 1e-9;
        let value = ctx.f64_property("offset")?
            + ctx.f64_property("amplitude")?
                * (TAU * ctx.f64_property("frequency")? * t + ctx.f64_property("phase_deg")?.to_radians())
                    .sin();
        ctx.write("out", Payload::F64(value))
    }

    fn property_changed(&mut self, name: &str, _value: &Value, ctx: &mut Context) -> ComponentResult {
        follow_rate(name, ctx)
    }
}

/// `core.square`: a square wave.
#[derive(Debug, Default)]
pub struct Square {
    start: Option<kairos_sdk::Timestamp>,
}

impl Square {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        generator(
            "core.square",
            "A square wave between offset − amplitude and offset + amplitude",
        )
        .output("out", DataType::F64, "The wave")
        .property(rate_property(100.0))
        .property(
            Property::f64("frequency", 1.0)
                .range(0.0, 50_000.0)
                .live()
                .doc("Wave frequency (Hz)"),
        )
        .property(
            Property::f64("amplitude", 1.0)
                .live()
                .doc("Half the peak-to-peak swing"),
        )
        .property(Property::f64("offset", 0.0).live().doc("Added to every value"))
        .property(
            Property::f64("duty", 0.5)
                .range(0.0, 1.0)
                .live()
                .doc("Fraction of each period spent high"),
        )
        .build()
    }
}

impl Component for Square {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        follow_rate("rate", ctx)
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let now = ctx.now();
        let start = *self.start.get_or_insert(now);
        let t = now.nanos_since(start) as f64 * 1e-9;
        let phase = (ctx.f64_property("frequency")? * t).fract();
        let sign = if phase < ctx.f64_property("duty")? {
            1.0
        } else {
            -1.0
        };
        let value = ctx.f64_property("offset")? + sign * ctx.f64_property("amplitude")?;
        ctx.write("out", Payload::F64(value))
    }

    fn property_changed(&mut self, name: &str, _value: &Value, ctx: &mut Context) -> ComponentResult {
        follow_rate(name, ctx)
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
        )
        .output("out", DataType::I64, "The count")
        .property(rate_property(10.0))
        .property(Property::i64("start", 0).doc("The first value"))
        .property(Property::i64("step", 1).live().doc("Added at each sample"))
        .action("reset", "Starts counting again from `start`")
        .build()
    }
}

impl Component for Counter {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        follow_rate("rate", ctx)
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let value = match self.next {
            Some(value) => value,
            None => ctx.i64_property("start")?,
        };
        ctx.write("out", Payload::I64(value))?;
        self.next = Some(value.wrapping_add(ctx.i64_property("step")?));
        Ok(())
    }

    fn property_changed(&mut self, name: &str, _value: &Value, ctx: &mut Context) -> ComponentResult {
        follow_rate(name, ctx)
    }

    fn action(&mut self, name: &str, _ctx: &mut Context) -> ComponentResult {
        match name {
            "reset" => {
                self.next = None;
                Ok(())
            }
            other => Err(kairos_sdk::ComponentError::failed(format_args!(
                "no action '{other}'"
            ))),
        }
    }
}

/// `core.constant`: the same value at a fixed rate.
#[derive(Debug, Default)]
pub struct Constant;

impl Constant {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        generator("core.constant", "A constant value, repeated at a fixed rate")
            .output("out", DataType::F64, "The value")
            .property(rate_property(10.0))
            .property(Property::f64("value", 0.0).live().doc("The value written"))
            .build()
    }
}

impl Component for Constant {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        follow_rate("rate", ctx)
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let value = ctx.f64_property("value")?;
        ctx.write("out", Payload::F64(value))
    }

    fn property_changed(&mut self, name: &str, _value: &Value, ctx: &mut Context) -> ComponentResult {
        follow_rate(name, ctx)
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
        )
        .output("out", DataType::F64, "The numbers")
        .property(rate_property(10.0))
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

impl Component for Random {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.rng = Some(NoiseRng::new(ctx.i64_property("seed")?, 0));
        follow_rate("rate", ctx)
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let rng = self.rng.get_or_insert_with(|| NoiseRng::new(1, 0));
        let value = if ctx.text_property("distribution")? == "normal" {
            ctx.f64_property("mean")? + ctx.f64_property("std_dev")? * rng.gaussian()
        } else {
            let (min, max) = (ctx.f64_property("min")?, ctx.f64_property("max")?);
            min + (max - min) * rng.uniform()
        };
        ctx.write("out", Payload::F64(value))
    }

    fn property_changed(&mut self, name: &str, _value: &Value, ctx: &mut Context) -> ComponentResult {
        follow_rate(name, ctx)
    }
}

/// `core.timer`: ticks at a fixed rate, to trigger or resample other components.
#[derive(Debug, Default)]
pub struct Timer {
    ticks: i64,
    start: Option<kairos_sdk::Timestamp>,
}

impl Timer {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        generator(
            "core.timer",
            "Ticks at a fixed rate; connect it to a triggered or Sampling reader to resample",
        )
        .output("tick", DataType::I64, "The tick number, from 0")
        .output("elapsed", DataType::F64, "Seconds since the first tick")
        .property(rate_property(10.0))
        .build()
    }
}

impl Component for Timer {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        follow_rate("rate", ctx)
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        if self.start.is_none() {
            self.start = Some(ctx.now());
        }
        let elapsed = elapsed_secs(ctx, self.start);
        ctx.write("tick", Payload::I64(self.ticks))?;
        ctx.write("elapsed", Payload::F64(elapsed))?;
        self.ticks += 1;
        Ok(())
    }

    fn property_changed(&mut self, name: &str, _value: &Value, ctx: &mut Context) -> ComponentResult {
        follow_rate(name, ctx)
    }
}

/// Registers the generators.
pub fn register(pack: &mut PackRegistrar<'_>) {
    pack.component::<Sine>(Sine::info())
        .component::<Square>(Square::info())
        .component::<Counter>(Counter::info())
        .component::<Constant>(Constant::info())
        .component::<Random>(Random::info())
        .component::<Timer>(Timer::info());
}
