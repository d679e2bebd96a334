//! The Kairos engine: turns a validated diagram into running components, each in its own thread
//! (or reactive, in its producer's), moving samples through per-output circular buffers, and keeps
//! per-link and per-component statistics.

pub mod engine;
mod group;
pub mod pack_host;
pub mod packs;
pub mod python_host;
pub mod scheduling;
mod start_gate;
pub mod stats;
mod stop_order;

pub use engine::{BuildError, ControlError, Engine, EngineState, LongWait};

use std::sync::Arc;

use kairos_sdk_core::{Clock, DisciplinedClock, RealTimeClock, Registry, SimulatedClock, Timestamp};

/// The clock a diagram runs on: real time; real time disciplined by its `clock_source`; or, when that
/// source is a simulator, its simulated time (from its `start_time`, at its `time_scale`).
pub fn clock_for(diagram: &kairos_diagram::Diagram, registry: &Registry) -> Arc<dyn Clock> {
    let Some(source) = &diagram.clock_source else {
        return RealTimeClock::shared();
    };
    let simulator = diagram.component(source).and_then(|instance| {
        let info = &registry.component(&instance.type_name)?.info;
        info.simulated_time.then_some((instance, info))
    });
    match simulator {
        Some((instance, info)) => {
            let number = |name: &str| {
                info.property_value(&instance.properties, name)
                    .and_then(kairos_diagram::Value::as_f64)
                    .unwrap_or(0.0)
            };
            Arc::new(SimulatedClock::new(
                Timestamp::from_secs_f64(number("start_time")),
                number("time_scale"),
            ))
        }
        None => Arc::new(DisciplinedClock::new(source.clone())),
    }
}
pub use packs::{PackScan, RefusedLibrary, load_packs, pack_path};
pub use stats::{ComponentState, ComponentStats, GroupStats, LinkStats, StatsSnapshot};
