//! The Kairos engine: turns a validated diagram into running components, each in its own thread
//! (or reactive, in its producer's), moving samples through per-output circular buffers, and keeps
//! per-link and per-component statistics.

pub mod engine;
pub mod pack_host;
pub mod packs;
pub mod scheduling;
pub mod stats;

pub use engine::{BuildError, ControlError, Engine, EngineState, LongWait, link_name};
pub use packs::{PackScan, RefusedLibrary, load_packs, pack_path};
pub use stats::{ComponentState, ComponentStats, LinkStats, StatsSnapshot};
