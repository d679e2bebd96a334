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

pub use engine::{BuildError, ControlError, Engine, EngineState, LongWait};

use std::sync::Arc;

use kairos_sdk_core::{Clock, DisciplinedClock, RealTimeClock};

/// The clock a diagram runs on: real time, or real time disciplined by its `clock_source`.
pub fn clock_for(diagram: &kairos_diagram::Diagram) -> Arc<dyn Clock> {
    match &diagram.clock_source {
        Some(source) => Arc::new(DisciplinedClock::new(source.clone())),
        None => RealTimeClock::shared(),
    }
}
pub use packs::{PackScan, RefusedLibrary, load_packs, pack_path};
pub use stats::{ComponentState, ComponentStats, GroupStats, LinkStats, StatsSnapshot};
