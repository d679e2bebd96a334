//! A pack that misbehaves on purpose: a constructor that panics, a component that panics on its third
//! sample, and a component type that another pack already offers.

use kairos_sdk::descriptor::Descriptor;
use kairos_sdk::{Component, ComponentResult, Context, DataType, Registry, TypeFilter};

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
