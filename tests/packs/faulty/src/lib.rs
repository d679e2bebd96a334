//! A pack for the loader's tests, built both into a test runtime and as a library: components that
//! misbehave on purpose (a constructor that panics, a component that panics on its third sample, a type
//! registered under another pack's name) and one that reports what its context tells it, so the same
//! component can be compared built in and loaded.

use std::sync::Arc;

use kairos_sdk::descriptor::Descriptor;
use kairos_sdk::{Component, ComponentResult, Context, DataType, Payload, Registry, TypeFilter};

/// Panics when constructed.
#[derive(Debug)]
pub struct BadConstructor;

impl Default for BadConstructor {
    fn default() -> Self {
        panic!("this constructor always panics");
    }
}

impl Component for BadConstructor {
    fn core(&mut self, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}

/// Passes samples on, and panics on the third.
#[derive(Debug, Default)]
pub struct PanicsOnThird {
    seen: u32,
}

impl Component for PanicsOnThird {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        self.seen += 1;
        assert!(self.seen < 3, "the third sample is one too many");
        ctx.forward("out", &sample)
    }
}

/// Claims a type name the core pack owns.
#[derive(Debug, Default)]
pub struct FakeGain;

impl Component for FakeGain {
    fn core(&mut self, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}

/// For every sample it reads, writes what its context says: its id, its input's source and link
/// counters, whether it knows its diagram and the clock; its status counts the samples it handled,
/// published by the runtime (or the pack library's shim).
#[derive(Debug, Default)]
pub struct ContextProbe {
    handled: u64,
}

impl Component for ContextProbe {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let source = ctx.inputs().first().and_then(|i| i.source()).unwrap_or("nothing");
        let read = ctx.input_counters("in").map_or(0, |c| c.read);
        let diagram = ctx.diagram_text().map_or(0, |text| text.len());
        let clock = ctx.clock_description();
        let report = format!(
            "{} reads {source}: {read} read; diagram of {diagram} bytes; clock {}",
            ctx.id(),
            clock.split(" (").next().unwrap_or_default(),
        );
        tracing::info!("{report}");
        self.handled += 1;
        ctx.write_processed("out", &sample, Payload::Text(Arc::from(report)))
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({ "handled": self.handled }))
    }
}

/// Registers the pack "faulty".
pub fn register(registry: &mut Registry) {
    registry
        .pack("faulty", "0.1.0", "built-in")
        .component::<BadConstructor>(
            Descriptor::new("faulty.bad_constructor", "test", "Panics when constructed").build(),
        )
        .component::<PanicsOnThird>(
            Descriptor::new("faulty.panics_on_third", "test", "Panics on its third sample")
                .input("in", TypeFilter::Any, "Any stream")
                .output("out", DataType::F64, "The input, until it panics")
                .build(),
        )
        .component::<ContextProbe>(
            Descriptor::new(
                "faulty.context_probe",
                "test",
                "Writes what its context says of it for every sample it reads",
            )
            .input("in", TypeFilter::Any, "Any stream")
            .output("out", DataType::Text, "One report per sample read")
            .build(),
        )
        .component::<FakeGain>(
            Descriptor::new(
                "core.gain",
                "test",
                "A second component claiming the core pack's type name",
            )
            .input("in", TypeFilter::Any, "")
            .build(),
        );
}

kairos_sdk::export_pack!(register);
