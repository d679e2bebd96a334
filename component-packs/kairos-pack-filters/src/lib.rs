//! Signal filters, shipped as a pack that loads at run time: build it and point the runtime at
//! `target/<profile>/` (or copy the library into a pack folder):
//!
//! ```sh
//! cargo build --release -p kairos-pack-filters
//! kairos --pack-path target/release packs
//! ```
//!
//! | type | what it does |
//! | --- | --- |
//! | `filters.low_pass` | first-order low-pass filter with a time constant, exact for any sample spacing |
//! | `filters.derivative` | rate of change between consecutive samples, per second |

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, Payload, Registry, Sample,
    Timestamp, TypeFilter,
};

fn number(sample: &Sample) -> Result<f64, ComponentError> {
    sample.payload.as_f64().ok_or_else(|| {
        ComponentError::failed(format_args!(
            "expected a number, got {}",
            sample.payload.data_type()
        ))
    })
}

fn numeric() -> TypeFilter {
    TypeFilter::OneOf(vec![DataType::F64, DataType::I64, DataType::Bool])
}

/// `filters.low_pass`: `y += (1 − e^(−Δt/τ)) (x − y)`, with Δt taken from the samples' timestamps.
#[derive(Debug, Default)]
pub struct LowPass {
    state: Option<(f64, Timestamp)>,
}

impl LowPass {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "filters.low_pass",
            "filters",
            "First-order low-pass filter; the time step comes from the timestamps",
        )
        .label("Low-pass filter")
        .input("in", numeric(), "The signal")
        .output("out", DataType::F64, "The smoothed signal, same timestamps")
        .property(
            Property::f64("time_constant_s", 0.1)
                .unit("s")
                .range(0.0, 3600.0)
                .live()
                .doc("τ in seconds; 0 passes the input through"),
        )
        .action("reset", "Forgets the filter's state")
        .build()
    }
}

impl Component for LowPass {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let x = number(&sample)?;
        let tau = ctx.f64_property("time_constant_s")?;
        let y = match self.state {
            Some((y, last)) if tau > 0.0 => {
                let dt = sample.timestamp.nanos_since(last).max(0) as f64 * 1e-9;
                y + (1.0 - (-dt / tau).exp()) * (x - y)
            }
            _ => x,
        };
        self.state = Some((y, sample.timestamp));
        ctx.write_processed("out", &sample, Payload::F64(y))
    }

    fn action(&mut self, name: &str, _ctx: &mut Context) -> ComponentResult {
        if name == "reset" {
            self.state = None;
            return Ok(());
        }
        Err(ComponentError::failed(format_args!("no action '{name}'")))
    }
}

/// `filters.derivative`: (x₁ − x₀) / (t₁ − t₀).
#[derive(Debug, Default)]
pub struct Derivative {
    last: Option<(f64, Timestamp)>,
}

impl Derivative {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "filters.derivative",
            "filters",
            "Rate of change between consecutive samples, per second",
        )
        .label("Derivative")
        .input("in", numeric(), "The signal")
        .output(
            "out",
            DataType::F64,
            "d(in)/dt, stamped with the newer sample's timestamp",
        )
        .build()
    }
}

impl Component for Derivative {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let x = number(&sample)?;
        if let Some((previous, at)) = self.last {
            let dt = sample.timestamp.nanos_since(at) as f64 * 1e-9;
            if dt > 0.0 {
                ctx.write_processed("out", &sample, Payload::F64((x - previous) / dt))?;
            }
        }
        self.last = Some((x, sample.timestamp));
        Ok(())
    }
}

/// Registers the pack "filters".
pub fn register(registry: &mut Registry) {
    registry
        .pack("filters", env!("CARGO_PKG_VERSION"), "built-in")
        .component::<LowPass>(LowPass::info())
        .component::<Derivative>(Derivative::info());
}

kairos_sdk::export_pack!(register);

#[cfg(test)]
mod tests {
    use kairos_sdk::harness::Harness;

    use super::*;

    #[test]
    fn low_pass_follows_a_step_with_its_time_constant() {
        let mut harness = Harness::new(LowPass::info(), LowPass::default());
        harness.set_property("time_constant_s", 1.0).unwrap();
        for second in 0..=3 {
            harness.push("in", Payload::F64(1.0), Timestamp::from_millis(second * 1000));
        }
        let out = harness.run().unwrap().f64_values("out");
        let expected = [1.0, 1.0, 1.0, 1.0];
        assert_eq!(out, expected, "a constant input stays constant");

        let mut harness = Harness::new(LowPass::info(), LowPass::default());
        harness.set_property("time_constant_s", 1.0).unwrap();
        harness.push("in", Payload::F64(0.0), Timestamp::from_millis(0));
        harness.push("in", Payload::F64(1.0), Timestamp::from_millis(1000));
        let out = harness.run().unwrap().f64_values("out");
        assert!((out[1] - (1.0 - (-1.0_f64).exp())).abs() < 1e-12, "{out:?}");
    }

    #[test]
    fn derivative_of_a_ramp_is_its_slope() {
        let mut harness = Harness::new(Derivative::info(), Derivative::default());
        for step in 0..5 {
            harness.push(
                "in",
                Payload::F64(3.0 * step as f64),
                Timestamp::from_millis(step * 500),
            );
        }
        let out = harness.run().unwrap().f64_values("out");
        assert_eq!(out, vec![6.0; 4]);
    }
}
